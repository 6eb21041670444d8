"""Polygon edits at render time on points and DSM tiles, checked on the rendered pixels.

Independent check: each pixel's depth gives the 3D point drawn there (points_from_distance); whether it lies
in a polygon is decided with matplotlib's ``Path.contains_points`` (not shapely, which the edits use).
Pixels within a few pixel footprints of a polygon edge are left out: a point sprite covers 2 px.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyproj
import pytest
import shapely
from matplotlib.path import Path as MplPath

from citylod.analysis.polygons import EditPolygon, PolygonLayer
from citylod.bench.synthetic import make_point_tileset, make_terrain_tileset
from citylod.core.camera import Camera
from citylod.render.depth import points_from_distance
from citylod.render.edits import PolygonEdits
from citylod.render.offscreen import OffscreenRenderer

pytestmark = pytest.mark.render

CORNER = np.array([500000.0, 5400000.0, 0.0])
EXT = 256.0
SIZE = (320, 320)
COLOURS = [(255, 0, 255), (0, 255, 255), (255, 255, 0), (0, 0, 255), (255, 128, 0), (128, 0, 255),
           (255, 255, 255), (0, 128, 128)]


def polygons() -> tuple[EditPolygon, ...]:
    """10 polygons: 8 recolour (triangles and boxes, two overlapping), one discard, one displace."""
    x0, y0 = CORNER[0], CORNER[1]
    out = []
    for i, col in enumerate(COLOURS):
        cx, cy = x0 + 30 + (i % 4) * 55, y0 + 40 + (i // 4) * 60
        g = shapely.Polygon([(cx - 20, cy - 15), (cx + 22, cy - 10), (cx + 5, cy + 25)]) if i % 2 else \
            shapely.box(cx - 18, cy - 18, cx + 18, cy + 14)
        out.append(EditPolygon(g, "recolor", col, name=f"r{i}"))
    out.append(EditPolygon(shapely.box(x0 + 20, y0 + 170, x0 + 90, y0 + 230), "discard", name="cut"))
    out.append(EditPolygon(shapely.box(x0 + 150, y0 + 170, x0 + 230, y0 + 235), "displace", height_m=30.0,
                           name="dyke"))
    return tuple(out)


def top_camera() -> Camera:
    c = CORNER + np.array([EXT / 2, EXT / 2, 0.0])
    return Camera(tuple(c + np.array([0, -0.01, 380.0])), tuple(c), (0.0, 1.0, 0.0), 45.0)


def world(frame, cam: Camera) -> np.ndarray:
    return points_from_distance(frame.depth, cam, relative=False)


def inside(poly: shapely.Polygon, xy: np.ndarray) -> np.ndarray:
    return MplPath(np.asarray(poly.exterior.coords)).contains_points(xy)


def margin_ok(polys: tuple[EditPolygon, ...], xy: np.ndarray, m: float) -> np.ndarray:
    edges = shapely.union_all([p.geometry.boundary for p in polys])
    return shapely.distance(edges, shapely.points(xy)) > m


def inside_px(points: np.ndarray, poly: EditPolygon, m: float) -> np.ndarray:
    """Pixels whose surface point (``world``; NaN where nothing is drawn) lies inside ``poly``, more than
    ``m`` metres from its edge."""
    seen = np.isfinite(points[..., 0])
    out = np.zeros(seen.shape, bool)
    xy = points[seen][:, :2]
    out[seen] = inside(poly.geometry, xy) & margin_ok((poly,), xy, m)
    return out


@pytest.fixture(scope="module")
def points_tiles(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_point_tileset(tmp_path_factory.mktemp("pts"), levels=3, points_per_tile=12000, extent=EXT,
                              corner=CORNER, crs="EPSG:25832")


def test_point_edits_match_an_independent_point_in_polygon_test(points_tiles: Path) -> None:
    cam = top_camera()
    polys = polygons()
    layer = PolygonLayer(polys, pyproj.CRS("EPSG:25832"))
    with OffscreenRenderer([points_tiles], size=SIZE, tau_px=0.5) as r:
        plain = r.render(cam, depth=True)
        edits = PolygonEdits(r.scene, layer)
        edited = r.render(cam, depth=True)
        n = edits.tiles_edited
        again = r.render(cam, depth=True)
        assert edits.tiles_edited == n  # steady state: nothing is classified again
        np.testing.assert_array_equal(again.rgb, edited.rgb)
        edits.close()
        restored = r.render(cam, depth=True)
    np.testing.assert_array_equal(restored.rgb, plain.rgb)

    # recolour: every drawn pixel gets the colour of the last recolour polygon holding its point
    p_ed = world(edited, cam)
    hit = np.isfinite(p_ed[..., 0])
    xy = p_ed[hit][:, :2]
    expect = np.full(len(xy), -1)
    for i, p in enumerate(polys[:8]):
        expect[inside(p.geometry, xy)] = i
    safe = margin_ok(polys, xy, 3.0)
    rgb = edited.rgb[hit].astype(int)
    table = np.array(COLOURS)
    got_in = (rgb[expect >= 0] == table[expect[expect >= 0]]).all(axis=1)
    assert (safe[expect >= 0]).sum() > 2000
    assert got_in[safe[expect >= 0]].mean() > 0.995
    outside = rgb[(expect < 0) & safe]
    is_edit_colour = (outside[:, None, :] == table[None]).all(axis=2).any(axis=1)
    assert is_edit_colour.mean() < 0.001
    plain_rgb = plain.rgb.reshape(-1, 3)
    assert not (plain_rgb[:, None, :] == table[None]).all(axis=2).any()  # the colours are the edits'

    # discard: where the plain render saw ground inside the cut, the edited one sees nothing
    p_pl = world(plain, cam)
    cut = inside_px(p_pl, polys[8], 3.0)
    assert cut.sum() > 500
    assert np.isinf(edited.depth[cut]).mean() > 0.99

    # displace: the points inside the dyke polygon are drawn 30 m higher
    dyke = inside_px(p_pl, polys[9], 8.0)
    z_plain = np.median(p_pl[dyke][:, 2])
    moved = np.isfinite(p_ed[..., 0]) & dyke
    z_edit = np.median(p_ed[moved][:, 2])
    assert z_edit - z_plain == pytest.approx(30.0, abs=1.0)


def test_discard_and_the_class_filter_reach_splats(points_tiles: Path) -> None:
    # Splats are glyphs of every point, not of the vertex cells that discard and the class filter trim:
    # they take a bit mask (VTK's glyph mapper ignores any other kind of mask array).
    cam = top_camera()
    polys = polygons()
    with OffscreenRenderer([points_tiles], size=SIZE, tau_px=0.5) as r:
        r.scene.layers[0].point_shape = "splat"
        plain = r.render(cam, depth=True)
        edits = PolygonEdits(r.scene, PolygonLayer(polys[8:9], pyproj.CRS("EPSG:25832")))  # the cut alone
        edited = r.render(cam, depth=True)
        edits.close()
        r.scene.layers[0].class_filter = frozenset({6})  # buildings only (the synthetic block)
        r.scene.layers[0].restyle()
        filtered = r.render(cam, depth=True)
    p_pl = world(plain, cam)
    seen = np.isfinite(p_pl[..., 0])
    cut = inside_px(p_pl, polys[8], 6.0)  # disks reach up to three spacings past their point: a 6 m margin
    assert cut.sum() > 500
    assert np.isinf(edited.depth[cut]).mean() > 0.99
    assert np.isfinite(edited.depth[seen & ~cut]).mean() > 0.9  # the rest stays
    assert np.isfinite(filtered.depth).sum() < 0.5 * seen.sum()  # the ground is filtered out


def test_mesh_edits_discard_displace_and_tint(tmp_path: Path) -> None:
    tiles = make_terrain_tileset(tmp_path / "dsm", levels=2, n=33, extent=EXT, corner=CORNER,
                                 height_fn=lambda x, y: np.zeros_like(x, dtype=np.float64), texture_px=64)
    cam = top_camera()
    x0, y0 = CORNER[0], CORNER[1]
    polys = (EditPolygon(shapely.box(x0 + 20, y0 + 20, x0 + 100, y0 + 100), "discard"),
             EditPolygon(shapely.box(x0 + 140, y0 + 20, x0 + 230, y0 + 110), "displace", height_m=20.0),
             EditPolygon(shapely.box(x0 + 40, y0 + 150, x0 + 200, y0 + 230), "recolor", (0, 0, 255)))
    with OffscreenRenderer([tiles], size=SIZE, tau_px=1.0) as r:
        plain = r.render(cam, depth=True)
        PolygonEdits(r.scene, PolygonLayer(polys, r.scene.crs))
        edited = r.render(cam, depth=True)
    p_pl = world(plain, cam)
    seen = np.isfinite(p_pl[..., 0])
    xy = p_pl[seen][:, :2]
    # triangles are cut or moved whole, so keep a margin of one triangle (EXT / 2 / 32 m) around edges
    m = EXT / 64 + 2.0
    cut = np.zeros(seen.shape, bool)
    cut[seen] = inside(polys[0].geometry, xy) & margin_ok(polys[:1], xy, m)
    assert cut.sum() > 500 and np.isinf(edited.depth[cut]).mean() > 0.99
    up = np.zeros(seen.shape, bool)
    up[seen] = inside(polys[1].geometry, xy) & margin_ok(polys[1:2], xy, m + 6.0)
    p_ed = world(edited, cam)
    assert np.median(p_ed[up][:, 2]) - np.median(p_pl[up][:, 2]) == pytest.approx(20.0, abs=0.5)
    blue = np.zeros(seen.shape, bool)
    blue[seen] = inside(polys[2].geometry, xy) & margin_ok(polys[2:], xy, m)
    tinted = edited.rgb[blue].astype(int)
    assert (tinted[:, 0] < 10).mean() > 0.99 and (tinted[:, 1] < 10).mean() > 0.99  # texture × blue
    rest = seen & ~cut & ~up & ~blue
    rest[seen] &= margin_ok(polys, xy, m + 6.0)
    np.testing.assert_array_equal(edited.rgb[rest], plain.rgb[rest])


def test_texture_edit_drapes_the_image_over_the_polygon(points_tiles: Path, tmp_path: Path) -> None:
    from citylod.io.image import encode_png

    quad = np.array([[[255, 0, 0], [0, 255, 0]], [[0, 0, 255], [255, 255, 0]]], np.uint8)  # row 0 = north
    img = tmp_path / "checker.png"
    img.write_bytes(encode_png(np.repeat(np.repeat(quad, 8, axis=0), 8, axis=1)))
    x0, y0 = CORNER[0] + 60, CORNER[1] + 60
    poly = shapely.box(x0, y0, x0 + 120, y0 + 120)
    layer = PolygonLayer((EditPolygon(poly, "texture", texture=str(img)),), pyproj.CRS("EPSG:25832"))
    cam = top_camera()
    with OffscreenRenderer([points_tiles], size=SIZE, tau_px=0.5) as r:
        PolygonEdits(r.scene, layer)
        frame = r.render(cam, depth=True)
    p = world(frame, cam)
    hit = np.isfinite(p[..., 0])
    xy = p[hit][:, :2]
    ok = inside(poly, xy) & margin_ok((EditPolygon(poly),), xy, 3.0)
    # quadrant of each point (independent of the edit's sampling): north-west red, north-east green, ...
    east = xy[:, 0] > x0 + 60
    north = xy[:, 1] > y0 + 60
    mid = (np.abs(xy[:, 0] - (x0 + 60)) > 3.0) & (np.abs(xy[:, 1] - (y0 + 60)) > 3.0)
    want = quad[np.where(north, 0, 1), np.where(east, 1, 0)]
    use = ok & mid
    assert use.sum() > 1000
    assert (frame.rgb[hit][use] == want[use]).all(axis=1).mean() > 0.995


def test_render_command_applies_edits_and_refuses_bad_polygons(points_tiles: Path, tmp_path: Path, capsys) -> None:
    import json

    from citylod.analysis.polygons import save_polygons
    from citylod.cli import main
    from citylod.io.image import decode_image

    top_camera().save(tmp_path / "cam.json")
    gj = save_polygons(PolygonLayer(polygons(), pyproj.CRS("EPSG:25832")), tmp_path / "edits.geojson")
    png = tmp_path / "edited.png"
    args = ["-q", "render", str(points_tiles), "-o", str(png), "--camera", str(tmp_path / "cam.json"),
            "--size", "160x160"]
    assert main([*args, "--edits", str(gj)]) == 0
    rgb = decode_image(png.read_bytes())
    assert ((rgb == COLOURS[0]).all(axis=-1)).sum() > 20
    bad = tmp_path / "bad.geojson"
    bad.write_text(json.dumps({"type": "Feature", "properties": {"action": "recolor"}, "geometry": {
        "type": "Polygon", "coordinates": [[[0, 0], [1, 1], [1, 0], [0, 1], [0, 0]]]}}))
    out = tmp_path / "bad.png"
    assert main([*args[:4], str(out), *args[5:], "--edits", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert "bad.geojson" in err and "Self-intersection" in err and len(err.splitlines()) == 1
    assert not out.exists()
