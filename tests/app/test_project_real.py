"""Project files through the real menus: save a set-up window with File > Save project (keys, the file
dialog typed into), open it in a fresh window with File > Open project, and check that the second window
shows the same thing: layers and their display, camera, bookmarks, highlighted and hidden objects, and the
same picture. Run under ``xvfb-run -a -s "-screen 0 1600x1200x24"`` (xdotool sends the input)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from tests.app.test_qt import _rgb, _store, sample  # noqa: F401  (the session fixture)
from tests.app.test_real_input import X, _wait_resolved, pytestmark, window, xin  # noqa: F401

__all__ = ["pytestmark"]

#: Calls of :func:`_menu_then_type` so far: a call's last-resort sweep leaves the dialogs of later calls be.
_calls = [0]


def _menu_then_type(xin: X, win, keys: list[str], *texts: str | None) -> None:  # noqa: F811
    """Press ``keys`` (a shortcut, or a menu's mnemonic and an item's), then answer the dialogs that open,
    one after the other: type each text into its dialog and press Enter (None: just Enter). A dialog runs
    its own event loop inside the key's handler, so a timer in that loop finds it, gives it the focus
    (Xvfb has no window manager to do so) and sends the keys."""
    import subprocess

    import shiboken6
    from PySide6.QtCore import QTimer
    from PySide6.QtWidgets import QAbstractSpinBox, QApplication, QLineEdit

    done: list[bool] = []
    seen: list[object] = []

    def answer() -> None:
        dlg = QApplication.activeModalWidget()
        # A dialog is modal as soon as its exec() starts, before X has mapped it: a click sent then lands on
        # the window below it (a cold or loaded machine), so wait until it is on screen.
        handle = dlg.windowHandle() if dlg is not None else None
        if dlg is None or (seen and dlg is seen[-1]) or handle is None or not handle.isExposed():
            if len(done) < len(texts):
                QTimer.singleShot(200, answer)
            return
        seen.append(dlg)
        dlg.activateWindow()
        dlg.raise_()
        # Xvfb has no window manager to give the new dialog the keyboard: a real click into its text field
        # (the file name, or the first editable field) does.
        field = dlg.findChild(QLineEdit, "fileNameEdit") or dlg.findChild(QAbstractSpinBox) \
            or dlg.findChild(QLineEdit)
        target = field if field is not None else dlg
        g = target.mapToGlobal(target.rect().center())
        text = texts[len(done)]
        steps = [["sleep", "0.3", "mousemove", "--sync", str(g.x()), str(g.y()), "click", "1"]]
        if text is not None:
            steps += [["sleep", "0.2", "key", "--clearmodifiers", "ctrl+a"], ["type", "--delay", "15", text]]
        for args in [*steps, ["sleep", "0.3", "key", "Return"]]:
            subprocess.run(["xdotool", *args], check=True, timeout=60)
        index = len(done)
        done.append(True)

        def closed() -> None:  # the keys went elsewhere: fail, and never leave the dialog open
            if shiboken6.isValid(dlg) and dlg.isVisible():  # a static dialog is deleted once closed
                done[index] = False
                dlg.reject()

        def enter_again() -> None:
            # A file dialog's completion list can appear late on a loaded machine and take the first Enter
            # (it accepts the completion); a user who sees the dialog still open presses Enter again.
            if shiboken6.isValid(dlg) and dlg.isVisible():
                subprocess.run(["xdotool", "key", "Return"], check=True, timeout=60)

        QTimer.singleShot(4000, enter_again)
        QTimer.singleShot(20000, closed)
        if len(done) < len(texts):
            QTimer.singleShot(200, answer)

    def give_up() -> None:  # never hang the suite on a dialog that did not get the keys
        dlg = QApplication.activeModalWidget()
        if len(done) < len(texts) and dlg is not None:
            done.append(False)
            dlg.reject()

    args = ["key", "--clearmodifiers", keys[0]]
    for k in keys[1:]:
        args += ["sleep", "0.4", "key", "--clearmodifiers", k]

    def press_again() -> None:  # the keys found no focused window (a loaded machine): press them again
        if not seen and QApplication.activeModalWidget() is None:
            win.activateWindow()
            win.raise_()
            subprocess.run(["xdotool", *args], check=True, timeout=60)

    _calls[0] += 1
    call = _calls[0]

    def sweep() -> None:
        # Last resort, never a hang: a dialog nobody answers (a second "replace the file?" box after an
        # Enter that came late on a loaded machine) is closed, innermost first, unless a later call owns it.
        for _ in range(4):
            dlg = QApplication.activeModalWidget()
            if dlg is None or _calls[0] != call:
                return
            dlg.reject()
            QApplication.processEvents()

    win.activateWindow()
    win.raise_()
    xin.qtbot.wait(200)
    QTimer.singleShot(300, answer)
    QTimer.singleShot(12000, press_again)
    QTimer.singleShot(30000, give_up)
    QTimer.singleShot(40000, sweep)
    xin._run(*args)
    xin.qtbot.waitUntil(lambda: len(done) >= len(texts), timeout=35000)
    xin.qtbot.wait(300)
    assert done == [True] * len(texts), "a dialog did not take the typed keys"


def _new_window(qtbot, tmp_path: Path):
    from PySide6.QtCore import QSettings

    from citylod.app.qt_main_window import MainWindow

    settings = QSettings(str(tmp_path / "citylod2.ini"), QSettings.Format.IniFormat)
    win = MainWindow(settings_=settings, interactive=False)
    qtbot.addWidget(win)
    win.move(0, 0)
    win.resize(1200, 800)
    win.show()
    qtbot.waitExposed(win)
    return win


def test_project_saves_and_reopens_the_same_view(qtbot, window, xin, sample, tmp_path) -> None:  # noqa: F811
    from citylod.core.camera import load_cameras

    store = _store(sample)
    assert window.open_path(sample["tiles"]) and window.open_path(store)
    doc = window.document
    cam = load_cameras(sample["camera"])[0]
    window.view.set_camera(cam)
    tallest = doc.tallest_building()
    others = [o for o in doc.store.ids if o != tallest]
    doc.highlight([tallest], "#ff3300")
    doc.hide(others[:3])
    doc.set_color_by(0, "elevation")
    doc.set_opacity(0, 0.8)
    _wait_resolved(qtbot, window)
    # A bookmark through Ctrl+B and its name dialog.
    _menu_then_type(xin, window, ["ctrl+b"], "roofs")
    qtbot.waitUntil(lambda: window.bookmarks.bookmarks.names() == ["roofs"], timeout=5000)
    # File > Save project (Alt+F, S) and the file dialog.
    target = tmp_path / "work" / "delft.citylod"
    target.parent.mkdir()
    _menu_then_type(xin, window, ["alt+f", "s"], str(target))
    qtbot.waitUntil(target.is_file, timeout=35000)  # past press_again and give_up
    data = json.loads(target.read_text())
    assert data["format"] == "citylod-project" and len(data["layers"]) == 2
    assert window.windowTitle().endswith("delft")
    before = _rgb(window.view.framebuffer())
    cam_before = window.view.camera()

    # A fresh window: File > Open project (Alt+F, J).
    other = _new_window(qtbot, tmp_path)
    try:
        _menu_then_type(xin, other, ["alt+f", "j"], str(target))
        qtbot.waitUntil(lambda: len(other.document.entries) == 2, timeout=35000)
        odoc = other.document
        assert [e.path.resolve() for e in odoc.entries] == [e.path.resolve() for e in doc.entries]
        assert [(e.visible, e.opacity, e.color_by) for e in odoc.entries] == \
            [(e.visible, e.opacity, e.color_by) for e in doc.entries]
        assert other.bookmarks.bookmarks.names() == ["roofs"]
        assert odoc.state.colors == doc.state.colors and odoc.state.hidden == doc.state.hidden
        _wait_resolved(qtbot, other)
        got = other.view.camera()
        np.testing.assert_allclose(got.position, cam_before.position, atol=1e-6)
        np.testing.assert_allclose(got.focal_point, cam_before.focal_point, atol=1e-6)
        after = _rgb(other.view.framebuffer())
        assert after.shape == before.shape
        # The same picture: nearly every pixel equal (the status text is outside the 3D view).
        diff = np.abs(after.astype(int) - before.astype(int)).max(axis=2)
        assert (diff <= 8).mean() > 0.99, f"{(diff > 8).mean():.2%} of the pixels differ"
        # The restored highlight shows: the tallest building's roof is drawn in its colour in both.
        red = (before[..., 0] > 180) & (before[..., 1] < 120)
        assert red.sum() > 50 and (after[red][:, 0] > 180).mean() > 0.95
    finally:
        other.close()


def test_project_with_a_missing_layer_is_refused_in_one_line(qtbot, window, tmp_path) -> None:  # noqa: F811
    bad = tmp_path / "bad.citylod"
    bad.write_text(json.dumps({"format": "citylod-project", "version": 1,
                               "layers": [{"path": "nowhere/tiles", "kind": "tileset"}]}))
    assert window.open_project(bad) is None
    assert window.errors and "bad.citylod" in window.errors[-1] and "does not exist" in window.errors[-1]
    assert "\n" not in window.errors[-1] and not window.document.entries


def test_export_image_keeps_what_the_view_shows(qtbot, window, xin, sample, tmp_path) -> None:  # noqa: F811
    """File > Export image (Ctrl+E, the options dialog, the file dialog): the PNG is the view at twice its
    size with its colours and the highlight, i.e. the view's own picture at a finer pixel grid."""
    from PIL import Image

    from citylod.core.camera import load_cameras

    store = _store(sample)
    assert window.open_path(sample["tiles"]) and window.open_path(store)
    doc = window.document
    window.view.set_camera(load_cameras(sample["camera"])[0])
    tallest = doc.tallest_building()
    doc.highlight([tallest], "#ff3300")
    doc.set_color_by(0, "elevation")
    _wait_resolved(qtbot, window)
    screen = _rgb(window.view.framebuffer())
    out = tmp_path / "export.png"
    _menu_then_type(xin, window, ["ctrl+e"], None, str(out))
    qtbot.waitUntil(out.is_file, timeout=20000)
    img = np.asarray(Image.open(out).convert("RGB"))
    h, w = screen.shape[:2]
    assert img.shape == (2 * h, 2 * w, 3)
    # Averaged back to the screen's grid it is the screen's picture (same tiles, same colours); the 2D
    # aids (scale bar, north arrow) are not exported, so compare away from the corners.
    small = img.reshape(h, 2, w, 2, 3).mean(axis=(1, 3))
    inner = np.s_[h // 8: h - h // 8, w // 8: w - w // 8]
    diff = np.abs(small[inner] - screen[inner].astype(float)).max(axis=2)
    assert np.median(diff) < 12 and (diff < 40).mean() > 0.9, f"median {np.median(diff):.1f}"
    # The highlighted building is in the export, in its colour, about where it is on the screen.
    red = lambda a: (a[..., 0] > 170) & (a[..., 1] < 120) & (a[..., 2] < 100)  # noqa: E731
    assert red(screen).sum() > 100
    assert abs(red(img).sum() / 4 - red(screen).sum()) < 0.25 * red(screen).sum()
    # …and the elevation colours (blue to red ramp) are there, not a grey fallback.
    assert np.std(img.reshape(-1, 3).mean(axis=1)) > 10
    shutil_copy = os.environ.get("CITYLOD_EXPORT_COPY")
    if shutil_copy:
        Image.fromarray(img).save(shutil_copy)


def test_export_points_keeps_class_colours_and_highlight(qtbot, window, xin, sample, tmp_path) -> None:  # noqa: F811
    """File > Export points (Alt+F, P, the file dialog): a LAS that laspy reads back with each point's drawn
    colour — its class colour, or the highlight colour inside the highlighted building's proxy (checked
    with shapely against the footprint) — and its class."""
    import laspy
    import shapely

    from citylod.core.camera import load_cameras
    from citylod.lod.build.points import build_points
    from citylod.render.colors import classification_rgb

    store = _store(sample)
    from citylod.semantics.store import CityStore

    with CityStore.open(store) as cs:
        px = cs.proxies
        i = int(np.argmax(px.zmax))
        foot, top, crs = px.footprints[i], float(px.zmax[i] - px.inflate), cs.crs
        zmin, zmax, inflate = float(px.zmin[i]), float(px.zmax[i]), float(px.inflate)
    x0, y0, x1, y1 = foot.bounds
    rng = np.random.default_rng(5)
    n = 4000
    las_in = tmp_path / "pts.las"
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales, header.offsets = np.array([0.01] * 3), np.array([x0, y0, 0.0])
    las = laspy.LasData(header)
    # Half on the roof of the tallest building, half on the ground around it.
    las.x = np.concatenate([rng.uniform(x0, x1, n // 2), rng.uniform(x0 - 40, x1 + 40, n // 2)])
    las.y = np.concatenate([rng.uniform(y0, y1, n // 2), rng.uniform(y0 - 40, y1 + 40, n // 2)])
    las.z = np.concatenate([np.full(n // 2, top - 0.2), np.full(n // 2, 0.3)])
    las.classification = np.concatenate([np.full(n // 2, 6, np.uint8), np.full(n // 2, 2, np.uint8)])
    las.write(str(las_in))
    tiles = tmp_path / "points_tiles"
    build_points([las_in], tiles, crs=crs, progress=False, workers=1)
    assert window.open_path(tiles) and window.open_path(store)
    doc = window.document
    doc.set_color_by(0, "classification")
    window.view.set_camera(load_cameras(sample["camera"])[0])
    window.view.reset_view()
    tallest = doc.store.proxies.object_ids[i]
    doc.highlight([tallest], "#ff0000")
    _wait_resolved(qtbot, window)
    out = tmp_path / "export.las"
    _menu_then_type(xin, window, ["alt+f", "p"], str(out))
    qtbot.waitUntil(out.is_file, timeout=20000)
    got = laspy.read(str(out))
    assert len(got.points) > 0.5 * n
    xyz = np.column_stack([got.x, got.y, got.z])
    rgb = np.column_stack([got.red, got.green, got.blue]) // 257
    cls = np.asarray(got.classification)
    # The proxy: the footprint grown by the store's inflate distance, from its lower to its upper
    # contour. Points within 5 cm of its outline are left out of the check (either side is right).
    def within(poly, lo, hi):
        return shapely.contains_xy(poly, xyz[:, 0], xyz[:, 1]) & (xyz[:, 2] >= lo) & (xyz[:, 2] <= hi)

    inside = within(foot.buffer(inflate - 0.05), zmin + 0.05, zmax - 0.05)
    outside = ~within(foot.buffer(inflate + 0.05), zmin - 0.05, zmax + 0.05)
    assert inside.sum() > 100 and outside.sum() > 100
    # Outside the highlighted building: the class colour the view draws.
    np.testing.assert_array_equal(rgb[outside], classification_rgb(cls[outside]))
    # Inside: the highlight's red (blended fully: alpha 1).
    assert (rgb[inside] == [255, 0, 0]).all(axis=1).all()
    assert set(np.unique(cls)) <= {2, 6}
