"""Measured screen-space error of an LOD frame against the full-resolution frame of the same camera.

Per pixel, both depth images give a 3D point along the same pixel ray (eye + d · ray). The measured
error is the object-space distance between the LOD point and the full-resolution point, divided by the
footprint of a pixel at that distance, ``2 · d · tan(fovy/2) / H`` (docs/DESIGN.md, decision 2): the error in pixels.

Two variants, both reported by the benchmark:

* ``ray``: the two points on the same ray (``|d_lod - d_full|``). This is what the request defines; at
  grazing angles and on silhouettes it overstates the error (a vertical offset δ seen at angle θ moves
  the hit by δ / sin θ along the ray; a silhouette pixel may hit a different object).
* ``near``: the distance from the LOD point to the full-resolution *surface* seen within ±``radius``
  pixels, the surface being interpolated between neighbouring full-resolution pixel points (two triangles
  per 2×2 block of pixels, skipped where the block straddles a depth discontinuity of more than 5 %).
  It approximates the one-sided Hausdorff distance the geometric error bounds, and is robust to
  silhouettes; distances to the pixel points alone would overstate it by up to half a pixel.

Pixels covered by only one of the two frames are counted apart: LOD-only pixels are overhangs, and
full-only pixels are holes or cracks in the LOD frame.

Pure numpy, no VTK.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from numba import njit

from citylod.core.camera import Camera
from citylod.core.jit import defer_blas_probe
from citylod.lod.kernels.distance import point_triangle_sq
from citylod.render.depth import world_rays

defer_blas_probe()  # before any kernel loads: numba starts without importing scipy.linalg


@dataclass(frozen=True)
class ErrorStats:
    """Measured error of one frame, pixels. ``valid`` pixels have geometry in both frames."""

    max_px: float
    p99_px: float
    near_max_px: float
    near_p99_px: float
    valid: int
    lod_only: int
    full_only: int


def measure_error(depth_lod: npt.ArrayLike, depth_full: npt.ArrayLike, camera: Camera, *, radius: int = 2,
                  return_maps: bool = False) -> ErrorStats | tuple[ErrorStats, npt.NDArray[np.float64]]:
    """Screen-space error of an LOD depth image against the full-resolution one, in pixels.

    Parameters
    ----------
    depth_lod, depth_full
        (H, W) distances from the eye along each pixel ray (``inf`` = background), same camera and size.
    camera
        The camera both were rendered with.
    radius
        Half-size of the window searched for the ``near`` variant, pixels.
    return_maps
        Also return the per-pixel ``ray`` error map (H, W), NaN where not valid.
    """
    dl = np.asarray(depth_lod, np.float64)
    df = np.asarray(depth_full, np.float64)
    h, w = df.shape
    fl, ff = np.isfinite(dl), np.isfinite(df)
    valid = fl & ff
    footprint = 2.0 * df * math.tan(math.radians(camera.fovy_deg) / 2.0) / h
    with np.errstate(invalid="ignore"):
        ray_err = np.where(valid, np.abs(dl - df) / footprint, np.nan)
    # Points relative to the eye, so differences stay exact at large coordinates.
    rays = world_rays(camera, w, h)
    p_lod = rays * np.where(fl, dl, np.nan)[..., None]
    p_full = rays * np.where(ff, df, np.nan)[..., None]
    best = _near_surface(p_lod, p_full, df, radius)
    with np.errstate(invalid="ignore"):
        near_err = np.where(valid, best / footprint, np.nan)
    v_ray = ray_err[valid]
    # The frame's outer ``radius`` pixels are left out of the near statistic: there the nearest surface
    # may lie outside the image.
    inner = np.zeros_like(valid)
    inner[radius:h - radius, radius:w - radius] = True
    v_near = near_err[valid & inner]
    stats = ErrorStats(
        max_px=float(v_ray.max()) if v_ray.size else 0.0,
        p99_px=float(np.percentile(v_ray, 99)) if v_ray.size else 0.0,
        near_max_px=float(v_near.max()) if v_near.size else 0.0,
        near_p99_px=float(np.percentile(v_near, 99)) if v_near.size else 0.0,
        valid=int(valid.sum()),
        lod_only=int((fl & ~ff).sum()),
        full_only=int((ff & ~fl).sum()),
    )
    return (stats, ray_err) if return_maps else stats


@njit(cache=True, nogil=True)
def _point_triangle_distance(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    return math.sqrt(point_triangle_sq(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz))


@njit(cache=True, nogil=True)
def _near_surface(p_lod, p_full, d_full, radius):
    h, w = d_full.shape
    best = np.full((h, w), np.inf)
    for y in range(h):
        for x in range(w):
            px, py, pz = p_lod[y, x, 0], p_lod[y, x, 1], p_lod[y, x, 2]
            if not np.isfinite(px):
                continue
            m = np.inf
            for yy in range(max(0, y - radius), min(h - 1, y + radius + 1)):
                for xx in range(max(0, x - radius), min(w - 1, x + radius + 1)):
                    d00, d01 = d_full[yy, xx], d_full[yy, xx + 1]
                    d10, d11 = d_full[yy + 1, xx], d_full[yy + 1, xx + 1]
                    ax, ay, az = p_full[yy, xx, 0], p_full[yy, xx, 1], p_full[yy, xx, 2]
                    if not (np.isfinite(d00) and np.isfinite(d01) and np.isfinite(d10) and np.isfinite(d11)):
                        if np.isfinite(d00):  # a lone point still counts
                            m = min(m, math.sqrt((px - ax) ** 2 + (py - ay) ** 2 + (pz - az) ** 2))
                        continue
                    lo = min(min(d00, d01), min(d10, d11))
                    hi = max(max(d00, d01), max(d10, d11))
                    if hi - lo > 0.05 * lo:  # a silhouette: do not bridge foreground and background
                        m = min(m, math.sqrt((px - ax) ** 2 + (py - ay) ** 2 + (pz - az) ** 2))
                        continue
                    bx, by, bz = p_full[yy, xx + 1, 0], p_full[yy, xx + 1, 1], p_full[yy, xx + 1, 2]
                    cx, cy, cz = p_full[yy + 1, xx, 0], p_full[yy + 1, xx, 1], p_full[yy + 1, xx, 2]
                    ex, ey, ez = p_full[yy + 1, xx + 1, 0], p_full[yy + 1, xx + 1, 1], p_full[yy + 1, xx + 1, 2]
                    m = min(m, _point_triangle_distance(px, py, pz, ax, ay, az, bx, by, bz, ex, ey, ez))
                    m = min(m, _point_triangle_distance(px, py, pz, ax, ay, az, ex, ey, ez, cx, cy, cz))
            best[y, x] = m
    return best
