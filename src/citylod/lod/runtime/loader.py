"""Background tile loading: decode tiles on worker threads, hand them to the cache on the render thread.

The render loop, once a frame::

    loader.poll()                                    # finished tiles enter the cache
    sel = select(root, view, tau_px=tau, budget=budget,
                 resident=cache.residency(), unavailable=loader.failed_keys())
    cache.touch(n.key for n in sel.render)
    loader.request(sel.request_nodes)                # replaces last frame's queue

Workers only run ``load_fn``; results enter the cache in :meth:`TileLoader.poll`, on the caller's
thread, so the cache never changes between a frame's ``select`` and its ``touch`` (a worker's ``put``
there could evict a tile the frame is about to draw). The queue is re-prioritised by every
:meth:`~TileLoader.request`: tiles no longer asked for are dropped before they start (CesiumJS cancels
requests of tiles that left the view the same way). A tile whose ``load_fn`` raises is recorded in
:attr:`~TileLoader.failed` and never tried again, so a corrupt tile is reported once and skipped.

No I/O happens here beyond what ``load_fn`` does; nothing imports VTK or Qt.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from citylod.core.camera import View
from citylod.lod.runtime.cache import ResidentInfo, TileCache
from citylod.lod.runtime.selection import Budget, Selection, TileNode, select

__all__ = ["Keyed", "LoadFn", "LoaderStats", "TileLoader"]


class Keyed(Protocol):
    """All the loader needs of a tile (a ``selection.TileNode`` is one): its key."""

    @property
    def key(self) -> str: ...


LoadFn = Callable[[Any], tuple[Any, int] | tuple[Any, int, ResidentInfo]]
"""``load_fn(node) -> (value, nbytes)`` or ``(value, nbytes, ResidentInfo)``: decode one tile;
``nbytes`` is the memory ``value`` holds; the optional third item gives the measured point and
triangle counts (otherwise the node's ``point_count`` / ``triangle_count`` hints are used)."""


@dataclass(frozen=True)
class LoaderStats:
    """Counters since the loader started (for tests and the HUD; no timings)."""

    queued: int = 0
    loaded: int = 0
    failed: int = 0
    dropped: int = 0
    refused: int = 0
    pending: int = 0
    in_flight: int = 0
    ready: int = 0  #: decoded, waiting for :meth:`TileLoader.poll` to admit them


def _cost(node: Keyed, measured: ResidentInfo | None) -> tuple[int, int]:
    """(points, triangles) of a decoded tile: measured when the load function said, else the hints."""
    if measured is not None:
        return int(measured.points), int(measured.triangles)
    return int(getattr(node, "point_count", 0) or 0), int(getattr(node, "triangle_count", 0) or 0)


class TileLoader:
    """A pool of worker threads that decode tiles in priority order.

    Parameters
    ----------
    load_fn
        ``load_fn(node) -> (value, nbytes[, ResidentInfo])``; may raise on a corrupt tile. The drawing
        cost stored with the value is the returned ``ResidentInfo``'s points and triangles when given,
        else the tile's ``point_count`` and ``triangle_count`` hints (0 when absent).
    cache
        Where :meth:`poll` puts finished tiles.
    workers
        Number of threads.
    """

    def __init__(self, load_fn: LoadFn, cache: TileCache, workers: int = 2) -> None:
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.cache = cache
        self._load_fn = load_fn
        self._cond = threading.Condition()
        self._pending: list[Keyed] = []  # highest priority first
        self._in_flight: set[str] = set()
        self._done: list[tuple[Keyed, Any, int, ResidentInfo | None]] = []
        self._failed: dict[str, str] = {}
        self._refused: dict[str, int] = {}  # key -> nbytes of a result the cache had no room for
        self._closed = False
        self._counts = {"queued": 0, "loaded": 0, "failed": 0, "dropped": 0, "refused": 0}
        self._threads = [
            threading.Thread(target=self._work, name=f"citylod-tile-loader-{i}", daemon=True)
            for i in range(workers)
        ]
        for t in self._threads:
            t.start()

    def ensure_workers(self, workers: int) -> None:
        """At least ``workers`` loader threads: tiles fetched over a network wait on it, not on the CPU, so
        more requests in flight fill the view sooner (3D Tiles clients keep a dozen or more)."""
        with self._cond:
            while len(self._threads) < workers and not self._closed:
                t = threading.Thread(target=self._work, name=f"citylod-tile-loader-{len(self._threads)}",
                                     daemon=True)
                self._threads.append(t)
                t.start()

    # -- render-thread API ------------------------------------------------------------------------

    @property
    def failed(self) -> dict[str, str]:
        """Tiles whose load failed: key -> error message (a copy)."""
        with self._cond:
            return dict(self._failed)

    def failed_keys(self) -> frozenset[str]:
        """Keys of failed tiles, the ``unavailable`` argument of ``select``."""
        with self._cond:
            return frozenset(self._failed)

    def busy_keys(self) -> frozenset[str]:
        """Keys being decoded or decoded and not yet polled: loads already committed, which will enter the
        cache whatever the next request says (a budget must count them as resident)."""
        with self._cond:
            return frozenset(self._in_flight) | {item[0].key for item in self._done}

    def stats(self) -> LoaderStats:
        with self._cond:
            return LoaderStats(**self._counts, pending=len(self._pending), in_flight=len(self._in_flight),
                               ready=len(self._done))

    def request(self, ordered_nodes: Iterable[Keyed]) -> int:
        """Replace the queue with ``ordered_nodes`` (most needed first).

        Tiles resident, loading, loaded but not yet polled, or failed are skipped; so is a tile the
        cache refused until the cache has room for it. Queued tiles missing from ``ordered_nodes`` are
        dropped. Tiles already being decoded cannot be stopped; their result still arrives.

        Returns
        -------
        int
            Number of tiles now queued.
        """
        with self._cond:
            if self._closed:
                raise RuntimeError("TileLoader is closed")
            done = {item[0].key for item in self._done}
            queue: list[Keyed] = []
            seen: set[str] = set()
            for node in ordered_nodes:
                key = node.key
                if key in seen or key in self._in_flight or key in done or key in self._failed:
                    continue
                if key in self.cache:
                    continue
                if key in self._refused and not self.cache.can_fit(key, self._refused[key]):
                    continue  # reloading it would be refused again: wait until the cache has room
                seen.add(key)
                queue.append(node)
            old = {n.key for n in self._pending}
            self._counts["dropped"] += len(old - seen)
            self._counts["queued"] += len(seen - old)
            self._pending = queue
            self._cond.notify_all()
            return len(queue)

    def poll(self, max_cost: int | None = None) -> list[str]:
        """Move finished tiles into the cache; returns the keys that became resident, in finish order.

        ``max_cost`` bounds the drawing cost (points + triangles) admitted by this call: tiles are taken
        in finish order until the next would pass it (the first is always taken), the rest wait for the
        next call. A frame's uploads to the GPU then stay bounded however many tiles finished at once.
        """
        with self._cond:
            if max_cost is None:
                done, self._done = self._done, []
            else:
                spent, take = 0, 0
                for node, _value, _nbytes, measured in self._done:
                    cost = sum(_cost(node, measured))
                    if take and spent + cost > max_cost:
                        break
                    spent += cost
                    take += 1
                done, self._done = self._done[:take], self._done[take:]
        resident: list[str] = []
        for node, value, nbytes, measured in done:
            points, triangles = _cost(node, measured)
            ok = self.cache.put(node.key, value, nbytes, points=points, triangles=triangles)
            with self._cond:
                if ok:
                    self._refused.pop(node.key, None)
                    resident.append(node.key)
                else:
                    self._refused[node.key] = nbytes
                    self._counts["refused"] += 1
        return resident

    def wait_idle(self, timeout: float | None = None) -> bool:
        """Block until nothing is queued or being decoded; False if ``timeout`` (s) ran out first.

        Finished tiles still need :meth:`poll` to enter the cache.
        """
        with self._cond:
            return self._cond.wait_for(lambda: not self._pending and not self._in_flight, timeout)

    def close(self, timeout: float | None = 5.0) -> None:
        """Drop the queue, let running decodes finish and stop the threads. Idempotent."""
        with self._cond:
            self._closed = True
            self._counts["dropped"] += len(self._pending)
            self._pending = []
            self._cond.notify_all()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout)

    def __enter__(self) -> TileLoader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- worker -----------------------------------------------------------------------------------

    def _work(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._closed or bool(self._pending))
                if self._closed:
                    return
                node = self._pending.pop(0)
                self._in_flight.add(node.key)
            try:
                result = self._load_fn(node)
                value, nbytes = result[0], int(result[1])
                measured = result[2] if len(result) > 2 else None
            except Exception as exc:  # a corrupt tile must not take the viewer down: record, skip
                with self._cond:
                    self._failed[node.key] = f"{type(exc).__name__}: {exc}"
                    self._counts["failed"] += 1
                    self._in_flight.discard(node.key)
                    self._cond.notify_all()
                continue
            with self._cond:
                self._done.append((node, value, nbytes, measured))
                self._counts["loaded"] += 1
                self._in_flight.discard(node.key)
                self._cond.notify_all()


