"""Fixtures shared by the render tests: a sampled smooth surface and its point tileset (the splat tests)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.render.test_splats import ORIGIN, _height, _write_las


@pytest.fixture(scope="module")
def surface_cloud() -> np.ndarray:
    rng = np.random.default_rng(3)
    n = 8_000  # 20 points/m², AHN-like
    xy = rng.uniform(0.0, 20.0, (n, 2))
    return np.column_stack([xy, _height(xy[:, 0], xy[:, 1])]) + ORIGIN


@pytest.fixture(scope="module")
def surface_tiles(surface_cloud: np.ndarray, tmp_path_factory: pytest.TempPathFactory):
    import warnings

    from citylod.lod.build.points import build_points

    d = tmp_path_factory.mktemp("splat_tiles")
    _write_las(d / "surface.las", surface_cloud)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # RD New has no vertical datum: said, not an error
        build_points([d / "surface.las"], d / "ts", crs="EPSG:28992", progress=False, hybrid=False)
    return d / "ts"
