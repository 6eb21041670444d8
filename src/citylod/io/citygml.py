"""CityGML 1.0 / 2.0 / 3.0 reader and the city model that every city reader produces.

The reader streams (lxml ``iterparse``; each ``cityObjectMember`` is cleared after use), so a file larger
than memory loads. It is hardened against hostile XML: no entity resolution, no network, no DTD loading, no
huge trees, and a document whose DOCTYPE declares entities or names an external DTD is refused before
parsing. Elements are matched by local name, so files whose root has no namespace (as found in the wild)
read like any other.

Geometry is repaired where that is safe (duplicate points dropped, rings closed, holes and shells oriented
by Newell normal and signed volume) and every repair or defect is reported as a warning carrying the object
id; the reader never crashes on bad geometry. Geographic (degree) input is projected to a metric CRS by
:func:`to_metric` before anything metric happens.

This module must not import VTK or Qt, and it knows nothing about proxies or stores (semantics/ does).
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pyproj

from citylod.core.errors import EmptyInputError, GeoreferenceError, InputError
from citylod.io.crs import horizontal_crs, is_geographic, parse_crs, utm_crs_for

F64 = npt.NDArray[np.float64]
Ring = F64  # (K, 3) float64, closed: ring[0] == ring[-1]
Polygon = list[Ring]  # exterior ring first, then holes

__all__ = [
    "CityModel",
    "CityObject",
    "orient_outward",
    "read_city_model",
    "read_citygml",
    "repair_polygon",
    "to_metric",
]


@dataclass(frozen=True)
class CityObject:
    """One city object in a metric or source CRS.

    Attributes
    ----------
    id
        ``gml:id`` (CityGML) or the CityObjects key (CityJSON).
    type
        Local class name: ``Building``, ``BuildingPart``, ``Road``, ...
    attributes
        Thematic and generic attributes (``name``, ``class``, ``function``, ``usage``, ``measuredHeight``
        (float, m), ``storeysAboveGround`` (int), ``address`` (dict), generic attributes by their name).
    surfaces
        Polygons; each a list of rings, exterior first, each ring (K, 3) float64 and closed.
    lod
        The level of detail the surfaces come from (0..4), -1 without geometry.
    parent
        Id of the parent object (a BuildingPart's Building), or None.
    semantics
        Per surface, its semantic class (``RoofSurface``, ``WallSurface``, ``GroundSurface``, ...) or None;
        same length as ``surfaces``.
    """

    id: str
    type: str
    attributes: dict[str, Any]
    surfaces: list[Polygon]
    lod: int
    parent: str | None = None
    semantics: list[str | None] = field(default_factory=list)

    def points(self) -> F64:
        """All ring vertices, (M, 3) float64 (closing duplicates included)."""
        rings = [r for poly in self.surfaces for r in poly]
        return np.concatenate(rings) if rings else np.zeros((0, 3))


@dataclass(frozen=True)
class CityModel:
    """What a city reader returns: objects, their CRS, and what was repaired or could not be.

    Attributes
    ----------
    objects
        The city objects, parents before their parts.
    crs
        Source CRS (``pyproj.CRS``) or None when the file names none.
    source
        The file read.
    warnings
        ``"<object id>: <message>"`` for each repair and each defect left in place.
    version
        Format and version, e.g. ``"CityGML 2.0"``, ``"CityJSON 1.0"``.
    """

    objects: list[CityObject]
    crs: pyproj.CRS | None
    source: str
    warnings: list[str] = field(default_factory=list)
    version: str = ""


# --------------------------------------------------------------------------------------------------------
# Geometry repair (shared with the CityJSON reader)

def _newell(ring: F64) -> F64:
    """Newell's area vector of a closed ring (K, 3): normal times twice the area, robust for non-planar rings."""
    c = ring - ring[:-1].mean(axis=0)  # centring keeps the cross products small for large coordinates
    a, b = c[:-1], c[1:]
    return 0.5 * np.cross(a, b).sum(axis=0)


def _clean_ring(pts: F64, tol: float, implicit_close: bool = False) -> tuple[F64 | None, list[str]]:
    """Drop non-finite and consecutive duplicate points, close the ring; None when fewer than 3 remain."""
    notes: list[str] = []
    pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
    finite = np.isfinite(pts).all(axis=1)
    if not finite.all():
        notes.append(f"dropped {int((~finite).sum())} non-finite vertices")
        pts = pts[finite]
    if len(pts) == 0:
        return None, notes
    closed_in = len(pts) > 1 and bool(np.all(np.abs(pts[0] - pts[-1]) <= tol))
    if len(pts) > 1:
        # A step of (almost) zero length is a duplicate point; it breaks normals and triangulation.
        step = np.abs(np.diff(pts, axis=0)).max(axis=1)
        keep = np.concatenate([[True], step > tol])
        dups = int((~keep).sum()) - (1 if closed_in else 0)
        if dups > 0:
            notes.append(f"dropped {dups} duplicate consecutive vertices")
        pts = pts[keep]
    if len(pts) > 1 and np.all(np.abs(pts[0] - pts[-1]) <= tol):
        pts = pts[:-1]
    elif not closed_in and not implicit_close:
        notes.append("closed an unclosed ring")
    if len(pts) < 3:
        notes.append(f"dropped a degenerate ring ({len(pts)} distinct vertices)")
        return None, notes
    return np.vstack([pts, pts[:1]]), notes


def repair_polygon(rings: list[F64], *, tol: float = 1e-6, planarity_tol: float = 0.05,
                   implicit_close: bool = False) -> tuple[Polygon | None, list[str]]:
    """Repair one polygon: clean and close its rings, orient holes against the exterior, check planarity.

    Parameters
    ----------
    rings
        Exterior ring first, then holes; each (K, 3) float64, closed or not.
    tol
        Distance (m or source units) below which consecutive vertices are duplicates.
    planarity_tol
        Largest distance (source units) of a vertex from the polygon's plane before it is reported.
    implicit_close
        Rings are closed by definition (CityJSON): closing them is not a repair worth reporting.

    Returns
    -------
    polygon, notes
        The repaired polygon (None if the exterior is degenerate) and what was done or found.
    """
    notes: list[str] = []
    out: Polygon = []
    for i, r in enumerate(rings):
        clean, n = _clean_ring(r, tol, implicit_close)
        notes += n
        if clean is None:
            if i == 0:
                notes.append("dropped a polygon with a degenerate exterior ring")
                return None, notes
            continue
        out.append(clean)
    ext_n = _newell(out[0])
    area = float(np.linalg.norm(ext_n))
    if area <= tol * tol:
        notes.append("dropped a polygon of zero area")
        return None, notes
    unit = ext_n / area
    for j in range(1, len(out)):
        # Holes run against the exterior (ISO 19107); a hole that runs with it is reversed.
        if float(_newell(out[j]) @ unit) > 0:
            out[j] = out[j][::-1].copy()
            notes.append("reversed a hole that ran with its exterior")
    dev = float(np.abs((out[0] - out[0][:-1].mean(axis=0)) @ unit).max())
    if dev > planarity_tol:
        notes.append(f"non-planar polygon ({dev:.3f} off its plane), kept")
    return out, notes


def _fan_volume(polys: list[Polygon]) -> float:
    """Signed volume enclosed by polygons (divergence theorem over fans of the exterior rings minus holes)."""
    if not polys:
        return 0.0
    origin = polys[0][0][0]
    vol = 0.0
    for poly in polys:
        for ring in poly:
            p = ring[:-1] - origin
            if len(p) < 3:
                continue
            a, b, c = p[0], p[1:-1], p[2:]
            vol += float(np.einsum("ij,ij->i", np.broadcast_to(a, b.shape), np.cross(b, c)).sum()) / 6.0
    return vol


def _open_edge_count(polys: list[Polygon], tol: float = 1e-3) -> int:
    """Number of undirected edges used once only: 0 for a closed (watertight) shell."""
    edges = []
    for poly in polys:
        for ring in poly:
            edges.append(np.stack([ring[:-1], ring[1:]], axis=1))
    if not edges:
        return 0
    e = np.round(np.concatenate(edges) / tol).astype(np.int64)  # (E, 2, 3), snapped to tol
    a, b = e[:, 0], e[:, 1]
    less = _lex_less(a, b)[:, None]
    keys = np.concatenate([np.where(less, a, b), np.where(less, b, a)], axis=1)
    _, counts = np.unique(keys, axis=0, return_counts=True)
    return int((counts == 1).sum())


def _lex_less(a: npt.NDArray[np.int64], b: npt.NDArray[np.int64]) -> npt.NDArray[np.bool_]:
    """Row-wise lexicographic a < b for (E, 3) integer arrays."""
    d = b - a
    first = np.argmax(d != 0, axis=1)
    return d[np.arange(len(d)), first] > 0


def orient_outward(polys: list[Polygon], semantics: list[str | None], *,
                   closed: bool = True) -> tuple[list[Polygon], list[str]]:
    """Orient an object's polygons outward.

    Roof surfaces must face up and ground surfaces down (their semantic class says so); a shell that is
    closed is flipped as a whole when its signed volume is negative. An open shell is reported, not
    repaired: its proxy is built from the footprint and height range, which do not need a closed shell.
    With ``closed=False`` (a MultiSurface that is not meant to bound a volume: roads, land use) only the
    semantic orientation is checked.
    """
    notes: list[str] = []
    polys = list(polys)
    for i, (poly, sem) in enumerate(zip(polys, semantics, strict=False)):
        if sem not in ("RoofSurface", "GroundSurface"):
            continue
        nz = _newell(poly[0])[2]
        if (sem == "RoofSurface" and nz < 0) or (sem == "GroundSurface" and nz > 0):
            polys[i] = [r[::-1].copy() for r in poly]
            notes.append(f"flipped an inverted {sem}")
    if not polys or not closed:
        return polys, notes
    open_edges = _open_edge_count(polys)
    if open_edges:
        notes.append(f"surfaces do not close a solid ({open_edges} open edges); proxy from footprint")
        return polys, notes
    if _fan_volume(polys) < 0:
        polys = [[r[::-1].copy() for r in poly] for poly in polys]
        notes.append("inverted solid (negative volume) reoriented outward")
    return polys, notes


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
        crs = parse_crs(_normalise_srs(srs[0]), str(p))
        if len(srs) > 1:
            warnings.append(f"{p.name}: several srsName values {srs}; used {srs[0]}")
    return CityModel(objects, crs, str(p), warnings, version)


def _normalise_srs(srs: str) -> str:
    """'urn:ogc:def:crs,crs:EPSG::28992,crs:EPSG::5109' style compound URNs and http forms to 'EPSG:n[+m]'."""
    codes = re.findall(r"EPSG(?:/\d+/|::?|/0/)(\d+)", srs, re.IGNORECASE)
    if len(codes) == 1:
        return f"EPSG:{codes[0]}"
    if len(codes) == 2:
        return f"EPSG:{codes[0]}+{codes[1]}"
    return srs


def read_city_model(path: str | PathLike[str], *, lod: int = 2) -> CityModel:
    """Read CityGML or CityJSON, told apart by suffix and first bytes (constant time)."""
    p = Path(path)
    if not p.is_file():
        raise InputError("no such file", p)
    with open(p, "rb") as fh:
        head = fh.read(256).lstrip(b"\xef\xbb\xbf \t\r\n")
    if p.suffix.lower() in (".json", ".cityjson") or head.startswith(b"{"):
        from citylod.io.cityjson import read_cityjson

        return read_cityjson(p, lod=lod)
    return read_citygml(p, lod=lod)


# --------------------------------------------------------------------------------------------------------
# Projection to metres

def _looks_like_gauss_krueger(xy: F64) -> int | None:
    """Zone (2..5) when positions are German Gauss-Krüger metres (easting with the zone as its first digit)."""
    x, y = xy[:, 0], xy[:, 1]
    zone = np.floor(x / 1e6)
    if zone.min() != zone.max() or not 2 <= zone[0] <= 5:
        return None
    inner = x - zone * 1e6
    if inner.min() < 200_000 or inner.max() > 800_000 or y.min() < 5_200_000 or y.max() > 6_150_000:
        return None
    return int(zone[0])


def to_metric(model: CityModel, crs: str | pyproj.CRS | None = None) -> CityModel:
    """The model in a metric CRS: unchanged if already metric, else projected to ``crs`` or its UTM zone.

    Geographic positions are read as longitude, latitude (the usual practice in CityGML and CityJSON files,
    whatever the EPSG axis order says); heights are kept. A file that declares a geographic CRS but holds
    positions far outside ±180/±90 is mislabelled: German Gauss-Krüger metres (the Karlsruhe sample) are
    recognised from their zone prefix and read as DHDN / 3-degree Gauss-Krüger, with a warning; anything
    else is a GeoreferenceError.

    Parameters
    ----------
    model
        As read.
    crs
        Target metric CRS; by default the source CRS if metric, else the UTM zone of the centroid.
    """
    pts = [r for o in model.objects for poly in o.surfaces for r in poly]
    if model.crs is None:
        if crs is None:
            return model
        return replace(model, crs=parse_crs(crs, model.source))
    if not pts:
        return model
    allxyz = np.concatenate(pts)
    src = model.crs
    warnings = list(model.warnings)
    target = None if crs is None else parse_crs(crs, model.source)
    if is_geographic(src):
        x, y = allxyz[:, 0], allxyz[:, 1]
        if np.abs(x).max() > 180 or np.abs(y).max() > 90:
            zone = _looks_like_gauss_krueger(allxyz[:, :2])
            if zone is None:
                raise GeoreferenceError(
                    f"the file declares {src.name} (degrees) but positions reach ({x.max():.1f}, {y.max():.1f}),"
                    " which are not degrees; fix the srsName", model.source)
            src = pyproj.CRS.from_epsg(31464 + zone)
            warnings.append(f"{Path(model.source).name}: declared {model.crs.name} but positions are Gauss-Krüger "
                            f"zone {zone} metres; read them as {src.name} (EPSG:{31464 + zone})")
    if target is None:
        if not is_geographic(model.crs):
            return replace(model, crs=src, warnings=warnings)
        # The UTM zone of the centroid keeps scale error below 0.04 % inside the zone.
        mid = np.median(allxyz[:, :2], axis=0)
        if is_geographic(src):
            lon, lat = float(mid[0]), float(mid[1])
        else:
            lon, lat = pyproj.Transformer.from_crs(horizontal_crs(src), "EPSG:4326", always_xy=True).transform(
                float(mid[0]), float(mid[1]))
        target = utm_crs_for(lon, lat)
    if is_geographic(target):
        raise GeoreferenceError(f"--crs must be metric, got {target.name}", model.source)
    tr = pyproj.Transformer.from_crs(horizontal_crs(src), horizontal_crs(target), always_xy=True)
    sizes = [len(r) for r in pts]
    nx, ny = tr.transform(allxyz[:, 0], allxyz[:, 1])
    out = np.column_stack([nx, ny, allxyz[:, 2]])
    if not np.isfinite(out).all():
        raise GeoreferenceError(f"positions cannot be projected from {src.name} to {target.name}", model.source)
    pieces = iter(np.split(out, np.cumsum(sizes)[:-1]))
    objects = []
    for o in model.objects:
        surfaces = [[next(pieces) for _ in poly] for poly in o.surfaces]
        objects.append(replace(o, surfaces=surfaces))
    return CityModel(objects, target, model.source, warnings, model.version)
