"""Drawing a city with far-field surface light fields (:mod:`citylod.lod.build.slf`), and the baseline that
draws its building geometry, into one off-screen window each.

:class:`SlfView` walks the far-field quadtree per frame: a cell whose screen-space error
(``geometricError`` at its distance, docs/DESIGN.md decision 2) is at most τ is drawn as its terrain quad with
the field evaluated for the direction from the cell's centre to the eye (bilinear between the four nearest
stored directions, depth-corrected with the cell's building tops,
:func:`citylod.lod.kernels.slf.depth_corrected_blend`): per pixel by the quad's fragment shader
(:mod:`citylod.render.slf_gpu`, the default), or per texel on the CPU into its texture (``lookup="cpu"``);
updated only when that direction moves by more than ``reeval_deg``. Only the direction patch that holds the four directions is read, on first use. A cell above τ is refined into its children; a finest cell above τ shows
its buildings (the city tiles the ordinary selection picks at τ, split by object between cells) on the bare
ground. Around the
switch the two cross-fade: with ``s = sse / τ`` and ``α = clip((s − ½) / ½, 0, 1)`` the buildings are drawn
at ``α`` of their height above the ground and the cell's texture is the field blended towards the ground
colour by ``α``, so a building grows out of its light field between half and all of the switching error
instead of popping. (Scaling, not opacity: translucent textured buildings cost llvmpipe 40× a frame.) Levels of the
field replace each other without a blend (they differ only in texel size).

:class:`GeometryView` draws the city tileset at the same τ through the ordinary
:class:`~citylod.render.tileset_actor.Scene`, on the same ground, or at full resolution (the reference).
"""

from __future__ import annotations

import contextlib
import json
import math
import time
import warnings
from collections import OrderedDict
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from citylod.core.camera import Camera, View
from citylod.core.errors import CitylodError, InputError
from citylod.io.image import decode_image
from citylod.io.tiles3d import Tile, is_tileset_path, open_tileset
from citylod.lod.build.slf import read_cell_arrays, read_group
from citylod.lod.kernels.slf import (
    DirectionSet,
    blend_of,
    depth_corrected_colours,
    direction_set,
    evaluate,
    march_heights,
    view_shifts,
    view_slope,
)
from citylod.render import _vtk
from citylod.render.gl_context import guard
from citylod.render.gl_texture import TextureWriter
from citylod.render.offscreen import OffscreenRenderer, frame_path, save_png
from citylod.render.slf_gpu import (
    AtlasLayout,
    encode_heights,
    height_texture,
    install_lookup,
    rgb_texture,
    set_fade,
    set_images,
    set_lookup,
    texels,
    texels_changed,
    texture_bytes,
)
from citylod.render.tileset_actor import BACKGROUND, camera_to_vtk, view_from_renderer

__all__ = ["GeometryView", "SlfFrame", "SlfView", "is_far_field", "open_slf", "render_far_field_command"]

#: A field cell is also refined while one of its texels covers more than this many pixels. The switching
#: error alone leaves the whole-city overview on coarse texels (8,000 houses: colour error 10.5 of 255);
#: at 1 px the pixels mostly take the shader's four-point branch and cost as much as the geometry. 1.5 is
#: the measured middle: on 32,000 houses errors 6.2–7.6 with 2.2–5.9× faster frames (docs/BENCHMARKS.md).
TEXEL_PX = 1.5

#: A view (the app, ``citylod render``) switches its far field from light fields to buildings at this multiple
#: of its τ. A field cell's ``geometricError`` is an expected displacement of the blend of directions, not a
#: bound as a DSM tile's is (lod/build/slf.py). At 2 px the fields' mean colour error against the full geometry
#: is 7.6 / 6.4 / 6.2 of 255 on 32,000 houses (docs/BENCHMARKS.md); at the view's 1 px every cell of an
#: 8,000-house overview showed its buildings, and the app drew 210 ms frames.
FIELD_TAU_SCALE = 2.0

U8 = npt.NDArray[np.uint8]
F64 = npt.NDArray[np.float64]


def open_slf(path: str | Path) -> tuple[Any, dict[str, Any]]:
    """The far-field tileset and its ``extras.citylod`` (``kind`` must be ``"slf"``)."""
    ts = open_tileset(Path(path))
    meta = ts.citylod
    if meta.get("kind") != "slf":
        raise InputError("not a far-field (surface light field) tileset: extras.citylod.kind is not 'slf'", ts.path)
    try:
        ok = (isinstance(meta["city"], str) and float(meta["ground_z"]) == float(meta["ground_z"])
              and len(meta["ground_rgb"]) == 3 and 3 <= int(meta["directions_grid"]) <= 65
              and float(meta["min_elevation_deg"]) < 90)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"far-field tileset metadata is incomplete ({exc!r})", ts.path) from exc
    if not ok:
        raise InputError("far-field tileset metadata is out of range", ts.path)
    return ts, meta


@dataclass
class SlfFrame:
    """What one frame drew: SLF ``cells`` (by level), finest cells with buildings (``geometry_cells``,
    ``fading`` of them between the two), bytes loaded so far, bytes this frame needs (``bytes_drawn``: the
    field files, ``bytes_fields``, plus the city tiles of its buildings, ``bytes_buildings``), seconds
    evaluating fields for this view (``eval_s``: the shader's uniforms, or on the CPU the view's ray march, the
    blend and the texture written into GL; work every frame of a moving view repeats) and seconds loading them (``load_s``: reading a cell's field for a patch
    of directions and reconstructing the stored directions' images and ray marches, kept per cell: work done
    once per cell and patch, like reading a city tile). ``eval_s`` does not include ``load_s``. ``loading``:
    cells drawn as fields because their buildings are still being read (embedded views only)."""

    cells: int = 0
    levels: dict[int, int] = field(default_factory=dict)
    geometry_cells: int = 0
    fading: int = 0
    bytes_loaded: int = 0
    bytes_drawn: int = 0
    bytes_fields: int = 0
    bytes_buildings: int = 0
    eval_s: float = 0.0
    load_s: float = 0.0
    evaluations: int = 0
    loading: int = 0


def _square(size_m: float, centre: F64, origin: F64, z: float) -> F64:
    """The corners (4, 3) of a cell's square at height ``z``, counter-clockwise from the south-west, relative
    to ``origin``."""
    h = size_m / 2
    return np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]]) + [centre[0] - origin[0],
                                                                         centre[1] - origin[1], z - origin[2]]


def _texture_actor(size_m: float, centre: F64, origin: F64, z: float) -> tuple[Any, Any, Any]:
    pts = _square(size_m, centre, origin, z)
    data = _vtk.vtkPolyData()
    p = _vtk.vtkPoints()
    p.SetData(_vtk.numpy_to_vtk(pts.astype(np.float32), deep=True))
    data.SetPoints(p)
    cells = _vtk.vtkCellArray()
    cells.SetData(3, _vtk.numpy_to_vtkIdTypeArray(np.array([0, 1, 2, 0, 2, 3], np.int64), deep=True))
    data.SetPolys(cells)
    tc = _vtk.numpy_to_vtk(np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32), deep=True)
    data.GetPointData().SetTCoords(tc)
    mapper = _vtk.vtkPolyDataMapper()
    mapper.SetInputData(data)
    actor = _vtk.vtkActor()
    actor.SetMapper(mapper)
    actor.GetProperty().LightingOff()
    tex = _vtk.vtkTexture()
    tex.InterpolateOn()
    tex.MipmapOn()
    # Far fields are seen at grazing angles: isotropic mip-mapping blurs them along the view (orbit frame at
    # 35° elevation, exact field: colour error 10.3 → 8.7 with 16× anisotropy, docs/PERFORMANCE_LOG.md).
    # SlfView switches it off per cell where the view is steep (see SlfView, ``anisotropic_from``).
    tex.SetMaximumAnisotropicFiltering(16.0)
    tex.EdgeClampOn()
    actor.SetTexture(tex)
    return actor, tex, data


