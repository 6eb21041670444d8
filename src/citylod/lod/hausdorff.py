"""A certified bound on the symmetric Hausdorff distance between a coarse DSM tile and the full raster.

The vertical L∞ error (:mod:`citylod.lod.certify`) is the ``geometricError`` the design asks for, and it
bounds the Hausdorff distance. On city rasters it is a poor bound, though. A façade that falls between two
samples of a coarse grid costs its full height vertically (12–20 m), while no point of either surface
lies more than about one coarse spacing from the other. Selection with the vertical bound therefore
never picks coarse city tiles. This module certifies the tighter bound. The builder records it as
``extras.hausdorff_m`` of the tile, and citylod's selection uses ``min(geometricError, hausdorff_m)``.
Other 3D Tiles clients see only the vertical bound.

The argument is an intermediate-value one, per cell of the tile's (coarse) grid:

* F, the full-resolution surface, is continuous over a block of fully valid cells. Over a block B it
  therefore takes every height between ``min_B F`` and ``max_B F`` somewhere in B. C, the tile's TIN, does
  the same over blocks it covers.
* Take a point q = (x, y, z) of C over cell c, and the block B_r of (2r+1)² cells centred on c. Some point of
  F in B_r lies at the height of z clamped to F's range over B_r, so
  ``dist(q, F) ≤ hypot(D_r, gap)``. Here ``D_r = (r + 1)·hypot(Sx, Sy)`` is the farthest horizontal distance
  from c into B_r (Sx, Sy are the cell sizes), and ``gap`` is how far C's range over c sticks out of F's
  range over B_r. Points of F over c get the same bound with the roles swapped.
* Each cell also keeps its vertical bound: the certifier's per-cell error, taken over the cell's 3×3
  neighbourhood, so that overlay points on the cell's edges count for both sides. The bound of a point is
  the smaller of the two.

The tile's bound is the maximum over cells, in both directions. It is exact arithmetic on exact ranges:

* F's range over a cell is that of its full-resolution samples, because F is linear on each full-resolution
  triangle.
* C's range over a cell is that of C at the cell's corners and at the crossings of the TIN's edges with
  the cell's sides. The TIN's vertices are grid samples, so none lies inside a cell.

Nothing is sampled. Only the horizontal quantisation of the stored positions is added by the caller.

Written by hand, because no library certifies Hausdorff distances between height fields. The ranges
are numba kernels and the blocks are ``scipy.ndimage`` min/max filters. Memory is bounded: the full
raster is read in bands of cell rows.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt
from numba import njit

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
ReadBlock = Callable[[int, int, int, int], tuple[np.ndarray, np.ndarray]]

DEFAULT_RADII = (0, 1, 2, 3)


@njit(cache=True, nogil=True)
def _cells_of(pos: I64, n: int) -> tuple[I64, I64]:  # pragma: no cover - compiled
    """For full-resolution lines ``pos[0] .. pos[-1]``: the first and last cell whose closed extent holds
    each line (a line on a cell boundary belongs to both cells)."""
    lo_c = np.empty(n, np.int64)
    hi_c = np.empty(n, np.int64)
    ncell = pos.shape[0] - 1
    k = 0
    for t in range(n):
        g = pos[0] + t
        while k < ncell - 1 and pos[k + 1] <= g:
            k += 1
        hi_c[t] = k  # the largest k with pos[k] <= g: pos[k + 1] > g, or k is the last cell
        lo_c[t] = k - 1 if (g == pos[k] and k > 0) else k
    return lo_c, hi_c


@njit(cache=True, nogil=True)
def _f_ranges_band(h: F64, ok: npt.NDArray[np.bool_], row_lo: I64, row_hi: I64, col_lo: I64, col_hi: I64,
                   fmin: F64, fmax: F64, fbad: npt.NDArray[np.bool_]) -> None:  # pragma: no cover - compiled
    """Fold one band of full-resolution samples into the cells' height ranges and validity."""
    nr, nc = h.shape
    for a in range(nr):
        for b in range(nc):
            for i in range(row_lo[a], row_hi[a] + 1):
                for j in range(col_lo[b], col_hi[b] + 1):
                    if not ok[a, b]:
                        fbad[i, j] = True
                        continue
                    z = h[a, b]
                    if z < fmin[i, j]:
                        fmin[i, j] = z
                    if z > fmax[i, j]:
                        fmax[i, j] = z


@njit(cache=True, nogil=True)
def _find_cell(pos: F64, x: float) -> int:  # pragma: no cover - compiled
    """Index k of the cell [pos[k], pos[k+1]] holding x (x strictly inside the grid's extent)."""
    lo, hi = 0, pos.shape[0] - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if pos[mid] <= x:
            lo = mid
        else:
            hi = mid
    return lo


