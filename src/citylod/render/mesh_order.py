"""Triangle and vertex order for a GPU's vertex cache: what a tile's mesh costs to draw depends on it.

The TIN builders emit triangles in the order their refinement inserts them, which jumps across the
tile: measured with a 32-entry FIFO vertex cache, about 2.5 vertex shader runs per triangle (ACMR; 3 is
no reuse at all, about 0.5 the best a regular grid allows). Mesa's llvmpipe shades vertices on one
thread in batches with such a cache, so a frame of coarse tiles paid two to three times the vertex work
its triangles need (docs/PERFORMANCE_LOG.md, 2026-12-03: "Frame time at τ = 1").

:func:`cache_order` numbers the vertices along a Morton (Z-order) curve of their x, y and sorts the
triangles by their first vertex, so consecutive triangles share vertices and a run of triangles uses a
short range of vertex numbers. It only reorders: the same triangles
with the same vertices and winding are drawn (per-vertex arrays are permuted alike), so the picture
is the same. Dedicated optimisers (Forsyth's, meshoptimizer's) reach ≈ 0.6–0.65; meshoptimizer's
Python wrappers on PyPI are alpha releases, and the vectorised sort here costs a fraction of a
tile's decode time.
"""

from __future__ import annotations

import os

import numpy as np
import numpy.typing as npt

__all__ = ["cache_order", "enabled"]

#: Set to "file" to draw meshes in the order the tile stores them (measuring the difference).
ENV = "CITYLOD_MESH_ORDER"


def enabled() -> bool:
    """True unless ``CITYLOD_MESH_ORDER=file`` asks for the stored order (A/B measurements)."""
    return os.environ.get(ENV, "").strip().lower() != "file"


def _spread(x: npt.NDArray[np.uint32]) -> npt.NDArray[np.uint32]:
    """Interleave zeros between the low 16 bits of ``x`` (bit i moves to bit 2i)."""
    x = (x | (x << np.uint32(8))) & np.uint32(0x00FF00FF)
    x = (x | (x << np.uint32(4))) & np.uint32(0x0F0F0F0F)
    x = (x | (x << np.uint32(2))) & np.uint32(0x33333333)
    return (x | (x << np.uint32(1))) & np.uint32(0x55555555)


def morton_order(points_xy: npt.NDArray[np.floating]) -> npt.NDArray[np.intp]:
    """Indices that sort (M, 2) points along a Z-order curve over their bounding box (16 bits a side)."""
    if len(points_xy) < 2:
        return np.arange(len(points_xy))
    p = np.asarray(points_xy)
    lo, hi = p.min(axis=0), p.max(axis=0)
    scale = np.float32(65535.0) / np.where(hi > lo, hi - lo, 1.0).astype(np.float32)
    q = ((p - lo) * scale).astype(np.uint32)
    return np.argsort(_spread(q[:, 0]) | (_spread(q[:, 1]) << np.uint32(1)))


def cache_order(positions: npt.NDArray[np.floating], *face_sets: npt.NDArray[np.integer]
                ) -> tuple[npt.NDArray[np.intp], list[npt.NDArray[np.int64]]]:
    """Reorder vertices and triangle sets for vertex-cache reuse.

    Vertices are numbered along a Z-order curve of their x, y; each set's triangles are then sorted by
    their smallest new vertex number, so consecutive triangles are neighbours and the vertex numbers of
    a run of triangles span a short range (llvmpipe shades a short index range as one batch).

    Parameters
    ----------
    positions
        (N, 3) vertex positions.
    face_sets
        Flat (3·M,) connectivities over ``positions`` (for example a tile's surface and its skirt),
        each sorted on its own and kept in the given sequence.

    Returns
    -------
    (perm, faces)
        ``perm`` (N,): new vertex i is old vertex ``perm[i]`` (apply it to every per-vertex array).
        ``faces``: each set's triangles in the new order, renumbered through ``perm``; every triangle
        keeps its corners' order (its winding).
    """
    pos = np.asarray(positions)
    n = len(pos)
    perm = morton_order(pos[:, :2])
    new_of_old = np.empty(n, np.int64)
    new_of_old[perm] = np.arange(n)
    out = []
    for fs in face_sets:
        f = new_of_old[np.asarray(fs, np.int64).reshape(-1, 3)]
        if len(f):
            f = f[np.argsort(f.min(axis=1))]
        out.append(f.reshape(-1))
    return perm, out
