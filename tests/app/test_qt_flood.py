"""The flood panel in the real main window under Xvfb, driven by real key and mouse events.

The affected buildings the panel lists for a level are checked against ``flood_raster`` (the command's
windowed path, which tests/analysis checks against an independent flood fill and footprint test).
"""

from __future__ import annotations

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
