"""Surface light fields (Ruiters, "View-dependent far-field level of detail rendering for urban models"):
the direction set, the baking rasteriser and the evaluation of a compressed field for one view direction.

**Directions.** A hemisphere direction ``d = (dx, dy, dz)`` (unit, ``dz >= 0``, pointing from the ground
towards the viewer) has parabolic coordinates ``(x, y) = (dx, dy) / (1 + dz)``, which map the hemisphere onto
the unit disc. The stored directions are the points of a ``grid`` × ``grid`` lattice on ``[-1, 1]²`` within
``1 + ½ spacing`` of the centre (97 of 121 for the paper's 11 × 11 patch); those just outside the disc stand
for the horizon and are clamped to ``min_elevation_deg``. A view direction is evaluated bilinearly between the
four lattice points around its parabolic coordinates; a corner that is not stored takes the nearest stored one.

**Baking.** For a flat terrain at height ``z0`` and a direction ``d``, the ray that meets the bare terrain at
ground point ``q`` is ``q + s·d``; the surface a viewer far along ``d`` sees there is the intersection with the
largest ``s``, i.e. the highest one. So the picture "rendered orthographically along ``d`` and mapped back to
the terrain texel each pixel's ray would hit without buildings" is exactly a rasterisation of every triangle
sheared onto the ground plane (``q = p.xy − (dx, dy)/dz · (p.z − z0)``) on the terrain's own texel grid, with
a depth test that keeps the highest point: the paper's orthographic projection stretched to fill the target
at shallow angles, without the resampling from screen pixels to texels. :func:`rasterise` does that with
``oversample``² samples per texel (texel centres of the finer grid), unlit texture colours (citylod draws
textured tiles unlit), nearest texel of the (pre-filtered) atlas.

**Evaluation.** Clustered PCA (Per Cluster Factorisation): each texel belongs to one cluster ``c`` and holds
weights ``w_k``; its colour for stored direction ``j`` is ``mean[c, j] + Σ_k w_k · basis[c, k, j]``. The
bilinear blend of four directions is applied to the clusters' lumispheres first (256 × 4 rows), then every
texel costs one gather and three multiply-adds (:func:`evaluate`).

**Depth-corrected evaluation.** Blending four stored directions draws a point of height ``h`` in up to four
places, ``h·|v/v_z − d_j/d_jz|`` apart (the parallax of the blend). With a per-texel height of the building
tops ``T`` (the highest surface over each texel seen from straight above) :func:`evaluate_parallax` first
finds the point the view ray through texel ``q`` meets, ``P = (q + h·v_xy/v_z, h)`` with ``h`` the largest
height at which ``T(q + h·v_xy/v_z) ≥ h`` (a ray march over the height field: the viewer is above, so the
first surface met is the highest), then reads each stored direction where *that point* lies in its image,
``q_j = q + h·(v_xy/v_z − d_j,xy/d_j,z)`` (bilinear in the texel grid), and blends those. A point visible in
the view and in the four stored directions is then drawn once, at its place; what one of the directions
does not see (disocclusion) still blends in its occluder.

numpy and numba only (see lod/kernels/__init__).
"""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt

__all__ = [
    "DirectionSet",
    "blend_of",
    "box_average",
    "depth_corrected_blend",
    "depth_corrected_colours",
    "direction_patches",
    "direction_set",
    "evaluate",
    "evaluate_parallax",
    "interpolation",
    "march_heights",
    "parabolic",
    "patch_of",
    "rasterise",
    "view_shifts",
    "view_slope",
]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


