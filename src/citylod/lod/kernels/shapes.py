"""Shape detection on a height grid and the shape map of its vertices (numba kernels).

Wahl, Schnabel, Klein, PFG 2008 (chapter 4 of Wahl's thesis): planes are found in the points of a DSM by
RANSAC in the style of Schnabel, Wahl & Klein 2007 (localised sampling: the minimal set is drawn from a
small neighbourhood of a random seed; a candidate's score is the connected component of compatible points
around the seed, not the global inlier count; the best of a batch of candidates is refitted by least
squares and accepted when it is large enough). Roofs (and ground) and façades get separate parameters:

* roof planes are fitted to the grid samples, ``z = a x + b y + c``, with a distance threshold, a normal
  deviation threshold and connectivity over the 4-neighbourhood of the grid;
* façade planes are vertical and are fitted to the façade points inserted at height discontinuities
  (a column of points every ``spacing`` metres between the low and the high sample of a grid edge whose
  heights differ by more than the jump threshold); all points of one column share their horizontal
  position, so the vertical-plane RANSAC runs on the columns weighted by their point count.

The *shape map* then gives every grid vertex the set of shape IDs within ε of it (up to :data:`MAX_IDS`,
sorted, -1 padded): a vertex with two IDs lies on an edge (ridge, eave), with more on a corner.

Written by hand: no maintained library detects planes on a height grid with connectivity and the separate
roof/façade parameters the simplification rules depend on (Open3D's ``segment_plane`` is global, without
connectivity; CGAL's efficient RANSAC has no Python binding in our environment). Hot loops are numba
(decision 4); no LAPACK (3×3 normal equations and a 2×2 eigenvector in closed form). This module imports
numpy and numba only.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: Width of the shape map: IDs kept per vertex (corners of more than four planes are truncated).
MAX_IDS = 4


@njit(cache=True, nogil=True)
def _rand(state):  # 64-bit LCG (Knuth MMIX), returns (new state, uniform in [0, 1))
    state = state * 6364136223846793005 + 1442695040888963407
    return state, ((state >> 11) & ((1 << 53) - 1)) / float(1 << 53)


@njit(cache=True, nogil=True)
def grid_normals(F, V, dx, dy):
    """Unit normals (H, W, 3) of the grid surface, one-sided differences chosen by min-mod.

    At an eave the central difference mixes roof and ground; taking, per axis, the smaller of the two
    one-sided slopes gives the roof's normal on the roof side of every discontinuity. Row index grows
    southwards, so y = -row * dy.
    """
    H, W = F.shape
    N = np.zeros((H, W, 3))
    for r in range(H):
        for c in range(W):
            if not V[r, c]:
                continue
            gx = math.inf
            if c + 1 < W and V[r, c + 1]:
                gx = (F[r, c + 1] - F[r, c]) / dx
            if c > 0 and V[r, c - 1]:
                g = (F[r, c] - F[r, c - 1]) / dx
                if abs(g) < abs(gx):
                    gx = g
            gy = math.inf
            if r + 1 < H and V[r + 1, c]:
                gy = -(F[r + 1, c] - F[r, c]) / dy
            if r > 0 and V[r - 1, c]:
                g = -(F[r, c] - F[r - 1, c]) / dy
                if abs(g) < abs(gy):
                    gy = g
            if gx == math.inf:
                gx = 0.0
            if gy == math.inf:
                gy = 0.0
            n = math.sqrt(gx * gx + gy * gy + 1.0)
            N[r, c, 0] = -gx / n
            N[r, c, 1] = -gy / n
            N[r, c, 2] = 1.0 / n
    return N


@njit(cache=True, nogil=True)
def _flood(F, V, N, free, label, tag, seed_r, seed_c, a, b, c0, nx, ny, nz, eps, cos_a, dx, dy, stack):
    """Label with ``tag`` the 4-connected component around the seed of free samples within ``eps`` of the
    plane z = a x + b y + c0 (x = col·dx, y = -row·dy) whose normal is within the angle; return its size."""
    H, W = F.shape
    top = 0
    stack[0] = seed_r * W + seed_c
    top = 1
    label[seed_r, seed_c] = tag
    count = 0
    while top > 0:
        top -= 1
        k = stack[top]
        r = k // W
        c = k - r * W
        count += 1
        for d in range(4):
            rr = r + (d == 0) - (d == 1)
            cc = c + (d == 2) - (d == 3)
            if rr < 0 or rr >= H or cc < 0 or cc >= W:
                continue
            if label[rr, cc] == tag or not free[rr, cc] or not V[rr, cc]:
                continue
            dz = F[rr, cc] - (a * cc * dx - b * rr * dy + c0)
            if abs(dz) * nz > eps:  # perpendicular distance to the plane
                continue
            if N[rr, cc, 0] * nx + N[rr, cc, 1] * ny + N[rr, cc, 2] * nz < cos_a:
                continue
            label[rr, cc] = tag
            stack[top] = rr * W + cc
            top += 1
    return count


@njit(cache=True, nogil=True)
def _fit_plane(F, label, tag, dx, dy):
    """Least-squares z = a x + b y + c over the samples labelled ``tag`` (Cramer's rule on the 3×3 normal
    equations, centred for conditioning). Returns (a, b, c, ok)."""
    H, W = F.shape
    n = 0
    sx = sy = sz = 0.0
    for r in range(H):
        for c in range(W):
            if label[r, c] == tag:
                n += 1
                sx += c * dx
                sy += -r * dy
                sz += F[r, c]
    if n < 3:
        return 0.0, 0.0, 0.0, False
    mx, my, mz = sx / n, sy / n, sz / n
    sxx = sxy = syy = sxz = syz = 0.0
    for r in range(H):
        for c in range(W):
            if label[r, c] == tag:
                x = c * dx - mx
                y = -r * dy - my
                z = F[r, c] - mz
                sxx += x * x
                sxy += x * y
                syy += y * y
                sxz += x * z
                syz += y * z
    det = sxx * syy - sxy * sxy
    if abs(det) < 1e-12:
        return 0.0, 0.0, 0.0, False
    a = (sxz * syy - syz * sxy) / det
    b = (syz * sxx - sxz * sxy) / det
    return a, b, mz - a * mx - b * my, True


@njit(cache=True, nogil=True)
def detect_roof_planes(F, V, dx, dy, eps, max_angle_deg, min_size, max_slope_deg, seed, candidates, max_fail,
                       window):
    """Planes among the grid samples by localised RANSAC with connected scores.

    Parameters
    ----------
    F, V
        (H, W) float64 heights and bool validity.
    dx, dy
        Sample spacing in metres.
    eps, max_angle_deg
        Distance (m) and normal deviation (degrees) of an inlier.
    min_size
        Fewest samples of an accepted plane.
    max_slope_deg
        Steeper candidates are left to the façade detector.
    seed, candidates, max_fail, window
        Random seed; candidates per round; rounds without an accepted plane before stopping; half size of
        the sampling window in samples.

    Returns
    -------
    label
        (H, W) int32 plane index per sample, -1 unassigned.
    planes
        (K, 4) float64 unit normal (x, y, z; y north) and offset d with n·p + d = 0.
    """
    H, W = F.shape
    N = grid_normals(F, V, dx, dy)
    cos_a = math.cos(math.radians(max_angle_deg))
    min_nz = math.cos(math.radians(max_slope_deg))
    label = np.full((H, W), -1, np.int32)
    scratch = np.full((H, W), -1, np.int32)
    free = V.copy()
    stack = np.empty(H * W + 1, np.int64)
    planes = np.zeros((H * W // max(min_size, 1) + 1, 4))
    nplanes = 0
    state = np.int64(seed) * 2654435761 + 12345
    fails = 0
    tag = 0
    n_free = 0
    for r in range(H):
        for c in range(W):
            if free[r, c]:
                n_free += 1
    while fails < max_fail and n_free >= min_size:
        best = 0
        ba = bb = bc = 0.0
        bsr = bsc = 0
        for _ in range(candidates):
            # seed drawn uniformly among the samples (rejection over the free ones)
            ok = False
            sr = sc = 0
            for _t in range(64):
                state, u = _rand(state)
                k = int(u * H * W)
                sr = k // W
                sc = k - sr * W
                if free[sr, sc]:
                    ok = True
                    break
            if not ok:
                continue
            if N[sr, sc, 2] < min_nz:
                continue
            # two more samples from the window around the seed (Schnabel et al. 2007: localised sampling)
            pr = np.empty(3, np.int64)
            pc = np.empty(3, np.int64)
            pr[0] = sr
            pc[0] = sc
            got = 1
            for _t in range(32):
                state, u = _rand(state)
                rr = sr + int(u * (2 * window + 1)) - window
                state, u = _rand(state)
                cc = sc + int(u * (2 * window + 1)) - window
                if rr < 0 or rr >= H or cc < 0 or cc >= W or not free[rr, cc]:
                    continue
                if got == 2 and ((rr == pr[1] and cc == pc[1]) or (rr == sr and cc == sc)):
                    continue
                if got == 1 and rr == sr and cc == sc:
                    continue
                pr[got] = rr
                pc[got] = cc
                got += 1
                if got == 3:
                    break
            if got < 3:
                continue
            x0, y0, z0 = pc[0] * dx, -pr[0] * dy, F[pr[0], pc[0]]
            ux, uy, uz = pc[1] * dx - x0, -pr[1] * dy - y0, F[pr[1], pc[1]] - z0
            vx, vy, vz = pc[2] * dx - x0, -pr[2] * dy - y0, F[pr[2], pc[2]] - z0
            nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
            nl = math.sqrt(nx * nx + ny * ny + nz * nz)
            if nl < 1e-12:
                continue
            if nz < 0:
                nx, ny, nz = -nx, -ny, -nz
            nx, ny, nz = nx / nl, ny / nl, nz / nl
            if nz < min_nz:
                continue
            okn = True
            for q in range(3):
                if N[pr[q], pc[q], 0] * nx + N[pr[q], pc[q], 1] * ny + N[pr[q], pc[q], 2] * nz < cos_a:
                    okn = False
            if not okn:
                continue
            a, b = -nx / nz, -ny / nz
            c0 = z0 - a * x0 - b * y0
            tag += 1
            size = _flood(F, V, N, free, scratch, tag, sr, sc, a, b, c0, nx, ny, nz, eps, cos_a, dx, dy, stack)
            if size > best:
                best, ba, bb, bc, bsr, bsc = size, a, b, c0, sr, sc
        if best < min_size:
            fails += 1
            continue
        # refit the best candidate by least squares on its component, then grow again with the refit
        tag += 1
        nz = 1.0 / math.sqrt(ba * ba + bb * bb + 1.0)
        _flood(F, V, N, free, scratch, tag, bsr, bsc, ba, bb, bc, -ba * nz, -bb * nz, nz, eps, cos_a, dx, dy, stack)
        a, b, c0, ok = _fit_plane(F, scratch, tag, dx, dy)
        if not ok:
            a, b, c0 = ba, bb, bc
        nz = 1.0 / math.sqrt(a * a + b * b + 1.0)
        nx, ny = -a * nz, -b * nz
        tag += 1
        if abs(F[bsr, bsc] - (a * bsc * dx - b * bsr * dy + c0)) * nz > eps:
            a, b, c0 = ba, bb, bc
            nz = 1.0 / math.sqrt(a * a + b * b + 1.0)
            nx, ny = -a * nz, -b * nz
        size = _flood(F, V, N, free, scratch, tag, bsr, bsc, a, b, c0, nx, ny, nz, eps, cos_a, dx, dy, stack)
        # a shape must be wide as well as large: a strip one or two samples wide (the flat top the grid
        # makes of a ridge between two sample rows, a wall's staircase) has no sample whose four
        # neighbours are all in it, and is left to the planes it separates
        inner = 0
        if size >= min_size:
            for r in range(1, H - 1):
                for c in range(1, W - 1):
                    if (scratch[r, c] == tag and scratch[r - 1, c] == tag and scratch[r + 1, c] == tag
                            and scratch[r, c - 1] == tag and scratch[r, c + 1] == tag):
                        inner += 1
        if size < min_size or inner < max(1, min_size // 4):
            fails += 1
            continue
        fails = 0
        for r in range(H):
            for c in range(W):
                if scratch[r, c] == tag:
                    label[r, c] = nplanes
                    free[r, c] = False
        n_free -= size
        planes[nplanes, 0] = nx
        planes[nplanes, 1] = ny
        planes[nplanes, 2] = nz
        planes[nplanes, 3] = -nz * c0  # n·p + d = 0 with z = a x + b y + c0
        nplanes += 1
    return label, planes[:nplanes].copy()


@njit(cache=True, nogil=True)
def facade_columns(F, V, dx, dy, jump):
    """The discontinuities of the grid: 4-neighbour edges whose heights differ by more than ``jump``.

    Returns
    -------
    cols
        (E, 6) float64 per edge: x, y of its midpoint (y = -row·dy), low z, high z, and the two samples'
        flat indices (row·W + col) as floats.
    """
    H, W = F.shape
    out = np.empty((2 * H * W, 6))
    n = 0
    for r in range(H):
        for c in range(W):
            if not V[r, c]:
                continue
            for d in range(2):
                rr = r + d
                cc = c + 1 - d
                if rr >= H or cc >= W or not V[rr, cc]:
                    continue
                dz = F[rr, cc] - F[r, c]
                if abs(dz) <= jump:
                    continue
                out[n, 0] = 0.5 * (c + cc) * dx
                out[n, 1] = -0.5 * (r + rr) * dy
                out[n, 2] = min(F[r, c], F[rr, cc])
                out[n, 3] = max(F[r, c], F[rr, cc])
                out[n, 4] = r * W + c
                out[n, 5] = rr * W + cc
                n += 1
    return out[:n].copy()


@njit(cache=True, nogil=True)
def detect_facades(cols, spacing, eps, min_points, seed, candidates, max_fail, window, gap):
    """Vertical planes among the façade points by localised RANSAC with connected scores.

    Each column of ``cols`` (see :func:`facade_columns`) stands for ``ceil((high - low) / spacing)`` façade
    points with its horizontal position; a vertical plane is a line in the horizontal plane. A candidate
    is drawn from two columns within ``window`` metres, scored by the points of the columns within ``eps``
    of the line that are connected along it (no gap over ``gap`` metres) to the seed, refitted by total
    least squares (closed-form 2×2 eigenvector) and accepted with at least ``min_points`` points.

    Returns
    -------
    label
        (E,) int32 façade index per column, -1 unassigned.
    planes
        (K, 4) float64 unit horizontal normal (nx, ny, 0) and d with n·p + d = 0.
    """
    E = cols.shape[0]
    label = np.full(E, -1, np.int32)
    weight = np.empty(E)
    for i in range(E):
        weight[i] = max(1.0, math.ceil((cols[i, 3] - cols[i, 2]) / spacing))
    planes = np.zeros((E + 1, 4))
    nplanes = 0
    if E < 2:
        return label, planes[:0].copy()
    state = np.int64(seed) * 2654435761 + 777
    free = np.ones(E, np.bool_)
    # a uniform bucket grid over the columns for the window search
    x0 = cols[:, 0].min()
    y0 = cols[:, 1].min()
    cell = max(window, 1e-6)
    gw = int((cols[:, 0].max() - x0) / cell) + 1
    gh = int((cols[:, 1].max() - y0) / cell) + 1
    bucket = np.empty(E, np.int64)
    for i in range(E):
        bucket[i] = int((cols[i, 1] - y0) / cell) * gw + int((cols[i, 0] - x0) / cell)
    order = np.argsort(bucket)
    start = np.zeros(gw * gh + 1, np.int64)
    for i in range(E):
        start[bucket[i] + 1] += 1
    for i in range(gw * gh):
        start[i + 1] += start[i]
    t = np.empty(E)
    idx = np.empty(E, np.int64)
    fails = 0
    while fails < max_fail:
        best_w = 0.0
        bnx = bny = bd = 0.0
        bs = -1
        for _ in range(candidates):
            ok = False
            s = 0
            for _t in range(64):
                state, u = _rand(state)
                s = int(u * E)
                if free[s]:
                    ok = True
                    break
            if not ok:
                continue
            gx = int((cols[s, 0] - x0) / cell)
            gy = int((cols[s, 1] - y0) / cell)
            # second column: a random free column in the 3×3 buckets around the seed, within the window
            cnt = 0
            for by in range(max(gy - 1, 0), min(gy + 2, gh)):
                for bx in range(max(gx - 1, 0), min(gx + 2, gw)):
                    b = by * gw + bx
                    for q in range(start[b], start[b + 1]):
                        j = order[q]
                        if j != s and free[j]:
                            ddx = cols[j, 0] - cols[s, 0]
                            ddy = cols[j, 1] - cols[s, 1]
                            if ddx * ddx + ddy * ddy <= window * window and ddx * ddx + ddy * ddy > 1e-12:
                                idx[cnt] = j
                                cnt += 1
            if cnt == 0:
                continue
            state, u = _rand(state)
            j = idx[int(u * cnt)]
            ux, uy = cols[j, 0] - cols[s, 0], cols[j, 1] - cols[s, 1]
            ul = math.sqrt(ux * ux + uy * uy)
            nx, ny = -uy / ul, ux / ul
            d = -(nx * cols[s, 0] + ny * cols[s, 1])
            w = _line_component(cols, weight, free, nx, ny, d, eps, s, gap, t, idx, None)
            if w > best_w:
                best_w, bnx, bny, bd, bs = w, nx, ny, d, s
        if best_w < min_points:
            fails += 1
            continue
        # refit: total least squares line through the component's columns (weighted)
        m = _line_component(cols, weight, free, bnx, bny, bd, eps, bs, gap, t, idx, label)
        sw = sx = sy = 0.0
        for q in range(E):
            if label[q] == -2:
                sw += weight[q]
                sx += weight[q] * cols[q, 0]
                sy += weight[q] * cols[q, 1]
        mx, my = sx / sw, sy / sw
        cxx = cxy = cyy = 0.0
        for q in range(E):
            if label[q] == -2:
                ex, ey = cols[q, 0] - mx, cols[q, 1] - my
                cxx += weight[q] * ex * ex
                cxy += weight[q] * ex * ey
                cyy += weight[q] * ey * ey
                label[q] = -1
        # normal = eigenvector of the smaller eigenvalue of [[cxx, cxy], [cxy, cyy]]
        lam = 0.5 * (cxx + cyy) - math.sqrt(0.25 * (cxx - cyy) ** 2 + cxy * cxy)
        nx, ny = cxy, lam - cxx
        nl = math.sqrt(nx * nx + ny * ny)
        if nl < 1e-12:
            nx, ny = (1.0, 0.0) if cxx < cyy else (0.0, 1.0)
        else:
            nx, ny = nx / nl, ny / nl
        d = -(nx * mx + ny * my)
        if abs(nx * cols[bs, 0] + ny * cols[bs, 1] + d) > eps:
            nx, ny, d = bnx, bny, bd
        m = _line_component(cols, weight, free, nx, ny, d, eps, bs, gap, t, idx, label)
        if m < min_points:
            for q in range(E):
                if label[q] == -2:
                    label[q] = -1
            fails += 1
            continue
        fails = 0
        for q in range(E):
            if label[q] == -2:
                label[q] = nplanes
                free[q] = False
        planes[nplanes, 0] = nx
        planes[nplanes, 1] = ny
        planes[nplanes, 3] = d
        nplanes += 1
    return label, planes[:nplanes].copy()


@njit(cache=True, nogil=True)
def _line_component(cols, weight, free, nx, ny, d, eps, s, gap, t, idx, mark):
    """Weight of the free columns within ``eps`` of the line that are connected along it to column ``s``
    (sorted by their position along the line, split where consecutive ones are over ``gap`` apart).
    With ``mark`` given, those columns get label -2 in it."""
    E = cols.shape[0]
    n = 0
    for q in range(E):
        if free[q] and abs(nx * cols[q, 0] + ny * cols[q, 1] + d) <= eps:
            idx[n] = q
            t[n] = -ny * cols[q, 0] + nx * cols[q, 1]
            n += 1
    if n == 0:
        return 0.0
    o = np.argsort(t[:n])
    ts = -ny * cols[s, 0] + nx * cols[s, 1]
    # find the run containing s
    k = 0
    for q in range(n):
        if idx[o[q]] == s:
            k = q
            break
    lo = k
    while lo > 0 and t[o[lo]] - t[o[lo - 1]] <= gap:
        lo -= 1
    hi = k
    while hi + 1 < n and t[o[hi + 1]] - t[o[hi]] <= gap:
        hi += 1
    w = 0.0
    for q in range(lo, hi + 1):
        w += weight[idx[o[q]]]
        if mark is not None:
            mark[idx[o[q]]] = -2
    _ = ts
    return w


@njit(cache=True, nogil=True)
def _add_id(S, v, k):
    for q in range(S.shape[1]):
        if S[v, q] == k:
            return
        if S[v, q] == -1:
            S[v, q] = k
            # keep sorted ascending (insertion)
            p = q
            while p > 0 and S[v, p - 1] > S[v, p]:
                tmp = S[v, p - 1]
                S[v, p - 1] = S[v, p]
                S[v, p] = tmp
                p -= 1
            return


@njit(cache=True, nogil=True)
def shape_map(F, V, dx, dy, roof_label, roof_planes, eps, col_label, cols, facade_planes, facade_eps, facade_offset,
              min_cos_edge):
    """Shape IDs within ε of every grid vertex, (H·W, MAX_IDS) int32 sorted, -1 padded.

    A vertex gets roof plane k when it is an inlier of k, or is within two samples of an inlier of k (the
    samples next to a ridge have one-sided normals of neither face and are often inliers of none) and
    lies within ``eps`` of the plane, and the two planes meet at an angle whose cosine is below
    ``min_cos_edge``: so the samples along a ridge carry both roof planes, while two nearly coplanar pieces
    of terrain do not make an edge. It gets façade f
    (ID ``facade_offset + f``) when it is an end of a discontinuity edge assigned to f: the sample at the
    top of a wall (eave) and the one at its foot; and a discontinuity sample next to such an end, at a
    similar height and within ``facade_eps`` of the façade plane (so eave corners carry both walls).
    """
    H, W = F.shape
    S = np.full((H * W, MAX_IDS), -1, np.int32)
    for r in range(H):
        for c in range(W):
            if not V[r, c]:
                continue
            v = r * W + c
            k0 = roof_label[r, c]
            if k0 >= 0:
                _add_id(S, v, k0)
            for rr in range(max(r - 2, 0), min(r + 3, H)):
                for cc in range(max(c - 2, 0), min(c + 3, W)):
                    k = roof_label[rr, cc]
                    if k < 0 or k == k0:
                        continue
                    if k0 >= 0 and (roof_planes[k, 0] * roof_planes[k0, 0] + roof_planes[k, 1] * roof_planes[k0, 1]
                                    + roof_planes[k, 2] * roof_planes[k0, 2]) > min_cos_edge:
                        continue
                    dist = (roof_planes[k, 0] * c * dx - roof_planes[k, 1] * r * dy + roof_planes[k, 2] * F[r, c]
                            + roof_planes[k, 3])
                    if abs(dist) <= eps:
                        _add_id(S, v, k)
    disc = np.zeros(H * W, np.bool_)
    for e in range(cols.shape[0]):
        disc[int(cols[e, 4])] = True
        disc[int(cols[e, 5])] = True
    for e in range(cols.shape[0]):
        f = col_label[e]
        if f < 0:
            continue
        for end in (4, 5):
            u = int(cols[e, end])
            _add_id(S, u, facade_offset + f)
            # the wall's end samples at a corner often belong to the other wall's columns: give the
            # façade to discontinuity samples next to its own within facade_eps of its plane
            ur, uc = u // W, u % W
            for rr in range(max(ur - 1, 0), min(ur + 2, H)):
                for cc in range(max(uc - 1, 0), min(uc + 2, W)):
                    x = rr * W + cc
                    if x == u or not disc[x]:
                        continue
                    if abs(F[rr, cc] - F[ur, uc]) > 0.5 * abs(cols[e, 3] - cols[e, 2]):
                        continue  # the other end of the wall, not a neighbour along it
                    dist = facade_planes[f, 0] * cc * dx - facade_planes[f, 1] * rr * dy + facade_planes[f, 3]
                    if abs(dist) <= facade_eps:
                        _add_id(S, x, facade_offset + f)
    return S
