"""The polygon layer: 2D polygons with an action each, saved and loaded as GeoJSON, KML or GeoPackage.

Polygons serve two users: the flood analysis (a river or sea polygon is a water source) and the run-time
edits of the renderer (Kehl, Tutenel, Eisemann: recolour, discard, texture or displace what lies inside).
The layer is a plain value (:class:`PolygonLayer` of :class:`EditPolygon`); readers check every polygon
(empty and self-intersecting polygons are refused with the file and the polygon named) and refuse KML whose
DOCTYPE declares entities. Writers go through :mod:`citylod.core.fileio` (temporary name, then rename).
No VTK, no Qt.
"""

from __future__ import annotations

import json
import os
import sqlite3
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import pyproj
import shapely
from shapely.geometry.base import BaseGeometry
from shapely.validation import explain_validity

from citylod.core.errors import InputError
from citylod.core.fileio import atomic_write, atomic_write_text
from citylod.io.gpkg import (
    add_feature_table,
    decode_geometry,
    encode_geometry,
    fill_rtree,
    init_geopackage,
    register_srs,
)
from citylod.io.xmlsafe import check_xml_prolog

__all__ = ["ACTIONS", "EditPolygon", "PolygonLayer", "load_polygons", "save_polygons"]

#: What a polygon does: ``source`` (water enters here), ``recolor``, ``discard`` (cut away), ``texture``
#: (drape an image), ``displace`` (raise or lower by ``height_m``, or by a displacement map ``texture``).
ACTIONS = ("source", "recolor", "discard", "texture", "displace")
_KML_NS = "http://www.opengis.net/kml/2.2"
_WGS84 = pyproj.CRS.from_epsg(4326)
_TABLE = "edit_polygons"


@dataclass(frozen=True)
class EditPolygon:
    """One polygon of the layer and its action.

    ``geometry`` is a shapely Polygon or MultiPolygon in the layer's CRS; ``color`` an RGB triple in 0..255
    (recolour); ``height_m`` the displacement in metres (displace); ``texture`` an image path (texture, or a
    displacement map for displace: grey 0..255 maps to 0..height_m).
    """

    geometry: BaseGeometry
    action: str = "recolor"
    color: tuple[int, int, int] = (40, 110, 220)
    height_m: float = 0.0
    texture: str = ""
    name: str = ""

    def properties(self) -> dict[str, Any]:
        return {"name": self.name, "action": self.action, "color": "#{:02x}{:02x}{:02x}".format(*self.color),
                "height_m": self.height_m, "texture": self.texture}


@dataclass(frozen=True)
class PolygonLayer:
    """Polygons with actions in one CRS (None: the CRS of whatever they are applied to)."""

    polygons: tuple[EditPolygon, ...] = ()
    crs: pyproj.CRS | None = None
    source: str = field(default="", compare=False)

    def __len__(self) -> int:
        return len(self.polygons)

    def with_action(self, action: str) -> PolygonLayer:
        """The polygons whose action is ``action``."""
        return replace(self, polygons=tuple(p for p in self.polygons if p.action == action))

    def to_crs(self, crs: pyproj.CRS | None) -> PolygonLayer:
        """The layer in ``crs`` (edges densified to 1/50 of the extent first, so long edges follow the
        projection's curvature); unchanged when either CRS is unknown or they are equal."""
        if crs is None or self.crs is None or self.crs.equals(crs) or not self.polygons:
            return self
        t = pyproj.Transformer.from_crs(self.crs, crs, always_xy=True)
        out = []
        for p in self.polygons:
            x0, y0, x1, y1 = p.geometry.bounds
            g = shapely.segmentize(p.geometry, max(x1 - x0, y1 - y0, 1e-9) / 50.0)
            out.append(replace(p, geometry=shapely.transform(g, lambda xy, t=t: _apply(t, xy))))
        return PolygonLayer(tuple(out), crs, self.source)


def _apply(t: pyproj.Transformer, xy: Any) -> Any:
    import numpy as np

    x, y = t.transform(xy[:, 0], xy[:, 1])
    return np.column_stack([x, y])


