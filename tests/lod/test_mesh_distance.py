"""The certified Hausdorff bound against analytic distances and an independent dense sampling (scipy)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from citylod.lod.kernels.mesh_distance import directed_hausdorff, hausdorff_bound

SQUARE = np.array([[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0]], float)
TWO = np.array([[0, 1, 2], [0, 2, 3]])


def _dense(v: np.ndarray, f: np.ndarray, n: int = 60) -> np.ndarray:
    """Points on every triangle on a barycentric grid of n subdivisions."""
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    a, b = i[keep] / n, j[keep] / n
    t = v[f]
    return (t[:, None, 0] * (1 - a - b)[None, :, None] + t[:, None, 1] * a[None, :, None]
            + t[:, None, 2] * b[None, :, None]).reshape(-1, 3)


def test_parallel_offset_and_tilt_are_exact() -> None:
    lo, hi = directed_hausdorff(SQUARE, TWO, SQUARE + [0, 0, 1.5], TWO[:, ::-1])
    assert lo <= 1.5 <= hi <= 1.5 + 0.05
    tilted = SQUARE.copy()
    tilted[:, 2] = 0.2 * tilted[:, 0]  # the plane z = 0.2 x: farthest point (10, y, 0) at 2 / sqrt(1.04)
    lo, hi = directed_hausdorff(SQUARE, TWO, tilted, TWO)
    true = 2.0 / np.sqrt(1.04)
    assert lo <= true + 1e-9 and true <= hi <= true + 0.05


def test_shifted_square_reaches_the_far_corner() -> None:
    # B is A shifted by (3, 4, 0): A's corner (0, 0) is 5 m from B; the symmetric distance is 5.
    b = SQUARE + [3, 4, 0]
    h = hausdorff_bound(SQUARE, TWO, b, TWO)
    assert 5.0 <= h <= 5.05


def test_random_meshes_against_dense_sampling() -> None:
    rng = np.random.default_rng(3)
    for _ in range(5):
        a = rng.uniform(0, 10, (12, 3))
        b = a + rng.normal(0, 0.7, a.shape)
        fa = rng.integers(0, 12, (8, 3))
        fa = fa[(fa[:, 0] != fa[:, 1]) & (fa[:, 1] != fa[:, 2]) & (fa[:, 0] != fa[:, 2])]
        pa, pb = _dense(a, fa), _dense(b, fa, n=200)
        # Dense samples of B overestimate d(p, B) by at most their spacing; sup over A's samples misses
        # the true supremum by at most A's spacing (the distance is 1-Lipschitz).
        spacing_b = np.linalg.norm(b[fa][:, 0] - b[fa][:, 1], axis=1).max() / 200 * 2
        est = cKDTree(pb).query(pa)[0].max()
        lo, hi = directed_hausdorff(a, fa, b, fa, tol=0.01)
        assert est - spacing_b <= hi + 1e-9
        assert lo <= hi <= lo + 0.01 + 1e-9


def test_empty_meshes() -> None:
    assert directed_hausdorff(SQUARE[:0], TWO[:0], SQUARE, TWO) == (0.0, 0.0)
    assert directed_hausdorff(SQUARE, TWO, SQUARE[:0], TWO[:0])[1] == np.inf
