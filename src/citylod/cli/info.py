"""``citylod info``: a short description of a tileset, raster, point cloud or city store."""

from __future__ import annotations

import argparse
import os
from collections import Counter
from pathlib import Path

from citylod.core.errors import InputError
from citylod.io.tiles3d.package import is_tileset_path
from citylod.io.tiles3d.remote import is_url


def describe(source: str | os.PathLike[str]) -> str:
    """A human-readable summary of ``source``; InputError when it is not something citylod reads."""
    p = Path(source)
    if is_url(source):
        return _describe_tileset(p)
    if not p.exists():
        raise InputError("not found", p)
    suffix = p.suffix.lower()
    if suffix in (".gml", ".xml", ".jsonl") or p.name.endswith(".city.json"):
        return f"{p}: city model (build a store with `citylod build city {p} -o CITY.gpkg`)"
    if is_tileset_path(p):
        return _describe_tileset(p)
    if suffix in (".las", ".laz"):
        return _describe_las(p)
    if suffix == ".gpkg":
        return _describe_store(p)
    return _describe_raster(p)


def _describe_tileset(p: Path) -> str:
    from citylod.io.tiles3d import open_tileset

    ts = open_tileset(p)
    levels: Counter[int] = Counter()
    errors: dict[int, float] = {}
    tri = pts = nbytes = tiles = 0
    for t in ts.walk():
        tiles += 1
        levels[t.level] += 1
        errors[t.level] = max(errors.get(t.level, 0.0), t.geometric_error)
        tri += t.triangle_count
        pts += t.point_count
        nbytes += t.content_bytes
    lo, hi = ts.bounds
    lines = [
        f"{ts.source}: 3D Tiles {ts.doc.get('asset', {}).get('version', '?')}, kind {ts.kind}",
        f"  crs      {ts.crs.name}" + (f" (EPSG:{ts.crs.to_epsg()})" if ts.crs.to_epsg() else ""),
        f"  bounds   x {lo[0]:.2f} … {hi[0]:.2f}, y {lo[1]:.2f} … {hi[1]:.2f}, z {lo[2]:.2f} … {hi[2]:.2f}",
        f"  tiles    {tiles} on {len(levels)} levels, "
        + ("content on a web server" if is_url(ts.source) else f"{nbytes / 1e6:.1f} MB content"),
    ]
    lines += [f"  credit   {text}" for text in ts.attributions]
    if ts.kind == "slf":  # a far field (citylod build slf): its light fields beside the average textures
        meta = ts.citylod
        fields = Path(ts.folder) / "slf"
        stored = sum(f.stat().st_size for f in fields.rglob("*.bin")) if fields.is_dir() else 0
        lines.append(f"  fields   {meta.get('directions', '?')} directions in {len(meta.get('patches') or [1])} patches, "
                     f"{meta.get('texels', '?')}² texels, {meta.get('clusters', '?')} clusters × "
                     f"{meta.get('components', '?')} components, {stored / 1e6:.1f} MB; city {meta.get('city', '?')}")
    if tri:
        lines.append(f"  triangles {tri:,}")
    if pts:
        lines.append(f"  points   {pts:,}")
    lines.append("  level  tiles  geometricError (max, m)")
    for lv in sorted(levels):
        lines.append(f"  {lv:5d} {levels[lv]:6d}  {errors[lv]:.4g}")
    return "\n".join(lines)


def _describe_raster(p: Path) -> str:
    from citylod.io.raster import read_info

    info = read_info(p)
    head = (f"{p}: raster {info.width}×{info.height} {info.dtype}, crs {info.crs.name}, "
            f"spacing {info.spacing_m:.3f} m{' (geographic, degrees)' if info.geographic else ''}, "
            f"nodata {info.nodata}")
    return "\n".join([head, *_raster_extent(p)])


# Rasters up to this many samples (the 8193² sample city; about 2 s here) are read in strips for their exact
# height range; larger ones get GDAL's approximate statistics.
_EXACT_HEIGHTS_SAMPLES = 8193 * 8193
_STRIP_SAMPLES = 4_194_304  # samples read at a time (16 MB as float32)


