"""``citylod view``: start the desktop application.

:func:`run_app` opens the sources, places the camera, optionally highlights the tallest building, and
either runs the event loop or, with ``screenshot`` / ``exit_after``, waits until every selected tile is
loaded and drawn, grabs the window and quits. ``profile_gui`` (``citylod view --profile-gui``, or
``CITYLOD_GUI_PROFILE=1``) times every GUI-thread handler and event delivery, logs those over 100 ms and
prints the longest per handler at exit.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path

__all__ = ["run_app"]

_RESOLVE_TIMEOUT_S = 120.0
_STABLE_TICKS = 3


def _app(profile: bool = False) -> object:
    from PySide6.QtWidgets import QApplication

    app = QApplication.instance()
    if app is None:
        if profile:
            from citylod.app.qt_profile import ProfiledApplication

            app = ProfiledApplication(sys.argv[:1])
        else:
            app = QApplication(sys.argv[:1])
        app.setOrganizationName("citylod")
        app.setApplicationName("citylod")
    return app


def run_app(sources: Sequence[str | os.PathLike[str]] = (), *, screenshot: str | os.PathLike[str] | None = None,
            exit_after: bool = False, camera: str | os.PathLike[str] | None = None,
            highlight_first: bool = False, profile_gui: bool = False) -> int:
    """Open the main window on ``sources`` and run it; returns the exit code.

    Parameters
    ----------
    sources
        Tileset folders / ``tileset.json``, ``.gpkg`` city stores, and raw inputs (built first).
    screenshot
        Save a PNG of the whole window once everything is loaded.
    exit_after
        Quit after loading (and the screenshot) instead of running interactively.
    camera
        A camera JSON (the first camera of a path is used); default: an overview of the data.
    highlight_first
        Highlight and select the tallest building of the city store.
    profile_gui
        Time every GUI-thread handler and event; log those over 100 ms, print the longest at exit.
    """
    if profile_gui:
        os.environ["CITYLOD_GUI_PROFILE"] = "1"
    from citylod.app import qt_profile

    app = _app(qt_profile.enabled())
    from PySide6.QtCore import QTimer

    from citylod.app.qt_main_window import MainWindow
    from citylod.core.camera import load_cameras
    from citylod.core.errors import CitylodError

    batch = screenshot is not None or exit_after
    # A batch run (screenshot) uses the default layout, not the one the user saved: the same command
    # gives the same picture on every machine.
    win = MainWindow(interactive=not batch, restore_layout=not batch)
    win.show()
    app.processEvents()  # type: ignore[attr-defined]
    win.open_paths([Path(s) for s in sources])
    if camera is not None:
        try:
            win.view.set_camera(load_cameras(camera)[0])
        except CitylodError as exc:
            win._error(str(exc))
    elif win.document.entries:
        win.view.reset_view()
    if highlight_first:
        oid = win.document.tallest_building()
        if oid is not None:
            win.document.highlight([oid], "#ff3300")
            win.document.select([oid])
    code = [0]
    if batch:
        t0 = time.monotonic()
        stable = [0]

        def check() -> None:
            if win.tasks:  # builds still running
                return
            if win.document.semantics_pending:  # the semantic overlay's map is still being built
                if win.document.poll_semantics():
                    win.view.render_now()
                return
            win.view.render_now()
            stable[0] = stable[0] + 1 if win.view.is_resolved() else 0
            timed_out = time.monotonic() - t0 > _RESOLVE_TIMEOUT_S
            if stable[0] < _STABLE_TICKS and not timed_out:
                return
            poll.stop()
            if timed_out:
                print("citylod: warning: tiles still loading after "
                      f"{_RESOLVE_TIMEOUT_S:.0f} s; screenshot taken anyway", file=sys.stderr)
            if screenshot is not None:
                try:
                    out = win.save_screenshot(screenshot)
                    print(f"{out}: window screenshot {win.width()}×{win.height()}")
                except CitylodError as exc:
                    print(f"citylod: error: {exc}", file=sys.stderr)
                    code[0] = 2
            if win.errors:
                code[0] = 2
            win.close()
            app.quit()  # type: ignore[attr-defined]

        poll = QTimer()
        poll.setInterval(100)
        poll.timeout.connect(check)
        poll.start()
    app.exec()  # type: ignore[attr-defined]
    if qt_profile.enabled():
        print("GUI-thread handlers (longest run):\n" + qt_profile.TIMINGS.report(), file=sys.stderr)
        if isinstance(app, qt_profile.ProfiledApplication):
            # PySide6 corrupts a reference count when a QApplication subclass overriding notify() is
            # collected at interpreter exit (the process aborts in none_dealloc); the run is over and
            # reported, so leave without that collection.
            win.deleteLater()
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code[0])
    return code[0]
