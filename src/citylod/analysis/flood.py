"""Flood scenarios on a height raster: what floods at a water level, how deep, and which buildings it hits.

A cell is flooded at level L when its height is below L **and** it is connected to a water source (seed
points, source polygons such as a river or the sea, or the raster's edge) through cells that are all below
L (Kehl, Tutenel, Eisemann: flood visualisation; the "bathtub with connectivity" model). Enclosed
depressions stay dry unless ``depressions=True`` (then every cell below L floods, as for rain). No-data is
neither flooded nor passable. Connectivity is 4-neighbour by default (water does not pass between two
diagonal dyke cells), 8-neighbour on request.

Connected components come from ``scipy.ndimage.label`` (C, one pass); the raster is processed in strips of
rows so memory depends on the strip, not the raster: pass 1 labels each strip and records which labels hold
a source and which labels of neighbouring strips touch across the seam; the seams are merged as a graph
(``scipy.sparse.csgraph.connected_components``); pass 2 writes each strip's depth. When the raster fits in
the strip budget the strips of pass 1 are kept and pass 2 reads nothing again.

Outputs (:func:`flood_raster`): a depth GeoTIFF per level (float32, dry and no-data = -9999, which QGIS
shows transparent), the flooded area (m²) and volume (m³) per level (cell areas on the ellipsoid for rasters
in degrees), and, with a city store, the affected buildings (:func:`affected_buildings`) as a GeoPackage
layer and a CSV. :class:`FloodModel` answers a new level interactively from heights held in memory.
No VTK, no Qt.
"""

from __future__ import annotations

import csv
import json
import math
import os
import shutil
import sqlite3
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pyproj
import shapely
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from citylod.analysis.polygons import EditPolygon, PolygonLayer
from citylod.core.errors import EmptyInputError, InputError
from citylod.core.fileio import atomic_write, publish_dir
from citylod.io.gpkg import add_feature_table, encode_geometry, fill_rtree, init_geopackage, register_srs
from citylod.io.raster import RasterInfo, RasterSource

__all__ = [
    "DEPTH_NODATA",
    "AffectedBuilding",
    "FloodModel",
    "FloodReport",
    "FloodSources",
    "LevelResult",
    "affected_buildings",
    "cell_areas",
    "flood_mask",
    "flood_raster",
    "flood_tileset",
]

#: Value of dry and no-data cells in the depth GeoTIFFs.
DEPTH_NODATA = -9999.0
_MARKER = "flood.json"
_STRIP_CELLS = 1 << 22  # cells per strip: 32 MB of float64 heights plus masks and labels
_KEEP_CELLS = 1 << 25  # keep pass 1's strips for pass 2 up to this many cells × levels


@dataclass(frozen=True)
class FloodSources:
    """Where water enters: seed points (x, y in the raster's CRS), source polygons, the raster's edge."""

    seeds_xy: tuple[tuple[float, float], ...] = ()
    polygons: PolygonLayer | None = None
    edge: bool = False

    def __bool__(self) -> bool:
        return bool(self.seeds_xy) or bool(self.polygons and len(self.polygons)) or self.edge


@dataclass(frozen=True)
class LevelResult:
    """One water level: flooded cells, area (m²), volume (m³), deepest water (m), its depth GeoTIFF."""

    level: float
    cells: int
    area_m2: float
    volume_m3: float
    max_depth_m: float
    depth_file: str = ""


@dataclass(frozen=True)
class AffectedBuilding:
    """A building whose footprint (grown by the touch distance) meets flooded cells at ``level``."""

    object_id: str
    level: float
    max_depth_m: float
    mean_depth_m: float
    flooded_cells: int


