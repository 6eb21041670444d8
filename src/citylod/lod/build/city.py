"""City model (CityGML / CityJSON) to a 3D Tiles 1.1 tileset: every object's surfaces, with feature metadata.

The tree is a 4-ary tree over the objects (an object is never split between tiles, so its feature ID and its
attributes live in one tile per level): each split cuts at the weighted median of the longer horizontal axis,
then each half at the weighted median of the other, the weight being an object's triangle count, until a
node holds at most ``leaf_triangles`` triangles or one object.

What each tile holds (building LOD, coarse to fine, ``refine: REPLACE``):

* leaves: the objects' surfaces triangulated (:mod:`citylod.lod.build.citymesh`), ``geometricError`` 0 plus
  float32 rounding;
* parents of leaves: blocks, each object's footprint extruded over its height range;
* higher nodes: merged blocks, footprints of neighbouring objects of the same type closed together over a
  distance that doubles per level, extruded over the group's heights.

A textured model (appearances with images, :mod:`citylod.io.city.appearance`) is built the other way, after
Buchholz (2006, ch. 4): the 4-ary tree is balanced by surface area and split until a leaf's images fit one
atlas at their own resolution; every tile holds its subtree's full surfaces and one fixed-size atlas
(:mod:`citylod.lod.build.atlas`), and its ``geometricError`` is that atlas's texel size on the surface, so
that at τ px no atlas texel covers more than τ pixels. Surfaces whose image is missing or refused keep
their material colour. With ``texture_blocks`` its inner tiles get building LOD instead: blocks and merged
blocks as below, each face in the mean colour of its object's surfaces of that class in the node's atlas,
with the certified Hausdorff bound plus the atlas's texel size as ``geometricError``; far views then bind no
texture. Off by default: a block's error (a gable roof's height) is far above the texel sizes of the levels
it replaces, so under a texture budget views refine to many leaves and fall back to coarse blocks
(docs/BENCHMARKS.md, "Textured city models").

A coarse tile's ``geometricError`` is a proven bound on the symmetric Hausdorff distance between its
triangles and the original surfaces of its objects (:mod:`citylod.lod.kernels.mesh_distance`; the union's
distance is at most the largest of the groups', since every group pairs originals with their own stand-in),
plus float32 rounding; a parent's error is never below its children's (docs/DESIGN.md, decision 3).

Every vertex carries two feature IDs (``EXT_mesh_features``): ``_FEATURE_ID_0`` the row of its city object in
the tile's ``city_object`` property table (``EXT_structural_metadata``: ``object_id``, ``type``, ``parent``,
``lod``, ``name``, ``function``, ``measured_height``, ``storeys`` and all attributes as JSON), and
``_FEATURE_ID_1`` the row of its semantic surface class (``RoofSurface``, ``WallSurface``, ...) in the
``surface`` table. Objects without geometry of their own (a Building made of BuildingParts) have a row in
the leaf of their first part, or in the root leaf.

The tileset is written into a temporary folder and published when complete. No VTK, no Qt.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pyproj
import shapely

from citylod.core.errors import InputError
from citylod.core.fileio import publish_dir
from citylod.io.city import CityModel, read_city_model, to_metric
from citylod.io.city.appearance import read_appearances
from citylod.io.city.model import CityObject
from citylod.io.image import encode_image
from citylod.io.tiles3d import (
    FeatureIdSet,
    MeshData,
    PropertyTable,
    TileContent,
    TileSpec,
    write_content,
    write_tileset,
)
from citylod.lod.build.atlas import (
    Square,
    atlas_uv,
    leaf_atlas,
    parent_atlas,
    quadrant,
    texel_size_m,
    tile_uv,
)
from citylod.lod.build.citymesh import ObjectMesh, block_mesh, footprint, object_mesh, prism
from citylod.lod.kernels.mesh_distance import hausdorff_bound

__all__ = ["CityTilesReport", "build_city_tiles", "default_tiles_dir"]

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]

#: Colours (RGBA) of semantic surface classes and, for surfaces without one, of object types.
SURFACE_RGBA = {
    "RoofSurface": (178, 84, 64, 255), "WallSurface": (226, 220, 204, 255), "GroundSurface": (110, 110, 110, 255),
    "ClosureSurface": (200, 200, 200, 255), "OuterCeilingSurface": (200, 196, 184, 255),
    "OuterFloorSurface": (160, 160, 160, 255), "Window": (120, 160, 200, 255), "Door": (120, 90, 60, 255),
}
TYPE_RGBA = {
    "Building": (214, 206, 190, 255), "BuildingPart": (214, 206, 190, 255), "Road": (90, 90, 96, 255),
    "Railway": (110, 100, 90, 255), "TransportSquare": (130, 130, 136, 255), "WaterBody": (70, 120, 190, 255),
    "PlantCover": (92, 150, 70, 255), "SolitaryVegetationObject": (70, 130, 60, 255),
    "LandUse": (170, 190, 130, 255), "Bridge": (150, 140, 130, 255), "TINRelief": (160, 150, 120, 255),
    "GenericCityObject": (180, 180, 180, 255),
}
_DEFAULT_RGBA = (190, 190, 190, 255)
_INT_NONE = np.iinfo(np.int32).min


@dataclass(frozen=True)
class CityTilesReport:
    """What :func:`build_city_tiles` did: ``objects`` in the tileset (rows over the leaves), ``tiles``,
    ``levels``, leaf and root triangle counts, the root's certified ``root_error`` (m), seconds."""

    path: Path
    objects: int
    tiles: int
    levels: int
    leaf_triangles: int
    root_triangles: int
    root_error: float
    seconds: float
    warnings: list[str] = field(default_factory=list)

    def summary(self) -> str:
        return (f"{self.path}: {self.objects} city objects in {self.tiles} tiles over {self.levels} levels, "
                f"{self.leaf_triangles} triangles at full detail, {self.root_triangles} in the root "
                f"(certified error {self.root_error:.2f} m), {self.seconds:.1f} s")


