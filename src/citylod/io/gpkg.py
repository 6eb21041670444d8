"""A minimal GeoPackage 1.3 writer and geometry codec on the standard library's sqlite3 (no GDAL).

What it writes opens in QGIS and GDAL: ``application_id`` 'GPKG', ``user_version`` 10300, the required
``gpkg_spatial_ref_sys`` / ``gpkg_contents`` / ``gpkg_geometry_columns`` tables, GeoPackage binary
geometries (header with envelope, then ISO WKB) and the ``gpkg_rtree_index`` extension: an
``rtree_<table>_<column>`` virtual table filled at write time, with the standard triggers added afterwards
so that later edits in GDAL/QGIS (which provide the ``ST_*`` functions the triggers call) keep it current.

No VTK, no Qt; shapely only for WKB.
"""

from __future__ import annotations

import sqlite3
import struct
from collections.abc import Iterable, Sequence

import numpy as np
import pyproj
import shapely
from shapely.geometry.base import BaseGeometry

__all__ = [
    "GPKG_APPLICATION_ID",
    "add_attributes_table",
    "add_feature_table",
    "decode_geometry",
    "encode_geometry",
    "fill_rtree",
    "init_geopackage",
    "register_srs",
]

GPKG_APPLICATION_ID = 0x47504B47  # 'GPKG'
GPKG_USER_VERSION = 10300

_CORE_SQL = """
CREATE TABLE gpkg_spatial_ref_sys (
  srs_name TEXT NOT NULL, srs_id INTEGER NOT NULL PRIMARY KEY, organization TEXT NOT NULL,
  organization_coordsys_id INTEGER NOT NULL, definition TEXT NOT NULL, description TEXT);
CREATE TABLE gpkg_contents (
  table_name TEXT NOT NULL PRIMARY KEY, data_type TEXT NOT NULL, identifier TEXT UNIQUE, description TEXT DEFAULT '',
  last_change DATETIME NOT NULL DEFAULT (strftime('%Y-%m-%dT%H:%M:%fZ','now')),
  min_x DOUBLE, min_y DOUBLE, max_x DOUBLE, max_y DOUBLE, srs_id INTEGER,
  CONSTRAINT fk_gc_r_srs_id FOREIGN KEY (srs_id) REFERENCES gpkg_spatial_ref_sys(srs_id));
CREATE TABLE gpkg_geometry_columns (
  table_name TEXT NOT NULL, column_name TEXT NOT NULL, geometry_type_name TEXT NOT NULL, srs_id INTEGER NOT NULL,
  z TINYINT NOT NULL, m TINYINT NOT NULL,
  CONSTRAINT pk_geom_cols PRIMARY KEY (table_name, column_name),
  CONSTRAINT fk_gc_tn FOREIGN KEY (table_name) REFERENCES gpkg_contents(table_name),
  CONSTRAINT fk_gc_srs FOREIGN KEY (srs_id) REFERENCES gpkg_spatial_ref_sys (srs_id));
CREATE TABLE gpkg_extensions (
  table_name TEXT, column_name TEXT, extension_name TEXT NOT NULL, definition TEXT NOT NULL, scope TEXT NOT NULL,
  CONSTRAINT ge_tce UNIQUE (table_name, column_name, extension_name));
INSERT INTO gpkg_spatial_ref_sys VALUES
  ('Undefined cartesian SRS', -1, 'NONE', -1, 'undefined', 'undefined cartesian coordinate reference system'),
  ('Undefined geographic SRS', 0, 'NONE', 0, 'undefined', 'undefined geographic coordinate reference system'),
  ('WGS 84 geodetic', 4326, 'EPSG', 4326,
   'GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563,AUTHORITY["EPSG","7030"]],AUTHORITY["EPSG","6326"]],PRIMEM["Greenwich",0,AUTHORITY["EPSG","8901"]],UNIT["degree",0.0174532925199433,AUTHORITY["EPSG","9122"]],AUTHORITY["EPSG","4326"]]',
   'longitude/latitude coordinates in decimal degrees on the WGS 84 spheroid');
"""

