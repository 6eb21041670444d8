"""The feature state store: selection, highlight colours, hidden objects and hover, keyed by object id.

A plain evented model (no Qt, no VTK): the renderer's semantic-shading adapter subscribes with
:meth:`FeatureState.on_change` and turns the state into per-object lookup tables that its shaders read
through the proxies' footprint-ID map (Wahl & Klein 2007). The state is keyed by object id, not by tile or
actor, so tiles coming and going never lose it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["RGBA", "FeatureState", "StateChange", "parse_color"]

RGBA = tuple[float, float, float, float]


@dataclass(frozen=True)
class StateChange:
    """One change: ``kind`` (select, highlight, hide, isolate, hover, clear), the ids concerned, the version."""

    kind: str
    ids: frozenset[str]
    version: int


def parse_color(color: str | Sequence[float]) -> RGBA:
    """RGBA in 0..1 from '#rrggbb[aa]', (r, g, b[, a]) floats in 0..1, or ints in 0..255."""
    if isinstance(color, str):
        h = color.lstrip("#")
        if len(h) not in (6, 8) or any(c not in "0123456789abcdefABCDEF" for c in h):
            raise ValueError(f"not a colour: {color!r}")
        vals = [int(h[i:i + 2], 16) / 255.0 for i in range(0, len(h), 2)]
    else:
        vals = [float(v) for v in color]
        if len(vals) not in (3, 4):
            raise ValueError(f"a colour has 3 or 4 components, got {color!r}")
        if any(v > 1.0 for v in vals):
            vals = [v / 255.0 for v in vals]
    if len(vals) == 3:
        vals.append(1.0)
    if any(not 0.0 <= v <= 1.0 for v in vals):
        raise ValueError(f"colour components out of range: {color!r}")
    return (vals[0], vals[1], vals[2], vals[3])


class FeatureState:
    """Selection, highlight, visibility and hover of city objects; every change bumps :attr:`version`.

    Examples
    --------
    >>> s = FeatureState()
    >>> seen = []
    >>> _ = s.on_change(seen.append)
    >>> s.highlight(["a", "b"], "#ff0000")
    >>> s.hide(["c"])
    >>> s.is_visible("c"), s.color("a"), s.version
    (False, (1.0, 0.0, 0.0, 1.0), 2)
    >>> [c.kind for c in seen]
    ['highlight', 'hide']
    """

    def __init__(self) -> None:
        self.selection: set[str] = set()
        self.colors: dict[str, RGBA] = {}
        self.hidden: set[str] = set()
        self.isolated: frozenset[str] | None = None
        self.hover: str | None = None
        self.version = 0
        self._callbacks: list[Callable[[StateChange], None]] = []

    def on_change(self, callback: Callable[[StateChange], None]) -> Callable[[], None]:
        """Call ``callback(change)`` after every change; returns a function that unsubscribes."""
        self._callbacks.append(callback)

        def unsubscribe() -> None:
            if callback in self._callbacks:
                self._callbacks.remove(callback)

        return unsubscribe

    def _emit(self, kind: str, ids: Iterable[str]) -> None:
        self.version += 1
        change = StateChange(kind, frozenset(ids), self.version)
        for cb in list(self._callbacks):
            cb(change)

    def select(self, ids: Iterable[str], mode: str = "replace") -> None:
        """Change the selection: ``mode`` is replace, add, remove or toggle."""
        ids = set(ids)
        before = set(self.selection)
        if mode == "replace":
            self.selection = ids
        elif mode == "add":
            self.selection |= ids
        elif mode == "remove":
            self.selection -= ids
        elif mode == "toggle":
            self.selection ^= ids
        else:
            raise ValueError(f"mode must be replace, add, remove or toggle, got {mode!r}")
        self._emit("select", before ^ self.selection)

    def highlight(self, ids: Iterable[str], color: str | Sequence[float] = "#ffcc00") -> None:
        """Give objects a highlight colour (RGBA; alpha is the blend weight over their own colour)."""
        rgba = parse_color(color)
        ids = list(ids)
        self.colors.update(dict.fromkeys(ids, rgba))
        self._emit("highlight", ids)

    def unhighlight(self, ids: Iterable[str] | None = None) -> None:
        """Remove highlights (all when ``ids`` is None)."""
        ids = list(self.colors) if ids is None else list(ids)
        for i in ids:
            self.colors.pop(i, None)
        self._emit("highlight", ids)

    def hide(self, ids: Iterable[str]) -> None:
        ids = set(ids)
        self.hidden |= ids
        self._emit("hide", ids)

    def show(self, ids: Iterable[str] | None = None) -> None:
        """Unhide objects (all when ``ids`` is None)."""
        ids = set(self.hidden) if ids is None else set(ids)
        self.hidden -= ids
        self._emit("hide", ids)

    def isolate(self, ids: Iterable[str] | None) -> None:
        """Show only these objects (None ends isolation). Hidden flags are kept and still apply."""
        self.isolated = None if ids is None else frozenset(ids)
        self._emit("isolate", self.isolated or ())

    def set_hover(self, object_id: str | None) -> None:
        if object_id != self.hover:
            old, self.hover = self.hover, object_id
            self._emit("hover", {i for i in (old, object_id) if i is not None})

    def clear(self) -> None:
        """Forget selection, highlights, hidden flags, isolation and hover."""
        ids = self.selection | set(self.colors) | self.hidden | (self.isolated or frozenset())
        self.selection, self.colors, self.hidden, self.isolated, self.hover = set(), {}, set(), None, None
        self._emit("clear", ids)

    def is_visible(self, object_id: str) -> bool:
        return object_id not in self.hidden and (self.isolated is None or object_id in self.isolated)

    def color(self, object_id: str) -> RGBA | None:
        return self.colors.get(object_id)

    def as_arrays(self, object_ids: Sequence[str]) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.bool_],
                                                              npt.NDArray[np.bool_]]:
        """Lookup tables for a renderer, indexed like ``object_ids`` (e.g. a store's ids, index = fid - 1).

        Returns
        -------
        rgba, visible, selected
            (N, 4) float32 highlight colour (alpha 0 where none), (N,) bool, (N,) bool.
        """
        n = len(object_ids)
        rgba = np.zeros((n, 4), dtype=np.float32)
        visible = np.ones(n, dtype=bool)
        selected = np.zeros(n, dtype=bool)
        if self.colors or self.hidden or self.isolated is not None or self.selection:
            # One pass over the ids (per object, not per point or pixel).
            for i, oid in enumerate(object_ids):
                c = self.colors.get(oid)
                if c is not None:
                    rgba[i] = c
                visible[i] = self.is_visible(oid)
                selected[i] = oid in self.selection
        return rgba, visible, selected
