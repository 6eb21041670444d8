"""Argument types shared by the subcommands."""

from __future__ import annotations

import argparse


def size(text: str) -> tuple[int, int]:
    """``WxH`` as a pair of positive ints."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must be WxH, e.g. 1280x720, got {text!r}") from None
    if w <= 0 or h <= 0:
        raise argparse.ArgumentTypeError("size must be positive")
    return w, h


def floats(text: str) -> list[float]:
    """``0.5,1,2`` as a list of floats."""
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
