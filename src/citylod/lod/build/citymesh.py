"""City object surfaces as triangle meshes, and their coarse stand-ins (blocks, merged blocks).

Polygons (exterior ring + holes, planar or nearly so) are triangulated by earcut (mapbox's C++ library through
``mapbox_earcut``) in the plane that drops the axis of their normal's largest component, the usual projection
for planar polygons in 3D: it is one-to-one for any polygon whose normal is not parallel to that plane, and
the largest component is at least 1/√3 of the normal. Triangles are then oriented along the polygon's Newell
normal, so outward-facing input gives outward-facing triangles.

Blocks are the coarse geometry of building LOD: an object's footprint (union of the xy projections of its
non-vertical faces) extruded over its height range; merged blocks are footprints of neighbouring objects
closed together (buffer out, union, buffer in) and simplified. Neither is trusted: the builder certifies their
Hausdorff distance to the original surfaces (:mod:`citylod.lod.kernels.mesh_distance`).

No VTK, no Qt, no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mapbox_earcut
import numpy as np
import numpy.typing as npt
import shapely
from shapely.geometry.base import BaseGeometry

from citylod.io.city.appearance import Appearances
from citylod.io.city.model import CityObject, Polygon

__all__ = ["ObjectMesh", "block_mesh", "footprint", "object_mesh", "prism", "triangulate_polygon"]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

#: A face is vertical (a wall, left out of footprints) when |n_z| / |n| is below this.
VERTICAL_NZ = 0.05


@dataclass
class ObjectMesh:
    """One object's triangles: ``vertices`` (V, 3) float64, ``faces`` (F, 3) int64, ``surface`` (V,) the
    semantic class of each vertex's surface (a string per vertex, None for none), and the sum of the
    triangle areas in m² (``area``). With appearances: ``image`` (V,) int64 the index of the vertex's texture
    image (-1 none), ``uv`` (V, 2) its texture coordinates (CityGML's, v up; NaN without), ``rgb`` (V, 3) its
    material colour in 0..1 (NaN without). ``repeating``: surfaces whose texture repeats (see
    :func:`unwrap_uv`) and which were left to their material."""

    vertices: F64
    faces: I64
    surface: list[str | None]
    area: float
    image: npt.NDArray[np.int64] | None = None
    uv: F64 | None = None
    rgb: F64 | None = None
    repeating: int = 0

    @staticmethod
    def empty() -> ObjectMesh:
        return ObjectMesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64), [], 0.0)


def _newell(ring: F64) -> F64:
    """Newell's area vector of an open ring (K, 3) (no closing duplicate)."""
    c = ring - ring[0]  # local coordinates keep the products small for large coordinates
    x, y, z = c[:, 0], c[:, 1], c[:, 2]
    # c[0] is the origin, so the wrap-around term (last, first) vanishes: consecutive pairs suffice.
    x0, y0, z0, x1, y1, z1 = x[:-1], y[:-1], z[:-1], x[1:], y[1:], z[1:]
    return 0.5 * np.array([(y0 @ z1 - z0 @ y1), (z0 @ x1 - x0 @ z1), (x0 @ y1 - y0 @ x1)])


def triangulate_polygon(rings: Polygon) -> tuple[F64, I64]:
    """Triangles of one polygon (rings closed, exterior first, then holes).

    Returns
    -------
    vertices, faces
        (V, 3) float64, the ring vertices without their closing duplicates; (F, 3) int64 into them,
        counter-clockwise seen from the side the polygon's Newell normal points to. Empty for a degenerate
        polygon.

    Examples
    --------
    >>> sq = np.array([[0, 0, 0], [4, 0, 0], [4, 4, 0], [0, 4, 0], [0, 0, 0]], float)
    >>> hole = np.array([[1, 1, 0], [1, 3, 0], [3, 3, 0], [3, 1, 0], [1, 1, 0]], float)
    >>> v, f = triangulate_polygon([sq, hole])
    >>> len(v), len(f), float(0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]),
    ...                                             axis=1).sum())
    (8, 8, 12.0)
    """
    pts = [np.asarray(r, np.float64)[:-1] for r in rings if len(r) >= 4]
    if not pts:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    v = np.concatenate(pts)
    n = _newell(pts[0])
    if not np.any(n):
        return v, np.zeros((0, 3), np.int64)
    if len(pts) == 1 and len(v) == 3:
        return v, np.array([[0, 1, 2]], np.int64)  # a triangle, oriented along its own normal
    drop = int(np.argmax(np.abs(n)))
    keep = [i for i in range(3) if i != drop]
    xy = v[:, keep] - v[0, keep]
    ends = np.cumsum([len(p) for p in pts]).astype(np.uint32)
    idx = mapbox_earcut.triangulate_float64(xy, ends).astype(np.int64).reshape(-1, 3)
    if len(idx):
        # The projection keeps or reverses orientation by the sign of the dropped component (cyclic axes).
        a, b, c = xy[idx[:, 0]], xy[idx[:, 1]], xy[idx[:, 2]]
        area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
        sign = 1.0 if drop != 1 else -1.0  # dropping y maps (x, z), which is (z, x) reversed
        flip = area2 * sign * n[drop] < 0
        idx[flip] = idx[flip][:, ::-1]
    return v, idx


def unwrap_uv(uv: F64, tol: float = 1e-4) -> F64 | None:
    """A surface's texture coordinates (K, 2) moved into [0, 1]² by a whole number of repeats, or None when
    they span more than one repeat of the image.

    Models written for repeating (``wrap``) textures give façades coordinates such as u in [-1, 0]; shifting a
    surface's coordinates by whole periods shows the same texels, so such a surface can use its image once,
    as an atlas holds it. A surface spanning several periods (a roof tiled 21 × 14 times with one small
    shingle image) would need its image repeated in the atlas; it is left to its material instead.
    """
    shift = np.floor(uv.min(axis=0) + tol)
    out = uv - shift
    if np.any(out.max(axis=0) > 1.0 + tol) or np.any(out.min(axis=0) < -tol):
        return None
    return np.clip(out, 0.0, 1.0)


def object_mesh(obj: CityObject, appearances: Appearances | None = None,
                image_index: dict[Path, int] | None = None, source: CityObject | None = None) -> ObjectMesh:
    """All surfaces of ``obj`` triangulated (see :func:`triangulate_polygon`), with per-vertex classes and,
    given ``appearances``, per-vertex texture image (numbered through ``image_index``, which grows),
    texture coordinates and material colour. Appearances are looked up by the coordinates of ``source``,
    the same object as read (before projection to metres; default ``obj``)."""
    verts, faces, surf, imgs, uvs, rgbs = [], [], [], [], [], []
    off = 0
    repeating = 0
    sems = obj.semantics if len(obj.semantics) == len(obj.surfaces) else [None] * len(obj.surfaces)
    src_polys = (source or obj).surfaces
    for poly, src, sem in zip(obj.surfaces, src_polys, sems, strict=True):
        v, f = triangulate_polygon(poly)
        if not len(f):
            continue
        verts.append(v)
        faces.append(f + off)
        surf.extend([sem] * len(v))
        off += len(v)
        if appearances is None:
            continue
        app = appearances.lookup(src[0])
        src_v = np.concatenate([np.asarray(r)[:-1] for r in src if len(r) >= 4])
        uv = app.uv_of(src_v) if app is not None and app.image is not None else None
        if uv is not None:
            uv = unwrap_uv(uv)
            repeating += uv is None
        if uv is not None and image_index is not None and app is not None and app.image is not None:
            imgs.append(np.full(len(v), image_index.setdefault(app.image, len(image_index)), np.int64))
            uvs.append(uv)
        else:
            imgs.append(np.full(len(v), -1, np.int64))
            uvs.append(np.full((len(v), 2), np.nan))
        rgb = np.nan if app is None or app.rgb is None else np.asarray(app.rgb, np.float64)
        rgbs.append(np.broadcast_to(rgb, (len(v), 3)))
    if not faces:
        return ObjectMesh.empty()
    vv, ff = np.concatenate(verts), np.concatenate(faces)
    mesh = ObjectMesh(vv, ff, surf, float(triangle_areas(vv, ff).sum()), repeating=repeating)
    if appearances is not None:
        mesh.image, mesh.uv, mesh.rgb = np.concatenate(imgs), np.concatenate(uvs), np.concatenate(rgbs)
    return mesh


def triangle_areas(vertices: F64, faces: I64) -> F64:
    """(F,) areas of the triangles."""
    v = vertices - vertices[0] if len(vertices) else vertices
    return 0.5 * np.linalg.norm(np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]]), axis=1)


