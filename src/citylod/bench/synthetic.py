"""Small synthetic tilesets made in code: a terrain quadtree and a point octree-like pyramid.

For tests and quick benchmarks of the renderer before (and besides) the real builders. The terrain is
a REPLACE quadtree: level ``l`` has ``2^l × 2^l`` tiles, each a regular ``n × n`` grid TIN of an analytic
height field, with skirts; the geometric error of a tile is the exact vertical L∞ distance between its
TIN and the leaf-level TIN, evaluated at every leaf vertex inside it (both are piecewise linear on nested
grids, so the maximum over leaf vertices and coarse-edge crossings bounds it; leaf vertices suffice here
because coarse vertices are leaf vertices and coarse edges cross leaf cells along their diagonals).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import numpy.typing as npt

from citylod.io.image import encode_png
from citylod.io.tiles3d import MeshData, PointData, TileContent, TileSpec, write_content, write_tileset

HeightFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


def rolling_hills(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A smooth default relief (metres), defined on coordinates relative to the terrain's corner."""
    return 30.0 * np.sin(x / 170.0) * np.cos(y / 230.0) + 12.0 * np.sin((x + 2 * y) / 61.0)


def _grid_faces(n: int) -> npt.NDArray[np.uint32]:
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1))
    a = (j * n + i).ravel()
    b, c = a + 1, a + n
    d = c + 1
    # Two triangles per cell split along a–d, counter-clockwise seen from +z (x east, y north).
    return np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.uint32)


def _skirt(positions: np.ndarray, n: int, depth: float) -> tuple[np.ndarray, np.ndarray]:
    """Border ring of an n×n grid lowered by ``depth``: extra vertices and the triangles joining them."""
    idx = np.arange(n * n).reshape(n, n)
    ring = np.concatenate([idx[0, :-1], idx[:-1, -1], idx[-1, ::-1][:-1], idx[::-1, 0][:-1]])
    low = positions[ring].copy()
    low[:, 2] -= depth
    base = len(positions)
    k = np.arange(len(ring))
    top0, top1 = ring[k], ring[(k + 1) % len(ring)]
    bot0, bot1 = base + k, base + (k + 1) % len(ring)
    faces = np.concatenate([np.stack([top0, bot0, bot1], 1), np.stack([top0, bot1, top1], 1)])
    return low, faces.astype(np.uint32)


