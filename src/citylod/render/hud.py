"""View aids drawn by VTK into a renderer: scale bar, north arrow, clipping box, Eye-Dome Lighting.

What GIS and point-cloud users expect on a 3D view (QGIS 3D, CloudCompare, Potree). The maths is in
plain functions (:func:`nice_length`, :func:`north_on_screen`, :func:`box_planes`) so it is tested
without a window; the classes only keep VTK objects in sync. No Qt.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from citylod.core.camera import Camera
from citylod.render import _vtk

__all__ = ["ClipBox", "Hud", "box_planes", "nice_length", "north_on_screen", "set_edl"]

F64 = npt.NDArray[np.float64]


def nice_length(metres_per_px: float, target_px: float = 120.0) -> tuple[float, float]:
    """The round length (1, 2 or 5 × 10^k m) whose bar is closest below ``target_px``; returns
    (length_m, length_px).

    >>> nice_length(0.5)
    (50.0, 100.0)
    """
    want = max(metres_per_px * target_px, 1e-9)
    k = math.floor(math.log10(want))
    best = 10.0 ** k
    for m in (1.0, 2.0, 5.0, 10.0):
        if m * 10.0 ** k <= want:
            best = m * 10.0 ** k
    return best, best / metres_per_px


def north_on_screen(camera: Camera, north: npt.ArrayLike = (0.0, 1.0, 0.0)) -> tuple[float, float]:
    """Unit 2D direction (right, up) in which the data's north (+y; for geocentric data the local north,
    :func:`citylod.core.camera.enu_axes`) points on screen.

    Projected through the camera's right and up vectors; looking north it points up, and straight down
    it turns with the camera's heading.

    >>> north_on_screen(Camera((0.0, -10.0, 10.0), (0.0, 0.0, 0.0)))
    (0.0, 1.0)
    """
    right, up, _fwd = camera.basis()
    north = np.asarray(north, np.float64)
    # A small step north at the focal point moves on screen by its components along the camera's right
    # and up vectors (the forward component only changes its depth). Looking level due north the step
    # is along the view and has no screen image: the arrow then points up.
    x = float(north @ right)
    y = float(north @ up)
    n = math.hypot(x, y)
    return (0.0, 1.0) if n < 1e-12 else (x / n, y / n)


def box_planes(lo: npt.ArrayLike, hi: npt.ArrayLike, origin: npt.ArrayLike) -> list[tuple[F64, F64]]:
    """The six (point, inward normal) planes of the box ``lo``–``hi`` shifted by the scene ``origin``."""
    lo_a = np.asarray(lo, np.float64) - np.asarray(origin, np.float64)
    hi_a = np.asarray(hi, np.float64) - np.asarray(origin, np.float64)
    out = []
    for axis in range(3):
        n = np.zeros(3)
        n[axis] = 1.0
        out.append((lo_a.copy(), n.copy()))
        out.append((hi_a.copy(), -n))
    return out


def set_edl(renderer: Any, on: bool) -> None:
    """Eye-Dome Lighting on ``renderer`` (a render pass; off restores the default passes). The 2D overlay
    (scale bar, north arrow, text) is drawn after the shading, not through it: EDL darkens every depth edge,
    and a thin arrow is all edge (it turned black)."""
    if on:
        basic = _vtk.vtkRenderStepsPass()
        basic.SetOverlayPass(None)
        edl = _vtk.vtkEDLShading()
        edl.SetDelegatePass(basic)
        overlay = _vtk.vtkOverlayPass()
        steps = _vtk.vtkRenderPassCollection()
        steps.AddItem(edl)
        steps.AddItem(overlay)
        seq = _vtk.vtkSequencePass()
        seq.SetPasses(steps)
        renderer.SetPass(seq)
        renderer._citylod_edl = (edl, basic, overlay, steps, seq)  # keep the passes alive with the renderer
    else:
        passes = getattr(renderer, "_citylod_edl", None)
        window = renderer.GetRenderWindow()
        if passes is not None and window is not None:
            # The pass owns GL objects: free them while the context exists (VTK complains otherwise).
            passes[0].ReleaseGraphicsResources(window)
        renderer.SetPass(None)
        renderer._citylod_edl = None


class ClipBox:
    """Clip every tile actor (present and future, through ``add_hook``) and extra actors to a box, and draw
    the box's edges."""

    def __init__(self, renderer: Any, add_hook: Callable[[Callable[[Any], None]], Callable[[], None]]) -> None:
        self.renderer = renderer
        self.planes = _vtk.vtkPlaneCollection()
        self.active = False
        self._actors: list[Any] = []
        self._remove_hook = add_hook(self.attach)
        self.outline = _vtk.vtkActor()
        self.outline.SetMapper(_vtk.vtkPolyDataMapper())
        self.outline.GetProperty().SetColor(1.0, 0.55, 0.0)
        self.outline.GetProperty().SetLineWidth(2.0)
        self.outline.GetProperty().LightingOff()
        self.outline.SetPickable(False)
        self.outline.VisibilityOff()
        renderer.AddActor(self.outline)

    def attach(self, actor: Any) -> None:
        """Clip ``actor`` with the box (when one is set) from now on."""
        self._actors.append(actor)
        if self.active:
            actor.GetMapper().SetClippingPlanes(self.planes)


    def set_box(self, box: tuple[npt.ArrayLike, npt.ArrayLike] | None, origin: npt.ArrayLike) -> None:
        self.planes.RemoveAllItems()
        self.active = box is not None
        if box is not None:
            for point, normal in box_planes(box[0], box[1], origin):
                plane = _vtk.vtkPlane()
                plane.SetOrigin(*point)
                plane.SetNormal(*normal)
                self.planes.AddItem(plane)
            lo = np.asarray(box[0], np.float64) - np.asarray(origin, np.float64)
            hi = np.asarray(box[1], np.float64) - np.asarray(origin, np.float64)
            corners = np.array([[x, y, z] for z in (lo[2], hi[2]) for y in (lo[1], hi[1]) for x in (lo[0], hi[0])])
            edges = np.array([[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7],
                              [0, 4], [1, 5], [2, 6], [3, 7]], np.int64)
            data = _vtk.vtkPolyData()
            pts = _vtk.vtkPoints()
            pts.SetData(_vtk.numpy_to_vtk(corners, deep=True))
            data.SetPoints(pts)
            cells = _vtk.vtkCellArray()
            cells.SetData(_vtk.numpy_to_vtkIdTypeArray(np.arange(0, 25, 2, dtype=np.int64), deep=True),
                          _vtk.numpy_to_vtkIdTypeArray(edges.reshape(-1).copy(), deep=True))
            data.SetLines(cells)
            self.outline.GetMapper().SetInputData(data)
        self.outline.SetVisibility(self.active)
        for actor in self._actors:
            mapper = actor.GetMapper()
            if self.active:
                mapper.SetClippingPlanes(self.planes)
            else:
                mapper.RemoveAllClippingPlanes()


