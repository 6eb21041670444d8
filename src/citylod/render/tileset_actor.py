"""LOD actors: show the tiles that view-dependent selection picks, for one or more 3D Tiles tilesets.

A :class:`Scene` holds one or more :class:`TilesetLayer` objects that share a scene origin, one
:class:`~citylod.lod.runtime.cache.TileCache` and one :class:`~citylod.lod.runtime.loader.TileLoader`. Before a frame
(:meth:`Scene.update`, or automatically from the renderer's ``StartEvent`` after :meth:`Scene.attach`)
it runs :func:`citylod.lod.runtime.selection.select` for every layer, requests what is missing, and shows the
selected resident tiles by toggling the visibility of pooled actors. Off-screen renders call
:meth:`Scene.resolve`, which loads until the selection is complete.

Design points, each measured or required:

* **Large coordinates** (design decision 6): an actor's user matrix is
  ``translate(-scene_origin) · tile.matrix`` computed in float64, so the float32 positions of a tile stay
  relative to its own centre and the camera sits near the origin; nothing float32 ever sees 5e6 m.
* **Upload once, pool actors**: a tile's VTK geometry is built the first time it is shown and kept
  while the tile is resident; when the cache evicts it its actors go back to a pool and carry the next
  tile. Actors are never created per frame.
* **One actor per tile, not a merged composite** (``citylod.bench.actors`` measures both): per-tile
  actors drew a changing subset of tiles faster than a ``vtkCompositePolyDataMapper`` over a multiblock,
  and a composite cannot give each tile its own texture, which the orthophoto-textured DSM tiles need.
* **Skirts** (Wahl et al. 2004) are drawn by the surface's actor (a second, unpickable actor per tile
  would double the per-actor cost, which is what llvmpipe spends most on besides triangles); their
  cells carry the flag :data:`SKIRT_ARRAY`, and :func:`is_skirt_cell` tells a picker to look past them.
* **One CRS per scene**, the first layer's: a layer in another CRS is reprojected on the fly
  (:mod:`citylod.render.reproject`): its proxies carry transformed boxes and errors and a ``matrix`` that maps
  the transformed positions its loads produce; layers in the scene's CRS are not touched.

Nothing here imports Qt; VTK comes from :mod:`citylod.render._vtk`.
"""

from __future__ import annotations

import math
import os
import time
import warnings
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from citylod.core.camera import Camera, View
from citylod.core.errors import CitylodError
from citylod.core.geometry import F64, Box, translation
from citylod.io.tiles3d import Tile, Tileset, open_tileset
from citylod.io.tiles3d.remote import is_url
from citylod.lod.runtime.cache import TauController, TileCache
from citylod.lod.runtime.loader import TileLoader, resolve_layers
from citylod.lod.runtime.selection import Budget, Selection, select
from citylod.render import _vtk, flat_colors, skirts
from citylod.render.colors import COLOR_MODES, classification_rgb, intensity_rgb, level_color, ramp_rgb
from citylod.render.reproject import Reprojection, reprojection_for
from citylod.render.texture_residency import TextureResidency
from citylod.render.tile_data import PreparedMesh, PreparedTile, prepare_tile

__all__ = ["DEFAULT_POINT_BUDGET", "SKIRT_ARRAY", "FrameStats", "Scene", "TilesetLayer", "camera_to_vtk", "is_skirt_cell",
           "view_from_renderer"]

#: Name of the uint8 cell array that marks skirt triangles (1) in a tile's polydata.
SKIRT_ARRAY = "citylod_skirt"

#: Point budget given to point layers (tilesets whose ``extras.citylod.kind`` is "points") when they are
#: added: what this machine (llvmpipe, 2 cores) draws at interactive rates. Change it per layer through
#: ``layer.budget``.
DEFAULT_POINT_BUDGET = 1_000_000

_SURFACE_RGB = (0.86, 0.83, 0.76)  # untextured, uncoloured surfaces: light stone, so shading reads well
BACKGROUND = (0.72, 0.80, 0.90)  # the sky every renderer clears to, so pictures compare


# ----------------------------------------------------------------------------------- selection proxies
class _Node:
    """A tile as selection sees it, with a key unique across the scene's layers.

    Layers share one cache and loader, whose keys must not collide ("0/1" exists in every tileset),
    so each layer selects over a proxy tree built once when the layer is added.
    """

    __slots__ = ("box", "children", "content_bytes", "content_uri", "external", "geometric_error", "key", "level",
                 "matrix", "point_count", "refine", "reproject", "tile", "tree", "triangle_count")

    def __init__(self, tile: Tile, prefix: str, tree: _Tree | None = None) -> None:
        self.tile = tile
        self.tree = tree
        self.key = f"{prefix}{tile.key}"
        self.level = tile.level
        self.box: Box = tile.box
        self.geometric_error = float(tile.geometric_error)
        self.refine = tile.refine
        self.external = tile.external  # content in an external tileset: traversed whatever the error
        self.content_uri = tile.content_uri
        self.content_bytes = tile.content_bytes
        self.children: list[_Node] = []
        # The tile's hints (extras "points" / "triangles", 0 when absent) until it is loaded, when the
        # loader replaces them with the loaded counts: a point budget must count a tile before loading it.
        self.point_count = int(tile.point_count)
        self.triangle_count = int(tile.triangle_count)
        # Where the prepared positions are measured from, into the scene's CRS: the tile's own matrix, or
        # for a reprojected layer a translation to its transformed box centre (see _proxy_tree).
        self.matrix: F64 = tile.matrix
        self.reproject: Reprojection | None = None


    @property
    def pending(self) -> bool:
        """Children not proxied yet: external tilesets not read (or being read in the background), or read
        through another path (a walk)."""
        tree = self.tree
        if tree is not None and self.key in tree.failed:
            return False
        if tree is not None and self.key in tree.expanding:
            return True
        return self.tile.pending is not None or len(self.children) != len(self.tile.children)

    def expand(self, wait: bool = False) -> bool:
        """Read this tile's external tilesets (selection refines into them) and proxy the new children; True
        when children were added. With the scene's background reader (an interactive view), the files are read
        on its threads and this returns False until they are: the frame goes on with what it has. A tileset
        that cannot be read is one warning; the tile then stays without those children."""
        tree = self.tree
        assert tree is not None
        pool = tree.scene.expander if tree.scene is not None else None
        wait = wait or pool is None  # without a background reader (Scene.resolve), read it in this frame
        future = tree.expanding.get(self.key)
        if future is not None:
            if not future.done() and not wait:
                return False
            exc = future.exception()  # waits when asked to
            del tree.expanding[self.key]
            if exc is not None:
                return self._failed(exc)
        elif self.tile.pending is not None:
            if pool is not None and not wait:
                tree.expanding[self.key] = pool.submit(self.tile.tileset.expand, self.tile)
                return False
            try:
                self.tile.tileset.expand(self.tile)
            except CitylodError as exc:
                return self._failed(exc)
        known = {id(c.tile): c for c in self.children}
        new = [c for c in self.tile.children if id(c) not in known]
        if not new:
            return False
        _grow_proxies(self, new, tree)
        order = {id(t): i for i, t in enumerate(self.tile.children)}
        self.children.sort(key=lambda c: order[id(c.tile)])
        return True

    def _failed(self, exc: BaseException) -> bool:
        assert self.tree is not None
        if not isinstance(exc, CitylodError):
            raise exc
        self.tree.failed[self.key] = str(exc)
        warnings.warn(f"{exc}; the tiles below it are not drawn", stacklevel=3)
        return False


