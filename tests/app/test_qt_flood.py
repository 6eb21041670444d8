"""The flood panel in the real main window under Xvfb, driven by real key and mouse events.

The affected buildings the panel lists for a level are checked against ``flood_raster`` (the command's
windowed path, which tests/analysis checks against an independent flood fill and footprint test).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import rasterio

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from tests.app.test_qt import _rgb, _wait_resolved, needs_display, qsettings, sample, window  # noqa: F401

pytestmark = [pytest.mark.gui, needs_display]


def test_flood_sliders_and_affected_buildings(qtbot, window, sample, tmp_path: Path) -> None:  # noqa: F811
    from PySide6.QtCore import Qt

    from citylod.analysis.flood import FloodSources, flood_raster

    assert window.open_path(sample["tiles"]) and window.open_path(sample["store"])
    with rasterio.open(sample["dsm"]) as ds:
        h = ds.read(1, masked=True).compressed()
    levels = [float(np.percentile(h, 30)), float(np.percentile(h, 60))]
    panel = window.flood
    window.docks["flood"].raise_()
    _wait_resolved(qtbot, window)

    def blue_share() -> float:
        qtbot.wait(200)
        img = _rgb(window.view.framebuffer()).astype(int)
        return float(((img[..., 2] > img[..., 0] + 60) & (img[..., 2] > img[..., 1] + 20)).mean())

    dry = blue_share()
    panel.load(sample["dsm"], FloodSources(edge=True), levels=levels, city=sample["store"])
    panel.wait()
    assert blue_share() > dry + 0.02  # the water shows in the window

    # a real key press on the level slider raises the level by a page (10 steps of 5 cm)
    panel.level.setFocus()
    start = panel.level.value()
    with qtbot.waitSignal(panel.updated, timeout=30000):
        qtbot.keyClick(panel.level, Qt.Key.Key_PageUp)
    res = panel.wait()
    assert panel.level.value() == start + panel.level.pageStep()
    assert res is not None and res.level == pytest.approx(panel.level.value() * 0.05)

    # the time slider steps to the series' second level
    panel.time.setFocus()
    with qtbot.waitSignal(panel.updated, timeout=30000):
        qtbot.keyClick(panel.time, Qt.Key.Key_Right)
    res = panel.wait()
    assert res.level == pytest.approx(levels[1])
    ref = flood_raster(sample["dsm"], [levels[1]], tmp_path / "ref", sources=FloodSources(edge=True),
                       city=sample["store"])
    want = {a.object_id: a for a in ref.affected}
    got = {panel.table.item(i, 0).text(): float(panel.table.item(i, 1).text()) for i in range(panel.table.rowCount())}
    assert want and set(got) == set(want)
    for oid, mx in got.items():
        assert mx == pytest.approx(want[oid].max_depth_m, abs=0.006)  # the table shows 2 decimals
    assert set(window.document.state.colors) >= set(want)  # highlighted through the semantic state
    assert "buildings affected" in panel.summary.text()

    # a click on a row selects that building
    rect = panel.table.visualItemRect(panel.table.item(0, 0))
    qtbot.mouseClick(panel.table.viewport(), Qt.MouseButton.LeftButton, pos=rect.center())
    assert window.document.state.selection == {panel.table.item(0, 0).text()}


@pytest.mark.skipif(shutil.which("xdotool") is None, reason="needs xdotool")
def test_flood_the_dsm_tileset_in_the_view(qtbot, window, sample) -> None:  # noqa: F811
    """X clicks (xdotool) on "Flood the DSM in the view" flood the open tileset's leaves; the extent lies
    between the source raster's floods at the level ∓ the leaves' error (independent breadth-first fill on
    the raster)."""
    from tests.analysis.test_flood import bfs_flood, edge_cells
    from tests.app.test_real_input import X

    xin = X(qtbot)
    panel = window.flood
    window.move(0, 0)
    window.docks["flood"].raise_()
    qtbot.waitExposed(panel.view_button)
    centre = panel.view_button.rect().center()
    xin.click(panel.view_button, centre.x(), centre.y())
    qtbot.waitUntil(lambda: panel.summary.text() == "no DSM tileset is open", timeout=10000)
    assert panel.scenario is None
    assert window.open_path(sample["tiles"])
    _wait_resolved(qtbot, window)
    xin.click(panel.view_button, centre.x(), centre.y())
    qtbot.waitUntil(lambda: panel.scenario is not None, timeout=30000)
    eps = panel.scenario.tileset_error_m
    with rasterio.open(sample["dsm"]) as ds:
        m = ds.read(1, masked=True)
    h, valid = np.ma.getdata(m).astype(np.float64), ~np.ma.getmaskarray(m)
    for _ in range(3):  # three pages up: 1.5 m above the lowest height
        xin.key(panel.level, "Page_Up")
    qtbot.waitUntil(lambda: panel.result is not None and panel.result.level == pytest.approx(
        panel.level.value() * 0.05), timeout=30000)
    res = panel.wait()
    assert res is not None and res.mask.shape == h.shape
    assert res.level == pytest.approx(panel.scenario.model.min_height + 1.5, abs=0.05)
    seeds = edge_cells(h.shape)
    lo, hi = bfs_flood(h, valid, seeds, res.level - eps), bfs_flood(h, valid, seeds, res.level + eps)
    assert res.mask.any() and not (lo & ~res.mask).any() and not (res.mask & ~hi).any()
    assert "tileset heights" in panel.summary.text()
