"""CRS helpers: parsing user input, the tileset's ECEF placement, geographic detection.

The tileset's root transform places the data on the globe (EPSG:4978) so that any 3D Tiles client shows it
in the right place. citylod itself works in the source CRS (recorded in the tileset), so this placement is
only for other clients; it is an affine approximation (local tangent frame at the data's origin, with the
projection's grid convergence and scale factor), whose error grows with the square of the distance from the
origin (Earth curvature: about 2 m at 5 km). citylod never reads positions through it.
"""

from __future__ import annotations

import functools
import os
import re
import warnings
from typing import Any

import numpy as np
import pyproj

from citylod.core.errors import GeoreferenceError
from citylod.core.frames import enu_to_ecef_matrix
from citylod.core.geometry import F64


def parse_crs(value: Any, source: str | None = None) -> pyproj.CRS:
    """A pyproj CRS from EPSG codes, WKT, PROJ strings or an existing CRS; GeoreferenceError otherwise."""
    if isinstance(value, pyproj.CRS):
        return value
    try:
        return pyproj.CRS.from_user_input(value)
    except (pyproj.exceptions.CRSError, TypeError) as exc:
        raise GeoreferenceError(f"not a coordinate reference system: {value!r} ({exc})", source) from exc


# EPSG codes in the forms found in city model files: "EPSG:n", "urn:ogc:def:crs:EPSG::n", versioned
# "urn:ogc:def:crs:EPSG:6.12:n", "http(s)://www.opengis.net/def/crs/EPSG/0/n", ".../epsg.xml#n"; the version
# group must be consumed whole, or "EPSG:6.12:25833" reads as EPSG:6.
_EPSG_CODE = re.compile(r"EPSG(?::[0-9.]*:|/[0-9.]+/|\.xml#|:)([0-9]{1,6})(?![0-9.])", re.IGNORECASE)
_CRS84 = re.compile(r"(?:OGC:[0-9.]*:|OGC/[0-9.]+/)CRS84\b", re.IGNORECASE)

# AdV (German surveying authorities) CRS names used in ALKIS/CityGML: "urn:adv:crs:HORIZONTAL*VERTICAL[*...]".
_ADV_HORIZONTAL: dict[str, int] = {
    "ETRS89_UTM31": 25831, "ETRS89_UTM32": 25832, "ETRS89_UTM33": 25833,
    "DE_DHDN_3GK2": 31466, "DE_DHDN_3GK3": 31467, "DE_DHDN_3GK4": 31468, "DE_DHDN_3GK5": 31469,
    "ETRS89_LAT-LON": 4258, "DE_DHDN_LAT-LON": 4314,
}
_ADV_VERTICAL: dict[str, int] = {
    "DE_DHHN2016_NH": 7837, "DE_DHHN92_NH": 5783, "DE_DHHN85_NOH": 5784, "DE_SNN76_NH": 5785,
}


def _adv_codes(name: str) -> list[int] | None:
    """EPSG codes (horizontal, then vertical if known) of an AdV URN; None when ``name`` is not one."""
    m = re.match(r"\s*urn:adv:crs:([^\s]+)", name, re.IGNORECASE)
    if m is None:
        return None
    parts = m.group(1).upper().split("*")
    # Regional variants carry a suffix ("DE_DHDN_3GK3_BW100", "ETRS89_UTM32_HE"): match the longest known prefix.
    horiz = next((code for key, code in sorted(_ADV_HORIZONTAL.items(), key=lambda kv: -len(kv[0]))
                  if parts[0].startswith(key)), None)
    if horiz is None:
        return []
    vert = _ADV_VERTICAL.get(parts[1]) if len(parts) > 1 else None
    return [horiz] if vert is None else [horiz, vert]