class Hud:
    """Scale bar (bottom right), north arrow (top right) and the data's credits (bottom left) as 2D actors,
    updated by :meth:`update` and :meth:`set_credits`."""

    def __init__(self, renderer: Any) -> None:
        self.renderer = renderer
        # Two strokes, a wide dark one under a narrow white one: readable on dark terrain and on the sky.
        self.bar_shadow = self._lines_actor((0.05, 0.05, 0.05), 5.0)
        self.bar = self._lines_actor((1.0, 1.0, 1.0), 2.0)
        self.arrow = self._lines_actor((0.75, 0.05, 0.05), 3.0)
        self.bar_text = self._text(14)
        self.north_text = self._text(16)
        self.north_text.SetInput("N")
        # Bottom left: the data's credits (a Cesium ion asset's attributions), shown while there are any.
        self.credit_text = self._text(12)
        self.credit_text.GetTextProperty().SetJustificationToLeft()
        self.credits: tuple[str, ...] = ()
        self.length_m = 0.0

    def _lines_actor(self, rgb: tuple[float, float, float], width: float) -> Any:
        actor = _vtk.vtkActor2D()
        actor.SetMapper(_vtk.vtkPolyDataMapper2D())
        actor.GetMapper().SetInputData(_vtk.vtkPolyData())
        actor.VisibilityOff()  # until the first update (no camera yet)
        actor.GetProperty().SetColor(*rgb)
        actor.GetProperty().SetLineWidth(width)
        actor.SetPickable(False)
        self.renderer.AddViewProp(actor)
        return actor

    def _text(self, size: int) -> Any:
        t = _vtk.vtkTextActor()
        prop = t.GetTextProperty()
        prop.SetFontSize(size)
        prop.SetColor(0.05, 0.05, 0.05)
        prop.SetBackgroundColor(1.0, 1.0, 1.0)
        prop.SetBackgroundOpacity(0.6)
        prop.SetJustificationToCentered()
        t.SetPickable(False)
        t.VisibilityOff()
        self.renderer.AddViewProp(t)
        return t

    @staticmethod
    def _polyline(actor: Any, xy: npt.ArrayLike, segments: npt.ArrayLike) -> None:
        p = np.asarray(xy, np.float64)
        data = _vtk.vtkPolyData()
        pts = _vtk.vtkPoints()
        pts.SetData(_vtk.numpy_to_vtk(np.column_stack([p, np.zeros(len(p))]), deep=True))
        data.SetPoints(pts)
        seg = np.asarray(segments, np.int64).reshape(-1)
        cells = _vtk.vtkCellArray()
        cells.SetData(_vtk.numpy_to_vtkIdTypeArray(np.arange(0, len(seg) + 1, 2, dtype=np.int64), deep=True),
                      _vtk.numpy_to_vtkIdTypeArray(seg.copy(), deep=True))
        data.SetLines(cells)
        actor.GetMapper().SetInputData(data)

    def set_credits(self, lines: list[str] | tuple[str, ...]) -> None:
        """Show ``lines`` (credits the data's servers ask for) bottom left; none hides the text."""
        self.credits = tuple(dict.fromkeys(line for line in lines if line))  # once each, in order
        self.credit_text.SetInput("\n".join(self.credits))
        self.credit_text.SetPosition(8, 6)
        self.credit_text.SetVisibility(bool(self.credits))

    def update(self, camera: Camera, metres_per_px: float, size: tuple[int, int],
               north: npt.ArrayLike = (0.0, 1.0, 0.0)) -> None:
        """Place both aids for a view ``size`` (w, h) pixels where one pixel spans ``metres_per_px`` at the
        focal distance, the arrow towards ``north`` (a direction in the data's frame)."""
        w, h = size
        for prop in (self.bar_shadow, self.bar, self.arrow, self.bar_text, self.north_text):
            prop.VisibilityOn()
        length_m, length_px = nice_length(metres_per_px, min(150.0, w / 4))
        self.length_m = length_m
        x1, y = w - 20.0, 24.0
        x0 = x1 - length_px
        for actor in (self.bar_shadow, self.bar):
            self._polyline(actor, [(x0, y), (x1, y), (x0, y - 6), (x0, y + 6), (x1, y - 6), (x1, y + 6)],
                           [(0, 1), (2, 3), (4, 5)])
        label = f"{length_m:g} m" if length_m >= 1 else f"{length_m * 100:g} cm"
        if length_m >= 1000:
            label = f"{length_m / 1000:g} km"
        self.bar_text.SetInput(label)
        self.bar_text.SetPosition((x0 + x1) / 2, y + 8)
        cx, cy, r = w - 40.0, h - 60.0, 22.0
        dx, dy = north_on_screen(camera, north)
        tip = (cx + dx * r, cy + dy * r)
        tail = (cx - dx * r, cy - dy * r)
        # Arrow head: two short strokes back from the tip, ±150° from the arrow's direction.
        head = []
        for sign in (1, -1):
            a = math.atan2(dy, dx) + sign * math.radians(150)
            head.append((tip[0] + 9 * math.cos(a), tip[1] + 9 * math.sin(a)))
        self._polyline(self.arrow, [tail, tip, head[0], head[1]], [(0, 1), (1, 2), (1, 3)])
        self.north_text.SetPosition(cx + dx * (r + 12), cy + dy * (r + 12) - 8)
