"""Far-field surface light fields over a city tileset (Ruiters, "View-dependent far-field level of detail
rendering for urban models"): baking, clustered-PCA compression and the tileset that stores them.

**Cells.** A square quadtree over the city's footprint; every cell holds ``texels``² terrain texels, so the
texel size halves per level, down to the first level whose texels are at most ``texel_m``.

**Baking** (:mod:`citylod.lod.kernels.slf`): for each stored direction every triangle of the city tileset's
leaves (full geometry, atlas textures pre-filtered to ``tex_px``) is sheared onto the flat terrain and
rasterised on the cell's texel grid with ``oversample``² samples per texel, keeping the highest surface;
samples no building covers keep the ground colour; the samples of a texel are averaged. The whole city is
drawn into each cell (not only its 8 neighbours): a tall building seen at 5° elevation reaches 230 m. The
terrain is a plane at the city's lowest point, which hides no texel, so no hidden texels need filling. A
numba rasteriser, not VTK: the mapping from pixels to terrain texels is then exact (no resampling of a
screen image) and the lod layer stays free of VTK (docs/DESIGN.md, layout).

**Compression** (Per Cluster Factorisation over direction patches): the stored directions are split into
overlapping patches of 3 × 3 lattice points (:func:`~citylod.lod.kernels.slf.direction_patches`; any
bilinear blend of four directions lies in one), and each patch is compressed on its own: the texels of the
``group`` × ``group`` neighbouring cells of one level share ``clusters`` clusters (k-means in a
12-dimensional PCA projection of the lumispheres, then the nearest centroid for every texel, refined by
reconstruction error); each cluster keeps its mean lumisphere and its ``components`` leading
eigen-lumispheres (orthogonal iteration), each texel its cluster and weights, quantised to 8 bits per
cluster and component. A texel's lumisphere over all directions is of high rank (it sees ground, façades and
roofs of different houses from different directions: 3 components of 69 directions leave a mean error of
22 of 255); over the 9 directions of one patch it is not (the same clusters leave 11, orbit frame of the
sample city, docs/PERFORMANCE_LOG.md). A view loads one patch per cell: 4 bytes per texel (deflated) and
its share of a table of 256 × 9 × 3 × 4 bytes.

**Storage.** Every cell is an ordinary 3D Tiles tile: a textured quad whose texture is the field's average
over all directions (what other clients draw). Its ``extras.citylod_slf`` names its binary files per patch
(``slf/cells/KEY_{patch}.bin`` texels and building tops, ``slf/groups/KEY_{patch}.bin`` lumispheres; format
in :func:`read_cell_arrays` and :func:`read_group`); the tileset's ``extras.citylod`` holds ``kind: "slf"``,
the direction set and its ``patches``, the ground and the city tileset it was baked from.
``geometricError`` is the texel size plus the mean parallax displacement of the view-direction
interpolation (:func:`parallax_factor`) times a height: without stored heights the mean building height in
the cell's 3 × 3 neighbourhood, with them what the depth-corrected lookup
(:func:`~citylod.lod.kernels.slf.evaluate_parallax`) gets wrong, the mean amount by which the texel's top
overstates the surface under it plus half a ray-march step. An expected displacement, not a bound.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import struct
import time
import zlib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from citylod.core.errors import InputError
from citylod.core.fileio import publish_dir
from citylod.io.image import decode_image, encode_image, resize_image
from citylod.io.tiles3d import MeshData, TileContent, TileSpec, open_tileset, write_content, write_tileset
from citylod.lod.kernels.slf import (
    DirectionSet,
    box_average,
    direction_patches,
    direction_set,
    interpolation,
    rasterise,
)

__all__ = ["Cpca", "SlfReport", "bake_cell", "bake_heights", "build_slf", "city_triangles", "compress", "parallax_factor",
           "read_cell", "read_cell_arrays", "read_group", "read_heights",
           "reconstruct"]

F64 = npt.NDArray[np.float64]
U8 = npt.NDArray[np.uint8]
MAGIC_CELL = b"CLSLFC1\0"
MAGIC_GROUP = b"CLSLFG1\0"
GROUND_RGB = (126, 132, 112)


# ----------------------------------------------------------------------------------------------- scene
@dataclass
class CityTriangles:
    """Every triangle of a city tileset's leaves in the tileset CRS: ``tri`` (T, 3, 3), ``uv`` (T, 3, 2),
    ``tex`` (T,) index into ``textures`` (K, S, S, 3) or −1, ``rgb`` (T, 3) colours of untextured ones."""

    tri: F64
    uv: F64
    tex: npt.NDArray[np.int64]
    rgb: U8
    textures: U8
    crs: Any
    path: Path
    _boxes: F64 | None = field(default=None, repr=False)

    def boxes(self) -> F64:
        """Each triangle's box (T, 6): x min, x max, y min, y max, z min, z max (computed once)."""
        if self._boxes is None:
            t = self.tri
            self._boxes = np.stack([t[:, :, 0].min(axis=1), t[:, :, 0].max(axis=1), t[:, :, 1].min(axis=1),
                                    t[:, :, 1].max(axis=1), t[:, :, 2].min(axis=1), t[:, :, 2].max(axis=1)], axis=1)
        return self._boxes

    def near(self, x0: float, y0: float, size_m: float, z0: float, reach: float) -> npt.NDArray[np.int64]:
        """Indices (ascending) of the triangles that can land on the square ``x0..x0+size_m`` ×
        ``y0..y0+size_m`` when sheared onto the plane ``z0`` along any direction whose horizontal run per
        metre of height is at most ``reach``: a vertex moves by at most ``reach`` × its height above (or
        below) the plane, so a triangle whose box, grown by that, misses the square lands outside it in
        every direction. A superset of what each direction's own test keeps, in the same order."""
        b = self.boxes()
        grow = reach * np.maximum(np.abs(b[:, 5] - z0), np.abs(b[:, 4] - z0)) + 1e-6 * (1.0 + size_m)
        keep = ((b[:, 1] + grow >= x0) & (b[:, 0] - grow <= x0 + size_m)
                & (b[:, 3] + grow >= y0) & (b[:, 2] - grow <= y0 + size_m))
        return np.flatnonzero(keep)

    def subset(self, idx: npt.NDArray[np.int64]) -> CityTriangles:
        """The triangles ``idx`` (same textures)."""
        return CityTriangles(self.tri[idx], self.uv[idx], self.tex[idx], self.rgb[idx], self.textures, self.crs,
                             self.path)


