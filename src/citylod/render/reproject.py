"""On-the-fly reprojection of a tileset layer into the scene's CRS (what QGIS calls on-the-fly CRS transformation).

A :class:`~citylod.render.tileset_actor.Scene` is drawn in the CRS of its first layer. A later layer in another
CRS gets a :class:`Reprojection` (from :func:`reprojection_for`); then

* its **tile contents** are transformed on the loader's worker threads, after decoding and before the scene
  origin shift: float32 tile-local positions → float64 source-CRS coordinates → pyproj → float64 scene-CRS
  coordinates → float32 relative to a new tile centre (:meth:`Reprojection.prepared`). The GUI thread only
  uploads, as for any tile;
* its **bounding volumes and geometric errors** are transformed once, when the layer is added
  (:meth:`Reprojection.boxes`), so that culling and screen-space error stay conservative (argument below).

A layer in the scene's own CRS gets no :class:`Reprojection` at all: nothing is transformed and its tiles,
boxes and bytes are those of the tileset.

**Why selection stays conservative.** Let T be the map from the layer's CRS to the scene's, smooth over a
tile's box B (half-widths h_a along its axes). Sample T on the 3×3×3 grid of B (corners, edge and face
midpoints, centre). On each of the 8 grid cells the trilinear interpolant of T lies in the convex hull of
the cell's corner images, hence in the axis-aligned box of the samples, and it differs from T by at most
``Σ_a h_a²/8 · max|∂²T/∂x_a²|`` per component (tensor-product linear interpolation; each factor has max-norm
1). The second differences of the samples along each axis estimate ``h_a² ∂²T/∂x_a²``; the box is padded by
twice that bound, so the padded box contains T(B), which contains the transformed content (the content lies in
B). The factor 2 covers the change of the second derivative across a tile: the derivatives of the
projections citylod meets vary on the scale of the Earth's radius, so over a tile of a few kilometres they
change by well under 1 %. The geometric error ε of a tile (a Hausdorff distance, docs/DESIGN.md decision 2)
becomes ``L·ε + c``: distances grow at most by the Lipschitz constant L of T over B, bounded by the largest
singular value of the Jacobian at the centre plus half-widths times the (estimated, doubled) second
derivatives; and c bounds how far a straight triangle edge or face between transformed vertices lies from
the true curved image of the source triangle: linear interpolation on a simplex errs by at most
``½·ρ²·‖∂²T‖``, ρ the radius of a ball holding the simplex (Waldron 1998), here B's circumscribed ball (ρ is
half B's diagonal), with the doubled second-derivative estimate. A tile therefore never looks
better on screen than it is, and culling never drops a tile that is in view.

**Geographic CRSs are refused** (:class:`~citylod.core.errors.CitylodError`): a scene in degrees would mix
degrees and metres in one frame, where screen-space error and the camera mean nothing, and citylod builds
never write a geographic tileset (they reproject to UTM). Vertical coordinates are transformed where both
CRSs state them (compound, 3D geographic or geocentric CRSs); otherwise heights pass unchanged and only x, y
are transformed (a 2D datum shift must not treat orthometric heights as ellipsoidal ones). PROJ grids come only
from installed packages: pyproj's network access stays off (its default), nothing is downloaded.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import numpy.typing as npt
import pyproj

from citylod.core.errors import CitylodError
from citylod.core.geometry import F64, Box
from citylod.io.crs import is_geographic, use_package_grids
from citylod.render.tile_data import PreparedTile

__all__ = ["Reprojection", "crs_label", "reprojection_for"]

# The 3×3×3 sampling grid of a box in its own unit coordinates, index (i, j, k) = 9·(i+1) + 3·(j+1) + (k+1).
_GRID = np.array([[i, j, k] for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)], dtype=np.float64)
# Half-width given to a flat box axis for sampling (metres): the sampled box only grows, so this stays safe.
_MIN_HALF = 0.5


def crs_label(crs: Any) -> str:
    """``EPSG:25832`` when the CRS has a code, else its name (for messages)."""
    try:
        epsg = crs.to_epsg()
    except Exception:  # pyproj raises several types for odd CRSs; the name is good enough then
        epsg = None
    return f"EPSG:{epsg}" if epsg else str(getattr(crs, "name", crs))


def _has_vertical(crs: pyproj.CRS) -> bool:
    return bool(crs.is_compound or crs.is_geocentric or len(crs.axis_info) >= 3)


class Reprojection:
    """The transformation of one layer's coordinates into the scene's CRS (made by :func:`reprojection_for`).

    ``use_z``: heights are transformed too (both CRSs state a vertical component, or one is geocentric).
    pyproj transformers are thread-safe (pyproj ≥ 3.1), so the loader's workers share this one.
    """

    def __init__(self, src: pyproj.CRS, dst: pyproj.CRS, transformer: pyproj.Transformer, source: str) -> None:
        self.src = src
        self.dst = dst
        self.transformer = transformer
        self.source = source
        self.use_z = (_has_vertical(src) and _has_vertical(dst)) or src.is_geocentric or dst.is_geocentric

    @property
    def label(self) -> str:
        """``EPSG:3035 reprojected on the fly to EPSG:32632`` (the app's status message, after the file name)."""
        return f"{crs_label(self.src)} reprojected on the fly to {crs_label(self.dst)}"

    def points(self, xyz: npt.ArrayLike) -> F64:
        """(N, 3) float64 coordinates in the layer's CRS → (N, 3) float64 in the scene's CRS.

        Raises CitylodError when a point falls outside the transformation's domain (an infinite result).
        """
        p = np.asarray(xyz, np.float64).reshape(-1, 3)
        x, y, z = (np.array(p[:, i]) for i in range(3))  # contiguous copies, transformed in place
        self._transform(x, y, z)
        return np.stack([x, y, z], axis=1)

    def _transform(self, x: F64, y: F64, z: F64) -> None:
        # In place on contiguous float64 columns: half the time of pyproj's strided-column copies
        # (docs/PERFORMANCE_LOG.md); heights stay as they are unless both CRSs state them.
        if self.use_z:
            self.transformer.transform(x, y, z, inplace=True)
        else:
            self.transformer.transform(x, y, inplace=True)
        if not (np.isfinite(x).all() and np.isfinite(y).all() and np.isfinite(z).all()):
            raise CitylodError(f"coordinates in {crs_label(self.src)} fall outside the transformation to "
                               f"{crs_label(self.dst)} ({self.transformer.description})", self.source)

    # -- bounding volumes -----------------------------------------------------------------------------
    def boxes(self, boxes: list[Box], errors: npt.ArrayLike) -> tuple[list[Box], F64, F64]:
        """Transform tiles' boxes and geometric errors (vectorised over all tiles, one pyproj call).

        Returns axis-aligned boxes in the scene's CRS that contain the image of each box (padded by the
        interpolation bound of the module docstring), the geometric errors ``L·ε + c``, and the scale
        bounds L (for tests and reports).
        """
        n = len(boxes)
        if n == 0:
            return [], np.zeros(0), np.zeros(0)
        centers = np.array([b.center for b in boxes], np.float64)
        axes = np.array([b.half_axes for b in boxes], np.float64)  # (n, 3, 3), one half-axis per column
        axes = _sampling_axes(axes)
        half = np.linalg.norm(axes, axis=1)  # (n, 3) half-widths h_a
        pts = centers[:, None, :] + np.einsum("gk,nik->ngi", _GRID, axes)
        o = self.points(pts.reshape(-1, 3)).reshape(n, 3, 3, 3, 3)  # [tile, i, j, k, component]
        lo = o.reshape(n, 27, 3).min(axis=1)
        hi = o.reshape(n, 27, 3).max(axis=1)
        # Second differences along each box axis (unit steps in box coordinates): ≈ h_a² ∂²T/∂x_a².
        d2 = [o[:, 2] - 2 * o[:, 1] + o[:, 0],
              o[:, :, 2] - 2 * o[:, :, 1] + o[:, :, 0],
              o[:, :, :, 2] - 2 * o[:, :, :, 1] + o[:, :, :, 0]]
        pure = np.stack([np.abs(d).reshape(n, -1, 3).max(axis=1) for d in d2], axis=1)  # (n, axis, component)
        # Twice the trilinear interpolation bound Σ_a h_a²/8 |∂²_a T|, per component; plus rounding room.
        pad = 0.25 * pure.sum(axis=1) + 1e-9 * np.abs(hi).max(axis=1, keepdims=True) + 1e-6
        lo, hi = lo - pad, hi + pad
        out = [Box.from_bounds(a, b) for a, b in zip(lo, hi, strict=True)]
        # Hessian estimate ∂²T/∂x_a∂x_b (metres⁻¹), norm over components: pure terms from the second
        # differences, mixed ones from the cross differences through the centre.
        hess = np.zeros((n, 3, 3))
        for a in range(3):
            hess[:, a, a] = np.linalg.norm(d2[a].reshape(n, -1, 3), axis=2).max(axis=1) / half[:, a] ** 2
        for a, b in ((0, 1), (0, 2), (1, 2)):
            def at(sa: int, sb: int, a: int = a, b: int = b) -> F64:
                idx = [1, 1, 1]
                idx[a], idx[b] = sa, sb
                return o[:, idx[0], idx[1], idx[2]]
            mixed = (at(2, 2) - at(2, 0) - at(0, 2) + at(0, 0)) / 4.0
            hess[:, a, b] = hess[:, b, a] = np.linalg.norm(mixed, axis=1) / (half[:, a] * half[:, b])
        hess *= 2.0  # the safety factor of the module docstring
        # Jacobian at the centre by central differences along the box axes, mapped back to x, y, z.
        jac_u = np.stack([(o[:, 2, 1, 1] - o[:, 0, 1, 1]) / (2 * half[:, 0:1]),
                          (o[:, 1, 2, 1] - o[:, 1, 0, 1]) / (2 * half[:, 1:2]),
                          (o[:, 1, 1, 2] - o[:, 1, 1, 0]) / (2 * half[:, 2:3])], axis=2)  # (n, comp, axis)
        sigma = np.linalg.svd(jac_u, compute_uv=False)[:, 0]
        variation = (half * np.sqrt((hess ** 2).sum(axis=2))).sum(axis=1)
        scale = sigma + variation
        # ½·ρ²·‖∂²T‖ with ρ² ≤ Σ h_a² (a triangle in B lies in B's circumscribed ball); the 2 is in ``hess``.
        chord = 0.5 * (half ** 2).sum(axis=1) * np.sqrt((hess ** 2).sum(axis=(1, 2)))
        return out, scale * np.asarray(errors, np.float64) + chord, scale

    # -- contents ---------------------------------------------------------------------------------------
    def local(self, positions: npt.ArrayLike, src_matrix: F64, dst_center: F64) -> npt.NDArray[np.float32]:
        """Tile-local float32 ``positions`` (mapped by ``src_matrix`` into the layer's CRS) → float32 relative
        to ``dst_center`` in the scene's CRS; float64 throughout until the final subtraction."""
        p = np.asarray(positions).reshape(-1, 3).astype(np.float64)
        m = np.asarray(src_matrix, np.float64)
        x, y, z = (p @ m[i, :3] + m[i, 3] for i in range(3))
        self._transform(x, y, z)
        c = np.asarray(dst_center, np.float64)
        out = np.empty((len(p), 3), np.float32)
        out[:, 0], out[:, 1], out[:, 2] = x - c[0], y - c[1], z - c[2]
        return out

    def prepared(self, tile: PreparedTile, src_matrix: F64, dst_center: F64) -> PreparedTile:
        """A copy of a decoded tile with every mesh and point position transformed (:meth:`local`);
        connectivity, texture coordinates, colours and attributes are shared, not copied."""
        meshes = [dataclasses.replace(m, positions=self.local(m.positions, src_matrix, dst_center))
                  if len(m.positions) else m for m in tile.meshes]
        points = tile.points
        if points is not None and len(points.positions):
            points = dataclasses.replace(points, positions=self.local(points.positions, src_matrix, dst_center))
        return PreparedTile(key=tile.key, level=tile.level, meshes=meshes, points=points)


def _sampling_axes(axes: F64) -> F64:
    """Half-axes with flat ones widened to :data:`_MIN_HALF` (along the normal of the others, or the
    coordinate axis), so that every direction is sampled and the derivatives are defined."""
    out = axes.copy()
    norms = np.linalg.norm(out, axis=1)  # (n, 3)
    for t, a in zip(*np.nonzero(norms < _MIN_HALF), strict=True):
        v = out[t, :, a]
        length = float(np.linalg.norm(v))
        if length > 1e-12:
            out[t, :, a] = v / length * _MIN_HALF
            continue
        others = [out[t, :, b] for b in range(3) if b != a]
        normal = np.cross(others[0], others[1])
        nl = float(np.linalg.norm(normal))
        out[t, :, a] = normal / nl * _MIN_HALF if nl > 1e-12 else np.eye(3)[a] * _MIN_HALF
    return out


# A tileset that states no CRS is read as 3D Tiles' ECEF (EPSG:4978); one whose coordinates do not lie near the
# Earth's surface (radius between the Dead Sea shore less 12 km and 100 km above the equator) is in a local
# frame that nothing relates to a CRS.
_EARTH_RADII = (6_356_752.0 - 12_000.0, 6_378_137.0 + 100_000.0)


def _unplaced(crs: Any, points: npt.ArrayLike | None) -> bool:
    if points is None or not getattr(crs, "is_geocentric", False):
        return False
    r = np.linalg.norm(np.asarray(points, np.float64).reshape(-1, 3), axis=1)
    return bool(((r < _EARTH_RADII[0]) | (r > _EARTH_RADII[1])).any())


def reprojection_for(src: Any, dst: Any, source: str, sample: npt.ArrayLike | None = None,
                     dst_sample: npt.ArrayLike | None = None) -> Reprojection | None:
    """The :class:`Reprojection` of a layer in ``src`` into a scene in ``dst``; None when they are equal.

    ``sample`` (N, 3): points of the layer (its root box corners) checked to transform to finite values;
    ``dst_sample``: points of the scene (its origin). Raises CitylodError, naming ``source``, when either
    CRS is missing, geographic, or a tileset without a CRS whose coordinates are not on the globe (a local
    frame), or when PROJ knows no transformation between them (engineering or unknown CRSs).
    """
    if src is not None and dst is not None and not src.equals(dst):
        if _unplaced(src, sample):
            src = None
        elif _unplaced(dst, dst_sample):
            dst = None
    if src is None or dst is None:
        raise CitylodError(f"cannot show a layer {'without' if src is None else 'in ' + crs_label(src)} a CRS in a "
                           f"scene {'without one' if dst is None else 'in ' + crs_label(dst)}: nothing says how "
                           "their coordinates relate", source)
    if src.equals(dst):
        return None
    for crs, role in ((dst, "the scene's CRS"), (src, "its CRS")):
        if is_geographic(crs):
            raise CitylodError(f"cannot reproject {crs_label(src)} into {crs_label(dst)} on the fly: {role} is "
                               "geographic (degrees); open a layer in a projected CRS first", source)
    use_package_grids()  # e.g. BETA2007 or a geoid for heights in a vertical datum
    try:
        transformer = pyproj.Transformer.from_crs(src, dst, always_xy=True)
    except pyproj.exceptions.ProjError as exc:
        raise CitylodError(f"no transformation from {crs_label(src)} to the scene's {crs_label(dst)} "
                           f"({exc}); layers in unrelated CRSs cannot be shown together", source) from None
    rep = Reprojection(src, dst, transformer, source)
    if sample is not None:
        rep.points(sample)
    return rep
