"""Dock panels of the main window. Each holds the :class:`~citylod.app.models.Document` and calls its methods;
none keeps state of its own that the document does not have.

* :class:`LayerPanel` — visibility, opacity, colour mode per layer;
* :class:`ObjectTreePanel` — the city objects grouped by type, selection linked both ways with the
  feature state;
* :class:`AttributePanel` — the attributes of the selected object;
* :class:`QueryPanel` — SQL WHERE (with history) or a registered query, results, highlight / hide /
  isolate / zoom to;
* :class:`LodPanel` — τ (log slider), point and memory budgets, freeze, colour by level;
* :class:`MeasurePanel` — distance, height difference, area, copy to the clipboard;
* :class:`BookmarkPanel` — named cameras.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

from PySide6.QtCore import QItemSelectionModel, QSettings, Qt, Signal
from PySide6.QtGui import QGuiApplication, QStandardItem, QStandardItemModel
from PySide6.QtWidgets import (
    QAbstractItemView,
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QFormLayout,
    QGridLayout,
    QHBoxLayout,
    QHeaderView,
    QInputDialog,
    QLabel,
    QListWidget,
    QMessageBox,
    QPlainTextEdit,
    QPushButton,
    QSlider,
    QSpinBox,
    QTableWidget,
    QTableWidgetItem,
    QTreeView,
    QTreeWidget,
    QTreeWidgetItem,
    QVBoxLayout,
    QWidget,
)

from citylod.app.models import (
    COLOR_MODES,
    Bookmarks,
    Document,
    QueryHistory,
    tau_from_slider,
    tau_to_slider,
)
from citylod.app.qt_profile import profiled
from citylod.core.camera import Camera
from citylod.core.errors import CitylodError
from citylod.semantics.state import StateChange
from citylod.semantics.store import CityStore

__all__ = ["AttributePanel", "BookmarkPanel", "LayerPanel", "LodPanel", "MeasurePanel", "ObjectTreePanel",
           "QueryPanel"]

ID_ROLE = Qt.ItemDataRole.UserRole + 1


class LayerPanel(QWidget):
    """One row per layer: visibility checkbox with the name, opacity slider, colour mode."""

    def __init__(self, document: Document, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.document = document
        self.rows: list[tuple[QCheckBox, QSlider, QComboBox]] = []
        self._layout = QVBoxLayout(self)
        self._layout.setContentsMargins(4, 4, 4, 4)
        self._empty = QLabel("No layers. File → Open, or drop files here.")
        self._empty.setWordWrap(True)
        self._layout.addWidget(self._empty)
        self._layout.addStretch(1)
        document.on_change(self._on_document)

    def _on_document(self, kind: str) -> None:
        if kind == "layers":
            self.rebuild()

    def rebuild(self) -> None:
        while self._layout.count() > 2:
            item = self._layout.takeAt(1)
            w = item.widget()
            if w is not None:
                w.hide()
                w.setParent(None)
                w.deleteLater()
        self.rows = []
        self._empty.setVisible(not self.document.entries)
        for i, e in enumerate(self.document.entries):
            row = QWidget()
            grid = QFormLayout(row)
            grid.setContentsMargins(0, 2, 0, 6)
            check = QCheckBox(f"{e.name}  ({e.kind})")
            check.setChecked(e.visible)
            check.setToolTip(str(e.path))
            check.toggled.connect(lambda on, i=i: self.document.set_visible(i, on))
            slider = QSlider(Qt.Orientation.Horizontal)
            slider.setRange(0, 100)
            slider.setValue(round(e.opacity * 100))
            slider.valueChanged.connect(lambda v, i=i: self.document.set_opacity(i, v / 100.0))
            combo = QComboBox()
            combo.addItems(COLOR_MODES)
            combo.setCurrentText(e.color_by)
            combo.currentTextChanged.connect(lambda m, i=i: self.document.set_color_by(i, m))
            if e.far is not None:  # light fields and textured buildings: no colour modes, drawn opaque
                slider.setEnabled(False)
                combo.setEnabled(False)
                check.setToolTip(f"{e.path}: the city with distant buildings drawn as surface light fields")
            elif e.layer is None:  # the city store: semantics, not drawn geometry
                slider.setEnabled(False)
                combo.setEnabled(False)
                check.setToolTip(f"{e.path}: show or hide the city objects (their shading on tiles, or "
                                 "their proxies when no tileset is open)")
            grid.addRow(check)
            grid.addRow("opacity", slider)
            grid.addRow("colour", combo)
            self._layout.insertWidget(self._layout.count() - 1, row)
            self.rows.append((check, slider, combo))


class ObjectTreePanel(QWidget):
    """City objects grouped by type; selecting rows selects objects (and the reverse)."""

    def __init__(self, document: Document, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.document = document
        self.model = QStandardItemModel(self)
        self.model.setHorizontalHeaderLabels(["object", "name"])
        self.tree = QTreeView()
        self.tree.setModel(self.model)
        self.tree.setSelectionMode(QAbstractItemView.SelectionMode.ExtendedSelection)
        self.tree.setUniformRowHeights(True)
        self.tree.header().setSectionResizeMode(0, QHeaderView.ResizeMode.ResizeToContents)
        lay = QVBoxLayout(self)
        lay.setContentsMargins(4, 4, 4, 4)
        lay.addWidget(self.tree)
        self._items: dict[str, QStandardItem] = {}
        self._syncing = False
        self.tree.selectionModel().selectionChanged.connect(self._on_tree_selection)
        document.on_change(lambda kind: self.rebuild() if kind == "layers" else None)
        document.state.on_change(self._on_state)

    @profiled("ObjectTreePanel.rebuild")
    def rebuild(self) -> None:
        self.model.removeRows(0, self.model.rowCount())
        self._items = {}
        for typ, objs in self.document.object_groups().items():
            group = QStandardItem(f"{typ} ({len(objs)})")
            group.setEditable(False)
            group.setSelectable(False)
            for oid, name in objs:
                it = QStandardItem(oid)
                it.setEditable(False)
                it.setData(oid, ID_ROLE)
                nm = QStandardItem(name)
                nm.setEditable(False)
                group.appendRow([it, nm])
                self._items[oid] = it
            self.model.appendRow([group, QStandardItem("")])
        if self.model.rowCount() == 1:
            self.tree.expandAll()

    def selected_ids(self) -> list[str]:
        return [i.data(ID_ROLE) for i in self.tree.selectionModel().selectedRows(0) if i.data(ID_ROLE)]

    @profiled("ObjectTreePanel.selection")
    def _on_tree_selection(self, *_: Any) -> None:
        if self._syncing:
            return
        self._syncing = True
        try:
            self.document.select(self.selected_ids())
        finally:
            self._syncing = False

    def _on_state(self, change: StateChange) -> None:
        if change.kind not in ("select", "clear") or self._syncing:
            return
        self._syncing = True
        try:
            sm = self.tree.selectionModel()
            sm.clearSelection()
            first = None
            for oid in self.document.state.selection:
                it = self._items.get(oid)
                if it is None:
                    continue
                idx = it.index()
                sm.select(idx, QItemSelectionModel.SelectionFlag.Select | QItemSelectionModel.SelectionFlag.Rows)
                first = first or idx
            if first is not None:
                self.tree.expand(first.parent())
                self.tree.scrollTo(first)
        finally:
            self._syncing = False


class AttributePanel(QWidget):
    """The attributes of the (first) selected object."""

    def __init__(self, document: Document, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.document = document
        self.title = QLabel("Nothing selected")
        self.table = QTableWidget(0, 2)
        self.table.setHorizontalHeaderLabels(["attribute", "value"])
        self.table.horizontalHeader().setStretchLastSection(True)
        self.table.verticalHeader().setVisible(False)
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        copy = QPushButton("Copy")
        copy.clicked.connect(self.copy)
        lay = QVBoxLayout(self)
        lay.setContentsMargins(4, 4, 4, 4)
        lay.addWidget(self.title)
        lay.addWidget(self.table)
        lay.addWidget(copy)
        self.object_id: str | None = None
        document.state.on_change(self._on_state)

    def _on_state(self, change: StateChange) -> None:
        if change.kind in ("select", "clear"):
            sel = sorted(self.document.state.selection)
            self.show_object(sel[0] if sel else None, len(sel))

    def show_object(self, object_id: str | None, count: int = 1) -> None:
        self.object_id = object_id
        attrs = self.document.attributes(object_id) if object_id else {}
        self.title.setText("Nothing selected" if object_id is None else
                           f"{object_id}" + (f"  (+{count - 1} more selected)" if count > 1 else ""))
        self.table.setRowCount(len(attrs))
        for r, (k, v) in enumerate(attrs.items()):
            self.table.setItem(r, 0, QTableWidgetItem(str(k)))
            text = f"{v:.3f}" if isinstance(v, float) else json.dumps(v) if isinstance(v, (list, dict)) else str(v)
            self.table.setItem(r, 1, QTableWidgetItem(text))

    def as_text(self) -> str:
        return "\n".join(f"{self.table.item(r, 0).text()}\t{self.table.item(r, 1).text()}"
                         for r in range(self.table.rowCount()))

    def copy(self) -> None:
        QGuiApplication.clipboard().setText(self.as_text())


class QueryPanel(QWidget):
    """A WHERE clause (or JSON parameters of a registered query), Run, results and what to do with them."""

    zoom_requested = Signal(list)

    def __init__(self, document: Document, settings: QSettings | None = None, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.document = document
        self.settings = settings
        stored = settings.value("query/history", []) if settings is not None else []
        self.history = QueryHistory(stored if isinstance(stored, list) else [stored])
        self.kind = QComboBox()
        self.kind.setToolTip("sql: the text is a WHERE clause over city_objects; other queries: JSON parameters")
        try:
            from citylod.semantics.queries import list_queries

            for q in list_queries():
                self.kind.addItem(q.name, q.source)
        except ImportError:  # pragma: no cover - semantics always ships with citylod
            self.kind.addItem("sql")
        self.kind.setCurrentText("sql")
        self.kind.currentTextChanged.connect(self._on_kind)
        self.recent = QComboBox()
        self.recent.setPlaceholderText("history")
        self.recent.textActivated.connect(self._use_history)
        self.edit = QPlainTextEdit()
        self.edit.setPlaceholderText("type = 'Building' AND measured_height > 15")
        self.edit.setMaximumHeight(70)
        self.run_button = QPushButton("Run")
        self.run_button.setShortcut("Ctrl+Return")
        self.run_button.clicked.connect(self.run)
        self.message = QLabel("")
        self.message.setWordWrap(True)
        self.results = QTreeWidget()
        self.results.setRootIsDecorated(False)
        self.results.setUniformRowHeights(True)
        self.results.setSortingEnabled(True)
        self.results.setHeaderLabels(["object_id", *CityStore.LIST_COLUMNS])
        self.results.setSelectionMode(QAbstractItemView.SelectionMode.ExtendedSelection)
        self.results.itemSelectionChanged.connect(self._on_results_selected)
        buttons = QGridLayout()  # three a row: five in one set the right dock's width at 430 px
        self.buttons: dict[str, QPushButton] = {}
        for i, (name, fn) in enumerate((("Highlight", lambda: self.document.highlight(self._targets())),
                         ("Hide", lambda: self.document.hide(self._targets())),
                         ("Isolate", lambda: self.document.isolate(self._targets())),
                         ("Reset", self.document.clear_state),
                         ("Zoom to", lambda: self.zoom_requested.emit(self._targets())))):
            b = QPushButton(name)
            b.clicked.connect(fn)
            buttons.addWidget(b, i // 3, i % 3)
            self.buttons[name] = b
        top = QHBoxLayout()
        top.addWidget(self.kind)
        top.addWidget(self.recent, 1)
        lay = QVBoxLayout(self)
        lay.setContentsMargins(4, 4, 4, 4)
        lay.addLayout(top)
        lay.addWidget(self.edit)
        lay.addWidget(self.run_button)
        lay.addWidget(self.message)
        lay.addWidget(self.results, 1)
        lay.addLayout(buttons)
        self._refresh_history()

    def _on_kind(self, name: str) -> None:
        """Show the chosen query's parameters (a JSON template from its signature) and its description."""
        if name == "sql":
            self.edit.setPlaceholderText("type = 'Building' AND measured_height > 15")
            self.edit.setToolTip("an SQL WHERE clause over city_objects")
            return
        from citylod.semantics.queries import get_query, parameter_hint

        hint = parameter_hint(name)
        query = get_query(name)
        self.edit.setPlaceholderText(f"parameters: {hint}" if hint else "")
        self.edit.setToolTip(getattr(query, "description", "") or "")
        if not self.edit.toPlainText().strip() and hint:
            self.edit.setPlainText(hint)  # a template to edit rather than an empty box

    def _refresh_history(self) -> None:
        self.recent.clear()
        self.recent.addItems(self.history.items)

    def _use_history(self, text: str) -> None:
        self.kind.setCurrentText("sql")
        self.edit.setPlainText(text)

    def _targets(self) -> list[str]:
        chosen = [i.text(0) for i in self.results.selectedItems()]
        return chosen or list(self.document.results)

    def _on_results_selected(self) -> None:
        ids = [i.text(0) for i in self.results.selectedItems()]
        if ids:
            self.document.select(ids)

    @profiled("QueryPanel.run")
    def run(self) -> list[str] | None:
        """Run the query in the edit; the results fill the list. Errors go to the message line."""
        text = self.edit.toPlainText().strip()
        name = self.kind.currentText() or "sql"
        try:
            if name == "sql":
                ids = self.document.run_sql(text)
                self.history.add(text)
                if self.settings is not None:
                    self.settings.setValue("query/history", self.history.items)
                self._refresh_history()
            else:
                params = json.loads(text) if text else {}
                if not isinstance(params, dict):
                    raise CitylodError("parameters of a registered query are a JSON object")
                ids = self.document.run_named(name, **params)
        except (CitylodError, json.JSONDecodeError, TypeError) as exc:
            self.message.setText(f"<span style='color:#b00'>{exc}</span>")
            return None
        self._fill_results(ids[:10000])
        more = " (first 10000 listed)" if len(ids) > 10000 else ""
        self.message.setText(f"{len(ids)} objects{more}")
        return ids


    def _fill_results(self, ids: list[str]) -> None:
        """One row per object: its id and the store's list columns (numbers sort as numbers)."""
        self.results.setSortingEnabled(False)
        self.results.clear()
        store = self.document.store
        rows = store.rows(ids) if store is not None else [()] * len(ids)
        items = []
        for oid, row in zip(ids, rows, strict=True):
            item = QTreeWidgetItem([oid, *("" if v is None else str(v) for v in row)])
            for col, v in enumerate(row, start=1):
                if isinstance(v, (int, float)):
                    item.setData(col, Qt.ItemDataRole.DisplayRole, v)
            items.append(item)
        self.results.addTopLevelItems(items)
        self.results.setSortingEnabled(True)
        self.results.sortByColumn(-1, Qt.SortOrder.AscendingOrder)  # keep the query's order until a click
        for col in range(self.results.columnCount()):
            self.results.resizeColumnToContents(col)