def city_triangles(city_dir: str | PathLike[str], tex_px: int = 256) -> CityTriangles:
    """Read the leaves of a city tileset (:mod:`citylod.lod.build.city`) with their atlases box-filtered to
    ``tex_px`` (a texel of a far field covers many atlas texels; the filter stands in for mip-mapping)."""
    ts = open_tileset(Path(city_dir))
    if ts.kind not in ("city", "unknown"):
        raise InputError(f"not a city tileset (citylod kind {ts.kind!r}); build one with 'citylod build city'",
                         ts.path)
    tris, uvs, texs, rgbs, images = [], [], [], [], []
    for tile in ts.walk():
        if tile.children or not tile.content_paths:
            continue
        content = tile.load_content()
        m = tile.matrix
        for mesh in content.meshes:
            if not len(mesh.faces):
                continue
            pos = mesh.positions.astype(np.float64) @ m[:3, :3].T + m[:3, 3]
            f = mesh.faces.astype(np.int64)
            tris.append(pos[f])
            if mesh.texture is not None and mesh.uv is not None:
                img = decode_image(mesh.texture, str(tile.content_path))[..., :3]
                if img.shape[0] != tex_px or img.shape[1] != tex_px:
                    img = _box_resize(img, tex_px)
                images.append(img)
                uvs.append(mesh.uv.astype(np.float64)[f])
                texs.append(np.full(len(f), len(images) - 1, np.int64))
                rgbs.append(np.zeros((len(f), 3), np.uint8))
            else:
                uvs.append(np.zeros((len(f), 3, 2)))
                texs.append(np.full(len(f), -1, np.int64))
                c = mesh.colors[f[:, 0], :3] if mesh.colors is not None else np.full((len(f), 3), 190, np.uint8)
                rgbs.append(c.astype(np.uint8))
    if not tris:
        raise InputError("the city tileset holds no triangles to bake", ts.path)
    textures = np.stack(images) if images else np.zeros((1, 1, 1, 3), np.uint8)
    return CityTriangles(np.concatenate(tris), np.concatenate(uvs), np.concatenate(texs), np.concatenate(rgbs),
                         textures, ts.crs, ts.path)


def _box_resize(img: U8, side: int) -> U8:
    """Area average to ``side``² when the image is a multiple of it, else OpenImageIO's resize."""
    h, w = img.shape[:2]
    if h % side == 0 and w % side == 0:
        return box_average(np.ascontiguousarray(img), side)
    return resize_image(img, side, side)


