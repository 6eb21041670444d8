"""Vertex removal after the greedy phase of `citylod.lod.kernels.tin` (``decimate=True``, the default).

Every TIN is checked with the brute-force oracle of ``test_tin`` (plain numpy, its own enumeration of
samples and edge / grid-line crossings, random interior points, coverage by probes), never with the
library's evaluator; the decimated TIN is compared with the plain greedy one (``decimate=False``).
"""

from __future__ import annotations

import numpy as np
import pytest

from citylod.lod.kernels import tin
from tests.lod.test_tin import assert_tile_ok, city


def _set(vij: np.ndarray) -> set[tuple[int, int]]:
    return {tuple(p) for p in vij.tolist()}


def _border(vij: np.ndarray, shape: tuple[int, int]) -> set[tuple[int, int]]:
    H, W = shape
    r, c = vij[:, 0], vij[:, 1]
    return _set(vij[(r == 0) | (c == 0) | (r == H - 1) | (c == W - 1)])


def _seeds(h: np.ndarray, valid: np.ndarray | None, e: float, lattice: int = 0) -> np.ndarray:
    """The seeds, computed here from their definition: interior samples at even row and column, four valid
    cells, whose 3×3 neighbourhood departs from the bilinear interpolation of its corners by more than
    ``SEED_DEVIATION·e``, or (``lattice``) whose row and column are multiples of ``lattice``."""
    H, W = h.shape
    v = np.isfinite(h) if valid is None else valid & np.isfinite(h)
    out = []
    for r in range(2, H - 1, 2):
        for c in range(2, W - 1, 2):
            if not v[r - 1:r + 2, c - 1:c + 2].all():
                continue
            if lattice and r % lattice == 0 and c % lattice == 0:
                out.append((r, c))
                continue
            blk = h[r - 1:r + 2, c - 1:c + 2]
            t = np.array([0.0, 0.5, 1.0])
            bil = ((1 - t)[:, None] * ((1 - t)[None, :] * blk[0, 0] + t[None, :] * blk[0, 2])
                   + t[:, None] * ((1 - t)[None, :] * blk[2, 0] + t[None, :] * blk[2, 2]))
            if np.abs(blk - bil).max() > tin.SEED_DEVIATION * e:
                out.append((r, c))
    return np.array(out, dtype=np.int64).reshape(-1, 2)


