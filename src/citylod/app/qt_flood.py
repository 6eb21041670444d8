"""The flood panel: water-level and time sliders, the water in the view, the affected buildings listed.

Model, adapter, widget (STYLE.md): :class:`~citylod.analysis.scenario.FloodScenario` holds the state,
:class:`~citylod.render.water.WaterSurface` shows it, this panel only holds them and calls their methods.
A slider move shows the 4× decimated extent at once, then computes the full-resolution result on a worker
thread and shows it when done (VTK is changed only here, on the GUI thread). Affected buildings are
highlighted through the document's feature state (the semantic overlay) and listed; a click selects one.
"""

from __future__ import annotations

import os
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

from PySide6.QtCore import Qt, QTimer, Signal
from PySide6.QtWidgets import (
    QFileDialog,
    QFormLayout,
    QHeaderView,
    QLabel,
    QPushButton,
    QSlider,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

from citylod.analysis.flood import FloodSources
from citylod.analysis.scenario import FloodResult, FloodScenario

__all__ = ["FloodPanel"]

_STEP_M = 0.05  # the level slider's step
_AFFECTED_RGB = "#ff4040"


class FloodPanel(QWidget):
    """Flood scenario controls for a :class:`~citylod.app.models.Document`. ``updated(result)`` after a
    full-resolution result is shown; ``render_requested`` when the view should draw again."""

    updated = Signal(object)
    render_requested = Signal()

    def __init__(self, document: Any, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.document = document
        self.scenario: FloodScenario | None = None
        self.water: Any = None
        self.result: FloodResult | None = None
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="flood")
        self._future: Future[FloodResult] | None = None
        self._again = False
        self._highlighted: list[str] = []
        self.load_button = QPushButton("Load raster or tileset…")
        self.load_button.clicked.connect(self._load_dialog)
        self.view_button = QPushButton("Flood the DSM in the view")
        self.view_button.setObjectName("flood_view_dsm")
        self.view_button.setToolTip("Flood the open DSM tileset from the edge: its leaves on the source grid, "
                                    "within their certified error of the source raster")
        self.view_button.clicked.connect(self.load_view_dsm)
        self.level = QSlider(Qt.Orientation.Horizontal)
        self.level.setObjectName("flood_level")
        self.level.setEnabled(False)
        self.level.valueChanged.connect(self._on_level)
        self.time = QSlider(Qt.Orientation.Horizontal)
        self.time.setObjectName("flood_time")
        self.time.setEnabled(False)
        self.time.valueChanged.connect(self._on_time)
        self.level_label = QLabel("–")
        self.summary = QLabel("no flood loaded")
        self.table = QTableWidget(0, 3)
        self.table.setHorizontalHeaderLabels(["building", "max depth", "mean depth"])
        self.table.setToolTip("affected buildings: water depth along the footprint, maximum and mean (m)")
        self.table.verticalHeader().setVisible(False)  # row numbers took a fifth of the dock's width
        head = self.table.horizontalHeader()
        head.setSectionResizeMode(0, QHeaderView.ResizeMode.Stretch)
        for col in (1, 2):
            head.setSectionResizeMode(col, QHeaderView.ResizeMode.ResizeToContents)
        self.table.cellClicked.connect(self._on_row)
        form = QFormLayout()
        form.addRow("Water level", self.level)
        form.addRow("", self.level_label)
        form.addRow("Time", self.time)
        lay = QVBoxLayout(self)
        lay.addWidget(self.load_button)
        lay.addWidget(self.view_button)
        lay.addLayout(form)
        lay.addWidget(self.summary)
        heading = QLabel("Affected buildings (water depth along the footprint, m)")
        heading.setWordWrap(True)  # a label's text would otherwise set the dock's narrowest width
        lay.addWidget(heading)
        lay.addWidget(self.table, 1)
        self._poll = QTimer(self)
        self._poll.setInterval(30)
        self._poll.timeout.connect(self._check)

    # -- loading ----------------------------------------------------------------------------------
    def _load_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Height raster or DSM tileset to flood", "",
                                              "Rasters or tilesets (*.tif *.tiff *.json *.3tz *.3dtiles)")
        if path:
            self.load(path, FloodSources(edge=True))

    def load_view_dsm(self) -> bool:
        """Flood the first DSM tileset open in the document from the edge; False (and a note) without one."""
        for entry in self.document.entries:
            ts = getattr(entry.layer, "tileset", None)
            if entry.kind == "tileset" and ts is not None and getattr(ts, "kind", "") == "dsm":
                self.load(entry.path, FloodSources(edge=True))
                return True
        self.summary.setText("no DSM tileset is open")
        return False

    def load(self, raster: str | os.PathLike[str], sources: FloodSources, *, levels: list[float] | None = None,
             city: str | os.PathLike[str] | None = None) -> None:
        """Open a flood over ``raster`` (city: the document's store when omitted)."""
        from citylod.render.water import WaterSurface

        if city is None and self.document.store is not None:
            city = self.document.store.path
        self.scenario = FloodScenario(raster, sources, city=city, levels=levels or [])
        lo, hi = self.scenario.height_range
        self.level.blockSignals(True)
        self.level.setRange(int(lo / _STEP_M), int(hi / _STEP_M) + 1)
        self.level.setValue(int(round(self.scenario.level / _STEP_M)))
        self.level.blockSignals(False)
        self.level.setEnabled(True)
        self.time.blockSignals(True)
        self.time.setRange(0, len(self.scenario.levels) - 1)
        self.time.setValue(0)
        self.time.blockSignals(False)
        self.time.setEnabled(len(self.scenario.levels) > 1)
        if self.water is not None:
            self.water.close()
        self.water = WaterSurface(self.document.scene, self.scenario.bounds)
        self.show_level(self.scenario.level)

    # -- level changes ----------------------------------------------------------------------------
    def _on_level(self, value: int) -> None:
        self.show_level(value * _STEP_M)

    def _on_time(self, index: int) -> None:
        if self.scenario is not None:
            self.scenario.set_time(index)
            self.level.blockSignals(True)
            self.level.setValue(int(round(self.scenario.level / _STEP_M)))
            self.level.blockSignals(False)
            self.show_level(self.scenario.level)

    def show_level(self, level: float) -> None:
        """Show ``level``: the coarse extent now, the full result when the worker has it."""
        if self.scenario is None:
            return
        self.scenario.set_level(level)
        self.level_label.setText(f"{level:.2f} m")
        coarse = self.scenario.preview(level)
        self.water.set_mask(coarse.mask, None, level)
        self.summary.setText(f"≈ {coarse.area_m2:,.0f} m² flooded (preview)")
        self._request_render()
        if self._future is not None and not self._future.done():
            self._again = True  # one computation at a time; the latest level follows
            return
        self._future = self._pool.submit(self.scenario.compute, level)
        self._poll.start()

    def _check(self) -> None:
        fut = self._future
        if fut is None or not fut.done():
            return
        self._poll.stop()
        res = fut.result()
        self._future = None
        if self._again and self.scenario is not None:
            self._again = False
            self._future = self._pool.submit(self.scenario.compute, self.scenario.level)
            self._poll.start()
            if res.level != self.scenario.level:
                return
        self._show(res)

    def _show(self, res: FloodResult) -> None:
        assert self.scenario is not None
        self.result = res
        self.water.set_mask(res.mask, self.scenario.model.heights, res.level)
        eps = self.scenario.tileset_error_m
        self.summary.setText(f"{res.area_m2:,.0f} m² flooded, {res.volume_m3:,.0f} m³, "
                             f"{len(res.affected)} buildings affected"
                             + (f" (tileset heights, within {eps:.2g} m)" if eps is not None else ""))
        self.table.setRowCount(len(res.affected))
        for i, a in enumerate(sorted(res.affected, key=lambda a: -a.max_depth_m)):
            for j, v in enumerate((a.object_id, f"{a.max_depth_m:.2f}", f"{a.mean_depth_m:.2f}")):
                self.table.setItem(i, j, QTableWidgetItem(v))
        ids = [a.object_id for a in res.affected]
        if self.document.store is not None:
            gone = set(self._highlighted) - set(ids)
            if gone:
                self.document.state.unhighlight(gone)
            self.document.state.highlight(ids, _AFFECTED_RGB)
            self._highlighted = ids
        self.document.results = ids
        self._request_render()
        self.updated.emit(res)

    def _on_row(self, row: int, _col: int) -> None:
        item = self.table.item(row, 0)
        if item is not None:
            self.document.select([item.text()])

    def _request_render(self) -> None:
        self.render_requested.emit()

    def wait(self, timeout_s: float = 30.0) -> FloodResult | None:
        """Block until the pending full-resolution result is shown (scripts and tests)."""
        import time

        end = time.monotonic() + timeout_s
        while (self._future is not None or self._again) and time.monotonic() < end:
            if self._future is not None:
                self._future.result(timeout=max(0.0, end - time.monotonic()))
            self._check()
        return self.result

    def closeEvent(self, event: Any) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
        super().closeEvent(event)
