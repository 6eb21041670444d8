"""``citylod flood RASTER|TILESET --level L -o OUT_DIR``: flooded area, depth and affected buildings."""

from __future__ import annotations

import argparse
from pathlib import Path

from citylod.cli._args import floats
from citylod.io.tiles3d.package import is_tileset_path


def _xy(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"seed must be X,Y in the raster's CRS, got {text!r}") from None
    return x, y


def add_parser(sub: argparse._SubParsersAction) -> None:
    f = sub.add_parser("flood", help="flood a DSM/DTM raster (or a built DSM tileset) from sources at water levels")
    f.add_argument("raster", type=Path, help="height raster, or a DSM tileset from `citylod build dsm` (its "
                                             "leaves are flooded on the source grid)")
    lv = f.add_mutually_exclusive_group(required=True)
    lv.add_argument("--level", type=float, help="water level (raster height units)")
    lv.add_argument("--levels", type=floats, help="a series of water levels, e.g. 1,1.5,2 (one result each)")
    f.add_argument("--seed", type=_xy, action="append", default=[], metavar="X,Y",
                   help="a water source point in the raster's CRS (repeatable)")
    f.add_argument("--source", type=Path, action="append", default=[], metavar="POLY",
                   help="source polygons: GeoJSON, KML or GeoPackage (repeatable)")
    f.add_argument("--edge", action="store_true", help="water enters along the raster's edge")
    f.add_argument("--depressions", action="store_true",
                   help="flood enclosed depressions below the level too (not only what a source reaches)")
    f.add_argument("--eight", action="store_true", help="8-neighbour connectivity (default 4)")
    f.add_argument("--city", type=Path, help="city store (.gpkg) for the affected buildings")
    f.add_argument("--touch", type=float, help="distance in metres within which a flooded cell affects a "
                                               "building (default: one sample spacing)")
    f.add_argument("-o", "--output", type=Path, required=True, help="output folder")


def run(args: argparse.Namespace, progress: bool) -> int:
    from citylod.analysis.flood import FloodSources, flood_raster, flood_tileset
    from citylod.analysis.polygons import PolygonLayer, load_polygons

    layers = [load_polygons(p) for p in args.source]
    poly = None
    if layers:
        crs = layers[0].crs
        poly = PolygonLayer(tuple(p for lay in layers for p in lay.to_crs(crs).polygons), crs,
                            ", ".join(str(p) for p in args.source))
    sources = FloodSources(tuple(args.seed), poly, args.edge)
    levels = args.levels if args.levels is not None else [args.level]
    is_tiles = is_tileset_path(args.raster)
    report = (flood_tileset if is_tiles else flood_raster)(args.raster, levels, args.output, sources=sources, depressions=args.depressions,
                          eight=args.eight, city=args.city, touch_m=args.touch, progress=progress)
    print(report.summary())
    return 0
