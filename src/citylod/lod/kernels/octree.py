"""Octree kernels for point clouds: integer cell addressing, counting sorts, vertex clustering, Morton order.

Every point gets integer coordinates ``q`` on a 2^:data:`QBITS` grid over the cloud's bounding cube, once,
from float64. All octree arithmetic after that is integer shifts, so a node's octants, its 64³ clustering
grid, its parent's grid and the 128³ counting grid of the out-of-core pass nest *exactly*: a parent's
clustering cell is exactly 2×2×2 of its children's cells, whatever floating point would have rounded.

Hot loops are numba kernels (``cache=True``); everything else is vectorised numpy. No I/O, no VTK, no Qt.
"""

from __future__ import annotations

from concurrent.futures import Executor

import numba
import numpy as np
import numpy.typing as npt

from citylod.core.jit import defer_blas_probe
from citylod.lod.kernels.aot import kernel

defer_blas_probe()  # before any kernel loads: numba starts without importing scipy.linalg

#: Bits of the integer grid per axis. Level L nodes are 2^(QBITS-L) units wide.
QBITS = 31
#: Vertex clustering grid per node: 2^6 = 64 cells per axis (Wahl, Guthe, Klein, PG 2005).
CLUSTER_BITS = 6
#: Deepest level: a node there still has a full 64³ clustering grid of whole integer units.
MAX_LEVEL = QBITS - CLUSTER_BITS - 1

I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]


def quantize(xyz: F64, cube_lo: F64, cube_size: float) -> I64:
    """Integer grid coordinates of points.

    Parameters
    ----------
    xyz
        (N, 3) float64 positions.
    cube_lo
        (3,) float64 lower corner of the bounding cube.
    cube_size
        Edge length of the cube.

    Returns
    -------
    (N, 3) int64 in [0, 2^QBITS), clamped, so a point on the upper face or a header that understated the
    bounds still lands in the cube.
    """
    return _quantize(np.asarray(xyz, np.float64), np.asarray(cube_lo, np.float64), float(1 << QBITS) / cube_size)


@numba.njit(cache=True, nogil=True, inline="always")
def grid_coord(v: float, lo: float, scale: float) -> int:  # pragma: no cover - compiled
    """One coordinate on the integer grid (``scale`` = 2^QBITS / cube size), clamped into the cube."""
    g = np.floor((v - lo) * scale)
    top = (1 << QBITS) - 1
    return 0 if not g > 0 else top if g > top else int(g)


@numba.njit(cache=True, nogil=True)
def _quantize(xyz: F64, cube_lo: F64, scale: float) -> I64:  # pragma: no cover - compiled
    n = xyz.shape[0]
    q = np.empty((n, 3), np.int64)
    for i in range(n):
        for a in range(3):
            q[i, a] = grid_coord(xyz[i, a], cube_lo[a], scale)
    return q


def bounds(xyz: F64) -> tuple[F64, F64]:
    """(3,) float64 lower and upper corner of (N, 3) positions, N > 0, in one compiled pass without the GIL
    (numpy reduces an (N, 3) array along axis 0 about 20 times slower than column by column)."""
    return kernel(_bounds, np.ascontiguousarray(xyz, np.float64))


@numba.njit(cache=True, nogil=True)
def _bounds(xyz: F64) -> tuple[F64, F64]:  # pragma: no cover - compiled
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for i in range(xyz.shape[0]):
        for a in range(3):
            v = xyz[i, a]
            lo[a] = min(lo[a], v)
            hi[a] = max(hi[a], v)
    return lo, hi


@numba.njit(cache=True, nogil=True, inline="always")
def _cell_key(q: I64, i: int, shift: int) -> int:  # pragma: no cover - compiled
    # Flat index x + 64·y + 64²·z of point i's cell in the 64³ grid of a node (``shift`` = QBITS − level − 6).
    mask = (1 << CLUSTER_BITS) - 1
    return (((q[i, 0] >> shift) & mask) | (((q[i, 1] >> shift) & mask) << CLUSTER_BITS)
            | (((q[i, 2] >> shift) & mask) << (2 * CLUSTER_BITS)))


