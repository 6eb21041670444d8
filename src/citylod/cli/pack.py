"""``citylod pack TILES -o OUT.3tz``: a tileset folder as one 3D Tiles Archive (3TZ) file."""

from __future__ import annotations

import argparse
import time
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    pk = sub.add_parser("pack", help="pack a tileset folder into one .3tz archive (3D Tiles Archive Format, "
                                     "with its index)")
    pk.add_argument("tiles", type=Path, help="a tileset folder (or its tileset.json)")
    pk.add_argument("-o", "--output", type=Path, required=True, help="the .3tz file to write")
    pk.add_argument("--deflate", action="store_true",
                    help="deflate the entries (smaller; by default they are stored, which reads fastest)")


def run(args: argparse.Namespace, progress: bool) -> int:
    from citylod.core.errors import InputError
    from citylod.io.tiles3d.archive3tz import write_3tz

    folder = args.tiles.parent if args.tiles.name == "tileset.json" else args.tiles
    if not folder.is_dir():
        raise InputError("not a tileset folder", args.tiles)
    if args.output.suffix.lower() != ".3tz":
        raise InputError("a 3D Tiles Archive must be named *.3tz", args.output)
    t0 = time.perf_counter()
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    if progress:
        from tqdm import tqdm

        n = write_3tz(folder, args.output, compress=args.deflate,
                      progress=tqdm(files, desc="pack", unit="file", leave=False))
    else:
        n = write_3tz(folder, args.output, compress=args.deflate)
    size = args.output.stat().st_size
    print(f"{args.output}: {n} files, {size / 1e6:.1f} MB, {time.perf_counter() - t0:.1f} s")
    return 0
