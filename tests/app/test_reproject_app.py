"""Two sources in different CRSs opened in the app through File → Open with real keys (xdotool under Xvfb):
both layers are drawn, the second reprojected on the fly into the first's CRS, and the status bar says so.
The old app refused the second source ("layers of one scene must share a CRS").
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from tests.app.test_real_input import _wait_resolved, pytestmark, type_into_dialog, window, xin  # noqa: F401
from tests.render.test_reproject import two_crs  # noqa: F401  (the module fixture)


def _open_with_dialog(qtbot, win, xin, path: Path) -> None:  # noqa: F811
    """Ctrl+O in the window, the file's path typed into Qt's file dialog, Return."""
    from PySide6.QtWidgets import QApplication, QFileDialog

    def dialog():
        return next((w for w in QApplication.topLevelWidgets() if isinstance(w, QFileDialog) and w.isVisible()),
                    None)

    typed = type_into_dialog(dialog, str(path), delay_ms=5, first_ms=300, give_up_ms=30000)
    entries = len(win.document.entries)
    xin.key(win.view.vtk, "ctrl+o")
    # A raw file is built first (a subprocess with a progress dialog), then opened.
    qtbot.waitUntil(lambda: len(win.document.entries) > entries or bool(win.errors), timeout=180000)
    assert typed and dialog() is None, win.errors
    assert not win.errors, win.errors


def test_second_crs_opens_reprojected(qtbot, window, xin, two_crs) -> None:  # noqa: F811
    """The UTM tileset, then the raw EPSG:3035 raster (built from the app, then opened reprojected)."""
    _open_with_dialog(qtbot, window, xin, two_crs["utm"] / "tileset.json")
    _open_with_dialog(qtbot, window, xin, two_crs["warped"])
    layers = [e.layer for e in window.document.entries]
    assert len(layers) == 2 and layers[0].reprojection is None and layers[1].reprojection is not None
    assert window.statusBar().currentMessage() == "dsm3035.tif: EPSG:3035 reprojected on the fly to EPSG:32632"
    assert window.document.crs.to_epsg() == 32632
    window.view.reset_view()
    _wait_resolved(qtbot, window)
    assert layers[0].shown_keys and layers[1].shown_keys
    # The reprojected layer alone (the first hidden): drawn where the UTM sample lies, covering the same
    # part of the view as the UTM layer alone does.
    covered = []
    for visible in ((False, True), (True, False)):
        for i, on in enumerate(visible):
            window.document.set_visible(i, on)
        window.view.request_render()
        _wait_resolved(qtbot, window)
        img = window.view.framebuffer().convertToFormat(window.view.framebuffer().Format.Format_RGB888)
        arr = np.frombuffer(img.constBits(), np.uint8).reshape(img.height(), img.bytesPerLine())
        rgb = arr[:, : img.width() * 3].reshape(img.height(), img.width(), 3).astype(int)
        sky = np.all(np.abs(rgb - rgb[0, 0]) <= 3, axis=2)
        covered.append(~sky)
    laea, utm = covered
    assert laea.mean() > 0.1, laea.mean()
    assert (laea & utm).sum() / (laea | utm).sum() > 0.95
    lo, hi = layers[1].bounds
    assert 511_990 < lo[0] and hi[0] < 512_140 and 5_402_990 < lo[1] and hi[1] < 5_403_140


def test_unrelated_crs_is_reported_naming_the_file(qtbot, window, two_crs) -> None:  # noqa: F811
    """A source whose CRS nothing relates to the project's: one error line naming it, the layer not added."""
    from tests.render.test_reproject import ENGINEERING, _with_crs

    site = two_crs["dir"] / "site_app"
    if not site.exists():
        _with_crs(two_crs["utm"], site, ENGINEERING)
    assert window.open_path(two_crs["utm"])
    assert not window.open_path(site)
    assert len(window.document.entries) == 1 and len(window.document.scene.layers) == 1
    assert len(window.errors) == 1 and str(site) in window.errors[0] and "no transformation" in window.errors[0]
    assert "\n" not in window.errors[0] and window.statusBar().currentMessage() == window.errors[0]
