"""``citylod render SOURCES -o IMAGE [--camera CAMERA | overview | orbit:N]``: off-screen renders."""

from __future__ import annotations

import argparse
from pathlib import Path

from citylod.cli._args import size


def add_parser(sub: argparse._SubParsersAction) -> None:
    r = sub.add_parser("render", help="off-screen render of tilesets and city stores (a far-field tileset is "
                                      "drawn with its light fields)")
    r.add_argument("sources", type=Path, nargs="+")
    r.add_argument("-o", "--output", type=Path, required=True, help="PNG; with a camera path, a frame pattern")
    r.add_argument("--camera", metavar="CAMERA",
                   help="camera JSON (one camera or a path), or 'overview' (the default: all the data in view) "
                        "or 'orbit[:N]' (N frames once around it, 36 by default)")
    r.add_argument("--tau", type=float, default=1.0, help="screen-space error threshold in pixels")
    r.add_argument("--size", type=size, default=(1280, 720))
    r.add_argument("--depth", type=Path, help="write the depth (distance from the eye) as float32 .npy")
    r.add_argument("--city", type=Path, help="city store (.gpkg) for --highlight / --hide")
    r.add_argument("--highlight", help="SQL WHERE clause of objects to highlight")
    r.add_argument("--hide", help="SQL WHERE clause of objects to hide")
    r.add_argument("--flood", type=Path, metavar="FLOOD_DIR",
                   help="draw the water of a `citylod flood` result (translucent, clipped to the flooded cells)")
    r.add_argument("--flood-index", type=int, default=-1,
                   help="which level of a flood series to draw (default: the last)")
    r.add_argument("--flood-series", action="store_true",
                   help="step through the flood's levels, one per frame of a camera path (the last one stays)")
    r.add_argument("--edits", type=Path, metavar="POLYGONS",
                   help="polygon edits applied while rendering (GeoJSON, KML or GeoPackage with actions)")
    r.add_argument("--color-by", default="auto", help="auto, rgb, classification, elevation, intensity, level")
    r.add_argument("--splats", action="store_true",
                   help="draw points as oriented disks sized by the local spacing (hole-free up close)")
    r.add_argument("--texture-budget", type=_megabytes, metavar="MB",
                   help="cap on the tiles' texture memory; coarser atlases are drawn where it binds")
    r.add_argument("--point-budget", type=_count, metavar="N",
                   help="fixed budget: most points drawn per point layer and frame (0 = unlimited)")
    r.add_argument("--target-ms", type=_milliseconds, metavar="MS",
                   help="budget mode: hold this frame time over a camera path by steering the point budget "
                        "and τ each frame (the fixed ones are the most detail); logs OUTPUT_budget.csv")


def _megabytes(text: str) -> float:
    try:
        mb = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number of megabytes: {text!r}") from None
    if not mb > 0:
        raise argparse.ArgumentTypeError(f"must be more than 0 MB, got {text!r}")
    return mb


def _count(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number of points: {text!r}") from None
    if n < 0:
        raise argparse.ArgumentTypeError(f"must be 0 (unlimited) or more, got {text!r}")
    return n


def _milliseconds(text: str) -> float:
    try:
        ms = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number of milliseconds: {text!r}") from None
    if not 0 < ms < float("inf"):
        raise argparse.ArgumentTypeError(f"must be more than 0 ms, got {text!r}")
    return ms


def run(args: argparse.Namespace, progress: bool) -> int:
    from citylod.render.offscreen import render_command
    from citylod.render.slf import is_far_field, render_far_field_command

    if any(is_far_field(s) for s in args.sources):  # drawn with its fields, not as the average texture
        return render_far_field_command(args, progress=progress)
    return render_command(args, progress=progress)