def footprint(obj: CityObject, grid_size: float = 1e-3) -> BaseGeometry:
    """Union of the xy projections of the object's non-vertical faces (roofs included, so eaves count);
    snapped to ``grid_size`` (m) so that the faces of a solid merge without slivers. Empty without such
    faces."""
    polys = []
    for poly in obj.surfaces:
        n = _newell(poly[0][:-1])
        norm = float(np.linalg.norm(n))
        if norm == 0 or abs(n[2]) / norm < VERTICAL_NZ:
            continue
        polys.append(shapely.Polygon(poly[0][:, :2], [r[:, :2] for r in poly[1:]]))
    if not polys:
        return shapely.Polygon()
    u = shapely.union_all(shapely.make_valid(np.asarray(polys, dtype=object)), grid_size=grid_size)
    parts = [g for g in shapely.get_parts(u) if g.geom_type == "Polygon" and g.area > 0]
    return shapely.union_all(parts) if parts else shapely.Polygon()


def prism(shape: BaseGeometry, z0: float, z1: float) -> tuple[F64, I64, list[str]]:
    """A footprint (Polygon or MultiPolygon) extruded from ``z0`` to ``z1``: roof, walls and ground.

    Returns (V, 3) vertices, (F, 3) faces oriented outward and per-vertex classes (``RoofSurface``,
    ``WallSurface``, ``GroundSurface``). A prism thinner than a centimetre is its top face only.
    """
    verts: list[F64] = []
    faces: list[I64] = []
    surf: list[str] = []
    off = 0
    flat = z1 - z0 < 0.01

    def add(v: F64, f: I64, cls: str) -> None:
        nonlocal off
        verts.append(v)
        faces.append(f + off)
        surf.extend([cls] * len(v))
        off += len(v)

    for part in shapely.get_parts(shape):
        if part.geom_type != "Polygon" or part.is_empty or part.area <= 0:
            continue
        part = shapely.geometry.polygon.orient(part, 1.0)  # exterior counter-clockwise, holes clockwise
        rings = [np.asarray(part.exterior.coords)] + [np.asarray(r.coords) for r in part.interiors]
        top = [np.column_stack([r[:, :2], np.full(len(r), z1)]) for r in rings]
        v, f = triangulate_polygon(top)
        if not len(f):
            continue
        add(v, f, "RoofSurface")
        if flat:
            continue
        add(np.column_stack([v[:, :2], np.full(len(v), z0)]), f[:, ::-1], "GroundSurface")
        for r in rings:
            a, b = r[:-1, :2], r[1:, :2]
            k = len(a)
            # One quad per ring edge, its own four vertices (flat shading, per-wall classes).
            q = np.empty((k, 4, 3))
            q[:, 0, :2], q[:, 1, :2], q[:, 2, :2], q[:, 3, :2] = a, b, b, a
            q[:, :2, 2], q[:, 2:, 2] = z0, z1
            base = 4 * np.arange(k)[:, None]
            wf = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]])
            add(q.reshape(-1, 3), wf, "WallSurface")
    if not faces:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), []
    return np.concatenate(verts), np.concatenate(faces), surf


def block_mesh(shape: BaseGeometry, mesh: ObjectMesh, simplify_m: float = 0.0) -> tuple[F64, I64, list[str | None]]:
    """An object's block: its footprint ``shape`` (see :func:`footprint`; simplified by ``simplify_m`` metres,
    topology kept) over the height range of its ``mesh``. An object without a footprint (walls only, say)
    keeps its full mesh."""
    if not len(mesh.faces):
        return mesh.vertices, mesh.faces, mesh.surface
    if simplify_m > 0 and not shape.is_empty:
        shape = shapely.simplify(shape, simplify_m, preserve_topology=True)
    if shape.is_empty:
        return mesh.vertices, mesh.faces, mesh.surface
    z = mesh.vertices[:, 2]
    v, f, cls = prism(shape, float(z.min()), float(z.max()))
    return v, f, list(cls)