class LodPanel(QWidget):
    """Level-of-detail controls."""

    def __init__(self, document: Document, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.document = document
        lod = document.lod
        self.tau = QSlider(Qt.Orientation.Horizontal)
        self.tau.setRange(0, 1000)
        self.tau.setValue(tau_to_slider(lod.tau_px))
        self.tau_label = QLabel(f"{lod.tau_px:.2f} px")
        self.tau.valueChanged.connect(self._on_tau)
        self.points = QSpinBox()
        self.points.setRange(0, 2_000_000_000)
        self.points.setSingleStep(500_000)
        self.points.setGroupSeparatorShown(True)
        self.points.setSpecialValueText("unlimited")
        self.points.setValue(lod.point_budget)
        self.points.valueChanged.connect(document.set_point_budget)
        # Budget mode next to the fixed budget: off (0), or a frame time to hold by steering τ and the
        # point budget every frame; the fixed τ and point budget are then the most detail it draws.
        self.hold = QDoubleSpinBox()
        self.hold.setRange(0.0, 1000.0)
        self.hold.setDecimals(1)
        self.hold.setSingleStep(5.0)
        self.hold.setSuffix(" ms")
        self.hold.setSpecialValueText("off")
        self.hold.setKeyboardTracking(False)  # typed digits apply on Return, not one by one
        self.hold.setToolTip("Hold this frame time by lowering the point budget and raising τ while the view "
                             "is heavy (Kehl's budget mode); off: the fixed budgets")
        self.hold.setValue(lod.target_ms)
        self.hold.valueChanged.connect(document.set_target_ms)
        self.hold_fps = QLabel(self._fps(lod.target_ms))
        self.hold.valueChanged.connect(lambda ms: self.hold_fps.setText(self._fps(ms)))
        self.memory = QSpinBox()
        self.memory.setRange(16, 1 << 20)
        self.memory.setSingleStep(128)
        self.memory.setSuffix(" MB")
        self.memory.setValue(lod.memory_mb)
        self.memory.valueChanged.connect(document.set_memory_budget)
        self.freeze = QCheckBox("freeze selection")
        self.freeze.toggled.connect(document.set_frozen)
        self.by_level = QCheckBox("colour by level")
        self.by_level.toggled.connect(document.set_color_by_level)
        tau_row = QHBoxLayout()
        tau_row.addWidget(self.tau, 1)
        tau_row.addWidget(self.tau_label)
        form = QFormLayout(self)
        form.addRow("τ (screen error)", tau_row)
        form.addRow("point budget", self.points)
        hold_row = QHBoxLayout()
        hold_row.addWidget(self.hold, 1)
        hold_row.addWidget(self.hold_fps)
        form.addRow("hold frame time", hold_row)
        form.addRow("memory budget", self.memory)
        document.on_change(self._on_document)
        form.addRow(self.freeze)
        form.addRow(self.by_level)

    def _on_document(self, kind: str) -> None:
        if kind == "lod" and self.hold.value() != self.document.lod.target_ms:  # e.g. a project was opened
            self.hold.blockSignals(True)
            self.hold.setValue(self.document.lod.target_ms)
            self.hold.blockSignals(False)
            self.hold_fps.setText(self._fps(self.document.lod.target_ms))

    @staticmethod
    def _fps(ms: float) -> str:
        return f"{1000.0 / ms:.0f} fps" if ms > 0 else "fixed budgets"

    def _on_tau(self, pos: int) -> None:
        tau = tau_from_slider(pos)
        self.tau_label.setText(f"{tau:.2f} px")
        self.document.set_tau(tau)


class MeasurePanel(QWidget):
    """Measurement tools; the view does the picking, this shows and copies the result."""

    def __init__(self, start: Callable[[str | None], None], clear: Callable[[], None],
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.result = QLabel("Pick a tool, then click points in the view (Esc ends).")
        self.result.setWordWrap(True)
        self.result.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        lay = QVBoxLayout(self)
        lay.setContentsMargins(4, 4, 4, 4)
        row = QGridLayout()  # two a row, so the dock does not widen the window's side column
        self.buttons: dict[str, QPushButton] = {}
        for i, (kind, label) in enumerate((("distance", "Distance"), ("height", "Height"), ("area", "Area"),
                                           ("profile", "Profile"))):
            b = QPushButton(label)
            b.setCheckable(True)
            b.clicked.connect(lambda on, k=kind: start(k if on else None))
            row.addWidget(b, i // 2, i % 2)
            self.buttons[kind] = b
        lay.addLayout(row)
        lay.addWidget(self.result)
        row2 = QHBoxLayout()
        self.copy_button = QPushButton("Copy")
        self.copy_button.clicked.connect(self.copy)
        clear_b = QPushButton("Clear")
        clear_b.clicked.connect(clear)
        row2.addWidget(self.copy_button)
        row2.addWidget(clear_b)
        lay.addLayout(row2)
        lay.addStretch(1)
        self.text = ""

    def set_active(self, kind: str | None) -> None:
        for k, b in self.buttons.items():
            b.setChecked(k == kind)

    def show_measurement(self, m: Any) -> None:
        self.text = "" if m is None else m.text()
        self.result.setText(self.text or "Pick a tool, then click points in the view (Esc ends).")

    def copy(self) -> None:
        if self.text:
            QGuiApplication.clipboard().setText(self.text)


class BookmarkPanel(QWidget):
    """Named cameras. The main window keeps them with the project (``settings`` None); given settings, they
    persist there (key ``bookmarks``)."""

    def __init__(self, get_camera: Callable[[], Camera | None], set_camera: Callable[[Camera], None],
                 settings: QSettings | None = None, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.get_camera, self.set_camera, self.settings = get_camera, set_camera, settings
        self.bookmarks = Bookmarks.from_json(settings.value("bookmarks", "") if settings is not None else "")
        self.list = QListWidget()
        self.list.itemDoubleClicked.connect(lambda it: self.restore(it.text()))
        add = QPushButton("Add")
        add.clicked.connect(lambda: self.add(None))
        go = QPushButton("Go")
        go.clicked.connect(lambda: self.restore(self.list.currentItem().text()) if self.list.currentItem() else None)
        rm = QPushButton("Delete")
        rm.clicked.connect(self._remove_current)
        row = QHBoxLayout()
        for b in (add, go, rm):
            row.addWidget(b)
        lay = QVBoxLayout(self)
        lay.setContentsMargins(4, 4, 4, 4)
        lay.addWidget(self.list)
        lay.addLayout(row)
        self._refresh()

    def _refresh(self) -> None:
        self.list.clear()
        self.list.addItems(self.bookmarks.names())

    def set_bookmarks(self, bookmarks: Bookmarks) -> None:
        """Show the bookmarks of a project that was opened (replacing the current ones)."""
        self.bookmarks = bookmarks
        self._save()

    def _save(self) -> None:
        if self.settings is not None:
            self.settings.setValue("bookmarks", self.bookmarks.to_json())
            self.settings.sync()
        self._refresh()

    def add(self, name: str | None) -> str | None:
        """Bookmark the current camera (asks for a name when ``name`` is None)."""
        cam = self.get_camera()
        if cam is None:
            return None
        if name is None:
            name, ok = QInputDialog.getText(self, "Bookmark", "Name:", text=f"View {len(self.bookmarks.items) + 1}")
            if not ok:
                return None
        stored = self.bookmarks.add(name, cam)
        self._save()
        return stored

    def restore(self, name: str) -> bool:
        if name not in self.bookmarks.items:
            return False
        self.set_camera(self.bookmarks.get(name))
        return True

    def _remove_current(self) -> None:
        it = self.list.currentItem()
        if it is not None and QMessageBox.question(self, "Bookmark", f"Delete {it.text()!r}?") == \
                QMessageBox.StandardButton.Yes:
            self.bookmarks.remove(it.text())
            self._save()
