"""Rendering what `build dsm` wrote: no cracks between levels, LOD close to full resolution."""

from __future__ import annotations

import numpy as np
import pytest

import citylod.render.tile_data as td
from citylod.core.camera import Camera
from citylod.io.tiles3d import open_tileset
from citylod.lod.build.dsm import build_dsm
from citylod.render.offscreen import render_images
from citylod.render.sse import measure_error
from citylod.sample.files import make_sample

pytestmark = pytest.mark.render


# The τ at which levels mix at these distances, per metric: façades make the coarse levels' vertical errors
# large (12-20 m here), their Hausdorff bounds are near their targets (1-4 m). The tests assert that levels
# do mix, or they would prove nothing.
TAU = {"vertical": 16.0, "hausdorff": 1.5}


@pytest.fixture(scope="module", params=["vertical", "hausdorff"])
def sample_tiles(tmp_path_factory, request):
    out = tmp_path_factory.mktemp("dsmrender")
    info = make_sample(out / "sample", size=257, seed=3)
    build_dsm(info.files["dsm"], out / "tiles", tile_size=65, workers=0, progress=False, metric=request.param)
    return out / "tiles", info, TAU[request.param]


def _oblique(tiles, sx: float = -1.0, sy: float = -1.0) -> Camera:
    """An oblique view from the (sx, sy) corner of the tileset (each ±1) towards its centre."""
    lo, hi = open_tileset(tiles).bounds
    c = (lo + hi) / 2
    ext = hi[0] - lo[0]
    eye = (c[0] + sx * 1.1 * ext, c[1] + sy * 1.1 * ext, hi[2] + 0.48 * ext)
    return Camera(eye, (c[0], c[1], lo[2]), fovy_deg=50)


def _levels(tiles, cam, tau: float) -> set[int]:
    from citylod.core.camera import View
    from citylod.lod.runtime.selection import select

    ts = open_tileset(tiles)
    sel = select(ts.root, View(cam, 480, 320), tau_px=tau, resident={t.key for t in ts.walk()})
    return {t.level for t in sel.render}


def _deep_skirts(real, depth: float):
    """``prepare_content`` whose skirts hang below the bottom of the whole tileset: they close every crack
    between tiles whatever the tiles' errors, and nothing else (a skirt lies on a tile border)."""

    def deep(content, key, level, source=""):
        out = real(content, key, level, source)
        for m in out.meshes:
            hanging = np.setdiff1d(np.unique(m.skirt), np.unique(m.surface))  # the skirts' bottom vertices
            m.positions = m.positions.copy()  # ``real`` may hand out cached arrays
            m.positions[hanging, 2] -= depth
        return out

    return deep


_REAL_PREPARE = td.prepare_content


def _gaps(tiles, cam, info, tau: float, monkeypatch: pytest.MonkeyPatch) -> int:
    """Background pixels of the τ frame that are terrain in the full-resolution frame, lie below LOD terrain
    in their image column, and are terrain when the same selection is drawn with skirts that reach below
    the whole tileset: holes in the surface that skirts exist to close (cracks).

    Left out: the skyline, where a coarse tile may legitimately drop a tree or a chimney that its certified
    error covers, and what no skirt closes because it is no crack: a ray that grazes a roof edge at full
    resolution passes over the coarse tile's (within its certified error) and runs on into a no-data hole
    (under the Hausdorff metric one view showed three such pixels, and they stay with skirts 40 m deeper).
    """
    import rasterio
    from scipy.ndimage import binary_erosion, distance_transform_edt

    from citylod.render.depth import points_from_distance

    ((_, d_lod),) = render_images([tiles], [cam], size=(480, 320), tau_px=tau, depth=True)
    # The references are drawn from the tiles as written, also when the frame under test is not (the control).
    current = td.prepare_content
    monkeypatch.setattr(td, "prepare_content", _REAL_PREPARE)
    ((_, d_full),) = render_images([tiles], [cam], size=(480, 320), tau_px=0.0, depth=True)
    lo, hi = open_tileset(tiles).bounds
    monkeypatch.setattr(td, "prepare_content", _deep_skirts(_REAL_PREPARE, float(hi[2] - lo[2]) + 1.0))
    ((_, d_ref),) = render_images([tiles], [cam], size=(480, 320), tau_px=tau, depth=True)
    monkeypatch.setattr(td, "prepare_content", current)
    full = np.isfinite(d_full)
    lod = np.isfinite(d_lod)
    # Near no-data, coarse tiles leave out a cell whose corner is no-data (a hole grows by up to one
    # coarse cell), so those pixels are not counted.
    with rasterio.open(info.files["dsm"]) as ds:
        nodata = ds.read_masks(1) == 0
        inv = ~ds.transform
    levels = max(t.level for t in open_tileset(tiles).walk())
    near_hole = distance_transform_edt(~nodata) <= 2**levels + 1
    pts = points_from_distance(d_full, cam, relative=False)
    ok = full.copy()
    cols, rows = inv * (np.nan_to_num(pts[..., 0][full]), np.nan_to_num(pts[..., 1][full]))
    r = np.clip(rows.astype(int), 0, nodata.shape[0] - 1)
    c = np.clip(cols.astype(int), 0, nodata.shape[1] - 1)
    ok[full] = ~near_hole[r, c]
    below_lod = np.zeros_like(lod)
    below_lod[1:] = np.maximum.accumulate(lod, axis=0)[:-1]  # some LOD terrain above, in the same column
    gap = ok & ~lod & binary_erosion(full, iterations=1) & below_lod & np.isfinite(d_ref)
    return int(gap.sum())


