"""Budget mode for a scene: hold a target frame time by steering τ and the point budget every frame.

:class:`FrameBudget` times each render of the scene's renderer (VTK ``StartEvent`` to ``EndEvent``, then waits
for the GL to finish, so the time is the completed frame's). Point layers are steered by a
:class:`~citylod.lod.runtime.budget.FeedForwardBudgetController`: before each frame's selection
(``Scene.before_select``) it selects the point layers once more at the user's τ and budget, reads the cost
curve of that view's candidate tiles (:attr:`~citylod.lod.runtime.selection.Selection.admitted`) and sets
the point budget whose predicted time, by a cost model fitted online on the frames drawn, is the target; a
PI controller corrects what the model misses, and the budget grows by a bounded factor a frame.
``controller="median"`` keeps the previous controller (:class:`~citylod.lod.runtime.budget.PointBudgetController`:
reacts to the last frames' cost per point), for comparisons. Other layers (meshes) get τ from a
:class:`~citylod.lod.runtime.budget.FrameTimeController` (PID on the frame time); their triangles enter the
point layers' cost model. Fixed budgets stay what they were when the mode is switched off (:meth:`close`).
While the mode is on, full garbage collections wait (:class:`~citylod.core.gc_policy.GcPolicy`): one in a
timed draw is a frame 20–30 ms over the target.
Creates no VTK objects; call from the GL thread. No Qt.
"""

from __future__ import annotations

import bisect
import time
from typing import Any

from citylod.core.camera import View
from citylod.core.gc_policy import GcPolicy
from citylod.lod.runtime.budget import FeedForwardBudgetController, FrameTimeController, PointBudgetController
from citylod.lod.runtime.selection import Budget, select
from citylod.render import _vtk

__all__ = ["FrameBudget"]