def default_tiles_dir(store: str | PathLike[str]) -> Path:
    """Where ``citylod build city`` writes the tileset beside the store: ``city.gpkg`` -> ``city_tiles/``."""
    p = Path(store)
    return p.with_name(p.stem + "_tiles")


@dataclass
class _Node:
    objects: npt.NDArray[np.int64]
    key: str
    level: int
    children: list[_Node] = field(default_factory=list)
    height: int = 0  # 0 for leaves, else 1 + the children's largest
    error: float = 0.0
    spec: TileSpec | None = None


def _split(idx: I64, centres: F64, weights: F64) -> list[I64]:
    """Four parts of ``idx`` of balanced weight: the longer axis at its weighted median, then the other."""
    def halve(part: I64, axis: int) -> list[I64]:
        if len(part) < 2:
            return [part]
        order = part[np.argsort(centres[part, axis], kind="stable")]
        cum = np.cumsum(weights[order])
        cut = int(np.searchsorted(cum, 0.5 * cum[-1]))
        cut = min(max(cut, 1), len(order) - 1)
        return [order[:cut], order[cut:]]

    ext = centres[idx].max(axis=0) - centres[idx].min(axis=0)
    first = 0 if ext[0] >= ext[1] else 1
    return [q for h in halve(idx, first) for q in halve(h, 1 - first) if len(q)]


def _build_tree(idx: I64, centres: F64, cost: F64, leaf_cost: float, weights: F64 | None = None) -> _Node:
    """Split while a node holding several objects costs more than ``leaf_cost``; parts balanced by
    ``weights`` (default: the cost)."""
    w = np.maximum(cost if weights is None else weights, 1e-9)
    root = _Node(idx, "0", 0)
    stack = [root]
    order: list[_Node] = []
    while stack:
        n = stack.pop()
        order.append(n)
        if len(n.objects) > 1 and cost[n.objects].sum() > leaf_cost:
            for i, part in enumerate(_split(n.objects, centres, w)):
                c = _Node(part, f"{n.key}-{i}", n.level + 1)
                n.children.append(c)
                stack.append(c)
    for n in reversed(order):
        n.height = 1 + max(c.height for c in n.children) if n.children else 0
    return root


def _walk(root: _Node) -> list[_Node]:
    out, stack = [], [root]
    while stack:
        n = stack.pop()
        out.append(n)
        stack.extend(n.children)
    return out


def _post_order(root: _Node) -> list[_Node]:
    """Every node after its children, each subtree finished before the next begins: a parent's atlas is made
    from its children's as soon as they exist, so at most four atlases a level wait (children first by
    height held every leaf's atlas at once: killed at 23.5 GB for 32,000 textured houses)."""
    out: list[_Node] = []
    stack: list[tuple[_Node, bool]] = [(root, False)]
    while stack:
        n, expanded = stack.pop()
        if expanded or not n.children:
            out.append(n)
            continue
        stack.append((n, True))
        stack.extend((c, False) for c in reversed(n.children))
    return out


