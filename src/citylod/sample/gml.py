"""CityGML 2.0 writer for the buildings of the sample city (LoD1 solid and LoD2 boundary surfaces).

Only :mod:`citylod.sample.files` uses it; it is not a general CityGML writer. Each building gets
``bldg:lod1Solid`` (the footprint extruded to the mean of eave and ridge), ``bldg:lod2Solid`` made of
``xlink:href`` references to the polygons of its ``bldg:boundedBy`` Ground/Wall/RoofSurfaces (the layout of
the official German and Dutch LoD2 models), and attributes. Polygons are planar, oriented outward
(counter-clockwise seen from outside) and share every edge with exactly one other polygon of the solid.
Chimneys are not modelled, as in most LoD2 data.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from lxml import etree

from citylod.sample.city import Building, SampleCity

CORE = "http://www.opengis.net/citygml/2.0"
BLDG = "http://www.opengis.net/citygml/building/2.0"
GML = "http://www.opengis.net/gml"
GEN = "http://www.opengis.net/citygml/generics/2.0"
XLINK = "http://www.w3.org/1999/xlink"
XSI = "http://www.w3.org/2001/XMLSchema-instance"
NSMAP = {"core": CORE, "bldg": BLDG, "gml": GML, "gen": GEN, "xlink": XLINK, "xsi": XSI}
SRS_NAME = "urn:ogc:def:crs:EPSG::32632"
_SCHEMAS = (f"{CORE} http://schemas.opengis.net/citygml/2.0/cityGMLBase.xsd "
            f"{BLDG} http://schemas.opengis.net/citygml/building/2.0/building.xsd "
            f"{GEN} http://schemas.opengis.net/citygml/generics/2.0/generics.xsd")


def _q(ns: str, tag: str) -> str:
    return f"{{{ns}}}{tag}"


def write_citygml(city: SampleCity, path: Path) -> None:
    """Write all buildings of ``city`` to ``path`` as one CityGML 2.0 ``core:CityModel``."""
    root = etree.Element(_q(CORE, "CityModel"), nsmap=NSMAP)
    root.set(_q(XSI, "schemaLocation"), _SCHEMAS)
    etree.SubElement(root, _q(GML, "name")).text = f"citylod sample city (size {city.size}, seed {city.seed})"
    xmin, ymin, xmax, ymax = city.bounds
    zs = [b.ground for b in city.buildings] + [b.ridge for b in city.buildings] or [0.0]
    env = etree.SubElement(etree.SubElement(root, _q(GML, "boundedBy")), _q(GML, "Envelope"),
                           srsName=SRS_NAME, srsDimension="3")
    etree.SubElement(env, _q(GML, "lowerCorner")).text = f"{xmin:.3f} {ymin:.3f} {min(zs):.3f}"
    etree.SubElement(env, _q(GML, "upperCorner")).text = f"{xmax:.3f} {ymax:.3f} {max(zs):.3f}"
    for b in city.buildings:
        member = etree.SubElement(root, _q(CORE, "cityObjectMember"))
        member.append(_building(b))
    etree.ElementTree(root).write(str(path), xml_declaration=True, encoding="UTF-8", pretty_print=True)


def _attr(parent: etree._Element, kind: str, name: str, value: str) -> None:
    el = etree.SubElement(parent, _q(GEN, kind), name=name)
    etree.SubElement(el, _q(GEN, "value")).text = value


def _building(b: Building) -> etree._Element:
    # Child order follows the CityGML 2.0 schema: gml, core generics, then bldg properties in sequence.
    el = etree.Element(_q(BLDG, "Building"))
    el.set(_q(GML, "id"), b.id)
    etree.SubElement(el, _q(GML, "name")).text = b.name
    _attr(el, "stringAttribute", "street", b.street)
    _attr(el, "stringAttribute", "shape", b.shape)
    _attr(el, "doubleAttribute", "eaveHeight", f"{b.eave - b.ground:.2f}")
    _attr(el, "doubleAttribute", "groundHeight", f"{b.ground:.2f}")
    etree.SubElement(el, _q(BLDG, "function")).text = b.function
    etree.SubElement(el, _q(BLDG, "roofType")).text = b.roof_type_code
    etree.SubElement(el, _q(BLDG, "measuredHeight"), uom="m").text = f"{b.measured_height:.2f}"
    etree.SubElement(el, _q(BLDG, "storeysAboveGround")).text = str(b.storeys)

    verts, faces = b.solid(lod=1)
    comp = _composite(etree.SubElement(el, _q(BLDG, "lod1Solid")))
    text = _vertex_text(verts)
    for k, (_, rings) in enumerate(faces):
        member = etree.SubElement(comp, _q(GML, "surfaceMember"))
        member.append(_polygon(f"{b.id}_lod1_{k}", rings, text))

    verts, faces = b.solid(lod=2)
    text = _vertex_text(verts)
    ids = [f"{b.id}_{kind[:-7].lower()}_{k}" for k, (kind, _) in enumerate(faces)]
    comp = _composite(etree.SubElement(el, _q(BLDG, "lod2Solid")))
    for pid in ids:
        etree.SubElement(comp, _q(GML, "surfaceMember")).set(_q(XLINK, "href"), f"#{pid}")
    for pid, (kind, rings) in zip(ids, faces, strict=True):
        surf = etree.SubElement(etree.SubElement(el, _q(BLDG, "boundedBy")), _q(BLDG, kind))
        surf.set(_q(GML, "id"), f"{pid}_s")
        ms = etree.SubElement(etree.SubElement(surf, _q(BLDG, "lod2MultiSurface")), _q(GML, "MultiSurface"))
        etree.SubElement(ms, _q(GML, "surfaceMember")).append(_polygon(pid, rings, text))
    return el


def _composite(prop: etree._Element) -> etree._Element:
    solid = etree.SubElement(prop, _q(GML, "Solid"))
    return etree.SubElement(etree.SubElement(solid, _q(GML, "exterior")), _q(GML, "CompositeSurface"))


def _vertex_text(verts: np.ndarray) -> np.ndarray:
    """Each vertex formatted once, so that shared vertices are byte-identical in every polygon."""
    return np.array([" ".join(row) for row in np.char.mod("%.3f", verts)])


def _polygon(pid: str, rings: list[np.ndarray], text: np.ndarray) -> etree._Element:
    poly = etree.Element(_q(GML, "Polygon"))
    poly.set(_q(GML, "id"), pid)
    for j, ring in enumerate(rings):
        closed = np.append(ring, ring[0])  # GML rings repeat their first position
        lr = etree.SubElement(etree.SubElement(poly, _q(GML, "exterior" if j == 0 else "interior")),
                              _q(GML, "LinearRing"))
        etree.SubElement(lr, _q(GML, "posList"), srsDimension="3").text = " ".join(text[closed])
    return poly
