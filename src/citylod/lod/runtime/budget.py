"""Rendering on a frame-time budget: a PID controller that steers τ and the point budget.

Kehl, Tutenel, Eisemann (flood visualisation) hold interactive frame rates on large point sets with a
PID controller on the measured frame time that sets how much detail a frame may draw. Here the controlled
variable is one *detail scale* ``s`` (s = 1: the user's τ and point budget). With a point budget, the budget
is what moves (``points / s²``, τ stays the user's): the budget admits nodes one by one in priority order
(Potree), so the frame time follows it finely, while τ moves whole levels at once near a level's switching
distance and makes the frame time jump (measured in tests/lod/test_budget.py). Without one (meshes) the
threshold ``τ·s`` moves (the work a view needs falls with about the square of τ: errors halve per level
while tile counts quadruple in area).

The error is ``log(frame / target)``, so being twice too slow weighs as much as being twice too fast, and
the controller acts on ``log s`` in incremental form (each frame adds kp·Δe + ki·e + kd·Δ²e, so limits and
the rate limit cannot wind anything up). The plant's gain is about −2 (frame time ∝ s⁻²), so ki = 0.25
removes half of an error per frame (faster gains follow measurement noise: ki = 0.4 held fewer frames
within ±20 % at 15 % noise per frame). Steps toward more detail are limited (``max_step``), so detail grows
gradually; point tiles that appear also fade in (smooth refinement in :mod:`citylod.render.tileset_actor`),
so a frame never pops.

Pure: no clock, no I/O, no VTK. The caller measures frame times and applies :attr:`tau_px` and
:attr:`point_budget` (``Scene`` in render/ does both in budget mode).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["FrameTimeController", "PidGains"]


@dataclass(frozen=True)
class PidGains:
    """Gains on ``log(frame/target)`` → ``log s`` per frame (the defaults are tuned in tests/lod/test_budget.py
    on plants whose cost falls with s² like a point layer's)."""

    kp: float = 0.1
    ki: float = 0.25
    kd: float = 0.0


class FrameTimeController:
    """Hold a target frame time by scaling τ and the point budget.

    Parameters
    ----------
    target_ms
        Frame time to hold.
    base_tau_px
        The user's threshold (scale 1).
    base_points
        The user's point budget (scale 1), or None for no point budget.
    min_scale, max_scale
        Limits on the detail scale: τ stays in [base·min_scale, base·max_scale].
    gains
        PID gains.
    max_step, max_step_coarser
        Largest change of ``log s`` in one frame toward more detail (0.25: the point budget grows by at most
        65 % a frame) and toward less (1.0).

    Examples
    --------
    >>> c = FrameTimeController(16.0, base_tau_px=1.0)
    >>> for _ in range(5):
    ...     _ = c.update(40.0)              # too slow: τ rises
    >>> c.tau_px > 1.0
    True
    >>> p = FrameTimeController(16.0, base_points=1_000_000)
    >>> _ = p.update(40.0)                  # with a point budget, the budget falls instead
    >>> p.point_budget < 1_000_000 and p.tau_px == 1.0
    True
    """

    def __init__(self, target_ms: float, *, base_tau_px: float = 1.0, base_points: int | None = None,
                 min_scale: float = 0.25, max_scale: float = 64.0, gains: PidGains | None = None,
                 max_step: float = 0.25, max_step_coarser: float = 1.0) -> None:
        if target_ms <= 0 or base_tau_px <= 0:
            raise ValueError("target_ms and base_tau_px must be > 0")
        if not 0 < min_scale <= 1.0 <= max_scale:
            raise ValueError(f"need 0 < min_scale <= 1 <= max_scale, got {min_scale}, {max_scale}")
        self.target_ms = float(target_ms)
        self.base_tau_px = float(base_tau_px)
        self.base_points = base_points
        self.gains = gains or PidGains()
        self.max_step = float(max_step)
        self.max_step_coarser = float(max_step_coarser)
        self._lo, self._hi = math.log(min_scale), math.log(max_scale)
        self.log_scale = 0.0
        self._last: float | None = None
        self._last2 = 0.0

    @property
    def scale(self) -> float:
        """The detail scale s (> 1: coarser than the user asked)."""
        return math.exp(self.log_scale)

    @property
    def tau_px(self) -> float:
        return self.base_tau_px if self.base_points is not None else self.base_tau_px * self.scale

    @property
    def point_budget(self) -> int | None:
        if self.base_points is None:
            return None
        return max(1, int(self.base_points / (self.scale * self.scale)))

    def update(self, frame_ms: float, drawn_points: int | None = None, budget_limited: bool = True) -> float:
        """Feed the last frame's time; returns the new scale.

        With a point budget, pass the points the frame drew and whether the budget stopped refinement
        (``SelectionStats.budget_limited``). A budget that did not bind says nothing about cost: when the
        frame was too slow the scale first moves to where the budget equals ``drawn_points`` (so the step
        acts at once), and when it was too fast the budget is not raised (the view drew all it needs;
        raising would only wind up and overshoot when the view changes).
        """
        e = math.log(max(frame_ms, 1e-3) / self.target_ms)
        free = self.base_points is not None and drawn_points is not None and not budget_limited
        if free and e > 0 and drawn_points and self.base_points is not None:
            self.log_scale = min(self._hi, max(self.log_scale, 0.5 * math.log(self.base_points / drawn_points)))
        g = self.gains
        last = e if self._last is None else self._last
        last2 = e if self._last is None else self._last2
        # Incremental (velocity) PID: the change of log s is kp·Δe + ki·e + kd·Δ²e. Limits and the rate
        # limit then cannot wind up an integral, since none is stored.
        du = g.kp * (e - last) + g.ki * e + g.kd * (e - 2.0 * last + last2)
        self._last2, self._last = last, e
        if free and e < 0:
            du = max(du, 0.0)  # the view drew all it needs: a larger budget would only wind up
        # Coarsening may be quick (a slow frame is worse than a coarse one); refining is slow, and new
        # point tiles fade in on top, so detail grows without popping.
        du = max(-self.max_step, min(self.max_step_coarser, du))
        self.log_scale = max(self._lo, min(self._hi, self.log_scale + du))
        return self.scale

    def reset(self) -> None:
        """Back to the user's τ and budget (a new scene, or budget mode switched on again)."""
        self.log_scale = 0.0
        self._last = None
        self._last2 = 0.0
