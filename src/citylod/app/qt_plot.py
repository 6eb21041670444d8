"""The height-profile dock: a matplotlib plot of :attr:`Document.last_profile`, redrawn when the document
emits ``profile`` (Tools → Height profile, then two clicks in the view)."""

from __future__ import annotations

import numpy as np
from matplotlib.backends.backend_qtagg import FigureCanvasQTAgg
from matplotlib.figure import Figure
from PySide6.QtWidgets import QLabel, QVBoxLayout, QWidget

from citylod.app.models import Document

__all__ = ["ProfilePanel"]


class ProfilePanel(QWidget):
    """Height against distance along the drawn line, with the bound of the drawn tiles in the title."""

    def __init__(self, document: Document, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.document = document
        self.figure = Figure(figsize=(4.0, 2.4), layout="constrained")
        self.axes = self.figure.add_subplot()
        self.canvas = FigureCanvasQTAgg(self.figure)
        self.canvas.setMinimumHeight(160)
        self.label = QLabel("Tools → Height profile (P), then click the two ends of the line in the view.")
        self.label.setWordWrap(True)
        lay = QVBoxLayout(self)
        lay.setContentsMargins(4, 4, 4, 4)
        lay.addWidget(self.canvas, 1)
        lay.addWidget(self.label)
        self.line = None
        document.on_change(self._on_document)

    def _on_document(self, kind: str) -> None:
        if kind == "profile":
            self.show_profile(self.document.last_profile)

    def show_profile(self, profile) -> None:
        ax = self.axes
        ax.clear()
        d, z = profile.distance, profile.heights
        (self.line,) = ax.plot(d, z, color="#1f5fa8", linewidth=1.5)
        ok = np.isfinite(z)
        if ok.any():
            ax.fill_between(d, np.nanmin(z), z, where=ok, color="#1f5fa8", alpha=0.15, linewidth=0)
        ax.set_xlabel("distance along the line on the ellipsoid (m)" if getattr(profile, "ellipsoidal", False)
                      else "distance along the line (m)")
        ax.set_ylabel("height (m)")
        ax.set_title(f"surface profile, drawn tiles within ±{profile.bound_m:.2f} m", fontsize=9)
        ax.grid(True, alpha=0.3)
        self.canvas.draw_idle()
        n = int(ok.sum())
        self.label.setText(f"{len(d)} samples over {d[-1]:.1f} m, {n} on drawn geometry"
                           + (f", heights {np.nanmin(z):.2f}–{np.nanmax(z):.2f} m" if n else ""))

    def plotted(self) -> tuple[np.ndarray, np.ndarray]:
        """(distance, height) of the plotted line, as the plot holds them."""
        if self.line is None:
            return np.empty(0), np.empty(0)
        return np.asarray(self.line.get_xdata(), float), np.asarray(self.line.get_ydata(), float)
