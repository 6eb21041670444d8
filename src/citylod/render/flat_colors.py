"""One colour per triangle without per-primitive lookups: flat-interpolated vertex colours.

Untextured tiles are drawn with the sun's light baked into one colour per triangle
(:func:`citylod.render.tileset_actor.baked_face_colors`). Given to VTK as cell scalars, those colours are
read in the fragment shader through ``gl_PrimitiveID``, and that costs twice on Mesa's llvmpipe: every
fragment fetches its colour from a buffer texture, and the draw module, which has no primitive IDs of
its own, runs its primitive assembler on every triangle to attach one (it de-indexes the triangles and
grows its output arrays triangle by triangle). On the 4097² city, frames drawn without any scalar
colours took 0.66× (full resolution) and 0.75–0.86× (τ = 1 px) the time of the cell-coloured ones
(docs/PERFORMANCE_LOG.md, 2026-12-03: "Frame time: cell colours").

OpenGL's ``flat`` interpolation gives every fragment of a triangle the value of one corner, its
*provoking vertex* (the last one, OpenGL's default convention). :func:`provoking_layout` rearranges a
mesh so that each triangle's last corner is a vertex no other triangle has as its last corner: triangles
are rotated (corner order is cyclic, so the winding stays) to end on a vertex still free, and the
triangles left over get a copy of one corner. A vertex can then carry its triangle's colour, and
:data:`VS_FLAT` / :data:`FS_FLAT` make VTK's colour varying flat. Same triangles, same positions, the
same colour value per triangle, so the same picture; a heightfield mesh has about twice as many
triangles as vertices, so about half the triangles need a copied vertex.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["ENV", "FS_FLAT", "VS_FLAT", "enabled", "provoking_layout", "set_flat"]

#: Set to "cells" to colour triangles through cell scalars (the former way; for A/B measurements).
ENV = "CITYLOD_FACE_COLORS"

#: (original, replacement) in VTK's polydata vertex and fragment shaders, applied after VTK's own
#: substitutions: the interpolated colour becomes the provoking vertex's.
VS_FLAT = ("out vec4 vertexColorVSOutput;", "flat out vec4 vertexColorVSOutput;")
FS_FLAT = ("in vec4 vertexColorVSOutput;", "flat in vec4 vertexColorVSOutput;")


def enabled() -> bool:
    """True unless ``CITYLOD_FACE_COLORS=cells`` asks for cell-scalar colours (A/B measurements)."""
    return os.environ.get(ENV, "").strip().lower() != "cells"


def provoking_layout(n_vertices: int, *face_sets: npt.NDArray[np.integer]
                     ) -> tuple[npt.NDArray[np.intp], list[npt.NDArray[np.int64]]]:
    """Give every triangle a last corner of its own.

    Parameters
    ----------
    n_vertices
        Number of vertices the faces index.
    face_sets
        Flat (3·M,) connectivities (for example a tile's surface and its skirt).

    Returns
    -------
    (source, faces)
        ``source`` (N',): new vertex i is a copy of old vertex ``source[i]`` (the first ``n_vertices``
        are the old vertices themselves; apply it to every per-vertex array). ``faces``: each set's
        triangles in the same sequence, each rotated (winding kept) and renumbered so that its last
        corner is the last corner of no other triangle in any set.
    """
    sizes = [len(np.asarray(fs).reshape(-1)) // 3 for fs in face_sets]
    f = (np.concatenate([np.asarray(fs, np.int64).reshape(-1, 3) for fs in face_sets])
         if face_sets else np.zeros((0, 3), np.int64))
    m = len(f)
    used = np.zeros(n_vertices, bool)
    corner = np.full(m, -1, np.int8)
    # Greedy: each round offers the still unserved triangles one corner; a free vertex goes to the first
    # triangle asking for it. Corner 2 first: a triangle that keeps its order needs no rotation.
    for c in (2, 0, 1):
        todo = np.flatnonzero(corner < 0)
        if not len(todo):
            break
        v = f[todo, c]
        free = ~used[v]
        uniq, first = np.unique(v[free], return_index=True)
        corner[todo[free][first]] = c
        used[uniq] = True
    rest = np.flatnonzero(corner < 0)
    source = np.concatenate([np.arange(n_vertices), f[rest, 2]])
    f[rest, 2] = n_vertices + np.arange(len(rest))
    corner[rest] = 2
    r0, r1 = corner == 0, corner == 1
    f[r0] = f[r0][:, [1, 2, 0]]  # (a, b, c) -> (b, c, a): a last
    f[r1] = f[r1][:, [2, 0, 1]]  # (a, b, c) -> (c, a, b): b last
    out, start = [], 0
    for k in sizes:
        out.append(f[start:start + k].reshape(-1))
        start += k
    return source, out


def set_flat(shader_property: Any, on: bool) -> None:
    """Make (or stop making) the vertex colour varying of an actor's shaders flat."""
    for add, clear, (old, new) in (
            (shader_property.AddVertexShaderReplacement, shader_property.ClearVertexShaderReplacement, VS_FLAT),
            (shader_property.AddFragmentShaderReplacement, shader_property.ClearFragmentShaderReplacement,
             FS_FLAT)):
        if on:
            add(old, False, new, False)
        else:
            clear(old, False)
