"""Planes in point-cloud nodes, replaced by textured quads (hybrid points + quads).

Wahl, Guthe, Klein, "Identifying planes in point-clouds for efficient hybrid rendering", PG 2005: in each
octree node, RANSAC finds planes among the node's representative points; a plane whose inliers can be
drawn more cheaply as a textured quad than as points (the compactness rule ``texels < φ·(inliers − 4)``)
becomes one quad, with the inliers splatted into a texture of texel spacing equal to the node's
clustering cell. The inliers are removed from the node's points.

What each removed point is replaced by is returned explicitly (the centre of the texel it was splatted
into), so the caller can measure the node's true error including the quads. No I/O; no VTK, no Qt.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from citylod.core.jit import defer_blas_probe
from citylod.core.palette import ASPRS_CLASS_RGB

defer_blas_probe()  # before any kernel loads: numba starts without importing scipy.linalg

F64 = npt.NDArray[np.float64]
U8 = npt.NDArray[np.uint8]

# ASPRS LAS 1.4 standard classes (and AHN's 26 bridge deck) for colouring quads of uncoloured clouds.


def splat_colors(rgb: U8 | None, classification: U8, intensity: npt.NDArray[np.uint16],
                 intensity_scale: float) -> U8:
    """Colour of each point for texturing quads, (N, 3) uint8.

    RGB when the cloud has it; otherwise the classification's colour from the palette the points are drawn
    with (:data:`citylod.core.palette.ASPRS_CLASS_RGB`), so a coarse node's quads and the finer nodes' points
    look alike. ``intensity`` and ``intensity_scale`` are kept for callers; class colours do not use them.
    """
    if rgb is not None:
        return rgb
    return ASPRS_CLASS_RGB[classification]


@numba.njit(cache=True, nogil=True)
def _next(state: int) -> int:  # pragma: no cover - compiled
    # 64-bit LCG (Knuth MMIX); int64 arithmetic wraps, which is what we want.
    return state * 6364136223846793005 + 1442695040888963407


@numba.njit(cache=True, nogil=True)
def _best_plane(p: F64, n_candidates: int, window: int, thr: float, seed: int
                ) -> tuple[F64, float, int]:  # pragma: no cover - compiled
    """Best of ``n_candidates`` 3-point planes by inlier count (|n·p + d| ≤ thr) on a subsample.

    Returns the plane (n, d) and its subsample count, -1 when every candidate was degenerate; the caller
    counts the winner's inliers on all points.

    ``p`` is in Morton order, so the 2nd and 3rd sample are drawn within ``window`` positions of the first:
    localised sampling (as in Schnabel et al. 2007) makes three points from the same surface likely even
    when that surface holds a small share of the node.
    """
    k = p.shape[0]
    # Score candidates on a regular subsample of about 512 points (the points are in Morton order, so a
    # stride is a spatially even subsample), count the winner on all points: ranking needs only estimates.
    step = max(1, k // 512)
    # The subsample as three contiguous columns, so the scoring loop below vectorises.
    ns = (k + step - 1) // step
    sx, sy, sz = np.empty(ns), np.empty(ns), np.empty(ns)
    for t in range(ns):
        sx[t], sy[t], sz[t] = p[t * step, 0], p[t * step, 1], p[t * step, 2]
    state = seed
    best_n = np.zeros(3)
    best_d = 0.0
    best = -1
    for _ in range(n_candidates):
        state = _next(state)
        i = ((state >> 33) & 0x7FFFFFFF) % k
        state = _next(state)
        j = min(max(i + ((state >> 33) & 0x7FFFFFFF) % (2 * window + 1) - window, 0), k - 1)
        state = _next(state)
        m = min(max(i + ((state >> 33) & 0x7FFFFFFF) % (2 * window + 1) - window, 0), k - 1)
        ax, ay, az = p[j, 0] - p[i, 0], p[j, 1] - p[i, 1], p[j, 2] - p[i, 2]
        bx, by, bz = p[m, 0] - p[i, 0], p[m, 1] - p[i, 1], p[m, 2] - p[i, 2]
        nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        nn = np.sqrt(nx * nx + ny * ny + nz * nz)
        la = np.sqrt(ax * ax + ay * ay + az * az)
        lb = np.sqrt(bx * bx + by * by + bz * bz)
        if nn <= 0.05 * la * lb or nn == 0.0:  # nearly collinear: the normal is noise
            continue
        nx, ny, nz = nx / nn, ny / nn, nz / nn
        d = -(nx * p[i, 0] + ny * p[i, 1] + nz * p[i, 2])
        cnt = 0
        for t in range(ns):
            cnt += abs(nx * sx[t] + ny * sy[t] + nz * sz[t] + d) <= thr
        if cnt > best:
            best = cnt
            best_n[0], best_n[1], best_n[2] = nx, ny, nz
            best_d = d
    return best_n, best_d, best


@dataclass(frozen=True)
class Quad:
    """One textured quad.

    Attributes
    ----------
    corners
        (4, 3) float64, relative to the node centre, counter-clockwise seen from the normal side:
        texture (0, 0), (W, 0), (W, H), (0, H) in texels.
    rgba
        (H, W, 4) uint8 texture; row 0 is the corners[0]–corners[1] edge. Empty texels have alpha 0.
    texel
        Texel spacing in metres.
    inliers
        Number of points the quad replaced.
    """

    corners: F64
    rgba: U8
    texel: float
    inliers: int


@dataclass(frozen=True)
class PlaneResult:
    """The quads of one node and what they replaced, as arrays (a node has tens of quads; objects per quad
    cost more Python time than the compiled search that found them).

    Attributes
    ----------
    corners
        (Q, 4, 3) float64, each quad's corners as `Quad.corners`.
    sizes
        (Q, 2) int64 texture width and height in texels.
    inliers
        (Q,) int64 number of points each quad replaced.
    tex, tex_off
        The textures, flat uint8: quad q's (H, W, 4) RGBA texels are ``tex[tex_off[q]:tex_off[q + 1]]``.
    texel
        Texel spacing in metres.
    replaced
        (K,) bool: the point was splatted into a quad (it is no longer drawn as a point).
    elem
        (K, 3) float64: for replaced points the centre of their texel, else the point itself.
    """

    corners: F64
    sizes: npt.NDArray[np.int64]
    inliers: npt.NDArray[np.int64]
    tex: U8
    tex_off: npt.NDArray[np.int64]
    texel: float
    replaced: npt.NDArray[np.bool_]
    elem: F64

    @property
    def n_quads(self) -> int:
        return len(self.inliers)

    def quad(self, q: int) -> Quad:
        """Quad ``q`` as an object."""
        w, h = (int(v) for v in self.sizes[q])
        return Quad(self.corners[q].copy(), self.tex[self.tex_off[q]:self.tex_off[q + 1]].reshape(h, w, 4),
                    self.texel, int(self.inliers[q]))


def find_planes(p: F64, colors: U8, texel: float, *, phi: float = 8.0, seed: int = 0,
                n_candidates: int = 100, max_planes: int = 32, min_inliers: int = 32,
                max_failures: int = 3, window: int = 48) -> PlaneResult:
    """RANSAC planes among a node's points, kept when a textured quad pays off (Wahl et al. 2005).

    Parameters
    ----------
    p
        (K, 3) float64 point positions relative to the node centre, in Morton order.
    colors
        (K, 3) uint8 colour to splat.
    texel
        The node's clustering cell size: texel spacing; points within ``texel / 2`` of a plane are its
        inliers, so a replaced point moves at most ``√(texel²/4 + texel²/2)`` to its texel centre.
    phi
        Compactness factor φ: accept when ``texels < φ · (inliers − 4)`` (4 vertices of the quad).
    seed
        Makes the RANSAC samples reproducible.
    n_candidates
        3-point candidates per plane search. On the Delft nodes 100 found 847 quads replacing 156,230
        points where 200 found 841 replacing 156,889, in 73 % of the time (measured before the quads took
        their smallest rectangle; now 100 find 845 replacing 158,121).
    max_planes, min_inliers, max_failures
        Stop after that many planes, below that many inliers, or after that many rejected planes in a row.

    Returns
    -------
    PlaneResult
    """
    res = _planes(np.ascontiguousarray(p, np.float64), np.ascontiguousarray(colors, np.uint8), float(texel),
                  float(phi), int(seed & 0x7FFFFFFFFFFF), int(n_candidates), int(max_planes), int(min_inliers),
                  int(max_failures), int(window))
    replaced, elem, corners, size, inliers, tex, tex_off = res
    return PlaneResult(corners, size, inliers, tex, tex_off, float(texel), replaced, elem)


@numba.njit(cache=True, nogil=True)
def _label8(occ: npt.NDArray[np.bool_]) -> tuple[npt.NDArray[np.int64], int]:  # pragma: no cover - compiled
    """8-connected components of ``occ``, numbered from 1 in raster order of their first pixel (as
    ``scipy.ndimage.label`` numbers them)."""
    h, w = occ.shape
    parent = np.arange(h * w)
    for y in range(h):
        for x in range(w):
            if not occ[y, x]:
                continue
            a = y * w + x
            for dy, dx in ((-1, -1), (-1, 0), (-1, 1), (0, -1)):
                yy, xx = y + dy, x + dx
                if 0 <= yy and 0 <= xx < w and occ[yy, xx]:
                    b = yy * w + xx
                    while parent[a] != a:
                        a = parent[a]
                    while parent[b] != b:
                        b = parent[b]
                    if a != b:
                        if a < b:
                            parent[b] = a
                        else:
                            parent[a] = b
                    a = y * w + x
    lab = np.zeros((h, w), np.int64)
    root_label = np.zeros(h * w, np.int64)
    n = 0
    for y in range(h):
        for x in range(w):
            if not occ[y, x]:
                continue
            r = y * w + x
            while parent[r] != r:
                r = parent[r]
            if root_label[r] == 0:
                n += 1
                root_label[r] = n
            lab[y, x] = root_label[r]
    return lab, n


@numba.njit(cache=True, nogil=True)
def _cross2(ox: float, oy: float, ax: float, ay: float, bx: float, by: float) -> float:  # pragma: no cover
    return (ax - ox) * (by - oy) - (ay - oy) * (bx - ox)


@numba.njit(cache=True, nogil=True)
def _patch(s: F64, tt: F64, texel: float) -> tuple[Any, ...]:  # pragma: no cover - compiled
    """Grid the inliers (s, t in the quad's frame) at ``texel`` and keep the largest 8-connected patch.

    Returns the grid origin (s0, t0), each inlier's texel (i, j), the kept inliers' indices and their
    texels' range [i0, i1) × [j0, j1). Inliers of an infinite plane can lie in several separate patches
    (coplanar roofs, terraces): the largest is kept so the quad's rectangle is not mostly empty."""
    m = s.shape[0]
    s0 = t0 = np.inf
    for e in range(m):
        s0, t0 = min(s0, s[e]), min(t0, tt[e])
    gi_ = np.empty(m, np.int64)
    gj_ = np.empty(m, np.int64)
    imax = jmax = 0
    for e in range(m):
        gi_[e] = np.int64(np.floor((s[e] - s0) / texel))
        gj_[e] = np.int64(np.floor((tt[e] - t0) / texel))
        imax, jmax = max(imax, gi_[e]), max(jmax, gj_[e])
    occ = np.zeros((jmax + 1, imax + 1), np.bool_)
    for e in range(m):
        occ[gj_[e], gi_[e]] = True
    lab, nlab = _label8(occ)
    keep_lab = 1
    if nlab > 1:
        lc = np.zeros(nlab + 1, np.int64)
        for e in range(m):
            lc[lab[gj_[e], gi_[e]]] += 1
        for lb in range(2, nlab + 1):
            if lc[lb] > lc[keep_lab]:
                keep_lab = lb
    sel = np.empty(m, np.int64)
    ns = 0
    i0 = j0 = np.int64(1 << 62)
    i1 = j1 = np.int64(-1)
    for e in range(m):
        if nlab <= 1 or lab[gj_[e], gi_[e]] == keep_lab:
            sel[ns] = e
            ns += 1
            i0, i1 = min(i0, gi_[e]), max(i1, gi_[e] + 1)
            j0, j1 = min(j0, gj_[e]), max(j1, gj_[e] + 1)
    return s0, t0, gi_, gj_, sel[:ns], i0, i1, j0, j1


@numba.njit(cache=True, nogil=True)
def _extremes(s: F64, t: F64, cell: float) -> npt.NDArray[np.int64]:  # pragma: no cover - compiled
    """Indices of the points that are leftmost or rightmost in their row of ``cell``-tall rows, or lowest
    or highest in their ``cell``-wide column: every vertex of the points' convex hull is within a cell of
    the hull of these (at most four a row or column), which is all the rectangle search needs."""
    m = s.shape[0]
    s0, t0 = s.min(), t.min()
    ns = int((s.max() - s0) / cell) + 1
    nt = int((t.max() - t0) / cell) + 1
    rmin = np.full(nt, -1, np.int64)
    rmax = np.full(nt, -1, np.int64)
    cmin = np.full(ns, -1, np.int64)
    cmax = np.full(ns, -1, np.int64)
    for e in range(m):
        r, c = int((t[e] - t0) / cell), int((s[e] - s0) / cell)
        if rmin[r] < 0 or s[e] < s[rmin[r]]:
            rmin[r] = e
        if rmax[r] < 0 or s[e] > s[rmax[r]]:
            rmax[r] = e
        if cmin[c] < 0 or t[e] < t[cmin[c]]:
            cmin[c] = e
        if cmax[c] < 0 or t[e] > t[cmax[c]]:
            cmax[c] = e
    keep = np.zeros(m, np.bool_)
    for arr in (rmin, rmax, cmin, cmax):
        for k in range(arr.shape[0]):
            if arr[k] >= 0:
                keep[arr[k]] = True
    return np.flatnonzero(keep)


@numba.njit(cache=True, nogil=True)
def _min_area_direction(s: F64, t: F64) -> tuple[float, float, float]:  # pragma: no cover - compiled
    """The direction (cos, sin in the s, t frame) of the smallest-area rectangle around the points (s, t),
    and that area relative to the rectangle along the s, t axes themselves (1 or less).

    The smallest rectangle has a side on an edge of the points' convex hull (Freeman and Shapira 1975), so
    the hull's edges (Andrew's monotone chain) are the only candidates. Written here because it runs for
    every plane inside the compiled RANSAC loop, where shapely's ``minimum_rotated_rectangle`` cannot be
    called."""
    m = s.shape[0]
    if m < 3:
        return 1.0, 0.0, 1.0
    order = np.argsort(t, kind="mergesort")
    order = order[np.argsort(s[order], kind="mergesort")]  # by s, then t
    hull = np.empty(2 * m, np.int64)
    k = 0
    for i in range(m):  # lower hull
        j = order[i]
        while k >= 2 and _cross2(s[hull[k - 2]], t[hull[k - 2]], s[hull[k - 1]], t[hull[k - 1]], s[j], t[j]) <= 0:
            k -= 1
        hull[k] = j
        k += 1
    lower = k + 1
    for i in range(m - 2, -1, -1):  # upper hull
        j = order[i]
        while k >= lower and _cross2(s[hull[k - 2]], t[hull[k - 2]], s[hull[k - 1]], t[hull[k - 1]], s[j], t[j]) <= 0:
            k -= 1
        hull[k] = j
        k += 1
    k -= 1  # the last point repeats the first
    base = (s[hull[:k]].max() - s[hull[:k]].min()) * (t[hull[:k]].max() - t[hull[:k]].min())
    best_c, best_s, best = 1.0, 0.0, base
    # A rectangle's orientation repeats every 90°: hull edges within a quarter degree of one already tried
    # (the many near-collinear edges of a gridded boundary) are skipped.
    seen = np.zeros(360, np.bool_)
    for e in range(k):
        a, b = hull[e], hull[(e + 1) % k]
        dx, dy = s[b] - s[a], t[b] - t[a]
        ln = np.sqrt(dx * dx + dy * dy)
        if ln <= 0.0:
            continue
        q = int((np.arctan2(dy, dx) % (0.5 * np.pi)) / (0.5 * np.pi) * 360.0) % 360
        if seen[q]:
            continue
        seen[q] = True
        c, sn = dx / ln, dy / ln
        lo1 = lo2 = np.inf
        hi1 = hi2 = -np.inf
        for q in range(k):
            x, y = s[hull[q]], t[hull[q]]
            p1, p2 = x * c + y * sn, -x * sn + y * c
            lo1, hi1 = min(lo1, p1), max(hi1, p1)
            lo2, hi2 = min(lo2, p2), max(hi2, p2)
        area = (hi1 - lo1) * (hi2 - lo2)
        if area < best:
            best_c, best_s, best = c, sn, area
    return best_c, best_s, best / base if base > 0 else 1.0


@numba.njit(cache=True, nogil=True)
def _dilate_u8(img: F64) -> U8:  # pragma: no cover - compiled
    """Fill transparent texels next to opaque ones with the mean of their opaque 8-neighbours; round to
    uint8 (H, W, 4)."""
    h, w, _ = img.shape
    out = np.empty((h, w, 4), np.uint8)
    for y in range(h):
        for x in range(w):
            if img[y, x, 3] > 0:
                for ch in range(4):
                    out[y, x, ch] = np.uint8(min(max(np.rint(img[y, x, ch]), 0.0), 255.0))
                continue
            r = g = b = 0.0
            num = 0
            for dy in range(-1, 2):
                for dx in range(-1, 2):
                    if dy == 0 and dx == 0:
                        continue
                    yy, xx = y + dy, x + dx
                    if 0 <= yy < h and 0 <= xx < w and img[yy, xx, 3] > 0:
                        r += img[yy, xx, 0]
                        g += img[yy, xx, 1]
                        b += img[yy, xx, 2]
                        num += 1
            if num > 0:
                out[y, x, 0] = np.uint8(min(max(np.rint(r / num), 0.0), 255.0))
                out[y, x, 1] = np.uint8(min(max(np.rint(g / num), 0.0), 255.0))
                out[y, x, 2] = np.uint8(min(max(np.rint(b / num), 0.0), 255.0))
                out[y, x, 3] = 255
            else:
                out[y, x, 0] = out[y, x, 1] = out[y, x, 2] = out[y, x, 3] = 0
    return out


@numba.njit(cache=True, nogil=True)
def _planes(p: F64, colors: U8, texel: float, phi: float, seed: int, n_candidates: int, max_planes: int,
            min_inliers: int, max_failures: int, window: int
            ) -> tuple[npt.NDArray[np.bool_], F64, F64, npt.NDArray[np.int64], npt.NDArray[np.int64], U8,
                       npt.NDArray[np.int64]]:  # pragma: no cover - compiled
    """The RANSAC loop of :func:`find_planes`, compiled (no Python work per plane or per point).

    Returns replaced (K,), elem (K, 3), and per quad: corners (Q, 4, 3), texture (width, height) (Q, 2),
    inliers (Q,), the textures' RGBA bytes one after the other and their offsets (Q + 1,).
    """
    k = p.shape[0]
    replaced = np.zeros(k, np.bool_)
    elem = p.copy()
    active = np.arange(k)
    na = k
    pa = p.copy()
    thr = 0.5 * texel
    failures = 0
    q_corners = np.zeros((max_planes, 4, 3))
    q_size = np.zeros((max_planes, 2), np.int64)
    q_inl = np.zeros(max_planes, np.int64)
    tex = np.empty(1 << 16, np.uint8)
    tex_off = np.zeros(max_planes + 1, np.int64)
    nq = 0
    inl = np.empty(k, np.bool_)
    inl2 = np.empty(k, np.bool_)
    for attempt in range(max_planes + max_failures * max_planes):
        if nq >= max_planes or failures >= max_failures or na < min_inliers:
            break
        sub = pa[:na]  # the active points, kept compacted below
        n, d, sampled = _best_plane(sub, n_candidates, window, thr, seed + 7919 * attempt)
        if sampled < 0:
            break
        nx, ny, nz = n[0], n[1], n[2]
        ninl = 0
        cx = cy = cz = 0.0
        for t in range(na):  # branch-free, so it vectorises
            ok = abs(nx * sub[t, 0] + ny * sub[t, 1] + nz * sub[t, 2] + d) <= thr
            inl[t] = ok
            wgt = 1.0 if ok else 0.0
            ninl += ok
            cx += wgt * sub[t, 0]
            cy += wgt * sub[t, 1]
            cz += wgt * sub[t, 2]
        if ninl < min_inliers:
            break
        cx, cy, cz = cx / ninl, cy / ninl, cz / ninl
        # Least-squares refit (PCA of the inliers), kept when it does not lose inliers.
        cov = np.zeros((3, 3))
        for t in range(na):
            if inl[t]:
                dx, dy, dz = sub[t, 0] - cx, sub[t, 1] - cy, sub[t, 2] - cz
                cov[0, 0] += dx * dx
                cov[0, 1] += dx * dy
                cov[0, 2] += dx * dz
                cov[1, 1] += dy * dy
                cov[1, 2] += dy * dz
                cov[2, 2] += dz * dz
        cov[1, 0], cov[2, 0], cov[2, 1] = cov[0, 1], cov[0, 2], cov[1, 2]
        _, v = np.linalg.eigh(cov / max(ninl - 1, 1))
        mx, my, mz = v[0, 0], v[1, 0], v[2, 0]
        ninl2 = 0
        for t in range(na):
            ok = abs((sub[t, 0] - cx) * mx + (sub[t, 1] - cy) * my + (sub[t, 2] - cz) * mz) <= thr
            inl2[t] = ok
            ninl2 += ok
        if ninl2 >= ninl:
            nx, ny, nz = mx, my, mz
            inl, inl2 = inl2, inl  # the refit's inliers, without a copy
            ninl = ninl2
        else:
            off = cx * nx + cy * ny + cz * nz + d  # project the centroid onto the RANSAC plane
            cx, cy, cz = cx - off * nx, cy - off * ny, cz - off * nz
        # In-plane long axis (PCA), orthogonalised against the final normal.
        lx, ly, lz = v[0, 2], v[1, 2], v[2, 2]
        dot = lx * nx + ly * ny + lz * nz
        ux, uy, uz = lx - dot * nx, ly - dot * ny, lz - dot * nz
        un = np.sqrt(ux * ux + uy * uy + uz * uz)
        ux, uy, uz = ux / un, uy / un, uz / un
        vx, vy, vz = ny * uz - nz * uy, nz * ux - nx * uz, nx * uy - ny * ux
        m = ninl  # the number of inliers, counted when they were marked
        idx = np.empty(m, np.int64)
        s = np.empty(m)
        tt = np.empty(m)
        m = 0
        for t in range(na):
            if inl[t]:
                idx[m] = t
                rx, ry, rz = sub[t, 0] - cx, sub[t, 1] - cy, sub[t, 2] - cz
                s[m] = rx * ux + ry * uy + rz * uz
                tt[m] = rx * vx + ry * vy + rz * vz
                m += 1
        # The quad's sides along the inliers' smallest bounding rectangle, not their principal axes: for a
        # square patch those are arbitrary, and at 45° the quad was twice the patch, its corners far outside
        # the data (they set the tile's bounding box) and half its texels empty. Found from the row and
        # column extremes of at most 1024 of the inliers, evenly strided (the hull of all of them cost as
        # much as the rest of the plane search; the rectangle itself is measured on every inlier), for
        # every plane before its compactness test, and turned only when that saves over 2 % of the area.
        step = max(1, m // 1024)
        ps, pt = s[::step], tt[::step]
        ext = _extremes(ps, pt, texel)
        rc, rs, shrink = _min_area_direction(ps[ext], pt[ext])
        if shrink < 0.98:
            ux, uy, uz = rc * ux + rs * vx, rc * uy + rs * vy, rc * uz + rs * vz
            vx, vy, vz = ny * uz - nz * uy, nz * ux - nx * uz, nx * uy - ny * ux
            for e in range(m):
                s[e], tt[e] = rc * s[e] + rs * tt[e], -rs * s[e] + rc * tt[e]
        s0, t0, gi_, gj_, sel, i0, i1, j0, j1 = _patch(s, tt, texel)
        ns = sel.shape[0]
        accept = ns >= min_inliers and (i1 - i0) * (j1 - j0) < phi * (ns - 4)
        if accept:
            ww, hh = i1 - i0 + 2, j1 - j0 + 2
            # Texel (i, j) of the W×H texture plus a one-texel border (the quad enlarged by one texel
            # against cracks, the border filled by dilation).
            img = np.zeros((hh, ww, 4))
            ox = cx + (s0 + (i0 - 1) * texel) * ux + (t0 + (j0 - 1) * texel) * vx
            oy = cy + (s0 + (i0 - 1) * texel) * uy + (t0 + (j0 - 1) * texel) * vy
            oz = cz + (s0 + (i0 - 1) * texel) * uz + (t0 + (j0 - 1) * texel) * vz
            for e_ in sel:
                ti, tj = gi_[e_] - i0 + 1, gj_[e_] - j0 + 1
                g = active[idx[e_]]
                img[tj, ti, 0] += colors[g, 0]
                img[tj, ti, 1] += colors[g, 1]
                img[tj, ti, 2] += colors[g, 2]
                img[tj, ti, 3] += 1.0
                a_ = (ti + 0.5) * texel
                b_ = (tj + 0.5) * texel
                elem[g, 0] = ox + a_ * ux + b_ * vx
                elem[g, 1] = oy + a_ * uy + b_ * vy
                elem[g, 2] = oz + a_ * uz + b_ * vz
                replaced[g] = True
            for y in range(hh):
                for x in range(ww):
                    c_ = img[y, x, 3]
                    if c_ > 0:
                        img[y, x, 0] /= c_
                        img[y, x, 1] /= c_
                        img[y, x, 2] /= c_
                        img[y, x, 3] = 255.0
            rgba = _dilate_u8(img).reshape(-1)
            end = tex_off[nq] + rgba.shape[0]
            if end > tex.shape[0]:
                grown = np.empty(max(2 * tex.shape[0], end), np.uint8)
                grown[:tex_off[nq]] = tex[:tex_off[nq]]
                tex = grown
            tex[tex_off[nq]:end] = rgba
            tex_off[nq + 1] = end
            wx, wy, wz = ww * texel * ux, ww * texel * uy, ww * texel * uz
            hx, hy, hz = hh * texel * vx, hh * texel * vy, hh * texel * vz
            q_corners[nq, 0, 0], q_corners[nq, 0, 1], q_corners[nq, 0, 2] = ox, oy, oz
            q_corners[nq, 1, 0], q_corners[nq, 1, 1], q_corners[nq, 1, 2] = ox + wx, oy + wy, oz + wz
            q_corners[nq, 2, 0], q_corners[nq, 2, 1], q_corners[nq, 2, 2] = ox + wx + hx, oy + wy + hy, oz + wz + hz
            q_corners[nq, 3, 0], q_corners[nq, 3, 1], q_corners[nq, 3, 2] = ox + hx, oy + hy, oz + hz
            q_size[nq, 0], q_size[nq, 1] = ww, hh
            q_inl[nq] = ns
            nq += 1
            failures = 0
        else:
            failures += 1  # not worth a quad: these points stay points; do not sample them again
        # Drop the patch's points from the active set either way.
        rm = np.zeros(na, np.bool_)
        for e_ in sel:
            rm[idx[e_]] = True
        w_ = 0
        for t in range(na):
            if not rm[t]:
                active[w_] = active[t]
                pa[w_, 0], pa[w_, 1], pa[w_, 2] = pa[t, 0], pa[t, 1], pa[t, 2]
                w_ += 1
        na = w_
    return (replaced, elem, q_corners[:nq], q_size[:nq], q_inl[:nq], tex[:tex_off[nq]], tex_off[:nq + 1])


@numba.njit(cache=True, nogil=True)
def _pow2_at_least(n: int) -> int:  # pragma: no cover - compiled
    p = 1
    while p < n:
        p *= 2
    return p


@numba.njit(cache=True, nogil=True)
def _shelves(sizes: npt.NDArray[np.int64], order: npt.NDArray[np.int64], width: int, gap: int,
             offsets: npt.NDArray[np.int64]) -> int:  # pragma: no cover - compiled
    """Shelf-pack ``sizes`` in ``order`` into rows ``width`` wide; fill ``offsets``, return the height."""
    x = 0
    y = 0
    shelf = 0
    for k in order:
        w, h = sizes[k, 0], sizes[k, 1]
        if x + w > width:
            x, y, shelf = 0, y + shelf + gap, 0
        offsets[k, 0], offsets[k, 1] = x, y
        x += w + gap
        shelf = max(shelf, h)
    return y + shelf


@numba.njit(cache=True, nogil=True)
def _pack_atlas(sizes: npt.NDArray[np.int64], tex: U8, tex_off: npt.NDArray[np.int64]
                ) -> tuple[U8, npt.NDArray[np.int64]]:  # pragma: no cover - compiled
    """:func:`pack_atlas` on the arrays of a :class:`PlaneResult`, compiled and without the GIL."""
    n = sizes.shape[0]
    gap = 1  # transparent texel between textures so linear filtering does not bleed colour across
    area = 0
    wmax = 0
    for k in range(n):
        area += (sizes[k, 0] + gap) * (sizes[k, 1] + gap)
        wmax = max(wmax, sizes[k, 0])
    order = np.argsort(-sizes[:, 1], kind="mergesort")  # tallest first, ties in the order given
    # Power-of-two sides: glTF clients mipmap only those (WebGL 1), and the glTF validator reports every other
    # image. Of the two power-of-two widths around the square's side, keep the one whose padded area is least.
    offsets = np.zeros((n, 2), np.int64)
    trial = np.zeros((n, 2), np.int64)
    width = _pow2_at_least(max(wmax + gap, int(np.ceil(np.sqrt(area)))))
    height = _pow2_at_least(_shelves(sizes, order, width, gap, offsets))
    if width > 1 and width // 2 >= wmax + gap:
        h2 = _pow2_at_least(_shelves(sizes, order, width // 2, gap, trial))
        if (width // 2) * h2 < width * height:
            width, height = width // 2, h2
            offsets[:] = trial
    atlas = np.zeros((height, width, 4), np.uint8)
    for k in range(n):
        w, h = sizes[k, 0], sizes[k, 1]
        ox, oy = offsets[k, 0], offsets[k, 1]
        atlas[oy:oy + h, ox:ox + w] = tex[tex_off[k]:tex_off[k + 1]].reshape(h, w, 4)
    return atlas, offsets


def pack_atlas(res: PlaneResult) -> tuple[U8, npt.NDArray[np.int64]]:
    """Shelf-pack the quads' textures into one RGBA atlas (one texture per node draws in one call).

    Returns
    -------
    atlas
        (H, W, 4) uint8, both sides powers of two (the rest transparent).
    offsets
        (Q, 2) int64 (x, y) texel offset of each quad's texture in the atlas, in the order given.
    """
    return _pack_atlas(res.sizes, res.tex, res.tex_off)


def quad_mesh_arrays(res: PlaneResult) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint32],
                                                npt.NDArray[np.float32], U8]:
    """Vertex, face, uv arrays and the atlas image for a node's quads.

    Returns
    -------
    positions
        (4Q, 3) float32 relative to the node centre.
    faces
        (2Q, 3) uint32.
    uv
        (4Q, 2) float32, origin at the atlas's top-left (glTF); exact, the sides being powers of two.
    atlas
        (H, W, 4) uint8, both sides powers of two.
    """
    atlas, offsets = pack_atlas(res)
    ah, aw = atlas.shape[:2]
    pos = res.corners.reshape(-1, 3).astype(np.float32)
    ox, oy = offsets[:, 0], offsets[:, 1]
    w, h = res.sizes[:, 0], res.sizes[:, 1]
    u = np.stack([ox, ox + w, ox + w, ox], axis=1) / aw
    v = np.stack([oy, oy, oy + h, oy + h], axis=1) / ah
    uv = np.stack([u, v], axis=2).reshape(-1, 2).astype(np.float32)
    base = 4 * np.arange(res.n_quads, dtype=np.uint32)[:, None]
    faces = np.concatenate([base + np.array([0, 1, 2], np.uint32), base + np.array([0, 2, 3], np.uint32)], axis=1)
    return pos, faces.reshape(-1, 3), uv, atlas
