"""Bounded-error TIN kernels (`citylod.lod.kernels.tin`), checked by computations written here.

The accuracy oracle below shares no code with the library: plain numpy, its own enumeration of the
overlay vertices (grid samples in each face, crossings of face edges with grid rows, columns and
cell diagonals), its own grid-surface formula, plus random points inside faces as a sanity check of
the "maximum lies on the overlay vertices" argument.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from citylod.lod.kernels import tin

TOL = 1e-9


# ------------------------------------------------------------------------------------------------
# independent oracle
# ------------------------------------------------------------------------------------------------


def _grid_surface(h: np.ndarray, r: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Grid surface at (r, c): per cell the two triangles split by the (i, j)-(i+1, j+1) diagonal."""
    H, W = h.shape
    i = np.clip(np.floor(r).astype(np.int64), 0, H - 2)
    j = np.clip(np.floor(c).astype(np.int64), 0, W - 2)
    v, u = r - i, c - j
    h00, h01, h10, h11 = h[i, j], h[i, j + 1], h[i + 1, j], h[i + 1, j + 1]
    upper = h00 + u * (h01 - h00) + v * (h11 - h01)  # u >= v: (i,j), (i,j+1), (i+1,j+1)
    lower = h00 + v * (h10 - h00) + u * (h11 - h10)  # u <  v: (i,j), (i+1,j), (i+1,j+1)
    return np.where(u >= v, upper, lower)


