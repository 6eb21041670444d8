"""Semantic shading by volume (Wahl & Klein 2007): picking, highlighting, hiding on DSM meshes and points.

Every expectation comes from the sample city's analytic ground truth (:meth:`SampleCity.inside_building`
applied to the 3D point each pixel shows, reconstructed from the depth buffer), never from the proxies or
the shader under test. Tinted pixels are found by comparing with the same frame without the highlight.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import ndimage

from citylod.core.camera import Camera
from citylod.render.depth import points_from_distance
from citylod.render.offscreen import OffscreenRenderer, render_command, save_png
from citylod.render.semantic import SemanticOverlay, build_contour_map, semantic_hook
from citylod.semantics.store import CityStore

pytestmark = pytest.mark.render

SIZE = (320, 240)
TINT = "#ff00ff"  # magenta: far from every colour of the sample's orthophoto and LiDAR


@pytest.fixture(scope="module")
def city(sample_built: SimpleNamespace) -> SimpleNamespace:
    return sample_built


def oblique(truth: object, b: object, dist: float = 45.0, az_deg: float = 200.0, el_deg: float = 50.0) -> Camera:
    """A camera looking at building ``b``'s roof centre from ``az_deg``/``el_deg`` at ``dist`` metres."""
    cx, cy = b.center  # type: ignore[attr-defined]
    cz = float(truth.roof_height(np.array([cx]), np.array([cy]))[0])  # type: ignore[attr-defined]
    if not np.isfinite(cz):
        cz = b.ridge  # type: ignore[attr-defined]
    az, el = np.radians(az_deg), np.radians(el_deg)
    eye = (cx + dist * np.cos(el) * np.sin(az), cy + dist * np.cos(el) * np.cos(az), cz + dist * np.sin(el))
    return Camera(eye, (cx, cy, cz), (0.0, 0.0, 1.0), 45.0)


def tinted(a: np.ndarray, b: np.ndarray, tol: int = 24) -> np.ndarray:
    return np.abs(a.astype(int) - b.astype(int)).max(axis=-1) > tol


def analytic_mask(truth: object, depth: np.ndarray, camera: Camera, index: int, inflate: float) -> np.ndarray:
    pts = points_from_distance(depth, camera, relative=False)
    ok = np.isfinite(depth)
    inside = np.zeros(depth.shape, bool)
    p = pts[ok]
    inside[ok] = truth.inside_building(p[:, 0], p[:, 1], p[:, 2], inflate) == index  # type: ignore[attr-defined]
    return inside


def boundary_band(mask: np.ndarray, px: int = 1) -> np.ndarray:
    """Pixels within ``px`` of the mask's boundary (both sides)."""
    st = np.ones((3, 3), bool)
    return ndimage.binary_dilation(mask, st, iterations=px) & ~ndimage.binary_erosion(mask, st, iterations=px)


def render_pair(sources: list[Path], gpkg: Path, camera: Camera, act: object, *,
                point_size_px: float = 2.0, splats: bool = False) -> tuple[object, object, SemanticOverlay, CityStore]:
    store = CityStore.open(gpkg)
    r = OffscreenRenderer(sources, size=SIZE, point_size_px=point_size_px)
    if splats:  # points as oriented disks (`citylod render --splats`), drawn by VTK's glyph mapper
        for layer in r.scene.layers:
            layer.point_shape = "splat"
    overlay = SemanticOverlay(r.scene, store, resolution=0.125)  # texels smaller than pixels
    before = r.render(camera, depth=True)
    act(overlay, store)  # type: ignore[operator]
    after = r.render(camera, depth=True)
    r.close()
    return before, after, overlay, store


@pytest.mark.parametrize("index", [3, 5])  # a flat roof and a gable roof
def test_highlight_mask_equals_the_analytic_inside_test(city: SimpleNamespace, tmp_path: Path, index: int) -> None:
    b = city.truth.buildings[index]
    cam = oblique(city.truth, b)
    before, after, _, store = render_pair([city.dir / "dsm"], city.gpkg, cam,
                                          lambda ov, st: ov.state.highlight([b.id], TINT))
    save_png(tmp_path / f"before_{index}.png", before.rgb)
    save_png(tmp_path / f"after_{index}.png", after.rgb)
    np.testing.assert_array_equal(before.depth, after.depth)  # tinting never moves geometry
    got = tinted(after.rgb, before.rgb)
    want = analytic_mask(city.truth, before.depth, cam, index, store.inflate)
    assert want.sum() > 2000, "the building must fill a good part of the frame"
    wrong = got ^ want
    # Only silhouette pixels may differ: there the pixel mixes the proxy's inside and outside.
    assert not (wrong & ~boundary_band(want)).any(), f"{int((wrong & ~boundary_band(want)).sum())} pixels off"
    assert wrong.sum() < 0.05 * want.sum()
    # Tinted pixels are magenta-dominated (the tint replaces the colour, keeping some shading).
    rgb = after.rgb[want & ~boundary_band(want)].astype(int)
    assert np.all(rgb[:, 0] > rgb[:, 1] + 40) and np.all(rgb[:, 2] > rgb[:, 1] + 40)


