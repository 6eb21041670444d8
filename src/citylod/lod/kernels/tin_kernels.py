"""Compiled kernels behind `citylod.lod.kernels.tin`: greedy-insertion Delaunay TIN with an exact vertical bound,
then bounded vertex removal (`_decimate`).

The public API, its contracts and the reasoning about correctness live in `citylod.lod.kernels.tin`; this
module holds only the numba kernels. It must not import anything but numpy, numba,
`citylod.core.jit` (which only makes numba's start cheaper) and the point–triangle distance of
`citylod.lod.kernels.distance`.

Layout of the triangulation (after mapbox/delatin, itself Garland & Heckbert 1995, algorithm III):
triangle ``t`` owns half-edges ``3t, 3t+1, 3t+2``; ``tri[e]`` is the vertex where half-edge ``e``
starts; ``half[e]`` is the twin half-edge or -1 on the hull. Vertices are grid samples with integer
coordinates ``x = col``, ``y = row``. Every triangle has ``_orient(a, b, c) > 0``, which with rows
growing downwards is counter-clockwise seen from above in (x east, y north).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

from citylod.core.jit import defer_blas_probe
from citylod.lod.kernels.distance import point_triangle_sq

defer_blas_probe()  # before any kernel loads: numba starts without importing scipy.linalg

# Helpers that take arrays but allocate, return and keep none are compiled with ``_nrt=False``. Otherwise
# numba increfs every array argument of a (non-inlined) function on entry and decrefs it on exit, each an
# atomic operation behind a call, and with up to a dozen arrays per call and several calls per inserted
# vertex that was a large share of the leaf kernels' time. Inlining the helpers instead doubled the cold
# compile. The caller holds the references for the duration of the call.

NO_NRT: dict[str, Any] = {"_nrt": False}  # (a keyword numba's type stubs do not list)

# Indices into the int64 counter array ``cnt`` shared by the kernels (numba has no mutable scalars).
_NTRI, _NPEND, _NHEAP, _NVERT, _ERRORS_ON, _STUCK, _NBORDER_ADDED = 0, 1, 2, 3, 4, 5, 6


# --------------------------------------------------------------------------------------------------
# exact predicates on integer coordinates
# --------------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True, inline="always")
def _orient(ax: int, ay: int, bx: int, by: int, cx: int, cy: int) -> int:
    # Delatin's sign convention; exact in int64 for any grid below 2**31 samples a side.
    return (bx - cx) * (ay - cy) - (by - cy) * (ax - cx)


@njit(cache=True, nogil=True, inline="always")
def _det3(dx: int, dy: int, ap: int, ex: int, ey: int, bp: int, fx: int, fy: int, cp: int) -> int:
    return dx * (ey * cp - bp * fy) - dy * (ex * cp - bp * fx) + ap * (ex * fy - ey * fx)


@njit(cache=True, nogil=True, **NO_NRT)
def _in_circle(ax: int, ay: int, bx: int, by: int, cx: int, cy: int, px: int, py: int) -> bool:
    """Whether p lies inside the circumcircle of (a, b, c) (``_orient(a, b, c) > 0``), ties perturbed.

    Exact in int64 for coordinates below 2**15. Lattice points are often cocircular (every grid cell),
    so ties are broken by a symbolic perturbation: Delaunay of the points mapped by
    ``I - e1 u u^T - e2 e_x e_x^T`` with u = (1, 1)/sqrt(2) and 0 < e2 << e1 -> 0. That is a regular
    triangulation under a strictly convex quadratic lifting, hence consistent (flips terminate and the
    result is unique), and it makes the Delaunay triangulation of a full grid use the diagonal
    (i, j)-(i+1, j+1) of every cell: the very surface the bound is measured against.
    """
    dx = ax - px
    dy = ay - py
    ex = bx - px
    ey = by - py
    fx = cx - px
    fy = cy - py
    d = _det3(dx, dy, dx * dx + dy * dy, ex, ey, ex * ex + ey * ey, fx, fy, fx * fx + fy * fy)
    if d != 0:
        return d < 0
    # lifted minus e1 * 2 * det[q, qx*qy] (the qx^2 + qy^2 parts cancel because d == 0)
    d = _det3(dx, dy, dx * dy, ex, ey, ex * ey, fx, fy, fx * fy)
    if d != 0:
        return d > 0
    d = _det3(dx, dy, dx * dx, ex, ey, ex * ex, fx, fy, fx * fx)
    return d > 0


# --------------------------------------------------------------------------------------------------
# max-heap of triangles keyed by their error
# --------------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True, **NO_NRT)
def _heap_up(heap: np.ndarray, hpos: np.ndarray, terr: np.ndarray, i: int) -> None:
    t = heap[i]
    e = terr[t]
    while i > 0:
        p = (i - 1) >> 1
        tp = heap[p]
        if terr[tp] >= e:
            break
        heap[i] = tp
        hpos[tp] = i
        i = p
    heap[i] = t
    hpos[t] = i


@njit(cache=True, nogil=True, **NO_NRT)
def _heap_down(heap: np.ndarray, hpos: np.ndarray, terr: np.ndarray, i: int, n: int) -> None:
    t = heap[i]
    e = terr[t]
    while True:
        c = 2 * i + 1
        if c >= n:
            break
        if c + 1 < n and terr[heap[c + 1]] > terr[heap[c]]:
            c += 1
        tc = heap[c]
        if terr[tc] <= e:
            break
        heap[i] = tc
        hpos[tc] = i
        i = c
    heap[i] = t
    hpos[t] = i


@njit(cache=True, nogil=True, **NO_NRT)
def _heap_push(heap: np.ndarray, hpos: np.ndarray, terr: np.ndarray, cnt: np.ndarray, t: int) -> None:
    i = cnt[_NHEAP]
    cnt[_NHEAP] = i + 1
    heap[i] = t
    hpos[t] = i
    _heap_up(heap, hpos, terr, i)


@njit(cache=True, nogil=True, **NO_NRT)
def _heap_remove(heap: np.ndarray, hpos: np.ndarray, terr: np.ndarray, cnt: np.ndarray, t: int) -> None:
    i = hpos[t]
    hpos[t] = -1
    n = cnt[_NHEAP] - 1
    cnt[_NHEAP] = n
    if i != n:
        last = heap[n]
        heap[i] = last
        hpos[last] = i
        _heap_down(heap, hpos, terr, i, n)
        _heap_up(heap, hpos, terr, hpos[last])


# --------------------------------------------------------------------------------------------------
# error of one triangle against the grid surface: samples and edge crossings
# --------------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True, inline="always")
def _is_border(s: int, H: int, W: int) -> bool:
    r = s // W
    c = s - r * W
    return r == 0 or c == 0 or r == H - 1 or c == W - 1


@njit(cache=True, nogil=True, **NO_NRT)
def _pick(
    ss: np.ndarray,
    n: int,
    h: np.ndarray,
    vid: np.ndarray,
    z0: float,
    x0: int,
    y0: int,
    a1: int,
    b1: int,
    c1: int,
    a2: int,
    b2: int,
    c2: int,
    g1: float,
    g2: float,
) -> int:
    """The best insertion candidate among samples ``ss[:n]``: not yet a vertex, interior before border.

    Border samples are the last resort so that the tile border keeps its 1D-simplified vertices
    whenever the 2D bound can be met without touching it. Among equals, the sample where the
    triangle's plane is farthest from the data wins (Garland & Heckbert's greedy criterion).
    """
    H, W = h.shape
    best = -1
    best_score = -1.0
    for k in range(n):
        s = ss[k]
        if s < 0 or vid[s] >= 0:
            continue
        y = s // W
        x = s - y * W
        e = abs((z0 - h[y, x]) + g1 * (a1 * x + b1 * y + c1) + g2 * (a2 * x + b2 * y + c2))
        if not _is_border(s, H, W):
            e += 1e300
        if e > best_score:
            best_score = e
            best = s
    return best


@njit(cache=True, nogil=True, **NO_NRT)
def _edge_error(
    h: np.ndarray, px: int, py: int, qx: int, qy: int, info: np.ndarray, o: int, stop: float
) -> float:
    """Max |TIN - grid surface| over the crossings of TIN edge p-q with grid lines (samples excluded).

    Columns x = m cross the vertical grid edge (fy, m)-(fy+1, m), rows y = m the horizontal one
    (m, fx)-(m, fx+1), diagonals x - y = m the cell diagonal (fy, fy+m)-(fy+1, fy+m+1); the crossing
    point is stepped along in integers, without divisions. Writes the worst crossing's grid edge (its
    two samples) and the cell(s) beside it (-1: none) to ``info[o:o + 4]``; symmetric in p and q.
    Returns early, with an error above ``stop``, as soon as one is found.
    """
    H, W = h.shape
    zp = h[py, px]
    zq = h[qy, qx]
    best = 0.0
    info[o] = -1
    info[o + 1] = -1
    info[o + 2] = -1
    info[o + 3] = -1
    # columns x = m: the crossed grid edge is vertical, (fy, m)-(fy+1, m)
    if px != qx:
        if px < qx:
            ax, ay, az, bx, by, bz = px, py, zp, qx, qy, zq
        else:
            ax, ay, az, bx, by, bz = qx, qy, zq, px, py, zp
        d = bx - ax
        dy = by - ay
        # y = ay + (m - ax) dy / d = fy + rem / d, stepped without divisions
        fy = ay
        rem = 0
        for m in range(ax + 1, bx):
            rem += dy
            while rem >= d:
                rem -= d
                fy += 1
            while rem < 0:
                rem += d
                fy -= 1
            if rem == 0:
                continue  # a grid sample: the triangle's sample scan counts it
            f = rem / d
            t = (m - ax) / d
            ga = h[fy, m]
            e = abs((az - ga) + t * (bz - az) - f * (h[fy + 1, m] - ga))
            if e > best:
                best = e
                if e > stop:
                    return e
                info[o] = fy * W + m
                info[o + 1] = fy * W + m + W
                info[o + 2] = fy * (W - 1) + m - 1
                info[o + 3] = fy * (W - 1) + m if m < W - 1 else -1
    # rows y = m: horizontal grid edge (m, fx)-(m, fx+1)
    if py != qy:
        if py < qy:
            ax, ay, az, bx, by, bz = px, py, zp, qx, qy, zq
        else:
            ax, ay, az, bx, by, bz = qx, qy, zq, px, py, zp
        d = by - ay
        dx = bx - ax
        fx = ax
        rem = 0
        for m in range(ay + 1, by):
            rem += dx
            while rem >= d:
                rem -= d
                fx += 1
            while rem < 0:
                rem += d
                fx -= 1
            if rem == 0:
                continue
            f = rem / d
            t = (m - ay) / d
            ga = h[m, fx]
            e = abs((az - ga) + t * (bz - az) - f * (h[m, fx + 1] - ga))
            if e > best:
                best = e
                if e > stop:
                    return e
                info[o] = m * W + fx
                info[o + 1] = m * W + fx + 1
                info[o + 2] = (m - 1) * (W - 1) + fx
                info[o + 3] = m * (W - 1) + fx if m < H - 1 else -1
    # diagonals x - y = m: grid edge (fy, fy+m)-(fy+1, fy+m+1), inside one cell
    sp = px - py
    sq = qx - qy
    if sp != sq:
        if sp < sq:
            ax, ay, az, bx, by, bz, sa, sb = px, py, zp, qx, qy, zq, sp, sq
        else:
            ax, ay, az, bx, by, bz, sa, sb = qx, qy, zq, px, py, zp, sq, sp
        d = sb - sa
        dy = by - ay
        fy = ay
        rem = 0
        for m in range(sa + 1, sb):
            rem += dy
            while rem >= d:
                rem -= d
                fy += 1
            while rem < 0:
                rem += d
                fy -= 1
            if rem == 0:
                continue
            f = rem / d
            t = (m - sa) / d
            ga = h[fy, fy + m]
            e = abs((az - ga) + t * (bz - az) - f * (h[fy + 1, fy + m + 1] - ga))
            if e > best:
                best = e
                if e > stop:
                    return e
                info[o] = fy * W + fy + m
                info[o + 1] = fy * W + fy + m + W + 1
                info[o + 2] = fy * (W - 1) + fy + m
                info[o + 3] = -1
    return best


@njit(cache=True, nogil=True, **NO_NRT)
def _point_error_3d(h: np.ndarray, cellvalid: np.ndarray, x: float, y: float, zr: float, zt: float,
                    t0x: float, t0y: float, t0z: float, t1x: float, t1y: float, t1z: float, t2x: float, t2y: float, t2z: float, sx: float, sy: float, tol: float, best: float) -> float:
    """3D error at one evaluation point (grid position x = column, y = row, raster height ``zr``, TIN height
    ``zt``) of a TIN triangle (``t0x``..``t2z``, in metres): the larger of dist(raster point, triangle) and
    dist(TIN point, grid surface), the latter searched over the grid cells within ``tol`` horizontally, in
    rings nearest first (a cell farther away is farther than ``tol`` in 3D too, so "> tol" is decided exactly;
    the value returned above it is the nearest cell's found, an upper bound). Both are at most the vertical error |zt − zr|, which is
    returned where nothing closer is found. ``best``: a result at most this is not needed exactly."""
    e = abs(zt - zr)
    X = x * sx
    Y = y * sy
    d1 = math.sqrt(point_triangle_sq(X, Y, zr, t0x, t0y, t0z, t1x, t1y, t1z, t2x, t2y, t2z))
    if d1 > tol and d1 > best:
        return min(d1, e)
    H, W = h.shape
    # rings of cells around the point's, nearest first: a cell of ring r is at least (r − 1)·min(sx, sy) away
    # horizontally, so the search stops at the first ring farther than ``tol`` or than the nearest cell found
    ci = min(max(int(math.floor(y)), 0), H - 2)
    cj = min(max(int(math.floor(x)), 0), W - 2)
    step = min(sx, sy)
    d2 = e * e
    lim = max(tol, best)
    lim *= lim
    r = 0
    while True:
        gap = max(r - 1, 0) * step
        if gap > tol or gap * gap >= d2 or (r > ci and r > cj and r > H - 2 - ci and r > W - 2 - cj):
            break
        for i in range(ci - r, ci + r + 1):
            if i < 0 or i > H - 2:
                continue
            edge = i == ci - r or i == ci + r
            j = cj - r
            while j <= cj + r:
                if 0 <= j <= W - 2 and cellvalid[i, j]:
                    xa = j * sx
                    xb = xa + sx
                    ya = i * sy
                    yb = ya + sy
                    za, zb, zc, zd = h[i, j], h[i, j + 1], h[i + 1, j], h[i + 1, j + 1]
                    d = point_triangle_sq(X, Y, zt, xa, ya, za, xa, yb, zc, xb, yb, zd)  # (i,j),(i+1,j),(i+1,j+1)
                    if d < d2:
                        d2 = d
                    d = point_triangle_sq(X, Y, zt, xa, ya, za, xb, ya, zb, xb, yb, zd)  # (i,j),(i,j+1),(i+1,j+1)
                    if d < d2:
                        d2 = d
                    if d2 <= lim:
                        return max(d1, math.sqrt(d2))
                j += 1 if (edge or r == 0) else 2 * r
        r += 1
    return max(d1, math.sqrt(d2))


@njit(cache=True, nogil=True, **NO_NRT)
def _edge_error_3d(
    h: np.ndarray, cellvalid: np.ndarray, px: int, py: int, qx: int, qy: int, info: np.ndarray, o: int,
    t0x: float, t0y: float, t0z: float, t1x: float, t1y: float, t1z: float, t2x: float, t2y: float, t2z: float,
    sx: float, sy: float, tol: float
) -> float:
    """`_edge_error` in 3D (``sx``, ``sy``: metres per column and row; ``t0x``..``t2z``: the triangle's
    vertices in metres): a crossing whose vertical error exceeds ``tol`` is charged `_point_error_3d` instead, the larger
    of the raster point's distance to the triangle and the TIN point's distance to the grid surface nearby."""
    H, W = h.shape
    zp = h[py, px]
    zq = h[qy, qx]
    best = 0.0
    info[o] = -1
    info[o + 1] = -1
    info[o + 2] = -1
    info[o + 3] = -1
    # columns x = m: the crossed grid edge is vertical, (fy, m)-(fy+1, m)
    if px != qx:
        if px < qx:
            ax, ay, az, bx, by, bz = px, py, zp, qx, qy, zq
        else:
            ax, ay, az, bx, by, bz = qx, qy, zq, px, py, zp
        d = bx - ax
        dy = by - ay
        # y = ay + (m - ax) dy / d = fy + rem / d, stepped without divisions
        fy = ay
        rem = 0
        for m in range(ax + 1, bx):
            rem += dy
            while rem >= d:
                rem -= d
                fy += 1
            while rem < 0:
                rem += d
                fy -= 1
            if rem == 0:
                continue  # a grid sample: the triangle's sample scan counts it
            f = rem / d
            t = (m - ax) / d
            ga = h[fy, m]
            zr = ga + f * (h[fy + 1, m] - ga)
            e = abs((az - zr) + t * (bz - az))
            if e > best and e > tol:
                e = _point_error_3d(h, cellvalid, m, fy + f, zr, az + t * (bz - az), t0x, t0y, t0z, t1x, t1y, t1z, t2x, t2y, t2z, sx, sy, tol, best)
            if e > best:
                best = e
                info[o] = fy * W + m
                info[o + 1] = fy * W + m + W
                info[o + 2] = fy * (W - 1) + m - 1
                info[o + 3] = fy * (W - 1) + m if m < W - 1 else -1
    # rows y = m: horizontal grid edge (m, fx)-(m, fx+1)
    if py != qy:
        if py < qy:
            ax, ay, az, bx, by, bz = px, py, zp, qx, qy, zq
        else:
            ax, ay, az, bx, by, bz = qx, qy, zq, px, py, zp
        d = by - ay
        dx = bx - ax
        fx = ax
        rem = 0
        for m in range(ay + 1, by):
            rem += dx
            while rem >= d:
                rem -= d
                fx += 1
            while rem < 0:
                rem += d
                fx -= 1
            if rem == 0:
                continue
            f = rem / d
            t = (m - ay) / d
            ga = h[m, fx]
            zr = ga + f * (h[m, fx + 1] - ga)
            e = abs((az - zr) + t * (bz - az))
            if e > best and e > tol:
                e = _point_error_3d(h, cellvalid, fx + f, m, zr, az + t * (bz - az), t0x, t0y, t0z, t1x, t1y, t1z, t2x, t2y, t2z, sx, sy, tol, best)
            if e > best:
                best = e
                info[o] = m * W + fx
                info[o + 1] = m * W + fx + 1
                info[o + 2] = (m - 1) * (W - 1) + fx
                info[o + 3] = m * (W - 1) + fx if m < H - 1 else -1
    # diagonals x - y = m: grid edge (fy, fy+m)-(fy+1, fy+m+1), inside one cell
    sp = px - py
    sq = qx - qy
    if sp != sq:
        if sp < sq:
            ax, ay, az, bx, by, bz, sa, sb = px, py, zp, qx, qy, zq, sp, sq
        else:
            ax, ay, az, bx, by, bz, sa, sb = qx, qy, zq, px, py, zp, sq, sp
        d = sb - sa
        dy = by - ay
        fy = ay
        rem = 0
        for m in range(sa + 1, sb):
            rem += dy
            while rem >= d:
                rem -= d
                fy += 1
            while rem < 0:
                rem += d
                fy -= 1
            if rem == 0:
                continue
            f = rem / d
            t = (m - sa) / d
            ga = h[fy, fy + m]
            zr = ga + f * (h[fy + 1, fy + m + 1] - ga)
            e = abs((az - zr) + t * (bz - az))
            if e > best and e > tol:
                e = _point_error_3d(h, cellvalid, fy + m + f, fy + f, zr, az + t * (bz - az), t0x, t0y, t0z, t1x, t1y, t1z, t2x, t2y, t2z, sx, sy, tol, best)
            if e > best:
                best = e
                info[o] = fy * W + fy + m
                info[o + 1] = fy * W + fy + m + W + 1
                info[o + 2] = fy * (W - 1) + fy + m
                info[o + 3] = -1
    return best


@njit(cache=True, nogil=True, inline="always")
def _row_span(y: int, xmin: int, xmax: int, a0: int, b0: int, c0: int, a1: int, b1: int, c1: int, a2: int,
              b2: int, c2: int) -> tuple[int, int]:
    """Columns [lo, hi] of row ``y`` inside the closed triangle whose half-planes are ``a·x + b·y + c >= 0``
    (integer arithmetic, clipped to [xmin, xmax]; empty when hi < lo)."""
    lo = xmin
    hi = xmax
    for k in range(3):
        if k == 0:
            a, r = a0, b0 * y + c0
        elif k == 1:
            a, r = a1, b1 * y + c1
        else:
            a, r = a2, b2 * y + c2
        if a > 0:
            lo = max(lo, -(r // a))
        elif a < 0:
            hi = min(hi, r // (-a))
        elif r < 0:
            hi = lo - 1
    return lo, hi


@njit(cache=True, nogil=True, **NO_NRT)
def _triangle_error(
    h: np.ndarray,
    cellvalid: np.ndarray,
    vid: np.ndarray,
    scratch: np.ndarray,
    x0: int,
    y0: int,
    x1: int,
    y1: int,
    x2: int,
    y2: int,
    crossings: bool,
    max_error: float,
    sx: float = 0.0,
    sy: float = 0.0,
) -> tuple[float, int]:
    """Max |TIN - grid surface| over one triangle and the sample to insert next (-1: none).

    The max of the difference of two piecewise-linear functions over the triangle is attained at a
    vertex of their overlay: a grid sample in the closed triangle, or a crossing of a triangle edge
    with a grid line (row, column or cell diagonal x - y = const). Both kinds are enumerated exactly
    with integer arithmetic, so the result is the exact vertical L-infinity distance (up to rounding).
    When a sample is already above ``max_error``, the crossings are skipped and the worst sample's
    error (a lower bound, enough to keep the triangle queued) and the sample are returned.

    With ``sx > 0`` (metres per grid column, ``sy`` per row) the error at a sample or crossing whose vertical
    error exceeds ``max_error`` is its 3D one instead (`_point_error_3d`: the raster point's distance to the
    triangle and the TIN point's to the grid surface): a steep triangle along a façade is charged about the
    horizontal offset of the points beside it, not the façade's height (the DSM builder's Hausdorff metric;
    a guide for where to insert, not a bound: its certificate decides).
    """
    H, W = h.shape
    z0 = h[y0, x0]
    area = _orient(x0, y0, x1, y1, x2, y2)
    g1 = (h[y1, x1] - z0) / area
    g2 = (h[y2, x2] - z0) / area
    # barycentric numerators w1 = orient(p2, p0, p), w2 = orient(p0, p1, p) as a*x + b*y + c
    a1 = y0 - y2
    b1 = x2 - x0
    c1 = x0 * y2 - y0 * x2
    a2 = y1 - y0
    b2 = x0 - x1
    c2 = x1 * y0 - y1 * x0
    a0 = y2 - y1
    b0 = x1 - x2
    c0 = x2 * y1 - y2 * x1

    best_s = 0.0
    cand_s = -1
    ymin = min(y0, min(y1, y2))
    ymax = max(y0, max(y1, y2))
    xmin = min(x0, min(x1, x2))
    xmax = max(x0, max(x1, x2))
    for y in range(ymin, ymax + 1):
        lo, hi = _row_span(y, xmin, xmax, a0, b0, c0, a1, b1, c1, a2, b2, c2)
        r1 = b1 * y + c1
        r2 = b2 * y + c2
        for x in range(lo, hi + 1):
            e = abs((z0 - h[y, x]) + g1 * (a1 * x + r1) + g2 * (a2 * x + r2))
            if sx > 0.0 and e > best_s and e > max_error:
                e = _point_error_3d(h, cellvalid, x, y, h[y, x], h[y, x] + (z0 - h[y, x]) + g1 * (a1 * x + r1)
                                    + g2 * (a2 * x + r2), x0 * sx, y0 * sy, z0, x1 * sx, y1 * sy, h[y1, x1],
                                    x2 * sx, y2 * sy, h[y2, x2], sx, sy, max_error, best_s)
            if e > best_s:
                s = y * W + x
                if vid[s] < 0:
                    best_s = e
                    cand_s = s

    if best_s > max_error:
        # Over the bound at a sample already: insert the worst sample (Garland & Heckbert's choice)
        # and skip the crossings, which could only raise the heap key. The full error is computed
        # whenever the samples are within the bound, so no triangle leaves the heap above it.
        return best_s, cand_s
    best_c = 0.0
    cs0 = -1  # the two samples of the crossed grid edge, and the cell(s) beside it
    cs1 = -1
    cell_a = -1
    cell_b = -1
    for k in range(3 if crossings else 0):
        if sx > 0.0:
            if k == 0:
                e = _edge_error_3d(h, cellvalid, x0, y0, x1, y1, scratch, 0, x0 * sx, y0 * sy, z0, x1 * sx,
                                   y1 * sy, h[y1, x1], x2 * sx, y2 * sy, h[y2, x2], sx, sy, max_error)
            elif k == 1:
                e = _edge_error_3d(h, cellvalid, x1, y1, x2, y2, scratch, 0, x0 * sx, y0 * sy, z0, x1 * sx,
                                   y1 * sy, h[y1, x1], x2 * sx, y2 * sy, h[y2, x2], sx, sy, max_error)
            else:
                e = _edge_error_3d(h, cellvalid, x2, y2, x0, y0, scratch, 0, x0 * sx, y0 * sy, z0, x1 * sx,
                                   y1 * sy, h[y1, x1], x2 * sx, y2 * sy, h[y2, x2], sx, sy, max_error)
        elif k == 0:
            e = _edge_error(h, x0, y0, x1, y1, scratch, 0, np.inf)
        elif k == 1:
            e = _edge_error(h, x1, y1, x2, y2, scratch, 0, np.inf)
        else:
            e = _edge_error(h, x2, y2, x0, y0, scratch, 0, np.inf)
        if e > best_c:
            best_c = e
            cs0 = scratch[0]
            cs1 = scratch[1]
            cell_a = scratch[2]
            cell_b = scratch[3]

    if best_s >= best_c:
        return best_s, cand_s
    # The worst point is a crossing, not a sample: insert an end of the crossed grid edge, else a
    # corner of a valid cell beside it. Such a corner always exists while the TIN is Delaunay: no
    # Delaunay edge crosses a cell whose four corners are all vertices.
    scratch[0] = cs0
    scratch[1] = cs1
    cand = _pick(scratch, 2, h, vid, z0, x0, y0, a1, b1, c1, a2, b2, c2, g1, g2)
    if cand < 0:
        n = 0
        for cell in (cell_a, cell_b):
            if cell < 0:
                continue
            ci = cell // (W - 1)
            cj = cell - ci * (W - 1)
            if not cellvalid[ci, cj]:
                continue
            s = ci * W + cj
            scratch[n] = s
            scratch[n + 1] = s + 1
            scratch[n + 2] = s + W
            scratch[n + 3] = s + W + 1
            n += 4
        cand = _pick(scratch, n, h, vid, z0, x0, y0, a1, b1, c1, a2, b2, c2, g1, g2)
    if cand < 0:
        # last resort, not expected to run: any valid non-vertex sample of the surrounding box
        n = 0
        best = -1.0
        for y in range(max(ymin - 1, 0), min(ymax + 2, H)):
            for x in range(max(xmin - 1, 0), min(xmax + 2, W)):
                s = y * W + x
                if vid[s] >= 0:
                    continue
                ok = False
                for ci in range(max(y - 1, 0), min(y + 1, H - 1)):
                    for cj in range(max(x - 1, 0), min(x + 1, W - 1)):
                        ok = ok or cellvalid[ci, cj]
                if not ok:
                    continue
                e = abs((z0 - h[y, x]) + g1 * (a1 * x + b1 * y + c1) + g2 * (a2 * x + b2 * y + c2))
                if not _is_border(s, H, W):
                    e += 1e300
                if e > best:
                    best = e
                    cand = s
    return best_c, cand


# --------------------------------------------------------------------------------------------------
# triangulation updates (Delatin's half-edge scheme, iterative legalisation)
# --------------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True, **NO_NRT)
def _add_triangle(
    tri: np.ndarray,
    half: np.ndarray,
    hpos: np.ndarray,
    heap: np.ndarray,
    terr: np.ndarray,
    pend: np.ndarray,
    inpend: np.ndarray,
    cnt: np.ndarray,
    e: int,
    a: int,
    b: int,
    c: int,
    ab: int,
    bc: int,
    ca: int,
) -> int:
    if e < 0:
        e = 3 * cnt[_NTRI]
        cnt[_NTRI] += 1
    t = e // 3
    tri[e] = a
    tri[e + 1] = b
    tri[e + 2] = c
    half[e] = ab
    half[e + 1] = bc
    half[e + 2] = ca
    if ab >= 0:
        half[ab] = e
    if bc >= 0:
        half[bc] = e + 1
    if ca >= 0:
        half[ca] = e + 2
    if hpos[t] >= 0:
        _heap_remove(heap, hpos, terr, cnt, t)
    if cnt[_ERRORS_ON] and not inpend[t]:
        inpend[t] = True
        pend[cnt[_NPEND]] = t
        cnt[_NPEND] += 1
    return e


@njit(cache=True, nogil=True, **NO_NRT)
def _legalize(
    tri: np.ndarray,
    half: np.ndarray,
    vx: np.ndarray,
    vy: np.ndarray,
    hpos: np.ndarray,
    heap: np.ndarray,
    terr: np.ndarray,
    pend: np.ndarray,
    inpend: np.ndarray,
    cnt: np.ndarray,
    stack: np.ndarray,
    n: int,
) -> None:
    """Lawson flips from the half-edges ``stack[:n]``, each opposite the point just inserted.

    An explicit stack replaces Delatin's recursion. Entries never go stale: a triangle on the stack
    touches the new point, and only its edge opposite that point (the one on the stack) can flip it.
    """
    while n > 0:
        n -= 1
        a = stack[n]
        b = half[a]
        if b < 0:
            continue
        a0 = a - a % 3
        b0 = b - b % 3
        al = a0 + (a + 1) % 3
        ar = a0 + (a + 2) % 3
        bl = b0 + (b + 2) % 3
        br = b0 + (b + 1) % 3
        p0 = tri[ar]
        pr = tri[a]
        pl = tri[al]
        p1 = tri[bl]
        if not _in_circle(vx[p0], vy[p0], vx[pr], vy[pr], vx[pl], vy[pl], vx[p1], vy[p1]):
            continue
        hal = half[al]
        har = half[ar]
        hbl = half[bl]
        hbr = half[br]
        t0 = _add_triangle(tri, half, hpos, heap, terr, pend, inpend, cnt, a0, p0, p1, pl, -1, hbl, hal)
        t1 = _add_triangle(tri, half, hpos, heap, terr, pend, inpend, cnt, b0, p1, p0, pr, t0, har, hbr)
        stack[n] = t0 + 1
        stack[n + 1] = t1 + 2
        n += 2


@njit(cache=True, nogil=True, **NO_NRT)
def _locate(
    tri: np.ndarray,
    half: np.ndarray,
    vx: np.ndarray,
    vy: np.ndarray,
    cnt: np.ndarray,
    t: int,
    px: int,
    py: int,
) -> int:
    """The triangle whose closed interior holds (px, py): a visibility walk from ``t``.

    The walk terminates on Delaunay triangulations (Edelsbrunner 1990); the step cap and the linear
    scan behind it only guard against a bug turning into a hang.
    """
    ntri = cnt[_NTRI]
    rot = 0
    for _ in range(4 * ntri + 16):
        e = 3 * t
        moved = False
        rot = (rot + 1) % 3
        for k in range(3):
            ee = e + (k + rot) % 3
            en = e + (ee - e + 1) % 3
            a = tri[ee]
            b = tri[en]
            if _orient(vx[a], vy[a], vx[b], vy[b], px, py) < 0:
                nb = half[ee]
                if nb >= 0:
                    t = nb // 3
                    moved = True
                    break
        if not moved:
            return t
    for t in range(ntri):
        e = 3 * t
        a, b, c = tri[e], tri[e + 1], tri[e + 2]
        if (
            _orient(vx[a], vy[a], vx[b], vy[b], px, py) >= 0
            and _orient(vx[b], vy[b], vx[c], vy[c], px, py) >= 0
            and _orient(vx[c], vy[c], vx[a], vy[a], px, py) >= 0
        ):
            return t
    return -1


@njit(cache=True, nogil=True, **NO_NRT)
def _insert(
    tri: np.ndarray,
    half: np.ndarray,
    vx: np.ndarray,
    vy: np.ndarray,
    vid: np.ndarray,
    hpos: np.ndarray,
    heap: np.ndarray,
    terr: np.ndarray,
    pend: np.ndarray,
    inpend: np.ndarray,
    cnt: np.ndarray,
    stack: np.ndarray,
    W: int,
    px: int,
    py: int,
    t: int,
) -> int:
    """Insert grid sample (px, py) starting the search at triangle ``t``; return a triangle near it."""
    if vid[py * W + px] >= 0:
        return t
    t = _locate(tri, half, vx, vy, cnt, t, px, py)
    pn = cnt[_NVERT]
    cnt[_NVERT] += 1
    vx[pn] = px
    vy[pn] = py
    vid[py * W + px] = pn
    e0 = 3 * t
    p0 = tri[e0]
    p1 = tri[e0 + 1]
    p2 = tri[e0 + 2]
    if _orient(vx[p0], vy[p0], vx[p1], vy[p1], px, py) == 0:
        return _split_edge(tri, half, vx, vy, hpos, heap, terr, pend, inpend, cnt, stack, pn, e0)
    if _orient(vx[p1], vy[p1], vx[p2], vy[p2], px, py) == 0:
        return _split_edge(tri, half, vx, vy, hpos, heap, terr, pend, inpend, cnt, stack, pn, e0 + 1)
    if _orient(vx[p2], vy[p2], vx[p0], vy[p0], px, py) == 0:
        return _split_edge(tri, half, vx, vy, hpos, heap, terr, pend, inpend, cnt, stack, pn, e0 + 2)
    h0 = half[e0]
    h1 = half[e0 + 1]
    h2 = half[e0 + 2]
    t0 = _add_triangle(tri, half, hpos, heap, terr, pend, inpend, cnt, e0, p0, p1, pn, h0, -1, -1)
    t1 = _add_triangle(tri, half, hpos, heap, terr, pend, inpend, cnt, -1, p1, p2, pn, h1, -1, t0 + 1)
    t2 = _add_triangle(tri, half, hpos, heap, terr, pend, inpend, cnt, -1, p2, p0, pn, h2, t0 + 2, t1 + 1)
    stack[0] = t0
    stack[1] = t1
    stack[2] = t2
    _legalize(tri, half, vx, vy, hpos, heap, terr, pend, inpend, cnt, stack, 3)
    return t0 // 3


@njit(cache=True, nogil=True, **NO_NRT)
def _split_edge(
    tri: np.ndarray,
    half: np.ndarray,
    vx: np.ndarray,
    vy: np.ndarray,
    hpos: np.ndarray,
    heap: np.ndarray,
    terr: np.ndarray,
    pend: np.ndarray,
    inpend: np.ndarray,
    cnt: np.ndarray,
    stack: np.ndarray,
    pn: int,
    a: int,
) -> int:
    """Insert vertex ``pn`` lying on half-edge ``a`` (Delatin's ``_handleCollinear``)."""
    a0 = a - a % 3
    al = a0 + (a + 1) % 3
    ar = a0 + (a + 2) % 3
    p0 = tri[ar]
    pr = tri[a]
    pl = tri[al]
    hal = half[al]
    har = half[ar]
    b = half[a]
    if b < 0:
        t0 = _add_triangle(tri, half, hpos, heap, terr, pend, inpend, cnt, a0, pn, p0, pr, -1, har, -1)
        t1 = _add_triangle(tri, half, hpos, heap, terr, pend, inpend, cnt, -1, p0, pn, pl, t0, -1, hal)
        stack[0] = t0 + 1
        stack[1] = t1 + 2
        _legalize(tri, half, vx, vy, hpos, heap, terr, pend, inpend, cnt, stack, 2)
        return t0 // 3
    b0 = b - b % 3
    bl = b0 + (b + 2) % 3
    br = b0 + (b + 1) % 3
    p1 = tri[bl]
    hbl = half[bl]
    hbr = half[br]
    t0 = _add_triangle(tri, half, hpos, heap, terr, pend, inpend, cnt, a0, p0, pr, pn, har, -1, -1)
    t1 = _add_triangle(tri, half, hpos, heap, terr, pend, inpend, cnt, b0, pr, p1, pn, hbr, -1, t0 + 1)
    t2 = _add_triangle(tri, half, hpos, heap, terr, pend, inpend, cnt, -1, p1, pl, pn, hbl, -1, t1 + 1)
    t3 = _add_triangle(tri, half, hpos, heap, terr, pend, inpend, cnt, -1, pl, p0, pn, hal, t0 + 2, t2 + 1)
    stack[0] = t0
    stack[1] = t1
    stack[2] = t2
    stack[3] = t3
    _legalize(tri, half, vx, vy, hpos, heap, terr, pend, inpend, cnt, stack, 4)
    return t0 // 3


@njit(cache=True, nogil=True)
def _grown(a: np.ndarray, n: int, fill: int) -> np.ndarray:
    out = np.full(n, fill, dtype=a.dtype)
    out[: a.size] = a
    return out


@njit(cache=True, nogil=True)
def _grown_all(cap: int, vx: np.ndarray, vy: np.ndarray, tri: np.ndarray, half: np.ndarray, hpos: np.ndarray,
               heap: np.ndarray, terr: np.ndarray, tcand: np.ndarray, pend: np.ndarray, inpend: np.ndarray,
               stack: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                           np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`build_tin`'s arrays grown for ``cap`` vertices (the triangle arrays for ``cap`` triangles)."""
    return (_grown(vx, cap, 0), _grown(vy, cap, 0), _grown(tri, 3 * cap, 0), _grown(half, 3 * cap, 0),
            _grown(hpos, cap, -1), _grown(heap, cap, 0), _grown(terr, cap, 0), _grown(tcand, cap, -1),
            _grown(pend, cap, 0), _grown(inpend, cap, 0), _grown(stack, 3 * cap, 0))


@njit(cache=True, nogil=True, **NO_NRT)
def _flush(
    h: np.ndarray,
    cellvalid: np.ndarray,
    vid: np.ndarray,
    scratch: np.ndarray,
    tri: np.ndarray,
    vx: np.ndarray,
    vy: np.ndarray,
    hpos: np.ndarray,
    heap: np.ndarray,
    terr: np.ndarray,
    tcand: np.ndarray,
    pend: np.ndarray,
    inpend: np.ndarray,
    cnt: np.ndarray,
    max_error: float,
    crossings: bool,
    sx: float = 0.0,
    sy: float = 0.0,
) -> None:
    """Compute the error of every pending triangle and queue those above ``max_error`` (``sx``, ``sy``: see
    `_triangle_error`)."""
    H, W = h.shape
    for i in range(cnt[_NPEND]):
        t = pend[i]
        inpend[t] = False
        e = 3 * t
        a, b, c = tri[e], tri[e + 1], tri[e + 2]
        x0, y0, x1, y1, x2, y2 = vx[a], vy[a], vx[b], vy[b], vx[c], vy[c]
        # Every edge of the valid region's boundary is a TIN edge (see tin.py), so a triangle lies
        # wholly inside or wholly outside it, and its centroid's cell tells which.
        ci = min((y0 + y1 + y2) // 3, H - 2)
        cj = min((x0 + x1 + x2) // 3, W - 2)
        if not cellvalid[ci, cj]:
            terr[t] = 0.0
            tcand[t] = -1
            continue
        err, cand = _triangle_error(h, cellvalid, vid, scratch, x0, y0, x1, y1, x2, y2, crossings, max_error, sx, sy)
        if cand < 0:
            if err > max_error:
                cnt[_STUCK] += 1
            err = 0.0
        terr[t] = err
        tcand[t] = cand
        if err > max_error:
            _heap_push(heap, hpos, terr, cnt, t)
    cnt[_NPEND] = 0


@njit(cache=True, nogil=True, inline="always")
def _cells_valid(cellvalid: np.ndarray, y: int, x: int) -> bool:
    """Whether the four cells around interior sample (y, x) are valid."""
    return cellvalid[y - 1, x - 1] and cellvalid[y - 1, x] and cellvalid[y, x - 1] and cellvalid[y, x]


@njit(cache=True, nogil=True, **NO_NRT)
def _rough(h: np.ndarray, cellvalid: np.ndarray, y: int, x: int, limit: float) -> bool:
    """True when interior sample (y, x) has its four cells valid and its 3×3 neighbourhood departs from the
    bilinear interpolation of the neighbourhood's corners by more than ``limit`` (a seed; see `build_tin`)."""
    if not _cells_valid(cellvalid, y, x):
        return False
    za = h[y - 1, x - 1]
    zb = h[y - 1, x + 1]
    zc = h[y + 1, x - 1]
    zd = h[y + 1, x + 1]
    return (abs(h[y - 1, x] - 0.5 * (za + zb)) > limit or abs(h[y + 1, x] - 0.5 * (zc + zd)) > limit
            or abs(h[y, x - 1] - 0.5 * (za + zc)) > limit or abs(h[y, x + 1] - 0.5 * (zb + zd)) > limit
            or abs(h[y, x] - 0.25 * (za + zb + zc + zd)) > limit)


@njit(cache=True, nogil=True, **NO_NRT)
def _insert_all(tri: np.ndarray, half: np.ndarray, vx: np.ndarray, vy: np.ndarray, vid: np.ndarray, hpos: np.ndarray,
                heap: np.ndarray, terr: np.ndarray, pend: np.ndarray, inpend: np.ndarray, cnt: np.ndarray,
                stack: np.ndarray, W: int, xs: np.ndarray, ys: np.ndarray, k: int, t: int) -> tuple[int, int]:
    """Insert samples (xs[k:], ys[k:]) in order until all are in or the arrays are full; return the next
    index (``xs.size`` when done) and a triangle near the last one inserted."""
    while k < xs.size:
        if 3 * (cnt[_NTRI] + 4) > tri.size:
            break
        t = _insert(tri, half, vx, vy, vid, hpos, heap, terr, pend, inpend, cnt, stack, W, xs[k], ys[k], t)
        k += 1
    return k, t


@njit(cache=True, nogil=True)
def _seeds(h: np.ndarray, cellvalid: np.ndarray, vid: np.ndarray, seed_limit: float,
           seed_lattice: int) -> tuple[np.ndarray, np.ndarray]:
    """Columns and rows of the seeds (`build_tin`), in row-major order of the even samples."""
    H, W = h.shape
    n = 0
    sx = np.empty(((H - 1) // 2) * ((W - 1) // 2) + 1, dtype=np.int64)
    sy = np.empty_like(sx)
    for y in range(2, H - 1, 2):
        for x in range(2, W - 1, 2):
            if vid[y * W + x] >= 0:
                continue
            lattice = seed_lattice > 0 and y % seed_lattice == 0 and x % seed_lattice == 0
            if not ((lattice and _cells_valid(cellvalid, y, x)) or _rough(h, cellvalid, y, x, seed_limit)):
                continue
            sx[n] = x
            sy[n] = y
            n += 1
    return sx[:n], sy[:n]


@njit(cache=True, nogil=True, **NO_NRT)
def _greedy(h: np.ndarray, cellvalid: np.ndarray, vid: np.ndarray, scratch: np.ndarray, tri: np.ndarray,
            half: np.ndarray, vx: np.ndarray, vy: np.ndarray, hpos: np.ndarray, heap: np.ndarray, terr: np.ndarray,
            tcand: np.ndarray, pend: np.ndarray, inpend: np.ndarray, cnt: np.ndarray, stack: np.ndarray,
            max_error: float, crossings: bool, sx: float = 0.0, sy: float = 0.0) -> bool:
    """`build_tin`'s greedy phase until no triangle is above ``max_error`` (True) or the arrays are full
    (False: grow them and call again). Apart from `build_tin`, which allocates, so that the loop runs without
    numba's reference counting (the reassigned arrays cost an incref and a decref each per insertion)."""
    H, W = h.shape
    while cnt[_NHEAP] > 0:
        if 3 * (cnt[_NTRI] + 4) > tri.size:
            return False
        t = heap[0]
        _heap_remove(heap, hpos, terr, cnt, t)
        s = tcand[t]
        y = s // W
        x = s - y * W
        if vid[s] < 0 and _is_border(s, H, W):
            cnt[_NBORDER_ADDED] += 1
        _insert(tri, half, vx, vy, vid, hpos, heap, terr, pend, inpend, cnt, stack, W, x, y, t)
        # A candidate outside t (from an edge crossing) may leave t untouched: re-evaluate it too.
        if not inpend[t]:
            inpend[t] = True
            pend[cnt[_NPEND]] = t
            cnt[_NPEND] += 1
        _flush(h, cellvalid, vid, scratch, tri, vx, vy, hpos, heap, terr, tcand, pend, inpend, cnt, max_error,
               crossings, sx, sy)
    return True


@njit(cache=True, nogil=True)
def build_tin(
    h: np.ndarray,
    cellvalid: np.ndarray,
    forced_x: np.ndarray,
    forced_y: np.ndarray,
    max_error: float,
    crossings: bool = True,
    decimate: bool = True,
    seed_limit: float = np.inf,
    seed_lattice: int = 0,
    sx: float = 0.0,
    sy: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    """Greedy-insertion Delaunay TIN of grid ``h`` (H, W), H, W >= 2, after the forced vertices and the
    seeds, then (``decimate``) the vertices the bound does not need removed.

    Parameters
    ----------
    h
        (H, W) float64 heights, finite everywhere (no-data already filled).
    cellvalid
        (H-1, W-1) bool, cell (i, j) has valid corners (i..i+1, j..j+1).
    forced_x, forced_y
        (K,) int64 column and row of the vertices inserted before the greedy phase, the four grid
        corners first.
    max_error
        Stop when no triangle inside the valid region has error above this.
    crossings
        False measures the error at samples only (Garland & Heckbert's criterion, pydelatin's), which
        is not a bound on the surfaces' distance; for benchmarks only (it also skips ``decimate``).
    decimate
        After the greedy phase, remove the vertices the bound does not need (`_decimate`); forced
        vertices and grid-border vertices stay.
    seed_limit
        Seeds: every interior sample at an even row and column whose four cells are valid and whose 3×3
        neighbourhood departs from the bilinear interpolation of its corners by more than this is
        inserted after the forced vertices, before any error is evaluated. Unlike forced vertices,
        seeds can be removed by the decimation. They only save work: the greedy phase would insert
        most of them (or a neighbour) anyway, one rescan of ever smaller triangles at a time. ``inf``:
        no seeds.
    seed_lattice
        Also seed every interior sample whose row and column are multiples of this (even, > 0; 0: none)
        and whose four cells are valid: a TIN with few vertices (a coarse tile) otherwise rescans large
        triangles at every insertion. Removable like the other seeds.
    sx, sy
        Metres per grid column and row: when > 0, the greedy phase and the decimation measure a 3D error
        (`_triangle_error`) instead of the vertical one, which is no longer a bound (the caller certifies);
        0: the vertical error, exact.

    Returns
    -------
    vx, vy
        (V,) int64 column and row of every vertex inserted, including removed ones (no triangle
        refers to those).
    tris
        (T, 3) int32 vertex indices, ``_orient > 0``; includes triangles outside the valid region.
    stuck
        Number of triangles left above ``max_error`` for want of a sample to insert (expected 0).
    border_added
        Number of grid-border samples the greedy phase had to add beyond the forced ones.
    """
    H, W = h.shape
    cap = 2 * forced_x.size + 256
    vx = np.empty(cap, dtype=np.int64)
    vy = np.empty(cap, dtype=np.int64)
    tri = np.empty(3 * cap, dtype=np.int32)
    half = np.empty(3 * cap, dtype=np.int32)
    hpos = np.full(cap, -1, dtype=np.int32)
    heap = np.empty(cap, dtype=np.int32)
    terr = np.zeros(cap, dtype=np.float64)
    tcand = np.full(cap, -1, dtype=np.int64)
    pend = np.empty(cap, dtype=np.int32)
    inpend = np.zeros(cap, dtype=np.bool_)
    stack = np.empty(3 * cap, dtype=np.int32)
    vid = np.full(H * W, -1, dtype=np.int32)
    scratch = np.empty(8, dtype=np.int64)
    cnt = np.zeros(8, dtype=np.int64)

    # the four corners, two triangles along the (0,0)-(H-1,W-1) diagonal (the perturbed-Delaunay one)
    for k in range(4):
        x = 0 if k % 2 == 0 else W - 1
        y = 0 if k < 2 else H - 1
        vx[k] = x
        vy[k] = y
        vid[y * W + x] = k
    cnt[_NVERT] = 4
    t0 = _add_triangle(tri, half, hpos, heap, terr, pend, inpend, cnt, -1, 3, 0, 2, -1, -1, -1)
    _add_triangle(tri, half, hpos, heap, terr, pend, inpend, cnt, -1, 0, 3, 1, t0, -1, -1)

    # The forced vertices, then the seeds (without a seed limit or lattice none: no test of every second
    # sample). Errors are only meaningful once every valid-region boundary sample is in (see tin.py).
    t = 0
    nfixed = 0
    xs, ys = forced_x, forced_y
    for phase in range(2):
        k = 0
        while True:
            k, t = _insert_all(tri, half, vx, vy, vid, hpos, heap, terr, pend, inpend, cnt, stack, W, xs, ys, k, t)
            if k == xs.size:
                break
            cap *= 2
            vx, vy, tri, half, hpos, heap, terr, tcand, pend, inpend, stack = _grown_all(
                cap, vx, vy, tri, half, hpos, heap, terr, tcand, pend, inpend, stack)
        if phase == 0:
            nfixed = cnt[_NVERT]
            if not (seed_limit < np.inf or seed_lattice > 0):
                break
            xs, ys = _seeds(h, cellvalid, vid, seed_limit, seed_lattice)
    cnt[_ERRORS_ON] = 1
    for t in range(cnt[_NTRI]):
        pend[t] = t
        inpend[t] = True
    cnt[_NPEND] = cnt[_NTRI]
    _flush(
        h,
        cellvalid,
        vid,
        scratch,
        tri,
        vx,
        vy,
        hpos,
        heap,
        terr,
        tcand,
        pend,
        inpend,
        cnt,
        max_error,
        crossings,
        sx,
        sy,
    )

    # Garland & Heckbert 1995: insert the worst sample of the worst triangle until all are within bound.
    while not _greedy(h, cellvalid, vid, scratch, tri, half, vx, vy, hpos, heap, terr, tcand, pend, inpend, cnt,
                      stack, max_error, crossings, sx, sy):
        cap *= 2
        vx, vy, tri, half, hpos, heap, terr, tcand, pend, inpend, stack = _grown_all(
            cap, vx, vy, tri, half, hpos, heap, terr, tcand, pend, inpend, stack)

    nv = cnt[_NVERT]
    nt = cnt[_NTRI]
    if decimate and crossings:
        _decimate(h, tri, half, vx, vy, nv, nfixed, nt, max_error, cellvalid, sx, sy)
    live = 0
    for t in range(nt):
        if tri[3 * t] >= 0:
            tri[3 * live] = tri[3 * t]
            tri[3 * live + 1] = tri[3 * t + 1]
            tri[3 * live + 2] = tri[3 * t + 2]
            live += 1
    return (
        vx[:nv].copy(),
        vy[:nv].copy(),
        tri[: 3 * live].reshape(live, 3).copy(),
        int(cnt[_STUCK]),
        int(cnt[_NBORDER_ADDED]),
    )


# --------------------------------------------------------------------------------------------------
# decimation: bounded vertex removal after the greedy phase
# --------------------------------------------------------------------------------------------------

#: Vertices of higher degree are kept (their hole's dynamic programme would cost O(degree³)).
_MAX_DEGREE = 24
#: Triangles holding the removed vertex tried per hole, best fitting first.
_MAX_CANDIDATES = 2


@njit(cache=True, nogil=True, inline="always")
def _samples_within(
    h: np.ndarray, x0: int, y0: int, x1: int, y1: int, x2: int, y2: int, px: int, py: int, eps: float
) -> bool:
    """Whether triangle (0, 1, 2) is non-degenerate, ``_orient > 0``, and within ``eps`` of the grid
    surface at every sample in it (the crossings of its edges are `_edge_error`'s).

    Sample (px, py), the vertex being removed, is tested first when it lies in the triangle.
    """
    area = _orient(x0, y0, x1, y1, x2, y2)
    if area <= 0:
        return False
    z0 = h[y0, x0]
    g1 = (h[y1, x1] - z0) / area
    g2 = (h[y2, x2] - z0) / area
    a1 = y0 - y2
    b1 = x2 - x0
    c1 = x0 * y2 - y0 * x2
    a2 = y1 - y0
    b2 = x0 - x1
    c2 = x1 * y0 - y1 * x0
    a0 = y2 - y1
    b0 = x1 - x2
    c0 = x2 * y1 - y2 * x1
    w1 = a1 * px + b1 * py + c1
    w2 = a2 * px + b2 * py + c2
    if a0 * px + b0 * py + c0 >= 0 and w1 >= 0 and w2 >= 0:
        if abs((z0 - h[py, px]) + g1 * w1 + g2 * w2) > eps:
            return False
    ymin = min(y0, min(y1, y2))
    ymax = max(y0, max(y1, y2))
    xmin = min(x0, min(x1, x2))
    xmax = max(x0, max(x1, x2))
    for y in range(ymin, ymax + 1):
        lo, hi = _row_span(y, xmin, xmax, a0, b0, c0, a1, b1, c1, a2, b2, c2)
        r1 = b1 * y + c1
        r2 = b2 * y + c2
        for x in range(lo, hi + 1):
            if abs((z0 - h[y, x]) + g1 * (a1 * x + r1) + g2 * (a2 * x + r2)) > eps:
                return False
    return True


@njit(cache=True, nogil=True, inline="always")
def _samples_within_3d(
    h: np.ndarray, cellvalid: np.ndarray, x0: int, y0: int, x1: int, y1: int, x2: int, y2: int, px: int, py: int,
    eps: float, sx: float, sy: float
) -> bool:
    """`_samples_within` with the 3D error of `_point_error_3d` (``sx``, ``sy``: metres per column, row)."""
    area = _orient(x0, y0, x1, y1, x2, y2)
    if area <= 0:
        return False
    z0 = h[y0, x0]
    g1 = (h[y1, x1] - z0) / area
    g2 = (h[y2, x2] - z0) / area
    a1 = y0 - y2
    b1 = x2 - x0
    c1 = x0 * y2 - y0 * x2
    a2 = y1 - y0
    b2 = x0 - x1
    c2 = x1 * y0 - y1 * x0
    a0 = y2 - y1
    b0 = x1 - x2
    c0 = x2 * y1 - y2 * x1
    w1 = a1 * px + b1 * py + c1
    w2 = a2 * px + b2 * py + c2
    if a0 * px + b0 * py + c0 >= 0 and w1 >= 0 and w2 >= 0:
        zt = z0 + g1 * w1 + g2 * w2
        if abs(zt - h[py, px]) > eps and _point_error_3d(h, cellvalid, px, py, h[py, px], zt, x0 * sx, y0 * sy, z0,
                                                         x1 * sx, y1 * sy, h[y1, x1], x2 * sx, y2 * sy, h[y2, x2],
                                                         sx, sy, eps, 0.0) > eps:
            return False
    ymin = min(y0, min(y1, y2))
    ymax = max(y0, max(y1, y2))
    xmin = min(x0, min(x1, x2))
    xmax = max(x0, max(x1, x2))
    for y in range(ymin, ymax + 1):
        lo, hi = _row_span(y, xmin, xmax, a0, b0, c0, a1, b1, c1, a2, b2, c2)
        r1 = b1 * y + c1
        r2 = b2 * y + c2
        for x in range(lo, hi + 1):
            zt = z0 + g1 * (a1 * x + r1) + g2 * (a2 * x + r2)
            if abs(zt - h[y, x]) > eps and _point_error_3d(h, cellvalid, x, y, h[y, x], zt, x0 * sx, y0 * sy, z0,
                                                           x1 * sx, y1 * sy, h[y1, x1], x2 * sx, y2 * sy,
                                                           h[y2, x2], sx, sy, eps, 0.0) > eps:
                return False
    return True


@njit(cache=True, nogil=True, inline="always")
def _hole_triangle_ok(
    h: np.ndarray,
    vx: np.ndarray,
    vy: np.ndarray,
    ring: np.ndarray,
    d: int,
    tstat: np.ndarray,
    dstat: np.ndarray,
    info: np.ndarray,
    gen: int,
    a: int,
    b: int,
    c: int,
    px: int,
    py: int,
    eps: float,
    cellvalid: np.ndarray,
    sx: float,
    sy: float,
) -> bool:
    """Whether the triangle of ring vertices (a, b, c) (indices mod d, in cyclic order) meets the
    bound: `_edge_error` on its edges that are diagonals of the hole (its sides are edges of the
    current TIN, already within the bound), then `_samples_within`.

    Memoised per hole in ``tstat[i, j, k]`` (smallest index first) and, for the diagonals, which
    most candidates fail on and many share, in ``dstat[i, j]``, i < j; entries are ``gen`` + status
    (1 yes, 2 no), anything below ``gen`` is from an earlier hole.
    """
    i, j, k = a % d, b % d, c % d
    # rotate to the smallest index first (same cyclic order, same triangle)
    if j < i and j < k:
        i, j, k = j, k, i
    elif k < i and k < j:
        i, j, k = k, i, j
    s = tstat[i, j, k] - gen
    if s <= 0 and sx > 0.0:
        # 3D (`_triangle_error`'s measure): the diagonals' crossings depend on the triangle, no memo per diagonal
        s = 1
        p, q, r = ring[i], ring[j], ring[k]
        if not _samples_within_3d(h, cellvalid, vx[p], vy[p], vx[q], vy[q], vx[r], vy[r], px, py, eps, sx, sy):
            s = 2
        for side in range(3 if s == 1 else 0):
            if side == 0:
                u, w = i, j
            elif side == 1:
                u, w = j, k
            else:
                u, w = i, k
            if w - u == 1 or (u == 0 and w == d - 1):
                continue
            if _edge_error_3d(h, cellvalid, vx[ring[u]], vy[ring[u]], vx[ring[w]], vy[ring[w]], info, 0,
                              vx[p] * sx, vy[p] * sy, h[vy[p], vx[p]], vx[q] * sx, vy[q] * sy, h[vy[q], vx[q]],
                              vx[r] * sx, vy[r] * sy, h[vy[r], vx[r]], sx, sy, eps) > eps:
                s = 2
                break
        tstat[i, j, k] = gen + s
    elif s <= 0:
        s = 1
        for side in range(3):
            if side == 0:
                p, q = i, j
            elif side == 1:
                p, q = j, k
            else:
                p, q = i, k
            if q - p == 1 or (p == 0 and q == d - 1):
                continue
            if dstat[p, q] <= gen:
                u, w = ring[p], ring[q]
                ok = _edge_error(h, vx[u], vy[u], vx[w], vy[w], info, 0, eps) <= eps
                dstat[p, q] = gen + (1 if ok else 2)
            if dstat[p, q] == gen + 2:
                s = 2
                break
        if s == 1:
            p, q, r = ring[i], ring[j], ring[k]
            if not _samples_within(h, vx[p], vy[p], vx[q], vy[q], vx[r], vy[r], px, py, eps):
                s = 2
        tstat[i, j, k] = gen + s
    return s == 1


@njit(cache=True, nogil=True, inline="always")
def _hole_feasible(
    h: np.ndarray,
    vx: np.ndarray,
    vy: np.ndarray,
    ring: np.ndarray,
    d: int,
    tstat: np.ndarray,
    dstat: np.ndarray,
    info: np.ndarray,
    feas: np.ndarray,
    choice: np.ndarray,
    gen: int,
    a: int,
    b: int,
    px: int,
    py: int,
    eps: float,
    cellvalid: np.ndarray,
    sx: float,
    sy: float,
) -> bool:
    """Whether the sub-polygon ring[a..b] (cyclic, closed by the edge b-a) has a triangulation whose
    triangles all pass `_hole_triangle_ok`; the apex chosen for each interval goes to ``choice``.

    Bottom-up over the sub-intervals, memoised in ``feas[start % d, length]`` (``gen`` + 1 yes,
    ``gen`` + 2 no, below ``gen`` unknown) across the calls made for one hole. Triangles are
    evaluated lazily; the first feasible apex wins.
    """
    if b - a < 2:
        return True
    for ln in range(2, b - a + 1):
        for s in range(a, b - ln + 1):
            si = s % d
            if feas[si, ln] > gen:
                continue
            feas[si, ln] = gen + 2
            for m in range(s + 1, s + ln):
                if m - s >= 2 and feas[si, m - s] != gen + 1:
                    continue
                if s + ln - m >= 2 and feas[m % d, s + ln - m] != gen + 1:
                    continue
                if _hole_triangle_ok(h, vx, vy, ring, d, tstat, dstat, info, gen, s, m, s + ln, px, py, eps, cellvalid,
                                     sx, sy):
                    feas[si, ln] = gen + 1
                    choice[si, ln] = m - s
                    break
    return feas[a % d, b - a] == gen + 1


@njit(cache=True, nogil=True)
def _decimate(
    h: np.ndarray,
    tri: np.ndarray,
    half: np.ndarray,
    vx: np.ndarray,
    vy: np.ndarray,
    nv: int,
    nfixed: int,
    ntri: int,
    max_error: float,
    cellvalid: np.ndarray,
    sx: float = 0.0,
    sy: float = 0.0,
) -> int:
    """Remove every vertex whose removal keeps the exact bound; return how many went (with ``sx`` > 0, the
    bound on `_triangle_error`'s 3D measure, not a bound on the result: see `build_tin`).

    Greedy insertion overshoots: a vertex inserted early for a large error is often redundant once
    its neighbourhood has been refined. Vertices are visited once, newest first; vertices below
    ``nfixed`` (the forced ones) and on the grid border are never removed, so the tile border and the
    valid-region boundary stay as they are. A vertex goes when its hole (the polygon of its
    neighbours) has a triangulation in which every triangle is within the bound at every sample and
    every grid-line crossing, the very test the greedy phase applies. Some triangle of the hole holds
    the vertex and must interpolate its height within the bound: those that do are the candidates,
    best fitting first (``_MAX_CANDIDATES`` of them); for each, the sub-polygons on its three sides
    are searched exhaustively by dynamic programming over their triangulations.

    Why the result is a triangulation: the hole's triangles are a combinatorial triangulation of its
    polygon, so as chains they sum to the polygon; with every triangle ``_orient > 0`` their indicator
    functions sum to the polygon's winding number, 1 inside and 0 outside, so they tile the hole. The
    vertex is inside the valid region R (forced vertices include ∂R), so its star, and the hole, lie
    in R, and every ∂R edge stays a TIN edge. The result is no longer Delaunay; nothing after
    this step needs it to be.

    Dead triangles get ``tri[3t] = -1``; their slots are reused by the hole's triangles.
    """
    vedge = np.full(nv, -1, dtype=np.int64)
    for e in range(3 * ntri):
        vedge[tri[e]] = e
    D = _MAX_DEGREE
    ring = np.empty(D, dtype=np.int64)
    ring_e = np.empty(D, dtype=np.int64)
    outer = np.empty(D, dtype=np.int64)
    lside = np.empty((D, D), dtype=np.int64)
    # memo tables of the hole searches: gen + status (1 yes, 2 no); below gen means unknown
    tstat = np.zeros((D, D, D), dtype=np.int64)
    dstat = np.zeros((D, D), dtype=np.int64)
    feas = np.zeros((D, D), dtype=np.int64)
    info = np.empty(4, dtype=np.int64)
    choice = np.zeros((D, D), dtype=np.int64)
    cand = np.empty((D * D * D // 6 + D, 3), dtype=np.int64)
    cerr = np.empty(D * D * D // 6 + D, dtype=np.float64)
    stk = np.empty(4 * D, dtype=np.int64)
    rz = np.empty(D, dtype=np.float64)
    return _decimate_run(h, tri, half, vx, vy, nv, nfixed, max_error, vedge, ring, ring_e, outer, lside, tstat,
                         dstat, feas, info, choice, cand, cerr, stk, rz, cellvalid, sx, sy)


@njit(cache=True, nogil=True, **NO_NRT)
def _decimate_run(h: np.ndarray, tri: np.ndarray, half: np.ndarray, vx: np.ndarray, vy: np.ndarray, nv: int,
                  nfixed: int, max_error: float, vedge: np.ndarray, ring: np.ndarray, ring_e: np.ndarray,
                  outer: np.ndarray, lside: np.ndarray, tstat: np.ndarray, dstat: np.ndarray, feas: np.ndarray,
                  info: np.ndarray, choice: np.ndarray, cand: np.ndarray, cerr: np.ndarray, stk: np.ndarray,
                  rz: np.ndarray, cellvalid: np.ndarray, sx: float, sy: float) -> int:
    """`_decimate`'s loop over the vertices, on the work arrays it allocated: it allocates none, so it runs
    without numba's reference counting (the inlined hole helpers pass arrays around at every step)."""
    H, W = h.shape
    D = _MAX_DEGREE
    gen = 0
    removed = 0
    for v in range(nv - 1, nfixed - 1, -1):
        x = vx[v]
        y = vy[v]
        if x == 0 or y == 0 or x == W - 1 or y == H - 1:
            continue
        # the ring of neighbours, counter-clockwise (`_orient > 0`): e -> twin of prev(e)
        e = vedge[v]
        d = 0
        while True:
            if d == D or e < 0:
                break  # too many neighbours; e < 0 (an open star) cannot happen off the grid border
            ring_e[d] = e
            nxt = e - e % 3 + (e + 1) % 3
            ring[d] = tri[nxt]
            outer[d] = half[nxt]  # twin of the hole's edge ring[d] -> ring[d + 1]
            d += 1
            e = half[e - e % 3 + (e + 2) % 3]
            if e == ring_e[0]:
                break
        if e != ring_e[0] or d < 3:
            continue
        # candidate triangles holding v whose plane meets v's height within the bound; lside[i, k] is
        # orient(ring i, ring k, v), so triangle (i, k, j) holds v iff its three sides see v on the
        # left, and its area is their sum
        # (the ring's heights gathered once: the loops below read each of them O(d^2) times)
        for i in range(d):
            pa = ring[i]
            ax = vx[pa]
            ay = vy[pa]
            rz[i] = h[ay, ax]
            for k in range(i + 1, d):
                pb = ring[k]
                lside[i, k] = _orient(ax, ay, vx[pb], vy[pb], x, y)
        zv = h[y, x]
        nc = 0
        for i in range(d):
            zi = rz[i]
            for k in range(i + 1, d):
                w2 = lside[i, k]
                if w2 < 0:
                    continue
                zk = rz[k]
                for j in range(k + 1, d):
                    w0 = lside[k, j]
                    w1 = -lside[i, j]
                    if w0 < 0 or w1 < 0:
                        continue
                    ar = w0 + w1 + w2
                    if ar <= 0:
                        continue
                    zt = (w0 * zi + w1 * zk + w2 * rz[j]) / ar
                    err = abs(zt - zv)
                    if err > max_error and sx > 0.0:
                        pi, pk, pj = ring[i], ring[k], ring[j]
                        err = _point_error_3d(h, cellvalid, x, y, zv, zt, vx[pi] * sx, vy[pi] * sy, zi,
                                              vx[pk] * sx, vy[pk] * sy, zk, vx[pj] * sx, vy[pj] * sy, rz[j], sx,
                                              sy, max_error, 0.0)
                    if err > max_error:
                        continue
                    # insertion sort by that error: the best fitting candidates first
                    q = nc
                    while q > 0 and cerr[q - 1] > err:
                        cerr[q] = cerr[q - 1]
                        cand[q, 0] = cand[q - 1, 0]
                        cand[q, 1] = cand[q - 1, 1]
                        cand[q, 2] = cand[q - 1, 2]
                        q -= 1
                    cerr[q] = err
                    cand[q, 0] = i
                    cand[q, 1] = k
                    cand[q, 2] = j
                    nc += 1
        if nc == 0:
            continue
        gen += 4  # a new generation of memo entries: older ones read as unknown
        found = -1
        # The two best fitting candidates find nearly every removal (99% on city rasters); trying
        # all of them costs a third more time for the last 1%.
        for q in range(min(nc, _MAX_CANDIDATES)):
            i, k, j = cand[q, 0], cand[q, 1], cand[q, 2]
            if not _hole_triangle_ok(h, vx, vy, ring, d, tstat, dstat, info, gen, i, k, j, x, y, max_error,
                                     cellvalid, sx, sy):
                continue
            if (
                _hole_feasible(
                    h, vx, vy, ring, d, tstat, dstat, info, feas, choice, gen, i, k, x, y, max_error, cellvalid, sx, sy
                )
                and _hole_feasible(
                    h, vx, vy, ring, d, tstat, dstat, info, feas, choice, gen, k, j, x, y, max_error, cellvalid, sx, sy
                )
                and _hole_feasible(
                    h, vx, vy, ring, d, tstat, dstat, info, feas, choice, gen, j, i + d, x, y, max_error, cellvalid,
                    sx, sy
                )
            ):
                found = q
                break
        if found < 0:
            continue
        # commit: d - 2 triangles in the first d - 2 of the star's d slots. A stack of (a, apex, b,
        # twin of the edge b -> a); the first entry is the triangle holding v, whose three sides all
        # border sub-polygons (twin -1 marks it).
        ns = 0
        stk[0] = cand[found, 0]
        stk[1] = cand[found, 1]
        stk[2] = cand[found, 2]
        stk[3] = -1
        sp = 4
        while sp > 0:
            sp -= 4
            a = stk[sp]
            m = stk[sp + 1]
            b = stk[sp + 2]
            tw = stk[sp + 3]
            base = ring_e[ns] - ring_e[ns] % 3
            ns += 1
            tri[base] = ring[a % d]
            tri[base + 1] = ring[m % d]
            tri[base + 2] = ring[b % d]
            vedge[ring[a % d]] = base
            vedge[ring[m % d]] = base + 1
            vedge[ring[b % d]] = base + 2
            for side in range(3):
                he = base + side
                if side == 0:
                    s0, s1 = a, m
                elif side == 1:
                    s0, s1 = m, b
                elif tw >= 0:
                    half[he] = tw
                    half[tw] = he
                    continue
                else:
                    s0, s1 = b, a + d
                if s1 - s0 == 1:
                    o = outer[s0 % d]  # a side of the hole
                    half[he] = o
                    if o >= 0:
                        half[o] = he
                else:  # a diagonal: the sub-polygon's triangle on it has it as its edge s1 -> s0
                    stk[sp] = s0
                    stk[sp + 1] = s0 + choice[s0 % d, s1 - s0]
                    stk[sp + 2] = s1
                    stk[sp + 3] = he
                    sp += 4
        for q in range(ns, d):
            base = ring_e[q] - ring_e[q] % 3
            tri[base] = -1
            tri[base + 1] = -1
            tri[base + 2] = -1
        removed += 1
    return removed


# --------------------------------------------------------------------------------------------------
# 1D: bounded-error polyline simplification
# --------------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def simplify_runs(z: np.ndarray, valid: np.ndarray, max_error: float) -> np.ndarray:
    """Keep-mask (N,) bool of a bounded-error simplification of each run of valid samples of ``z``.

    Top-down splitting at the worst sample (Douglas & Peucker 1973) on vertical distance. In 1D the
    max of |polyline - chord| is attained at samples, so checking samples is exact. The result
    depends only on ``z[run]`` and ``max_error``, scanned in index order (first maximum wins).
    """
    n = z.size
    keep = np.zeros(n, dtype=np.bool_)
    stack = np.empty(2 * n + 2, dtype=np.int64)
    i = 0
    while i < n:
        if not valid[i]:
            i += 1
            continue
        j = i
        while j + 1 < n and valid[j + 1]:
            j += 1
        keep[i] = True
        keep[j] = True
        sp = 0
        if j - i > 1:
            stack[0] = i
            stack[1] = j
            sp = 2
        while sp > 0:
            sp -= 2
            lo = stack[sp]
            hi = stack[sp + 1]
            zl = z[lo]
            slope = (z[hi] - zl) / (hi - lo)
            worst = 0.0
            at = -1
            for k in range(lo + 1, hi):
                e = abs((zl - z[k]) + slope * (k - lo))
                if e > worst:
                    worst = e
                    at = k
            if worst > max_error:
                keep[at] = True
                if at - lo > 1:
                    stack[sp] = lo
                    stack[sp + 1] = at
                    sp += 2
                if hi - at > 1:
                    stack[sp] = at
                    stack[sp + 1] = hi
                    sp += 2
        i = j + 1
    return keep


# --------------------------------------------------------------------------------------------------
# independent evaluator and coverage (share nothing with the inserter above)
# --------------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _grid_z(h: np.ndarray, valid: np.ndarray, r: float, c: float) -> float:
    """Height of the grid surface (diagonal (i,j)-(i+1,j+1) per cell) at (r, c); NaN if no-data."""
    H, W = h.shape
    i = min(max(int(np.floor(r)), 0), H - 2) if H > 1 else 0
    j = min(max(int(np.floor(c)), 0), W - 2) if W > 1 else 0
    v = r - i
    u = c - j
    i1 = min(i + 1, H - 1)
    j1 = min(j + 1, W - 1)
    if u >= v:
        if not (valid[i, j] and valid[i, j1] and valid[i1, j1]):
            return np.nan
        return h[i, j] + u * (h[i, j1] - h[i, j]) + v * (h[i1, j1] - h[i, j1])
    if not (valid[i, j] and valid[i1, j] and valid[i1, j1]):
        return np.nan
    return h[i, j] + v * (h[i1, j] - h[i, j]) + u * (h[i1, j1] - h[i1, j])


@njit(cache=True, nogil=True)
def eval_max_error(
    h: np.ndarray,
    valid: np.ndarray,
    vr: np.ndarray,
    vc: np.ndarray,
    vz: np.ndarray,
    faces: np.ndarray,
) -> tuple[float, float, float]:
    """Max |TIN - grid| at grid samples in faces and at face-edge / grid-line crossings.

    Written independently of `build_tin`: floating-point barycentrics and a generic line-crossing
    parametrisation. Returns (error, row, col) of the worst point; (0, nan, nan) when nothing is covered.
    """
    worst = 0.0
    wr = np.nan
    wc = np.nan
    for f in range(faces.shape[0]):
        ia, ib, ic = faces[f, 0], faces[f, 1], faces[f, 2]
        ra, ca, za = float(vr[ia]), float(vc[ia]), vz[ia]
        rb, cb, zb = float(vr[ib]), float(vc[ib]), vz[ib]
        rc, cc, zc = float(vr[ic]), float(vc[ic]), vz[ic]
        det = (rb - ra) * (cc - ca) - (rc - ra) * (cb - ca)
        if det == 0.0:
            continue
        # samples: barycentric coordinates of every sample in the bounding box
        for r in range(int(min(ra, rb, rc)), int(max(ra, rb, rc)) + 1):
            for c in range(int(min(ca, cb, cc)), int(max(ca, cb, cc)) + 1):
                lb = ((r - ra) * (cc - ca) - (rc - ra) * (c - ca)) / det
                lc = ((rb - ra) * (c - ca) - (r - ra) * (cb - ca)) / det
                if lb < -1e-12 or lc < -1e-12 or lb + lc > 1.0 + 1e-12:
                    continue
                if not valid[r, c]:
                    continue
                e = abs((za - h[r, c]) + lb * (zb - za) + lc * (zc - za))
                if e > worst:
                    worst, wr, wc = e, float(r), float(c)
        # crossings of each edge with every grid line n.(r, c) = k, n in {(0,1), (1,0), (-1,1)}
        for k in range(3):
            if k == 0:
                r0, c0, z0, r1, c1, z1 = ra, ca, za, rb, cb, zb
            elif k == 1:
                r0, c0, z0, r1, c1, z1 = rb, cb, zb, rc, cc, zc
            else:
                r0, c0, z0, r1, c1, z1 = rc, cc, zc, ra, ca, za
            for fam in range(3):
                nr = 0.0 if fam == 0 else (1.0 if fam == 1 else -1.0)
                nc = 1.0 if fam != 1 else 0.0
                s0 = nr * r0 + nc * c0
                s1 = nr * r1 + nc * c1
                if s0 == s1:
                    continue
                for line in range(int(np.ceil(min(s0, s1))), int(np.floor(max(s0, s1))) + 1):
                    t = (line - s0) / (s1 - s0)
                    if t <= 0.0 or t >= 1.0:
                        continue
                    rf = r0 + t * (r1 - r0)
                    cf = c0 + t * (c1 - c0)
                    g = _grid_z(h, valid, rf, cf)
                    if np.isnan(g):
                        continue
                    e = abs((z0 - g) + t * (z1 - z0))
                    if e > worst:
                        worst, wr, wc = e, rf, cf
    return worst, wr, wc


@njit(cache=True, nogil=True)
def _clip_area(px: np.ndarray, py: np.ndarray, n: int, x0: float, y0: float) -> float:
    """Area of polygon (px, py)[:n] clipped to the unit square at (x0, y0) (Sutherland-Hodgman)."""
    bx = np.empty(16)
    by = np.empty(16)
    cx = px[:n].copy()
    cy = py[:n].copy()
    m = n
    for side in range(4):
        k = 0
        for i in range(m):
            ax, ay = cx[i], cy[i]
            qx, qy = cx[(i + 1) % m], cy[(i + 1) % m]
            if side == 0:
                da, dq = ax - x0, qx - x0
            elif side == 1:
                da, dq = x0 + 1.0 - ax, x0 + 1.0 - qx
            elif side == 2:
                da, dq = ay - y0, qy - y0
            else:
                da, dq = y0 + 1.0 - ay, y0 + 1.0 - qy
            if da >= 0:
                bx[k], by[k] = ax, ay
                k += 1
            if (da >= 0) != (dq >= 0):
                s = da / (da - dq)
                bx[k], by[k] = ax + s * (qx - ax), ay + s * (qy - ay)
                k += 1
        m = k
        if m == 0:
            return 0.0
        cx = bx[:m].copy()
        cy = by[:m].copy()
    a = 0.0
    for i in range(m):
        a += cx[i] * cy[(i + 1) % m] - cx[(i + 1) % m] * cy[i]
    return abs(a) / 2.0


@njit(cache=True, nogil=True)
def cell_coverage(
    shape_cells: tuple[int, int], vr: np.ndarray, vc: np.ndarray, faces: np.ndarray
) -> np.ndarray:
    """(H-1, W-1) float64 sum over faces of the area of face ∩ cell (cells have area 1)."""
    cov = np.zeros(shape_cells)
    px = np.empty(3)
    py = np.empty(3)
    for f in range(faces.shape[0]):
        for k in range(3):
            px[k] = vc[faces[f, k]]
            py[k] = vr[faces[f, k]]
        for i in range(max(int(py.min()), 0), min(int(np.ceil(py.max())), shape_cells[0])):
            for j in range(max(int(px.min()), 0), min(int(np.ceil(px.max())), shape_cells[1])):
                cov[i, j] += _clip_area(px, py, 3, float(j), float(i))
    return cov


# --------------------------------------------------------------------------------------------------
# stage 2 of a DSM tile: neighbours' border samples inserted as fans (see dsm._insert_border_vertices)
# --------------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _mids(pos: np.ndarray, u: int, w: int) -> tuple[int, int]:
    """The slice [i, j) of sorted ``pos`` strictly between ``u`` and ``w``."""
    lo = min(u, w)
    hi = max(u, w)
    return int(np.searchsorted(pos, lo, side="right")), int(np.searchsorted(pos, hi, side="left"))


@njit(cache=True, nogil=True)
def border_fans(vr: np.ndarray, vc: np.ndarray, faces: np.ndarray, side_ax: np.ndarray, side_line: np.ndarray,
                side_limit: np.ndarray, want: np.ndarray, want_off: np.ndarray, last_r: int, last_c: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The kernel of :func:`citylod.lod.build.dsm._insert_border_vertices`. Side ``s`` is the grid line ``side_line[s]`` of axis ``side_ax[s]`` (0: a row, 1: a column),
    positions 0..``side_limit[s]`` along it; the samples wanted on it are ``want[want_off[s]:want_off[s + 1]]``
    (any order, repeats and positions off the side allowed: those and the ones already vertices on the
    line are dropped).

    Returns the added vertices (row, col) in order of first use, the faces (unchanged ones first, in their
    order, then each replaced face's fan in order), and the replaced-face mask. A face is replaced when one
    of its edges lies on a side and passes over one of its samples; it is split at the samples of the first
    side (in the given order) its edge lies on, and each piece again, depth first.
    """
    m = faces.shape[0]
    nsides = side_ax.shape[0]
    n_old = vr.shape[0]
    # The wanted samples of each side, sorted and distinct, without those already vertices on its line.
    pos = np.empty(want.shape[0], np.int64)
    pos_off = np.zeros(nsides + 1, np.int64)
    for s in range(nsides):
        limit = side_limit[s]
        mark = np.zeros(limit + 1, np.bool_)
        for i in range(want_off[s], want_off[s + 1]):
            if 0 <= want[i] <= limit:
                mark[want[i]] = True
        for v in range(n_old):
            if side_ax[s] == 0 and vr[v] == side_line[s] and 0 <= vc[v] <= limit:
                mark[vc[v]] = False
            elif side_ax[s] == 1 and vc[v] == side_line[s] and 0 <= vr[v] <= limit:
                mark[vr[v]] = False
        n = pos_off[s]
        for p in range(limit + 1):
            if mark[p]:
                pos[n] = p
                n += 1
        pos_off[s + 1] = n
    pos = pos[:pos_off[nsides]]
    hit = np.zeros(m, np.bool_)
    n_hit = 0
    for t in range(m):
        for k in range(3):
            a = faces[t, k]
            b = faces[t, (k + 1) % 3]
            for s in range(nsides):
                if side_ax[s] == 0:
                    on = vr[a] == side_line[s] and vr[b] == side_line[s]
                    u, w = vc[a], vc[b]
                else:
                    on = vc[a] == side_line[s] and vc[b] == side_line[s]
                    u, w = vr[a], vr[b]
                if on:
                    i, j = _mids(pos[pos_off[s]:pos_off[s + 1]], u, w)
                    if j > i:
                        hit[t] = True
        n_hit += hit[t]
    width = last_c + 1
    index = np.full((last_r + 1) * width, -1, np.int64)
    added = np.empty((max(pos.shape[0], 1), 2), np.int64)
    n_add = 0
    out = np.empty((m - n_hit + 8 * n_hit + 4 * pos.shape[0], 3), np.int64)
    n_out = 0
    for t in range(m):
        if not hit[t]:
            out[n_out, 0], out[n_out, 1], out[n_out, 2] = faces[t, 0], faces[t, 1], faces[t, 2]
            n_out += 1
    stack = np.empty((3 * pos.shape[0] + 8, 3), np.int64)
    chain = np.empty(pos.shape[0] + 2, np.int64)
    for t0 in range(m):
        if not hit[t0]:
            continue
        stack[0, 0], stack[0, 1], stack[0, 2] = faces[t0, 0], faces[t0, 1], faces[t0, 2]
        sp = 1
        while sp > 0:
            sp -= 1
            t_a, t_b, t_c = stack[sp, 0], stack[sp, 1], stack[sp, 2]
            split = False
            for k in range(3):
                if k == 0:
                    a, b, o = t_a, t_b, t_c
                elif k == 1:
                    a, b, o = t_b, t_c, t_a
                else:
                    a, b, o = t_c, t_a, t_b
                ra = vr[a] if a < n_old else added[a - n_old, 0]
                ca = vc[a] if a < n_old else added[a - n_old, 1]
                rb = vr[b] if b < n_old else added[b - n_old, 0]
                cb = vc[b] if b < n_old else added[b - n_old, 1]
                nm = 0
                for s in range(nsides):
                    line = side_line[s]
                    if pos_off[s + 1] == pos_off[s]:
                        continue  # no sample left on this side: as if it had not been asked for
                    if side_ax[s] == 0:
                        if not (ra == line and rb == line):
                            continue
                        u, w = ca, cb
                    else:
                        if not (ca == line and cb == line):
                            continue
                        u, w = ra, rb
                    sub = pos[pos_off[s]:pos_off[s + 1]]
                    i, j = _mids(sub, u, w)
                    chain[0] = a
                    for q in range(j - i):
                        p = sub[i + q] if u < w else sub[j - 1 - q]
                        r = line if side_ax[s] == 0 else p
                        c = p if side_ax[s] == 0 else line
                        key = r * width + c
                        if index[key] < 0:
                            index[key] = n_old + n_add
                            added[n_add, 0], added[n_add, 1] = r, c
                            n_add += 1
                        chain[1 + q] = index[key]
                    nm = j - i
                    break  # the first side the edge lies on decides
                if nm > 0:
                    chain[nm + 1] = b
                    for q in range(nm, -1, -1):  # pushed in reverse: popped (and emitted) in chain order
                        stack[sp, 0], stack[sp, 1], stack[sp, 2] = chain[q], chain[q + 1], o
                        sp += 1
                    split = True
                    break
            if not split:
                out[n_out, 0], out[n_out, 1], out[n_out, 2] = t_a, t_b, t_c
                n_out += 1
    return added[:n_add].copy(), out[:n_out].copy(), hit


# --------------------------------------------------------------------------------------------------
# `tin.build`'s preparation and clean-up, compiled (numpy's dozen small passes cost a millisecond a tile)
# --------------------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def forced_mask(hz: np.ndarray, valid: np.ndarray, cellvalid: np.ndarray, border_error: float) -> np.ndarray:
    """`tin.forced_vertices` (grid of at least 2 × 2) in one compiled pass: the corners, each border's valid
    runs simplified to ``border_error`` (`simplify_runs`), and every sample on the boundary of the valid
    region. ``hz`` are the heights with no-data as 0, ``cellvalid`` `tin.cell_validity` of ``valid``."""
    H, W = hz.shape
    out = np.zeros((H, W), np.bool_)
    out[0, 0] = out[0, W - 1] = out[H - 1, 0] = out[H - 1, W - 1] = True
    for side in range(4):
        if side == 0:
            z, v = hz[0, :].copy(), valid[0, :].copy()
        elif side == 1:
            z, v = hz[H - 1, :].copy(), valid[H - 1, :].copy()
        elif side == 2:
            z, v = hz[:, 0].copy(), valid[:, 0].copy()
        else:
            z, v = hz[:, W - 1].copy(), valid[:, W - 1].copy()
        keep = simplify_runs(z, v, border_error)
        for k in range(keep.size):
            if keep[k]:
                if side == 0:
                    out[0, k] = True
                elif side == 1:
                    out[H - 1, k] = True
                elif side == 2:
                    out[k, 0] = True
                else:
                    out[k, W - 1] = True
    # a sample is on the boundary of the valid region iff some but not all of its in-grid cells are valid
    for i in range(H):
        for j in range(W):
            n_cells = 0
            n_valid = 0
            for ci in range(i - 1, i + 1):
                for cj in range(j - 1, j + 1):
                    if 0 <= ci < H - 1 and 0 <= cj < W - 1:
                        n_cells += 1
                        n_valid += cellvalid[ci, cj]
            if 0 < n_valid < n_cells:
                out[i, j] = True
    return out


@njit(cache=True, nogil=True)
def z_ordered(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The samples of ``mask`` as (columns, rows) in Z order (bits of column and row interleaved), so
    consecutive insertions are close and point location walks are short."""
    H, W = mask.shape
    n = 0
    for i in range(H):
        for j in range(W):
            n += mask[i, j]
    rows = np.empty(n, np.int64)
    cols = np.empty(n, np.int64)
    keys = np.zeros(n, np.int64)
    n = 0
    for i in range(H):
        for j in range(W):
            if mask[i, j]:
                rows[n] = i
                cols[n] = j
                key = 0
                for b in range(16):
                    key |= ((j >> b) & 1) << (2 * b)
                    key |= ((i >> b) & 1) << (2 * b + 1)
                keys[n] = key
                n += 1
    order = np.argsort(keys, kind="mergesort")
    return cols[order], rows[order]


@njit(cache=True, nogil=True)
def live_mesh(vx: np.ndarray, vy: np.ndarray, tris: np.ndarray, cellvalid: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """The triangles of ``build_tin`` inside the valid region (centroid cell valid; see `tin`), and the
    vertices they use, in index order: (V, 2) int32 (row, col) and (F, 3) int32 renumbered faces."""
    H = cellvalid.shape[0] + 1
    W = cellvalid.shape[1] + 1
    nt = tris.shape[0]
    keep = np.zeros(nt, np.bool_)
    used = np.zeros(vx.size, np.bool_)
    nk = 0
    for t in range(nt):
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        ci = min((vy[a] + vy[b] + vy[c]) // 3, H - 2)
        cj = min((vx[a] + vx[b] + vx[c]) // 3, W - 2)
        if cellvalid[ci, cj]:
            keep[t] = True
            used[a] = used[b] = used[c] = True
            nk += 1
    remap = np.full(vx.size, -1, np.int32)
    n = 0
    for v in range(vx.size):
        if used[v]:
            remap[v] = n
            n += 1
    vertices = np.empty((n, 2), np.int32)
    for v in range(vx.size):
        if used[v]:
            vertices[remap[v], 0] = vy[v]
            vertices[remap[v], 1] = vx[v]
    faces = np.empty((nk, 3), np.int32)
    k = 0
    for t in range(nt):
        if keep[t]:
            faces[k, 0] = remap[tris[t, 0]]
            faces[k, 1] = remap[tris[t, 1]]
            faces[k, 2] = remap[tris[t, 2]]
            k += 1
    return vertices, faces
