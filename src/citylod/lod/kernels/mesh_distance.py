"""A certified upper bound on the directed Hausdorff distance between two triangle meshes.

``sup_{p in A} d(p, B)`` is bounded by branch and bound over A's triangles. Distances from points to B are
exact point–triangle distances (Ericson, "Real-Time Collision Detection", 2005, §5.1.5), taken over all of
B's triangles. For a piece T of A with vertices v_i, d(., B) is 1-Lipschitz, so for every p in T
``d(p, B) <= d(v_i, B) + |p - v_i| <= d(v_i, B) + max(|e| for the two edges at v_i)`` (the distance from a
vertex to the points of a triangle is largest at another vertex, by convexity). That is the piece's upper
bound; the vertex distances are lower bounds of the supremum. A piece whose upper bound is within ``tol`` of
the largest lower bound found so far (or within ``rel`` of it, whichever is larger) is settled; otherwise it is split into four at its edge midpoints. The
result ``upper`` is the largest upper bound of all settled pieces: a proven bound, at most ``max(tol, rel * value)`` above
the true value.

A second bound settles pieces that lie at a near-constant distance (a roof over a parallel roof), where the
Lipschitz bound would need pieces of size ``tol``: the distance to one convex set (one triangle t of B) is a
convex function, so over the piece it is largest at a vertex, and ``d(p, B) <= d(p, t) <= max_i d(v_i, t)``
for every t. The piece's upper bound is the smaller of the two.

numpy and numba only (see lod/kernels/__init__).
"""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

from citylod.lod.kernels.distance import point_triangle_sq

__all__ = ["directed_hausdorff", "hausdorff_bound"]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


@numba.njit(cache=True, inline="always")
def _box_sq(p, box, k):  # squared distance from p to the bounding box of triangle k (a lower bound)
    s = 0.0
    for j in range(3):
        lo, hi = box[k, j], box[k, 3 + j]
        e = lo - p[j] if p[j] < lo else (p[j] - hi if p[j] > hi else 0.0)
        s += e * e
    return s


@numba.njit(cache=True)
def _dist(p, tri, box):  # pragma: no cover - compiled
    best = np.inf
    for k in range(tri.shape[0]):
        if _box_sq(p, box, k) >= best:
            continue
        d = point_triangle_sq(p[0], p[1], p[2], tri[k, 0], tri[k, 1], tri[k, 2], tri[k, 3], tri[k, 4], tri[k, 5],
                        tri[k, 6], tri[k, 7], tri[k, 8])
        if d < best:
            best = d
    return np.sqrt(best)


@numba.njit(cache=True)
def _convex_bound(a, b, c, tri, box):  # pragma: no cover - compiled
    # min over B's triangles t of the largest vertex distance to t (see the module docstring).
    best = np.inf
    for k in range(tri.shape[0]):
        if max(_box_sq(a, box, k), max(_box_sq(b, box, k), _box_sq(c, box, k))) >= best:
            continue
        worst = 0.0
        for p in (a, b, c):
            d = point_triangle_sq(p[0], p[1], p[2], tri[k, 0], tri[k, 1], tri[k, 2], tri[k, 3], tri[k, 4], tri[k, 5],
                            tri[k, 6], tri[k, 7], tri[k, 8])
            if d > worst:
                worst = d
                if worst >= best:
                    break
        if worst < best:
            best = worst
    return np.sqrt(best)


