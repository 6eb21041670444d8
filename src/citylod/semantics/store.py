"""The semantic store: city objects, their attributes and proxies in one GeoPackage.

:func:`build_city` reads a CityGML / CityJSON model, projects it to metres, builds the proxies
(:mod:`citylod.semantics.proxy`) and writes a GeoPackage that QGIS opens: the feature table
``city_objects`` (attributes + footprint MULTIPOLYGON, R-tree indexed), the feature table ``proxies``
(inflated footprint, height interval, closed mesh and roof planes as npz blobs), ``citylod_metadata``
(crs, inflate, source, lod) and ``citylod_warnings`` (what the reader repaired or could not).
The file is written under a temporary name and renamed when complete.

:class:`CityStore` opens it read-only: SQL over attributes (user SQL runs under an authorizer that
allows reading only), spatial queries through the R-tree, and the :class:`ProxySet` for volume linking
(Wahl & Klein 2007). No VTK, no Qt.
"""

from __future__ import annotations

import io
import json
import os
import sqlite3
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pyproj
import shapely
from shapely.geometry.base import BaseGeometry

from citylod.core.errors import GeoreferenceError, InputError
from citylod.io.city import CityModel, read_city_model, to_metric
from citylod.io.crs import horizontal_crs
from citylod.io.gpkg import (
    GPKG_APPLICATION_ID,
    add_attributes_table,
    add_feature_table,
    decode_geometry,
    encode_geometry,
    fill_rtree,
    init_geopackage,
    register_srs,
)
from citylod.semantics.proxy import DEFAULT_INFLATE_M, ProxySet, footprint_of, prism_mesh, roof_planes

__all__ = ["BuildReport", "CityStore", "build_city"]

_BUILDING_TYPES = ("Building", "BuildingPart")
_OBJECT_COLUMNS = [
    ("object_id", "TEXT NOT NULL UNIQUE"), ("type", "TEXT"), ("name", "TEXT"), ("function", "TEXT"),
    ("measured_height", "REAL"), ("storeys", "INTEGER"), ("zmin", "REAL"), ("zmax", "REAL"), ("lod", "INTEGER"),
    ("parent", "TEXT"), ("attributes", "TEXT"),
]


@dataclass(frozen=True)
class BuildReport:
    """What :func:`build_city` did."""

    path: Path
    objects: int
    buildings: int
    proxies: int
    warnings: list[str] = field(default_factory=list)
    seconds: float = 0.0
    crs: str = ""
    inflate: float = DEFAULT_INFLATE_M

    def summary(self) -> str:
        """One paragraph for the command line."""
        text = (f"{self.path}: {self.objects} city objects ({self.buildings} buildings), {self.proxies} proxies "
                f"inflated by {self.inflate:g} m, CRS {self.crs}, {len(self.warnings)} warnings, "
                f"{self.seconds:.1f} s")
        if self.warnings:
            text += "\n  " + "\n  ".join(self.warnings[:5])
            if len(self.warnings) > 5:
                text += f"\n  ... {len(self.warnings) - 5} more in table citylod_warnings"
        return text


def _npz(**arrays: npt.ArrayLike) -> bytes:
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)  # type: ignore[arg-type]
    return buf.getvalue()


