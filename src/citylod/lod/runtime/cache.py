"""Resident tiles: an LRU cache with a hard byte budget, and the memory-adjusted error threshold.

:class:`TileCache` follows CesiumJS ``Cesium3DTilesetCache.js``: least recently used tiles go first,
and what the current frame uses (``touch``) is never evicted. Unlike Cesium it is a hard cap: the
cached bytes never exceed the budget, so a tile that does not fit beside the frame's in-use tiles is
refused rather than admitted over the limit. :class:`TauController` is the other half of Cesium's
answer to memory pressure (``memoryAdjustedScreenSpaceError``): raise the threshold a little each
frame while the cache is nearly full, so the frame needs fewer tiles, instead of evicting and reloading
the same tiles every frame.

Neither does I/O; both are plain Python and safe to call from several threads.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

__all__ = ["TauController", "TileCache"]


@dataclass(frozen=True)
class ResidentInfo:
    """Measured size of a resident (loaded, decoded) tile: what it costs to draw."""

    bytes: int = 0
    triangles: int = 0
    points: int = 0


@dataclass(frozen=True)
class _Entry:
    value: Any
    info: ResidentInfo


class TileCache:
    """LRU cache of decoded tiles with a hard byte budget.

    Parameters
    ----------
    budget_bytes
        Most bytes the cache ever holds (sum of the ``nbytes`` given to :meth:`put`).

    Notes
    -----
    ``key in cache`` makes the cache itself a residency container for
    :func:`citylod.lod.runtime.selection.select`; :meth:`residency` gives the measured costs as well.
    """

    def __init__(self, budget_bytes: int) -> None:
        if budget_bytes < 0:
            raise ValueError(f"budget_bytes must be >= 0, got {budget_bytes}")
        self._budget = int(budget_bytes)
        self._entries: OrderedDict[str, _Entry] = OrderedDict()  # least recently used first
        self._in_use: frozenset[str] = frozenset()
        self._bytes = 0
        self._evicted: list[str] = []  # evicted since the last evict() call, for the renderer to release
        self._first_out: dict[str, int] = {}  # eviction-order hook: these keys go first, in this order
        self._lock = threading.RLock()

    # -- queries ----------------------------------------------------------------------------------

    @property
    def budget_bytes(self) -> int:
        return self._budget

    @property
    def bytes_used(self) -> int:
        """Bytes held now (always <= ``budget_bytes``)."""
        return self._bytes

    @property
    def in_use(self) -> frozenset[str]:
        """Keys of the last :meth:`touch` (present or not)."""
        return self._in_use

    @property
    def in_use_bytes(self) -> int:
        """Bytes held by in-use tiles: what no eviction can free."""
        with self._lock:
            return sum(self._entries[k].info.bytes for k in self._in_use if k in self._entries)

    def __contains__(self, key: object) -> bool:
        return key in self._entries

    def __len__(self) -> int:
        return len(self._entries)

    def __iter__(self) -> Iterator[str]:
        with self._lock:
            return iter(list(self._entries))

    def get(self, key: str, default: Any = None) -> Any:
        """The value of ``key`` (marking it recently used), or ``default``."""
        with self._lock:
            entry = self._entries.get(key)
            if entry is None:
                return default
            self._entries.move_to_end(key)
            return entry.value

    def peek(self, key: str, default: Any = None) -> Any:
        """The value of ``key`` without marking it recently used (for bookkeeping that must not change the
        LRU order), or ``default``."""
        entry = self._entries.get(key)
        return default if entry is None else entry.value

    def info(self, key: str) -> ResidentInfo | None:
        """Measured size of ``key``, or ``None`` when it is not resident."""
        entry = self._entries.get(key)
        return None if entry is None else entry.info

    def residency(self) -> Mapping[str, ResidentInfo]:
        """A read-only snapshot key -> :class:`ResidentInfo`, the ``resident`` argument of ``select``."""
        with self._lock:
            return MappingProxyType({k: e.info for k, e in self._entries.items()})

    def can_fit(self, key: str, nbytes: int) -> bool:
        """Whether :meth:`put` of ``nbytes`` under ``key`` would be accepted now."""
        with self._lock:
            return self._pinned_bytes_except(key) + int(nbytes) <= self._budget

    # -- updates ----------------------------------------------------------------------------------

    def touch(self, keys_in_use: Iterable[str]) -> None:
        """Declare the keys the current frame uses; they cannot be evicted until the next ``touch``.

        Present keys also become the most recently used. Pass the frame's render set, and its request
        set too when the tiles being loaded must not evict one another (``resolve`` does).
        """
        with self._lock:
            self._in_use = frozenset(keys_in_use)
            for key in self._in_use:
                if key in self._entries:
                    self._entries.move_to_end(key)

    def put(self, key: str, value: Any, nbytes: int, *, points: int = 0, triangles: int = 0) -> bool:
        """Store ``value`` (replacing an entry of the same key), evicting LRU tiles not in use.

        Parameters
        ----------
        key, value
            The tile and its decoded content.
        nbytes
            Memory the value holds, bytes.
        points, triangles
            Its drawing cost, reported to selection through :meth:`residency`.

        Returns
        -------
        bool
            False, and nothing changed, when ``nbytes`` does not fit beside the in-use tiles: the cap
            is hard, and evicting in-use tiles would blank the current frame.
        """
        nbytes = int(nbytes)
        if nbytes < 0:
            raise ValueError(f"nbytes must be >= 0, got {nbytes}")
        with self._lock:
            if self._pinned_bytes_except(key) + nbytes > self._budget:
                return False
            old = self._entries.pop(key, None)
            if old is not None:
                self._bytes -= old.info.bytes
            self._entries[key] = _Entry(value, ResidentInfo(nbytes, int(triangles), int(points)))
            self._bytes += nbytes
            self._shrink_to(self._budget, protect=key)
            return True

    def remove(self, key: str) -> bool:
        """Drop ``key`` (in use or not); True if it was present. Not reported by :meth:`evict`."""
        with self._lock:
            entry = self._entries.pop(key, None)
            if entry is None:
                return False
            self._bytes -= entry.info.bytes
            return True

    def evict(self, target_bytes: int | None = None) -> list[str]:
        """Evict LRU tiles not in use down to ``target_bytes`` (default: the budget).

        Returns
        -------
        list of str
            Every key evicted since the previous call, including those :meth:`put` evicted to make
            room, oldest first: the renderer releases their GPU resources.
        """
        with self._lock:
            self._shrink_to(self._budget if target_bytes is None else int(target_bytes), protect=None)
            evicted, self._evicted = self._evicted, []
            return evicted

    def set_eviction_order(self, keys: Iterable[str] | None) -> None:
        """Evict ``keys`` first, in this order, before the least recently used rest (None: plain LRU).

        The hook through which a caller's own priority decides what leaves first, e.g. Buchholz's texture
        priority (:mod:`citylod.lod.runtime.texture_budget`): pass the resident keys least important
        first. In-use keys are still never evicted.
        """
        with self._lock:
            self._first_out = {} if keys is None else {k: i for i, k in enumerate(keys)}

    def set_budget(self, budget_bytes: int) -> list[str]:
        """Change the budget; evicts what no longer fits (in-use tiles stay) and returns :meth:`evict`."""
        with self._lock:
            self._budget = int(budget_bytes)
            return self.evict()

    # -- internals --------------------------------------------------------------------------------

    def _pinned_bytes_except(self, key: str) -> int:
        return sum(self._entries[k].info.bytes for k in self._in_use if k != key and k in self._entries)

    def _shrink_to(self, target: int, protect: str | None) -> None:
        if self._bytes <= target:
            return
        order = list(self._entries)  # LRU first
        if self._first_out:
            late = len(self._first_out)
            order.sort(key=lambda k: self._first_out.get(k, late))  # stable: LRU among the rest
        for key in order:
            if self._bytes <= target:
                break
            if key in self._in_use or key == protect:
                continue
            entry = self._entries.pop(key)
            self._bytes -= entry.info.bytes
            self._evicted.append(key)


class TauController:
    """Memory-adjusted screen-space error threshold with hysteresis.

    CesiumJS (``Cesium3DTileset.js``, ``increaseScreenSpaceError`` / ``decreaseScreenSpaceError``)
    multiplies the threshold by 1.02 in each frame the tiles it needs exceed the cache and divides it back
    toward the user's value otherwise. Reacting at one level makes it oscillate at the boundary, so here
    τ rises while the cache is above ``high_water`` of its budget, holds in the band between, and eases
    back only below ``low_water``.

    Parameters
    ----------
    base_tau_px
        The user's threshold, pixels; τ never goes below it.
    raise_factor
        Multiplier per frame under pressure.
    ease_factor
        Divisor per frame once pressure is gone.
    high_water, low_water
        Fractions of the budget that start raising and easing (``low_water < high_water``).
    max_tau_px
        Ceiling on τ (default 64 × ``base_tau_px``), so a hopeless budget still draws something sane.
    """

    def __init__(
        self,
        base_tau_px: float,
        *,
        raise_factor: float = 1.05,
        ease_factor: float = 1.02,
        high_water: float = 0.9,
        low_water: float = 0.7,
        max_tau_px: float | None = None,
    ) -> None:
        if base_tau_px <= 0:
            raise ValueError(f"base_tau_px must be > 0, got {base_tau_px}")
        if raise_factor <= 1.0 or ease_factor <= 1.0:
            raise ValueError("raise_factor and ease_factor must be > 1")
        if not 0.0 < low_water < high_water:
            raise ValueError(f"need 0 < low_water < high_water, got {low_water}, {high_water}")
        self.base_tau_px = float(base_tau_px)
        self.raise_factor = float(raise_factor)
        self.ease_factor = float(ease_factor)
        self.high_water = float(high_water)
        self.low_water = float(low_water)
        self.max_tau_px = float(max_tau_px) if max_tau_px is not None else 64.0 * self.base_tau_px
        self._tau = self.base_tau_px

    @property
    def tau_px(self) -> float:
        """The current threshold, pixels."""
        return self._tau

    def update(self, resident_bytes: int, budget_bytes: int) -> float:
        """Adjust τ for this frame's memory use and return it.

        Parameters
        ----------
        resident_bytes
            Bytes the cache holds (or would need) this frame.
        budget_bytes
            The cache budget.
        """
        fill = resident_bytes / budget_bytes if budget_bytes > 0 else float("inf")
        if fill > self.high_water:
            self._tau = min(self._tau * self.raise_factor, self.max_tau_px)
        elif fill < self.low_water:
            self._tau = max(self._tau / self.ease_factor, self.base_tau_px)
        return self._tau

    def reset(self) -> None:
        """Back to ``base_tau_px`` (e.g. after loading another dataset)."""
        self._tau = self.base_tau_px
