"""Heights in a vertical datum (Delft: EPSG:7415, RD New + NAP) are placed on the WGS84 ellipsoid in the
tileset's root transform, with a geoid model from installed packages; where none is, a clear warning."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pyproj
import pytest

from citylod.io import crs as crs_mod
from citylod.io.tiles3d import TileSpec, write_tileset

DELFT = np.array([85000.0, 447000.0, 0.0])  # RD New metres, NAP 0 m


def _origin_height(tmp_path, crs: str) -> float:
    spec = TileSpec("0", 0, DELFT, DELFT - 50, DELFT + 50, 1.0)
    write_tileset(tmp_path, spec, crs)
    m = np.asarray(json.loads((tmp_path / "tileset.json").read_text())["root"]["transform"]).reshape(4, 4).T
    x, y, z = m[:3, 3]
    return float(pyproj.Transformer.from_crs(4978, 4979, always_xy=True).transform(x, y, z)[2])


def test_nap_heights_are_raised_to_the_ellipsoid(tmp_path) -> None:
    if crs_mod._grid_path(crs_mod._GLOBAL_GEOID) is None:
        pytest.skip("no geoid model installed (Debian proj-data)")
    crs_mod._height_offset.cache_clear()
    with pytest.warns(UserWarning, match="nl_nsgi_nlgeo2018"):
        h = _origin_height(tmp_path / "nap", "EPSG:7415")
    # NAP 0 m lies 43.2 to 43.5 m above the WGS84 ellipsoid around Delft (the geoid undulation there).
    assert 42.8 < h < 44.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a CRS without a vertical datum: heights taken as given, silently
        assert abs(_origin_height(tmp_path / "rd", "EPSG:28992")) < 1e-3


def test_without_a_geoid_model_the_warning_says_so(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(crs_mod, "_grid_path", lambda name: None)
    crs_mod._height_offset.cache_clear()
    try:
        with pytest.warns(UserWarning, match="no geoid model is installed"):
            h = _origin_height(tmp_path, "EPSG:7415")
    finally:
        crs_mod._height_offset.cache_clear()
    assert abs(h) < 1e-3
