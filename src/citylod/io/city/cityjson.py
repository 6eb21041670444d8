"""CityJSON 1.0 / 1.1 / 2.0 reader producing the common :class:`~citylod.io.city.model.CityModel`.

CityJSON keeps all vertices in one (optionally quantised) array; boundaries index into it. The reader
dequantises once (``transform``: scale, translate), then turns each geometry's nested index lists into
polygons of (K, 3) rings, repaired and oriented like CityGML's (same functions, same warnings).
A CityJSON file is one JSON document, so it is read whole; a CityJSONSeq stream (``.city.jsonl``) is read
one feature (line) at a time. Every structural violation of the schema is one InputError naming the file
and the object; nothing in a file can make the reader index outside its arrays.

No VTK, no Qt, no proxies here.
"""

from __future__ import annotations

import json
import re
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

from citylod.core.errors import EmptyInputError, InputError
from citylod.io.city.model import CityModel, CityObject, Polygon, orient_outward, repair_polygon
from citylod.io.crs import crs_from_srs_name

__all__ = ["read_cityjson", "read_cityjsonseq"]


def _crs_of(meta: dict[str, Any], source: str) -> pyproj.CRS | None:
    """CRS from ``metadata.referenceSystem`` (1.0: URN, 1.1+/2.0: OGC http URI) or 1.0's ``crs.epsg``."""
    ref = meta.get("referenceSystem")
    if ref is None and isinstance(meta.get("crs"), dict):
        ref = meta["crs"].get("epsg")
    if ref is None:
        return None
    if (type(ref) is int and ref > 0) or re.fullmatch(r"[0-9]{1,6}", str(ref)):
        return crs_from_srs_name(f"EPSG:{ref}", source)
    return crs_from_srs_name(ref, source)


class _Bad(Exception):
    """A structural violation of the CityJSON schema, turned into one InputError naming the file."""


def _lod(geom: dict[str, Any]) -> int:
    """LoD of a geometry: a number (1.0) or a numeric string ("1.2", 1.1+); the refinement counts as its LoD."""
    raw = geom.get("lod", 0)
    if isinstance(raw, bool) or not isinstance(raw, (int, float, str)):
        raise _Bad(f"lod {raw!r} is not a level of detail")
    try:
        value = float(raw)
    except ValueError:
        raise _Bad(f"lod {raw!r} is not a level of detail") from None
    if not 0 <= value < 5:
        raise _Bad(f"lod {raw!r} is outside 0..4")
    return int(value)


def _pick(vals: Any, *index: int) -> Any:
    """``vals[i][j]...`` of a semantics ``values`` array, None where the nesting does not reach."""
    for i in index:
        if not isinstance(vals, list) or i >= len(vals):
            return None
        vals = vals[i]
    return vals


def _surfaces(geom: dict[str, Any]) -> list[tuple[list[Any], Any]]:
    """(surface as ring index lists, semantic value) pairs of one geometry, whatever its type."""
    t = geom.get("type")
    b = geom.get("boundaries")
    if b is None:
        b = []
    if not isinstance(b, list):
        raise _Bad(f"{t} boundaries are not an array")
    vals = geom.get("semantics", {}).get("values") if isinstance(geom.get("semantics"), dict) else None
    depth = {"MultiSurface": 1, "CompositeSurface": 1, "Solid": 2, "MultiSolid": 3, "CompositeSolid": 3}.get(
        str(t), 0)
    out: list[tuple[list[Any], Any]] = []
    if depth == 0:  # points and lines have no surfaces
        return out
    # Boundaries nest surfaces in shells in solids; walk as deep as the type says, checking each level.
    level: list[tuple[Any, tuple[int, ...]]] = [(b, ())]
    for _ in range(depth - 1):
        nxt: list[tuple[Any, tuple[int, ...]]] = []
        for node, idx in level:
            if not isinstance(node, list):
                raise _Bad(f"{t} boundaries are not nested {depth + 2} deep")
            nxt.extend((child, (*idx, k)) for k, child in enumerate(node))
        level = nxt
    for node, idx in level:
        if not isinstance(node, list):
            raise _Bad(f"{t} boundaries are not nested {depth + 2} deep")
        for j, surface in enumerate(node):
            if not isinstance(surface, list):
                raise _Bad(f"{t} surface is not an array of rings")
            out.append((surface, _pick(vals, *idx, j)))
    return out


