"""A default camera flight derived from the data's bounds, for benchmarks without a ``--path``.

Three legs of about equal length, each stressing the LOD differently: an approach from far away
(coarse levels, few tiles), a low pass across the data looking ahead (mixed levels, many tiles near the
camera), and an oblique orbit around the centre (a steady mix, every side seen).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from citylod.core.camera import Camera


def default_flight_legs(n: int = 30) -> list[tuple[str, range]]:
    """The legs of :func:`default_flight` with ``n`` cameras, as (name, camera indices); the flight is built
    from them, so the two cannot disagree."""
    k = max(n // 3, 1)
    return [("approach", range(0, k)), ("low pass", range(k, 2 * k)), ("orbit", range(2 * k, max(n, 2 * k)))]


def default_flight(lo: npt.ArrayLike, hi: npt.ArrayLike, n: int = 30, fovy_deg: float = 45.0) -> list[Camera]:
    """About ``n`` cameras (approach, low pass, orbit) over the box ``lo``–``hi`` (data CRS)."""
    lo_a = np.asarray(lo, np.float64)
    hi_a = np.asarray(hi, np.float64)
    centre = (lo_a + hi_a) / 2.0
    ext = float(max(hi_a[0] - lo_a[0], hi_a[1] - lo_a[1], 1.0))
    ground = float(lo_a[2] + 0.5 * (hi_a[2] - lo_a[2]))
    top = float(hi_a[2])
    approach, low_pass, orbit = (idx for _, idx in default_flight_legs(n))
    cams: list[Camera] = []
    target = np.array([centre[0], centre[1], ground])
    # Approach: from 4 extents away, at a 35° glide, down to half an extent.
    for i in range(len(approach)):
        s = i / max(len(approach) - 1, 1)
        dist = ext * (4.0 * (1 - s) + 0.5 * s)
        eye = target + dist * np.array([0.0, -math.cos(math.radians(35)), math.sin(math.radians(35))])
        cams.append(Camera(tuple(eye), tuple(target), (0.0, 0.0, 1.0), fovy_deg))
    # Low pass: south-west to north-east at 5 % of the extent above the highest point, looking ahead and
    # down at a point a fifth of the extent in front.
    a = np.array([lo_a[0] + 0.1 * ext, lo_a[1] + 0.1 * ext])
    b = np.array([hi_a[0] - 0.1 * ext, hi_a[1] - 0.1 * ext])
    heading = (b - a) / max(float(np.linalg.norm(b - a)), 1e-9)
    for i in range(len(low_pass)):
        p = a + (b - a) * (i / max(len(low_pass) - 1, 1))
        eye = np.array([p[0], p[1], top + 0.05 * ext])
        look = np.array([p[0] + heading[0] * 0.2 * ext, p[1] + heading[1] * 0.2 * ext, ground])
        cams.append(Camera(tuple(eye), tuple(look), (0.0, 0.0, 1.0), fovy_deg))
    # Oblique orbit: 45° down, at 0.8 extents, once around.
    for i in range(len(orbit)):
        az = 2 * math.pi * i / max(len(orbit), 1)
        r = 0.8 * ext
        eye = target + np.array([r * math.cos(az) * math.cos(math.pi / 4), r * math.sin(az) * math.cos(math.pi / 4),
                                 r * math.sin(math.pi / 4)])
        cams.append(Camera(tuple(eye), tuple(target), (0.0, 0.0, 1.0), fovy_deg))
    return cams
