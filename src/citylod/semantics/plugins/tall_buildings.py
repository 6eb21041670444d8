"""Template query plugin: buildings at least ``min_height`` metres tall.

Copy this file into your own package, rename the class, and declare it in your ``pyproject.toml``::

    [project.entry-points."citylod.queries"]
    tall_buildings = "citylod.semantics.plugins.tall_buildings:TallBuildings"

citylod finds it through :func:`citylod.semantics.queries.list_queries` without importing it, and imports
it on first use. Keep the module light at import time; a plugin that raises while loading becomes a
warning naming it, not a crash. ``run`` gets a :class:`citylod.semantics.store.CityStore` and keyword
parameters, and returns object ids. Use ``store.query`` with ``?`` placeholders for values, never string
formatting.
"""

from __future__ import annotations

from typing import Any


class TallBuildings:
    """Buildings whose measured height (or, lacking it, height range) is at least ``min_height`` m."""

    name = "tall_buildings"
    description = "Buildings and building parts at least min_height metres tall (default 20)."

    def run(self, store: Any, *, min_height: float = 20.0, **_: Any) -> list[str]:
        """Object ids of tall buildings.

        Parameters
        ----------
        store
            The city store.
        min_height
            Threshold in metres.
        """
        return store.query(
            "type IN ('Building', 'BuildingPart') AND COALESCE(measured_height, zmax - zmin) >= ?",
            (float(min_height),),
        )
