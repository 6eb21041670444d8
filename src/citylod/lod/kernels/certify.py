"""Exact vertical L∞ error of a TIN against the full-resolution height grid, evaluated block by block.

This is the certificate behind every ``geometricError`` the DSM builder writes (decision 3 of the design).

The full-resolution surface F is the grid of samples triangulated with a fixed diagonal per cell, from
sample (i, j) to (i+1, j+1). The TIN T is piecewise linear too, so T − F is linear on every face of the
overlay of the two triangulations, and its maximum absolute value is attained at a vertex of the overlay:
a grid sample, a TIN vertex (also a grid sample here), or a point where a TIN edge crosses a grid edge (a
row segment, a column segment or a cell diagonal). Evaluating at all of these gives the exact
``max |T − F|`` over the valid part of the domain, not a sampled estimate.

Why it bounds the symmetric Hausdorff distance: every point (x, y, T(x, y)) has the point (x, y, F(x, y)) of
the other surface within ``|T − F| ≤ ε`` and vice versa, over the common domain.

The grid arrives in blocks that overlap by one sample, so memory depends on the block size, not on the
raster or tile size. Written by hand because no library computes the exact overlay maximum; numba-compiled
(decision 4).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from numba import njit

from citylod.lod.kernels.aot import kernel
from citylod.lod.kernels.sort import counting_sort
from citylod.lod.kernels.tin_kernels import NO_NRT

_EPS = 1e-9

# The per-crossing helpers below take arrays and allocate none: compiled with ``_nrt=False`` (NO_NRT) so that
# a call does not incref and decref each array argument (see tin_kernels).


@njit(cache=True, nogil=True, **NO_NRT)
def _f_row(F, V, r, x):  # F along the row line r at fractional column x (global coords already local)
    j = int(math.floor(x))
    if j < 0 or j + 1 >= F.shape[1] or r < 0 or r >= F.shape[0]:
        return math.nan
    if not (V[r, j] and V[r, j + 1]):
        return math.nan
    f = x - j
    return F[r, j] * (1.0 - f) + F[r, j + 1] * f


@njit(cache=True, nogil=True, **NO_NRT)
def _f_col(F, V, y, c):
    i = int(math.floor(y))
    if i < 0 or i + 1 >= F.shape[0] or c < 0 or c >= F.shape[1]:
        return math.nan
    if not (V[i, c] and V[i + 1, c]):
        return math.nan
    f = y - i
    return F[i, c] * (1.0 - f) + F[i + 1, c] * f


@njit(cache=True, nogil=True, **NO_NRT)
def _f_diag(F, V, y, k):  # on the diagonal line row - col = k
    i = int(math.floor(y))
    j = i - k
    if i < 0 or i + 1 >= F.shape[0] or j < 0 or j + 1 >= F.shape[1]:
        return math.nan
    if not (V[i, j] and V[i + 1, j + 1]):
        return math.nan
    f = y - i
    return F[i, j] * (1.0 - f) + F[i + 1, j + 1] * f


@njit(cache=True, nogil=True, **NO_NRT)
def _record(err, y, x, cell_err, tr0, tc0, stride, best):
    # attribute an error to the level cell containing (y, x) (global full-resolution coordinates)
    ci = int(math.floor((y - tr0) / stride))
    cj = int(math.floor((x - tc0) / stride))
    ci = min(max(ci, 0), cell_err.shape[0] - 1)
    cj = min(max(cj, 0), cell_err.shape[1] - 1)
    if err > cell_err[ci, cj]:
        cell_err[ci, cj] = err
    if err > best[0]:
        best[0] = err
        best[1] = y
        best[2] = x


@njit(cache=True, nogil=True, **NO_NRT)
def _cross(err, y, x, cell_err, tr0, tc0, stride, best, track):
    if track:
        _record(err, y, x, cell_err, tr0, tc0, stride, best)
    elif err > best[0]:
        best[0] = err
        best[1] = y
        best[2] = x


@njit(cache=True, nogil=True)
def certify_block(F, V, r0, c0, vr, vc, vz, faces, edges, cell_err, tr0, tc0, stride, best, track):
    """Update ``best`` = [max error, row, col] and ``cell_err`` with the exact error inside one block.

    Parameters
    ----------
    F, V : (bh, bw) float64, bool
        Full-resolution heights and validity of the block whose sample (0, 0) is global (r0, c0).
    vr, vc, vz : (N,) float64
        TIN vertex rows, columns (global full-resolution sample coordinates) and heights.
    faces : (M, 3) int64
    edges : (K, 2) int64
        The faces' edges, each once (an edge shared by two faces has the same crossings in both).
    cell_err : (h, w) float64
        Per-level-cell maximum, updated in place when ``track``; level cell (a, b) spans global rows
        ``tr0 + a·stride`` to ``tr0 + (a+1)·stride``.
    """
    bh, bw = F.shape
    rmax_b = r0 + bh - 1
    cmax_b = c0 + bw - 1
    # samples inside each face, scanline by scanline
    for t in range(faces.shape[0]):
        a, b, c = faces[t, 0], faces[t, 1], faces[t, 2]
        ys = (vr[a], vr[b], vr[c])
        xs = (vc[a], vc[b], vc[c])
        zs = (vz[a], vz[b], vz[c])
        ymin = min(ys[0], min(ys[1], ys[2]))
        ymax = max(ys[0], max(ys[1], ys[2]))
        xmin = min(xs[0], min(xs[1], xs[2]))
        xmax = max(xs[0], max(xs[1], xs[2]))
        if ymax < r0 or ymin > rmax_b or xmax < c0 or xmin > cmax_b:
            continue
        # plane z = pa*y + pb*x + pc
        det = (ys[1] - ys[0]) * (xs[2] - xs[0]) - (ys[2] - ys[0]) * (xs[1] - xs[0])
        if abs(det) <= 1e-12:
            continue
        pa = ((zs[1] - zs[0]) * (xs[2] - xs[0]) - (zs[2] - zs[0]) * (xs[1] - xs[0])) / det
        pb = ((ys[1] - ys[0]) * (zs[2] - zs[0]) - (ys[2] - ys[0]) * (zs[1] - zs[0])) / det
        pc = zs[0] - pa * ys[0] - pb * xs[0]
        r_lo = max(int(math.ceil(ymin - _EPS)), r0)
        r_hi = min(int(math.floor(ymax + _EPS)), rmax_b)
        for r in range(r_lo, r_hi + 1):
            lo = math.inf
            hi = -math.inf
            for e in range(3):
                y1, x1 = ys[e], xs[e]
                y2, x2 = ys[(e + 1) % 3], xs[(e + 1) % 3]
                if (y1 - _EPS <= r <= y2 + _EPS) or (y2 - _EPS <= r <= y1 + _EPS):
                    if abs(y2 - y1) < 1e-12:
                        lo = min(lo, min(x1, x2))
                        hi = max(hi, max(x1, x2))
                    else:
                        x = x1 + (r - y1) * (x2 - x1) / (y2 - y1)
                        lo = min(lo, x)
                        hi = max(hi, x)
            c_lo = max(int(math.ceil(lo - _EPS)), c0)
            c_hi = min(int(math.floor(hi + _EPS)), cmax_b)
            if c_lo > c_hi:
                continue
            fr = F[r - r0]
            vrow = V[r - r0]
            base = pa * r + pc
            if track:
                ci = int(math.floor((r - tr0) / stride))
                ci = min(max(ci, 0), cell_err.shape[0] - 1)
                ncol = cell_err.shape[1]
                cc = c_lo
                while cc <= c_hi:
                    # the run of samples in one level cell (tc0 and stride are whole numbers)
                    cj = min(max(int(math.floor((cc - tc0) / stride)), 0), ncol - 1)
                    seg_end = c_hi if cj == ncol - 1 else min(c_hi, int(tc0 + (cj + 1) * stride) - 1)
                    m = -1.0
                    mc = cc
                    for q in range(cc, seg_end + 1):
                        if vrow[q - c0]:
                            err = abs(base + pb * q - fr[q - c0])
                            if err > m:
                                m = err
                                mc = q
                    if m > best[0]:
                        best[0] = m
                        best[1] = float(r)
                        best[2] = float(mc)
                    if m > cell_err[ci, cj]:
                        cell_err[ci, cj] = m
                    cc = seg_end + 1
            else:
                for cc in range(c_lo, c_hi + 1):
                    if vrow[cc - c0]:
                        err = abs(base + pb * cc - fr[cc - c0])
                        if err > best[0]:
                            best[0] = err
                            best[1] = float(r)
                            best[2] = float(cc)
    # crossings of the TIN's edges with grid rows, columns and diagonals, once per edge
    for k_e in range(edges.shape[0]):
        a, b = edges[k_e, 0], edges[k_e, 1]
        y1, x1, z1 = vr[a], vc[a], vz[a]
        y2, x2, z2 = vr[b], vc[b], vz[b]
        if max(y1, y2) < r0 or min(y1, y2) > rmax_b or max(x1, x2) < c0 or min(x1, x2) > cmax_b:
            continue
        dy = y2 - y1
        dx = x2 - x1
        if abs(dy) > 1e-12:
            k_lo = int(math.ceil(min(y1, y2)))
            k_hi = int(math.floor(max(y1, y2)))
            for r in range(max(k_lo, r0), min(k_hi, rmax_b) + 1):
                s = (r - y1) / dy
                x = x1 + s * dx
                if x < c0 or x > cmax_b:
                    continue
                f = _f_row(F, V, r - r0, x - c0)
                if not math.isnan(f):
                    _cross(abs(z1 + s * (z2 - z1) - f), float(r), x, cell_err, tr0, tc0, stride, best, track)
        if abs(dx) > 1e-12:
            k_lo = int(math.ceil(min(x1, x2)))
            k_hi = int(math.floor(max(x1, x2)))
            for cc in range(max(k_lo, c0), min(k_hi, cmax_b) + 1):
                s = (cc - x1) / dx
                y = y1 + s * dy
                if y < r0 or y > rmax_b:
                    continue
                f = _f_col(F, V, y - r0, cc - c0)
                if not math.isnan(f):
                    _cross(abs(z1 + s * (z2 - z1) - f), y, float(cc), cell_err, tr0, tc0, stride, best, track)
        d1 = y1 - x1
        d2 = y2 - x2
        if abs(d2 - d1) > 1e-12:
            k_lo = int(math.ceil(min(d1, d2)))
            k_hi = int(math.floor(max(d1, d2)))
            for k in range(k_lo, k_hi + 1):
                s = (k - d1) / (d2 - d1)
                y = y1 + s * dy
                x = x1 + s * dx
                if y < r0 or y > rmax_b or x < c0 or x > cmax_b:
                    continue
                # local diagonal index: (y - r0) - (x - c0) = k - r0 + c0
                f = _f_diag(F, V, y - r0, k - r0 + c0)
                if not math.isnan(f):
                    _cross(abs(z1 + s * (z2 - z1) - f), y, x, cell_err, tr0, tc0, stride, best, track)


@njit(cache=True, nogil=True)
def _edge_table(faces, nv):
    """For the directed edges of ``faces`` (edge k of face t at ``k·F + t``, from corner k to corner k+1):
    whether each is the first occurrence of its undirected edge, and how many faces share that edge.
    Linear time: edges are bucketed by their smaller vertex and matched with a stamp array."""
    nf = faces.shape[0]
    m = 3 * nf
    lo = np.empty(m, np.int64)
    hi = np.empty(m, np.int64)
    for k in range(3):
        for t in range(nf):
            a = faces[t, k]
            b = faces[t, (k + 1) % 3]
            lo[k * nf + t] = min(a, b)
            hi[k * nf + t] = max(a, b)
    order, start = counting_sort(lo, nv)  # edges bucketed by their smaller vertex
    first = np.zeros(m, np.bool_)
    count = np.zeros(m, np.int64)
    mark = np.full(nv, -1, np.int64)
    slot = np.zeros(nv, np.int64)
    for v in range(nv):
        for q in range(start[v], start[v + 1]):
            i = order[q]
            h = hi[i]
            if mark[h] != v:
                mark[h] = v
                slot[h] = i
                first[i] = True
            count[slot[h]] += 1
        for q in range(start[v], start[v + 1]):
            i = order[q]
            count[i] = count[slot[hi[i]]]
    return first, count


@njit(cache=True, nogil=True)
def skirt_strip(local: np.ndarray, faces: np.ndarray, vr: np.ndarray, vc: np.ndarray, side_ax: np.ndarray,
                side_line: np.ndarray, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The DSM builder's skirts (`citylod.lod.build.dsm._add_skirts`) in one compiled pass: below every edge of
    ``faces`` that belongs to one face and lies on a side (grid line ``side_line[s]`` of axis ``side_ax[s]``,
    0: a row of ``vr``, 1: a column of ``vc``), a vertical strip ``depth[s]`` deep. Each side's strip has
    bottom vertices of its own, so at a corner a shallow side does not slope down to its neighbour's depth.
    Edges are taken in `edge_table`'s order (edge 0 of every face, then 1, then 2). Returns positions
    (float32, the skirt vertices after ``local``), faces (the given ones, then every strip's first triangle,
    then every strip's second), the skirt mask per face and the surface vertex each skirt vertex hangs from
    (sorted)."""
    nf = faces.shape[0]
    nv = local.shape[0]
    nsd = side_ax.shape[0]
    sel = np.empty(3 * nf, np.int64)
    sel_side = np.empty(3 * nf, np.int64)
    ns = 0
    is_src = np.zeros((nv, max(nsd, 1)), np.bool_)
    # An edge on a side line has faces on one side of it only (the tile ends there), so it belongs to one
    # face: no edge table is needed to find the mesh border there (building one was 0.2 ms a leaf tile).
    # Its two vertices are distinct grid points, so it lies on one side at most.
    for k in range(3):
        for t in range(nf):
            i = k * nf + t
            a = faces[t, k]
            b = faces[t, (k + 1) % 3]
            for s in range(nsd):
                if side_ax[s] == 0:
                    here = vr[a] == side_line[s] and vr[b] == side_line[s]
                else:
                    here = vc[a] == side_line[s] and vc[b] == side_line[s]
                if here:
                    sel[ns] = i
                    sel_side[ns] = s
                    ns += 1
                    is_src[a, s] = True
                    is_src[b, s] = True
                    break
    dup = np.full((nv, max(nsd, 1)), -1, np.int64)
    nsrc = 0
    for v in range(nv):
        for s in range(nsd):
            if is_src[v, s]:
                dup[v, s] = nv + nsrc
                nsrc += 1
    sources = np.empty(nsrc, np.int64)
    positions = np.empty((nv + nsrc, 3), np.float32)
    positions[:nv] = local
    for v in range(nv):
        for s in range(nsd):
            if is_src[v, s]:
                j = dup[v, s] - nv
                sources[j] = v
                positions[nv + j, 0] = local[v, 0]
                positions[nv + j, 1] = local[v, 1]
                positions[nv + j, 2] = local[v, 2] - np.float32(depth[s])
    faces_all = np.empty((nf + 2 * ns, 3), np.int64)
    faces_all[:nf] = faces
    for q in range(ns):
        i = sel[q]
        s = sel_side[q]
        k = i // nf
        t = i - k * nf
        a = faces[t, k]
        b = faces[t, (k + 1) % 3]
        # The surface runs a->b counter-clockwise seen from above, so outside is to the right: these two
        # triangles are counter-clockwise seen from outside.
        faces_all[nf + q, 0], faces_all[nf + q, 1], faces_all[nf + q, 2] = b, a, dup[a, s]
        faces_all[nf + ns + q, 0], faces_all[nf + ns + q, 1], faces_all[nf + ns + q, 2] = b, dup[a, s], dup[b, s]
    skirt = np.zeros(nf + 2 * ns, np.bool_)
    skirt[nf:] = True
    return positions, faces_all, skirt, sources


