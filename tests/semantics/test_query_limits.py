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


def test_an_unknown_column_names_the_ones_there_are(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A query on a column the store lacks says which columns there are and where the other attributes are;
    ``citylod info`` lists both, the attributes with how many objects have each."""
    import numpy as np

    from citylod.cli import main

    ring = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 0, 0]], float)
    objs = [CityObject("A", "Building", {"roofType": "1000", "yearOfConstruction": 1970}, [[ring]], 1),
            CityObject("B", "Building", {"roofType": "3100"}, [[ring + 2]], 1)]
    out = tmp_path / "a.gpkg"
    build_city(CityModel(objs, None, "a.gml"), out, crs="EPSG:25832", progress=False)
    with CityStore.open(out) as s:
        with pytest.raises(InputError, match=r"no such column: height \(columns: object_id, type, .*measured_height"
                                              r".*json_extract\(attributes"):
            s.query("height > 10")
        assert s.query("json_extract(attributes, '$.roofType') = '3100'") == ["B"]  # as the hint says
        assert s.attribute_names() == [("roofType", 2), ("yearOfConstruction", 1)]
    assert main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "measured_height" in text and "roofType (2), yearOfConstruction (1)" in text
