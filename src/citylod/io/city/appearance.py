"""Appearances of city models: CityGML 2.0/3.0 ``ParameterizedTexture`` and ``X3DMaterial``, CityJSON
``appearance`` (textures, materials), and the per-feature ``appearance`` of CityJSONSeq streams.

The readers of :mod:`citylod.io.city` produce polygons without their ids, so appearances are tied to the
model's polygons by geometry: a polygon's key is the set of its exterior ring's vertices rounded to a
millimetre (robust to the reader's repairs: a reversed ring, a dropped duplicate vertex, another start
vertex), and texture coordinates are looked up per vertex by the same rounding. Two different polygons of a
model do not share all exterior vertices, so the key is unique where it matters.

Images are referenced, not decoded, here: :func:`check_image` says whether one may be used (inside the
model's folder, present, readable, of a sane declared size) and otherwise gives the warning that names it;
the surface then falls back to its material (or to the default colours).

No LOD logic, no VTK, no Qt.
"""

from __future__ import annotations

import json
import os
import urllib.parse
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from lxml import etree

from citylod.core.errors import InputError
from citylod.io.xmlsafe import check_xml_prolog

__all__ = ["Appearances", "SurfaceAppearance", "check_image", "read_appearances", "ring_key"]

F64 = npt.NDArray[np.float64]

#: Largest image, in declared pixels, that a surface may use (64 Mpx: a 8192² texture).
MAX_IMAGE_PIXELS = 8192 * 8192
_ROUND = 1e-3


def _keys(points: F64) -> list[tuple[int, int, int]]:
    q = np.round(np.asarray(points, np.float64)[:, :3] / _ROUND).astype(np.int64)
    return [tuple(r) for r in q.tolist()]


def ring_key(ring: F64) -> bytes:
    """The key of a polygon by its exterior ring (K, 3): sorted distinct vertices rounded to 1 mm."""
    q = np.unique(np.round(np.asarray(ring, np.float64)[:, :3] / _ROUND).astype(np.int64), axis=0)
    return q.tobytes()


@dataclass(frozen=True)
class SurfaceAppearance:
    """What one polygon looks like: ``image`` (a file inside the model's folder, or None), the texture
    coordinate of each of its vertices (``uv``, keyed by the vertex rounded to 1 mm; (u, v) with v up, as
    CityGML and CityJSON give them), and the material's diffuse ``rgb`` in 0..1 (or None)."""

    image: Path | None = None
    uv: dict[tuple[int, int, int], tuple[float, float]] = field(default_factory=dict)
    rgb: tuple[float, float, float] | None = None

    def uv_of(self, vertices: F64) -> npt.NDArray[np.float64] | None:
        """(K, 2) texture coordinates of ``vertices`` (K, 3), None when one of them has none."""
        try:
            return np.array([self.uv[k] for k in _keys(vertices)], np.float64).reshape(-1, 2)
        except KeyError:
            return None


@dataclass
class Appearances:
    """The appearances of one model by polygon key (see :func:`ring_key`), and what was wrong with them."""

    surfaces: dict[bytes, SurfaceAppearance] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    def lookup(self, exterior: F64) -> SurfaceAppearance | None:
        return self.surfaces.get(ring_key(exterior))

    @property
    def images(self) -> set[Path]:
        return {s.image for s in self.surfaces.values() if s.image is not None}


def check_image(uri: str, model_dir: Path, *, max_pixels: int = MAX_IMAGE_PIXELS) -> tuple[Path | None, str | None]:
    """Resolve an image URI of a model and check that it may be used: ``(path, None)`` or ``(None, warning)``.

    Refused, each with a warning naming the image: URLs and paths leaving the model's folder (a model must
    not make citylod read files elsewhere), missing files, files OpenImageIO cannot open, and images whose
    header declares more than ``max_pixels`` pixels (checked before any pixel is decoded).
    """
    parsed = urllib.parse.urlsplit(uri)
    if (parsed.scheme and len(parsed.scheme) > 1) or parsed.netloc:
        return None, f"texture {uri!r} is a URL; only files in the model's folder are read"
    rel = urllib.parse.unquote(parsed.path if parsed.scheme else uri).replace("\\", "/")
    root = model_dir.resolve()
    path = (root / rel).resolve()
    if not path.is_relative_to(root):
        return None, f"texture {uri!r} lies outside the model's folder {root}; surface drawn with its material"
    if not path.is_file():
        return None, f"texture {uri!r} is missing; surface drawn with its material"
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        why = oiio.geterror().strip().splitlines()
        detail = f" ({why[0]})" if why else ""
        return None, f"texture {uri!r} cannot be read as an image{detail}; surface drawn with its material"
    try:
        spec = inp.spec()
        w, h = int(spec.width), int(spec.height)
    finally:
        inp.close()
    if w <= 0 or h <= 0 or w * h > max_pixels:
        return None, (f"texture {uri!r} declares {w}×{h} pixels (more than {max_pixels:,}); "
                      "surface drawn with its material")
    return path, None


