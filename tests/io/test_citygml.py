"""CityGML / CityJSON readers: hostile XML refused, geometry repaired and reported, CRS handling."""

from __future__ import annotations

import json
from itertools import pairwise
from pathlib import Path

import numpy as np
import pyproj
import pytest
import shapely

from citylod.core.errors import EmptyInputError, GeoreferenceError, InputError
from citylod.io.city import read_city_model, to_metric
from citylod.io.city.citygml import read_citygml

NS2 = ('xmlns="http://www.opengis.net/citygml/2.0" xmlns:core="http://www.opengis.net/citygml/2.0" '
       'xmlns:gml="http://www.opengis.net/gml" xmlns:bldg="http://www.opengis.net/citygml/building/2.0" '
       'xmlns:gen="http://www.opengis.net/citygml/generics/2.0" '
       'xmlns:xAL="urn:oasis:names:tc:ciq:xsdschema:xAL:2.0"')


def ring(pts: list[tuple[float, float, float]]) -> str:
    return " ".join(f"{x} {y} {z}" for x, y, z in pts)


def box_surfaces(x0: float, y0: float, x1: float, y1: float, z0: float, z1: float) -> list[list[tuple]]:
    """Outward rings of an axis-aligned box (closed)."""
    b = [(x0, y0, z0), (x0, y1, z0), (x1, y1, z0), (x1, y0, z0), (x0, y0, z0)]  # ground, facing down
    t = [(x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1), (x0, y0, z1)]  # roof, facing up
    walls = []
    c = [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)]
    for (ax, ay), (bx, by) in pairwise(c):
        walls.append([(ax, ay, z0), (bx, by, z0), (bx, by, z1), (ax, ay, z1), (ax, ay, z0)])
    return [b, t, *walls]


def building(gid: str, surfaces: list[list[tuple]], sem: list[str] | None = None, extra: str = "",
             holes: dict[int, list[tuple]] | None = None) -> str:
    holes = holes or {}
    parts = []
    for i, s in enumerate(surfaces):
        hole = f"<gml:interior><gml:LinearRing><gml:posList>{ring(holes[i])}</gml:posList></gml:LinearRing></gml:interior>" if i in holes else ""
        poly = (f'<gml:Polygon gml:id="{gid}_p{i}"><gml:exterior><gml:LinearRing><gml:posList srsDimension="3">'
                f"{ring(s)}</gml:posList></gml:LinearRing></gml:exterior>{hole}</gml:Polygon>")
        kind = (sem or ["GroundSurface", "RoofSurface"] + ["WallSurface"] * 8)[i]
        parts.append(f"<bldg:boundedBy><bldg:{kind}><bldg:lod2MultiSurface><gml:MultiSurface><gml:surfaceMember>"
                     f"{poly}</gml:surfaceMember></gml:MultiSurface></bldg:lod2MultiSurface></bldg:{kind}></bldg:boundedBy>")
    return (f'<cityObjectMember><bldg:Building gml:id="{gid}"><gml:name>{gid} name</gml:name>{extra}'
            f'{"".join(parts)}</bldg:Building></cityObjectMember>')


def document(members: str, ns: str = NS2, srs: str = "EPSG:25832") -> str:
    return (f'<?xml version="1.0" encoding="UTF-8"?>\n<CityModel {ns}><gml:boundedBy><gml:Envelope srsName="{srs}" '
            f'srsDimension="3"><gml:lowerCorner>0 0 0</gml:lowerCorner><gml:upperCorner>1 1 1</gml:upperCorner>'
            f"</gml:Envelope></gml:boundedBy>{members}</CityModel>")


def write(tmp_path: Path, text: str, name: str = "city.gml") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


# --- hostile and malformed XML -------------------------------------------------------------------------

BILLION_LAUGHS = """<?xml version="1.0"?>
<!DOCTYPE lolz [<!ENTITY lol "lol"><!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">
<!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">]>
<CityModel><gml:name xmlns:gml="http://www.opengis.net/gml">&lol3;</gml:name></CityModel>"""
XXE = """<?xml version="1.0"?>
<!DOCTYPE CityModel [<!ENTITY xxe SYSTEM "file:///etc/passwd">]>
<CityModel><cityObjectMember><Building><name>&xxe;</name></Building></cityObjectMember></CityModel>"""
EXTERNAL_DTD = """<?xml version="1.0"?>
<!DOCTYPE CityModel SYSTEM "http://example.invalid/evil.dtd">
<CityModel><cityObjectMember><Building/></cityObjectMember></CityModel>"""


