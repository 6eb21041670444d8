"""Multiresolution texture atlases (Buchholz, PhD thesis, Potsdam 2006, ch. 4; Buchholz & Döllner 2005).

The tile tree is a 4-ary tree; every node owns one ``atlas_px``² atlas and a square of one common texture
space (the root's square is [0, 1]²; child k gets quadrant (k mod 2, k div 2) of its parent's square). A leaf
packs the images of its triangles into its atlas, each at its native resolution unless the atlas is too
small for that (then each is shrunk to its cell): at a leaf, no image is magnified beyond its original
(but for the half-texel inset that keeps filtering inside an image: a w-pixel side spans w - 1 texels). An
inner node's atlas is its children's atlases, each shrunk by 2 into its quadrant. Hence one set of texture
coordinates, in the common space, serves every level: a tile's own coordinates are the common ones
relative to its square (:func:`tile_uv`).

The error a node's atlas adds is its texel size on the surface (:func:`texel_size_m`), the largest distance
on a triangle that one texel of the node's atlas covers; a node at τ px is refined while that texel would
cover more than τ pixels, so no texture is magnified on screen beyond the original's own resolution.

No VTK, no Qt.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from citylod.io.image import read_image, resize_image

__all__ = [
    "Placement",
    "Square",
    "atlas_uv",
    "leaf_atlas",
    "parent_atlas",
    "quadrant",
    "texel_size_m",
    "tile_uv",
]

F64 = npt.NDArray[np.float64]
U8 = npt.NDArray[np.uint8]


@dataclass(frozen=True)
class Square:
    """A node's square of the common texture space: origin (``ox``, ``oy``; y down) and side ``size``."""

    ox: float = 0.0
    oy: float = 0.0
    size: float = 1.0


def quadrant(parent: Square, k: int) -> Square:
    """Child ``k``'s square (k = 0..3: left/right by k mod 2, top/bottom by k div 2)."""
    h = parent.size / 2
    return Square(parent.ox + (k % 2) * h, parent.oy + (k // 2) * h, h)


@dataclass(frozen=True)
class Placement:
    """Where an image lies in a leaf atlas: pixel rectangle ``x0``, ``y0``, ``w``, ``h``."""

    x0: int
    y0: int
    w: int
    h: int


def leaf_atlas(images: Mapping[int, Path], atlas_px: int,
               cache: dict[Path, U8] | None = None) -> tuple[U8, dict[int, Placement], list[str]]:
    """Pack ``images`` (index -> file) into one ``atlas_px``² atlas on a square grid of cells.

    Each image keeps its native size when it fits its cell, else it is shrunk (aspect kept) to the cell.
    Returns the atlas (A, A, 3) uint8, the placement of each image that could be decoded, and warnings for
    those that could not (their surfaces fall back to their material).
    """
    from citylod.core.errors import CitylodError

    keys = sorted(images)
    grid = max(1, int(np.ceil(np.sqrt(len(keys)))))
    cell = atlas_px // grid
    atlas = np.full((atlas_px, atlas_px, 3), 128, np.uint8)
    placed: dict[int, Placement] = {}
    warnings: list[str] = []
    for n, k in enumerate(keys):
        path = images[k]
        try:
            img = cache[path] if cache is not None and path in cache else read_image(path)
        except CitylodError as exc:
            warnings.append(f"texture {path.name} cannot be decoded ({exc}); surface drawn with its material")
            continue
        h, w = img.shape[:2]
        if max(h, w) > cell:
            s = cell / max(h, w)
            w, h = max(1, int(w * s)), max(1, int(h * s))
            img = resize_image(img, w, h)
        y0, x0 = (n // grid) * cell, (n % grid) * cell
        atlas[y0:y0 + h, x0:x0 + w] = img
        placed[k] = Placement(x0, y0, w, h)
    return atlas, placed, warnings


def parent_atlas(children: Sequence[tuple[int, U8]], atlas_px: int) -> U8:
    """An inner node's atlas: each child's atlas (quadrant k, atlas) shrunk by 2 (2×2 box mean) into its
    quadrant; empty quadrants stay grey."""
    out = np.full((atlas_px, atlas_px, 3), 128, np.uint8)
    h = atlas_px // 2
    for k, a in children:
        small = a.reshape(h, 2, h, 2, 3).astype(np.uint16).sum(axis=(1, 3))
        y0, x0 = (k // 2) * h, (k % 2) * h
        out[y0:y0 + h, x0:x0 + h] = ((small + 2) // 4).astype(np.uint8)
    return out


def atlas_uv(uv: F64, where: Sequence[Placement], square: Square, atlas_px: int) -> F64:
    """Common texture coordinates (V, 2), y down, of vertices with image coordinates ``uv`` (CityGML's:
    origin at the image's lower left) placed at ``where`` in the leaf atlas of ``square``.

    Coordinates outside [0, 1] (repeating textures) are clamped, and points are kept half a texel inside
    their image so that bilinear filtering at the leaf does not read a neighbour.
    """
    x0 = np.array([p.x0 for p in where], np.float64)
    y0 = np.array([p.y0 for p in where], np.float64)
    w = np.array([p.w for p in where], np.float64)
    h = np.array([p.h for p in where], np.float64)
    u = np.clip(uv[:, 0], 0.0, 1.0)
    v = np.clip(uv[:, 1], 0.0, 1.0)
    px = np.clip(x0 + u * w, x0 + 0.5, x0 + w - 0.5)
    py = np.clip(y0 + (1.0 - v) * h, y0 + 0.5, y0 + h - 0.5)
    return np.column_stack([square.ox + px / atlas_px * square.size, square.oy + py / atlas_px * square.size])


def tile_uv(common: F64, square: Square) -> npt.NDArray[np.float32]:
    """A tile's own texture coordinates (origin top left, as glTF) from the common ones."""
    return ((common - [square.ox, square.oy]) / square.size).astype(np.float32)


def texel_size_m(vertices: F64, faces: npt.NDArray[np.int64], common: F64, square: Square, atlas_px: int) -> float:
    """Largest distance on the surface (m) that one texel of the node's atlas covers, over the triangles.

    Per triangle, the map from the triangle's plane to atlas texels is linear, M = T P⁻¹ with P and T its edge
    vectors in the plane and in texels; a texel covers at most σ_max(M⁻¹) = σ_max(P T⁻¹) metres. Triangles
    whose texture coordinates are degenerate (a surface mapped to a point or a line) are skipped: they show
    one colour, which no resolution changes.
    """
    if not len(faces):
        return 0.0
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    e1, e2 = b - a, c - a
    l1 = np.linalg.norm(e1, axis=1)
    x = e1 / np.maximum(l1, 1e-12)[:, None]
    n = np.cross(e1, e2)
    y = np.cross(n, x)
    y /= np.maximum(np.linalg.norm(y, axis=1), 1e-12)[:, None]
    p = np.stack([np.stack([l1, np.zeros_like(l1)], 1), np.stack([(e2 * x).sum(1), (e2 * y).sum(1)], 1)], 2)
    scale = atlas_px / square.size
    t = np.stack([(common[faces[:, 1]] - common[faces[:, 0]]) * scale,
                  (common[faces[:, 2]] - common[faces[:, 0]]) * scale], 2)  # (F, 2, 2): columns are edges
    det = t[:, 0, 0] * t[:, 1, 1] - t[:, 0, 1] * t[:, 1, 0]
    ok = np.abs(det) > 1e-9
    if not ok.any():
        return 0.0
    m = p[ok] @ np.linalg.inv(t[ok])
    return float(np.linalg.svd(m, compute_uv=False)[:, 0].max())
