"""Polygon edits applied while rendering: recolour, discard, texture or displace what lies inside 2D polygons.

Kehl, Tutenel, Eisemann (§4) edit point attributes on the fly from 2D polygons, without rebuilding the
hierarchy. Here each resident tile (points and DSM meshes alike) is edited on the CPU once per polygon
set, when it is first shown: its vertices are carried into the data's CRS with the tile's matrix, classified
against the polygons (``shapely.contains_xy``, exact point-in-polygon, only for vertices inside a polygon's
box), and the tile's VTK arrays are changed in place:

* ``recolor`` / ``texture``: the colour array (point colours, per-vertex or baked per-face mesh colours; on
  an orthophoto-textured mesh a per-vertex tint that modulates the texture);
* ``discard``: points leave the vertex cell array (drawn as splats, they are masked out of the glyphs); mesh
  triangles whose centre is inside collapse to a point (cell arrays keep their length, so per-cell colours
  and skirt flags stay aligned);
* ``displace``: vertices move by ``height_m`` along the data's vertical axis.

The later polygon of the layer wins where polygons overlap. A frame then costs what it cost before: the
edited arrays are what VTK draws. Per frame the work is one check per shown tile (is its geometry, colour
array or drawn-point count the one that was edited?), so re-styling or the fade-in of point tiles gets
the edit again on their next frame. Changing the layer restores every tile and edits them anew.

Creates and changes VTK objects: call from the thread that owns the GL context. No Qt.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import shapely

from citylod.analysis.polygons import EditPolygon, PolygonLayer
from citylod.render import _vtk
from citylod.render.tileset_actor import _cells, _points

__all__ = ["PolygonEdits", "classify"]


def classify(polygons: tuple[EditPolygon, ...], x: npt.NDArray[np.float64], y: npt.NDArray[np.float64]
             ) -> npt.NDArray[np.int16]:
    """Index of the polygon containing each point (the last one where they overlap), -1 for none; (N,)."""
    out = np.full(len(x), -1, np.int16)
    for i, p in enumerate(polygons):
        x0, y0, x1, y1 = p.geometry.bounds
        cand = np.flatnonzero((x >= x0) & (x <= x1) & (y >= y0) & (y <= y1))
        if len(cand):
            inside = shapely.contains_xy(p.geometry, x[cand], y[cand])
            out[cand[inside]] = i
    return out


@dataclass
class _Edited:
    """What was edited in one drawn object (a mesh or the points of a tile), to tell when to redo it."""

    data: Any
    scalars: Any
    drawn: int
    version: int
    idx: Any = None
    world: Any = None


def _address(obj: Any) -> str:
    return "" if obj is None else obj.GetAddressAsString("vtkObject")


class PolygonEdits:
    """The edits of a :class:`PolygonLayer` on every tile of a scene, applied before each render.

    Parameters
    ----------
    scene
        A :class:`~citylod.render.tileset_actor.Scene`.
    layer
        The polygons (carried into the scene's CRS).
    """

    def __init__(self, scene: Any, layer: PolygonLayer) -> None:
        self.scene = scene
        self.version = 0
        self.tiles_edited = 0  # counter for tests: classifications computed, not frames drawn
        self._state: dict[tuple[int, str, int], _Edited] = {}
        self._textures: dict[int, np.ndarray] = {}
        self._set(layer)
        self._observer = scene.renderer.AddObserver(_vtk.vtkCommand.StartEvent, self._on_start)

    def _set(self, layer: PolygonLayer) -> None:
        self.layer = layer.to_crs(self.scene.crs)
        self.polygons = tuple(p for p in self.layer.polygons if p.action != "source")
        self._colors = np.array([p.color for p in self.polygons] or [(0, 0, 0)], np.uint8)
        self._textures = {i: _load_texture(p.texture) for i, p in enumerate(self.polygons)
                          if p.action == "texture" and p.texture}

    def set_layer(self, layer: PolygonLayer) -> None:
        """Replace the polygons: every edited tile is restored, then edited again on its next frame."""
        self._restore_all()
        self._set(layer)
        self.version += 1

    def close(self) -> None:
        """Remove the edits (tiles restored) and stop editing."""
        self._restore_all()
        self.scene.renderer.RemoveObserver(self._observer)

    # -- per frame ------------------------------------------------------------------------------------
    def _on_start(self, _obj: Any, _event: str) -> None:
        before = self.tiles_edited
        self.apply()
        if self.tiles_edited != before and self._has("displace"):
            # Displaced geometry can leave the depth range set for this frame before the edit.
            self.scene.renderer.ResetCameraClippingRange()

    def apply(self) -> None:
        """Edit every shown tile that is not edited yet in its current state (called before each render)."""
        if not self.polygons:
            return
        for li, layer in enumerate(self.scene.layers):
            for key, slot in layer._slots.items():
                if not slot.visible or slot.prepared is None:
                    continue
                matrix = layer.node(key).matrix  # maps prepared positions (reprojected or not)
                for mi, (props, mesh) in enumerate(zip(slot.meshes, slot.prepared.meshes, strict=False)):
                    if props.data is not None:
                        self._mesh(li, key, mi, props, mesh, matrix)
                pts = slot.points
                if pts is not None and pts.data is not None and slot.prepared.points is not None:
                    self._points(li, key, pts, slot.prepared.points.positions, matrix)

    def _fresh(self, k: tuple[int, str, int], data: Any, scalars: Any, drawn: int) -> bool:
        s = self._state.get(k)
        return (s is not None and s.data is data and s.version == self.version and s.drawn == drawn
                and _address(s.scalars) == _address(scalars))

    def _where(self, k: tuple[int, str, int], data: Any, positions: npt.NDArray[np.float32],
               matrix: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.int16], npt.NDArray[np.float64]]:
        s = self._state.get(k)
        if s is not None and s.data is data and s.version == self.version and s.idx is not None:
            return s.idx, s.world  # the same geometry re-styled or re-faded: classification stands
        self.tiles_edited += 1
        world = positions.astype(np.float64) @ matrix[:3, :3].T + matrix[:3, 3]
        return classify(self.polygons, world[:, 0], world[:, 1]), world

    def _offsets(self, idx: npt.NDArray[np.int16], matrix: npt.NDArray[np.float64]) -> np.ndarray | None:
        """Local-frame displacement (N, 3) for ``displace`` polygons, None when there is none."""
        heights = np.array([p.height_m if p.action == "displace" else 0.0 for p in self.polygons])
        h = np.where(idx >= 0, heights[np.maximum(idx, 0)], 0.0)
        if not h.any():
            return None
        up_local = np.linalg.solve(matrix[:3, :3], np.array([0.0, 0.0, 1.0]))
        return h[:, None] * up_local[None, :]

    def _colour(self, idx: npt.NDArray[np.int16], world: npt.NDArray[np.float64], rgb: np.ndarray) -> None:
        """Recolour/texture the rows of ``rgb`` (N, ≥3) uint8 in place."""
        actions = np.array([p.action for p in self.polygons])
        hit = idx >= 0
        recol = hit & (actions[np.maximum(idx, 0)] == "recolor")
        rgb[recol, :3] = self._colors[idx[recol]]
        for i, img in self._textures.items():
            sel = idx == i
            if sel.any():
                x0, y0, x1, y1 = self.polygons[i].geometry.bounds
                u = (world[sel, 0] - x0) / max(x1 - x0, 1e-9)
                v = (y1 - world[sel, 1]) / max(y1 - y0, 1e-9)
                r = np.clip((v * img.shape[0]).astype(int), 0, img.shape[0] - 1)
                c = np.clip((u * img.shape[1]).astype(int), 0, img.shape[1] - 1)
                rgb[sel, :3] = img[r, c, :3]

    def _has(self, action: str) -> bool:
        return any(p.action == action for p in self.polygons)

    def _points(self, li: int, key: str, props: Any, positions: npt.NDArray[np.float32],
                matrix: npt.NDArray[np.float64]) -> None:
        data = props.data
        k = (li, key, -1)
        if self._fresh(k, data, data.GetPointData().GetScalars(), props.drawn):
            return
        idx, world = self._where(k, data, positions, matrix)
        if (idx >= 0).any():
            off = self._offsets(idx, matrix)
            if off is not None:
                data.SetPoints(_points((positions + off).astype(np.float32)))
            if self._has("recolor") or self._textures:
                scalars = data.GetPointData().GetScalars()
                if scalars is None or not props.mapper.GetScalarVisibility():
                    c = np.asarray(props.actor.GetProperty().GetColor()) * 255
                    rgb = np.tile(c.astype(np.uint8), (len(positions), 1))
                    scalars = _vtk.numpy_to_vtk(rgb, deep=True, array_type=_vtk.VTK_UNSIGNED_CHAR)
                    data.GetPointData().SetScalars(scalars)
                    props.mapper.ScalarVisibilityOn()
                self._colour(idx, world, _vtk.vtk_to_numpy(scalars))
                scalars.Modified()
            if self._has("discard"):
                actions = np.array([p.action for p in self.polygons])
                gone = (idx >= 0) & (actions[np.maximum(idx, 0)] == "discard")
                keep = np.flatnonzero(~gone[: props.drawn])
                data.SetVerts(_cells(keep.astype(np.int64), 1))
                if props.splat_mapper is not None and props.actor.GetMapper() is props.splat_mapper:
                    # Splats are glyphs of every point, not of the vertex cells: masked instead, with the
                    # class filter's mask.
                    props.set_splat_mask(~gone if props.keep is None else ~gone & props.keep)
        data.Modified()
        self._state[k] = _Edited(data, data.GetPointData().GetScalars(), props.drawn, self.version, idx, world)

    def _mesh(self, li: int, key: str, mi: int, props: Any, mesh: Any, matrix: npt.NDArray[np.float64]) -> None:
        data = props.data
        k = (li, key, mi)
        cell_scalars = data.GetCellData().GetScalars()
        point_scalars = data.GetPointData().GetScalars()
        scalars = cell_scalars if props.mapper.GetScalarModeAsString() == "UseCellData" else point_scalars
        if self._fresh(k, data, scalars, 0):
            return
        idx, world = self._where(k, data, mesh.positions, matrix)
        if (idx >= 0).any():
            conn = np.concatenate([mesh.surface, mesh.skirt]).reshape(-1, 3)
            # A triangle belongs to the polygon of its vertices' majority (ties: the first vertex's), a
            # cheap stand-in for its centre that never leaves a triangle half edited.
            tri = idx[conn]
            t_idx = np.where((tri[:, 1] == tri[:, 2]) & (tri[:, 1] != tri[:, 0]), tri[:, 1], tri[:, 0])
            off = self._offsets(idx, matrix)
            if off is not None:
                data.SetPoints(_points((mesh.positions + off).astype(np.float32)))
            actions = np.array([p.action for p in self.polygons])
            if self._has("discard"):
                gone = (t_idx >= 0) & (actions[np.maximum(t_idx, 0)] == "discard")
                c2 = conn.copy()
                c2[gone] = c2[gone, :1]  # collapse: zero area, nothing drawn, cells keep their count
                data.SetPolys(_cells(c2.reshape(-1), 3))
            if self._has("recolor") or self._textures:
                if scalars is not None and scalars is cell_scalars and props.mapper.GetScalarVisibility():
                    centre = world[conn].mean(axis=1)
                    self._colour(t_idx, centre, _vtk.vtk_to_numpy(cell_scalars))
                    cell_scalars.Modified()
                elif getattr(props, "flat", False) and props.mapper.GetScalarVisibility():
                    # One colour per triangle on its own last corner (render/flat_colors.py): recolour
                    # triangles as the cell colours above are, through those corners.
                    centre = world[conn].mean(axis=1)
                    base = _vtk.vtk_to_numpy(point_scalars)
                    rgb = base[conn[:, 2]]
                    self._colour(t_idx, centre, rgb)
                    base[conn[:, 2]] = rgb
                    point_scalars.Modified()
                    scalars = point_scalars
                else:
                    base = (_vtk.vtk_to_numpy(point_scalars) if point_scalars is not None
                            and props.mapper.GetScalarVisibility() else None)
                    if base is None:  # textured or uniform: a white tint, coloured inside the polygons
                        rgb = np.full((len(mesh.positions), 3), 255, np.uint8)
                        point_scalars = _vtk.numpy_to_vtk(rgb, deep=True, array_type=_vtk.VTK_UNSIGNED_CHAR)
                        data.GetPointData().SetScalars(point_scalars)
                        props.mapper.SetScalarModeToUsePointData()
                        props.mapper.ScalarVisibilityOn()
                        base = _vtk.vtk_to_numpy(point_scalars)
                    self._colour(idx, world, base)
                    point_scalars.Modified()
                    scalars = point_scalars
        data.Modified()
        self._state[k] = _Edited(data, scalars, 0, self.version, idx, world)

    def _restore_all(self) -> None:
        for li, layer in enumerate(self.scene.layers):
            for key, slot in layer._slots.items():
                if slot.prepared is None:
                    continue
                for mi, (props, mesh) in enumerate(zip(slot.meshes, slot.prepared.meshes, strict=False)):
                    if (li, key, mi) in self._state and props.data is not None:
                        props.data.SetPoints(_points(mesh.positions))
                        props.data.SetPolys(_cells(np.concatenate([mesh.surface, mesh.skirt]), 3))
                pts = slot.points
                if (li, key, -1) in self._state and pts is not None and pts.data is not None:
                    pts.data.SetPoints(_points(slot.prepared.points.positions))
                    pts.data.SetVerts(_cells(np.arange(pts.drawn, dtype=np.int64), 1))
            layer.restyle()
        self._state.clear()


def _load_texture(path: str) -> np.ndarray:
    """An image as (H, W, C) uint8, row 0 at the top."""
    from pathlib import Path

    from citylod.core.errors import InputError
    from citylod.io.image import decode_image

    p = Path(path)
    if not p.is_file():
        raise InputError("texture image of a polygon edit not found", p)
    return decode_image(p.read_bytes(), str(p))