@pytest.mark.parametrize("text", [BILLION_LAUGHS, XXE, EXTERNAL_DTD], ids=["billion-laughs", "xxe", "external-dtd"])
def test_hostile_xml_is_refused_naming_the_file(tmp_path: Path, text: str) -> None:
    p = write(tmp_path, text, "hostile.gml")
    with pytest.raises(InputError, match="refused") as info:
        read_citygml(p)
    assert "hostile.gml" in str(info.value)


def test_malformed_xml_is_an_input_error(tmp_path: Path) -> None:
    p = write(tmp_path, document(building("B1", box_surfaces(0, 0, 10, 10, 0, 5)))[:-40], "broken.gml")
    with pytest.raises(InputError, match="malformed") as info:
        read_citygml(p)
    assert "broken.gml" in str(info.value)


def test_no_objects_is_empty_input(tmp_path: Path) -> None:
    with pytest.raises(EmptyInputError):
        read_citygml(write(tmp_path, document("")))


# --- geometry and attributes ---------------------------------------------------------------------------

def test_building_attributes_and_lod2_box(tmp_path: Path) -> None:
    extra = ("<bldg:function>31001_1000</bldg:function><bldg:measuredHeight uom='m'>5.0</bldg:measuredHeight>"
             "<bldg:storeysAboveGround>2</bldg:storeysAboveGround>"
             "<gen:stringAttribute name='owner'><gen:value>city</gen:value></gen:stringAttribute>"
             "<gen:doubleAttribute name='area'><gen:value>100.5</gen:value></gen:doubleAttribute>"
             "<bldg:address><core:Address><core:xalAddress><xAL:AddressDetails><xAL:Country><xAL:Locality>"
             "<xAL:LocalityName>Bonn</xAL:LocalityName><xAL:Thoroughfare><xAL:ThoroughfareName>Main St"
             "</xAL:ThoroughfareName></xAL:Thoroughfare></xAL:Locality></xAL:Country></xAL:AddressDetails>"
             "</core:xalAddress></core:Address></bldg:address>")
    m = read_citygml(write(tmp_path, document(building("B1", box_surfaces(0, 0, 10, 10, 0, 5), extra=extra))))
    (o,) = m.objects
    assert (o.id, o.type, o.lod) == ("B1", "Building", 2)
    a = o.attributes
    assert a["name"] == "B1 name" and a["function"] == "31001_1000"
    assert a["measuredHeight"] == 5.0 and a["storeysAboveGround"] == 2
    assert a["owner"] == "city" and a["area"] == 100.5
    assert a["address"]["LocalityName"] == "Bonn" and a["address"]["ThoroughfareName"] == "Main St"
    assert len(o.surfaces) == 6 and o.semantics.count("WallSurface") == 4
    assert m.crs is not None and m.crs.to_epsg() == 25832 and m.version == "CityGML 2.0"
    assert m.warnings == []


def test_courtyard_hole_is_kept_and_oriented(tmp_path: Path) -> None:
    outer = [(0, 0, 5), (20, 0, 5), (20, 20, 5), (0, 20, 5), (0, 0, 5)]
    hole = [(5, 5, 5), (15, 5, 5), (15, 15, 5), (5, 15, 5), (5, 5, 5)]  # same sense as exterior: wrong
    m = read_citygml(write(tmp_path, document(building("C", [outer], ["RoofSurface"], holes={0: hole}))))
    poly = m.objects[0].surfaces[0]
    assert len(poly) == 2
    sp = shapely.Polygon(poly[0][:, :2], [poly[1][:, :2]])
    assert sp.is_valid and sp.area == pytest.approx(400 - 100)
    assert shapely.Polygon(poly[0][:, :2]).exterior.is_ccw != shapely.LinearRing(poly[1][:, :2]).is_ccw
    assert any("hole" in w for w in m.warnings)


def test_inverted_solid_is_reoriented_outward(tmp_path: Path) -> None:
    inverted = [s[::-1] for s in box_surfaces(0, 0, 10, 10, 0, 5)]
    m = read_citygml(write(tmp_path, document(building("INV", inverted, ["WallSurface"] * 6))))
    o = m.objects[0]
    # Signed volume by the divergence theorem, computed independently of the reader.
    vol = 0.0
    for poly in o.surfaces:
        r = poly[0][:-1]
        for k in range(1, len(r) - 1):
            vol += float(np.dot(r[0], np.cross(r[k], r[k + 1]))) / 6.0
    assert vol == pytest.approx(500.0)
    assert any("inverted" in w and w.startswith("INV:") for w in m.warnings)


def test_unclosed_ring_and_duplicates_are_repaired(tmp_path: Path) -> None:
    roof = [(0, 0, 5), (10, 0, 5), (10, 0, 5), (10, 10, 5), (0, 10, 5)]  # duplicate, not closed
    m = read_citygml(write(tmp_path, document(building("U", [roof], ["RoofSurface"]))))
    r = m.objects[0].surfaces[0][0]
    assert np.array_equal(r[0], r[-1]) and len(r) == 5
    assert any(w.startswith("U:") and "closed an unclosed ring" in w for w in m.warnings)
    assert any("duplicate" in w for w in m.warnings)


