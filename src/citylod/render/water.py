"""A translucent water surface at the flood level, clipped to the flooded cells, drawn with the LOD tiles.

One quad at height ``level`` over the raster's extent, textured with an RGBA image of the flooded cells
(blue, deeper water darker, alpha 0 where dry), sampled nearest so the clip follows the cell edges exactly.
A new level or a new extent only re-uploads the texture: nothing is rebuilt, and the tiles are untouched.
The quad sits in the scene's frame (minus the scene origin, as the tiles do); VTK draws it in its
translucent pass after the opaque tiles and points, so the ground shows through shallow water.

Creates and changes VTK objects: call from the thread that owns the GL context. No Qt.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from citylod.core.errors import InputError
from citylod.render import _vtk

__all__ = ["WATER_RGB", "WaterSurface", "water_rgba"]

#: Colour of shallow water; deep water goes to half of it.
WATER_RGB = (40, 120, 220)
_MAX_TEXELS = 4096  # GL textures of at most 4096 a side are safe on every driver


def water_rgba(depth: npt.ArrayLike, *, alpha: float = 0.55, deep_m: float = 3.0) -> npt.NDArray[np.uint8]:
    """RGBA (H, W, 4) uint8 of a depth grid (row 0 = north; NaN, ≤ 0 = dry): alpha 0 where dry, colour
    darkening linearly to half at ``deep_m`` and below."""
    d = np.asarray(depth, dtype=np.float32)
    wet = np.isfinite(d) & (d > 0)
    shade = 1.0 - 0.5 * np.clip(np.where(wet, d, 0.0) / deep_m, 0.0, 1.0)
    out = np.zeros(d.shape + (4,), np.uint8)
    for k, c in enumerate(WATER_RGB):
        out[..., k] = (c * shade).astype(np.uint8)
    out[..., 3] = np.where(wet, np.uint8(round(255 * alpha)), np.uint8(0))
    return out


class WaterSurface:
    """The water quad of a :class:`~citylod.render.tileset_actor.Scene`.

    Parameters
    ----------
    scene
        The scene; its origin places the quad.
    bounds
        (xmin, ymin, xmax, ymax) of the raster in the scene's CRS.
    """

    def __init__(self, scene: Any, bounds: tuple[float, float, float, float]) -> None:
        self.scene = scene
        self.bounds = tuple(float(v) for v in bounds)
        self.level = 0.0
        self._points = _vtk.vtkPoints()
        self._points.SetNumberOfPoints(4)
        poly = _vtk.vtkPolyData()
        poly.SetPoints(self._points)
        cells = _vtk.vtkCellArray()
        cells.InsertNextCell(4)
        for i in range(4):
            cells.InsertCellPoint(i)
        poly.SetPolys(cells)
        tc = _vtk.numpy_to_vtk(np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32), deep=True)
        tc.SetName("tcoords")
        poly.GetPointData().SetTCoords(tc)
        self.texture = _vtk.vtkTexture()
        self.texture.InterpolateOff()  # nearest: the clip follows the cells' edges
        self.texture.RepeatOff()
        self.texture.EdgeClampOn()
        mapper = _vtk.vtkPolyDataMapper()
        mapper.SetInputData(poly)
        self.actor = _vtk.vtkActor()
        self.actor.SetMapper(mapper)
        self.actor.SetTexture(self.texture)
        prop = self.actor.GetProperty()
        prop.LightingOff()
        prop.SetColor(1.0, 1.0, 1.0)
        self.actor.PickableOff()
        self.actor.VisibilityOff()
        self._poly = poly
        scene.renderer.AddActor(self.actor)

    @classmethod
    def from_flood(cls, scene: Any, flood_dir: str | os.PathLike[str], index: int = -1) -> WaterSurface:
        """The surface of level ``index`` of a ``citylod flood`` output folder (its depth GeoTIFF)."""
        bounds, depth, level = _read_level(scene, flood_dir, index)
        surface = cls(scene, bounds)
        surface.set_depth(depth, level)
        return surface

    def load_level(self, flood_dir: str | os.PathLike[str], index: int) -> None:
        """Show level ``index`` of a flood folder (clamped to its last level: a time series that ended)."""
        _, depth, level = _read_level(self.scene, flood_dir, index, clamp=True)
        self.set_depth(depth, level)

    def set_depth(self, depth: npt.ArrayLike, level: float) -> None:
        """Show water ``depth`` (H, W) over the bounds (row 0 north; NaN or ≤ 0 dry) at height ``level``.

        Grids larger than 4096 a side are decimated (every k-th cell) to fit a texture."""
        d = np.asarray(depth)
        step = max(1, -(-max(d.shape) // _MAX_TEXELS))
        rgba = water_rgba(d[::step, ::step] if step > 1 else d)
        h, w = rgba.shape[:2]
        img = _vtk.vtkImageData()
        img.SetDimensions(w, h, 1)
        # VTK images start at the bottom row; rasters at the top.
        arr = _vtk.numpy_to_vtk(np.ascontiguousarray(rgba[::-1]).reshape(-1, 4), deep=True,
                                array_type=_vtk.VTK_UNSIGNED_CHAR)
        img.GetPointData().SetScalars(arr)
        self.texture.SetInputData(img)
        self.set_level(level)
        self.actor.SetVisibility(bool(rgba[..., 3].any()))

    def set_mask(self, mask: npt.ArrayLike, heights: npt.ArrayLike | None, level: float) -> None:
        """Show the flooded cells ``mask`` (H, W) bool at ``level`` (the GUI's slider): depth-shaded with
        ``heights`` (H, W), flat blue without."""
        m = np.asarray(mask, bool)
        if heights is None:
            self.set_depth(np.where(m, np.float32(1.0), np.float32(np.nan)), level)
        else:
            self.set_depth(np.where(m, np.float32(level) - np.asarray(heights, np.float32), np.nan), level)

    def set_level(self, level: float) -> None:
        """Move the quad to height ``level`` (the scene's vertical unit)."""
        self.level = float(level)
        x0, y0, x1, y1 = self.bounds
        o = self.scene.origin if self.scene.origin is not None else np.zeros(3)
        corners = np.array([[x0, y0, level], [x1, y0, level], [x1, y1, level], [x0, y1, level]]) - o
        for i, c in enumerate(corners):
            self._points.SetPoint(i, *c)
        self._points.Modified()
        self._poly.Modified()

    def set_visible(self, on: bool) -> None:
        self.actor.SetVisibility(on)

    def close(self) -> None:
        self.scene.renderer.RemoveActor(self.actor)


def _read_level(scene: Any, flood_dir: str | os.PathLike[str], index: int, *, clamp: bool = False
                ) -> tuple[tuple[float, float, float, float], npt.NDArray[np.float32], float]:
    """(bounds in the scene's CRS, depth with NaN where dry, decimated to ≤ 4096 a side, level)."""
    import rasterio
    from rasterio.enums import Resampling

    folder = Path(flood_dir)
    meta = folder / "flood.json"
    if not meta.is_file():
        raise InputError("not a flood result (no flood.json; make one with `citylod flood`)", folder)
    levels = json.loads(meta.read_text(encoding="utf-8"))["levels"]
    if clamp:
        index = min(index, len(levels) - 1)
    if not -len(levels) <= index < len(levels):
        raise InputError(f"flood level index {index} out of range (it has {len(levels)})", folder)
    entry = levels[index]
    with rasterio.open(folder / entry["depth_file"]) as ds:
        step = max(1, -(-max(ds.width, ds.height) // _MAX_TEXELS))
        shape = (-(-ds.height // step), -(-ds.width // step))
        depth = ds.read(1, out_shape=shape, resampling=Resampling.nearest)
        depth = np.where(depth == ds.nodata, np.nan, depth).astype(np.float32)
        b = tuple(ds.bounds)
        if scene.crs is not None and ds.crs is not None:
            import pyproj

            if not pyproj.CRS.from_wkt(ds.crs.to_wkt()).equals(scene.crs):
                from rasterio.warp import transform_bounds

                b = transform_bounds(ds.crs, scene.crs.to_wkt(), *b)
    return (float(b[0]), float(b[1]), float(b[2]), float(b[3])), depth, float(entry["level"])
