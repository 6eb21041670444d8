"""The desktop application: documents without a window, widgets through qtbot, real windows under Xvfb.

Run under ``xvfb-run -a -s "-screen 0 1600x1200x24"``; the window tests are skipped without a display.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from citylod.app.models import Document
from citylod.core.camera import Camera, load_cameras

needs_display = pytest.mark.skipif(not os.environ.get("DISPLAY"), reason="needs an X display (xvfb-run)")


# ------------------------------------------------------------------------------------------ fixtures
@pytest.fixture(scope="session")
def sample(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A tiny sample city: DSM tileset (textured) and its city store."""
    from citylod.lod.build.dsm import build_dsm
    from citylod.sample.files import make_sample

    out = tmp_path_factory.mktemp("app_sample")
    info = make_sample(out / "src", size=97)
    build_dsm(info.files["dsm"], out / "dsm_tiles", ortho=info.files["ortho"], workers=0, progress=False,
              tile_size=33)
    files = {"tiles": out / "dsm_tiles", "camera": info.files["camera"], "dsm": info.files["dsm"],
             "city_gml": info.files["city"]}
    from citylod.semantics.store import build_city

    build_city(info.files["city"], out / "city.gpkg", progress=False)
    files["store"] = out / "city.gpkg"
    return files


@pytest.fixture()
def qsettings(tmp_path: Path):
    from PySide6.QtCore import QSettings

    return QSettings(str(tmp_path / "citylod.ini"), QSettings.Format.IniFormat)


@pytest.fixture()
def window(qtbot, qsettings):
    from citylod.app.qt_main_window import MainWindow

    win = MainWindow(settings_=qsettings, interactive=False)
    qtbot.addWidget(win)
    win.resize(1200, 800)
    win.show()
    qtbot.waitExposed(win)
    yield win
    win.close()


def _store(sample: dict[str, Path]) -> Path:
    if "store" not in sample:
        pytest.skip("city store build not available")
    return sample["store"]


def _rgb(image) -> np.ndarray:
    from PySide6.QtGui import QImage

    img = image.convertToFormat(QImage.Format.Format_RGB888)
    w, h, bpl = img.width(), img.height(), img.bytesPerLine()
    arr = np.frombuffer(img.constBits(), np.uint8, count=h * bpl).reshape(h, bpl)[:, : w * 3]
    return arr.reshape(h, w, 3).copy()


# --------------------------------------------------------------------------- document (no window)
def test_document_layer_actions(sample) -> None:
    doc = Document(workers=1)
    try:
        entry = doc.open(sample["tiles"])
        layer = entry.layer
        seen = []
        doc.on_change(seen.append)
        doc.set_visible(0, False)
        assert layer.visible is False
        doc.set_tau(4.0)
        assert layer.tau_px == 4.0 and doc.scene.tau_px == 4.0
        doc.set_color_by(0, "elevation")
        assert layer.color_by == "elevation"
        doc.set_color_by_level(True)
        assert layer.color_by == "level"
        doc.set_color_by_level(False)
        assert layer.color_by == "elevation"
        doc.set_point_budget(1000)
        assert layer.budget.max_points == 1000
        doc.set_memory_budget(64)
        assert doc.scene.cache.budget_bytes == 64 << 20
        doc.set_frozen(True)
        assert doc.scene.frozen
        assert seen == ["style", "lod", "style", "lod", "lod", "lod", "lod", "lod"]
        with pytest.raises(Exception, match="built"):
            doc.open(sample["dsm"])
    finally:
        doc.close()


def test_document_queries_and_picking(sample) -> None:
    store_path = _store(sample)
    doc = Document(workers=1)
    try:
        doc.open(store_path)
        groups = doc.object_groups()
        assert sum(len(v) for v in groups.values()) == len(doc.store)
        ids = doc.run_sql("type = 'Building'")
        assert ids and doc.results == ids
        doc.highlight()
        assert set(doc.state.colors) == set(ids)
        doc.isolate(ids[:1])
        assert (doc.state.is_visible(ids[0]) and not doc.state.is_visible(ids[-1])) or len(ids) == 1
        doc.clear_state()
        tallest = doc.tallest_building()
        assert tallest in ids
        # Pick the centre of the tallest proxy: the document selects that object.
        import shapely

        px = doc.store.proxies
        i = px.index_of(tallest)
        inside = shapely.point_on_surface(px.footprints[i])
        centre = np.array([inside.x, inside.y, (px.zmin[i] + px.zmax[i]) / 2])
        assert doc.object_at(centre) == tallest
        assert doc.pick(centre) == tallest and doc.state.selection == {tallest}
        assert doc.pick(None) is None and doc.state.selection == set()
    finally:
        doc.close()


