"""Far-field surface light fields drawn (issue 28): the field's image against the geometry's for a simple
scene, the cross-fade without popping, the command line and the validator."""

from __future__ import annotations

import contextlib
import itertools
import math
import time
from pathlib import Path

import numpy as np
import pytest

from citylod.cli import main
from citylod.core.camera import Camera
from citylod.lod.build.slf import GROUND_RGB, build_slf
from citylod.lod.kernels.slf import mip_levels
from citylod.render.gl_texture import TextureWriter
from citylod.render.slf import TEXEL_PX, GeometryView, SlfView
from citylod.render.slf_gpu import encode_heights
from tests.lod.slf_scene import BOX, X0, Y0, Z0, write_box_city

SIZE = (320, 240)
BIG = (800, 600)


@pytest.fixture(scope="module")
def box_slf(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("slf_render")
    city = write_box_city(tmp / "city")
    out = tmp / "slf"
    build_slf(city, out, texel_m=0.5, texels=128, grid=11, oversample=2, clusters=64, progress=False)
    return out


def _camera(dist: float, az_deg: float, el_deg: float) -> Camera:
    c = np.array([X0 + 30.0, Y0 + 30.0, Z0])
    az, el = math.radians(az_deg), math.radians(el_deg)
    eye = c + dist * np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])
    return Camera(tuple(eye), tuple(c), (0.0, 0.0, 1.0) if el_deg < 89 else (0.0, 1.0, 0.0), 20.0)


@pytest.mark.parametrize(("az", "el"), [(0.0, 90.0), (200.0, 40.0), (120.0, 55.0)])
def test_field_image_matches_the_geometry(box_slf: Path, az: float, el: float) -> None:
    """Where the selection at τ = 8 px picks the field (one box, one colour per face), it draws what the
    box's geometry draws: the mean colour error over the field's pixels is small, and the box's roof is
    there. (Nearer, the blend of four directions shows the roof in up to four places: the parallax that
    the cell's geometricError accounts for.)"""
    cam = _camera(2000.0, az, el)  # a pixel is 1.2 m, the box 9 px wide, the cell's error 3.6 px
    with SlfView(box_slf, size=BIG, tau_px=8.0) as sv:
        f = sv.prepare(cam)
        assert f.cells >= 1 and f.geometry_cells == 0
        sv.draw()
        img, mask = sv.grab_rgb(), sv.field_mask()
    with GeometryView(box_slf, size=BIG) as gv:
        gv.prepare(cam, full_resolution=True)
        gv.draw()
        ref = gv.grab_rgb()
    assert mask.sum() > 1000
    d = np.abs(img.astype(int) - ref.astype(int)).mean(axis=2)[mask]
    assert d.mean() <= 8.0, d.mean()
    ground = np.array(GROUND_RGB)
    box_ref = (np.abs(ref.astype(int) - ground).max(axis=2) > 40) & mask
    box_img = (np.abs(img.astype(int) - ground).max(axis=2) > 40) & mask
    assert box_ref.sum() > 20  # the box is there from every side
    assert 0.5 * box_ref.sum() <= box_img.sum() <= 2.0 * box_ref.sum()
    assert (box_ref & box_img).sum() >= 0.4 * box_ref.sum()  # and in the same place


@pytest.mark.parametrize("lookup", ["gpu", "cpu"])
def test_a_view_that_moved_draws_what_a_fresh_view_draws(box_slf: Path, lookup: str) -> None:
    """Fields re-evaluated as the camera moves update their textures in place (CPU), or their shader's
    uniforms (GPU): after three views, the fourth is drawn exactly as by a view that opens on it, and differs
    from the first (the field did change)."""
    cams = [_camera(2000.0, az, 40.0) for az in (200.0, 230.0, 260.0, 290.0)]
    with SlfView(box_slf, size=SIZE, tau_px=8.0, lookup=lookup) as sv:
        for cam in cams:
            f = sv.prepare(cam)
            assert f.evaluations >= 1
            sv.draw()
            if cam is cams[0]:
                first = sv.grab_rgb()
        moved = sv.grab_rgb()
    with SlfView(box_slf, size=SIZE, tau_px=8.0, lookup=lookup) as sv:
        sv.prepare(cams[-1])
        sv.draw()
        fresh = sv.grab_rgb()
    assert np.array_equal(moved, fresh)
    assert not np.array_equal(first, fresh)