@njit(cache=True, nogil=True)
def _c_ranges(rpos: F64, cpos: F64, vi: I64, vj: I64, vz: F64, faces: I64
              ) -> tuple[F64, F64, npt.NDArray[np.bool_]]:  # pragma: no cover - compiled
    """C's exact height range over every cell, and which cells C covers (all four corners inside it).

    ``vi, vj`` are the vertices' grid-line indices, ``rpos, cpos`` the lines' full-resolution positions
    (the last spacing may be shorter), so every test is done in full-resolution coordinates.
    """
    nr, nc = rpos.shape[0], cpos.shape[0]
    cs = np.full((nr, nc), np.nan)
    for f in range(faces.shape[0]):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        ax, ay, bx, by, cx, cy = cpos[vj[a]], rpos[vi[a]], cpos[vj[b]], rpos[vi[b]], cpos[vj[c]], rpos[vi[c]]
        area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        if area == 0.0:
            continue
        i0, i1 = min(vi[a], vi[b], vi[c]), max(vi[a], vi[b], vi[c])
        j0, j1 = min(vj[a], vj[b], vj[c]), max(vj[a], vj[b], vj[c])
        for i in range(i0, i1 + 1):
            py = rpos[i]
            for j in range(j0, j1 + 1):
                if not np.isnan(cs[i, j]):
                    continue
                px = cpos[j]
                w0 = (bx - px) * (cy - py) - (by - py) * (cx - px)
                w1 = (cx - px) * (ay - py) - (cy - py) * (ax - px)
                w2 = (ax - px) * (by - py) - (ay - py) * (bx - px)
                if area < 0.0:
                    w0, w1, w2 = -w0, -w1, -w2
                if w0 >= 0.0 and w1 >= 0.0 and w2 >= 0.0:
                    aa = abs(area)
                    cs[i, j] = (w0 * vz[a] + w1 * vz[b] + w2 * vz[c]) / aa
    cmin = np.full((nr - 1, nc - 1), np.inf)
    cmax = np.full((nr - 1, nc - 1), -np.inf)
    cov = np.ones((nr - 1, nc - 1), np.bool_)
    for i in range(nr - 1):
        for j in range(nc - 1):
            for di in range(2):
                for dj in range(2):
                    z = cs[i + di, j + dj]
                    if np.isnan(z):
                        cov[i, j] = False
                    else:
                        cmin[i, j] = min(cmin[i, j], z)
                        cmax[i, j] = max(cmax[i, j], z)
    # Crossings of every TIN edge (each visited from both faces: harmless) with the grid lines.
    for f in range(faces.shape[0]):
        for e in range(3):
            p, q = faces[f, e], faces[f, (e + 1) % 3]
            ra, ca, za = rpos[vi[p]], cpos[vj[p]], vz[p]
            rb, cb, zb = rpos[vi[q]], cpos[vj[q]], vz[q]
            # row lines strictly between the endpoints
            lo_i, hi_i = min(vi[p], vi[q]), max(vi[p], vi[q])
            for i in range(lo_i + 1, hi_i):
                t = (rpos[i] - ra) / (rb - ra)
                x = ca + t * (cb - ca)
                z = za + t * (zb - za)
                k = _find_cell(cpos, x)
                for ii in (i - 1, i):
                    cmin[ii, k] = min(cmin[ii, k], z)
                    cmax[ii, k] = max(cmax[ii, k], z)
                    if x == cpos[k] and k > 0:
                        cmin[ii, k - 1] = min(cmin[ii, k - 1], z)
                        cmax[ii, k - 1] = max(cmax[ii, k - 1], z)
            lo_j, hi_j = min(vj[p], vj[q]), max(vj[p], vj[q])
            for j in range(lo_j + 1, hi_j):
                t = (cpos[j] - ca) / (cb - ca)
                y = ra + t * (rb - ra)
                z = za + t * (zb - za)
                k = _find_cell(rpos, y)
                for jj in (j - 1, j):
                    cmin[k, jj] = min(cmin[k, jj], z)
                    cmax[k, jj] = max(cmax[k, jj], z)
                    if y == rpos[k] and k > 0:
                        cmin[k - 1, jj] = min(cmin[k - 1, jj], z)
                        cmax[k - 1, jj] = max(cmax[k - 1, jj], z)
    return cmin, cmax, cov


