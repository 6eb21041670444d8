"""Open handles kept per thread (GDAL datasets, journal files), and dropped by a forked child.

A handle (an open file, a GDAL dataset) must not be used by two threads at once, nor by two processes: a
forked child would share its file offset with the parent and its siblings. :class:`PerThread` gives each
thread its own ordered dict of handles; a process forked from this one starts with empty ones (the
inherited objects are dropped, not closed: closing could flush or release what the parent still uses).
No VTK, no Qt.
"""

from __future__ import annotations

import os
import threading
from collections import OrderedDict
from typing import Any


class PerThread:
    """An ordered dict per thread, empty again in a forked child."""

    def __init__(self) -> None:
        self._local = threading.local()
        os.register_at_fork(after_in_child=self.forget)

    def get(self) -> OrderedDict[Any, Any]:
        """This thread's dict (created on first use)."""
        d: OrderedDict[Any, Any] | None = getattr(self._local, "d", None)
        if d is None:
            d = self._local.d = OrderedDict()
        return d

    def forget(self) -> None:
        """Drop this thread's dict without closing what it holds."""
        self._local.__dict__.pop("d", None)

    def __len__(self) -> int:
        return len(getattr(self._local, "d", ()))


__all__ = ["PerThread"]