# ----------------------------------------------------------------------------------------------- baking
def bake_cell(scene: CityTriangles, x0: float, y0: float, size_m: float, texels: int, z0: float,
              ds: DirectionSet, *, oversample: int = 2, ground_rgb: tuple[int, int, int] = GROUND_RGB) -> U8:
    """The uncompressed field of one cell, (texels, texels, N, 3) uint8, row 0 at the cell's north edge
    (image order), for the square ``x0..x0+size_m`` × ``y0..y0+size_m``."""
    n = texels * oversample
    step = size_m / n  # metres per sample
    out = np.empty((texels, texels, len(ds), 3), np.uint8)
    # Only the triangles that some direction can shear onto the cell (the same ones, in the same order, that
    # each direction's test below keeps from the whole city): a fine cell of a large city then tests a few
    # per cent of its triangles 69–97 times instead of all of them.
    reach = float(np.max(np.hypot(ds.dirs[:, 0], ds.dirs[:, 1]) / np.maximum(ds.dirs[:, 2], 1e-9)))
    scene = scene.subset(scene.near(x0, y0, size_m, z0, reach))
    z = scene.tri[:, :, 2]
    h = z - z0
    for j, d in enumerate(ds.dirs):
        sx, sy = d[0] / d[2], d[1] / d[2]
        qx = scene.tri[:, :, 0] - sx * h
        qy = scene.tri[:, :, 1] - sy * h
        # Sample coordinates: column from x, row from the north edge (y0 + size_m) down.
        cx = (qx - x0) / step
        cy = (y0 + size_m - qy) / step
        sel = (cx.max(axis=1) >= 0) & (cx.min(axis=1) <= n) & (cy.max(axis=1) >= 0) & (cy.min(axis=1) <= n)
        sel &= h.max(axis=1) > 1e-3  # triangles lying on the ground are the ground
        q = np.ascontiguousarray(np.stack([cx[sel], cy[sel]], axis=-1))
        zbuf = np.full((n, n), z0 + 1e-3)
        col = np.empty((n, n, 3), np.uint8)
        col[:] = ground_rgb
        rasterise(q, np.ascontiguousarray(z[sel]), np.ascontiguousarray(scene.uv[sel]),
                  np.ascontiguousarray(scene.tex[sel]), np.ascontiguousarray(scene.rgb[sel]), scene.textures,
                  zbuf, col)
        avg = col.reshape(texels, oversample, texels, oversample, 3).astype(np.float32).mean(axis=(1, 3))
        out[:, :, j] = np.rint(avg).astype(np.uint8)
    return out


def bake_heights(scene: CityTriangles, x0: float, y0: float, size_m: float, texels: int, z0: float, *,
                 oversample: int = 2) -> tuple[npt.NDArray[np.float32], float]:
    """Building-top heights of a cell for the depth-corrected evaluation
    (:func:`citylod.lod.kernels.slf.evaluate_parallax`): (texels, texels) metres above ``z0``, row 0 north,
    the highest of ``oversample``² samples per texel seen from straight above; and the mean amount by which
    that overstates the true height of the building samples (the height error the lookup is left with)."""
    n = texels * oversample
    step = size_m / n
    scene = scene.subset(scene.near(x0, y0, size_m, z0, 0.0))
    z = scene.tri[:, :, 2]
    cx = (scene.tri[:, :, 0] - x0) / step
    cy = (y0 + size_m - scene.tri[:, :, 1]) / step
    sel = (cx.max(axis=1) >= 0) & (cx.min(axis=1) <= n) & (cy.max(axis=1) >= 0) & (cy.min(axis=1) <= n)
    sel &= (z - z0).max(axis=1) > 1e-3
    zbuf = np.full((n, n), z0 + 1e-3)
    col = np.zeros((n, n, 3), np.uint8)
    rasterise(np.ascontiguousarray(np.stack([cx[sel], cy[sel]], axis=-1)), np.ascontiguousarray(z[sel]),
              np.ascontiguousarray(scene.uv[sel]), np.ascontiguousarray(scene.tex[sel]),
              np.ascontiguousarray(scene.rgb[sel]), scene.textures, zbuf, col)
    h = np.maximum(zbuf - z0, 0.0).reshape(texels, oversample, texels, oversample)
    top = h.max(axis=(1, 3))
    built = h > 0.01
    over = (top[:, None, :, None] - h)[built]
    return top.astype(np.float32), float(over.mean()) if over.size else 0.0


def parallax_factor(ds: DirectionSet, min_elevation_deg: float = 10.0, samples: int = 4000) -> float:
    """Mean displacement, per metre of height, of a point drawn from the bilinear blend of four stored
    directions instead of the exact view direction, measured across the view (views of elevation ≥
    ``min_elevation_deg``, uniform in azimuth and elevation, fixed seed)."""
    rng = np.random.default_rng(0)
    total = 0.0
    for _ in range(samples):
        az, el = rng.uniform(0, 2 * math.pi), math.radians(rng.uniform(min_elevation_deg, 90.0))
        v = np.array([math.cos(az) * math.cos(el), math.sin(az) * math.cos(el), math.sin(el)])
        idx, w = interpolation(ds, v)
        diff = ds.dirs[idx] / ds.dirs[idx, 2:3] - v / v[2]
        perp = diff - (diff @ v)[:, None] * v
        total += float(w @ np.linalg.norm(perp, axis=1))
    return total / samples