def _set_image(tex: Any, rgb: U8, writer: TextureWriter | None = None, renderer: Any = None) -> None:
    """Texture from an image whose row 0 is the north (top) edge; VTK's row 0 is the bottom. An image of the
    texture's current size is written into its pixels in place (a cell's field changes every few frames). With
    ``writer`` (and ``renderer``'s GL context current), the texture and its mip chain are written into GL
    directly (:mod:`citylod.render.gl_texture`: llvmpipe's own mip generation costs 0.35–0.55 ms a texture);
    otherwise, or where that cannot be done, VTK uploads the image at its next render."""
    h, w, _ = rgb.shape
    img = tex.GetInput()
    scalars = img.GetPointData().GetScalars() if img is not None else None
    if (scalars is not None and tuple(img.GetDimensions()) == (w, h, 1) and scalars.GetNumberOfComponents() == 3
            and scalars.GetDataType() == _vtk.VTK_UNSIGNED_CHAR):
        _vtk.vtk_to_numpy(scalars).reshape(h, w, 3)[:] = rgb[::-1]
        if writer is not None and writer.write(tex, rgb, renderer):
            return
        scalars.Modified()
        img.Modified()
    else:
        img = _vtk.vtkImageData()
        img.SetDimensions(w, h, 1)
        img.GetPointData().SetScalars(_vtk.numpy_to_vtk(np.ascontiguousarray(rgb[::-1]).reshape(-1, 3), deep=True,
                                                        array_type=_vtk.VTK_UNSIGNED_CHAR))
        tex.SetInputData(img)
        if writer is not None and writer.write(tex, rgb, renderer):
            return
    tex.Modified()


class _Cell:
    def __init__(self, tile: Tile, view: SlfView) -> None:
        self.tile = tile
        lo, hi = tile.box.bounds()
        self.centre = 0.5 * (lo + hi)
        self.size = float(hi[0] - lo[0])
        self.info = view.cell_info.get(tile.key)
        self.actor, self.tex, _ = _texture_actor(self.size, self.centre, view.origin, view.ground_z - 0.05)
        self.actor.VisibilityOff()
        view.renderer.AddActor(self.actor)
        self.last_dir: F64 | None = None
        self.last_alpha = -1.0
        self.colours: U8 | None = None
        self.fields: dict[int, tuple[Any, ...]] = {}
        # patch -> the stored directions' images (P, T, T, 3), ray marches (P, T, T), which are filled (P,), and
        # the building tops as float64 (T, T)
        self.images: dict[int, tuple[Any, Any, Any, Any]] = {}
        self.files: tuple[str, str] | None = None  # the field files of the patch last drawn
        self.anisotropy = 16.0
        # The lookup on the GPU (render.slf_gpu): per patch the atlases of its stored directions' images and
        # ray marches (textures) and their layout, the patch the shader reads, the building tops.
        self.gpu: dict[int, tuple[Any, Any, AtlasLayout]] = {}
        self.gpu_patch: int | None = None
        self.top_tex: Any = None
        self.top_max = 0.0
        self.patch: int | None = None  # the direction patch last evaluated

    @property
    def evaluated(self) -> bool:
        """A field has been shown (on the CPU: its texture; on the GPU: its lookup's uniforms)."""
        return self.colours is not None or self.gpu_patch is not None


def _load_leaf(leaf: Tile) -> list[tuple[Any, F64, F64]]:
    """A city tile's meshes in world coordinates, each with the centre of the object of each vertex (the
    middle of the object's footprint box over all meshes of the tile: feature ID 0 is the object's row).
    No state: runs on a worker thread for an embedded view."""
    content = leaf.load_content()
    m = leaf.matrix
    out = []
    meshes = [(mesh, mesh.positions.astype(np.float64) @ m[:3, :3].T + m[:3, 3]) for mesh in content.meshes]
    # Object footprint boxes over all meshes of the leaf (feature ID 0 is the object's row), by scatter-min/max.
    tagged = [(mesh.features[0].ids.astype(np.int64), pos) for mesh, pos in meshes if mesh.features]
    n_obj = max((int(ids.max()) + 1 for ids, _ in tagged if len(ids)), default=0)
    lo = np.full((n_obj, 2), np.inf)
    hi = np.full((n_obj, 2), -np.inf)
    for ids, pos in tagged:
        np.minimum.at(lo, ids, pos[:, :2])
        np.maximum.at(hi, ids, pos[:, :2])
    for mesh, pos in meshes:
        if mesh.features:
            ids = mesh.features[0].ids.astype(np.int64)
            cen = 0.5 * (lo[ids] + hi[ids])
        else:
            cen = pos[:, :2]
        out.append((mesh, pos, cen))
    return out


