"""Long jobs in a subprocess: builds (``python -m citylod.cli build ...``) and large image exports
(``citylod render``), with a cancellable progress dialog.

A subprocess keeps the GUI thread free, can be killed at any point (the builds write under a temporary name
and rename, so a killed build leaves nothing half written), and its tqdm progress on stderr is parsed
(:func:`~citylod.app.models.parse_progress`) into the dialog.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from pathlib import Path

from PySide6.QtCore import QObject, QProcess, QProcessEnvironment, Signal
from PySide6.QtWidgets import QProgressDialog, QWidget

from citylod.app.models import parse_progress
from citylod.app.qt_profile import profiled

__all__ = ["ProcessTask"]


class ProcessTask(QObject):
    """One subprocess with a progress dialog. ``finished(ok, output, message)`` when it ends; ``ok`` is
    False when it failed or was cancelled."""

    finished = Signal(bool, str, str)

    def __init__(self, argv: Sequence[str], output: str | os.PathLike[str], label: str,
                 parent: QWidget | None = None, *, show_dialog: bool = True) -> None:
        super().__init__(parent)
        self.argv = list(argv)
        self.output = Path(output)
        self.label = label
        self.cancelled = False
        self.stderr_tail = ""
        self.process = QProcess(self)
        env = QProcessEnvironment.systemEnvironment()
        env.insert("PYTHONUNBUFFERED", "1")
        # tqdm draws to stderr only when it thinks it may; force it for a pipe.
        env.insert("TQDM_MININTERVAL", "0.2")
        self.process.setProcessEnvironment(env)
        self.process.readyReadStandardError.connect(self._on_stderr)
        self.process.readyReadStandardOutput.connect(self._on_stdout)
        self.process.finished.connect(self._on_finished)
        self.process.errorOccurred.connect(self._on_error)
        self.dialog: QProgressDialog | None = None
        if show_dialog:
            self.dialog = QProgressDialog(label, "Cancel", 0, 100, parent)
            self.dialog.setWindowTitle("citylod")
            self.dialog.setMinimumDuration(300)
            self.dialog.setAutoClose(False)
            self.dialog.setAutoReset(False)
            self.dialog.canceled.connect(self.cancel)
        self.stdout = ""
        self.stage = ""

    def start(self) -> None:
        self.process.start(self.argv[0], self.argv[1:])

    def cancel(self) -> None:
        """Kill the subprocess (the build's temporary output is its own to clean; nothing is renamed)."""
        if self.process.state() != QProcess.ProcessState.NotRunning:
            self.cancelled = True
            self.process.kill()

    @profiled("ProcessTask.stderr")
    def _on_stderr(self) -> None:
        text = bytes(self.process.readAllStandardError().data()).decode("utf-8", "replace")
        self.stderr_tail = (self.stderr_tail + text)[-4000:]
        prog = parse_progress(text)
        if prog is not None and self.dialog is not None:
            desc, pct = prog
            self.stage = desc
            if pct >= 100:
                # A build runs several stages, each with its own bar; a finished stage is not a finished
                # build, so the bar goes busy until the next stage reports instead of reading 100 %.
                self.dialog.setRange(0, 0)
                self.dialog.setLabelText(f"{self.label}\n{desc} done; next stage…" if desc else self.label)
            else:
                self.dialog.setRange(0, 100)
                self.dialog.setValue(pct)
                self.dialog.setLabelText(f"{self.label}\n{desc}: {pct} %" if desc else self.label)

    def _on_stdout(self) -> None:
        self.stdout += bytes(self.process.readAllStandardOutput().data()).decode("utf-8", "replace")

    def _close_dialog(self) -> None:
        # reset() also stops the dialog's show-after-minimumDuration timer: closing alone left a dialog
        # that a fast failure closed before it appeared to pop up afterwards, with its Cancel disconnected.
        if self.dialog is not None:
            dialog, self.dialog = self.dialog, None
            dialog.blockSignals(True)
            dialog.reset()
            dialog.hide()
            dialog.deleteLater()

    def _on_finished(self, code: int, _status: object) -> None:
        self._close_dialog()
        if self.cancelled:
            self.finished.emit(False, str(self.output), "cancelled")
        elif code == 0:
            self.finished.emit(True, str(self.output), self.stdout.strip())
        else:
            lines = [ln for ln in self.stderr_tail.replace("\r", "\n").splitlines() if ln.strip()]
            err = next((ln for ln in reversed(lines) if "error" in ln.lower()), lines[-1] if lines else "")
            self.finished.emit(False, str(self.output), err or f"exit code {code}")

    def _on_error(self, error: QProcess.ProcessError) -> None:
        if error == QProcess.ProcessError.FailedToStart:
            self._close_dialog()
            self.finished.emit(False, str(self.output), f"cannot start {self.argv[0]}")


def python() -> str:
    return sys.executable
