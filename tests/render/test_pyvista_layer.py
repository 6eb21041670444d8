"""PyVista for scripted users: tiles as PolyData, and citylod's LOD inside a pyvista.Plotter."""

from __future__ import annotations

import numpy as np
import pytest

import citylod

pytestmark = pytest.mark.render


def test_point_tile_to_pyvista_keeps_positions_and_classes(sample_built) -> None:
    ts = citylod.open_tileset(sample_built.points)
    tile = next(t for t in ts.walk() if t.content_path is not None and t.load().points is not None)
    mesh = tile.load()
    origin = ts.root.box.center
    cloud = mesh.to_pyvista(origin=origin, part="points")
    assert cloud.n_points == len(mesh.points)
    np.testing.assert_allclose(np.asarray(cloud.points) + origin, mesh.points, atol=1e-6)
    if mesh.content.points.classification is not None:
        np.testing.assert_array_equal(cloud.point_data["classification"], mesh.content.points.classification)


def test_lod_layer_draws_less_at_a_coarser_tau(sample_built) -> None:
    import pyvista as pv

    counts = {}
    for tau in (0.5, 64.0):
        pl = pv.Plotter(off_screen=True, window_size=(480, 320))
        layer = citylod.add_lod_layer(pl, sample_built.points, tau_px=tau)
        stats = layer.resolve()
        counts[tau] = stats.points
        img = pl.screenshot(return_img=True)
        assert (np.abs(img.astype(int) - img[0, 0].astype(int)).sum(axis=2) > 30).mean() > 0.02, "blank frame"
        layer.close()
        pl.close()
    assert 0 < counts[64.0] < counts[0.5]


def test_lod_layer_draws_splats_without_holes(surface_tiles) -> None:
    """``add_lod_layer(..., point_shape="splat")`` in a pyvista.Plotter: from close, the surface fills the
    frame where the same tiles as points leave most of it background (depth read back from the plotter)."""
    import pyvista as pv

    from tests.render.test_splats import CLOSE

    empty = {}
    for shape in ("points", "splat"):
        pl = pv.Plotter(off_screen=True, window_size=(320, 240))
        layer = citylod.add_lod_layer(pl, surface_tiles, camera=CLOSE, point_shape=shape)
        layer.resolve()
        pl.screenshot(return_img=True)
        z = np.asarray(pl.get_image_depth(fill_value=np.nan))
        empty[shape] = float(np.mean(np.isnan(z)))
        layer.close()
        pl.close()
    assert empty["splat"] <= 0.01, empty
    assert empty["points"] > 0.3, empty
    with pytest.raises(ValueError, match="point_shape"):
        citylod.add_lod_layer(pv.Plotter(off_screen=True), surface_tiles, point_shape="cubes")
