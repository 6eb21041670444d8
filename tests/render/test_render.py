"""Off-screen rendering of tilesets (EGL/Mesa, no X): pixels, depth, cracks, corrupt tiles, pooling, budgets.

Assertions are on arrays and counters, never on timings. The tilesets are made by code
(:mod:`citylod.bench.synthetic`), at 5.4e6 m northing so every test also exercises large coordinates.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import pytest

from citylod.bench.synthetic import make_point_tileset, make_terrain_tileset
from citylod.core.camera import Camera
from citylod.core.errors import InputError
from citylod.lod.runtime.selection import Budget
from citylod.render.depth import world_rays, zbuffer_to_distance
from citylod.render.offscreen import OffscreenRenderer, render_command, save_png
from citylod.render.tileset_actor import _SURFACE_RGB, baked_face_colors

pytestmark = pytest.mark.render

CORNER = np.array([500000.0, 5400000.0, 0.0])
EXTENT = 1024.0


def flat(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.zeros_like(x, dtype=np.float64)


@pytest.fixture(scope="module")
def flat_terrain(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_terrain_tileset(tmp_path_factory.mktemp("flat"), levels=3, n=9, extent=EXTENT, corner=CORNER,
                                height_fn=flat, texture_px=32)


@pytest.fixture(scope="module")
def hills(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_terrain_tileset(tmp_path_factory.mktemp("hills"), levels=4, n=17, extent=EXTENT, corner=CORNER,
                                texture_px=None)


def top_camera(x: float, y: float, h: float, fovy: float = 45.0) -> Camera:
    return Camera((x, y, h), (x, y, 0.0), (0.0, 1.0, 0.0), fovy)


def test_depth_conversion_matches_the_projection() -> None:
    # A plane at eye distance 10 along the axis, seen through the perspective depth mapping.
    near, far, fovy, w, h = 1.0, 100.0, 60.0, 8, 6
    z_eye = 10.0
    z_ndc = ((far + near) - 2 * near * far / z_eye) / (far - near)
    zb = np.full((h, w), (z_ndc + 1) / 2)
    zb[0, 0] = 1.0
    dist = zbuffer_to_distance(zb, near, far, fovy)
    cam = Camera((0.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0), fovy)
    rays = world_rays(cam, w, h)
    expected = z_eye / -rays[..., 2]
    assert np.isinf(dist[0, 0])
    np.testing.assert_allclose(dist[1:], expected[1:], rtol=1e-5)


def test_textured_render_is_oriented_and_coloured(flat_terrain: Path, tmp_path: Path) -> None:
    cx, cy = CORNER[0] + EXTENT / 2, CORNER[1] + EXTENT / 2
    h = 1400.0
    w_px, h_px = 320, 240
    with OffscreenRenderer([flat_terrain], size=(w_px, h_px), tau_px=1.0) as r:
        frame = r.render(top_camera(cx, cy, h), depth=True)
    save_png(tmp_path / "top.png", frame.rgb)
    rgb = frame.rgb.astype(int)
    # Background outside the footprint, geometry inside.
    assert np.all(rgb[:, :5] == rgb[0, 0])
    assert np.isinf(frame.depth[:, :5]).all()
    level = max(frame.stats.levels)
    base = np.array([[60, 140, 60], [200, 120, 40], [60, 100, 200]])[level % 5]
    bright = np.minimum(base + 70, 255)
    # Project a ground point to a pixel: the camera looks straight down with north up.
    px_m = 2 * h * math.tan(math.radians(22.5)) / h_px

    def pixel(x: float, y: float) -> np.ndarray:
        col = int(w_px / 2 + (x - cx) / px_m)
        row = int(h_px / 2 - (y - cy) / px_m)
        return rgb[row, col]

    tile = EXTENT / 2**level
    # North-west quadrant of the north-west tile is the bright one; its south-east quadrant is the base
    # colour. A mirrored or flipped texture swaps them.
    x_w, y_n = CORNER[0], CORNER[1] + EXTENT
    np.testing.assert_allclose(pixel(x_w + tile * 0.25, y_n - tile * 0.25), bright, atol=12)
    np.testing.assert_allclose(pixel(x_w + tile * 0.75, y_n - tile * 0.75), base, atol=12)
    np.testing.assert_allclose(pixel(x_w + tile * 0.75, y_n - tile * 0.25), base, atol=12)


def test_large_coordinates_depth_matches_the_analytic_plane(flat_terrain: Path) -> None:
    # Oblique view of the plane z = 0 at 5.4e6 m northing: the distance along every pixel ray must match
    # the ray-plane intersection computed in float64.
    target = CORNER + np.array([EXTENT * 0.5, EXTENT * 0.6, 0.0])
    cam = Camera(tuple(target + np.array([-150.0, -420.0, 260.0])), tuple(target), (0.0, 0.0, 1.0), 50.0)
    w, h = 200, 150
    with OffscreenRenderer([flat_terrain], size=(w, h), tau_px=1.0) as r:
        frame = r.render(cam, depth=True)
    rays = world_rays(cam, w, h)
    with np.errstate(divide="ignore"):
        t = -cam.position[2] / rays[..., 2]
    hit = np.asarray(cam.position) + rays * t[..., None]
    inside = (rays[..., 2] < 0) & np.all((hit[..., :2] > CORNER[:2] + 5) & (hit[..., :2] < CORNER[:2] + EXTENT - 5),
                                         axis=-1)
    assert inside.mean() > 0.3
    assert np.isfinite(frame.depth[inside]).all()
    rel = np.abs(frame.depth[inside] - t[inside]) / t[inside]
    assert rel.max() < 2e-3, rel.max()


def rough(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    # Short wavelengths give coarse tiles metres of error, so level boundaries open visible cracks.
    return 20 * np.sin(x / 19.0) * np.cos(y / 27.0) + 8 * np.sin((x - y) / 11.0)


@pytest.mark.parametrize("skirts", [True, False])
def test_mixed_levels_leave_no_cracks(tmp_path: Path, skirts: bool) -> None:
    ts = make_terrain_tileset(tmp_path / "rough", levels=4, n=17, extent=EXTENT, corner=CORNER, height_fn=rough,
                              texture_px=None, skirts=skirts)
    # Above the interior, wide angle: tiles near the camera refine further than those at the image
    # border, with T-junctions between levels 2 and 3.
    cam = Camera(tuple(CORNER + np.array([380.0, 330.0, 300.0])), tuple(CORNER + np.array([420.0, 380.0, 0.0])), (0.0, 1.0, 0.0), 70.0)
    with OffscreenRenderer([ts], size=(480, 360), tau_px=2.0) as r:
        frame = r.render(cam, depth=True)
    assert set(frame.stats.levels) == {2, 3}, frame.stats.levels
    assert frame.stats.complete
    holes = int(np.isinf(frame.depth).sum())
    if skirts:
        # The view lies entirely inside the terrain's footprint: no background pixel anywhere.
        assert holes == 0
    else:
        # Control: the same selection without skirts shows background through the cracks.
        assert holes > 0


def test_corrupt_tile_is_reported_and_skipped(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    ts = make_terrain_tileset(tmp_path / "ts", levels=2, n=9, extent=EXTENT, corner=CORNER, texture_px=None)
    bad = ts / "tiles" / "1" / "0" / "0.glb"
    bad.write_bytes(b"this is not a glb at all" * 10)
    cam = top_camera(CORNER[0] + EXTENT / 2, CORNER[1] + EXTENT / 2, 900.0)
    with OffscreenRenderer([ts], size=(160, 120), tau_px=0.05) as r:
        frame = r.render(cam, depth=True)
        failed = r.scene.loader.failed
        bad_key = next(n.key for n in r.scene.layers[0]._nodes.values() if n.content_uri == "tiles/1/0/0.glb")
    assert list(failed) == [bad_key]
    assert "0.glb" in failed[bad_key] and "magic" in failed[bad_key]
    # The three good leaves are drawn; the corrupt one is a hole, not a crash.
    assert frame.stats.tiles == 3
    assert frame.stats.levels == {1: 3}
    assert np.isfinite(frame.depth).mean() > 0.2
    # The command line refuses the picture (a hole looks plausible and is wrong): one error naming the
    # tile file, exit 2 through main(), and no image or depth file written.
    cam_file = tmp_path / "cam.json"
    cam.save(cam_file)
    args = argparse.Namespace(sources=[ts], output=tmp_path / "out.png", camera=cam_file, tau=0.05,
                              size=(160, 120), depth=tmp_path / "d.npy", city=None, highlight=None, hide=None,
                              color_by="level")
    with pytest.raises(InputError, match=r"1/0/0\.glb"):
        render_command(args, progress=False)
    assert not (tmp_path / "out.png").exists() and not (tmp_path / "d.npy").exists()


def _flight(n: int) -> list[Camera]:
    cams = []
    for i in range(n):
        a = 2 * math.pi * i / n
        target = CORNER + np.array([EXTENT / 2 + 200 * math.cos(a), EXTENT / 2 + 200 * math.sin(a), 0.0])
        eye = target + np.array([300 * math.cos(a + 2), 300 * math.sin(a + 2), 120.0 + 60 * i])
        cams.append(Camera(tuple(eye), tuple(target), (0.0, 0.0, 1.0), 45.0))
    return cams


def _actors(renderer: object) -> list[object]:
    coll = renderer.GetActors()  # type: ignore[attr-defined]
    return [coll.GetItemAsObject(i) for i in range(coll.GetNumberOfItems())]


def test_actors_are_pooled(hills: Path) -> None:
    peak = 0
    with OffscreenRenderer([hills], size=(160, 120), tau_px=1.0) as r:
        for cam in _flight(5):
            frame = r.render(cam)
            peak = max(peak, len(r.scene.cache))
            visible = sum(a.GetVisibility() for a in _actors(r.renderer))
            assert visible == frame.stats.tiles
        # One actor per resident tile at most, however many frames and uploads there were.
        assert r.scene.actors_created <= peak
        assert len(_actors(r.renderer)) == r.scene.actors_created
        assert r.scene.uploads > 0


def test_budget_is_never_exceeded_during_a_flight(hills: Path) -> None:
    total = sum(p.stat().st_size for p in (hills / "tiles").rglob("*.glb"))
    cache_bytes = 400_000
    draw_bytes = 250_000
    with OffscreenRenderer([hills], size=(160, 120), tau_px=0.5, cache_bytes=cache_bytes) as r:
        r.scene.layers[0].budget = Budget(max_bytes=draw_bytes)
        # The decoded data is larger than the cache: the cache must evict and refuse, never overflow.
        assert total > cache_bytes
        limited = 0
        for cam in _flight(8):
            frame = r.render(cam)
            assert r.scene.cache.bytes_used <= cache_bytes
            assert frame.stats.bytes_drawn <= draw_bytes
            limited += r.scene.layers[0].selection.stats.budget_limited
            assert frame.stats.tiles > 0
        assert limited > 0  # the budget was actually binding


def test_points_are_coloured_by_classification(tmp_path: Path) -> None:
    ts = make_point_tileset(tmp_path / "pts", levels=2, points_per_tile=3000, extent=256.0, corner=CORNER)
    cam = top_camera(CORNER[0] + 128, CORNER[1] + 128, 400.0)
    with OffscreenRenderer([ts], size=(200, 150), tau_px=0.5, color_by="classification",
                           point_size_px=3) as r:
        frame = r.render(cam)
        assert frame.stats.points > 0
        r.scene.set_color_by("rgb")
        frame_rgb = r.render(cam)
    save_png(tmp_path / "pts.png", frame.rgb)
    colours = frame.rgb.reshape(-1, 3).astype(int)
    building = np.all(np.abs(colours - [220, 60, 50]) < 8, axis=1).sum()
    ground = np.all(np.abs(colours - [166, 118, 70]) < 8, axis=1).sum()
    assert building > 100 and ground > 100
    colours_rgb = frame_rgb.rgb.reshape(-1, 3).astype(int)
    assert np.all(np.abs(colours_rgb - [200, 80, 60]) < 8, axis=1).sum() > 100


def test_two_tilesets_share_one_scene(flat_terrain: Path, tmp_path: Path) -> None:
    pts = make_point_tileset(tmp_path / "pts", levels=2, points_per_tile=2000, extent=256.0,
                             corner=CORNER + np.array([0.0, 0.0, 5.0]))
    cam = top_camera(CORNER[0] + 128, CORNER[1] + 128, 600.0)
    with OffscreenRenderer([flat_terrain, pts], size=(160, 120), tau_px=0.5, edl=True) as r:
        frame = r.render(cam, depth=True)
        keys = set(r.scene.cache)
        assert len(r.scene.layers) == 2
    # Keys are namespaced per layer in the shared cache; both kinds of geometry are drawn.
    assert {k.split(":")[0] for k in keys} == {"0", "1"}
    assert frame.stats.points > 0 and frame.stats.triangles > 0
    # The camera is over the terrain's south-west corner: the north-east three quarters are covered.
    assert np.isfinite(frame.depth[: 120 // 2 - 5, 160 // 2 + 5:]).all()


def test_edl_shades_the_scene_not_the_view_aids(tmp_path: Path) -> None:
    """Eye-Dome Lighting darkens the points' depth edges but draws the scale bar and north arrow as without
    it: the red arrow stays red (through the shading it turned black, being all edge)."""
    from citylod.render.hud import Hud, set_edl

    pts = make_point_tileset(tmp_path / "pts", levels=2, points_per_tile=3000, extent=256.0, corner=CORNER)
    cam = Camera((CORNER[0] + 128.0, CORNER[1] - 200.0, 300.0), (CORNER[0] + 128.0, CORNER[1] + 128.0, 0.0),
                 (0.0, 0.0, 1.0), 45.0)
    size = (320, 240)
    pictures = []
    with OffscreenRenderer([pts], size=size, tau_px=0.5) as r:
        hud = Hud(r.renderer)
        for on in (False, True):
            set_edl(r.renderer, on)
            r.prepare(cam)
            hud.update(cam, 1.0, size)
            r.draw()
            pictures.append(r.grab_rgb().astype(int))
        set_edl(r.renderer, False)
    plain, shaded = pictures
    arrow = (slice(20, 100), slice(size[0] - 80, size[0]))  # top right (rows from the top)
    red = [((p[arrow][..., 0] > 150) & (p[arrow][..., 1] < 60) & (p[arrow][..., 2] < 60)).sum() for p in pictures]
    assert red[0] > 20 and red[1] >= 0.8 * red[0], red
    assert np.abs(plain[arrow] - shaded[arrow]).mean() < 2.0
    assert np.abs(plain - shaded).mean() > 2.0  # the points are shaded


def test_baked_sun_matches_vtk_per_fragment_lighting(hills: Path) -> None:
    """Untextured surfaces are drawn unlit with the sun baked into triangle colours: the image must equal
    VTK's own per-fragment lighting of the same faceted meshes (the independent computation)."""
    cam = Camera((CORNER[0] + 200.0, CORNER[1] - 300.0, 600.0), (CORNER[0] + 512.0, CORNER[1] + 512.0, 0.0),
                 (0.0, 0.0, 1.0), 50.0)
    with OffscreenRenderer([hills], size=(240, 160), tau_px=1.0) as r:
        baked = r.render(cam).rgb.astype(int)
        shown = [a for a in _actors(r.renderer) if a.GetVisibility()]
        assert shown and all(not a.GetProperty().GetLighting() for a in shown)
        for a in shown:  # back to VTK's lighting: flat normals from screen derivatives, the same sun
            a.GetMapper().ScalarVisibilityOff()
            a.GetProperty().SetColor(*_SURFACE_RGB)
            a.GetProperty().LightingOn()
            a.GetProperty().SetAmbient(0.3)
            a.GetProperty().SetDiffuse(0.75)
        r.draw()
        lit = r.grab_rgb().astype(int)
    terrain = np.any(baked != baked[0, 0], axis=2)  # not sky
    assert terrain.mean() > 0.5
    diff = np.abs(baked - lit).max(axis=2)[terrain]
    assert np.percentile(diff, 99) <= 3, np.percentile(diff, [50, 99, 100])
    # and the shading is not flat: slopes facing the sun and away from it differ
    assert np.ptp(baked[terrain].mean(axis=1)) > 30


