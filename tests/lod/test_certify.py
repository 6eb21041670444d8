"""The exact certifier against a brute-force evaluation of the two piecewise-linear surfaces."""

from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay

from citylod.lod.kernels.certify import certify


def _grid_surface(z: np.ndarray, y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """F at points, cells split by the diagonal (i, j)-(i+1, j+1): an independent evaluation."""
    i = np.clip(np.floor(y).astype(int), 0, z.shape[0] - 2)
    j = np.clip(np.floor(x).astype(int), 0, z.shape[1] - 2)
    fy, fx = y - i, x - j
    lower = fy >= fx  # below the diagonal (in row-major orientation): triangle (i,j),(i+1,j),(i+1,j+1)
    z00, z10, z11, z01 = z[i, j], z[i + 1, j], z[i + 1, j + 1], z[i, j + 1]
    a = np.where(lower, z00 + fy * (z10 - z00) + fx * (z11 - z10), z00 + fx * (z01 - z00) + fy * (z11 - z01))
    return a


def test_certifier_matches_dense_brute_force() -> None:
    rng = np.random.default_rng(5)
    z = rng.normal(0, 1, (33, 29)).cumsum(axis=0).cumsum(axis=1) * 0.1
    z[10:14, 5:9] += 30.0  # a block with façades
    pts = np.concatenate([rng.integers(0, [33, 29], (40, 2)), [[0, 0], [0, 28], [32, 0], [32, 28]]])
    pts = np.unique(pts, axis=0).astype(float)
    tri = Delaunay(pts)
    faces = tri.simplices.astype(np.int64)
    vz = z[pts[:, 0].astype(int), pts[:, 1].astype(int)] + rng.normal(0, 0.05, len(pts))
    valid = np.ones_like(z, bool)

    def read(r, c, nr, nc):
        return z[r:r + nr, c:c + nc], valid[r:r + nr, c:c + nc]

    err, cell_err, _where = certify(read, (0, 0, 32, 28), pts[:, 0], pts[:, 1], vz, faces, (32, 28), 1, block=7)
    # Brute force: sample every triangle densely (barycentric grid) and evaluate both surfaces.
    k = 120
    u, v = np.meshgrid(np.linspace(0, 1, k), np.linspace(0, 1, k))
    keep = u + v <= 1
    u, v = u[keep], v[keep]
    brute = 0.0
    for f in faces:
        p = pts[f]
        y = p[0, 0] + u * (p[1, 0] - p[0, 0]) + v * (p[2, 0] - p[0, 0])
        x = p[0, 1] + u * (p[1, 1] - p[0, 1]) + v * (p[2, 1] - p[0, 1])
        t = vz[f[0]] + u * (vz[f[1]] - vz[f[0]]) + v * (vz[f[2]] - vz[f[0]])
        brute = max(brute, float(np.abs(t - _grid_surface(z, y, x)).max()))
    # dense sampling can only under-estimate the exact maximum, and gets close to it
    assert err >= brute - 1e-9
    assert err <= brute * 1.02 + 1e-6
    assert cell_err.max() == err


def _full_grid(rpos: np.ndarray, cpos: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The coarse grid as a TIN (every sample a vertex, cells split by their (a,b)-(a+1,b+1) diagonal)."""
    nr, nc = len(rpos), len(cpos)
    idx = np.arange(nr * nc).reshape(nr, nc)
    gv = valid[np.ix_(rpos, cpos)]
    cv = gv[:-1, :-1] & gv[:-1, 1:] & gv[1:, :-1] & gv[1:, 1:]
    a, b, c, d = idx[:-1, :-1][cv], idx[:-1, 1:][cv], idx[1:, :-1][cv], idx[1:, 1:][cv]
    faces = np.concatenate([np.stack([a, d, c], 1), np.stack([a, b, d], 1)]).astype(np.int64)
    vr, vc = (g.reshape(-1).astype(float) for g in np.meshgrid(rpos, cpos, indexing="ij"))
    return vr, vc, faces


def test_grid_lower_bound_is_exact_on_square_cells_and_a_bound_otherwise() -> None:
    from citylod.lod.kernels.certify import grid_error_lower_bound

    rng = np.random.default_rng(3)
    z = rng.normal(0, 1, (65, 65)).cumsum(axis=0).cumsum(axis=1) * 0.05
    z[9:30, 13:22] += 25.0  # buildings: façades between the coarse samples
    z[40:43, 50:60] += 12.0
    valid = np.ones_like(z, bool)
    valid[55:60, 3:9] = False  # a no-data hole

    def read(r, c, nr, nc):
        return z[r:r + nr, c:c + nc], valid[r:r + nr, c:c + nc]

    for rpos, cpos, square in ((np.arange(0, 65, 8), np.arange(0, 65, 8), True),
                               (np.arange(0, 65, 4), np.r_[np.arange(0, 61, 6), 64], False)):
        vr, vc, faces = _full_grid(rpos, cpos, valid)
        exact, _, _ = certify(read, (0, 0, 64, 64), vr, vc, z[vr.astype(int), vc.astype(int)], faces, (8, 8), 8,
                              block=16, per_cell=False)
        gz, gv = z[np.ix_(rpos, cpos)], valid[np.ix_(rpos, cpos)]
        lb = grid_error_lower_bound(read, (0, 0, 64, 64), rpos, cpos, gz, gv, block=16)
        assert lb > 5.0  # the façades are seen
        assert lb <= exact + 1e-9
        if square:  # the coarse diagonals lie on the raster's: the samples are the whole overlay
            assert abs(lb - exact) < 1e-9
