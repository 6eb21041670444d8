"""Local frames: east-north-up tangent frames on WGS84 and their ECEF matrices.

Decision 6 of the design: large coordinates never reach float32 unshifted. Every tile has a local origin
(its centre, held in float64 in the tile transform); the renderer keeps a scene origin near the camera.
Pure numpy; the CRS transformation of the origin itself happens in :mod:`citylod.io.crs`.
"""

from __future__ import annotations

import math

import numpy as np

from citylod.core.geometry import F64

WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)


def geodetic_to_ecef(lon_deg: float, lat_deg: float, h: float) -> F64:
    """WGS84 geodetic (degrees, metres) to ECEF (EPSG:4978) metres, (3,)."""
    lon, lat = math.radians(lon_deg), math.radians(lat_deg)
    n = WGS84_A / math.sqrt(1.0 - WGS84_E2 * math.sin(lat) ** 2)
    return np.array(
        [
            (n + h) * math.cos(lat) * math.cos(lon),
            (n + h) * math.cos(lat) * math.sin(lon),
            (n * (1.0 - WGS84_E2) + h) * math.sin(lat),
        ]
    )


def enu_to_ecef_matrix(lon_deg: float, lat_deg: float, h: float) -> F64:
    """4×4 matrix taking east-north-up metres at (lon, lat, h) to ECEF metres."""
    lon, lat = math.radians(lon_deg), math.radians(lat_deg)
    east = np.array([-math.sin(lon), math.cos(lon), 0.0])
    north = np.array([-math.sin(lat) * math.cos(lon), -math.sin(lat) * math.sin(lon), math.cos(lat)])
    up = np.array([math.cos(lat) * math.cos(lon), math.cos(lat) * math.sin(lon), math.sin(lat)])
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = east, north, up
    m[:3, 3] = geodetic_to_ecef(lon_deg, lat_deg, h)
    return m
