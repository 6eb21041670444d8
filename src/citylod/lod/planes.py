"""Planes in point-cloud nodes, replaced by textured quads (hybrid points + quads).

Wahl, Guthe, Klein, "Identifying planes in point-clouds for efficient hybrid rendering", PG 2005: in each
octree node, RANSAC finds planes among the node's representative points; a plane whose inliers can be
drawn more cheaply as a textured quad than as points (the compactness rule ``texels < φ·(inliers − 4)``)
becomes one quad, with the inliers splatted into a texture of texel spacing equal to the node's
clustering cell. The inliers are removed from the node's points.

What each removed point is replaced by is returned explicitly (the centre of the texel it was splatted
into), so the caller can measure the node's true error including the quads. No I/O except PNG encoding
into bytes; no VTK, no Qt.
"""

from __future__ import annotations

import os
import tempfile
import zlib
from dataclasses import dataclass

import numba
import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
U8 = npt.NDArray[np.uint8]

# ASPRS LAS 1.4 standard classes (and AHN's 26 bridge deck) for colouring quads of uncoloured clouds.
_CLASS_RGB = np.full((256, 3), 180, np.uint8)
_CLASS_RGB[2] = (176, 140, 96)     # ground
_CLASS_RGB[3] = (150, 200, 110)    # low vegetation
_CLASS_RGB[4] = (100, 170, 80)     # medium vegetation
_CLASS_RGB[5] = (50, 130, 50)      # high vegetation
_CLASS_RGB[6] = (205, 90, 70)      # building
_CLASS_RGB[9] = (70, 130, 220)     # water
_CLASS_RGB[17] = (150, 150, 160)   # bridge deck
_CLASS_RGB[26] = (150, 150, 160)   # AHN: bridge deck


def splat_colors(rgb: U8 | None, classification: U8, intensity: npt.NDArray[np.uint16],
                 intensity_scale: float) -> U8:
    """Colour of each point for texturing quads, (N, 3) uint8.

    RGB when the cloud has it; otherwise the classification's colour, and intensity grey for classes 0
    and 1 (never classified / unclassified), scaled so ``intensity_scale`` is white.
    """
    if rgb is not None:
        return rgb
    out = _CLASS_RGB[classification].copy()
    grey_sel = classification <= 1
    g = np.clip(intensity[grey_sel] * (255.0 / max(intensity_scale, 1.0)), 0, 255).astype(np.uint8)
    out[grey_sel] = g[:, None]
    return out


@numba.njit(cache=True)
def _next(state: int) -> int:  # pragma: no cover - compiled
    # 64-bit LCG (Knuth MMIX); int64 arithmetic wraps, which is what we want.
    return state * 6364136223846793005 + 1442695040888963407