def crs_from_srs_name(name: Any, source: str | None = None) -> pyproj.CRS:
    """The CRS named by a city model file (CityGML ``srsName``, CityJSON ``referenceSystem``).

    Understands EPSG codes in all the URN and URL spellings found in published files, versioned or not
    (``urn:ogc:def:crs:EPSG:6.12:25833``), compound URNs and URLs (``urn:ogc:def:crs,crs:EPSG::28992,crs:EPSG::5709``
    is the compound RD New + NAP height, not its last part), OGC CRS84 and the AdV names of German
    surveying data (``urn:adv:crs:ETRS89_UTM32*DE_DHHN2016_NH`` is EPSG:25832 + EPSG:7837). Other names go
    to pyproj as they are.

    Raises
    ------
    GeoreferenceError
        The name is not a CRS pyproj knows, or it names only a vertical CRS (positions could not be placed).

    Examples
    --------
    >>> crs_from_srs_name("urn:ogc:def:crs:EPSG:6.12:25833").to_epsg()
    25833
    >>> crs_from_srs_name("urn:adv:crs:ETRS89_UTM32*DE_DHHN2016_NH").name
    'ETRS89 / UTM zone 32N + DHHN2016 height'
    """
    text = str(name).strip()
    if len(text) > 4096:
        raise GeoreferenceError(f"not a coordinate reference system name ({len(text)} characters)", source)
    adv = _adv_codes(text)
    if adv is not None:
        if not adv:
            raise GeoreferenceError(f"unknown AdV coordinate reference system {text!r}", source)
        codes = [str(c) for c in adv]
    else:
        codes = _EPSG_CODE.findall(text)
    if len(codes) > 2:
        raise GeoreferenceError(f"{text!r} names {len(codes)} coordinate reference systems, expected at most 2",
                                source)
    if codes:
        crs = parse_crs("EPSG:" + "+".join(codes), source)
    elif _CRS84.search(text):
        crs = pyproj.CRS.from_user_input("OGC:CRS84")
    else:
        crs = parse_crs(text, source)
    if crs.is_vertical and not crs.is_compound:
        raise GeoreferenceError(f"{text!r} names only a vertical CRS ({crs.name}); positions need a horizontal "
                                "one", source)
    return crs


def horizontal_crs(crs: pyproj.CRS) -> pyproj.CRS:
    """The horizontal part of a compound CRS (e.g. EPSG:7415 → EPSG:28992); the CRS itself otherwise."""
    if crs.is_compound:
        for sub in crs.sub_crs_list:
            if sub.is_projected or sub.is_geographic:
                return sub
    return crs


def is_geographic(crs: pyproj.CRS) -> bool:
    """True when horizontal coordinates are angles (degrees), not metres."""
    return bool(horizontal_crs(crs).is_geographic)


def utm_crs_for(lon_deg: float, lat_deg: float) -> pyproj.CRS:
    """The WGS84 UTM zone CRS containing a point."""
    zone = int(np.floor((lon_deg + 180.0) / 6.0)) % 60 + 1
    epsg = (32600 if lat_deg >= 0 else 32700) + zone
    return pyproj.CRS.from_epsg(epsg)


@functools.lru_cache(maxsize=16)
def _to_wgs84(wkt: str) -> pyproj.Transformer:
    # Creating a transformer and its first transform cost ≈25 ms (PROJ sets up the pipeline); a process
    # writing many tilesets (tests, benchmarks, scripts) pays that once per CRS. Callers use the
    # transformer from one thread at a time (tileset writing happens on the calling thread).
    return pyproj.Transformer.from_crs(pyproj.CRS.from_wkt(wkt), "EPSG:4326", always_xy=True)


#: Folders searched for PROJ grids installed by packages (Debian's proj-data; pyproj's own data folder).
#: PROJ's network access stays off: nothing is downloaded at run time.
_GRID_DIRS = ("/usr/share/proj", "/usr/local/share/proj")
_GLOBAL_GEOID = "egm96_15.gtx"  # EGM96 geoid heights on a 15' grid, in Debian's proj-data