def _raster_extent(p: Path) -> list[str]:
    """Bounds and the range of heights (what a flood level or a camera is chosen from): exact for rasters
    up to :data:`_EXACT_HEIGHTS_SAMPLES` samples (read in strips), else GDAL's approximate statistics
    (overviews or a subsample), said so."""
    import numpy as np
    import rasterio

    # No .aux.xml beside the user's file: GDAL would save the statistics it computes there.
    with rasterio.Env(GDAL_PAM_ENABLED="NO"), rasterio.open(p) as ds:
        b = ds.bounds
        lines = [f"  bounds   x {b.left:.2f} … {b.right:.2f}, y {b.bottom:.2f} … {b.top:.2f}"]
        # An image (an orthophoto: bytes, several bands) has values, not heights.
        what = "heights " if ds.count == 1 and ds.dtypes[0] != "uint8" else "band 1  "
        if ds.width * ds.height <= _EXACT_HEIGHTS_SAMPLES:
            from rasterio.windows import Window

            lo, hi, total, count = np.inf, -np.inf, 0.0, 0
            rows = max(1, _STRIP_SAMPLES // ds.width)
            for r0 in range(0, ds.height, rows):  # strips: memory stays bounded, the result is exact
                band = ds.read(1, masked=True, window=Window(0, r0, ds.width, min(rows, ds.height - r0)))
                valid = band.compressed()
                valid = valid[np.isfinite(valid)]
                if valid.size:
                    lo, hi = min(lo, float(valid.min())), max(hi, float(valid.max()))
                    total += float(valid.sum(dtype=np.float64))
                    count += valid.size
            if count == 0:
                lines.append(f"  {what} none (every sample is no-data)")
            else:
                lines.append(f"  {what} {lo:.2f} … {hi:.2f} (mean {total / count:.2f}), "
                             f"{100.0 * count / (ds.width * ds.height):.1f} % of the samples valid")
        else:
            st = ds.stats(indexes=[1], approx=True)[0] if hasattr(ds, "stats") else ds.statistics(1, approx=True)
            lines.append(f"  {what} ≈ {st.min:.2f} … {st.max:.2f} (mean {st.mean:.2f}; approximate, from GDAL's "
                         "statistics of a subsample)")
    return lines


def _describe_las(p: Path) -> str:
    import laspy

    from citylod.io.las import check_header

    check_header(p)
    try:
        with laspy.open(p) as f:
            h = f.header
            crs = h.parse_crs()
            return (f"{p}: LAS {h.version} point format {h.point_format.id}, {h.point_count:,} points, "
                    f"crs {crs.name if crs else 'none'}, x {h.mins[0]:.2f} … {h.maxs[0]:.2f}, "
                    f"y {h.mins[1]:.2f} … {h.maxs[1]:.2f}, z {h.mins[2]:.2f} … {h.maxs[2]:.2f}")
    except Exception as exc:  # laspy raises several types for bad headers
        raise InputError(f"not a readable LAS/LAZ file ({exc})", p) from exc


def _describe_store(p: Path) -> str:
    import pyproj

    from citylod.semantics.store import CityStore

    with CityStore.open(p) as store:
        x0, y0, z0, x1, y1, z1 = store.bounds
        n = len(store)
        buildings = len(store.query("type IN ('Building', 'BuildingPart')"))
        lines = [f"{p}: city store (GeoPackage), {n} objects, {buildings} buildings"]
        if store.crs is None:  # stores written before a CRS was required
            lines.append("  crs      none (the source named none; rebuild with --crs to place it)")
        else:
            epsg = store.crs.to_epsg()
            lines.append(f"  crs      {store.crs.name}" + (f" (EPSG:{epsg})" if epsg else ""))
        lines.append(f"  bounds   x {x0:.2f} … {x1:.2f}, y {y0:.2f} … {y1:.2f}, z {z0:.2f} … {z1:.2f}")
        if store.crs is not None:
            lon, lat = pyproj.Transformer.from_crs(store.crs, "EPSG:4326", always_xy=True).transform(
                (x0 + x1) / 2, (y0 + y1) / 2)
            lines.append(f"  centre   {lat:.5f}° N, {lon:.5f}° E")
        # What --highlight / --hide and the query panel can ask about.
        lines.append(f"  columns  {', '.join(store.query_columns())}")
        names = store.attribute_names()
        if names:
            lines.append("  attributes (json_extract(attributes, '$.NAME')): "
                         + ", ".join(f"{k} ({n})" for k, n in names))
        return "\n".join(lines)


def add_parser(sub: argparse._SubParsersAction) -> None:
    i = sub.add_parser("info", help="describe a tileset, raster, point cloud or city store")
    i.add_argument("source", type=Path)


def run(args: argparse.Namespace, progress: bool) -> int:
    print(describe(args.source))
    return 0
