"""When Python's cyclic garbage collector may run: in the desktop application, and in budget mode.

A full (generation 2) collection visits every container object the process holds. With a city open that
is hundreds of thousands of objects (tile trees, VTK wrappers, pyproj and Qt bindings), and a collection
triggered by an allocation in the middle of a frame held the GUI thread for a third of a second or more
(docs/PERFORMANCE_LOG.md); off screen, one in a timed draw cost a budget-mode frame 20–30 ms over a 65 ms
target. So the application, and :class:`~citylod.render.frame_budget.FrameBudget` while it holds a frame
time, take full collections out of the allocator's hands:

* :meth:`GcPolicy.settle` moves the objects alive after start-up and after each opened source (they live
  as long as the window or the layer) to the permanent generation (``gc.freeze``, which costs nothing):
  no collection visits them again;
* automatic collections stay on for the young generations (cheap: they visit only new objects), while the
  full collection's threshold is set out of reach;
* :meth:`GcPolicy.tick`, called from the view's timer, runs the full collection itself when the view has
  been idle (no camera motion, nothing loading) for ``idle_s`` and the last one is ``every_s`` ago, and
  freezes the survivors; it visits only what was created since the last freeze, and never delays a frame
  of a motion. Budget mode does not tick: an off-screen flight has no idle time, and the collection runs
  when the mode ends (:meth:`uninstall` of the last policy gives the thresholds back).

Frozen objects are still freed by reference counting (an evicted tile's arrays and VTK objects go as
before); only garbage *cycles* among frozen objects stay until :meth:`uninstall`. The application's
long-lived objects hold few such cycles, so the trade is a little memory for no pause.
"""

from __future__ import annotations

import gc
import time
from collections.abc import Callable

__all__ = ["GcPolicy"]


class GcPolicy:
    """Full collections only while idle. ``clock`` is replaceable for tests."""

    #: Young-generation thresholds (CPython's defaults are 700 and 10); the full one is never reached.
    THRESHOLDS = (5000, 20, 1 << 30)

    def __init__(self, *, idle_s: float = 1.5, every_s: float = 30.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.idle_s = float(idle_s)
        self.every_s = float(every_s)
        self.clock = clock
        self._busy_since_idle = clock()
        self._last_full = clock()
        self.full_collections = 0
        self.installed = False

    #: Installed policies in the process (several windows): the first saves CPython's thresholds, the
    #: last to go restores them.
    _active = 0
    _saved_thresholds: tuple[int, ...] = ()

    def install(self) -> None:
        """Take over full collections (idempotent)."""
        if not self.installed:
            if GcPolicy._active == 0:
                GcPolicy._saved_thresholds = gc.get_threshold()
                gc.set_threshold(*self.THRESHOLDS)
            GcPolicy._active += 1
            self.installed = True
        self.settle()

    def uninstall(self) -> None:
        """Give full collections back to CPython once no window holds a policy."""
        if self.installed:
            self.installed = False
            GcPolicy._active -= 1
            if GcPolicy._active == 0:
                gc.set_threshold(*GcPolicy._saved_thresholds)
                gc.unfreeze()

    def settle(self) -> None:
        """Freeze what is alive now (after start-up or opening a source); constant time."""
        gc.freeze()

    def tick(self, busy: bool) -> bool:
        """Called every timer tick; ``busy`` while the camera moves or tiles load. Returns True when a full
        collection ran."""
        now = self.clock()
        if busy:
            self._busy_since_idle = now
            return False
        if not self.installed or now - self._busy_since_idle < self.idle_s or now - self._last_full < self.every_s:
            return False
        gc.collect()
        gc.freeze()
        self._last_full = self.clock()
        self.full_collections += 1
        return True