def resolve_layers(select_round: Callable[[int], list[Selection]], loader: TileLoader, *,
                   request: Callable[[Sequence[Selection]], int] | None = None, max_iterations: int = 64,
                   timeout_s: float | None = 60.0) -> list[Selection]:
    """Select, load and select again until nothing more is requested (for off-screen renders).

    ``select_round(frame)`` runs selection for every layer against the loader's cache. Each round pins the
    frame's render and request sets in the cache (so a tile being loaded cannot evict a sibling the same
    refinement needs), requests the missing tiles through ``request`` (default: the layers' requests in
    order) and waits for the loader to go idle. Stops when no selection requests anything, when a round
    makes no progress (every requested tile failed or does not fit the cache) or after ``max_iterations``
    rounds. One loop serves one tree (:func:`resolve`) and a scene of several layers sharing a cache.

    Returns
    -------
    list of Selection
        The last round's selections. A non-empty ``request`` means incomplete (cache too small, or the
        iteration limit reached); failed tiles are in ``loader.failed``.

    Raises
    ------
    TimeoutError
        If one round's loads do not finish within ``timeout_s``.
    """

    def _request(sels: Sequence[Selection]) -> int:
        return loader.request([n for s in sels for n in s.request_nodes])

    request = request or _request
    sels: list[Selection] = []
    for frame in range(max(1, max_iterations)):
        loader.poll()
        sels = select_round(frame)
        loader.cache.touch([n.key for s in sels for n in s.render] + [k for s in sels for k in s.request])
        if not any(s.request for s in sels):
            break
        queued = request(sels)
        if not loader.wait_idle(timeout_s):
            raise TimeoutError(f"tile loads did not finish within {timeout_s} s")
        newly = loader.poll()
        if queued == 0 and not newly:
            break  # nothing could be loaded: failed or larger than the cache allows
    return sels


def resolve(tree: TileNode, view: View, tau_px: float, budget: Budget | None, loader: TileLoader, *,
            max_iterations: int = 64, timeout_s: float | None = 60.0) -> Selection:
    """:func:`resolve_layers` for one tree: the complete selection for ``view`` with its tiles loaded.

    Examples
    --------
    >>> from citylod.lod.runtime.cache import TileCache
    >>> from citylod.lod.runtime.selection import select
    >>> import citylod
    >>> ts = citylod.open_tileset("TILES")                                   # doctest: +SKIP
    >>> with TileLoader(lambda t: (t.load(), t.content_bytes), TileCache(1 << 30)) as loader:  # doctest: +SKIP
    ...     sel = resolve(ts.root, view, tau_px=1.0, budget=None, loader=loader)
    """

    def one(frame: int) -> list[Selection]:
        return [select(tree, view, tau_px=tau_px, budget=budget, resident=loader.cache.residency(),
                       unavailable=loader.failed_keys(), frame=frame)]

    return resolve_layers(one, loader, max_iterations=max_iterations, timeout_s=timeout_s)[0]
