"""``citylod build dsm|points|city|model``: the offline builders."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    b = sub.add_parser("build", help="build an LOD hierarchy or a semantic store")
    bsub = b.add_subparsers(dest="kind", required=True, metavar="KIND")
    d = bsub.add_parser("dsm", help="DSM raster to a 3D Tiles quadtree with guaranteed error")
    d.add_argument("raster", type=Path)
    d.add_argument("-o", "--output", type=Path, required=True)
    d.add_argument("--ortho", type=Path, help="orthophoto to texture the tiles with")
    d.add_argument("--max-error", type=float, help="leaf error bound in metres (default: half the sample spacing)")
    d.add_argument("--tile-size", type=int, default=129, help="samples per tile side, 2^k+1 (default 129)")
    d.add_argument("--workers", type=int,
                   help="local worker processes, spawned (default: one per CPU, forked from this process on Linux)")
    d.add_argument("--scheduler", help="Dask scheduler address, e.g. tcp://127.0.0.1:8786")
    d.add_argument("--certify-leaves", action="store_true",
                   help="certify the leaves against the raster too (default: the TIN kernel's exact bound)")
    d.add_argument("--metric", choices=("hausdorff", "vertical"), default="hausdorff",
                   help="what geometricError bounds: the symmetric 3D Hausdorff distance to the raster surface "
                        "(default; a façade costs its slope's offset, so coarse levels of a city stay within 1.5x "
                        "their targets) or the vertical distance (counts a façade at its full height; builds "
                        "faster, for terrain)")
    pt = bsub.add_parser("points", help="LAS/LAZ files to a 3D Tiles octree")
    pt.add_argument("files", type=Path, nargs="+")
    pt.add_argument("-o", "--output", type=Path, required=True)
    pt.add_argument("--crs", help="CRS when the LAS header has none, e.g. EPSG:28992")
    pt.add_argument("--no-hybrid", action="store_true", help="points only, no plane quads")
    pt.add_argument("--complete", nargs="?", const="points", choices=("points", "quads"),
                    help="add walls (as points, the default, or as quads) and ground under canopy from the "
                         "ASPRS classes (2 ground, 6 building, 3-5 vegetation); added points are flagged "
                         "synthetic. Unclassified input gets a warning and nothing added")
    pt.add_argument("--no-ground-fill", action="store_true", help="with --complete: walls only")
    pt.add_argument("--footprints", type=Path, help="with --complete: building footprints (GeoPackage or OGR "
                    "SQLite, the points' CRS); outer walls stand on their outlines, not under the roof edge")
    pt.add_argument("--eaves", type=float, default=0.25, metavar="M",
                    help="with --complete: walls from the roof edge stand this far inside it, under the eaves "
                         "(default 0.25; 0 for roofs without overhang)")
    pt.add_argument("--roof-fill", action="store_true",
                    help="with --complete: also roof points where the roof returned nothing (dark, glass)")
    pt.add_argument("--refine-roofs", action="store_true",
                    help="smooth the range noise of the building-class (6) roofs per building, ridges kept "
                         "(bilateral, Gao ch. 5); the moved points replace their originals in the tileset, "
                         "flagged synthetic = 2; unclassified input is left as it is")
    pt.add_argument("--workers", type=int)
    pt.add_argument("--scheduler")
    m = bsub.add_parser("model", help="DSM raster to a simplified city mesh (3D Tiles) and buildings (CityJSON)")
    m.add_argument("raster", type=Path)
    m.add_argument("-o", "--output", type=Path, required=True)
    m.add_argument("--max-error", type=float, help="certified error bound in metres (default: the spacing)")
    m.add_argument("--metric", choices=("hausdorff", "vertical"), default="hausdorff",
                   help="what the bound bounds: 3D Hausdorff distance (default) or vertical distance")
    m.add_argument("--cell", type=int, default=512, help="samples per out-of-core cell side (default 512)")
    m.add_argument("--no-shapes", action="store_true", help="plain QEM collapse under the bound, no shape rules")
    m.add_argument("--ortho", type=Path, help="orthophoto to texture the mesh with")
    m.add_argument("--workers", type=int)
    m.add_argument("--scheduler")
    c = bsub.add_parser("city", help="CityGML / CityJSON to a GeoPackage semantic store and a 3D Tiles tileset")
    c.add_argument("citymodel", type=Path)
    c.add_argument("-o", "--output", type=Path, required=True)
    c.add_argument("--tiles", type=Path,
                   help="tileset folder of the geometry (default: beside the store, city.gpkg -> city_tiles/)")
    c.add_argument("--no-tiles", action="store_true", help="write the semantic store only")
    c.add_argument("--leaf-triangles", type=int, default=20_000,
                   help="largest triangle count of a leaf tile holding several objects (default 20000)")
    c.add_argument("--atlas-px", type=int, default=1024, choices=(256, 512, 1024, 2048, 4096),
                   help="side of the texture atlas of every tile of a textured model (default 1024)")
    c.add_argument("--no-textures", action="store_true", help="ignore the model's appearances")
    c.add_argument("--texture-blocks", action="store_true",
                   help="textured model: far tiles carry blocks in the atlas's mean colours (building LOD) "
                        "instead of full surfaces with atlases")
    c.add_argument("--lod", type=int, choices=(1, 2), default=2)
    c.add_argument("--inflate", type=float, help="proxy inflation in metres")
    c.add_argument("--crs", help="metric CRS to project geographic input to, or the CRS of a file that names none, "
                   "e.g. EPSG:32632")
    add_slf_parser(bsub)


def add_slf_parser(bsub: argparse._SubParsersAction) -> None:
    """``citylod build slf CITY_TILES -o OUT``: far-field surface light fields (issue 28)."""
    f = bsub.add_parser("slf", help="far-field surface light fields over a city tileset (replace distant buildings)")
    f.add_argument("city_tiles", type=Path, help="city tileset (citylod build city)")
    f.add_argument("-o", "--output", type=Path, required=True)
    f.add_argument("--texel-m", type=float, default=4.0, help="texel size of the finest level in metres (default 4)")
    f.add_argument("--texels", type=int, default=64, help="texels per cell side, a power of two (default 64)")
    f.add_argument("--directions", type=int, default=11,
                   help="side of the parabolic direction lattice (11: 97 directions, 9: 69, 7: 37)")
    f.add_argument("--oversample", type=int, default=6, help="samples per texel side (default 6)")
    f.add_argument("--clusters", type=int, default=256, help="clusters per group of four cells (≤ 256)")
    f.add_argument("--components", type=int, default=3, help="eigen-lumispheres per cluster (default 3)")
    f.add_argument("--workers", type=int, help="threads that bake and compress (default: one per CPU)")


def _packaged(output: Path) -> tuple[Path, Path | None]:
    """(the folder to build into, the package to write from it) for an output named ``*.3tz`` or ``*.3dtiles``:
    the build runs in ``OUT.build/`` (resumable as any folder build) and is packed when complete."""
    from citylod.io.tiles3d.package import PACKAGE_SUFFIXES

    if output.suffix.lower() in PACKAGE_SUFFIXES:
        return output.with_name(output.name + ".build"), output
    return output, None


def _pack(folder: Path, package: Path | None) -> None:
    if package is None:
        return
    import shutil

    from citylod.io.tiles3d.archive3tz import write_package

    write_package(folder, package)
    shutil.rmtree(folder)
    print(f"{package}: packed from {folder.name}/")


def run(args: argparse.Namespace, progress: bool) -> int:
    if args.kind == "slf":
        from citylod.lod.build.slf import build_slf

        print(build_slf(args.city_tiles, args.output, texel_m=args.texel_m, texels=args.texels, grid=args.directions,
                        oversample=args.oversample, clusters=args.clusters, components=args.components,
                        workers=args.workers, progress=progress).summary())
        return 0
    if args.kind == "dsm":
        from citylod.lod.build.dsm import build_dsm

        folder, package = _packaged(args.output)
        report = build_dsm(
            args.raster, folder, ortho=args.ortho, max_error=args.max_error, tile_size=args.tile_size,
            workers=args.workers, scheduler=args.scheduler, progress=progress, certify_leaves=args.certify_leaves,
            metric=args.metric,
        )
        _pack(folder, package)
    elif args.kind == "points":
        from citylod.lod.build.complete import CompleteOptions
        from citylod.lod.build.points import build_points

        if args.footprints is not None:
            from citylod.io.footprints import read_footprints

            read_footprints(args.footprints)  # a bad file is refused before the build starts
        complete = (None if args.complete is None
                    else CompleteOptions(walls=args.complete, ground=not args.no_ground_fill,
                                         footprints=None if args.footprints is None else str(args.footprints),
                                         eave_m=args.eaves, roof_fill=args.roof_fill))
        folder, package = _packaged(args.output)
        report = build_points(
            args.files, folder, crs=args.crs, hybrid=not args.no_hybrid, workers=args.workers,
            scheduler=args.scheduler, progress=progress, complete=complete, refine_roofs=args.refine_roofs,
        )
        _pack(folder, package)
    elif args.kind == "model":
        from citylod.lod.build.model import build_model

        report = build_model(args.raster, args.output, max_error=args.max_error, cell=args.cell,
                             constrained=not args.no_shapes, workers=args.workers, scheduler=args.scheduler,
                             progress=progress, ortho=args.ortho, metric=args.metric)
    else:
        from citylod.io.city import read_city_model, to_metric
        from citylod.semantics.store import build_city

        # Read once; the store and the tileset are two products of the same model (the tileset builder
        # projects it itself: appearances are matched in the coordinates as read).
        raw = read_city_model(args.citymodel, lod=args.lod)
        report = build_city(to_metric(raw, args.crs), args.output, lod=args.lod, inflate=args.inflate,
                            progress=progress)
        if not args.no_tiles:
            from citylod.lod.build.city import build_city_tiles, default_tiles_dir

            print(report.summary())
            folder, package = _packaged(args.tiles or default_tiles_dir(args.output))
            report = build_city_tiles(raw, folder, crs=args.crs,
                                      leaf_triangles=args.leaf_triangles, atlas_px=args.atlas_px,
                                      textures=not args.no_textures,
                                      texture_blocks=args.texture_blocks, progress=progress)
            _pack(folder, package)
            for w in report.warnings:
                if "texture" in w:
                    print(f"citylod: warning: {w}")
    print(report.summary())
    return 0