@numba.njit(cache=True, nogil=True)
def _cluster(q: I64, shift: int, xyz: F64, sums: F64, counts: I64, nbins: int
             ) -> tuple[I64, I64, F64, I64]:  # pragma: no cover - compiled
    # Only the occupied cells are visited (not all 64³); candidates are taken in input order, so each
    # cell gets the same sums (same order of additions) and the same representative (the first nearest)
    # as a stable counting sort by cell would give.
    keys = np.empty(q.shape[0], np.int64)
    for i in range(q.shape[0]):
        keys[i] = _cell_key(q, i, shift)
    slot = np.full(nbins, -1, np.int32)
    cells = np.empty(keys.shape[0], np.int64)
    ncell = 0
    for i in range(keys.shape[0]):
        k = keys[i]
        if slot[k] < 0:
            slot[k] = 0
            cells[ncell] = k
            ncell += 1
    cells = np.sort(cells[:ncell])
    for c in range(ncell):
        slot[cells[c]] = c
    out_sums = np.zeros((ncell, 3))
    out_counts = np.zeros(ncell, np.int64)
    for i in range(keys.shape[0]):
        c = slot[keys[i]]
        out_sums[c, 0] += sums[i, 0]
        out_sums[c, 1] += sums[i, 1]
        out_sums[c, 2] += sums[i, 2]
        out_counts[c] += counts[i]
    rep = np.full(ncell, -1, np.int64)
    bd = np.full(ncell, np.inf)
    for i in range(keys.shape[0]):
        c = slot[keys[i]]
        cnt = out_counts[c]
        mx, my, mz = out_sums[c, 0] / cnt, out_sums[c, 1] / cnt, out_sums[c, 2] / cnt
        d = (xyz[i, 0] - mx) ** 2 + (xyz[i, 1] - my) ** 2 + (xyz[i, 2] - mz) ** 2
        if d < bd[c]:
            bd[c] = d
            rep[c] = i
    return cells, rep, out_sums, out_counts


def cluster(q: I64, xyz: F64, sums: F64, counts: I64, level: int) -> tuple[I64, I64, F64, I64]:
    """Vertex clustering on the 64³ grid of a level-``level`` node (Wahl, Guthe, Klein, PG 2005).

    The candidates are the children's representatives; each carries the sum and count of the input
    points it stands for, so the cluster mean is the mean of the *input* points in the cell. The
    representative is the candidate nearest that mean: a real input point, so its attributes are true.

    Parameters
    ----------
    q
        (K, 3) int64 grid coordinates of the candidates.
    xyz
        (K, 3) float64 candidate positions.
    sums
        (K, 3) float64 sum of the input positions each candidate stands for.
    counts
        (K,) int64 number of input points each candidate stands for.
    level
        The node's level.

    Returns
    -------
    cells
        (C,) int64 sorted flat cell indices of the occupied cells.
    rep
        (C,) int64 index of each cell's representative among the candidates.
    sums, counts
        (C, 3) float64 and (C,) int64 aggregated over the cell.
    """
    return _cluster(q, QBITS - level - CLUSTER_BITS, xyz, sums, counts, 1 << (3 * CLUSTER_BITS))


@numba.njit(cache=True, nogil=True)
def _spread10(v: I64) -> I64:  # pragma: no cover - compiled
    v = v & 0x3FF
    v = (v | (v << 16)) & 0x030000FF
    v = (v | (v << 8)) & 0x0300F00F
    v = (v | (v << 4)) & 0x030C30C3
    v = (v | (v << 2)) & 0x09249249
    return v


@numba.njit(cache=True, nogil=True)
def _morton(q: I64, shift: int) -> I64:  # pragma: no cover - compiled
    n = q.shape[0]
    out = np.empty(n, np.int64)
    for i in range(n):
        out[i] = (_spread10(q[i, 0] >> shift) | (_spread10(q[i, 1] >> shift) << 1)
                  | (_spread10(q[i, 2] >> shift) << 2))
    return out


