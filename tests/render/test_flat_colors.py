"""One colour per triangle through flat vertex colours (render/flat_colors.py): every triangle owns its last
corner, the triangles and their winding stay, and a render draws the same picture as cell colours."""

from __future__ import annotations

import numpy as np
import pytest

from citylod.core.camera import Camera
from citylod.io.tiles3d import open_tileset
from citylod.lod.build.dsm import build_dsm
from citylod.render.flat_colors import ENV, provoking_layout
from citylod.render.offscreen import OffscreenRenderer
from citylod.sample.files import make_sample
from tests.render.test_mesh_order import _grid_in_random_order as _grid
from tests.render.test_mesh_order import _oriented


def test_every_triangle_owns_its_last_corner_and_keeps_its_winding() -> None:
    pos, faces = _grid(40)
    surface, skirt = faces[:-150].ravel(), faces[-150:].ravel()
    src, (s2, k2) = provoking_layout(len(pos), surface, skirt)
    assert np.array_equal(src[: len(pos)], np.arange(len(pos)))  # old vertices keep their numbers
    new = pos[src]
    # The same triangles with the same winding, in the same sequence, each set on its own.
    assert _oriented(new, s2) == _oriented(pos, surface)
    assert _oriented(new, k2) == _oriented(pos, skirt)
    last = np.concatenate([s2, k2]).reshape(-1, 3)[:, 2]
    assert len(np.unique(last)) == len(last)  # no two triangles share a last corner
    # Copies only where needed: a triangle per vertex at best, so at least T - V copies.
    t, v = len(faces), len(pos)
    assert t - v <= len(src) - v <= 1.1 * (t - v) + 0.05 * t, (len(src), t, v)


def test_triangles_that_share_no_vertex_need_no_copies() -> None:
    faces = np.arange(12)
    src, (f,) = provoking_layout(12, faces)
    assert len(src) == 12 and np.array_equal(f, faces)


@pytest.mark.render
def test_flat_vertex_colours_draw_the_cell_colours_picture(tmp_path, monkeypatch) -> None:
    info = make_sample(tmp_path / "sample", size=129, seed=5)
    build_dsm(info.files["dsm"], tmp_path / "tiles", tile_size=33, workers=0, progress=False)
    lo, hi = open_tileset(tmp_path / "tiles").bounds
    c, ext = (lo + hi) / 2, hi[0] - lo[0]
    cam = Camera((c[0] - 0.9 * ext, c[1] - 0.7 * ext, hi[2] + 0.4 * ext), (c[0], c[1], lo[2]), fovy_deg=50)
    frames, modes = {}, {}
    for colours in ("cells", "flat"):
        monkeypatch.setenv(ENV, colours)
        with OffscreenRenderer([tmp_path / "tiles"], size=(320, 240), tau_px=1.0) as r:
            # Every skirt in both: cell colours keep them all (render/skirts.py), and this compares colours.
            r.scene.layers[0].skirts_where_needed = False
            f = r.render(cam, depth=True)
            frames[colours] = (f.rgb, f.depth)
            shown = [a for a in r.scene.tile_actors if a.GetVisibility()]
            modes[colours] = {a.GetMapper().GetScalarModeAsString() for a in shown}
    assert modes == {"cells": {"UseCellData"}, "flat": {"UsePointData"}}
    (rgb_a, depth_a), (rgb_b, depth_b) = frames["cells"], frames["flat"]
    assert np.isfinite(depth_a).mean() > 0.2
    # The same triangles: the same pixels covered, at the same depth.
    assert np.array_equal(np.isfinite(depth_a), np.isfinite(depth_b))
    both = np.isfinite(depth_a)
    assert np.abs(depth_a[both] - depth_b[both]).max() <= 1e-4 * depth_a[both].max()
    # The same colours but for ties on shared edges. Smoothly interpolated instead of flat, a triangle
    # would blend the colours of its neighbours' corners, which changes most pixels.
    differ = (np.abs(rgb_a.astype(int) - rgb_b.astype(int)).max(axis=2) > 2).mean()
    assert differ < 2e-3, differ
    assert len(np.unique(rgb_b[both].reshape(-1, 3), axis=0)) > 20  # shaded, not one flat colour


@pytest.mark.render
def test_recolour_edit_tints_whole_flat_coloured_triangles(tmp_path, monkeypatch) -> None:
    """A recolour polygon over an untextured DSM paints the triangles whose majority of corners lies
    inside it, through their own last corners, as it painted their cell colours."""
    import shapely

    from citylod.analysis.polygons import EditPolygon, PolygonLayer
    from citylod.bench.synthetic import make_terrain_tileset
    from citylod.render.edits import PolygonEdits

    corner, ext = np.array([500000.0, 5400000.0, 0.0]), 256.0
    tiles = make_terrain_tileset(tmp_path / "dsm", levels=2, n=33, extent=ext, corner=corner, texture_px=None)
    centre = corner + np.array([ext / 2, ext / 2, 0.0])
    cam = Camera(tuple(centre + np.array([0.0, -1.0, 400.0])), tuple(centre), fovy_deg=40)
    poly = shapely.box(corner[0] + 40, corner[1] + 60, corner[0] + 200, corner[1] + 180)
    frames = {}
    for colours in ("cells", "flat"):
        monkeypatch.setenv(ENV, colours)
        with OffscreenRenderer([tiles], size=(256, 256), tau_px=1.0) as r:
            plain = r.render(cam)
            PolygonEdits(r.scene, PolygonLayer((EditPolygon(poly, "recolor", (0, 0, 255)),), r.scene.crs))
            frames[colours] = (plain.rgb, r.render(cam).rgb)
    plain, edited = frames["flat"]
    blue = (edited[..., 2] > 200) & (edited[..., 0] < 10) & (edited[..., 1] < 10)
    assert 0.2 < blue.mean() < 0.5  # the polygon's share of the view, painted
    assert not ((plain[..., 2] > 200) & (plain[..., 0] < 10)).any()
    # The same triangles painted as through cell colours (ties on shared edges aside).
    assert (np.abs(edited.astype(int) - frames["cells"][1].astype(int)).max(axis=2) > 2).mean() < 2e-3