@numba.njit(cache=True)
def _directed(src, dst, tol, rel, max_pieces):  # pragma: no cover - compiled
    # src, dst: (n, 9) triangles as rows a|b|c. Returns (lower, upper).
    if src.shape[0] == 0:
        return 0.0, 0.0
    if dst.shape[0] == 0:
        return np.inf, np.inf
    box = np.empty((dst.shape[0], 6))
    for k in range(dst.shape[0]):
        for j in range(3):
            box[k, j] = min(dst[k, j], min(dst[k, 3 + j], dst[k, 6 + j]))
            box[k, 3 + j] = max(dst[k, j], max(dst[k, 3 + j], dst[k, 6 + j]))
    cap = max(64, 4 * src.shape[0] + 64)
    pts = np.empty((cap, 3, 3))
    dis = np.empty((cap, 3))
    top = 0
    lower = 0.0
    p = np.empty(3)
    for t in range(src.shape[0]):
        if top >= cap:
            break
        for i in range(3):
            for j in range(3):
                pts[top, i, j] = src[t, 3 * i + j]
            p[:] = pts[top, i]
            dis[top, i] = _dist(p, dst, box)
            lower = max(lower, dis[top, i])
        top += 1
    upper = lower
    pieces = 0
    while top > 0:
        top -= 1
        a = pts[top, 0].copy()
        b = pts[top, 1].copy()
        c = pts[top, 2].copy()
        da, db, dc = dis[top, 0], dis[top, 1], dis[top, 2]
        lab = np.sqrt(((a - b) ** 2).sum())
        lbc = np.sqrt(((b - c) ** 2).sum())
        lca = np.sqrt(((c - a) ** 2).sum())
        ub = min(da + max(lab, lca), db + max(lab, lbc), dc + max(lbc, lca))
        slack = max(tol, rel * lower)
        if ub > lower + slack:
            ub = min(ub, _convex_bound(a, b, c, dst, box))
        pieces += 1
        if ub <= lower + slack or pieces > max_pieces or top + 4 > cap:
            upper = max(upper, ub)
            continue
        mab = 0.5 * (a + b)
        mbc = 0.5 * (b + c)
        mca = 0.5 * (c + a)
        dab = _dist(mab, dst, box)
        dbc = _dist(mbc, dst, box)
        dca = _dist(mca, dst, box)
        lower = max(lower, max(dab, max(dbc, dca)))
        kids = ((a, mab, mca, da, dab, dca), (mab, b, mbc, dab, db, dbc), (mca, mbc, c, dca, dbc, dc),
                (mab, mbc, mca, dab, dbc, dca))
        for k in range(4):
            pa, pb, pc, qa, qb, qc = kids[k]
            pts[top, 0] = pa
            pts[top, 1] = pb
            pts[top, 2] = pc
            dis[top, 0] = qa
            dis[top, 1] = qb
            dis[top, 2] = qc
            top += 1
    return lower, max(upper, lower)


def _rows(vertices: F64, faces: I64) -> F64:
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    return np.ascontiguousarray(v[f].reshape(-1, 9))


def directed_hausdorff(a_vertices: F64, a_faces: I64, b_vertices: F64, b_faces: I64, *, tol: float = 0.05,
                       rel: float = 0.0, max_pieces: int = 2_000_000) -> tuple[float, float]:
    """``(lower, upper)`` bounds on ``sup_{p in A} d(p, B)`` in the units of the vertices.

    ``upper`` is proven (see the module docstring); ``upper - lower <= tol`` unless ``max_pieces`` pieces
    were examined first (or ``upper - lower <= rel * lower`` when that is larger), in which case ``upper`` is still a proven bound, only a looser one. Coordinates
    should be local (near the origin) so that differences keep their precision.
    """
    lo, hi = _directed(_rows(a_vertices, a_faces), _rows(b_vertices, b_faces), float(tol), float(rel), int(max_pieces))
    return float(lo), float(hi)


def hausdorff_bound(a_vertices: F64, a_faces: I64, b_vertices: F64, b_faces: I64, *, tol: float = 0.05,
                    rel: float = 0.0) -> float:
    """A proven upper bound on the symmetric Hausdorff distance between meshes A and B (the larger of the
    two directed bounds), at most ``max(tol, rel * distance)`` above the true distance."""
    return max(directed_hausdorff(a_vertices, a_faces, b_vertices, b_faces, tol=tol, rel=rel)[1],
               directed_hausdorff(b_vertices, b_faces, a_vertices, a_faces, tol=tol, rel=rel)[1])
