"""Semantic shading: highlight, hide, hover and thematic colours on any drawn geometry, by volume.

Design decision 7 (Wahl & Klein 2007, "Towards semantic interaction in high-detail realtime terrain and city
visualization"): city objects are linked to what is drawn (DSM tile meshes, point tiles, any mesh) only by
volume, never by labels. For the scene this module builds, once, Wahl & Klein's top-down *contour maps*
from the store's proxies: a footprint-ID map over the objects' extent plus, per texel, the proxy's lower
and upper contour (for LoD2 objects the upper contour follows the roof faces + inflate, so a glass roof or
a tree crown above a flat roof is *not* inside). Together with a per-object state table they live in two
GPU textures:

* ``citylodMap`` (W, H) RGBA32F: proxy index (-1 none), zmin, zmax relative to the scene origin;
* ``citylodState`` RGBA8, one texel per object (index = fid - 1): highlight rgb, a = 0 nothing,
  1..254 tint weight, 255 hidden.

A vertex-shader replacement passes each vertex's position, mapped by one per-actor matrix (the actor's
model matrix composed with the map's placement) into map texel units, to the fragment stage; the fragment
shader fetches the texel under the fragment, tests z against its interval, and tints or ``discard``\\ s.
On surfaces (DSM tiles, meshes) the vertex stage also lowers the vertices of a hidden object onto its
ground (the lower contour + inflate) and the fragment stage keeps those triangles: a DSM holds nothing
behind a building, so discarding its roof would open a hole onto the background. A frame therefore
costs two texel fetches per drawn fragment (plus up to 18 per vertex of a surface tile near an object
with a state): the cost depends on the pixels and vertices drawn, not on
the size of the dataset or the number of objects highlighted or hidden. A state change re-uploads the
state table (4 bytes per object); tiles streaming in get the shader through
:meth:`~citylod.render.tileset_actor.Scene.add_actor_hook`.

Picking reads the depth buffer under the cursor (so a hidden object's discarded fragments are looked
through), turns it into a point in the data's CRS and asks the proxies which object contains it.

This module creates and changes VTK objects and must run on the thread that owns the GL context. No Qt.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
import shapely

from citylod.core.errors import CitylodError
from citylod.render import _vtk
from citylod.render.gl_context import guard
from citylod.semantics.state import FeatureState, StateChange, parse_color
from citylod.semantics.store import CityStore

__all__ = ["AttributeLegend", "ContourMap", "PickResult", "SemanticOverlay", "build_contour_map",
           "semantic_hook"]

F64 = npt.NDArray[np.float64]

#: Colour and tint weight of the selection and of the hovered object.
SELECTION_RGBA = (0.15, 0.85, 1.0, 0.7)
HOVER_RGBA = (1.0, 1.0, 1.0, 0.45)
_HIDDEN = 255
_LUT_WIDTH = 4096  # objects per row of the state table (GL textures are at least 4096 wide)

_VS_DEC = """//VTK::PositionVC::Dec
uniform mat4 citylodToMap;
uniform mat4 citylodFromMap;
uniform sampler2D citylodMap;
uniform sampler2D citylodState;
uniform int citylodOn;
uniform int citylodLutWidth;
uniform int citylodFlatten;
uniform float citylodGround;
uniform float citylodReach;
out vec3 citylodG;
out float citylodFlat;
"""
_VS_IMPL = """//VTK::PositionVC::Impl
citylodG = (citylodToMap * vertexMC).xyz;
"""
# After VTK's own position code: a surface vertex inside a hidden object's volume is lowered onto the
# object's ground (the proxy's lower contour + inflate), so a hidden building on a DSM leaves the terrain
# under it, not a hole onto the sky. Point tiles do not flatten (their points inside are discarded).
_VS_END = """//VTK::CustomEnd::Impl
citylodFlat = 0.0;
if (citylodOn != 0 && citylodFlatten != 0) {
  ivec2 clSize = textureSize(citylodMap, 0);
  float clGround = 1e30;
  // The vertex's texel and its neighbours up to citylodReach texels away: a DSM vertex on an eave or a
  // gable just outside the footprint's texels would otherwise stay up as a spike.
  for (int dj = -1; dj <= 1; ++dj) {
    for (int di = -1; di <= 1; ++di) {
      ivec2 clIJ = ivec2(floor(citylodG.xy + vec2(di, dj) * citylodReach));
      if (clIJ.x < 0 || clIJ.y < 0 || clIJ.x >= clSize.x || clIJ.y >= clSize.y) continue;
      vec4 clM = texelFetch(citylodMap, clIJ, 0);
      bool clIn = (di == 0 && dj == 0) ? citylodG.z <= clM.b : true;
      if (clM.r >= 0.0 && citylodG.z >= clM.g && clIn) {
        int clId = int(clM.r + 0.5);
        vec4 clS = texelFetch(citylodState, ivec2(clId % citylodLutWidth, clId / citylodLutWidth), 0);
        if (clS.a * 255.0 > 254.5) clGround = min(clGround, clM.g + citylodGround);
      }
    }
  }
  if (clGround < 1e29) {
    // Marked even when already at or below the ground: its triangles are then kept by the fragment stage.
    citylodFlat = 1.0;
    if (citylodG.z > clGround) {
      gl_Position = MCDCMatrix * (citylodFromMap * vec4(citylodG.xy, clGround, 1.0));
    }
  }
}
"""
_FS_DEC = """//VTK::PositionVC::Dec
in vec3 citylodG;
in float citylodFlat;
uniform sampler2D citylodMap;
uniform sampler2D citylodState;
uniform int citylodOn;
uniform int citylodLutWidth;
"""
# Splats (a glyph mapper): the instance's position, and no flattening (points inside a hidden object are
# discarded). VTK declares the samplers (property textures) and the fragment stage's custom uniforms; the
# glyph vertex template has no place for custom uniforms, so the matrix, a fragment custom uniform too (one
# value per program), is declared here as well.
_VS_DEC_GLYPH = """//VTK::PositionVC::Dec
uniform mat4 citylodToMap;
out vec3 citylodG;
out float citylodFlat;
"""
_VS_IMPL_GLYPH = """//VTK::PositionVC::Impl
citylodG = (citylodToMap * vertex).xyz;
citylodFlat = 0.0;
"""
_FS_DEC_GLYPH = """//VTK::PositionVC::Dec
in vec3 citylodG;
in float citylodFlat;
"""
# After the texture is applied (TCoord::Impl follows Light::Impl in VTK's fragment template), so the tint
# goes over orthophotos and point colours alike.
#
# A texel holds one object, the one nearest to its centre. Where a road meets a building, the texels along
# the wall go to either, about half each, so a wall fragment whose texel's height interval misses it (a wall
# above the road's texel) takes another object of a neighbouring texel whose interval holds it (not its own
# texel's object again: above a roof stays untinted): without that, highlighted walls were striped, half
# tinted (Delft, roads of the city model against its buildings).
_FS_IMPL = """//VTK::TCoord::Impl
if (citylodOn != 0) {
  ivec2 clIJ = ivec2(floor(citylodG.xy));
  ivec2 clSize = textureSize(citylodMap, 0);
  if (clIJ.x >= 0 && clIJ.y >= 0 && clIJ.x < clSize.x && clIJ.y < clSize.y) {
    vec4 clM = texelFetch(citylodMap, clIJ, 0);
    bool clHit = clM.r >= 0.0 && citylodG.z >= clM.g && citylodG.z <= clM.b;
    if (!clHit && clM.r >= 0.0) {
      for (int dj = -1; dj <= 1; ++dj) {
        for (int di = -1; di <= 1; ++di) {
          ivec2 clN = clamp(clIJ + ivec2(di, dj), ivec2(0), clSize - 1);
          vec4 clT = texelFetch(citylodMap, clN, 0);
          if (!clHit && clT.r >= 0.0 && abs(clT.r - clM.r) > 0.5 && citylodG.z >= clT.g && citylodG.z <= clT.b) {
            clM = clT;
            clHit = true;
          }
        }
      }
    }
    if (clHit) {
      int clId = int(clM.r + 0.5);
      vec4 clS = texelFetch(citylodState, ivec2(clId % citylodLutWidth, clId / citylodLutWidth), 0);
      float clA = clS.a * 255.0;
      if (clA > 254.5) {
        if (citylodFlat <= 0.0) discard;
      } else if (clA > 0.5) {
        // The highlight colour keeps a little of the surface's shading but stays saturated and bright,
        // so it reads on a grey DSM as well as on an orthophoto (a plain luminance scale turned yellow
        // into khaki there).
        float clL = dot(gl_FragData[0].rgb, vec3(0.299, 0.587, 0.114));
        gl_FragData[0].rgb = mix(gl_FragData[0].rgb, min(clS.rgb * (0.8 + 0.4 * clL), vec3(1.0)), clA / 254.0);
      }
    }
  }
}
"""


# ------------------------------------------------------------------------------------------ contour map
@dataclass(frozen=True)
class ContourMap:
    """Wahl & Klein's contour maps of a scene, as uploaded.

    Attributes
    ----------
    texels
        (H, W, 4) float32: proxy index (-1 none), lower and upper contour (z minus ``z_ref``), 0. Row 0 is
        the northern edge.
    x0, y1
        West and north edge of the grid in the data's CRS.
    resolution
        Texel size in metres.
    z_ref
        Height subtracted from the contours (the scene origin's z).
    """

    texels: npt.NDArray[np.float32]
    x0: float
    y1: float
    resolution: float
    z_ref: float

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.texels.shape[0]), int(self.texels.shape[1])

    def world_to_texel(self, origin: npt.ArrayLike) -> F64:
        """(4, 4) matrix from scene-relative coordinates (data CRS minus ``origin``) to (column, row, z - z_ref)
        in texel units, the frame of the shader's lookup."""
        o = np.asarray(origin, np.float64)
        r = self.resolution
        g = np.zeros((4, 4))
        g[0, 0], g[0, 3] = 1.0 / r, (o[0] - self.x0) / r
        g[1, 1], g[1, 3] = -1.0 / r, (self.y1 - o[1]) / r
        g[2, 2], g[2, 3] = 1.0, o[2] - self.z_ref
        g[3, 3] = 1.0
        return g


def build_contour_map(store: CityStore, *, resolution: float = 0.5, max_texels: int = 2048 * 2048,
                      bounds: Sequence[float] | None = None, z_ref: float = 0.0) -> ContourMap:
    """Rasterise the store's proxies into the footprint-ID map with per-texel lower and upper contours.

    Parameters
    ----------
    store
        The city store.
    resolution
        Wanted texel size in metres; coarsened when the extent would need more than ``max_texels``.
    bounds
        (xmin, ymin, xmax, ymax) to cover; default: every proxy (inflated footprints).
    z_ref
        Subtracted from the heights (keep float32 contours near zero, decision 6).

    Returns
    -------
    ContourMap
    """
    proxies = store.proxies
    has = np.isfinite(proxies.zmin)
    if not has.any():
        raise CitylodError("the city store has no object with a proxy", store.path)
    x0, y0, x1, y1 = shapely.total_bounds(proxies.shapes[has])
    if bounds is not None:
        x0, y0 = max(x0, float(bounds[0])), max(y0, float(bounds[1]))
        x1, y1 = min(x1, float(bounds[2])), min(y1, float(bounds[3]))
        if x1 <= x0 or y1 <= y0:
            raise CitylodError("the city store does not overlap the scene", store.path)
    pad = float(resolution)
    x0, y0, x1, y1 = x0 - pad, y0 - pad, x1 + pad, y1 + pad
    res = max(float(resolution), math.sqrt((x1 - x0) * (y1 - y0) / max_texels))
    fmap = proxies.rasterize_footprints((x0, y0, x1, y1), res)
    ids, zmin, zmax = fmap.id_map, fmap.zmin.astype(np.float64), fmap.zmax.astype(np.float64)
    h, w = ids.shape
    top = zmax.copy()
    if len(proxies.roof_owner):
        # LoD2: the upper contour follows the roof + inflate (as ProxySet.contains does). Sampled at the
        # texel's centre and corners and the highest kept, so a sloped roof is never cut inside a texel.
        rows, cols = np.nonzero(ids >= 0)
        owner = ids[rows, cols].astype(np.int64)
        roof = np.full(len(rows), -np.inf)
        for du, dv in ((0.5, 0.5), (0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)):
            xy = np.column_stack([x0 + (cols + du) * res, y1 - (rows + dv) * res])
            t = proxies.roof_top(xy, owner)
            roof = np.fmax(roof, np.where(np.isnan(t), -np.inf, t))
        ok = np.isfinite(roof)
        sel = (rows[ok], cols[ok])
        top[sel] = np.minimum(zmax[sel], roof[ok] + proxies.inflate)
    texels = np.zeros((h, w, 4), np.float32)
    texels[..., 0] = ids
    inside = ids >= 0
    texels[..., 1] = np.where(inside, zmin - z_ref, 0.0)
    texels[..., 2] = np.where(inside, top - z_ref, -1.0)
    return ContourMap(texels, float(x0), float(fmap.bounds[3]), float(res), float(z_ref))


# ------------------------------------------------------------------------------------------ results
@dataclass(frozen=True)
class PickResult:
    """What lies under a pixel: ``point_xyz`` (3,) in the data's CRS (None over the background), the
    ``object_id`` whose proxy contains it (None when none), and that object's ``attributes``."""

    point_xyz: F64 | None
    object_id: str | None
    attributes: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class AttributeLegend:
    """How :meth:`SemanticOverlay.color_by_attribute` mapped values to colours.

    ``kind`` is "numeric" (``vmin``..``vmax`` through ``cmap``) or "category" (``categories``: value to
    RGB in 0..1); ``missing`` counts objects without a value (left uncoloured).
    """

    column: str
    kind: str
    cmap: str
    vmin: float = float("nan")
    vmax: float = float("nan")
    categories: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    missing: int = 0


# ------------------------------------------------------------------------------------------ overlay
def overlay_map_args(scene: Any, *, resolution: float = 0.5, max_texels: int = 2048 * 2048) -> dict[str, Any]:
    """The keyword arguments of :func:`build_contour_map` that :class:`SemanticOverlay` uses for ``scene``.

    The map is pure numpy, so a GUI can build it on a worker thread and pass it in as ``contour_map``.
    """
    bounds = None
    if scene.layers:
        lo, hi = scene.bounds
        bounds = (lo[0], lo[1], hi[0], hi[1])
    return {"resolution": resolution, "max_texels": max_texels, "bounds": bounds,
            "z_ref": float(np.asarray(scene.origin, np.float64)[2])}


class SemanticOverlay:
    """Keeps every tile actor of a :class:`~citylod.render.tileset_actor.Scene` shaded by a
    :class:`~citylod.semantics.state.FeatureState` through the proxies of a :class:`CityStore`.

    Parameters
    ----------
    scene
        The scene; its present and future tile actors get the shader.
    store
        The city store whose proxies define the objects' volumes.
    state
        The feature state (a new one when omitted); the overlay follows its changes.
    resolution
        Texel size of the contour map in metres (0.25 to 0.5 is enough for inflated proxies).
    max_texels
        Cap on the contour map's size; a larger extent gets coarser texels.

    Examples
    --------
    >>> overlay = SemanticOverlay(scene, store)                    # doctest: +SKIP
    >>> overlay.state.highlight(store.query("measured_height > 20"))  # doctest: +SKIP
    >>> overlay.pick(scene.renderer, 400, 300).object_id            # doctest: +SKIP
    """

    def __init__(self, scene: Any, store: CityStore, state: FeatureState | None = None, *,
                 resolution: float = 0.5, max_texels: int = 2048 * 2048, contour_map: Any = None) -> None:
        if scene.origin is None:
            raise CitylodError("add a tileset to the scene before the semantic overlay")
        self.scene = scene
        self.store = store
        self.state = state if state is not None else FeatureState()
        self.enabled = True
        origin = np.asarray(scene.origin, np.float64)
        self._origin = origin
        # A map built beforehand (e.g. on a worker thread by the GUI; see overlay_map_args) is used as is.
        self.map = contour_map if contour_map is not None else build_contour_map(
            store, **overlay_map_args(scene, resolution=resolution, max_texels=max_texels))
        self._to_map = self.map.world_to_texel(origin)
        n = len(store.ids)
        self._lut_h = max(1, -(-n // _LUT_WIDTH))
        self._lut_w = _LUT_WIDTH if n > _LUT_WIDTH else max(n, 1)
        self._theme = np.zeros((n, 4), np.float32)  # thematic colour, weight in alpha
        self._lut = np.zeros((self._lut_h * self._lut_w, 4), np.uint8)
        self._lut_version = 0
        self._any_state = False
        self._active_boxes: F64 | None = None
        b = shapely.bounds(store.proxies.shapes)  # (N, 4) xmin, ymin, xmax, ymax; NaN when empty
        self._boxes = np.column_stack([b[:, 0], b[:, 2], b[:, 1], b[:, 3], store.proxies.zmin,
                                       store.proxies.zmax]) - np.repeat(origin, 2)
        self._rebuild_lut()
        self._map_tex: Any = None
        self._lut_tex: Any = None
        self._uploaded_lut = -1
        self._window: Any = None
        self._actors: list[tuple[Any, Any, int]] = []  # (actor, observed mapper, observer tag)
        # id(actor) -> the semantic shader attached: None, "mc" (a mapper drawing the data's vertices) or
        # "glyph" (splats: a glyph mapper's instances, whose uniforms go through the shader property)
        self._shaded: dict[int, str | None] = {}
        self._glyph_textures: tuple[Any, Any] | None = None  # the two maps as textures of an actor's property
        self._glyph_matrix: dict[int, int] = {}  # id(actor) -> MTime of the matrix its uniform was made from
        self._unsubscribe = self.state.on_change(self._on_state)
        self._remove_hook = scene.add_actor_hook(self._attach)
        # After the scene's own StartEvent observer (which picks the tiles): lower priority runs later.
        self._start_tag = scene.renderer.AddObserver(_vtk.vtkCommand.StartEvent, self._on_start, -1.0)

    # -- public -----------------------------------------------------------------------------------
    def set_hover(self, object_id: str | None) -> None:
        """Mark the object under the cursor (None for none); shown as a light tint."""
        self.state.set_hover(object_id)

    def set_enabled(self, on: bool) -> None:
        """Switch the semantic shading off (the shader then returns at its first test) or on."""
        self.enabled = bool(on)

    def color_by_attribute(self, column: str | None, cmap: str = "viridis", *, weight: float = 0.85,
                           vmin: float | None = None, vmax: float | None = None) -> AttributeLegend | None:
        """Tint each object's proxy region by an attribute (Buchholz et al.'s thematic styling).

        Parameters
        ----------
        column
            A column of ``city_objects`` (``measured_height``, ``function``, ...) or a source attribute;
            None removes the thematic colours.
        cmap
            A matplotlib colour map: continuous for numbers, its first colours for categories (a
            qualitative map such as ``tab10`` is used when ``cmap`` is the default and the values are not
            numbers).
        weight
            Blend weight of the colour over the drawn geometry's own.
        vmin, vmax
            Range of the numeric map (default: the values' range).
        """
        n = len(self.store.ids)
        self._theme = np.zeros((n, 4), np.float32)
        if column is None:
            self._rebuild_lut()
            return None
        from matplotlib import colormaps

        values: list[Any] = [self.store.attributes(oid).get(column) for oid in self.store.ids]
        present = np.array([v is not None and v != "" for v in values])
        numeric = all(isinstance(v, (int, float)) and not isinstance(v, bool)
                      for v, p in zip(values, present, strict=True) if p)
        if numeric and present.any():
            x = np.array([float(v) if p else np.nan for v, p in zip(values, present, strict=True)])
            ok = np.isfinite(x)
            lo = float(np.nanmin(x[ok])) if vmin is None else float(vmin)
            hi = float(np.nanmax(x[ok])) if vmax is None else float(vmax)
            t = np.clip((x - lo) / (hi - lo if hi > lo else 1.0), 0.0, 1.0)
            rgb = colormaps[cmap](np.where(ok, t, 0.0))[:, :3]
            self._theme[ok, :3] = rgb[ok]
            self._theme[ok, 3] = weight
            legend = AttributeLegend(column, "numeric", cmap, lo, hi, missing=int((~ok).sum()))
        else:
            cats = sorted({str(v) for v, p in zip(values, present, strict=True) if p})
            cm = colormaps["tab10" if cmap == "viridis" else cmap]
            k = max(len(cats), 1)
            table = {c: tuple(float(u) for u in (cm(i % cm.N) if cm.N < 256 else cm(i / max(k - 1, 1)))[:3])
                     for i, c in enumerate(cats)}
            for i, (v, p) in enumerate(zip(values, present, strict=True)):
                if p:
                    self._theme[i, :3] = table[str(v)]
                    self._theme[i, 3] = weight
            legend = AttributeLegend(column, "category", cm.name, categories=table,  # type: ignore[arg-type]
                                     missing=int((~present).sum()))
        self._rebuild_lut()
        return legend

    def pick(self, renderer: Any, x_px: int, y_px: int) -> PickResult:
        """The point and object under a pixel of the last rendered frame.

        Parameters
        ----------
        renderer
            The renderer the scene draws into (its window must have rendered).
        x_px, y_px
            Display coordinates, origin at the bottom left (VTK's, as ``GetEventPosition`` gives them).

        Returns
        -------
        PickResult
            The depth-buffer point in the data's CRS (so hidden objects, whose fragments were discarded, are
            looked through), the object whose proxy contains it and its attributes.
        """
        window = renderer.GetRenderWindow()
        with guard(window):  # an off-screen window's depth, not a PyVista window's (render.gl_context)
            z = float(window.GetZbufferDataAtPoint(int(x_px), int(y_px)))
        if not z < 1.0:
            return PickResult(None, None, {})
        renderer.SetDisplayPoint(float(x_px), float(y_px), z)
        renderer.DisplayToWorld()
        w = np.asarray(renderer.GetWorldPoint(), np.float64)
        xyz = w[:3] / w[3] + self._origin
        idx = int(self.store.proxies.contains(xyz[None, :])[0])
        if idx < 0:
            return PickResult(xyz, None, {})
        oid = self.store.ids[idx]
        if not self.state.is_visible(oid):
            return PickResult(xyz, None, {})
        return PickResult(xyz, oid, self.store.attributes(oid))

    def close(self) -> None:
        """Detach from the scene and the state, and free the GPU textures."""
        self._unsubscribe()
        self._remove_hook()
        self.scene.renderer.RemoveObserver(self._start_tag)
        for actor, mapper, tag in self._actors:
            mapper.RemoveObserver(tag)
            if self._shaded.get(id(actor)):
                self._set_shader(actor, None)
        self._actors.clear()
        self._shaded.clear()
        for tex in (self._map_tex, self._lut_tex):
            if tex is not None and self._window is not None:
                with guard(self._window):  # freed in our context, not a PyVista window's
                    tex.Deactivate()
                    tex.ReleaseGraphicsResources(self._window)
        self._map_tex = self._lut_tex = None
        self._glyph_textures = None
        self._glyph_matrix.clear()

    # -- state table ------------------------------------------------------------------------------
    def _on_state(self, change: StateChange) -> None:
        if change.kind in ("hover", "highlight", "hide", "select") and len(change.ids) < 64:
            for oid in change.ids:
                try:
                    i = self.store.proxies.index_of(oid)
                except KeyError:
                    continue
                self._lut[i] = self._row(oid, self._theme[i])
            self._state_changed()
        else:
            self._rebuild_lut()

    def _state_changed(self) -> None:
        self._any_state = self._has_state()
        self._lut_version += 1
        n = len(self.store.ids)
        active = np.flatnonzero(self._lut[:n, 3] > 0)
        if len(active) == 0:
            self._active_boxes = None
        else:
            boxes = self._boxes[active]
            boxes = boxes[np.isfinite(boxes).all(axis=1)]
            if len(boxes) > 256:  # many objects: their union box (conservative, one test per actor)
                lo, hi = boxes[:, 0::2].min(axis=0), boxes[:, 1::2].max(axis=0)
                boxes = np.stack([lo, hi], axis=1).reshape(1, 6)
            self._active_boxes = boxes if len(boxes) else None

    def _has_state(self) -> bool:
        s = self.state
        return bool(s.colors or s.hidden or s.selection or s.hover is not None or s.isolated is not None
                    or self._theme[:, 3].any())

    def _row(self, oid: str, theme: npt.NDArray[np.float32]) -> npt.NDArray[np.uint8]:
        s = self.state
        if not s.is_visible(oid):
            return np.array([0, 0, 0, _HIDDEN], np.uint8)
        rgb, w = theme[:3].astype(np.float64), float(theme[3])
        hl = s.colors.get(oid)
        if hl is not None:
            rgb, w = np.asarray(hl[:3]), float(hl[3])
        if oid in s.selection:
            rgb, w = np.asarray(SELECTION_RGBA[:3]), SELECTION_RGBA[3]
        if oid == s.hover:
            hv = np.asarray(HOVER_RGBA[:3])
            rgb = hv if w == 0.0 else 0.5 * (rgb + hv)
            w = max(w, HOVER_RGBA[3])
        return np.array([*np.round(np.clip(rgb, 0, 1) * 255), round(min(max(w, 0.0), 1.0) * 254)], np.uint8)

    def _rebuild_lut(self) -> None:
        n = len(self.store.ids)
        rgba, visible, selected = self.state.as_arrays(self.store.ids)
        rgb = self._theme[:, :3].astype(np.float64)
        w = self._theme[:, 3].astype(np.float64)
        has = rgba[:, 3] > 0
        rgb[has], w[has] = rgba[has, :3], rgba[has, 3]
        rgb[selected], w[selected] = SELECTION_RGBA[:3], SELECTION_RGBA[3]
        lut = np.zeros((self._lut_h * self._lut_w, 4), np.uint8)
        lut[:n, :3] = np.round(np.clip(rgb, 0, 1) * 255)
        lut[:n, 3] = np.round(np.clip(w, 0, 1) * 254)
        lut[:n][~visible] = (0, 0, 0, _HIDDEN)
        self._lut = lut
        hover = self.state.hover
        if hover is not None and self.state.is_visible(hover):
            try:
                i = self.store.proxies.index_of(hover)
            except KeyError:
                i = -1
            if i >= 0:
                self._lut[i] = self._row(hover, self._theme[i])
        self._state_changed()

    # -- GL ---------------------------------------------------------------------------------------
    def _attach(self, actor: Any) -> None:
        mapper = actor.GetMapper()
        tag = mapper.AddObserver(_vtk.vtkCommand.UpdateShaderEvent, self._callback(actor))
        self._actors.append((actor, mapper, tag))
        self._shaded[id(actor)] = None

    def _on_start(self, _obj: Any, _event: str) -> None:
        """Before each frame: give the shader to the shown actors whose tile touches an object with a state,
        take it from the others. Tiles away from every highlighted or hidden object draw with VTK's own
        shader, so they cost nothing extra (on llvmpipe the lookup costs ~15 % of a tile's frame time)."""
        boxes = self._active_boxes if self.enabled else None
        for i, (actor, mapper, tag) in enumerate(self._actors):
            if not actor.GetVisibility():
                continue
            need = False
            if boxes is not None:
                b = actor.GetBounds()
                need = bool(np.any((boxes[:, 0] <= b[1]) & (boxes[:, 1] >= b[0]) & (boxes[:, 2] <= b[3])
                                   & (boxes[:, 3] >= b[2]) & (boxes[:, 4] <= b[5]) & (boxes[:, 5] >= b[4])))
            current = actor.GetMapper()
            glyph = bool(current.IsA("vtkGlyph3DMapper"))
            if not glyph and current is not mapper:  # a tile back from splats on a mapper not yet observed
                mapper.RemoveObserver(tag)
                self._actors[i] = (actor, current, current.AddObserver(_vtk.vtkCommand.UpdateShaderEvent,
                                                                       self._callback(actor)))
            mode = ("glyph" if glyph else "mc") if need else None
            if mode != self._shaded[id(actor)]:
                self._set_shader(actor, mode)
            if mode == "glyph":
                self._glyph_uniforms(actor)

    def _set_shader(self, actor: Any, mode: str | None) -> None:
        sp = actor.GetShaderProperty()
        sp.ClearVertexShaderReplacement("//VTK::PositionVC::Dec", True)
        sp.ClearVertexShaderReplacement("//VTK::PositionVC::Impl", True)
        sp.ClearVertexShaderReplacement("//VTK::CustomEnd::Impl", True)
        sp.ClearFragmentShaderReplacement("//VTK::PositionVC::Dec", True)
        sp.ClearFragmentShaderReplacement("//VTK::TCoord::Impl", True)
        if mode == "mc":
            sp.AddVertexShaderReplacement("//VTK::PositionVC::Dec", True, _VS_DEC, False)
            sp.AddVertexShaderReplacement("//VTK::PositionVC::Impl", True, _VS_IMPL, False)
            sp.AddVertexShaderReplacement("//VTK::CustomEnd::Impl", True, _VS_END, False)
            sp.AddFragmentShaderReplacement("//VTK::PositionVC::Dec", True, _FS_DEC, False)
        elif mode == "glyph":
            sp.AddVertexShaderReplacement("//VTK::PositionVC::Dec", True, _VS_DEC_GLYPH, False)
            sp.AddVertexShaderReplacement("//VTK::PositionVC::Impl", True, _VS_IMPL_GLYPH, False)
            sp.AddFragmentShaderReplacement("//VTK::PositionVC::Dec", True, _FS_DEC_GLYPH, False)
        if mode is not None:
            sp.AddFragmentShaderReplacement("//VTK::TCoord::Impl", True, _FS_IMPL, False)
        if mode != "glyph" and self._shaded.get(id(actor)) == "glyph":
            prop = actor.GetProperty()
            for name in ("citylodMap", "citylodState"):
                prop.RemoveTexture(name)
            sp.GetFragmentCustomUniforms().RemoveAllUniforms()
            self._glyph_matrix.pop(id(actor), None)
        self._shaded[id(actor)] = mode

    def _glyph_uniforms(self, actor: Any) -> None:
        """The uniforms of a glyph (splat) actor, set before each frame (called from the renderer's StartEvent,
        with the GL context current).

        VTK's glyph mapper draws through internal helper mappers, which raise no ``UpdateShaderEvent`` to
        observe; so the two maps become textures of the actor's property (VTK declares and binds them), and
        the numbers are the shader property's custom uniforms (VTK declares and sets them). The instance
        position is the glyph shader's ``vertex`` (``GCMCMatrix * vertexMC``), in the dataset's coordinates,
        which the glyph mapper uploads unshifted. The glyph vertex template has no place for custom uniforms:
        the matrix is a fragment custom uniform, declared by hand in the vertex stage too."""
        self._bind()
        if self._glyph_textures is None:
            wrapped = []
            for tex in (self._map_tex, self._lut_tex):
                t = _vtk.vtkOpenGLTexture()
                t.SetTextureObject(tex)
                wrapped.append(t)
            self._glyph_textures = (wrapped[0], wrapped[1])
        prop = actor.GetProperty()
        if prop.GetTexture("citylodMap") is not self._glyph_textures[0]:
            prop.SetTexture("citylodMap", self._glyph_textures[0])
            prop.SetTexture("citylodState", self._glyph_textures[1])
        sp = actor.GetShaderProperty()
        fu = sp.GetFragmentCustomUniforms()
        fu.SetUniformi("citylodOn", 1 if self.enabled and self._any_state else 0)
        fu.SetUniformi("citylodLutWidth", self._lut_w)
        m = actor.GetMatrix()
        if self._glyph_matrix.get(id(actor)) != m.GetMTime():  # the tile's placement changed (or is new)
            model = np.array([m.GetElement(i, j) for i in range(4) for j in range(4)]).reshape(4, 4)
            to_map = _vtk.vtkMatrix4x4()
            to_map.DeepCopy((self._to_map @ model).T.ravel().tolist())  # GLSL reads column by column
            fu.SetUniformMatrix("citylodToMap", to_map)
            self._glyph_matrix[id(actor)] = m.GetMTime()

    def _callback(self, actor: Any) -> Callable[..., None]:
        cache: dict[str, Any] = {"key": None, "matrix": _vtk.vtkMatrix4x4(), "inverse": _vtk.vtkMatrix4x4()}

        @_vtk.calldata_type(_vtk.VTK_OBJECT)
        def update(mapper: Any, _event: str, program: Any) -> None:
            if program is None or not self._shaded.get(id(actor)):
                return
            self._bind()
            program.SetUniformi("citylodOn", 1 if self.enabled and self._any_state else 0)
            program.SetUniformi("citylodMap", self._map_tex.GetTextureUnit())
            program.SetUniformi("citylodState", self._lut_tex.GetTextureUnit())
            program.SetUniformi("citylodLutWidth", self._lut_w)
            data = mapper.GetInput()
            surface = data is not None and data.GetNumberOfPolys() + data.GetNumberOfStrips() > 0
            program.SetUniformi("citylodFlatten", 1 if surface else 0)
            program.SetUniformf("citylodGround", float(self.store.inflate))
            # One inflate distance (at least one texel): the proxies' own tolerance around a footprint.
            program.SetUniformf("citylodReach", max(1.0, float(self.store.inflate) / self.map.resolution))
            m = actor.GetMatrix()
            # VTK may upload positions shifted and scaled (vtkOpenGLVertexBufferObject's coordinate
            # shift/scale): vertexMC = (p - shift) * scale, so undo it before the model matrix.
            vbo = mapper.GetVBOs().GetVBO("vertexMC")
            shift, scale = ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))
            if vbo is not None and vbo.GetCoordShiftAndScaleEnabled():
                shift, scale = tuple(vbo.GetShift()), tuple(vbo.GetScale())
            key = (m.GetMTime(), shift, scale)
            if key != cache["key"]:
                model = np.array([m.GetElement(i, j) for i in range(4) for j in range(4)]).reshape(4, 4)
                unshift = np.eye(4)
                unshift[:3, :3] = np.diag(1.0 / np.asarray(scale, np.float64))
                unshift[:3, 3] = shift
                # GLSL reads the 16 values column by column: hand it the transpose.
                to_map = self._to_map @ model @ unshift
                cache["matrix"].DeepCopy(to_map.T.ravel().tolist())
                cache["inverse"].DeepCopy(np.linalg.inv(to_map).T.ravel().tolist())
                cache["key"] = key
            program.SetUniformMatrix("citylodToMap", cache["matrix"])
            program.SetUniformMatrix("citylodFromMap", cache["inverse"])

        return update

    def _bind(self) -> None:
        """Create the textures on first use (the GL context is current during a render) and bind them."""
        if self._map_tex is None:
            self._window = self.scene.renderer.GetRenderWindow()
            tex = _vtk.vtkTextureObject()
            tex.SetContext(self._window)
            h, w = self.map.shape
            if not tex.Create2DFromRaw(w, h, 4, _vtk.VTK_FLOAT, np.ascontiguousarray(self.map.texels)):
                raise CitylodError("cannot create the semantic contour-map texture")
            self._nearest(tex)
            self._map_tex = tex
            lut = _vtk.vtkTextureObject()
            lut.SetContext(self._window)
            self._lut_tex = lut
        if self._uploaded_lut != self._lut_version:
            if not self._lut_tex.Create2DFromRaw(self._lut_w, self._lut_h, 4, _vtk.VTK_UNSIGNED_CHAR,
                                                 np.ascontiguousarray(self._lut)):
                raise CitylodError("cannot create the semantic state texture")
            self._nearest(self._lut_tex)
            self._uploaded_lut = self._lut_version
        self._map_tex.Activate()
        self._lut_tex.Activate()

    @staticmethod
    def _nearest(tex: Any) -> None:
        tex.SetMinificationFilter(_vtk.vtkTextureObject.Nearest)
        tex.SetMagnificationFilter(_vtk.vtkTextureObject.Nearest)
        tex.SetWrapS(_vtk.vtkTextureObject.ClampToEdge)
        tex.SetWrapT(_vtk.vtkTextureObject.ClampToEdge)


# ------------------------------------------------------------------------------------------ command line
def semantic_hook(scene: Any, city: str | os.PathLike[str] | None = None, highlight: str | None = None,
                  hide: str | None = None, *, color: str = "#ffcc00") -> SemanticOverlay:
    """``citylod render --city STORE.gpkg --highlight SQL --hide SQL``: attach an overlay to ``scene``.

    Parameters
    ----------
    scene
        The off-screen renderer's scene (tilesets added).
    city
        The city store (a ``.gpkg`` written by ``citylod build city``).
    highlight, hide
        WHERE clauses over ``city_objects`` (see :meth:`CityStore.query`).
    color
        Highlight colour.

    Returns
    -------
    SemanticOverlay
        Kept alive by the scene's actor hooks for as long as the scene lives.
    """
    if city is None:
        raise CitylodError("--highlight and --hide need a city store: pass --city STORE.gpkg")
    store = CityStore.open(city)
    overlay = SemanticOverlay(scene, store)
    if highlight:
        overlay.state.highlight(store.query(highlight), parse_color(color))
    if hide:
        overlay.state.hide(store.query(hide))
    return overlay