# ------------------------------------------------------------------------------------- widgets
def test_layer_panel_toggles_visibility(qtbot, sample) -> None:
    from citylod.app.qt_panels import LayerPanel

    doc = Document(workers=1)
    panel = LayerPanel(doc)
    qtbot.addWidget(panel)
    try:
        doc.open(sample["tiles"])
        assert len(panel.rows) == 1
        check, slider, combo = panel.rows[0]
        check.setChecked(False)
        assert doc.entries[0].layer.visible is False
        slider.setValue(40)
        assert doc.entries[0].opacity == pytest.approx(0.4)
        combo.setCurrentText("level")
        assert doc.entries[0].layer.color_by == "level"
    finally:
        doc.close()


def test_lod_panel_sets_tau(qtbot, sample) -> None:
    from citylod.app.models import tau_to_slider
    from citylod.app.qt_panels import LodPanel

    doc = Document(workers=1)
    try:
        doc.open(sample["tiles"])
        panel = LodPanel(doc)
        qtbot.addWidget(panel)
        panel.tau.setValue(tau_to_slider(8.0))
        assert doc.entries[0].layer.tau_px == pytest.approx(8.0, rel=0.01)
        assert panel.tau_label.text() == f"{doc.entries[0].layer.tau_px:.2f} px"
        panel.freeze.setChecked(True)
        assert doc.scene.frozen
        panel.points.setValue(250_000)
        assert doc.entries[0].layer.budget.max_points == 250_000
    finally:
        doc.close()


def test_query_panel_runs_sql_with_history(qtbot, sample, qsettings) -> None:
    store_path = _store(sample)
    from citylod.app.qt_panels import QueryPanel

    doc = Document(workers=1)
    try:
        doc.open(store_path)
        panel = QueryPanel(doc, qsettings)
        qtbot.addWidget(panel)
        assert panel.kind.currentText() == "sql"
        panel.edit.setPlainText("type = 'Building'")
        ids = panel.run()
        assert ids and panel.results.topLevelItemCount() == len(ids)
        # Attribute columns next to the id, from the store (one row per object).
        header = [panel.results.headerItem().text(c) for c in range(panel.results.columnCount())]
        assert header[:2] == ["object_id", "type"] and "measured_height" in header
        first = panel.results.topLevelItem(0)
        attrs = doc.store.attributes(first.text(0))
        assert first.text(1) == str(attrs["type"])
        assert first.text(header.index("measured_height")) == str(attrs["measured_height"])
        assert qsettings.value("query/history") == ["type = 'Building'"]
        panel.buttons["Highlight"].click()
        assert set(doc.state.colors) == set(ids)
        panel.buttons["Hide"].click()
        assert doc.state.hidden == set(ids)
        panel.edit.setPlainText("no_such_column = 1")
        assert panel.run() is None
        assert "bad query" in panel.message.text()
        # The history survives a new panel (QSettings).
        again = QueryPanel(doc, qsettings)
        qtbot.addWidget(again)
        assert again.history.items == ["type = 'Building'"]
    finally:
        doc.close()


def test_plugin_query_shows_its_parameters(qtbot, sample, qsettings) -> None:
    """Choosing a registered query by keyboard puts a JSON template of its parameters in the box; filled in
    by typing and run with a click, it finds the objects an independent footprint-distance test finds."""
    import json

    import shapely
    from PySide6.QtCore import Qt

    from citylod.app.qt_panels import QueryPanel
    from citylod.semantics.store import CityStore

    store_path = _store(sample)
    doc = Document(workers=1)
    try:
        doc.open(store_path)
        panel = QueryPanel(doc, qsettings)
        qtbot.addWidget(panel)
        panel.show()
        qtbot.waitExposed(panel)
        panel.kind.setFocus()
        qtbot.keyClicks(panel.kind, "distance")
        assert panel.kind.currentText() == "distance"
        template = json.loads(panel.edit.toPlainText())
        assert set(template) == {"point", "distance"}
        assert "point" in panel.edit.placeholderText() and panel.edit.toolTip()
        store = CityStore.open(store_path)
        shapes = store.proxies.shapes
        cx, cy = shapely.centroid(shapes[0]).coords[0]
        store.close()
        panel.edit.clear()
        qtbot.keyClicks(panel.edit, json.dumps({"point": [cx, cy], "distance": 30.0}))
        qtbot.mouseClick(panel.run_button, Qt.MouseButton.LeftButton)
        got = {panel.results.topLevelItem(i).text(0) for i in range(panel.results.topLevelItemCount())}
        # Proxies are footprints grown by ``inflate``: sure inside within 30 m - inflate of the proxy, sure
        # outside beyond 30 m of it, whichever of the two the query measures to.
        d = shapely.distance(shapes, shapely.Point(cx, cy))
        ids = np.asarray(store.ids)
        assert got and set(ids[d <= 30.0 - store.inflate]) <= got
        assert not got & set(ids[d > 30.0])
    finally:
        doc.close()


