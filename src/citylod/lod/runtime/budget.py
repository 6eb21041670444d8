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

import bisect
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["CostModel", "FeedForwardBudgetController", "FrameTimeController", "PidGains", "PointBudgetController"]


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


class CostModel:
    """Frame time as a machine speed times a sum of per-element costs, fitted online:
    ``ms ≈ s · (c₀ + c_p·points + c_t·triangles + c_n·new)`` (``new``: points and triangles of tiles not
    drawn the frame before, whose buffers the GL builds during the frame).

    Two time scales, because the two parts change at different rates. The **costs** ``c`` (what a point,
    a triangle, an upload, the frame's overhead cost) are fitted by recursive least squares with slow
    forgetting (``forget`` per frame) on the frames' times: relative
    errors (each frame weighs ``1/ms²``) with a Huber weight (a frame off by more than ``huber`` weighs
    ``huber/|error|``), and a ridge toward ``prior`` so that a cost no frame has exercised (no triangles yet)
    stays at its prior instead of being undefined. The **speed** ``s`` (the machine's load, the view's fill)
    is the median over the last ``window`` frames of measured / fitted time (the fit does not depend on it,
    so the two cannot chase each other): it follows a drift within a
    few frames, and one 3× slow frame of a loaded machine moves neither part much (least squares alone was
    thrown by such frames, docs/PERFORMANCE_LOG.md). A frame added with ``restart`` (a camera cut: most of what it
    drew is new) starts the speed's window afresh: the last frames' speeds belong to another view, and with
    them the frame after a cut was predicted from the view before it (1.8× too fast on the budget bench).
    Coefficients are clamped at 0.

    Examples
    --------
    >>> m = CostModel()
    >>> for p in (100_000, 300_000, 200_000, 400_000, 250_000, 350_000):
    ...     m.add(2.0 + 1e-4 * p, points=p)
    >>> abs(m.predict(points=1_000_000) - 102.0) < 2.0     # 2 ms + 0.1 µs a point
    True
    """

    def __init__(self, *, forget: float = 0.9, huber: float = 0.3, window: int = 3,
                 prior: Sequence[float] = (1.0, 0.0, 0.0, 0.0),
                 prior_weight: Sequence[float] = (0.3, 1e-6, 1e-6, 0.3)) -> None:
        self.forget, self.huber = float(forget), float(huber)
        self.prior = np.asarray(prior, np.float64)
        self.prior_weight = np.asarray(prior_weight, np.float64)
        self.S = np.zeros((4, 4))
        self.b = np.zeros(4)
        self.frames = 0
        self.coef = self.prior.copy()
        self.speed = 1.0
        self._recent: deque[tuple[np.ndarray, float]] = deque(maxlen=int(window))
        self._history: deque[tuple[np.ndarray, float]] = deque(maxlen=20)  # (coef, speed) after each frame

    @staticmethod
    def features(points: float, triangles: float = 0.0, new: float = 0.0) -> np.ndarray:
        return np.array([1.0, points * 1e-5, triangles * 1e-5, new * 1e-5])  # per 100 k elements

    def predict(self, points: float, triangles: float = 0.0, new: float = 0.0, *, cautious: bool = False) -> float:
        """Predicted ms. ``cautious``: the upper quartile of what the models of the last 20 frames (costs and
        speed as they stood after each) predict, for the first frame of a new view, whose costs no recent
        frame tells (a stretch of cheap views teaches the model cheap points; a quartile, not the maximum, so
        that one 3× frame of a loaded machine does not set it)."""
        phi = self.features(points, triangles, new)
        if cautious and self._history:
            return float(np.quantile([s * float(phi @ c) for c, s in self._history], 0.75))
        return self.speed * float(phi @ self.coef)

    def add(self, ms: float, points: float, triangles: float = 0.0, new: float = 0.0, *,
            restart: bool = False) -> None:
        phi = self.features(points, triangles, new)
        ms = max(float(ms), 1e-3)
        y = ms
        guess = float(phi @ self.coef) if self.frames else y
        scale = max(guess, 1e-3)
        err = abs(y - guess) / scale
        w = (1.0 if err <= self.huber else (self.huber / err) ** 2) / (scale * scale)
        self.S = self.forget * self.S + w * np.outer(phi, phi)
        self.b = self.forget * self.b + w * phi * y
        self.frames += 1
        ridge = np.diag(self.prior_weight / (scale * scale))  # in frames' worth of weight
        self.coef = np.maximum(np.linalg.solve(self.S + ridge, self.b + ridge @ self.prior), 0.0)
        if restart:
            self._recent.clear()
        self._recent.append((phi, ms))
        ratios = sorted(m / max(float(f @ self.coef), 1e-6) for f, m in self._recent)
        mid = len(ratios) // 2
        self.speed = ratios[mid] if len(ratios) % 2 else 0.5 * (ratios[mid - 1] + ratios[mid])
        self._history.append((self.coef.copy(), self.speed))

    def reset(self) -> None:
        self.S[:] = 0.0
        self.b[:] = 0.0
        self.frames = 0
        self.coef = self.prior.copy()
        self.speed = 1.0
        self._recent.clear()
        self._history.clear()


