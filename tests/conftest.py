"""Fixtures shared by the whole suite, built once per test process (session scope).

The sample city is the expensive one: written once at 129² and, for the tests that need them, its DSM
tileset (textured), its city store and its point octree built once beside it.
"""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from citylod.sample import SampleInfo, make_sample


@pytest.fixture(scope="session")
def sample_city(tmp_path_factory: pytest.TempPathFactory) -> SampleInfo:
    """The 129² synthetic sample city (seed 7): DSM, orthophoto, LAZ, CityGML, camera and flight files."""
    return make_sample(tmp_path_factory.mktemp("sample129"), size=129, seed=7)


@pytest.fixture(scope="session")
def sample_built(sample_city: SampleInfo, tmp_path_factory: pytest.TempPathFactory) -> SimpleNamespace:
    """:func:`sample_city` with its products: ``dsm`` (textured tileset), ``gpkg`` (city store), ``points``."""
    from citylod.lod.build.dsm import build_dsm
    from citylod.lod.build.points import build_points
    from citylod.semantics.store import build_city

    out = tmp_path_factory.mktemp("sample129_built")
    info = sample_city
    build_dsm(info.files["dsm"], out / "dsm", ortho=info.files["ortho"], workers=0, progress=False)
    build_city(info.files["city"], out / "city.gpkg", progress=False)
    build_points([info.files["points"]], out / "points", workers=0, progress=False)
    return SimpleNamespace(dir=out, info=info, truth=info.city, gpkg=out / "city.gpkg", dsm=out / "dsm",
                           points=out / "points")
