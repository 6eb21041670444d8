"""``citylod link CITY.gpkg POINTS.laz -o OUT.laz``: the containing city object's id for every point."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    lk = sub.add_parser("link", help="write the id of the containing city object into each point")
    lk.add_argument("store", type=Path)
    lk.add_argument("points", type=Path)
    lk.add_argument("-o", "--output", type=Path, required=True)


def run(args: argparse.Namespace, progress: bool) -> int:
    from citylod.semantics.link import link_command

    return link_command(args.store, args.points, args.output, progress=progress)
