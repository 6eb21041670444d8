"""CRS names as city model files spell them, each checked against the CRS pyproj builds from EPSG codes."""

from __future__ import annotations

import json
from pathlib import Path

import pyproj
import pytest

from citylod.core.errors import GeoreferenceError
from citylod.io.city.citygml import read_citygml
from citylod.io.city.cityjson import read_cityjson
from citylod.io.crs import crs_from_srs_name
from tests.cli_harness import assert_clean_refusal, run_cli

# (name in the file, EPSG codes of the CRS it names: horizontal[, vertical])
NAMES = [
    ("urn:ogc:def:crs:EPSG:6.12:25833", (25833,)),  # 3DCityDB Potsdam, TUM Munich
    ("urn:ogc:def:crs:EPSG:6.6:31467", (31467,)),
    ("urn:x-ogc:def:crs:EPSG:6.6:31467", (31467,)),
    ("urn:ogc:def:crs:EPSG::25832", (25832,)),
    ("urn:ogc:def:crs:EPSG:25832", (25832,)),
    ("EPSG:25832", (25832,)),
    ("epsg:28992", (28992,)),
    ("http://www.opengis.net/def/crs/EPSG/0/7415", (7415,)),
    ("https://www.opengis.net/def/crs/EPSG/0/28992", (28992,)),
    ("http://www.opengis.net/gml/srs/epsg.xml#4326", (4326,)),
    ("urn:ogc:def:crs,crs:EPSG::28992,crs:EPSG::5709", (28992, 5709)),  # CityJSON 1.0 compound
    ("urn:ogc:def:crs,crs:EPSG:6.12:25832,crs:EPSG:6.12:7837", (25832, 7837)),
    ("http://www.opengis.net/def/crs-compound?1=http://www.opengis.net/def/crs/EPSG/0/28992"
     "&2=http://www.opengis.net/def/crs/EPSG/0/5709", (28992, 5709)),
    ("urn:adv:crs:ETRS89_UTM32*DE_DHHN2016_NH", (25832, 7837)),
    ("urn:adv:crs:ETRS89_UTM33*DE_DHHN92_NH", (25833, 5783)),
    ("urn:adv:crs:ETRS89_UTM32*DE_DHHN2016_NH*GCG2016", (25832, 7837)),
    ("urn:adv:crs:DE_DHDN_3GK3*DE_DHHN92_NH", (31467, 5783)),
    ("urn:adv:crs:DE_DHDN_3GK4_BY120", (31468,)),
    ("urn:adv:crs:ETRS89_UTM32", (25832,)),
]


@pytest.mark.parametrize(("name", "codes"), NAMES)
def test_srs_names_match_pyproj(name: str, codes: tuple[int, ...]) -> None:
    got = crs_from_srs_name(name)
    parts = [pyproj.CRS.from_epsg(c) for c in codes]
    if len(parts) == 1:
        assert got.equals(parts[0]), (name, got.name)
    else:
        # Compound: horizontal and vertical parts are the named ones (not vertical-only, not reordered).
        assert got.is_compound, (name, got.name)
        subs = got.sub_crs_list if len(got.sub_crs_list) == 2 else []
        if not subs:  # a registered compound code (7415)
            subs = pyproj.CRS.from_epsg(codes[0]).sub_crs_list
        assert [s.equals(p) for s, p in zip(subs, parts, strict=True)] == [True, True], (name, got.name)


def test_registered_compound_is_compound() -> None:
    got = crs_from_srs_name("http://www.opengis.net/def/crs/EPSG/0/7415")
    assert got.is_compound and got.equals(pyproj.CRS.from_epsg(7415))


@pytest.mark.parametrize("name", ["urn:ogc:def:crs:EPSG::5709", "urn:adv:crs:XX_UNKNOWN*DE_DHHN2016_NH",
                                  "not a crs", "urn:ogc:def:crs,crs:EPSG::1,crs:EPSG::2,crs:EPSG::3",
                                  "EPSG:" + "9" * 5000, "urn:ogc:def:crs:EPSG::999999"])
