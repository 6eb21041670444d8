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
from citylod.io.city.model import (
    F64,
    CityModel,
    CityObject,
    Polygon,
    open_edge_count,
    orient_outward,
    repair_polygon,
)
from citylod.io.crs import crs_from_srs_name
from citylod.io.xmlsafe import check_xml_prolog

__all__ = ["read_citygml"]


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
# Children of a feature whose geometry is not the feature's outside: parts (objects of their own), rooms,
# furniture and interior installations (LoD4 / CityGML 3.0 interiors), appearances, roof edges (lines).
_NOT_GEOMETRY = {
    "consistsOfBuildingPart", "buildingPart", "appearance", "lod0RoofEdge", "interiorRoom", "buildingRoom",
    "interiorFurniture", "buildingFurniture", "roomInstallation", "interiorBuildingInstallation",
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


_COORDS = {"posList", "pos", "coordinates"}

#: A polygon as collected: its rings, semantic class, and gml:id (None without one).
_Collected = tuple[list[F64], "str | None", "str | None"]


@dataclass
class _Collector:
    """Polygons found under one object, with their semantic class and LoD, and xlink targets to resolve.

    ``walked`` maps the gml:id of every geometry element collected directly to its LoD, so that an xlink
    to it (a Solid naming its boundary surfaces' polygons) does not count it twice. Openings (windows and
    doors) are kept apart: they join the shell only where they close it.
    """

    by_lod: dict[int, list[_Collected]] = field(default_factory=dict)
    opening_by_lod: dict[int, list[_Collected]] = field(default_factory=dict)
    polygon_ids: dict[str, list[F64]] = field(default_factory=dict)
    walked: dict[str, int] = field(default_factory=dict)
    hrefs: list[tuple[int, str, str | None, bool]] = field(default_factory=list)
    opening_hrefs: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    solid_lods: set[int] = field(default_factory=set)
    saw_coords: bool = False


def _polygons(elem: Any, dim: int, col: _Collector, lod: int, sem: str | None, *, opening: bool = False,
              reverse0: bool = False) -> None:
    """Collect every polygon (Polygon, PolygonPatch, Triangle, xlinks) below a geometry property."""
    into = col.opening_by_lod if opening else col.by_lod
    stack: list[tuple[Any, bool]] = [(elem, reverse0)]
    while stack:
        node, reverse = stack.pop()
        name = _local(node.tag)
        href = next((v for k, v in node.attrib.items() if _local(k) == "href"), None)
        if href and len(node) == 0:
            col.hrefs.append((lod, href.lstrip("#"), sem, reverse))
            continue
        if name in _COORDS:
            col.saw_coords = True
        gid = _attr(node, "id")
        if gid and not opening:
            col.walked.setdefault(gid, lod)
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
            into.setdefault(lod, []).append((rings, sem, gid))
            if gid:
                col.polygon_ids[gid] = rings
            continue
        flip = reverse
        if name == "OrientableSurface" and node.get("orientation") == "-":
            flip = not reverse
        for child in reversed(list(node)):
            if isinstance(child.tag, str):
                stack.append((child, flip))


def _relief_lod(node: Any) -> int:
    """LoD of a relief component (CityGML ``dem:lod`` element of the TINRelief or its ReliefFeature)."""
    for owner in (node, *node.iterancestors()):
        for child in owner:
            if _local(child.tag) == "lod":
                try:
                    return min(max(int(_text(child)), 0), 4)
                except ValueError:
                    return 0
    return 0


def _geometry_walk(feature: Any, dim: int, col: _Collector, *, opening: bool = False) -> None:
    """Geometry of one feature, not descending into its parts (BuildingParts become objects of their own).

    Openings (windows, doors, inline or by xlink) go to the collector's opening lists; a relief's ``tin``
    (gml:TriangulatedSurface / gml:Tin of Triangles) takes its LoD from the ``lod`` element beside it.
    """
    stack: list[tuple[Any, str | None, bool]] = [(c, None, opening) for c in reversed(feature)]
    while stack:
        node, sem, in_opening = stack.pop()
        if not isinstance(node.tag, str):
            continue
        name = _local(node.tag)
        if name in _NOT_GEOMETRY:
            continue
        if name in ("opening", "tin"):
            href = next((v for k, v in node.attrib.items() if _local(k) == "href"), None)
            if href and len(node) == 0:
                if name == "opening":
                    col.opening_hrefs.append(href.lstrip("#"))
                else:
                    col.hrefs.append((_relief_lod(node.getparent()), href.lstrip("#"), None, False))
                continue
            if name == "tin":
                _polygons(node, dim, col, _relief_lod(node.getparent()), None, opening=in_opening)
                continue
            in_opening = True
        m = _GEOM_CONTAINERS.match(name)
        if m:
            level = int(m.group(1))
            if not in_opening and (name.endswith("Solid") or sem in ("RoofSurface", "WallSurface", "GroundSurface")):
                col.solid_lods.add(level)  # a shell expected to close: check and orient it as a volume
            _polygons(node, dim, col, level, sem, opening=in_opening)
            continue
        if name in _COORDS:
            col.saw_coords = True
        if name in _SURFACE_CLASSES:
            sem = name
        for child in reversed(node):
            stack.append((child, sem, in_opening))


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


def _semantic_of(elem: Any) -> str | None:
    """The semantic surface class (RoofSurface, Window, ...) an element lies in, or None."""
    return next((_local(a.tag) for a in elem.iterancestors() if _local(a.tag) in _SURFACE_CLASSES), None)


def _resolve_xlinks(col: _Collector, index: dict[str, Any], dim: int) -> None:
    """Bring in the geometry xlinks point at, from anywhere in the same cityObjectMember.

    Targets may be polygons or surface aggregates (CompositeSurface, MultiSurface, a Window's geometry) of
    this object, of its parent (a BuildingPart sharing its parent's wall) or of an opening. What this
    object already holds at the same LoD (a Solid naming its boundary surfaces) is not counted twice; an
    ``OrientableSurface orientation="-"`` reverses what it points at. Chains of links are followed, each
    target once (a cycle ends).
    """
    seen: set[tuple[str, int, bool]] = set()
    work = list(col.hrefs)
    while work:
        target_lod, href, sem, reverse = work.pop()
        if (href, target_lod, reverse) in seen:
            continue
        seen.add((href, target_lod, reverse))
        if col.walked.get(href) == target_lod:
            continue  # collected directly already
        elem = index.get(href)
        if elem is None:
            col.notes.append(f"unresolved xlink #{href[:80]}")
            continue
        sub = _Collector()
        _polygons(elem, dim, sub, target_lod, _semantic_of(elem) or sem, reverse0=reverse)
        have = col.by_lod.setdefault(target_lod, [])
        for rings, s, gid in sub.by_lod.get(target_lod, []):
            if gid is None or col.walked.get(gid) != target_lod:
                have.append((rings, s, gid))
                if gid:
                    col.walked[gid] = target_lod
        col.notes += sub.notes
        work += sub.hrefs
    for href in dict.fromkeys(col.opening_hrefs):
        elem = index.get(href)
        if elem is None:
            col.notes.append(f"unresolved xlink #{href[:80]}")
            continue
        sub = _Collector()
        _geometry_walk(elem, dim, sub, opening=True)
        for level, polys in sub.opening_by_lod.items():
            have = col.opening_by_lod.setdefault(level, [])
            known = {gid for _, _, gid in have if gid}  # the same window inline in another wall
            have.extend((rings, s or _local(elem.tag), gid) for rings, s, gid in polys if gid is None or gid not in known)


def _repaired(collected: list[_Collected], notes: list[str]) -> tuple[list[Polygon], list[str | None]]:
    polys: list[Polygon] = []
    sems: list[str | None] = []
    for rings, sem, _ in collected:
        poly, n = repair_polygon(rings)
        notes += n
        if poly is not None:
            polys.append(poly)
            sems.append(sem)
    return polys, sems


def _finish_object(fid: str, ftype: str, attrs: dict[str, Any], col: _Collector, lod: int, parent: str | None,
                   warnings: list[str], index: dict[str, Any], dim: int) -> CityObject:
    """Choose the LoD, resolve xlinks, repair and orient; every note becomes a warning with the id."""
    _resolve_xlinks(col, index, dim)
    chosen = -1
    if col.by_lod:
        avail = sorted(col.by_lod)
        lower = [v for v in avail if v <= lod]
        chosen = max(lower) if lower else min(avail)
    notes = list(col.notes)
    polys, sems = _repaired(col.by_lod.get(chosen, []), notes)
    # Openings a solid already names (by xlink) are in the shell; the others are candidates.
    openings = [o for o in col.opening_by_lod.get(chosen, []) if o[2] is None or col.walked.get(o[2]) != chosen]
    if polys and openings and chosen in col.solid_lods and open_edge_count(polys):
        # Walls with holes for their windows close only with the windows in them; windows drawn over walls
        # without holes would open a closed shell, so they join only where they close it.
        o_notes: list[str] = []
        o_polys, o_sems = _repaired(openings, o_notes)
        if open_edge_count(polys + o_polys) < open_edge_count(polys):
            polys, sems, notes = polys + o_polys, sems + o_sems, notes + o_notes
    if not col.by_lod and col.saw_coords:
        notes.append("has coordinates but no surfaces citylod reads (points or lines only?); kept without "
                     "geometry")
    if polys:
        polys, n = orient_outward(polys, sems, closed=chosen in col.solid_lods)
        notes += n
    for note in dict.fromkeys(notes):  # one warning per kind of note and object
        count = notes.count(note)
        warnings.append(f"{fid}: {note}" + (f" (x{count})" if count > 1 else ""))
    return CityObject(fid, ftype, attrs, polys, chosen if polys else -1, parent, sems)


def _feature_objects(feature: Any, dim: int, lod: int, warnings: list[str], counter: list[int],
                     index: dict[str, Any], parent: str | None = None) -> Iterator[CityObject]:
    ftype = _local(feature.tag)
    fid = _attr(feature, "id")
    if not fid:
        counter[0] += 1
        fid = f"{ftype}_{counter[0]}"
    attrs = _attributes(feature)
    col = _Collector()
    _geometry_walk(feature, dim, col)
    yield _finish_object(fid, ftype, attrs, col, lod, parent, warnings, index, dim)
    for child in feature:
        if _local(child.tag) in ("consistsOfBuildingPart", "buildingPart"):
            for part in child:
                if isinstance(part.tag, str):
                    yield from _feature_objects(part, dim, lod, warnings, counter, index, parent=fid)


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
    check_xml_prolog(p)
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
                # xlinks resolve within the member: a part's link to its parent's wall, a solid's to its
                # surfaces, a wall's to its windows.
                index = {gid: e for e in elem.iter() if isinstance(e.tag, str) and (gid := _attr(e, "id"))}
                for feature in elem:
                    if isinstance(feature.tag, str):
                        objects.extend(_feature_objects(feature, default_dim, lod, warnings, counter, index))
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

