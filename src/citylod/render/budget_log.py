"""Budget mode for ``citylod render --camera PATH.json --target-ms MS``: a fly-through on a frame-time budget.

:class:`BudgetRun` sets the fixed point budget (``--point-budget``) on the point layers, attaches a
:class:`~citylod.render.frame_budget.FrameBudget` when a target is given, and logs each frame: the point
budget it set, the points drawn and the frame time it measured (the draw until the GL finished, as
:class:`FrameBudget` times it; selection and tile loading are outside it, since an off-screen frame waits for
its tiles). The log is a CSV next to the frames; one summary line tells the median frame time against the
target and the share of frames within ±20 % of it (the issue's measure). No Qt.
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path
from typing import Any

from citylod.core.fileio import atomic_write_text
from citylod.lod.runtime.selection import Budget

__all__ = ["BudgetRun", "budget_log_path"]

#: A frame counts as on target within this relative band (the issue's ±20 %).
BAND = 0.2


def budget_log_path(output: Path) -> Path:
    """Where the per-frame log of ``--target-ms`` goes: ``<stem>_budget.csv`` next to the frames."""
    return output.with_name(f"{output.stem}_budget.csv")


class BudgetRun:
    """The fixed budget and budget mode of one ``render`` command over a scene.

    Parameters
    ----------
    scene
        The off-screen renderer's scene.
    point_budget
        Fixed point budget per point layer (None: the layers keep theirs; 0: unlimited).
    target_ms
        Frame time to hold over the camera path (None: fixed budgets, nothing logged).
    """

    def __init__(self, scene: Any, point_budget: int | None, target_ms: float | None) -> None:
        self.scene = scene
        if point_budget is not None:
            for layer in scene.layers:
                if layer.budget is not None or layer.kind == "points":
                    layer.budget = Budget(max_points=int(point_budget)) if point_budget > 0 else None
        self.target_ms = target_ms
        self.mode: Any = None
        if target_ms is not None:
            from citylod.render.frame_budget import FrameBudget

            self.mode = FrameBudget(scene, float(target_ms))
        self.rows: list[tuple[int, int, int, float]] = []

    @classmethod
    def from_args(cls, scene: Any, args: argparse.Namespace) -> BudgetRun:
        return cls(scene, getattr(args, "point_budget", None), getattr(args, "target_ms", None))

    def frame(self, index: int, stats: Any) -> None:
        """Record the frame just drawn (call after the render)."""
        if self.mode is None or not self.mode.frame_ms:
            return
        budget = sum(int(layer.budget.max_points) for layer in self.scene.layers
                     if layer.budget is not None and layer.budget.max_points)
        self.rows.append((index, budget, int(stats.points), float(self.mode.frame_ms[-1])))

    def within(self) -> float:
        """Share of the logged frames whose time is within ±20 % of the target."""
        if not self.rows or not self.target_ms:
            return 0.0
        return sum(abs(ms / self.target_ms - 1.0) <= BAND for *_, ms in self.rows) / len(self.rows)

    def finish(self, output: Path) -> str | None:
        """Write the log (``frame,point_budget,points_drawn,frame_ms,target_ms``) and return the summary
        line; None when budget mode is off."""
        if self.mode is None:
            return None
        self.mode.close()
        path = budget_log_path(output)
        lines = ["frame,point_budget,points_drawn,frame_ms,target_ms"]
        lines += [f"{i},{b},{p},{ms:.3f},{self.target_ms:g}" for i, b, p, ms in self.rows]
        atomic_write_text(path, "\n".join(lines) + "\n")
        med = statistics.median(ms for *_, ms in self.rows) if self.rows else float("nan")
        return (f"budget mode: median frame {med:.1f} ms vs target {self.target_ms:g} ms, "
                f"{100 * self.within():.0f} % of {len(self.rows)} frames within ±20 %; log {path}")
