"""citylod: city-scale 3D geodata through level-of-detail hierarchies with a guaranteed geometric error.

The scripting entry points are re-exported here and imported lazily, so ``import citylod`` stays light::

    ts = citylod.open_tileset("TILESET_DIR")
"""

from __future__ import annotations

from typing import Any

from citylod._version import __version__

__all__ = ["__version__", "open_tileset"]


def __getattr__(name: str) -> Any:
    if name == "open_tileset":
        from citylod.io.tiles3d import open_tileset

        return open_tileset
    raise AttributeError(f"module 'citylod' has no attribute {name!r}")