def morton_order(q: I64, level: int) -> I64:
    """(N,) int64 permutation sorting points of one level-``level`` node in Morton (Z-curve) order.

    Codes use the 10 bits per axis below the node's level (a 1024³ grid over the node).
    """
    if len(q) == 0:
        return np.zeros(0, np.int64)
    return _radix_argsort30(_morton(q, max(QBITS - level - 10, 0)))


@numba.njit(cache=True, nogil=True)
def _radix_argsort30(codes: I64) -> I64:  # pragma: no cover - compiled
    """Stable argsort of codes in [0, 2^30): three passes of a 10-bit LSD radix sort (the same
    permutation as ``np.argsort(codes, kind="stable")``, several times faster)."""
    n = codes.shape[0]
    order = np.arange(n)
    tmp = np.empty(n, np.int64)
    cnt = np.empty(1025, np.int64)
    for shift in (0, 10, 20):
        cnt[:] = 0
        for t in range(n):
            cnt[((codes[order[t]] >> shift) & 1023) + 1] += 1
        for b in range(1024):
            cnt[b + 1] += cnt[b]
        for t in range(n):
            i = order[t]
            b = (codes[i] >> shift) & 1023
            tmp[cnt[b]] = i
            cnt[b] += 1
        order, tmp = tmp, order
    return order


