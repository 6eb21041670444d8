"""The measured screen-space error against analytic cases (no rendering: depth images from ray casting)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from citylod.core.camera import Camera
from citylod.render.depth import world_rays
from citylod.render.sse import measure_error


def _plane_depth(cam: Camera, w: int, h: int, normal: np.ndarray, offset: float) -> np.ndarray:
    """Distance along each pixel ray to the plane n·x = offset (inf where missed or behind)."""
    rays = world_rays(cam, w, h)
    eye = np.asarray(cam.position, float)
    denom = rays @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (offset - eye @ normal) / denom
    return np.where(t > 0, t, np.inf)


@pytest.mark.parametrize("slope_deg", [0.0, 30.0])
def test_near_error_is_the_distance_between_parallel_planes(slope_deg: float) -> None:
    cam = Camera((0.0, -300.0, 200.0), (0.0, 0.0, 0.0), fovy_deg=45)
    w, h = 160, 120
    n = np.array([0.0, -math.sin(math.radians(slope_deg)), math.cos(math.radians(slope_deg))])
    delta = 0.5  # the LOD plane is 0.5 m above the full-resolution plane, along its normal
    full = _plane_depth(cam, w, h, n, 0.0)
    lod = _plane_depth(cam, w, h, n, delta)
    stats, _ = measure_error(lod, full, cam, return_maps=True)
    # independent expectation per pixel: delta / footprint at that depth
    foot = 2.0 * full * math.tan(math.radians(22.5)) / h
    ok = np.isfinite(full) & np.isfinite(lod)
    expected = delta / foot[ok]
    assert stats.near_max_px == pytest.approx(expected.max(), rel=0.03)
    assert stats.near_p99_px == pytest.approx(np.percentile(expected, 99), rel=0.03)
    # along the ray, an oblique view sees more than the normal distance
    assert stats.p99_px >= stats.near_p99_px