class DirectionSet:
    """The stored directions: ``dirs`` (N, 3) unit vectors (towards the viewer), ``grid`` the lattice side,
    ``cells`` (N, 2) their lattice (column, row), ``table`` (grid, grid) the stored index of each lattice
    point (itself, or the nearest stored point for corners outside the set)."""

    def __init__(self, grid: int, min_elevation_deg: float) -> None:
        if grid < 3 or grid > 65:
            raise ValueError(f"direction grid must be 3..65 points per side, got {grid}")
        self.grid = int(grid)
        self.min_elevation_deg = float(min_elevation_deg)
        x = np.linspace(-1.0, 1.0, grid)
        step = 2.0 / (grid - 1)
        cols, rows = np.meshgrid(np.arange(grid), np.arange(grid))
        px, py = x[cols], x[rows]
        r = np.hypot(px, py)
        keep = r <= 1.0 + 0.5 * step + 1e-9
        self.cells = np.column_stack([cols[keep], rows[keep]]).astype(np.int64)
        u, v = px[keep], py[keep]
        rr = np.hypot(u, v)
        scale = np.where(rr > 1.0, 1.0 / np.maximum(rr, 1e-12), 1.0)  # outside the disc: onto the horizon
        u, v = u * scale, v * scale
        s = u * u + v * v
        d = np.column_stack([2 * u, 2 * v, 1 - s]) / (1 + s)[:, None]
        lo = math.sin(math.radians(min_elevation_deg))
        low = d[:, 2] < lo
        if low.any():  # lift to the lowest elevation baked, keeping the azimuth
            h = np.hypot(d[low, 0], d[low, 1])
            d[low, 0] *= math.cos(math.asin(lo)) / h
            d[low, 1] *= math.cos(math.asin(lo)) / h
            d[low, 2] = lo
        self.dirs = d / np.linalg.norm(d, axis=1)[:, None]
        #: First lattice column (and row) of each direction patch (:func:`direction_patches`).
        self.patch_starts = sorted({min(2 * k, self.grid - 3) for k in range(self.grid // 2)})
        stored = np.full((grid, grid), -1, np.int64)
        stored[self.cells[:, 1], self.cells[:, 0]] = np.arange(len(self.cells))
        table = stored.copy()
        for rw in range(grid):
            for cl in range(grid):
                if table[rw, cl] < 0:
                    dist = (self.cells[:, 0] - cl) ** 2 + (self.cells[:, 1] - rw) ** 2
                    table[rw, cl] = int(np.argmin(dist))
        self.table = table

    def __len__(self) -> int:
        return len(self.dirs)


def direction_set(grid: int = 11, min_elevation_deg: float = 5.0) -> DirectionSet:
    """The parabolic direction set (97 directions for ``grid`` 11).

    >>> len(direction_set(11)), len(direction_set(7))
    (97, 37)
    """
    return DirectionSet(grid, min_elevation_deg)


def parabolic(d: npt.ArrayLike) -> F64:
    """Parabolic coordinates (…, 2) of unit directions (…, 3) (``dz`` clamped to ≥ 0)."""
    a = np.asarray(d, np.float64)
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    return a[..., :2] / (1.0 + np.maximum(a[..., 2:3], 0.0))


def _lattice(ds: DirectionSet, d: npt.ArrayLike) -> tuple[I64, F64]:
    """Lattice (column, row) of the lower corner of the lattice square around ``d`` and the fractions."""
    p = parabolic(d)
    r = float(np.hypot(*p))
    if r > 1.0:
        p = p / r
    g = (np.clip(p, -1.0, 1.0) + 1.0) * 0.5 * (ds.grid - 1)
    c0 = np.minimum(np.floor(g).astype(np.int64), ds.grid - 2)
    return c0, g - c0


def direction_patches(ds: DirectionSet) -> list[I64]:
    """The stored directions split into overlapping patches of 3 × 3 lattice points, one starting at every
    second lattice point (the last ones clamped to the lattice), so that the four directions of any
    bilinear blend lie in one patch (:func:`patch_of`). Each patch: its stored direction indices, ascending.

    >>> [len(p) for p in direction_patches(direction_set(5))]
    [8, 8, 8, 8]
    """
    starts = ds.patch_starts
    return [np.array(sorted({int(ds.table[r, c]) for r in range(r0, r0 + 3) for c in range(c0, c0 + 3)}), np.int64)
            for r0 in starts for c0 in starts]


def _patch(ds: DirectionSet, c0: I64) -> int:
    starts = ds.patch_starts
    col = max(i for i, s in enumerate(starts) if s <= c0[0])
    row = max(i for i, s in enumerate(starts) if s <= c0[1])
    return row * len(starts) + col


def _corners(ds: DirectionSet, c0: I64, f: F64) -> tuple[I64, F64]:
    idx = np.array([ds.table[c0[1], c0[0]], ds.table[c0[1], c0[0] + 1], ds.table[c0[1] + 1, c0[0]],
                    ds.table[c0[1] + 1, c0[0] + 1]], np.int64)
    w = np.array([(1 - f[0]) * (1 - f[1]), f[0] * (1 - f[1]), (1 - f[0]) * f[1], f[0] * f[1]])
    return idx, w


def patch_of(ds: DirectionSet, d: npt.ArrayLike) -> int:
    """Index in :func:`direction_patches` of the patch holding the four directions blended for ``d``."""
    return _patch(ds, _lattice(ds, d)[0])


def interpolation(ds: DirectionSet, d: npt.ArrayLike) -> tuple[I64, F64]:
    """The four stored directions around ``d`` (3,) (towards the viewer) and their bilinear weights."""
    return _corners(ds, *_lattice(ds, d))


def blend_of(ds: DirectionSet, d: npt.ArrayLike) -> tuple[I64, F64, int]:
    """:func:`interpolation` and :func:`patch_of` of ``d`` from one lattice lookup (per cell and frame)."""
    c0, f = _lattice(ds, d)
    idx, w = _corners(ds, c0, f)
    return idx, w, _patch(ds, c0)


@numba.njit(cache=True)
def _edge(ax, ay, bx, by, px, py):  # twice the signed area of (a, b, p)
    return (bx - ax) * (py - ay) - (by - ay) * (px - ax)


@numba.njit(cache=True, nogil=True)
def rasterise(q: F64, z: F64, uv: F64, tex: I64, rgb: npt.NDArray[np.uint8], textures: npt.NDArray[np.uint8],
              zbuf: F64, col: npt.NDArray[np.uint8]) -> int:
    """Draw triangles into ``col`` (H, W, 3) keeping the highest (``zbuf`` (H, W), start it at the ground).

    ``q`` (T, 3, 2) vertex positions in sample units (sample (i, j) has its centre at (j + ½, i + ½)),
    ``z`` (T, 3) heights, ``uv`` (T, 3, 2) texture coordinates in 0..1 (origin top left), ``tex`` (T,) the
    texture of each triangle in ``textures`` (K, S, S, 3) or −1 for ``rgb`` (T, 3). Returns the number of
    samples written. Samples on a shared edge are drawn by both triangles (the depth test decides).
    """
    H, W = zbuf.shape
    S = textures.shape[1]
    written = 0
    for t in range(q.shape[0]):
        ax, ay = q[t, 0, 0], q[t, 0, 1]
        bx, by = q[t, 1, 0], q[t, 1, 1]
        cx, cy = q[t, 2, 0], q[t, 2, 1]
        area = _edge(ax, ay, bx, by, cx, cy)
        if abs(area) < 1e-12:
            continue
        x0 = max(int(math.floor(min(ax, bx, cx) - 0.5)), 0)
        x1 = min(int(math.ceil(max(ax, bx, cx) - 0.5)), W - 1)
        y0 = max(int(math.floor(min(ay, by, cy) - 0.5)), 0)
        y1 = min(int(math.ceil(max(ay, by, cy) - 0.5)), H - 1)
        if x0 > x1 or y0 > y1:
            continue
        inv = 1.0 / area
        k = tex[t]
        for i in range(y0, y1 + 1):
            py = i + 0.5
            for j in range(x0, x1 + 1):
                px = j + 0.5
                w0 = _edge(bx, by, cx, cy, px, py) * inv
                w1 = _edge(cx, cy, ax, ay, px, py) * inv
                w2 = 1.0 - w0 - w1
                if w0 < -1e-9 or w1 < -1e-9 or w2 < -1e-9:
                    continue
                h = w0 * z[t, 0] + w1 * z[t, 1] + w2 * z[t, 2]
                if h <= zbuf[i, j]:
                    continue
                zbuf[i, j] = h
                written += 1
                if k < 0:
                    col[i, j, 0] = rgb[t, 0]
                    col[i, j, 1] = rgb[t, 1]
                    col[i, j, 2] = rgb[t, 2]
                else:
                    u = w0 * uv[t, 0, 0] + w1 * uv[t, 1, 0] + w2 * uv[t, 2, 0]
                    v = w0 * uv[t, 0, 1] + w1 * uv[t, 1, 1] + w2 * uv[t, 2, 1]
                    tu = min(max(int(u * S), 0), S - 1)
                    tv = min(max(int(v * S), 0), S - 1)
                    col[i, j, 0] = textures[k, tv, tu, 0]
                    col[i, j, 1] = textures[k, tv, tu, 1]
                    col[i, j, 2] = textures[k, tv, tu, 2]
    return written


@numba.njit(cache=True, nogil=True)
def box_average(img: npt.NDArray[np.uint8], side: int) -> npt.NDArray[np.uint8]:  # pragma: no cover - compiled
    """The area average of ``img`` (H, W, C) uint8 to ``side`` × ``side`` when H and W are multiples of it,
    rounded half to even: the same bytes as numpy's ``reshape(...).mean(axis=(1, 3)).round()``, whose
    reduction over two strided axes took 12 ms for a city tile's atlas (compiled: one pass of integer sums)."""
    h, w, ch = img.shape
    bh, bw = h // side, w // side
    acc = np.zeros((side, side, ch), np.uint64)
    for r in range(h):
        rr = r // bh
        for c in range(w):
            cc = c // bw
            for k in range(ch):
                acc[rr, cc, k] += img[r, c, k]
    out = np.empty((side, side, ch), np.uint8)
    n = float(bh * bw)
    for rr in range(side):
        for cc in range(side):
            for k in range(ch):
                out[rr, cc, k] = np.uint8(np.rint(acc[rr, cc, k] / n))
    return out


@numba.njit(cache=True, nogil=True)
def mip_levels(rgb: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:  # pragma: no cover - compiled
    """The mip chain of a square power-of-two image ``rgb`` (n, n, 3), row 0 the top, packed as GL takes it:
    levels n², (n/2)², … 1² one after the other, each RGBA (alpha 255) with row 0 the bottom; each level the
    mean of 2 × 2 texels of the one above, rounded half up (what ``glGenerateMipmap`` of such a texture
    computes, to its rounding). Compiled: numpy's version took 0.1 ms a 64² field texture, every frame of a
    moving view for every cell."""
    n = rgb.shape[0]
    total, m = 0, n
    while m >= 1:
        total += m * m
        m //= 2
    out = np.empty(total * 4, np.uint8)
    for r in range(n):
        for c in range(n):
            o = ((n - 1 - r) * n + c) * 4
            out[o] = rgb[r, c, 0]
            out[o + 1] = rgb[r, c, 1]
            out[o + 2] = rgb[r, c, 2]
            out[o + 3] = 255
    above, off, m = 0, n * n * 4, n
    while m > 1:
        h = m // 2
        for r in range(h):
            for c in range(h):
                a = above + (2 * r * m + 2 * c) * 4
                b = a + m * 4
                o = off + (r * h + c) * 4
                for k in range(3):
                    s = np.int32(out[a + k]) + out[a + 4 + k] + out[b + k] + out[b + 4 + k]
                    out[o + k] = (s + 2) // 4
                out[o + 3] = 255
        above, off, m = off, off + h * h * 4, h
    return out


def evaluate(cluster: npt.NDArray[np.uint8], weights: F64, mean: F64, basis: F64, idx: I64,
             w: F64) -> npt.NDArray[np.uint8]:
    """Colours (…, 3) uint8 of texels with ``cluster`` (…) ids and ``weights`` (…, K) for the view blended
    from stored directions ``idx`` with bilinear weights ``w``.

    ``mean`` (C, N, 3) and ``basis`` (C, K, N, 3) are the clusters' mean and eigen-lumispheres over the N
    stored directions.
    """
    m = np.tensordot(mean[:, idx, :], w, axes=([1], [0]))  # (C, 3)
    b = np.tensordot(basis[:, :, idx, :], w, axes=([2], [0]))  # (C, K, 3)
    c = cluster.astype(np.int64)
    out = m[c] + np.einsum("...k,...kc->...c", weights, b[c])
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def view_slope(v: npt.ArrayLike) -> F64:
    """The horizontal run (x, y) per metre of height of a ray along ``v`` (3,) (any length, towards the
    viewer; ``v_z`` floored at 1e-6)."""
    vv = np.asarray(v, np.float64)
    return vv[:2] / max(float(vv[2]), 1e-6)


def march_heights(top: npt.NDArray[np.floating], texel_m: float, v: npt.ArrayLike) -> F64:
    """Height (m above the ground) of the point each texel's view ray meets, (T, T).

    ``top`` (T, T): height of the building tops per texel, row 0 at the north edge; ``v`` (3,): unit view
    direction towards the viewer. The ray through the centre of texel ``q`` rises along ``q + s·v_xy/v_z``
    at height ``s``; the answer is the largest ``s`` at which the texel column it is in reaches ``s``
    (``top`` is a field of flat-topped columns, one per texel; outside the cell the ground is assumed), so a
    ground texel answers its own top. Exact: :func:`_ray_top` walks the columns the ray crosses from the top
    down.
    """
    a = view_slope(v)
    hmax = float(top.max()) if top.size else 0.0
    if hmax <= 0.0:
        return np.zeros(top.shape)
    return _march(np.ascontiguousarray(top, np.float64), hmax, a[0] / texel_m, a[1] / texel_m)


@numba.njit(cache=True, nogil=True)
def _ray_top(top, r, c, ax, ay, smax):  # pragma: no cover - compiled
    """The largest ``s`` in [0, ``smax``] with ``top[floor(r + ½ − s·ay), floor(c + ½ + s·ax)] ≥ s``: the
    ray from texel (``r``, ``c``)'s centre, ``ax, ay`` its advance in texels per metre of height.

    A 2D DDA from the top down. In the column it crosses for heights [s_lo, s_hi], the ray is below that
    column's top somewhere iff top ≥ s_lo, and then highest at min(top, s_hi); columns crossed higher up
    give larger heights, so the first column met from the top that reaches the ray holds the answer. The
    walk starts where the ray leaves the cell (or at ``smax``) and crosses at most 2T + 2 columns, where the
    sampled march it replaces tested every half metre of height."""
    t = top.shape[0]
    x0, y0 = c + 0.5, r + 0.5
    dx, dy = ax, -ay
    s_hi = smax  # the ray leaves the cell's square at the smallest slab exit
    if dx > 0.0:
        s_hi = min(s_hi, (t - x0) / dx)
    elif dx < 0.0:
        s_hi = min(s_hi, -x0 / dx)
    if dy > 0.0:
        s_hi = min(s_hi, (t - y0) / dy)
    elif dy < 0.0:
        s_hi = min(s_hi, -y0 / dy)
    j = min(max(int(math.floor(x0 + s_hi * dx)), 0), t - 1)
    i = min(max(int(math.floor(y0 + s_hi * dy)), 0), t - 1)
    for _ in range(2 * t + 4):
        sx = (j - x0) / dx if dx > 0.0 else ((j + 1 - x0) / dx if dx < 0.0 else -1.0)
        sy = (i - y0) / dy if dy > 0.0 else ((i + 1 - y0) / dy if dy < 0.0 else -1.0)
        s_lo = max(sx, sy, 0.0)
        h = top[i, j]
        if s_lo < s_hi and h >= s_lo:  # a column only touched at a corner (length 0) is not entered
            return min(h, s_hi)
        if s_lo <= 0.0:
            break
        if sx >= sy:
            j += -1 if dx > 0.0 else 1
        if sy >= sx:
            i += -1 if dy > 0.0 else 1
        if not (0 <= i < t and 0 <= j < t):
            break
        s_hi = s_lo
    return 0.0


@numba.njit(cache=True, nogil=True)
def _march(top, smax, ax, ay):  # pragma: no cover - compiled
    """march_heights per texel (:func:`_ray_top`)."""
    t = top.shape[0]
    h = np.zeros(top.shape)
    for r in range(t):
        for c in range(t):
            h[r, c] = _ray_top(top, r, c, ax, ay, smax)
    return h


def view_shifts(v: npt.ArrayLike, dirs: F64, idx: I64, texel_m: float) -> tuple[F64, F64]:
    """The unit view direction and, for each blended stored direction ``dirs[idx]``, the parallax between it
    and the view per metre of height, in texels (x, y): where a point that high lies in that direction's
    image relative to where the view sees it."""
    vv = np.asarray(v, np.float64)
    vv = vv / np.linalg.norm(vv)
    a = view_slope(vv)
    d = np.asarray(dirs, np.float64)[np.asarray(idx, np.int64)]
    return vv, (a - d[:, :2] / np.maximum(d[:, 2:3], 1e-6)) / texel_m


def depth_corrected_blend(images: F64, idx: I64, w: F64, dirs: F64, top: npt.NDArray[np.floating],
                          texel_m: float, v: npt.ArrayLike, tolerance_m: float = 1.0,
                          seen_heights: list[npt.NDArray[np.floating]] | None = None) -> F64:
    """Blend ``images`` (4, T, T, 3), the field of stored directions ``idx`` with bilinear weights ``w``, for
    the view ``v`` (unit, towards the viewer) with the depth correction of the module's docstring: ``dirs``
    (N, 3) the stored directions, ``top`` (T, T) building-top heights (m), ``texel_m`` the texel size.

    A stored direction whose own ray march meets, at the texel where the viewed point should lie, a surface
    more than ``tolerance_m`` higher or lower, does not see that point (it is hidden there, or the height
    field is too coarse to tell): its weight goes to the directions that do; where none does, the plain
    weights stay. ``seen_heights``: the ray marches of the stored directions (``march_heights(top, texel_m,
    dirs[j])`` for each of ``idx``), when the caller keeps them between views. Evaluated at run time for every
    cell drawn whose direction moved, hence compiled (:func:`_blend`)."""
    vv, shifts = view_shifts(v, dirs, idx, texel_m)
    h = march_heights(top, texel_m, vv)
    w = np.asarray(w, np.float64)
    if seen_heights is None:
        seen_heights = [march_heights(top, texel_m, dirs[j]) for j in idx]
    return _blend(np.ascontiguousarray(images), shifts, w, np.ascontiguousarray(np.stack(seen_heights)), h,
                  float(tolerance_m))


@numba.njit(cache=True, nogil=True)
def _blend_texel(images, seen, loc, w, shifts, r, c, hh, tol, wtot):  # pragma: no cover - compiled
    """The depth-corrected blend at texel (``r``, ``c``) whose view ray meets height ``hh``: the colour
    (3 floats). ``loc`` the rows of ``images`` (P, T, T, 3) and ``seen`` (P, T, T) blended with weights
    ``w`` (sum of the positive ones ``wtot``), ``shifts`` (4, 2) each direction's parallax per metre of
    height in texels (x, y). Each direction is sampled bilinearly at where the viewed point lies in its
    image (edges clamped); one whose own ray march there is more than ``tol`` off does not see the point."""
    t = images.shape[1]
    acc0 = acc1 = acc2 = 0.0
    fb0 = fb1 = fb2 = 0.0
    wsum = 0.0
    for k in range(loc.shape[0]):
        wj = w[k]
        if wj <= 0.0:
            continue
        j = loc[k]
        rr = r - hh * shifts[k, 1]
        cc = c + hh * shifts[k, 0]
        rq = min(max(rr, 0.0), t - 1.0)
        cq = min(max(cc, 0.0), t - 1.0)
        r0 = min(int(math.floor(rq)), t - 2) if t > 1 else 0
        c0 = min(int(math.floor(cq)), t - 2) if t > 1 else 0
        fr, fc = rq - r0, cq - c0
        r1, c1 = min(r0 + 1, t - 1), min(c0 + 1, t - 1)
        s0 = ((1 - fr) * ((1 - fc) * images[j, r0, c0, 0] + fc * images[j, r0, c1, 0])
              + fr * ((1 - fc) * images[j, r1, c0, 0] + fc * images[j, r1, c1, 0]))
        s1 = ((1 - fr) * ((1 - fc) * images[j, r0, c0, 1] + fc * images[j, r0, c1, 1])
              + fr * ((1 - fc) * images[j, r1, c0, 1] + fc * images[j, r1, c1, 1]))
        s2 = ((1 - fr) * ((1 - fc) * images[j, r0, c0, 2] + fc * images[j, r0, c1, 2])
              + fr * ((1 - fc) * images[j, r1, c0, 2] + fc * images[j, r1, c1, 2]))
        ri = min(max(int(np.rint(rr)), 0), t - 1)
        ci = min(max(int(np.rint(cc)), 0), t - 1)
        if abs(seen[j, ri, ci] - hh) <= tol:
            acc0 += wj * s0
            acc1 += wj * s1
            acc2 += wj * s2
            wsum += wj
        fb0 += wj * s0
        fb1 += wj * s1
        fb2 += wj * s2
    if wsum > 1e-9:
        return acc0 / wsum, acc1 / wsum, acc2 / wsum
    return fb0 / wtot, fb1 / wtot, fb2 / wtot


@numba.njit(cache=True, nogil=True)
def _positive_sum(w):  # pragma: no cover - compiled
    tot = 0.0
    for k in range(w.shape[0]):
        if w[k] > 0.0:
            tot += w[k]
    return max(tot, 1e-9)


@numba.njit(cache=True, nogil=True)
def _blend(images, shifts, w, seen, h, tol):  # pragma: no cover - compiled
    """The per-texel loop of :func:`depth_corrected_blend` (:func:`_blend_texel` over ``images`` (4, T, T, 3)
    and ``seen`` (4, T, T), the view's ray march ``h`` (T, T))."""
    t = images.shape[1]
    loc = np.arange(images.shape[0])
    wtot = _positive_sum(w)
    out = np.zeros((t, t, 3))
    for r in range(t):
        for c in range(t):
            out[r, c, 0], out[r, c, 1], out[r, c, 2] = _blend_texel(images, seen, loc, w, shifts, r, c, h[r, c],
                                                                    tol, wtot)
    return out


def depth_corrected_colours(images: npt.NDArray[np.float32], seen: npt.NDArray[np.float32], loc: I64, w: F64,
                            dirs: F64, top: F64, texel_m: float, v: npt.ArrayLike,
                            tolerance_m: float = 1.0) -> npt.NDArray[np.uint8]:
    """:func:`depth_corrected_blend` rounded to colours (T, T, 3) uint8, in one compiled pass: the run-time
    lookup of a cell. ``images`` (P, T, T, 3) and ``seen`` (P, T, T) hold the stored directions' images and
    ray marches of the cell's direction patch (only the rows ``loc`` are read), ``dirs`` (P, 3) their
    directions, ``top`` (T, T) float64 building tops. The view's ray march and the blend run per texel row
    on numba's threads; the result equals ``rint(depth_corrected_blend(images[loc], …))`` clipped to 0–255
    (same arithmetic, per texel)."""
    vv, shifts = view_shifts(v, dirs, loc, texel_m)
    a = view_slope(vv)
    hmax = float(top.max()) if top.size else 0.0
    return _lookup(images, seen, np.asarray(loc, np.int64), np.asarray(w, np.float64), shifts, top, max(hmax, 0.0),
                   a[0] / texel_m, a[1] / texel_m, float(tolerance_m))


@numba.njit(cache=True, nogil=True, parallel=True)  # texel rows on numba's threads
def _lookup(images, seen, loc, w, shifts, top, smax, ax, ay, tol):  # pragma: no cover - compiled
    """:func:`_march` and :func:`_blend` fused per texel (no intermediate arrays), rounded to bytes."""
    t = top.shape[0]
    out = np.empty((t, t, 3), np.uint8)
    wtot = _positive_sum(w)
    for r in numba.prange(t):
        for c in range(t):
            hh = _ray_top(top, r, c, ax, ay, smax) if smax > 0.0 else 0.0
            x0, x1, x2 = _blend_texel(images, seen, loc, w, shifts, r, c, hh, tol, wtot)
            out[r, c, 0] = min(max(np.rint(x0), 0.0), 255.0)
            out[r, c, 1] = min(max(np.rint(x1), 0.0), 255.0)
            out[r, c, 2] = min(max(np.rint(x2), 0.0), 255.0)
    return out


def evaluate_parallax(cluster: npt.NDArray[np.uint8], weights: F64, mean: F64, basis: F64, idx: I64, w: F64,
                      dirs: F64, top: npt.NDArray[np.floating], texel_m: float,
                      v: npt.ArrayLike) -> npt.NDArray[np.uint8]:
    """Like :func:`evaluate` for a square cell (``cluster`` (T, T)) with the depth correction
    (:func:`depth_corrected_blend`): the four directions' images are reconstructed whole, then resampled."""
    cl = cluster.astype(np.int64)
    images = np.stack([mean[cl, j] + np.einsum("...k,...kc->...c", weights, basis[cl, :, j]) for j in idx])
    out = depth_corrected_blend(images, idx, w, dirs, top, texel_m, v)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)