def _color(value: Any, where: str) -> tuple[int, int, int]:
    if value in (None, ""):
        return EditPolygon.color
    if isinstance(value, str) and value.startswith("#") and len(value) == 7:
        try:
            return (int(value[1:3], 16), int(value[3:5], 16), int(value[5:7], 16))
        except ValueError:
            pass
    elif isinstance(value, list | tuple) and len(value) == 3:
        return tuple(int(v) for v in value)  # type: ignore[return-value]
    raise InputError(f"{where}: colour must be '#rrggbb' or [r, g, b], got {value!r}")


def _checked(geom: BaseGeometry | None, props: dict[str, Any], k: int, path: Path) -> EditPolygon:
    name = str(props.get("name") or "")
    where = f"polygon {k + 1}" + (f" ({name!r})" if name else "")
    if geom is None or geom.is_empty:
        raise InputError(f"{where} is empty", path)
    if geom.geom_type not in ("Polygon", "MultiPolygon"):
        raise InputError(f"{where} is a {geom.geom_type}, not a polygon", path)
    if not geom.is_valid:
        raise InputError(f"{where} is not a valid polygon: {explain_validity(geom)}", path)
    action = str(props.get("action") or "recolor").lower()
    if action not in ACTIONS:
        raise InputError(f"{where}: unknown action {action!r} (one of {', '.join(ACTIONS)})", path)
    try:
        height = float(props.get("height_m") or 0.0)
    except (TypeError, ValueError):
        raise InputError(f"{where}: height_m is not a number: {props.get('height_m')!r}", path) from None
    try:
        color = _color(props.get("color"), where)
    except InputError as exc:
        raise InputError(exc.message, path) from None
    return EditPolygon(geom, action, color, height, str(props.get("texture") or ""), name)


# -- GeoJSON ------------------------------------------------------------------------------------------
def _read_geojson(path: Path) -> PolygonLayer:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"not valid GeoJSON ({exc})", path) from None
    if not isinstance(doc, dict):
        raise InputError("not a GeoJSON object", path)
    feats = doc.get("features") if doc.get("type") == "FeatureCollection" else [doc]
    if not isinstance(feats, list):
        raise InputError("GeoJSON FeatureCollection without a features list", path)
    crs = _WGS84
    name = (doc.get("crs") or {}).get("properties", {}).get("name") if isinstance(doc.get("crs"), dict) else None
    if name:
        try:
            crs = pyproj.CRS.from_user_input(name)
        except pyproj.exceptions.CRSError:
            raise InputError(f"unknown CRS {name!r}", path) from None
    polys = []
    for k, f in enumerate(feats):
        geom_doc = f.get("geometry") if isinstance(f, dict) and f.get("type") == "Feature" else f
        try:
            geom = shapely.geometry.shape(geom_doc) if geom_doc else None
        except (AttributeError, TypeError, ValueError, shapely.errors.GEOSException) as exc:
            raise InputError(f"polygon {k + 1}: unreadable geometry ({exc})", path) from None
        polys.append(_checked(geom, (f.get("properties") or {}) if isinstance(f, dict) else {}, k, path))
    return PolygonLayer(tuple(polys), crs, str(path))


def _geojson_text(layer: PolygonLayer) -> str:
    doc: dict[str, Any] = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": p.properties(), "geometry": shapely.geometry.mapping(p.geometry)}
        for p in layer.polygons]}
    if layer.crs is not None and not layer.crs.equals(_WGS84):
        auth = layer.crs.to_authority()
        doc["crs"] = {"type": "name", "properties": {"name": ":".join(auth) if auth else layer.crs.to_wkt()}}
    return json.dumps(doc)


# -- KML ----------------------------------------------------------------------------------------------
def _kml_ring(elem: Any, path: Path) -> list[tuple[float, float]]:
    text = " ".join(t for t in elem.itertext()).split()
    pts = []
    for tok in text:
        parts = tok.split(",")
        try:
            pts.append((float(parts[0]), float(parts[1])))
        except (IndexError, ValueError):
            raise InputError(f"bad KML coordinate {tok!r}", path) from None
    return pts


