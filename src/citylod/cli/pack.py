"""``citylod pack TILES -o OUT.3tz|OUT.3dtiles``: a tileset folder as one package file (a 3D Tiles Archive, or
a 3DTILES SQLite database)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    pk = sub.add_parser("pack", help="pack a tileset folder into one .3tz archive (3D Tiles Archive Format, "
                                     "with its index) or .3dtiles database")
    pk.add_argument("tiles", type=Path, help="a tileset folder (or its tileset.json)")
    pk.add_argument("-o", "--output", type=Path, required=True, help="the .3tz or .3dtiles file to write")
    pk.add_argument("--deflate", action="store_true",
                    help="deflate the entries (smaller; by default they are stored, which reads fastest)")


def run(args: argparse.Namespace, progress: bool) -> int:
    from citylod.core.errors import InputError
    from citylod.io.tiles3d.archive3tz import write_package

    folder = args.tiles.parent if args.tiles.name == "tileset.json" else args.tiles
    if not folder.is_dir():
        raise InputError("not a tileset folder", args.tiles)
    suffix = args.output.suffix.lower()
    if suffix not in (".3tz", ".3dtiles"):
        raise InputError("the package must be named *.3tz (3D Tiles Archive) or *.3dtiles (SQLite)", args.output)
    if suffix == ".3dtiles" and args.deflate:
        raise InputError("--deflate is for .3tz archives", args.output)
    t0 = time.perf_counter()
    bar = None
    if progress:
        from tqdm import tqdm

        bar = lambda files: tqdm(files, desc="pack", unit="file", leave=False)  # noqa: E731
    n = write_package(folder, args.output, compress=args.deflate, progress=bar)
    size = args.output.stat().st_size
    print(f"{args.output}: {n} files, {size / 1e6:.1f} MB, {time.perf_counter() - t0:.1f} s")
    return 0