@dataclass
class FloodReport:
    """What :func:`flood_raster` did."""

    out_dir: Path
    levels: list[LevelResult]
    affected: list[AffectedBuilding] = field(default_factory=list)
    buildings_checked: int = 0
    seconds: float = 0.0
    warnings: list[str] = field(default_factory=list)
    heights: str = ""  # where the heights came from, when not the raster itself (a tileset)

    def summary(self) -> str:
        lines = [f"{self.out_dir}: {len(self.levels)} level(s) in {self.seconds:.2f} s"]
        for r in self.levels:
            n = sum(1 for a in self.affected if a.level == r.level)
            b = f", {n} of {self.buildings_checked} buildings affected" if self.buildings_checked else ""
            lines.append(f"  level {r.level:g} m: {r.area_m2:,.0f} m² flooded, {r.volume_m3:,.0f} m³, "
                         f"max depth {r.max_depth_m:.2f} m{b}")
        lines += [f"  heights: {self.heights}"] if self.heights else []
        lines += [f"  warning: {w}" for w in self.warnings]
        return "\n".join(lines)


# -- geometry of the grid -----------------------------------------------------------------------------
def cell_areas(info: RasterInfo) -> npt.NDArray[np.float64]:
    """Area in m² of one cell of each row, (height,) float64.

    Projected rasters: |a·e| times the square of the CRS unit. Rasters in degrees: the exact area of a cell
    bounded by two meridians and two parallels on the CRS's ellipsoid, from the area of the zone between
    the equator and latitude φ, S(φ) = π b² (sin φ / (1 − e² sin² φ) + atanh(e sin φ) / e), per 360° of
    longitude (the authalic-latitude formula; Snyder 1987, eq. 3-12).
    """
    a, _, _, _, e_, f = info.transform
    if not info.geographic:
        crs = info.crs
        unit = crs.axis_info[0].unit_conversion_factor if crs.axis_info else 1.0
        return np.full(info.height, abs(a * e_) * unit * unit)
    ell = info.crs.ellipsoid
    major = ell.semi_major_metre if ell else 6378137.0
    inv_f = ell.inverse_flattening if ell and ell.inverse_flattening else 298.257223563
    ecc2 = (2.0 - 1.0 / inv_f) / inv_f
    ecc = math.sqrt(ecc2)
    minor2 = major * major * (1.0 - ecc2)
    edges = np.radians(f + e_ * np.arange(info.height + 1, dtype=np.float64))
    s = np.sin(edges)
    zone = math.pi * minor2 * (s / (1.0 - ecc2 * s * s) + np.arctanh(ecc * s) / ecc)
    return np.abs(np.diff(zone)) * abs(a) / 360.0


def _world_to_cell(info: RasterInfo, x: float, y: float) -> tuple[int, int]:
    a, _, c, _, e_, f = info.transform
    return math.floor((y - f) / e_), math.floor((x - c) / a)


def _structure(eight: bool) -> np.ndarray:
    return np.ones((3, 3), bool) if eight else ndimage.generate_binary_structure(2, 1)


# -- the in-memory core ---------------------------------------------------------------------------------
def flood_mask(heights: npt.ArrayLike, valid: npt.ArrayLike, source: npt.ArrayLike, level: float, *,
               eight: bool = False, depressions: bool = False) -> npt.NDArray[np.bool_]:
    """Cells flooded at ``level``: below it, valid, and connected to a ``source`` cell through such cells.

    ``heights`` (R, C) float, ``valid`` and ``source`` (R, C) bool. With ``depressions`` every valid cell
    below the level floods, connected or not.

    Examples
    --------
    >>> import numpy as np
    >>> h = np.array([[0., 0., 5., 0.], [0., 0., 5., 0.]])   # a dyke of height 5 in column 2
    >>> src = np.zeros(h.shape, bool); src[0, 0] = True
    >>> flood_mask(h, np.ones(h.shape, bool), src, 1.0).astype(int)
    array([[1, 1, 0, 0],
           [1, 1, 0, 0]])
    """
    h = np.asarray(heights)
    below = np.asarray(valid, bool) & (h < level)
    if depressions:
        return below
    lab, n = ndimage.label(below, _structure(eight))
    keep = np.zeros(n + 1, bool)
    keep[lab[np.asarray(source, bool) & below]] = True
    keep[0] = False
    return keep[lab]


