"""The main window: the 3D view in the centre, panels in docks, menus, shortcuts, status bar, settings.

Opening: tilesets and city stores open at once (:meth:`Document.open`); rasters, LAS/LAZ and city models
are built first in a subprocess (:class:`~citylod.app.qt_tasks.ProcessTask`, cancellable) and the result
opens when the build ends. Recent files, window geometry, dock layout and query history persist in
``QSettings("citylod", "citylod")``; bookmarks, the camera, styles and object state go into a project
file (File > Save project, app/project.py).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from PySide6.QtCore import QByteArray, QRect, QSettings, Qt, QTimer, Signal
from PySide6.QtGui import QAction, QGuiApplication, QImage, QKeySequence, QPainter
from PySide6.QtWidgets import (
    QApplication,
    QDialog,
    QDialogButtonBox,
    QDockWidget,
    QFileDialog,
    QFormLayout,
    QLabel,
    QMainWindow,
    QMessageBox,
    QSpinBox,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
)

from citylod.app.models import (
    SHORTCUTS,
    Document,
    build_plan,
    check_crs,
    format_budget_status,
    format_cursor,
    format_far_status,
    format_status,
    missing_crs,
    source_kind,
)
from citylod.app.qt_flood import FloodPanel
from citylod.app.qt_panels import (
    AttributePanel,
    BookmarkPanel,
    LayerPanel,
    LodPanel,
    MeasurePanel,
    ObjectTreePanel,
    QueryPanel,
)
from citylod.app.qt_plot import ProfilePanel
from citylod.app.qt_profile import profiled
from citylod.app.qt_tasks import ProcessTask
from citylod.app.qt_tools import ClipPanel, PointPanel
from citylod.app.qt_view import SceneView
from citylod.core.errors import CitylodError
from citylod.core.gc_policy import GcPolicy
from citylod.io.tiles3d.remote import is_ion, is_url, unfold_url

__all__ = ["MainWindow", "settings"]

_FILTER = ("All supported (*.citylod *.json *.3tz *.3dtiles *.gpkg *.tif *.tiff *.vrt *.las *.laz *.gml *.xml *.cityjson);;"
           "citylod project (*.citylod);;"
           "Tileset (tileset.json *.3tz *.3dtiles);;City store (*.gpkg);;Raster DSM (*.tif *.tiff *.vrt);;"
           "Point cloud (*.las *.laz);;City model (*.gml *.xml *.json *.cityjson);;All files (*)")
_MAX_RECENT = 10
# Width of each side column of docks at first start (later, the saved layout): the widest panel's narrowest.
SIDE_PX = 300


def settings() -> QSettings:
    return QSettings("citylod", "citylod")


class MainWindow(QMainWindow):
    """The citylod desktop window. ``opened(path)`` after a source is open; ``failed(message)``."""

    opened = Signal(str)
    failed = Signal(str)

    def __init__(self, document: Document | None = None, *, settings_: QSettings | None = None,
                 interactive: bool = True, restore_layout: bool = True) -> None:
        super().__init__()
        self.setWindowTitle("citylod")
        self.setAcceptDrops(True)
        self.settings = settings_ if settings_ is not None else settings()
        self.document = document if document is not None else Document()
        # the semantic overlay's height map is built off the GUI thread (100 ms rule)
        self.document.async_semantics = True
        self.interactive = interactive  # False: errors go to the status bar and stderr, no message boxes
        self.tasks: list[ProcessTask] = []
        self._built_from: dict[str, str] = {}  # build output → the raw file's name, for messages
        self.errors: list[str] = []
        self.view = SceneView(self.document, self)
        self.setCentralWidget(self.view)
        self.layers = LayerPanel(self.document)
        self.tree = ObjectTreePanel(self.document)
        self.inspector = AttributePanel(self.document)
        self.query = QueryPanel(self.document, self.settings)
        self.lod = LodPanel(self.document)
        self.measure = MeasurePanel(self.start_measure, self.view.clear_measure)
        # Bookmarks belong to the project (saved in its file), not to the user's settings.
        self.bookmarks = BookmarkPanel(self.view.camera, self.view.set_camera, None)
        self.project_path: Path | None = None
        self.windows: list[MainWindow] = []  # projects opened from a window that already held data
        self.profile = ProfilePanel(self.document)
        self.points = PointPanel(self.document)
        self.clip = ClipPanel(self.document, self._focus)
        self.flood = FloodPanel(self.document)
        self.flood.render_requested.connect(self.view.request_render)
        self.docks: dict[str, QDockWidget] = {}
        left, right = Qt.DockWidgetArea.LeftDockWidgetArea, Qt.DockWidgetArea.RightDockWidgetArea
        for name, title, widget, area in (
                ("layers", "Layers", self.layers, left), ("lod", "Level of detail", self.lod, left),
                ("objects", "City objects", self.tree, left), ("attributes", "Attributes", self.inspector, right),
                ("query", "Query", self.query, right), ("measure", "Measure", self.measure, right),
                ("bookmarks", "Bookmarks", self.bookmarks, right),
                ("profile", "Profile", self.profile, right), ("flood", "Flood", self.flood, right),
                ("points", "Points", self.points, left), ("clip", "Clipping", self.clip, left)):
            dock = QDockWidget(title, self)
            dock.setObjectName(f"dock_{name}")
            dock.setWidget(widget)
            self.addDockWidget(area, dock)
            self.docks[name] = dock
        self.tabifyDockWidget(self.docks["measure"], self.docks["bookmarks"])
        self.tabifyDockWidget(self.docks["measure"], self.docks["profile"])
        self.tabifyDockWidget(self.docks["measure"], self.docks["flood"])
        self.tabifyDockWidget(self.docks["lod"], self.docks["points"])
        self.tabifyDockWidget(self.docks["lod"], self.docks["clip"])
        self.docks["measure"].raise_()
        self.docks["lod"].raise_()
        # The side columns at their panels' narrowest useful width, so the 3D view gets most of the window
        # (at 1400 px: 787 px against 614 before the panels' button rows were wrapped).
        self.resizeDocks([self.docks["layers"], self.docks["attributes"]], [SIDE_PX, SIDE_PX],
                         Qt.Orientation.Horizontal)
        # Permanent widgets on the right, without stretch: the left part stays free for showMessage()
        # (a stretched statistics label used to cover every status message).
        self.cursor_label = QLabel("")
        self.status = QLabel("no data")
        self.statusBar().addPermanentWidget(self.cursor_label)
        self.statusBar().addPermanentWidget(self.status)
        self.view.cursor.connect(self._on_cursor)
        self.view.frame.connect(self._on_frame)
        self.view.picked.connect(self._on_picked)
        self.view.measured.connect(self.measure.show_measurement)
        self.query.zoom_requested.connect(self.view.frame_objects)
        self.actions: dict[str, QAction] = {}
        self._build_menus()
        self.resize(1400, 900)
        self.restore_layout = restore_layout
        geo = self.settings.value("window/geometry") if restore_layout else None
        if isinstance(geo, QByteArray) and not geo.isEmpty():
            self.restoreGeometry(geo)
        state = self.settings.value("window/state") if restore_layout else None
        if isinstance(state, QByteArray) and not state.isEmpty():
            self.restoreState(state)
        self._status_timer = QTimer(self)
        self._status_timer.setInterval(250)
        self._status_timer.timeout.connect(self._update_status)
        self._status_timer.start()
        # Python's full garbage collections held the GUI thread for 0.3-0.6 s in the middle of a frame:
        # they run only while the view is idle (core/gc_policy.py).
        self.gc_policy = GcPolicy()
        self.gc_policy.install()
        self.view.gc_policy = self.gc_policy

    # -- menus and shortcuts ----------------------------------------------------------------------
    def _action(self, key: str, text: str, slot: Any, shortcut: str | None = None, menu: Any = None,
                context: Qt.ShortcutContext = Qt.ShortcutContext.WindowShortcut) -> QAction:
        act = QAction(text, self)
        if shortcut:
            act.setShortcut(QKeySequence(shortcut))
            act.setShortcutContext(context)
        act.triggered.connect(profiled(f"action.{key}")(lambda *_: slot()))
        if menu is not None:
            menu.addAction(act)
        else:
            self.addAction(act)
        self.actions[key] = act
        return act

    def _build_menus(self) -> None:
        mb = self.menuBar()
        f = mb.addMenu("&File")
        self._action("open", "&Open…", self.open_dialog, "Ctrl+O", f)
        self._action("open_folder", "Open tileset &folder…", self.open_folder_dialog, None, f)
        self._action("open_url", "Open tileset &URL…", self.open_url_dialog, None, f)
        self.recent_menu = f.addMenu("Open &recent")
        self._refresh_recent()
        f.addSeparator()
        self._action("open_project", "Open pro&ject…", self.open_project_dialog, None, f)
        self._action("save_project", "&Save project", self.save_project_dialog, "Ctrl+S", f)
        self._action("save_project_as", "Save project &as…", lambda: self.save_project_dialog(ask=True), None, f)
        f.addSeparator()
        self._action("save_camera", "Save &camera…", self.save_camera_dialog, "Ctrl+Shift+S", f)
        self._action("export", "&Export image…", self.export_dialog, "Ctrl+E", f)
        self._action("export_points", "Export &points…", self.export_points_dialog, None, f)
        self._action("screenshot", "Save &window screenshot…", self.screenshot_dialog, None, f)
        f.addSeparator()
        self._action("quit", "&Quit", self.close, "Ctrl+Q", f)
        v = mb.addMenu("&View")
        self._action("reset", "&Reset view", self.view.reset_view, "R", v)
        self._action("navigation", "&Turntable / fly navigation", self.toggle_navigation, "T", v)
        self._action("focus", "&Focus on point under cursor", self.view.focus_under_cursor, "F", v)
        nav = v.addMenu("Fly")
        for key, direction in (("W", "forward"), ("S", "backward"), ("A", "left"), ("D", "right"),
                               ("E", "up"), ("Q", "down")):
            act = self._action(f"fly_{direction}", f"Fly {direction}", lambda d=direction: self.view.fly(d), key,
                               nav)
            act.setAutoRepeat(True)
        v.addSeparator()
        self._action("bookmark", "Add &bookmark", lambda: self.bookmarks.add(None), "Ctrl+B", v)
        v.addSeparator()
        for dock in self.docks.values():
            v.addAction(dock.toggleViewAction())
        t = mb.addMenu("&Tools")
        self._action("measure_distance", "Measure &distance", lambda: self.start_measure("distance"), "M", t)
        self._action("measure_height", "Measure &height difference", lambda: self.start_measure("height"), "H", t)
        self._action("measure_area", "Measure &area", lambda: self.start_measure("area"), "G", t)
        self._action("profile", "Height &profile", lambda: self.start_measure("profile"), "P", t)
        self._action("escape", "End measurement", self._escape, "Esc", t)
        ell = self._action("ellipsoidal", "&Ellipsoidal distances (geodesic)", lambda: None, None, t)
        ell.setCheckable(True)
        ell.setToolTip("measure lengths and areas on the CRS's ellipsoid (GeographicLib) instead of the "
                       "projection's plane")
        ell.toggled.connect(self._set_ellipsoidal)
        t.addSeparator()
        self._action("clear_state", "Clear highlight / hide / isolate", self.document.clear_state, None, t)
        h = mb.addMenu("&Help")
        self._action("shortcuts", "&Shortcuts", self.show_shortcuts, "F1", h)
        self._action("about", "&About citylod", self._about, None, h)

    def _focus(self) -> tuple[Any, float] | None:
        cam = self.view.camera()
        if cam is None:
            return None
        import numpy as np

        return np.asarray(cam.focal_point), float(np.linalg.norm(np.subtract(cam.position, cam.focal_point)))

    def toggle_navigation(self) -> str:
        """Switch between turntable and fly navigation; returns the new mode."""
        mode = "fly" if self.view.navigator.mode == "turntable" else "turntable"
        self.view.navigator.set_mode(mode)
        self.statusBar().showMessage(f"navigation: {mode}"
                                     + (" (left drag looks around, wheel moves forward, WASD/QE fly)"
                                        if mode == "fly" else " (left drag orbits, middle pans, wheel zooms)"), 6000)
        return mode

    def _escape(self) -> None:
        self.view.escape()
        self.measure.set_active(self.view.measure_kind)

    def show_shortcuts(self) -> QDialog:
        dlg = QDialog(self)
        dlg.setWindowTitle("Keyboard shortcuts")
        table = QTableWidget(len(SHORTCUTS), 2)
        table.setHorizontalHeaderLabels(["keys", "action"])
        table.verticalHeader().setVisible(False)
        table.horizontalHeader().setStretchLastSection(True)
        for r, (k, text) in enumerate(SHORTCUTS):
            table.setItem(r, 0, QTableWidgetItem(k))
            table.setItem(r, 1, QTableWidgetItem(text))
        table.resizeColumnToContents(0)
        lay = QVBoxLayout(dlg)
        lay.addWidget(QLabel("Mouse: left drag orbits, middle drag pans, wheel zooms, click picks."))
        lay.addWidget(table)
        box = QDialogButtonBox(QDialogButtonBox.StandardButton.Close)
        box.rejected.connect(dlg.reject)
        lay.addWidget(box)
        dlg.resize(520, 480)
        dlg.show()
        return dlg

    def _about(self) -> None:
        QMessageBox.about(self, "citylod", "citylod — level-of-detail rendering and semantic interaction for "
                          "DSMs, LiDAR point clouds and city models.")

    # -- status -----------------------------------------------------------------------------------
    def _on_frame(self, ms: float) -> None:
        self._last_frame_ms = ms

    @profiled("MainWindow.status")
    def _update_status(self) -> None:
        if not self.document.entries:
            return
        ms = getattr(self, "_last_frame_ms", 0.0)
        if self.document.scene.layers or not any(e.far is not None for e in self.document.entries):
            text = format_status(self.document.scene.last_stats, ms, self.view.pending())
        else:  # only far fields: the scene's tile counts and τ would read as zeros
            pending = self.view.pending()
            text = f"{ms:.0f} ms" + (f" · {pending} loading" if pending else " · complete")
        budget = format_budget_status(self.document)
        far = format_far_status(self.document)
        self.status.setText(" · ".join(t for t in (budget, text, far) if t))

    def _on_cursor(self, point: Any) -> None:
        if self.document.entries:
            self.cursor_label.setText(format_cursor(point, self.document.crs, self.document.geographic))

    # -- picking and measuring ----------------------------------------------------------------------
    def _on_picked(self, object_id: str | None) -> None:
        if object_id is not None:
            self.statusBar().showMessage(f"picked {object_id}", 4000)

    def _set_ellipsoidal(self, on: bool) -> None:
        self.document.ellipsoidal = bool(on)
        self.statusBar().showMessage("measuring on the ellipsoid" if on else "measuring in the projection", 3000)

    def start_measure(self, kind: str | None) -> None:
        self.view.start_measure(kind)
        self.measure.set_active(kind)
        if kind is not None:
            self.docks["profile" if kind == "profile" else "measure"].raise_()
            self.statusBar().showMessage(f"measure {kind}: click points in the view, Esc ends", 6000)

    # -- opening ------------------------------------------------------------------------------------
    def _error(self, message: str) -> None:
        self.errors.append(message)
        self.failed.emit(message)
        self.statusBar().showMessage(message, 10000)
        if self.interactive:
            QMessageBox.warning(self, "citylod", message)
        else:
            import sys

            print(f"citylod: error: {message}", file=sys.stderr)

    def open_paths(self, paths: Sequence[str | os.PathLike[str]]) -> None:
        for p in paths:
            self.open_path(p)

    # -- projects -----------------------------------------------------------------------------------
    def save_project(self, path: str | os.PathLike[str]) -> Path | None:
        """Save sources, display, camera, bookmarks and object state to a project file (app/project.py)."""
        from citylod.app.project import save_project

        try:
            out = save_project(path, self.document, self.view.camera(), self.bookmarks.bookmarks)
        except OSError as exc:
            self._error(f"{path}: cannot write the project ({exc})")
            return None
        self.project_path = out
        self.setWindowTitle(f"citylod — {out.stem}")
        self.statusBar().showMessage(f"project saved to {out}", 6000)
        return out

    def save_project_dialog(self, ask: bool = False) -> None:
        path: str | Path | None = self.project_path
        if path is None or ask:
            path, _ = QFileDialog.getSaveFileName(self, "Save project", str(self.settings.value(
                "last_dir", str(Path.home()))) + "/project.citylod", "citylod project (*.citylod)")
        if path:
            self.save_project(path)

    def open_project(self, path: str | os.PathLike[str]) -> MainWindow | None:
        """Open a project; in this window when it is empty, else in a new one (returned)."""
        from citylod.app.project import apply_project, read_project

        try:
            project = read_project(path)
        except CitylodError as exc:
            self._error(str(exc))
            return None
        if self.document.entries:
            win = MainWindow(settings_=self.settings, interactive=self.interactive,
                             restore_layout=self.restore_layout)
            win.resize(self.size())
            win.show()
            self.windows.append(win)
            return win if win.open_project(path) is not None else None
        try:
            apply_project(self.document, project)
        except (CitylodError, OSError, ValueError) as exc:
            self._error(f"{path}: {exc}")
            return None
        self.gc_policy.settle()
        self.bookmarks.set_bookmarks(project.bookmarks)
        if project.camera is not None:
            self.view.set_camera(project.camera)
        else:
            self.view.reset_view()
        self.project_path = project.path
        self.setWindowTitle(f"citylod — {project.path.stem}")
        self._add_recent(project.path)
        self.opened.emit(str(project.path))
        return self

    def open_project_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Open project", str(self.settings.value(
            "last_dir", str(Path.home()))), "citylod project (*.citylod)")
        if path:
            self.open_project(path)

    @profiled("MainWindow.open_path")
    def open_path(self, path: str | os.PathLike[str]) -> bool:
        """Open a source (a file, folder or tileset URL); raw inputs start a build whose result opens when done.
        False on an error."""
        p = Path(path)
        if p.suffix == ".citylod":
            return self.open_project(p) is not None
        if is_ion(p) and not self._ion_token():
            return False
        kind = source_kind(p)
        if kind in ("raster", "points", "citymodel"):
            return self.build_and_open(p)
        first = not self.document.entries
        try:
            entry = self.document.open(p)
        except (CitylodError, OSError, ValueError) as exc:
            self._error(str(exc))
            return False
        reprojection = getattr(entry.layer, "reprojection", None)
        if reprojection is not None:  # a layer in another CRS than the project's (the first layer's)
            name = self._built_from.get(str(p)) or (p.parent.name if p.name == "tileset.json" else p.name)
            self.statusBar().showMessage(f"{name}: {reprojection.label}", 10000)
        self._add_recent(p)
        self.gc_policy.settle()  # the layer's tile tree and store live as long as the window
        if first or (kind == "tileset" and len(self.document.scene.layers) == 1):
            self.view.reset_view()
        self.view.request_render()
        self.opened.emit(str(p))
        return True

    def ask_crs(self, path: Path) -> str | None:
        """Ask for the CRS of a file that declares none; None when the user cancels."""
        from PySide6.QtWidgets import QInputDialog

        text, ok = QInputDialog.getText(
            self, "CRS needed", f"{path.name} does not say which coordinate reference system it uses.\n"
            "Enter it (e.g. EPSG:28992 for the Netherlands, EPSG:25832 for UTM 32N):", text="EPSG:")
        return text if ok else None

    def build_and_open(self, path: Path, crs: str | None = None) -> bool:
        """Build a raw input in a subprocess and open the result; a LAS/LAZ without a CRS asks for one."""
        if crs is None and missing_crs(path):
            answer = self.ask_crs(path) if self.interactive else None
            if answer is None:
                self._error(f"{path}: the header has no CRS; open it again and enter one (e.g. EPSG:28992)")
                return False
            try:
                crs = check_crs(answer)
            except CitylodError as exc:
                self._error(str(exc))
                return False
        try:
            plan = build_plan(path, crs=crs)
        except CitylodError as exc:
            self._error(str(exc))
            return False
        if plan.output.exists():
            target = plan.output
            if source_kind(target) in ("tileset", "store"):
                self._built_from[str(target)] = path.name
                self.statusBar().showMessage(f"{path.name}: opening the existing {plan.label} {target}", 6000)
                return self.open_path(target)
        self._built_from[str(plan.output)] = path.name
        task = ProcessTask(plan.argv, plan.output, f"Building the {plan.label} of {path.name}…", self)
        task.finished.connect(lambda ok, out, msg, t=task: self._build_done(t, ok, out, msg))
        self.tasks.append(task)
        task.start()
        return True

    def _build_done(self, task: ProcessTask, ok: bool, output: str, message: str) -> None:
        if task in self.tasks:
            self.tasks.remove(task)
        if ok:
            self.open_path(output)
        elif message == "cancelled":
            self.statusBar().showMessage("build cancelled", 6000)
        else:
            self._error(f"build of {output} failed: {message}")
        task.deleteLater()

    def open_dialog(self) -> None:
        last = self.settings.value("last_dir", str(Path.home()))
        files, _ = QFileDialog.getOpenFileNames(self, "Open", str(last), _FILTER)
        if files:
            self.settings.setValue("last_dir", str(Path(files[0]).parent))
            self.open_paths(files)

    def open_folder_dialog(self) -> None:
        folder = QFileDialog.getExistingDirectory(self, "Open tileset folder",
                                                  str(self.settings.value("last_dir", str(Path.home()))))
        if folder:
            self.open_path(folder)

    def _ion_token(self) -> bool:
        """Whether a Cesium ion token is set (``CESIUM_ION_TOKEN``); if not, ask for one, kept in this process's
        environment for the session and never written to the settings."""
        from PySide6.QtWidgets import QInputDialog, QLineEdit

        if os.environ.get("CESIUM_ION_TOKEN", "").strip():
            return True
        token, ok = QInputDialog.getText(self, "Cesium ion access token",
                                         "Access token for Cesium ion (kept for this session only):",
                                         QLineEdit.EchoMode.Password)
        if not ok or not token.strip():
            return False
        os.environ["CESIUM_ION_TOKEN"] = token.strip()
        return True

    def open_url_dialog(self) -> None:
        """A tileset on a web server: the URL of its tileset JSON (tiles are fetched as views need them)."""
        from PySide6.QtWidgets import QInputDialog

        url, ok = QInputDialog.getText(self, "Open tileset URL",
                                       "URL of a 3D Tiles tileset JSON (http or https), or ion:ASSET_ID for a Cesium "
                                       "ion asset:",
                                       text=str(self.settings.value("last_url", "https://")))
        url = url.strip()
        if not ok or not url:
            return
        if not is_url(url):
            self._error(f"{url}: not an http(s) URL or ion:ASSET_ID")
            return
        self.settings.setValue("last_url", url)
        QApplication.setOverrideCursor(Qt.CursorShape.WaitCursor)  # the tileset JSON is fetched on this thread
        try:
            self.open_path(url)
        finally:
            QApplication.restoreOverrideCursor()

    def recent_files(self) -> list[str]:
        val = self.settings.value("recent", [])
        return [str(v) for v in (val if isinstance(val, list) else [val]) if v]

    def _add_recent(self, path: Path) -> None:
        p = unfold_url(str(path)) if is_url(path) else str(path.resolve())
        items = [p] + [r for r in self.recent_files() if r != p]
        self.settings.setValue("recent", items[:_MAX_RECENT])
        self._refresh_recent()

    def _refresh_recent(self) -> None:
        self.recent_menu.clear()
        for r in self.recent_files():
            act = self.recent_menu.addAction(r)
            act.triggered.connect(lambda *_, r=r: self.open_path(r))
        self.recent_menu.setEnabled(bool(self.recent_files()))

    # -- drag and drop ------------------------------------------------------------------------------
    def dragEnterEvent(self, event: Any) -> None:
        if event.mimeData().hasUrls():
            event.acceptProposedAction()

    def dropEvent(self, event: Any) -> None:
        paths = [u.toLocalFile() for u in event.mimeData().urls() if u.isLocalFile()]
        if paths:
            event.acceptProposedAction()
            QTimer.singleShot(0, lambda: self.open_paths(paths))

    # -- camera and images ----------------------------------------------------------------------------
    def save_camera(self, path: str | os.PathLike[str]) -> bool:
        cam = self.view.camera()
        if cam is None:
            return False
        cam.save(path)
        return True

    def save_camera_dialog(self) -> None:
        path, _ = QFileDialog.getSaveFileName(self, "Save camera", "camera.json", "Camera (*.json)")
        if path and self.save_camera(path):
            self.statusBar().showMessage(f"camera saved to {path} (for citylod render --camera)", 6000)

    def grab_window(self) -> QImage:
        """The whole window as an image, with the 3D view's framebuffer composited in (a plain grab of a
        native GL child is black)."""
        frame = self.view.framebuffer()
        image = self.grab().toImage().convertToFormat(QImage.Format.Format_RGB32)
        painter = QPainter(image)
        # Logical rectangle: QPainter scales the device-pixel framebuffer on high-DPI screens.
        painter.drawImage(QRect(self.view.origin_in(self), self.view.vtk.size()), frame)
        painter.end()
        return image

    def save_screenshot(self, path: str | os.PathLike[str]) -> Path:
        from citylod.core.fileio import atomic_write

        p = Path(path)
        image = self.grab_window()

        def write(tmp: Path) -> None:
            if not image.save(str(tmp)):
                raise CitylodError("cannot write the screenshot", p)

        return atomic_write(p, write, suffix=p.suffix or ".png")

    def screenshot_dialog(self) -> None:
        path, _ = QFileDialog.getSaveFileName(self, "Save window screenshot", "citylod.png", "PNG (*.png)")
        if path:
            self.save_screenshot(path)

    def export_image(self, path: str | os.PathLike[str], scale: int = 2) -> Path | None:
        """Write the 3D view as drawn now at ``scale``× its size to a PNG: class colours, highlights, hidden
        objects, class filter and clipping box as on screen (:meth:`SceneView.render_image`)."""
        from citylod.core.fileio import atomic_write_bytes
        from citylod.io.image import encode_png

        if not self.document.entries:
            self._error("nothing to export: open a source first")
            return None
        rgb = self.view.render_image(scale)
        try:
            out = atomic_write_bytes(path, encode_png(rgb, level=6))
        except OSError as exc:
            self._error(f"{path}: cannot write the image ({exc})")
            return None
        self.statusBar().showMessage(f"image {rgb.shape[1]}×{rgb.shape[0]} written to {out}", 8000)
        return out

    def export_points(self, path: str | os.PathLike[str]) -> int | None:
        """Write the drawn points with their drawn colours (class colours, highlights) to a LAS file."""
        try:
            n = self.document.export_points(path)
        except (CitylodError, OSError) as exc:
            self._error(f"{path}: {exc}" if isinstance(exc, OSError) else str(exc))
            return None
        self.statusBar().showMessage(f"{n} points written to {path}", 8000)
        return n

    def export_points_dialog(self) -> None:
        path, _ = QFileDialog.getSaveFileName(self, "Export points", str(self.settings.value(
            "last_dir", str(Path.home()))) + "/points.las", "LAS (*.las)")
        if path:
            self.export_points(path)

    def export_dialog(self) -> None:
        dlg = QDialog(self)
        dlg.setWindowTitle("Export image")
        form = QFormLayout(dlg)
        scale = QSpinBox()
        scale.setRange(1, 8)
        scale.setValue(2)
        size = QLabel()

        def show_size(k: int) -> None:
            ratio = self.view.vtk.devicePixelRatioF()
            size.setText(f"{round(self.view.vtk.width() * ratio) * k} × {round(self.view.vtk.height() * ratio) * k} px")

        scale.valueChanged.connect(show_size)
        show_size(scale.value())
        form.addRow("scale (× the view)", scale)
        form.addRow("size", size)
        box = QDialogButtonBox(QDialogButtonBox.StandardButton.Ok | QDialogButtonBox.StandardButton.Cancel)
        box.accepted.connect(dlg.accept)
        box.rejected.connect(dlg.reject)
        form.addRow(box)
        if dlg.exec() != QDialog.DialogCode.Accepted:
            return
        path, _ = QFileDialog.getSaveFileName(self, "Export image", str(self.settings.value(
            "last_dir", str(Path.home()))) + "/citylod.png", "PNG (*.png)")
        if path:
            self.export_image(path, scale.value())

    # -- closing --------------------------------------------------------------------------------------
    def closeEvent(self, event: Any) -> None:
        if self.restore_layout:  # a batch window's default layout must not replace the user's
            self.settings.setValue("window/geometry", self.saveGeometry())
            self.settings.setValue("window/state", self.saveState())
            self.settings.sync()
        for t in list(self.tasks):
            t.cancel()
        self._status_timer.stop()
        self.view.shutdown()
        self.document.close()
        self.gc_policy.uninstall()
        super().closeEvent(event)

    def copy_text(self, text: str) -> None:
        QGuiApplication.clipboard().setText(text)