# ------------------------------------------------------------------------------------------ compression
@dataclass
class Cpca:
    """A clustered PCA of texels (n, N, 3): ``cluster`` (n,) uint8, ``q`` (n, K) uint8 weights,
    ``mean`` (C, N, 3) uint8, ``lo``/``step`` (C, K) float32 (weight = lo + q·step),
    ``basis`` (C, K, N, 3) int8 scaled by ``scale`` (C, K) float32."""

    cluster: U8
    q: U8
    mean: U8
    lo: npt.NDArray[np.float32]
    step: npt.NDArray[np.float32]
    basis: npt.NDArray[np.int8]
    scale: npt.NDArray[np.float32]

    def lumispheres(self) -> tuple[F64, F64]:
        """(mean, basis) in colour units for :func:`citylod.lod.kernels.slf.evaluate` with weights ``q``."""
        b = self.basis.astype(np.float64) * self.scale[:, :, None, None]
        mean = self.mean.astype(np.float64) + np.einsum("ck,cknj->cnj", self.lo.astype(np.float64), b)
        return mean, b * self.step[:, :, None, None]


def _kmeans_pp(x: F64, k: int, rng: np.random.Generator) -> F64:
    """k-means++ seeds (Arthur and Vassilvitskii 2007): each next seed drawn with probability proportional to
    its squared distance to the nearest seed so far, kept per point (O(k·n)). scipy's ``kmeans2(minit="++")``
    draws the same way but measures every point against all seeds again for each new one (O(k²·n)): half of
    a 65,536-texel compression's time."""
    n = len(x)
    seeds = np.empty((k, x.shape[1]))
    i = int(rng.integers(n))
    seeds[0] = x[i]
    d2 = ((x - x[i]) ** 2).sum(axis=1)
    for j in range(1, k):
        total = float(d2.sum())
        i = int(rng.integers(n)) if total <= 0 else min(int(np.searchsorted(np.cumsum(d2), rng.random() * total)), n - 1)
        seeds[j] = x[i]
        d2 = np.minimum(d2, ((x - x[i]) ** 2).sum(axis=1))
    return seeds


