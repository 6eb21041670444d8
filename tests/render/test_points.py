"""Point layers in a Scene: the default point budget, point-count hints, smooth refinement (fade-in)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from citylod.core.camera import Camera
from citylod.lod.build.points import build_points
from citylod.lod.runtime.selection import Budget
from citylod.render.offscreen import OffscreenRenderer
from citylod.render.tileset_actor import DEFAULT_POINT_BUDGET, Scene, fade_fraction
from tests.lod.test_points_cloud import X0, Y0, make_cloud

SIZE = (320, 240)


@pytest.fixture(scope="module")
def cloud(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("render_points")
    las = d / "cloud.laz"
    make_cloud(las, n_terrain=60_000)
    out = d / "tiles"
    build_points([las], out, workers=0, progress=False, max_leaf_points=2_000, max_chunk_points=20_000,
                 segment_points=40_000)
    return out


def _flight(n: int) -> list[Camera]:
    """From high above the 100 m square down to a low oblique view over the roof."""
    cams = []
    for i in range(n):
        s = i / (n - 1)
        height = 400.0 * (1 - s) + 12.0 * s
        target = np.array([X0 + 50.0, Y0 + 46.0, 5.0])
        eye = target + np.array([0.0, -(20.0 + 60.0 * s), height])
        cams.append(Camera(tuple(eye), tuple(target), (0.0, 0.0, 1.0), 50.0))  # type: ignore[arg-type]
    return cams


def _vtk_points_drawn(scene: Scene) -> int:
    """Points the visible point actors draw (vertex cells of their polydata), counted in VTK."""
    n = 0
    for layer in scene.layers:
        for slot in layer._slots.values():
            if slot.visible and slot.points is not None and slot.points.data is not None:
                n += slot.points.data.GetNumberOfVerts()
    return n


def test_point_layer_gets_the_default_budget_and_count_hints(cloud: Path) -> None:
    with Scene(tau_px=0.5) as scene:
        layer = scene.add(cloud)
        assert layer.kind == "points" and layer.smooth_refinement
        assert layer.budget == Budget(max_points=DEFAULT_POINT_BUDGET)
        # The builder's per-tile "points" extras reach selection before anything is loaded.
        hinted = [n for n in layer._nodes.values() if n.content_uri is not None]
        assert all(n.point_count > 0 for n in hinted)
        leaves = sum(n.point_count for n in hinted if not n.children)
        assert leaves == 87_000


def test_point_budget_holds_over_a_flight_and_more_budget_draws_more(cloud: Path) -> None:
    budget = 20_000
    with Scene(tau_px=0.5) as scene:
        layer = scene.add(cloud)
        assert layer.root.point_count < budget  # the root alone is drawn whatever it costs
        layer.budget = Budget(max_points=budget)
        limited = 0
        tiles_small = []
        for cam in _flight(6):
            view = scene.view(cam, SIZE)
            stats = scene.resolve(view)
            assert 0 < stats.points <= budget
            assert _vtk_points_drawn(scene) == stats.points <= budget
            limited += bool(layer.selection and layer.selection.stats.budget_limited)
            tiles_small.append(stats.tiles)
        assert limited > 0  # the budget was binding, not just satisfied
        layer.budget = Budget(max_points=10 * budget)
        stats = scene.resolve(scene.view(_flight(6)[-1], SIZE))
        assert stats.tiles > tiles_small[-1] and stats.points > budget
        assert _vtk_points_drawn(scene) == stats.points


def test_fade_fraction() -> None:
    assert fade_fraction(0.0, 0.3, 0.2) == pytest.approx(0.2)
    assert fade_fraction(0.15, 0.3, 0.2) == pytest.approx(0.6)
    assert fade_fraction(0.3, 0.3, 0.2) == 1.0
    assert fade_fraction(5.0, 0.0, 0.2) == 1.0


def _count_non_background(rgb: np.ndarray, background: np.ndarray) -> int:
    return int(np.any(np.abs(rgb.astype(int) - background) > 3, axis=2).sum())


def test_fresh_point_tiles_fade_in(cloud: Path) -> None:
    cam = _flight(6)[2]
    now = [0.0]
    with OffscreenRenderer([cloud], size=SIZE, tau_px=0.5, point_size_px=1.0) as r:
        scene = r.scene
        scene.clock = lambda: now[0]
        layer = scene.layers[0]
        view = scene.view(cam, SIZE)
        r.prepare(cam)  # load and show everything (resolve does not fade: off-screen frames are final)
        full = _vtk_points_drawn(scene)
        assert full == scene.last_stats.points > 0 and not scene.fading
        r.draw()
        background = np.array(r.renderer.GetBackground()) * 255
        px_full = _count_non_background(r.grab_rgb(), background)
        layer.visible = False
        scene.update(view)
        assert _vtk_points_drawn(scene) == 0
        layer.visible = True
        scene.update(view)  # every tile appears now: each draws a prefix of its points
        first = _vtk_points_drawn(scene)
        assert scene.fading and 0 < first < 0.3 * full
        r.draw()
        px_first = _count_non_background(r.grab_rgb(), background)
        now[0] = 0.15
        scene.update(view)
        middle = _vtk_points_drawn(scene)
        assert first < middle < full
        now[0] = 0.31
        scene.update(view)
        assert _vtk_points_drawn(scene) == full and not scene.fading
        r.draw()
        px_done = _count_non_background(r.grab_rgb(), background)
        assert px_first < px_done and px_done == px_full
        # Without smooth refinement a tile that appears draws all its points at once.
        layer.smooth_refinement = False
        layer.visible = False
        scene.update(view)
        layer.visible = True
        scene.update(view)
        assert _vtk_points_drawn(scene) == full