def _ring(indices: Any, verts: np.ndarray) -> np.ndarray | None:
    """Vertices of one ring; None when an index is outside the vertex list (a defect, reported by the caller)."""
    if not isinstance(indices, list):
        raise _Bad("a ring is not an array of vertex indices")
    try:
        idx = np.asarray(indices)
    except (ValueError, TypeError):
        raise _Bad("a ring is not a flat array of vertex indices") from None
    if idx.ndim != 1 or (idx.size and idx.dtype.kind not in "iu"):
        raise _Bad(f"vertex indices must be integers, got {indices[:4]!r}")
    # Negative indices are not CityJSON (numpy would silently read them from the end of the list); an index
    # past the end is a defect of the vertex list, left to the caller to report.
    if idx.size and int(idx.min()) < 0:
        raise _Bad(f"negative vertex index {int(idx.min())}")
    if idx.size and int(idx.max()) >= len(verts):
        return None
    return verts[idx.astype(np.int64)]


def _vector3(value: Any, what: str) -> np.ndarray:
    if not isinstance(value, list) or len(value) != 3 or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
        raise _Bad(f"{what} is not three numbers: {str(value)[:60]}")
    arr = np.asarray(value, dtype=np.float64)
    if not np.isfinite(arr).all():
        raise _Bad(f"{what} is not finite: {value}")
    return arr


def _vertices(raw: Any, transform: Any, what: str = "vertices") -> np.ndarray:
    """(N, 3) float64 positions, dequantised with ``transform`` (scale, translate) when there is one."""
    if raw is None:
        raw = []
    if not isinstance(raw, list):
        raise _Bad(f"{what} is not an array")
    try:
        verts = np.asarray(raw, dtype=np.float64)
    except (ValueError, TypeError, OverflowError):
        raise _Bad(f"{what} are not (x, y, z) number triples") from None
    if verts.size and (verts.ndim != 2 or verts.shape[1] != 3):
        raise _Bad(f"{what} are not (x, y, z) triples (shape {verts.shape})")
    verts = verts.reshape(-1, 3)
    if transform:
        if not isinstance(transform, dict):
            raise _Bad("transform is not an object")
        verts = verts * _vector3(transform.get("scale", [1, 1, 1]), "transform.scale") + _vector3(
            transform.get("translate", [0, 0, 0]), "transform.translate")
    return verts


def _load_json(p: Path, text: bytes | None = None) -> Any:
    """One JSON document; InputError for bad syntax, numbers of thousands of digits or absurd nesting."""
    try:
        if text is None:
            with open(p, "rb") as fh:
                text = fh.read()
        return json.loads(text)
    except FileNotFoundError as exc:
        raise InputError("no such file", p) from exc
    except RecursionError as exc:
        raise InputError("not readable JSON: nested too deeply", p) from exc
    except (ValueError, UnicodeDecodeError) as exc:  # JSONDecodeError, and int() of a 5000-digit number
        raise InputError(f"not valid JSON: {str(exc)[:200]}", p) from exc


def read_cityjson(path: str | PathLike[str], *, lod: int = 2) -> CityModel:
    """Read a CityJSON 1.0, 1.1 or 2.0 file (or a CityJSONSeq stream, see :func:`read_cityjsonseq`).

    Parameters
    ----------
    path
        The ``.json`` / ``.city.json`` file.
    lod
        Preferred level of detail: each object keeps its geometry with the highest LoD not above ``lod``,
        else its lowest.

    Returns
    -------
    CityModel
        Objects in the source CRS (project with :func:`citylod.io.city.model.to_metric`).

    Raises
    ------
    InputError
        Unreadable, not JSON, not CityJSON, or not shaped as the CityJSON schema says (the message names the
        object). A vertex index outside the vertex list is a defect: the surface is dropped with a warning.
    """
    p = Path(path)
    try:
        doc = _load_json(p)
    except InputError as exc:
        if "Extra data" in str(exc):  # several JSON documents, one per line: CityJSONSeq
            return read_cityjsonseq(p, lod=lod)
        raise
    if not isinstance(doc, dict) or doc.get("type") != "CityJSON":
        raise InputError("not a CityJSON document (no \"type\": \"CityJSON\")", p)
    version = str(doc.get("version", "?"))[:20]
    try:
        verts = _vertices(doc.get("vertices"), doc.get("transform"))
        crs = _crs_of(doc.get("metadata") or {}, str(p)) if isinstance(doc.get("metadata") or {}, dict) else None
        templates = _templates(doc)
        cos = doc.get("CityObjects")
        if not isinstance(cos, dict):
            raise _Bad("CityObjects is not an object (id -> city object)")
        if not cos:
            raise EmptyInputError("no CityObjects", p)
        warnings: list[str] = []
        objects = _objects(cos, verts, templates, lod, warnings)
    except _Bad as exc:
        raise InputError(f"not valid CityJSON: {exc}", p) from exc
    return CityModel(objects, crs, str(p), warnings, f"CityJSON {version}")


