"""Building footprints from a GeoPackage or an OGR SQLite file (e.g. the Dutch BGT ``pand`` layer).

:func:`read_footprints` returns the polygons of the first (or the named) polygon table as shapely
geometries, in the file's CRS. GeoPackage geometries are decoded by :func:`citylod.io.gpkg.decode_geometry`,
OGR SQLite ones are plain WKB (``geometry_columns.geometry_format = 'WKB'``). No VTK, no Qt.
"""

from __future__ import annotations

import sqlite3
from os import PathLike
from pathlib import Path

import shapely
from shapely.geometry.base import BaseGeometry

from citylod.core.errors import InputError

__all__ = ["read_footprints"]


def read_footprints(path: str | PathLike[str], table: str | None = None) -> list[BaseGeometry]:
    """Polygons and multipolygons of ``table`` (default: the first table with a geometry column).

    Raises :class:`~citylod.core.errors.InputError` naming the file when it is no SQLite database, has no
    geometry table, or holds no polygon.
    """
    from citylod.io.gpkg import decode_geometry

    p = Path(path)
    if not p.is_file():
        raise InputError("no such footprint file", p)
    try:
        conn = sqlite3.connect(f"file:{p}?mode=ro", uri=True)
        with conn:
            names = {r[0] for r in conn.execute("select name from sqlite_master where type='table'")}
            if "gpkg_geometry_columns" in names:
                cols = list(conn.execute("select table_name, column_name from gpkg_geometry_columns"))
                gpkg = True
            elif "geometry_columns" in names:
                cols = list(conn.execute("select f_table_name, f_geometry_column from geometry_columns"))
                gpkg = False
            else:
                raise InputError("no geometry table (neither a GeoPackage nor an OGR SQLite file)", p)
            if table is not None:
                cols = [c for c in cols if c[0] == table]
            if not cols:
                raise InputError(f"no geometry table {table!r}", p)
            tname, gcol = cols[0]
            blobs = [r[0] for r in conn.execute(f'select "{gcol}" from "{tname}"')]  # names from the file's catalogue
        conn.close()
    except sqlite3.DatabaseError as exc:
        raise InputError(f"not a readable SQLite database ({exc})", p) from exc
    out = []
    for b in blobs:
        if b is None:
            continue
        try:
            g = decode_geometry(b) if gpkg else shapely.from_wkb(bytes(b))
        except Exception as exc:
            raise InputError(f"undecodable geometry in table {tname!r} ({exc})", p) from exc
        if g is not None and g.geom_type in ("Polygon", "MultiPolygon") and not g.is_empty:
            out.append(g)
    if not out:
        raise InputError(f"table {tname!r} holds no polygon", p)
    return out
