"""``citylod view [SOURCES]``: the desktop application."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    v = sub.add_parser("view", help="the desktop application")
    v.add_argument("sources", type=Path, nargs="*")
    v.add_argument("--screenshot", type=Path, help="save a screenshot of the window")
    v.add_argument("--exit", action="store_true", help="quit after loading (and the screenshot)")
    v.add_argument("--camera", type=Path, help="start from this camera JSON (citylod render's format)")
    v.add_argument("--profile-gui", action="store_true",
                   help="time every GUI-thread handler and event; log those over 100 ms, print the longest at exit")


def run(args: argparse.Namespace, progress: bool) -> int:
    from citylod.app.main import run_app

    return run_app(args.sources, screenshot=args.screenshot, exit_after=args.exit, camera=args.camera,
                   profile_gui=args.profile_gui)
