"""Skirts drawn only where a crack can open: on the sides of a drawn tile whose neighbour is of another level.

A DSM tile's skirts (Wahl et al. 2004; :mod:`citylod.lod.build.dsm`) hang from its borders to close the cracks
between tiles of different levels, whose borders differ by up to the sum of their errors. Between two tiles
of the *same* level there is no crack to close: stage 2 of the build gives both the same border vertices
wherever both have a surface (the module docstring of :mod:`citylod.lod.build.dsm`; on the 4097² city every
shared border of every level has the same vertices on both sides, to 2e-9 m: docs/PERFORMANCE_LOG.md), so
the two surfaces meet edge to edge and a skirt there is drawn, and costs, for nothing. At τ = 1 px on the
4097² city (built with the skirts that reached down to the lowest sample of the border line) skirts were
3 % of the triangles drawn and about 9 % of the frame: tall, they cover many pixels behind the surface.

Which skirt is which is decided once per loaded tile (:func:`skirt_sides`): the side of the tile's box
(``−``/``+`` its first and second half-axis) on which a skirt triangle hangs, or −1 when it lies on none
(such a skirt is always drawn). Which sides a frame needs is decided from the drawn tiles alone
(:func:`needed_sides`): a side keeps its skirt unless a drawn tile of the same level, with a box of the same
horizontal size, sits exactly across it. Anything else keeps it: a neighbour of another level, one not
drawn (culled, not loaded, failed), a box that does not reach the footprint's edge (no-data along a
border). So every skirt that can close a crack is drawn, and the crack tests of the DSM tiles stay as they
were (tests/render/test_dsm.py, tests/render/test_render.py).

Off by default (``TilesetLayer.skirts_where_needed``). A frame that draws fewer skirts is faster (4097² city,
same process, alternating: full-resolution frames, which need none, 0.89×; τ = 1 px frames 0.97×), but
a tile's skirts live in its one cell array, and VTK uploads the whole mesh again when that changes: along
the default flight the tiles whose kept sides change as the camera moves hold 1.3× the triangles of the
tiles that appear, so a moving view would upload more than twice as much (docs/PERFORMANCE_LOG.md). It
pays for frames drawn many times from one place (off-screen renders, full-resolution baselines).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import numpy as np
import numpy.typing as npt

from citylod.core.geometry import F64, Box

__all__ = ["ALL_SIDES", "needed_sides", "side_offsets", "skirt_sides"]

#: Every side of a tile: 0 = −first half-axis, 1 = +first, 2 = −second, 3 = +second (x−, x+, y−, y+ for
#: the axis-aligned boxes of citylod's DSM tiles).
ALL_SIDES = frozenset(range(4))

_ON_FACE = 1e-3  # a skirt's centroid lies on a box face to within this share of the half-axis


def skirt_sides(positions: npt.NDArray[np.float32], skirt: npt.NDArray[np.int64], matrix: F64,
                box: Box) -> npt.NDArray[np.int8]:
    """The side of ``box`` each skirt triangle hangs on (0–3, see :data:`ALL_SIDES`), or −1 for none.

    ``positions`` are tile-local, ``matrix`` maps them into the frame of ``box``, ``skirt`` is the flat
    (3·M,) connectivity. A skirt hangs vertically from a border, so its centroid lies on the box face
    through that border (the box bounds the surface, whose border reaches the footprint's edge).
    """
    tri = np.asarray(skirt, np.int64).reshape(-1, 3)
    out = np.full(len(tri), -1, np.int8)
    if not len(tri):
        return out
    m = np.asarray(matrix, np.float64)
    centroid = positions[tri].astype(np.float64).mean(axis=1) @ m[:3, :3].T + m[:3, 3]
    rel = centroid - box.center
    u = []
    for i in range(2):
        axis = box.half_axes[:, i]
        length2 = float(axis @ axis)
        u.append(rel @ axis / length2 if length2 > 0 else np.zeros(len(tri)))
    u0, u1 = u
    on0 = (np.abs(u0) >= 1.0 - _ON_FACE) & (np.abs(u0) >= np.abs(u1))
    on1 = ~on0 & (np.abs(u1) >= 1.0 - _ON_FACE)
    out[on0] = np.where(u0[on0] < 0, 0, 1)
    out[on1] = np.where(u1[on1] < 0, 2, 3)
    return out


def side_offsets(sides: npt.NDArray[np.int8]) -> tuple[npt.NDArray[np.intp], tuple[int, ...]]:
    """A stable order of the skirt triangles by side (−1 first, then 0–3) and the triangle offsets of the five
    groups (6 numbers): group ``g`` (side ``g − 1``) is ``order[off[g]:off[g + 1]]``."""
    key = sides.astype(np.int64) + 1
    order = np.argsort(key, kind="stable")
    counts = np.bincount(key, minlength=5)
    return order, tuple(int(x) for x in np.concatenate([[0], np.cumsum(counts)]))


def needed_sides(nodes: Iterable[Any]) -> dict[str, frozenset[int]]:
    """For each drawn tile (``key``, ``level``, ``box``), the sides whose skirt may close a crack.

    A side is left out only when a drawn tile of the same level whose box has the same horizontal
    half-axes lies exactly across it (its centre at this one's plus twice the half-axis of that side, to
    1e-3 of the half-axis). Horizontal means the boxes' first two half-axes, compared in the frame's x
    and y.
    """
    tiles = list(nodes)
    index: dict[tuple[int, int, int], list[tuple[F64, F64, F64]]] = {}
    geo = []
    for n in tiles:
        c = np.asarray(n.box.center, np.float64)
        a0 = np.asarray(n.box.half_axes[:, 0], np.float64)
        a1 = np.asarray(n.box.half_axes[:, 1], np.float64)
        q = max(float(np.linalg.norm(a0[:2])), float(np.linalg.norm(a1[:2])), 1e-9) / 4.0
        geo.append((c, a0, a1, q))
        index.setdefault(_cell(int(n.level), c, q), []).append((c, a0, a1))
    out: dict[str, frozenset[int]] = {}
    for n, (c, a0, a1, q) in zip(tiles, geo, strict=True):
        tol = 1e-3 * min(float(np.linalg.norm(a0[:2])), float(np.linalg.norm(a1[:2]))) + 1e-9
        keep = set(ALL_SIDES)
        for side, step in ((0, -2.0 * a0), (1, 2.0 * a0), (2, -2.0 * a1), (3, 2.0 * a1)):
            target = c + step
            lv, cx, cy = _cell(int(n.level), target, q)
            found = False
            for dx in (-1, 0, 1):
                for dy in (-1, 0, 1):
                    for oc, o0, o1 in index.get((lv, cx + dx, cy + dy), ()):
                        if (abs(oc[0] - target[0]) <= tol and abs(oc[1] - target[1]) <= tol
                                and np.all(np.abs(o0[:2] - a0[:2]) <= tol) and np.all(np.abs(o1[:2] - a1[:2]) <= tol)):
                            found = True
            if found:
                keep.discard(side)
        out[n.key] = frozenset(keep)
    return out


def _cell(level: int, c: npt.NDArray[np.float64], q: float) -> tuple[int, int, int]:
    return level, math.floor(float(c[0]) / q), math.floor(float(c[1]) / q)
