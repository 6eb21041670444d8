"""``citylod build-kernels``: compile the DSM build's kernels ahead of time and fill numba's cache with the points
build's (what ``make`` runs)."""

from __future__ import annotations

import argparse
import sys


def add_parser(sub: argparse._SubParsersAction) -> None:
    bk = sub.add_parser("build-kernels", help="compile the DSM build's kernels ahead of time and cache the points "
                        "build's (what `make` runs; saves numba's start in every DSM build, ≈0.5 s, and "
                        "≈20 s of compiling in the first points build)")
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
    # The points build's kernels stay JIT-compiled (numba's on-disk cache): one small build fills the cache, a
    # second or so when it is full.
    import time
    import warnings

    from citylod.lod.build import points

    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the test clouds' CRS has no vertical datum: not the user's concern
        points.exercise_kernels()
    if time.perf_counter() - t0 > 5.0:
        print(f"cached the points build's kernels ({time.perf_counter() - t0:.0f} s, once)", file=sys.stderr)
    return 0