class FloodModel:
    """Heights in memory for interactive use (the GUI's level and time sliders): a new level costs one
    labelling of the raster (:func:`flood_mask`), and :meth:`coarse` answers first from a 4× decimated
    copy (block minimum, so a coarse cell is wet when its lowest sample could be; thin dykes may leak in the
    preview, never in :meth:`mask`).

    Parameters
    ----------
    heights, valid
        (R, C) float and bool.
    source
        (R, C) bool source cells.
    """

    def __init__(self, heights: npt.ArrayLike, valid: npt.ArrayLike, source: npt.ArrayLike, *,
                 eight: bool = False, depressions: bool = False, factor: int = 4) -> None:
        self.heights = np.asarray(heights, dtype=np.float32)
        self.valid = np.asarray(valid, bool)
        self.source = np.asarray(source, bool) & self.valid
        self.eight = eight
        self.depressions = depressions
        self.factor = factor
        f = factor
        r, c = self.heights.shape
        pr, pc = -r % f, -c % f
        hp = np.pad(np.where(self.valid, self.heights, np.inf), ((0, pr), (0, pc)), constant_values=np.inf)
        sp = np.pad(self.source, ((0, pr), (0, pc)))
        blocks = hp.reshape(hp.shape[0] // f, f, hp.shape[1] // f, f)
        self._coarse_h = blocks.min(axis=(1, 3))
        self._coarse_src = sp.reshape(blocks.shape).any(axis=(1, 3))
        self.min_height = float(self.heights[self.valid].min()) if self.valid.any() else math.nan

    @classmethod
    def from_raster(cls, raster: str | os.PathLike[str], sources: FloodSources, **kw: object) -> FloodModel:
        """Read a whole raster (it must fit in memory) and rasterise its sources."""
        src = RasterSource(raster)
        h, v = src.read_window(0, 0, src.info.height, src.info.width)
        s = _source_mask(src, sources, 0, src.info.height)
        return cls(h, v, s, **kw)  # type: ignore[arg-type]

    def mask(self, level: float) -> npt.NDArray[np.bool_]:
        """Full-resolution flooded cells at ``level``, (R, C) bool."""
        return flood_mask(self.heights, self.valid, self.source, level, eight=self.eight,
                          depressions=self.depressions)

    def coarse(self, level: float) -> npt.NDArray[np.bool_]:
        """Flooded cells of the decimated copy, (ceil(R/f), ceil(C/f)) bool: the first answer while
        :meth:`mask` computes."""
        valid = np.isfinite(self._coarse_h)
        return flood_mask(self._coarse_h, valid, self._coarse_src, level, eight=self.eight,
                          depressions=self.depressions)

    def depth(self, level: float, mask: npt.NDArray[np.bool_] | None = None) -> npt.NDArray[np.float32]:
        """Water depth (R, C) float32, 0 where dry."""
        m = self.mask(level) if mask is None else mask
        return np.where(m, np.float32(level) - self.heights, np.float32(0.0))


# -- sources ------------------------------------------------------------------------------------------
def _check_seeds(src: RasterSource, sources: FloodSources) -> list[tuple[int, int]]:
    cells = []
    info = src.info
    for x, y in sources.seeds_xy:
        r, c = _world_to_cell(info, x, y)
        if not (0 <= r < info.height and 0 <= c < info.width):
            raise InputError(f"seed ({x:g}, {y:g}) lies outside the raster (its CRS: {info.crs.name})", src.path)
        _, ok = src.read_window(r, c, 1, 1)
        if not ok[0, 0]:
            raise InputError(f"seed ({x:g}, {y:g}) lies in no-data", src.path)
        cells.append((r, c))
    return cells


def _source_mask(src: RasterSource, sources: FloodSources, row0: int, row1: int,
                 seeds: Sequence[tuple[int, int]] | None = None) -> npt.NDArray[np.bool_]:
    """Source cells of rows row0..row1-1, (row1-row0, width) bool."""
    info = src.info
    out = np.zeros((row1 - row0, info.width), bool)
    if sources.edge:
        out[:, 0] = out[:, -1] = True
        if row0 == 0:
            out[0] = True
        if row1 == info.height:
            out[-1] = True
    for r, c in seeds if seeds is not None else _check_seeds(src, sources):
        if row0 <= r < row1:
            out[r - row0, c] = True
    if sources.polygons is not None and len(sources.polygons):
        from affine import Affine
        from rasterio.features import rasterize

        a, b, c0, d, e_, f = info.transform
        t = Affine(a, b, c0 + b * row0, d, e_, f + e_ * row0)
        layer = sources.polygons.to_crs(info.crs)
        out |= rasterize([p.geometry for p in layer.polygons], out_shape=out.shape, transform=t,
                         all_touched=True, dtype=np.uint8).astype(bool)
    return out


# -- the windowed raster pass -------------------------------------------------------------------------
@dataclass
class _Strip:
    row0: int
    row1: int
    heights: np.ndarray | None = None
    valid: np.ndarray | None = None
    labels: list[np.ndarray] | None = None


def _label_strip(h: np.ndarray, v: np.ndarray, levels: Sequence[float], struct: np.ndarray
                 ) -> tuple[list[np.ndarray], list[int]]:
    labs, counts = [], []
    for level in levels:
        lab, n = ndimage.label(v & (h < level), struct)
        labs.append(lab)
        counts.append(n)
    return labs, counts


def _seam_pairs(upper: np.ndarray, lower: np.ndarray, eight: bool) -> np.ndarray:
    """(K, 2) global label pairs that touch across a strip seam (last row above, first row below)."""
    pairs = [np.column_stack([upper, lower])]
    if eight:
        pairs += [np.column_stack([upper[1:], lower[:-1]]), np.column_stack([upper[:-1], lower[1:]])]
    p = np.concatenate(pairs)
    return p[(p[:, 0] > 0) & (p[:, 1] > 0)]


def _wet_labels(n_labels: int, pairs: list[np.ndarray], wet: list[np.ndarray]) -> np.ndarray:
    """Lookup table label -> flooded, after merging the labels joined across seams."""
    edges = np.concatenate(pairs) if pairs else np.zeros((0, 2), np.int64)
    graph = coo_matrix((np.ones(len(edges), np.int8), (edges[:, 0], edges[:, 1])), shape=(n_labels + 1,) * 2)
    _, comp = connected_components(graph, directed=False)
    src = np.concatenate(wet) if wet else np.zeros(0, np.int64)
    wet_comp = np.zeros(comp.max() + 1, bool)
    wet_comp[comp[src]] = True
    keep = wet_comp[comp]
    keep[0] = False
    return keep


def _depth_profile(info: RasterInfo) -> dict[str, object]:
    from affine import Affine

    return {"driver": "GTiff", "width": info.width, "height": info.height, "count": 1, "dtype": "float32",
            "crs": info.crs_wkt, "transform": Affine(*info.transform), "nodata": DEPTH_NODATA,
            "tiled": True, "blockxsize": 256, "blockysize": 256}


def _open_depth(path: Path, info: RasterInfo):  # type: ignore[no-untyped-def]
    """A depth GeoTIFF opened for writing: ZSTD level 1 (a 4097² depth raster writes ≈5x faster than with
    DEFLATE level 1; GDAL ≥ 2.3 and QGIS read it), DEFLATE where this GDAL lacks ZSTD."""
    import rasterio
    from rasterio.errors import RasterioError

    try:
        return rasterio.open(path, "w", **_depth_profile(info), compress="zstd", zstd_level=1)
    except RasterioError:
        return rasterio.open(path, "w", **_depth_profile(info), compress="deflate")


def flood_raster(raster: str | os.PathLike[str], levels: Sequence[float], out_dir: str | os.PathLike[str], *,
                 sources: FloodSources, depressions: bool = False, eight: bool = False,
                 city: str | os.PathLike[str] | None = None, touch_m: float | None = None,
                 strip_rows: int | None = None, progress: bool = False,
                 note: dict[str, object] | None = None) -> FloodReport:
    """Flood a height raster at one or more water levels and write the results to ``out_dir``.

    Parameters
    ----------
    raster
        DSM or DTM GeoTIFF (any GDAL raster; projected or in degrees).
    levels
        Water levels in the raster's height unit (a series: one result per level, in order).
    out_dir
        Output folder: ``depth_NNN.tif`` per level, ``levels.csv``, ``flood.json`` and, with ``city``,
        ``affected_buildings.gpkg`` and ``.csv``. Built as ``OUT.partial`` and renamed when complete.
    sources
        Where water enters; required unless ``depressions``.
    depressions
        Flood every cell below the level, connected to a source or not.
    eight
        8-neighbour connectivity (default 4: water does not pass between diagonal cells).
    city
        A city store (``citylod build city``) for the affected buildings.
    touch_m
        A building is affected when a flooded cell lies within this distance of its footprint (default:
        the raster's sample spacing, which absorbs the half-cell misregistration of walls and footprints).
    strip_rows
        Rows per window (default: about 4 M cells per window).
    note
        Further entries for ``flood.json`` (where the heights came from, see :func:`flood_tileset`).

    Raises
    ------
    InputError
        No source, a seed outside the raster or in no-data, a level below the raster's lowest height, a
        source that covers no valid cell. Nothing is written then.
    """
    t0 = time.perf_counter()
    src = RasterSource(raster)
    info = src.info
    levels = [float(v) for v in levels]
    if not levels:
        raise InputError("give at least one water level", src.path)
    bad = [lv for lv in levels if not math.isfinite(lv)]
    if bad:
        raise InputError(f"water level {bad[0]} is not a number", src.path)
    if not sources and not depressions:
        raise InputError("give a water source (a seed, a source polygon or the edge) or flag depressions",
                         src.path)
    seeds = _check_seeds(src, sources)
    struct = _structure(eight)
    rows = strip_rows or max(16, _STRIP_CELLS // max(info.width, 1))
    bounds = list(range(0, info.height, rows))
    keep_strips = info.width * info.height * len(levels) <= _KEEP_CELLS
    strips: list[_Strip] = []
    offsets = [0] * len(levels)
    pairs: list[list[np.ndarray]] = [[] for _ in levels]
    wet: list[list[np.ndarray]] = [[] for _ in levels]
    prev_last: list[np.ndarray] | None = None
    zmin = math.inf
    any_source = False
    bar = _bar(progress, 2 * len(bounds), "flood")
    for row0 in bounds:
        row1 = min(row0 + rows, info.height)
        h, v = src.read_window(row0, 0, row1 - row0, info.width)
        if v.any():
            zmin = min(zmin, float(h[v].min()))
        s = _source_mask(src, sources, row0, row1, seeds) & v
        any_source |= bool(s.any())
        labs, counts = _label_strip(h, v, levels, struct)
        for k, lab in enumerate(labs):
            lab[lab > 0] += offsets[k]
            offsets[k] += counts[k]
            wet[k].append(np.unique(lab[s & (lab > 0)]))
            if prev_last is not None:
                pairs[k].append(_seam_pairs(prev_last[k], lab[0], eight))
        prev_last = [lab[-1].copy() for lab in labs]
        strips.append(_Strip(row0, row1, h, v, labs) if keep_strips else _Strip(row0, row1))
        bar.update(1)
    if not math.isfinite(zmin):
        bar.close()
        raise EmptyInputError("raster holds no valid samples (all no-data)", src.path)
    low = [lv for lv in levels if lv < zmin]
    if low:
        bar.close()
        raise InputError(f"water level {low[0]:g} is below the raster's lowest height {zmin:g}: nothing can "
                         "flood", src.path)
    if not depressions and not any_source:
        bar.close()
        raise InputError("the water sources cover no valid cell of the raster", src.path)
    keep = [_wet_labels(offsets[k], pairs[k], wet[k]) if not depressions
            else np.arange(offsets[k] + 1) > 0 for k in range(len(levels))]

    out = Path(out_dir)
    partial = out.with_name(out.name + ".partial")
    shutil.rmtree(partial, ignore_errors=True)
    partial.mkdir(parents=True)
    try:
        results = _write_depths(src, strips, levels, keep, struct, partial, bar)
        bar.close()
        report = FloodReport(out, results)
        if any(r.cells == 0 for r in results):
            report.warnings.append("some levels flood nothing (every source lies at or above them)")
        if city is not None:
            affected, checked = affected_buildings(
                [(r.level, partial / r.depth_file) for r in results], city, touch_m=touch_m)
            _write_affected(affected, city, partial)
            report.affected, report.buildings_checked = affected, checked
        report.seconds = time.perf_counter() - t0
        _write_summary(report, info, sources, depressions, eight, partial, note)
        publish_dir(partial, out, marker=_MARKER)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    return report


def flood_tileset(tileset: str | os.PathLike[str], levels: Sequence[float], out_dir: str | os.PathLike[str], *,
                  sources: FloodSources, strip_rows: int | None = None, **kw: object) -> FloodReport:
    """Flood a DSM tileset built by ``citylod build dsm``: its leaves are rasterised on the source grid
    (:func:`citylod.analysis.tileset_heights.rasterise_tileset`, in strips) into a temporary GeoTIFF beside
    ``out_dir``, which :func:`flood_raster` then floods (same arguments, same outputs).

    The result differs from flooding the source raster by no more than the leaves' certified error ε:
    flood(source, L − ε) ⊆ flood(tileset, L) ⊆ flood(source, L + ε), depths within ε (the argument is in
    :mod:`citylod.analysis.tileset_heights`). ``flood.json`` records the tileset and ε; the summary says it.
    Errors name the tileset, not the temporary raster.
    """
    import tempfile

    from citylod.analysis.tileset_heights import rasterise_tileset

    out = Path(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f".{out.name}.heights.", dir=out.parent) as tmp:
        th = rasterise_tileset(tileset, Path(tmp) / "heights.tif", strip_rows=strip_rows)
        try:
            report = flood_raster(th.path, levels, out, sources=sources, strip_rows=strip_rows,
                                  note={"raster": "", "tileset": str(th.tileset), "tileset_leaves": th.leaves,
                                        "tileset_error_m": th.max_error_m}, **kw)  # type: ignore[arg-type]
        except InputError as exc:
            raise type(exc)(exc.message, th.tileset) from None
    report.heights = (f"the tileset's {th.leaves} leaves, within {th.max_error_m:.3g} m of its source raster "
                      "(the extent lies between the source's at level ± that)")
    return report


def _bar(progress: bool, total: int, desc: str):  # type: ignore[no-untyped-def]
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="strip", disable=not progress, leave=False)


def _write_depths(src: RasterSource, strips: list[_Strip], levels: list[float], keep: list[np.ndarray],
                  struct: np.ndarray, folder: Path, bar) -> list[LevelResult]:  # type: ignore[no-untyped-def]
    from rasterio.windows import Window

    info = src.info
    areas = cell_areas(info)
    names = [f"depth_{k:03d}.tif" for k in range(len(levels))]
    dsts = [_open_depth(folder / n, info) for n in names]
    cells = [0] * len(levels)
    area = [0.0] * len(levels)
    volume = [0.0] * len(levels)
    deepest = [0.0] * len(levels)
    offsets = [0] * len(levels)
    try:
        for st in strips:
            if st.labels is None:
                h, v = src.read_window(st.row0, 0, st.row1 - st.row0, info.width)
                labs, counts = _label_strip(h, v, levels, struct)
                for k, lab in enumerate(labs):
                    lab[lab > 0] += offsets[k]
                    offsets[k] += counts[k]
            else:
                h, labs = st.heights, st.labels
            row_area = areas[st.row0:st.row1]
            for k, level in enumerate(levels):
                dry = ~keep[k][labs[k]]
                depth = np.subtract(np.float32(level), h, dtype=np.float32)
                np.copyto(depth, np.float32(0.0), where=dry)
                per_row = (h.shape[1] - dry.sum(axis=1)).astype(np.float64)
                if per_row.any():
                    cells[k] += int(per_row.sum())
                    area[k] += float(per_row @ row_area)
                    volume[k] += float(depth.sum(axis=1, dtype=np.float64) @ row_area)
                    deepest[k] = max(deepest[k], float(depth.max()))
                np.copyto(depth, np.float32(DEPTH_NODATA), where=dry)
                dsts[k].write(depth, 1, window=Window(0, st.row0, info.width, st.row1 - st.row0))
            st.heights = st.valid = None
            st.labels = None
            bar.update(1)
    finally:
        for d in dsts:
            d.close()
    return [LevelResult(lv, cells[k], area[k], volume[k], deepest[k], names[k]) for k, lv in enumerate(levels)]


# -- affected buildings ---------------------------------------------------------------------------------
def affected_buildings(depths: Sequence[tuple[float, str | os.PathLike[str]]], city: str | os.PathLike[str], *,
                       touch_m: float | None = None) -> tuple[list[AffectedBuilding], int]:
    """Buildings of a city store that the flood reaches, per level, from depth GeoTIFFs.

    A building is affected when a flooded cell (depth > 0, not no-data) lies within ``touch_m`` of its
    footprint: the footprint grown by ``touch_m`` in the store's metric CRS, carried into the raster's CRS,
    then every cell whose square it meets (GDAL's all-touched rasterisation). Max and mean depth are over
    those cells. Returns (affected rows in level then store order, number of buildings checked).
    """
    import rasterio
    from affine import Affine
    from rasterio.features import rasterize
    from rasterio.warp import transform_bounds
    from rasterio.windows import Window, from_bounds

    from citylod.semantics.store import CityStore

    if not depths:
        return [], 0
    with rasterio.open(depths[0][1]) as ds:
        r_crs = pyproj.CRS.from_wkt(ds.crs.to_wkt())
        r_bounds, r_transform, shape = tuple(ds.bounds), ds.transform, (ds.height, ds.width)
    spacing = 0.5 * (abs(r_transform.a) + abs(r_transform.e))
    with CityStore.open(city) as store:
        s_crs = store.crs or r_crs
        if touch_m is None:
            touch_m = spacing * (111_320.0 if r_crs.is_geographic else 1.0)
        sb = transform_bounds(r_crs, s_crs, *r_bounds) if not s_crs.equals(r_crs) else r_bounds
        feet = store.footprints(sb)
    grown = PolygonLayer(tuple(EditPolygon(g.buffer(touch_m), "source") for _, g in feet), s_crs).to_crs(r_crs)
    out: list[AffectedBuilding] = []
    for level, path in depths:
        with rasterio.open(path) as ds:
            for (oid, _), poly in zip(feet, grown.polygons, strict=True):
                win = from_bounds(*poly.geometry.bounds, transform=r_transform)
                r0, c0 = max(int(math.floor(win.row_off)), 0), max(int(math.floor(win.col_off)), 0)
                r1 = min(int(math.ceil(win.row_off + win.height)), shape[0])
                c1 = min(int(math.ceil(win.col_off + win.width)), shape[1])
                if r1 <= r0 or c1 <= c0:
                    continue
                w = Window(c0, r0, c1 - c0, r1 - r0)
                depth = ds.read(1, window=w)
                inside = rasterize([poly.geometry], out_shape=depth.shape, transform=r_transform @ Affine.translation(c0, r0),
                                   all_touched=True, dtype=np.uint8).astype(bool)
                d = depth[inside & (depth != DEPTH_NODATA) & (depth > 0)]
                if d.size:
                    out.append(AffectedBuilding(oid, float(level), float(d.max()), float(d.mean()), int(d.size)))
    return out, len(feet)


def _write_affected(rows: list[AffectedBuilding], city: str | os.PathLike[str], folder: Path) -> None:
    """``affected_buildings.gpkg`` (layer ``affected_buildings``: footprints in the store's CRS) and ``.csv``."""
    from citylod.semantics.store import CityStore

    with CityStore.open(city) as store:
        crs = store.crs
        feet = dict(store.footprints())
    fields = ["object_id", "level", "max_depth_m", "mean_depth_m", "flooded_cells"]

    def write_csv(tmp: Path) -> None:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            w = csv.DictWriter(fh, fieldnames=fields)
            w.writeheader()
            for r in rows:
                w.writerow(asdict(r))

    def write_gpkg(tmp: Path) -> None:
        conn = sqlite3.connect(tmp)
        try:
            init_geopackage(conn)
            srs = register_srs(conn, crs)
            add_feature_table(conn, "affected_buildings", [("object_id", "TEXT NOT NULL"), ("level", "REAL"),
                                                           ("max_depth_m", "REAL"), ("mean_depth_m", "REAL"),
                                                           ("flooded_cells", "INTEGER")],
                              "footprint", "MULTIPOLYGON", srs, description="buildings the flood reaches")
            bounds = []
            for r in rows:
                g = feet[r.object_id]
                g = g if g.geom_type == "MultiPolygon" else shapely.MultiPolygon(shapely.get_parts(g))
                conn.execute("INSERT INTO affected_buildings (object_id, level, max_depth_m, mean_depth_m, "
                             "flooded_cells, footprint) VALUES (?, ?, ?, ?, ?, ?)",
                             (r.object_id, r.level, r.max_depth_m, r.mean_depth_m, r.flooded_cells,
                              encode_geometry(g, srs)))
                bounds.append(g.bounds)
            fill_rtree(conn, "affected_buildings", "footprint", range(1, len(rows) + 1),
                       np.asarray(bounds, dtype=np.float64).reshape(-1, 4))
            conn.commit()
        finally:
            conn.close()

    atomic_write(folder / "affected_buildings.csv", write_csv, suffix=".csv")
    atomic_write(folder / "affected_buildings.gpkg", write_gpkg, suffix=".gpkg")


def _write_summary(report: FloodReport, info: RasterInfo, sources: FloodSources, depressions: bool,
                   eight: bool, folder: Path, note: dict[str, object] | None = None) -> None:
    def write_csv(tmp: Path) -> None:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            w = csv.DictWriter(fh, fieldnames=list(asdict(report.levels[0])))
            w.writeheader()
            for r in report.levels:
                w.writerow(asdict(r))

    atomic_write(folder / "levels.csv", write_csv, suffix=".csv")
    doc = {
        "raster": info.path, "crs": info.crs_wkt, "levels": [asdict(r) for r in report.levels],
        "sources": {"seeds_xy": [list(s) for s in sources.seeds_xy], "edge": sources.edge,
                    "polygons": sources.polygons.source if sources.polygons else ""},
        "depressions": depressions, "connectivity": 8 if eight else 4,
        "affected_buildings": len(report.affected), "buildings_checked": report.buildings_checked,
        "seconds": report.seconds, **(note or {}),
    }
    atomic_write(folder / _MARKER, lambda t: t.write_text(json.dumps(doc, indent=1), encoding="utf-8"))
