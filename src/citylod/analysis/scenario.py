"""The flood scenario as an interactive model: a water level (or a time series of levels) over heights held in
memory, with the flooded extent, its area and volume and the affected buildings of a city store.

The GUI's sliders call :meth:`FloodScenario.set_level` / :meth:`FloodScenario.set_time`; listeners hear
``"level"`` after each change. :meth:`preview` answers first from the 4× decimated copy
(:meth:`FloodModel.coarse`), :meth:`compute` gives the full-resolution result and may run on a worker
thread (it only reads the model). Same definitions as :func:`citylod.analysis.flood.flood_raster`. No Qt.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pyproj

from citylod.analysis.flood import AffectedBuilding, FloodModel, FloodSources, cell_areas
from citylod.analysis.tileset_heights import is_tileset, rasterise_tileset
from citylod.io.raster import RasterInfo, RasterSource

__all__ = ["FloodResult", "FloodScenario"]


@dataclass
class FloodResult:
    """One level: mask (R, C) bool, area m², volume m³ and the affected buildings."""

    level: float
    mask: npt.NDArray[np.bool_]
    area_m2: float
    volume_m3: float
    affected: list[AffectedBuilding] = field(default_factory=list)
    coarse: bool = False


class FloodScenario:
    """A flood over one raster, for interactive use.

    Parameters
    ----------
    raster
        Height raster (read whole: interactive use needs it in memory), or a DSM tileset from ``citylod build
        dsm``: its leaves are rasterised on the source grid into a temporary GeoTIFF first (as ``citylod
        flood`` does; the extent is within the leaves' error ε of the source's, :attr:`tileset_error_m`).
    sources
        Where water enters.
    city
        Optional city store for the affected buildings.
    levels
        The time series of levels (time index i shows ``levels[i]``); default: one level, the lowest height.
    touch_m
        Touch distance of a building (default: the sample spacing), as in ``citylod flood``.
    """

    def __init__(self, raster: str | os.PathLike[str], sources: FloodSources, *,
                 city: str | os.PathLike[str] | None = None, levels: Sequence[float] = (),
                 touch_m: float | None = None, **model_kw: object) -> None:
        self.tileset_error_m: float | None = None
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        if is_tileset(raster):
            self._tmp = tempfile.TemporaryDirectory(prefix="citylod-flood-")
            th = rasterise_tileset(raster, Path(self._tmp.name) / "heights.tif")
            raster, self.tileset_error_m = th.path, th.max_error_m
        src = RasterSource(raster)
        self.info: RasterInfo = src.info
        self.model = FloodModel.from_raster(raster, sources, **model_kw)
        self.areas = cell_areas(self.info)
        self.levels = [float(v) for v in levels] or [self.model.min_height]
        self.level = self.levels[0]
        self.time = 0
        self._listeners: list[Callable[[str], None]] = []
        self.buildings: list[tuple[str, npt.NDArray[np.int64]]] = []
        if city is not None:
            self.buildings = _building_cells(self.info, city, touch_m)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        a, _, c, _, e, f = self.info.transform
        xs = (c, c + a * self.info.width)
        ys = (f, f + e * self.info.height)
        return min(xs), min(ys), max(xs), max(ys)

    @property
    def height_range(self) -> tuple[float, float]:
        h = self.model.heights[self.model.valid]
        return float(h.min()), float(h.max())

    def on_change(self, listener: Callable[[str], None]) -> Callable[[], None]:
        self._listeners.append(listener)
        return lambda: self._listeners.remove(listener) if listener in self._listeners else None

    def set_level(self, level: float) -> None:
        self.level = float(level)
        for cb in list(self._listeners):
            cb("level")

    def set_time(self, index: int) -> None:
        """Show level ``index`` of the series (clamped)."""
        self.time = max(0, min(int(index), len(self.levels) - 1))
        self.set_level(self.levels[self.time])

    def preview(self, level: float | None = None) -> FloodResult:
        """The decimated answer (mask of the coarse grid); area from the coarse cells, no buildings."""
        lv = self.level if level is None else float(level)
        m = self.model.coarse(lv)
        f = self.model.factor
        rows = np.minimum(np.arange(m.shape[0]) * f, self.info.height - 1)
        area = float(m.sum(axis=1) @ self.areas[rows]) * f * f
        return FloodResult(lv, m, area, math.nan, coarse=True)

    def compute(self, level: float | None = None) -> FloodResult:
        """The full-resolution result (safe on a worker thread: reads the model only)."""
        lv = self.level if level is None else float(level)
        m = self.model.mask(lv)
        depth = np.where(m, np.float32(lv) - self.model.heights, np.float32(0.0))
        area = float(m.sum(axis=1) @ self.areas)
        volume = float(depth.sum(axis=1, dtype=np.float64) @ self.areas)
        affected = []
        flat_m, flat_d = m.reshape(-1), depth.reshape(-1)
        for oid, cells in self.buildings:
            wet = cells[flat_m[cells]]
            if len(wet):
                d = flat_d[wet]
                affected.append(AffectedBuilding(oid, lv, float(d.max()), float(d.mean()), len(wet)))
        return FloodResult(lv, m, area, volume, affected)


def _building_cells(info: RasterInfo, city: str | os.PathLike[str], touch_m: float | None
                    ) -> list[tuple[str, npt.NDArray[np.int64]]]:
    """Flat indices of the raster cells each building's grown footprint touches (as affected_buildings)."""
    from affine import Affine
    from rasterio.features import rasterize
    from rasterio.warp import transform_bounds

    from citylod.analysis.polygons import EditPolygon, PolygonLayer
    from citylod.semantics.store import CityStore

    r_crs = pyproj.CRS.from_wkt(info.crs_wkt)
    a, _, c, _, e, f = info.transform
    t = Affine(a, 0.0, c, 0.0, e, f)
    if touch_m is None:
        touch_m = info.spacing_m
    with CityStore.open(city) as store:
        s_crs = store.crs or r_crs
        x0, y0 = c, f + e * info.height
        b = (min(x0, c + a * info.width), min(y0, f), max(x0, c + a * info.width), max(y0, f))
        sb = transform_bounds(r_crs, s_crs, *b) if not s_crs.equals(r_crs) else b
        feet = store.footprints(sb)
    grown = PolygonLayer(tuple(EditPolygon(g.buffer(touch_m), "source") for _, g in feet), s_crs).to_crs(r_crs)
    out = []
    for (oid, _), p in zip(feet, grown.polygons, strict=True):
        gx0, gy0, gx1, gy1 = p.geometry.bounds
        c0 = max(int(math.floor((gx0 - c) / a)), 0)
        c1 = min(int(math.ceil((gx1 - c) / a)), info.width)
        r0 = max(int(math.floor((gy1 - f) / e)), 0)
        r1 = min(int(math.ceil((gy0 - f) / e)), info.height)
        if r1 <= r0 or c1 <= c0:
            continue
        win = rasterize([p.geometry], out_shape=(r1 - r0, c1 - c0), transform=t @ Affine.translation(c0, r0),
                        all_touched=True, dtype=np.uint8)
        rr, cc = np.nonzero(win)
        out.append((oid, ((rr + r0) * info.width + cc + c0).astype(np.int64)))
    return out