def compress(x: U8, clusters: int = 256, components: int = 3, seed: int = 0) -> Cpca:
    """Per Cluster Factorisation of texels ``x`` (n, N, 3) uint8 (see the module's docstring)."""
    from scipy.cluster.vq import kmeans2, vq

    n, nd, _ = x.shape
    data = x.reshape(n, nd * 3).astype(np.float32)
    rng = np.random.default_rng(seed)
    mu = data.mean(axis=0)
    sample = data[rng.choice(n, min(n, 16384), replace=False)] - mu
    _, _, vt = np.linalg.svd(sample, full_matrices=False)
    proj = (data - mu) @ vt[:12].T
    c = min(clusters, n)
    pick = proj[rng.choice(n, min(n, 16384), replace=False)]
    centroids, _ = kmeans2(pick.astype(np.float64), _kmeans_pp(pick.astype(np.float64), c, rng), iter=8,
                           minit="matrix")
    label, _ = vq(proj.astype(np.float64), centroids)
    k = components

    def fit(label: npt.NDArray[np.int64]) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        """Each cluster's mean and k leading eigenvectors (orthogonal iteration: a few products with xc)."""
        mean = np.zeros((clusters, nd * 3), np.float32)
        basis = np.zeros((clusters, k, nd * 3), np.float32)
        for ci in range(c):
            xc = data[label == ci]
            if not len(xc):
                continue
            mean[ci] = xc.mean(axis=0)
            xc = xc - mean[ci]
            q = np.linalg.qr(rng.standard_normal((nd * 3, k)).astype(np.float32))[0]
            for _ in range(6):
                q = np.linalg.qr(xc.T @ (xc @ q))[0]
            basis[ci] = q.T
        return mean, basis

    def residual(label: npt.NDArray[np.int64], mean: npt.NDArray[np.float32],
                 basis: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        out = np.empty(n, np.float32)
        for s0 in range(0, n, 8192):  # in blocks: the gathered bases are (block, k, N·3)
            sl = slice(s0, s0 + 8192)
            xc = data[sl] - mean[label[sl]]
            b = basis[label[sl]]
            w = np.einsum("nd,nkd->nk", xc, b)
            out[sl] = (xc ** 2).sum(axis=1) - (w ** 2).sum(axis=1)
        return out

    label = label.astype(np.int64)
    mean, basis = fit(label)
    # Per Cluster Factorisation: move each texel to whichever of its 6 nearest centroids reconstructs it best
    # with that cluster's eigen-lumispheres, refit, twice (−10 % RMS on a 2 × 2 group of the sample city).
    cf = centroids.astype(np.float32)
    dist = (proj ** 2).sum(axis=1)[:, None] - 2 * proj @ cf.T + (cf ** 2).sum(axis=1)[None]
    near = np.argsort(dist, axis=1)[:, :6]
    del dist
    for _ in range(2):
        best = np.full(n, np.inf, np.float32)
        new = label.copy()
        for j in range(near.shape[1]):
            e = residual(near[:, j], mean, basis)
            better = e < best
            best[better] = e[better]
            new[better] = near[better, j]
        label = new
        mean, basis = fit(label)
    weights = np.einsum("nd,nkd->nk", data - mean[label], basis[label])
    lo = np.zeros((clusters, k), np.float32)
    hi = np.zeros((clusters, k), np.float32)
    for ci in range(c):
        rows = label == ci
        if rows.any():
            lo[ci], hi[ci] = weights[rows].min(axis=0), weights[rows].max(axis=0)
    step = np.maximum(hi - lo, 1e-6) / 255.0
    qw = np.clip(np.rint((weights - lo[label]) / step[label]), 0, 255).astype(np.uint8)
    scale = np.maximum(np.abs(basis).max(axis=2), 1e-12) / 127.0
    bq = np.clip(np.rint(basis / scale[:, :, None]), -127, 127).astype(np.int8)
    return Cpca(label.astype(np.uint8), qw, np.clip(np.rint(mean), 0, 255).astype(np.uint8).reshape(clusters, nd, 3),
                lo, step.astype(np.float32), bq.reshape(clusters, k, nd, 3), scale.astype(np.float32))


def reconstruct(c: Cpca, rows: npt.NDArray[np.int64] | slice = slice(None)) -> F64:
    """The compressed texels ``rows`` for every stored direction, (n, N, 3) float64 colours."""
    mean, basis = c.lumispheres()
    cl = c.cluster[rows].astype(np.int64)
    return mean[cl] + np.einsum("nk,nkjc->njc", c.q[rows].astype(np.float64), basis[cl])


# ---------------------------------------------------------------------------------------------- format
def _pack(magic: bytes, header: dict[str, Any], payload: bytes) -> bytes:
    h = json.dumps(header, separators=(",", ":")).encode()
    return magic + struct.pack("<I", len(h)) + h + payload


def _unpack(data: bytes, magic: bytes, source: str) -> tuple[dict[str, Any], bytes]:
    if len(data) < 12 or data[:8] != magic:
        raise InputError("not a citylod surface light field file (bad magic)", source)
    (hl,) = struct.unpack_from("<I", data, 8)
    try:
        header = json.loads(data[12:12 + hl])
    except ValueError as exc:
        raise InputError(f"surface light field header is not JSON ({exc})", source) from exc
    if not isinstance(header, dict):
        raise InputError("surface light field header is not an object", source)
    return header, data[12 + hl:]


def write_cell(c: Cpca, rows: slice, texels: int, heights: npt.NDArray[np.floating] | None = None) -> bytes:
    """A cell's file: ``CLSLFC1\\0``, header length (u32), JSON header, deflated (cluster ids, weights and,
    with ``heights`` (T, T) metres, the building tops as u8 in steps of the header's ``height_step``)."""
    header: dict[str, Any] = {"texels": texels, "components": int(c.q.shape[1])}
    raw = c.cluster[rows].tobytes() + c.q[rows].tobytes()
    if heights is not None:
        hs = max(float(np.max(heights)), 1e-3) / 255.0
        header["height_step"] = hs
        # Rounded up: a top never drops below the surface it stands for (the ray march would miss it).
        raw += np.clip(np.ceil(np.asarray(heights) / hs - 1e-6), 0, 255).astype(np.uint8).tobytes()
    return _pack(MAGIC_CELL, header, zlib.compress(raw, 9))


def read_cell_arrays(data: bytes, source: str = "") -> tuple[U8, U8, npt.NDArray[np.float32] | None]:
    """(cluster ids (T, T), weights (T, T, K), building-top heights (T, T) metres or None) of a cell file."""
    header, payload = _unpack(data, MAGIC_CELL, source)
    try:
        t, k = int(header["texels"]), int(header["components"])
        hs = header.get("height_step")
        hs = None if hs is None else float(hs)
        raw = zlib.decompress(payload)
    except (KeyError, TypeError, ValueError, zlib.error) as exc:
        raise InputError(f"surface light field cell is damaged ({exc})", source) from exc
    per = 1 + k + (hs is not None)
    if not (0 < t <= 4096 and 0 < k <= 16) or len(raw) != t * t * per or (hs is not None and not 0 < hs < 1e3):
        raise InputError(f"surface light field cell holds {len(raw)} bytes, not {t}² texels × {per}", source)
    arr = np.frombuffer(raw, np.uint8)
    top = None if hs is None else (arr[t * t * (1 + k):].reshape(t, t).astype(np.float32) * np.float32(hs))
    return arr[:t * t].reshape(t, t), arr[t * t:t * t * (1 + k)].reshape(t, t, k), top


def read_cell(data: bytes, source: str = "") -> tuple[U8, U8]:
    """(cluster ids (T, T) uint8, weights (T, T, K) uint8) of a cell file."""
    cl, q, _ = read_cell_arrays(data, source)
    return cl, q


def read_heights(data: bytes, source: str = "") -> npt.NDArray[np.float32] | None:
    """The building-top heights (T, T) in metres of a cell file, None for a file without them."""
    return read_cell_arrays(data, source)[2]


def write_group(c: Cpca) -> bytes:
    """A group's file: ``CLSLFG1\\0``, header, then deflated (header ``deflate``): mean (C, N, 3) u8, lo, step,
    scale (C, K) f32 each, basis (C, K, N, 3) i8."""
    cl, k, nd, _ = c.basis.shape
    payload = (c.mean.tobytes() + c.lo.astype("<f4").tobytes() + c.step.astype("<f4").tobytes()
               + c.scale.astype("<f4").tobytes() + c.basis.tobytes())
    return _pack(MAGIC_GROUP, {"clusters": cl, "components": k, "directions": nd, "deflate": True},
                 zlib.compress(payload, 9))


def read_group(data: bytes, source: str = "") -> Cpca:
    """The lumispheres of a group file (texel arrays empty)."""
    header, p = _unpack(data, MAGIC_GROUP, source)
    try:
        cl, k, nd = int(header["clusters"]), int(header["components"]), int(header["directions"])
        if header.get("deflate"):
            p = zlib.decompress(p)
    except (KeyError, TypeError, ValueError, zlib.error) as exc:
        raise InputError(f"surface light field group header is damaged ({exc})", source) from exc
    sizes = [cl * nd * 3, 4 * cl * k, 4 * cl * k, 4 * cl * k, cl * k * nd * 3]
    if not (0 < cl <= 256 and 0 < k <= 16 and 0 < nd <= 4225) or len(p) != sum(sizes):
        raise InputError(f"surface light field group holds {len(p)} bytes, not {sum(sizes)}", source)
    o = np.cumsum([0, *sizes])
    f4 = np.dtype("<f4")
    return Cpca(np.zeros(0, np.uint8), np.zeros((0, k), np.uint8),
                np.frombuffer(p[o[0]:o[1]], np.uint8).reshape(cl, nd, 3),
                np.frombuffer(p[o[1]:o[2]], f4).reshape(cl, k), np.frombuffer(p[o[2]:o[3]], f4).reshape(cl, k),
                np.frombuffer(p[o[4]:o[5]], np.int8).reshape(cl, k, nd, 3),
                np.frombuffer(p[o[3]:o[4]], f4).reshape(cl, k))


# ---------------------------------------------------------------------------------------------- build
@dataclass(frozen=True)
class SlfReport:
    """What :func:`build_slf` wrote: ``cells`` over ``levels``, ``directions``, the mean bytes one view loads
    per cell (``cell_bytes``: one direction patch of the cell + its share of that patch's cluster table) and
    all a cell stores on disk (``disk_cell_bytes``, every patch) against ``raw_cell_bytes`` uncompressed, the
    compression's RMS and p99 colour error (0..255) over every texel and direction of every patch, seconds
    baking and compressing."""

    path: Path
    cells: int
    levels: int
    directions: int
    texels: int
    cell_bytes: float
    disk_cell_bytes: float
    raw_cell_bytes: int
    rms_error: float
    p99_error: float
    bake_s: float
    compress_s: float
    warnings: list[str] = field(default_factory=list)

    def summary(self) -> str:
        return (f"{self.path}: {self.cells} cells over {self.levels} levels, {self.directions} directions, "
                f"{self.texels}² texels; {self.cell_bytes / 1024:.0f} KiB per cell and view "
                f"({self.disk_cell_bytes / 1024:.0f} KiB stored) against {self.raw_cell_bytes / 1e6:.2f} MB "
                f"uncompressed ({self.raw_cell_bytes / self.cell_bytes:.0f}×, "
                f"{self.raw_cell_bytes / self.disk_cell_bytes:.1f}× stored), "
                f"compression error RMS {self.rms_error:.2f}, p99 {self.p99_error:.1f} (of 255); "
                f"bake {self.bake_s:.0f} s, compress {self.compress_s:.0f} s")


def _quad(size_m: float, z: float, texture: bytes) -> TileContent:
    """A square of side ``size_m`` centred on the tile origin at height ``z``, textured (north up)."""
    h = size_m / 2
    pos = np.array([[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]], np.float32)
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32)
    faces = np.array([[0, 1, 2], [0, 2, 3]], np.uint32)
    return TileContent([MeshData(pos, faces, uv=uv, texture=texture, name="slf_average")])