def shuffled_runs(n: int, seed: int, batch: int) -> I64:
    """The order in which a node's ``n`` Morton-ordered points are written: runs of ``batch`` consecutive
    points, the runs shuffled (what :func:`point_columns` takes).

    Each run stays spatially compact (cache-friendly) while any prefix of the result is a roughly uniform
    subsample of the node, so a renderer with a point budget can draw the first k points (smooth
    refinement, Kehl et al.; Potree's point budgets). ``seed`` makes the order reproducible, so every
    executor writes the same tileset.
    """
    return _permutation(-(-n // batch), seed & 0x7FFFFFFFFFFFFFFF)  # an int64 for the kernel


@numba.njit(cache=True, nogil=True)
def _permutation(n: int, seed: int) -> I64:  # pragma: no cover - compiled
    """A permutation of ``0..n-1``: Fisher–Yates driven by SplitMix64 (Steele et al. 2014) from ``seed``.

    Written out because seeding numpy's ``Generator`` costs tens of microseconds under the GIL per node,
    which on a point build added up to more than the shuffle itself; statistical quality beyond "not
    spatially ordered" does not matter here.
    """
    out = np.arange(n)
    s = np.uint64(seed)
    for i in range(n - 1, 0, -1):
        s += np.uint64(0x9E3779B97F4A7C15)
        z = s
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
        j = np.int64(z % np.uint64(i + 1))
        out[i], out[j] = out[j], out[i]
    return out


@numba.njit(cache=True, nogil=True)
def point_columns(recs: npt.NDArray[np.void], xyz: F64, order: I64, runs: I64, batch: int, center: F64
                  ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8], npt.NDArray[np.uint16],
                             npt.NDArray[np.uint8], npt.NDArray[np.uint8],
                             npt.NDArray[np.uint8]]:  # pragma: no cover - compiled
    """A node's drawn columns in one compiled pass, without the GIL: the points ``order[t]`` taken in runs
    of ``batch`` whose order is ``runs`` (:func:`shuffled_runs`), split out of their records (``recs``,
    POINT_DTYPE) into contiguous arrays.

    Returns positions relative to ``center`` (float32), RGB, intensity, classification, return number and
    the synthetic flag.
    The per-node numpy calls it replaces held the GIL for most of a leaf's time, which kept a build's two
    threads from running nodes side by side.
    """
    n = order.shape[0]
    pos = np.empty((n, 3), np.float32)
    rgb = np.empty((n, 3), np.uint8)
    inten = np.empty(n, np.uint16)
    cls = np.empty(n, np.uint8)
    ret = np.empty(n, np.uint8)
    syn = np.empty(n, np.uint8)
    cx, cy, cz = center[0], center[1], center[2]
    k = 0
    for r in runs:
        for t in range(r * batch, min(r * batch + batch, n)):
            i = order[t]
            pos[k, 0] = xyz[i, 0] - cx
            pos[k, 1] = xyz[i, 1] - cy
            pos[k, 2] = xyz[i, 2] - cz
            rec = recs[i]
            inten[k] = rec.intensity
            cls[k] = rec.classification
            ret[k] = rec.return_number
            syn[k] = rec.synthetic
            rgb[k, 0], rgb[k, 1], rgb[k, 2] = rec.red, rec.green, rec.blue
            k += 1
    return pos, rgb, inten, cls, ret, syn


def partition(q: I64, level: int, idx: tuple[int, int, int], max_leaf_points: int, max_level: int,
              pool: Executor | None = None) -> tuple[I64, I64]:
    """The octree under one node, partitioned in one compiled pass (PotreeConverter 2's counting sort).

    A node with at most ``max_leaf_points`` points, or at ``max_level``, is a leaf; any other node is
    split into its 8 octants by a stable counting sort, so the points of every node are one contiguous
    run of the returned order and, within a leaf, keep their input order.

    Parameters
    ----------
    q
        (N, 3) int64 grid coordinates of the node's points.
    level, idx
        The node's level and integer index (x, y, z).
    max_leaf_points, max_level
        The leaf rule.

    Returns
    -------
    order
        (N,) int64 permutation of the points: node ``k`` holds ``order[nodes[k, 4]:nodes[k, 5]]``.
    nodes
        (M, 7) int64 rows (level, x, y, z, start, end, parent), in pre-order (children after their
        parent, siblings in octant order); the parent of the first row is -1.

    With ``pool`` (threads), the root is split first and its octants are partitioned as tasks of their
    own, side by side (the kernel releases the GIL); the result is the same.
    """
    order = np.arange(q.shape[0])
    x, y, z = (int(v) for v in idx)
    if pool is None or level >= max_level or len(order) <= max_leaf_points:
        return order, _partition(q, order, level, x, y, z, max_leaf_points, max_level)
    top = _partition(q, order, level, x, y, z, max_leaf_points, level + 1)  # the root and its octants
    subs = [pool.submit(_partition, q, order[a:b], lv, cx, cy, cz, max_leaf_points, max_level)
            for lv, cx, cy, cz, a, b, _ in top[1:]]
    parts = [top[:1]]
    base = 1
    for (*_, a, _b, _p), fut in zip(top[1:], subs, strict=True):
        sub = fut.result().copy()
        sub[:, 4:6] += a
        sub[1:, 6] += base
        sub[0, 6] = 0
        parts.append(sub)
        base += len(sub)
    return order, np.concatenate(parts)


@numba.njit(cache=True, nogil=True)
def _partition(q: I64, order: I64, level: int, x0: int, y0: int, z0: int, max_leaf_points: int,
               max_level: int) -> I64:  # pragma: no cover - compiled
    """:func:`partition` of the points ``order`` (permuted in place); the nodes' start and end index
    ``order``."""
    n = order.shape[0]
    tmp = np.empty(n, np.int64)
    out = np.empty((64, 7), np.int64)
    m = 0
    stack = np.empty((8 * (max_level + 2) + 8, 7), np.int64)
    stack[0, 0], stack[0, 1], stack[0, 2], stack[0, 3] = level, x0, y0, z0
    stack[0, 4], stack[0, 5], stack[0, 6] = 0, n, -1
    sp = 1
    cnt = np.zeros(9, np.int64)
    fill = np.zeros(8, np.int64)
    while sp > 0:
        sp -= 1
        if m == out.shape[0]:
            grown = np.empty((2 * m, 7), np.int64)
            grown[:m] = out
            out = grown
        for c in range(7):
            out[m, c] = stack[sp, c]
        me = m
        m += 1
        lv, x, y, z, a, b = out[me, 0], out[me, 1], out[me, 2], out[me, 3], out[me, 4], out[me, 5]
        if b - a <= max_leaf_points or lv >= max_level:
            continue
        s = QBITS - lv - 1
        cnt[:] = 0
        for t in range(a, b):
            i = order[t]
            cnt[1 + (((q[i, 0] >> s) & 1) | (((q[i, 1] >> s) & 1) << 1) | (((q[i, 2] >> s) & 1) << 2))] += 1
        for o in range(8):
            cnt[o + 1] += cnt[o]
            fill[o] = a + cnt[o]
        for t in range(a, b):
            i = order[t]
            o = ((q[i, 0] >> s) & 1) | (((q[i, 1] >> s) & 1) << 1) | (((q[i, 2] >> s) & 1) << 2)
            tmp[fill[o]] = i
            fill[o] += 1
        order[a:b] = tmp[a:b]
        for o in range(7, -1, -1):  # pushed in reverse, so popped (numbered) in octant order
            if cnt[o + 1] > cnt[o]:
                stack[sp, 0], stack[sp, 1] = lv + 1, 2 * x + (o & 1)
                stack[sp, 2], stack[sp, 3] = 2 * y + ((o >> 1) & 1), 2 * z + ((o >> 2) & 1)
                stack[sp, 4], stack[sp, 5], stack[sp, 6] = a + cnt[o], a + cnt[o + 1], me
                sp += 1
    return out[:m]


def gather_points(recs: npt.NDArray[np.void], q: I64, xyz: F64, order: I64, pool: Executor | None = None
                  ) -> tuple[npt.NDArray[np.void], I64, F64]:
    """``recs[order]``, ``q[order]``, ``xyz[order]`` in one compiled pass without the GIL, in two halves
    side by side with ``pool``: numpy's three gathers hold the GIL in the build's serial stretch."""
    n = len(order)
    out = np.empty(n, recs.dtype), np.empty((n, 3), np.int64), np.empty((n, 3))
    if pool is None or n < 100_000:
        _gather(recs, q, xyz, order, 0, n, *out)
        return out
    half = n // 2
    fut = pool.submit(_gather, recs, q, xyz, order, half, n, *out)
    _gather(recs, q, xyz, order, 0, half, *out)
    fut.result()
    return out


@numba.njit(cache=True, nogil=True)
def _gather(recs: npt.NDArray[np.void], q: I64, xyz: F64, order: I64, a: int, b: int,
            out_recs: npt.NDArray[np.void], out_q: I64, out_xyz: F64) -> None:  # pragma: no cover - compiled
    for t in range(a, b):
        i = order[t]
        out_recs[t] = recs[i]
        for c in range(3):
            out_q[t, c] = q[i, c]
            out_xyz[t, c] = xyz[i, c]


@numba.njit(cache=True, nogil=True)
def _lookup_error(q: I64, xyz: F64, shift: int, cells: I64, elem: F64) -> float:  # pragma: no cover - compiled
    # A dense table over the 64³ grid (1 MiB) instead of a binary search per point.
    lut = np.full(1 << (3 * CLUSTER_BITS), -1, np.int32)
    for c in range(cells.shape[0]):
        lut[cells[c]] = c
    best = 0.0
    for i in range(q.shape[0]):
        e = lut[_cell_key(q, i, shift)]
        if e < 0:
            return -1.0
        dx, dy, dz = xyz[i, 0] - elem[e, 0], xyz[i, 1] - elem[e, 1], xyz[i, 2] - elem[e, 2]
        d = dx * dx + dy * dy + dz * dz
        if d > best:
            best = d
    return np.sqrt(best)


def lookup_error(q: I64, xyz: F64, level: int, cells: I64, elem: F64) -> float:
    """Exact max distance from input points to the element standing for their cell.

    Parameters
    ----------
    q, xyz
        (N, 3) int64 grid coordinates and (N, 3) float64 positions of input points of the node's subtree.
    level
        The node's level.
    cells
        (C,) int64 occupied cells of the node's 64³ grid.
    elem
        (C, 3) float64 what the node draws for each cell: the representative point, or the centre of the
        quad texel the representative was splatted into.

    Returns
    -------
    float
        max over points of ``|p - elem[cell(p)]|``; every point's cell must be in ``cells``.
    """
    if len(q) == 0:
        return 0.0
    err = _lookup_error(q, xyz, QBITS - level - CLUSTER_BITS, np.asarray(cells, np.int64),
                        np.asarray(elem, np.float64))
    if err < 0:
        raise AssertionError("an input point's cell has no representative (octree invariant broken)")
    return float(err)
