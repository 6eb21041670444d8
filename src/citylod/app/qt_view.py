"""The 3D view: a VTK render window in a Qt widget, drawing a :class:`~citylod.app.models.Document`'s scene.

* Input: an event filter on the VTK widget takes every mouse event before VTK sees it and hands it to a
  :class:`~citylod.app.navigation.Navigator` (turntable orbit with a level horizon, or fly mode; left drag
  orbits, middle or shift+left drag pans, right drag and the wheel zoom). VTK's interactor styles grab the
  mouse on press, so a release observer never ran and clicks were lost; here press and release are Qt's.
  The fly keys and R/F are actions of the main window that call :meth:`SceneView.fly` etc.; VTK's own key
  bindings (``e``/``q`` quit, ``w`` wireframe …) are switched off.
* Frames: input only changes the camera; a 30 ms ``QTimer`` renders at most once per tick, so a burst of
  mouse or wheel events costs one frame (wheel notches are summed, :meth:`Navigator.flush`). While the
  camera moves the document draws with a coarser τ and point budget (:meth:`Document.set_moving`); when
  it stops the next tick refines. Tile decoding stays on the loader's threads.
* Picking: a click (press and release within a few pixels) picks with a ``vtkCellPicker``, looking past
  skirt triangles (:func:`~citylod.render.tileset_actor.is_skirt_cell`); the world point goes to
  :meth:`Document.pick`, to the running measurement or to the profile line. The cursor's surface point
  (depth buffer, ``vtkWorldPointPicker``) is sent as ``cursor`` for the status bar.
* Overlays: the measurement polyline and its text, and translucent proxies of selected/highlighted objects
  (only when the renderer-side semantic shading, ``citylod.render.semantic``, is not installed).
* :meth:`SceneView.framebuffer` reads the rendered image back, so a grab of the whole window can show the
  GL part (``QWidget.grab`` alone leaves a native GL child black).

VTK objects are created and changed only here, on the GUI thread.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import numpy.typing as npt
import vtkmodules.qt

vtkmodules.qt.PyQtImpl = "PySide6"

from PySide6.QtCore import QEvent, QObject, QPoint, Qt, QTimer, Signal  # noqa: E402
from PySide6.QtGui import QCursor, QImage  # noqa: E402
from PySide6.QtWidgets import QVBoxLayout, QWidget  # noqa: E402
from vtkmodules.qt.QVTKRenderWindowInteractor import QVTKRenderWindowInteractor  # noqa: E402
from vtkmodules.vtkInteractionStyle import vtkInteractorStyleTrackballCamera  # noqa: E402
from vtkmodules.vtkRenderingCore import vtkCellPicker, vtkTextActor, vtkWorldPointPicker  # noqa: E402

from citylod.app.models import Document, Measurement, fly, focus_on, measure  # noqa: E402
from citylod.app.navigation import Navigator  # noqa: E402
from citylod.app.qt_profile import profiled, timed  # noqa: E402
from citylod.core.camera import Camera  # noqa: E402
from citylod.render import _vtk  # noqa: E402
from citylod.render.tileset_actor import is_skirt_cell, view_from_renderer  # noqa: E402
from citylod.semantics.state import StateChange  # noqa: E402

__all__ = ["SceneView"]

_BUTTONS = {Qt.MouseButton.LeftButton: "left", Qt.MouseButton.MiddleButton: "middle",
            Qt.MouseButton.RightButton: "right"}
_SELECT_RGBA = (0.0, 0.85, 1.0, 0.45)
_MAX_OVERLAY_OBJECTS = 2000


def _polydata(vertices: npt.NDArray[np.float64], faces: npt.NDArray[np.int64], per_cell: int) -> Any:
    data = _vtk.vtkPolyData()
    pts = _vtk.vtkPoints()
    pts.SetData(_vtk.numpy_to_vtk(np.ascontiguousarray(vertices, np.float64), deep=True))
    data.SetPoints(pts)
    conn = np.ascontiguousarray(faces, np.int64).reshape(-1)
    ca = _vtk.vtkCellArray()
    offsets = np.arange(0, len(conn) + 1, per_cell, dtype=np.int64)
    ca.SetData(_vtk.numpy_to_vtkIdTypeArray(offsets, deep=True), _vtk.numpy_to_vtkIdTypeArray(conn, deep=True))
    if per_cell == 3:
        data.SetPolys(ca)
    else:
        data.SetLines(ca)
    return data


class SceneView(QWidget):
    """The 3D view of a document. Signals: ``picked(object_id or None)``, ``measured(Measurement or
    None)``, ``frame(ms)`` after every render."""

    picked = Signal(object)
    measured = Signal(object)
    frame = Signal(float)
    cursor = Signal(object)
    clicked = Signal(object)

    #: Time (ms) a frame may spend uploading newly admitted tiles, on top of drawing the scene.
    UPLOAD_SLICE_MS = 30.0
    ADMIT_START, ADMIT_MIN, ADMIT_MAX = 60_000, 5_000, 2_000_000

    def __init__(self, document: Document, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.document = document
        self.scene = document.scene
        self.vtk = QVTKRenderWindowInteractor(self)
        lay = QVBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.vtk)
        self.window = self.vtk.GetRenderWindow()
        self.window.SetMultiSamples(0)
        self.renderer = self.scene.renderer
        self.window.AddRenderer(self.renderer)
        self.interactor = self.window.GetInteractor()
        style = vtkInteractorStyleTrackballCamera()
        # An observer on the style replaces its default handler: VTK's own keys (e/q quit, w/s wireframe,
        # r/f camera) would fight the application's actions.
        for event in ("CharEvent", "KeyPressEvent", "KeyReleaseEvent"):
            style.AddObserver(event, lambda *_: None)
        self.interactor.SetInteractorStyle(style)
        self._style = style
        self.navigator = Navigator(self.camera, self.set_camera, get_up=lambda: self.document.up())
        self.vtk.installEventFilter(self)
        self.vtk.setMouseTracking(True)
        self._cursor_xy: tuple[int, int] | None = None
        self._cursor_due = False
        self.world_picker = vtkWorldPointPicker()
        self.scene.attach()
        # After Scene.update (priority 0): pooled actors may have changed layer, so opacity is re-applied.
        self.renderer.AddObserver("StartEvent", self._after_update, -1.0)
        self.window.AddObserver("StartEvent", self._frame_start)
        self.window.AddObserver("EndEvent", self._frame_end)
        self._t0 = 0.0
        self.frame_ms = 0.0
        # Tiles that finished decoding enter the scene (and the GPU) at most ``admit_cost`` points +
        # triangles per frame, adapted to the measured upload time (see _frame_end): a burst of finished
        # tiles becomes several short frames instead of one long one that holds the GUI thread.
        self.scene.admit_cost = self.ADMIT_START
        # External tilesets a view reaches are read on background threads: no frame waits on a file or server.
        self.scene.expand_in_background()
        #: Full garbage collections only while idle (core/gc_policy.py); set by the main window.
        self.gc_policy: Any = None
        self._uploads = self.scene.uploads
        self._base_ms: float | None = None
        self._exporting = False
        self.renders = 0
        self._dirty = True
        self._camera_mtime = 0
        self.picker = vtkCellPicker()
        self.picker.SetTolerance(0.002)
        # Measurement
        self.measure_kind: str | None = None
        self.measure_points: list[npt.NDArray[np.float64]] = []
        self.measurement: Measurement | None = None
        self._measure_actor: Any = None
        self._measure_text = vtkTextActor()
        self._measure_text.GetTextProperty().SetFontSize(18)
        self._measure_text.GetTextProperty().SetColor(1.0, 1.0, 0.2)
        self._measure_text.GetTextProperty().SetBackgroundColor(0.0, 0.0, 0.0)
        self._measure_text.GetTextProperty().SetBackgroundOpacity(0.6)
        self._measure_text.SetPosition(12, 12)
        self._measure_text.SetPickable(False)
        self._measure_text.VisibilityOff()
        self.renderer.AddViewProp(self._measure_text)
        # Semantic overlay (fallback while citylod.render.semantic is absent)
        self._overlay_actors: list[Any] = []
        # A city store open on its own is drawn as its lit proxies (read on a worker thread).
        self.store_actor: Any = None
        self._store_future: Any = None
        # Scale bar, north arrow, clipping box (render/hud.py).
        from citylod.render.hud import ClipBox, Hud

        self.hud = Hud(self.renderer)
        self.clip = ClipBox(self.renderer, self.scene.add_actor_hook)
        document.state.on_change(self._on_state)
        document.on_change(self._on_document)
        self.timer = QTimer(self)
        self.timer.setInterval(30)
        self.timer.timeout.connect(self._tick)
        self.timer.start()
        self.setMinimumSize(200, 150)

    # -- frames -----------------------------------------------------------------------------------
    def _frame_start(self, *_: Any) -> None:
        self._t0 = time.perf_counter()

    def _frame_end(self, *_: Any) -> None:
        self.frame_ms = (time.perf_counter() - self._t0) * 1e3
        self.renders += 1
        admitted = self.scene.admitted_cost if self.scene.uploads != self._uploads else 0
        self._uploads = self.scene.uploads
        if admitted <= 0:
            # A frame without uploads: what drawing the scene costs now (smoothed).
            self._base_ms = self.frame_ms if self._base_ms is None else 0.7 * self._base_ms + 0.3 * self.frame_ms
        elif self._base_ms is not None:
            # The uploads took what the frame took beyond the scene's own cost. The cost of an upload
            # (VBO building, texture mipmaps) depends on the machine and its load, so it is measured: the
            # next frames admit what fits UPLOAD_SLICE_MS at the measured rate (geometric steps, ≤ 2×).
            extra = max(self.frame_ms - self._base_ms, 1.0)
            want = self.UPLOAD_SLICE_MS / extra * admitted
            old = self.scene.admit_cost or self.ADMIT_START
            cost = int(min(max(want, old / 2.0), old * 2.0))
            self.scene.admit_cost = min(max(cost, self.ADMIT_MIN), self.ADMIT_MAX)
        self.frame.emit(self.frame_ms)

    def _after_update(self, *_: Any) -> None:
        self.document.apply_opacity()
        cam = self.camera()
        if cam is not None and not self._exporting:
            w, h = self.renderer.GetSize()
            dist = float(np.linalg.norm(np.subtract(cam.position, cam.focal_point)))
            self.hud.update(cam, 2.0 * dist * np.tan(np.radians(cam.fovy_deg) / 2.0) / max(h, 1), (w, h),
                            self.document.north())
            credits = [c for layer in self.scene.layers for c in layer.tileset.attributions]
            if tuple(dict.fromkeys(credits)) != self.hud.credits:
                self.hud.set_credits(credits)
            self._measure_text.SetPosition(12, max(h - 40, 12))  # top left: the scale bar is bottom right

    def request_render(self) -> None:
        """Render at the next timer tick (coalesces several model changes into one frame)."""
        self._dirty = True

    def render_now(self) -> None:
        with timed("SceneView.render"):
            self.window.Render()
        self._dirty = False

    @profiled("SceneView._tick")
    def _tick(self) -> None:
        if not self.isVisible():
            return
        self.navigator.flush()
        if self.document.set_moving(self.navigator.moving):
            self._dirty = True  # started moving: coarser; stopped: refine to full quality
        if self._store_future is not None and self._store_future.done():
            self._attach_store_actor()
        # Finished tiles are admitted by the scene's update inside the render, a bounded amount a frame.
        newly = ((self.scene.layers and (self.scene.loader.stats().ready > 0 or self.scene.expansions_done() > 0))
                 or self.document.far_loads_ready())
        if self.document.poll_semantics():
            self._dirty = True
        mtime = self.renderer.GetActiveCamera().GetMTime()
        moved = mtime != self._camera_mtime
        if newly or moved or self._dirty or getattr(self.scene, "fading", False):
            self._camera_mtime = mtime
            self.render_now()
            self._camera_mtime = self.renderer.GetActiveCamera().GetMTime()
        if self._cursor_due and self._cursor_xy is not None:
            self._cursor_due = False
            self.cursor.emit(self.surface_point(*self._cursor_xy))
        if self.gc_policy is not None:
            busy = self.navigator.moving or self.document.moving or self._dirty or self.pending() > 0
            with timed("SceneView.gc"):
                self.gc_policy.tick(busy)

    def pending(self) -> int:
        """Tile requests queued or being decoded, external tilesets being read, and city tiles the far-field
        layers are reading."""
        st = self.scene.loader.stats()
        return int(st.pending + st.in_flight + st.ready) + self.document.far_pending() + self.scene.expanding()

    def is_resolved(self) -> bool:
        """The last frame drew everything selection wanted and nothing is loading."""
        return bool(self.scene.last_stats.complete and self.pending() == 0 and self.renders > 0)

    # -- camera -----------------------------------------------------------------------------------
    def camera(self) -> Camera | None:
        if self.scene.origin is None:
            return None
        return view_from_renderer(self.renderer, self.scene.origin).camera

    def set_camera(self, camera: Camera) -> None:
        if self.scene.origin is None:
            self.scene.origin = np.round(np.asarray(camera.focal_point, np.float64))
        self.scene.set_camera(camera)
        self.renderer.ResetCameraClippingRange()
        self.request_render()

    def reset_view(self) -> None:
        w, h = max(self.vtk.width(), 1), max(self.vtk.height(), 1)
        cam = self.document.home_camera(aspect=w / h)
        if cam is not None:
            self.set_camera(cam)

    def fly(self, direction: str) -> None:
        cam = self.camera()
        if cam is None:
            return
        dist = float(np.linalg.norm(np.subtract(cam.position, cam.focal_point)))
        self.set_camera(fly(cam, direction, max(dist * 0.08, 1.0), self.document.up()))

    def focus_under_cursor(self) -> bool:
        """Focus the camera on the surface point under the mouse cursor (F)."""
        pos = self.vtk.mapFromGlobal(QCursor.pos())
        point = self.pick_point(pos.x(), pos.y())
        cam = self.camera()
        if point is None or cam is None:
            return False
        self.set_camera(focus_on(cam, point))
        return True

    def frame_objects(self, ids: list[str]) -> bool:
        """Zoom to objects (their proxies' box)."""
        box = self.document.object_box(ids)
        cam = self.camera()
        if box is None or cam is None:
            return False
        from citylod.app.models import frame_box

        self.set_camera(frame_box(cam, *box))
        return True

    # -- picking ----------------------------------------------------------------------------------
    def _display_xy(self, x: int, y: int) -> tuple[int, int]:
        """VTK display coordinates (origin bottom-left, device pixels) of a widget position."""
        ratio = self.vtk.devicePixelRatioF()
        return int(x * ratio), int((self.vtk.height() - 1 - y) * ratio)

    def pick_point(self, x: int, y: int, *, display: bool = False) -> npt.NDArray[np.float64] | None:
        """The data-CRS point (3,) of the surface under widget position (x, y), skirts skipped."""
        if self.scene.origin is None:
            return None
        dx, dy = (x, y) if display else self._display_xy(x, y)
        picker = self.picker
        picker.PickFromListOff()
        if not picker.Pick(dx, dy, 0, self.renderer):
            return None
        actor = picker.GetActor()
        if is_skirt_cell(actor, picker.GetCellId()):
            # A skirt hangs below a tile edge; the surface behind it belongs to another tile: pick again
            # among the other drawn actors.
            picker.InitializePickList()
            actors = self.renderer.GetActors()
            actors.InitTraversal()
            for _ in range(actors.GetNumberOfItems()):
                a = actors.GetNextActor()
                if a is not actor and a.GetVisibility() and a.GetPickable():
                    picker.AddPickList(a)
            picker.PickFromListOn()
            ok = picker.Pick(dx, dy, 0, self.renderer)
            picker.PickFromListOff()
            if not ok or is_skirt_cell(picker.GetActor(), picker.GetCellId()):
                return None
        return np.asarray(picker.GetPickPosition(), np.float64) + self.scene.origin

    # -- mouse ------------------------------------------------------------------------------------
    def eventFilter(self, obj: QObject, event: QEvent) -> bool:
        """Every mouse event of the VTK widget: navigation, clicks, cursor; VTK never sees them."""
        if obj is not self.vtk:
            return False
        kind = event.type()
        if kind == QEvent.Type.MouseButtonPress or kind == QEvent.Type.MouseButtonDblClick:
            button = _BUTTONS.get(event.button())  # type: ignore[attr-defined]
            if button is not None:
                pos = event.position()  # type: ignore[attr-defined]
                shift = bool(event.modifiers() & Qt.KeyboardModifier.ShiftModifier)  # type: ignore[attr-defined]
                self.navigator.press(button, int(pos.x()), int(pos.y()), shift=shift)
            return True
        if kind == QEvent.Type.MouseMove:
            pos = event.position()  # type: ignore[attr-defined]
            x, y = int(pos.x()), int(pos.y())
            self.navigator.move(x, y, self.vtk.height())
            self._cursor_xy = (x, y)
            self._cursor_due = True
            return True
        if kind == QEvent.Type.MouseButtonRelease:
            button = _BUTTONS.get(event.button())  # type: ignore[attr-defined]
            pos = event.position()  # type: ignore[attr-defined]
            x, y = int(pos.x()), int(pos.y())
            if button is not None and self.navigator.release(button, x, y) and button == "left":
                self._click(x, y)
            return True
        if kind == QEvent.Type.Wheel:
            notches = event.angleDelta().y() / 120.0  # type: ignore[attr-defined]
            pos = event.position()  # type: ignore[attr-defined]
            toward = self.surface_point(int(pos.x()), int(pos.y())) if self.navigator.mode == "turntable" else None
            self.navigator.wheel(notches, toward)
            return True
        return False

    @profiled("SceneView.click")
    def _click(self, x: int, y: int) -> None:
        self.clicked.emit((x, y))
        self.click_display(*self._display_xy(x, y))

    def surface_point(self, x: int, y: int) -> npt.NDArray[np.float64] | None:
        """The data-CRS point (3,) under widget position (x, y) read from the last frame's depth buffer
        (cheap: one pixel), or None over the background."""
        if self.scene.origin is None or self.renders == 0:
            return None
        dx, dy = self._display_xy(x, y)
        if not (0 <= dx < self.window.GetSize()[0] and 0 <= dy < self.window.GetSize()[1]):
            return None
        if self.renderer.GetZ(dx, dy) >= 1.0:
            return None
        self.world_picker.Pick(dx, dy, 0, self.renderer)
        return np.asarray(self.world_picker.GetPickPosition(), np.float64) + self.scene.origin

    def click_display(self, x: int, y: int) -> None:
        """A click at VTK display position (x, y): a measurement point or a pick."""
        sem = self.document.semantic
        if self.measure_kind is None and sem is not None:
            # The semantic overlay reads the depth buffer, so hidden (discarded) objects are looked through.
            res = sem.pick(self.renderer, x, y)
            oid = res.object_id
            self.document.select([] if oid is None else [oid])
            self.picked.emit(oid)
            return
        point = self.pick_point(x, y, display=True)
        if self.measure_kind is not None:
            if point is not None:
                self.add_measure_point(point)
            return
        if point is not None and self.store_actor is not None and self.picker.GetActor() is self.store_actor.actor:
            # A proxy was hit: the object is the cell's owner (a point on a proxy's surface is not
            # reliably "inside" it for the containment test).
            idx = self.store_actor.object_of_cell(self.picker.GetCellId())
            oid = None if idx is None else self.document.store.ids[idx]
            self.document.select([] if oid is None else [oid])
        else:
            cam = self.camera() if point is not None else None
            oid = self.document.pick(point, eye=None if cam is None else cam.position)
        self.picked.emit(oid)

    # -- measuring --------------------------------------------------------------------------------
    def start_measure(self, kind: str | None) -> None:
        """Start a measurement (distance, height, area); None ends it (the result stays shown)."""
        self.measure_kind = kind
        if kind is not None:
            self.measure_points = []
            self.measurement = None
            self._update_measure_overlay()

    def clear_measure(self) -> None:
        self.measure_kind = None
        self.measure_points = []
        self.measurement = None
        self._update_measure_overlay()
        self.measured.emit(None)

    def add_measure_point(self, point: npt.ArrayLike) -> Measurement:
        """Add a clicked point to the running measurement. ``profile`` takes two points (a third starts a
        new line) and asks the document for the height profile along them."""
        kind = self.measure_kind or (self.measurement.kind if self.measurement else "distance")
        if kind in ("height", "profile") and len(self.measure_points) >= 2:
            self.measure_points = []
        self.measure_points.append(np.asarray(point, np.float64))
        self.measurement = measure("distance" if kind == "profile" else kind, np.array(self.measure_points),
                                   geographic=self.document.geographic, crs=self.document.crs,
                                   ellipsoidal=self.document.ellipsoidal)
        if kind == "profile" and len(self.measure_points) == 2:
            with timed("SceneView.profile"):
                self.document.profile(*self.measure_points)
        self._update_measure_overlay()
        self.measured.emit(self.measurement)
        return self.measurement

    def _update_measure_overlay(self) -> None:
        if self._measure_actor is not None:
            self.renderer.RemoveActor(self._measure_actor)
            self._measure_actor = None
        pts = self.measure_points
        if pts and self.scene.origin is not None:
            verts = np.array(pts) - self.scene.origin
            n = len(verts)
            idx = list(range(n))
            if self.measurement is not None and self.measurement.kind == "area" and n >= 3:
                idx.append(0)
            lines = np.array([[idx[i], idx[i + 1]] for i in range(len(idx) - 1)], np.int64).reshape(-1, 2)
            data = _polydata(verts, lines, 2)
            va = _vtk.vtkCellArray()
            va.SetData(_vtk.numpy_to_vtkIdTypeArray(np.arange(n + 1, dtype=np.int64), deep=True),
                       _vtk.numpy_to_vtkIdTypeArray(np.arange(n, dtype=np.int64), deep=True))
            data.SetVerts(va)
            mapper = _vtk.vtkPolyDataMapper()
            mapper.SetInputData(data)
            actor = _vtk.vtkActor()
            actor.SetMapper(mapper)
            prop = actor.GetProperty()
            prop.SetColor(1.0, 0.9, 0.1)
            prop.SetLineWidth(3.0)
            prop.SetPointSize(9.0)
            prop.RenderPointsAsSpheresOn()
            prop.LightingOff()
            actor.SetPickable(False)
            # Drawn over everything, as measuring tools do: a segment from a roof to the ground in front of
            # its house runs inside the house, and a depth test hid all of it but its ends. Every fragment
            # of this actor gets the nearest depth (its own shader, no other mapper is touched).
            actor.GetShaderProperty().AddFragmentShaderReplacement(
                "//VTK::Depth::Impl", True, "//VTK::Depth::Impl\n  gl_FragDepth = 0.0;\n", False)
            self._measure_actor = actor
            self.renderer.AddActor(actor)
        if self.measurement is not None:
            self._measure_text.SetInput(self.measurement.text())
            self._measure_text.VisibilityOn()
        else:
            self._measure_text.VisibilityOff()
        self.request_render()

    # -- semantic overlay -------------------------------------------------------------------------
    def _on_document(self, kind: str) -> None:
        if kind in ("layers", "style"):
            self._sync_store_actor()
        if kind == "layers":
            for layer in self.scene.layers:
                # No fade-in of point tiles here: each step of a fade replaces the tile's vertex cells,
                # and VTK then rebuilds the tile's whole vertex buffer, frame after frame while it fades.
                layer.smooth_refinement = False
        if kind == "display":
            from citylod.render.hud import set_edl

            set_edl(self.renderer, self.document.edl)
            if self.scene.origin is not None:
                self.clip.set_box(self.document.clip_box, self.scene.origin)
        self.request_render()

    def _sync_store_actor(self) -> None:
        doc = self.document
        if doc.store_alone and self.store_actor is None and self._store_future is None:
            import concurrent.futures

            pool = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="citylod-proxies")
            self._store_future = pool.submit(doc.proxy_meshes)
            pool.shutdown(wait=False)
        if self.store_actor is not None:
            entry = next((e for e in doc.entries if e.kind == "store"), None)
            self.store_actor.set_visible(doc.store_alone and (entry is None or entry.visible))

    @profiled("SceneView.attach_store")
    def _attach_store_actor(self) -> None:
        from citylod.render.store_actor import StoreActor

        fut, self._store_future = self._store_future, None
        doc = self.document
        if doc.store is None or doc.scene.origin is None:
            return
        verts, faces, owner = fut.result()
        self.store_actor = StoreActor(self.renderer, verts, faces, owner, doc.scene.origin)
        self.clip.attach(self.store_actor.actor)
        self.store_actor.restyle(*doc.state.as_arrays(doc.store.ids))
        self._sync_store_actor()
        self.refresh_overlay()
        self.request_render()

    def _on_state(self, change: StateChange) -> None:
        if self.store_actor is not None and self.document.store is not None:
            self.store_actor.restyle(*self.document.state.as_arrays(self.document.store.ids))
        if self.document.semantic is None:
            self.refresh_overlay()
        self.request_render()

    @profiled("SceneView.refresh_overlay")
    def refresh_overlay(self) -> None:
        """Translucent proxies of highlighted (their colour) and selected (cyan) objects."""
        for a in self._overlay_actors:
            self.renderer.RemoveActor(a)
        self._overlay_actors = []
        doc = self.document
        if doc.store is None or doc.scene.origin is None:
            return
        if self.store_actor is not None and doc.store_alone:
            return  # the store actor colours the objects itself
        state = doc.state
        groups: dict[tuple[float, float, float, float], list[str]] = {}
        for oid, rgba in state.colors.items():
            if state.is_visible(oid):
                groups.setdefault((rgba[0], rgba[1], rgba[2], min(rgba[3], 0.55)), []).append(oid)
        sel = [o for o in state.selection if state.is_visible(o)]
        if sel:
            groups.setdefault(_SELECT_RGBA, []).extend(sel)
        for rgba, ids in groups.items():
            verts, faces, base = [], [], 0
            for oid in ids[:_MAX_OVERLAY_OBJECTS]:
                v, f = doc.store.mesh(oid)
                if len(f) == 0:
                    continue
                verts.append(v - doc.scene.origin)
                faces.append(np.asarray(f, np.int64) + base)
                base += len(v)
            if not verts:
                continue
            mapper = _vtk.vtkPolyDataMapper()
            mapper.SetInputData(_polydata(np.vstack(verts), np.vstack(faces), 3))
            actor = _vtk.vtkActor()
            actor.SetMapper(mapper)
            prop = actor.GetProperty()
            prop.SetColor(*rgba[:3])
            prop.SetOpacity(rgba[3])
            prop.LightingOff()
            actor.SetPickable(False)
            self.renderer.AddActor(actor)
            self._overlay_actors.append(actor)

    # -- images -----------------------------------------------------------------------------------
    def framebuffer(self) -> QImage:
        """The rendered image (re-rendered now), the size of the widget in device pixels."""
        self.render_now()
        grab = _vtk.vtkWindowToImageFilter()
        grab.SetInput(self.window)
        grab.ReadFrontBufferOff()
        grab.ShouldRerenderOn()
        grab.SetInputBufferTypeToRGB()
        grab.Update()
        img = grab.GetOutput()
        w, h, _ = img.GetDimensions()
        arr = _vtk.vtk_to_numpy(img.GetPointData().GetScalars()).reshape(h, w, 3)[::-1].copy()
        qimg = QImage(arr.data, w, h, 3 * w, QImage.Format.Format_RGB888).copy()
        return qimg

    def render_image(self, scale: int = 2) -> npt.NDArray[np.uint8]:
        """The view as it is drawn now, ``scale`` times its size in each direction: (H, W, 3) RGB, row 0 at
        the top.

        Everything the view shows is kept because the view's own renderer draws it: class and elevation
        colours, highlights and hidden objects (the semantic shader), class filter, clipping box, EDL and
        the measurement line. ``vtkRenderLargeImage`` renders the view in ``scale``² tiles through narrowed
        cameras; the LOD selection is frozen meanwhile so every tile draws the same tiles as the screen
        (a tile's narrow camera would otherwise ask for finer tiles that are not loaded). The 2D aids
        (scale bar, north arrow, texts) are left out: their sizes are screen pixels."""
        scale = int(min(max(scale, 1), 8))
        self.render_now()
        huds = [self.hud.bar_shadow, self.hud.bar, self.hud.arrow, self.hud.bar_text, self.hud.north_text,
                self.hud.credit_text, self._measure_text]
        shown = [p.GetVisibility() for p in huds]
        frozen = self.scene.frozen
        self._exporting = True
        self.scene.frozen = True
        try:
            for p in huds:
                p.VisibilityOff()
            big = _vtk.vtkRenderLargeImage()
            big.SetInput(self.renderer)
            big.SetMagnification(scale)
            big.Update()
            img = big.GetOutput()
            w, h, _ = img.GetDimensions()
            arr = _vtk.vtk_to_numpy(img.GetPointData().GetScalars())
            rgb = arr.reshape(h, w, -1)[::-1, :, :3].copy()
        finally:
            self.scene.frozen = frozen
            self._exporting = False
            for p, on in zip(huds, shown, strict=True):
                p.SetVisibility(on)
            self.request_render()
        return np.ascontiguousarray(rgb, np.uint8)

    def escape(self) -> None:
        """Esc: end a running measurement (its result stays), else clear the measurement overlay."""
        if self.measure_kind is not None:
            self.start_measure(None)
        else:
            self.clear_measure()

    def shutdown(self) -> None:
        self.timer.stop()
        if self.document.edl:
            from citylod.render.hud import set_edl

            set_edl(self.renderer, False)
        self.scene.detach()
        self.vtk.Finalize()

    def origin_in(self, widget: QWidget) -> QPoint:
        return self.vtk.mapTo(widget, QPoint(0, 0))
