"""Budget mode on the real renderer: it measures each render and moves the point budget (no timing asserted:
targets far below and far above any real frame time make the direction certain)."""

from __future__ import annotations

import gc
from pathlib import Path

import numpy as np
import pytest

from citylod.bench.synthetic import make_point_tileset
from citylod.core.camera import Camera
from citylod.render.frame_budget import FrameBudget
from citylod.render.offscreen import OffscreenRenderer

pytestmark = pytest.mark.render

CORNER = np.array([500000.0, 5400000.0, 0.0])


def test_budget_mode_steers_points_and_restores(tmp_path: Path) -> None:
    tiles = make_point_tileset(tmp_path / "pts", levels=3, points_per_tile=4000, extent=256.0, corner=CORNER)
    c = CORNER + np.array([128.0, 128.0, 0.0])
    cam = Camera(tuple(c + np.array([0.0, -200.0, 150.0])), tuple(c), (0.0, 0.0, 1.0), 45.0)
    with OffscreenRenderer([tiles], size=(160, 120), tau_px=0.5) as r:
        layer = r.scene.layers[0]
        fixed = layer.budget
        full = r.render(cam).stats.points
        thresholds = gc.get_threshold()
        mode = FrameBudget(r.scene, target_ms=1e-3)  # unreachably fast: detail must fall
        assert gc.get_threshold()[2] > 1e6 and gc.get_freeze_count() > 0  # no full collection in a frame
        for _ in range(6):
            r.render(cam)
        assert len(mode.frame_ms) == 6
        assert layer.budget.max_points < fixed.max_points
        assert r.render(cam).stats.points < full
        mode.close()
        assert gc.get_threshold() == thresholds  # as before the mode (CPython's, or an open window's policy)
        assert layer.budget == fixed
        assert r.render(cam).stats.points == full
        slow = FrameBudget(r.scene, target_ms=1e6)  # any frame is fast enough: the budget never rises past
        for _ in range(4):                          # what the view needs (no wind-up)
            r.render(cam)
        assert slow.points_ctl is not None and layer.budget.max_points == fixed.max_points
        slow.close()
