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


def run(args: argparse.Namespace, progress: bool) -> int:
    if args.command == "bench-suite":
        from citylod.bench.suite import run_suite

        return run_suite(args.out_dir, quick=args.quick, progress=progress)
    from citylod.bench.report import bench_command

    return bench_command(args, progress=progress)