def test_baked_face_colors_follow_the_tile_rotation() -> None:
    # A triangle facing +x, tile rotated 90° about z so it faces +y in the scene (towards the sun's
    # north-west quadrant): independent formula base · (0.3 + 0.75 · max(0, n·L)).
    pos = np.array([[0, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32)
    faces = np.array([0, 1, 2], np.int64)
    rot = np.eye(4)
    rot[:2, :2] = [[0.0, -1.0], [1.0, 0.0]]
    sun = np.array([-1.0, 1.0, math.sqrt(2.0)]) / 2.0
    for matrix, normal in ((np.eye(4), np.array([1.0, 0.0, 0.0])), (rot, np.array([0.0, 1.0, 0.0]))):
        rgb = baked_face_colors(pos, faces, matrix, (1.0, 1.0, 1.0))
        expect = 255.0 * min(1.0, 0.3 + 0.75 * max(0.0, float(normal @ sun)))
        assert abs(int(rgb[0, 0]) - expect) <= 0.51


def test_render_without_a_camera_frames_the_data(hills: Path, tmp_path: Path) -> None:
    """``citylod render TILES -o OUT`` (no ``--camera``) shows all the data filling the frame; ``--camera
    orbit:3`` writes three frames around it, each with all the data in view."""
    from citylod.cli import main

    assert main(["render", str(hills), "-o", str(tmp_path / "a.png"), "--size", "320x180",
                 "--depth", str(tmp_path / "a.npy")]) == 0
    seen = np.isfinite(np.load(tmp_path / "a.npy"))
    rows, cols = np.flatnonzero(seen.any(axis=1)), np.flatnonzero(seen.any(axis=0))
    # Nothing cut at the frame's edges, and the data spans most of its width or height.
    assert rows[0] > 0 and rows[-1] < 179 and cols[0] > 0 and cols[-1] < 319
    assert max((rows[-1] - rows[0]) / 180, (cols[-1] - cols[0]) / 320) > 0.6
    assert main(["render", str(hills), "-o", str(tmp_path / "o.png"), "--size", "160x90", "--camera", "orbit:3",
                 "--depth", str(tmp_path / "o.npy")]) == 0
    frames = [np.load(tmp_path / f"o_{i:04d}.npy") for i in range(3)]
    for d in frames:
        m = np.isfinite(d)
        assert m.any() and not (m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any())
    assert not np.array_equal(np.isfinite(frames[0]), np.isfinite(frames[1]))


def test_render_camera_keywords_refuse_bad_counts(hills: Path, tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    from citylod.cli import main

    for spec, says in (("orbit:0", "1 to 100000"), ("overview:4", "one camera"), ("nothere.json", "camera file")):
        assert main(["render", str(hills), "-o", str(tmp_path / "x.png"), "--camera", spec]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and says in err[0], err
    assert not list(tmp_path.glob("x*.png"))