@dataclass
class _Piece:
    """Triangles of one object (or one merged group, shown as its representative object)."""

    obj: int
    vertices: F64
    faces: I64
    surface: list[str | None]
    uv: F64 | None = None  # common texture coordinates (V, 2), NaN where untextured
    rgb: F64 | None = None  # material colours (V, 3) in 0..1, NaN where none
    image: npt.NDArray[np.int64] | None = None  # original image per vertex (-1 none), for textures="original"

    @staticmethod
    def of(i: int, m: ObjectMesh, uv: F64 | None = None) -> _Piece:
        return _Piece(int(i), m.vertices, m.faces, m.surface, uv, m.rgb, m.image)


def _text(v: Any) -> str | None:
    if v is None:
        return None
    return ", ".join(str(x) for x in v) if isinstance(v, list) else str(v)


def _num(v: Any, kind: type) -> float | int | None:
    try:
        return None if v is None else kind(float(v))
    except (TypeError, ValueError, OverflowError):
        return None


def _object_table(objects: Sequence[CityObject]) -> PropertyTable:
    height = [_num(o.attributes.get("measuredHeight"), float) for o in objects]
    storeys = [_num(o.attributes.get("storeysAboveGround"), int) for o in objects]
    return PropertyTable("city_object", {
        "object_id": [o.id for o in objects],
        "type": [o.type for o in objects],
        "parent": [o.parent for o in objects],
        "lod": np.array([o.lod for o in objects], np.int32),
        "name": [_text(o.attributes.get("name")) for o in objects],
        "function": [_text(o.attributes.get("function")) for o in objects],
        "measured_height": np.array([np.nan if h is None else h for h in height], np.float64),
        "storeys": np.array([_INT_NONE if s is None or abs(s) >= 2**31 else s for s in storeys], np.int32),
        "attributes": [json.dumps(o.attributes, default=str, ensure_ascii=False, sort_keys=True) for o in objects],
    })


def _closed_outward(verts: F64, faces: npt.NDArray[np.int64]) -> bool:
    """Whether the triangles bound closed volumes with every face wound counter-clockwise seen from outside,
    so that a client may cull back faces without opening a hole in what can be seen from outside.

    Vertices are welded by position first (texture seams and per-polygon rings duplicate them). The surface
    is then closed and consistently oriented exactly when every directed edge occurs once and its reverse
    occurs too (each edge shared by two faces that traverse it in opposite directions; a T-junction, a hole
    or a flipped face breaks this). Each connected shell then has a signed volume of one sign, and it is
    positive when the normals point out (divergence theorem), which is checked per shell. Degenerate
    triangles (two corners welded together) have no side and are left out. Conservative: any other input,
    such as shells that share edges or the open shells that CityGML data often has, says False.

    The reader (:func:`citylod.io.city.model.orient_outward`) already flips closed solids outward as a whole;
    this checks the triangles as written, face by face, which that repair does not promise.
    """
    if not len(faces):
        return False
    pts = np.asarray(verts, np.float64)
    tri = np.asarray(faces, np.int64)
    _, vid = np.unique(np.round(pts, 6), axis=0, return_inverse=True)
    vid = vid.reshape(-1)
    f = vid[tri]
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])
    f, tri = f[keep], tri[keep]
    if not len(f):
        return False
    n = int(vid.max()) + 1
    a = f.ravel()
    b = f[:, [1, 2, 0]].ravel()
    code = a * n + b
    if len(np.unique(code)) != len(code) or not np.isin(b * n + a, code).all():
        return False
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    _, comp = connected_components(coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n)), directed=False)
    p = pts[tri] - pts.mean(axis=0)  # volumes about a near origin: no cancellation at UTM coordinates
    vol = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])) / 6.0
    shell = np.bincount(comp[f[:, 0]], weights=vol, minlength=int(comp.max()) + 1)
    used = np.bincount(comp[f[:, 0]], minlength=len(shell)) > 0
    return bool((shell[used] > 0.0).all())


