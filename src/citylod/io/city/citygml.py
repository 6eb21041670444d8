"""CityGML 1.0 / 2.0 / 3.0 reader.

The reader streams (lxml ``iterparse``; each ``cityObjectMember`` is cleared after use), so a file larger
than memory loads. It is hardened against hostile XML: no entity resolution, no network, no DTD loading, no
huge trees, and a document whose DOCTYPE declares entities or names an external DTD is refused before
parsing. Elements are matched by local name, so files whose root has no namespace (as found in the wild)
read like any other. The reader never crashes on bad geometry: repairs and defects become warnings.

This module must not import VTK or Qt, and it knows nothing about proxies or stores (semantics/ does).
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from citylod.core.errors import EmptyInputError, InputError
from citylod.io.city.model import F64, CityModel, CityObject, Polygon, orient_outward, repair_polygon
from citylod.io.crs import crs_from_srs_name

__all__ = ["read_citygml"]


# --------------------------------------------------------------------------------------------------------
# Hardened XML

_PROLOG_LIMIT = 1 << 20
_ENTITY_RE = re.compile(rb"<!ENTITY", re.IGNORECASE)
_DOCTYPE_RE = re.compile(rb"<!DOCTYPE", re.IGNORECASE)
_EXTERNAL_RE = re.compile(rb"<!DOCTYPE\s+[^\s\[>]+\s+(SYSTEM|PUBLIC)\b", re.IGNORECASE)


def _check_prolog(path: Path) -> None:
    """Refuse a DOCTYPE that declares entities or names an external DTD (entity bombs, XXE).

    A DOCTYPE can only stand in the prolog, and ``<!ENTITY`` cannot appear literally in element content
    ('<' must be escaped there), so a search of the first megabyte is enough. UTF-16 files are read with
    their zero bytes removed, which keeps ASCII markup readable.
    """
    with open(path, "rb") as fh:
        head = fh.read(_PROLOG_LIMIT).replace(b"\x00", b"")
    doctype = _DOCTYPE_RE.search(head)
    if doctype is None:
        return
    if _ENTITY_RE.search(head, doctype.start()) or _EXTERNAL_RE.search(head, doctype.start()):
        raise InputError("refused: the XML declares entities or an external DTD (possible entity-expansion "
                         "or external-entity attack)", path)


def _local(tag: Any) -> str:
    """Local name of an element tag ('{ns}name' or 'name'); '' for comments and processing instructions."""
    if not isinstance(tag, str):
        return ""
    return tag.rsplit("}", 1)[-1]


def _attr(elem: Any, local: str) -> str | None:
    """An attribute by local name, in any namespace (``gml:id`` is namespaced in GML 3, not in some files)."""
    for k, v in elem.attrib.items():
        if _local(k) == local:
            return str(v)
    return None


# --------------------------------------------------------------------------------------------------------
# Geometry elements

_GEOM_CONTAINERS = re.compile(r"^lod([0-4])")
_SURFACE_CLASSES = {
    "RoofSurface", "WallSurface", "GroundSurface", "ClosureSurface", "CeilingSurface", "InteriorWallSurface",
    "FloorSurface", "OuterCeilingSurface", "OuterFloorSurface", "Window", "Door",
}
# Children of a feature that hold other features or geometry, not attributes.
_NOT_ATTRIBUTES = {
    "boundedBy", "boundary", "consistsOfBuildingPart", "buildingPart", "outerBuildingInstallation",
    "interiorBuildingInstallation", "buildingInstallation", "interiorRoom", "buildingRoom", "opening",
    "appearance", "externalReference", "generalizesTo", "relativeToTerrain", "relativeToWater",
    "lod0FootPrint", "lod0RoofEdge", "address", "genericAttribute", "groupMember", "parent",
}
_GENERIC = {"stringAttribute", "intAttribute", "doubleAttribute", "dateAttribute", "uriAttribute",
            "measureAttribute", "StringAttribute", "IntAttribute", "DoubleAttribute", "DateAttribute",
            "UriAttribute", "MeasureAttribute", "CodeAttribute"}
_FLOATS = {"measuredHeight", "storeyHeightsAboveGround", "storeyHeightsBelowGround"}
_INTS = {"storeysAboveGround", "storeysBelowGround", "yearOfConstruction", "yearOfDemolition"}


def _coords(elem: Any, dim: int) -> F64:
    """Coordinates of a LinearRing (posList, pos list, GML 2 coordinates) as (K, 3); z = 0 when 2D."""
    vals: list[float] = []
    for child in elem.iter():
        name = _local(child.tag)
        if name in ("posList", "pos", "coordinates"):
            d = child.get("srsDimension") or child.get("dimension")
            if d is not None:
                dim = int(d)
            text = (child.text or "").strip()
            if not text:
                continue
            if name == "coordinates":
                tuples = [t.split(",") for t in text.split()]
                dim = len(tuples[0])
                vals.extend(float(v) for t in tuples for v in t)
            else:
                vals.extend(float(v) for v in text.split())
    arr = np.asarray(vals, dtype=np.float64)
    if dim not in (2, 3) or arr.size % dim:
        raise ValueError(f"{arr.size} coordinates do not make {dim}D positions")
    arr = arr.reshape(-1, dim)
    if dim == 2:
        arr = np.column_stack([arr, np.zeros(len(arr))])
    return arr


@dataclass
class _Collector:
    """Polygons found under one object, with their semantic class and LoD, and xlink targets to resolve."""

    by_lod: dict[int, list[tuple[list[F64], str | None]]] = field(default_factory=dict)
    polygon_ids: dict[str, list[F64]] = field(default_factory=dict)
    hrefs: list[tuple[int, str, str | None]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    solid_lods: set[int] = field(default_factory=set)


def _polygons(elem: Any, dim: int, col: _Collector, lod: int, sem: str | None) -> None:
    """Collect every polygon (Polygon, PolygonPatch, Triangle, xlinks) below a geometry property."""
    stack: list[tuple[Any, bool]] = [(elem, False)]
    while stack:
        node, reverse = stack.pop()
        name = _local(node.tag)
        href = next((v for k, v in node.attrib.items() if _local(k) == "href"), None)
        if href and len(node) == 0:
            col.hrefs.append((lod, href.lstrip("#"), sem))
            continue
        if name in ("Polygon", "PolygonPatch", "Triangle", "Rectangle"):
            try:
                rings: list[F64] = []
                for part in node:
                    pname = _local(part.tag)
                    if pname in ("exterior", "outerBoundaryIs"):
                        rings.insert(0, _coords(part, dim))
                    elif pname in ("interior", "innerBoundaryIs"):
                        rings.append(_coords(part, dim))
            except ValueError as exc:
                col.notes.append(f"dropped a polygon with bad coordinates ({exc})")
                continue
            if not rings:
                continue
            if reverse:
                rings = [r[::-1].copy() for r in rings]
            col.by_lod.setdefault(lod, []).append((rings, sem))
            pid = _attr(node, "id")
            if pid:
                col.polygon_ids[pid] = rings
            continue
        flip = reverse
        if name == "OrientableSurface" and node.get("orientation") == "-":
            flip = not reverse
        for child in reversed(list(node)):
            if isinstance(child.tag, str):
                stack.append((child, flip))


def _geometry_walk(feature: Any, dim: int, col: _Collector) -> None:
    """Geometry of one feature, not descending into its parts (BuildingParts become objects of their own)."""
    stack: list[tuple[Any, str | None, int | None]] = [(c, None, None) for c in reversed(feature)]
    while stack:
        node, sem, lod = stack.pop()
        if not isinstance(node.tag, str):
            continue
        name = _local(node.tag)
        if name in ("consistsOfBuildingPart", "buildingPart", "opening", "appearance", "lod0RoofEdge"):
            continue  # openings lie in their wall's plane: they add nothing to a proxy
        m = _GEOM_CONTAINERS.match(name)
        if m and lod is None:
            level = int(m.group(1))
            if name.endswith("Solid") or sem in ("RoofSurface", "WallSurface", "GroundSurface"):
                col.solid_lods.add(level)  # a shell expected to close: check and orient it as a volume
            _polygons(node, dim, col, level, sem)
            continue
        if name in _SURFACE_CLASSES:
            sem = name
        for child in reversed(node):
            stack.append((child, sem, lod))


def _text(elem: Any) -> str:
    return (elem.text or "").strip()


def _attributes(feature: Any) -> dict[str, Any]:
    """Thematic attributes, generic attributes and the address of a feature (best effort)."""
    attrs: dict[str, Any] = {}
    for child in feature:
        if not isinstance(child.tag, str):
            continue
        name = _local(child.tag)
        if name in _GENERIC or name == "genericAttribute":
            node = child
            if name == "genericAttribute" and len(child):
                node = child[0]  # CityGML 3.0: genericAttribute/gen:StringAttribute/(name, value)
            key = node.get("name")
            value = None
            for sub in node:
                sn = _local(sub.tag)
                if sn == "name":
                    key = _text(sub)
                elif sn == "value":
                    value = _text(sub)
            if key:
                attrs[key] = _convert(_local(node.tag), value)
            continue
        if name == "address":
            addr = {(_local(e.tag)): _text(e) for e in child.iter() if isinstance(e.tag, str) and len(e) == 0
                    and _text(e)}
            if addr:
                attrs["address"] = addr
            continue
        if name in _NOT_ATTRIBUTES or _GEOM_CONTAINERS.match(name) or name == "boundedBy":
            continue
        if len(child) == 0:
            text = _text(child)
            if not text:
                continue
            if name in _FLOATS:
                try:
                    attrs[name] = float(text)
                    continue
                except ValueError:
                    pass
            if name in _INTS:
                try:
                    attrs[name] = int(float(text))
                    continue
                except ValueError:
                    pass
            if name in attrs:  # repeated properties (several gml:name, function) become lists
                prev = attrs[name]
                attrs[name] = [*prev, text] if isinstance(prev, list) else [prev, text]
            else:
                attrs[name] = text
    return attrs


def _convert(kind: str, value: str | None) -> Any:
    if value is None:
        return None
    k = kind.lower()
    try:
        if k.startswith("int"):
            return int(value)
        if k.startswith(("double", "measure")):
            return float(value)
    except ValueError:
        return value
    return value


def _finish_object(fid: str, ftype: str, attrs: dict[str, Any], col: _Collector, lod: int, parent: str | None,
                   warnings: list[str]) -> CityObject:
    """Choose the LoD, resolve xlinks, repair and orient; every note becomes a warning with the id."""
    for target_lod, href, sem in col.hrefs:
        rings = col.polygon_ids.get(href)
        if rings is None:
            col.notes.append(f"unresolved xlink #{href}")
            continue
        # A solid that references its boundary surfaces' polygons: same polygons, count them once.
        if not any(r is rings for r, _ in col.by_lod.get(target_lod, [])):
            col.by_lod.setdefault(target_lod, []).append((rings, sem))
    chosen = -1
    if col.by_lod:
        avail = sorted(col.by_lod)
        lower = [v for v in avail if v <= lod]
        chosen = max(lower) if lower else min(avail)
    polys: list[Polygon] = []
    sems: list[str | None] = []
    notes = list(col.notes)
    for rings, sem in col.by_lod.get(chosen, []):
        poly, n = repair_polygon(rings)
        notes += n
        if poly is not None:
            polys.append(poly)
            sems.append(sem)
    if polys:
        polys, n = orient_outward(polys, sems, closed=chosen in col.solid_lods)
        notes += n
    for note in dict.fromkeys(notes):  # one warning per kind of note and object
        count = notes.count(note)
        warnings.append(f"{fid}: {note}" + (f" (x{count})" if count > 1 else ""))
    return CityObject(fid, ftype, attrs, polys, chosen if polys else -1, parent, sems)


def _feature_objects(feature: Any, dim: int, lod: int, warnings: list[str], counter: list[int],
                     parent: str | None = None) -> Iterator[CityObject]:
    ftype = _local(feature.tag)
    fid = _attr(feature, "id")
    if not fid:
        counter[0] += 1
        fid = f"{ftype}_{counter[0]}"
    attrs = _attributes(feature)
    col = _Collector()
    _geometry_walk(feature, dim, col)
    yield _finish_object(fid, ftype, attrs, col, lod, parent, warnings)
    for child in feature:
        if _local(child.tag) in ("consistsOfBuildingPart", "buildingPart"):
            for part in child:
                if isinstance(part.tag, str):
                    yield from _feature_objects(part, dim, lod, warnings, counter, parent=fid)


def _version_of(nsmap: dict[Any, str]) -> str:
    for uri in nsmap.values():
        m = re.search(r"opengis\.net/citygml/(?:[a-z]+/)?(\d\.\d)", uri or "")
        if m:
            return f"CityGML {m.group(1)}"
    return "CityGML"


def read_citygml(path: str | PathLike[str], *, lod: int = 2) -> CityModel:
    """Read a CityGML 1.0, 2.0 or 3.0 file, streamed.

    Parameters
    ----------
    path
        The ``.gml`` / ``.xml`` file.
    lod
        Preferred level of detail: each object keeps the highest LoD not above ``lod`` it has, else its
        lowest.

    Returns
    -------
    CityModel
        Objects in the source CRS (see :func:`to_metric`), with repair warnings.

    Raises
    ------
    InputError
        Missing, malformed or hostile XML, named with the file.
    EmptyInputError
        No city objects.
    """
    from lxml import etree

    p = Path(path)
    if not p.is_file():
        raise InputError("no such file", p)
    _check_prolog(p)
    objects: list[CityObject] = []
    warnings: list[str] = []
    srs: list[str] = []
    version = "CityGML"
    counter = [0]
    default_dim = 3
    try:
        context = etree.iterparse(
            str(p), events=("start", "end"), resolve_entities=False, no_network=True, load_dtd=False,
            huge_tree=False, remove_comments=True, remove_pis=True,
        )
        depth = 0
        for event, elem in context:
            if event == "start":
                depth += 1
                if depth == 1:
                    version = _version_of(elem.nsmap)
                    docinfo = elem.getroottree().docinfo
                    dtd = docinfo.internalDTD
                    if dtd is not None and (list(dtd.entities()) or docinfo.system_url):
                        raise InputError("refused: the XML declares entities or an external DTD", p)
                s = elem.get("srsName")
                if s and s not in srs:
                    srs.append(s)
                d = elem.get("srsDimension")
                if d and _local(elem.tag) == "Envelope":
                    default_dim = int(d)
                continue
            depth -= 1
            name = _local(elem.tag)
            if name in ("cityObjectMember", "featureMember", "member") and depth == 1:
                for feature in elem:
                    if isinstance(feature.tag, str):
                        objects.extend(_feature_objects(feature, default_dim, lod, warnings, counter))
                elem.clear(keep_tail=False)
                # Streaming: drop the members already processed so memory stays bounded.
                parent = elem.getparent()
                while parent is not None and elem.getprevious() is not None:
                    del parent[0]
    except etree.XMLSyntaxError as exc:
        raise InputError(f"malformed XML: {exc}", p) from exc
    except (ValueError, OverflowError) as exc:
        raise InputError(f"bad value: {exc}", p) from exc
    if not objects:
        raise EmptyInputError("no city objects (no cityObjectMember)", p)
    crs = None
    if srs:
        crs = crs_from_srs_name(srs[0], str(p))
        if len(srs) > 1:
            warnings.append(f"{p.name}: several srsName values {srs}; used {srs[0]}")
    return CityModel(objects, crs, str(p), warnings, version)