def test_mip_levels_are_the_rounded_means_of_the_level_above() -> None:
    """The packed chain GL is given: level 0 the image bottom row first, each level the mean of 2 × 2 texels
    of the one above rounded half up (numpy, independently), alpha 255."""
    img = np.random.default_rng(3).integers(0, 256, (16, 16, 3), dtype=np.uint8)
    packed = mip_levels(img)
    chain, off = [], 0
    for k in range(5):
        n = 16 >> k
        chain.append(packed[off:off + n * n * 4].reshape(n, n, 4))
        off += n * n * 4
    assert off == packed.size
    assert np.array_equal(chain[0][..., :3], img[::-1])
    for above, lv in itertools.pairwise(chain):
        n = lv.shape[0]
        mean = above.astype(np.float64).reshape(n, 2, n, 2, 4).mean(axis=(1, 3))
        assert np.array_equal(lv, np.floor(mean + 0.5).astype(np.uint8))
    assert (packed[3::4] == 255).all()


def test_field_textures_are_written_into_gl_as_vtk_would_draw_them(box_slf: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """A moving view writes its fields' textures and their mip chains straight into GL
    (:class:`~citylod.render.gl_texture.TextureWriter`: no upload through VTK, no GL mip generation, which
    costs llvmpipe 0.35–0.55 ms a texture), and draws what VTK's own upload draws, to one step of rounding in
    the minified levels. From far and steep, the cells' textures are minified."""
    cams = [_camera(d, az, el) for d, az, el in ((2000.0, 200.0, 40.0), (2600.0, 215.0, 25.0),
                                                 (3200.0, 230.0, 60.0), (2000.0, 245.0, 35.0))]

    def frames() -> tuple[list[np.ndarray], int]:
        with SlfView(box_slf, size=SIZE, tau_px=8.0, lookup="cpu") as sv:
            out = []
            for cam in cams:
                assert sv.prepare(cam).evaluations >= 1
                sv.draw()
                out.append(sv.grab_rgb())
            return out, sv._writer.writes

    direct, writes = frames()
    monkeypatch.setattr(TextureWriter, "write", lambda self, *a: False)
    through_vtk, none = frames()
    assert writes >= len(cams) and none == 0
    for a, b in zip(direct, through_vtk, strict=True):
        assert np.abs(a.astype(int) - b.astype(int)).max() <= 1


@pytest.mark.parametrize(("dist", "az", "el", "tau"), [(400.0, 200.0, 40.0, 1e6), (400.0, 75.0, 30.0, 1e6),
                                                      (2000.0, 200.0, 40.0, 8.0), (3000.0, 300.0, 25.0, 8.0)])
def test_gpu_lookup_draws_what_the_cpu_lookup_draws(box_slf: Path, dist: float, az: float, el: float,
                                                    tau: float) -> None:
    """The fragment shader's lookup (per pixel) against the compiled kernel's (per texel, then a filtered
    texture), magnified up close and minified far away: the two pictures agree over the field's pixels, and
    the shader's is at least as close to the geometry (it evaluates each pixel's own point of the field)."""
    cam = _camera(dist, az, el)
    imgs = {}
    for lookup in ("cpu", "gpu"):
        with SlfView(box_slf, size=BIG, tau_px=tau, lookup=lookup) as sv:
            f = sv.prepare(cam)
            assert f.cells == 1 and f.geometry_cells == 0
            sv.draw()
            imgs[lookup], mask = sv.grab_rgb().astype(int), sv.field_mask()
            assert (next(iter(sv.cells.values())).gpu_patch is not None) == (lookup == "gpu")
    with GeometryView(box_slf, size=BIG) as gv:
        gv.prepare(cam, full_resolution=True)
        gv.draw()
        ref = gv.grab_rgb().astype(int)
    assert mask.sum() > 300
    err = {k: float(np.abs(v - ref).mean(axis=2)[mask].mean()) for k, v in imgs.items()}
    assert float(np.abs(imgs["gpu"] - imgs["cpu"]).mean(axis=2)[mask].mean()) <= 1.5
    assert err["gpu"] <= err["cpu"] + 0.25, err


def test_a_shader_that_does_not_build_falls_back_to_the_cpu_lookup(box_slf: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """A GL that cannot build the lookup shader (VTK then draws the quad with its atlas, and says so only
    through the mapper's ErrorEvent) gets the CPU lookup: the same draw call's picture is the CPU lookup's,
    with one warning, and later frames stay on the CPU."""
    import citylod.render.slf_gpu as slf_gpu

    monkeypatch.setattr(slf_gpu, "_IMPL", slf_gpu._IMPL.replace("float hh = slfRayTop(r, c);", "float hh = ;"))
    cams = [_camera(2000.0, 200.0, 40.0), _camera(2000.0, 230.0, 40.0)]
    with SlfView(box_slf, size=SIZE, tau_px=8.0, lookup="cpu") as ref:
        want = []
        for cam in cams:
            ref.prepare(cam)
            ref.draw()
            want.append(ref.grab_rgb())
    with SlfView(box_slf, size=SIZE, tau_px=8.0) as sv:
        assert sv.lookup == "gpu"
        sv.prepare(cams[0])
        with pytest.warns(RuntimeWarning, match="lookup shader could not be built"):
            sv.draw()
        assert sv.lookup == "cpu" and sv.pending() == 0
        assert np.array_equal(sv.grab_rgb(), want[0])
        sv.prepare(cams[1])
        sv.draw()
        assert np.array_equal(sv.grab_rgb(), want[1])


def test_the_shader_antialiases_only_where_a_pixel_covers_several_texels(box_slf: Path) -> None:
    """``antialias`` averages four points of a pixel wider than a texel: up close (texels larger than pixels)
    the picture is the same with and without it; far away (3.5 texels a pixel) it differs, and it is closer to
    the aliased lookup rendered at 3 × 3 the pixels and box-filtered (an independent antialiasing)."""
    near, far = _camera(400.0, 200.0, 40.0), _camera(3000.0, 300.0, 25.0)

    def picture(cam: Camera, antialias: bool, size: tuple[int, int] = BIG) -> tuple[np.ndarray, np.ndarray]:
        with SlfView(box_slf, size=size, tau_px=1e6, antialias=antialias) as sv:
            sv.prepare(cam)
            sv.draw()
            return sv.grab_rgb().astype(float), sv.field_mask()

    a, _ = picture(near, True)
    b, _ = picture(near, False)
    assert np.array_equal(a, b)
    smooth, mask = picture(far, True)
    sharp, _ = picture(far, False)
    big, _ = picture(far, False, (3 * BIG[0], 3 * BIG[1]))
    ref = big.reshape(BIG[1], 3, BIG[0], 3, 3).mean(axis=(1, 3))
    assert mask.sum() > 300 and not np.array_equal(smooth, sharp)
    err = [float(np.abs(x - ref).mean(axis=2)[mask].mean()) for x in (smooth, sharp)]
    assert err[0] < 0.8 * err[1], err


@pytest.mark.parametrize("lookup", ["gpu", "cpu"])
def test_a_small_field_cache_drops_what_is_not_drawn_and_draws_the_same(box_slf: Path, lookup: str) -> None:
    """With a cache too small for more than the frame's own fields, the views go around the scene (other
    direction patches), and alternate between the field from far away and the buildings in full up close
    (the cell hidden, so its patch is dropped too, and a shader's lookup reset): what a frame does not draw
    is dropped, reloaded when drawn again, and each picture equals an unbounded view's."""
    cams = [_camera(d, az, el) for az, el in ((200.0, 40.0), (250.0, 30.0), (320.0, 60.0), (200.0, 40.0))
            for d in (2500.0, 150.0)]
    with SlfView(box_slf, size=SIZE, tau_px=2.0, lookup=lookup) as big, \
            SlfView(box_slf, size=SIZE, tau_px=2.0, lookup=lookup, cache_mb=1e-6) as small:
        full = 0
        for cam in cams:
            f = big.prepare(cam)
            full += f.cells == 0
            big.draw()
            small.prepare(cam)
            small.draw()
            assert np.array_equal(small.grab_rgb(), big.grab_rgb())
            shown = {(key, c.patch) for key, c in small.cells.items() if c.actor.GetVisibility()}
            assert set(small._lru) == shown  # nothing else is kept
            held = {(key, p) for key, c in small.cells.items() for p in (*c.fields, *c.images, *c.gpu)}
            assert held <= shown
            assert set(small.groups) == {small.cells[k].fields[p][6] for k, p in shown}
        assert full == 4 and len(big._lru) >= 3  # buildings in full half the time; three patches drawn


def test_heights_travel_to_the_shader_as_bytes_within_a_millimetre() -> None:
    h = np.array([[0.0, 0.0004, 1.0, 15.0], [123.4567, 999.999, 16383.99, -3.0]])
    b = encode_heights(h).astype(np.float64)
    decoded = (b[..., 0] * 65536 + b[..., 1] * 256 + b[..., 2]) / 1024.0  # what the shader's slfHeight does
    assert np.abs(decoded - np.clip(h, 0, None)).max() <= 0.5 / 1024 + 1e-12


@pytest.mark.parametrize(("az", "el"), [(200.0, 40.0), (75.0, 30.0)])
def test_depth_correction_draws_the_box_once(box_slf: Path, az: float, el: float) -> None:
    """Nearer than its switching error (τ forced high), the plain blend of four directions draws the box
    in up to four places; the depth-corrected lookup with the stored building tops puts it in one, so its
    picture is much closer to the geometry's (same window, same camera, the two evaluations)."""
    cam = _camera(400.0, az, el)
    errs = []
    for depth in (False, True):
        with SlfView(box_slf, size=BIG, tau_px=1e6, depth_correct=depth) as sv:
            f = sv.prepare(cam)
            assert f.cells == 1 and f.geometry_cells == 0
            sv.draw()
            img, mask = sv.grab_rgb(), sv.field_mask()
        errs.append(img)
    with GeometryView(box_slf, size=BIG) as gv:
        gv.prepare(cam, full_resolution=True)
        gv.draw()
        ref = gv.grab_rgb()
    plain, fixed = (float(np.abs(e.astype(int) - ref.astype(int)).mean(axis=2)[mask].mean()) for e in errs)
    assert fixed < 0.6 * plain, (plain, fixed)


def test_buildings_grow_out_of_the_field_without_popping(box_slf: Path) -> None:
    """Walking the camera in, the cell goes from field to geometry through a fade; no step between two
    frames changes the picture by much more than the same step does with the geometry alone (camera
    motion), i.e. nothing pops."""
    dists = np.geomspace(4000.0, 150.0, 24)
    seqs = []
    for fields in (True, False):
        with SlfView(box_slf, size=SIZE, tau_px=2.0, fields=fields) as sv:
            frames, states = [], []
            for dist in dists:
                f = sv.prepare(_camera(float(dist), 200.0, 40.0))
                sv.draw()
                frames.append(sv.grab_rgb().astype(int))
                states.append((f.cells, f.geometry_cells, f.fading))
        seqs.append((frames, states))
    (frames, states), (geo, _) = seqs
    assert states[0][1] == 0 and states[-1][1] >= 1  # field far away, buildings near
    assert sum(1 for s in states if s[2]) >= 2  # and a fade over several frames between
    jumps = [np.abs(a - b).mean() for a, b in itertools.pairwise(frames)]
    motion = [np.abs(a - b).mean() for a, b in itertools.pairwise(geo)]
    excess = [j - m for j, m in zip(jumps, motion, strict=True)]
    assert max(excess) < 1.0, (jumps, motion)


def test_cli_build_slf(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    city = write_box_city(tmp_path / "city")
    assert main(["-q", "build", "slf", str(city), "-o", str(tmp_path / "f"), "--texels", "32", "--texel-m", "2",
                 "--directions", "5", "--clusters", "16", "--workers", "2"]) == 0
    assert "cells" in capsys.readouterr().out
    assert main(["info", str(tmp_path / "f")]) == 0  # what the far field holds, its field files counted
    fields = [ln for ln in capsys.readouterr().out.splitlines() if ln.strip().startswith("fields")]
    stored = sum(f.stat().st_size for f in (tmp_path / "f" / "slf").rglob("*.bin")) / 1e6
    assert len(fields) == 1 and "21 directions" in fields[0] and "32² texels" in fields[0]
    assert f"{stored:.1f} MB" in fields[0]
    assert main(["-q", "build", "slf", str(tmp_path / "nothing"), "-o", str(tmp_path / "g")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("citylod: error:") and len(err.strip().splitlines()) == 1
    assert main(["-q", "build", "slf", str(city), "-o", str(tmp_path / "g"), "--texels", "50"]) == 2
    assert not (tmp_path / "g").exists()
    capsys.readouterr()
    assert main(["-q", "build", "slf", str(city), "-o", str(tmp_path / "g"), "--workers", "0"]) == 2
    err = capsys.readouterr().err
    assert "--workers" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "g").exists()


def test_cli_render_draws_a_far_field_tileset_with_its_fields(box_slf: Path, tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """``citylod render SLF_DIR`` draws what SlfView draws for the camera (the field evaluated for its
    direction), not the average texture that other clients see; options of the tileset scene are refused in
    one line, with nothing written."""
    from citylod.io.image import decode_image
    from citylod.render.offscreen import OffscreenRenderer

    cam = _camera(2000.0, 200.0, 40.0)
    cam.save(tmp_path / "cam.json")
    png = tmp_path / "far.png"
    assert main(["-q", "render", str(box_slf), "-o", str(png), "--camera", str(tmp_path / "cam.json"),
                 "--size", f"{BIG[0]}x{BIG[1]}", "--tau", "8"]) == 0
    assert "field cells" in capsys.readouterr().out
    got = decode_image(png.read_bytes())[..., :3].astype(int)
    with SlfView(box_slf, size=BIG, tau_px=8.0) as sv:
        sv.prepare(cam)
        sv.draw()
        want = sv.grab_rgb().astype(int)
        mask = sv.field_mask()
    assert np.abs(got - want).max() <= 1 and mask.sum() > 1000
    with GeometryView(box_slf, size=BIG) as gv:
        gv.prepare(cam, full_resolution=True)
        gv.draw()
        ref = gv.grab_rgb().astype(int)
    with OffscreenRenderer([box_slf], size=BIG, tau_px=8.0) as r:  # the average texture, as other clients
        plain = r.render(cam).rgb.astype(int)
    err_field = np.abs(got - ref).mean(axis=2)[mask].mean()
    err_plain = np.abs(plain - ref).mean(axis=2)[mask].mean()
    assert err_field < 0.7 * err_plain, (err_field, err_plain)
    bad = tmp_path / "bad.png"
    assert main(["-q", "render", str(box_slf), "-o", str(bad), "--camera", str(tmp_path / "cam.json"),
                 "--depth", str(tmp_path / "d.npy")]) == 2
    err = capsys.readouterr().err
    assert "--depth" in err and len(err.strip().splitlines()) == 1 and not bad.exists()
    # Without --camera: the whole far field in view (the overview), drawn with its fields.
    over = tmp_path / "over.png"
    assert main(["-q", "render", str(box_slf), "-o", str(over), "--size", "160x90"]) == 0
    img = decode_image(over.read_bytes())[..., :3].astype(int)
    background = img[0, 0]
    drawn = np.abs(img - background).sum(axis=2) > 30
    assert drawn.mean() > 0.1 and not (drawn[0].any() or drawn[-1].any() or drawn[:, 0].any() or drawn[:, -1].any())


def test_damaged_field_file_is_refused(box_slf: Path, tmp_path: Path) -> None:
    import shutil

    from citylod.core.errors import InputError

    bad = tmp_path / "slf"
    shutil.copytree(box_slf, bad)
    shutil.copytree(box_slf.parent / "city", tmp_path / "city")
    for f in (bad / "slf" / "cells").iterdir():
        f.write_bytes(f.read_bytes()[:20])
    with SlfView(bad, size=SIZE, tau_px=1e6) as sv, pytest.raises(InputError, match="damaged|holds"):
        sv.prepare(_camera(400.0, 0.0, 90.0))
    assert BOX[0][2] == Z0


def test_not_a_far_field_tileset(box_slf: Path, tmp_path: Path) -> None:
    import json
    import shutil

    from citylod.core.errors import InputError

    with pytest.raises(InputError, match="not a far-field"):
        SlfView(box_slf.parent / "city", size=SIZE)
    bad = tmp_path / "slf"
    shutil.copytree(box_slf, bad)
    doc = json.loads((bad / "tileset.json").read_text())
    del doc["extras"]["citylod"]["ground_z"]
    (bad / "tileset.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match="incomplete"):
        SlfView(bad, size=SIZE)


def test_a_finer_level_keeps_fading_cells_to_fields(tmp_path: Path) -> None:
    """Only a finest cell fades to buildings. Where the one-level field (one cell of 1 m texels) is above half
    its switching error and grows its box, loading the city tile, the same field with one level more draws
    the same cell as a field: no building, no city bytes (why the overview of the sample city is built with
    one level more, docs/PERFORMANCE_LOG.md)."""
    city = write_box_city(tmp_path / "city")
    kw = {"texels": 64, "grid": 7, "oversample": 2, "clusters": 32, "progress": False}
    one, two = tmp_path / "one", tmp_path / "two"
    assert build_slf(city, one, texel_m=1.0, **kw).levels == 1
    assert build_slf(city, two, texel_m=0.5, **kw).levels == 2
    kv = {"size": SIZE, "tau_px": 2.0, "texel_px": None}  # the switching error alone decides
    with SlfView(one, **kv) as sv1, SlfView(two, **kv) as sv2:
        fading = []
        for dist in np.geomspace(6000.0, 300.0, 16):
            cam = _camera(float(dist), 200.0, 40.0)
            f1 = sv1.prepare(cam)
            if f1.fading:
                f2 = sv2.prepare(cam)
                fading.append(dist)
                assert f1.bytes_buildings > 0 and f1.bytes_fields > 0
                assert f2.geometry_cells == 0 and f2.bytes_buildings == 0 and f2.cells >= 1
                assert f2.levels == {0: 1}  # the same (root) cell, as a field
        assert len(fading) >= 2  # the fade spans several of these distances


def test_fields_refine_while_a_texel_covers_more_than_texel_px_pixels(tmp_path: Path) -> None:
    """By default (``TEXEL_PX``) a field cell whose texels cover more than 1.5 pixels where the cell is nearest
    the eye is drawn as its children, even where the switching error would keep it; with ``texel_px=None``
    the switching error alone decides. The texel's size in pixels is worked out here from the cell's side,
    the box and the camera's field of view, not by the view's own screen-space error."""
    city = write_box_city(tmp_path / "city")
    two = tmp_path / "two"
    assert build_slf(city, two, texel_m=0.5, texels=64, grid=7, oversample=2, clusters=32, progress=False).levels == 2
    assert TEXEL_PX == 1.5
    seen = set()
    with SlfView(two, size=SIZE, tau_px=2.0) as sv, SlfView(two, size=SIZE, tau_px=2.0, texel_px=None) as sv0:
        lo, hi = sv.ts.root.box.bounds()
        texel_m = float(hi[0] - lo[0]) / 64
        for dist in np.geomspace(6000.0, 300.0, 16):
            cam = _camera(float(dist), 200.0, 40.0)
            alone = sv0.prepare(cam)
            if alone.levels != {0: 1}:
                continue  # the switching error already refines
            eye = np.asarray(cam.position)
            near = float(np.linalg.norm(np.maximum(np.maximum(lo - eye, eye - hi), 0.0)))
            px = texel_m / (2.0 * near * math.tan(math.radians(cam.fovy_deg) / 2.0)) * SIZE[1]
            f = sv.prepare(cam)
            seen.add(px > 1.5)
            assert f.levels == ({1: 4} if px > 1.5 else {0: 1}), (dist, px, f.levels)
    assert seen == {True, False}  # both sides of the threshold were flown


def test_anisotropic_filtering_only_for_oblique_views(box_slf: Path) -> None:
    """A field's texture is filtered anisotropically while a pixel's ground footprint is at least 1.5 times
    elongated (elevation ≤ 41.8° from the cell's centre) and isotropically above; ``anisotropic_from=1`` keeps
    it everywhere. The GL texture gets the setting (read back from VTK), and the steep picture stays the field's.
    (The CPU lookup's texture: the GPU lookup evaluates each pixel and filters nothing.)"""
    with SlfView(box_slf, size=SIZE, tau_px=8.0, lookup="cpu") as sv, SlfView(
            box_slf, size=SIZE, tau_px=8.0, anisotropic_from=1.0, lookup="cpu") as always:
        for el, expect in ((30.0, 16.0), (40.0, 16.0), (44.0, 1.0), (70.0, 1.0), (35.0, 16.0)):
            cam = _camera(2000.0, 200.0, el)
            f = sv.prepare(cam)
            always.prepare(cam)
            assert f.cells == 1
            (cell,) = sv.cells.values()
            assert cell.tex.GetMaximumAnisotropicFiltering() == expect, el
            assert next(iter(always.cells.values())).tex.GetMaximumAnisotropicFiltering() == 16.0
        sv.prepare(_camera(2000.0, 200.0, 70.0))
        always.prepare(_camera(2000.0, 200.0, 70.0))
        sv.draw()
        always.draw()
        a, b = sv.grab_rgb().astype(int), always.grab_rgb().astype(int)
        mask = sv.field_mask()
        assert mask.sum() > 100 and np.abs(a - b).mean(axis=2)[mask].mean() < 3.0


@contextlib.contextmanager
def _embedded(path: Path, size: tuple[int, int], tau: float, cam: Camera):
    """A far field drawn into a renderer of another window, as the desktop app draws it: (the SlfView, a
    function that renders that window and returns its picture)."""
    from citylod.render import _vtk
    from citylod.render.gl_context import guard
    from citylod.render.tileset_actor import BACKGROUND, camera_to_vtk

    window = _vtk.offscreen_window(*size)
    ren = _vtk.vtkOpenGLRenderer()
    ren.SetBackground(*BACKGROUND)
    window.AddRenderer(ren)
    origin = np.array([X0 + 30.0, Y0 + 30.0, Z0])
    far = SlfView(path, renderer=ren, origin=origin, tau_px=tau)
    far.attach()
    camera_to_vtk(cam, ren.GetActiveCamera(), origin)

    def frame() -> np.ndarray:
        with guard(window):
            window.Render()
            window.WaitForCompletion()
            arr = _vtk.vtkUnsignedCharArray()
            window.GetPixelData(0, 0, size[0] - 1, size[1] - 1, 0, arr, 0)
        return _vtk.vtk_to_numpy(arr).reshape(size[1], size[0], 3)[::-1].astype(int)

    try:
        yield far, frame
    finally:
        far.close()
        with guard(window):
            window.Finalize()


def test_embedded_view_reads_buildings_without_waiting(box_slf: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Drawn into another renderer (as the desktop app does), a far field does not wait for a city tile: the
    frame that first needs the box's buildings draws the cell's field and requests the tile from a worker;
    once it is read, the next frame draws the buildings, and the picture is the one a SlfView with its own
    window (which reads the tile at once) draws for the same camera."""
    import threading

    from citylod.render import slf

    gate = threading.Event()
    real = slf._load_leaf

    def gated(leaf):  # the worker's read finishes only when the test lets it
        assert gate.wait(30.0)
        return real(leaf)

    monkeypatch.setattr(slf, "_load_leaf", gated)
    cam = _camera(150.0, 200.0, 40.0)  # the box's cell (0.55 m) at 2.5 px of τ = 1: its buildings are drawn
    try:
        with _embedded(box_slf, SIZE, 1.0, cam) as (far, frame):
            frame()
            first = far.last_frame
            assert first is not None and first.loading == 1 and first.geometry_cells == 0 and first.cells >= 1
            assert far.pending() == 1 and not far.loads_ready()
            gate.set()
            deadline = time.monotonic() + 30.0
            while not far.loads_ready():
                assert time.monotonic() < deadline
                time.sleep(0.01)
            got = frame()
            assert far.last_frame.geometry_cells == 1 and far.last_frame.loading == 0 and far.pending() == 0
    finally:
        gate.set()
    with SlfView(box_slf, size=SIZE, tau_px=1.0) as own:
        assert own.prepare(cam).geometry_cells == 1
        own.draw()
        want = own.grab_rgb().astype(int)
    assert np.abs(got - want).max() <= 2, np.abs(got - want).max()


def test_embedded_view_defers_evaluation_past_its_time_slice(box_slf: Path) -> None:
    """Past its time slice for reading and evaluating fields, an embedded far field shows a cell not yet
    evaluated as bare ground and asks for another frame (pending); the next frame within the slice draws
    the field, as a SlfView with its own window does."""
    cam = _camera(2000.0, 200.0, 40.0)
    with _embedded(box_slf, BIG, 8.0, cam) as (far, frame):
        far.eval_slice_s = -1.0  # spent before the first cell
        bare = frame()
        assert far.last_frame.loading == 1 and far.last_frame.evaluations == 0 and far.pending() == 1
        assert far.loads_ready()
        far.eval_slice_s = 0.05
        got = frame()
        assert far.last_frame.evaluations == 1 and far.pending() == 0 and not far.loads_ready()
    with SlfView(box_slf, size=BIG, tau_px=8.0) as own:
        own.prepare(cam)
        own.draw()
        want, mask = own.grab_rgb().astype(int), own.field_mask()
    assert np.abs(got - want).max() <= 2
    ground = np.array(GROUND_RGB)
    assert np.abs(bare - ground).max(axis=2)[mask].max() <= 2  # the cell was bare ground
    assert np.abs(got - ground).max(axis=2)[mask].max() > 40  # and the box shows once evaluated