def _content(pieces: list[_Piece], extra_rows: Sequence[int], objects: Sequence[CityObject],
             centre: F64, atlas: tuple[bytes, Square] | None = None,
             originals: Sequence[Path] | None = None) -> tuple[TileContent, float, int]:
    """A tile's content from its pieces: positions relative to ``centre``; the float32 rounding bound (m)
    and the triangle count. With an ``atlas`` (encoded image, the node's square), triangles whose vertices
    all have texture coordinates form a textured mesh, the others a coloured one. With ``originals`` (the
    image files), each image's triangles form a mesh of their own with the image as it is (the baseline
    that atlases are measured against)."""
    rows = sorted({p.obj for p in pieces} | set(extra_rows))
    row_of = {o: i for i, o in enumerate(rows)}
    verts = np.concatenate([p.vertices for p in pieces]) if pieces else np.zeros((0, 3))
    sizes = [len(p.vertices) for p in pieces]
    offsets = np.cumsum([0, *sizes[:-1]])
    faces = (np.concatenate([p.faces + o for p, o in zip(pieces, offsets, strict=True)]) if pieces
             else np.zeros((0, 3), np.int64))
    obj_of_vertex = np.repeat(np.array([row_of[p.obj] for p in pieces], np.uint32), sizes)
    surf = [s for p in pieces for s in p.surface]
    classes = sorted({s or "" for s in surf})
    class_row = {c: i for i, c in enumerate(classes)}
    surf_ids = np.array([class_row[s or ""] for s in surf], np.uint32)
    rgba = np.array([SURFACE_RGBA.get(s or "", TYPE_RGBA.get(objects[p.obj].type, _DEFAULT_RGBA))
                     for p in pieces for s in p.surface], np.uint8).reshape(-1, 4)
    rgb = np.concatenate([np.full((len(p.vertices), 3), np.nan) if p.rgb is None else p.rgb for p in pieces]
                         ) if pieces else np.zeros((0, 3))
    has_rgb = np.isfinite(rgb).all(axis=1)
    rgba[has_rgb, :3] = np.round(rgb[has_rgb] * 255).astype(np.uint8)  # the model's own materials first
    local = verts - centre
    pos = local.astype(np.float32)
    # float32 rounding of positions relative to the centre: half an ulp per coordinate, in 3D.
    rounding = float(np.abs(pos).max() * 2.0**-24 * np.sqrt(3.0)) if len(pos) else 0.0
    meshes = []
    # Single-sided only where every building of the tile is a closed, outward-wound shell: back faces are then
    # hidden from every viewpoint outside, and clients (citylod too) cull them (a quarter of a city frame).
    one_sided = _closed_outward(verts, faces)
    textured = np.zeros(len(faces), bool)
    uv = None
    # The surface classes are a second feature ID set when the tile has any (a table needs a property).
    has_classes = any(classes)

    def feature_sets(used: npt.NDArray[np.int64]) -> list[FeatureIdSet]:
        sets = [FeatureIdSet(obj_of_vertex[used], 0, len(rows), "city_object")]
        if has_classes:
            sets.append(FeatureIdSet(surf_ids[used], 1, len(classes), "surface"))
        return sets

    if (atlas is not None or originals is not None) and pieces:
        uv = np.concatenate([np.full((len(p.vertices), 2), np.nan) if p.uv is None else p.uv for p in pieces])
        textured = np.isfinite(uv).all(axis=1)[faces].all(axis=1)
    if originals is not None and uv is not None:
        image = np.concatenate([np.full(len(p.vertices), -1) if p.image is None else p.image for p in pieces])
        face_image = np.where(textured, image[faces[:, 0]], -1)
        for k in np.unique(face_image[face_image >= 0]):
            sel = faces[face_image == k]
            used, inv = np.unique(sel, return_inverse=True)
            img_uv = np.column_stack([uv[used, 0], 1.0 - uv[used, 1]]).astype(np.float32)  # glTF: origin top left
            meshes.append(MeshData(pos[used], inv.reshape(-1, 3).astype(np.uint32), uv=img_uv,
                                   texture=Path(originals[int(k)]).read_bytes(), name=f"image_{int(k)}",
                                   features=feature_sets(used), double_sided=not one_sided))
        textured_done = True
    else:
        textured_done = False
    for tex in (False, True):
        sel = faces[textured == tex]
        if not len(sel) or (tex and textured_done):
            continue
        # Each mesh keeps only the vertices its faces use (glTF accessors are per primitive).
        used, inv = np.unique(sel, return_inverse=True)
        sets = feature_sets(used)
        if tex:
            assert atlas is not None and uv is not None
            meshes.append(MeshData(pos[used], inv.reshape(-1, 3).astype(np.uint32), uv=tile_uv(uv[used], atlas[1]),
                                   texture=atlas[0], name="city_textured", features=sets,
                                   double_sided=not one_sided))
        else:
            meshes.append(MeshData(pos[used], inv.reshape(-1, 3).astype(np.uint32), colors=rgba[used], name="city",
                                   features=sets, double_sided=not one_sided))
    tables = [_object_table([objects[i] for i in rows])]
    if has_classes:
        tables.append(PropertyTable("surface", {"surface_class": [c or None for c in classes]}))
    return TileContent(meshes, property_tables=tables), rounding, int(len(faces))