def _sample_city_window(size: int, r0: int, c0: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    from citylod.sample.city import make_city

    c = make_city(size, seed=11)
    x, y = c.pixel_centers()
    h = c.surface_height(x, y)[r0 : r0 + n, c0 : c0 + n]
    valid = ~c.nodata_mask(x, y)[r0 : r0 + n, c0 : c0 + n]
    return h, valid


def _check_against_greedy(h: np.ndarray, valid: np.ndarray | None, e: float, lattice: int = 0) -> tuple[int, int]:
    """The three TINs meet the bound (plain greedy, greedy from the seeds, and that decimated); the
    decimated one keeps a subset of its greedy phase's vertices, among them every forced one and every
    border one. Returns (seeded greedy faces, decimated faces)."""
    vp, fp = tin.triangulate(h, valid, e, decimate=False)
    assert_tile_ok(h, valid, vp, fp, e)
    v0, f0 = tin.triangulate(h, valid, e, decimate=False, seed=True, lattice=lattice)
    v1, f1 = tin.triangulate(h, valid, e, lattice=lattice)
    assert_tile_ok(h, valid, v0, f0, e)
    assert_tile_ok(h, valid, v1, f1, e)
    assert _set(_seeds(h, valid, e, lattice)) <= _set(v0)
    assert _set(v1) <= _set(v0)
    # forced samples touching no valid cell are in no face, hence in neither vertex list
    assert _set(np.argwhere(tin.forced_vertices(h, valid, e))) & _set(v0) <= _set(v1)
    assert _border(v1, h.shape) == _border(v0, h.shape)
    assert len(f1) <= len(f0)
    return len(f0), len(f1)


@pytest.mark.parametrize("max_error", [0.05, 0.3, 2.0])
@pytest.mark.parametrize("seed", [0, 1])
def test_city_cliffs_bound_and_fewer_faces(max_error: float, seed: int) -> None:
    h = city((65, 71), seed=seed, n_buildings=25)
    n0, n1 = _check_against_greedy(h, None, max_error)
    assert n1 < n0


@pytest.mark.parametrize("max_error", [0.3, 8.0])
def test_lattice_seeds_are_vertices_of_the_greedy_phase_and_removable(max_error: float) -> None:
    # the coarse tiles' lattice (every 16th row and column) with no-data: seeds where four cells are valid
    h, valid = _sample_city_window(513, 0, 0, 129)
    assert not valid.all()
    _check_against_greedy(h, valid, max_error, lattice=tin.SEED_LATTICE)
    v1, _ = tin.triangulate(h, valid, 8.0, lattice=tin.SEED_LATTICE)
    lattice = _set(_seeds(h, valid, 8.0, tin.SEED_LATTICE)) - _set(_seeds(h, valid, 8.0))
    assert len(lattice) > 20 and len(lattice & _set(v1)) < len(lattice)  # some went in the removal pass
    with pytest.raises(ValueError, match="even"):
        tin.triangulate(h, valid, 8.0, lattice=15)


@pytest.mark.parametrize("max_error", [0.0, 0.1, 1.0])
def test_rough_random_grid(max_error: float) -> None:
    # rough data: many non-convex holes, vertices of high degree, removals next to the hull
    rng = np.random.default_rng(3)
    h = rng.normal(size=(41, 37)).cumsum(0).cumsum(1) * 0.2 + rng.normal(size=(41, 37))
    _check_against_greedy(h, None, max_error)


def test_sample_city_tile_about_30_percent_fewer_faces() -> None:
    # a 129² leaf tile of the benchmark city (1 m spacing, leaf bound 0.5 m): façades, roofs, no-data
    h, valid = _sample_city_window(513, 256, 128, 129)
    n0, n1 = _check_against_greedy(h, valid, 0.5)
    assert n1 <= 0.85 * n0, (n0, n1)


def test_seeds_are_removable_and_cost_no_faces() -> None:
    # Seeds only save the greedy phase work: the decimation removes those the bound does not need (most of
    # them on a city tile), and the result has about as many faces as without them.
    h, valid = _sample_city_window(513, 256, 128, 129)
    v1, f1 = tin.triangulate(h, valid, 0.5)
    _, f2 = tin.triangulate(h, valid, 0.5, seed=False)
    seeds = _set(_seeds(h, valid, 0.5))
    assert len(seeds) > 100
    assert len(seeds & _set(v1)) < 0.5 * len(seeds)
    assert len(f1) <= 1.02 * len(f2), (len(f1), len(f2))


def test_no_data_and_must_include() -> None:
    rng = np.random.default_rng(4)
    h = city((48, 57), seed=4)
    valid = np.ones(h.shape, bool)
    valid[10:20, 15:30] = False
    valid[30:, 40:] = False
    valid[rng.integers(0, 48, 25), rng.integers(0, 57, 25)] = False
    h[~valid] = rng.uniform(-1e4, 1e4, (~valid).sum())
    _check_against_greedy(h, valid, 0.3)
    must = np.array([[5, 7], [24, 36], [40, 9], [0, 13], [47, 30]])
    vij, faces = tin.triangulate(h, valid, 0.3, must_include=must)
    assert _set(must) <= _set(vij)
    assert_tile_ok(h, valid, vij, faces, 0.3)


def test_adjacent_tiles_keep_matching_borders() -> None:
    # the border vertex sets are the greedy phase's: tiles that matched before decimation still match
    h = city((65, 129), seed=9, n_buildings=20)
    left, right = h[:, :65], h[:, 64:]
    for e in (0.25, 1.0):
        vl0, _ = tin.triangulate(left, None, e, decimate=False)
        vr0, _ = tin.triangulate(right, None, e, decimate=False)
        vl, fl = tin.triangulate(left, None, e)
        vr, fr = tin.triangulate(right, None, e)
        assert set(vl[vl[:, 1] == 64, 0].tolist()) == set(vl0[vl0[:, 1] == 64, 0].tolist())
        assert set(vr[vr[:, 1] == 0, 0].tolist()) == set(vr0[vr0[:, 1] == 0, 0].tolist())
        assert_tile_ok(left, None, vl, fl, e)
        assert_tile_ok(right, None, vr, fr, e)


def test_wall_under_a_sloped_roof_needs_its_crossings() -> None:
    # A straight wall (one cell wide ramp) between a sloped roof and flat ground: no sample is ever
    # off, but long TIN edges across the ramp are, so the TIN must keep vertices along the wall.
    H, W = 40, 60
    y, x = np.mgrid[0:H, 0:W].astype(float)
    h = np.where(y >= 20, 10.0 + 0.5 * x, 0.0)
    n0, n1 = _check_against_greedy(h, None, 0.25)
    vij, faces = tin.triangulate(h, None, 0.25)
    assert_tile_ok(h, None, vij, faces, 0.25)
    assert n1 <= n0


def test_infinite_bound_and_exact_bound() -> None:
    h = city((33, 33), seed=7)
    # inf: the forced vertices only, none removable
    v, f = tin.triangulate(h, None, np.inf)
    assert _set(v) == _set(np.argwhere(tin.forced_vertices(h, None, np.inf)))
    # 0: every sample whose removal would change the surface stays; the surface is the grid's
    v, f = tin.triangulate(h, None, 0.0)
    assert_tile_ok(h, None, v, f, 0.0)
