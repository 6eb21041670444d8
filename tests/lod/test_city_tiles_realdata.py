"""City tilesets of real models written by others (../shared/data): every object with its attributes.

The expectations come from independent parses: the CityJSON with the json module, the CityGML with lxml.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from lxml import etree

from citylod.io.tiles3d import open_tileset
from citylod.lod.build.city import build_city_tiles
from tests.paths import SHARED_DATA

pytestmark = [
    pytest.mark.realdata,
    pytest.mark.skipif(not SHARED_DATA.is_dir(), reason=f"real data folder {SHARED_DATA} is absent"),
]


def _rows(folder: Path) -> dict[str, dict]:
    """object_id -> row over the leaves (each object in exactly one leaf)."""
    rows: dict[str, dict] = {}
    ts = open_tileset(folder)
    for t in ts.walk():
        if t.children:
            continue
        table = t.load_content().property_tables[0]
        for i in range(table.count):
            r = table.row(i)
            assert r["object_id"] not in rows
            rows[r["object_id"]] = r
    return rows


def test_delft_cityjson_objects_and_attributes(tmp_path: Path) -> None:
    src = SHARED_DATA / "delft" / "testarea.city.json"
    report = build_city_tiles(src, tmp_path / "delft", leaf_triangles=4000, progress=False)
    assert report.levels >= 3
    doc = json.loads(src.read_text())
    rows = _rows(tmp_path / "delft")
    assert set(rows) == set(doc["CityObjects"])
    for oid, obj in doc["CityObjects"].items():
        assert rows[oid]["type"] == obj["type"]
        assert json.loads(rows[oid]["attributes"]) == obj.get("attributes", {})
    ts = open_tileset(tmp_path / "delft")
    assert ts.crs.to_epsg() in (7415, 28992)


def test_karlsruhe_citygml_buildings(tmp_path: Path) -> None:
    src = SHARED_DATA / "karlsruhe" / "hagsfeld_lod2_270_buildings.gml"
    build_city_tiles(src, tmp_path / "ka", leaf_triangles=2000, progress=False)
    tree = etree.parse(str(src))
    ids = {el.get("{http://www.opengis.net/gml}id") for el in tree.iter()
           if isinstance(el.tag, str) and etree.QName(el).localname == "Building"}
    assert len(ids) == 266
    rows = _rows(tmp_path / "ka")
    assert ids <= set(rows)
    assert all(rows[i]["type"] == "Building" for i in ids)