class _Tree:
    """What a layer's proxies share: their index by key, the layer's key prefix, its reprojection, and the
    tiles whose external tilesets could not be read."""

    __slots__ = ("expanding", "failed", "index", "prefix", "reprojection", "scene")

    def __init__(self, prefix: str, reprojection: Reprojection | None) -> None:
        self.index: dict[str, _Node] = {}
        self.prefix = prefix
        self.reprojection = reprojection
        self.failed: dict[str, str] = {}
        self.expanding: dict[str, Future[bool]] = {}  # key -> expansion running on the scene's reader
        self.scene: Scene | None = None


def _grow_proxies(parent: _Node | None, tiles: list[Tile], tree: _Tree) -> list[_Node]:
    """Proxies for ``tiles`` and every child already read below them, under ``parent``."""
    made: list[_Node] = []
    stack: list[tuple[_Node | None, Tile]] = [(parent, t) for t in tiles]
    while stack:
        up, tile = stack.pop()
        proxy = _Node(tile, tree.prefix, tree)
        if up is not None:
            up.children.append(proxy)
        tree.index[proxy.key] = proxy
        made.append(proxy)
        stack.extend((proxy, c) for c in reversed(tile.children))
    if tree.reprojection is not None:
        # Boxes and errors in the scene's CRS for selection (conservative: citylod.render.reproject).
        boxes, errors, _scale = tree.reprojection.boxes([n.box for n in made], [n.geometric_error for n in made])
        for n, box, err in zip(made, boxes, errors, strict=True):
            n.box = box
            n.geometric_error = float(err)
            n.matrix = translation(np.round(box.center))
            n.reproject = tree.reprojection
    return made


def _proxy_tree(root: Tile, prefix: str, reprojection: Reprojection | None = None) -> tuple[_Node, _Tree]:
    tree = _Tree(prefix, reprojection)
    top = _grow_proxies(None, [root], tree)[0]
    return top, tree


def _load_node(node: _Node) -> tuple[PreparedTile, int]:
    prepared, nbytes = prepare_tile(node)
    if node.reproject is not None:
        # On the loader's worker thread, in float64, before the scene origin shift.
        prepared = node.reproject.prepared(prepared, node.tile.matrix, node.matrix[:3, 3])
    for mesh in prepared.meshes:
        if len(mesh.skirt):
            # Skirts grouped by the side they hang on, so a frame draws only those a crack needs (render/skirts.py).
            order, mesh.skirt_groups = skirts.side_offsets(skirts.skirt_sides(mesh.positions, mesh.skirt, node.matrix,
                                                                              node.box))
            mesh.skirt = np.ascontiguousarray(mesh.skirt.reshape(-1, 3)[order].reshape(-1))
    node.point_count = prepared.point_count
    node.triangle_count = prepared.triangles
    return prepared, nbytes


# ------------------------------------------------------------------------------------------ VTK helpers
def _matrix(m: F64) -> Any:
    vm = _vtk.vtkMatrix4x4()
    vm.DeepCopy([float(v) for v in np.asarray(m, np.float64).reshape(16)])
    return vm


def _cells(conn: npt.NDArray[np.int64], per_cell: int) -> Any:
    ca = _vtk.vtkCellArray()
    offsets = np.arange(0, len(conn) + 1, per_cell, dtype=np.int64)
    ca.SetData(_vtk.numpy_to_vtkIdTypeArray(offsets, deep=True), _vtk.numpy_to_vtkIdTypeArray(conn, deep=True))
    return ca