def f_ranges(read_block: ReadBlock, rpos: I64, cpos: I64, band_samples: int = 4_000_000
             ) -> tuple[F64, F64, npt.NDArray[np.bool_]]:
    """F's height range over every cell of the grid ``rpos × cpos``, and which cells are fully valid.

    The footprint is read in bands of whole cell rows of about ``band_samples`` samples, so memory does not
    grow with the tile.
    """
    rpos, cpos = np.asarray(rpos, np.int64), np.asarray(cpos, np.int64)
    ncr, ncc = len(rpos) - 1, len(cpos) - 1
    fmin = np.full((ncr, ncc), np.inf)
    fmax = np.full((ncr, ncc), -np.inf)
    fbad = np.zeros((ncr, ncc), np.bool_)
    width = int(cpos[-1] - cpos[0] + 1)
    col_lo, col_hi = _cells_of(cpos, width)
    step = max(1, band_samples // max(width * max(int(rpos[1] - rpos[0]), 1), 1))
    for k0 in range(0, ncr, step):
        k1 = min(k0 + step, ncr)
        r0, r1 = int(rpos[k0]), int(rpos[k1])
        heights, valid = read_block(r0, int(cpos[0]), r1 - r0 + 1, width)
        h = np.ascontiguousarray(heights, np.float64)
        row_lo, row_hi = _cells_of(rpos[k0:k1 + 1], r1 - r0 + 1)
        _f_ranges_band(h, np.ascontiguousarray(valid, np.bool_), row_lo + k0, row_hi + k0, col_lo, col_hi,
                       fmin, fmax, fbad)
    return fmin, fmax, ~fbad


def hausdorff_bound(read_block: ReadBlock, rpos: npt.ArrayLike, cpos: npt.ArrayLike, vij: npt.ArrayLike,
                    vz: npt.ArrayLike, faces: npt.ArrayLike, cell_vertical: F64, cell_size: tuple[float, float],
                    radii: Sequence[int] = DEFAULT_RADII, cells_out: list[F64] | None = None) -> float:
    """Certified bound on the symmetric Hausdorff distance between the TIN and the full-resolution surface.

    Parameters
    ----------
    read_block
        ``read_block(row0, col0, nrows, ncols) -> (heights, valid)`` of the full-resolution raster.
    rpos, cpos
        Full-resolution indices of the tile's grid lines (rows, columns), increasing.
    vij
        (V, 2) TIN vertices as grid-line indices (row, column).
    vz
        (V,) vertex heights as stored (after quantisation).
    faces
        (M, 3) triangles.
    cell_vertical
        (len(rpos) - 1, len(cpos) - 1) the certifier's per-cell vertical error.
    cell_size
        Largest cell extent along x (columns) and y (rows), metres.
    radii
        Block radii tried, in cells.
    cells_out
        When given, the per-cell bound (len(rpos) - 1, len(cpos) - 1) is appended to it.

    Returns
    -------
    float
        The bound, metres (never above the vertical bound; no quantisation included).
    """
    from scipy import ndimage

    rpos_i, cpos_i = np.asarray(rpos, np.int64), np.asarray(cpos, np.int64)
    vij = np.asarray(vij, np.int64)
    fc = np.ascontiguousarray(faces, np.int64).reshape(-1, 3)
    vert = ndimage.maximum_filter(np.asarray(cell_vertical, np.float64), size=3, mode="nearest")
    if len(fc) == 0 or len(rpos_i) < 2 or len(cpos_i) < 2:
        return float(vert.max(initial=0.0))
    fmin, fmax, fok = f_ranges(read_block, rpos_i, cpos_i)
    cmin, cmax, cok = _c_ranges(rpos_i.astype(np.float64), cpos_i.astype(np.float64), vij[:, 0].copy(),
                                vij[:, 1].copy(), np.ascontiguousarray(vz, np.float64), fc)
    cok &= np.isfinite(cmin)
    # Points of C over a cell it does not fully cover, and points of F over partial cells: vertical only.
    best_cf = np.where(cok, np.inf, vert)
    best_fc = np.where(fok, np.inf, vert)
    diag = math.hypot(float(cell_size[0]), float(cell_size[1]))
    f_lo, f_hi = np.where(fok, fmin, 0.0), np.where(fok, fmax, 0.0)
    c_lo, c_hi = np.where(cok, cmin, 0.0), np.where(cok, cmax, 0.0)
    both = fok & cok  # blocks of such cells: F and C are both defined and continuous over all of them
    for r in sorted(set(int(v) for v in radii)):
        size = 2 * r + 1
        d = (r + 1) * diag
        block_bad = ndimage.maximum_filter(~both, size=size, mode="constant", cval=True)
        # C -> F: F's range over the block.
        fb_lo = ndimage.minimum_filter(f_lo, size=size, mode="nearest")
        fb_hi = ndimage.maximum_filter(f_hi, size=size, mode="nearest")
        gap = np.maximum(np.maximum(c_hi - fb_hi, fb_lo - c_lo), 0.0)
        cand = np.where(cok & ~block_bad, np.hypot(d, gap), np.inf)
        best_cf = np.minimum(best_cf, cand)
        # F -> C: C's range over the block.
        cb_lo = ndimage.minimum_filter(c_lo, size=size, mode="nearest")
        cb_hi = ndimage.maximum_filter(c_hi, size=size, mode="nearest")
        gap = np.maximum(np.maximum(f_hi - cb_hi, cb_lo - f_lo), 0.0)
        cand = np.where(fok & ~block_bad, np.hypot(d, gap), np.inf)
        best_fc = np.minimum(best_fc, cand)
    per_cell = np.maximum(np.minimum(best_cf, vert), np.minimum(best_fc, vert))
    if cells_out is not None:
        cells_out.append(per_cell)
    return float(per_cell.max(initial=0.0))


__all__ = ["DEFAULT_RADII", "f_ranges", "hausdorff_bound"]