def _texture(level: int, ix: int, iy: int, size: int) -> npt.NDArray[np.uint8]:
    """A tile texture: hue by level, a brighter north-west quadrant and a dark border, so orientation
    and mirroring errors are visible in a render."""
    img = np.empty((size, size, 3), np.uint8)
    base = np.array([[60, 140, 60], [200, 120, 40], [60, 100, 200], [180, 60, 160], [90, 170, 170]])[level % 5]
    img[:] = base
    img[: size // 2, : size // 2] = np.minimum(base + 70, 255)  # rows from the top: north; cols: west
    img[:2], img[-2:], img[:, :2], img[:, -2:] = 20, 20, 20, 20
    return img


def _attach_children(spec: TileSpec, specs: dict[tuple[int, int, int], TileSpec], level: int, ix: int,
                     iy: int) -> None:
    """Make the four tiles below (level, ix, iy) the children of ``spec`` and grow its box over them."""
    spec.children = [specs[(level + 1, 2 * ix + dx, 2 * iy + dy)] for dy in (0, 1) for dx in (0, 1)]
    spec.lo = np.minimum.reduce([spec.lo] + [c.lo for c in spec.children])
    spec.hi = np.maximum.reduce([spec.hi] + [c.hi for c in spec.children])


def make_terrain_tileset(out_dir: str | os.PathLike[str], *, levels: int = 3, n: int = 17,
                         extent: float = 1024.0, corner: npt.ArrayLike = (500000.0, 5400000.0, 0.0),
                         height_fn: HeightFn = rolling_hills, crs: str = "EPSG:25832",
                         texture_px: int | None = 32, skirts: bool = True,
                         vertex_colors: bool = False) -> Path:
    """Write a terrain quadtree tileset and return its folder.

    Parameters
    ----------
    out_dir
        Output folder (created).
    levels
        Number of levels (root = level 0); the leaves are level ``levels - 1``.
    n
        Grid samples per tile side.
    extent
        Side of the square terrain, metres.
    corner
        South-west corner (x, y, z offset) in ``crs``; the default sits at 5.4e6 m northing.
    height_fn
        Heights (metres, added to ``corner[2]``) at coordinates relative to the corner.
    texture_px
        Side of each tile's PNG texture; None for untextured tiles.
    skirts
        Add skirts, as deep as twice the tile's error plus a metre.
    vertex_colors
        Colour vertices by level (used when there is no texture).
    """
    out = Path(out_dir)
    x0, y0, z0 = (float(v) for v in corner)
    leaf_cells = (n - 1) * 2 ** (levels - 1)
    step = extent / leaf_cells

    def leaf_height(gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
        return height_fn(gx * step, gy * step) + z0

    faces = _grid_faces(n)
    specs: dict[tuple[int, int, int], TileSpec] = {}
    for level in range(levels - 1, -1, -1):
        tiles = 2**level
        stride = 2 ** (levels - 1 - level)  # leaf cells per cell of this level
        for iy in range(tiles):
            for ix in range(tiles):
                gx0, gy0 = ix * (n - 1) * stride, iy * (n - 1) * stride
                g = np.arange(n) * stride
                gx, gy = np.meshgrid(gx0 + g, gy0 + g)
                z = leaf_height(gx, gy)
                # Exact error against the leaf TIN: interpolate this tile's TIN at every leaf vertex.
                if stride > 1:
                    m = (n - 1) * stride + 1
                    fx, fy = np.meshgrid(np.arange(m), np.arange(m))
                    zf = leaf_height(gx0 + fx, gy0 + fy)
                    cx, cy = np.minimum(fx // stride, n - 2), np.minimum(fy // stride, n - 2)
                    u, v = fx / stride - cx, fy / stride - cy
                    za, zb = z[cy, cx], z[cy, cx + 1]
                    zc, zd = z[cy + 1, cx], z[cy + 1, cx + 1]
                    # Triangles a-b-d (u >= v) and a-d-c (u < v) of _grid_faces.
                    zi = np.where(u >= v, za + u * (zb - za) + v * (zd - zb), za + v * (zc - za) + u * (zd - zc))
                    err = float(np.abs(zi - zf).max())
                else:
                    err = 0.0
                xs, ys = x0 + gx * step, y0 + gy * step
                lo = np.array([xs.min(), ys.min(), z.min()])
                hi = np.array([xs.max(), ys.max(), z.max()])
                center = (lo + hi) / 2.0
                pos = np.stack([xs.ravel(), ys.ravel(), z.ravel()], 1) - center
                tri = faces
                skirt_flags = np.zeros(len(tri), bool)
                if skirts:
                    low, sf = _skirt(pos, n, 2.0 * err + 1.0)
                    pos = np.concatenate([pos, low])
                    tri = np.concatenate([tri, sf])
                    skirt_flags = np.concatenate([skirt_flags, np.ones(len(sf), bool)])
                uv = tex = colors = None
                if texture_px:
                    ring_uv = None
                    u_ = (gx - gx0).ravel() / ((n - 1) * stride)
                    v_ = 1.0 - (gy - gy0).ravel() / ((n - 1) * stride)  # glTF: v from the top (north)
                    uv = np.stack([u_, v_], 1)
                    if skirts:
                        idx = np.arange(n * n).reshape(n, n)
                        ring_uv = uv[np.concatenate([idx[0, :-1], idx[:-1, -1], idx[-1, ::-1][:-1],
                                                     idx[::-1, 0][:-1]])]
                        uv = np.concatenate([uv, ring_uv])
                    tex = encode_png(_texture(level, ix, iy, texture_px))
                if vertex_colors:
                    from citylod.render.colors import LEVEL_PALETTE

                    colors = np.empty((len(pos), 4), np.uint8)
                    colors[:, :3] = LEVEL_PALETTE[level % len(LEVEL_PALETTE)]
                    colors[:, 3] = 255
                key = f"{level}/{ix}/{iy}"
                content = TileContent(meshes=[MeshData(
                    positions=pos.astype(np.float32), faces=tri, skirt=skirt_flags,
                    uv=None if uv is None else uv.astype(np.float32), texture=tex, colors=colors)])
                uri = write_content(out, key, content)
                spec = TileSpec(key=key, level=level, center=center, lo=lo, hi=hi, geometric_error=err,
                                content=uri)
                if level < levels - 1:
                    _attach_children(spec, specs, level, ix, iy)
                specs[(level, ix, iy)] = spec
    write_tileset(out, specs[(0, 0, 0)], crs, extras={"citylod": {"kind": "dsm"}})
    return out


def make_point_tileset(out_dir: str | os.PathLike[str], *, levels: int = 3, points_per_tile: int = 4000,
                       extent: float = 256.0, corner: npt.ArrayLike = (500000.0, 5400000.0, 0.0),
                       crs: str = "EPSG:25832", seed: int = 0) -> Path:
    """Write a quadtree of point tiles (ADD refinement, as point octrees use) on a gentle slope.

    Points carry rgb, classification (2 ground / 6 building by a square block) and intensity.
    """
    out = Path(out_dir)
    rng = np.random.default_rng(seed)
    x0, y0, z0 = (float(v) for v in corner)
    specs: dict[tuple[int, int, int], TileSpec] = {}
    for level in range(levels - 1, -1, -1):
        tiles = 2**level
        size = extent / tiles
        for iy in range(tiles):
            for ix in range(tiles):
                px = rng.uniform(ix * size, (ix + 1) * size, points_per_tile)
                py = rng.uniform(iy * size, (iy + 1) * size, points_per_tile)
                building = (np.abs(px - extent / 2) < extent / 6) & (np.abs(py - extent / 2) < extent / 6)
                pz = 0.02 * px + np.where(building, 15.0, 0.0)
                xyz = np.stack([x0 + px, y0 + py, z0 + pz], 1)
                lo, hi = xyz.min(axis=0), xyz.max(axis=0)
                center = (lo + hi) / 2.0
                rgb = np.where(building[:, None], [[200, 80, 60]], [[90, 160, 80]]).astype(np.uint8)
                pts = PointData(positions=(xyz - center).astype(np.float32), rgb=rgb,
                                classification=np.where(building, 6, 2).astype(np.uint8),
                                intensity=rng.integers(100, 4000, points_per_tile).astype(np.uint16))
                key = f"{level}/{ix}/{iy}"
                uri = write_content(out, key, TileContent(points=pts))
                spec = TileSpec(key=key, level=level, center=center, lo=lo, hi=hi,
                                geometric_error=size / np.sqrt(points_per_tile), content=uri, refine="ADD")
                if level < levels - 1:
                    _attach_children(spec, specs, level, ix, iy)
                specs[(level, ix, iy)] = spec
    write_tileset(out, specs[(0, 0, 0)], crs, extras={"citylod": {"kind": "points"}})
    return out
