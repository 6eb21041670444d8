"""The point-shape choice of the Points dock, driven by a real key press (xdotool through the X server):
choosing "splat" closes the holes between points in the 3D view.

Run under ``xvfb-run -a -s "-screen 0 1600x1200x24"``; skipped without a display or without xdotool.
"""

from __future__ import annotations

import os
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from tests.app.test_real_input import _wait_resolved, window, xin  # noqa: F401  (fixtures)
from tests.render.test_splats import CLOSE, _height, _write_las

pytestmark = pytest.mark.skipif(not os.environ.get("DISPLAY") or shutil.which("xdotool") is None,
                                reason="needs an X display (xvfb-run) and xdotool")


def _view_background(window) -> float:  # noqa: F811
    """Share of the 3D view's pixels in the background colour, from a grab of the whole window."""
    from tests.app.test_qt import _rgb

    rgb = _rgb(window.grab_window())
    pos, size = window.view.origin_in(window), window.view.vtk.size()
    view = rgb[pos.y(): pos.y() + size.height(), pos.x(): pos.x() + size.width()].astype(int)
    background = np.array([0.72, 0.80, 0.90]) * 255
    return float((np.abs(view - background).sum(axis=2) <= 12).mean())


def test_point_shape_splat_by_key_closes_holes(qtbot, window, xin, tmp_path: Path) -> None:  # noqa: F811
    from citylod.lod.build.points import build_points
    from tests.render.test_splats import ORIGIN

    rng = np.random.default_rng(3)
    xy = rng.uniform(0.0, 20.0, (8_000, 2))
    _write_las(tmp_path / "surface.las", np.column_stack([xy, _height(xy[:, 0], xy[:, 1])]) + ORIGIN)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        build_points([tmp_path / "surface.las"], tmp_path / "ts", crs="EPSG:28992", progress=False, hybrid=False)
    window.resize(1200, 800)
    assert window.open_path(tmp_path / "ts")
    window.view.set_camera(CLOSE)
    _wait_resolved(qtbot, window)
    before = _view_background(window)
    window.docks["points"].raise_()
    qtbot.wait(100)
    combo = window.points.shape
    assert combo.currentText() == "square"
    xin.key(combo, "End")  # the last choice of the combo box: "splat"
    layer = window.document.entries[0].layer
    qtbot.waitUntil(lambda: layer.point_shape == "splat", timeout=5000)
    assert combo.currentText() == "splat"
    _wait_resolved(qtbot, window)
    after = _view_background(window)
    assert all(layer._slots[k].points.actor.GetMapper().IsA("vtkGlyph3DMapper") for k in layer.shown_keys)
    assert before > 0.3, before  # 2-pixel points this close: mostly background between them
    assert after <= 0.01, after
