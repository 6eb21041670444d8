"""The proxy solids of a city store drawn as one lit VTK actor, coloured per object from the feature state.

A city model opened on its own (no tileset to shade) would otherwise show nothing: the semantic overlay
(:mod:`citylod.render.semantic`) only tints geometry drawn by tile layers. This adapter draws every
object's closed proxy mesh, lit, in a neutral colour; highlighted objects take their colour, selected
ones cyan, hidden ones are left out. Colours are per cell from a per-object table, so a state change
costs one vectorised lookup, not a rebuild.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from citylod.render import _vtk

__all__ = ["StoreActor", "stack_meshes"]

BASE_RGB = (0.86, 0.83, 0.78)
SELECT_RGB = (0.0, 0.85, 1.0)


def stack_meshes(meshes: list[tuple[int, npt.NDArray[np.float64], npt.NDArray[np.int64]]]
                 ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """One mesh of many: ``meshes`` holds (object index, (V, 3) vertices, (F, 3) faces); returns vertices
    (ΣV, 3), faces (ΣF, 3) and the object index of every face (ΣF,)."""
    if not meshes:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
    counts = np.array([len(v) for _, v, _ in meshes])
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
    faces = np.concatenate([np.asarray(f, np.int64).reshape(-1, 3) + o for (_, _, f), o in zip(meshes, offsets,
                                                                                            strict=True)])
    owner = np.concatenate([np.full(len(f), i, np.int64) for i, _, f in meshes])
    return np.concatenate([v for _, v, _ in meshes]).astype(np.float64), faces, owner


class StoreActor:
    """Proxies of all objects in ``renderer``, positions shifted by ``origin`` (3,)."""

    def __init__(self, renderer: Any, vertices: npt.NDArray[np.float64], faces: npt.NDArray[np.int64],
                 owner: npt.NDArray[np.int64], origin: npt.ArrayLike) -> None:
        self.renderer = renderer
        self.owner = np.asarray(owner, np.int64)
        self._faces = np.asarray(faces, np.int64)
        self.data = _vtk.vtkPolyData()
        pts = _vtk.vtkPoints()
        pts.SetData(_vtk.numpy_to_vtk(np.ascontiguousarray(vertices - np.asarray(origin, np.float64)), deep=True))
        self.data.SetPoints(pts)
        self._set_cells(np.ones(len(self._faces), bool))
        self.mapper = _vtk.vtkPolyDataMapper()
        self.mapper.SetInputData(self.data)
        self.mapper.SetScalarModeToUseCellData()
        self.mapper.SetColorModeToDirectScalars()
        self.actor = _vtk.vtkActor()
        self.actor.SetMapper(self.mapper)
        prop = self.actor.GetProperty()
        # Walls facing away from the scene's single sun get only the ambient term: enough of it that
        # they read as shaded, not black.
        prop.SetAmbient(0.45)
        prop.SetDiffuse(0.65)
        renderer.AddActor(self.actor)
        self._visible = np.ones(len(self._faces), bool)

    def _set_cells(self, keep: npt.NDArray[np.bool_]) -> None:
        f = self._faces[keep]
        conn = np.ascontiguousarray(f.reshape(-1))
        cells = _vtk.vtkCellArray()
        cells.SetData(_vtk.numpy_to_vtkIdTypeArray(np.arange(0, len(conn) + 1, 3, dtype=np.int64), deep=True),
                      _vtk.numpy_to_vtkIdTypeArray(conn, deep=True))
        self.data.SetPolys(cells)
        self._kept = keep

    def restyle(self, rgba: npt.NDArray[np.float32], visible: npt.NDArray[np.bool_],
                selected: npt.NDArray[np.bool_]) -> None:
        """Per-object tables from :meth:`FeatureState.as_arrays`: highlight colour (alpha 0: none),
        visibility, selection."""
        colors = np.tile(np.asarray(BASE_RGB, np.float32), (len(rgba), 1))
        lit = rgba[:, 3] > 0
        colors[lit] = rgba[lit, :3]
        colors[selected] = SELECT_RGB
        keep = visible[self.owner]
        if not np.array_equal(keep, self._kept):
            self._set_cells(keep)
        face_rgb = (colors[self.owner[keep]] * 255).astype(np.uint8)
        arr = _vtk.numpy_to_vtk(face_rgb, deep=True, array_type=_vtk.VTK_UNSIGNED_CHAR)
        arr.SetName("rgb")
        self.data.GetCellData().SetScalars(arr)
        self.data.Modified()

    def object_of_cell(self, cell_id: int) -> int | None:
        """Object index of a drawn cell (a picker's cell id), or None."""
        idx = np.flatnonzero(self._kept)
        return int(self.owner[idx[cell_id]]) if 0 <= cell_id < len(idx) else None

    def set_visible(self, on: bool) -> None:
        self.actor.SetVisibility(bool(on))

    def remove(self) -> None:
        self.renderer.RemoveActor(self.actor)
