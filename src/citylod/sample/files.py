"""``citylod sample``: write a reproducible synthetic city for demos, tests and benchmarks.

The scene is the analytic :class:`~citylod.sample.city.SampleCity` (see :func:`make_city`); this module
samples it into the files every other part of citylod reads:

``dsm.tif``
    float32 GeoTIFF (EPSG:32632, 1 m pixels by default, 256×256 deflate tiles, nodata -9999 on a lake and
    an irregular gap), the surface sampled at pixel centres.
``ortho.tif``
    RGB uint8 GeoTIFF on the same grid: fields, grass, roads, roofs, trees, water, hill shading and sun
    shadows.
``points.laz``
    LAS 1.4 point format 7 (RGB from the orthophoto), ~2 points/m², jittered, 2 cm noise, ASPRS classes
    2 ground, 5 high vegetation, 6 building, 9 water, 17 bridge deck; second returns under trees.
``city.gml``
    CityGML 2.0 buildings, LoD1 and LoD2 (see :mod:`citylod.sample.gml`).
``camera.json``, ``path.json``
    An overview camera and a flight (approach, low pass along a street, orbit).
``sample.json``
    Metadata: CRS, grid, seed, counts and a building list.

Every file is written under a temporary name and renamed when complete. The same size and seed give
byte-identical files.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from citylod.core.camera import Camera
from citylod.core.errors import CitylodError, InputError
from citylod.core.fileio import atomic_write
from citylod.sample.city import (
    CRS,
    KIND_BRIDGE,
    KIND_BUILDING,
    KIND_CHIMNEY,
    KIND_TREE,
    Building,
    SampleCity,
    make_city,
)

__all__ = ["NODATA", "SampleCity", "SampleInfo", "make_city", "make_sample"]

F64 = npt.NDArray[np.float64]
U8 = npt.NDArray[np.uint8]

NODATA = -9999.0
_BAND_ROWS = 256  # rows of the grid evaluated and written at a time: one tile row of the GeoTIFFs
_SUN_AZIMUTH_DEG, _SUN_ALTITUDE_DEG = 150.0, 50.0  # a late-morning sun from the south-south-east


@dataclass(frozen=True)
class SampleInfo:
    """What :func:`make_sample` wrote.

    Attributes
    ----------
    files
        Name (``dsm``, ``ortho``, ``points``, ``city``, ``camera``, ``path``, ``metadata``) to path.
    city
        The analytic ground truth the files were sampled from.
    crs
        ``"EPSG:32632"``.
    bounds
        (xmin, ymin, xmax, ymax) of the grid in the CRS.
    """

    files: dict[str, Path]
    city: SampleCity
    crs: str
    bounds: tuple[float, float, float, float]


def make_sample(out_dir: str | os.PathLike[str], size: int = 513, seed: int = 7, *, spacing: float = 1.0,
                density: float = 2.0) -> SampleInfo:
    """Write the sample city into ``out_dir`` (created if missing; existing sample files are replaced).

    Parameters
    ----------
    out_dir
        Output folder.
    size
        DSM samples per side (at least 33).
    seed
        Seed of the scene and of all sampling noise.
    spacing
        DSM sample spacing in metres.
    density
        Mean LiDAR first returns per m².

    Returns
    -------
    SampleInfo
    """
    out = Path(out_dir)
    if size > 8193:
        raise CitylodError(f"sample size {size} is too large (at most 8193 samples per side)")
    if not density > 0.0:
        raise CitylodError(f"point density must be positive, got {density}")
    city = make_city(size, seed, spacing=spacing)  # validates the arguments before anything is created
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create the output folder ({exc.strerror})", out) from exc
    grid = _Grid.evaluate(city)

    files = {
        "dsm": out / "dsm.tif", "ortho": out / "ortho.tif", "points": out / "points.laz",
        "city": out / "city.gml", "camera": out / "camera.json", "path": out / "path.json",
        "metadata": out / "sample.json",
    }
    ortho = _ortho(city, grid)
    _atomic(files["dsm"], lambda p: _write_dsm(city, grid, p))
    _atomic(files["ortho"], lambda p: _write_ortho(city, ortho, p))
    counts: dict[str, int] = {}
    _atomic(files["points"], lambda p: counts.update(_write_points(city, ortho, density, p)))

    from citylod.sample.gml import write_citygml

    _atomic(files["city"], lambda p: write_citygml(city, p))
    overview, flight = _cameras(city, grid)
    _atomic(files["camera"], lambda p: p.write_text(json.dumps(overview.to_dict(), indent=2) + "\n"))
    _atomic(files["path"], lambda p: p.write_text(
        json.dumps({"cameras": [c.to_dict() for c in flight]}, indent=1) + "\n"))
    meta = _metadata(city, files, counts, density)
    _atomic(files["metadata"], lambda p: p.write_text(json.dumps(meta, indent=1, ensure_ascii=False) + "\n"))
    return SampleInfo(files=files, city=city, crs=CRS, bounds=city.bounds)


def _atomic(path: Path, write: Callable[[Path], object]) -> None:
    """Run ``write`` on a temporary name beside ``path`` and rename it into place when it succeeds."""
    try:
        atomic_write(path, write, suffix=".part")
    except OSError as exc:
        raise InputError(f"cannot write ({exc.strerror or exc})", path) from exc


@dataclass(frozen=True)
class _Grid:
    """The scene evaluated at every pixel centre, row 0 in the north: (size, size) arrays."""

    z: F64
    kind: npt.NDArray[np.int8]
    ident: npt.NDArray[np.int64]
    nodata: npt.NDArray[np.bool_]

    @staticmethod
    def evaluate(city: SampleCity) -> _Grid:
        x, y = city.pixel_centers()
        z, kind, ident = city.surface_with_kind(x, y)
        return _Grid(z, kind, ident, city.nodata_mask(x, y))


def _profile(city: SampleCity, count: int, dtype: str) -> dict[str, object]:
    from affine import Affine
    from rasterio.crs import CRS as RioCRS

    x0, y0 = city.origin
    return {
        "driver": "GTiff", "width": city.size, "height": city.size, "count": count, "dtype": dtype,
        "crs": RioCRS.from_string(CRS), "transform": Affine(city.spacing, 0.0, x0, 0.0, -city.spacing, y0 + city.extent),
        "tiled": True, "blockxsize": 256, "blockysize": 256, "compress": "deflate",
        # Floating-point prediction roughly halves a smooth DSM; horizontal differencing suits imagery.
        "predictor": 3 if dtype == "float32" else 2,
    }


def _write_dsm(city: SampleCity, grid: _Grid, path: Path) -> None:
    import rasterio

    dsm = np.where(grid.nodata, NODATA, grid.z).astype(np.float32)
    with rasterio.open(path, "w", nodata=NODATA, **_profile(city, 1, "float32")) as dst:
        dst.write(dsm, 1)
        dst.set_band_description(1, "surface height (m)")
        dst.update_tags(AREA_OR_POINT="Area", SOURCE=f"citylod sample size={city.size} seed={city.seed}")
        dst.update_tags(1, UNITTYPE="metre")


def _write_ortho(city: SampleCity, rgb: U8, path: Path) -> None:
    import rasterio
    from rasterio.enums import ColorInterp

    with rasterio.open(path, "w", photometric="RGB", **_profile(city, 3, "uint8")) as dst:
        dst.write(np.moveaxis(rgb, -1, 0))
        dst.colorinterp = [ColorInterp.red, ColorInterp.green, ColorInterp.blue]
        dst.update_tags(AREA_OR_POINT="Area")


# --------------------------------------------------------------------------------------------------
# Orthophoto
# --------------------------------------------------------------------------------------------------


def _noise(rng: np.random.Generator, n: int, scale_px: float) -> F64:
    """Smooth noise of unit standard deviation with features about ``scale_px`` pixels large, (n, n)."""
    from scipy.ndimage import zoom

    m = math.ceil(n / scale_px) + 3
    coarse = rng.standard_normal((m, m))
    fine = zoom(coarse, scale_px, order=3, mode="reflect")[:n, :n]
    return (fine - fine.mean()) / (fine.std() + 1e-12)


def _shading(city: SampleCity, z: F64) -> tuple[F64, npt.NDArray[np.bool_]]:
    """Lambert factor (1 on flat ground) and cast shadows of the sun on the surface grid."""
    s = city.spacing
    # minmod of one-sided differences: a roof pixel beside a façade takes its slope from the roof side.
    def grad(axis: int) -> F64:
        fwd = np.diff(z, axis=axis, append=np.take(z, [-1], axis=axis))
        bwd = np.diff(z, axis=axis, prepend=np.take(z, [0], axis=axis))
        return np.where(np.abs(fwd) < np.abs(bwd), fwd, bwd) / s

    gx, gy = grad(1), -grad(0)  # rows run south
    az, alt = math.radians(_SUN_AZIMUTH_DEG), math.radians(_SUN_ALTITUDE_DEG)
    sun = np.array([math.sin(az) * math.cos(alt), math.cos(az) * math.cos(alt), math.sin(alt)])
    lam = (-gx * sun[0] - gy * sun[1] + sun[2]) / np.sqrt(gx * gx + gy * gy + 1.0)
    lam = np.clip(lam / sun[2], 0.0, 1.6)
    # March towards the sun one pixel at a time: a pixel is shadowed if the surface there rises above
    # the sun ray. Vectorised per step over the whole grid.
    shadow = np.zeros(z.shape, dtype=bool)
    step = np.array([-math.cos(az), math.sin(az)])  # (row, col) per unit horizontal distance
    rise = math.tan(alt) * s
    # Only objects cast shadows at this sun altitude (the terrain is far less steep than the sun ray), so
    # the march ends at the tallest object's shadow length.
    tallest = max([b.ridge - b.ground + 2.0 for b in city.buildings] + [float(h) + 1.0 for h in city.trees.height]
                  + [8.0])
    n_steps = min(120, math.ceil(tallest / rise))
    n = z.shape[0]
    for k in range(1, n_steps + 1):
        dr, dc = (round(float(v)) for v in step * k)
        if abs(dr) >= n or abs(dc) >= n:
            break
        src = z[max(dr, 0) : n + min(dr, 0), max(dc, 0) : n + min(dc, 0)]
        dst = (slice(max(-dr, 0), n + min(-dr, 0)), slice(max(-dc, 0), n + min(-dc, 0)))
        shadow[dst] |= src > z[dst] + rise * math.hypot(dr, dc) + 0.05
    return lam, shadow


def _ortho(city: SampleCity, grid: _Grid) -> U8:
    """The orthophoto (size, size, 3) uint8, north up."""
    n = city.size
    rng = np.random.default_rng([city.seed, 1])
    x, y = city.pixel_centers()
    t = city.terrain
    n_fine, n_mid, n_coarse = _noise(rng, n, 1.5), _noise(rng, n, 6.0), _noise(rng, n, 40.0)

    # A palette colour per pixel times a grey texture: masked assignment keeps a 2049² image in a few
    # float32 passes instead of many full (n, n, 3) temporaries.
    base = np.empty((n, n, 3), dtype=np.float32)
    tex = np.empty((n, n), dtype=np.float32)
    # Land cover on bare ground: grass in town, crop parcels east of the river, banks, roads, water.
    base[:] = (92.0, 124.0, 58.0)
    tex[:] = 1.0 + 0.06 * n_mid + 0.05 * n_coarse
    east = x - t.river_center_x(y) > t.valley_half_width
    th = math.radians(8.0 + 10.0 * rng.random())  # parcels are not aligned with the grid
    pu = (x[east] - t.x0) * math.cos(th) + (y[east] - t.y0) * math.sin(th)
    pv = -(x[east] - t.x0) * math.sin(th) + (y[east] - t.y0) * math.cos(th)
    parcel = (np.floor(pu / 55.0) * 7919 + np.floor(pv / 140.0) * 104729).astype(np.int64) % 5
    crops = np.array([[196, 176, 104], [132, 150, 70], [150, 118, 82], [108, 140, 64], [182, 160, 90]], np.float32)
    base[east] = crops[parcel]
    stripes = np.where(parcel % 2 == 0, np.sin(pu * 2.1), np.sin(pv * 2.1))  # plough and seed rows
    tex[east] = 1.0 + 0.07 * stripes + 0.04 * n_mid[east]
    bank = t.river_distance(x, y) < t.channel_half_width + t.bank_width + 1.0
    base[bank] = (118.0, 112.0, 84.0)
    tex[bank] = 1.0 + 0.08 * n_fine[bank]
    on_road, d_road = city.road_mask(x, y)
    base[on_road] = (82.0, 82.0, 86.0)
    base[on_road & (d_road > 3.0)] = (158.0, 154.0, 146.0)  # pavements
    # x + y advances along either road axis, so one expression dashes both east–west and north–south lines.
    base[(d_road < 0.5) & (np.mod(x + y, 9.0) < 4.5)] = (225.0, 225.0, 215.0)
    tex[on_road] = 1.0 + 0.04 * n_fine[on_road]
    water = city.water_mask(x, y)
    base[water] = (46.0, 78.0, 96.0)
    tex[water] = 1.0 + 0.03 * n_mid[water]

    # Objects that form the surface: roofs, chimneys, crowns, bridge decks.
    nb = len(city.buildings)
    roof_rng = np.random.default_rng([city.seed, 2])
    tiles = np.array([[168, 72, 52], [150, 60, 48], [120, 68, 56], [86, 80, 82], [176, 96, 64]], np.float32)
    flats = np.array([[150, 150, 148], [118, 118, 120], [176, 170, 156], [96, 120, 80], [134, 128, 118]], np.float32)
    pick = roof_rng.integers(0, 5, nb)
    pitched = np.array([b.roof != "flat" for b in city.buildings], dtype=bool)
    roof_col = np.where(pitched[:, None], tiles[pick], flats[pick]) * roof_rng.uniform(0.9, 1.1, (nb, 1))
    tree_col = np.array([54.0, 86.0, 40.0]) * np.random.default_rng([city.seed, 3]).uniform(0.8, 1.2, (len(city.trees), 3))
    k, i = grid.kind, grid.ident
    m = k == KIND_BUILDING
    base[m] = roof_col[i[m]]
    tex[m] = 1.0 + 0.04 * n_fine[m]
    m = k == KIND_TREE
    base[m] = tree_col[i[m]]
    tex[m] = 1.0 + 0.12 * n_fine[m]
    base[k == KIND_CHIMNEY] = (112.0, 62.0, 52.0)
    base[k == KIND_BRIDGE] = (100.0, 98.0, 96.0)
    tex[(k == KIND_CHIMNEY) | (k == KIND_BRIDGE)] = 1.0

    lam, shadow = _shading(city, grid.z)
    light = (0.25 + 0.75 * lam) * np.where(shadow, 0.55, 1.0)
    light = np.where(water & (k == 0), 0.9 + 0.1 * light, light)  # water is lit by the sky more than by the sun
    tex *= light
    base *= tex[..., None]
    return np.clip(base, 0, 255).astype(np.uint8)


# --------------------------------------------------------------------------------------------------
# Point cloud
# --------------------------------------------------------------------------------------------------

_CLASS = {"ground": 2, "vegetation": 5, "building": 6, "water": 9, "bridge": 17}


def _write_points(city: SampleCity, rgb: U8, density: float, path: Path) -> dict[str, int]:
    """Stream the LAZ in row bands; returns point counts per class name."""
    import laspy
    import pyproj

    rng = np.random.default_rng([city.seed, 4])
    x0, y0 = city.origin
    header = laspy.LasHeader(point_format=7, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([math.floor(x0 / 1000.0) * 1000.0, math.floor(y0 / 1000.0) * 1000.0, 0.0])
    header.add_crs(pyproj.CRS.from_string(CRS))
    header.system_identifier = "citylod sample"
    header.generating_software = "citylod"
    header.creation_date = _dt.date(2024, 1, 1)  # fixed, so that a seed always gives the same bytes
    pitch = 1.0 / math.sqrt(density)  # a jittered grid: even coverage like a real scan, no lattice
    n_cols = max(1, int(city.extent / pitch))
    rows_per_band = max(1, int(64.0 / pitch))
    n_rows = n_cols
    counts = dict.fromkeys(_CLASS, 0)
    t_pulse = 3.0e8
    with laspy.open(path, mode="w", header=header, do_compress=True) as writer:
        for r0 in range(0, n_rows, rows_per_band):
            cols, rows = np.meshgrid(np.arange(n_cols), np.arange(r0, min(r0 + rows_per_band, n_rows)))
            px = x0 + (cols.ravel() + rng.random(cols.size)) * pitch
            py = y0 + (rows.ravel() + rng.random(cols.size)) * pitch
            band = _band_points(city, rgb, rng, px, py)
            for name, cls in _CLASS.items():
                counts[name] += int((band["classification"] == cls).sum())
            rec = laspy.ScaleAwarePointRecord.zeros(len(band["x"]), header=header)
            for key, val in band.items():
                setattr(rec, key, val)
            rec.gps_time = t_pulse + band["pulse"] * 1.0e-5
            t_pulse += len(band["x"]) * 1.0e-5
            writer.write_points(rec)
    counts["total"] = sum(counts[k] for k in _CLASS)
    return counts


def _band_points(city: SampleCity, rgb: U8, rng: np.random.Generator, px: F64, py: F64) -> dict[str, np.ndarray]:
    keep = ~city.nodata_mask(px, py)  # the lake and the gap return nothing
    water = city.water_mask(px, py)
    keep &= ~water | (rng.random(px.size) < 0.1)  # calm water returns few pulses
    px, py, water = px[keep], py[keep], water[keep]
    z, kind, _ = city.surface_with_kind(px, py)
    cls = np.full(px.size, _CLASS["ground"], dtype=np.uint8)
    cls[water] = _CLASS["water"]
    cls[(kind == KIND_BUILDING) | (kind == KIND_CHIMNEY)] = _CLASS["building"]
    cls[kind == KIND_TREE] = _CLASS["vegetation"]
    cls[kind == KIND_BRIDGE] = _CLASS["bridge"]
    # Part of the pulses through a crown also return from the ground below: return 2 of 2.
    second = (kind == KIND_TREE) & (rng.random(px.size) < 0.5)
    n_ret = np.where(second, 2, 1).astype(np.uint8)
    gx, gy = px[second], py[second]
    pulse = np.arange(px.size)
    x = np.concatenate([px, gx])
    y = np.concatenate([py, gy])
    zz = np.concatenate([z, city.terrain_height(gx, gy)]) + rng.normal(0.0, 0.02, px.size + gx.size)
    cls = np.concatenate([cls, np.full(gx.size, _CLASS["ground"], np.uint8)])
    ret = np.concatenate([np.ones(px.size, np.uint8), np.full(gx.size, 2, np.uint8)])
    nret = np.concatenate([n_ret, np.full(gx.size, 2, np.uint8)])
    pulse = np.concatenate([pulse, pulse[second]])
    order = np.argsort(pulse, kind="stable")  # returns of one pulse are consecutive, as scanners write them
    base = np.array([0, 0, 18000, 0, 0, 12000, 26000, 0, 0, 3000] + [0] * 7 + [10000], dtype=np.float64)
    intensity = base[cls] * rng.uniform(0.85, 1.15, cls.size) / np.where(ret == 2, 2.0, 1.0)
    x0, y0 = city.origin
    col = np.clip(((x - x0) / city.spacing).astype(np.int64), 0, city.size - 1)
    row = np.clip(((y0 + city.extent - y) / city.spacing).astype(np.int64), 0, city.size - 1)
    colour = rgb[row, col].astype(np.uint16) * 257  # 8-bit to the 16-bit range LAS expects
    # Flight lines run north–south, 300 m apart, 600 m above ground.
    line = np.floor((x - x0) / 300.0)
    scan = np.degrees(np.arctan2(x - (x0 + (line + 0.5) * 300.0), 600.0))
    out = {
        "x": x, "y": y, "z": zz, "intensity": intensity.astype(np.uint16), "return_number": ret,
        "number_of_returns": nret, "classification": cls, "scan_angle": np.round(scan / 0.006).astype(np.int16),
        "point_source_id": (line + 1).astype(np.uint16), "red": colour[:, 0], "green": colour[:, 1],
        "blue": colour[:, 2],
    }
    out = {k: v[order] for k, v in out.items()}
    out["pulse"] = pulse[order]
    return out


# --------------------------------------------------------------------------------------------------
# Cameras and metadata
# --------------------------------------------------------------------------------------------------


def _cameras(city: SampleCity, grid: _Grid) -> tuple[Camera, list[Camera]]:
    """An overview and a flight: approach from afar, a low pass along a street, an orbit."""
    ext = city.extent
    x0, y0 = city.origin
    valid = grid.z[~grid.nodata] if (~grid.nodata).any() else grid.z.ravel()
    zc = float(np.median(valid))
    ztop = float(valid.max())
    c = np.array([x0 + ext / 2, y0 + ext / 2, zc])

    def at(az_deg: float, el_deg: float, dist: float, focus: F64) -> Camera:
        az, el = math.radians(az_deg), math.radians(el_deg)
        off = np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)]) * dist
        return Camera(tuple(focus + off), tuple(focus))  # type: ignore[arg-type]

    overview = at(200.0, 38.0, 1.25 * ext, c)
    flight = [at(210.0 - 10.0 * f, 30.0 - 8.0 * f, (4.0 - 2.9 * f) * ext, c) for f in np.linspace(0, 1, 12)]
    # Low pass along the first east–west road, a little above the roofs, looking ahead and down.
    road = next((r for r in city.roads if r.axis == "x"), None)
    yr = road.center if road is not None else y0 + ext / 2
    xs = np.linspace(x0 + 0.05 * ext, x0 + 0.95 * ext, 16)
    look = max(40.0, 0.15 * ext)
    line_z = city.surface_height(np.linspace(x0, x0 + ext, 256), np.full(256, yr))
    alt = float(line_z.max()) + max(15.0, 0.03 * ext)
    ground_ahead = city.terrain_height(xs + look, np.full(xs.shape, yr))
    flight += [Camera((float(x), yr, alt), (float(x + look), yr, float(g))) for x, g in zip(xs, ground_ahead, strict=True)]
    # Orbit: once round the centre, high enough to see over everything.
    orbit_h = max(ztop - zc + 20.0, 0.35 * ext)
    for a in np.linspace(90.0, 450.0, 24, endpoint=False):
        flight.append(at(float(a), math.degrees(math.atan2(orbit_h, 0.7 * ext)), math.hypot(orbit_h, 0.7 * ext), c))
    return overview, flight


def _building_summary(b: Building) -> dict[str, object]:
    return {
        "id": b.id, "name": b.name, "function": b.function, "roof": b.roof, "shape": b.shape,
        "storeys": b.storeys, "ground": b.ground, "eave": b.eave, "ridge": b.ridge,
        "measuredHeight": round(b.measured_height, 2), "footprint_area": round(b.footprint_area, 2),
        "center": [round(v, 3) for v in b.center],
    }


def _metadata(city: SampleCity, files: dict[str, Path], counts: dict[str, int], density: float) -> dict[str, object]:
    return {
        "generator": "citylod sample",
        "crs": CRS, "size": city.size, "seed": city.seed, "spacing": city.spacing,
        "origin": list(city.origin), "bounds": list(city.bounds), "nodata": NODATA,
        "point_density_per_m2": density,
        "files": {k: p.name for k, p in files.items()},
        "counts": {"buildings": len(city.buildings), "chimneys": len(city.chimneys), "trees": len(city.trees),
                   "bridges": len(city.bridges), "roads": len(city.roads), "points": counts},
        "buildings": [_building_summary(b) for b in city.buildings],
    }
