"""citylod: city-scale 3D geodata through level-of-detail hierarchies with a guaranteed geometric error.

The scripting entry points are re-exported here and imported lazily, so ``import citylod`` stays light.

Examples
--------
>>> import citylod
>>> citylod.open_tileset.__module__
'citylod.io.tiles3d.tileset'
>>> "build_dsm" in dir(citylod)
True
"""

from __future__ import annotations

import importlib
from typing import Any

from citylod._version import __version__

#: Public name -> the module that defines it.
_EXPORTS = {
    "open_tileset": "citylod.io.tiles3d",
    "build_dsm": "citylod.lod.build.dsm",
    "build_points": "citylod.lod.build.points",
    "build_city": "citylod.semantics.store",
    "CityStore": "citylod.semantics.store",
    "make_sample": "citylod.sample",
    "Camera": "citylod.core.camera",
    "load_cameras": "citylod.core.camera",
    "framing_camera": "citylod.core.camera",
    "orbit_cameras": "citylod.core.camera",
    "render_images": "citylod.render.offscreen",
    "add_lod_layer": "citylod.render.pyvista_layer",
}
__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'citylod' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)


def __dir__() -> list[str]:
    return sorted(__all__)