# A model whose first frame built its buffers (see FeedForwardBudgetController.update): its second frame is
# planned for this factor over the model's price (the first frame ran 1.1–2.0× the same frame drawn again on
# the budget bench, 1.3 interleaved, 1.6–2.0 alone), at the low end because the two errors are not alike: a
# second frame under the band is recovered in the third (the first frame is forgotten when the second comes
# in under _FIRST_FRAME_SLACK of the model's price), one over it is not (the model keeps both frames).
# 1.41 put the second frame at 1.27–1.56× the target in three of four interleaved runs.
_FIRST_FRAME_SLACK = 0.75
_FIRST_FRAME_HEDGE = 1.25


class FeedForwardBudgetController:
    """Hold a target frame time on point layers by choosing each frame's point budget *before* it is drawn,
    from that frame's candidate tiles and a fitted cost model (Kehl et al.'s controller with a cost model
    in front of it), with a PI controller correcting only what the model gets wrong.

    Per frame:

    1. :meth:`plan` gets the next frame's **cost curve**: the budget's admissions in order
       (:attr:`~citylod.lod.runtime.selection.Selection.admitted` of a selection at the user's τ and
       budget), each as cumulative ``(points, triangles, new)``. It picks the longest prefix whose
       predicted time (:class:`CostModel`) stays within ``target·exp(−correction)`` and returns the
       budget that admits exactly that prefix. A view change is thereby met in the frame it happens: the
       curve of the new view, not the last frame's error, sets the budget.
    2. :meth:`update` gets the frame's measured time and what it drew: the model is refitted, and while the
       budget bound, the PI integrates the clipped log error of the frame against the target with gain
       ``ki`` (what the model misses persistently: a non-linear cost, the prefix's granularity). Against the
       target, not the prediction: the model already learns its own error, and integrating that too wound
       the correction up while the frames were on target (measured on the plant of tests/lod/test_budget.py).

    **Smooth refinement**: the budget grows by at most ``max_growth`` a frame (new detail arrives over a
    few frames; new point tiles also fade in on screen); it shrinks at once. A budget the view did not need
    (everything in view fitted) is not raised past what the view drew: a model fitted on sparse, cheap
    views would otherwise send the next dense view far over the target.

    **Start**: the first frame draws the user's budget (there is no model yet). When it built most of its
    buffers (a renderer's first draw), its one-time costs are taken into account for the second frame
    (planned 1.25× over the model's price) and forgotten after it, when the second frame shows them;
    the third frame's budget is then not bounded by the second's growth.

    **Views too light for the target**: when everything in view at the user's τ is predicted to cost less
    than the target, the frame draws it all (:attr:`reachable` is False); τ is not lowered, since the data
    may hold nothing finer (on the budget bench's flight these views draw their leaves already) and a finer
    τ made dense views cheaper per point than their budget could use (docs/PERFORMANCE_LOG.md).

    Pure: no clock, no I/O, no VTK.

    Examples
    --------
    >>> c = FeedForwardBudgetController(40.0, base_points=1_000_000)
    >>> curve = [(k * 50_000, 0, 0) for k in range(1, 21)]          # 50 k points per admission
    >>> for _ in range(6):                                           # 0.1 µs a point + 5 ms
    ...     b = c.plan(curve)
    ...     c.update(5.0 + 1e-4 * min(b, 1_000_000), min(b, 1_000_000), budget_limited=b < 1_000_000)
    >>> 300_000 <= c.point_budget <= 350_000
    True
    """

    def __init__(self, target_ms: float, *, base_points: int, base_tau_px: float = 1.0, ki: float = 0.1,
                 clip: float = 0.4, max_growth: float = 1.15, min_points: int | None = None,
                 model: CostModel | None = None, cut_share: float = 0.7) -> None:
        if target_ms <= 0 or base_points <= 0:
            raise ValueError("target_ms and base_points must be > 0")
        self.target_ms = float(target_ms)
        self.base_points = int(base_points)
        self.base_tau_px = float(base_tau_px)
        self.tau_scale = 1.0
        self.ki, self.clip, self.max_growth = float(ki), float(clip), float(max_growth)
        self.min_points = int(min_points if min_points is not None else max(1, base_points // 1000))
        self.model = model or CostModel()
        self.cut_share = float(cut_share)  # new share of a view that makes it a cut (> 1: never)
        self.correction = 0.0
        self.point_budget = self.base_points
        self.predicted_ms: float | None = None
        self.reachable = True
        self._first_new = False  # the model's only frame built most of what it drew
        self._uncap = False  # the next budget is not bounded by the last one's growth
        self._model_ms: float | None = None  # the model's own prediction for the planned frame

    @property
    def tau_px(self) -> float:
        return self.base_tau_px

    def plan(self, curve: Sequence[tuple[int, int, int]]) -> int:
        """The point budget for the next frame from its cost curve (cumulative ``(points, triangles, new)``
        per admission, in order; the first entry is drawn whatever the budget)."""
        if not curve:
            self.predicted_ms = None
            return self.point_budget
        if not self.model.frames:  # no measurement yet: the user's budget (the first frame warms up)
            self.predicted_ms = self._model_ms = None
            self.reachable = True
            return self.point_budget
        # The frame after a first frame that built its buffers: that frame's one-time costs make the
        # model price this one high (_FIRST_FRAME_HEDGE).
        hedge = _FIRST_FRAME_HEDGE if self.model.frames == 1 and self._first_new else 1.0
        goal = self.target_ms * math.exp(-self.correction) * hedge
        cap = float(self.base_points) if self._uncap else min(float(self.base_points),
                                                               self.point_budget * self.max_growth)
        self._uncap = False
        # A view mostly new to the GL (a camera cut) is priced cautiously (CostModel.predict): the last
        # frames' costs are another view's, and on the budget bench the first frame after a cut from a
        # sparse stretch took 1.8× its prediction. The new share is taken over the prefix the last budget
        # admits (beyond it, tiles are new in any view).
        j = max(bisect.bisect_right([c[0] for c in curve], self.point_budget) - 1, 0)
        cut = curve[j][2] > self.cut_share * (curve[j][0] + curve[j][1])
        k = 0
        for i, (pts, tri, new) in enumerate(curve):
            if pts > cap or self.model.predict(pts, tri, new, cautious=cut) > goal:
                break
            k = i
        else:
            k = len(curve) - 1
        total = curve[-1][0]
        self.reachable = self.model.predict(*curve[-1], cautious=cut) >= goal or total > cap
        pts = curve[k][0]
        if k == len(curve) - 1:  # all of the view fits: keep the budget, raised to the view if need be
            self.point_budget = max(self.min_points, int(min(cap, max(self.point_budget, pts))))
        else:  # the budget binds: the largest budget that still refuses the next admission
            self.point_budget = max(self.min_points, int(min(cap, max(pts, curve[k + 1][0] - 1))))
        self._model_ms = self.model.predict(*curve[k], cautious=cut)
        self.predicted_ms = self._model_ms / hedge
        return self.point_budget

    def update(self, frame_ms: float, drawn_points: int, drawn_triangles: int = 0, new_elements: int = 0,
               budget_limited: bool = True) -> None:
        """Feed the frame just drawn: its time, what it drew (points, triangles, elements new to the GL) and
        whether the budget stopped refinement. A frame where most of what it drew is new (a camera cut)
        restarts the model's speed window (:class:`CostModel`)."""
        mostly_new = new_elements > self.cut_share * (drawn_points + drawn_triangles)
        cut = self.model.frames > 0 and mostly_new
        forget = bool(self.model.frames == 1 and self._first_new and self._model_ms
                      and frame_ms < _FIRST_FRAME_SLACK * self._model_ms)
        if forget:
            # The first frame built its buffers (a renderer's first draw: uploads, shader compiles; on the
            # budget bench 1.1–2.0× the same frame drawn again). With one frame that one-time cost is taken for
            # the points' cost, so this frame's budget came out short of what the target allows, and the
            # bounded growth would take five frames to get there. The first frame is forgotten, and the next
            # budget may go straight to the model's: it was wrong, not a view change.
            self.model.reset()
            self._uncap = True
            cut = False
        self._first_new = self.model.frames == 0 and mostly_new and not forget  # once per start
        self.model.add(frame_ms, drawn_points, drawn_triangles, new_elements, restart=cut)
        if budget_limited:
            e = math.log(max(frame_ms, 1e-3) / self.target_ms)
            self.correction += self.ki * max(-self.clip, min(self.clip, e))
            self.correction = max(-1.0, min(1.0, self.correction))

    def reset(self) -> None:
        """Forget the model and the corrections (a new scene, or budget mode switched on again)."""
        self.model.reset()
        self.correction = 0.0
        self._first_new = self._uncap = False
        self.point_budget = self.base_points
        self.predicted_ms = None
        self.reachable = True