def edge_table(faces: npt.NDArray[np.int64], n_vertices: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Directed edges (3F, 2) of ``faces`` (all of edge 0, then 1, then 2), whether each is the first of its
    undirected edge, and how many faces share it (1 on the border of the mesh)."""
    f = np.ascontiguousarray(faces, dtype=np.int64)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    if len(f) == 0:
        return e, np.zeros(0, bool), np.zeros(0, np.int64)
    first, count = kernel(_edge_table, f, max(int(n_vertices), int(f.max()) + 1))
    return e, first, count


def unique_edges(faces: npt.NDArray[np.int64]) -> npt.NDArray[np.int64]:
    """(K, 2) the undirected edges of ``faces``, each once, as (smaller, larger) vertex index.

    The fixed direction makes an edge's crossings evaluate to the same numbers whichever faces are
    certified together, so maxima over subsets of faces combine exactly (see the DSM builder's stage 2).
    """
    e, first, _ = edge_table(faces, 0)
    u = e[first]
    return np.ascontiguousarray(np.column_stack([u.min(axis=1), u.max(axis=1)]))


def certify(read_block, footprint: tuple[int, int, int, int], vr: npt.NDArray[np.float64],
            vc: npt.NDArray[np.float64], vz: npt.NDArray[np.float64], faces: npt.NDArray[np.int64],
            cells: tuple[int, int], stride: int, block: int = 1024,
            per_cell: bool = True) -> tuple[float, np.ndarray, tuple[float, float]]:
    """Exact max |T − F| over a footprint, read in overlapping blocks.

    Parameters
    ----------
    read_block : callable
        ``read_block(row0, col0, nrows, ncols) -> (heights, valid)`` in full-resolution samples.
    footprint : (row0, col0, row1, col1)
        Inclusive global sample range covered by the tile.
    cells : (h, w)
        Level cells of the tile, for the per-cell error map.
    per_cell : bool
        Keep the per-cell map (False leaves it zero, a little faster, same maximum).

    Returns
    -------
    (max error, per-cell error (h, w) float64, (row, col) of the maximum)
    """
    r0, c0, r1, c1 = footprint
    cell_err = np.zeros(cells, np.float64)
    best = np.zeros(3, np.float64)
    if len(faces) == 0:
        return 0.0, cell_err, (0.0, 0.0)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    edges = unique_edges(f)
    vr, vc, vz = (np.ascontiguousarray(a, dtype=np.float64) for a in (vr, vc, vz))
    # Blocks overlap by one sample, so the last block starting before r1 (c1) already reaches it.
    for br in range(r0, max(r1, r0 + 1), block):
        for bc in range(c0, max(c1, c0 + 1), block):
            nr = min(block + 1, r1 - br + 1)  # one sample of overlap keeps grid edges whole
            nc = min(block + 1, c1 - bc + 1)
            heights, valid = read_block(br, bc, nr, nc)
            if not valid.any():
                continue
            kernel(certify_block, heights, valid, br, bc, vr, vc, vz, f, edges, cell_err, float(r0), float(c0),
                   float(stride), best, bool(per_cell))
    return float(best[0]), cell_err, (float(best[1]), float(best[2]))


@njit(cache=True, nogil=True)
def _grid_sample_error(F, V, br, bc, rpos, cpos, gz, gv):  # pragma: no cover - compiled
    nr, nc = F.shape
    worst = 0.0
    for a in range(len(rpos) - 1):
        ra, rb = rpos[a], rpos[a + 1]
        if rb < br or ra > br + nr - 1:
            continue
        for b in range(len(cpos) - 1):
            ca, cb = cpos[b], cpos[b + 1]
            if cb < bc or ca > bc + nc - 1:
                continue
            if not (gv[a, b] and gv[a, b + 1] and gv[a + 1, b] and gv[a + 1, b + 1]):
                continue
            z00, z01, z10, z11 = gz[a, b], gz[a, b + 1], gz[a + 1, b], gz[a + 1, b + 1]
            hr, hc = float(rb - ra), float(cb - ca)
            for r in range(max(ra, br), min(rb, br + nr - 1) + 1):
                u = (r - ra) / hr
                for c in range(max(ca, bc), min(cb, bc + nc - 1) + 1):
                    if not V[r - br, c - bc]:
                        continue
                    v = (c - ca) / hc
                    if u >= v:  # below the (a, b)–(a+1, b+1) diagonal: triangle 00, 10, 11
                        t = z00 + u * (z10 - z00) + v * (z11 - z10)
                    else:  # triangle 00, 01, 11
                        t = z00 + v * (z01 - z00) + u * (z11 - z01)
                    d = abs(F[r - br, c - bc] - t)
                    if d > worst:
                        worst = d
    return worst


def grid_error_lower_bound(read_block, footprint: tuple[int, int, int, int], rpos: npt.NDArray[np.int64],
                           cpos: npt.NDArray[np.int64], gz: npt.NDArray[np.float64], gv: npt.NDArray[np.bool_],
                           block: int = 1024) -> float:
    """max |G − F| over the full-resolution samples, G the tile's full grid (every valid sample of rows
    ``rpos`` × columns ``cpos`` a vertex, cells split by their (a, b)–(a+1, b+1) diagonal).

    A lower bound of the full grid's certified error (crossings are not visited; where the grid's cells
    are square, its diagonals lie on the raster's own and the bound is exact). One pass over the samples,
    ≈ 25× cheaper than certifying the full grid's 33 k faces: what a coarse tile's build uses to tell that
    its target is out of reach on its grid before triangulating towards it.
    """
    r0, c0, r1, c1 = footprint
    rp, cp = np.ascontiguousarray(rpos, np.int64), np.ascontiguousarray(cpos, np.int64)
    z, v = np.ascontiguousarray(gz, np.float64), np.ascontiguousarray(gv, np.bool_)
    worst = 0.0
    for br in range(r0, max(r1, r0 + 1), block):
        for bc in range(c0, max(c1, c0 + 1), block):
            nr, nc = min(block + 1, r1 - br + 1), min(block + 1, c1 - bc + 1)
            heights, valid = read_block(br, bc, nr, nc)
            if valid.any():
                worst = max(worst, kernel(_grid_sample_error, np.ascontiguousarray(heights, np.float64),
                                          np.ascontiguousarray(valid), br, bc, rp, cp, z, v))
    return float(worst)
