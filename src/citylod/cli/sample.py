"""``citylod sample OUT_DIR``: a reproducible synthetic city (or, with ``--textured N``, N textured houses)."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    s = sub.add_parser("sample", help="write a reproducible synthetic city (DSM, orthophoto, LAZ, CityGML)")
    s.add_argument("out_dir", type=Path)
    s.add_argument("--size", type=int, default=513, help="DSM size in samples per side (default 513)")
    s.add_argument("--seed", type=int, default=7)
    s.add_argument("--textured", type=int, metavar="N",
                   help="instead: N LoD2 houses with their own facade and roof images (CityGML + textures/)")
    s.add_argument("--image-px", type=int, default=256, help="side of each texture image with --textured")


def run(args: argparse.Namespace, progress: bool) -> int:
    if args.textured is not None:
        from citylod.sample.textured import make_textured_city

        city = make_textured_city(args.out_dir, buildings=args.textured, seed=args.seed, image_px=args.image_px,
                                  progress=progress)
        print(f"city       {city.path}")
        print(f"textures   {city.path.parent / 'textures'} ({2 * len(city.houses)} images of {city.image_px} px)")
        return 0
    from citylod.sample import make_sample

    info = make_sample(args.out_dir, size=args.size, seed=args.seed)
    for name, path in info.files.items():
        print(f"{name:10s} {path}")
    return 0
