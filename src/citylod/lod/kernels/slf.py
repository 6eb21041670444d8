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

numpy and numba only (see lod/kernels/__init__).
"""

from __future__ import annotations

import math

import numba
import numpy as np
import numpy.typing as npt

__all__ = ["DirectionSet", "direction_set", "evaluate", "interpolation", "parabolic", "rasterise"]

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


def interpolation(ds: DirectionSet, d: npt.ArrayLike) -> tuple[I64, F64]:
    """The four stored directions around ``d`` (3,) (towards the viewer) and their bilinear weights."""
    p = parabolic(d)
    r = float(np.hypot(*p))
    if r > 1.0:
        p = p / r
    g = (np.clip(p, -1.0, 1.0) + 1.0) * 0.5 * (ds.grid - 1)
    c0 = np.minimum(np.floor(g).astype(np.int64), ds.grid - 2)
    f = g - c0
    idx = np.array([ds.table[c0[1], c0[0]], ds.table[c0[1], c0[0] + 1], ds.table[c0[1] + 1, c0[0]],
                    ds.table[c0[1] + 1, c0[0] + 1]], np.int64)
    w = np.array([(1 - f[0]) * (1 - f[1]), f[0] * (1 - f[1]), (1 - f[0]) * f[1], f[0] * f[1]])
    return idx, w


@numba.njit(cache=True)
def _edge(ax, ay, bx, by, px, py):  # twice the signed area of (a, b, p)
    return (bx - ax) * (py - ay) - (by - ay) * (px - ax)


@numba.njit(cache=True)
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