def test_degenerate_polygon_is_reported_not_fatal(tmp_path: Path) -> None:
    bad = [(0, 0, 0), (1, 1, 1), (0, 0, 0)]
    good = box_surfaces(0, 0, 1, 1, 0, 1)
    m = read_citygml(write(tmp_path, document(building("D", [*good, bad], ["GroundSurface", "RoofSurface"] + ["WallSurface"] * 5))))
    assert len(m.objects[0].surfaces) == 6
    assert any(w.startswith("D:") and "degenerate" in w for w in m.warnings)


def test_no_namespace_root_building_parts_lod1_solid_and_gml_coordinates(tmp_path: Path) -> None:
    # CityGML 1.0 namespaces, a root without namespace, a BuildingPart with an lod1Solid in 2D posList.
    ns = ('xmlns:gml="http://www.opengis.net/gml" xmlns:bldg="http://www.opengis.net/citygml/building/1.0"')
    faces = box_surfaces(0, 0, 4, 4, 0, 3)
    members = "".join(
        f"<gml:surfaceMember><gml:Polygon><gml:exterior><gml:LinearRing><gml:posList>{ring(f)}</gml:posList>"
        f"</gml:LinearRing></gml:exterior></gml:Polygon></gml:surfaceMember>" for f in faces)
    text = (f'<CityModel {ns}><cityObjectMember><bldg:Building gml:id="P"><bldg:consistsOfBuildingPart>'
            f'<bldg:BuildingPart gml:id="P1"><bldg:lod1Solid><gml:Solid><gml:exterior><gml:CompositeSurface>'
            f"{members}</gml:CompositeSurface></gml:exterior></gml:Solid></bldg:lod1Solid></bldg:BuildingPart>"
            f"</bldg:consistsOfBuildingPart></bldg:Building></cityObjectMember></CityModel>")
    m = read_citygml(write(tmp_path, text))
    assert [(o.id, o.type, o.parent) for o in m.objects] == [("P", "Building", None), ("P1", "BuildingPart", "P")]
    assert m.objects[0].lod == -1 and m.objects[1].lod == 1 and len(m.objects[1].surfaces) == 6
    assert m.crs is None


def test_citygml3_boundary_and_generic_attribute(tmp_path: Path) -> None:
    ns = ('xmlns="http://www.opengis.net/citygml/3.0" xmlns:con="http://www.opengis.net/citygml/construction/3.0" '
          'xmlns:gml="http://www.opengis.net/gml/3.2" xmlns:bldg="http://www.opengis.net/citygml/building/3.0" '
          'xmlns:gen="http://www.opengis.net/citygml/generics/3.0"')
    surf = box_surfaces(0, 0, 5, 5, 0, 4)
    kinds = ["GroundSurface", "RoofSurface"] + ["WallSurface"] * 4
    bounds = "".join(
        f"<boundary><con:{k}><lod2MultiSurface><gml:MultiSurface><gml:surfaceMember><gml:Polygon><gml:exterior>"
        f"<gml:LinearRing><gml:posList>{ring(s)}</gml:posList></gml:LinearRing></gml:exterior></gml:Polygon>"
        f"</gml:surfaceMember></gml:MultiSurface></lod2MultiSurface></con:{k}></boundary>" for k, s in zip(kinds, surf, strict=True))
    text = (f'<CityModel {ns}><cityObjectMember><bldg:Building gml:id="G3"><genericAttribute><gen:IntAttribute>'
            f"<gen:name>levels</gen:name><gen:value>3</gen:value></gen:IntAttribute></genericAttribute>{bounds}"
            "</bldg:Building></cityObjectMember></CityModel>")
    m = read_citygml(write(tmp_path, text))
    o = m.objects[0]
    assert m.version == "CityGML 3.0" and o.attributes["levels"] == 3 and o.lod == 2
    assert sorted(o.semantics) == sorted(kinds) and m.warnings == []


def test_other_city_objects_are_kept(tmp_path: Path) -> None:
    ns = NS2 + ' xmlns:veg="http://www.opengis.net/citygml/vegetation/2.0"'
    text = document('<cityObjectMember><veg:SolitaryVegetationObject gml:id="T1"><veg:species>oak</veg:species>'
                    "</veg:SolitaryVegetationObject></cityObjectMember>", ns=ns)
    (o,) = read_citygml(write(tmp_path, text)).objects
    assert (o.id, o.type, o.attributes["species"], o.lod) == ("T1", "SolitaryVegetationObject", "oak", -1)


