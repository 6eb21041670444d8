"""The Examples sections of the public modules run (doctest); those that need files on disk are skipped."""

from __future__ import annotations

import doctest
import importlib

import pytest

MODULES = [
    "citylod",
    "citylod.io.crs",
    "citylod.io.image",
    "citylod.io.tiles3d.colour",
    "citylod.io.tiles3d.tileset",
    "citylod.lod.runtime.selection",
    "citylod.lod.runtime.loader",
    "citylod.app.navigation",
    "citylod.render.hud",
    "citylod.lod.runtime.texture_budget",
    "citylod.lod.build.citymesh",
    "citylod.sample.textured",
    "citylod.lod.build.model",
    "citylod.lod.build.dsm",
    "citylod.lod.kernels.hausdorff",
    "citylod.render.offscreen",
    "citylod.render.pyvista_layer",
    "citylod.render.splats",
    "citylod.analysis.flood",
    "citylod.analysis.polygons",
    "citylod.lod.runtime.budget",
]


@pytest.mark.parametrize("name", MODULES)
def test_examples_run(name: str) -> None:
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed in {name}"
