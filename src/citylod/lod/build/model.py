"""City models from a DSM: shapes, the shape map, and constrained simplification with a certified error.

Wahl, Schnabel, Klein, PFG 2008; Möser, Wahl, Klein, ISPRS 2009 (chapters 4–5 of Wahl's thesis). A detailed
DSM becomes a compact mesh that keeps its planes, ridges, eaves and corners:

1. height field → points; façade points are inserted at height discontinuities every ``spacing`` metres
   (:func:`citylod.lod.kernels.shapes.facade_columns`);
2. planes by localised RANSAC, roofs and façades with separate parameters and a minimum size
   (:mod:`citylod.lod.kernels.shapes`);
3. the shape map: per DSM vertex the shape IDs within ε (edge vertices two, corners more);
4. half-edge collapses ordered by quadric error, under the subset, edge/corner, shape-border and tunnel
   rules, the topological filter and a certified bound on the 3D Hausdorff distance (or, optionally, the
   vertical distance) to the grid surface (:mod:`citylod.lod.kernels.collapse`).

Out of core: the raster is cut into square cells that share their border row and column with their east
and south neighbours; the shared samples are locked, so the cells' meshes meet without cracks, and each
cell is a task on citylod's executor (local processes or Dask), reading only its window: memory is
bounded by the cells in flight. The mesh is written as 3D Tiles (one tile per cell, ``geometricError`` the
certified bound); connected components standing above the ground become city objects in CityJSON
(LoD1 solid from the footprint, measured height and roof planes as attributes) that ``citylod build city``
reads. No VTK, no Qt.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from citylod.core.errors import InputError
from citylod.core.fileio import atomic_write_text, publish_dir
from citylod.lod.kernels import collapse, shapes

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]


@dataclass(frozen=True)
class ShapeParams:
    """Parameters of shape detection, lengths in metres (None: scaled from the sample spacing).

    Roofs (and ground) and façades have separate thresholds, as in Wahl's thesis: roofs are fitted to the
    samples (distance ``roof_eps``, normal deviation ``roof_angle_deg``, at least ``roof_min_area`` m²);
    façades to the points inserted at jumps over ``jump`` m (distance ``facade_eps``, at least
    ``facade_min_area`` m² of wall). ``map_eps`` is the ε of the shape map; two planes make an edge only
    where they meet at ``min_edge_angle_deg`` or more. Planes of the ground are dropped unless
    ``ground_planes``.
    """

    roof_eps: float | None = None
    roof_angle_deg: float = 20.0
    roof_min_area: float = 15.0
    roof_max_slope_deg: float = 75.0
    facade_eps: float | None = None
    facade_min_area: float = 12.0
    jump: float = 1.5
    map_eps: float | None = None
    min_edge_angle_deg: float = 25.0
    seed: int = 1
    ground_planes: bool = False

    def resolved(self, spacing: float) -> ShapeParams:
        """The parameters with the spacing-dependent defaults filled in."""
        return ShapeParams(
            roof_eps=self.roof_eps if self.roof_eps is not None else max(0.15, 0.3 * spacing),
            roof_angle_deg=self.roof_angle_deg, roof_min_area=self.roof_min_area,
            roof_max_slope_deg=self.roof_max_slope_deg,
            facade_eps=self.facade_eps if self.facade_eps is not None else 0.8 * spacing,
            facade_min_area=self.facade_min_area, jump=self.jump,
            map_eps=self.map_eps if self.map_eps is not None else max(0.25, 0.8 * spacing),
            min_edge_angle_deg=self.min_edge_angle_deg, seed=self.seed, ground_planes=self.ground_planes)


@dataclass
class Shapes:
    """Detected shapes of one grid and its shape map.

    ``roof_label`` (H, W) int32 plane per sample (-1 none); ``roof_planes`` (K, 4) normal and offset in grid
    metres (x = col·dx, y = -row·dy); ``facade_planes`` (F, 4); ``shape_map`` (H·W, MAX_IDS) int32, façade
    IDs offset by K.
    """

    roof_label: npt.NDArray[np.int32]
    roof_planes: F64
    facade_planes: F64
    facade_columns: int
    shape_map: npt.NDArray[np.int32]

    @property
    def vertex_classes(self) -> npt.NDArray[np.int64]:
        """Vertices with 0, 1, 2, 3, … shape IDs (unassigned, face, edge, corner…)."""
        return np.bincount((self.shape_map >= 0).sum(axis=1), minlength=shapes.MAX_IDS + 1)


def _keep_mostly(label: npt.NDArray[np.int32], shapes_: F64, where: npt.NDArray[np.bool_]
                 ) -> tuple[npt.NDArray[np.int32], F64]:
    """Keep the shapes at least half of whose labelled samples lie ``where``; the others' samples get -1
    and the kept shapes are renumbered in order."""
    ok = label >= 0
    n_all = np.bincount(label[ok], minlength=len(shapes_))
    n_in = np.bincount(label[ok & where], minlength=len(shapes_))
    keep = n_in >= 0.5 * np.maximum(n_all, 1)
    remap = np.where(keep, np.cumsum(keep) - 1, -1).astype(np.int32)
    return (np.where(ok, remap[np.maximum(label, 0)], -1).astype(np.int32),
            np.ascontiguousarray(shapes_[keep]))


def detect_shapes(F: F64, V: npt.NDArray[np.bool_], dx: float, dy: float, params: ShapeParams | None = None,
                  ground: F64 | None = None) -> Shapes:
    """Planes of a height grid and its shape map (steps 1–3 of the module docstring).

    Parameters
    ----------
    F, V
        (H, W) float64 heights (row 0 north) and bool validity.
    dx, dy
        Sample spacing in metres.
    ground
        (H, W) bare-earth heights where known (else estimated, :func:`ground_height`).
    """
    spacing = 0.5 * (dx + dy)
    p = (params or ShapeParams()).resolved(spacing)
    F = np.ascontiguousarray(np.where(V, F, 0.0), dtype=np.float64)
    V = np.ascontiguousarray(V, dtype=bool)
    min_size = max(3, int(math.ceil(p.roof_min_area / (dx * dy))))
    label, planes = shapes.detect_roof_planes(F, V, dx, dy, p.roof_eps, p.roof_angle_deg, min_size,
                                              p.roof_max_slope_deg, p.seed, 24, 24, 3)
    if not p.ground_planes and len(planes):
        # RANSAC cuts curved terrain into many nearly coplanar planes whose borders are no feature of the
        # city; their border rule would keep ragged polylines across the ground. Planes mostly standing
        # less than ``jump`` above the bare-earth estimate are dropped (the ground is left to QEM and the
        # certified bound).
        lifted = (F - (ground_height(F, V, spacing) if ground is None else ground)) > p.jump
        label, planes = _keep_mostly(label, planes, lifted)
    cols = shapes.facade_columns(F, V, dx, dy, p.jump)
    fl, fplanes = shapes.detect_facades(cols, spacing, p.facade_eps, p.facade_min_area / (spacing * spacing),
                                        p.seed, 24, 24, 4.0 * spacing, 2.5 * spacing)
    if len(fplanes):
        # a wall holds up a roof: façades whose columns mostly have no roof plane at their top (the
        # rims of tree crowns, terrain steps) are dropped, so they do not pin vertices on trees
        top = np.where(F.reshape(-1)[cols[:, 4].astype(np.int64)] > F.reshape(-1)[cols[:, 5].astype(np.int64)],
                       cols[:, 4], cols[:, 5]).astype(np.int64)
        fl, fplanes = _keep_mostly(fl, fplanes, label.reshape(-1)[top] >= 0)
    smap = shapes.shape_map(F, V, dx, dy, label, planes, p.map_eps, fl, cols, fplanes, p.facade_eps, len(planes),
                            math.cos(math.radians(p.min_edge_angle_deg)))
    return Shapes(label, planes, fplanes, len(cols), smap)


@dataclass
class ModelMesh:
    """A simplified grid mesh: ``faces`` (M, 3) int64 flat sample indices (row·W + col) of the grid,
    counter-clockwise in (col, row); ``max_error`` the certified bound in metres, on the distance ``metric``
    names; ``rejections`` the half-edges each rule rejected."""

    shape: tuple[int, int]
    faces: I64
    max_error: float
    collapses: int
    seconds: float
    shapes: Shapes | None = None
    rejections: dict[str, int] = field(default_factory=dict)
    metric: str = "hausdorff"

    @property
    def vertex_ids(self) -> I64:
        """Flat sample indices of the vertices used, sorted."""
        return np.unique(self.faces)

    def vertices(self, F: F64, dx: float, dy: float) -> tuple[F64, I64]:
        """(V, 3) float64 grid-metre positions (x = col·dx, y = -row·dy, z) and the faces re-indexed."""
        ids, inv = np.unique(self.faces, return_inverse=True)
        W = self.shape[1]
        r, c = np.divmod(ids, W)
        pos = np.column_stack([c * dx, -r * dy, F.reshape(-1)[ids]])
        return pos, inv.reshape(-1, 3).astype(np.int64)


def simplify_grid(F: F64, V: npt.NDArray[np.bool_], dx: float, dy: float, max_error: float, *,
                  params: ShapeParams | None = None, constrained: bool = True, locked: npt.ArrayLike | None = None,
                  target_triangles: int = 0, metric: str = "hausdorff") -> ModelMesh:
    """Detect shapes and simplify the grid under their constraints with a certified error.

    With ``metric="hausdorff"`` every accepted collapse is certified to keep the symmetric 3D Hausdorff
    distance between the mesh and the grid surface at most ``max_error`` (piece by piece over the overlay,
    :func:`citylod.lod.kernels.collapse.hausdorff_check`): walls between samples may be cut, as long as
    they stay within the bound in 3D. With ``metric="vertical"`` every collapse keeps
    ``max |T − F| ≤ max_error`` exactly (overlay vertices evaluated), which also bounds the Hausdorff
    distance but keeps a vertex on every step of a wall. ``constrained=False`` runs the same collapse with
    an empty shape map (QEM and the bound only), the ablation the shape rules are measured against.
    ``rejections`` of the result counts, per rule, the half-edges it rejected.

    Examples
    --------
    >>> import numpy as np
    >>> F = np.fromfunction(lambda r, c: 10.0 + 0.2 * c, (17, 17))  # one tilted plane
    >>> m = simplify_grid(F, np.ones_like(F, bool), 1.0, 1.0, 0.01)
    >>> len(m.faces) < 2 * 16 * 16, m.max_error
    (True, 0.01)
    """
    t0 = time.perf_counter()
    F = np.ascontiguousarray(np.where(V, F, 0.0), dtype=np.float64)
    V = np.ascontiguousarray(V, dtype=bool)
    sh = detect_shapes(F, V, dx, dy, params) if constrained else None
    smap = sh.shape_map if sh is not None else np.full((F.size, shapes.MAX_IDS), -1, np.int32)
    lk = np.zeros(F.size, bool) if locked is None else np.ascontiguousarray(np.asarray(locked, bool).reshape(-1))
    if metric not in ("hausdorff", "vertical"):
        raise ValueError(f"metric must be 'hausdorff' or 'vertical', got {metric!r}")
    stats = np.zeros(len(collapse.REJECT_NAMES), np.int64)
    faces, n = collapse.simplify(F, V, smap, lk, float(dx), float(dy), float(max_error), int(target_triangles),
                                 1 if metric == "hausdorff" else 0, stats)
    return ModelMesh(F.shape, faces, float(max_error), int(n), time.perf_counter() - t0, sh,
                     dict(zip(collapse.REJECT_NAMES, stats.tolist(), strict=True)), metric)


# ------------------------------------------------------------------------------------------ city objects
@dataclass
class Footprint:
    """One connected component above the ground: ``polygon`` a shapely Polygon in CRS metres,
    ``height`` metres above the ground, ``ground`` and ``top`` absolute, ``roof_planes`` (K, 4)."""

    polygon: Any
    ground: float
    height: float
    roof_planes: F64 = field(default_factory=lambda: np.zeros((0, 4)))


def ground_height(F: F64, V: npt.NDArray[np.bool_], spacing: float, window_m: float = 40.0) -> F64:
    """A bare-earth estimate: grey-scale opening of the DSM with a ``window_m`` square (scipy.ndimage),
    which removes every object narrower than the window; no-data filled from the nearest sample."""
    from scipy import ndimage

    if not V.any():
        return np.zeros_like(F)
    idx = ndimage.distance_transform_edt(~V, return_distances=False, return_indices=True)
    filled = F[tuple(idx)]
    size = max(3, int(round(window_m / spacing)) | 1)
    g = ndimage.grey_opening(filled, size=(size, size))
    return ndimage.uniform_filter(g, size=max(3, size // 4))


def split_roofs(F: F64, mask: npt.NDArray[np.bool_], roof_label: npt.NDArray[np.int32], roof_planes: F64,
                dx: float, dy: float, *, step: float = 1.0, parallel_deg: float = 10.0, offset: float = 0.3,
                attach: float = 1.5, meet: float = 1.5) -> npt.NDArray[np.int64]:
    """Cut a building mask into buildings along the roof: (H, W) int64 building per sample (0 none).

    Two roof planes that share a border belong to the same building when they meet at a ridge (convex:
    each plane, extended across the border, passes above the other's samples; and the two planes'
    heights at the border within ``meet`` m, so that they do meet there), or when they are nearly the
    same plane (normals within ``parallel_deg``, heights at the border within ``offset`` m: one roof that
    RANSAC cut in two). They belong to *different* buildings when nearly parallel but offset by more than
    ``offset`` (the slopes of terraced houses whose roofs are not flush) or when a height step over ``step``
    metres separates them (an annex, a neighbour of another height); a valley (concave) decides nothing,
    so the wings of an L-shaped roof still join through their hips. Each verdict is the majority of the
    sample pairs along the border. Joins are made longest border first with a union-find that refuses a
    join putting two separated planes into one building (otherwise one ridge shared along a row would
    glue every house back together).

    Samples of the mask on no plane (walls, chimneys, small dormers, roofs too small for a plane) take the
    building of the nearest plane sample in their connected part of the mask when within ``attach`` m of
    its height; the rest (a lower annex or garage next to a higher roof) are buildings of their own, one
    per connected part.
    """
    from scipy import ndimage

    H, W = F.shape
    K = len(roof_planes)
    lab = np.where(mask & (roof_label >= 0), roof_label, -1).astype(np.int64)
    # the samples along a ridge or a valley are often on neither plane (their one-sided normals fit
    # neither): planes are made to meet by giving mask samples next to a plane its label (not across a
    # step: a lower roof next to a wall stays apart)
    if K and (lab >= 0).any():
        dist, idx = ndimage.distance_transform_edt(lab < 0, return_indices=True)
        near_f = F[tuple(idx)]
        lab = np.where(mask & (lab < 0) & (dist <= 1.0) & (np.abs(near_f - F) <= step), lab[tuple(idx)], lab)
    parent = np.arange(K)
    apart: list[set[int]] = [set() for _ in range(K)]  # per root: the roots it must stay apart from

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    if K:
        rr, cc = np.mgrid[0:H, 0:W]
        n = roof_planes
        cos_par = math.cos(math.radians(parallel_deg))
        keys, joins, seps = [], [], []
        for a_sl, b_sl in (((slice(None), slice(0, W - 1)), (slice(None), slice(1, W))),
                           ((slice(0, H - 1), slice(None)), (slice(1, H), slice(None)))):
            la, lb = lab[a_sl], lab[b_sl]
            sel = (la >= 0) & (lb >= 0) & (la != lb)
            if not sel.any():
                continue
            i, j = la[sel], lb[sel]
            fa, fb = F[a_sl][sel], F[b_sl][sel]
            xa, ya = cc[a_sl][sel] * dx, -rr[a_sl][sel] * dy
            xb, yb = cc[b_sl][sel] * dx, -rr[b_sl][sel] * dy
            with np.errstate(divide="ignore", invalid="ignore"):
                zi_b = -(n[i, 0] * xb + n[i, 1] * yb + n[i, 3]) / n[i, 2]
                zj_a = -(n[j, 0] * xa + n[j, 1] * ya + n[j, 3]) / n[j, 2]
                zi_a = -(n[i, 0] * xa + n[i, 1] * ya + n[i, 3]) / n[i, 2]
                zj_b = -(n[j, 0] * xb + n[j, 1] * yb + n[j, 3]) / n[j, 2]
            parallel = np.abs(np.einsum("ij,ij->i", n[i, :3], n[j, :3])) >= cos_par
            gap = 0.5 * (np.abs(zi_a - zj_a) + np.abs(zi_b - zj_b))  # the two planes' heights apart, at the border
            convex = (zi_b - fb) + (zj_a - fa) > 0
            stepped = np.abs(fa - fb) > step
            flush = parallel & (gap <= offset)
            keys.append(np.minimum(i, j) * K + np.maximum(i, j))
            joins.append(np.where(parallel, flush, convex & (gap <= meet)) & ~stepped)
            seps.append(stepped | (parallel & ~flush))
        if keys:
            key = np.concatenate(keys)
            uk, inv = np.unique(key, return_inverse=True)
            tot = np.bincount(inv)
            join = np.bincount(inv, weights=np.concatenate(joins))
            sep = np.bincount(inv, weights=np.concatenate(seps))
            ok = tot >= 3
            for k in uk[ok & (sep > 0.5 * tot)]:
                a, b = int(k // K), int(k % K)
                apart[a].add(b)
                apart[b].add(a)
            cand = ok & (join > 0.5 * tot)
            for k in uk[cand][np.argsort(-tot[cand], kind="stable")]:
                pa, pb = find(int(k // K)), find(int(k % K))
                if pa == pb or pb in apart[pa]:
                    continue
                lo, hi = min(pa, pb), max(pa, pb)
                parent[hi] = lo
                apart[lo] |= apart[hi]
                for o in apart[hi]:
                    apart[o].discard(hi)
                    apart[o].add(lo)
    roots = np.array([find(i) for i in range(K)] or [0], np.int64)
    group = np.where(lab >= 0, roots[np.maximum(lab, 0)] + 1, 0)
    # samples on no plane: the nearest plane sample's building, within the same part of the mask and
    # within ``attach`` of its height
    parts, _ = ndimage.label(mask)
    idx = ndimage.distance_transform_edt(group == 0, return_distances=False, return_indices=True)
    near = group[tuple(idx)]
    same = (parts[tuple(idx)] == parts) & (np.abs(F[tuple(idx)] - F) <= attach)
    out = np.where(mask, np.where(group > 0, group, np.where(same & (near > 0), near, 0)), 0)
    # the rest: one building per connected part
    rest, _ = ndimage.label(mask & (out == 0))
    out = np.where(rest > 0, rest + K + 1, out)
    return out.astype(np.int64)


def merge_annexes(lab: npt.NDArray[np.int64], F: F64, *, step: float = 1.0, share: float = 0.3,
                  rounds: int = 3) -> npt.NDArray[np.int64]:
    """Join each building (``lab`` > 0) whose roof (90th percentile of ``F``) is more than ``step`` m below a
    neighbour's and which shares at least ``share`` of its outline with it to that neighbour: a lower back
    half, an annex or a porch belongs to the house it leans against (as a cadastral building does), where
    the roof split cut it off at the step. The neighbour with the longest shared border wins; ``rounds``
    passes follow chains (an annex of an annex). Returns the new labels (0 stays 0)."""

    for _ in range(rounds):
        uniq, inv = np.unique(lab, return_inverse=True)
        lab = (inv.reshape(lab.shape) + (0 if uniq[0] == 0 else 1)).astype(np.int64)
        n = int(lab.max())
        if n < 2:
            break
        # 90th percentile per building (nearest rank): samples sorted by building, then height
        flat, fz = lab.reshape(-1), F.reshape(-1)
        order = np.lexsort((fz, flat))
        cnt_l = np.bincount(flat, minlength=n + 1)
        start = np.concatenate([[0], np.cumsum(cnt_l)[:-1]])
        top = fz[order][np.minimum(start + (0.9 * np.maximum(cnt_l - 1, 0)).astype(np.int64), len(fz) - 1)]
        outline = np.zeros(n + 1)
        keys = []
        for a_sl, b_sl in (((slice(None), slice(0, -1)), (slice(None), slice(1, None))),
                           ((slice(0, -1), slice(None)), (slice(1, None), slice(None)))):
            la, lb = lab[a_sl], lab[b_sl]
            sel = la != lb
            outline += np.bincount(la[sel], minlength=n + 1) + np.bincount(lb[sel], minlength=n + 1)
            sel &= (la > 0) & (lb > 0)
            keys += [la[sel] * (n + 1) + lb[sel], lb[sel] * (n + 1) + la[sel]]
        if not keys:
            break
        uk, cnt = np.unique(np.concatenate(keys), return_counts=True)
        x, y = uk // (n + 1), uk % (n + 1)
        ok = (top[y] > top[x] + step) & (cnt >= share * outline[x])
        target = np.arange(n + 1)
        order = np.argsort(-cnt[ok], kind="stable")
        for xi, yi in zip(x[ok][order], y[ok][order], strict=True):
            if target[xi] == xi:
                target[xi] = yi
        if (target == np.arange(n + 1)).all():
            break
        for _ in range(8):
            target = target[target]
        lab = target[lab]
    return lab


def extract_buildings(F: F64, V: npt.NDArray[np.bool_], transform: tuple[float, ...], spacing: float,
                      roof_label: npt.NDArray[np.int32] | None = None, roof_planes: F64 | None = None, *,
                      min_height: float = 2.0, min_area: float = 12.0, min_planar: float = 0.5,
                      ground: F64 | None = None, classes: F64 | None = None, core: npt.NDArray[np.bool_] | None = None,
                      annex_share: float = 0.3, annex_step: float = 1.0) -> list[Footprint]:
    """Buildings standing ``min_height`` above the ground: footprints, heights, roof planes.

    The building samples are those classified as buildings (``classes`` == 6, the ASPRS class, where the
    raster carries the point classes) or else those whose roof planes cover ``min_planar`` of their
    connected part (tree crowns are rough and fail it; a tree touching a building is cut off by keeping only
    the planar samples, opened by one sample). They are cut into buildings along their roofs
    (:func:`split_roofs`: ridges join, valleys and steps separate, so terraced houses come apart); a
    building under ``min_area`` m² joins the neighbour it shares the longest border with, and a part more
    than ``annex_step`` m lower than a neighbour sharing ``annex_share`` of its outline joins it
    (:func:`merge_annexes`; 0 turns it off). Footprints are
    polygonised with rasterio (``rasterio.features.shapes``) and simplified by ¾ of the spacing (shapely).
    The height is the 90th percentile of the DSM over the footprint above the 10th percentile of the
    ground (3dfier's LoD1 defaults). ``ground`` defaults to a grey-scale opening of the DSM
    (:func:`ground_height`); ``transform`` is the affine (a, b, c, d, e, f) of the grid; only buildings
    whose first sample in raster order lies in ``core`` (default: all) are returned, so cells whose windows
    overlap report each building once.
    """
    from affine import Affine
    from rasterio import features
    from scipy import ndimage
    from shapely.geometry import shape as to_shape

    g = ground_height(F, V, spacing) if ground is None else ground
    above = V & (F - g > min_height)
    box3 = np.ones((3, 3), bool)
    if classes is not None:
        mask = above & (classes == 6)
        mask = ndimage.binary_closing(mask, structure=box3) & above
        mask = ndimage.binary_fill_holes(mask) & above
        mask = ndimage.binary_opening(mask, structure=box3)
    elif roof_label is not None:
        planar = above & (roof_label >= 0)
        planar = ndimage.binary_opening(planar, structure=box3)
        mask = ndimage.binary_closing(planar, structure=box3) & above
        parts, n = ndimage.label(mask)
        if n:
            share = ndimage.mean((roof_label >= 0).astype(float), parts, index=np.arange(1, n + 1))
            mask &= np.concatenate([[False], np.asarray(share) >= min_planar])[parts]
    else:
        mask = above
    out: list[Footprint] = []
    if not mask.any():
        return out
    if roof_label is not None and roof_planes is not None:
        a_, b_, _, d_, e_, _ = transform
        lab = split_roofs(F, mask, roof_label, roof_planes, math.hypot(a_, d_), math.hypot(b_, e_))
    else:
        lab = ndimage.label(mask)[0].astype(np.int64)
    # relabel 1..n, then merge buildings under min_area into the neighbour with the longest shared border
    uniq, inv = np.unique(lab, return_inverse=True)
    lab = inv.reshape(lab.shape) + (0 if uniq[0] == 0 else 1)
    n = int(lab.max())
    counts = np.bincount(lab.reshape(-1), minlength=n + 1)
    small = np.flatnonzero(counts * spacing * spacing < min_area)
    small = small[small > 0]
    if len(small):
        pairs = []
        for a_sl, b_sl in (((slice(None), slice(0, -1)), (slice(None), slice(1, None))),
                           ((slice(0, -1), slice(None)), (slice(1, None), slice(None)))):
            la, lb = lab[a_sl], lab[b_sl]
            sel = (la > 0) & (lb > 0) & (la != lb)
            pairs.append(np.column_stack([la[sel], lb[sel]]))
            pairs.append(np.column_stack([lb[sel], la[sel]]))
        pr = np.concatenate(pairs)
        target = np.arange(n + 1)
        for k in small[np.argsort(counts[small])]:
            nb = pr[pr[:, 0] == k, 1]
            nb = target[nb]
            nb = nb[nb != k]
            if len(nb):
                vals, cnt = np.unique(nb, return_counts=True)
                target[k] = vals[np.argmax(cnt)]
        for _ in range(4):  # chains of small parts
            target = target[target]
        lab = target[lab]
    if annex_share > 0:
        lab = merge_annexes(lab, F, step=annex_step, share=annex_share)
    aff = Affine(*transform)
    objs = ndimage.find_objects(lab)
    counts = np.bincount(lab.reshape(-1), minlength=len(objs) + 1)
    for k in range(1, len(objs) + 1):
        if objs[k - 1] is None or counts[k] * spacing * spacing < min_area:
            continue
        sl = objs[k - 1]
        m = lab[sl] == k
        if core is not None:  # reported by the cell that holds its first sample in raster order
            fr, fc = np.unravel_index(int(np.argmax(m)), m.shape)
            if not core[sl][fr, fc]:
                continue
        r0, c0 = sl[0].start, sl[1].start
        polys = [to_shape(geom) for geom, val in features.shapes(m.astype(np.uint8), mask=m,
                                                                  transform=aff @ Affine.translation(c0, r0))
                 if val == 1]
        if not polys:
            continue
        poly = max(polys, key=lambda p: p.area).simplify(spacing * 0.75, preserve_topology=True)
        if poly.is_empty or poly.area < min_area:
            continue
        ground_z = float(np.percentile(g[sl][m], 10))
        top = float(np.percentile(F[sl][m], 90))
        planes_here = np.zeros((0, 4))
        if roof_label is not None and roof_planes is not None and len(roof_planes):
            ids, cnt = np.unique(roof_label[sl][m], return_counts=True)
            keep = (ids >= 0) & (cnt * spacing * spacing >= 2.0)
            planes_here = roof_planes[ids[keep]]
        out.append(Footprint(poly, ground_z, top - ground_z, planes_here))
    return out


def write_cityjson(path: str | os.PathLike[str], footprints: list[Footprint], crs_epsg: int | None,
                   origin: tuple[float, float] = (0.0, 0.0)) -> Path:
    """Write footprints as CityJSON 2.0 Buildings: an LoD1 solid (footprint extruded from the ground to
    the measured height) with ``measuredHeight``, ``footprintArea`` and ``roofPlanes`` (normal and offset
    per plane, in metres of the CRS relative to ``origin``) as attributes. Atomic."""
    scale = 0.001
    verts: list[list[int]] = []
    objects: dict[str, Any] = {}
    for i, fp in enumerate(footprints):
        ring = np.asarray(fp.polygon.exterior.coords)[:-1]
        if fp.polygon.exterior.is_ccw is False:
            ring = ring[::-1]
        base = len(verts)
        k = len(ring)
        for z in (fp.ground, fp.ground + fp.height):
            verts += [[int(round(x / scale)), int(round(y / scale)), int(round(z / scale))] for x, y in ring]
        bottom = [[list(range(base + k - 1, base - 1, -1))]]
        top = [[list(range(base + k, base + 2 * k))]]
        walls = [[[base + j, base + (j + 1) % k, base + k + (j + 1) % k, base + k + j]] for j in range(k)]
        objects[f"model-{i}"] = {
            "type": "Building",
            "attributes": {"measuredHeight": round(fp.height, 3), "footprintArea": round(float(fp.polygon.area), 2),
                           "groundHeight": round(fp.ground, 3),
                           "roofPlanes": [[round(float(v), 6) for v in p] for p in fp.roof_planes]},
            "geometry": [{"type": "Solid", "lod": "1", "boundaries": [bottom + top + walls],
                          "semantics": {"surfaces": [{"type": "GroundSurface"}, {"type": "RoofSurface"},
                                                     {"type": "WallSurface"}],
                                        "values": [[0, 1] + [2] * k]}}],
        }
    doc: dict[str, Any] = {"type": "CityJSON", "version": "2.0",
                           "transform": {"scale": [scale] * 3, "translate": [0.0, 0.0, 0.0]},
                           "CityObjects": objects, "vertices": verts}
    if crs_epsg:
        doc["metadata"] = {"referenceSystem": f"https://www.opengis.net/def/crs/EPSG/0/{crs_epsg}"}
    _ = origin
    return atomic_write_text(path, json.dumps(doc, separators=(",", ":")))


# ------------------------------------------------------------------------------------------ point clouds
def rasterize_las(files: list[str | os.PathLike[str]], out_tif: str | os.PathLike[str], *, spacing: float = 0.5,
                  crs: str | None = None, fill_samples: int = 2) -> Path:
    """A DSM from LAS/LAZ files, with the point classes the model build uses where the files have them.

    Band 1 ``dsm``: the highest point per ``spacing`` cell (numpy binning of laspy chunks), noise classes
    (7, 18) dropped, empty cells filled from the nearest sample up to ``fill_samples`` away and no-data
    beyond. Band 2 ``ground``: the lowest ground point (class 2) per cell, every other cell filled from the
    nearest ground cell (a bare-earth model; no-data when the files have no ground class). Band 3
    ``class``: the class of the highest point per cell (no-data where the DSM is). Float32 GeoTIFF
    (rasterio), written atomically; readers of DSMs read band 1.
    """
    import laspy
    import rasterio
    from affine import Affine
    from scipy import ndimage

    from citylod.core.fileio import atomic_write
    from citylod.io.las import iter_points

    if not files:
        raise InputError("no point files given", out_tif)
    lo = np.array([np.inf, np.inf])
    hi = -lo
    wkt = None
    for f in files:
        try:
            with laspy.open(f) as r:
                lo = np.minimum(lo, r.header.mins[:2])
                hi = np.maximum(hi, r.header.maxs[:2])
                wkt = wkt or (r.header.parse_crs().to_wkt() if r.header.parse_crs() else None)
        except Exception as exc:  # laspy raises several types for unreadable files
            raise InputError(f"not a readable LAS/LAZ file ({exc})", f) from exc
    x0, y1 = math.floor(lo[0] / spacing) * spacing, math.ceil(hi[1] / spacing) * spacing
    W = int(math.ceil((hi[0] - x0) / spacing)) + 1
    H = int(math.ceil((y1 - lo[1]) / spacing)) + 1
    grid = np.full(H * W, -np.inf)
    low = np.full(H * W, np.inf)
    top_cls = np.zeros(H * W, np.float64)
    for f in files:
        for pts in iter_points(f, raw=True):
            cls = np.asarray(pts.classification)
            keep = (cls != 7) & (cls != 18)
            x, y, z = (np.asarray(a, np.float64)[keep] for a in (pts.x, pts.y, pts.z))
            cls = cls[keep]
            c = np.clip(((x - x0) / spacing).astype(np.int64), 0, W - 1)
            r = np.clip(((y1 - y) / spacing).astype(np.int64), 0, H - 1)
            k = r * W + c
            np.maximum.at(grid, k, z)
            g = cls == 2
            np.minimum.at(low, k[g], z[g])
            # the class of the highest point: points sorted by height, the last write per cell wins
            o = np.argsort(z, kind="stable")
            hit = z[o] >= grid[k[o]]
            top_cls[k[o][hit]] = cls[o][hit]
    grid2 = grid.reshape(H, W)
    empty = ~np.isfinite(grid2)
    dist, idx = ndimage.distance_transform_edt(empty, return_indices=True)
    dsm = grid2[tuple(idx)]
    cls2 = top_cls.reshape(H, W)[tuple(idx)]
    dsm[dist > fill_samples] = -9999.0
    cls2[dist > fill_samples] = -9999.0
    low2 = low.reshape(H, W)
    if np.isfinite(low2).any():
        gidx = ndimage.distance_transform_edt(~np.isfinite(low2), return_distances=False, return_indices=True)
        ground = ndimage.uniform_filter(low2[tuple(gidx)], size=3)
    else:
        ground = np.full((H, W), -9999.0)
    crs_out = crs or wkt
    if crs_out is None:
        raise InputError("the point files name no CRS; pass one", files[0])

    def write(tmp: Path) -> None:
        with rasterio.open(tmp, "w", driver="GTiff", width=W, height=H, count=3, dtype="float32", crs=crs_out,
                           transform=Affine(spacing, 0, x0, 0, -spacing, y1), nodata=-9999.0) as ds:
            for band, (name, arr) in enumerate((("dsm", dsm), ("ground", ground), ("class", cls2)), start=1):
                ds.write(arr.astype(np.float32), band)
                ds.set_band_description(band, name)

    return atomic_write(out_tif, write, suffix=".tif")


def _aux_bands(path: str | os.PathLike[str]) -> tuple[int, int]:
    """Band numbers of ``ground`` and ``class`` in a raster written by :func:`rasterize_las` (0: none)."""
    import rasterio

    with rasterio.open(path) as ds:
        names = [str(d or "").lower() for d in ds.descriptions]
    return ((names.index("ground") + 1) if "ground" in names else 0,
            (names.index("class") + 1) if "class" in names else 0)


# ------------------------------------------------------------------------------------------ the build
@dataclass
class ModelBuildReport:
    """What :func:`build_model` did."""

    output: Path
    cells: int
    samples: int
    triangles: int
    grid_triangles: int
    buildings: int
    max_error: float
    seconds: float
    heights: str = ""  # what the CRS leaves unsaid about the heights (no vertical datum), as in build dsm
    metric: str = "hausdorff"

    @property
    def vertices_per_second(self) -> float:
        return self.samples / max(self.seconds, 1e-9)

    def summary(self) -> str:
        return (f"model: {self.samples} samples in {self.cells} cells -> {self.triangles} triangles "
                f"({self.grid_triangles / max(self.triangles, 1):.1f}x fewer than the grid), certified "
                f"≤ {self.max_error:g} m ({self.metric}); {self.buildings} buildings; {self.seconds:.1f} s, "
                f"{self.vertices_per_second:,.0f} vertices/s -> {self.output}"
                + (f"\nheights: {self.heights}" if self.heights else ""))


def _cell_task(raster: str, r0: int, c0: int, cell: int, max_error: float, params: ShapeParams,
               out_dir: str, key: str, constrained: bool, ortho: str | None = None,
               metric: str = "hausdorff", aux: tuple[int, int] = (0, 0)) -> dict[str, Any]:
    """One cell: read its window (sharing the border row/column with the east/south neighbours), simplify
    with the border locked, write its glb (textured by the orthophoto projected from above when one is
    given), find its buildings. Returns the tile's description."""
    from citylod.io.raster import RasterSource
    from citylod.io.tiles3d.content import MeshData, TileContent
    from citylod.io.tiles3d.tileset import write_content

    src = RasterSource(raster)
    info = src.info
    nr = min(cell + 1, info.height - r0)
    nc = min(cell + 1, info.width - c0)
    F, V = src.read_window(r0, c0, nr, nc)
    if not V.any():  # nothing to mesh, no building to find
        return {"key": key, "samples": 0, "triangles": 0, "grid_triangles": 0, "seconds": 0.0, "content": None,
                "footprints": []}
    dx, dy = _spacing_xy(info)
    locked = np.zeros((nr, nc), bool)
    if r0 > 0:
        locked[0, :] = True
    if c0 > 0:
        locked[:, 0] = True
    if r0 + nr < info.height:
        locked[-1, :] = True
    if c0 + nc < info.width:
        locked[:, -1] = True
    mesh = simplify_grid(F, V, dx, dy, max_error, params=params, constrained=constrained, locked=locked,
                         metric=metric)
    res: dict[str, Any] = {"key": key, "samples": int(V.sum()), "triangles": len(mesh.faces),
                           "grid_triangles": int(collapse.grid_triangles(V).shape[0]), "seconds": mesh.seconds,
                           "content": None, "footprints": []}
    if len(mesh.faces) == 0:
        return res
    ids, inv = np.unique(mesh.faces, return_inverse=True)
    rr, cc = np.divmod(ids, nc)
    x, y = _world_xy(info, r0 + rr, c0 + cc)
    z = F.reshape(-1)[ids]
    pos = np.column_stack([x, y, z])
    lo, hi = pos.min(axis=0), pos.max(axis=0)
    center = 0.5 * (lo + hi)
    faces = inv.reshape(-1, 3)
    # counter-clockwise in (col, row) is clockwise seen from above (row grows southwards): flip for glTF
    faces = faces[:, ::-1]
    uv = texture = None
    if ortho is not None:
        from citylod.io.image import encode_image
        from citylod.io.raster import read_image_window

        # orthophoto projected from above: one texel per sample, uv from the horizontal position
        size = 1 << max(6, min(11, int(math.ceil(math.log2(max(nr, nc))))))
        img = read_image_window(ortho, (lo[0], lo[1], hi[0], hi[1]), info.metric_crs(), size)
        if img is not None:
            texture = encode_image(img, "jpg")
            span = np.maximum(hi[:2] - lo[:2], 1e-9)
            uv = np.column_stack([(x - lo[0]) / span[0], (hi[1] - y) / span[1]]).astype(np.float32)
    content = TileContent(meshes=[MeshData((pos - center).astype(np.float32), faces.astype(np.uint32), uv=uv,
                                           texture=texture)])
    res["content"] = write_content(out_dir, key, content)
    res.update(center=center.tolist(), lo=lo.tolist(), hi=hi.tolist())
    if constrained:
        res["footprints"] = _cell_buildings(src, r0, c0, cell, dx, dy, params, aux)
    return res


def _cell_buildings(src: Any, r0: int, c0: int, cell: int, dx: float, dy: float, params: ShapeParams,
                    aux: tuple[int, int], halo: int = 96) -> list[Footprint]:
    """The buildings a cell reports: found in its window grown by ``halo`` samples on every side (so a
    building across the cell border is seen whole when it fits), reported by the cell holding its first
    sample (:func:`extract_buildings`). The ground and the point classes come from the raster's ``ground``
    and ``class`` bands where it has them (:func:`rasterize_las`)."""
    from citylod.io.raster import RasterSource

    info = src.info
    rh0, ch0 = max(r0 - halo, 0), max(c0 - halo, 0)
    nr = min(r0 + cell + halo, info.height) - rh0
    nc = min(c0 + cell + halo, info.width) - ch0
    F, V = src.read_window(rh0, ch0, nr, nc)
    if not V.any():
        return []
    ground = classes = None
    if aux[0]:
        G, GV = RasterSource(src.path, band=aux[0]).read_window(rh0, ch0, nr, nc)
        ground = np.where(GV, G, np.where(V, F, 0.0)) if GV.any() else None
    if aux[1]:
        C, CV = RasterSource(src.path, band=aux[1]).read_window(rh0, ch0, nr, nc)
        classes = np.where(CV, C, 0.0)
    Fd = F
    if classes is not None:
        # a raster from points (it has their classes): the highest point per cell is noisy, so its roofs are
        # found on the 3×3 median with looser thresholds (measured on Delft AHN3, see
        # docs/PERFORMANCE_LOG.md)
        from dataclasses import replace

        from scipy import ndimage

        Fd = np.where(V, ndimage.median_filter(F, size=3), F)
        params = replace(params, roof_min_area=min(params.roof_min_area, 10.0),
                         roof_eps=max(params.roof_eps or 0.0, 0.3), roof_angle_deg=max(params.roof_angle_deg, 35.0))
    sh = detect_shapes(Fd, V, dx, dy, params, ground)
    core = np.zeros((nr, nc), bool)
    core[r0 - rh0: r0 - rh0 + cell, c0 - ch0: c0 - ch0 + cell] = True
    # with point classes a small blob of building points is a shed or a garage, not noise: 5 m² is enough
    return extract_buildings(F, V, _window_transform(info, rh0, ch0), 0.5 * (dx + dy), sh.roof_label, sh.roof_planes,
                             ground=ground, classes=classes, core=core, min_area=12.0 if classes is None else 5.0)


def _spacing_xy(info: Any) -> tuple[float, float]:
    a, b, _, d, e, _ = info.transform
    if not info.geographic:
        return float(math.hypot(a, d)), float(math.hypot(b, e))
    # degrees: the metric steps along a row and along a column at the raster's centre (they differ by the
    # cosine of the latitude), so that the 3D bound is measured in metres on both axes
    r, c = info.height // 2, info.width // 2
    x, y = _world_xy(info, np.array([r, r, r + 1]), np.array([c, c + 1, c]))
    return float(math.hypot(x[1] - x[0], y[1] - y[0])), float(math.hypot(x[2] - x[0], y[2] - y[0]))


def _world_xy(info: Any, rows: npt.ArrayLike, cols: npt.ArrayLike) -> tuple[F64, F64]:
    """Metric CRS coordinates of samples (projected to the metric CRS for geographic rasters, pyproj)."""
    x, y = info.sample_xy(rows, cols)
    if info.geographic:
        import pyproj

        tr = pyproj.Transformer.from_crs(info.crs, info.metric_crs(), always_xy=True)
        x, y = tr.transform(x, y)
    return np.asarray(x, np.float64), np.asarray(y, np.float64)


def _window_transform(info: Any, r0: int, c0: int) -> tuple[float, ...]:
    a, b, c, d, e, f = info.transform
    if info.geographic:  # footprints in the metric CRS: a local affine from three projected samples
        x0, y0 = _world_xy(info, np.array([r0 - 0.5, r0 - 0.5, r0 + 0.5]), np.array([c0 - 0.5, c0 + 0.5, c0 - 0.5]))
        return (x0[1] - x0[0], x0[2] - x0[0], x0[0], y0[1] - y0[0], y0[2] - y0[0], y0[0])
    return (a, b, a * c0 + b * r0 + c, d, e, d * c0 + e * r0 + f)


def build_model(raster: str | os.PathLike[str], out_dir: str | os.PathLike[str], *, max_error: float | None = None,
                cell: int = 512, params: ShapeParams | None = None, workers: int | None = None,
                scheduler: str | None = None, progress: bool = True, constrained: bool = True,
                ortho: str | os.PathLike[str] | None = None, metric: str = "hausdorff") -> ModelBuildReport:
    """Build the simplified city mesh of a DSM as 3D Tiles plus its buildings as CityJSON.

    Parameters
    ----------
    raster
        A DSM GDAL reads (projected or geographic).
    out_dir
        Folder to create: ``tileset.json``, ``tiles/*.glb`` and ``buildings.city.json``.
    max_error
        Certified bound in metres (default: the sample spacing) on the symmetric 3D Hausdorff distance
        between the mesh and the raster surface, or with ``metric="vertical"`` on the vertical distance.
    cell
        Samples per cell side; memory grows with ``cell²`` times the cells in flight.
    workers, scheduler
        As for :func:`citylod.lod.build.dsm.build_dsm`: local processes, or a Dask scheduler address.
    ortho
        Orthophoto (any CRS) to texture the mesh with, projected from above.

    Raises
    ------
    InputError
        Unreadable raster or no valid sample.
    """
    from citylod.io.crs import missing_vertical_datum
    from citylod.io.raster import RasterSource, check_has_data
    from citylod.io.tiles3d.tileset import TileSpec, write_tileset
    from citylod.lod.build.executor import make_executor, run_tasks

    t0 = time.perf_counter()
    src = RasterSource(raster)
    check_has_data(src)
    info = src.info
    if cell < 16:
        raise InputError(f"cell must be at least 16 samples, got {cell}", raster)
    dx, dy = _spacing_xy(info)
    eps = float(max_error) if max_error is not None else 0.5 * (dx + dy)
    p = (params or ShapeParams()).resolved(0.5 * (dx + dy))
    out = Path(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial", dir=out.parent))
    try:
        if ortho is not None and not Path(ortho).is_file():
            raise InputError("no such orthophoto", ortho)
        aux = _aux_bands(src.path)
        tasks = [(str(src.path), r0, c0, cell, eps, p, str(partial), f"{r0 // cell}_{c0 // cell}", constrained,
                  None if ortho is None else str(ortho), metric, aux)
                 for r0 in range(0, max(info.height - 1, 1), cell) for c0 in range(0, max(info.width - 1, 1), cell)]
        results = []
        with make_executor(workers, scheduler) as ex:
            results = list(run_tasks(ex, _cell_task, tasks, progress=progress, desc="model cells"))
        results.sort(key=lambda r: r["key"])
        children = [TileSpec(r["key"], 1, np.array(r["center"]), np.array(r["lo"]), np.array(r["hi"]), eps,
                             content=r["content"]) for r in results if r["content"]]
        if not children:
            raise InputError("the raster produced no triangles", raster)
        lo = np.min([c.lo for c in children], axis=0)
        hi = np.max([c.hi for c in children], axis=0)
        extent = float(np.linalg.norm(hi - lo))
        # the root has no content: drawing it instead of its children would show nothing, an error as large
        # as the whole box, so a client always refines it
        root = TileSpec("root", 0, 0.5 * (lo + hi), lo, hi, max(extent, 2 * eps), children=children)
        crs = info.metric_crs()
        write_tileset(partial, root, crs, extras={"citylod": {"kind": "model", "max_error_m": eps, "metric": metric}})
        fps = [fp for r in results for fp in r["footprints"]]
        write_cityjson(partial / "buildings.city.json", fps, crs.to_epsg())
        publish_dir(partial, out)
    finally:
        if partial.exists():
            import shutil

            shutil.rmtree(partial, ignore_errors=True)
    return ModelBuildReport(out, len(tasks), sum(r["samples"] for r in results), sum(r["triangles"] for r in results),
                            sum(r["grid_triangles"] for r in results), len(fps), eps, time.perf_counter() - t0,
                            heights=missing_vertical_datum(crs) or "", metric=metric)
