"""``citylod build-kernels``: compile the DSM build's kernels ahead of time (what ``make`` runs)."""

from __future__ import annotations

import argparse
import sys


def add_parser(sub: argparse._SubParsersAction) -> None:
    bk = sub.add_parser("build-kernels", help="compile the DSM build's kernels ahead of time (what `make` runs; "
                        "saves numba's start, ≈0.5 s, in every build)")
    bk.add_argument("--force", action="store_true", help="compile again even when they are up to date")
    bk.add_argument("--check", action="store_true", help="only say whether they are built; exit 1 when not")


def run(args: argparse.Namespace, progress: bool) -> int:
    from citylod.lod.kernels import aot

    if args.check:
        ok = aot.available()
        print(f"compiled-ahead kernels {'loaded' if ok else 'not built'}: {aot.kernel_dir()}")
        return 0 if ok else 1
    from citylod.lod.build.dsm import exercise_kernels

    # Not built is not an error: every build still runs, on the JIT kernels; the reason is printed.
    aot.build(exercise_kernels, force=args.force, log=lambda m: print(m, file=sys.stderr))
    return 0