@numba.njit(cache=True)
def _best_plane(p: F64, n_candidates: int, window: int, thr: float, seed: int
                ) -> tuple[F64, float, int]:  # pragma: no cover - compiled
    """Best of ``n_candidates`` 3-point planes by inlier count (|n·p + d| ≤ thr); returns its full count.

    ``p`` is in Morton order, so the 2nd and 3rd sample are drawn within ``window`` positions of the first:
    localised sampling (as in Schnabel et al. 2007) makes three points from the same surface likely even
    when that surface holds a small share of the node.
    """
    k = p.shape[0]
    # Score candidates on a regular subsample of about 512 points (the points are in Morton order, so a
    # stride is a spatially even subsample), count the winner on all points: ranking needs only estimates.
    step = max(1, k // 512)
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
        for t in range(0, k, step):
            if abs(nx * p[t, 0] + ny * p[t, 1] + nz * p[t, 2] + d) <= thr:
                cnt += 1
        if cnt > best:
            best = cnt
            best_n[0], best_n[1], best_n[2] = nx, ny, nz
            best_d = d
    if best < 0:
        return best_n, best_d, -1
    cnt = 0
    for t in range(k):
        if abs(best_n[0] * p[t, 0] + best_n[1] * p[t, 1] + best_n[2] * p[t, 2] + best_d) <= thr:
            cnt += 1
    return best_n, best_d, cnt


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
    """The quads of one node and what they replaced.

    Attributes
    ----------
    quads
        Accepted quads.
    replaced
        (K,) bool: the point was splatted into a quad (it is no longer drawn as a point).
    elem
        (K, 3) float64: for replaced points the centre of their texel, else the point itself.
    """

    quads: list[Quad]
    replaced: npt.NDArray[np.bool_]
    elem: F64


def find_planes(p: F64, colors: U8, texel: float, *, phi: float = 8.0, seed: int = 0,
                n_candidates: int = 200, max_planes: int = 32, min_inliers: int = 32,
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
        3-point candidates per plane search.
    max_planes, min_inliers, max_failures
        Stop after that many planes, below that many inliers, or after that many rejected planes in a row.

    Returns
    -------
    PlaneResult
    """
    from scipy import ndimage

    k = len(p)
    replaced = np.zeros(k, bool)
    elem = p.copy()
    quads: list[Quad] = []
    active = np.arange(k)
    thr = 0.5 * texel
    failures = 0
    state = np.int64(seed & 0x7FFFFFFFFFFF)
    for attempt in range(max_planes + max_failures * max_planes):
        if len(quads) >= max_planes or failures >= max_failures or len(active) < min_inliers:
            break
        pa = np.ascontiguousarray(p[active])
        n, d, cnt = _best_plane(pa, n_candidates, window, thr, int(state) + 7919 * attempt)
        if cnt < min_inliers:
            break
        inl = np.abs(pa @ n + d) <= thr
        # Least-squares refit (PCA of the inliers), kept when it does not lose inliers.
        c = pa[inl].mean(axis=0)
        _, v = np.linalg.eigh(np.cov((pa[inl] - c).T))
        n2 = v[:, 0]
        inl2 = np.abs((pa - c) @ n2) <= thr
        if inl2.sum() >= inl.sum():
            n, inl = n2, inl2
        else:
            c = pa[inl].mean(axis=0)
            c = c - ((c @ n) + d) * n  # project the centroid onto the RANSAC plane
        u = v[:, 2] - (v[:, 2] @ n) * n  # in-plane long axis (PCA), orthogonalised against the final normal
        u /= np.linalg.norm(u)
        vv = np.cross(n, u)
        idx = np.flatnonzero(inl)
        rel = pa[idx] - c
        s, t = rel @ u, rel @ vv
        s0, t0 = s.min(), t.min()
        i = np.floor((s - s0) / texel).astype(np.int64)
        j = np.floor((t - t0) / texel).astype(np.int64)
        occ = np.zeros((j.max() + 1, i.max() + 1), bool)
        occ[j, i] = True
        # Inliers of an infinite plane can lie in several separate patches (coplanar roofs, terraces):
        # keep the largest 8-connected patch so the quad's rectangle is not mostly empty.
        lab, nlab = ndimage.label(occ, structure=np.ones((3, 3), bool))
        pl = lab[j, i]
        if nlab > 1:
            keep_lab = np.argmax(np.bincount(pl, minlength=nlab + 1)[1:]) + 1
            sel = pl == keep_lab
            idx, i, j = idx[sel], i[sel], j[sel]
        i0, i1, j0, j1 = i.min(), i.max() + 1, j.min(), j.max() + 1
        texels = (i1 - i0) * (j1 - j0)
        ninl = len(idx)
        if ninl < min_inliers or not texels < phi * (ninl - 4):
            failures += 1
            # Not worth a quad: these points stay points; do not sample them again.
            active = np.delete(active, idx)
            continue
        failures = 0
        gi = active[idx]
        # Texel (i, j) of the W×H quad texture plus a one-texel border (the quad enlarged by one texel
        # against cracks, the border filled by dilation).
        ww, hh = i1 - i0 + 2, j1 - j0 + 2
        ti, tj = i - i0 + 1, j - j0 + 1
        flat = tj * ww + ti
        cnt_t = np.bincount(flat, minlength=ww * hh)
        rgba = np.zeros((hh * ww, 4), np.float64)
        for ch in range(3):
            rgba[:, ch] = np.bincount(flat, weights=colors[gi, ch].astype(np.float64), minlength=ww * hh)
        filled = cnt_t > 0
        rgba[filled, :3] /= cnt_t[filled, None]
        rgba[filled, 3] = 255.0
        img = _dilate(rgba.reshape(hh, ww, 4))
        origin = c + (s0 + (i0 - 1) * texel) * u + (t0 + (j0 - 1) * texel) * vv
        corners = np.array([origin, origin + ww * texel * u, origin + ww * texel * u + hh * texel * vv,
                            origin + hh * texel * vv])
        elem[gi] = origin + ((ti + 0.5) * texel)[:, None] * u + ((tj + 0.5) * texel)[:, None] * vv
        replaced[gi] = True
        quads.append(Quad(corners, np.clip(np.rint(img), 0, 255).astype(np.uint8), texel, ninl))
        active = np.delete(active, idx)
    return PlaneResult(quads, replaced, elem)


def _dilate(img: F64) -> F64:
    """Fill transparent texels next to opaque ones with the mean of their opaque 8-neighbours."""
    h, w, _ = img.shape
    pad = np.zeros((h + 2, w + 2, 4))
    pad[1:-1, 1:-1] = img
    opaque = (pad[..., 3] > 0).astype(np.float64)
    acc = np.zeros((h, w, 3))
    num = np.zeros((h, w))
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy == 0 and dx == 0:
                continue
            o = opaque[1 + dy:h + 1 + dy, 1 + dx:w + 1 + dx]
            acc += pad[1 + dy:h + 1 + dy, 1 + dx:w + 1 + dx, :3] * o[..., None]
            num += o
    out = img.copy()
    grow = (img[..., 3] == 0) & (num > 0)
    out[grow, :3] = acc[grow] / num[grow, None]
    out[grow, 3] = 255.0
    return out


def pack_atlas(quads: list[Quad]) -> tuple[U8, list[tuple[int, int]]]:
    """Shelf-pack the quads' textures into one RGBA atlas (one texture per node draws in one call).

    Returns
    -------
    atlas
        (H, W, 4) uint8.
    offsets
        (x, y) texel offset of each quad's texture in the atlas, in the order given.
    """
    gap = 1  # transparent texel between textures so linear filtering does not bleed colour across
    sizes = [(q.rgba.shape[1], q.rgba.shape[0]) for q in quads]
    area = sum((w + gap) * (h + gap) for w, h in sizes)
    width = max(max(w for w, _ in sizes) + gap, int(np.ceil(np.sqrt(area) * 1.15)))
    order = sorted(range(len(quads)), key=lambda k: -sizes[k][1])
    offsets: list[tuple[int, int]] = [(0, 0)] * len(quads)
    x = y = shelf = 0
    for k in order:
        w, h = sizes[k]
        if x + w > width:
            x, y, shelf = 0, y + shelf + gap, 0
        offsets[k] = (x, y)
        x += w + gap
        shelf = max(shelf, h)
    atlas = np.zeros((y + shelf, width, 4), np.uint8)
    for k, (ox, oy) in enumerate(offsets):
        h, w = quads[k].rgba.shape[:2]
        atlas[oy:oy + h, ox:ox + w] = quads[k].rgba
    return atlas, offsets


def quad_mesh_arrays(quads: list[Quad]) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint32],
                                                 npt.NDArray[np.float32], U8]:
    """Vertex, face, uv arrays and the atlas image for a node's quads.

    Returns
    -------
    positions
        (4Q, 3) float32 relative to the node centre.
    faces
        (2Q, 3) uint32.
    uv
        (4Q, 2) float32, origin at the atlas's top-left (glTF).
    atlas
        (H, W, 4) uint8.
    """
    atlas, offsets = pack_atlas(quads)
    ah, aw = atlas.shape[:2]
    pos = np.concatenate([q.corners for q in quads]).astype(np.float32)
    uv = np.empty((4 * len(quads), 2), np.float32)
    for k, (q, (ox, oy)) in enumerate(zip(quads, offsets, strict=True)):
        h, w = q.rgba.shape[:2]
        uv[4 * k:4 * k + 4] = np.array([[ox, oy], [ox + w, oy], [ox + w, oy + h], [ox, oy + h]]) / [aw, ah]
    base = 4 * np.arange(len(quads), dtype=np.uint32)[:, None]
    faces = np.concatenate([base + np.array([0, 1, 2], np.uint32), base + np.array([0, 2, 3], np.uint32)], axis=1)
    return pos, faces.reshape(-1, 3), uv, atlas


def encode_png(rgba: U8) -> bytes:
    """PNG bytes of an (H, W, 4) uint8 image: OpenImageIO when installed, else a minimal zlib writer."""
    try:
        import OpenImageIO as oiio
    except ImportError:
        return png_zlib(rgba)
    h, w = rgba.shape[:2]
    fd, name = tempfile.mkstemp(suffix=".png")
    os.close(fd)
    try:
        out = oiio.ImageOutput.create(name)
        if out is None:
            return png_zlib(rgba)
        out.open(name, oiio.ImageSpec(w, h, 4, "uint8"))
        out.write_image(np.ascontiguousarray(rgba))
        out.close()
        with open(name, "rb") as f:
            return f.read()
    finally:
        os.unlink(name)


def png_zlib(rgba: U8) -> bytes:
    """Minimal RGBA8 PNG (filter 0 on every row, zlib level 6): the fallback without OpenImageIO."""
    h, w = rgba.shape[:2]
    raw = np.zeros((h, w * 4 + 1), np.uint8)
    raw[:, 1:] = rgba.reshape(h, w * 4)

    def chunk(tag: bytes, data: bytes) -> bytes:
        return len(data).to_bytes(4, "big") + tag + data + zlib.crc32(tag + data).to_bytes(4, "big")

    ihdr = w.to_bytes(4, "big") + h.to_bytes(4, "big") + bytes([8, 6, 0, 0, 0])
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw.tobytes(), 6))
            + chunk(b"IEND", b""))
