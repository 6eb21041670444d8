"""Depth buffers as distances: z-buffer to eye distance, pixel rays, and 3D points back from depth.

Pure numpy (no VTK), so the benchmark's error measurement and the tests can use it on saved arrays.
Images here are top row first, as PNGs are; VTK's buffers are bottom row first and are flipped by the
caller (:mod:`citylod.render.offscreen`).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from citylod.core.camera import Camera

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]


def ray_directions_eye(width: int, height: int, fovy_deg: float) -> F64:
    """Per-pixel ray directions in eye space, (H, W, 3) float64, not normalised, with z = -1.

    Pixel centres; row 0 is the top of the image; x right, y up, looking down -z (OpenGL eye space).
    """
    ty = math.tan(math.radians(fovy_deg) / 2.0)
    tx = ty * width / height
    xs = ((np.arange(width) + 0.5) / width * 2.0 - 1.0) * tx
    ys = (1.0 - (np.arange(height) + 0.5) / height * 2.0) * ty
    d = np.empty((height, width, 3))
    d[..., 0] = xs[None, :]
    d[..., 1] = ys[:, None]
    d[..., 2] = -1.0
    return d


def zbuffer_to_distance(zbuffer: npt.ArrayLike, near: float, far: float, fovy_deg: float) -> F32:
    """Convert an OpenGL window-space depth buffer to the distance from the eye along each pixel ray.

    Parameters
    ----------
    zbuffer
        (H, W) values in [0, 1] (top row first), as ``glReadPixels(GL_DEPTH_COMPONENT)`` returns.
    near, far
        The clipping range the frame was drawn with (positive distances along the view axis).
    fovy_deg
        Vertical field of view.

    Returns
    -------
    (H, W) float32
        Euclidean distance from the eye to the surface seen in each pixel; ``inf`` where nothing was
        drawn (z-buffer at the far plane).
    """
    zb = np.asarray(zbuffer, dtype=np.float64)
    h, w = zb.shape
    z_ndc = 2.0 * zb - 1.0
    # Inverse of the perspective depth mapping: eye-space depth along the view axis (positive).
    z_eye = 2.0 * near * far / ((far + near) - z_ndc * (far - near))
    rays = ray_directions_eye(w, h, fovy_deg)
    stretch = np.sqrt(rays[..., 0] ** 2 + rays[..., 1] ** 2 + 1.0)  # |ray| for a unit step along -z
    dist = z_eye * stretch
    dist[zb >= 1.0] = np.inf
    return dist.astype(np.float32)


def world_rays(camera: Camera, width: int, height: int) -> F64:
    """Unit ray directions per pixel in the data's frame, (H, W, 3) float64 (row 0 = top)."""
    right, up, fwd = camera.basis()
    d = ray_directions_eye(width, height, camera.fovy_deg)
    world = d[..., 0:1] * right + d[..., 1:2] * up + (-d[..., 2:3]) * fwd
    return world / np.linalg.norm(world, axis=-1, keepdims=True)


def points_from_distance(distance: npt.ArrayLike, camera: Camera, *, relative: bool = True) -> F64:
    """3D points (H, W, 3) seen in each pixel, from a distance image; NaN where the distance is inf.

    With ``relative`` (default) the points are relative to the eye, which keeps differences between two
    such images exact even at 5e6 m coordinates; otherwise in the data's frame.
    """
    dist = np.asarray(distance, dtype=np.float64)
    h, w = dist.shape
    rays = world_rays(camera, w, h)
    with np.errstate(invalid="ignore"):
        pts = rays * np.where(np.isfinite(dist), dist, np.nan)[..., None]
    if not relative:
        pts = pts + np.asarray(camera.position, np.float64)
    return pts


def pixel_footprint(distance: npt.ArrayLike, height_px: int, fovy_deg: float) -> F64:
    """Object-space size of one pixel at ``distance``: ``2 · d · tan(fovy/2) / H`` (docs/DESIGN.md, decision 2)."""
    return 2.0 * np.asarray(distance, np.float64) * math.tan(math.radians(fovy_deg) / 2.0) / height_px