def _pyproj_data_dir() -> str:
    """pyproj's own data folder (the first of PROJ's search path once package folders are appended)."""
    return pyproj.datadir.get_data_dir().split(os.pathsep)[0]


@functools.lru_cache(maxsize=1)
def use_package_grids() -> None:
    """Let PROJ find the grids installed by packages (Debian's proj-data) for every transformation, after
    pyproj's own data folder (whose proj.db stays the one used). Network access stays off."""
    for folder in _GRID_DIRS:
        if os.path.isdir(folder) and folder != _pyproj_data_dir():
            pyproj.datadir.append_data_dir(folder)


def _grid_path(name: str) -> str | None:
    for folder in (_pyproj_data_dir(), *_GRID_DIRS):
        path = os.path.join(folder, name)
        if os.path.isfile(path):
            return path
    return None


@functools.lru_cache(maxsize=64)
def _height_offset(wkt: str, x: float, y: float, z: float, lon: float, lat: float) -> tuple[float, str | None]:
    crs = pyproj.CRS.from_wkt(wkt)
    vertical = next((c for c in crs.sub_crs_list if c.is_vertical), None) if crs.is_compound else None
    if vertical is None:
        return 0.0, None  # ellipsoidal heights already, or no vertical datum stated: taken as ellipsoidal
    use_package_grids()
    with warnings.catch_warnings():  # pyproj's warning names the missing grid; the message below does too
        warnings.simplefilter("ignore")
        group = pyproj.transformer.TransformerGroup(crs, "EPSG:4979", always_xy=True)
    missing = sorted({g.short_name for op in group.unavailable_operations for g in op.grids if not g.available})
    exact = [t for t in group.transformers if "ballpark vertical" not in t.description.lower()]
    if exact:
        return float(exact[0].transform(x, y, z)[2]) - z, None
    needs = f" (it needs the PROJ grid {', '.join(missing)})" if missing else ""
    geoid = _grid_path(_GLOBAL_GEOID)
    if geoid is not None:
        # A geoid model in place of the datum's own: EGM96 differs from national height datums by decimetres.
        n = float(pyproj.Transformer.from_pipeline(f"+proj=vgridshift +grids={geoid} +multiplier=1")
                  .transform(lon, lat, 0.0)[2])
        return n, (f"heights in {vertical.name} raised to the WGS84 ellipsoid with the EGM96 geoid "
                   f"({n:+.2f} m here), not the datum's own model{needs}: within about a metre")
    return 0.0, (f"heights in {vertical.name} written as WGS84 ellipsoidal heights: no geoid model is installed"
                 f"{needs}, so on a globe the data sits tens of metres off; install Debian's proj-data package "
                 f"(EGM96) or the datum's grid into {_pyproj_data_dir()}")


def compound_crs_for(crs: pyproj.CRS, limit: int = 3) -> list[str]:
    """Up to ``limit`` EPSG compound CRSs ("EPSG:7415 (Amersfoort / RD New + NAP height)") whose horizontal
    part is ``crs``, from PROJ's own database (proj.db, read-only); empty where there is none or the
    CRS has no EPSG code."""
    import sqlite3

    auth = crs.to_authority()
    if auth is None or auth[0] != "EPSG":
        return []
    try:
        path = os.path.join(_pyproj_data_dir(), "proj.db")
        db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        try:
            rows = db.execute("SELECT code, name FROM compound_crs WHERE auth_name = 'EPSG' "
                              "AND deprecated = 0 AND horiz_crs_auth_name = 'EPSG' AND horiz_crs_code = ? "
                              "ORDER BY CAST(code AS INTEGER) LIMIT ?", (auth[1], limit)).fetchall()
        finally:
            db.close()
    except sqlite3.Error:  # another PROJ database layout: no suggestion rather than a failed build
        return []
    return [f"EPSG:{code} ({name})" for code, name in rows]


