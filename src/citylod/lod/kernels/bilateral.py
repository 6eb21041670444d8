"""Compiled passes of roof refinement (:mod:`citylod.lod.build.refine`): neighbourhood covariances, then the
bilateral smoothing of normals and of positions over a fixed neighbour table.

The same arithmetic as the numpy formulation of :func:`citylod.lod.build.refine.refine_roofs` (``compiled=False``, the
reference a test compares against), without its (N, k, 3) temporaries: that formulation spent ≈ 1.2 s of
1.9 s on Delft's 280,000 building points in them (docs/PERFORMANCE_LOG.md). Numba kernels
(``cache=True``, ``nogil``). No I/O, no VTK, no Qt.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt

from citylod.core.jit import defer_blas_probe

defer_blas_probe()

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


@numba.njit(cache=True, nogil=True)
def covariances(p: F64, j: I64, ok: npt.NDArray[np.bool_]) -> F64:  # pragma: no cover - compiled
    """(N, 3, 3) covariance of each point's neighbours ``p[j[i]]`` where ``ok[i]``."""
    n, k = j.shape
    cov = np.zeros((n, 3, 3))
    for i in range(n):
        cnt = 0.0
        m0 = m1 = m2 = 0.0
        for t in range(k):
            if ok[i, t]:
                q = j[i, t]
                m0 += p[q, 0]
                m1 += p[q, 1]
                m2 += p[q, 2]
                cnt += 1.0
        c = max(cnt, 1.0)
        m0, m1, m2 = m0 / c, m1 / c, m2 / c
        for t in range(k):
            if ok[i, t]:
                q = j[i, t]
                d = (p[q, 0] - m0, p[q, 1] - m1, p[q, 2] - m2)
                for a in range(3):
                    for b in range(3):
                        cov[i, a, b] += d[a] * d[b]
        for a in range(3):
            for b in range(3):
                cov[i, a, b] /= c
    return cov


@numba.njit(cache=True, nogil=True)
def _weights(n: F64, j: I64, w_s: F64, sigma_n: float, i: int, w: F64) -> None:  # pragma: no cover - compiled
    for t in range(j.shape[1]):
        q = j[i, t]
        agree = 1.0 - (n[i, 0] * n[q, 0] + n[i, 1] * n[q, 1] + n[i, 2] * n[q, 2])
        w[t] = w_s[i, t] * math.exp(-0.5 * (agree / sigma_n) ** 2)


@numba.njit(cache=True, nogil=True)
def bilateral(p: F64, n: F64, j: I64, w_s: F64, sigma_n: float, normal_passes: int, position_passes: int,
              max_move: float) -> tuple[F64, F64]:  # pragma: no cover - compiled
    """Smoothed normals, then positions (each pass from the previous pass's values, as the numpy
    formulation): see :func:`citylod.lod.build.refine.refine_roofs`. Returns (positions, normals)."""
    npts, k = j.shape
    w = np.empty(k)
    for _ in range(normal_passes):
        out = np.empty_like(n)
        for i in range(npts):
            _weights(n, j, w_s, sigma_n, i, w)
            m0 = m1 = m2 = 0.0
            for t in range(k):
                q = j[i, t]
                m0 += w[t] * n[q, 0]
                m1 += w[t] * n[q, 1]
                m2 += w[t] * n[q, 2]
            norm = max(math.sqrt(m0 * m0 + m1 * m1 + m2 * m2), 1e-12)
            out[i, 0], out[i, 1], out[i, 2] = m0 / norm, m1 / norm, m2 / norm
        n = out
    start = p.copy()
    for _ in range(position_passes):
        out = np.empty_like(p)
        for i in range(npts):
            _weights(n, j, w_s, sigma_n, i, w)
            num = den = 0.0
            for t in range(k):
                q = j[i, t]
                off = ((p[q, 0] - p[i, 0]) * n[q, 0] + (p[q, 1] - p[i, 1]) * n[q, 1]
                       + (p[q, 2] - p[i, 2]) * n[q, 2])
                num += w[t] * off
                den += w[t]
            step = num / max(den, 1e-12)
            moved = 0.0
            for a in range(3):
                out[i, a] = p[i, a] + step * n[i, a]
                moved += (out[i, a] - start[i, a]) * n[i, a]
            over = moved - min(max(moved, -max_move), max_move)
            for a in range(3):
                out[i, a] -= over * n[i, a]
        p = out
    return p, n
