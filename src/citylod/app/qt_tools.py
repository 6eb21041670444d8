"""Dock panels for point clouds and clipping (what CloudCompare and Potree users reach for).

* :class:`PointPanel` — point size and shape, Eye-Dome Lighting, and the class legend: one checkbox per
  ASPRS class present in the loaded tiles, with its colour and point count; unchecking filters the class.
* :class:`ClipPanel` — a clipping box (x/y/z ranges in the data's CRS), set around the view's focus or
  typed in; everything outside it is cut away.

Both only call :class:`~citylod.app.models.Document` methods.
"""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import Qt, QTimer
from PySide6.QtGui import QColor, QIcon, QPixmap
from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QFormLayout,
    QGridLayout,
    QHBoxLayout,
    QLabel,
    QListWidget,
    QListWidgetItem,
    QPushButton,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

from citylod.app.models import ASPRS_CLASSES, POINT_SHAPES, Document

__all__ = ["ClipPanel", "PointPanel"]


def _swatch(rgb: tuple[int, int, int]) -> QIcon:
    pix = QPixmap(14, 14)
    pix.fill(QColor(*rgb))
    return QIcon(pix)


class PointPanel(QWidget):
    """Point size/shape, EDL, and the class legend with its filter."""

    def __init__(self, document: Document, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.document = document
        lay = QVBoxLayout(self)
        lay.setContentsMargins(4, 4, 4, 4)
        form = QFormLayout()
        self.size = QSpinBox()
        self.size.setRange(1, 20)
        self.size.setValue(2)
        self.size.setSuffix(" px")
        self.size.valueChanged.connect(lambda _v: self._apply_points())
        self.shape = QComboBox()
        self.shape.addItems(list(POINT_SHAPES))
        self.shape.setToolTip("splat: oriented disks sized by the local spacing, hole-free up close")
        self.shape.currentTextChanged.connect(lambda _t: self._apply_shape())
        self.edl = QCheckBox("Eye-Dome Lighting")
        self.edl.toggled.connect(document.set_edl)
        form.addRow("point size", self.size)
        form.addRow("point shape", self.shape)
        form.addRow(self.edl)
        lay.addLayout(form)
        lay.addWidget(QLabel("Classes (uncheck to hide):"))
        self.legend = QListWidget()
        self.legend.itemChanged.connect(self._on_item)
        lay.addWidget(self.legend, 1)
        self._classes: dict[int, QListWidgetItem] = {}
        self._updating = False
        self.timer = QTimer(self)
        self.timer.setInterval(1000)
        self.timer.timeout.connect(self.refresh)
        self.timer.start()

    def _apply_points(self) -> None:
        for i, e in enumerate(self.document.entries):
            if e.layer is not None:
                self.document.set_point_size(i, self.size.value())

    def _apply_shape(self) -> None:
        for i, e in enumerate(self.document.entries):
            if e.layer is not None:
                self.document.set_point_shape(i, self.shape.currentText())

    def refresh(self) -> None:
        """Add legend rows for classes that appeared in newly loaded tiles; update the counts."""
        if not self.isVisible() and self._classes:
            return
        from citylod.render.colors import CLASSIFICATION_PALETTE

        counts = self.document.point_classes()
        self._updating = True
        try:
            for code, n in counts.items():
                item = self._classes.get(code)
                if item is None:
                    item = QListWidgetItem(_swatch(tuple(int(v) for v in CLASSIFICATION_PALETTE[code])), "")
                    item.setFlags(item.flags() | Qt.ItemFlag.ItemIsUserCheckable)
                    shown = self.document.class_filter is None or code in self.document.class_filter
                    item.setCheckState(Qt.CheckState.Checked if shown else Qt.CheckState.Unchecked)
                    item.setData(Qt.ItemDataRole.UserRole, code)
                    self.legend.addItem(item)
                    self._classes[code] = item
                item.setText(f"{code} {ASPRS_CLASSES.get(code, f'class {code}')}  ({n:,} points)")
        finally:
            self._updating = False

    def _on_item(self, _item: QListWidgetItem) -> None:
        if self._updating:
            return
        shown = [c for c, it in self._classes.items() if it.checkState() == Qt.CheckState.Checked]
        self.document.set_class_filter(None if len(shown) == len(self._classes) else shown)

    def set_class_checked(self, code: int, on: bool) -> None:
        """Check or uncheck a class row (what a click on its box does)."""
        self._classes[code].setCheckState(Qt.CheckState.Checked if on else Qt.CheckState.Unchecked)


class ClipPanel(QWidget):
    """A clipping box: on/off, ranges, and "around the view" (a box about the focal point)."""

    def __init__(self, document: Document, focus, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.document = document
        self.focus = focus  # () -> (focal point (3,), distance) or None
        lay = QVBoxLayout(self)
        lay.setContentsMargins(4, 4, 4, 4)
        self.enabled = QCheckBox("clip to the box")
        self.enabled.toggled.connect(lambda _on: self.apply())
        lay.addWidget(self.enabled)
        grid = QGridLayout()
        self.spins: list[QDoubleSpinBox] = []
        for r, axis in enumerate("xyz"):
            grid.addWidget(QLabel(axis), r, 0)
            for c in range(2):
                sp = QDoubleSpinBox()
                sp.setRange(-1e9, 1e9)
                sp.setDecimals(2)
                sp.setKeyboardTracking(False)
                sp.valueChanged.connect(lambda _v: self.apply())
                grid.addWidget(sp, r, 1 + c)
                self.spins.append(sp)
        lay.addLayout(grid)
        row = QHBoxLayout()
        around = QPushButton("Around the view")
        around.clicked.connect(self.around_view)
        row.addWidget(around)
        lay.addLayout(row)
        lay.addStretch(1)
        self._setting = False

    def box(self) -> tuple[np.ndarray, np.ndarray]:
        v = np.array([s.value() for s in self.spins]).reshape(3, 2)
        return v[:, 0], v[:, 1]

    def set_box(self, lo, hi, enable: bool = True) -> None:
        """Fill the ranges and (by default) switch clipping on."""
        self._setting = True
        try:
            for i, (a, b) in enumerate(zip(lo, hi, strict=True)):
                self.spins[2 * i].setValue(float(a))
                self.spins[2 * i + 1].setValue(float(b))
        finally:
            self._setting = False
        if enable and not self.enabled.isChecked():
            self.enabled.setChecked(True)
        else:
            self.apply()

    def around_view(self) -> None:
        """A box centred on the focal point, a quarter of the focal distance and at most 60 % of the data
        across, the full data height."""
        f = self.focus()
        bounds = self.document.bounds()
        if f is None or bounds is None:
            return
        centre, dist = f
        extent = float(np.min(bounds[1][:2] - bounds[0][:2]))
        half = max(min(dist * 0.25, extent * 0.3), 1.0)
        lo = np.array([centre[0] - half, centre[1] - half, bounds[0][2] - 1.0])
        hi = np.array([centre[0] + half, centre[1] + half, bounds[1][2] + 1.0])
        self.set_box(lo, hi)

    def apply(self) -> None:
        if self._setting:
            return
        self.document.set_clip_box(self.box() if self.enabled.isChecked() else None)