def build_slf(city_dir: str | PathLike[str], out_dir: str | PathLike[str], *, texel_m: float = 4.0,
              texels: int = 64, grid: int = 11, oversample: int = 6, clusters: int = 256, components: int = 3,
              min_elevation_deg: float = 5.0, ground_z: float | None = None,
              ground_rgb: tuple[int, int, int] = GROUND_RGB, tex_px: int = 64, group: int = 4,
              heights: bool = True, patches: bool = True, workers: int | None = None,
              progress: bool = True) -> SlfReport:
    """Bake, compress and write the far-field surface light fields of a city tileset.

    Parameters
    ----------
    city_dir
        A city tileset (``citylod build city``).
    out_dir
        The far-field tileset folder (replaced when complete).
    texel_m
        Largest texel size of the finest level (m); levels are added until it is reached.
    texels
        Texels per cell side (a power of two).
    grid
        Parabolic lattice side (11: 97 directions).
    oversample
        Samples per texel side (6: 36 a texel; on 8,000 houses the colour error is 0.2–0.5 of 255 lower than
        with 3, for about three times the baking, which is a third of the build).
    clusters, components
        Clustered PCA: clusters per group of four sibling cells, eigen-lumispheres per cluster.
    ground_z
        Height of the terrain plane (default: the city's lowest point).
    tex_px
        Side to which atlases are filtered before sampling.
    group
        Cells per side of the squares that share one cluster table (4: 16 neighbouring cells share the
        ``clusters`` lumispheres; a level with fewer cells shares one table).
    heights
        Store the building-top heights per texel for the depth-corrected evaluation; the cells'
        ``geometricError`` then carries the height error left to that lookup instead of the whole height.
    patches
        Compress the directions in overlapping patches of 3 × 3 lattice points
        (:func:`~citylod.lod.kernels.slf.direction_patches`), one file per cell and patch, so that a view
        loads one patch; False: one clustered PCA over all directions.
    workers
        Threads that bake the cells of a group and compress its direction patches (default: one per CPU).
    """
    from tqdm import tqdm

    if texels < 8 or texels & (texels - 1) or texels > 1024:
        raise InputError(f"--texels must be a power of two in 8..1024, got {texels}", city_dir)
    if group < 1 or group & (group - 1):
        raise InputError(f"group must be a power of two, got {group}", city_dir)
    if workers is not None and workers < 1:
        raise InputError(f"--workers must be at least 1, got {workers}", city_dir)
    if not texel_m > 0 or oversample < 1 or not 1 <= clusters <= 256 or not 1 <= components <= 8:
        raise InputError("texel size must be > 0, oversample ≥ 1, clusters 1..256, components 1..8", city_dir)
    ds = direction_set(grid, min_elevation_deg)
    scene = city_triangles(city_dir, tex_px)
    lo = scene.tri.reshape(-1, 3).min(axis=0)
    hi = scene.tri.reshape(-1, 3).max(axis=0)
    z0 = float(lo[2]) if ground_z is None else float(ground_z)
    side = float(max(hi[0] - lo[0], hi[1] - lo[1])) + 2 * texel_m
    levels = max(1, math.ceil(math.log2(side / (texels * texel_m))) + 1)
    x0, y0 = float(lo[0]) - texel_m, float(lo[1]) - texel_m
    factor = parallax_factor(ds)
    # Mean building height above the ground on a coarse raster, for the cells' parallax term.
    tri_c = scene.tri.mean(axis=1)
    height = np.clip(scene.tri[:, :, 2].max(axis=1) - z0, 0, None)
    out = Path(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_name(f".{out.name}.partial{os.getpid()}")
    shutil.rmtree(partial, ignore_errors=True)
    (partial / "slf" / "cells").mkdir(parents=True)
    (partial / "slf" / "groups").mkdir(parents=True)
    bake_s = comp_s = 0.0
    sq_err = 0.0
    count = 0
    p99s: list[float] = []
    cell_bytes: list[float] = []
    view_bytes: list[float] = []
    patch_sets = direction_patches(ds) if patches else [np.arange(len(ds))]
    specs: dict[tuple[int, int, int], TileSpec] = {}
    scene.boxes()  # once, before the bake threads share them
    # The cells of a group bake on threads (the rasteriser releases the GIL), and its direction patches are
    # compressed on them: each piece on its own, in the same order, so the output does not depend on
    # ``workers``.
    pool = ThreadPoolExecutor(workers if workers is not None else (os.cpu_count() or 1))
    try:
        jobs = [(lv, gi, gj) for lv in range(levels) for gi in range(max(1, 2 ** lv // group))
                for gj in range(max(1, 2 ** lv // group))]
        for lv, gi, gj in tqdm(jobs, desc="slf groups", unit="group", disable=not progress):
            n = 2 ** lv
            size = side / n
            g = min(n, group)
            members = [(lv, g * gi + a, g * gj + b) for a in range(g) for b in range(g)]
            tb = time.perf_counter()
            def bake(member: tuple[int, int, int], size: float = size) -> tuple[U8, Any]:
                _, i, j = member  # i: column (x), j: row (y, south to north)
                return (bake_cell(scene, x0 + i * size, y0 + j * size, size, texels, z0, ds,
                                  oversample=oversample, ground_rgb=ground_rgb),
                        bake_heights(scene, x0 + i * size, y0 + j * size, size, texels, z0,
                                     oversample=oversample) if heights else None)

            baked = list(pool.map(bake, members))
            fields, tops = [f for f, _ in baked], [t for _, t in baked]
            tc = time.perf_counter()
            bake_s += tc - tb
            stacked = np.concatenate([f.reshape(texels * texels, len(ds), 3) for f in fields])
            gkey = f"{lv}_{gi}_{gj}"
            cell_files: list[list[int]] = [[] for _ in members]
            group_files: list[int] = []
            def squeeze(patch: tuple[int, npt.NDArray[np.int64]], lv: int = lv, gi: int = gi,
                        gj: int = gj, stacked: U8 = stacked) -> tuple[Cpca, float, int, float]:
                pi, sel = patch
                part = np.ascontiguousarray(stacked[:, sel])
                cp = compress(part, clusters, components, seed=lv * 7919 + gi * 31 + gj + 104729 * pi)
                err = reconstruct(cp) - part
                return cp, float((err ** 2).sum()), err.size, float(np.percentile(np.abs(err), 99))

            # The patches are compressed on the threads too (numpy and scipy release the GIL in their loops),
            # each with its own seed, and written in order.
            for pi, (cp, sq, size_err, p99) in enumerate(pool.map(squeeze, enumerate(patch_sets))):
                sq_err += sq
                count += size_err
                p99s.append(p99)
                gbytes = write_group(cp)
                (partial / "slf" / "groups" / f"{gkey}_{pi}.bin").write_bytes(gbytes)
                group_files.append(len(gbytes))
                for m, (_, i, j) in enumerate(members):
                    rows = slice(m * texels * texels, (m + 1) * texels * texels)
                    top = tops[m]
                    cbytes = write_cell(cp, rows, texels, None if top is None else top[0])
                    (partial / "slf" / "cells" / f"{lv}_{i}_{j}_{pi}.bin").write_bytes(cbytes)
                    cell_files[m].append(len(cbytes))
            comp_s += time.perf_counter() - tc
            for m, ((_, i, j), fld) in enumerate(zip(members, fields, strict=True)):
                key = f"{lv}_{i}_{j}"
                top = tops[m]
                # What one view loads: one patch of the cell and its share of that patch's cluster table.
                view_bytes.append(float(np.mean(cell_files[m])) + float(np.mean(group_files)) / len(members))
                cell_bytes.append(sum(cell_files[m]) + sum(group_files) / len(members))
                cx, cy = x0 + (i + 0.5) * size, y0 + (j + 0.5) * size
                avg = np.rint(fld.astype(np.float32).mean(axis=2)).astype(np.uint8)
                uri = write_content(partial, key, _quad(size, 0.0, encode_image(avg, "jpg", 90)), atomic=False)
                near = ((np.abs(tri_c[:, 0] - cx) <= 1.5 * size) & (np.abs(tri_c[:, 1] - cy) <= 1.5 * size))
                h_mean = float(height[near].mean()) if near.any() else 0.0
                if top is not None:  # what the depth-corrected lookup gets wrong: its height error + ½ march step
                    h_mean = min(h_mean, top[1] + 0.25)
                error = size / texels + factor * h_mean
                centre = np.array([cx, cy, z0])
                specs[(lv, i, j)] = TileSpec(key=key, level=lv, center=centre,
                                             lo=np.array([cx - size / 2, cy - size / 2, z0]),
                                             hi=np.array([cx + size / 2, cy + size / 2, z0 + 1e-3]),
                                             geometric_error=error, content=uri, extras={"citylod_slf": {
                                                 "cell": f"slf/cells/{key}_{{patch}}.bin",
                                                 "group": f"slf/groups/{gkey}_{{patch}}.bin",
                                                 "texel_m": size / texels, "parallax_m": factor * h_mean,
                                                 "heights": top is not None}})
        for (lv, i, j), spec in specs.items():
            if lv + 1 < levels:
                spec.children = [specs[(lv + 1, 2 * i + a, 2 * j + b)] for b in (0, 1) for a in (0, 1)]
        root = specs[(0, 0, 0)]
        # Parents never claim less error than their children (3D Tiles: errors shrink downwards).
        for _key, spec in sorted(specs.items(), key=lambda kv: -kv[0][0]):
            if spec.children:
                spec.geometric_error = max(spec.geometric_error, *(c.geometric_error for c in spec.children))
        write_tileset(partial, root, scene.crs, extras={"citylod": {
            "kind": "slf", "directions_grid": grid, "directions": len(ds), "min_elevation_deg": min_elevation_deg,
            "texels": texels, "levels": levels, "ground_z": z0, "ground_rgb": list(ground_rgb),
            "city": os.path.relpath(Path(scene.path).resolve().parent if Path(scene.path).is_file()
                                    else Path(scene.path).resolve(), out.resolve()),
            "parallax_factor": factor, "clusters": clusters, "components": components, "group": group,
            "heights": heights, "patches": [p.tolist() for p in patch_sets]}})
        publish_dir(partial, out)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    raw = texels * texels * len(ds) * 3
    return SlfReport(out, len(specs), levels, len(ds), texels, float(np.mean(view_bytes)), float(np.mean(cell_bytes)),
                     raw,
                     math.sqrt(sq_err / max(count, 1)), float(np.median(p99s)), bake_s, comp_s)
