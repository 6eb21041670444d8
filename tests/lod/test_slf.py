"""Far-field surface light fields (issue 28): baking against an independent ray cast, the compression's
error, the direction interpolation, the tileset round trip and bad input. No VTK."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from citylod.core.errors import InputError
from citylod.io.image import decode_image
from citylod.io.tiles3d import decode_glb, open_tileset
from citylod.lod.build.slf import (
    GROUND_RGB,
    bake_cell,
    bake_heights,
    build_slf,
    city_triangles,
    compress,
    read_cell,
    read_group,
    read_heights,
    reconstruct,
    write_cell,
    write_group,
)
from citylod.lod.kernels.slf import (
    box_average,
    depth_corrected_blend,
    depth_corrected_colours,
    direction_set,
    evaluate,
    interpolation,
    march_heights,
    parabolic,
    patch_of,
)
from tests.lod.slf_scene import X0, Y0, Z0, ray_colour, write_box_city


@pytest.fixture(scope="module")
def box_city(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_box_city(tmp_path_factory.mktemp("slf_box") / "city")


def test_direction_set_is_the_parabolic_lattice() -> None:
    ds = direction_set(11)
    assert len(ds) == 97
    assert np.allclose(np.linalg.norm(ds.dirs, axis=1), 1.0)
    assert ds.dirs[:, 2].min() >= np.sin(np.radians(5.0)) - 1e-9
    inner = np.hypot(*(ds.cells.T / 5.0 - 1.0)) <= 1.0  # lattice points inside the disc map back onto themselves
    assert np.allclose(parabolic(ds.dirs[inner & (ds.dirs[:, 2] > 0.1)]),
                       (ds.cells[inner & (ds.dirs[:, 2] > 0.1)] / 5.0 - 1.0), atol=1e-12)
    # a stored direction interpolates to itself
    for j in (0, 40, 48, 60):
        idx, w = interpolation(ds, ds.dirs[j])
        if ds.dirs[j, 2] > 0.2:
            assert idx[np.argmax(w)] == j and w.max() == pytest.approx(1.0)


def test_bake_matches_an_independent_ray_cast(box_city: Path) -> None:
    """Every texel of the baked field, for every direction, against slab ray casting of the same samples."""
    scene = city_triangles(box_city)
    ds = direction_set(5, min_elevation_deg=10.0)
    texels, ss = 32, 2
    field = bake_cell(scene, X0, Y0, 60.0, texels, Z0, ds, oversample=ss)
    n = texels * ss
    step = 60.0 / n
    jj, ii = np.meshgrid(np.arange(n), np.arange(n))
    qx = X0 + (jj.ravel() + 0.5) * step
    qy = Y0 + 60.0 - (ii.ravel() + 0.5) * step
    bad = 0
    for j, d in enumerate(ds.dirs):
        ref = ray_colour(qx, qy, d, GROUND_RGB).reshape(n, n, 3).astype(np.float64)
        ref = ref.reshape(texels, ss, texels, ss, 3).mean(axis=(1, 3))
        diff = np.abs(field[:, :, j].astype(np.float64) - ref).max(axis=2)
        bad += int((diff > 1.0).sum())
    # Only samples exactly on an edge may be drawn by the other face; none should be off here.
    assert bad <= 0.002 * texels * texels * len(ds), bad
    # and the field does see the box: the zenith view shows the roof colour over the box footprint
    zen = int(np.argmax(ds.dirs[:, 2]))
    assert tuple(field[16, 16, zen]) == (200, 50, 50)


@pytest.mark.parametrize("corner", [(180.0, 20.0), (-130.0, -130.0), (30.0, 170.0)])
def test_bake_reads_only_the_triangles_that_can_reach_the_cell(box_city: Path, monkeypatch: pytest.MonkeyPatch,
                                                               corner: tuple[float, float]) -> None:
    """Cells east, south-west and north of the box, so far that only the lowest directions (5° elevation: the
    15 m box sheared by up to 171 m) see it in them: baked from the triangles ``near`` keeps, the field is
    byte for byte the one baked from all triangles, and the box is in it."""
    scene = city_triangles(box_city)
    ds = direction_set(7, min_elevation_deg=5.0)
    x0, y0 = X0 + corner[0], Y0 + corner[1]
    kept = scene.near(x0, y0, 40.0, Z0, 11.5)
    assert 0 < len(kept) < len(scene.tri)  # the ground quad outside the cell is left out
    field = bake_cell(scene, x0, y0, 40.0, 16, Z0, ds, oversample=2)
    monkeypatch.setattr(type(scene), "near", lambda self, *a: np.arange(len(self.tri)))
    every = bake_cell(scene, x0, y0, 40.0, 16, Z0, ds, oversample=2)
    assert np.array_equal(field, every)
    assert (np.abs(field.astype(int) - np.array(GROUND_RGB)).max(axis=-1) > 30).any()


def test_depth_corrected_blend_draws_the_box_once(box_city: Path) -> None:
    """A view between the stored directions of a coarse set (5 × 5: 21 directions, 25–45° apart): the plain
    blend of four directions draws the 15 m box in four places (mean error 5.5–8.2 of 255); the
    depth-corrected lookup, with the building-top heights of the bake, must come close to an independent ray
    cast for the exact view (measured 0.9–1.4)."""
    scene = city_triangles(box_city)
    ds = direction_set(5, min_elevation_deg=10.0)
    texels, ss = 32, 2
    field = bake_cell(scene, X0, Y0, 60.0, texels, Z0, ds, oversample=ss).astype(np.float64)
    top, over = bake_heights(scene, X0, Y0, 60.0, texels, Z0, oversample=ss)
    assert top.max() == pytest.approx(15.0, abs=1e-3) and over < 1e-3  # a flat roof: the tops are exact
    n = texels * ss
    step = 60.0 / n
    jj, ii = np.meshgrid(np.arange(n), np.arange(n))
    qx, qy = X0 + (jj.ravel() + 0.5) * step, Y0 + 60.0 - (ii.ravel() + 0.5) * step
    errors = []
    for az, el in ((30.0, 40.0), (200.0, 55.0), (290.0, 25.0)):
        a, e = np.radians(az), np.radians(el)
        v = np.array([np.sin(a) * np.cos(e), np.cos(a) * np.cos(e), np.sin(e)])
        ref = ray_colour(qx, qy, v, GROUND_RGB).reshape(n, n, 3).astype(np.float64)
        ref = ref.reshape(texels, ss, texels, ss, 3).mean(axis=(1, 3))
        idx, w = interpolation(ds, v)
        assert w.max() < 0.9  # really between stored directions
        plain = np.tensordot(field[:, :, idx], w, axes=([2], [0]))
        fixed = depth_corrected_blend(np.moveaxis(field[:, :, idx], 2, 0), idx, w, ds.dirs, top, 60.0 / texels, v)
        errors.append((float(np.abs(plain - ref).mean()), float(np.abs(fixed - ref).mean())))
    for plain_err, fixed_err in errors:
        assert fixed_err < 0.25 * plain_err and fixed_err < 2.5, errors


def _march_reference(top: np.ndarray, texel_m: float, v: np.ndarray, min_length: float) -> np.ndarray:
    """march_heights written out whole-array by slabs: for every texel's ray and every column of the cell,
    the heights at which the ray is inside that column (the intersection of its x and y slabs with
    [0, max top], longer than ``min_length``), the highest of them below the column's top, the largest over
    all columns. A ray that passes a texel corner within rounding touches the columns beside it for a
    length of about 1e-15 m: whether it enters them is the rounding's choice (``min_length`` -1e-9: every
    touch counts; 1e-9: none)."""
    t = top.shape[0]
    a = v[:2] / max(v[2], 1e-6)
    hmax = float(top.max())
    if hmax <= 0.0:
        return np.zeros(top.shape)
    dx, dy = a[0] / texel_m, -a[1] / texel_m
    r, c = np.mgrid[0:t, 0:t].astype(np.float64)
    x0, y0 = (c + 0.5)[..., None, None], (r + 0.5)[..., None, None]  # (T, T, 1, 1): the rays
    ii, jj = np.mgrid[0:t, 0:t].astype(np.float64)  # (T, T): the columns

    def slab(p0, d, k):
        if d == 0.0:
            inside = (k <= p0) & (p0 < k + 1)
            return np.where(inside, -np.inf, np.inf), np.where(inside, np.inf, -np.inf)
        e0, e1 = (k - p0) / d, (k + 1 - p0) / d
        return np.minimum(e0, e1), np.maximum(e0, e1)

    xa, xb = slab(x0, dx, jj)
    ya, yb = slab(y0, dy, ii)
    s_a = np.maximum(np.maximum(xa, ya), 0.0)
    s_b = np.minimum(np.minimum(xb, yb), hmax)
    hit = (s_b - s_a > min_length) & (top >= s_a)
    return np.where(hit, np.minimum(top, s_b), 0.0).max(axis=(2, 3))


def _blend_reference(images, idx, w, dirs, top, texel_m, v, tol=1.0):
    """depth_corrected_blend as whole-array numpy: bilinear resampling by index arithmetic, the visibility
    test by rounding; the ray marches are march_heights' (tested against the slabs on their own)."""
    t = images.shape[1]
    h = march_heights(top, texel_m, v)
    r, c = np.mgrid[0:t, 0:t].astype(np.float64)
    a = v[:2] / max(v[2], 1e-6)
    acc, wsum, fallback = np.zeros((t, t, 3)), np.zeros((t, t)), np.zeros((t, t, 3))
    for img, j, wj in zip(images, idx, w, strict=True):
        shift = (a - dirs[j, :2] / max(dirs[j, 2], 1e-6)) / texel_m  # per metre of height, in texels: the
        rr = np.clip(r - h * shift[1], 0, t - 1)  # kernel's order of operations, so that a point on a texel
        cc = np.clip(c + h * shift[0], 0, t - 1)  # edge (a wall the ray meets) rounds the same way
        r0, c0 = np.minimum(np.floor(rr).astype(int), t - 2), np.minimum(np.floor(cc).astype(int), t - 2)
        fr, fc = (rr - r0)[..., None], (cc - c0)[..., None]
        sample = ((1 - fr) * ((1 - fc) * img[r0, c0] + fc * img[r0, c0 + 1])
                  + fr * ((1 - fc) * img[r0 + 1, c0] + fc * img[r0 + 1, c0 + 1]))
        seen = march_heights(top, texel_m, dirs[j])[np.rint(rr).astype(int), np.rint(cc).astype(int)]
        ok = (np.abs(seen - h) <= tol) * wj
        acc += ok[..., None] * sample
        wsum += ok
        fallback += wj * sample
    return np.where(wsum[..., None] > 1e-9, acc / np.maximum(wsum, 1e-9)[..., None], fallback / w.sum())