# The gpkg_rtree_index triggers of GeoPackage 1.3 (http://www.geopackage.org/spec130/#extension_rtree).
_RTREE_TRIGGERS = """
CREATE TRIGGER rtree_{t}_{c}_insert AFTER INSERT ON {t}
WHEN (new.{c} NOT NULL AND NOT ST_IsEmpty(NEW.{c}))
BEGIN INSERT OR REPLACE INTO rtree_{t}_{c} VALUES (NEW.{i}, ST_MinX(NEW.{c}), ST_MaxX(NEW.{c}), ST_MinY(NEW.{c}), ST_MaxY(NEW.{c})); END;
CREATE TRIGGER rtree_{t}_{c}_update1 AFTER UPDATE OF {c} ON {t}
WHEN OLD.{i} = NEW.{i} AND (NEW.{c} NOTNULL AND NOT ST_IsEmpty(NEW.{c}))
BEGIN INSERT OR REPLACE INTO rtree_{t}_{c} VALUES (NEW.{i}, ST_MinX(NEW.{c}), ST_MaxX(NEW.{c}), ST_MinY(NEW.{c}), ST_MaxY(NEW.{c})); END;
CREATE TRIGGER rtree_{t}_{c}_update2 AFTER UPDATE OF {c} ON {t}
WHEN OLD.{i} = NEW.{i} AND (NEW.{c} IS NULL OR ST_IsEmpty(NEW.{c}))
BEGIN DELETE FROM rtree_{t}_{c} WHERE id = OLD.{i}; END;
CREATE TRIGGER rtree_{t}_{c}_update3 AFTER UPDATE ON {t}
WHEN OLD.{i} != NEW.{i} AND (NEW.{c} NOTNULL AND NOT ST_IsEmpty(NEW.{c}))
BEGIN DELETE FROM rtree_{t}_{c} WHERE id = OLD.{i};
INSERT OR REPLACE INTO rtree_{t}_{c} VALUES (NEW.{i}, ST_MinX(NEW.{c}), ST_MaxX(NEW.{c}), ST_MinY(NEW.{c}), ST_MaxY(NEW.{c})); END;
CREATE TRIGGER rtree_{t}_{c}_update4 AFTER UPDATE ON {t}
WHEN OLD.{i} != NEW.{i} AND (NEW.{c} IS NULL OR ST_IsEmpty(NEW.{c}))
BEGIN DELETE FROM rtree_{t}_{c} WHERE id IN (OLD.{i}, NEW.{i}); END;
CREATE TRIGGER rtree_{t}_{c}_delete AFTER DELETE ON {t}
WHEN old.{c} NOT NULL
BEGIN DELETE FROM rtree_{t}_{c} WHERE id = OLD.{i}; END;
"""


def init_geopackage(conn: sqlite3.Connection) -> None:
    """Turn an empty SQLite database into an empty GeoPackage 1.3."""
    conn.execute(f"PRAGMA application_id = {GPKG_APPLICATION_ID}")
    conn.execute(f"PRAGMA user_version = {GPKG_USER_VERSION}")
    conn.executescript(_CORE_SQL)


def register_srs(conn: sqlite3.Connection, crs: pyproj.CRS | None) -> int:
    """Add a CRS to ``gpkg_spatial_ref_sys`` and return its srs_id (the EPSG code when there is one)."""
    if crs is None:
        return -1
    auth = crs.to_authority() or (None, None)
    if auth[0] == "EPSG" and auth[1] is not None:
        srs_id, org, code = int(auth[1]), "EPSG", int(auth[1])
    else:
        srs_id = 100000 + int(conn.execute("SELECT COUNT(*) FROM gpkg_spatial_ref_sys").fetchone()[0])
        org, code = "NONE", srs_id
    if conn.execute("SELECT 1 FROM gpkg_spatial_ref_sys WHERE srs_id = ?", (srs_id,)).fetchone() is None:
        try:
            wkt = crs.to_wkt("WKT1_GDAL")
        except pyproj.exceptions.CRSError:
            wkt = crs.to_wkt()
        conn.execute("INSERT INTO gpkg_spatial_ref_sys VALUES (?, ?, ?, ?, ?, ?)",
                     (crs.name, srs_id, org, code, wkt, crs.name))
    return srs_id


def encode_geometry(geom: BaseGeometry | None, srs_id: int) -> bytes | None:
    """GeoPackage binary geometry: 'GP', version 0, flags, srs_id, xy envelope, ISO WKB (little endian)."""
    if geom is None:
        return None
    empty = geom.is_empty
    flags = 0x01 | (0x10 if empty else 0) | (0 if empty else 0x02)  # LE, empty flag, xy envelope
    head = b"GP" + struct.pack("<BBi", 0, flags, srs_id)
    if not empty:
        x0, y0, x1, y1 = geom.bounds
        head += struct.pack("<4d", x0, x1, y0, y1)
    return head + shapely.to_wkb(geom, flavor="iso", byte_order=1)