class SlfView:
    """A city drawn with far-field surface light fields (see the module docstring).

    Parameters
    ----------
    slf_dir
        A far-field tileset (``citylod build slf``); its ``city`` extra names the city tileset.
    size
        (width, height) pixels.
    tau_px
        Screen-space error threshold.
    fields
        False: never draw a field (every finest cell shows its buildings): the same code path without SLFs.
    texel_px
        Also refine a field cell while its texels cover more than this many pixels (sharper far field for
        more bytes; default :data:`TEXEL_PX`); None: the switching error alone decides.
    depth_correct
        Evaluate cells that store building heights with the depth-corrected lookup
        (:func:`~citylod.lod.kernels.slf.depth_corrected_blend`); False: the plain blend of four directions.
    anisotropic_from
        Filter a cell's texture anisotropically (16×) only while a pixel's footprint on the ground is at least
        this elongated, ``1 / sin(elevation)`` of the view from the cell's centre; 1: always. Isotropic
        mip-mapping picks its level by the footprint's long axis, so it blurs the short one by that ratio:
        at 1.5 (elevation 42°) by under 0.6 of a mip level. On a software rasteriser the anisotropic filter
        doubles the cost of a field pixel (whole-city overview at 55°: 9.3 against 4.3 ms, colour error
        10.9 against 10.6; at 35° it lowers the error, docs/PERFORMANCE_LOG.md).
    antialias
        With the GPU lookup, average the field at four points of a pixel wider than a texel (default); False:
        one point, aliased, and cheaper to draw on a software rasteriser (the 8,000-house overview 8–13 ms
        against 14–18 ms; flicker on its slow orbit 7.7 against 5.6, the geometry's 9.0; docs/BENCHMARKS.md).
    cache_mb
        Memory for the cells' decoded fields (their read arrays, reconstructed directions, ray marches and
        atlases, 1–2 MB a cell and direction patch), least recently drawn dropped first; what the current
        frame draws is always kept. Unbounded, one orbit around the 8,000-house city held 1.75 GB.
    lookup
        ``"gpu"`` (default): cells with building tops are evaluated per pixel in the fragment shader
        (:mod:`citylod.render.slf_gpu`); a frame sets uniforms only. ``"cpu"``: evaluated per texel by the
        compiled kernel into a texture written each time the cell's direction moves (the path the shader
        reproduces, and the one for cells without building tops or with ``depth_correct=False``).
    renderer, origin
        Draw into this VTK renderer (an application's view, shifted by ``origin``, the world point at its
        coordinate origin) instead of an off-screen window of its own. :meth:`attach` then updates the far
        field before every render of it, from its camera and size; ``size``, :meth:`draw` and the grabs are
        the own window's only.
    """

    def __init__(self, slf_dir: str | Path, *, size: tuple[int, int] = (960, 540), tau_px: float = 1.0,
                 fields: bool = True, reeval_deg: float = 0.5, city_dir: str | Path | None = None,
                 texel_px: float | None = TEXEL_PX, depth_correct: bool = True, anisotropic_from: float = 1.5,
                 lookup: str = "gpu", antialias: bool = True, cache_mb: float = 256.0, renderer: Any = None,
                 origin: npt.ArrayLike | None = None) -> None:
        if lookup not in ("gpu", "cpu"):
            raise ValueError(f"lookup must be 'gpu' or 'cpu', got {lookup!r}")
        self.lookup = lookup
        self.antialias = bool(antialias)
        self.cache_bytes = int(cache_mb * 2**20)
        self._lru: OrderedDict[tuple[str, int], int] = OrderedDict()  # (cell, patch) -> bytes, oldest first
        self._lru_bytes = 0
        self.ts, self.meta = open_slf(slf_dir)
        self.anisotropic_from = float(anisotropic_from)
        self.depth_correct = depth_correct
        self.folder = Path(self.ts.folder)
        city = Path(city_dir) if city_dir is not None else (self.folder / self.meta["city"])
        self.city = open_tileset(city)
        self.size = (int(size[0]), int(size[1]))
        self.tau_px = float(tau_px)
        self.fields = fields
        self.texel_px = texel_px or None
        self.reeval = math.radians(reeval_deg)
        self.ground_z = float(self.meta["ground_z"])
        self.ground_rgb = np.array(self.meta["ground_rgb"], np.float64)
        self.ds: DirectionSet = direction_set(int(self.meta["directions_grid"]),
                                              float(self.meta["min_elevation_deg"]))
        patches = self.meta.get("patches")
        try:
            self.patches = ([np.arange(len(self.ds))] if patches is None
                            else [np.asarray(p, np.int64) for p in patches])
            ok = all(p.ndim == 1 and len(p) and p.min() >= 0 and p.max() < len(self.ds) for p in self.patches)
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise InputError("far-field tileset's direction patches are damaged", self.ts.path)
        lo, hi = self.ts.root.box.bounds()
        self.origin = np.round(0.5 * (lo + hi)) if origin is None else np.asarray(origin, np.float64)
        self.embedded = renderer is not None
        self._observer: int | None = None
        self._end_observer = 0
        self._visible = True
        self.last_frame: SlfFrame | None = None
        if renderer is None:
            self.window = _vtk.offscreen_window(*self.size)
            self.gl: Any = guard(self.window)  # apart from a PyVista window's GLX context (render.gl_context)
            self.renderer = _vtk.vtkOpenGLRenderer()
            self.renderer.SetBackground(*BACKGROUND)
            self.window.AddRenderer(self.renderer)
        else:
            self.window = None
            self.gl = contextlib.nullcontext()  # the application's window holds the context while it renders
            self.renderer = renderer
        self.cell_info = {t.key: t for t in self.ts.walk()}
        self._extras = self._tile_extras()
        self.cells: dict[str, _Cell] = {}
        self.groups: dict[str, tuple[F64, F64]] = {}
        self.loaded: set[str] = set()
        self.bytes_loaded = 0
        self._building_actors: dict[tuple[str, str], list[Any]] = {}  # (city tile, cell) -> actors
        self._used: dict[str, list[Tile]] = {}
        self._file_bytes: dict[str, int] = {}
        self._textures: dict[int, Any] = {}  # id of a city mesh -> its atlas's texture, shared by cells
        self._ground_rgb_u8 = np.full((2, 2, 3), np.rint(self.ground_rgb), np.uint8)
        self._leaf_cache: dict[str, list[tuple[Any, F64, F64]]] = {}
        self._faces: dict[tuple[str, str], list[tuple[int, npt.NDArray[np.int64]]]] = {}
        self._box_cache: dict[int, tuple[F64, F64]] = {}
        self._merged: dict[str, tuple[frozenset[str], list[Any]]] = {}
        # The ground of the cells whose buildings are drawn in full, one plain mesh for all of them: their own
        # textured quads cost 24 of a 119 ms frame with 115 such cells (one draw call and texture each).
        self._ground = _vtk.vtkActor()
        self._ground_mapper = _vtk.vtkPolyDataMapper()
        self._ground.SetMapper(self._ground_mapper)
        self._ground.GetProperty().LightingOff()
        self._ground.GetProperty().SetColor(*(self.ground_rgb / 255.0))
        self._ground.VisibilityOff()
        self._ground_cells: frozenset[str] = frozenset()
        self.renderer.AddActor(self._ground)
        # Field textures are written into GL with their mip chain while the window's context is current
        # (``_writing``: inside its render when embedded, inside the context guard in :meth:`prepare`).
        self._writer = TextureWriter()
        self._writing = False
        self._gpu_failed = False  # a lookup shader failed in the last render: the view goes over to the CPU
        # A lookup shader was installed since the last render: VTK builds it in the next one and reports a
        # failure only while its warnings are displayed (citylod keeps them off), so they are on for that render.
        self._watch = False
        self._watched: bool | None = None  # the global display setting to restore after a watched render
        self._last_camera: Camera | None = None
        if self.window is not None:  # the context exists from here on, so that prepare can write into it
            with self.gl:
                self.window.Render()
        self._loads: dict[str, Future[list[tuple[Any, F64, F64]]]] = {}
        self._pool: ThreadPoolExecutor | None = None
        self._built_all = True
        #: Embedded: seconds a frame may spend making building actors (the app's upload slice is 30 ms),
        #: and reading and evaluating fields.
        self.build_slice_s = 0.03
        self.eval_slice_s = 0.05
        if depth_correct:  # load the compiled kernels now, not in the first frame (numba's start: ~0.4 s)
            march_heights(np.ones((2, 2)), 1.0, self.ds.dirs[0])
        if depth_correct and lookup == "cpu":
            self._load_cpu_lookup()

    def _tile_extras(self) -> dict[str, dict[str, Any]]:
        doc = json.loads((self.folder / "tileset.json").read_text())
        out: dict[str, dict[str, Any]] = {}
        # The reader names tiles by their path of child indices ("0", "0/2", ...): walk the document alike.
        stack = [("0", doc["root"])]
        keys = [t.key for t in self.ts.walk()]
        while stack:
            key, t = stack.pop()
            stack.extend((f"{key}/{i}", c) for i, c in enumerate(t.get("children", [])))
            e = t.get("extras", {}).get("citylod_slf")
            if not isinstance(e, dict) or not isinstance(e.get("cell"), str) or not isinstance(e.get("group"), str):
                raise InputError("a far-field tile lacks extras.citylod_slf", self.ts.path)
            out[key] = e
        missing = set(keys) - set(out)
        if missing:
            raise InputError(f"far-field tiles without a field: {sorted(missing)[:3]}", self.ts.path)
        return out

    # -- data ---------------------------------------------------------------------------------------
    def _read(self, rel: str) -> bytes:
        path = (self.folder / rel).resolve()
        if self.folder.resolve() not in path.parents:
            raise InputError(f"far-field file {rel!r} lies outside the tileset", self.ts.path)
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise InputError(f"cannot read far-field file ({exc.strerror})", path) from exc
        if rel not in self.loaded:
            self.loaded.add(rel)
            self.bytes_loaded += len(data)
        return data

    def _field(self, cell: _Cell, patch: int) -> tuple[Any, ...]:
        """(cluster ids, weights, building tops or None, mean, basis) of a cell's direction ``patch``."""
        got = cell.fields.get(patch)
        if got is not None:
            return got
        e = self._extras[cell.tile.key]
        cell_file, group_file = e["cell"].format(patch=patch), e["group"].format(patch=patch)
        cl, q, top = read_cell_arrays(self._read(cell_file), str(self.folder / cell_file))
        if group_file not in self.groups:
            cp = read_group(self._read(group_file), str(self.folder / group_file))
            if cp.mean.shape[1] != len(self.patches[patch]):
                raise InputError(f"far-field group has {cp.mean.shape[1]} directions, the tileset's patch "
                                 f"{len(self.patches[patch])}", self.folder / group_file)
            self.groups[group_file] = cp.lumispheres()
        mean, basis = self.groups[group_file]
        got = cell.fields[patch] = (cl, q.astype(np.float64), top, mean, basis, cell_file, group_file)
        return got

    def _bounds(self, tile: Tile) -> tuple[F64, F64]:
        """A tile's axis-aligned bounds, kept (selection asks for them every frame, for every cell)."""
        got = self._box_cache.get(id(tile))
        if got is None:
            got = self._box_cache[id(tile)] = tile.box.bounds()
        return got

    def _city_tiles(self, view: View, lo: F64, hi: F64) -> list[Tile]:
        """The city tiles the ordinary selection draws at τ (refine while ``sse > τ``) over the box lo–hi."""
        eye = view.eye
        out, stack = [], [self.city.root]
        while stack:
            t = stack.pop()
            tlo, thi = self._bounds(t)
            if tlo[0] > hi[0] or thi[0] < lo[0] or tlo[1] > hi[1] or thi[1] < lo[1]:
                continue
            d = float(np.linalg.norm(np.maximum(np.maximum(tlo - eye, eye - thi), 0.0)))
            if t.children and view.sse(t.geometric_error, max(d, 1e-6)) > self.tau_px:
                stack.extend(t.children)
            elif t.content_paths:
                out.append(t)
        return out

    def _cell_faces(self, cell: _Cell, tile: Tile) -> list[tuple[int, npt.NDArray[np.int64]]]:
        """The faces of the objects of ``tile`` whose centre lies in ``cell``, per mesh of the tile (index,
        faces into the mesh's vertices); computed on first use, kept."""
        key = (tile.key, cell.tile.key)
        got = self._faces.get(key)
        if got is None:
            lo, hi = self._bounds(cell.tile)
            got = []
            for mi, (mesh, _pos, centre_of_vertex) in enumerate(self._leaf_content(tile)):
                inside = ((centre_of_vertex[:, 0] >= lo[0]) & (centre_of_vertex[:, 0] < hi[0])
                          & (centre_of_vertex[:, 1] >= lo[1]) & (centre_of_vertex[:, 1] < hi[1]))
                faces = mesh.faces.astype(np.int64)
                keep = inside[faces[:, 0]]
                if keep.any():
                    got.append((mi, faces[keep]))
            self._faces[key] = got
        return got

    def _actors_of(self, tile: Tile, parts: list[tuple[int, npt.NDArray[np.int64]]]) -> list[Any]:
        """One actor per mesh of ``tile`` for the given faces, holding only the vertices they use."""
        content = self._leaf_content(tile)
        by_mesh: dict[int, list[npt.NDArray[np.int64]]] = {}
        for mi, faces in parts:
            by_mesh.setdefault(mi, []).append(faces)
        out = []
        for mi, chunks in sorted(by_mesh.items()):
            mesh, pos, _ = content[mi]
            used, local = np.unique(np.concatenate(chunks), return_inverse=True)
            out.append(self._mesh_actor(mesh, pos, local.reshape(-1, 3), used))
        return out

    def _buildings(self, cell: _Cell, tiles: list[Tile]) -> list[Any]:
        """Actors of the objects of ``tiles`` whose centre lies in ``cell``, for a cell whose buildings grow
        (built on first use, kept). Cells drawn in full share one actor per city tile and mesh
        (:meth:`_full_buildings`)."""
        actors: list[Any] = []
        for tile in tiles:
            key = (tile.key, cell.tile.key)
            if key not in self._building_actors:
                self._building_actors[key] = self._actors_of(tile, self._cell_faces(cell, tile))
            actors += self._building_actors[key]
        return actors

    def _set_ground(self, cells: frozenset[str]) -> None:
        """The plain ground under ``cells`` (drawn in full), remade when the set changes."""
        if cells != self._ground_cells:
            self._ground_cells = cells
            quads = [_square(self.cells[k].size, self.cells[k].centre, self.origin, self.ground_z - 0.05)
                     for k in sorted(cells)]
            data = _vtk.vtkPolyData()
            if quads:
                pts = _vtk.vtkPoints()
                pts.SetData(_vtk.numpy_to_vtk(np.concatenate(quads).astype(np.float32), deep=True))
                data.SetPoints(pts)
                base = 4 * np.arange(len(quads), dtype=np.int64)[:, None]
                polys = _vtk.vtkCellArray()
                polys.SetData(3, _vtk.numpy_to_vtkIdTypeArray(
                    (base + np.array([0, 1, 2, 0, 2, 3])).reshape(-1), deep=True))
                data.SetPolys(polys)
            self._ground_mapper.SetInputData(data)
        self._ground.SetVisibility(bool(cells) and self._visible)

    def _full_buildings(self, tile: Tile, cells: frozenset[str]) -> list[Any]:
        """The actors of ``tile``'s objects in all of ``cells`` (drawn in full), one per mesh; remade when the
        set of cells changes. On llvmpipe each actor costs its draw call's state: one per cell and city tile
        made a view of 228 cells of buildings 570 actors and 137 ms to draw."""
        cached = self._merged.get(tile.key)
        if cached is not None and cached[0] == cells:
            return cached[1]
        if cached is not None:
            for actor in cached[1]:
                self.renderer.RemoveActor(actor)
        parts = [part for key in sorted(cells) for part in self._cell_faces(self.cells[key], tile)]
        actors = self._actors_of(tile, parts)
        self._merged[tile.key] = (cells, actors)
        return actors

    def _leaf_ready(self, leaf: Tile) -> bool:
        """Whether the city tile's buildings are loaded. With its own window the tile is read now; embedded
        in an application's view it is read on a worker thread, and False until it has been (the frame does
        not wait: the cell stays a field meanwhile). A tile that cannot be read there adds no buildings and
        is reported once as a warning."""
        if leaf.key in self._leaf_cache:
            return True
        if not self.embedded:
            self._leaf_cache[leaf.key] = _load_leaf(leaf)
            self.bytes_loaded += leaf.content_bytes
            return True
        fut = self._loads.get(leaf.key)
        if fut is None:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="citylod-far-field")
            self._loads[leaf.key] = self._pool.submit(_load_leaf, leaf)
            return False
        if not fut.done():
            return False
        del self._loads[leaf.key]
        try:
            self._leaf_cache[leaf.key] = fut.result()
            self.bytes_loaded += leaf.content_bytes
        except (CitylodError, OSError, ValueError) as exc:
            warnings.warn(f"far field: city tile {leaf.key} could not be read ({exc}); its buildings are not "
                          "drawn", stacklevel=2)
            self._leaf_cache[leaf.key] = []
        return True

    def pending(self) -> int:
        """City tiles being read for buildings, plus one while cells wait for their building actors or
        their field's evaluation (embedded only)."""
        return len(self._loads) + (not self._built_all) + self._gpu_failed

    def loads_ready(self) -> bool:
        """The next frame would draw more: a city tile has been read since the last frame, or cells wait
        for their building actors or their field's evaluation."""
        return not self._built_all or self._gpu_failed or any(f.done() for f in self._loads.values())

    def _leaf_content(self, leaf: Tile) -> list[tuple[Any, F64, F64]]:
        if not self._leaf_ready(leaf):  # called only for tiles found ready in this frame
            raise RuntimeError(f"city tile {leaf.key} is not loaded")
        return self._leaf_cache[leaf.key]

    def _mesh_actor(self, mesh: Any, pos: F64, faces: npt.NDArray[np.int64], used: npt.NDArray[np.int64]) -> Any:
        """An actor of the vertices ``used`` of ``mesh`` (world positions ``pos``), ``faces`` indexing them."""
        data = _vtk.vtkPolyData()
        p = _vtk.vtkPoints()
        p.SetData(_vtk.numpy_to_vtk((pos[used] - self.origin).astype(np.float32), deep=True))
        data.SetPoints(p)
        cells = _vtk.vtkCellArray()
        cells.SetData(3, _vtk.numpy_to_vtkIdTypeArray(faces.reshape(-1), deep=True))
        data.SetPolys(cells)
        mapper = _vtk.vtkPolyDataMapper()
        mapper.SetInputData(data)
        mapper.SetColorModeToDirectScalars()
        actor = _vtk.vtkActor()
        actor.SetMapper(mapper)
        actor.SetOrigin(0.0, 0.0, self.ground_z - self.origin[2])  # grows from the ground (fade-in)
        actor.GetProperty().LightingOff()
        if mesh.texture is not None and mesh.uv is not None:
            uv = mesh.uv[used]
            tc = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]]).astype(np.float32)  # VTK: origin bottom left
            data.GetPointData().SetTCoords(_vtk.numpy_to_vtk(tc, deep=True))
            tex = self._textures.get(id(mesh))  # one texture per atlas, shared by cells
            if tex is None:
                tex = self._textures[id(mesh)] = _vtk.vtkTexture()
                tex.InterpolateOn()
                tex.MipmapOn()
                tex.EdgeClampOn()
                _set_image(tex, decode_image(mesh.texture)[..., :3])
            actor.SetTexture(tex)
        elif mesh.colors is not None:
            data.GetPointData().SetScalars(_vtk.numpy_to_vtk(np.ascontiguousarray(mesh.colors[used, :3]), deep=True,
                                                             array_type=_vtk.VTK_UNSIGNED_CHAR))
            mapper.ScalarVisibilityOn()
        self.renderer.AddActor(actor)
        return actor

    # -- frames -------------------------------------------------------------------------------------
    def _cell(self, tile: Tile) -> _Cell:
        c = self.cells.get(tile.key)
        if c is None:
            c = self.cells[tile.key] = _Cell(tile, self)
        return c

    def prepare(self, camera: Camera) -> SlfFrame:
        """Choose, evaluate and show this camera's cells (no drawing). Embedded (``renderer`` given), the
        renderer's own camera is not moved."""
        if self.embedded:
            return self._prepare(camera)
        with self.gl, self._gl_writes():
            return self._prepare(camera)

    def invalidate(self) -> None:
        """Forget the view directions the fields were evaluated for: the next :meth:`prepare` evaluates every
        cell it shows (as a view arriving from elsewhere does), with nothing left to load."""
        for cell in self.cells.values():
            cell.last_dir = None

    @contextlib.contextmanager
    def _gl_writes(self) -> Any:
        """Textures may be written into GL in this block (the window's context is current)."""
        was, self._writing = self._writing, True
        try:
            yield
        finally:
            self._writing = was

    def _set(self, tex: Any, rgb: U8) -> None:
        _set_image(tex, rgb, self._writer if self._writing else None, self.renderer)

    def _prepare(self, camera: Camera) -> SlfFrame:
        self._last_camera = camera
        if self._gpu_failed:
            self._to_cpu()
        if self.embedded:
            w, h = self.renderer.GetSize()
            self.size = (max(int(w), 1), max(int(h), 1))
        view = View(camera, *self.size)
        eye = np.asarray(camera.position, np.float64)
        frame = SlfFrame()
        show: dict[str, float] = {}  # cell key -> buildings' opacity (0: field only)
        stack = [self.ts.root]
        while stack:
            t = stack.pop()
            if view.cull_box(t.box):
                continue
            lo, hi = self._bounds(t)
            d = float(np.linalg.norm(np.maximum(np.maximum(lo - eye, eye - hi), 0.0)))
            sse = view.sse(t.geometric_error, max(d, 1e-6))
            fine = self.texel_px is not None and view.sse(self._extras[t.key]["texel_m"], max(d, 1e-6)) > self.texel_px
            if t.children and (sse > self.tau_px or fine or not self.fields):
                stack.extend(t.children)
                continue
            s = sse / self.tau_px
            alpha = 1.0 if not self.fields else (float(np.clip((s - 0.5) / 0.5, 0.0, 1.0)) if not t.children else 0.0)
            show[t.key] = alpha
        for key, cell in self.cells.items():
            if key not in show:
                cell.actor.VisibilityOff()
        shown: set[int] = set()
        used: dict[str, list[Tile]] = {}
        self._built_all = True
        building_s = 0.0
        full: dict[str, tuple[Tile, set[str]]] = {}  # city tile -> cells whose buildings it draws in full
        drawn: set[tuple[str, int]] = set()  # (cell, patch) of the fields this frame draws
        for key, alpha in list(show.items()):
            cell = self._cell(self.cell_info[key])
            tiles: list[Tile] = []
            if alpha > 0.0:
                lo, hi = self._bounds(cell.tile)
                tiles = self._city_tiles(view, lo, hi)
                if not all([self._leaf_ready(t) for t in tiles]):  # a list: every missing tile is requested
                    alpha = show[key] = 0.0  # drawn as its field until its buildings have loaded
                    frame.loading += 1
                elif (self.embedded and building_s > self.build_slice_s
                      and any((t.key, key) not in self._faces for t in tiles)):
                    # Building actors (and their atlases' textures) are made a bounded time a frame, so a
                    # view that zooms in on many cells at once renders in steps rather than stalling.
                    alpha = show[key] = 0.0
                    frame.loading += 1
                    self._built_all = False
            frame.cells += alpha < 1.0
            frame.levels[cell.tile.level] = frame.levels.get(cell.tile.level, 0) + 1
            if alpha > 0.0:
                frame.geometry_cells += 1
                frame.fading += alpha < 1.0
                used[key] = tiles
                tb = time.perf_counter()
                if alpha < 1.0:  # growing out of the field: the cell's own actors, scaled
                    for a in self._buildings(cell, tiles):
                        a.VisibilityOn()
                        a.SetScale(1.0, 1.0, max(alpha, 1e-3))
                        shown.add(id(a))
                else:
                    for t in tiles:
                        self._cell_faces(cell, t)
                        full.setdefault(t.key, (t, set()))[1].add(key)
                building_s += time.perf_counter() - tb
            if (self.embedded and frame.eval_s + frame.load_s > self.eval_slice_s
                    and self._stale(cell, self._direction(cell, eye), alpha)):
                # Fields are read and evaluated a bounded time a frame in an application's view: a cell not
                # reached keeps the direction it was evaluated for, or shows the bare ground until its first
                # evaluation, and the next frames go on.
                if not cell.evaluated and cell.last_alpha != 1.0:
                    self._set(cell.tex, self._ground_rgb_u8)
                    cell.last_alpha = 1.0
                self._built_all = False
                frame.loading += 1
            else:
                t0 = time.perf_counter()
                evaluated, load_s = self._update_texture(cell, eye, alpha)
                frame.evaluations += evaluated
                frame.eval_s += time.perf_counter() - t0 - load_s
                frame.load_s += load_s
            if alpha < 1.0 and cell.patch is not None:
                drawn.add(self._touch(cell, cell.patch))
            cell.actor.SetVisibility(alpha < 1.0)  # a cell drawn in full stands on the shared ground
        self._evict(drawn)
        self._set_ground(frozenset(k for k, a in show.items() if a >= 1.0))
        for tile, cells in full.values():
            for a in self._full_buildings(tile, frozenset(cells)):
                a.VisibilityOn()
                shown.add(id(a))
        for actors in [*self._building_actors.values(), *(m[1] for m in self._merged.values())]:
            for a in actors:
                if id(a) not in shown:
                    a.VisibilityOff()
        self._used = used
        frame.bytes_loaded = self.bytes_loaded
        frame.bytes_fields, frame.bytes_buildings = self._bytes_drawn(show)
        frame.bytes_drawn = frame.bytes_fields + frame.bytes_buildings
        if not self.embedded:
            camera_to_vtk(camera, self.renderer.GetActiveCamera(), self.origin)
        self.renderer.ResetCameraClippingRange()
        self.last_frame = frame
        return frame

    # -- in an application's view --------------------------------------------------------------------
    def bounds(self) -> tuple[F64, F64]:
        """(lo, hi) of the far field's cells, in the data's CRS."""
        return self.ts.root.box.bounds()

    def attach(self) -> None:
        """Embedded: update the far field from the renderer's camera before each of its renders."""
        if self.embedded and self._observer is None:
            self._observer = self.renderer.AddObserver(_vtk.vtkCommand.StartEvent, self._on_start)
            self._end_observer = self.renderer.AddObserver(_vtk.vtkCommand.EndEvent, self._watch_off)

    def _on_start(self, _obj: Any, _event: str) -> None:
        if self._visible:  # inside the application window's render: its context is current
            with self._gl_writes():
                self.prepare(view_from_renderer(self.renderer, self.origin).camera)
            self._watch_on()

    @property
    def visible(self) -> bool:
        return self._visible

    @visible.setter
    def visible(self, on: bool) -> None:
        """Show or hide every cell and building (hidden, the far field is not updated either)."""
        self._visible = bool(on)
        if not on:
            for cell in self.cells.values():
                cell.actor.VisibilityOff()
            for actors in [*self._building_actors.values(), *(m[1] for m in self._merged.values())]:
                for a in actors:
                    a.VisibilityOff()
            self._ground.VisibilityOff()

    def _bytes_drawn(self, show: dict[str, float]) -> tuple[int, int]:
        """Bytes of what this frame needs: the files of fields drawn (groups once), and the city tiles of the
        buildings drawn."""
        files: set[str] = set()
        leaves: set[Tile] = set()
        for key, alpha in show.items():
            drawn = self.cells[key].files
            if alpha < 1.0 and drawn is not None:
                files.update(drawn)
            if alpha > 0.0:
                leaves.update(self._used.get(key, []))
        size = 0
        for f in files:  # each file's size read once: this runs every frame
            got = self._file_bytes.get(f)
            if got is None:
                got = self._file_bytes[f] = (self.folder / f).stat().st_size
            size += got
        return size, sum(t.content_bytes for t in leaves)

    def _direction(self, cell: _Cell, eye: F64) -> F64:
        """The unit view direction from the cell's centre on the ground towards ``eye``."""
        v = eye - np.array([cell.centre[0], cell.centre[1], self.ground_z])
        return v / np.linalg.norm(v)

    def _same_dir(self, cell: _Cell, v: F64) -> bool:
        """The cell was last evaluated within ``reeval`` of direction ``v``."""
        return cell.last_dir is not None and float(v @ cell.last_dir) > math.cos(self.reeval)

    def _stale(self, cell: _Cell, v: F64, alpha: float) -> bool:
        """Whether :meth:`_update_texture` would evaluate the cell's field for view direction ``v`` or
        recolour it."""
        if alpha >= 1.0:
            return False
        return cell.last_dir is None or abs(alpha - cell.last_alpha) >= 1e-3 or not self._same_dir(cell, v)

    def _watch_on(self) -> None:
        if self._watch and self._watched is None:
            self._watched = bool(_vtk.vtkObject.GetGlobalWarningDisplay())
            _vtk.vtkObject.GlobalWarningDisplayOn()

    def _watch_off(self, *_args: Any) -> None:
        if self._watched is not None:
            _vtk.vtkObject.SetGlobalWarningDisplay(int(self._watched))
            self._watched = None
            self._watch = False

    def _shader_failed(self, *_args: Any) -> None:
        # VTK reports a shader it cannot build as an ErrorEvent of the mapper (and draws the quad with its
        # first texture, the atlas): the next prepare evaluates on the CPU instead, and an own window's draw
        # draws again.
        self._gpu_failed = True

    @staticmethod
    def _reset_gpu(cell: _Cell) -> None:
        """The cell back to a plain textured quad, its lookup to be installed and evaluated again."""
        prop = cell.actor.GetProperty()
        for name in ("slfTop", "slfImages", "slfSeen"):
            prop.RemoveTexture(name)
        cell.actor.GetShaderProperty().ClearAllFragmentShaderReplacements()
        cell.actor.SetTexture(cell.tex)
        cell.gpu.clear()
        cell.images.clear()  # the shader's directions live only in its atlases
        cell.gpu_patch = None
        cell.top_tex = None
        cell.last_dir = None

    def _touch(self, cell: _Cell, patch: int) -> tuple[str, int]:
        """Mark the cell's ``patch`` data as drawn now; (cell key, patch). Its size is counted once, when it
        enters the cache: a patch's arrays and atlases are made whole on its first evaluation."""
        key = (cell.tile.key, patch)
        if key in self._lru:
            self._lru.move_to_end(key)
            return key
        size = 0
        for part in (cell.fields.get(patch, ())[:3], cell.images.get(patch, ())):
            size += sum(int(a.nbytes) for a in part if isinstance(a, np.ndarray))
        # The atlases: VTK's image and the GL texture's copy of it.
        size += 2 * sum(texture_bytes(t) for t in cell.gpu.get(patch, ())[:2])
        self._lru_bytes += size
        self._lru[key] = size
        return key

    def _evict(self, keep: set[tuple[str, int]]) -> None:
        """Drop the least recently drawn cells' patch data beyond ``cache_bytes``, never what ``keep`` holds,
        and the groups' lumispheres no cached cell reads any more (not counted in the budget: about 0.2 MB a
        group and patch). A cell whose lookup reads a dropped patch is reset (it is not drawn this frame)."""
        total = self._lru_bytes
        dropped: set[str] = set()
        for key in list(self._lru):
            if total <= self.cache_bytes:
                break
            if key in keep:
                continue
            total -= self._lru.pop(key)
            cell = self.cells[key[0]]
            patch = key[1]
            field = cell.fields.pop(patch, None)
            if field is not None:
                dropped.add(field[6])
            cell.images.pop(patch, None)
            cell.gpu.pop(patch, None)
            if cell.gpu_patch == patch:
                self._reset_gpu(cell)
            if cell.patch == patch:
                cell.patch = None
                cell.last_dir = None
        self._lru_bytes = total
        if dropped:  # a group's shared lumispheres go with the last cached cell that reads them
            used = {self.cells[k].fields[p][6] for k, p in self._lru if p in self.cells[k].fields}
            for group_file in dropped - used:
                self.groups.pop(group_file, None)

    def _to_cpu(self) -> None:
        """Every cell back to the CPU lookup (a textured quad), to be evaluated again."""
        warnings.warn("the far field's lookup shader could not be built here; evaluating on the CPU",
                      RuntimeWarning, stacklevel=3)
        self.lookup = "cpu"
        self._gpu_failed = False
        for cell in self.cells.values():
            if cell.top_tex is not None:
                self._reset_gpu(cell)
                for key in [k for k in self._lru if k[0] == cell.tile.key]:  # counted again on the CPU
                    self._lru_bytes -= self._lru.pop(key)
        if self.depth_correct:
            self._load_cpu_lookup()

    def _load_cpu_lookup(self) -> None:
        """Load the compiled CPU lookup now, not in the first frame that needs it (numba's start: ~0.4 s)."""
        depth_corrected_colours(np.zeros((1, 2, 2, 3), np.float32), np.zeros((1, 2, 2), np.float32),
                                np.zeros(1, np.int64), np.ones(1), self.ds.dirs, np.ones((2, 2)), 1.0,
                                self.ds.dirs[0])

    def _gpu_patch(self, cell: _Cell, patch: int, p: int, t: int, top64: F64,
                   filled: list[tuple[int, Any, Any]]) -> None:
        """Give the cell's shader the atlases of ``patch`` (``p`` directions of ``t`` × ``t`` texels; made on
        first use) with the directions ``filled`` just reconstructed (index, image, ray march) written into
        them, installing the shader on the cell's first GPU lookup."""
        entry = cell.gpu.get(patch)
        if entry is None:
            lay = AtlasLayout(p, t)
            entry = cell.gpu[patch] = (rgb_texture(np.zeros((*lay.shape, 3), np.uint8)),
                                       height_texture(np.zeros(lay.shape)), lay)
        img_tex, seen_tex, lay = entry
        if filled:
            rgb, heights = texels(img_tex), texels(seen_tex)
            for k, image, seen in filled:
                ys, xs = lay.tile(k)
                rgb[ys, xs] = np.clip(np.rint(image), 0, 255)
                heights[ys, xs] = encode_heights(seen)
            texels_changed(img_tex)
            texels_changed(seen_tex)
        if cell.top_tex is None:
            cell.top_tex = height_texture(top64)
            cell.top_max = max(float(top64.max()) if top64.size else 0.0, 0.0)  # where the shader's march starts
            install_lookup(cell.actor, cell.top_tex, img_tex, seen_tex, lay.t, lay.cols, self.ground_rgb,
                           self.antialias)
            mapper = cell.actor.GetMapper()
            if not mapper.HasObserver(_vtk.vtkCommand.ErrorEvent):
                mapper.AddObserver(_vtk.vtkCommand.ErrorEvent, self._shader_failed)
            self._watch = True
        elif cell.gpu_patch != patch:
            set_images(cell.actor, img_tex, seen_tex, lay.cols)
        cell.gpu_patch = patch

    def _update_texture(self, cell: _Cell, eye: F64, alpha: float) -> tuple[bool, float]:
        """Bring the cell's texture to the view from ``eye`` and fade ``alpha``: (whether it was evaluated
        or recoloured, seconds of it spent loading the field). A cell drawn in full (alpha 1) is hidden on the
        shared ground and keeps its texture."""
        v = self._direction(cell, eye)
        aniso = 16.0 if v[2] * self.anisotropic_from <= 1.0 else 1.0  # footprint elongation 1/v_z ≥ the limit
        if aniso != cell.anisotropy and cell.gpu_patch is None:
            cell.tex.SetMaximumAnisotropicFiltering(aniso)
            cell.anisotropy = aniso
        if not self._stale(cell, v, alpha):
            return False, 0.0
        load_s = 0.0
        if not self._same_dir(cell, v) or not cell.evaluated:
            idx, w, patch = blend_of(self.ds, v)
            patch = patch if len(self.patches) > 1 else 0
            sel = self.patches[patch]
            t_load = time.perf_counter()
            cl, q, top, mean, basis, *files = self._field(cell, patch)
            gpu = self.lookup == "gpu" and top is not None and self.depth_correct
            img = cell.tex.GetInput()
            n = cl.shape[0]
            if not gpu and (img is None or tuple(img.GetDimensions())[:2] != (n, n)):  # GL texture, field's size
                self._set(cell.tex, np.zeros((n, n, 3), np.uint8))  # made once, with the loading
            load_s += time.perf_counter() - t_load
            loc = np.searchsorted(sel, idx)  # the blended directions' rows in the patch's lumispheres
            if top is not None and self.depth_correct:
                texel = cell.size / cl.shape[0]
                t_ = cl.shape[0]
                got = cell.images.get(patch)
                if got is None:  # a stored direction's image and ray march do not depend on the view: kept
                    # (on the GPU only in the shader's atlases)
                    got = cell.images[patch] = (None if gpu else np.zeros((len(sel), t_, t_, 3), np.float32),
                                                None if gpu else np.zeros((len(sel), t_, t_), np.float32),
                                                np.zeros(len(sel), bool), np.asarray(top, np.float64))
                images, seen, have, top64 = got
                filled = []
                for jl in loc:
                    if not have[jl]:
                        t_load = time.perf_counter()
                        image = mean[cl, jl] + np.einsum("...k,...kc->...c", q, basis[cl, :, jl])
                        marched = march_heights(top64, texel, self.ds.dirs[sel[jl]])
                        if gpu:
                            filled.append((int(jl), image, marched))
                        else:
                            images[jl], seen[jl] = image, marched
                        have[jl] = True
                        load_s += time.perf_counter() - t_load
                if gpu:
                    t_load = time.perf_counter()
                    self._gpu_patch(cell, patch, len(sel), t_, top64, filled)
                    load_s += time.perf_counter() - t_load
                    _, shifts = view_shifts(v, self.ds.dirs[sel], loc, texel)
                    a = view_slope(v) / texel
                    set_lookup(cell.actor, loc, w, shifts, (a[0], a[1], cell.top_max))
                    if alpha != cell.last_alpha:
                        set_fade(cell.actor, alpha)
                    cell.files = (files[0], files[1])
                    cell.last_dir = v
                    cell.patch = patch
                    cell.last_alpha = alpha
                    return True, load_s
                cell.colours = depth_corrected_colours(images, seen, loc, w, self.ds.dirs[sel], top64, texel, v)
            else:
                cell.colours = evaluate(cl, q, mean, basis, loc, w)
            cell.files = (files[0], files[1])
            cell.last_dir = v
            cell.patch = patch
        if cell.gpu_patch is not None:  # the lookup's direction is current: only the fade moved
            set_fade(cell.actor, alpha)
            cell.last_alpha = alpha
            return True, load_s
        rgb = cell.colours
        if alpha > 0.0:
            rgb = np.rint((1 - alpha) * rgb + alpha * self.ground_rgb).astype(np.uint8)
        self._set(cell.tex, rgb)
        cell.last_alpha = alpha
        return True, load_s

    def draw(self) -> float:
        if self.window is None:
            raise RuntimeError("an embedded far field is drawn by the application's window")
        t0 = time.perf_counter()
        with self.gl:
            self._watch_on()
            try:
                self.window.Render()
            finally:
                self._watch_off()
            self.window.WaitForCompletion()
        if self._gpu_failed and self._last_camera is not None:  # drawn with a shader that did not build
            self.prepare(self._last_camera)
            with self.gl:
                self.window.Render()
                self.window.WaitForCompletion()
        return time.perf_counter() - t0

    def grab_rgb(self) -> U8:
        w, h = self.size
        arr = _vtk.vtkUnsignedCharArray()
        with self.gl:
            self.window.GetPixelData(0, 0, w - 1, h - 1, 0, arr, 0)
        return np.ascontiguousarray(_vtk.vtk_to_numpy(arr).reshape(h, w, 3)[::-1])

    def field_mask(self) -> npt.NDArray[np.bool_]:
        """Pixels of the last prepared frame covered by a cell drawn with its field (a second, flat render)."""
        with self.gl, self._gl_writes():
            return self._field_mask()

    def _field_mask(self) -> npt.NDArray[np.bool_]:
        saved = []
        for cell in self.cells.values():
            saved.append((cell, cell.actor.GetVisibility(), cell.last_alpha))
        bg = self.renderer.GetBackground()
        self.renderer.SetBackground(0, 0, 0)
        hidden = [a for acts in [*self._building_actors.values(), *(m[1] for m in self._merged.values()),
                                 [self._ground]]
                  for a in acts if a.GetVisibility()]
        for a in hidden:
            a.VisibilityOff()
        white = np.full((2, 2, 3), 255, np.uint8)
        for cell, vis, alpha in saved:
            if vis and alpha < 1.0 and cell.gpu_patch is not None:
                set_fade(cell.actor, alpha, white=True)
            elif vis and alpha < 1.0:
                self._set(cell.tex, white)
            else:
                cell.actor.VisibilityOff()
        self.draw()
        mask = self.grab_rgb()[..., 0] > 127
        self.renderer.SetBackground(*bg)
        for a in hidden:
            a.VisibilityOn()
        for cell, vis, alpha in saved:
            cell.actor.SetVisibility(vis)
            if vis and alpha < 1.0 and cell.gpu_patch is not None:
                set_fade(cell.actor, alpha)
            elif vis and alpha < 1.0 and cell.colours is not None:
                rgb = cell.colours if alpha <= 0 else np.rint((1 - alpha) * cell.colours + alpha * self.ground_rgb
                                                              ).astype(np.uint8)
                self._set(cell.tex, rgb)
        return mask

    def close(self) -> None:
        if self.embedded:  # leave the application's renderer as it was
            if self._observer is not None:
                self.renderer.RemoveObserver(self._observer)
                self.renderer.RemoveObserver(self._end_observer)
                self._observer = None
            for cell in self.cells.values():
                self.renderer.RemoveActor(cell.actor)
            for actors in [*self._building_actors.values(), *(m[1] for m in self._merged.values())]:
                for a in actors:
                    self.renderer.RemoveActor(a)
            self.renderer.RemoveActor(self._ground)
            if self._pool is not None:
                self._pool.shutdown(wait=False, cancel_futures=True)
            return
        with self.gl:
            self.window.Finalize()

    def __enter__(self) -> SlfView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class GeometryView:
    """The city tileset at τ (or at full resolution) through the ordinary scene, on the far field's ground
    plane (a flat quad in the ground colour over the field's extent), for comparison with :class:`SlfView`."""

    def __init__(self, slf_dir: str | Path, *, size: tuple[int, int] = (960, 540), tau_px: float = 1.0,
                 city_dir: str | Path | None = None) -> None:
        ts, meta = open_slf(slf_dir)
        city = Path(city_dir) if city_dir is not None else Path(ts.folder) / meta["city"]
        self.r = OffscreenRenderer([city], size=size, tau_px=tau_px)
        lo, hi = ts.root.box.bounds()
        origin = self.r.scene.origin
        assert origin is not None
        actor, tex, _ = _texture_actor(float(hi[0] - lo[0]), 0.5 * (lo + hi), origin,
                                       float(meta["ground_z"]) - 0.05)
        _set_image(tex, np.full((2, 2, 3), np.rint(meta["ground_rgb"]), np.uint8))
        self.r.renderer.AddActor(actor)
        self.size = self.r.size

    def prepare(self, camera: Camera, *, full_resolution: bool = False, tau_px: float | None = None) -> Any:
        """Select and load the city's tiles for ``camera``: at the view's τ, at ``tau_px``, or at full
        resolution (every leaf with its original textures)."""
        layer = self.r.scene.layers[0]
        saved = layer.tau_px
        if tau_px is not None:
            layer.tau_px = tau_px
        try:
            return self.r.prepare(camera, full_resolution=full_resolution)
        finally:
            layer.tau_px = saved

    def file_bytes(self) -> int:
        """Content file bytes of the tiles drawn in the last frame (what a client downloads for it)."""
        layer = self.r.scene.layers[0]
        return sum(layer.node(k).tile.content_bytes for k in layer.shown_keys)

    def draw(self) -> float:
        return self.r.draw()

    def grab_rgb(self) -> U8:
        return self.r.grab_rgb()

    def close(self) -> None:
        self.r.close()

    def __enter__(self) -> GeometryView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def is_far_field(source: str | Path) -> bool:
    """Whether ``source`` (a tileset folder or ``tileset.json``) is a far-field tileset (``citylod build
    slf``). Unreadable sources answer False: the ordinary renderer reports them."""
    p = Path(source)
    if not is_tileset_path(p) or not p.exists():
        return False
    try:
        return open_tileset(p).citylod.get("kind") == "slf"
    except (CitylodError, OSError, ValueError):  # the renderer that reads it for real reports the damage
        return False


