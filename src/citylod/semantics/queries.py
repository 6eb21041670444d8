"""Semantic queries and their plugin registry.

Queries are found through the ``citylod.queries`` entry-point group (importlib.metadata), scanned once;
a query is imported only when first used, and one that fails to load or is not a :class:`Query` becomes
a ``warnings.warn`` naming it and where it came from, never a crash. The built-in queries (sql, polygon,
distance) are registered as entry points of the same kind, so they go through the same code path.
No VTK, no Qt.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from importlib.metadata import EntryPoint, entry_points
from typing import Any, Protocol, runtime_checkable

from citylod.core.errors import PluginError

__all__ = ["GROUP", "Query", "QueryInfo", "QueryRegistry", "get_query", "list_queries", "parameter_hint", "registry", "run_query"]

GROUP = "citylod.queries"
_BUILTIN_SOURCE = "citylod (built-in)"


@runtime_checkable
class Query(Protocol):
    """A named query over a city store that returns object ids."""

    name: str
    description: str

    def run(self, store: Any, **params: Any) -> list[str]:
        """Object ids matching the query on ``store`` (a :class:`~citylod.semantics.store.CityStore`)."""
        ...


class SqlQuery:
    name = "sql"
    description = "Objects matching an SQL WHERE clause over city_objects (parameter: where, params)."

    def run(self, store: Any, *, where: str, params: tuple[Any, ...] = (), **_: Any) -> list[str]:
        return list(store.query(where, params))


class PolygonQuery:
    name = "polygon"
    description = "Objects whose footprint intersects a polygon (parameter: polygon, (K, 2) x/y)."

    def run(self, store: Any, *, polygon: Any, predicate: str = "intersects", **_: Any) -> list[str]:
        return list(store.within_polygon(polygon, predicate=predicate))


class DistanceQuery:
    name = "distance"
    description = "Objects within a distance of a point (parameters: point (x, y), distance in m)."

    def run(self, store: Any, *, point: Any, distance: float, **_: Any) -> list[str]:
        return list(store.within_distance(point, distance))


_BUILTINS = (
    EntryPoint("sql", "citylod.semantics.queries:SqlQuery", GROUP),
    EntryPoint("polygon", "citylod.semantics.queries:PolygonQuery", GROUP),
    EntryPoint("distance", "citylod.semantics.queries:DistanceQuery", GROUP),
)


@dataclass(frozen=True)
class QueryInfo:
    """A registered query: its name, where it comes from (distribution or built-in) and its entry point."""

    name: str
    source: str
    value: str



def _source(ep: EntryPoint) -> str:
    dist = getattr(ep, "dist", None)
    if dist is None:
        return _BUILTIN_SOURCE
    return f"{dist.metadata['Name']} {dist.version}"


class QueryRegistry:
    """Entry points scanned once, queries loaded lazily and cached."""

    def __init__(self) -> None:
        self._eps: dict[str, tuple[EntryPoint, str]] | None = None
        self._loaded: dict[str, Query] = {}
        self._broken: dict[str, str] = {}

    def _scan(self) -> dict[str, tuple[EntryPoint, str]]:
        if self._eps is None:
            eps: dict[str, tuple[EntryPoint, str]] = {ep.name: (ep, _BUILTIN_SOURCE) for ep in _BUILTINS}
            for ep in entry_points(group=GROUP):
                if ep.name in eps and eps[ep.name][1] == _BUILTIN_SOURCE:
                    warnings.warn(f"citylod query plugin {ep.name!r} from {_source(ep)} ignored: the name is "
                                  "taken by a built-in query", stacklevel=3)
                    continue
                eps[ep.name] = (ep, _source(ep))
            self._eps = eps
        return self._eps

    def registered(self) -> list[QueryInfo]:
        """Every registered query, without importing any."""
        return [QueryInfo(n, src, ep.value) for n, (ep, src) in sorted(self._scan().items())]

    def get(self, name: str) -> Query | None:
        """The query called ``name``, imported on first use; None (and a warning) if it is broken."""
        if name in self._loaded:
            return self._loaded[name]
        eps = self._scan()
        if name not in eps:
            raise KeyError(f"no query named {name!r}; registered: {', '.join(sorted(eps))}")
        if name in self._broken:
            return None
        ep, src = eps[name]
        try:
            obj = ep.load()
            query = obj() if isinstance(obj, type) else obj
            if not isinstance(query, Query):
                raise TypeError(f"{ep.value} is not a Query (needs name, description and run(store, **params))")
        except Exception as exc:  # a plugin can fail in any way; it must not take citylod down
            msg = f"citylod query plugin {name!r} ({ep.value}, from {src}) failed to load: {type(exc).__name__}: {exc}"
            self._broken[name] = msg
            warnings.warn(msg, stacklevel=2)
            return None
        self._loaded[name] = query
        return query

    def run(self, store: Any, name: str, **params: Any) -> list[str]:
        """Run a query by name; PluginError if it is broken or fails."""
        query = self.get(name)
        if query is None:
            raise PluginError(self._broken[name])
        try:
            return list(query.run(store, **params))
        except PluginError:
            raise
        except Exception as exc:
            from citylod.core.errors import CitylodError

            if isinstance(exc, CitylodError):
                raise
            raise PluginError(f"query {name!r} failed: {type(exc).__name__}: {exc}") from exc


registry = QueryRegistry()


def list_queries() -> list[QueryInfo]:
    """Name and origin of every registered query (built-ins and ``citylod.queries`` plugins)."""
    return registry.registered()


def get_query(name: str) -> Query | None:
    """A query by name (imported on first use); None and a warning if it fails to load."""
    return registry.get(name)


def parameter_hint(name: str) -> str:
    """A JSON template of a registered query's parameters, read from its ``run`` signature.

    Keyword parameters with a default show it; those without show ``null`` to fill in. The GUI shows this
    as the placeholder of the parameter box, so a plugin's parameters are discoverable without its source.
    Empty for the SQL query (its box takes a WHERE clause) and for a query that fails to load.
    """
    import inspect
    import json

    if name == "sql":
        return ""
    query = registry.get(name)
    if query is None:
        return ""
    fields: dict[str, Any] = {}
    for p in list(inspect.signature(query.run).parameters.values())[1:]:  # after ``store``
        if p.kind in (p.VAR_KEYWORD, p.VAR_POSITIONAL):
            continue
        default = None if p.default is p.empty else p.default
        fields[p.name] = list(default) if isinstance(default, tuple) else default
    try:
        return json.dumps(fields)
    except TypeError:  # a default JSON cannot show
        return json.dumps(dict.fromkeys(fields))


def run_query(store: Any, name: str, **params: Any) -> list[str]:
    """Run a registered query on a store."""
    return registry.run(store, name, **params)