def test_tree_and_inspector_follow_selection(qtbot, sample) -> None:
    store_path = _store(sample)
    from citylod.app.qt_panels import AttributePanel, ObjectTreePanel

    doc = Document(workers=1)
    tree = ObjectTreePanel(doc)
    inspector = AttributePanel(doc)
    qtbot.addWidget(tree)
    qtbot.addWidget(inspector)
    try:
        doc.open(store_path)
        oid = doc.store.ids[0]
        doc.select([oid])  # e.g. a pick in the view
        assert tree.selected_ids() == [oid]
        assert inspector.object_id == oid
        assert "object_id" in inspector.as_text()
        # Selecting in the tree selects in the feature state.
        other = doc.store.ids[1]
        tree.tree.selectionModel().clearSelection()
        from PySide6.QtCore import QItemSelectionModel

        tree.tree.selectionModel().select(tree._items[other].index(),
                                          QItemSelectionModel.SelectionFlag.Select
                                          | QItemSelectionModel.SelectionFlag.Rows)
        assert doc.state.selection == {other}
        assert inspector.object_id == other
    finally:
        doc.close()


def test_bookmarks_persist(qtbot, qsettings) -> None:
    from citylod.app.qt_panels import BookmarkPanel

    current = [Camera((0.0, -50.0, 30.0), (0.0, 0.0, 0.0))]
    restored = []
    panel = BookmarkPanel(lambda: current[0], restored.append, qsettings)
    qtbot.addWidget(panel)
    assert panel.add("overview") == "overview"
    again = BookmarkPanel(lambda: None, restored.append, qsettings)
    qtbot.addWidget(again)
    assert again.bookmarks.names() == ["overview"]
    assert again.restore("overview") and restored == [current[0]]


# ------------------------------------------------------------------------------------ real windows
def _wait_resolved(qtbot, win, timeout_ms: int = 60000) -> None:
    def done() -> None:
        win.view.render_now()
        assert win.view.is_resolved()

    qtbot.waitUntil(done, timeout=timeout_ms)


