"""``citylod sample OUT_DIR``: a reproducible synthetic city."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("sample", help="write a reproducible synthetic city (DSM, orthophoto, LAZ, CityGML)")
    s.add_argument("out_dir", type=Path)
    s.add_argument("--size", type=int, default=513, help="DSM size in samples per side (default 513)")
    s.add_argument("--seed", type=int, default=7)


def run(args: argparse.Namespace, progress: bool) -> int:
    from citylod.sample import make_sample

    info = make_sample(args.out_dir, size=args.size, seed=args.seed)
    for name, path in info.files.items():
        print(f"{name:10s} {path}")
    return 0