def _image_pixels(path: Path) -> int:
    """Pixels an image header declares (checked readable by :func:`check_image` already)."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        oiio.geterror()
        return 0
    try:
        return int(inp.spec().width) * int(inp.spec().height)
    finally:
        inp.close()


def _atlas_node(n: _Node, square: Square, meshes: Sequence[ObjectMesh], images: Sequence[Path],
                atlases: dict[str, npt.NDArray[np.uint8]], common: dict[int, F64], atlas_px: int,
                warnings: list[str]) -> tuple[list[_Piece], tuple[bytes, Square], float]:
    """A node of a textured model (Buchholz): its subtree's surfaces, its atlas (a leaf packs its images, an
    inner node shrinks its children's atlases into quadrants) and the atlas's texel size in metres."""
    if not n.children:
        used = sorted({int(k) for i in n.objects if meshes[i].image is not None
                       for k in np.unique(meshes[i].image) if k >= 0})
        pixels, placed, warns = leaf_atlas({k: images[k] for k in used}, atlas_px)
        warnings += warns
        for i in n.objects:
            m = meshes[i]
            uv = np.full((len(m.vertices), 2), np.nan)
            if m.image is not None and m.uv is not None:
                ok = np.array([k in placed for k in m.image]) & (m.image >= 0)
                if ok.any():
                    uv[ok] = atlas_uv(m.uv[ok], [placed[int(k)] for k in m.image[ok]], square, atlas_px)
            common[int(i)] = uv
    else:
        pixels = parent_atlas([(k, atlases.pop(c.key)) for k, c in enumerate(n.children)], atlas_px)
    atlases[n.key] = pixels
    pieces = [_Piece.of(i, meshes[i], common[int(i)]) for i in n.objects]
    err = 0.0
    for p in pieces:
        assert p.uv is not None
        tex = np.asarray(np.isfinite(p.uv).all(axis=1))[p.faces].all(axis=1)
        if tex.any():
            err = max(err, texel_size_m(p.vertices, p.faces[tex], np.nan_to_num(p.uv), square, atlas_px))
    return pieces, (encode_image(pixels, "jpg", 90), square), err


def _merged_pieces(members: I64, objects: Sequence[CityObject], meshes: Sequence[ObjectMesh],
                   feet: Sequence[Any], distance_m: float, tol_m: float) -> tuple[list[_Piece], float]:
    """Merged blocks of ``members``: per object type, footprints closed over ``distance_m`` and simplified
    by half of it, each part extruded over its members' heights (ground: lowest base; roof: midrange of the
    members' tops, which minimises the largest roof offset). The certified error is the largest Hausdorff
    bound over the parts. Objects without a footprint keep their surfaces."""
    pieces: list[_Piece] = []
    err = 0.0
    by_type: dict[str, list[int]] = {}
    for i in members:
        if feet[i].is_empty:
            m = meshes[i]
            pieces.append(_Piece(int(i), m.vertices, m.faces, m.surface))
        else:
            by_type.setdefault(objects[i].type, []).append(int(i))
    for ids in by_type.values():
        shapes = np.asarray([feet[i] for i in ids], dtype=object)
        merged = shapely.buffer(shapely.union_all(shapely.buffer(shapes, distance_m, join_style="mitre")), -distance_m,
                                join_style="mitre")
        merged = shapely.simplify(merged, 0.5 * distance_m, preserve_topology=True)
        parts = [g for g in shapely.get_parts(merged) if not g.is_empty and g.area > 0]
        tree = shapely.STRtree(shapes)
        owned = np.zeros(len(ids), bool)
        for part in parts:
            hit = np.asarray(tree.query(part, predicate="intersects"), np.int64)
            hit = hit[~owned[hit]]
            if not len(hit):
                continue
            owned[hit] = True
            group = [ids[k] for k in hit]
            lo = min(float(meshes[i].vertices[:, 2].min()) for i in group)
            tops = [float(meshes[i].vertices[:, 2].max()) for i in group]
            v, f, s = prism(part, lo, 0.5 * (min(tops) + max(tops)))
            rep = max(group, key=lambda i: feet[i].area)
            pieces.append(_Piece(rep, v, f, list(s)))
            err = max(err, _group_error(v, f, [meshes[i] for i in group], tol_m))
        for k in np.flatnonzero(~owned):  # a footprint lost by the closing (a sliver): keep its block
            i = ids[k]
            bv, bf, bs = block_mesh(feet[i], meshes[i])
            pieces.append(_Piece(i, bv, bf, list(bs)))
            err = max(err, _group_error(v, f, [meshes[i]], tol_m))
    return pieces, err


def _block_pieces(n: _Node, objects: Sequence[CityObject], meshes: Sequence[ObjectMesh], feet: Sequence[Any],
                  merge_m: float, tol_m: float) -> tuple[list[_Piece], float]:
    """A coarse node's stand-ins and their certified error: blocks for parents of leaves, merged blocks
    (closing distance doubling per level) above."""
    if n.height >= 2:
        return _merged_pieces(n.objects, objects, meshes, feet, merge_m * 2.0 ** (n.height - 2), tol_m)
    pieces, err = [], 0.0
    for i in n.objects:
        v, f, s = block_mesh(feet[i], meshes[i], simplify_m=0.5 * merge_m)
        pieces.append(_Piece(int(i), v, f, list(s)))
        if v is not meshes[i].vertices:
            err = max(err, _group_error(v, f, [meshes[i]], tol_m))
    return pieces, err


def _surface_colours(pieces: Sequence[_Piece], atlas: npt.NDArray[np.uint8],
                     square: Square) -> dict[int, dict[str, F64]]:
    """Area-weighted mean atlas colour (RGB in 0..1) of each object's textured triangles per surface class
    (key ``""`` for all its textured triangles), read at the triangles' centroids in the node's atlas."""
    side = atlas.shape[0]
    out: dict[int, dict[str, F64]] = {}
    for p in pieces:
        if p.uv is None or not len(p.faces):
            continue
        tex = np.asarray(np.isfinite(p.uv).all(axis=1))[p.faces].all(axis=1)
        if not tex.any():
            continue
        f = p.faces[tex]
        a, b, c = p.vertices[f[:, 0]], p.vertices[f[:, 1]], p.vertices[f[:, 2]]
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
        uv = tile_uv(p.uv[f].mean(axis=1), square)
        px = np.clip((uv * side).astype(np.int64), 0, side - 1)
        rgb = atlas[px[:, 1], px[:, 0], :3].astype(np.float64) / 255.0
        cls = np.array([p.surface[k] or "" for k in f[:, 0]])
        w = np.maximum(area, 1e-12)
        cols = {"": (rgb * w[:, None]).sum(axis=0) / w.sum()}
        for name in np.unique(cls):
            m = cls == name
            cols[str(name)] = (rgb[m] * w[m, None]).sum(axis=0) / w[m].sum()
        out[p.obj] = cols
    return out


def _coloured(p: _Piece, colours: dict[str, F64]) -> _Piece:
    """``p`` with per-vertex material colours from ``colours`` (by surface class, else the object's mean;
    NaN, hence the class colour, for an object without textures)."""
    if not colours:
        return p
    rgb = np.array([colours.get(s or "", colours[""]) for s in p.surface], np.float64).reshape(-1, 3)
    return _Piece(p.obj, p.vertices, p.faces, p.surface, rgb=rgb)


def _group_error(v: F64, f: I64, originals: Sequence[ObjectMesh], tol_m: float) -> float:
    """Certified Hausdorff bound between a stand-in (v, f) and the union of the original meshes."""
    ov = np.concatenate([m.vertices for m in originals])
    offs = np.cumsum([0, *[len(m.vertices) for m in originals[:-1]]])
    of = np.concatenate([m.faces + o for m, o in zip(originals, offs, strict=True)])
    if not len(f) or not len(of):
        return 0.0
    c = ov.mean(axis=0)  # local coordinates keep the differences precise
    return hausdorff_bound(v - c, f, ov - c, of, tol=tol_m, rel=0.02)


def build_city_tiles(citymodel: str | PathLike[str] | CityModel, out_dir: str | PathLike[str], *, lod: int = 2,
                     crs: str | pyproj.CRS | None = None, leaf_triangles: int = 20_000, merge_m: float = 2.0,
                     tol_m: float = 0.05, textures: bool | str = True, atlas_px: int = 1024,
                     texture_blocks: bool = False, progress: bool = True) -> CityTilesReport:
    """Write the city model's geometry as a 3D Tiles 1.1 tileset with feature IDs and property tables.

    Parameters
    ----------
    citymodel
        CityGML / CityJSON file, or a model already read (projected to metres here if it is not).
    out_dir
        Tileset folder (replaced when complete; a non-empty folder that is no tileset is refused).
    lod
        Preferred LoD of the geometry read from a file.
    crs
        Metric CRS for geographic input (default: the UTM zone of the data).
    leaf_triangles
        Largest triangle count of a leaf tile holding more than one object.
    merge_m
        Closing distance of merged blocks on the lowest merged level; it doubles per level up.
    tol_m
        Slack of the Hausdorff bounds (each certified bound is at most this above the true distance).
    textures
        Read the model's appearances. A textured model gets Buchholz's multiresolution atlases
        (:mod:`citylod.lod.build.atlas`) instead of building LOD: every tile holds its subtree's surfaces
        and one ``atlas_px``² atlas, and its ``geometricError`` is the atlas's texel size on the surface.
        ``"original"`` writes one tile with every image as it is, one mesh per image (the baseline).
    atlas_px
        Side of every atlas in pixels (a power of two).
    texture_blocks
        Give a textured model building LOD too: its inner tiles carry blocks and merged blocks (as an
        untextured model's do) coloured with the node atlas's mean colour per object and surface class, and
        their ``geometricError`` is the blocks' certified Hausdorff bound plus that atlas's texel size. Off
        (default): every tile holds its subtree's full surfaces with its atlas (texture LOD only).
    progress
        Show progress bars.

    Returns
    -------
    CityTilesReport
    """
    from tqdm import tqdm

    t0 = time.perf_counter()
    raw = citymodel if isinstance(citymodel, CityModel) else read_city_model(citymodel, lod=lod)
    model = to_metric(raw, crs)
    warnings = list(model.warnings)
    if model.crs is None:
        raise InputError("the city model names no CRS; a tileset must be placed on the globe (pass --crs)",
                         model.source)
    objects = model.objects
    if not objects:
        raise InputError("the city model holds no city objects", model.source)
    apps = None
    if textures and Path(model.source).is_file():
        apps = read_appearances(model.source)
        warnings += apps.warnings
        apps = apps if apps.surfaces else None
    image_index: dict[Path, int] = {}
    meshes = [object_mesh(o, apps, image_index, raw.objects[i])
              for i, o in enumerate(tqdm(objects, desc="triangulate", unit="obj", disable=not progress))]
    images = sorted(image_index, key=image_index.__getitem__)
    repeating = sum(m.repeating for m in meshes)
    if repeating:
        warnings.append(f"{repeating} surface(s) repeat their texture over more than one period; an atlas holds "
                        "each image once, so they are drawn with their material")
    textured = bool(images)
    has_geom = np.array([len(m.faces) > 0 for m in meshes])
    if not has_geom.any():
        raise InputError("no city object has surfaces to draw", model.source)
    geo = np.flatnonzero(has_geom)
    boxes = np.zeros((len(objects), 6))
    for i in geo:
        v = meshes[i].vertices
        boxes[i, :3], boxes[i, 3:] = v.min(axis=0), v.max(axis=0)
    centres = 0.5 * (boxes[:, :3] + boxes[:, 3:])
    tris = np.array([len(m.faces) for m in meshes], np.float64)
    if textured and textures == "original":
        root = _Node(geo, "0", 0)
    elif textured:
        # Buchholz: split by balanced surface area until a leaf's images fit its atlas at full resolution.
        px = np.array([_image_pixels(p) for p in images], np.float64)
        demand = np.array([px[np.unique(m.image[m.image >= 0])].sum() if m.image is not None else 0.0
                           for m in meshes])
        areas = np.array([m.area for m in meshes])
        root = _build_tree(geo, centres, demand, float(atlas_px) ** 2, weights=areas)
    else:
        root = _build_tree(geo, centres, tris, leaf_triangles)
    nodes = _walk(root)
    leaves = [n for n in nodes if not n.children]
    leaf_of = np.full(len(objects), -1, np.int64)
    for li, n in enumerate(leaves):
        leaf_of[n.objects] = li
    first_part: dict[str, int] = {}
    for j in geo:
        if objects[j].parent is not None:
            first_part.setdefault(objects[j].parent, int(j))
    extra: dict[str, list[int]] = {}
    for i in np.flatnonzero(~has_geom):
        # A geometry-less object sits with its first part that has geometry, else in the first leaf.
        j = first_part.get(objects[i].id)
        host = leaves[leaf_of[j]] if j is not None else leaves[0]
        extra.setdefault(host.key, []).append(int(i))

    feet = [footprint(o) if has_geom[i] else shapely.Polygon() for i, o in enumerate(objects)]
    out = Path(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_name(f".{out.name}.partial{os.getpid()}")
    shutil.rmtree(partial, ignore_errors=True)
    partial.mkdir()
    total_leaf_tris = 0
    root_tris = 0
    squares = {root.key: Square()}
    for n in nodes:
        for k, c in enumerate(n.children):
            squares[c.key] = quadrant(squares[n.key], k)
    common: dict[int, F64] = {}  # object -> common texture coordinates of its vertices
    atlases: dict[str, npt.NDArray[np.uint8]] = {}
    try:
        # Children before parents: a parent's error must cover its children's, and its atlas shrinks theirs.
        for n in tqdm(_post_order(root), desc="tiles", unit="tile", disable=not progress):
            err = 0.0
            atlas = None
            if textured and textures == "original":
                pieces = [_Piece.of(i, meshes[i], meshes[i].uv) for i in n.objects]
            elif textured:
                pieces, atlas, err = _atlas_node(n, squares[n.key], meshes, images, atlases, common, atlas_px,
                                                 warnings)
                if texture_blocks and n.height >= 1:
                    # Geometric LOD for far textured tiles: blocks in the atlas's mean colours. The error adds
                    # the blocks' Hausdorff bound to the texel size of the atlas the colours come from.
                    colours = _surface_colours(pieces, atlases[n.key], squares[n.key])
                    pieces, hd = _block_pieces(n, objects, meshes, feet, merge_m, tol_m)
                    pieces = [_coloured(p, colours.get(p.obj, {})) for p in pieces]
                    atlas, err = None, err + hd
            elif n.height == 0:
                pieces = [_Piece.of(i, meshes[i]) for i in n.objects]
            else:
                pieces, err = _block_pieces(n, objects, meshes, feet, merge_m, tol_m)
            lo = boxes[n.objects, :3].min(axis=0)
            hi = boxes[n.objects, 3:].max(axis=0)
            for p in pieces:  # stand-ins may reach out of the originals' box (closing, midrange roofs)
                lo, hi = np.minimum(lo, p.vertices.min(axis=0)), np.maximum(hi, p.vertices.max(axis=0))
            centre = 0.5 * (lo + hi)
            rows = extra.get(n.key, []) if n.height == 0 else []
            content, rounding, ntri = _content(pieces, rows, objects, centre, atlas,
                                               images if textures == "original" else None)
            n.error = max([err + rounding, *(c.error for c in n.children)])
            uri = write_content(partial, n.key, content, atomic=False)
            n.spec = TileSpec(key=n.key, level=n.level, center=centre, lo=lo, hi=hi, geometric_error=n.error,
                              content=uri, extras={"triangles": ntri})
            if n.height == 0:
                total_leaf_tris += ntri
            if n is root:
                root_tris = ntri
        for n in nodes:
            assert n.spec is not None
            n.spec.children = [c.spec for c in n.children if c.spec is not None]
        assert root.spec is not None
        write_tileset(partial, root.spec, model.crs, extras={"citylod": {
            "kind": "city", "objects": len(objects), "source": str(model.source), "format": model.version,
            "textured": textured, "atlas_px": atlas_px if textured else 0}})
        publish_dir(partial, out)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    return CityTilesReport(out, len(objects), len(nodes), root.height + 1, total_leaf_tris, root_tris,
                           root.error, time.perf_counter() - t0, warnings)