@needs_display
def test_window_screenshot_shows_terrain(qtbot, window, sample, tmp_path) -> None:
    assert window.open_path(sample["tiles"])
    window.view.set_camera(load_cameras(sample["camera"])[0])
    _wait_resolved(qtbot, window)
    assert window.document.scene.last_stats.tiles > 0
    out = window.save_screenshot(tmp_path / "window.png")
    assert out.is_file()
    rgb = _rgb(window.grab_window())
    pos, size = window.view.origin_in(window), window.view.vtk.size()
    view = rgb[pos.y(): pos.y() + size.height(), pos.x(): pos.x() + size.width()].astype(int)
    assert view.shape[0] > 100 and view.shape[1] > 100
    # Not black (a plain grab of the GL child would be), not uniform background.
    assert view.mean() > 40
    assert view.reshape(-1, 3).std(axis=0).max() > 15
    background = np.array([0.72, 0.80, 0.90]) * 255
    terrain = np.abs(view - background).sum(axis=2) > 40
    assert terrain.mean() > 0.3, "the 3D view should mostly show terrain from the sample camera"
    # The bottom half of the view (the near ground) is terrain-coloured: greener/redder than the sky.
    bottom = view[view.shape[0] // 2:]
    assert (np.abs(bottom - background).sum(axis=2) > 40).mean() > 0.6
    # Window chrome is grabbed too: the menu bar area is light grey, not the 3D view.
    assert rgb[: 10, : 50].mean() > 150


@needs_display
def test_the_view_has_most_of_the_window_and_no_button_is_cut(qtbot, qsettings) -> None:
    """At first start (no saved layout, the default 1400 px wide window), the 3D view takes more than half
    the window's width (the side columns were 342 and 432 px, leaving it 614), and every button of the shown
    panels lies wholly inside its dock."""
    from PySide6.QtCore import QRect
    from PySide6.QtWidgets import QPushButton

    from citylod.app.qt_main_window import MainWindow

    win = MainWindow(settings_=qsettings, interactive=False)
    qtbot.addWidget(win)
    win.show()
    qtbot.waitExposed(win)
    qtbot.wait(200)
    assert win.width() >= 1400
    assert win.view.width() >= 0.55 * win.width(), (win.view.width(), win.width())
    shown = 0
    for dock in win.docks.values():
        if not dock.isVisible() or dock.visibleRegion().isEmpty():
            continue  # a tab behind another
        for b in dock.findChildren(QPushButton):
            if b.isVisible():
                r = QRect(b.mapTo(dock, b.rect().topLeft()), b.size())
                assert dock.rect().contains(r), (dock.windowTitle(), b.text(), r, dock.rect())
                shown += 1
    assert shown >= 8
    win.close()


@needs_display
def test_window_pick_measure_and_camera(qtbot, window, sample, tmp_path) -> None:
    window.open_path(sample["tiles"])
    window.view.set_camera(load_cameras(sample["camera"])[0])
    _wait_resolved(qtbot, window)
    vw, vh = window.view.vtk.width(), window.view.vtk.height()
    p1 = window.view.pick_point(vw // 2, int(vh * 0.75))
    p2 = window.view.pick_point(vw // 3, int(vh * 0.85))
    assert p1 is not None and p2 is not None
    lo, hi = window.document.bounds()
    assert np.all(p1 >= lo - 1) and np.all(p1 <= hi + 1)
    window.start_measure("distance")
    window.view.add_measure_point(p1)
    m = window.view.add_measure_point(p2)
    assert m.value == pytest.approx(float(np.linalg.norm(p2 - p1)))
    assert window.measure.text.startswith("distance")
    window.measure.copy()
    from PySide6.QtGui import QGuiApplication

    assert QGuiApplication.clipboard().text() == m.text()
    # Fly and reset move the camera; the saved camera is what `citylod render` reads.
    before = window.view.camera()
    window.actions["fly_forward"].trigger()
    assert window.view.camera().position != before.position
    window.actions["reset"].trigger()
    window.save_camera(tmp_path / "cam.json")
    cam = load_cameras(tmp_path / "cam.json")[0]
    np.testing.assert_allclose(cam.position, window.view.camera().position, atol=1e-6)
    dlg = window.show_shortcuts()
    assert dlg.findChild(type(dlg.children()[-1])) is not None
    dlg.close()


@needs_display
def test_window_with_store_highlight_and_pick(qtbot, window, sample) -> None:
    store_path = _store(sample)
    window.open_path(sample["tiles"])
    window.open_path(store_path)
    doc = window.document
    tallest = doc.tallest_building()
    doc.highlight([tallest], "#ff3300")
    assert window.view.frame_objects([tallest])
    # Look straight at a point of the roof, so the centre pixel is on the building.
    import shapely

    from citylod.app.models import focus_on

    px = doc.store.proxies
    i = px.index_of(tallest)
    inside = shapely.point_on_surface(px.footprints[i])
    window.view.set_camera(focus_on(window.view.camera(), (inside.x, inside.y, px.zmax[i] - px.inflate)))
    _wait_resolved(qtbot, window)
    # Click the middle of the view: the pick selects the building there.
    vw, vh = window.view.vtk.width(), window.view.vtk.height()
    x, y = window.view._display_xy(vw // 2, vh // 2)
    window.view.click_display(x, y)
    assert doc.state.selection == {tallest}
    assert window.tree.selected_ids() == [tallest]
    assert window.inspector.object_id == tallest


def test_cli_view_screenshot_exit(sample, tmp_path) -> None:
    if not os.environ.get("DISPLAY"):
        pytest.skip("needs an X display (xvfb-run)")
    out = tmp_path / "shot.png"
    env = dict(os.environ, XDG_CONFIG_HOME=str(tmp_path / "config"))
    r = subprocess.run([sys.executable, "-m", "citylod.cli", "view", str(sample["tiles"]), "--camera",
                        str(sample["camera"]), "--screenshot", str(out), "--exit"],
                       capture_output=True, text=True, timeout=180, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    assert out.is_file()
    from PySide6.QtGui import QImage

    img = _rgb(QImage(str(out)))
    assert img.shape[0] > 300 and img.shape[1] > 400
    centre = img[img.shape[0] // 3: 2 * img.shape[0] // 3, img.shape[1] // 3: 2 * img.shape[1] // 3]
    assert centre.reshape(-1, 3).std(axis=0).max() > 15 and centre.mean() > 40