_ENVELOPE_DOUBLES = {0: 0, 1: 4, 2: 6, 3: 6, 4: 8}


def decode_geometry(blob: bytes | None) -> BaseGeometry | None:
    """A shapely geometry from a GeoPackage binary geometry (None for NULL)."""
    if blob is None:
        return None
    if blob[:2] != b"GP":
        raise ValueError("not a GeoPackage geometry blob")
    flags = blob[3]
    n = _ENVELOPE_DOUBLES.get((flags >> 1) & 0x07)
    if n is None:
        raise ValueError(f"bad envelope code in GeoPackage geometry flags {flags:#x}")
    return shapely.from_wkb(bytes(blob[8 + 8 * n:]))


def add_feature_table(conn: sqlite3.Connection, table: str, columns: Sequence[tuple[str, str]], geom_col: str,
                      geom_type: str, srs_id: int, *, z: bool = False, description: str = "") -> None:
    """Create a feature table (``fid INTEGER PRIMARY KEY`` + ``columns`` + geometry) and register it.

    ``columns`` are (name, SQL type with constraints) pairs; ``table`` and column names come from the
    caller's code, never from users.
    """
    cols = ", ".join(f'"{n}" {t}' for n, t in columns)
    conn.execute(f'CREATE TABLE "{table}" (fid INTEGER PRIMARY KEY AUTOINCREMENT, {cols}, "{geom_col}" {geom_type})')
    conn.execute("INSERT INTO gpkg_contents (table_name, data_type, identifier, description, srs_id) "
                 "VALUES (?, 'features', ?, ?, ?)", (table, table, description, srs_id))
    conn.execute("INSERT INTO gpkg_geometry_columns VALUES (?, ?, ?, ?, ?, 0)",
                 (table, geom_col, geom_type, srs_id, 1 if z else 0))
    conn.execute(f'CREATE VIRTUAL TABLE "rtree_{table}_{geom_col}" USING rtree(id, minx, maxx, miny, maxy)')
    conn.execute("INSERT INTO gpkg_extensions VALUES (?, ?, 'gpkg_rtree_index', "
                 "'http://www.geopackage.org/spec120/#extension_rtree', 'write-only')", (table, geom_col))


def add_attributes_table(conn: sqlite3.Connection, table: str, columns: Sequence[tuple[str, str]],
                         description: str = "") -> None:
    """Create a non-spatial table and register it in ``gpkg_contents`` as 'attributes'."""
    cols = ", ".join(f'"{n}" {t}' for n, t in columns)
    conn.execute(f'CREATE TABLE "{table}" ({cols})')
    conn.execute("INSERT INTO gpkg_contents (table_name, data_type, identifier, description) "
                 "VALUES (?, 'attributes', ?, ?)", (table, table, description))


def fill_rtree(conn: sqlite3.Connection, table: str, geom_col: str, fids: Iterable[int],
               bounds: np.ndarray) -> None:
    """Fill the R-tree from (N, 4) (minx, miny, maxx, maxy) bounds, set the extent, add the triggers.

    Rows with non-finite bounds (empty geometries) are left out, as the triggers would leave them out.
    """
    b = np.asarray(bounds, dtype=np.float64).reshape(-1, 4)
    fid_list = list(fids)
    ok = np.isfinite(b).all(axis=1)
    rows = [(int(fid_list[k]), float(b[k, 0]), float(b[k, 2]), float(b[k, 1]), float(b[k, 3]))
            for k in np.flatnonzero(ok)]
    conn.executemany(f'INSERT INTO "rtree_{table}_{geom_col}" VALUES (?, ?, ?, ?, ?)', rows)
    if ok.any():
        g = b[ok]
        conn.execute("UPDATE gpkg_contents SET min_x = ?, min_y = ?, max_x = ?, max_y = ? WHERE table_name = ?",
                     (float(g[:, 0].min()), float(g[:, 1].min()), float(g[:, 2].max()), float(g[:, 3].max()),
                      table))
    conn.executescript(_RTREE_TRIGGERS.format(t=table, c=geom_col, i="fid"))
