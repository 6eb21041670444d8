"""CityJSON 1.0 / 1.1 / 2.0 reader producing the common :class:`~citylod.io.city.model.CityModel`.

CityJSON keeps all vertices in one (optionally quantised) array; boundaries index into it. The reader
dequantises once (``transform``: scale, translate), then turns each geometry's nested index lists into
polygons of (K, 3) rings, repaired and oriented like CityGML's (same functions, same warnings).
A CityJSON file is one JSON document, so it is read whole; CityJSONSeq is not supported.

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
from citylod.io.crs import parse_crs

__all__ = ["read_cityjson"]


def _crs_of(meta: dict[str, Any], source: str) -> pyproj.CRS | None:
    """CRS from ``metadata.referenceSystem`` (1.0: URN, 1.1+/2.0: OGC http URI) or 1.0's ``crs.epsg``."""
    ref = meta.get("referenceSystem")
    if ref is None and isinstance(meta.get("crs"), dict):
        ref = meta["crs"].get("epsg")
    if ref is None:
        return None
    codes = re.findall(r"EPSG(?:/\d+/|::?|/0/)(\d+)", str(ref), re.IGNORECASE)
    if codes:
        return parse_crs(f"EPSG:{codes[-1]}", source)
    return parse_crs(int(ref) if str(ref).isdigit() else ref, source)


def _lod(geom: dict[str, Any]) -> int:
    try:
        return int(float(str(geom.get("lod", 0))))  # "1.2" (LoD refinement, 1.1+) counts as LoD 1
    except ValueError:
        return 0


def _surfaces(geom: dict[str, Any]) -> list[tuple[list[list[int]], Any]]:
    """(surface as ring index lists, semantic value) pairs of one geometry, whatever its type."""
    t = geom.get("type")
    b = geom.get("boundaries") or []
    vals = (geom.get("semantics") or {}).get("values")
    out: list[tuple[list[list[int]], Any]] = []
    if t in ("MultiSurface", "CompositeSurface"):
        for i, s in enumerate(b):
            out.append((s, vals[i] if isinstance(vals, list) and i < len(vals) else None))
    elif t == "Solid":
        for i, shell in enumerate(b):
            for j, s in enumerate(shell):
                v = vals[i][j] if isinstance(vals, list) and i < len(vals) and vals[i] is not None else None
                out.append((s, v))
    elif t in ("MultiSolid", "CompositeSolid"):
        for k, solid in enumerate(b):
            for i, shell in enumerate(solid):
                for j, s in enumerate(shell):
                    v = None
                    if isinstance(vals, list) and k < len(vals) and vals[k] is not None and vals[k][i] is not None:
                        v = vals[k][i][j]
                    out.append((s, v))
    return out


def read_cityjson(path: str | PathLike[str], *, lod: int = 2) -> CityModel:
    """Read a CityJSON 1.0, 1.1 or 2.0 file.

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
        Unreadable, not JSON, not CityJSON, or indices out of range; named with the file.
    """
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            doc = json.load(fh)
    except FileNotFoundError as exc:
        raise InputError("no such file", p) from exc
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"not valid JSON: {exc}", p) from exc
    if not isinstance(doc, dict) or doc.get("type") != "CityJSON":
        raise InputError("not a CityJSON document (no \"type\": \"CityJSON\")", p)
    version = str(doc.get("version", "?"))
    try:
        verts = np.asarray(doc.get("vertices", []), dtype=np.float64).reshape(-1, 3)
    except ValueError as exc:
        raise InputError(f"vertices are not (x, y, z) triples: {exc}", p) from exc
    tf = doc.get("transform")
    if tf:
        verts = verts * np.asarray(tf.get("scale", [1, 1, 1]), dtype=np.float64) + np.asarray(
            tf.get("translate", [0, 0, 0]), dtype=np.float64)
    crs = _crs_of(doc.get("metadata") or {}, str(p))
    templates = doc.get("geometry-templates") or {}
    tverts = np.asarray(templates.get("vertices-templates", []), dtype=np.float64).reshape(-1, 3)
    cos = doc.get("CityObjects") or {}
    if not cos:
        raise EmptyInputError("no CityObjects", p)
    parent_of: dict[str, str] = {}
    for oid, co in cos.items():
        for child in co.get("children", []) or []:
            parent_of[child] = oid
        for par in co.get("parents", []) or []:
            parent_of.setdefault(oid, par)
    warnings: list[str] = []
    objects: list[CityObject] = []
    nverts = len(verts)
    for oid, co in cos.items():
        geoms = co.get("geometry") or []
        avail = sorted({_lod(g) for g in geoms})
        lower = [v for v in avail if v <= lod]
        chosen = (max(lower) if lower else min(avail)) if avail else -1
        polys: list[Polygon] = []
        sems: list[str | None] = []
        notes: list[str] = []
        closed = False
        for g in geoms:
            if _lod(g) != chosen:
                continue
            closed = closed or g.get("type") in ("Solid", "MultiSolid", "CompositeSolid")
            if g.get("type") == "GeometryInstance":
                _instance(g, templates, tverts, verts, polys, sems, notes)
                continue
            table = (g.get("semantics") or {}).get("surfaces") or []
            for rings_idx, sval in _surfaces(g):
                try:
                    rings = [verts[np.asarray(r, dtype=np.int64)] for r in rings_idx if len(r)]
                except (IndexError, ValueError, TypeError):
                    notes.append(f"dropped a surface with vertex indices outside 0..{nverts - 1}")
                    continue
                if not rings:
                    continue
                poly, n = repair_polygon(rings, implicit_close=True)
                notes += n
                if poly is not None:
                    polys.append(poly)
                    sem = table[sval].get("type") if isinstance(sval, int) and 0 <= sval < len(table) else None
                    sems.append(sem)
        if polys:
            polys, n = orient_outward(polys, sems, closed=closed)
            notes += n
        for note in dict.fromkeys(notes):
            c = notes.count(note)
            warnings.append(f"{oid}: {note}" + (f" (x{c})" if c > 1 else ""))
        attrs = dict(co.get("attributes") or {})
        if co.get("address"):
            attrs["address"] = co["address"]
        objects.append(CityObject(oid, str(co.get("type", "CityObject")), attrs, polys,
                                  chosen if polys else -1, parent_of.get(oid), sems))
    return CityModel(objects, crs, str(p), warnings, f"CityJSON {version}")


def _instance(g: dict[str, Any], templates: dict[str, Any], tverts: np.ndarray, verts: np.ndarray,
              polys: list[Polygon], sems: list[str | None], notes: list[str]) -> None:
    """A GeometryInstance: template geometry, transformed by its 4×4 matrix and moved to its anchor vertex."""
    try:
        tpl = templates["templates"][g["template"]]
        m = np.asarray(g.get("transformationMatrix", np.eye(4).ravel()), dtype=np.float64).reshape(4, 4)
        anchor = verts[int(g["boundaries"][0])]
    except (KeyError, IndexError, TypeError, ValueError):
        notes.append("dropped a GeometryInstance with a bad template reference")
        return
    local = tverts @ m[:3, :3].T + m[:3, 3] + anchor
    for rings_idx, _ in _surfaces(tpl):
        try:
            rings = [local[np.asarray(r, dtype=np.int64)] for r in rings_idx if len(r)]
        except IndexError:
            notes.append("dropped a template surface with bad indices")
            continue
        poly, n = repair_polygon(rings, implicit_close=True) if rings else (None, [])
        notes += n
        if poly is not None:
            polys.append(poly)
            sems.append(None)
