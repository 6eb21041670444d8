"""Budget mode for a scene: hold a target frame time by steering τ and the point budget every frame.

:class:`FrameBudget` times each render of the scene's renderer (VTK ``StartEvent`` to ``EndEvent``, then waits
for the GL to finish, so the time is the completed frame's). Point
layers are steered by a :class:`~citylod.lod.runtime.budget.PointBudgetController` (a cost model fitted
online and fed forward, a PI controller on its residual, growth limited per frame): it sets their shared
point budget and scales their τ down where a view holds fewer points than the target allows. Other layers
(meshes) get τ from a :class:`~citylod.lod.runtime.budget.FrameTimeController` (PID on the frame time). Fixed budgets stay what they were when
the mode is switched off (:meth:`close`). Creates no VTK objects; call from the GL thread. No Qt.
"""

from __future__ import annotations

import time
from typing import Any

from citylod.lod.runtime.budget import FrameTimeController, PointBudgetController
from citylod.lod.runtime.selection import Budget
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
    """

    def __init__(self, scene: Any, target_ms: float) -> None:
        self.scene = scene
        self._saved = [(layer, layer.budget, layer.tau_px) for layer in scene.layers]
        self._points = [layer for layer in scene.layers if layer.budget is not None and layer.budget.max_points]
        self._others = [layer for layer in scene.layers if layer not in self._points]
        base_points = sum(int(layer.budget.max_points) for layer in self._points) or None
        self.points_ctl = PointBudgetController(target_ms, base_points=base_points) if base_points else None
        self.tau_ctl = FrameTimeController(target_ms, base_tau_px=scene.tau_px) if self._others else None
        self.frame_ms: list[float] = []
        self._t0 = 0.0
        ren = scene.renderer
        self._tags = [ren.AddObserver(_vtk.vtkCommand.StartEvent, self._start),
                      ren.AddObserver(_vtk.vtkCommand.EndEvent, self._end)]

    def _start(self, _obj: Any, _event: str) -> None:
        self._t0 = time.perf_counter()

    def _end(self, _obj: Any, _event: str) -> None:
        # The renderer's EndEvent comes when the draw calls are issued, not done: a software GL (llvmpipe)
        # rasterises on its threads until the window waits for it, so without waiting here the time is the
        # submission's (a third of the frame on this machine) and steers nothing that the user sees.
        win = self.scene.renderer.GetRenderWindow()
        if win is not None:
            win.WaitForCompletion()
        ms = (time.perf_counter() - self._t0) * 1000.0
        self.frame_ms.append(ms)
        if self.points_ctl is not None:
            drawn = sum(layer.selection.stats.points for layer in self._points if layer.selection is not None)
            limited = any(layer.selection is not None and layer.selection.stats.budget_limited
                          for layer in self._points)
            self.points_ctl.update(ms, drawn, limited)
            share = self.points_ctl.point_budget
            total = sum(int(b.max_points) for _, b, _ in self._saved if b is not None and b.max_points) or 1
            for layer, budget, _ in self._saved:
                if layer in self._points and budget is not None and budget.max_points:
                    layer.budget = Budget(max_bytes=budget.max_bytes, max_triangles=budget.max_triangles,
                                          max_points=max(1, share * int(budget.max_points) // total))
            for layer, _, tau in self._saved:
                if layer in self._points:  # a layer without its own τ follows the scene's
                    layer.tau_px = (tau if tau is not None else self.scene.tau_px) * self.points_ctl.tau_scale
        if self.tau_ctl is not None:
            self.tau_ctl.update(ms)
            for layer in self._others:
                layer.tau_px = self.tau_ctl.tau_px

    def close(self) -> None:
        """Leave budget mode: the layers get their fixed budgets and τ back."""
        for tag in self._tags:
            self.scene.renderer.RemoveObserver(tag)
        for layer, budget, tau in self._saved:
            layer.budget, layer.tau_px = budget, tau
