"""The ``citylod`` command.

Each subcommand imports what it needs when it runs, so ``citylod --help`` is fast and a machine without a
display can run every command but ``view``. A :class:`~citylod.core.errors.CitylodError` becomes one line on
stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from citylod.core.errors import CitylodError


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must be WxH, e.g. 1280x720, got {text!r}") from None
    if w <= 0 or h <= 0:
        raise argparse.ArgumentTypeError("size must be positive")
    return w, h


def _floats(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="citylod", description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bars")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    s = sub.add_parser("sample", help="write a reproducible synthetic city (DSM, orthophoto, LAZ, CityGML)")
    s.add_argument("out_dir", type=Path)
    s.add_argument("--size", type=int, default=513, help="DSM size in samples per side (default 513)")
    s.add_argument("--seed", type=int, default=7)

    b = sub.add_parser("build", help="build an LOD hierarchy or a semantic store")
    bsub = b.add_subparsers(dest="kind", required=True, metavar="KIND")
    d = bsub.add_parser("dsm", help="DSM raster to a 3D Tiles quadtree with guaranteed error")
    d.add_argument("raster", type=Path)
    d.add_argument("-o", "--output", type=Path, required=True)
    d.add_argument("--ortho", type=Path, help="orthophoto to texture the tiles with")
    d.add_argument("--max-error", type=float, help="leaf error bound in metres (default: half the sample spacing)")
    d.add_argument("--tile-size", type=int, default=129, help="samples per tile side, 2^k+1 (default 129)")
    d.add_argument("--workers", type=int, help="local worker processes, spawned (default: one per CPU, forked from this process on Linux)")
    d.add_argument("--scheduler", help="Dask scheduler address, e.g. tcp://127.0.0.1:8786")
    d.add_argument("--certify-leaves", action="store_true",
                   help="certify the leaves against the raster too (default: the TIN kernel's exact bound)")
    pt = bsub.add_parser("points", help="LAS/LAZ files to a 3D Tiles octree")
    pt.add_argument("files", type=Path, nargs="+")
    pt.add_argument("-o", "--output", type=Path, required=True)
    pt.add_argument("--crs", help="CRS when the LAS header has none, e.g. EPSG:28992")
    pt.add_argument("--no-hybrid", action="store_true", help="points only, no plane quads")
    pt.add_argument("--workers", type=int)
    pt.add_argument("--scheduler")
    c = bsub.add_parser("city", help="CityGML / CityJSON to a GeoPackage semantic store")
    c.add_argument("citymodel", type=Path)
    c.add_argument("-o", "--output", type=Path, required=True)
    c.add_argument("--lod", type=int, choices=(1, 2), default=2)
    c.add_argument("--inflate", type=float, help="proxy inflation in metres")
    c.add_argument("--crs", help="metric CRS to project geographic input to, e.g. EPSG:32632")

    i = sub.add_parser("info", help="describe a tileset, raster, point cloud or city store")
    i.add_argument("source", type=Path)

    r = sub.add_parser("render", help="off-screen render of tilesets and city stores")
    r.add_argument("sources", type=Path, nargs="+")
    r.add_argument("-o", "--output", type=Path, required=True, help="PNG; with a camera path, a frame pattern")
    r.add_argument("--camera", type=Path, required=True, help="camera JSON (one camera or a path)")
    r.add_argument("--tau", type=float, default=1.0, help="screen-space error threshold in pixels")
    r.add_argument("--size", type=_size, default=(1280, 720))
    r.add_argument("--depth", type=Path, help="write the depth (distance from the eye) as float32 .npy")
    r.add_argument("--city", type=Path, help="city store (.gpkg) for --highlight / --hide")
    r.add_argument("--highlight", help="SQL WHERE clause of objects to highlight")
    r.add_argument("--hide", help="SQL WHERE clause of objects to hide")
    r.add_argument("--color-by", default="auto", help="auto, rgb, classification, elevation, intensity, level")

    be = sub.add_parser("bench", help="speed-against-error report for a camera path")
    be.add_argument("sources", type=Path, nargs="+")
    be.add_argument("--path", type=Path, help="camera path JSON (default: a flight derived from the bounds)")
    be.add_argument("-o", "--output", type=Path, required=True)
    be.add_argument("--tau", type=_floats, default=[0.5, 1, 2, 4, 8])
    be.add_argument("--size", type=_size, default=(960, 540))

    bs = sub.add_parser("bench-suite", help="the full benchmark suite behind the README's results table")
    bs.add_argument("out_dir", type=Path)
    bs.add_argument("--quick", action="store_true", help="smaller inputs")

    lk = sub.add_parser("link", help="write the id of the containing city object into each point")
    lk.add_argument("store", type=Path)
    lk.add_argument("points", type=Path)
    lk.add_argument("-o", "--output", type=Path, required=True)

    v = sub.add_parser("view", help="the desktop application")
    v.add_argument("sources", type=Path, nargs="*")
    v.add_argument("--screenshot", type=Path, help="save a screenshot of the window")
    v.add_argument("--exit", action="store_true", help="quit after loading (and the screenshot)")
    v.add_argument("--camera", type=Path)

    bk = sub.add_parser("build-kernels", help="compile the DSM build's kernels ahead of time (what `make` runs; "
                        "saves numba's start, ≈0.5 s, in every build)")
    bk.add_argument("--force", action="store_true", help="compile again even when they are up to date")
    bk.add_argument("--check", action="store_true", help="only say whether they are built; exit 1 when not")

    dm = sub.add_parser("demo", help="the main job on a built-in sample (what `make demo` runs)")
    dm.add_argument("out_dir", type=Path)
    dm.add_argument("--no-gui", action="store_true", help="render off-screen even when a display exists")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    progress = not args.quiet
    try:
        return _dispatch(args, progress)
    except CitylodError as exc:
        print(f"citylod: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("citylod: interrupted", file=sys.stderr)
        return 130


def _dispatch(args: argparse.Namespace, progress: bool) -> int:
    cmd = args.command
    if cmd == "sample":
        from citylod.io.sample import make_sample

        info = make_sample(args.out_dir, size=args.size, seed=args.seed)
        for name, path in info.files.items():
            print(f"{name:10s} {path}")
        return 0
    if cmd == "build" and args.kind == "dsm":
        from citylod.lod.dsm import build_dsm

        report = build_dsm(
            args.raster, args.output, ortho=args.ortho, max_error=args.max_error, tile_size=args.tile_size,
            workers=args.workers, scheduler=args.scheduler, progress=progress, certify_leaves=args.certify_leaves,
        )
        print(report.summary())
        return 0
    if cmd == "build" and args.kind == "points":
        from citylod.lod.points import build_points

        report = build_points(
            args.files, args.output, crs=args.crs, hybrid=not args.no_hybrid, workers=args.workers,
            scheduler=args.scheduler, progress=progress,
        )
        print(report.summary())
        return 0
    if cmd == "build" and args.kind == "city":
        from citylod.semantics.store import build_city

        report = build_city(args.citymodel, args.output, lod=args.lod, inflate=args.inflate, crs=args.crs,
                            progress=progress)
        print(report.summary())
        return 0
    if cmd == "info":
        from citylod.info import describe

        print(describe(args.source))
        return 0
    if cmd == "render":
        from citylod.render.offscreen import render_command

        return render_command(args, progress=progress)
    if cmd == "bench":
        from citylod.bench.report import bench_command

        return bench_command(args, progress=progress)
    if cmd == "bench-suite":
        from citylod.bench.suite import run_suite

        return run_suite(args.out_dir, quick=args.quick, progress=progress)
    if cmd == "link":
        from citylod.semantics.link import link_command

        return link_command(args.store, args.points, args.output, progress=progress)
    if cmd == "view":
        from citylod.app.main import run_app

        return run_app(args.sources, screenshot=args.screenshot, exit_after=args.exit, camera=args.camera)
    if cmd == "build-kernels":
        from citylod.lod import aot

        if args.check:
            ok = aot.available()
            print(f"compiled-ahead kernels {'loaded' if ok else 'not built'}: {aot.kernel_dir()}")
            return 0 if ok else 1
        # Not built is not an error: every build still runs, on the JIT kernels; the reason is printed.
        aot.build(force=args.force, log=lambda m: print(m, file=sys.stderr))
        return 0
    if cmd == "demo":
        from citylod.demo import run_demo

        return run_demo(args.out_dir, no_gui=args.no_gui, progress=progress)
    raise AssertionError(f"unhandled command {cmd}")


if __name__ == "__main__":
    sys.exit(main())