def read_appearances(path: str | os.PathLike[str]) -> Appearances:
    """The appearances of a CityGML or CityJSON file (told apart as :func:`read_city_model` does)."""
    p = Path(path)
    if p.suffix.lower() == ".jsonl":
        return _cityjsonseq(p)
    with open(p, "rb") as fh:
        head = fh.read(256).lstrip(b"\xef\xbb\xbf \t\r\n")
    if p.suffix.lower() in (".json", ".cityjson") or head.startswith(b"{"):
        return _cityjson(p)
    return _citygml(p)


# ------------------------------------------------------------------------------------------------ CityGML
def _local(tag: Any) -> str:
    return etree.QName(tag).localname if isinstance(tag, str) else ""


def _gml_id(el: etree._Element) -> str | None:
    for k, v in el.attrib.items():
        if _local(k) == "id":
            return str(v)
    return None


def _numbers(text: str | None) -> F64:
    try:
        return np.array((text or "").split(), np.float64)
    except ValueError:
        return np.zeros(0)


def _ring_coords(lr: etree._Element) -> F64:
    for child in lr:
        if _local(child.tag) == "posList":
            dim = int(child.get("srsDimension", "3") or 3)
            v = _numbers(child.text)
            return v[: len(v) // dim * dim].reshape(-1, dim)[:, :3] if dim >= 3 else np.zeros((0, 3))
    pts = [_numbers(c.text) for c in lr if _local(c.tag) in ("pos", "coordinates")]
    pts = [q for q in pts if len(q) >= 3]
    return np.array([q[:3] for q in pts]) if pts else np.zeros((0, 3))


def _citygml(path: Path) -> Appearances:
    rings: dict[str, F64] = {}  # ring id -> coordinates
    exterior: dict[str, F64] = {}  # polygon id -> exterior ring coordinates
    textures: list[tuple[str, dict[str, F64]]] = []  # (image uri, ring id -> uv list)
    ring_owner: dict[str, str] = {}  # ring id -> polygon id
    materials: list[tuple[tuple[float, float, float], list[str]]] = []
    check_xml_prolog(path)
    try:
        for _, el in etree.iterparse(str(path), events=("end",), resolve_entities=False, no_network=True,
                                     huge_tree=False, remove_comments=True):
            name = _local(el.tag)
            if name == "LinearRing":
                rid = _gml_id(el)
                if rid:
                    rings[rid] = _ring_coords(el)
            elif name == "Polygon":
                pid = _gml_id(el)
                if pid:
                    for child in el:
                        for lr in child:
                            if _local(lr.tag) != "LinearRing":
                                continue
                            rid = _gml_id(lr)
                            if rid:
                                ring_owner[rid] = pid
                            if _local(child.tag) == "exterior":
                                exterior[pid] = rings[rid] if rid in rings else _ring_coords(lr)
            elif name == "ParameterizedTexture":
                uri = ""
                coords: dict[str, F64] = {}
                for child in el:
                    if _local(child.tag) == "imageURI":
                        uri = (child.text or "").strip()
                    elif _local(child.tag) == "target":
                        for tc in child.iter():
                            if _local(tc.tag) == "textureCoordinates":
                                ring = (tc.get("ring") or "").lstrip("#")
                                uv = _numbers(tc.text)
                                coords[ring] = uv[: len(uv) // 2 * 2].reshape(-1, 2)
                textures.append((uri, coords))
            elif name == "X3DMaterial":
                rgb = (0.8, 0.8, 0.8)
                targets = []
                for child in el:
                    if _local(child.tag) == "diffuseColor":
                        c = _numbers(child.text)
                        if len(c) >= 3 and np.all(np.isfinite(c[:3])):
                            rgb = tuple(float(x) for x in np.clip(c[:3], 0, 1))  # type: ignore[assignment]
                    elif _local(child.tag) == "target":
                        targets.append((child.text or child.get("uri") or "").strip().lstrip("#"))
                materials.append((rgb, targets))  # type: ignore[arg-type]
    except etree.XMLSyntaxError as exc:
        raise InputError(f"XML is malformed ({exc})", path) from exc
    out = Appearances()
    material_of: dict[str, tuple[float, float, float]] = {}
    for rgb, targets in materials:
        for t in targets:
            material_of[t] = rgb
    checked: dict[str, tuple[Path | None, str | None]] = {}
    textured: dict[str, tuple[Path | None, dict[tuple[int, int, int], tuple[float, float]]]] = {}
    for uri, coords in textures:
        if uri not in checked:
            checked[uri] = check_image(uri, path.parent)
            if checked[uri][1]:
                out.warnings.append(f"{path.name}: {checked[uri][1]}")
        image = checked[uri][0]
        for rid, uv in coords.items():
            xyz = rings.get(rid)
            pid = ring_owner.get(rid)
            if xyz is None or pid is None or len(xyz) != len(uv):
                continue
            entry = textured.setdefault(pid, (image, {}))
            entry[1].update(zip(_keys(xyz), map(tuple, uv.tolist()), strict=True))
    for pid in set(textured) | set(material_of):
        ext = exterior.get(pid)
        if ext is None or len(ext) < 3:
            continue
        image, uv_of = textured.get(pid, (None, {}))
        out.surfaces[ring_key(ext)] = SurfaceAppearance(image if uv_of else None, uv_of, material_of.get(pid))
    return out


# ------------------------------------------------------------------------------------------------ CityJSON
def _cityjson(path: Path) -> Appearances:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read CityJSON ({exc})", path) from exc
    out = Appearances()
    app = doc.get("appearance") or {}
    if not isinstance(app, dict) or not isinstance(doc.get("CityObjects"), dict):
        return out
    _cityjson_objects(doc["CityObjects"], doc.get("vertices", []), doc.get("transform"), app, path, out, {})
    return out


def _cityjson_objects(objects: dict[str, Any], vertices: Any, transform: Any, app: dict[str, Any], path: Path,
                      out: Appearances, checked: dict[str, Path | None]) -> None:
    """The appearances of ``objects`` (a CityJSON ``CityObjects`` member) with their ``vertices``, quantised
    by ``transform``, and the ``appearance`` their texture and material indices point into. ``checked``
    remembers the images already resolved, so an image shared by many features is checked (and warned
    about) once."""
    verts = np.asarray(vertices, np.float64).reshape(-1, 3)
    if isinstance(transform, dict):
        verts = verts * np.asarray(transform.get("scale", [1, 1, 1]), float) + np.asarray(
            transform.get("translate", [0, 0, 0]), float)
    tex_uv = np.asarray(app.get("vertices-texture", []), np.float64).reshape(-1, 2)
    images: list[Path | None] = []
    for t in app.get("textures", []) or []:
        uri = str(t.get("image", "")) if isinstance(t, dict) else ""
        if uri not in checked:
            image, warn = check_image(uri, path.parent) if uri else (None, None)
            if warn:
                out.warnings.append(f"{path.name}: {warn}")
            checked[uri] = image
        images.append(checked[uri])
    mats = []
    for m in app.get("materials", []) or []:
        c = m.get("diffuseColor") if isinstance(m, dict) else None
        mats.append(tuple(float(x) for x in c[:3]) if isinstance(c, list) and len(c) >= 3 else None)
    for obj in objects.values():
        if isinstance(obj, dict):
            for geom in obj.get("geometry", []) or []:
                if isinstance(geom, dict):
                    _cityjson_geometry(geom, verts, tex_uv, images, mats, out)


def _cityjsonseq(path: Path) -> Appearances:
    """CityJSONSeq (CityJSON 2.0 §"CityJSON Text Sequences"): each CityJSONFeature carries its own vertices
    and its own ``appearance`` (textures, materials, texture vertices), its indices local to the feature;
    a feature without one uses the header's. Read a line at a time, as the geometry reader does."""
    out = Appearances()
    header: dict[str, Any] | None = None
    checked: dict[str, Path | None] = {}
    try:
        with open(path, "rb") as fh:
            for line in fh:
                if not line.strip():
                    continue
                doc = json.loads(line)
                if not isinstance(doc, dict):
                    continue
                if header is None:
                    header = doc
                    if isinstance(doc.get("CityObjects"), dict) and isinstance(doc.get("appearance"), dict):
                        _cityjson_objects(doc["CityObjects"], doc.get("vertices", []), doc.get("transform"),
                                          doc["appearance"], path, out, checked)
                    continue
                app = doc.get("appearance")
                app = app if isinstance(app, dict) else header.get("appearance")
                if isinstance(app, dict) and isinstance(doc.get("CityObjects"), dict):
                    _cityjson_objects(doc["CityObjects"], doc.get("vertices", []), header.get("transform"), app,
                                      path, out, checked)
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise InputError(f"cannot read CityJSONSeq ({str(exc)[:200]})", path) from exc
    return out


def _surfaces_of(boundaries: Any, values: Any, gtype: str) -> list[tuple[Any, Any]]:
    """(surface boundary, its texture/material value) pairs, flattening solids and composite solids."""
    if gtype in ("MultiSurface", "CompositeSurface"):
        return list(zip(boundaries, values if isinstance(values, list) else [values] * len(boundaries),
                        strict=False))
    if gtype == "Solid":
        out = []
        for shell, vals in zip(boundaries, values if isinstance(values, list) else [values] * len(boundaries),
                               strict=False):
            out += _surfaces_of(shell, vals, "MultiSurface")
        return out
    if gtype in ("MultiSolid", "CompositeSolid"):
        out = []
        for solid, vals in zip(boundaries, values if isinstance(values, list) else [values] * len(boundaries),
                               strict=False):
            out += _surfaces_of(solid, vals, "Solid")
        return out
    return []


def _cityjson_geometry(geom: dict[str, Any], verts: F64, tex_uv: F64, images: list[Path | None],
                       mats: list[Any], out: Appearances) -> None:
    gtype = str(geom.get("type", ""))
    bounds = geom.get("boundaries", [])
    tex_theme = next(iter((geom.get("texture") or {}).values()), None)
    mat_theme = next(iter((geom.get("material") or {}).values()), None)
    tex_vals = tex_theme.get("values") if isinstance(tex_theme, dict) else None
    if isinstance(mat_theme, dict):
        mat_vals = mat_theme.get("values", mat_theme.get("value"))
    else:
        mat_vals = None
    try:
        tex_pairs = _surfaces_of(bounds, tex_vals, gtype) if tex_vals is not None else []
        mat_pairs = _surfaces_of(bounds, mat_vals, gtype) if mat_vals is not None else []
        rgb_of: dict[bytes, Any] = {}
        for surface, m in mat_pairs:
            if isinstance(m, int) and 0 <= m < len(mats) and surface:
                rgb_of[ring_key(verts[np.asarray(surface[0], int)])] = mats[m]
        done = set()
        for surface, t in tex_pairs:
            if not surface or not isinstance(t, list) or not t or not isinstance(t[0], list):
                continue
            ext_idx = np.asarray(surface[0], int)
            key = ring_key(verts[ext_idx])
            uv: dict[tuple[int, int, int], tuple[float, float]] = {}
            image = None
            for ring, tv in zip(surface, t, strict=False):
                if not isinstance(tv, list) or len(tv) != len(ring) + 1 or tv[0] is None:
                    continue
                image = images[tv[0]] if 0 <= tv[0] < len(images) else None
                uv.update(zip(_keys(verts[np.asarray(ring, int)]), map(tuple, tex_uv[np.asarray(tv[1:], int)].tolist()),
                              strict=True))
            out.surfaces[key] = SurfaceAppearance(image if uv else None, uv, rgb_of.get(key))
            done.add(key)
        for key, rgb in rgb_of.items():
            if key not in done:
                out.surfaces[key] = SurfaceAppearance(None, {}, rgb)
    except (IndexError, TypeError, ValueError):
        out.warnings.append("an appearance of a CityJSON geometry is malformed; surfaces drawn with default colours")
