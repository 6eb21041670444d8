"""Triangle and vertex order for a GPU's vertex cache: what a tile's mesh costs to draw depends on it.

The TIN builders emit triangles in the order their refinement inserts them, which jumps across the
tile: measured with a 32-entry FIFO vertex cache, about 2.5 vertex shader runs per triangle (ACMR; 3 is
no reuse at all, about 0.5 the best a regular grid allows). Mesa's llvmpipe shades vertices on one
thread in batches with such a cache, so a frame of coarse tiles paid two to three times the vertex work
its triangles need (docs/PERFORMANCE_LOG.md, 2026-12-03: "Frame time at τ = 1").

:func:`cache_order` sorts each triangle set along a Morton (Z-order) curve of its centroids' x, y and
numbers the vertices in first-use order, so consecutive triangles share vertices and each vertex is
fetched close to when it is shaded: ACMR ≈ 0.7 on the DSM tiles. It only reorders: the same triangles
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


def _spread(x: npt.NDArray[np.uint64]) -> npt.NDArray[np.uint64]:
    """Interleave zeros between the low 16 bits of ``x`` (bit i moves to bit 2i)."""
    x = (x | (x << np.uint64(8))) & np.uint64(0x00FF00FF)
    x = (x | (x << np.uint64(4))) & np.uint64(0x0F0F0F0F)
    x = (x | (x << np.uint64(2))) & np.uint64(0x33333333)
    return (x | (x << np.uint64(1))) & np.uint64(0x55555555)


def morton_order(points_xy: npt.NDArray[np.floating]) -> npt.NDArray[np.intp]:
    """Indices that sort (M, 2) points along a Z-order curve over their bounding box (16 bits a side)."""
    if len(points_xy) < 2:
        return np.arange(len(points_xy))
    p = np.asarray(points_xy, np.float64)
    lo, hi = p.min(axis=0), p.max(axis=0)
    q = ((p - lo) / np.where(hi > lo, hi - lo, 1.0) * 65535.0).astype(np.uint64)
    return np.argsort(_spread(q[:, 0]) | (_spread(q[:, 1]) << np.uint64(1)), kind="stable")


def cache_order(positions: npt.NDArray[np.floating], *face_sets: npt.NDArray[np.integer]
                ) -> tuple[npt.NDArray[np.intp], list[npt.NDArray[np.int64]]]:
    """Reorder triangle sets for vertex-cache reuse.

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
        ``perm`` (N,): new vertex i is old vertex ``perm[i]`` (apply it to every per-vertex array);
        vertices no triangle uses keep their relative order after the used ones. ``faces``: each set's
        triangles in Morton order of their centroids, renumbered through ``perm``; every triangle keeps
        its corners' cyclic order (its winding).
    """
    pos = np.asarray(positions)
    n = len(pos)
    tris = []
    for fs in face_sets:
        f = np.asarray(fs, np.int64).reshape(-1, 3)
        if len(f):
            f = f[morton_order(pos[f].mean(axis=1)[:, :2])]
        tris.append(f)
    flat = np.concatenate([t.reshape(-1) for t in tris]) if tris else np.zeros(0, np.int64)
    used, first = np.unique(flat, return_index=True)
    perm = used[np.argsort(first, kind="stable")]  # used vertices, in first-use order
    unused = np.ones(n, bool)
    unused[perm] = False
    perm = np.concatenate([perm, np.flatnonzero(unused)])
    new_of_old = np.empty(n, np.int64)
    new_of_old[perm] = np.arange(n)
    return perm, [new_of_old[t].reshape(-1) for t in tris]