#: ``citylod render`` options that act on a scene of tilesets; a far-field view draws its city and fields only.
_SCENE_ONLY = ("depth", "city", "highlight", "hide", "flood", "edits", "texture_budget", "point_budget",
               "target_ms")


def render_far_field_command(args: Any, progress: bool = True) -> int:
    """``citylod render SLF_DIR -o IMAGE.png [--camera CAMERA.json | overview | orbit:N] [--tau PX] [--size WxH]``: the city of a
    far-field tileset as :class:`SlfView` draws it (fields evaluated for each camera, buildings where the
    fields hand over, at :data:`FIELD_TAU_SCALE` times ``--tau``), one PNG per camera. The far-field tileset
    is the only source."""
    from tqdm import tqdm

    from citylod.core.camera import built_in_camera, cameras_for, load_cameras

    if len(args.sources) != 1:
        raise CitylodError("a far-field tileset is rendered alone (it names its own city tileset); "
                           f"got {len(args.sources)} sources")
    used = [f"--{name.replace('_', '-')}" for name in _SCENE_ONLY if getattr(args, name, None) not in (None, False)]
    if getattr(args, "splats", False):
        used.append("--splats")
    if getattr(args, "color_by", "auto") not in (None, "auto"):
        used.append("--color-by")
    if used:
        raise CitylodError(f"{', '.join(used)}: not available with a far-field tileset")
    out = Path(args.output)
    if out.suffix.lower() != ".png":
        raise CitylodError(f"output must be a .png file, got {out.name!r}")
    spec = getattr(args, "camera", None)
    built_in = built_in_camera(spec)
    cameras = load_cameras(spec) if built_in is None else []
    last = None
    with SlfView(args.sources[0], size=tuple(args.size), tau_px=FIELD_TAU_SCALE * args.tau) as sv:
        if built_in is not None:
            cameras = cameras_for(spec, *sv.bounds(), aspect=sv.size[0] / sv.size[1])
        n = len(cameras)
        for i, cam in enumerate(tqdm(cameras, desc="render", unit="frame", disable=not progress or n < 2)):
            last = sv.prepare(cam)
            sv.draw()
            save_png(frame_path(out, i, n), sv.grab_rgb())
    if last is not None:
        where = out if n == 1 else out.with_name(f"{out.stem}_NNNN{out.suffix}")
        print(f"{where}: {n} frame(s), last: {last.cells} field cells, {last.geometry_cells} cells of buildings, "
              f"{last.bytes_drawn / 1e6:.2f} MB")
    return 0