# --- CRS ------------------------------------------------------------------------------------------------

def test_geographic_input_is_projected_to_utm(tmp_path: Path) -> None:
    lon, lat, d = 8.45, 49.03, 0.0001
    m = read_citygml(write(tmp_path, document(building("GEO", box_surfaces(lon, lat, lon + d, lat + d, 110, 120)),
                                              srs="EPSG:4326")))
    mm = to_metric(m)
    assert mm.crs.to_epsg() == 32632
    p = mm.objects[0].points()
    ex, ny = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True).transform(
        [lon, lon + d, lon + d, lon], [lat, lat, lat + d, lat + d])
    assert p[:, 0].min() == pytest.approx(min(ex), abs=1e-3) and p[:, 1].min() == pytest.approx(min(ny), abs=1e-3)
    assert p[:, 2].max() == 120.0
    assert to_metric(m, "EPSG:25832").crs.to_epsg() == 25832


def test_mislabelled_geographic_crs_is_an_error_unless_recognised(tmp_path: Path) -> None:
    m = read_citygml(write(tmp_path, document(building("X", box_surfaces(1000, 1000, 1010, 1010, 0, 5)),
                                              srs="EPSG:4326")))
    with pytest.raises(GeoreferenceError, match="not degrees"):
        to_metric(m)


# --- CityJSON -------------------------------------------------------------------------------------------

def cityjson_doc(version: str = "2.0") -> dict:
    # A unit cube quantised with scale 0.5 and translated, as a Solid with semantics, and a child part.
    v = [[0, 0, 0], [2, 0, 0], [2, 2, 0], [0, 2, 0], [0, 0, 2], [2, 0, 2], [2, 2, 2], [0, 2, 2]]
    shell = [[[0, 3, 2, 1]], [[4, 5, 6, 7]], [[0, 1, 5, 4]], [[1, 2, 6, 5]], [[2, 3, 7, 6]], [[3, 0, 4, 7]]]
    return {
        "type": "CityJSON", "version": version,
        "transform": {"scale": [0.5, 0.5, 0.5], "translate": [1000.0, 2000.0, 10.0]},
        "metadata": {"referenceSystem": "https://www.opengis.net/def/crs/EPSG/0/7415"},
        "CityObjects": {
            "B": {"type": "Building", "attributes": {"measuredHeight": 1.0}, "children": ["BP"]},
            "BP": {"type": "BuildingPart", "parents": ["B"], "geometry": [{
                "type": "Solid", "lod": "2.2", "boundaries": [shell],
                "semantics": {"surfaces": [{"type": "GroundSurface"}, {"type": "RoofSurface"},
                                           {"type": "WallSurface"}], "values": [[0, 1, 2, 2, 2, 2]]}}]},
            "R": {"type": "Road", "geometry": [{"type": "MultiSurface", "lod": 1, "boundaries": [[[0, 1, 2, 3]]]}]},
        },
        "vertices": v,
    }


def test_cityjson_reader(tmp_path: Path) -> None:
    p = tmp_path / "c.city.json"
    p.write_text(json.dumps(cityjson_doc()))
    m = read_city_model(p)
    objs = {o.id: o for o in m.objects}
    assert m.version == "CityJSON 2.0" and m.crs.to_epsg() == 7415
    bp = objs["BP"]
    assert bp.parent == "B" and bp.lod == 2 and bp.semantics[:2] == ["GroundSurface", "RoofSurface"]
    pts = bp.points()
    assert pts.min(axis=0).tolist() == [1000.0, 2000.0, 10.0] and pts.max(axis=0).tolist() == [1001.0, 2001.0, 11.0]
    assert objs["B"].lod == -1 and objs["R"].lod == 1
    assert m.warnings == []  # implicit closure of CityJSON rings is not a repair


def test_cityjson_errors(tmp_path: Path) -> None:
    p = tmp_path / "bad.json"
    p.write_text("{not json")
    with pytest.raises(InputError, match=r"bad\.json"):
        read_city_model(p)
    doc = cityjson_doc()
    doc["CityObjects"]["R"]["geometry"][0]["boundaries"] = [[[0, 1, 99]]]
    p.write_text(json.dumps(doc))
    m = read_city_model(p)
    assert any(w.startswith("R:") and "outside" in w for w in m.warnings)


def test_a_file_that_is_no_city_model_says_so(tmp_path: Path) -> None:
    """A raster or point cloud given as a city model: one line saying what was expected, not an XML parser's."""
    from citylod.io.city.read import read_city_model

    p = tmp_path / "dsm.tif"
    p.write_bytes(b"II*\x00" + bytes(100))
    with pytest.raises(InputError, match="not a city model: CityGML") as info:
        read_city_model(p)
    assert "dsm.tif" in str(info.value)