def test_no_cracks_between_levels(sample_tiles, monkeypatch: pytest.MonkeyPatch) -> None:
    tiles, info, tau = sample_tiles
    cams = [_oblique(tiles, sx, sy) for sx in (-1.0, 1.0) for sy in (-1.0, 1.0)]  # from the four corners
    for cam in cams:
        assert len(_levels(tiles, cam, tau)) >= 2, "the view must mix levels for this test to mean anything"
    gaps = [_gaps(tiles, cam, info, tau, monkeypatch) for cam in cams]
    assert gaps == [0, 0, 0, 0]
    # The control: cracks the count above must find. Whether a frame without skirts shows one depends on
    # the view and on every coarse TIN (this sample's showed a few pixels in some builds, none in others),
    # so cracks are made: without skirts, every tile shrunk by 6 % towards its centre (slits of 4–8 m between tiles).
    real = td.prepare_content

    def cracked(content, key, level, source=""):
        out = real(content, key, level, source)
        for m in out.meshes:
            m.skirt = m.skirt[:0]
            m.positions = m.positions.copy()  # not the arrays ``real`` may hand out again
            xy = m.positions[:, :2]
            m.positions[:, :2] = (xy - xy.mean(axis=0)) * 0.94 + xy.mean(axis=0)
        return out

    monkeypatch.setattr(td, "prepare_content", cracked)
    counts = [_gaps(tiles, cam, info, tau, monkeypatch) for cam in cams]
    assert all(n >= 100 for n in counts), counts  # 460-970 per view at the time of writing


def test_measured_error_respects_tau(sample_tiles) -> None:
    tiles, _, tau = sample_tiles
    cam = _oblique(tiles)
    assert len(_levels(tiles, cam, tau)) >= 2
    ((_, d_lod),) = render_images([tiles], [cam], size=(480, 320), tau_px=tau, depth=True)
    ((_, d_full),) = render_images([tiles], [cam], size=(480, 320), tau_px=0.0, depth=True)
    stats = measure_error(d_lod, d_full, cam)
    assert stats.valid > 0.1 * d_lod.size
    assert stats.near_p99_px > 0  # coarse tiles really differ from the leaves
    assert stats.near_p99_px <= tau  # the geometric errors bound what the screen shows


def _drawn_skirts(r) -> list[tuple[object, np.ndarray]]:
    """Every skirt triangle the shown tile actors hold, as (tile, centroid in the data's CRS)."""
    from citylod.render._vtk import vtk_to_numpy
    from citylod.render.tileset_actor import SKIRT_ARRAY

    layer = r.scene.layers[0]
    out = []
    for key in layer.shown_keys:
        node = layer.node(key)
        for props in layer._slots[key].meshes:
            data = props.data
            flags = vtk_to_numpy(data.GetCellData().GetArray(SKIRT_ARRAY)).astype(bool)
            conn = vtk_to_numpy(data.GetPolys().GetConnectivityArray()).reshape(-1, 3)[flags]
            pos = props.mesh.positions.astype(np.float64)
            c = pos[conn].mean(axis=1) @ node.matrix[:3, :3].T + node.matrix[:3, 3]
            out.extend((node, p) for p in c)
    return out


def _across(node, p, shown):
    """The shown tiles whose footprint holds the point just outside ``node``'s box beyond ``p`` (a point on
    one of its side faces): the tiles across that side."""
    lo, hi = node.box.bounds()
    centre = (lo + hi) / 2
    half = (hi - lo) / 2
    u = (p[:2] - centre[:2]) / half[:2]
    axis = int(np.argmax(np.abs(u)))
    q = p[:2].copy()
    q[axis] += np.sign(u[axis]) * 0.01 * half[axis]
    hits = []
    for other in shown:
        olo, ohi = other.box.bounds()
        if other is not node and np.all(q >= olo[:2]) and np.all(q <= ohi[:2]):
            hits.append(other)
    return hits