def test_bad_names_are_georeference_errors(name: str) -> None:
    with pytest.raises(GeoreferenceError, match="src.gml"):
        crs_from_srs_name(name, "src.gml")


CUBE_GML = """<?xml version="1.0" encoding="UTF-8"?>
<core:CityModel xmlns:core="http://www.opengis.net/citygml/2.0" xmlns:bldg="http://www.opengis.net/citygml/building/2.0"
 xmlns:gml="http://www.opengis.net/gml">
 <core:cityObjectMember><bldg:Building gml:id="B1"><bldg:lod1Solid><gml:Solid{srs}><gml:exterior><gml:CompositeSurface>
  <gml:surfaceMember><gml:Polygon><gml:exterior><gml:LinearRing><gml:posList srsDimension="3">
  370000 5800000 30 370010 5800000 30 370010 5800010 30 370000 5800010 30 370000 5800000 30
  </gml:posList></gml:LinearRing></gml:exterior></gml:Polygon></gml:surfaceMember>
 </gml:CompositeSurface></gml:exterior></gml:Solid></bldg:lod1Solid></bldg:Building></core:cityObjectMember>
</core:CityModel>
"""


def test_citygml_reader_reads_versioned_and_adv_names(tmp_path: Path) -> None:
    for name, codes in [("urn:ogc:def:crs:EPSG:6.12:25833", (25833,)),
                        ("urn:adv:crs:ETRS89_UTM33*DE_DHHN2016_NH", (25833, 7837))]:
        p = tmp_path / "m.gml"
        p.write_text(CUBE_GML.format(srs=f' srsName="{name}"'))
        crs = read_citygml(p).crs
        assert crs is not None and crs.sub_crs_list[0].equals(pyproj.CRS.from_epsg(codes[0])) if len(codes) > 1 \
            else crs.equals(pyproj.CRS.from_epsg(codes[0]))


def test_cityjson_compound_urn_is_compound(tmp_path: Path) -> None:
    doc = {"type": "CityJSON", "version": "1.0",
           "metadata": {"referenceSystem": "urn:ogc:def:crs,crs:EPSG::28992,crs:EPSG::5709"},
           "CityObjects": {"A": {"type": "Building", "geometry": [
               {"type": "MultiSurface", "lod": 1, "boundaries": [[[0, 1, 2]]]}]}},
           "vertices": [[85000, 447000, 0], [85010, 447000, 0], [85010, 447010, 0]]}
    p = tmp_path / "c.city.json"
    p.write_text(json.dumps(doc))
    crs = read_cityjson(p).crs
    assert crs.is_compound
    assert crs.sub_crs_list[0].equals(pyproj.CRS.from_epsg(28992))
    assert crs.sub_crs_list[1].equals(pyproj.CRS.from_epsg(5709))


def test_file_without_srsname_is_a_clear_error_and_info_still_works(tmp_path: Path) -> None:
    p = tmp_path / "nosrs.gml"
    p.write_text(CUBE_GML.format(srs=""))
    out = tmp_path / "city.gpkg"
    r = run_cli(["build", "city", p, "-o", out])
    assert_clean_refusal(r, "nosrs.gml", tmp_path)
    assert "--crs" in r.stderr and not out.exists() and list(tmp_path.iterdir()) == [p]
    r = run_cli(["build", "city", p, "-o", out, "--crs", "EPSG:25833"])
    assert r.returncode == 0, r.stderr
    r = run_cli(["info", out])
    assert r.returncode == 0 and "ETRS89 / UTM zone 33N" in r.stdout, r.stderr
    # A store written before a CRS was required (empty crs in its metadata) is described, not a crash.
    import sqlite3

    with sqlite3.connect(out) as conn:
        conn.execute("UPDATE citylod_metadata SET value = '' WHERE key IN ('crs', 'crs_name')")
    r = run_cli(["info", out])
    assert r.returncode == 0 and "crs      none" in r.stdout, r.stderr
