"""``citylod bench`` (speed against error along a camera path) and ``citylod bench-suite`` (the README's
results)."""

from __future__ import annotations

import argparse
from pathlib import Path

from citylod.cli._args import floats, size


def add_parser(sub: argparse._SubParsersAction) -> None:
    be = sub.add_parser("bench", help="speed-against-error report for a camera path")
    be.add_argument("sources", type=Path, nargs="+")
    be.add_argument("--path", type=Path, help="camera path JSON (default: a flight derived from the bounds)")
    be.add_argument("-o", "--output", type=Path, required=True)
    be.add_argument("--tau", type=floats, default=[0.5, 1, 2, 4, 8])
    be.add_argument("--size", type=size, default=(960, 540))

    bs = sub.add_parser("bench-suite", help="the full benchmark suite behind the README's results table")
    bs.add_argument("out_dir", type=Path)
    bs.add_argument("--quick", action="store_true", help="smaller inputs")

    bf = sub.add_parser("bench-slf", help="far-field surface light fields against the building geometry")
    bf.add_argument("slf_dir", type=Path, help="far-field tileset (citylod build slf)")
    bf.add_argument("-o", "--output", type=Path, required=True)
    bf.add_argument("--tau", type=float, default=2.0)
    bf.add_argument("--orbit-frames", type=int, default=12)
    bf.add_argument("--texel-px", type=float, default=1.5,  # render.slf.TEXEL_PX (not imported here: VTK)
                    help="also refine fields while a texel covers more pixels than this (default 1.5; 0: never)")
    bf.add_argument("--lookup", choices=("gpu", "cpu"), default="gpu",
                    help="evaluate the fields per pixel in the fragment shader (default) or per texel on the CPU")
    bf.add_argument("--no-antialias", action="store_true",
                    help="shader lookup: one point a pixel where a pixel covers several texels (faster, aliased)")


def run(args: argparse.Namespace, progress: bool) -> int:
    if args.command == "bench-slf":
        from citylod.bench.slf_bench import slf_bench

        slf_bench(args.slf_dir, args.output, tau_px=args.tau, orbit_frames=args.orbit_frames,
                  texel_px=args.texel_px, lookup=args.lookup, antialias=not args.no_antialias, progress=progress)
        print((args.output / "slf_report.md").read_text())
        return 0
    if args.command == "bench-suite":
        from citylod.bench.suite import run_suite

        return run_suite(args.out_dir, quick=args.quick, progress=progress)
    from citylod.bench.report import bench_command

    return bench_command(args, progress=progress)
