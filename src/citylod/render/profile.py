"""Height profile along a line, read from the geometry a :class:`~citylod.render.tileset_actor.Scene` draws.

The profile is what the user sees: the surface of the tiles drawn in the last frame (skirts left out),
so its heights are within the drawn tiles' ``geometricError`` of the full-resolution data, and that
bound is returned with it. Point layers give the highest point within a corridor around each sample.
No VTK objects are touched; the function only reads the prepared tile arrays.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["Profile", "surface_profile"]

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Profile:
    """Heights along the line ``a``–``b``.

    ``xyz`` (N, 3) float64 sample positions in the data's CRS with their surface height (NaN where no
    drawn geometry covers the sample); ``distance`` (N,) metres from ``a`` along the horizontal line;
    ``bound_m`` the largest ``geometricError`` of the tiles the heights come from (0 when none).
    """

    a: tuple[float, float, float]
    b: tuple[float, float, float]
    distance: F64
    xyz: F64
    bound_m: float
    #: ``distance`` is measured on the ellipsoid (geodesic from ``a``), not on the projection's plane.
    ellipsoidal: bool = False

    @property
    def heights(self) -> F64:
        return self.xyz[:, 2]


def _world(positions: npt.NDArray[np.float32], matrix: F64) -> F64:
    p = positions.astype(np.float64)
    return p @ matrix[:3, :3].T + matrix[:3, 3]


def _mesh_heights(xy: F64, a: F64, normal: F64, world: F64, surface: npt.NDArray[np.int64]) -> F64:
    """Highest point of the triangles (world (N, 3), flat ``surface``) above each sample ``xy`` (S, 2) of
    the line through ``a`` with unit ``normal``; NaN where no triangle covers the sample.

    Only triangles that straddle the line can cover a sample, so they are kept first (a line crosses
    O(length / triangle size) of them), then every kept triangle is tested against every sample with
    barycentric coordinates, vectorised. A TIN with façades has several triangles over one point in
    plan view: the highest wins, as seen from above.
    """
    tri = np.asarray(surface, np.int64).reshape(-1, 3)
    out = np.full(len(xy), np.nan)
    if not len(tri):
        return out
    side = (world[:, :2] - a) @ normal
    s = side[tri]
    tri = tri[(s.min(axis=1) <= 1e-9) & (s.max(axis=1) >= -1e-9)]
    if not len(tri):
        return out
    p0, p1, p2 = world[tri[:, 0]], world[tri[:, 1]], world[tri[:, 2]]
    e1, e2 = (p1 - p0)[:, :2], (p2 - p0)[:, :2]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    flat = np.abs(det) > 1e-12  # walls (vertical in plan view) cover no area
    p0, p1, p2, e1, e2, det = p0[flat], p1[flat], p2[flat], e1[flat], e2[flat], det[flat]
    for lo in range(0, len(p0), 4096):  # bounded memory: samples × 4096 triangles at a time
        sl = slice(lo, lo + 4096)
        r = xy[:, None, :] - p0[None, sl, :2]
        u = (r[..., 0] * e2[None, sl, 1] - r[..., 1] * e2[None, sl, 0]) / det[None, sl]
        v = (e1[None, sl, 0] * r[..., 1] - e1[None, sl, 1] * r[..., 0]) / det[None, sl]
        eps = 1e-9
        inside = (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps)
        z = p0[None, sl, 2] + u * (p1[None, sl, 2] - p0[None, sl, 2]) + v * (p2[None, sl, 2] - p0[None, sl, 2])
        z = np.where(inside, z, -np.inf).max(axis=1)
        hit = np.isfinite(z)
        out[hit] = np.fmax(out[hit], z[hit])
    return out


def _point_heights(xy: F64, a: F64, direction: F64, length: float, step: float, world: F64) -> F64:
    """Highest point within half a sample step of the line at each sample; NaN where none."""
    rel = world[:, :2] - a
    along = rel @ direction
    across = np.abs(rel @ np.array([-direction[1], direction[0]]))
    keep = (across <= step) & (along >= -step / 2) & (along <= length + step / 2)
    out = np.full(len(xy), -np.inf)
    idx = np.clip(np.rint(along[keep] / step).astype(np.int64), 0, len(xy) - 1)
    np.maximum.at(out, idx, world[keep, 2])
    out[~np.isfinite(out)] = np.nan
    return out


def surface_profile(scene: Any, a: npt.ArrayLike, b: npt.ArrayLike, samples: int = 256) -> Profile:
    """Heights of the drawn surface along the horizontal line from ``a`` to ``b`` ((3,) or (2,), data CRS).

    Parameters
    ----------
    scene
        The :class:`~citylod.render.tileset_actor.Scene`; the tiles shown in its last frame are read.
    samples
        Number of equally spaced samples, ends included.

    Where several tiles or layers cover a sample the highest surface wins (a roof over the ground).
    """
    pa, pb = np.asarray(a, np.float64)[:2], np.asarray(b, np.float64)[:2]
    n = max(int(samples), 2)
    length = float(np.linalg.norm(pb - pa))
    t = np.linspace(0.0, 1.0, n)
    xy = pa + t[:, None] * (pb - pa)
    z = np.full(n, np.nan)
    direction = (pb - pa) / length if length > 0 else np.array([1.0, 0.0])
    normal = np.array([-direction[1], direction[0]])
    step = max(length / (n - 1), 1e-9)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    bound = 0.0
    for layer in scene.layers:
        if not layer.visible:
            continue
        for key in layer.shown_keys:
            slot = layer._slots.get(key)
            node = layer.node(key)
            if slot is None or slot.prepared is None:
                continue
            box_lo, box_hi = node.box.corners().min(axis=0), node.box.corners().max(axis=0)
            if np.any(box_hi[:2] < lo - step) or np.any(box_lo[:2] > hi + step):
                continue
            matrix = np.asarray(node.matrix, np.float64)  # prepared positions → scene CRS
            heights = []
            for mesh in slot.prepared.meshes:
                heights.append(_mesh_heights(xy, pa, normal, _world(mesh.positions, matrix), mesh.surface))
            pts = slot.prepared.points
            if pts is not None and len(pts.positions):
                heights.append(_point_heights(xy, pa, direction, length, step, _world(pts.positions, matrix)))
            for h in heights:
                hit = np.isfinite(h)
                if hit.any():
                    bound = max(bound, node.geometric_error)
                    z[hit] = np.fmax(z[hit], h[hit])
    xyz = np.column_stack([xy, z])
    return Profile(tuple(np.append(pa, 0.0)), tuple(np.append(pb, 0.0)),  # type: ignore[arg-type]
                   t * length, xyz, float(bound))