def _read_kml(path: Path) -> PolygonLayer:
    from lxml import etree

    check_xml_prolog(path)
    parser = etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False, huge_tree=False)
    try:
        root = etree.parse(str(path), parser).getroot()
    except etree.XMLSyntaxError as exc:
        raise InputError(f"not valid KML ({exc})", path) from None
    polys = []
    for k, pm in enumerate(e for e in root.iter() if isinstance(e.tag, str) and e.tag.endswith("Placemark")):
        props: dict[str, Any] = {}
        for e in pm.iter():
            tag = e.tag.rsplit("}", 1)[-1] if isinstance(e.tag, str) else ""
            if tag == "name" and e.getparent() is pm:
                props["name"] = (e.text or "").strip()
            elif tag == "Data" and e.get("name"):
                props[e.get("name")] = "".join(v.text or "" for v in e if str(v.tag).endswith("value")).strip()
        parts = []
        for poly in (e for e in pm.iter() if isinstance(e.tag, str) and e.tag.endswith("}Polygon")):
            outer = [e for e in poly.iter() if isinstance(e.tag, str) and e.tag.endswith("outerBoundaryIs")]
            inner = [e for e in poly.iter() if isinstance(e.tag, str) and e.tag.endswith("innerBoundaryIs")]
            if not outer:
                continue
            shell = _kml_ring(outer[0], path)
            holes = [_kml_ring(i, path) for i in inner]
            try:
                parts.append(shapely.Polygon(shell, holes))
            except (ValueError, shapely.errors.GEOSException) as exc:
                raise InputError(f"polygon {k + 1}: unreadable KML polygon ({exc})", path) from None
        geom = None if not parts else parts[0] if len(parts) == 1 else shapely.MultiPolygon(parts)
        polys.append(_checked(geom, props, k, path))
    return PolygonLayer(tuple(polys), _WGS84, str(path))


def _kml_text(layer: PolygonLayer) -> str:
    from xml.sax.saxutils import escape

    wgs = layer.to_crs(_WGS84) if layer.crs is not None else layer

    def ring(coords: Any) -> str:
        return " ".join(f"{x!r},{y!r}" for x, y in coords)

    marks = []
    for p in wgs.polygons:
        polys = []
        for g in shapely.get_parts(p.geometry):
            holes = "".join(f"<innerBoundaryIs><LinearRing><coordinates>{ring(h.coords)}</coordinates>"
                            f"</LinearRing></innerBoundaryIs>" for h in g.interiors)
            polys.append(f"<Polygon><outerBoundaryIs><LinearRing><coordinates>{ring(g.exterior.coords)}"
                         f"</coordinates></LinearRing></outerBoundaryIs>{holes}</Polygon>")
        geom = polys[0] if len(polys) == 1 else f"<MultiGeometry>{''.join(polys)}</MultiGeometry>"
        data = "".join(f'<Data name="{k}"><value>{escape(str(v))}</value></Data>'
                       for k, v in p.properties().items() if k != "name")
        marks.append(f"<Placemark><name>{escape(p.name)}</name><ExtendedData>{data}</ExtendedData>{geom}</Placemark>")
    return (f'<?xml version="1.0" encoding="UTF-8"?>\n<kml xmlns="{_KML_NS}"><Document>'
            + "".join(marks) + "</Document></kml>\n")


