"""The application tests run under the profiling ``QApplication`` (every event delivery is timed), so a
test can read how long any GUI-thread handler held the thread (``citylod.app.qt_profile.TIMINGS``)."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def qapp_cls():
    pytest.importorskip("PySide6")
    from citylod.app.qt_profile import ProfiledApplication

    return ProfiledApplication