def read_cityjsonseq(path: str | PathLike[str], *, lod: int = 2) -> CityModel:
    """Read a CityJSONSeq stream (``.city.jsonl``): a CityJSON header line, then one CityJSONFeature a line.

    Each feature has its own vertex list, quantised with the header's ``transform``; features are read one
    line at a time, so memory holds one feature's JSON besides the model.

    Raises
    ------
    InputError
        As :func:`read_cityjson`, with the line number of the bad line.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError("no such file", p)
    objects: list[CityObject] = []
    warnings: list[str] = []
    header: dict[str, Any] | None = None
    crs = None
    templates: tuple[dict[str, Any], np.ndarray] = ({}, np.zeros((0, 3)))
    with open(p, "rb") as fh:
        for lineno, line in enumerate(fh, 1):
            if not line.strip():
                continue
            doc = _load_json(p, line)
            try:
                if header is None:
                    if not isinstance(doc, dict) or doc.get("type") != "CityJSON":
                        raise _Bad("the first line is not a CityJSON header (\"type\": \"CityJSON\")")
                    header = doc
                    if isinstance(doc.get("metadata") or {}, dict):
                        crs = _crs_of(doc.get("metadata") or {}, str(p))
                    templates = _templates(doc)
                    cos = doc.get("CityObjects") or {}
                    if not isinstance(cos, dict):
                        raise _Bad("CityObjects is not an object (id -> city object)")
                    if cos:  # a header may carry objects too (1.1 allows it), with its own vertices
                        objects += _objects(cos, _vertices(doc.get("vertices"), doc.get("transform")), templates,
                                            lod, warnings)
                    continue
                if not isinstance(doc, dict) or doc.get("type") != "CityJSONFeature":
                    raise _Bad("not a CityJSONFeature")
                cos = doc.get("CityObjects")
                if not isinstance(cos, dict):
                    raise _Bad("CityObjects is not an object (id -> city object)")
                verts = _vertices(doc.get("vertices"), header.get("transform"))
                objects += _objects(cos, verts, templates, lod, warnings)
            except _Bad as exc:
                raise InputError(f"line {lineno}: not valid CityJSONSeq: {exc}", p) from exc
    if header is None:
        raise EmptyInputError("no CityJSON header line", p)
    if not objects:
        raise EmptyInputError("no CityObjects", p)
    return CityModel(objects, crs, str(p), warnings, f"CityJSONSeq {str(header.get('version', '?'))[:20]}")


def _templates(doc: dict[str, Any]) -> tuple[dict[str, Any], np.ndarray]:
    templates = doc.get("geometry-templates") or {}
    if not isinstance(templates, dict):
        raise _Bad("geometry-templates is not an object")
    return templates, _vertices(templates.get("vertices-templates"), None, "vertices-templates")


def _objects(cos: dict[str, Any], verts: np.ndarray, templates: tuple[dict[str, Any], np.ndarray], lod: int,
             warnings: list[str]) -> list[CityObject]:
    """The city objects of one CityObjects table (a file's, or one CityJSONFeature's) over its vertices."""
    parent_of: dict[str, str] = {}
    for oid, co in cos.items():
        if not isinstance(co, dict):
            raise _Bad(f"city object {oid!r} is not an object")
        for key in ("children", "parents"):
            refs = co.get(key) or []
            if not isinstance(refs, list) or not all(isinstance(r, str) for r in refs):
                raise _Bad(f"{oid}: {key} is not an array of ids")
        for child in co.get("children") or []:
            parent_of[child] = oid
        for par in co.get("parents") or []:
            parent_of.setdefault(oid, par)
    objects: list[CityObject] = []
    nverts = len(verts)
    for oid, co in cos.items():
        geoms = co.get("geometry") or []
        if not isinstance(geoms, list) or not all(isinstance(g, dict) for g in geoms):
            raise _Bad(f"{oid}: geometry is not an array of geometry objects")
        try:
            lods = [_lod(g) for g in geoms]
        except _Bad as exc:
            raise _Bad(f"{oid}: {exc}") from None
        avail = sorted(set(lods))
        lower = [v for v in avail if v <= lod]
        chosen = (max(lower) if lower else min(avail)) if avail else -1
        polys: list[Polygon] = []
        sems: list[str | None] = []
        notes: list[str] = []
        closed = False
        for g, g_lod in zip(geoms, lods, strict=True):
            if g_lod != chosen:
                continue
            closed = closed or g.get("type") in ("Solid", "MultiSolid", "CompositeSolid")
            if g.get("type") == "GeometryInstance":
                _instance(g, templates, verts, polys, sems, notes)
                continue
            sem_doc = g.get("semantics")
            table = sem_doc.get("surfaces") if isinstance(sem_doc, dict) else None
            table = table if isinstance(table, list) else []
            try:
                surfaces = _surfaces(g)
            except _Bad as exc:
                raise _Bad(f"{oid}: {exc}") from None
            for rings_idx, sval in surfaces:
                try:
                    rings = [_ring(r, verts) for r in rings_idx if not isinstance(r, list) or len(r)]
                except _Bad as exc:
                    raise _Bad(f"{oid}: {exc}") from None
                if any(r is None for r in rings):
                    notes.append(f"dropped a surface with vertex indices outside 0..{nverts - 1}")
                    continue
                if not rings:
                    continue
                poly, n = repair_polygon([r for r in rings if r is not None], implicit_close=True)
                notes += n
                if poly is not None:
                    polys.append(poly)
                    entry = table[sval] if type(sval) is int and 0 <= sval < len(table) else None
                    sem = entry.get("type") if isinstance(entry, dict) else None
                    sems.append(sem if isinstance(sem, str) else None)
        if polys:
            polys, n = orient_outward(polys, sems, closed=closed)
            notes += n
        for note in dict.fromkeys(notes):
            c = notes.count(note)
            warnings.append(f"{oid}: {note}" + (f" (x{c})" if c > 1 else ""))
        attrs = co.get("attributes") or {}
        if not isinstance(attrs, dict):
            raise _Bad(f"{oid}: attributes is not an object")
        attrs = dict(attrs)
        if co.get("address"):
            attrs["address"] = co["address"]
        objects.append(CityObject(str(oid), str(co.get("type", "CityObject"))[:100], attrs, polys,
                                  chosen if polys else -1, parent_of.get(oid), sems))
    return objects


def _instance(g: dict[str, Any], templates: tuple[dict[str, Any], np.ndarray], verts: np.ndarray,
              polys: list[Polygon], sems: list[str | None], notes: list[str]) -> None:
    """A GeometryInstance: template geometry, transformed by its 4×4 matrix and moved to its anchor vertex."""
    table, tverts = templates
    try:
        tpls = table["templates"]
        ti = g["template"]
        ai = g["boundaries"][0]
        if type(ti) is not int or type(ai) is not int or not 0 <= ti < len(tpls) or not 0 <= ai < len(verts):
            raise IndexError(ti)
        tpl = tpls[ti]
        m = np.asarray(g.get("transformationMatrix", np.eye(4).ravel()), dtype=np.float64).reshape(4, 4)
        anchor = verts[ai]
        if not isinstance(tpl, dict) or not np.isfinite(m).all():
            raise ValueError(tpl)
    except (KeyError, IndexError, TypeError, ValueError):
        notes.append("dropped a GeometryInstance with a bad template reference")
        return
    local = tverts @ m[:3, :3].T + m[:3, 3] + anchor
    for rings_idx, _ in _surfaces(tpl):
        rings = [_ring(r, local) for r in rings_idx if not isinstance(r, list) or len(r)]
        if any(r is None for r in rings):
            notes.append("dropped a template surface with bad indices")
            continue
        poly, n = repair_polygon([r for r in rings if r is not None], implicit_close=True) if rings else (None, [])
        notes += n
        if poly is not None:
            polys.append(poly)
            sems.append(None)
