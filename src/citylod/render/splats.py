"""Oriented-disk splats for point clouds: hole-free surfaces at close range.

Fixed-size points leave the background showing between them once the camera is closer than the point
spacing allows; splats (Zwicker et al. 2001; Botsch, Hornung, Zwicker, Kobbelt, "High-quality
surface splatting on today's GPUs", 2005, as used by Gao 2014 ch. 6) draw each point as a disk in its
tangent plane, sized by the local spacing, so neighbouring disks overlap and close the surface.

Here a disk is a small polygon (:data:`SIDES` corners) instanced per point by ``vtkGlyph3DMapper``
(GPU instancing), oriented by the point's normal and scaled by its radius; normals and radii come from
the ``k`` nearest neighbours (``scipy.spatial.cKDTree``, principal component analysis). Each disk is
lit with its own normal (VTK's per-fragment lighting). Botsch et al. also blend overlapping splats
(normalised accumulation in a deferred pass); VTK gives no such pass without custom shaders, so the
nearest disk wins in the z-buffer: edges between disks can show, holes cannot.

The tile renderer (``TilesetLayer.point_shape = "splat"``: ``citylod render --splats``, ``add_lod_layer(...,
point_shape="splat")``, the app's point shape) uses :func:`glyph_mapper` and :func:`add_splat_arrays` on each
tile's own points, drawn unlit like its points; the estimate runs once per uploaded tile, on the thread
that uploads it (a KD-tree over the tile's points).

VTK comes from :mod:`citylod.render._vtk`; nothing here imports Qt.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from citylod.render import _vtk

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]

#: Corners of a splat disk: a hexagon's inscribed circle is 0.87 of its radius, an octagon's 0.92.
SIDES = 8

__all__ = ["SIDES", "Splats", "add_splat_arrays", "estimate_splats", "glyph_mapper", "splat_actor"]


@dataclass(frozen=True)
class Splats:
    """Oriented disks: ``centers`` (N, 3) float64, ``normals`` (N, 3) float32 unit, ``radii`` (N,)
    float32 in the units of the centres."""

    centers: F64
    normals: F32
    radii: F32


def estimate_splats(xyz: npt.ArrayLike, *, k: int = 8, normals: npt.ArrayLike | None = None,
                    radius_factor: float = 1.0, max_radius_factor: float = 3.0) -> Splats:
    """Normals and radii of disks that cover the surface sampled by ``xyz``.

    The normal is the direction of least variance of the point and its ``k`` nearest neighbours (the
    tangent plane fit of Hoppe et al. 1992), unless ``normals`` are given (e.g. the boundary normals of
    added walls). The radius is the distance to the ``k``-th neighbour times ``radius_factor``: around a
    point of a surface sampled with spacing h its k = 8 nearest neighbours reach about 1.5 h, so disks of
    that radius overlap their neighbours' and leave no gap where the sampling has none wider than that.
    Radii are capped at ``max_radius_factor`` times the median: isolated returns (a tree's crown, a bird)
    would otherwise become disks metres wide.

    Examples
    --------
    >>> g = np.stack(np.meshgrid(np.arange(10.0), np.arange(10.0)), -1).reshape(-1, 2)
    >>> s = estimate_splats(np.column_stack([g, np.zeros(len(g))]))
    >>> bool(np.allclose(np.abs(s.normals[:, 2]), 1.0)), float(s.radii.min()) >= 1.0
    (True, True)
    """
    from scipy.spatial import cKDTree

    pts = np.asarray(xyz, np.float64)
    n = len(pts)
    if n == 0:
        return Splats(pts.reshape(0, 3), np.zeros((0, 3), np.float32), np.zeros(0, np.float32))
    kk = min(k + 1, n)
    center = pts.mean(axis=0)
    local = pts - center
    dist, idx = cKDTree(local).query(local, kk)
    dist = dist.reshape(n, kk)
    idx = idx.reshape(n, kk)
    radius = dist[:, -1] * radius_factor
    radius = np.minimum(radius, max_radius_factor * float(np.median(radius)))
    if normals is None:
        nb = local[idx]  # (n, kk, 3)
        nb = nb - nb.mean(axis=1, keepdims=True)
        cov = np.einsum("nki,nkj->nij", nb, nb)
        _, vecs = np.linalg.eigh(cov)
        nrm = vecs[:, :, 0]  # eigenvalues ascending: the first vector is the normal
    else:
        nrm = np.asarray(normals, np.float64).reshape(n, 3)
    norm = np.linalg.norm(nrm, axis=1, keepdims=True)
    nrm = np.where(norm > 0, nrm / np.maximum(norm, 1e-300), [0.0, 0.0, 1.0])
    # One orientation per cloud (upwards, for airborne data): lighting is two-sided, this keeps it stable.
    nrm = np.where(nrm[:, 2:3] < 0, -nrm, nrm)
    return Splats(pts, nrm.astype(np.float32), radius.astype(np.float32))


def glyph_mapper() -> Any:
    """A ``vtkGlyph3DMapper`` drawing every point of its input as a disk of :data:`SIDES` corners, oriented
    by the point array ``splat_normal`` and scaled by ``splat_radius`` (:func:`add_splat_arrays`); colours
    from the input's scalars (RGB, direct) when scalar visibility is on."""
    disk = _vtk.vtkRegularPolygonSource()
    disk.SetNumberOfSides(SIDES)
    disk.SetRadius(1.0)
    disk.SetCenter(0.0, 0.0, 0.0)
    # vtkGlyph3DMapper's DIRECTION mode turns the glyph's x axis onto the orientation vector.
    disk.SetNormal(1.0, 0.0, 0.0)
    disk.GeneratePolylineOff()
    mapper = _vtk.vtkGlyph3DMapper()
    mapper.SetSourceConnection(disk.GetOutputPort())
    mapper.SetOrientationArray("splat_normal")
    mapper.SetOrientationModeToDirection()
    mapper.SetScaleArray("splat_radius")
    mapper.SetScaleModeToScaleByMagnitude()
    mapper.SetScaleFactor(1.0)
    mapper.SetColorModeToDirectScalars()
    mapper.SetScalarModeToUsePointData()
    return mapper


def add_splat_arrays(data: Any, splats: Splats) -> None:
    """Attach ``splats``' normals and radii to ``data`` (a vtkPolyData of the same points, same order) as
    the arrays :func:`glyph_mapper` reads."""
    nrm = _vtk.numpy_to_vtk(np.ascontiguousarray(splats.normals, np.float32), deep=True)
    nrm.SetName("splat_normal")
    data.GetPointData().AddArray(nrm)
    rad = _vtk.numpy_to_vtk(np.ascontiguousarray(splats.radii, np.float32), deep=True)
    rad.SetName("splat_radius")
    data.GetPointData().AddArray(rad)


def splat_actor(splats: Splats, origin: npt.ArrayLike, rgb: npt.ArrayLike | None = None,
                color: tuple[float, float, float] = (0.85, 0.85, 0.85)) -> Any:
    """A VTK actor drawing ``splats`` shifted by ``origin`` (the scene origin: float32 never sees large
    coordinates), coloured per point by ``rgb`` (N, 3) uint8 or one ``color``."""
    org = np.asarray(origin, np.float64)
    data = _vtk.vtkPolyData()
    pts = _vtk.vtkPoints()
    pts.SetData(_vtk.numpy_to_vtk(np.ascontiguousarray(splats.centers - org, np.float32), deep=True))
    data.SetPoints(pts)
    add_splat_arrays(data, splats)
    mapper = glyph_mapper()
    mapper.SetInputData(data)
    actor = _vtk.vtkActor()
    actor.SetMapper(mapper)
    if rgb is not None:
        col = _vtk.numpy_to_vtk(np.ascontiguousarray(np.asarray(rgb, np.uint8).reshape(-1, 3)), deep=True,
                                array_type=_vtk.VTK_UNSIGNED_CHAR)
        col.SetName("splat_rgb")
        data.GetPointData().SetScalars(col)
        mapper.ScalarVisibilityOn()
    else:
        mapper.ScalarVisibilityOff()
        actor.GetProperty().SetColor(*color)
    prop = actor.GetProperty()
    prop.SetAmbient(0.35)
    prop.SetDiffuse(0.65)
    prop.BackfaceCullingOff()
    return actor
