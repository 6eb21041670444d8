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
from collections import deque
from dataclasses import dataclass

__all__ = ["FrameTimeController", "PidGains", "PointBudgetController"]


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


class PointBudgetController:
    """Hold a target frame time on point layers: a cost model fitted online, fed forward, plus a PI
    controller on what the model gets wrong.

    The frame time of a point renderer is about ``overhead + cost · points`` (measured on this project's
    off-screen renderer: 0.7 µs a point, a few ms overhead, docs/PERFORMANCE_LOG.md), but the cost per point
    moves with the view (fill: how many points land on how many pixels) and with the machine's load, and a
    loaded machine adds single frames 2–5× too slow. A pure PID on the frame time either follows that
    noise or lags the view. Here:

    * **feed-forward**: the cost per point is the median, over the last ``window`` frames, of
      ``(frame − overhead) / points`` (a robust fit: least squares is thrown by one 5× frame, a median is
      not), and the next budget is the one the model says costs the target;
    * **PI on the residual**: ``log(frame / target)``, clipped to ±``clip`` so one slow frame moves little,
      integrated with gain ``ki`` into a factor on the budget; it removes what the model misses
      persistently (a non-linear cost, an overhead that is not zero) and is frozen while the budget does not
      bind (the view drew all it could: the error says nothing about the budget, and integrating it would
      wind up);
    * **smooth refinement**: while the budget binds it grows by at most ``max_growth`` a frame (new detail
      arrives over several frames, and new point tiles also fade in on screen); it shrinks at once.
      ``deadband`` (off by default) keeps the budget while the model asks for less than that relative
      change: on the real renderer it held a few more frames in the band, on the plant of the tests fewer;
    * **a reachable target**: the budget never exceeds the user's (``base_points``) and τ stays the user's
      (``tau_scale`` 1): a view whose every point at that τ costs less than the target cannot reach it, and
      the budget bench counts those frames apart. (τ/4 was tried, so that sparse views would refine further:
      the finer points of a dense view then cost a third as much each, and fewer frames could reach the
      target within the user's budget; docs/PERFORMANCE_LOG.md.)

    Pure: no clock, no I/O, no VTK.

    Examples
    --------
    >>> c = PointBudgetController(100.0, base_points=1_000_000)
    >>> for _ in range(8):                                  # 0.2 µs a point: 500 k points cost 100 ms
    ...     _ = c.update(0.2e-3 * c.point_budget, c.point_budget, True)
    >>> 450_000 < c.point_budget < 550_000
    True
    """

    def __init__(self, target_ms: float, *, base_points: int, base_tau_px: float = 1.0, window: int = 3,
                 ki: float = 0.1, clip: float = 0.4, max_growth: float = 1.15, min_points: int | None = None,
                 tau_scale: float = 1.0, overhead_ms: float = 0.0, deadband: float = 0.0) -> None:
        if target_ms <= 0 or base_points <= 0:
            raise ValueError("target_ms and base_points must be > 0")
        self.target_ms = float(target_ms)
        self.base_points = int(base_points)
        self.base_tau_px = float(base_tau_px)
        self.ki, self.clip, self.max_growth = float(ki), float(clip), float(max_growth)
        self.min_points = int(min_points if min_points is not None else max(1, base_points // 1000))
        self.overhead_ms = float(overhead_ms)
        self.deadband = float(deadband)
        self._hist: deque[tuple[int, float]] = deque(maxlen=int(window))
        self.correction = 0.0  # log of the PI factor on the feed-forward budget
        self.tau_scale = float(tau_scale)
        self.point_budget = self.base_points
        self.per_point_ms: float | None = None

    @property
    def tau_px(self) -> float:
        return self.base_tau_px * self.tau_scale

    def predict_ms(self, points: int) -> float | None:
        """The model's frame time for ``points`` (None before the first frame)."""
        if self.per_point_ms is None:
            return None
        return self.overhead_ms + self.per_point_ms * points

    def update(self, frame_ms: float, drawn_points: int, budget_limited: bool) -> int:
        """Feed the last frame (its time, the points it drew, whether the budget stopped refinement);
        returns the next frame's point budget."""
        if drawn_points > 0:
            self._hist.append((int(drawn_points), float(frame_ms)))
        if self._hist:
            ratios = sorted(max(ms - self.overhead_ms, 1e-6) / n for n, ms in self._hist)
            mid = len(ratios) // 2
            self.per_point_ms = ratios[mid] if len(ratios) % 2 else 0.5 * (ratios[mid - 1] + ratios[mid])
        e = math.log(max(frame_ms, 1e-3) / self.target_ms)
        if budget_limited:
            self.correction += self.ki * max(-self.clip, min(self.clip, e))
            self.correction = max(-1.0, min(1.0, self.correction))
        if self.per_point_ms is None:
            return self.point_budget
        want = max(self.target_ms - self.overhead_ms, 0.0) / self.per_point_ms * math.exp(-self.correction)
        # Growth is limited while the budget binds: then a larger budget changes what is drawn, and detail
        # arrives over a few frames. A budget that did not bind is never raised: the view drew all it holds,
        # and a model fitted on sparse views (cheap points) would raise it far past what the next dense
        # view can draw in time (measured: 83 and 70 ms against a 41 ms target after such a stretch). It
        # may fall (a view that drew all it holds and was still too slow).
        nxt = min(want, self.point_budget * self.max_growth) if budget_limited else min(want, self.point_budget)
        nxt = min(nxt, float(self.base_points))
        if budget_limited and abs(nxt / self.point_budget - 1.0) < self.deadband:
            return self.point_budget  # a small change is mostly noise, and new tiles cost an upload
        self.point_budget = max(self.min_points, int(nxt))
        return self.point_budget

    def reset(self) -> None:
        """Forget the model and the corrections (a new scene, or budget mode switched on again)."""
        self._hist.clear()
        self.correction = 0.0
        self.point_budget = self.base_points
        self.per_point_ms = None
