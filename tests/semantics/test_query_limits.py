"""WHERE clauses that would run for ever or build huge values are stopped with an InputError."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from citylod.core.errors import InputError
from citylod.io.city.model import CityModel, CityObject
from citylod.semantics.store import CityStore, build_city


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    import numpy as np

    ring = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 0, 0]], float)
    obj = CityObject("A", "Building", {}, [[ring]], 1)
    out = tmp_path_factory.mktemp("q") / "q.gpkg"
    build_city(CityModel([obj], None, "q.gml"), out, crs="EPSG:25832", progress=False)
    return out


@pytest.mark.parametrize("where", [
    "object_id IN (WITH RECURSIVE c(x) AS (SELECT 1 UNION ALL SELECT x + 1 FROM c) SELECT x FROM c)",
    "length(printf('%.*c', 2000000000, 'x')) > 0",
    "length(randomblob(1000000000)) > 0",
    "load_extension('evil')",
])
def test_runaway_queries_are_stopped(store: Path, where: str) -> None:
    with CityStore.open(store) as s:
        s.query_time_limit_s = 0.5
        t0 = time.perf_counter()
        with pytest.raises(InputError, match=r"q\.gpkg"):
            s.query(where)
        assert time.perf_counter() - t0 < 5.0
        assert s.query("type = 'Building'") == ["A"]