def test_compiled_march_and_blend_match_the_array_formulation() -> None:
    """The compiled ray march and blend (evaluated per cell at run time) against the whole-array numpy
    formulation, and the renderer's fused lookup against them, on random building tops: a street grid of blocks of random heights, a tower at a cell's
    edge and one past it, views from straight above to 8° above the horizon (the lowest along a texel
    diagonal, whose rays pass texel corners)."""
    rng = np.random.default_rng(7)
    ds = direction_set(9)
    t = 48
    top = np.where(rng.random((t // 4, t // 4)) < 0.6, rng.uniform(3.0, 40.0, (t // 4, t // 4)), 0.0)
    top = np.kron(top, np.ones((4, 4)))
    top[:, :2] = 0.0  # a street along the west edge
    top[0, t - 1] = 80.0  # a tower in the corner
    images = rng.uniform(0, 255, (4, t, t, 3))
    images32 = rng.uniform(-20, 275, (4, t, t, 3)).astype(np.float32)  # out of range: the clip is tested too
    for az, el in ((0.0, 90.0), (37.0, 61.0), (140.0, 33.0), (260.0, 18.0), (315.0, 8.0)):
        a, e = np.radians(az), np.radians(el)
        v = np.array([np.sin(a) * np.cos(e), np.cos(a) * np.cos(e), np.sin(e)])
        v /= np.linalg.norm(v)
        got_h = march_heights(top, 1.3, v)
        strict, loose = _march_reference(top, 1.3, v, 1e-9), _march_reference(top, 1.3, v, -1e-9)
        assert np.all(got_h >= strict - 1e-9) and np.all(got_h <= loose + 1e-9), (az, el)
        if az != 315.0:  # off the diagonal no ray passes a corner within rounding: one answer
            assert np.array_equal(strict, loose) and np.abs(got_h - strict).max() < 1e-9, (az, el)
        assert np.mean(got_h > 0) > 0.3  # and the rays do meet the blocks
        idx, w = interpolation(ds, v)
        got = depth_corrected_blend(images, idx, w, ds.dirs, top, 1.3, v)
        want = _blend_reference(images, idx, w, ds.dirs, top, 1.3, v)
        assert np.abs(got - want).max() < 1e-9, (az, el)
        # the renderer's fused lookup: every stored direction's image and march in one array, rows ``idx`` read
        rows = np.zeros((len(ds), t, t, 3), np.float32)
        rows[idx] = images32
        seen = np.zeros((len(ds), t, t), np.float32)
        seen[idx] = [march_heights(top, 1.3, ds.dirs[j]) for j in idx]
        fused = depth_corrected_colours(rows, seen, idx, w, ds.dirs, top, 1.3, v)
        blended = depth_corrected_blend(images32, idx, w, ds.dirs, top, 1.3, v,
                                        seen_heights=[seen[j] for j in idx])
        assert fused.dtype == np.uint8
        assert np.array_equal(fused, np.clip(np.rint(blended), 0, 255).astype(np.uint8)), (az, el)
    assert not march_heights(np.zeros((t, t)), 1.0, np.array([0.0, 0.0, 1.0])).any()


def test_box_average_is_numpys_area_mean() -> None:
    """The compiled area average of the atlases against numpy's mean, halves rounded to even included (blocks
    of two texels 0/1 and 1/2 average to 0.5 and 1.5)."""
    rng = np.random.default_rng(3)
    for h, w, side in ((512, 256, 64), (64, 64, 64), (96, 192, 32), (2, 4, 1)):
        img = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
        want = img.reshape(side, h // side, side, w // side, 3).mean(axis=(1, 3)).round().astype(np.uint8)
        assert np.array_equal(box_average(img, side), want), (h, w, side)
    ties = np.array([[[0, 1, 2], [1, 2, 3]]], np.uint8).reshape(1, 2, 3)  # one row, two texels
    assert box_average(ties, 1).tolist() == [[[0, 2, 2]]]  # 0.5 → 0, 1.5 → 2, 2.5 → 2


def test_compression_error_is_bounded_on_low_rank_clusters() -> None:
    """Eight kinds of texels, each an exact rank-2 family of lumispheres: clustered PCA (3 components)
    must reproduce them to within the 8-bit quantisation of weights, means and eigen-lumispheres."""
    rng = np.random.default_rng(1)
    nd, n = 49, 4096
    kinds = rng.integers(0, 8, n)
    base = rng.uniform(40, 200, (8, nd, 3))
    vecs = rng.normal(0, 1, (8, 2, nd, 3))
    vecs /= np.linalg.norm(vecs.reshape(8, 2, -1), axis=2)[:, :, None, None]
    w = rng.uniform(-60, 60, (n, 2))
    x = base[kinds] + np.einsum("nk,nkjc->njc", w, vecs[kinds])
    x = np.clip(np.rint(x), 0, 255).astype(np.uint8)
    c = compress(x, clusters=32, components=3)
    err = np.abs(reconstruct(c) - x)
    assert err.mean() < 1.0 and err.max() < 6.0, (err.mean(), err.max())


def test_compression_of_a_baked_field(box_city: Path) -> None:
    scene = city_triangles(box_city)
    ds = direction_set(7)
    field = bake_cell(scene, X0, Y0, 60.0, 32, Z0, ds, oversample=2).reshape(-1, len(ds), 3)
    c = compress(field, clusters=64, components=3)
    err = reconstruct(c) - field
    rms = float(np.sqrt((err ** 2).mean()))
    assert rms < 6.0, rms  # few distinct colours: most texels are exact, edges carry the error
    # the evaluation of a stored direction is the reconstruction of that direction
    mean, basis = c.lumispheres()
    j = int(np.argmax(ds.dirs[:, 2]))
    idx, w = np.array([j, j, j, j]), np.array([1.0, 0.0, 0.0, 0.0])
    ev = evaluate(c.cluster, c.q.astype(np.float64), mean, basis, idx, w)
    assert np.abs(ev.astype(float) - reconstruct(c)[:, j]).max() <= 0.5 + 1e-9


def test_binary_round_trip_and_damage() -> None:
    rng = np.random.default_rng(2)
    x = rng.integers(0, 255, (16 * 16, 9, 3)).astype(np.uint8)
    c = compress(x, clusters=8, components=3)
    cl, q = read_cell(write_cell(c, slice(None), 16))
    assert np.array_equal(cl.ravel(), c.cluster) and np.array_equal(q.reshape(-1, 3), c.q)
    g = read_group(write_group(c))
    for a in ("mean", "lo", "step", "basis", "scale"):
        assert np.array_equal(getattr(g, a), getattr(c, a))
    tops = rng.uniform(0, 30, (16, 16))
    with_heights = write_cell(c, slice(None), 16, tops)
    assert np.array_equal(read_cell(with_heights)[0], c.cluster.reshape(16, 16))
    back = read_heights(with_heights)
    assert back is not None and np.all(back >= tops - 1e-4) and np.all(back - tops <= 30 / 255 + 1e-4)
    data = write_cell(c, slice(None), 16)
    assert read_heights(data) is None
    with pytest.raises(InputError, match="bad magic"):
        read_cell(b"XXXX" + data[4:], "c.bin")
    with pytest.raises(InputError, match="damaged|holds"):
        read_cell(data[:-7], "c.bin")
    with pytest.raises(InputError, match="damaged|holds"):
        read_group(write_group(c)[:-1], "g.bin")


def test_build_does_not_depend_on_the_bake_threads(box_city: Path, tmp_path: Path) -> None:
    """One bake thread or four: the same files, byte for byte."""
    outs = []
    for workers in (1, 4):
        out = tmp_path / f"slf{workers}"
        build_slf(box_city, out, texel_m=1.0, texels=16, grid=5, oversample=2, clusters=16, workers=workers,
                  progress=False)
        outs.append({p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()})
    assert len(outs[0]) > 10 and outs[0] == outs[1]


def test_tileset_round_trip(box_city: Path, tmp_path: Path) -> None:
    out = tmp_path / "slf"
    report = build_slf(box_city, out, texel_m=1.0, texels=32, grid=5, oversample=2, clusters=32, progress=False)
    assert report.levels == 2 and report.cells == 5 and report.directions == 21
    assert report.raw_cell_bytes == 32 * 32 * 21 * 3
    ts = open_tileset(out)
    assert ts.kind == "slf" and ts.citylod["directions"] == 21
    doc = json.loads((out / "tileset.json").read_text())
    root = doc["root"]
    assert len(root["children"]) == 4
    patches = ts.citylod["patches"]
    assert len(patches) == 4 and set().union(*patches) == set(range(21))  # every direction in some patch
    for tile in [root, *root["children"]]:
        e = tile["extras"]["citylod_slf"]
        for pi, sel in enumerate(patches):
            cl, q = read_cell((out / e["cell"].format(patch=pi)).read_bytes())
            assert cl.shape == (32, 32) and q.shape == (32, 32, 3)
            top = read_heights((out / e["cell"].format(patch=pi)).read_bytes())
            assert top is not None and top.max() == pytest.approx(15.0, abs=0.1)  # the box's roof
            g = read_group((out / e["group"].format(patch=pi)).read_bytes())
            assert g.mean.shape == (32, len(sel), 3)
        assert tile["geometricError"] > e["texel_m"]
        # what other clients see: a textured quad whose texture is the field's average
        content = decode_glb((out / tile["content"]["uri"]).read_bytes())
        (mesh,) = content.meshes
        img = decode_image(mesh.texture)
        assert img.shape[:2] == (32, 32) and len(mesh.faces) == 2
    # the children's field reproduces the bake of their square
    scene = city_triangles(box_city)
    ds = direction_set(5)
    child = root["children"][0]
    key = Path(child["extras"]["citylod_slf"]["cell"]).stem  # LEVEL_COLUMN_ROW_{patch}
    lv, i, j = (int(v) for v in key.split("_")[:3])
    assert lv == 1
    side = 60.0 + 2.0  # the field's square: the extent plus a texel each side
    x0, y0 = X0 - 1.0, Y0 - 1.0
    raw = bake_cell(scene, x0 + i * side / 2, y0 + j * side / 2, side / 2, 32, Z0, ds, oversample=2)
    zen = int(np.argmax(ds.dirs[:, 2]))
    pi = patch_of(ds, ds.dirs[zen])
    cl, q = read_cell((out / child["extras"]["citylod_slf"]["cell"].format(patch=pi)).read_bytes())
    g = read_group((out / child["extras"]["citylod_slf"]["group"].format(patch=pi)).read_bytes())
    mean, basis = g.lumispheres()
    loc = patches[pi].index(zen)
    ev = evaluate(cl, q.astype(np.float64), mean, basis, np.array([loc] * 4), np.array([1.0, 0, 0, 0]))
    assert np.abs(ev.astype(float) - raw[:, :, zen]).mean() < 3.0


def test_bad_input(tmp_path: Path, box_city: Path) -> None:
    with pytest.raises(InputError):
        build_slf(tmp_path / "missing", tmp_path / "out", progress=False)
    with pytest.raises(InputError, match="power of two"):
        build_slf(box_city, tmp_path / "out", texels=48, progress=False)
    out = tmp_path / "slf"
    build_slf(box_city, out, texel_m=2.0, texels=32, grid=3, oversample=1, clusters=4, progress=False)
    with pytest.raises(InputError, match="not a city tileset"):
        build_slf(out, tmp_path / "again", progress=False)
    assert not (tmp_path / "again").exists() and not (tmp_path / "out").exists()
    assert not list(tmp_path.glob(".*partial*"))


def test_far_field_tileset_passes_the_validator(box_city: Path, tmp_path: Path) -> None:
    """Other 3D Tiles clients see ordinary textured terrain: the official validator reports nothing."""
    from tests.io.test_validator import VALIDATOR, _validate

    if not VALIDATOR.exists():
        pytest.skip("3d-tiles-validator not built (scripts/validator.sh)")
    import shutil

    if shutil.which("node") is None:
        pytest.skip("node is not installed")
    out = tmp_path / "slf"
    build_slf(box_city, out, texel_m=1.0, texels=32, grid=5, oversample=1, clusters=16, progress=False)
    assert _validate(VALIDATOR, out, tmp_path) == []
