"""GUI-thread timing: how long each event handler and timer callback holds the GUI thread.

Every handler the application connects goes through :func:`profiled`, which times it with a
``QElapsedTimer`` into :data:`TIMINGS`. With ``citylod view --profile-gui`` (or ``CITYLOD_GUI_PROFILE=1``)
the application is a :class:`ProfiledApplication`, which also times every event Qt delivers (paint,
resize, mouse, key, timer events of any widget, VTK's included), so nothing that holds the GUI thread
escapes; handlers over 100 ms are logged on stderr as they happen and a table is printed at exit.
"""

from __future__ import annotations

import functools
import os
import sys
from collections.abc import Callable
from typing import Any, TypeVar

from PySide6.QtCore import QElapsedTimer, QEvent, QObject
from PySide6.QtWidgets import QApplication

from citylod.app.models import GuiTimings

__all__ = ["TIMINGS", "ProfiledApplication", "enabled", "profiled", "timed"]

TIMINGS = GuiTimings()
SLOW_MS = 100.0
F = TypeVar("F", bound=Callable[..., Any])


def enabled() -> bool:
    return os.environ.get("CITYLOD_GUI_PROFILE", "") not in ("", "0")


class timed:
    """``with timed("name"):`` records the block's GUI-thread time."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.timer = QElapsedTimer()

    def __enter__(self) -> timed:
        self.timer.start()
        return self

    def __exit__(self, *exc: object) -> None:
        ms = self.timer.nsecsElapsed() / 1e6
        if TIMINGS.record(self.name, ms, SLOW_MS) and enabled():
            print(f"citylod: GUI thread held {ms:.1f} ms by {self.name}", file=sys.stderr)


def profiled(name: str | None = None) -> Callable[[F], F]:
    """Decorator: time every call of a handler under ``name`` (default: its qualified name)."""

    def wrap(fn: F) -> F:
        label = name or fn.__qualname__

        @functools.wraps(fn)
        def inner(*args: Any, **kwargs: Any) -> Any:
            with timed(label):
                return fn(*args, **kwargs)

        return inner  # type: ignore[return-value]

    return wrap


class ProfiledApplication(QApplication):
    """A ``QApplication`` that times the delivery of every event (``notify``) under
    ``event.<receiver class>.<event type>``. Nested deliveries are timed too (a handler that sends events
    is counted with them), so the longest entry is the longest time the GUI thread was held."""

    def notify(self, receiver: QObject, event: QEvent) -> bool:
        # Named before delivery: a DeferredDelete (or any handler) may destroy the receiver and the
        # event, and touching their wrappers afterwards corrupts reference counts.
        name = f"event.{type(receiver).__name__}.{event.type().name}"
        timer = QElapsedTimer()
        timer.start()
        try:
            return super().notify(receiver, event)
        finally:
            ms = timer.nsecsElapsed() / 1e6
            if TIMINGS.record(name, ms, SLOW_MS) and enabled():
                print(f"citylod: GUI thread held {ms:.1f} ms by {name}", file=sys.stderr)