def missing_vertical_datum(crs: pyproj.CRS) -> str | None:
    """Why heights in ``crs`` are written as WGS84 ellipsoidal heights; None where ``crs`` says what they are.

    A horizontal-only CRS (plain EPSG:28992, as Delft's LiDAR headers carry) names no vertical datum, so
    heights are taken as ellipsoidal; where they are in fact orthometric (NAP, DHHN, ...) they sit tens of
    metres off on a globe (43 m under the terrain at Delft). A compound CRS or a 3D geographic or geocentric
    one says what its heights are. The message names the compound CRSs EPSG pairs with ``crs``.
    """
    if crs.is_compound or crs.is_geocentric or len(crs.axis_info) >= 3:
        return None
    options = compound_crs_for(crs)
    hint = (f"if they are above a height datum, name its compound CRS, e.g. {' or '.join(options)}" if options
            else "if they are above a height datum, name a compound CRS that includes it")
    return f"{crs.name} has no vertical datum: heights are written as WGS84 ellipsoidal heights; {hint}"


def height_to_ellipsoid(crs: pyproj.CRS, x: float, y: float, z: float, lon: float, lat: float) -> float:
    """Metres to add to a height of ``crs`` at (x, y, z) (lon, lat in degrees) to get a WGS84 ellipsoidal height.

    A compound CRS with a vertical datum (Delft: EPSG:7415, RD New + NAP) goes through PROJ's transformation
    to EPSG:4979 when its grid is installed; otherwise through the EGM96 geoid of Debian's proj-data, with a
    warning that names the missing grid; otherwise 0, with a warning that the data will sit off on a globe.
    Grids come only from installed packages: PROJ's network access stays off.
    """
    offset, warning = _height_offset(crs.to_wkt(), float(x), float(y), float(z), float(lon), float(lat))
    if warning:
        warnings.warn(warning, stacklevel=3)
    return offset


def ecef_from_local(crs: pyproj.CRS, origin: F64) -> F64:
    """4×4 matrix from the local frame (source CRS coordinates minus ``origin``) to ECEF.

    The horizontal axes are mapped with the Jacobian of the projection at the origin (grid convergence and
    scale factor, from a central difference of ±100 m), heights go to the local up axis, raised from the CRS's
    vertical datum to the WGS84 ellipsoid at the origin (:func:`height_to_ellipsoid`). For a geographic CRS
    the local frame is already metric only after projection, so ``crs`` must be metric here.
    """
    h = horizontal_crs(crs)
    to_geo = _to_wgs84(h.to_wkt())
    x0, y0, z0 = (float(v) for v in origin)
    lon0, lat0 = to_geo.transform(x0, y0)
    if not (np.isfinite(lon0) and np.isfinite(lat0)):
        raise GeoreferenceError(f"cannot place origin {origin} of {h.name} on the globe")
    enu = enu_to_ecef_matrix(lon0, lat0, z0 + height_to_ellipsoid(crs, x0, y0, z0, lon0, lat0))
    # Jacobian of (x, y) -> (east, north) in metres, by central differences on the ellipsoid's tangent plane.
    d = 100.0
    pts_x = np.array([x0 - d, x0 + d, x0, x0])
    pts_y = np.array([y0, y0, y0 - d, y0 + d])
    lon, lat = to_geo.transform(pts_x, pts_y)
    geod = pyproj.Geod(ellps="WGS84")
    az, _, dist = geod.inv(np.full(4, lon0), np.full(4, lat0), lon, lat)
    az_r = np.radians(az)
    east = dist * np.sin(az_r)
    north = dist * np.cos(az_r)
    jac = np.array([[(east[1] - east[0]) / (2 * d), (east[3] - east[2]) / (2 * d)],
                    [(north[1] - north[0]) / (2 * d), (north[3] - north[2]) / (2 * d)]])
    local_to_enu = np.eye(4)
    local_to_enu[:2, :2] = jac
    return enu @ local_to_enu