# -- GeoPackage ---------------------------------------------------------------------------------------
def _read_gpkg(path: Path) -> PolygonLayer:
    try:
        conn = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)
        rows = conn.execute("SELECT g.table_name, g.column_name, s.definition FROM gpkg_geometry_columns g "
                            "JOIN gpkg_spatial_ref_sys s ON s.srs_id = g.srs_id").fetchall()
    except sqlite3.DatabaseError as exc:
        raise InputError(f"not a GeoPackage ({exc})", path) from None
    try:
        pick = [r for r in rows if r[0] == _TABLE] or rows
        if not pick:
            raise InputError("GeoPackage holds no feature table", path)
        table, col, wkt = pick[0]
        crs = None if wkt in ("undefined", "") else pyproj.CRS.from_wkt(wkt)
        cur = conn.execute(f'SELECT * FROM "{table}"')
        names = [d[0] for d in cur.description]
        polys = []
        for k, row in enumerate(cur):
            props = dict(zip(names, row, strict=True))
            try:
                geom = decode_geometry(props.pop(col))
            except (ValueError, shapely.errors.GEOSException) as exc:
                raise InputError(f"polygon {k + 1}: unreadable geometry ({exc})", path) from None
            polys.append(_checked(geom, props, k, path))
    finally:
        conn.close()
    return PolygonLayer(tuple(polys), crs, str(path))


def _write_gpkg(layer: PolygonLayer, tmp: Path) -> None:
    conn = sqlite3.connect(tmp)
    try:
        init_geopackage(conn)
        srs = register_srs(conn, layer.crs)
        add_feature_table(conn, _TABLE, [("name", "TEXT"), ("action", "TEXT"), ("color", "TEXT"),
                                         ("height_m", "REAL"), ("texture", "TEXT")],
                          "geom", "MULTIPOLYGON", srs, description="citylod polygon edits")
        bounds = []
        for p in layer.polygons:
            g = p.geometry if p.geometry.geom_type == "MultiPolygon" else shapely.MultiPolygon([p.geometry])
            pr = p.properties()
            conn.execute(f'INSERT INTO "{_TABLE}" (name, action, color, height_m, texture, geom) '
                         "VALUES (?, ?, ?, ?, ?, ?)", (pr["name"], pr["action"], pr["color"], pr["height_m"],
                                                       pr["texture"], encode_geometry(g, srs)))
            bounds.append(g.bounds)
        import numpy as np

        fill_rtree(conn, _TABLE, "geom", range(1, len(bounds) + 1), np.asarray(bounds, dtype=np.float64))
        conn.commit()
    finally:
        conn.close()


_READERS = {".geojson": _read_geojson, ".json": _read_geojson, ".kml": _read_kml, ".gpkg": _read_gpkg}


def load_polygons(path: str | os.PathLike[str]) -> PolygonLayer:
    """Read a polygon layer from GeoJSON (``.geojson``/``.json``), KML (``.kml``) or GeoPackage (``.gpkg``).

    Properties ``action``, ``color`` ('#rrggbb'), ``height_m``, ``texture`` and ``name`` are read when
    present (KML: ``ExtendedData``). Raises :class:`InputError` naming the file and the polygon for an
    empty or self-intersecting polygon, an unknown action, and for KML whose DOCTYPE declares entities.

    Examples
    --------
    >>> import tempfile, pathlib, shapely
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> layer = PolygonLayer((EditPolygon(shapely.box(0, 0, 10, 5), "discard", name="cut"),))
    >>> _ = save_polygons(layer, d / "edits.geojson")
    >>> load_polygons(d / "edits.geojson").polygons[0].action
    'discard'
    """
    p = Path(path)
    reader = _READERS.get(p.suffix.lower())
    if reader is None:
        raise InputError("polygons must be .geojson, .json, .kml or .gpkg", p)
    if not p.is_file():
        raise InputError("no such polygon file", p)
    return reader(p)


def save_polygons(layer: PolygonLayer, path: str | os.PathLike[str]) -> Path:
    """Write ``layer`` as GeoJSON, KML (lon/lat, as KML requires) or GeoPackage, by suffix, atomically."""
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in (".geojson", ".json"):
        return atomic_write_text(p, _geojson_text(layer))
    if suffix == ".kml":
        return atomic_write_text(p, _kml_text(layer))
    if suffix == ".gpkg":
        return atomic_write(p, lambda t: _write_gpkg(layer, t), suffix=".gpkg")
    raise InputError("polygons must be saved as .geojson, .json, .kml or .gpkg", p)