def test_skirts_drawn_where_levels_meet_only(sample_tiles) -> None:
    """Skirts are drawn on the sides of a tile that border another level or nothing drawn, and not between
    two drawn tiles of one level (their borders are the same: stage 2 of the build), which the frame shows
    unchanged: not one pixel the full-resolution surface covers turns to background."""
    from citylod.render.offscreen import OffscreenRenderer

    tiles, _, tau = sample_tiles
    cam = _oblique(tiles)
    assert len(_levels(tiles, cam, tau)) >= 2
    depth, kept = {}, {}
    for fitted in (True, False):
        with OffscreenRenderer([tiles], size=(480, 320), tau_px=tau) as r:
            r.scene.layers[0].skirts_where_needed = fitted
            depth[fitted] = r.render(cam, depth=True).depth
            layer = r.scene.layers[0]
            shown = [layer.node(k) for k in layer.shown_keys]
            kept[fitted] = _drawn_skirts(r)
            if fitted:
                # Independent of render/skirts.py: each drawn skirt, stepped 1 % of the tile outwards, lands in
                # no drawn tile or in one of another level (or of another size).
                for node, p in kept[True]:
                    for other in _across(node, p, shown):
                        assert other.level != node.level, (node.key, other.key)
                full = r.render(cam, depth=True, full_resolution=True)
                # A full-resolution frame is all one level: no skirt drawn at all.
                assert _drawn_skirts(r) == []
                d_full = full.depth
                # Turned off again, every tile drawn has all its skirts back.
                r.scene.layers[0].skirts_where_needed = False
                r.render(cam)
                restored = len(_drawn_skirts(r))
    # Without fitting, some skirts lie between tiles of one level; they are gone, and the others stay.
    same = [(n, p) for n, p in kept[False] if any(o.level == n.level for o in _across(n, p, shown))]
    other = [(n, p) for n, p in kept[False] if not any(o.level == n.level for o in _across(n, p, shown))]
    assert same and other
    assert len(kept[True]) == len(other)
    assert restored == len(kept[False])
    holes = np.isfinite(depth[False]) & ~np.isfinite(depth[True]) & np.isfinite(d_full)
    assert int(holes.sum()) == 0


def _frame(r, cam, cull: bool | None):
    """Draw ``cam`` with the tiles' own back-face culling (None) or culling forced on/off for this frame;
    (rgb, depth, the share of the drawn actors that cull as the tiles set it)."""
    r.prepare(cam)
    actors = r.renderer.GetActors()
    props = []
    actors.InitTraversal()
    for _ in range(actors.GetNumberOfItems()):
        actor = actors.GetNextActor()
        if actor.GetVisibility():
            props.append(actor.GetProperty())
    own = [bool(p.GetBackfaceCulling()) for p in props]
    if cull is not None:
        for p in props:
            p.SetBackfaceCulling(cull)
    r.draw()
    out = r.grab_rgb().astype(int), r.grab_depth(), float(np.mean(own)) if own else 0.0
    for p, c in zip(props, own, strict=True):
        p.SetBackfaceCulling(c)
    return out


def test_back_faces_culled_the_same_picture_from_above(sample_tiles) -> None:
    """DSM tiles are single-sided (surface up, skirts outward), so the renderer culls their back faces. From
    above and obliquely the picture is the one drawn without culling (no skirt culled where it closes a
    crack) but where the data ends inside a building (the raster's edge: no skirt hangs there), which one
    now looks into instead of at the back of its far wall: 0–0.13 % of the pixels here. From below the
    surface (the control) culling removes it but for skirts."""
    from citylod.render.offscreen import OffscreenRenderer

    tiles, _info, tau = sample_tiles
    lo, hi = open_tileset(tiles).bounds
    c = (lo + hi) / 2
    below = Camera((c[0], c[1] - 10.0, lo[2] - 200.0), (c[0], c[1], hi[2]), fovy_deg=60)
    with OffscreenRenderer([tiles], size=(320, 240), tau_px=tau) as r:
        for cam in (_oblique(tiles), _oblique(tiles, 1.0, -1.0)):
            rgb, depth, share = _frame(r, cam, None)
            assert share == 1.0  # every DSM tile drawn single-sided
            rgb2, depth2, _ = _frame(r, cam, False)
            covered = np.isfinite(depth2)
            assert covered.mean() > 0.1
            assert (np.isfinite(depth) != covered).sum() <= 1e-3 * covered.sum()
            both = covered & np.isfinite(depth)
            assert (np.abs(depth[both] - depth2[both]) > 1e-3 * depth2[both].max()).mean() < 0.015
            assert (np.abs(rgb - rgb2).max(axis=2) > 8).mean() < 2e-3
        _, depth_up, _ = _frame(r, below, None)
        _, depth_both, _ = _frame(r, below, False)
        # what stays are skirts, which face their neighbours: seen from below, half of them face the camera
        assert np.isfinite(depth_both).mean() > 0.3 and np.isfinite(depth_up).mean() < 0.1