class FrameBudget:
    """Budget mode on a :class:`~citylod.render.tileset_actor.Scene`.

    Parameters
    ----------
    scene
        The scene whose renders are timed.
    target_ms
        Frame time to hold.
    controller
        ``"feedforward"`` (default: cost model on the next frame's candidates, PI on the residual) or
        ``"median"`` (the previous, reactive controller).
    """

    def __init__(self, scene: Any, target_ms: float, controller: str = "feedforward") -> None:
        if controller not in ("feedforward", "median"):
            raise ValueError(f"controller must be 'feedforward' or 'median', got {controller!r}")
        self.scene = scene
        self._saved = [(layer, layer.budget, layer.tau_px) for layer in scene.layers]
        self._points = [layer for layer in scene.layers if layer.budget is not None and layer.budget.max_points]
        self._others = [layer for layer in scene.layers if layer not in self._points]
        base_points = sum(int(layer.budget.max_points) for layer in self._points) or None
        self._share = {id(layer): int(layer.budget.max_points) / base_points for layer in self._points} \
            if base_points else {}
        self.points_ctl: FeedForwardBudgetController | PointBudgetController | None = None
        if base_points and controller == "feedforward":
            self.points_ctl = FeedForwardBudgetController(target_ms, base_points=base_points)
            scene.before_select = self._plan
        elif base_points:
            self.points_ctl = PointBudgetController(target_ms, base_points=base_points)
        self.tau_ctl = FrameTimeController(target_ms, base_tau_px=scene.tau_px) if self._others else None
        self.frame_ms: list[float] = []
        self.active = True  # False: renders are neither timed nor steered (a redraw for a measurement)
        self.predicted_ms: list[float | None] = []
        self._planned = -1
        self._drawn: dict[int, set[str]] = {id(layer): set() for layer in self._points}
        self._other_triangles = 0
        self._t0 = 0.0
        ren = scene.renderer
        self._tags = [ren.AddObserver(_vtk.vtkCommand.StartEvent, self._start),
                      ren.AddObserver(_vtk.vtkCommand.EndEvent, self._end)]
        self._gc = GcPolicy()
        self._gc.install()  # what lives now (the scene, its tiles) is frozen; full collections wait

    # -- feed-forward: the next frame's budget from its candidates ---------------------------------------
    def _cost(self, key: str) -> int:
        info = self.scene.cache.info(key)
        return 0 if info is None else int(info.points) + int(info.triangles)

    def _layer_curve(self, layer: Any, budget: Budget, view: View) -> list[tuple[int, int, int]]:
        sel = select(layer.root, view, tau_px=self.scene._tau(layer), budget=budget, resident=self.scene.cache.residency(),
                     unavailable=self.scene.loader.failed_keys(), frame=self.scene.frame)
        drawn = self._drawn[id(layer)]
        curve, new = [], 0
        for pts, tri, keys in sel.admitted:
            new += sum(self._cost(k) for k in keys if k not in drawn)
            curve.append((pts, tri, new))
        return curve

    def _plan(self, view: View) -> None:
        """Set the point layers' budgets for the frame about to be selected (once per frame: an off-screen
        ``resolve`` selects several times while tiles load)."""
        ctl = self.points_ctl
        if self.scene.frame == self._planned or not isinstance(ctl, FeedForwardBudgetController):
            return
        self._planned = self.scene.frame
        saved = {id(layer): budget for layer, budget, _ in self._saved}
        curves = [self._layer_curve(layer, saved[id(layer)], view) for layer in self._points]
        curves = [c for c in curves if c] or [[(0, 0, 0)]]
        if len(curves) == 1:
            merged = curves[0]
        else:  # a total budget B gives each layer B·share: merge the layers' curves on B
            shares = [self._share[id(layer)] for layer in self._points]
            steps = sorted({p / s for c, s in zip(curves, shares, strict=False) for p, _, _ in c})
            merged = []
            for b in steps:
                tot = [0, 0, 0]
                for c, s in zip(curves, shares, strict=False):
                    i = max(bisect.bisect_right([p for p, _, _ in c], b * s) - 1, 0)
                    tot = [t + v for t, v in zip(tot, c[i], strict=True)]
                merged.append((int(b), tot[1], tot[2]))
        extra = self._other_triangles  # the mesh layers' last triangles: their τ moves slowly
        budget = ctl.plan([(p, t + extra, n) for p, t, n in merged])
        self.predicted_ms.append(ctl.predicted_ms)
        self._apply(budget)

    def _apply(self, share: int) -> None:
        total = sum(int(b.max_points) for _, b, _ in self._saved if b is not None and b.max_points) or 1
        for layer, budget, _ in self._saved:
            if layer in self._points and budget is not None and budget.max_points:
                layer.budget = Budget(max_bytes=budget.max_bytes, max_triangles=budget.max_triangles,
                                      max_points=max(1, share * int(budget.max_points) // total))

    # -- measurement --------------------------------------------------------------------------------------
    def _start(self, _obj: Any, _event: str) -> None:
        if not self.active:
            return
        self._t0 = time.perf_counter()

    def _end(self, _obj: Any, _event: str) -> None:
        # The renderer's EndEvent comes when the draw calls are issued, not done: a software GL (llvmpipe)
        # rasterises on its threads until the window waits for it, so without waiting here the time is the
        # submission's (a third of the frame on this machine) and steers nothing that the user sees.
        if not self.active:
            return
        win = self.scene.renderer.GetRenderWindow()
        if win is not None:
            win.WaitForCompletion()
        ms = (time.perf_counter() - self._t0) * 1000.0
        self.frame_ms.append(ms)
        sels = [layer.selection for layer in self._points]
        drawn = sum(s.stats.points for s in sels if s is not None)
        limited = any(s is not None and s.stats.budget_limited for s in sels)
        others = sum(layer.selection.stats.triangles for layer in self._others if layer.selection is not None)
        triangles = others + sum(s.stats.triangles for s in sels if s is not None)
        new = 0
        for layer in self._points:
            keys = {n.key for n in layer.selection.render} if layer.selection is not None else set()
            new += sum(self._cost(k) for k in keys - self._drawn[id(layer)])
            self._drawn[id(layer)] = keys
        self._other_triangles = others
        ctl = self.points_ctl
        if isinstance(ctl, FeedForwardBudgetController):
            ctl.update(ms, drawn, triangles, new, limited)
        elif ctl is not None:
            self._apply(ctl.update(ms, drawn, limited))
        if ctl is not None:
            for layer, _, tau in self._saved:
                if layer in self._points:  # a layer without its own τ follows the scene's
                    layer.tau_px = (tau if tau is not None else self.scene.tau_px) * ctl.tau_scale
        if self.tau_ctl is not None:
            self.tau_ctl.update(ms)
            for layer in self._others:
                layer.tau_px = self.tau_ctl.tau_px

    def close(self) -> None:
        """Leave budget mode: the layers get their fixed budgets and τ back, and garbage collection its
        thresholds."""
        self._gc.uninstall()
        for tag in self._tags:
            self.scene.renderer.RemoveObserver(tag)
        if self.scene.before_select == self._plan:
            self.scene.before_select = None
        for layer, budget, tau in self._saved:
            layer.budget, layer.tau_px = budget, tau