def _ranges(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For integer ranges [lo_k, hi_k], the owner k and the value of every member, flattened."""
    n = np.maximum(hi - lo + 1, 0)
    owner = np.repeat(np.arange(len(n)), n)
    start = np.repeat(np.cumsum(n) - n, n)
    return owner, lo[owner] + np.arange(n.sum()) - start


def oracle_error(
    h: np.ndarray, vij: np.ndarray, faces: np.ndarray, vz: np.ndarray | None = None, seed: int = 0
) -> tuple[float, float]:
    """(max |TIN - grid| over overlay vertices, max over random points in faces)."""
    if len(faces) == 0:
        return 0.0, 0.0
    base = h.flat[0]
    hh = h - base  # exact for huge base heights (Sterbenz), so the oracle is not the weak link
    zz = (h[vij[:, 0], vij[:, 1]] if vz is None else vz) - base
    r, c = vij[:, 0].astype(np.float64), vij[:, 1].astype(np.float64)
    errs = [0.0]
    # grid samples inside each face (integer barycentrics: exact inside test)
    ra, rb, rc = (r[faces[:, k]] for k in range(3))
    ca, cb, cc = (c[faces[:, k]] for k in range(3))
    own, rr = _ranges(
        np.minimum(np.minimum(ra, rb), rc).astype(np.int64),
        np.maximum(np.maximum(ra, rb), rc).astype(np.int64),
    )
    cmin = np.minimum(np.minimum(ca, cb), cc).astype(np.int64)[own]
    cmax = np.maximum(np.maximum(ca, cb), cc).astype(np.int64)[own]
    own2, cc_ = _ranges(cmin, cmax)
    f = own[own2]
    pr, pc = rr[own2].astype(np.float64), cc_.astype(np.float64)
    A = (rb - ra) * (cc - ca) - (rc - ra) * (cb - ca)
    wb = ((pr - ra[f]) * (cc[f] - ca[f]) - (rc[f] - ra[f]) * (pc - ca[f])) / A[f]
    wc = ((rb[f] - ra[f]) * (pc - ca[f]) - (pr - ra[f]) * (cb[f] - ca[f])) / A[f]
    inside = (wb >= 0) & (wc >= 0) & (wb + wc <= 1)
    za, zb, zc = (zz[faces[f, k]] for k in range(3))
    tinz = za + wb * (zb - za) + wc * (zc - za)
    d = np.abs(tinz - hh[pr.astype(np.int64), pc.astype(np.int64)])[inside]
    errs.append(d.max(initial=0.0))
    # crossings of every face edge with grid lines s = n . (r, c) = k
    e0 = faces.reshape(-1)
    e1 = faces[:, [1, 2, 0]].reshape(-1)
    for nr, nc in ((0, 1), (1, 0), (-1, 1)):
        s0 = nr * r[e0] + nc * c[e0]
        s1 = nr * r[e1] + nc * c[e1]
        own, k = _ranges(np.minimum(s0, s1).astype(np.int64) + 1, np.maximum(s0, s1).astype(np.int64) - 1)
        t = (k - s0[own]) / (s1[own] - s0[own])
        pr = r[e0[own]] + t * (r[e1[own]] - r[e0[own]])
        pc = c[e0[own]] + t * (c[e1[own]] - c[e0[own]])
        tinz = zz[e0[own]] + t * (zz[e1[own]] - zz[e0[own]])
        errs.append(np.abs(tinz - _grid_surface(hh, pr, pc)).max(initial=0.0))
    # random points in faces: never worse than the overlay vertices
    rng = np.random.default_rng(seed)
    w = rng.dirichlet(np.ones(3), size=(len(faces), 8))
    pr = (w * r[faces][:, None, :]).sum(-1)
    pc = (w * c[faces][:, None, :]).sum(-1)
    tinz = (w * zz[faces][:, None, :]).sum(-1)
    rand = np.abs(tinz - _grid_surface(hh, pr, pc)).max()
    return float(max(errs)), float(rand)


def assert_tile_ok(
    h: np.ndarray, valid: npt.ArrayLike | None, vij: np.ndarray, faces: np.ndarray, max_error: float
) -> None:
    """The bound, exact single coverage of valid cells, no invalid cell touched, CCW faces."""
    v = np.ones(h.shape, bool) if valid is None else np.asarray(valid, bool)
    cv = v[:-1, :-1] & v[1:, :-1] & v[:-1, 1:] & v[1:, 1:]
    err, rand = oracle_error(h, vij, faces)
    assert err <= max_error + TOL, err
    assert rand <= err + TOL
    assert v[vij[:, 0], vij[:, 1]].all()
    # CCW seen from above in (x = col, y = -row)
    x, y = vij[:, 1].astype(float), -vij[:, 0].astype(float)
    a = (x[faces[:, 1]] - x[faces[:, 0]]) * (y[faces[:, 2]] - y[faces[:, 0]]) - (
        x[faces[:, 2]] - x[faces[:, 0]]
    ) * (y[faces[:, 1]] - y[faces[:, 0]])
    assert (a > 0).all()
    assert a.sum() / 2 == pytest.approx(cv.sum(), abs=1e-9)
    # one probe per cell, off every lattice line: covered exactly once if valid, never if not
    pi, pj = np.nonzero(np.ones_like(cv))
    pr, pc = pi + 0.5 + 1e-3 * np.pi, pj + 0.5 + 1e-3 * np.e
    R, C = vij[faces, 0].astype(float), vij[faces, 1].astype(float)

    def side(k: int, m: int) -> np.ndarray:
        return (C[:, m] - C[:, k])[:, None] * (-pr[None] + R[:, k][:, None]) - (-R[:, m] + R[:, k])[
            :, None
        ] * (pc[None] - C[:, k][:, None])

    count = ((side(0, 1) > 0) & (side(1, 2) > 0) & (side(2, 0) > 0)).sum(axis=0).reshape(cv.shape)
    np.testing.assert_array_equal(count, cv.astype(int))
    cov = tin.coverage_check(v, vij, faces)
    np.testing.assert_allclose(cov, cv.astype(float), atol=1e-9)


# ------------------------------------------------------------------------------------------------
# data made by code
# ------------------------------------------------------------------------------------------------


def city(shape: tuple[int, int], seed: int = 0, n_buildings: int = 12) -> np.ndarray:
    """Rolling ground, 5-50 m box buildings (cliffs within one sample) and 5 cm noise."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0 : shape[0], 0 : shape[1]] / max(shape)
    h = 8 * np.sin(3 * x) * np.cos(2 * y) + 3 * x
    for _ in range(n_buildings):
        r, c = rng.integers(0, shape[0]), rng.integers(0, shape[1])
        a, b = rng.integers(2, 12, 2)
        h[r : r + a, c : c + b] = h[r, c] + rng.uniform(5, 50)
    return h + rng.normal(0, 0.05, shape)


# ------------------------------------------------------------------------------------------------
# tests
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("max_error", [0.0, 0.05, 0.5, 3.0])
def test_random_grid_37x53_bound_and_coverage(max_error: float) -> None:
    rng = np.random.default_rng(1)
    h = rng.normal(size=(37, 53)).cumsum(0).cumsum(1) * 0.1
    vij, faces = tin.triangulate(h, None, max_error)
    assert_tile_ok(h, None, vij, faces, max_error)
    assert vij.dtype == np.int32 and faces.dtype == np.int32


def test_zero_error_reproduces_the_grid_surface() -> None:
    h = np.random.default_rng(2).normal(size=(9, 11))
    vij, faces = tin.triangulate(h, None, 0.0)
    assert len(faces) == 2 * 8 * 10
    assert oracle_error(h, vij, faces)[0] <= TOL


@pytest.mark.parametrize("shape", [(65, 65), (40, 71)])
def test_city_cliffs(shape: tuple[int, int]) -> None:
    h = city(shape, seed=shape[1])
    vij, faces = tin.triangulate(h, None, 0.1)
    assert_tile_ok(h, None, vij, faces, 0.1)


def test_single_cliff_inside_one_sample() -> None:
    h = np.zeros((33, 33))
    h[:, 17:] = 50.0
    h[10:20, 5:9] = 50.0
    vij, faces = tin.triangulate(h, None, 0.5)
    assert_tile_ok(h, None, vij, faces, 0.5)


@pytest.mark.parametrize("shape", [(2, 2), (5, 9), (129, 129)])
def test_constant_and_planar_tiles_are_two_triangles(shape: tuple[int, int]) -> None:
    for h in (np.full(shape, 7.25), 0.3 * np.arange(shape[1])[None, :] - 0.2 * np.arange(shape[0])[:, None]):
        vij, faces = tin.triangulate(h, None, 0.0 if h.std() == 0 else 1e-9)
        assert len(faces) == 2
        assert {tuple(p) for p in vij.tolist()} == {
            (0, 0),
            (0, shape[1] - 1),
            (shape[0] - 1, 0),
            (shape[0] - 1, shape[1] - 1),
        }
        assert_tile_ok(h, None, vij, faces, 1e-9)


def test_2x2_uses_the_grid_diagonal() -> None:
    h = np.array([[0.0, 0.0], [0.0, 10.0]])
    vij, faces = tin.triangulate(h, None, 0.0)
    assert len(faces) == 2
    assert_tile_ok(h, None, vij, faces, 0.0)


@pytest.mark.parametrize("shape", [(1, 40), (40, 1), (1, 1)])
def test_thin_grids_give_a_polyline_and_no_faces(shape: tuple[int, int]) -> None:
    z = np.sin(np.linspace(0, 6, max(shape))) * 10
    vij, faces = tin.triangulate(z.reshape(shape), None, 0.5)
    assert faces.shape == (0, 3)
    k = vij[:, 1] if shape[0] == 1 else vij[:, 0]
    assert k[0] == 0 and k[-1] == max(shape) - 1
    np.testing.assert_array_equal(k, tin.simplify_polyline(z, 0.5))


def test_all_invalid_is_empty() -> None:
    vij, faces = tin.triangulate(np.zeros((9, 9)), np.zeros((9, 9), bool), 1.0)
    assert vij.shape == (0, 2) and faces.shape == (0, 3)
    h = np.full((9, 9), np.nan)
    h[::2, ::2] = 1.0  # valid samples but no valid cell
    assert tin.triangulate(h, None, 1.0)[1].shape == (0, 3)


def test_no_data_holes_and_borders() -> None:
    rng = np.random.default_rng(4)
    h = city((48, 57), seed=4)
    valid = np.ones(h.shape, bool)
    valid[10:20, 15:30] = False  # a hole
    valid[:, :3] = False  # a no-data border strip
    valid[30:, 40:] = False  # a no-data corner
    valid[rng.integers(0, 48, 25), rng.integers(0, 57, 25)] = False  # speckle
    valid[44, 20] = valid[45, 21] = False  # cells touching only at a corner
    h[~valid] = rng.uniform(-1e4, 1e4, (~valid).sum())  # garbage under no-data must not matter
    for e in (0.0, 0.3, 5.0):
        vij, faces = tin.triangulate(h, valid, e)
        assert_tile_ok(h, valid, vij, faces, e)


def test_nan_heights_are_no_data() -> None:
    h = city((30, 30), seed=5)
    h[5:9, 5:9] = np.nan
    vij, faces = tin.triangulate(h, None, 0.2)
    assert_tile_ok(np.nan_to_num(h), np.isfinite(h), vij, faces, 0.2)


def test_huge_base_height_keeps_the_bound_exact() -> None:
    h = city((41, 47), seed=6) + 5.5e6
    vij, faces = tin.triangulate(h, None, 0.05)
    assert_tile_ok(h, None, vij, faces, 0.05)
    err, _ = tin.max_vertical_error(h, None, vij, faces)
    assert err <= 0.05 + TOL


def test_real_dem_jacksboro() -> None:
    cbook = pytest.importorskip("matplotlib.cbook")
    dem = np.asarray(cbook.get_sample_data("jacksboro_fault_dem.npz")["elevation"], dtype=np.float64)
    h = dem[100:197, 150:251]
    for e in (2.0, 10.0):
        vij, faces = tin.triangulate(h, None, e)
        assert_tile_ok(h, None, vij, faces, e)


def test_must_include_and_refine() -> None:
    h = city((33, 33), seed=7)
    extra = np.array([[5, 7], [16, 16], [30, 2], [0, 9]])
    vij, faces = tin.triangulate(h, None, 1.0, must_include=extra)
    have = {tuple(p) for p in vij.tolist()}
    assert {tuple(p) for p in extra.tolist()} <= have
    assert_tile_ok(h, None, vij, faces, 1.0)
    v2, f2 = tin.refine(h, None, vij, [[20, 21], [3, 30]])  # max_error=inf: exactly these vertices
    assert have | {(20, 21), (3, 30)} == {tuple(p) for p in v2.tolist()}
    assert_tile_ok(h, None, v2, f2, np.inf)  # coverage; the bound may have moved (Delaunay flips)
    v3, f3 = tin.refine(h, None, vij, [[20, 21], [3, 30]], max_error=1.0)
    assert have | {(20, 21), (3, 30)} <= {tuple(p) for p in v3.tolist()}
    assert_tile_ok(h, None, v3, f3, 1.0)


def test_corners_are_vertices_and_borders_follow_the_1d_simplification() -> None:
    h = city((50, 61), seed=8)
    e = 0.4
    vij, _ = tin.triangulate(h, None, e)
    have = {tuple(p) for p in vij.tolist()}
    assert {(0, 0), (0, 60), (49, 0), (49, 60)} <= have
    for line, to_ij in (
        (h[0], lambda k: (0, k)),
        (h[-1], lambda k: (49, k)),
        (h[:, 0], lambda k: (k, 0)),
        (h[:, -1], lambda k: (k, 60)),
    ):
        assert {to_ij(k) for k in tin.simplify_polyline(line, e).tolist()} <= have


def _forced_reference(h: np.ndarray, valid: np.ndarray, e: float) -> np.ndarray:
    """The forced-sample rule written independently with numpy: corners, each border's valid runs
    simplified (1D, to the border fraction of the bound), and every sample on the valid region's boundary
    (some but not all of its in-grid cells valid)."""
    H, W = h.shape
    eb = e * tin.BORDER_ERROR_FRACTION
    out = np.zeros((H, W), dtype=bool)
    out[[0, 0, -1, -1], [0, -1, 0, -1]] = True
    for line in (np.s_[0, :], np.s_[-1, :], np.s_[:, 0], np.s_[:, -1]):
        out[line][tin.simplify_polyline(h[line], eb, valid=valid[line])] = True
    cv = np.pad(tin.cell_validity(valid), 1).astype(np.int8)
    n_valid = cv[:-1, :-1] + cv[1:, :-1] + cv[:-1, 1:] + cv[1:, 1:]
    inside = np.pad(np.ones((H - 1, W - 1), dtype=np.int8), 1)
    n_cells = inside[:-1, :-1] + inside[1:, :-1] + inside[:-1, 1:] + inside[1:, 1:]
    return out | ((n_valid > 0) & (n_valid < n_cells))


@pytest.mark.parametrize("seed", range(4))
def test_forced_samples_are_forced_vertices_in_z_order(seed: int) -> None:
    """The compiled preparation inserts exactly the forced samples (checked against the rule written
    independently above) and ``must_include``, ordered by Z-order keys computed here bit by bit."""
    from citylod.lod.kernels import tin_kernels

    rng = np.random.default_rng(seed)
    h = city((29 + seed, 41), seed=seed)
    valid = rng.random(h.shape) > 0.1 if seed % 2 else np.ones(h.shape, bool)
    e = 0.5
    mi = np.stack([rng.integers(0, h.shape[0], 6), rng.integers(0, h.shape[1], 6)], axis=1)
    assert np.array_equal(tin.forced_vertices(h, valid, e), _forced_reference(h, valid, e))
    mask = tin.forced_vertices(h, valid, e)
    mask[mi[:, 0], mi[:, 1]] = True
    fx, fy = tin_kernels.z_ordered(mask)
    want = _forced_reference(h, valid, e)
    want[mi[:, 0], mi[:, 1]] = True
    assert {(int(r), int(c)) for r, c in zip(fy, fx, strict=True)} == {tuple(p) for p in np.argwhere(want).tolist()}
    assert len(fx) == int(want.sum())

    def z_key(r: int, c: int) -> int:
        return sum((((c >> b) & 1) << (2 * b)) | (((r >> b) & 1) << (2 * b + 1)) for b in range(16))

    keys = [z_key(int(r), int(c)) for r, c in zip(fy, fx, strict=True)]
    assert keys == sorted(keys)


def _border(vij: np.ndarray, col: int) -> set[int]:
    return set(vij[vij[:, 1] == col, 0].tolist())


def test_adjacent_tiles_share_border_vertices() -> None:
    h = city((65, 129), seed=9, n_buildings=20)
    left, right = h[:, :65], h[:, 64:]
    e = 0.25
    # the forced border part depends only on the shared column
    fl = tin.forced_vertices(left, None, e)[:, -1]
    fr = tin.forced_vertices(right, None, e)[:, 0]
    np.testing.assert_array_equal(fl, fr)
    vl, fl_ = tin.triangulate(left, None, e)
    vr, fr_ = tin.triangulate(right, None, e)
    shared_1d = set(np.flatnonzero(fl).tolist())
    assert shared_1d <= _border(vl, 64) and shared_1d <= _border(vr, 0)
    # the builder's reconciliation: force each side's border vertices into the other until stable
    for _ in range(5):
        union = sorted(_border(vl, 64) | _border(vr, 0))
        if _border(vl, 64) == _border(vr, 0):
            break
        vl, fl_ = tin.triangulate(left, None, e, must_include=[(r, 64) for r in union])
        vr, fr_ = tin.triangulate(right, None, e, must_include=[(r, 0) for r in union])
    assert _border(vl, 64) == _border(vr, 0)
    assert_tile_ok(left, None, vl, fl_, e)
    assert_tile_ok(right, None, vr, fr_, e)


def test_smooth_tiles_share_borders_without_reconciliation() -> None:
    # when neither side had to add border samples, the border sets are the 1D ones: equal
    y, x = np.mgrid[0:33, 0:65] / 8.0
    h = 10 * np.sin(x) * np.cos(0.7 * y)
    r1 = tin.build(h[:, :33], None, 1.0)
    r2 = tin.build(h[:, 32:], None, 1.0)
    assert r1.border_added == r2.border_added == 0
    assert _border(r1.vertices_ij, 32) == _border(r2.vertices_ij, 0)


@pytest.mark.parametrize("max_error", [0.0, 0.3, 2.0])
def test_simplify_polyline_bound(max_error: float) -> None:
    z = np.random.default_rng(10).normal(size=300).cumsum()
    k = tin.simplify_polyline(z, max_error)
    assert k[0] == 0 and k[-1] == 299 and (np.diff(k) > 0).all()
    approx = np.interp(np.arange(300), k, z[k])
    assert np.abs(approx - z).max() <= max_error + TOL
    np.testing.assert_array_equal(k, tin.simplify_polyline(z.copy(), max_error))


def test_simplify_polyline_runs_and_constants() -> None:
    assert tin.simplify_polyline(np.full(10, 3.0), 0.0).tolist() == [0, 9]
    z = np.arange(12, dtype=float) ** 2
    valid = np.ones(12, bool)
    valid[[4, 5, 9]] = False
    k = tin.simplify_polyline(z, 100.0, valid=valid)
    assert k.tolist() == [0, 3, 6, 8, 10, 11]


def test_max_vertical_error_matches_the_oracle_on_bad_tins() -> None:
    rng = np.random.default_rng(11)
    h = rng.normal(size=(17, 23)) * 3 + 1e5
    vij = np.array([[0, 0], [0, 22], [16, 0], [16, 22], [8, 11], [3, 17]], dtype=np.int32)
    from scipy.spatial import Delaunay

    faces = Delaunay(vij[:, ::-1].astype(float)).simplices
    ours, where = tin.max_vertical_error(h, None, vij, faces)
    ref, _ = oracle_error(h, vij, faces)
    assert ours == pytest.approx(ref, abs=TOL)
    assert 0 <= where[0] <= 16 and 0 <= where[1] <= 22
    vz = h[vij[:, 0], vij[:, 1]] + rng.uniform(-0.5, 0.5, len(vij))
    ours_q, _ = tin.max_vertical_error(h, None, vij, faces, vertex_z=vz)
    assert ours_q == pytest.approx(oracle_error(h, vij, faces, vz)[0], abs=TOL)


def test_max_vertical_error_sees_crossings_that_samples_miss() -> None:
    # a 2x2 cell triangulated on the wrong diagonal: all samples exact, the crossing is not
    h = np.array([[0.0, 0.0], [0.0, 10.0]])
    vij = np.array([[0, 0], [0, 1], [1, 0], [1, 1]])
    faces = np.array([[0, 2, 1], [1, 2, 3]])
    err, where = tin.max_vertical_error(h, None, vij, faces)
    assert err == pytest.approx(5.0)
    assert where == pytest.approx((0.5, 0.5))


def test_bad_input() -> None:
    with pytest.raises(ValueError):
        tin.triangulate(np.zeros((4, 4)), None, -1.0)
    with pytest.raises(ValueError):
        tin.triangulate(np.zeros((4, 4)), np.ones((3, 4), bool), 1.0)
    with pytest.raises(ValueError):
        tin.triangulate(np.zeros((4, 4)), None, 1.0, must_include=[[4, 0]])


def test_3d_error_follows_facades_with_fewer_triangles() -> None:
    """``plane=``: the kernel measures 3D distances, so a façade between two vertices costs the slope's
    offset, not its height. On a rotated block and round towers (1 m samples) the TIN has at most 3/4 of the
    vertical TIN's triangles at the same tolerance, its Hausdorff distance to the raster (certified) stays
    within 1.5× the tolerance, and its vertical error is far above it (the façades are slopes now)."""
    from citylod.lod.kernels.certify import certify
    from citylod.lod.kernels.hausdorff import certify_hausdorff

    n = 97
    yy, xx = np.mgrid[0:n, 0:n].astype(float)
    z = 0.02 * xx
    u = (xx - 48) * np.cos(0.4) + (yy - 40) * np.sin(0.4)
    v = -(xx - 48) * np.sin(0.4) + (yy - 40) * np.cos(0.4)
    z[(abs(u) < 20) & (abs(v) < 10)] += 15.0
    for cx, cy in ((15, 80), (80, 80), (20, 15)):
        z[(xx - cx) ** 2 + (yy - cy) ** 2 < 25] += 12.0
    ok = np.ones_like(z, bool)

    def read(r, c, nr, nc):
        return z[r:r + nr, c:c + nc], ok[r:r + nr, c:c + nc]

    tol = 1.0
    vertical = tin.build(z, ok, tol)
    r = tin.build(z, ok, tol, plane=(1.0, 1.0))
    assert len(r.faces) <= 0.75 * len(vertical.faces), (len(r.faces), len(vertical.faces))
    vr, vc = r.vertices_ij[:, 0].astype(float), r.vertices_ij[:, 1].astype(float)
    vz = z[r.vertices_ij[:, 0], r.vertices_ij[:, 1]]
    faces = r.faces.astype(np.int64)
    hd, _, _ = certify_hausdorff(read, (0, 0, n - 1, n - 1), vr, vc, vz, faces, (1, 1), n - 1, (1.0, 0.0, 0.0, -1.0))
    vt, _, _ = certify(read, (0, 0, n - 1, n - 1), vr, vc, vz, faces, (1, 1), n - 1)
    assert hd <= 1.5 * tol, hd
    assert vt > 5 * tol, vt
    with pytest.raises(ValueError, match="plane"):
        tin.build(z, ok, tol, plane=(0.0, 1.0))
