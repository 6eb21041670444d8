"""Budget mode on a real renderer: how often the frame time stays within ±20 % of the target.

``python -m citylod.bench.budget_bench [FRAMES] [FRACTION]`` writes a synthetic point tileset, flies the
default flight off screen once with the fixed point budget (the baseline, same run) and once in budget mode
(:class:`~citylod.render.frame_budget.FrameBudget`) with the target set to FRACTION (default 0.5) of the
baseline's median frame time, and prints the share of frames within ±20 % of the target for both. Frames
are resolved (all selected tiles resident) before each draw, so the time is the draw's. Not an assertion.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np


def run(frames: int = 60, fraction: float = 0.5) -> dict[str, object]:
    from citylod.bench.flight import default_flight
    from citylod.bench.synthetic import make_point_tileset
    from citylod.render.frame_budget import FrameBudget
    from citylod.render.offscreen import OffscreenRenderer

    corner = np.array([500000.0, 5400000.0, 0.0])
    ext = 512.0
    with tempfile.TemporaryDirectory() as tmp:
        tiles = make_point_tileset(Path(tmp) / "pts", levels=5, points_per_tile=6000, extent=ext, corner=corner)
        cams = default_flight(corner, corner + np.array([ext, ext, 30.0]), n=frames)
        fixed: list[float] = []
        with OffscreenRenderer([tiles], size=(960, 540), tau_px=0.5) as r:
            for cam in cams:
                r.prepare(cam)
                fixed.append(r.draw() * 1000.0)
        target = fraction * statistics.median(fixed)
        with OffscreenRenderer([tiles], size=(960, 540), tau_px=0.5) as r:
            mode = FrameBudget(r.scene, target)
            for cam in cams:
                r.prepare(cam)
                r.draw()
            steered = list(mode.frame_ms)
    def share(ts: list[float], t: float) -> float:
        return float(np.mean(np.abs(np.asarray(ts) / t - 1.0) <= 0.2))

    return {"target_ms": target, "fixed_ms": fixed, "budget_ms": steered,
            "fixed_within": share(fixed, statistics.median(fixed)), "budget_within": share(steered, target)}


def main(argv: list[str]) -> None:
    res = run(int(argv[0]) if argv else 60, float(argv[1]) if len(argv) > 1 else 0.5)
    f, b = res["fixed_ms"], res["budget_ms"]
    print(f"target {res['target_ms']:.1f} ms ({len(b)} frames of the default flight)")
    print(f"  fixed budget: median {statistics.median(f):.1f} ms, within ±20 % of its own median: "
          f"{100 * res['fixed_within']:.0f} %")
    print(f"  budget mode:  median {statistics.median(b):.1f} ms, within ±20 % of the target: "
          f"{100 * res['budget_within']:.0f} %")
    print("  budget-mode frames (ms):", ", ".join(f"{v:.0f}" for v in b))


if __name__ == "__main__":
    main(sys.argv[1:])