def _set_surface_and_skirts(data: Any, surface: npt.NDArray[np.int64], skirt: npt.NDArray[np.int64]) -> Any:
    """Give ``data`` one triangle cell array, the surface's then the skirts' (one actor per tile, see the
    module docstring), with the skirt cells flagged in :data:`SKIRT_ARRAY` so a picker can reject them
    (:func:`is_skirt_cell`); returns the cell array."""
    data.SetPolys(_cells(np.concatenate([surface, skirt]), 3))
    flags = np.zeros((len(surface) + len(skirt)) // 3, np.uint8)
    flags[len(surface) // 3:] = 1
    flag_array = _vtk.numpy_to_vtk(flags, deep=True, array_type=_vtk.VTK_UNSIGNED_CHAR)
    flag_array.SetName(SKIRT_ARRAY)
    data.GetCellData().AddArray(flag_array)
    return data.GetPolys()


def _points(positions: npt.NDArray[np.float32]) -> Any:
    pts = _vtk.vtkPoints()
    # deep=True: VTK must own the buffer, since the numpy array may be freed with the cache entry.
    pts.SetData(_vtk.numpy_to_vtk(np.ascontiguousarray(positions, np.float32), deep=True))
    return pts


def _rgb_array(rgb: npt.NDArray[np.uint8], name: str = "rgb") -> Any:
    arr = _vtk.numpy_to_vtk(np.ascontiguousarray(rgb, np.uint8), deep=True, array_type=_vtk.VTK_UNSIGNED_CHAR)
    arr.SetName(name)
    return arr


# The scene's sun (see Scene._setup_renderer): a directional light from the north-west at 45°, with the
# surface material's ambient and diffuse coefficients.
_SUN = np.array([-1.0, 1.0, math.sqrt(2.0)]) / 2.0
_AMBIENT, _DIFFUSE = 0.3, 0.75


def baked_face_colors(positions: npt.NDArray[np.float32], faces: npt.NDArray[np.int64], matrix: F64,
                      base: Sequence[float]) -> npt.NDArray[np.uint8]:
    """(M, 3) uint8 colours of triangles lit by the scene's sun: ``base · (ambient + diffuse · max(0, n·L))``.

    ``positions`` are tile-local, ``faces`` the flat (3·M,) connectivity, ``matrix`` the tile's 4×4
    transform into the scene (normals transform with its inverse transpose). Faces keep their glTF
    winding (counter-clockwise is the front).
    """
    tri = positions.astype(np.float64)[faces.reshape(-1, 3)]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    lin = np.asarray(matrix, np.float64)[:3, :3]
    if not np.allclose(lin, np.eye(3)):
        n = n @ np.linalg.inv(lin)  # (inv(A)^T n^T)^T
    norm = np.linalg.norm(n, axis=1)
    cos = np.divide(n @ _SUN, norm, out=np.zeros(len(n)), where=norm > 0)
    shade = _AMBIENT + _DIFFUSE * np.maximum(cos, 0.0)
    rgb = np.clip(np.outer(shade, np.asarray(base, np.float64)), 0.0, 1.0)
    return np.round(rgb * 255.0).astype(np.uint8)


def camera_to_vtk(camera: Camera, vtk_camera: Any, origin: F64) -> None:
    """Set a VTK camera from a citylod :class:`Camera`, shifted by the scene ``origin``."""
    vtk_camera.SetPosition(*(np.asarray(camera.position, np.float64) - origin))
    vtk_camera.SetFocalPoint(*(np.asarray(camera.focal_point, np.float64) - origin))
    vtk_camera.SetViewUp(*camera.view_up)
    vtk_camera.SetViewAngle(camera.fovy_deg)
    vtk_camera.OrthogonalizeViewUp()


def is_skirt_cell(actor: Any, cell_id: int) -> bool:
    """True if cell ``cell_id`` of ``actor``'s tile mesh is a skirt triangle (pickers skip those)."""
    data = actor.GetMapper().GetInput() if actor is not None and actor.GetMapper() is not None else None
    arr = None if data is None else data.GetCellData().GetArray(SKIRT_ARRAY)
    return bool(arr is not None and 0 <= cell_id < arr.GetNumberOfTuples() and arr.GetValue(cell_id))


def view_from_renderer(renderer: Any, origin: F64) -> View:
    """The :class:`View` (in the data's CRS) of a VTK renderer whose scene is shifted by ``origin``."""
    cam = renderer.GetActiveCamera()
    w, h = renderer.GetSize()
    camera = Camera(
        position=tuple(np.asarray(cam.GetPosition()) + origin),  # type: ignore[arg-type]
        focal_point=tuple(np.asarray(cam.GetFocalPoint()) + origin),  # type: ignore[arg-type]
        view_up=tuple(cam.GetViewUp()),  # type: ignore[arg-type]
        fovy_deg=float(cam.GetViewAngle()),
    )
    return View(camera, max(int(w), 1), max(int(h), 1))


# -------------------------------------------------------------------------------------------- pooling
class _MeshProps:
    """The actor of one mesh (surface and skirt triangles in one polydata); pooled."""

    def __init__(self, counter: Callable[[], None]) -> None:
        self.mapper = _vtk.vtkPolyDataMapper()
        self.mapper.StaticOn()  # inputs are never pipeline outputs: skip the per-frame pipeline update
        self.mapper.SetColorModeToDirectScalars()
        self.actor = _vtk.vtkActor()
        counter()
        self.actor.SetMapper(self.mapper)
        self.actor.VisibilityOff()
        self.texture = _vtk.vtkTexture()
        self.texture.InterpolateOn()
        self.texture.MipmapOn()
        self.texture.RepeatOff()
        self.texture.EdgeClampOn()
        self.data: Any = None
        self.mesh: PreparedMesh | None = None
        self.flat = False  # the colour varying is flat (render/flat_colors.py)
        # The cell array this actor's tile was last given by fit_skirts or _upload, and the sides whose skirts
        # it holds; another owner of the cells (polygon edits) makes fit_skirts leave them alone.
        self.skirt_cells: Any = None
        self.skirt_kept = skirts.ALL_SIDES

    def set_flat(self, on: bool) -> None:
        if on != self.flat:
            flat_colors.set_flat(self.actor.GetShaderProperty(), on)
            self.flat = on

    def fit_skirts(self, sides: frozenset[int]) -> None:
        """Draw the surface and the skirts of ``sides`` only (render/skirts.py); skirts on no side always.

        Left alone: meshes without grouped skirts, meshes that could carry one colour per cell (their cell
        arrays must keep every triangle), and cells another owner has replaced."""
        mesh, data = self.mesh, self.data
        if mesh is None or data is None or mesh.skirt_groups is None or sides == self.skirt_kept:
            return
        if not (mesh.provoking or mesh.texture is not None or mesh.colors is not None):
            return
        if data.GetPolys() is not self.skirt_cells:
            return
        off = mesh.skirt_groups
        kept = [mesh.skirt[3 * off[0]:3 * off[1]]] + [mesh.skirt[3 * off[s + 1]:3 * off[s + 2]] for s in sorted(sides)]
        self.skirt_cells = _set_surface_and_skirts(data, mesh.surface, np.concatenate(kept))
        self.skirt_kept = sides


class _PointProps:
    def __init__(self, counter: Callable[[], None]) -> None:
        self.mapper = _vtk.vtkPolyDataMapper()
        self.mapper.StaticOn()
        self.mapper.SetColorModeToDirectScalars()
        self.actor = _vtk.vtkActor()
        counter()
        self.actor.SetMapper(self.mapper)
        self.actor.VisibilityOff()
        self.actor.GetProperty().LightingOff()
        self.data: Any = None
        # Smooth refinement draws a prefix of the tile's points: builders store them in shuffled Morton
        # batches, so any prefix is a uniform subsample (citylod.lod.kernels.octree.shuffled_runs).
        self.total = 0
        self.drawn = 0
        self.fade_start_s: float | None = None
        self.keep: npt.NDArray[np.bool_] | None = None
        # Splat drawing (TilesetLayer.point_shape == "splat"): a glyph mapper over the same data.
        self.splat_mapper: Any = None
        self.splat_data: Any = None  # the vtkPolyData whose splat arrays are computed
        self._splat_bits: npt.NDArray[np.uint8] | None = None  # the mask's bits, which VTK reads in place

    def use_splats(self, positions: npt.NDArray[np.float32]) -> None:
        """Draw the tile's points as oriented disks (:mod:`citylod.render.splats`): normals and radii from
        the tile's own points (refinement REPLACE: a tile's points are the whole surface at its level),
        computed once per uploaded tile. The smooth-refinement prefix does not apply to splats."""
        from citylod.render.splats import add_splat_arrays, estimate_splats, glyph_mapper

        if self.data is None:
            return
        if self.splat_mapper is None:
            self.splat_mapper = glyph_mapper()
        if self.splat_data is not self.data:
            add_splat_arrays(self.data, estimate_splats(positions))
            self.splat_data = self.data
        self.splat_mapper.SetInputData(self.data)
        self.set_splat_mask(self.keep)
        if self.actor.GetMapper() is not self.splat_mapper:
            # Unlit, as points are: a pixel has its point's colour (class, elevation...), and a disk whose
            # estimated normal is off (edges, crowns) does not show as a dark sliver.
            self.actor.SetMapper(self.splat_mapper)

    def set_splat_mask(self, mask: npt.NDArray[np.bool_] | None) -> None:
        """Glyph only the points where ``mask`` (total,) is true; None glyphs all. Splats are glyphs of the
        points, not of the vertex cells that :meth:`draw_first` and :meth:`set_keep` trim, so a class filter
        or a polygon's discard reaches them only through this mask. VTK's glyph mapper reads a bit array and
        ignores any other kind (a byte array was silently ignored before): bits packed first point highest,
        as ``vtkBitArray`` keeps them, read in place."""
        if self.splat_mapper is None or self.data is None:
            return
        if mask is None:
            self.splat_mapper.SetMasking(False)
            return
        self._splat_bits = np.packbits(np.asarray(mask, bool))
        bits = _vtk.vtkBitArray()
        bits.SetVoidArray(self._splat_bits, len(mask), 1)
        bits.SetName("splat_keep")
        self.data.GetPointData().AddArray(bits)
        self.splat_mapper.SetMaskArray("splat_keep")
        self.splat_mapper.SetMasking(True)

    def use_points(self) -> None:
        """Back to plain points (after :meth:`use_splats`)."""
        if self.actor.GetMapper() is not self.mapper:
            self.actor.SetMapper(self.mapper)

    def draw_first(self, k: int) -> None:
        """Draw the first ``k`` points of the tile (clamped to 1..total), those of them ``keep`` allows."""
        k = max(1, min(int(k), self.total))
        if k != self.drawn and self.data is not None:
            idx = np.arange(k, dtype=np.int64) if self.keep is None else np.flatnonzero(self.keep[:k])
            self.data.SetVerts(_cells(idx.astype(np.int64), 1))
            self.drawn = k

    def set_keep(self, keep: npt.NDArray[np.bool_] | None) -> None:
        """Draw only the points where ``keep`` (total,) is true (a class filter); None draws all."""
        if keep is None and self.keep is None:
            return
        self.keep = keep
        k = self.drawn if self.drawn > 0 else self.total
        self.drawn = -1
        self.draw_first(k)


class _Slot:
    """The VTK objects showing one resident tile. Returned to the pool when the tile leaves the cache."""

    def __init__(self) -> None:
        self.meshes: list[_MeshProps] = []
        self.points: _PointProps | None = None
        self.key: str | None = None
        self.level = 0
        self.prepared: PreparedTile | None = None
        self.visible = False
        self.user_matrix: Any = None

    def actors(self) -> Iterable[Any]:
        for m in self.meshes:
            yield m.actor
        if self.points is not None:
            yield self.points.actor

    def set_visible(self, on: bool) -> None:
        if on == self.visible:
            return
        self.visible = on
        n = 0 if self.prepared is None else len(self.prepared.meshes)
        for i, m in enumerate(self.meshes):
            m.actor.SetVisibility(on and i < n)
        if self.points is not None:
            self.points.actor.SetVisibility(on and self.points.data is not None)


# ------------------------------------------------------------------------------------------ statistics
@dataclass
class FrameStats:
    """What one frame drew and what the scene holds (counters only, no timings).

    ``tiles``, ``triangles``, ``points`` are summed over the drawn tiles of every layer; ``bytes_resident``
    is the cache fill; ``max_sse_px`` the largest screen-space error among the drawn tiles;
    ``requested`` the tiles still missing; ``complete`` is True when nothing more is requested.
    """

    tiles: int = 0
    triangles: int = 0
    points: int = 0
    bytes_drawn: int = 0
    bytes_resident: int = 0
    max_sse_px: float = 0.0
    requested: int = 0
    levels: dict[int, int] = field(default_factory=dict)
    tau_px: float = 0.0
    complete: bool = True
    failed: dict[str, str] = field(default_factory=dict)


# ---------------------------------------------------------------------------------------------- layer
class TilesetLayer:
    """One opened tileset in a :class:`Scene`: its selection, shown tiles and style.

    Created by :meth:`Scene.add`. Attributes that scripts change: ``visible``, ``tau_px`` (None → the
    scene's), ``budget`` (a :class:`~citylod.lod.runtime.selection.Budget`; point layers start with
    :data:`DEFAULT_POINT_BUDGET` points), ``color_by`` (None → the scene's), ``point_size_px``,
    ``smooth_refinement`` (point nodes that appear fade in over ``Scene.fade_s``; on for point layers).
    """

    def __init__(self, scene: Scene, tileset: Tileset, index: int, reprojection: Reprojection | None = None) -> None:
        self.scene = scene
        self.tileset = tileset
        self.name = tileset.path.parent.name
        self.prefix = f"{index}:"
        #: How the layer's coordinates reach the scene's CRS; None when the layer is in the scene's CRS.
        self.reprojection = reprojection
        self.root, self._tree = _proxy_tree(tileset.root, self.prefix, reprojection)
        self._tree.scene = scene
        self._nodes = self._tree.index
        self.visible = True
        self.tau_px: float | None = None
        cl = tileset.extras.get("citylod", {}) if isinstance(tileset.extras, dict) else {}
        self.kind = str(cl.get("kind", "")) if isinstance(cl, dict) else ""
        is_points = self.kind == "points"
        self.budget: Budget | None = Budget(max_points=DEFAULT_POINT_BUDGET) if is_points else None
        self.smooth_refinement = is_points
        self.color_by: str | None = None
        self.point_size_px = 2.0
        self.point_round = False  # round (sphere-shaded) points instead of squares
        #: "points" (squares, or round with ``point_round``) or "splat" (oriented disks sized by the local
        #: spacing, hole-free at close range: :mod:`citylod.render.splats`).
        self.point_shape = "points"
        #: ASPRS classes to draw (None: all); points of other classes are left out of the drawn cells.
        self.class_filter: frozenset[int] | None = None
        #: Refine a tile whose visible children hold fewer triangles, though its error is small enough
        #: (``select(..., refine_to_cull=...)``; False for A/B measurements).
        self.refine_to_cull = True
        #: Draw a tile's skirts only on sides without a drawn same-level neighbour (render/skirts.py). Off by
        #: default: each change of a tile's sides uploads its whole mesh again (see render/skirts.py).
        self.skirts_where_needed = False
        self._skirt_keys: tuple[frozenset[str], bool] | None = None
        self._skirts_fitted = False
        self.selection: Selection | None = None
        self._slots: dict[str, _Slot] = {}
        self._shown: set[str] = set()
        self._intensity_range: tuple[float, float] | None = None

    def __repr__(self) -> str:
        return f"TilesetLayer({self.name!r}, tiles shown={len(self._shown)})"

    @property
    def shown_keys(self) -> frozenset[str]:
        """Scene keys of the tiles drawn in the last frame."""
        return frozenset(self._shown)

    @property
    def bounds(self) -> tuple[F64, F64]:
        """Axis-aligned bounds of the layer in the scene's CRS (the tileset's, reprojected if it must be)."""
        return self.root.box.bounds()

    @property
    def effective_color_by(self) -> str:
        return self.color_by or self.scene.color_by

    def node(self, key: str) -> _Node:
        return self._nodes[key]

    def leaves(self) -> list[_Node]:
        """Proxy nodes of the tiles with content and no children with content (the full resolution); external
        tilesets not read yet are read first."""
        stack = [self.root]
        while stack:
            node = stack.pop()
            if node.pending:
                node.expand(wait=True)
            stack.extend(node.children)
        out = []
        for node in list(self._nodes.values()):
            if node.content_uri is not None and not node.children:
                out.append(node)
        return out

    # -- styling ----------------------------------------------------------------------------------
    def _mesh_style(self, props: _MeshProps, mesh: PreparedMesh, level: int, mode: str, tile: Tile | _Node) -> None:
        prop = props.actor.GetProperty()
        props.mapper.ScalarVisibilityOff()
        props.mapper.SetScalarModeToDefault()
        props.actor.SetTexture(None)
        lit = True
        flat = False
        if mode == "level" or (mode in ("auto", "rgb") and mesh.texture is None and mesh.colors is None):
            # One colour per tile: the sun's diffuse light is baked into per-triangle colours, drawn
            # unlit. Same image as VTK's per-fragment lighting of faceted meshes (a directional light, no
            # specular), at about half the fill cost on llvmpipe.
            base = level_color(level) if mode == "level" else _SURFACE_RGB
            conn = np.concatenate([mesh.surface, mesh.skirt])
            rgb = baked_face_colors(mesh.positions, conn, tile.matrix, base)
            if mesh.provoking:
                # Each triangle's colour on its own last corner, drawn flat (render/flat_colors.py):
                # no per-fragment lookup by primitive ID.
                vertex_rgb = np.zeros((len(mesh.positions), 3), np.uint8)
                vertex_rgb[conn.reshape(-1, 3)[:, 2]] = rgb
                props.data.GetPointData().SetScalars(_rgb_array(vertex_rgb, "shaded"))
                props.mapper.SetScalarModeToUsePointData()
                flat = True
            else:
                props.data.GetCellData().SetScalars(_rgb_array(rgb, "shaded"))
                props.mapper.SetScalarModeToUseCellData()
            props.mapper.ScalarVisibilityOn()
            prop.SetColor(1.0, 1.0, 1.0)
            lit = False
        elif mode in ("auto", "rgb") and mesh.texture is not None:
            props.actor.SetTexture(props.texture)
            prop.SetColor(1.0, 1.0, 1.0)
            lit = False  # the orthophoto already holds the light (glTF KHR_materials_unlit)
        elif mode in ("auto", "rgb") and mesh.colors is not None:
            props.data.GetPointData().SetScalars(_rgb_array(mesh.colors, "colors"))
            props.mapper.ScalarVisibilityOn()
        elif mode == "elevation":
            rgb = ramp_rgb(self._absolute_z(mesh.positions, tile), *self.scene.elevation_range)
            props.data.GetPointData().SetScalars(_rgb_array(rgb, "elevation"))
            props.mapper.SetScalarModeToUsePointData()
            props.mapper.ScalarVisibilityOn()
        else:
            prop.SetColor(*_SURFACE_RGB)
        if lit:
            prop.LightingOn()
            prop.SetAmbient(_AMBIENT)
            prop.SetDiffuse(_DIFFUSE)
            prop.SetSpecular(0.0)
        else:
            prop.LightingOff()
        props.set_flat(flat)
        # Single-sided content (a height field: surface up, skirts outward) has its back faces culled, as
        # glTF clients do: on a city DSM about a quarter of the τ = 1 px frame's time went to rasterising faces
        # that the front ones hide (docs/PERFORMANCE_LOG.md). Not through a reprojection, whose warp may mirror.
        prop.SetBackfaceCulling(not mesh.double_sided and self.reprojection is None)

    @staticmethod
    def _absolute_z(positions: npt.NDArray[np.float32], tile: Tile | _Node) -> npt.NDArray[np.float64]:
        m = tile.matrix
        return positions.astype(np.float64) @ m[2, :3] + m[2, 3]

    def _point_rgb(self, pts: Any, mode: str, level: int, tile: Tile | _Node) -> npt.NDArray[np.uint8] | None:
        if mode == "auto":
            mode = "rgb" if pts.rgb is not None else "classification" if pts.classification is not None \
                else "elevation"
        if mode == "level":
            return None
        if mode == "rgb" and pts.rgb is not None:
            return np.asarray(pts.rgb, np.uint8)
        if mode == "classification" and pts.classification is not None:
            return classification_rgb(pts.classification)
        if mode == "intensity" and pts.intensity is not None:
            if self._intensity_range is None:
                # Fixed at the first tile seen, so colours do not jump as tiles stream in.
                lo, hi = np.percentile(pts.intensity, [2, 98])
                self._intensity_range = (float(lo), float(max(hi, lo + 1)))
            return intensity_rgb(pts.intensity, *self._intensity_range)
        return ramp_rgb(self._absolute_z(pts.positions, tile), *self.scene.elevation_range)

    def _point_style(self, props: _PointProps, pts: Any, level: int, mode: str, tile: Tile | _Node) -> None:
        rgb = self._point_rgb(pts, mode, level, tile)
        prop = props.actor.GetProperty()
        prop.SetPointSize(self.point_size_px)
        prop.SetRenderPointsAsSpheres(self.point_round)
        keep = None
        if self.class_filter is not None and pts.classification is not None:
            keep = np.isin(pts.classification, np.fromiter(self.class_filter, np.int64))
        props.set_keep(keep)
        if rgb is None:
            props.mapper.ScalarVisibilityOff()
            prop.SetColor(*level_color(level))
        else:
            props.data.GetPointData().SetScalars(_rgb_array(rgb))
            props.mapper.ScalarVisibilityOn()
        if self.point_shape == "splat":
            props.use_splats(pts.positions)
            props.splat_mapper.SetScalarVisibility(rgb is not None)
        else:
            props.use_points()

    def restyle(self) -> None:
        """Apply the current ``color_by`` and point size to every uploaded tile (once, not per frame)."""
        mode = self.effective_color_by
        for slot in self._slots.values():
            self._style_slot(slot, mode)

    def _style_slot(self, slot: _Slot, mode: str) -> None:
        prepared = slot.prepared
        assert prepared is not None and slot.key is not None
        tile = self._nodes[slot.key]  # its matrix maps the prepared positions (reprojected or not)
        for props, mesh in zip(slot.meshes, prepared.meshes, strict=False):
            self._mesh_style(props, mesh, prepared.level, mode, tile)
        if slot.points is not None and prepared.points is not None and slot.points.data is not None:
            self._point_style(slot.points, prepared.points, prepared.level, mode, tile)

    # -- upload -----------------------------------------------------------------------------------
    def _upload(self, node: _Node, prepared: PreparedTile) -> _Slot:
        slot = self.scene._take_slot()
        slot.key = node.key
        slot.level = node.level
        slot.prepared = prepared
        user = _matrix(translation(-self.scene.origin) @ node.matrix)
        slot.user_matrix = user
        while len(slot.meshes) < len(prepared.meshes):
            props = _MeshProps(self.scene._count_actor)
            props.texture.SetMaximumAnisotropicFiltering(self.scene.texture_anisotropy)
            slot.meshes.append(props)
            self.scene.renderer.AddActor(props.actor)
            self.scene._actor_created(props.actor)
        for props, mesh in zip(slot.meshes, prepared.meshes, strict=False):
            data = _vtk.vtkPolyData()
            data.SetPoints(_points(mesh.positions))
            props.skirt_cells = _set_surface_and_skirts(data, mesh.surface, mesh.skirt)
            props.skirt_kept = skirts.ALL_SIDES
            if mesh.tcoords is not None and mesh.texture is not None:
                tc = _vtk.numpy_to_vtk(mesh.tcoords, deep=True)
                tc.SetName("tcoords")
                data.GetPointData().SetTCoords(tc)
                props.texture.SetInputData(_image(mesh.texture))
            props.data, props.mesh = data, mesh
            props.mapper.SetInputData(data)
            props.actor.SetUserMatrix(user)
        if prepared.points is not None and len(prepared.points.positions):
            if slot.points is None:
                slot.points = _PointProps(self.scene._count_actor)
                self.scene.renderer.AddActor(slot.points.actor)
                self.scene._actor_created(slot.points.actor)
            data = _vtk.vtkPolyData()
            data.SetPoints(_points(prepared.points.positions))
            data.SetVerts(_cells(np.arange(len(prepared.points.positions), dtype=np.int64), 1))
            slot.points.data = data
            slot.points.total = slot.points.drawn = len(prepared.points.positions)
            slot.points.fade_start_s = None
            slot.points.mapper.SetInputData(data)
            slot.points.actor.SetUserMatrix(user)
        elif slot.points is not None:
            slot.points.data = None
        self._style_slot(slot, self.effective_color_by)
        self._slots[node.key] = slot
        self._skirt_keys = None  # its skirts are fitted with the next frame's
        self.scene.uploads += 1
        return slot

    def _release(self, key: str) -> None:
        slot = self._slots.pop(key, None)
        self._shown.discard(key)
        if slot is not None:
            self.scene._return_slot(slot)

    # -- frame ------------------------------------------------------------------------------------
    def _show(self, render: Sequence[Any], now_s: float | None = None) -> None:
        """Show exactly the tiles of ``render``: upload what is new, hide what left.

        ``now_s`` (the scene clock, from :meth:`Scene.update`) lets point tiles that appear fade in
        (``smooth_refinement``); without it every shown tile draws all its points.
        """
        want = {n.key for n in render} if self.visible else set()
        for key in self._shown - want:
            slot = self._slots.get(key)
            if slot is not None:
                slot.set_visible(False)
        shown: set[str] = set()
        fade = now_s is not None and self.smooth_refinement
        for node in render if self.visible else ():
            slot = self._slots.get(node.key)
            if slot is None:
                prepared = self.scene.cache.get(node.key)
                if prepared is None:
                    continue
                slot = self._upload(node, prepared)
            appears = not slot.visible
            slot.set_visible(True)
            shown.add(node.key)
            pts = slot.points
            if pts is not None and pts.data is not None:
                if fade and appears:
                    pts.fade_start_s = now_s
                if fade and pts.fade_start_s is not None:
                    assert now_s is not None
                    f = fade_fraction(now_s - pts.fade_start_s, self.scene.fade_s, self.scene.fade_from)
                    if f >= 1.0:
                        pts.fade_start_s = None
                    pts.draw_first(math.ceil(f * pts.total))
                else:
                    pts.fade_start_s = None
                    pts.draw_first(pts.total)
        self._shown = shown
        self._fit_skirts(render)

    def _fit_skirts(self, render: Sequence[Any]) -> None:
        """Give every shown tile the skirts its drawn neighbours leave a crack for (once per set of tiles)."""
        state = (frozenset(self._shown), self.skirts_where_needed)
        # Until fitting is first turned on every tile keeps every skirt, and there is nothing to do; after, a
        # tile shown again gets its skirts back once fitting is off.
        self._skirts_fitted = self._skirts_fitted or self.skirts_where_needed
        if state == self._skirt_keys or not self._skirts_fitted:
            return
        self._skirt_keys = state
        nodes = [n for n in render if n.key in self._shown]
        need = skirts.needed_sides(nodes) if self.skirts_where_needed else {}
        for n in nodes:
            for props in self._slots[n.key].meshes:
                props.fit_skirts(need.get(n.key, skirts.ALL_SIDES))

    def show_leaves(self, keys: Iterable[str] | None = None) -> None:
        """Show the given tiles (default: every leaf), bypassing selection; used for full-resolution
        baselines. The tiles must be resident (see :meth:`Scene.load`)."""
        nodes = [self._nodes[k] for k in keys] if keys is not None else self.leaves()
        self._show(nodes)


_EMPTY = _vtk.vtkPolyData()
#: Loader threads of a scene with a layer on a web server (Scene.add): they mostly wait on the network.
REMOTE_LOADER_WORKERS = 8


def fade_fraction(age_s: float, fade_s: float, start: float) -> float:
    """Share of a point tile's points drawn ``age_s`` after it appeared: ``start`` growing linearly to 1
    over ``fade_s`` (smooth refinement, Kehl et al.: new detail fades in instead of popping)."""
    if fade_s <= 0.0 or age_s >= fade_s:
        return 1.0
    return min(1.0, max(start, start + (1.0 - start) * max(age_s, 0.0) / fade_s))


def _image(rgb: npt.NDArray[np.uint8]) -> Any:
    h, w, c = rgb.shape
    img = _vtk.vtkImageData()
    img.SetDimensions(w, h, 1)
    arr = _vtk.numpy_to_vtk(np.ascontiguousarray(rgb).reshape(-1, c), deep=True,
                            array_type=_vtk.VTK_UNSIGNED_CHAR)
    img.GetPointData().SetScalars(arr)
    return img


# ---------------------------------------------------------------------------------------------- scene
class Scene:
    """Several tilesets drawn into one VTK renderer with a shared origin, cache and loader.

    Parameters
    ----------
    renderer
        The VTK renderer to draw into (a new one when omitted).
    origin
        Scene origin in the data's CRS (3,); default: the centre of the first layer's root box, rounded to
        the metre. Actors and the camera are placed relative to it.
    cache_bytes
        Byte budget of the shared tile cache (a hard cap).
    workers
        Loader threads.
    tau_px
        Default screen-space error threshold in pixels.
    color_by
        One of :data:`citylod.render.colors.COLOR_MODES`.
    adaptive_tau
        Raise τ under memory pressure (:class:`~citylod.lod.runtime.cache.TauController`) in :meth:`update`.
    texture_budget_bytes
        Cap on the GL texture memory of the tiles (None: only the cache budget limits it), kept with
        Buchholz's priority (:class:`~citylod.render.texture_residency.TextureResidency`) by :meth:`update`
        and :meth:`resolve`; full-resolution baselines (:meth:`load`) bypass it.
    texture_anisotropy
        Largest anisotropic filtering of tile textures; 1 (OpenGL's default) is isotropic trilinear
        mipmapping. VTK's default of 4 costs up to 55× the fill time of oblique façades on llvmpipe
        (docs/PERFORMANCE_LOG.md) for a slightly sharper grazing view.
    """

    def __init__(self, renderer: Any = None, *, origin: npt.ArrayLike | None = None,
                 cache_bytes: int = 1 << 30, workers: int = 2, tau_px: float = 1.0, color_by: str = "auto",
                 adaptive_tau: bool = False, texture_budget_bytes: int | None = None,
                 texture_anisotropy: float = 1.0) -> None:
        if color_by not in COLOR_MODES:
            raise CitylodError(f"unknown colour mode {color_by!r}; choose one of {', '.join(COLOR_MODES)}")
        self.renderer = renderer if renderer is not None else _vtk.vtkRenderer()
        self.origin: F64 | None = None if origin is None else np.asarray(origin, np.float64)
        self.cache = TileCache(cache_bytes)
        self.loader = TileLoader(_load_node, self.cache, workers=workers)
        # Reads external tilesets in the background (expand_in_background); None reads them in the frame that
        # reaches them, which off-screen renders want (they resolve until nothing is missing).
        self.expander: ThreadPoolExecutor | None = None
        self.tau_px = float(tau_px)
        self.color_by = color_by
        self.layers: list[TilesetLayer] = []
        self.frozen = False
        self.tau_controller = TauController(self.tau_px) if adaptive_tau else None
        # Smooth refinement of point layers in update(): a point tile that appears draws fade_from of
        # its points, growing to all of them over fade_s seconds of clock() (replaceable in tests).
        self.fade_s = 0.3
        self.fade_from = 0.2
        self.clock: Callable[[], float] = time.monotonic
        # Most drawing cost (points + triangles) of finished tiles that one update() admits and uploads;
        # None admits all. An interactive view sets it so one frame's uploads stay bounded.
        self.admit_cost: int | None = None
        self.admitted_cost = 0  # what the last update() admitted, same units
        # Called with the frame's view before its selection (budget mode plans the point budget from the
        # view's candidate tiles: citylod.render.frame_budget). None: nothing is called.
        self.before_select: Callable[[View], None] | None = None
        self.crs: Any = None
        self.elevation_range = (0.0, 1.0)
        # Counters that tests and the HUD read.
        self.actors_created = 0
        self.uploads = 0
        self.frame = 0
        self.last_stats = FrameStats()
        self._free: list[_Slot] = []
        self._observer: int | None = None
        # Semantic overlays (citylod.render.semantic) style every tile actor, present and future.
        self._tile_actors: list[Any] = []
        self._actor_hooks: list[Callable[[Any], None]] = []
        self.texture_anisotropy = float(texture_anisotropy)
        self.textures = None if texture_budget_bytes is None else TextureResidency(self, texture_budget_bytes)
        self._frame_view: View | None = None
        self._setup_renderer()

    def _setup_renderer(self) -> None:
        ren = self.renderer
        ren.SetBackground(*BACKGROUND)
        ren.AutomaticLightCreationOff()
        ren.RemoveAllLights()
        light = _vtk.vtkLight()
        # A sun from the north-west at 45° in the data frame (shaded relief convention), not a headlight:
        # terrain seen from above would otherwise look flat.
        light.SetLightTypeToSceneLight()
        light.SetPositional(False)
        light.SetPosition(-1.0, 1.0, math.sqrt(2.0))
        light.SetFocalPoint(0.0, 0.0, 0.0)
        light.SetIntensity(1.0)
        ren.AddLight(light)

    # -- layers -----------------------------------------------------------------------------------
    def add(self, source: str | os.PathLike[str] | Tileset) -> TilesetLayer:
        """Open and add a tileset (folder, ``tileset.json`` or an opened :class:`Tileset`).

        The scene's CRS is the first layer's; a layer in another CRS is reprojected on the fly
        (:mod:`citylod.render.reproject`, ``layer.reprojection``). CitylodError when no transformation
        relates the two CRSs.
        """
        ts = source if isinstance(source, Tileset) else open_tileset(Path(source))
        reprojection = None
        if self.crs is not None and not ts.crs.equals(self.crs):
            # Drawn in the scene's CRS (the first layer's), transformed on the fly: citylod.render.reproject.
            reprojection = reprojection_for(ts.crs, self.crs, str(ts.path), ts.root.box.corners(), self.origin)
        self.crs = self.crs if self.crs is not None else ts.crs
        if self.origin is None:
            self.origin = np.round(ts.root.box.center)
        layer = TilesetLayer(self, ts, len(self.layers), reprojection)
        self.layers.append(layer)
        if is_url(ts.source):
            self.loader.ensure_workers(REMOTE_LOADER_WORKERS)
        lo = min(lay.bounds[0][2] for lay in self.layers)
        hi = max(lay.bounds[1][2] for lay in self.layers)
        self.elevation_range = (float(lo), float(hi if hi > lo else lo + 1.0))
        return layer

    def expand_in_background(self, workers: int = 4) -> None:
        """Read external tilesets (and implicit subtrees) that views reach on background threads: a frame
        never waits on a file or a web server; until they are read, the tiles above them stay drawn. For
        interactive views; :meth:`expanding` says how many are being read."""
        if self.expander is None:
            self.expander = ThreadPoolExecutor(workers, thread_name_prefix="citylod-expand")

    def expanding(self) -> int:
        """External tilesets being read in the background, and read but not yet taken into the tree."""
        return sum(len(layer._tree.expanding) for layer in self.layers)

    def expansions_done(self) -> int:
        """External tilesets read in the background that the next frame takes into the tree."""
        return sum(f.done() for layer in self.layers for f in layer._tree.expanding.values())

    @property
    def bounds(self) -> tuple[F64, F64]:
        """Axis-aligned bounds of every layer in the scene's CRS (reprojected layers' transformed boxes)."""
        if not self.layers:
            raise CitylodError("the scene has no layers")
        los = np.array([lay.bounds[0] for lay in self.layers])
        his = np.array([lay.bounds[1] for lay in self.layers])
        return los.min(axis=0), his.max(axis=0)

    def set_color_by(self, mode: str) -> None:
        """Change the colour mode of every layer (recolours resident tiles once)."""
        if mode not in COLOR_MODES:
            raise CitylodError(f"unknown colour mode {mode!r}; choose one of {', '.join(COLOR_MODES)}")
        self.color_by = mode
        for layer in self.layers:
            layer.restyle()

    # -- pool -------------------------------------------------------------------------------------
    def _count_actor(self) -> None:
        self.actors_created += 1

    def add_actor_hook(self, hook: Callable[[Any], None]) -> Callable[[], None]:
        """Call ``hook(actor)`` for every tile actor: now for those that exist, then for each new one.

        Actors are pooled, so a hook runs once per actor, not once per tile (used by
        :class:`citylod.render.semantic.SemanticOverlay` to attach its shader). Returns a function that
        removes the hook.
        """
        self._actor_hooks.append(hook)
        for actor in self._tile_actors:
            hook(actor)

        def remove() -> None:
            if hook in self._actor_hooks:
                self._actor_hooks.remove(hook)

        return remove

    @property
    def tile_actors(self) -> tuple[Any, ...]:
        """Every tile actor created so far (shown, hidden or pooled)."""
        return tuple(self._tile_actors)

    def _actor_created(self, actor: Any) -> None:
        self._tile_actors.append(actor)
        for hook in list(self._actor_hooks):
            hook(actor)

    def _take_slot(self) -> _Slot:
        return self._free.pop() if self._free else _Slot()

    def _return_slot(self, slot: _Slot) -> None:
        slot.set_visible(False)
        slot.key = None
        slot.prepared = None
        for m in slot.meshes:
            # Drop geometry and texture so their memory goes with the evicted tile; actors stay pooled.
            m.mapper.SetInputData(_EMPTY)
            m.data = m.mesh = None
            m.texture.SetInputData(None)
            window = self.renderer.GetRenderWindow()
            if window is not None:
                m.texture.ReleaseGraphicsResources(window)  # the GL texture leaves with the tile
        if slot.points is not None:
            slot.points.mapper.SetInputData(_EMPTY)
            slot.points.data = None
            if slot.points.splat_mapper is not None:
                slot.points.splat_mapper.SetInputData(_EMPTY)
                slot.points.splat_data = None
        self._free.append(slot)

    def tile_textures(self) -> Iterable[Any]:
        """Every tile actor's ``vtkTexture`` (shown, hidden and pooled), for counting texture memory."""
        for slot in [s for layer in self.layers for s in layer._slots.values()] + self._free:
            for m in slot.meshes:
                yield m.texture

    @property
    def slots_in_use(self) -> int:
        return sum(len(layer._slots) for layer in self.layers)

    @property
    def fading(self) -> bool:
        """True while a shown point tile is still fading in: a view should keep rendering frames."""
        return any(slot.visible and slot.points is not None and slot.points.fade_start_s is not None
                   for layer in self.layers for slot in layer._slots.values())

    def _layer_of(self, key: str) -> TilesetLayer:
        return self.layers[int(key.split(":", 1)[0])]

    def _release_evicted(self) -> None:
        for key in self.cache.evict():
            self._layer_of(key)._release(key)

    # -- camera -----------------------------------------------------------------------------------
    def set_camera(self, camera: Camera) -> None:
        """Place the renderer's camera (``camera`` is in the data's CRS)."""
        assert self.origin is not None, "add a layer first"
        camera_to_vtk(camera, self.renderer.GetActiveCamera(), self.origin)

    def view(self, camera: Camera | None = None, size: tuple[int, int] | None = None) -> View:
        """The :class:`View` of ``camera`` (default: the renderer's) at ``size`` (default: the renderer's)."""
        assert self.origin is not None, "add a layer first"
        if camera is None:
            return view_from_renderer(self.renderer, self.origin)
        w, h = size if size is not None else self.renderer.GetSize()
        return View(camera, max(int(w), 1), max(int(h), 1))

    # -- frames -----------------------------------------------------------------------------------
    def _tau(self, layer: TilesetLayer) -> float:
        base = layer.tau_px if layer.tau_px is not None else self.tau_px
        if self.tau_controller is not None:
            return base * self.tau_controller.tau_px / self.tau_controller.base_tau_px
        return base

    def select_all(self, view: View) -> list[Selection]:
        """Run selection for every layer against what is resident now (no loading, no showing)."""
        if self.before_select is not None:
            self.before_select(view)
        residency = self.cache.residency()
        failed = self.loader.failed_keys()
        sels = []
        for layer in self.layers:
            if not layer.visible:
                sels.append(Selection([], [], _empty_stats()))
                continue
            sels.append(select(layer.root, view, tau_px=self._tau(layer), budget=layer.budget,
                               resident=residency, unavailable=failed, frame=self.frame,
                               refine_to_cull=layer.refine_to_cull))
        return sels

    def _pin_and_request(self, sels: Sequence[Selection], request: bool = True) -> int:
        keys = [n.key for s in sels for n in s.render] + [k for s in sels for k in s.request]
        self.cache.touch(keys)
        if not request:
            return 0
        # Interleave the layers' request lists so one large layer cannot starve the others.
        merged: list[Any] = []
        if self.textures is not None and self._frame_view is not None:
            # Buchholz's texture budget: loads it does not admit wait, and their parents stay drawn.
            self.textures.apply(sels, self._frame_view)
            refused = self.textures.refused
            lists = [[n for n in s.request_nodes if n.key not in refused] for s in sels]
        else:
            lists = [list(s.request_nodes) for s in sels]
        for i in range(max((len(x) for x in lists), default=0)):
            merged.extend(x[i] for x in lists if i < len(x))
        return self.loader.request(merged)

    def update(self, view: View | None = None) -> FrameStats:
        """Select and show tiles for ``view`` (default: the renderer's camera); never blocks on I/O once the
        scene reads external tilesets in the background (:meth:`expand_in_background`, as the app does).

        Finished loads enter the cache, missing tiles are requested, and the tiles already resident are
        shown. Call before every render (or use :meth:`attach`). In frozen mode the shown tiles stay.
        """
        if not self.layers:
            return FrameStats()
        admitted = self.loader.poll(self.admit_cost)
        self.admitted_cost = 0
        for key in admitted:
            info = self.cache.info(key)
            if info is not None:
                self.admitted_cost += int(info.points) + int(info.triangles)
        if self.frozen:
            return self.last_stats
        view = view or self.view()
        if self.tau_controller is not None:
            self.tau_controller.update(self.cache.bytes_used, self.cache.budget_bytes)
        sels = self.select_all(view)
        self._frame_view = view
        self._pin_and_request(sels)
        self._release_evicted()
        now_s = self.clock()
        for layer, sel in zip(self.layers, sels, strict=True):
            layer.selection = sel
            layer._show(sel.render, now_s)
        self.frame += 1
        self.last_stats = self._stats(sels, view)
        return self.last_stats

    def resolve(self, view: View, *, max_rounds: int = 64, timeout_s: float | None = 120.0) -> FrameStats:
        """Load until the selection for ``view`` is complete, then show it (for off-screen renders).

        :func:`citylod.lod.runtime.loader.resolve_layers` over every layer at once, so the tiles of one
        layer stay pinned in the shared cache while another's load.
        """
        if not self.layers:
            return FrameStats()
        self._frame_view = view
        # External tilesets are read in the frame that reaches them here, so "complete" means complete.
        pool, self.expander = self.expander, None
        try:
            sels = resolve_layers(lambda _frame: self.select_all(view), self.loader,
                                  request=self._pin_and_request, max_iterations=max_rounds, timeout_s=timeout_s)
        except TimeoutError as exc:
            raise CitylodError(str(exc)) from None
        finally:
            self.expander = pool
        self._release_evicted()
        for layer, sel in zip(self.layers, sels, strict=True):
            layer.selection = sel
            layer._show(sel.render)
        self.frame += 1
        self.last_stats = self._stats(sels, view)
        return self.last_stats

    def load(self, keys_by_layer: Sequence[Sequence[str]], *, timeout_s: float | None = 300.0) -> list[str]:
        """Make the given tiles resident (pinned), bypassing selection; returns keys that are not.

        For full-resolution baselines: every leaf of a layer, whatever the view.
        """
        keys = [k for ks in keys_by_layer for k in ks]
        nodes = [self._layer_of(k).node(k) for k in keys]
        self.cache.touch(keys)
        self.loader.request(nodes)
        if not self.loader.wait_idle(timeout_s):
            raise CitylodError(f"tile loads did not finish within {timeout_s} s")
        self.loader.poll()
        self._release_evicted()
        return [k for k in keys if k not in self.cache]

    def show_full_resolution(self, view: View | None = None) -> FrameStats:
        """Load and show every leaf of every layer (no LOD): the baseline the benchmark compares with."""
        leaves = [[n.key for n in layer.leaves()] for layer in self.layers]
        missing = self.load(leaves)
        failed = self.loader.failed_keys()
        missing = [k for k in missing if k not in failed]
        if missing:
            raise CitylodError(f"{len(missing)} full-resolution tiles do not fit the cache "
                               f"({self.cache.budget_bytes} bytes); raise cache_bytes")
        stats = FrameStats(tau_px=0.0)
        for layer, keys in zip(self.layers, leaves, strict=True):
            present = [k for k in keys if k in self.cache]
            layer.selection = None
            layer._show([layer.node(k) for k in present])
            for k in present:
                info = self.cache.info(k)
                stats.tiles += 1
                lvl = layer.node(k).level
                stats.levels[lvl] = stats.levels.get(lvl, 0) + 1
                if info is not None:
                    stats.triangles += info.triangles
                    stats.points += info.points
                    stats.bytes_drawn += info.bytes
        stats.bytes_resident = self.cache.bytes_used
        stats.failed = self.loader.failed
        self.last_stats = stats
        return stats

    def _stats(self, sels: Sequence[Selection], view: View) -> FrameStats:
        st = FrameStats(bytes_resident=self.cache.bytes_used, failed=self.loader.failed)
        st.tau_px = self._tau(self.layers[0]) if self.layers else self.tau_px
        for sel in sels:
            st.tiles += sel.stats.selected
            st.triangles += sel.stats.triangles
            st.points += sel.stats.points
            st.bytes_drawn += sel.stats.bytes
            st.max_sse_px = max(st.max_sse_px, sel.stats.max_sse_px)
            st.requested += len(sel.request)
            for n in sel.render:
                st.levels[n.level] = st.levels.get(n.level, 0) + 1
        st.complete = st.requested == 0 and self.expanding() == 0
        return st

    # -- renderer hook ----------------------------------------------------------------------------
    def attach(self) -> None:
        """Run :meth:`update` from the renderer's ``StartEvent``, i.e. before every render."""
        if self._observer is None:
            self._observer = self.renderer.AddObserver(_vtk.vtkCommand.StartEvent, self._on_start)

    def detach(self) -> None:
        if self._observer is not None:
            self.renderer.RemoveObserver(self._observer)
            self._observer = None

    def _on_start(self, _obj: Any, _event: str) -> None:
        self.update()
        self.renderer.ResetCameraClippingRange()

    def close(self) -> None:
        """Stop the loader threads."""
        self.detach()
        self.loader.close()

    def __enter__(self) -> Scene:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _empty_stats() -> Any:
    from citylod.lod.runtime.selection import SelectionStats

    return SelectionStats()