def test_above_the_proxy_stays_untinted(city: SimpleNamespace) -> None:
    # Pixels inside a building's footprint but above its inflated roof (chimneys, tree crowns) are not
    # tinted: the test is 3D, not a 2D overlay of the footprint.
    b = city.truth.buildings[0]
    cam = oblique(city.truth, b, dist=70.0, el_deg=60.0)
    before, after, _, store = render_pair([city.dir / "dsm"], city.gpkg, cam,
                                          lambda ov, st: ov.state.highlight([b.id], TINT))
    pts = points_from_distance(before.depth, cam, relative=False)
    ok = np.isfinite(before.depth)
    foot = np.zeros(ok.shape, bool)
    foot[ok] = city.truth.building_id_at(pts[ok][:, 0], pts[ok][:, 1]) == b.index
    inside = analytic_mask(city.truth, before.depth, cam, b.index, store.inflate)
    above = foot & ~inside & ~boundary_band(inside, 2)
    got = tinted(after.rgb, before.rgb)
    assert not (got & above).any()


def test_pick_returns_the_building_under_its_roof_centre(city: SimpleNamespace) -> None:
    store = CityStore.open(city.gpkg)
    with OffscreenRenderer([city.dir / "dsm"], size=SIZE) as r:
        overlay = SemanticOverlay(r.scene, store)
        for b in city.truth.buildings:
            if b.hole is not None:  # a courtyard's centre is not on the roof
                continue
            cam = oblique(city.truth, b, dist=60.0)
            r.render(cam)
            ren = r.renderer
            cx, cy = b.center
            cz = float(city.truth.roof_height(np.array([cx]), np.array([cy]))[0])
            if not np.isfinite(cz):  # an L-shaped building's centre can lie outside it
                continue
            ren.SetWorldPoint(*(np.array([cx, cy, cz]) - r.scene.origin), 1.0)
            ren.WorldToDisplay()
            x, y, _ = ren.GetDisplayPoint()
            hit = overlay.pick(ren, int(round(x)), int(round(y)))
            assert hit.object_id == b.id
            assert hit.attributes["object_id"] == b.id
            # The hit is on the drawn DSM, which lies vertically within the leaf bound (0.5 m) of the
            # raster surface, itself within half a sample diagonal × roof slope (≤ 1) of the true roof;
            # along a ray 50° above the horizon that vertical gap becomes gap / sin(50°).
            tol = (0.5 + 0.5 * math.sqrt(2.0)) / math.sin(math.radians(50.0))
            assert np.linalg.norm(hit.point_xyz - [cx, cy, cz]) < tol
        # The background has no point and no object.
        r.render(Camera((cx, cy, cz + 50), (cx, cy + 1000, cz + 50), (0, 0, 1), 30.0))
        miss = overlay.pick(r.renderer, SIZE[0] // 2, SIZE[1] - 2)
        assert miss.point_xyz is None and miss.object_id is None
        overlay.close()


def test_hiding_a_building_on_a_dsm_leaves_the_ground_under_it(city: SimpleNamespace, tmp_path: Path) -> None:
    """A DSM has nothing behind a building: hiding it lowers its surface onto its ground (no hole onto the
    sky), checked against the sample's analytic footprint and ground height."""
    b = city.truth.buildings[5]
    cam = oblique(city.truth, b)
    before, after, overlay, store = render_pair([city.dir / "dsm"], city.gpkg, cam,
                                                lambda ov, st: ov.state.hide([b.id]))
    save_png(tmp_path / "before.png", before.rgb)
    save_png(tmp_path / "hidden.png", after.rgb)
    inside = analytic_mask(city.truth, before.depth, cam, b.index, store.inflate)
    core = ndimage.binary_erosion(inside, np.ones((3, 3), bool), iterations=1)
    assert core.sum() > 1000
    # No pixel of the building shows the background, and none shows anything nearer than before.
    assert np.isfinite(after.depth[core]).all()
    assert np.all(after.depth[core] >= before.depth[core] - 0.05)
    # Elsewhere the surface only moves away from the eye: a TIN's large triangles that joined the roof to
    # distant ground vertices sink with the roof vertices, nothing rises
    far = ~ndimage.binary_dilation(inside, np.ones((3, 3), bool), iterations=2)
    # (pixels that showed the background may now show ground: the sample's DSM has a no-data hole.)
    seen = far & np.isfinite(before.depth)
    assert np.all(after.depth[seen] >= before.depth[seen] - 0.02)  # 2 cm: depth-buffer rounding
    # What is seen over the footprint (analytic: 1 m above that point's ground is inside the building) is at
    # the building's ground: its roof is gone.
    pts = points_from_distance(after.depth, cam, relative=False)[np.isfinite(after.depth)]
    over = city.truth.inside_building(pts[:, 0], pts[:, 1], np.full(len(pts), b.ground + 1.0), 0.0) == b.index
    assert over.sum() > 1000
    err = np.abs(pts[over, 2] - b.ground)
    assert np.percentile(err, 99) <= 0.05
    assert err.max() <= 0.5  # a few pixels on triangles that straddle the outline slope up to the outside
    overlay.close()


def test_points_inside_the_proxy_are_tinted(city: SimpleNamespace, tmp_path: Path) -> None:
    b = city.truth.buildings[5]
    cam = oblique(city.truth, b)
    before, after, _, store = render_pair([city.dir / "points"], city.gpkg, cam,
                                          lambda ov, st: ov.state.highlight([b.id], TINT), point_size_px=3.0)
    save_png(tmp_path / "points_before.png", before.rgb)
    save_png(tmp_path / "points_after.png", after.rgb)
    got = tinted(after.rgb, before.rgb)
    want = analytic_mask(city.truth, before.depth, cam, b.index, store.inflate)
    assert want.sum() > 500
    wrong = got ^ want
    # A point sprite covers a few pixels around its centre, so its pixels' depth-reconstructed positions
    # differ from the point's: allow the sprite's size around the silhouette.
    assert not (wrong & ~boundary_band(want, 2)).any()
    assert got[want].mean() > 0.95


def test_splats_inside_the_proxy_are_tinted_and_hidden(city: SimpleNamespace, tmp_path: Path) -> None:
    # Splats are drawn through VTK's glyph mapper, whose shaders the overlay reaches another way (property
    # textures, custom uniforms): the same per-fragment test, on the disks' own fragments.
    b = city.truth.buildings[5]
    cam = oblique(city.truth, b)
    before, after, _, store = render_pair([city.dir / "points"], city.gpkg, cam,
                                          lambda ov, st: ov.state.highlight([b.id], TINT), splats=True)
    save_png(tmp_path / "splats_before.png", before.rgb)
    save_png(tmp_path / "splats_after.png", after.rgb)
    got = tinted(after.rgb, before.rgb)
    want = analytic_mask(city.truth, before.depth, cam, b.index, store.inflate)
    assert want.sum() > 500
    # Tilted disks put fragments anywhere along the proxy's upper contour, which the map holds per texel
    # (0.125 m): a handful of pixels there may fall either way (3 of 9,174 when written).
    assert ((got ^ want) & ~boundary_band(want, 2)).sum() <= 0.001 * want.sum()
    assert got[want].mean() > 0.95
    _, hidden, _, _ = render_pair([city.dir / "points"], city.gpkg, cam, lambda ov, st: ov.state.hide([b.id]),
                                  splats=True)
    gone = analytic_mask(city.truth, hidden.depth, cam, b.index, store.inflate)
    assert gone.sum() < 0.02 * want.sum()  # what shows there now lies outside the building


def test_state_changes_update_the_frame_and_undo_exactly(city: SimpleNamespace) -> None:
    b = city.truth.buildings[3]
    cam = oblique(city.truth, b)
    store = CityStore.open(city.gpkg)
    with OffscreenRenderer([city.dir / "dsm", city.dir / "points"], size=SIZE) as r:
        overlay = SemanticOverlay(r.scene, store)
        base = r.render(cam).rgb
        overlay.state.highlight([b.id], TINT)
        assert tinted(r.render(cam).rgb, base).sum() > 1000
        overlay.state.unhighlight()
        np.testing.assert_array_equal(r.render(cam).rgb, base)
        overlay.set_hover(b.id)
        hover = r.render(cam).rgb
        assert tinted(hover, base, 8).sum() > 1000
        overlay.set_hover(None)
        overlay.state.select([b.id])
        assert tinted(r.render(cam).rgb, base).sum() > 1000
        overlay.state.clear()
        legend = overlay.color_by_attribute("measured_height")
        assert legend is not None and legend.kind == "numeric" and legend.vmin < legend.vmax
        assert tinted(r.render(cam).rgb, base).sum() > 1000
        legend = overlay.color_by_attribute("function")
        assert legend is not None and legend.kind == "category" and legend.categories
        overlay.color_by_attribute(None)
        np.testing.assert_array_equal(r.render(cam).rgb, base)
        overlay.state.isolate([city.truth.buildings[0].id])  # every other building hidden
        assert (r.render(cam, depth=True).depth is not None)
        overlay.close()
        np.testing.assert_array_equal(r.render(cam).rgb, base)


def test_contour_map_follows_the_roof(city: SimpleNamespace) -> None:
    # Independent check of the upper contour against the analytic LoD2 roof of the gable building.
    store = CityStore.open(city.gpkg)
    cmap = build_contour_map(store, resolution=0.5)
    b = city.truth.buildings[5]
    idx = store.proxies.index_of(b.id)
    rows, cols = np.nonzero(cmap.texels[..., 0] == idx)
    x = cmap.x0 + (cols + 0.5) * cmap.resolution
    y = cmap.y1 - (rows + 0.5) * cmap.resolution
    roof = city.truth.roof_height(x, y)
    inner = np.isfinite(roof)
    top = cmap.texels[rows, cols, 2] + cmap.z_ref
    # Above the roof by the inflation, plus at most the rise of the roof across one texel (slope ≤ 1).
    assert np.all(top[inner] >= roof[inner] + store.inflate - 1e-3)
    assert np.all(top[inner] <= roof[inner] + store.inflate + cmap.resolution + 1e-3)


def test_render_command_with_city_among_sources(city: SimpleNamespace, tmp_path: Path) -> None:
    b = city.truth.buildings[3]
    cam_file = tmp_path / "cam.json"
    cam_file.write_text(json.dumps(oblique(city.truth, b).to_dict()))
    common = dict(camera=cam_file, tau=1.0, size=list(SIZE), color_by="auto")
    plain = argparse.Namespace(sources=[str(city.dir / "dsm")], output=str(tmp_path / "plain.png"),
                               depth=str(tmp_path / "plain.npy"), **common)
    render_command(plain, progress=False)
    lit = argparse.Namespace(sources=[str(city.dir / "dsm"), str(city.gpkg)], output=str(tmp_path / "lit.png"),
                             depth=None, highlight=f"object_id = '{b.id}'", hide=None, **common)
    render_command(lit, progress=False)
    hid = argparse.Namespace(sources=[str(city.dir / "dsm")], city=str(city.gpkg), output=str(tmp_path / "hid.png"),
                             depth=str(tmp_path / "hid.npy"), highlight=None, hide="measured_height > 0", **common)
    render_command(hid, progress=False)
    a, lit_rgb, hid_rgb = (read_png(tmp_path / n) for n in ("plain.png", "lit.png", "hid.png"))
    assert tinted(lit_rgb, a).sum() > 1000
    # Hiding every building looks through them: many pixels now show something farther away.
    d0, d1 = np.load(tmp_path / "plain.npy"), np.load(tmp_path / "hid.npy")
    assert (d1 > d0 + 1.0).sum() > 2000
    assert tinted(hid_rgb, a).sum() > 2000


def read_png(path: Path) -> np.ndarray:
    import matplotlib.image

    return (matplotlib.image.imread(path)[..., :3] * 255).round().astype(np.uint8)


def test_semantic_hook_needs_a_city(city: SimpleNamespace) -> None:
    from citylod.core.errors import CitylodError

    with OffscreenRenderer([city.dir / "dsm"], size=(32, 32)) as r, pytest.raises(CitylodError):
        semantic_hook(r.scene, city=None, highlight="1 = 1")


def test_highlight_on_a_dsm_reads_as_its_colour(city: SimpleNamespace, tmp_path: Path) -> None:
    """The app's default highlight (#ffcc00) on a textured DSM is a bright, saturated yellow over the
    building, not a darkened khaki: the median pixel over the analytic footprint is near the colour."""
    b = city.truth.buildings[5]
    cam = oblique(city.truth, b)
    before, after, overlay, store = render_pair([city.dir / "dsm"], city.gpkg, cam,
                                                lambda ov, st: ov.state.highlight([b.id], "#ffcc00"))
    save_png(tmp_path / "highlight.png", after.rgb)
    inside = analytic_mask(city.truth, before.depth, cam, b.index, store.inflate)
    core = ndimage.binary_erosion(inside, np.ones((3, 3), bool), iterations=1)
    assert core.sum() > 1000
    r, g, bl = np.median(after.rgb[core].astype(float), axis=0)
    assert r >= 215 and g >= 170 and bl <= 40, (r, g, bl)
    overlay.close()


def test_a_wall_above_an_abutting_road_is_tinted_whole(tmp_path: Path) -> None:
    """A road polygon of the city model meets a building at its wall (as BGT's roads meet Delft's houses).
    The footprint map gives each texel one object, and about half the texels along the wall went to the
    road, whose height interval holds none of the wall: the highlighted wall came out striped. Expected from
    geometry alone: every pixel showing the wall between 1 m above the ground and 0.5 m under the roof."""
    from citylod.bench.synthetic import make_terrain_tileset
    from citylod.io.city.model import CityModel, CityObject
    from citylod.semantics.store import build_city

    corner = np.array([500_000.0, 5_400_000.0, 0.0])
    bx0, by0, bx1, by1, top = 20.3, 30.3, 40.3, 44.3, 10.0  # off the texel grid on purpose

    def box(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.where((x >= bx0) & (x <= bx1) & (y >= by0) & (y <= by1), top, 0.0)

    tiles = make_terrain_tileset(tmp_path / "t", levels=1, n=257, extent=64.0, corner=corner, height_fn=box,
                                 texture_px=None)

    def ring(xy: list[tuple[float, float]], z: float) -> np.ndarray:
        return np.array([(x + corner[0], y + corner[1], z) for x, y in xy + [xy[0]]])

    def wall(a: tuple[float, float], b: tuple[float, float]) -> np.ndarray:
        return np.array([(a[0], a[1], 0.0), (b[0], b[1], 0.0), (b[0], b[1], top), (a[0], a[1], top),
                         (a[0], a[1], 0.0)]) + corner

    corners_xy = [(bx0, by0), (bx0, by1), (bx1, by1), (bx1, by0)]
    sides = list(zip(corners_xy[::-1], corners_xy[::-1][1:] + corners_xy[::-1][:1], strict=True))
    building = CityObject("house", "Building", {}, [[ring(corners_xy, 0.0)], [ring(corners_xy[::-1], top)]]
                          + [[wall(a, b)] for a, b in sides], 1)
    road = CityObject("road", "Road", {}, [[ring([(0.0, 10.0), (64.0, 10.0), (64.0, by0), (0.0, by0)], 0.0)]], 1)
    gpkg = tmp_path / "city.gpkg"
    build_city(CityModel([building, road], None, "m.gml"), gpkg, crs="EPSG:25832", progress=False)
    # From the road's side, looking at the south wall.
    cx = corner[0] + (bx0 + bx1) / 2
    cam = Camera((cx, corner[1] + by0 - 30.0, 12.0), (cx, corner[1] + by0, 5.0), (0.0, 0.0, 1.0), 45.0)
    store = CityStore.open(gpkg)
    with OffscreenRenderer([tiles], size=SIZE) as r:
        overlay = SemanticOverlay(r.scene, store)  # the default texel size, coarser than these pixels
        before = r.render(cam, depth=True)
        overlay.state.highlight(["house"], TINT)
        after = r.render(cam, depth=True)
    pts = points_from_distance(before.depth, cam, relative=False)
    ok = np.isfinite(before.depth)
    x, y, z = (np.where(ok, pts[..., k], np.nan) for k in range(3))
    wall = ok & (np.abs(y - (corner[1] + by0)) < 0.3) & (x > corner[0] + bx0 + 0.5) & (x < corner[0] + bx1 - 0.5)
    wall &= (z > 1.0) & (z < top - 0.5)
    assert wall.sum() > 2000
    got = tinted(after.rgb, before.rgb)
    assert got[wall].mean() > 0.98, got[wall].mean()