def _unnpz(blob: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(blob), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _multi(geom: BaseGeometry) -> BaseGeometry:
    """A MultiPolygon (the declared column type) from a Polygon, MultiPolygon or empty geometry."""
    if geom.geom_type == "MultiPolygon":
        return geom
    if geom.geom_type == "Polygon" and not geom.is_empty:
        return shapely.MultiPolygon([geom])
    parts = [g for g in shapely.get_parts(geom) if g.geom_type == "Polygon" and not g.is_empty]
    return shapely.MultiPolygon(parts)


def _text(value: Any) -> str | None:
    if value is None:
        return None
    if isinstance(value, list):
        return ", ".join(str(v) for v in value)
    return str(value)


def _number(value: Any, kind: type) -> Any:
    try:
        return None if value is None else kind(float(value) if kind is int else value)
    except (TypeError, ValueError):
        return None


def build_city(citymodel: str | PathLike[str] | CityModel, out_gpkg: str | PathLike[str], *, lod: int = 2,
               inflate: float | None = None, crs: str | pyproj.CRS | None = None,
               progress: bool = True) -> BuildReport:
    """Build the GeoPackage semantic store of a city model.

    Parameters
    ----------
    citymodel
        A CityGML / CityJSON file, or a model already read.
    out_gpkg
        The GeoPackage to write (replaced atomically if it exists).
    lod
        Preferred LoD (1 or 2) of the geometry the proxies are made from.
    inflate
        Proxy inflation in metres (default :data:`~citylod.semantics.proxy.DEFAULT_INFLATE_M`).
    crs
        Metric CRS for geographic input (default: the UTM zone of the data).
    progress
        Show a progress bar.

    Returns
    -------
    BuildReport
    """
    t0 = time.perf_counter()
    infl = DEFAULT_INFLATE_M if inflate is None else float(inflate)
    if not np.isfinite(infl) or infl < 0:
        raise InputError(f"inflate must be a non-negative number of metres, got {inflate}")
    model = citymodel if isinstance(citymodel, CityModel) else read_city_model(citymodel, lod=lod)
    if model.crs is None and crs is None:
        # A store without a CRS cannot be linked to point clouds or placed on a map; guessing is worse.
        raise GeoreferenceError("the file names no coordinate reference system (no srsName / referenceSystem); "
                                "say which with --crs, e.g. --crs EPSG:25832", model.source)
    model = to_metric(model, crs)
    out = Path(out_gpkg)
    if out.parent and not out.parent.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    if tmp.exists():
        tmp.unlink()
    objects = model.objects
    iterator: Any = objects
    if progress:
        from tqdm import tqdm

        iterator = tqdm(objects, desc="city objects", unit="obj")
    try:
        conn = sqlite3.connect(tmp)
        try:
            init_geopackage(conn)
            srs_id = register_srs(conn, None if model.crs is None else horizontal_crs(model.crs))
            add_feature_table(conn, "city_objects", _OBJECT_COLUMNS, "footprint", "MULTIPOLYGON", srs_id,
                              description="city objects and their attributes; footprint not inflated")
            add_feature_table(conn, "proxies", [("object_id", "TEXT NOT NULL UNIQUE"), ("zmin", "REAL"),
                                                ("zmax", "REAL"), ("mesh", "BLOB"), ("roof", "BLOB")],
                              "proxy_footprint", "MULTIPOLYGON", srs_id,
                              description="inflated proxy solids: footprint x [zmin, zmax], mesh, roof planes")
            add_attributes_table(conn, "citylod_metadata", [("key", "TEXT PRIMARY KEY"), ("value", "TEXT")],
                                 "citylod store metadata")
            add_attributes_table(conn, "citylod_warnings", [("object_id", "TEXT"), ("message", "TEXT")],
                                 "repairs and defects reported by the reader")
            feet = np.empty(len(objects), dtype=object)
            zmin = np.full(len(objects), np.nan)
            zmax = np.full(len(objects), np.nan)
            roofs: list[tuple[list[BaseGeometry], np.ndarray]] = []
            rows = []
            for i, o in enumerate(iterator):
                feet[i] = footprint_of(o)
                pts = o.points()
                if len(pts):
                    zmin[i], zmax[i] = float(pts[:, 2].min()), float(pts[:, 2].max())
                roofs.append(roof_planes(o) if o.lod >= 2 and not feet[i].is_empty else ([], np.zeros((0, 4))))
                a = o.attributes
                rows.append((
                    i + 1, o.id, o.type, _text(a.get("name")), _text(a.get("function")),
                    _number(a.get("measuredHeight"), float), _number(a.get("storeysAboveGround"), int),
                    None if np.isnan(zmin[i]) else zmin[i], None if np.isnan(zmax[i]) else zmax[i],
                    o.lod, o.parent, json.dumps(a, default=str, ensure_ascii=False),
                    encode_geometry(_multi(feet[i]), srs_id),
                ))
            try:
                conn.executemany("INSERT INTO city_objects (fid, object_id, type, name, function, measured_height, "
                                 "storeys, zmin, zmax, lod, parent, attributes, footprint) "
                                 "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", rows)
            except sqlite3.IntegrityError as exc:
                raise InputError(f"duplicate object ids ({exc})", model.source) from exc
            fids = np.arange(1, len(objects) + 1, dtype=np.int32)
            r_owner = np.concatenate([np.full(len(r[0]), i, np.int32) for i, r in enumerate(roofs)] or
                                     [np.zeros(0, np.int32)])
            r_shapes = np.asarray([s for r in roofs for s in r[0]], dtype=object).reshape(-1)
            r_planes = np.concatenate([r[1] for r in roofs]) if roofs else np.zeros((0, 4))
            proxies = ProxySet.build(tuple(o.id for o in objects), fids, feet, zmin, zmax, infl, r_owner,
                                     r_shapes, r_planes)
            prow = []
            for i, o in enumerate(objects):
                if not np.isfinite(proxies.zmin[i]):
                    continue
                v, f = prism_mesh(proxies.shapes[i], float(proxies.zmin[i]), float(proxies.zmax[i]))
                rs, rp = roofs[i]
                # Roof faces as one MultiPolygon WKB whose parts keep the order of the planes.
                roof = _npz(planes=rp, shapes=np.frombuffer(shapely.to_wkb(shapely.MultiPolygon(rs)), np.uint8)
                            ) if rs else None
                prow.append((i + 1, o.id, float(proxies.zmin[i]), float(proxies.zmax[i]),
                             _npz(vertices=v, faces=f), roof, encode_geometry(_multi(proxies.shapes[i]), srs_id)))
            conn.executemany("INSERT INTO proxies (fid, object_id, zmin, zmax, mesh, roof, proxy_footprint) "
                             "VALUES (?, ?, ?, ?, ?, ?, ?)", prow)
            fill_rtree(conn, "city_objects", "footprint", fids, shapely.bounds(feet))
            pf = np.asarray([r[0] for r in prow], dtype=np.int64)
            fill_rtree(conn, "proxies", "proxy_footprint", pf, shapely.bounds(proxies.shapes[pf - 1]))
            meta = {
                "crs": "" if model.crs is None else model.crs.to_wkt(),
                "crs_name": "" if model.crs is None else model.crs.name,
                "inflate": repr(infl), "source": str(model.source), "format": model.version, "lod": str(lod),
                "objects": str(len(objects)), "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            }
            conn.executemany("INSERT INTO citylod_metadata VALUES (?, ?)", list(meta.items()))
            conn.executemany("INSERT INTO citylod_warnings VALUES (?, ?)",
                             [tuple(w.split(": ", 1)) if ": " in w else (None, w) for w in model.warnings])
            conn.commit()
        finally:
            conn.close()
        os.replace(tmp, out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    n_build = sum(o.type in _BUILDING_TYPES for o in objects)
    return BuildReport(out, len(objects), n_build, len(prow), list(model.warnings), time.perf_counter() - t0,
                       "" if model.crs is None else model.crs.name, infl)


# ------------------------------------------------------------------------------------------------------
# Reading

# sqlite3 authorizer action codes that a read-only WHERE clause may need.
_ALLOWED_ACTIONS = {sqlite3.SQLITE_SELECT, sqlite3.SQLITE_READ, sqlite3.SQLITE_FUNCTION,
                    getattr(sqlite3, "SQLITE_RECURSIVE", 33)}


#: Longest a WHERE clause may run (a recursive CTE can loop for ever) and longest value it may build.
QUERY_TIME_LIMIT_S = 5.0
QUERY_MAX_LENGTH = 64 << 20


# Functions that can run for long inside one call, where the progress handler cannot stop them:
# printf('%.*c', 2000000000, 'x') loops 2e9 times (25 s) even after the length limit made its result NULL.
_DENIED_FUNCTIONS = {"printf", "format", "load_extension"}


def _read_only_authorizer(action: int, arg1: Any = None, arg2: Any = None, *_: Any) -> int:
    if action == sqlite3.SQLITE_FUNCTION and str(arg2).lower() in _DENIED_FUNCTIONS:
        return sqlite3.SQLITE_DENY
    return sqlite3.SQLITE_OK if action in _ALLOWED_ACTIONS else sqlite3.SQLITE_DENY


class CityStore:
    """A city store opened read-only; use :meth:`open`.

    Object ids are strings (``gml:id``); ``fid`` is the GeoPackage feature id (1-based), the integer that
    linked point clouds carry; proxy index = fid - 1.
    """

    def __init__(self, path: Path, conn: sqlite3.Connection) -> None:
        self.path = path
        self._conn = conn
        self._proxies: ProxySet | None = None
        meta = dict(conn.execute("SELECT key, value FROM citylod_metadata").fetchall())
        self.metadata: dict[str, str] = meta
        self.crs: pyproj.CRS | None = pyproj.CRS.from_wkt(meta["crs"]) if meta.get("crs") else None
        self.inflate = float(meta.get("inflate", DEFAULT_INFLATE_M))
        self.query_time_limit_s = QUERY_TIME_LIMIT_S
        conn.setlimit(sqlite3.SQLITE_LIMIT_LENGTH, QUERY_MAX_LENGTH)
        self.ids: list[str] = [r[0] for r in conn.execute("SELECT object_id FROM city_objects ORDER BY fid")]

    @classmethod
    def open(cls, path: str | PathLike[str]) -> CityStore:
        """Open a store written by :func:`build_city`; InputError if it is not one."""
        p = Path(path)
        if not p.is_file():
            raise InputError("no such city store", p)
        try:
            conn = sqlite3.connect(f"{p.resolve().as_uri()}?mode=ro", uri=True, check_same_thread=False)
            app = conn.execute("PRAGMA application_id").fetchone()[0]
            tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        except sqlite3.DatabaseError as exc:
            raise InputError(f"not a GeoPackage ({exc})", p) from exc
        if app != GPKG_APPLICATION_ID or not {"city_objects", "proxies", "citylod_metadata"} <= tables:
            conn.close()
            raise InputError("not a citylod city store (build one with `citylod build city`)", p)
        conn.execute("PRAGMA query_only = ON")
        return cls(p, conn)

    def close(self) -> None:
        self._conn.close()

    def __enter__(self) -> CityStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __len__(self) -> int:
        return len(self.ids)

    # -- attributes -----------------------------------------------------------------------------------
    def query(self, where_sql: str, params: Sequence[Any] = ()) -> list[str]:
        """Object ids of ``SELECT object_id FROM city_objects WHERE (where_sql)``.

        Parameters
        ----------
        where_sql
            A WHERE clause over the columns of ``city_objects`` (``type = 'Building' AND measured_height > 20``,
            ``json_extract(attributes, '$.roofType') = '1000'``).
        params
            Values for ``?`` placeholders.

        Raises
        ------
        InputError
            For more than one statement, anything but reading (an authorizer denies it), or an SQL error.
        """
        if ";" in where_sql:
            raise InputError(f"refused SQL: ';' is not allowed in a WHERE clause: {where_sql!r}", self.path)
        sql = f"SELECT object_id FROM city_objects WHERE ({where_sql}) ORDER BY fid"
        deadline = time.monotonic() + self.query_time_limit_s
        self._conn.set_authorizer(_read_only_authorizer)
        # SQLite calls the handler every 10k VM steps; a non-zero return interrupts the statement.
        self._conn.set_progress_handler(lambda: int(time.monotonic() > deadline), 10_000)
        try:
            return [r[0] for r in self._conn.execute(sql, tuple(params))]
        except sqlite3.OperationalError as exc:
            if time.monotonic() > deadline:
                raise InputError(f"query {where_sql[:200]!r} ran longer than {self.query_time_limit_s:g} s; "
                                 "stopped", self.path) from exc
            failed: Exception = exc
        except (sqlite3.Error, ValueError, OverflowError, MemoryError) as exc:
            failed = exc
        finally:
            self._conn.set_progress_handler(None, 0)
            self._conn.set_authorizer(None)
        hint = ""
        if "no such column" in str(failed):  # what the user can write instead
            hint = (f" (columns: {', '.join(self.query_columns())}; other attributes as "
                    "json_extract(attributes, '$.NAME'), which `citylod info` lists)")
        raise InputError(f"bad query {where_sql[:200]!r}: {failed}{hint}", self.path) from failed

    def query_columns(self) -> list[str]:
        """The columns of ``city_objects`` a query can name (the footprint geometry and the row id aside)."""
        return [r[1] for r in self._conn.execute("PRAGMA table_info(city_objects)")
                if r[1] not in ("fid", "footprint")]

    def attribute_names(self, limit: int = 12) -> list[tuple[str, int]]:
        """The most common keys of the objects' ``attributes`` (JSON), with how many objects have each."""
        sql = ("SELECT j.key, count(*) FROM city_objects, json_each(city_objects.attributes) AS j "
               "WHERE json_valid(city_objects.attributes) GROUP BY j.key ORDER BY count(*) DESC, j.key LIMIT ?")
        try:
            return [(str(k), int(n)) for k, n in self._conn.execute(sql, (int(limit),))]
        except sqlite3.Error:  # an SQLite without JSON functions: queries on attributes fail there too
            return []

    #: The columns of ``city_objects`` a result list shows next to the id.
    LIST_COLUMNS = ("type", "name", "function", "measured_height", "storeys", "lod")

    def rows(self, object_ids: Sequence[str], columns: Sequence[str] = LIST_COLUMNS) -> list[tuple[Any, ...]]:
        """``columns`` of ``city_objects`` for each id, in the order given (one query per 500 ids).

        Column names are checked against the table, never pasted from user input.
        """
        known = {r[1] for r in self._conn.execute("PRAGMA table_info(city_objects)")}
        bad = [c for c in columns if c not in known]
        if bad:
            raise InputError(f"city_objects has no column {', '.join(bad)}", self.path)
        cols = ", ".join(["object_id", *columns])
        found: dict[str, tuple[Any, ...]] = {}
        ids = list(object_ids)
        for i in range(0, len(ids), 500):
            chunk = ids[i:i + 500]
            marks = ",".join("?" * len(chunk))
            for r in self._conn.execute(f"SELECT {cols} FROM city_objects WHERE object_id IN ({marks})", chunk):
                found[r[0]] = tuple(r[1:])
        empty = (None,) * len(columns)
        return [found.get(oid, empty) for oid in ids]

    def attributes(self, object_id: str) -> dict[str, Any]:
        """All attributes of an object: the columns of ``city_objects`` and the source attributes."""
        cur = self._conn.execute(
            "SELECT fid, object_id, type, name, function, measured_height, storeys, zmin, zmax, lod, parent, "
            "attributes FROM city_objects WHERE object_id = ?", (object_id,))
        row = cur.fetchone()
        if row is None:
            raise KeyError(object_id)
        names = [d[0] for d in cur.description]
        out = dict(zip(names[:-1], row[:-1], strict=True))
        out.update(json.loads(row[-1]) if row[-1] else {})
        return out

    def fid(self, object_id: str) -> int:
        """Feature id of an object id."""
        return self.proxies.index_of(object_id) + 1

    def object_id(self, fid: int) -> str:
        """Object id of a feature id (as written into linked point clouds)."""
        return self.ids[int(fid) - 1]

    # -- space ----------------------------------------------------------------------------------------
    @property
    def bounds(self) -> tuple[float, float, float, float, float, float]:
        """(xmin, ymin, zmin, xmax, ymax, zmax) of all footprints and heights (not inflated)."""
        x0, y0, x1, y1 = self._conn.execute(
            "SELECT min_x, min_y, max_x, max_y FROM gpkg_contents WHERE table_name = 'city_objects'").fetchone()
        z0, z1 = self._conn.execute("SELECT MIN(zmin), MAX(zmax) FROM city_objects").fetchone()
        return tuple(float("nan") if v is None else float(v) for v in (x0, y0, z0, x1, y1, z1))  # type: ignore[return-value]

    def _candidates(self, x0: float, y0: float, x1: float, y1: float) -> list[int]:
        return [r[0] for r in self._conn.execute(
            "SELECT id FROM rtree_city_objects_footprint WHERE maxx >= ? AND minx <= ? AND maxy >= ? AND miny <= ?",
            (x0, x1, y0, y1))]

    def _footprints(self, fids: list[int]) -> list[tuple[int, BaseGeometry]]:
        if not fids:
            return []
        marks = ",".join("?" * len(fids))
        return [(r[0], decode_geometry(r[1])) for r in self._conn.execute(
            f"SELECT fid, footprint FROM city_objects WHERE fid IN ({marks}) ORDER BY fid", fids)]

    def footprints(self, bounds: tuple[float, float, float, float] | None = None, *,
                   types: Sequence[str] = _BUILDING_TYPES[:1]) -> list[tuple[str, BaseGeometry]]:
        """(object id, footprint) of the objects of ``types`` whose footprint box meets ``bounds``
        (xmin, ymin, xmax, ymax in the store's CRS; None: all), in fid order, through the R-tree.

        The default is whole buildings (``Building``), not their parts, whose footprints lie inside."""
        if bounds is None:
            fids = [r[0] for r in self._conn.execute("SELECT fid FROM city_objects ORDER BY fid")]
        else:
            fids = self._candidates(*bounds)
        wanted = set(types)
        kinds = dict(self._conn.execute("SELECT fid, type FROM city_objects"))
        return [(self.ids[f - 1], g) for f, g in self._footprints([f for f in fids if kinds.get(f) in wanted])
                if g is not None and not g.is_empty]

    def within_polygon(self, polygon_xy: npt.ArrayLike | BaseGeometry, *, predicate: str = "intersects") -> list[str]:
        """Objects whose footprint intersects (or, with ``predicate='within'``, lies within) a polygon.

        Parameters
        ----------
        polygon_xy
            (K, 2) float64 vertices in the store's CRS, or a shapely polygon.
        """
        poly = polygon_xy if isinstance(polygon_xy, BaseGeometry) else shapely.Polygon(np.asarray(polygon_xy)[:, :2])
        if predicate not in ("intersects", "within"):
            raise ValueError(f"predicate must be 'intersects' or 'within', got {predicate!r}")
        rows = self._footprints(self._candidates(*poly.bounds))
        if not rows:
            return []
        geoms = np.asarray([g for _, g in rows], dtype=object)
        test = shapely.intersects(geoms, poly) if predicate == "intersects" else shapely.within(geoms, poly)
        return [self.ids[f - 1] for (f, _), t in zip(rows, test, strict=True) if t]

    def within_distance(self, point_xy: npt.ArrayLike, distance: float) -> list[str]:
        """Objects whose footprint is at most ``distance`` metres from a point (x, y), nearest first."""
        x, y = (float(v) for v in np.asarray(point_xy, dtype=np.float64).ravel()[:2])
        d = float(distance)
        rows = self._footprints(self._candidates(x - d, y - d, x + d, y + d))
        if not rows:
            return []
        dist = shapely.distance(np.asarray([g for _, g in rows], dtype=object), shapely.Point(x, y))
        order = np.argsort(dist, kind="stable")
        return [self.ids[rows[i][0] - 1] for i in order if dist[i] <= d]

    # -- proxies --------------------------------------------------------------------------------------
    @property
    def proxies(self) -> ProxySet:
        """The proxy set (loaded on first use); index i is the object with fid i + 1."""
        if self._proxies is None:
            self._proxies = self._load_proxies()
        return self._proxies

    def _load_proxies(self) -> ProxySet:
        n = len(self.ids)
        feet = np.asarray([shapely.Polygon()] * n, dtype=object)
        for fid, blob in self._conn.execute("SELECT fid, footprint FROM city_objects"):
            feet[fid - 1] = decode_geometry(blob)
        shapes = np.asarray([shapely.Polygon()] * n, dtype=object)
        zmin = np.full(n, np.nan)
        zmax = np.full(n, np.nan)
        owner: list[np.ndarray] = []
        r_shapes: list[np.ndarray] = []
        r_planes: list[np.ndarray] = []
        for fid, z0, z1, roof, shp in self._conn.execute(
                "SELECT fid, zmin, zmax, roof, proxy_footprint FROM proxies"):
            shapes[fid - 1] = decode_geometry(shp)
            zmin[fid - 1], zmax[fid - 1] = z0, z1
            if roof is not None:
                r = _unnpz(roof)
                owner.append(np.full(len(r["planes"]), fid - 1, dtype=np.int32))
                r_shapes.append(shapely.get_parts(shapely.from_wkb(r["shapes"].tobytes())))
                r_planes.append(r["planes"])
        # zmin/zmax stored inflated; ProxySet.build would inflate again, so construct directly.
        return ProxySet(
            tuple(self.ids), np.arange(1, n + 1, dtype=np.int32), feet, shapes, zmin, zmax, self.inflate,
            np.concatenate(owner) if owner else np.zeros(0, np.int32),
            np.concatenate(r_shapes) if r_shapes else np.zeros(0, object),
            np.concatenate(r_planes) if r_planes else np.zeros((0, 4)),
        )

    def mesh(self, object_id: str) -> tuple[np.ndarray, np.ndarray]:
        """The closed proxy mesh of an object: (V, 3) float64 vertices, (F, 3) int32 faces."""
        row = self._conn.execute("SELECT mesh FROM proxies WHERE object_id = ?", (object_id,)).fetchone()
        if row is None or row[0] is None:
            return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int32)
        m = _unnpz(row[0])
        return m["vertices"], m["faces"]
