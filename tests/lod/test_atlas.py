"""Buchholz's multiresolution atlases: texel sizes by hand, atlas contents against the original images at
every level through the one set of texture coordinates."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from citylod.io.city import read_city_model
from citylod.io.image import decode_image, read_image
from citylod.io.tiles3d import open_tileset
from citylod.lod.build.atlas import Square, quadrant, texel_size_m
from citylod.lod.build.city import build_city_tiles
from citylod.sample.textured import make_textured_city
from tests.lod.test_city_tiles import _samples


def test_texel_size_of_a_quad_by_hand() -> None:
    v = np.array([[0, 0, 0], [10, 0, 0], [10, 0, 5], [0, 0, 5]], float)  # a 10 m × 5 m wall
    f = np.array([[0, 1, 2], [0, 2, 3]])
    sq = quadrant(quadrant(Square(), 3), 0)  # a square of side 1/4 of the common space
    # the wall fills a 256 px cell of a 1024 px atlas: a quarter of the square's side
    cell = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], float) * 0.25 * sq.size + [sq.ox, sq.oy]
    assert texel_size_m(v, f, cell, sq, 1024) == pytest.approx(10 / 256)
    # the parent's atlas covers twice the space with the same pixels: texels twice as large
    assert texel_size_m(v, f, cell, quadrant(Square(), 3), 1024) == pytest.approx(10 / 128)


@pytest.fixture(scope="module")
def textured(tmp_path_factory: pytest.TempPathFactory):
    d = tmp_path_factory.mktemp("textured")
    city = make_textured_city(d, buildings=12, image_px=64, seed=3)
    report = build_city_tiles(city.path, d / "tiles", atlas_px=256, texture_blocks=False, progress=False)
    return city, report, open_tileset(d / "tiles")


def _sample(img: np.ndarray, uv_top_left: np.ndarray) -> np.ndarray:
    h, w = img.shape[:2]
    x = np.clip((uv_top_left[:, 0] * w).astype(int), 0, w - 1)
    y = np.clip((uv_top_left[:, 1] * h).astype(int), 0, h - 1)
    return img[y, x].astype(float)


def test_every_level_shows_the_original_images(textured) -> None:
    city, report, ts = textured
    assert report.levels >= 2 and ts.citylod["textured"]
    from citylod.io.city.appearance import read_appearances

    apps = read_appearances(city.path)
    model = read_city_model(city.path)
    # original colour of every textured surface, averaged over a barycentric grid of its first triangle
    bary = np.array([(a, b) for a in np.linspace(0.1, 0.8, 6) for b in np.linspace(0.1, 0.8, 6) if a + b < 0.9])
    tiles = {t.key: t for t in ts.walk()}
    checked = 0
    for t in ts.walk():
        content = t.load_content()
        tex = [m for m in content.meshes if m.texture is not None]
        assert len(tex) == 1  # one atlas per tile, whatever the level
        m = tex[0]
        atlas = decode_image(m.texture)[:, :, :3]
        assert atlas.shape[:2] == (256, 256)
        world = m.positions.astype(np.float64) @ t.matrix[:3, :3].T + t.matrix[:3, 3]
        diffs = []
        for face in m.faces[::3]:
            p = world[face]
            pts = p[0] + bary[:, :1] * (p[1] - p[0]) + bary[:, 1:] * (p[2] - p[0])
            tile_uv = m.uv[face[0]] + bary[:, :1] * (m.uv[face[1]] - m.uv[face[0]]) + bary[:, 1:] * (
                m.uv[face[2]] - m.uv[face[0]])
            # the surface this triangle lies on, in the model as read, and its own image coordinates
            obj = next(o for o in model.objects for poly in o.surfaces
                       if np.abs(np.cross(poly[0][1] - poly[0][0], poly[0][2] - poly[0][0]) @ (p[0] - poly[0][0])) < 1e-3
                       and np.abs(np.cross(poly[0][1] - poly[0][0], poly[0][2] - poly[0][0]) @ (p[1] - poly[0][0])) < 1e-3
                       and np.all(p.min(0) >= poly[0].min(0) - 1e-3) and np.all(p.max(0) <= poly[0].max(0) + 1e-3))
            poly = next(poly for poly in obj.surfaces
                        if np.all(p.min(0) >= poly[0].min(0) - 1e-3) and np.all(p.max(0) <= poly[0].max(0) + 1e-3)
                        and apps.lookup(poly[0]) is not None)
            app = apps.lookup(poly[0])
            ring = poly[0][:-1]
            uv_ring = app.uv_of(ring)
            # image coordinates of the sample points: affine in the polygon's plane (a quad or triangle)
            a, b, c = ring[0], ring[1], ring[-1]
            basis = np.column_stack([b - a, c - a])
            coef = np.linalg.lstsq(basis, (pts - a).T, rcond=None)[0].T
            uv = uv_ring[0] + coef[:, :1] * (uv_ring[1] - uv_ring[0]) + coef[:, 1:] * (uv_ring[-1] - uv_ring[0])
            orig = read_image(app.image)
            want = _sample(orig, np.column_stack([uv[:, 0], 1 - uv[:, 1]])).mean(axis=0)
            got = _sample(atlas, tile_uv).mean(axis=0)
            diffs.append(np.abs(want - got).max())
        # JPEG and the shrinking by 2 per level change colours a little, never the picture
        assert np.median(diffs) < 12 + 6 * (report.levels - 1 - t.level), (t.key, np.median(diffs))
        checked += len(diffs)
    assert checked > 50
    del tiles


def test_texel_sizes_double_per_level_and_leaves_are_native(textured) -> None:
    city, _report, ts = textured
    for t in ts.walk():
        for c in t.children:
            assert c.geometric_error <= t.geometric_error
    # a leaf holds every image at its native 64 px, its coordinates kept half a texel inside the image (63
    # texels span a side): its texel is at most the largest façade or roof side / 63
    longest = max(max(h.width, h.depth, h.eave, np.hypot(h.depth / 2, h.ridge_m)) for h in city.houses)
    for t in ts.walk():
        if not t.children:
            assert t.geometric_error <= longest / 63 * (1 + 1e-6) + 1e-4
    assert ts.root.geometric_error > max(c.geometric_error for c in ts.root.children) * 1.5


def test_a_missing_image_falls_back_to_the_material(tmp_path: Path) -> None:
    city = make_textured_city(tmp_path, buildings=2, image_px=32)
    (tmp_path / city.houses[0].roof).unlink()
    report = build_city_tiles(city.path, tmp_path / "tiles", atlas_px=128, progress=False)
    assert any(city.houses[0].roof.split("/")[-1] in w and "missing" in w for w in report.warnings)
    ts = open_tileset(tmp_path / "tiles")
    leaf = next(t for t in ts.walk() if not t.children)
    colours = np.concatenate([m.colors[:, :3] for t in ts.walk() if not t.children
                              for m in t.load_content().meshes if m.colors is not None])
    # the roof's X3DMaterial (0.62, 0.30, 0.22) is drawn where its texture is missing
    assert (np.abs(colours.astype(int) - [158, 76, 56]).max(axis=1) <= 1).any()
    del leaf


def _world_meshes(t) -> tuple[np.ndarray, np.ndarray, list]:
    """All meshes of a tile in world coordinates, concatenated, and the meshes themselves."""
    meshes = t.load_content().meshes
    vs, fs, off = [], [], 0
    for m in meshes:
        vs.append(m.positions.astype(np.float64) @ t.matrix[:3, :3].T + t.matrix[:3, 3])
        fs.append(m.faces.astype(np.int64) + off)
        off += len(m.positions)
    return np.concatenate(vs), np.concatenate(fs), meshes


def test_far_textured_tiles_are_blocks_in_the_atlas_colours(tmp_path: Path) -> None:
    city = make_textured_city(tmp_path, buildings=24, image_px=64, seed=5)
    report = build_city_tiles(city.path, tmp_path / "tiles", atlas_px=256, texture_blocks=True, progress=False)
    ts = open_tileset(tmp_path / "tiles")
    inner = [t for t in ts.walk() if t.children]
    assert inner and report.root_triangles < report.leaf_triangles
    roof_means = [read_image(tmp_path / h.roof)[:, :, :3].reshape(-1, 3).mean(axis=0) for h in city.houses]
    for t in inner:
        v, f, meshes = _world_meshes(t)
        assert all(m.texture is None for m in meshes)  # a far tile binds no texture
        leaves = [_world_meshes(x)[:2] for x in ts.walk_from(t) if not x.children]
        lv = np.concatenate([a for a, _ in leaves])
        lf = np.concatenate([b + o for (_, b), o in zip(leaves, np.cumsum([0] + [len(a) for a, _ in leaves[:-1]]),
                                                          strict=True)])
        # independent Hausdorff estimate between the blocks and the full surfaces (dense samples, scipy)
        ps, rs = _samples(v, f, 0.5)
        pf, rf = _samples(lv, lf, 0.5)
        est = max(cKDTree(pf).query(ps)[0].max() - rf, cKDTree(ps).query(pf)[0].max() - rs)
        assert est <= t.geometric_error + 1e-6
        assert all(c.geometric_error <= t.geometric_error for c in t.children)
        # roof faces are drawn in colours of the roof images (mean of the atlas, shrunk and JPEG-coded)
        cols = np.concatenate([m.colors[:, :3] for m in meshes]).astype(float)
        n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        up = n[:, 2] / np.linalg.norm(n, axis=1) > 0.5
        roof_cols = cols[f[up, 0]]
        near = np.min(np.abs(roof_cols[:, None, :] - np.array(roof_means)[None]).max(axis=2), axis=1)
        assert np.median(near) < 25, np.median(near)
