"""DSM raster → quadtree of bounded-error TIN tiles, written as 3D Tiles (Wahl et al., WSCG 2004).

The tile tree: leaves sit on the raster's own grid, ``tile_size`` samples a side (129 by default, 128 cells,
borders shared with neighbours); each coarser level covers 2×2 tiles of the level below on the same number
of samples (every second sample), so a level-d tile has a sample stride of ``2^(L−d)``. Each tile is one TIN
whose vertices lie on its grid (under the Hausdorff metric, a finer one: see below), simplified to a target
that doubles per level (the leaf target defaults to half the sample spacing).

The guarantee: every coarse tile's TIN is certified against the *full-resolution* raster, exactly, by
:mod:`citylod.lod.kernels.certify` (vertical L∞ at every sample and every crossing of a TIN edge with a grid edge),
after quantisation to float32. A leaf's grid is the raster itself, on which the TIN kernel already evaluates
that same exact distance for every face it keeps: its bound is the kernel's (the target) plus the float32
rounding of its heights, and only the faces stage 2 changes are certified (``certify_leaves`` certifies
whole leaves as well, for a measured value instead of a bound; it cost a third of a leaf's build). Where
a coarse tile's certificate exceeds the level's target, the builder forces the grid vertices of the
offending cells into the TIN and tries again; ``geometricError`` is the certified value plus
the horizontal quantisation error, so it is a true bound even where a coarse grid cannot reach its target
(a one-sample chimney cannot be represented on a grid of stride 16). This is provably conservative, which is
what the issue allows in place of Wahl's l−2 reference bookkeeping. A tile's footprint is read once, in one
window, when it holds up to ``_WHOLE_FOOTPRINT_SAMPLES`` samples (its grid and every certification are then
taken from memory), and in cached blocks otherwise, so memory does not grow with the raster.

The metric (``metric``). ``"vertical"`` certifies the vertical L∞ distance described above for every
level; with ``"hausdorff"`` a coarse tile's ``geometricError`` bounds the symmetric 3D Hausdorff distance
between the tile and the raster surface over its footprint (:mod:`citylod.lod.kernels.hausdorff`), which
charges a façade between two vertices about the horizontal offset of the slope that replaces it rather than
its height. Its TIN is built for that metric: on a grid of every full-resolution sample (up to 2049 a side;
coarser above, with grid heights raised or lowered to features narrower than its stride,
`_feature_heights`), the TIN kernel inserts and removes vertices by a 3D error (distances to the triangles
and to the grid surface, `citylod.lod.kernels.tin.build`'s ``plane``), so vertices sit at façade edges and on
tree tops wherever a sample is, and the coarsest tolerance whose certificate is within 1.5× the target is
kept. Its skirts are sized from the border's measured vertical error. Leaves keep the kernel's vertical
bound, which bounds Hausdorff too; geographic rasters are certified vertically.

Borders, in two stages. Stage 1 (:func:`build_tile`) chooses every tile's TIN. Its border vertices are the
1D simplification of the border samples (the same on both sides) plus the few the exact 2D bound or a
no-data boundary made the kernel add, which differ between neighbours. Stage 2 (:func:`finish_tile`) gives
each tile the vertices its same-level neighbours have on the shared border and it lacks, by splitting the
border edge they lie on into a fan (no re-triangulation, no other triangle changes), so both sides carry the
same border vertices wherever both have a surface; one round suffices, since a split adds vertices on that
border only. Every coarse tile is certified on its final TIN: in stage 1 (refinement is steered by the
certificate) and, where stage 2 changed it, again, on the faces it changed (the certificate is a maximum over
faces, and each face evaluates to the same numbers in any subset); a leaf's changed faces are certified in
stage 2, beside the kernel's bound for the others.

Skirts (Wahl 2004: "a triangle strip along the border that reaches down") hang from each tile's outer
border, except along the raster's own edges. Every border is linear between samples of its line, so its
vertical deviation from the raster line is measured exactly; stage 1 records it per side, and a tile's
skirt reaches its own deviation plus twice the largest of any tile across that line, at any level (stage
2's insertions at most double a border's deviation): where this tile's border is the higher one, that
closes the crack whatever neighbour a view selects (`_skirt_reach`). Skirt triangles are marked in the glb
and are not part of the certified surface.

Every tile is an independent task per stage (decision 5): it reads its own windows, so tasks run on worker
processes forked from the builder (the default where forking is safe), threads of the calling process
(the kernels release the GIL), spawned worker processes or a Dask cluster. Output goes to ``OUT.partial/`` and is renamed when complete; stage 1 journals
each tile's TIN and borders, stage 2 writes the glb and journals the tile's result
(:mod:`citylod.core.journal`: append-only files, one per thread, not a file per tile and stage), so an
interrupted build resumes without redoing either.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

from citylod.core import journal
from citylod.core.errors import GeoreferenceError, InputError
from citylod.core.fileio import discard_partial_on_refusal, publish_dir
from citylod.io.crs import missing_vertical_datum
from citylod.io.raster import RasterInfo, RasterSource, check_has_data, read_image_window
from citylod.io.tiles3d import MeshData, TileContent, TileSpec, write_content, write_tileset
from citylod.lod.kernels import aot
from citylod.lod.kernels.certify import certify, grid_error_lower_bound, skirt_strip
from citylod.lod.kernels.hausdorff import certify_hausdorff
from citylod.lod.kernels.octree import bounds as xyz_bounds

# Coarse levels may need several passes of "force the vertices of bad cells"; after this many the
# certified error is accepted as it is (and written as the tile's bound).
_MAX_REFINE_PASSES = 4
_REFINE_GAIN = 0.9  # a refinement pass is kept when it lowers the certified error by 10 % or more
# Default executor where workers cannot be forked: threads below this many raster samples, spawned worker
# processes above, where their start-up pays for itself (docs/PERFORMANCE_LOG.md has the measurements).
_THREADS_BELOW_SAMPLES = 6_000_000
# A coarse tile whose full grid misses its target by more than 2× is built at once at 0.8× the full grid's
# error when that TIN certifies within this factor of it (else the target-driven path runs).
_SHORTCUT_SLACK = 1.25
# Tile footprints up to this many full-resolution samples are read in one window and kept while the tile is
# built (2049² float64 heights + validity ≈ 38 MB); larger ones are read in cached blocks of _BLOCK cells.
_WHOLE_FOOTPRINT_SAMPLES = 2049 * 2049
_BLOCK = 1024
# Hausdorff metric: rings of raster cells searched around a piece for a closer part of the surface; the TIN
# kernel's 3D tolerances tried on a coarse tile, as fractions of its target, and the certificate (as a
# multiple of the target) that stops the search (see build_tile). The search starts at the target: a
# tile's certificate comes out 1.04–1.5× its tolerance on cities, so a tolerance above the target was never
# kept within _HAUSDORFF_ACCEPT and only cost a TIN and a certificate (docs/PERFORMANCE_LOG.md).
_HAUSDORFF_REACH = 12
_HAUSDORFF_TOLERANCES = (1.0, 0.5, 0.25)
_HAUSDORFF_ACCEPT = 1.5
# Hausdorff metric: a coarse tile's grid has up to this many times the lines of its level's, every
# full-resolution sample while the grid stays within 16·128 + 1 = 2049 samples a side (see _grid_stride).
_HAUSDORFF_REFINE = 16


# What a tileset's geometricError means, written into its citylod extras.
_METRIC_TEXT = {
    "hausdorff": "symmetric 3D Hausdorff distance vs full-resolution grid, certified upper bound (coarse tiles: "
                 "point-triangle distances at the vertices of the overlay pieces; leaves: exact vertical "
                 "L-infinity), plus float32 horizontal quantisation",
    "vertical": "vertical L-infinity vs full-resolution grid, exact (samples + edge crossings), "
                "plus float32 horizontal quantisation; bounds the symmetric Hausdorff distance",
}


@dataclass(frozen=True)
class DsmJob:
    """Everything a worker needs to build one tile (picklable)."""

    source: RasterSource
    out_dir: str
    level: int
    row: int
    col: int
    levels: int
    tile_size: int
    target: float
    ortho: str | None
    texture_size: int
    metric_crs_wkt: str
    # Stage 2 only: vertices the same-level neighbours have on a shared border and this tile lacks (grid
    # index along the side): side -> indices, sides "n" (row 0), "s" (last row), "w" (col 0), "e" (last col).
    border_extra: tuple[tuple[str, tuple[int, ...]], ...] = ()
    stage1: TileResult | None = None  # stage 2 only: this tile's stage-1 result
    stage1_tin: journal.Entry | None = None  # stage 2 only: where its stage-1 TIN is journalled
    certify_leaves: bool = False  # certify leaves against the raster too (see finish_tile)
    metric: str = "vertical"  # what geometricError bounds: "hausdorff" (3D, symmetric) or "vertical" (L∞)
    # Stage 2 only: per side, how far below the raster line any tile across that side (any level) may lie
    # along it (_skirt_reach); None where a neighbour's stage 1 did not record it (the old bound is used).
    skirt_reach: tuple[tuple[str, float], ...] | None = None


@dataclass
class TileResult:
    key: str
    level: int
    row: int
    col: int
    has_content: bool
    geometric_error: float = 0.0
    certified: float = 0.0
    target: float = 0.0
    quantisation: float = 0.0
    center: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    lo: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    hi: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    triangles: int = 0
    vertices: int = 0
    samples: int = 0
    seconds: float = 0.0
    passes: int = 0
    projection: float = 0.0
    borders: dict[str, list[int]] = field(default_factory=dict)
    # Leaves: the TIN kernel's bound on the tile's own (full-resolution) grid, NaN when it has none
    kernel_bound: float = math.nan
    # Stage 1: max |TIN − raster| along each side's line ("n", "s", "w", "e"; see _border_deviations), and the
    # full-resolution rows and columns of the sides [first row, last row, first column, last column]: what
    # the neighbours' skirts are sized from (_skirt_reach).
    border_dev: dict[str, float] = field(default_factory=dict)
    box: list[int] = field(default_factory=list)


@dataclass
class DsmBuildReport:
    """What a build did: per-level counts and errors, time and memory."""

    output: str
    raster: str
    width: int
    height: int
    levels: int
    tiles: int
    seconds: float
    samples_per_s: float
    peak_rss_mb: float
    leaf_target: float
    per_level: list[dict[str, Any]]
    resumed: int = 0
    executor: str = ""  # where the tiles were built: "inline", "threads", "forked processes", ...
    kernels: str = ""  # "compiled-ahead" (citylod.lod.kernels.aot) or "JIT"
    heights: str = ""  # what the CRS leaves unsaid about the heights (no vertical datum), for the summary

    def summary(self) -> str:
        lines = [f"{self.output}: {self.tiles} tiles on {self.levels} levels from {self.width}×{self.height} "
                 f"samples in {self.seconds:.1f} s{f' on {self.executor}' if self.executor else ''}"
                 f"{f' ({self.kernels} kernels)' if self.kernels else ''} "
                 f"({self.samples_per_s / 1e6:.2f} M samples/s, "
                 f"peak {self.peak_rss_mb:.0f} MB){f', {self.resumed} tiles resumed' if self.resumed else ''}"]
        lines.append("level  tiles   triangles   target_m   max_error_m")
        for lv in self.per_level:
            lines.append(f"{lv['level']:5d} {lv['tiles']:6d} {lv['triangles']:11d} {lv['target']:10.3f} "
                         f"{lv['max_error']:13.3f}")
        if self.heights:
            lines.append(f"heights: {self.heights}")
        return "\n".join(lines)


def _triangulate(heights: np.ndarray, valid: np.ndarray, max_error: float,
                 must_include: np.ndarray | None, lattice: bool = False,
                 plane: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """The TIN kernel's vertices, faces and number of triangles it left above ``max_error`` (0 but for a bug).
    ``lattice``: seeded on `citylod.lod.kernels.tin.SEED_LATTICE` too (coarse tiles whose target is out of reach).
    ``plane``: the grid's metric spacing, for the kernel's 3D error (Hausdorff metric)."""
    from citylod.lod.kernels.tin import SEED_LATTICE, build

    r = build(heights, valid, max_error, must_include=must_include, lattice=SEED_LATTICE if lattice else 0,
              plane=plane)
    return r.vertices_ij, r.faces, r.stuck


def _grid_positions(start: int, count: int, stride: int, limit: int) -> tuple[np.ndarray, np.ndarray]:
    """Full-resolution indices of a tile's grid lines along one axis, and which exist.

    Positions past the raster's last sample are clamped onto it once (so coarse tiles reach the raster's
    edge even when its size is not a multiple of the stride); later ones do not exist.
    """
    pos = start + stride * np.arange(count)
    exists = pos <= limit
    over = np.flatnonzero(pos > limit)
    if len(over) and (over[0] == 0 or pos[over[0] - 1] < limit):
        pos[over[0]] = limit
        exists[over[0]] = True
    return np.minimum(pos, limit), exists


def _tile_grid(job: DsmJob) -> tuple[int, np.ndarray, np.ndarray] | None:
    """(stride, full-resolution rows, full-resolution columns) of a tile's grid lines; None when it is
    outside the raster. Tiles at the raster's far edges are cropped to the grid lines that exist rather
    than padded with no-data: the TIN kernel forces every sample on a no-data boundary, which would waste
    triangles."""
    info = job.source.info
    cells = job.tile_size - 1
    stride = 2 ** (job.levels - job.level)
    g = _grid_stride(job)
    n = cells * (stride // g) + 1
    rpos, rex = _grid_positions(job.row * cells * stride, n, g, info.height - 1)
    cpos, cex = _grid_positions(job.col * cells * stride, n, g, info.width - 1)
    if not rex.any() or not cex.any():
        return None
    return g, rpos[rex], cpos[cex]


def _grid_stride(job: DsmJob) -> int:
    """Full-resolution samples between a tile's grid lines: its level's stride, or under the Hausdorff metric
    ``_HAUSDORFF_REFINE`` times fewer, so that a coarse TIN's vertices can sit next to a façade or on a tree
    rather than up to a stride away (a façade between two vertices becomes a slope as wide as their
    distance, which the Hausdorff distance charges)."""
    stride = 2 ** (job.levels - job.level)
    if job.metric == "hausdorff" and stride > 1 and not job.source.info.geographic:
        return max(1, stride // _HAUSDORFF_REFINE)
    return stride


class _Footprint:
    """The full-resolution samples under one tile, for its grid and its certification.

    A footprint of up to ``_WHOLE_FOOTPRINT_SAMPLES`` is read in one window, once, and both the tile's
    (strided) grid and the certifier's blocks are views of it; a larger one (the coarsest levels of a large
    raster) is read in blocks of ``_BLOCK`` cells, a few of which are kept, so memory stays bounded whatever
    the raster's size.
    """

    def __init__(self, src: RasterSource, rpos: np.ndarray, cpos: np.ndarray) -> None:
        self.src, self.rpos, self.cpos = src, rpos, cpos
        self.footprint = (int(rpos[0]), int(cpos[0]), int(rpos[-1]), int(cpos[-1]))
        r0, c0, r1, c1 = self.footprint
        self.shape = (r1 - r0 + 1, c1 - c0 + 1)
        self.whole = self.shape[0] * self.shape[1] <= _WHOLE_FOOTPRINT_SAMPLES
        # the certifier's block size: the whole footprint in one block when it is in memory
        self.block = max(self.shape[0], self.shape[1], 2) if self.whole else _BLOCK
        self._all: tuple[np.ndarray, np.ndarray] | None = None
        self._blocks: dict[tuple[int, int, int, int], tuple[np.ndarray, np.ndarray]] = {}
        self._grid: tuple[np.ndarray, np.ndarray] | None = None

    def read_block(self, r: int, c: int, nr: int, nc: int) -> tuple[np.ndarray, np.ndarray]:
        """Full-resolution heights and validity of rows r..r+nr−1 × columns c..c+nc−1 (inside the footprint)."""
        r0, c0, _, _ = self.footprint
        if self.whole:
            if self._all is None:
                self._all = self.src.read_window(r0, c0, *self.shape)
            h, v = self._all
            if (r, c, nr, nc) == (r0, c0, *self.shape):
                return h, v
            sl = (slice(r - r0, r - r0 + nr), slice(c - c0, c - c0 + nc))
            return np.ascontiguousarray(h[sl]), np.ascontiguousarray(v[sl])
        k = (r, c, nr, nc)
        if k not in self._blocks:
            if len(self._blocks) >= 8:  # 8 blocks of 1025² ≈ 75 MB at most
                self._blocks.pop(next(iter(self._blocks)))
            self._blocks[k] = self.src.read_window(r, c, nr, nc)
        return self._blocks[k]

    def grid(self) -> tuple[np.ndarray, np.ndarray]:
        """Heights and validity at the tile's grid lines (rows ``rpos`` × columns ``cpos``)."""
        if self._grid is not None:
            return self._grid
        r0, c0, r1, c1 = self.footprint
        if self.whole:
            h, v = self.read_block(r0, c0, *self.shape)
            if len(self.rpos) == self.shape[0] and len(self.cpos) == self.shape[1]:
                self._grid = (h, v)  # every sample of the footprint (a leaf): the grid is the block itself
            else:
                ix = np.ix_(self.rpos - r0, self.cpos - c0)
                self._grid = (h[ix], v[ix])
            return self._grid
        heights = np.zeros((len(self.rpos), len(self.cpos)))
        valid = np.zeros((len(self.rpos), len(self.cpos)), bool)
        # the same blocks the certifier reads (overlapping by one sample), so they are read once
        for br in range(r0, max(r1, r0 + 1), _BLOCK):
            nr = min(_BLOCK + 1, r1 - br + 1)
            ri = np.flatnonzero((self.rpos >= br) & (self.rpos < br + nr))
            for bc in range(c0, max(c1, c0 + 1), _BLOCK):
                nc = min(_BLOCK + 1, c1 - bc + 1)
                ci = np.flatnonzero((self.cpos >= bc) & (self.cpos < bc + nc))
                if len(ri) == 0 or len(ci) == 0:
                    continue
                h, v = self.read_block(br, bc, nr, nc)
                ix = np.ix_(self.rpos[ri] - br, self.cpos[ci] - bc)
                heights[np.ix_(ri, ci)] = h[ix]
                valid[np.ix_(ri, ci)] = v[ix]
        self._grid = (heights, valid)
        return self._grid


def _to_metric(info: RasterInfo, job: DsmJob) -> pyproj.Transformer | None:
    """Geographic rasters: vertical errors are metres already; vertices are projected afterwards."""
    if not info.geographic:
        return None
    return pyproj.Transformer.from_crs(info.crs, pyproj.CRS.from_wkt(job.metric_crs_wkt), always_xy=True)


def _place(info: RasterInfo, to_metric: pyproj.Transformer | None, rpos: np.ndarray, cpos: np.ndarray,
           vij: np.ndarray, vz: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, np.ndarray, np.ndarray, np.ndarray]:
    """Vertex positions as written (float32 around a centre) and what certification needs.

    Returns local (V, 3) float32, centre (3,), the horizontal quantisation error, and the vertices' full-
    resolution rows, columns and quantised heights.
    """
    vr = rpos[vij[:, 0]].astype(np.float64)
    vc = cpos[vij[:, 1]].astype(np.float64)
    x, y = info.sample_xy(vr, vc)
    if to_metric is not None:
        x, y = to_metric.transform(x, y)
    xyz = np.column_stack([x, y, vz])
    lo, hi = xyz_bounds(xyz) if len(xyz) else (xyz.min(axis=0), xyz.max(axis=0))
    center = 0.5 * (lo + hi)
    local = (xyz - center).astype(np.float32)
    back = local.astype(np.float64) + center
    q_xy = float(np.max(np.hypot(back[:, 0] - xyz[:, 0], back[:, 1] - xyz[:, 1]), initial=0.0))
    return local, center, q_xy, vr, vc, back[:, 2]


def _certify(fp: _Footprint, vr: np.ndarray, vc: np.ndarray, zq: np.ndarray, faces: np.ndarray, cells: int,
             stride: int, per_cell: bool = False, hausdorff: tuple[float, float, float, float] | None = None,
             floor: float = 0.0, evaluate: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """The TIN's certified error (quantised heights) against the full-resolution footprint, and per cell
    (zeros unless ``per_cell``): exact vertical L∞, or with ``hausdorff`` (the raster's affine, see
    `citylod.lod.kernels.hausdorff.certify_hausdorff`) a bound of the symmetric 3D Hausdorff distance, pieces
    under ``floor`` kept at their vertical bound (only the pieces of the ``evaluate`` faces, if given)."""
    if hausdorff is not None:
        err, cell_err, _ = certify_hausdorff(fp.read_block, fp.footprint, vr, vc, zq, faces.astype(np.int64),
                                             (cells, cells), stride, hausdorff, block=fp.block, per_cell=per_cell,
                                             floor=floor, reach=_HAUSDORFF_REACH, evaluate=evaluate)
        return err, cell_err
    err, cell_err, _ = certify(fp.read_block, fp.footprint, vr, vc, zq, faces.astype(np.int64), (cells, cells),
                               stride, block=fp.block, per_cell=per_cell)
    return err, cell_err


def _hausdorff_affine(info: RasterInfo, job: DsmJob) -> tuple[float, float, float, float] | None:
    """The raster's affine without offsets when ``job`` certifies the Hausdorff distance, else None.

    Geographic rasters keep the vertical metric: their samples are not an affine image of rows and
    columns in the metric CRS, and the vertical bound (plus the projection term) bounds Hausdorff too.
    """
    if job.metric != "hausdorff" or info.geographic:
        return None
    a, b, _, d, e, _ = info.transform[:6]
    return float(a), float(b), float(d), float(e)


def _feature_heights(fp: _Footprint, heights: np.ndarray, valid: np.ndarray, stride: int,
                     target: float) -> np.ndarray:
    """Grid heights for the Hausdorff metric: an interior grid vertex near a feature narrower than the stride
    (a tree, a chimney, a one-sample trench) that the grid G misses by more than ``target`` takes that
    feature's height.

    Every full-resolution sample lies within half a stride (per axis) of a grid vertex; where the samples in
    that window rise above (sink below) G by more than ``target``, the vertex is raised (lowered) by the
    largest such residual, so the TIN reaches the feature within half a stride horizontally instead of
    passing over (under) it at its full height. Border vertices keep their samples, so neighbours still
    share their border heights. Only a better candidate surface: the certificate decides.
    """
    from scipy.ndimage import maximum_filter, minimum_filter

    rpos, cpos = fp.rpos, fp.cpos
    nr, nc = heights.shape
    if nr < 3 or nc < 3:
        return heights
    up = np.full((nr, nc), -np.inf)
    down = np.full((nr, nc), np.inf)
    top = np.full((nr, nc), -np.inf)
    bottom = np.full((nr, nc), np.inf)
    r0, c0, r1, c1 = fp.footprint
    size = 2 * (stride // 2) + 1
    for br in range(r0, max(r1, r0 + 1), fp.block):
        for bc in range(c0, max(c1, c0 + 1), fp.block):
            bh, bw = min(fp.block + 1, r1 - br + 1), min(fp.block + 1, c1 - bc + 1)
            f, v = fp.read_block(br, bc, bh, bw)
            rows, cols = np.arange(br, br + bh), np.arange(bc, bc + bw)
            a = np.clip(np.searchsorted(rpos, rows, "right") - 1, 0, nr - 2)
            b = np.clip(np.searchsorted(cpos, cols, "right") - 1, 0, nc - 2)
            u = ((rows - rpos[a]) / (rpos[a + 1] - rpos[a]))[:, None]
            w = ((cols - cpos[b]) / (cpos[b + 1] - cpos[b]))[None, :]
            z00, z01 = heights[np.ix_(a, b)], heights[np.ix_(a, b + 1)]
            z10, z11 = heights[np.ix_(a + 1, b)], heights[np.ix_(a + 1, b + 1)]
            g = np.where(u >= w, z00 + u * (z10 - z00) + w * (z11 - z10), z00 + w * (z01 - z00) + u * (z11 - z01))
            ok = v & valid[np.ix_(a, b)] & valid[np.ix_(a, b + 1)] & valid[np.ix_(a + 1, b)] & valid[np.ix_(a + 1, b + 1)]
            res = f - g
            hi = maximum_filter(np.where(ok, res, -np.inf), size=size, mode="constant", cval=-np.inf)
            lo = minimum_filter(np.where(ok, res, np.inf), size=size, mode="constant", cval=np.inf)
            ri = np.flatnonzero((rpos >= br) & (rpos < br + bh))
            ci = np.flatnonzero((cpos >= bc) & (cpos < bc + bw))
            ix = np.ix_(ri, ci)
            sub = np.ix_(rpos[ri] - br, cpos[ci] - bc)
            up[ix] = np.maximum(up[ix], hi[sub])
            down[ix] = np.minimum(down[ix], lo[sub])
            fmax = maximum_filter(np.where(ok, f, -np.inf), size=size, mode="constant", cval=-np.inf)
            fmin = minimum_filter(np.where(ok, f, np.inf), size=size, mode="constant", cval=np.inf)
            top[ix] = np.maximum(top[ix], fmax[sub])
            bottom[ix] = np.minimum(bottom[ix], fmin[sub])
    # Only features the grid misses: a vertex is raised when it and its eight grid neighbours all lie more
    # than ``target`` below the window's top (a tree or chimney between them), lowered likewise (a trench);
    # never beyond the heights the window holds. A vertex beside a façade has a neighbour on the other side
    # and stays where it is (moving it would delete a building whose only grid vertex it is).
    hv = np.where(valid, heights, np.nan)
    nmax = maximum_filter(np.where(valid, heights, -np.inf), size=3, mode="nearest")
    nmin = minimum_filter(np.where(valid, heights, np.inf), size=3, mode="nearest")
    can_up = (up > target) & (nmax < top - target)
    can_down = (-down > target) & (nmin > bottom + target)
    raised = np.minimum(hv + up, top)
    lowered = np.maximum(hv + down, bottom)
    out = np.where(can_up & (~can_down | (up >= -down)), raised, np.where(can_down, lowered, hv))
    keep = ~np.isfinite(out) | ~(can_up | can_down) | ~valid
    keep[[0, -1], :] = True
    keep[:, [0, -1]] = True
    return np.where(keep, heights, out)


def _fixed_cell(cell: tuple[int, int], vij: np.ndarray, must: np.ndarray | None, last_r: int, last_c: int) -> bool:
    """Whether the next refinement pass is sure to triangulate this level cell exactly as now.

    It forces the interior corners of bad cells; when all four corners of the worst cell are vertices
    already and each is either interior (forced again) or in ``must``, the cell's triangles are the grid's
    own two (a unit square whose corners are all vertices is triangulated by its edges and the grid's
    diagonal: see :mod:`citylod.lod.kernels.tin`), so the worst error stays where it is and the pass cannot help.
    """
    i, j = cell
    for r, c in ((i, j), (i, j + 1), (i + 1, j), (i + 1, j + 1)):
        if not np.any((vij[:, 0] == r) & (vij[:, 1] == c)):
            return False
        if not (0 < r < last_r and 0 < c < last_c) and (
                must is None or not np.any((must[:, 0] == r) & (must[:, 1] == c))):
            return False
    return True


def _refit(heights: np.ndarray, valid: np.ndarray, vij: np.ndarray, tol: float, last_r: int,
           last_c: int) -> tuple[np.ndarray, np.ndarray] | None:
    """A TIN within ``tol`` on the tile's grid that keeps every vertex of ``vij`` and has exactly its border
    vertices, or None when the kernel needed another border vertex."""
    v2, f2, _ = _triangulate(heights, valid, tol, np.ascontiguousarray(vij, dtype=np.int32))
    if len(f2) == 0 or _border_sets(v2, last_r, last_c) != _border_sets(vij, last_r, last_c):
        return None
    return v2, f2


def _grid_cell_error(fp: _Footprint, rpos: np.ndarray, cpos: np.ndarray, heights: np.ndarray, i: int, j: int,
                     cells: int, stride: int) -> float:
    """Exact vertical L∞ of level cell (i, j) triangulated as the grid (diagonal (i, j)–(i+1, j+1))."""
    vr = rpos[[i, i, i + 1, i + 1]].astype(np.float64)
    vc = cpos[[j, j + 1, j, j + 1]].astype(np.float64)
    vz = heights[[i, i, i + 1, i + 1], [j, j + 1, j, j + 1]]
    err, _ = _certify(fp, vr, vc, vz, np.array([[0, 3, 2], [0, 1, 3]]), cells, stride)
    return err


def build_tile(job: DsmJob) -> TileResult:
    """Stage 1 of a tile, on a worker: read its grid and choose its TIN.

    Leaves are triangulated once (the kernel's bound is exact on their own grid, and is recorded as the leaf's
    ``kernel_bound`` unless the kernel left a triangle above it; :func:`finish_tile` certifies the faces it
    changes, or the whole leaf without that bound or with ``certify_leaves``). Coarser tiles are certified here, because refinement is
    steered by where the certificate is exceeded. The TIN is journalled with its stage-1 result (border vertices,
    certificate), so the build resumes from it.
    """
    t0 = time.perf_counter()
    src, info = job.source, job.source.info
    cells = job.tile_size - 1
    key = f"{job.level}/{job.row}/{job.col}"
    res = TileResult(key, job.level, job.row, job.col, False, target=job.target)
    g = _tile_grid(job)
    if g is None:
        _journal_result(job.out_dir, key, res)
        return res
    stride, rpos, cpos = g  # the grid's stride (finer than the level's under the Hausdorff metric)
    cells *= 2 ** (job.levels - job.level) // stride
    is_coarse = job.level < job.levels
    fp = _Footprint(src, rpos, cpos)
    heights, valid = fp.grid()
    last_r, last_c = len(rpos) - 1, len(cpos) - 1
    if valid.sum() < 3:
        _journal_result(job.out_dir, key, res)
        return res
    to_metric = _to_metric(info, job)

    stuck = 0

    def attempt(tol: float, must: np.ndarray | None, check: bool = True, lattice: bool = False,
                per_cell: bool = True) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        nonlocal stuck
        vij, faces, stuck = _triangulate(heights, valid, tol, must, lattice, plane)
        vz = heights[vij[:, 0], vij[:, 1]]
        if len(faces) == 0 or not check:
            return math.nan, vij, faces, vz, np.zeros((cells, cells))
        _, _, _, vr, vc, zq = _place(info, to_metric, rpos, cpos, vij, vz)
        err, cell_err = _certify(fp, vr, vc, zq, faces, cells, stride, per_cell=per_cell, hausdorff=haus,
                                 floor=0.5 * job.target)
        return err, vij, faces, vz, cell_err

    haus = _hausdorff_affine(info, job) if is_coarse else None
    plane = None
    if haus is not None:
        plane = (math.hypot(haus[0], haus[2]) * stride, math.hypot(haus[1], haus[3]) * stride)
        if stride > 1:  # a grid of every sample misses no feature narrower than its stride
            heights = _feature_heights(fp, heights, valid, stride, job.target)
        # The TIN kernel simplifies the tile's grid G (every full-resolution sample, up to 2049 a side) within
        # a 3D tolerance (`citylod.lod.kernels.tin.build`'s ``plane``: distances to the triangles and to the
        # grid surface, not vertical ones), so vertices sit at façade edges and on tree tops and a façade
        # costs its slope's offset, not its height. That measure is a guide, not a bound: the certificate
        # decides. The coarsest tolerance whose certificate is within _HAUSDORFF_ACCEPT × the target is
        # kept (the issue allows 1.5× per level; a level's count of triangles falls with its tolerance); a
        # finer one only when it lowers the certificate clearly. Lattice seeds spare the kernel the rescans of
        # large triangles at about the same triangles (docs/PERFORMANCE_LOG.md).
        kept = None
        for frac in _HAUSDORFF_TOLERANCES:
            trial = attempt(frac * job.target, None, per_cell=False, lattice=True)
            if len(trial[2]) == 0:
                break
            if kept is not None and trial[0] >= kept[0] * _REFINE_GAIN:
                break
            kept = trial
            if trial[0] <= _HAUSDORFF_ACCEPT * job.target:
                break
        if kept is None:
            _journal_result(job.out_dir, key, res)
            return res
        return _stage1_done(job, res, key, kept, 1, valid, stride, last_r, last_c, t0, fp)
    if stride > 1:
        full = grid_error_lower_bound(fp.read_block, fp.footprint, rpos, cpos, heights, valid, block=fp.block)
        if full > 2.0 * job.target:
            # Out of reach on this grid (a façade between its samples): even every sample as a vertex
            # certifies at ``full`` or more. A TIN at a tolerance of 0.8·full is as good wherever a bound of
            # ``full`` lets it be drawn, and costs a fraction of the triangles and time of one aimed at the
            # target (on the 2049² city, level 3: 19 k triangles at 20.4 m against 347 k at 20.2 m).
            # Its borders stay simplified at the target, as the target-driven path leaves them: a much
            # coarser border would open cracks that the finer neighbours' skirts (2× their own error)
            # do not cover.
            quick = attempt(0.8 * full, _border_vertices(heights, valid, job.target), per_cell=False, lattice=True)
            if len(quick[2]) and quick[0] <= full * _SHORTCUT_SLACK:
                return _stage1_done(job, res, key, quick, 1, valid, stride, last_r, last_c, t0, fp)
    best = attempt(job.target, None, check=stride > 1)
    if len(best[2]) == 0:
        _journal_result(job.out_dir, key, res)
        return res
    if stride == 1 and stuck == 0:
        res.kernel_bound = job.target
    cell_err = best[4]
    passes = 1
    must: np.ndarray | None = None
    tol = job.target
    while passes < _MAX_REFINE_PASSES and best[0] > job.target and stride > 1:
        wi, wj = (int(w) for w in np.unravel_index(int(np.argmax(cell_err)), cell_err.shape))
        if _fixed_cell((wi, wj), best[1], must, last_r, last_c):
            break  # the outcome is known: the pass below would find no lower error and be dropped
        if (0 < wi and wi + 1 < last_r and 0 < wj and wj + 1 < last_c and valid[wi:wi + 2, wj:wj + 2].all()
                and _grid_cell_error(fp, rpos, cpos, heights, wi, wj, cells, stride) >= 0.98 * best[0] + 1e-3):
            # The pass would force the worst cell's four (interior) corners, which triangulates it as the
            # grid does; that alone keeps the error above what the pass must beat. Known outcome: skip it.
            break
        bad = np.argwhere(cell_err > job.target)
        # Force the grid corners of offending interior cells; border vertices stay as the border
        # simplification chose them (neighbours are reconciled in stage 2).
        corners = np.concatenate([bad, bad + [0, 1], bad + [1, 0], bad + [1, 1]])
        interior = (corners[:, 0] > 0) & (corners[:, 0] < last_r) & (corners[:, 1] > 0) & (corners[:, 1] < last_c)
        corners = corners[interior]
        corners = corners[valid[corners[:, 0], corners[:, 1]]]
        new = _unique_ij(np.concatenate([corners, must]) if must is not None else corners, last_c + 1)
        if must is not None and len(new) == len(must):
            break
        must = new.astype(np.int32)
        tol *= 0.5
        passes += 1
        trial = attempt(tol, must)
        cell_err = trial[4]
        # Forcing vertices only pays when it lowers the certified error clearly: façades between the
        # samples of a coarse grid cannot be fixed on that grid, and a 2 % gain measured 3.8× the triangles.
        if trial[0] >= best[0] * _REFINE_GAIN:
            break
        best = trial
    if best[0] > 2.0 * job.target and stride > 1:
        # The target is out of reach on this grid; the tile's bound is best[0] wherever it is shown, so a
        # TIN that stays under that bound everywhere looks the same at the distances where it is drawn.
        coarse = attempt(0.8 * best[0], None, per_cell=False, lattice=True)  # only its maximum is looked at
        if len(coarse[2]) and coarse[0] <= best[0] and len(coarse[2]) < len(best[2]):
            best = coarse
    return _stage1_done(job, res, key, best, passes, valid, stride, last_r, last_c, t0, fp)


def _border_vertices(heights: np.ndarray, valid: np.ndarray, tol: float) -> np.ndarray:
    """(K, 2) int32 grid indices of the four borders, each simplified as a polyline within ``tol``."""
    from citylod.lod.kernels.tin import simplify_polyline

    nr, nc = heights.shape
    out = []
    for fixed, along_rows in ((0, False), (nr - 1, False), (0, True), (nc - 1, True)):
        z, v = (heights[:, fixed], valid[:, fixed]) if along_rows else (heights[fixed], valid[fixed])
        k = simplify_polyline(z, tol, valid=v)
        out.append(np.column_stack([k, np.full_like(k, fixed)]) if along_rows
                   else np.column_stack([np.full_like(k, fixed), k]))
    return _unique_ij(np.concatenate(out), nc).astype(np.int32)


def _stage1_done(job: DsmJob, res: TileResult, key: str, best: tuple[float, np.ndarray, np.ndarray, np.ndarray,
                                                                      np.ndarray],
                 passes: int, valid: np.ndarray, stride: int, last_r: int, last_c: int, t0: float,
                 fp: _Footprint) -> TileResult:
    err, vij, faces, vz, _ = best
    res.has_content = True
    res.passes = passes
    res.certified = err
    res.samples = int(valid.sum()) * stride * stride
    res.borders = _border_sets(vij, last_r, last_c)
    rpos, cpos = fp.rpos, fp.cpos
    res.border_dev = {side: d for side, (d, _) in
                      _border_deviations(fp.read_block, rpos, cpos, vij, vz, last_r, last_c).items()}
    res.box = [int(rpos[0]), int(rpos[-1]), int(cpos[0]), int(cpos[-1])]
    res.seconds = time.perf_counter() - t0
    _save_tin(job.out_dir, key, vij, faces, vz, res)
    return res


def finish_tile(job: DsmJob) -> TileResult:
    """Stage 2 of a tile, on a worker: match its borders to its neighbours', certify, write.

    ``job.border_extra`` holds the vertices the same-level neighbours have on the shared borders and this
    tile lacks. Each is inserted into the border edge it lies on (the edge's triangle becomes a fan from
    its opposite vertex), so both tiles carry the same border vertices wherever both have a surface,
    without re-triangulating either; the result is then certified like any other TIN (exact, against the
    full-resolution raster), and that certificate is the tile's error.
    """
    t0 = time.perf_counter()
    info = job.source.info
    cells = job.tile_size - 1
    key = f"{job.level}/{job.row}/{job.col}"
    g = _tile_grid(job)
    if g is None:
        raise RuntimeError(f"tile {key}: outside the raster")
    stride, rpos, cpos = g  # the grid's stride (finer than the level's under the Hausdorff metric)
    cells *= 2 ** (job.levels - job.level) // stride
    is_coarse = job.level < job.levels
    last_r, last_c = len(rpos) - 1, len(cpos) - 1
    if job.stage1_tin is None:
        raise RuntimeError(f"tile {key}: stage 2 without a stage-1 TIN")
    stored, tin = _decode_tin(job.stage1_tin.read())
    vij, faces, vz = tin["vij"], tin["faces"], tin["vz"]
    res = dataclasses.replace(job.stage1) if job.stage1 is not None else stored
    err = res.certified
    to_metric = _to_metric(info, job)
    fp: _Footprint | None = None
    n_kept = len(faces)  # faces[:n_kept] are stage 1's; the rest are the fans that replaced the others
    replaced = faces[:0]
    old_center = None
    # A leaf's error is its kernel's bound (see below), not a certificate: nothing of stage 1 is re-evaluated.
    haus = _hausdorff_affine(info, job) if is_coarse else None
    kernel_leaf = not is_coarse and math.isnan(err) and not math.isnan(res.kernel_bound) and not job.certify_leaves
    if job.border_extra:
        vij2, faces2, replaced = _insert_border_vertices(vij, faces, dict(job.border_extra), last_r, last_c)
        if len(replaced):
            fp = _Footprint(job.source, rpos, cpos)
            heights, _ = fp.grid()
            if not kernel_leaf:
                old_center = _place(info, to_metric, rpos, cpos, vij, vz)[1]
            vz = np.concatenate([vz, heights[vij2[len(vij):, 0], vij2[len(vij):, 1]]])
            n_kept = len(faces) - len(replaced)
            vij, faces = vij2, faces2
    local, center, q_xy, vr, vc, zq = _place(info, to_metric, rpos, cpos, vij, vz)
    limit = job.target  # above this, the fans made the tile miss what stage 1 met
    if kernel_leaf:
        # A leaf's grid is the raster's: the kernel evaluated the exact vertical distance at every sample and
        # every grid-edge crossing of every face (what certify computes) and left none above its bound; float32
        # heights move a face by at most its vertices' rounding. Only the fans are new: they are certified.
        # (Certifying every leaf again cost a third of the leaf's build; ``certify_leaves`` still does.)
        err = limit = res.kernel_bound + float(np.max(np.abs(zq - vz), initial=0.0))
        if len(replaced):
            assert fp is not None
            err = max(err, _certify(fp, vr, vc, zq, faces[n_kept:], cells, stride)[0])
    elif haus is not None:
        if fp is not None and old_center is not None and not math.isnan(err) and np.array_equal(center, old_center):
            # A piece's bound depends on the raster, its own face and the faces around that face's vertices
            # (`citylod.lod.kernels.hausdorff`). Faces none of whose vertices belongs to a replaced face keep all
            # three, and the old vertices quantise as they did, so their stage-1 bounds (at most ``err``) hold:
            # only the fans and the kept faces touching a replaced face's vertices are bounded again, with
            # every face of the new TIN as a candidate.
            touched = np.zeros(len(vij), bool)
            touched[replaced.reshape(-1)] = True
            evaluate = touched[faces].any(axis=1)
            evaluate[n_kept:] = True
            e_new, _ = _certify(fp, vr, vc, zq, faces, cells, stride, hausdorff=haus, floor=0.5 * job.target,
                                evaluate=evaluate)
            err = max(err, e_new)
        elif fp is not None or math.isnan(err):
            err, _ = _certify(fp or _Footprint(job.source, rpos, cpos), vr, vc, zq, faces, cells, stride,
                              hausdorff=haus, floor=0.5 * job.target)
    elif fp is not None and old_center is not None and not math.isnan(err) and np.array_equal(center, old_center):
        # Certified in stage 1, and the old vertices quantise as they did: the certificate is a maximum
        # over faces, so the fans, and where needed the faces they replaced or kept, are evaluated (exactly,
        # with the same numbers as in stage 1) instead of the whole tile.
        e_fans, _ = _certify(fp, vr, vc, zq, faces[n_kept:], cells, stride)
        if e_fans < err:
            e_replaced, _ = _certify(fp, vr, vc, zq, replaced, cells, stride)
            if e_replaced >= err:  # stage 1's maximum may have been on a replaced face
                e_kept, _ = _certify(fp, vr, vc, zq, faces[:n_kept], cells, stride)
                err = max(e_kept, e_fans)
            # else the maximum is on a kept face: err stands
        else:
            err = e_fans  # the kept faces are at most stage 1's err
    elif fp is not None or math.isnan(err):
        err, _ = _certify(fp or _Footprint(job.source, rpos, cpos), vr, vc, zq, faces, cells, stride)
    if len(replaced) and err > limit and not res.certified > job.target:
        # The fans pushed a tile that met its target over it (not seen on real data, but possible): re-mesh
        # with every current vertex forced, and keep that when it adds no border vertex and is certified
        # lower. Otherwise the fans stay, with their (certified, so still true) error.
        assert fp is not None
        heights, valid = fp.grid()
        again = _refit(heights, valid, vij, job.target, last_r, last_c)
        if again is not None:
            vz2 = heights[again[0][:, 0], again[0][:, 1]]
            placed = _place(info, to_metric, rpos, cpos, again[0], vz2)
            err2, _ = _certify(fp, placed[3], placed[4], placed[5], again[1], cells, stride, hausdorff=haus,
                               floor=0.5 * job.target)
            if err2 < err:
                (vij, faces), vz, err = again, vz2, err2
                local, center, q_xy, vr, vc, zq = placed
    res.certified = err
    res.quantisation = q_xy
    res.projection = 0.0 if to_metric is None else _projection_bound(info, to_metric, rpos, cpos, vij, faces)
    res.geometric_error = err + q_xy + res.projection
    # No skirt along the raster's own edges: no tile lies beyond them, so there is no crack to close, and a
    # skirt there only hangs a curtain of twice the tile's error under the data's outline (40 m under the
    # coarse tiles of a city).
    sides = "".join(side for side, outer in (("n", rpos[0] == 0), ("s", rpos[-1] >= info.height - 1),
                                             ("w", cpos[0] == 0), ("e", cpos[-1] >= info.width - 1))
                    if not outer)
    # Along a side, this tile's border lies within dev (its measured deviation, exact: both it and the raster
    # are linear between samples) of the raster line, and any tile across it, of any level, within its reach
    # (_skirt_reach) of it, so where this border is the higher one the crack is at most dev + reach deep: the
    # skirt reaches that, plus the level's target. Sized from the actual borders, not from geometricError,
    # which under the Hausdorff metric says nothing vertical, and which hung coarse tiles' skirts tens of
    # metres under the data's outline where it ends at no-data inside the raster (a reprojected raster).
    if len(replaced) == 0 and job.stage1 is not None and job.stage1.box and job.skirt_reach is not None:
        # stage 1's TIN, unchanged: its deviations (its heights before float32, which the margin covers)
        dev = {side: (d, 0.0) for side, d in job.stage1.border_dev.items()}
    else:
        dev = _border_deviations(fp.read_block if fp is not None else job.source.read_window, rpos, cpos, vij, zq,
                                 last_r, last_c)
    if job.skirt_reach is not None:
        reach = dict(job.skirt_reach)
        depth = {s: max(2.0 * job.target, dev.get(s, (0.0, 0.0))[0] + reach.get(s, 0.0) + job.target) for s in sides}
    else:  # an older journal: neighbours' deviations unknown, so the lowest sample on the lines bounds them
        border_err = max((d for d, _ in dev.values()), default=0.0)
        drop = max((k for _, k in dev.values()), default=0.0)
        old = (max(2.0 * max(border_err, job.target), drop + job.target) if haus is not None
               else 2.0 * max(res.geometric_error, job.target))
        depth = {s: old for s in sides}
    skirt_depth = max(depth.values(), default=0.0)
    out_faces = faces[:, ::-1] if info.transform[0] * info.transform[4] > 0 else faces  # south-up: mirrored
    positions, faces_all, skirt, skirt_src = _add_skirts(local, out_faces, vij, last_r, last_c, depth)
    uv = texture = None
    if job.ortho:
        from citylod.io.image import encode_image

        xs, ys = info.sample_xy(np.array([rpos[0], rpos[-1]]), np.array([cpos[0], cpos[-1]]))
        bounds = (float(min(xs)), float(min(ys)), float(max(xs)), float(max(ys)))
        img = read_image_window(job.ortho, bounds, info.crs, job.texture_size)
        if img is not None:
            texture = encode_image(img, "jpg")
            gx, gy = info.sample_xy(rpos[vij[:, 0]], cpos[vij[:, 1]])
            u = (gx - bounds[0]) / max(bounds[2] - bounds[0], 1e-12)
            v = (bounds[3] - gy) / max(bounds[3] - bounds[1], 1e-12)
            uv_v = np.column_stack([u, v]).astype(np.float32)
            uv = np.concatenate([uv_v, uv_v[skirt_src]])
    # Single-sided: the surface is wound counter-clockwise seen from above and each skirt strip faces away
    # from its tile (tests/lod/test_dsm.py checks every triangle), so clients may cull back faces.
    mesh = MeshData(positions, faces_all.astype(np.uint32), skirt=skirt, uv=uv, texture=texture, name="surface",
                    double_sided=False)
    # Not atomic (no temporary name and rename): the tile counts as finished only through its journal record,
    # written after this returns, so a glb torn by an interruption is rewritten when the build resumes.
    write_content(job.out_dir, key, TileContent([mesh]), atomic=False)
    surf = local.astype(np.float64) + center
    lo, hi = xyz_bounds(surf)
    lo[2] -= skirt_depth  # the skirt hangs below the surface; bounding volumes must hold it
    res.center, res.lo, res.hi = center.tolist(), lo.tolist(), hi.tolist()
    res.triangles = len(faces)
    res.vertices = len(vij)
    res.borders = _border_sets(vij, last_r, last_c)
    res.seconds += time.perf_counter() - t0
    _journal_result(job.out_dir, key, res)
    return res


def _border_deviations(read: Callable[[int, int, int, int], tuple[np.ndarray, np.ndarray]], rpos: np.ndarray,
                       cpos: np.ndarray, vij: np.ndarray, z: np.ndarray, last_r: int,
                       last_c: int) -> dict[str, tuple[float, float]]:
    """Per side ("n", "s", "w", "e"): max |TIN − raster| along the side's line, at every full-resolution
    sample on it (the TIN's border is linear between its border vertices, which are samples, so that is the
    exact maximum), and how far the lowest valid sample on the line lies below the TIN's highest vertex on
    it. A side with fewer than two vertices has no border edge (no surface reaches it) and is left out.
    ``read(row, col, rows, cols)`` gives full-resolution heights and validity (a footprint's, or the raster's)."""
    out: dict[str, tuple[float, float]] = {}
    for side in "nswe":
        axis, fixed, _ = _side(side, last_r, last_c)
        on = vij[:, axis] == fixed
        if on.sum() < 2:
            continue
        along = vij[on, 1 - axis]
        order = np.argsort(along)
        pos = (cpos if axis == 0 else rpos)[along[order]].astype(np.float64)
        zt = z[on][order]
        if axis == 0:
            f, v = read(int(rpos[fixed]), int(pos[0]), 1, int(pos[-1] - pos[0]) + 1)
        else:
            f, v = read(int(pos[0]), int(cpos[fixed]), int(pos[-1] - pos[0]) + 1, 1)
        f, v = f.reshape(-1), v.reshape(-1)
        x = pos[0] + np.arange(len(f))
        t = np.interp(x, pos, zt)
        d = np.abs(t - f)[v]
        out[side] = (float(d.max(initial=0.0)), float(zt.max() - f[v].min()) if v.any() else 0.0)
    return out


def _skirt_reach(stage1: dict[str, TileResult]) -> dict[str, tuple[tuple[str, float], ...] | None]:
    """For every tile with content, per side: how far below the raster along that side's line the border of
    any tile across it (of any level) may lie: 2× the largest stage-1 deviation of those borders.

    Why 2×: a tile's final border is its stage-1 border plus samples of the line inserted in stage 2, and
    between two consecutive final vertices the stage-1 border is linear and within e of the raster at both,
    so the final one is within e of the stage-1 one, and within 2e of the raster. All None when a stage-1
    record has no deviations (a build resumed from an older journal): the skirts then keep the older bound.
    """
    if any(r.has_content and len(r.box) != 4 for r in stage1.values()):
        return {key: None for key, r in stage1.items() if r.has_content}
    # a side's line in the tile's box, and the side a tile across it shows to it
    where = {"n": (0, "s"), "s": (1, "n"), "w": (2, "e"), "e": (3, "w")}
    lines: dict[tuple[str, int], list[tuple[int, int, float]]] = {}
    for r in stage1.values():
        if r.has_content:
            for side, (k, _) in where.items():
                lo, hi = (r.box[2], r.box[3]) if k < 2 else (r.box[0], r.box[1])
                lines.setdefault((side, r.box[k]), []).append((lo, hi, r.border_dev.get(side, 0.0)))
    out: dict[str, tuple[tuple[str, float], ...] | None] = {}
    for key, r in stage1.items():
        if r.has_content:
            reach = []
            for side, (k, other) in where.items():
                lo, hi = (r.box[2], r.box[3]) if k < 2 else (r.box[0], r.box[1])
                near = [d for a, b, d in lines.get((other, r.box[k]), []) if a < hi and b > lo]
                reach.append((side, 2.0 * max(near, default=0.0)))
            out[key] = tuple(reach)
    return out


def _projection_bound(info: RasterInfo, to_metric: pyproj.Transformer, rpos: np.ndarray, cpos: np.ndarray,
                      vij: np.ndarray, faces: np.ndarray) -> float:
    """Horizontal distance between a TIN triangle in degrees, projected, and the straight triangle
    through its projected vertices (geographic rasters only).

    Over a tile the projection is quadratic to within (h/R)³ of its value; for a quadratic map the
    interpolation error inside a triangle is at most 4/3 of the largest deviation at an edge midpoint
    (the error is Σ c_ij b_i b_j in barycentric coordinates, with Σ b_i b_j ≤ 1/3 and c_ij = 4 × the
    midpoint deviation). The cubic remainder is added as h³/R². This horizontal term enters the
    Hausdorff bound the tile's geometricError promises.
    """
    r = rpos[vij[:, 0]].astype(np.float64)
    c = cpos[vij[:, 1]].astype(np.float64)
    x, y = info.sample_xy(r, c)
    px, py = to_metric.transform(x, y)
    worst, longest = 0.0, 0.0
    for a, b in ((0, 1), (1, 2), (2, 0)):
        i, j = faces[:, a], faces[:, b]
        mx, my = info.sample_xy((r[i] + r[j]) / 2, (c[i] + c[j]) / 2)
        qx, qy = to_metric.transform(mx, my)
        dev = np.hypot(qx - (px[i] + px[j]) / 2, qy - (py[i] + py[j]) / 2)
        worst = max(worst, float(dev.max(initial=0.0)))
        longest = max(longest, float(np.hypot(px[i] - px[j], py[i] - py[j]).max(initial=0.0)))
    return 4.0 / 3.0 * worst + longest**3 / 6.371e6**2


def _unique_ij(ij: np.ndarray, width: int) -> np.ndarray:
    """Unique (row, col) pairs, sorted row-major (one 1D unique instead of a slow ``axis=0`` one)."""
    ij = np.asarray(ij, np.int64).reshape(-1, 2)
    keys = np.unique(ij[:, 0] * width + ij[:, 1])
    return np.column_stack([keys // width, keys % width])


def _border_sets(vij: np.ndarray, last_r: int, last_c: int) -> dict[str, list[int]]:
    """Vertex positions along each tile side: "n" (row 0), "s" (last row), "w" (col 0), "e" (last col)."""
    r_, c_ = vij[:, 0], vij[:, 1]
    return {"n": np.sort(c_[r_ == 0]).tolist(), "s": np.sort(c_[r_ == last_r]).tolist(),
            "w": np.sort(r_[c_ == 0]).tolist(), "e": np.sort(r_[c_ == last_c]).tolist()}


def _border_additions(stage1: dict[str, TileResult]) -> dict[str, dict[str, list[int]]]:
    """For every tile, the vertices its same-level neighbours have on a shared border and it lacks.

    Tiles of one level and row share their grid rows (columns likewise), so positions along a shared side
    compare directly.
    """
    out: dict[str, dict[str, list[int]]] = {}
    for key, r in stage1.items():
        if not r.has_content:
            continue
        for side, (dr, dc), other in (("e", (0, 1), "w"), ("w", (0, -1), "e"), ("s", (1, 0), "n"),
                                      ("n", (-1, 0), "s")):
            n = stage1.get(f"{r.level}/{r.row + dr}/{r.col + dc}")
            if n is None or not n.has_content:
                continue
            miss = set(n.borders.get(other, [])) - set(r.borders.get(side, []))
            if miss:
                out.setdefault(key, {})[side] = sorted(miss)
    return out


def _side(side: str, last_r: int, last_c: int) -> tuple[int, int, int]:
    """A tile side as (axis of the fixed index: 0 = row, 1 = column; that index; the last index along it):
    "n" row 0, "s" the last row, "w" column 0, "e" the last column."""
    return {"n": (0, 0, last_c), "s": (0, last_r, last_c), "w": (1, 0, last_r), "e": (1, last_c, last_r)}[side]


def _insert_border_vertices(vij: np.ndarray, faces: np.ndarray, extra: dict[str, tuple[int, ...]],
                            last_r: int, last_c: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Insert border samples into the border edges they lie on.

    A triangle (a, b, o) whose edge a→b lies on a tile side and passes over samples p1..pk of ``extra``
    becomes the fan (a, p1, o), (p1, p2, o), …, (pk, b, o): same orientation, same area, no other triangle
    changes (an edge on the tile's outer border has one triangle). A sample that lies on no border edge
    (this tile has no surface there) is left out, so it cannot create a crack either. Returns the vertices
    (new ones appended), the faces (the unchanged ones first, in their order, then the fans) and the faces
    that were replaced.
    """
    if not extra:
        return vij, faces, faces[:0]
    from citylod.lod.kernels.tin_kernels import border_fans

    sides = [_side(sd, last_r, last_c) for sd in extra]
    want = [np.asarray(v, np.int64).reshape(-1) for v in extra.values()]
    added, faces_out, hit = aot.kernel(
        border_fans,
        np.ascontiguousarray(vij[:, 0], np.int64), np.ascontiguousarray(vij[:, 1], np.int64),
        np.ascontiguousarray(faces, np.int64), np.array([sd[0] for sd in sides], np.int64),
        np.array([sd[1] for sd in sides], np.int64), np.array([sd[2] for sd in sides], np.int64),
        np.concatenate(want), np.cumsum([0] + [len(w) for w in want]).astype(np.int64), last_r, last_c)
    if not hit.any():
        return vij, faces, faces[:0]
    return np.concatenate([vij, added.astype(vij.dtype)]), faces_out.astype(faces.dtype), faces[hit]


# Stage 1's output per tile: one JSON header line (array shapes and dtypes, the stage-1 result), then the
# arrays' raw bytes. Plain data only (no pickle): a resumed build reads what it finds in OUT.partial.
_TIN_ARRAYS = ("vij", "faces", "vz")


def _save_tin(out_dir: str, key: str, vij: np.ndarray, faces: np.ndarray, vz: np.ndarray, res: TileResult) -> None:
    """Stage 1's output: the TIN, its vertex heights and the stage-1 result (certified error or NaN, borders)."""
    arrays = [np.ascontiguousarray(a) for a in (vij, faces, vz)]
    head = {"result": _as_doc(res),
            "arrays": [[n, a.dtype.str, list(a.shape)] for n, a in zip(_TIN_ARRAYS, arrays, strict=True)]}
    data = json.dumps(head).encode() + b"\n" + b"".join(a.tobytes() for a in arrays)
    journal.append(_journal_dir(out_dir), "tin/" + key, data)


def _journal_dir(out_dir: str | Path) -> Path:
    # Stage results go to append-only journals (one file per thread), not a file or two per tile: creating
    # files is serialised in the kernel and was a large share of a build.
    return Path(out_dir) / ".journal"


def _decode_tin(data: bytes) -> tuple[TileResult, dict[str, np.ndarray]]:
    nl = data.index(b"\n")
    head = json.loads(data[:nl])
    out: dict[str, np.ndarray] = {}
    at = nl + 1
    for name, dtype, shape in head["arrays"]:
        dt = np.dtype(dtype)
        n = int(np.prod(shape))
        out[name] = np.frombuffer(data, dt, n, at).reshape(shape)
        at += n * dt.itemsize
    if at != len(data) or set(out) != set(_TIN_ARRAYS):
        raise ValueError("truncated stage-1 file")
    return TileResult(**head["result"]), out


def _add_skirts(local: np.ndarray, faces: np.ndarray, vij: np.ndarray, last_r: int, last_c: int,
                depth: dict[str, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Append a vertical strip below each TIN edge on the tile's outer border, ``depth[side]`` deep on each
    side given ("n": row 0, "s": the last row, "w": column 0, "e": the last column).

    Returns positions, faces, the skirt mask per face, and for each appended vertex the surface vertex it
    hangs from (so attributes such as texture coordinates can be copied).
    """
    sd = [_side(side, last_r, last_c) for side in depth]
    return aot.kernel(skirt_strip, np.ascontiguousarray(local, np.float32), np.ascontiguousarray(faces, np.int64),
                      np.ascontiguousarray(vij[:, 0], np.int64), np.ascontiguousarray(vij[:, 1], np.int64),
                      np.array([a for a, _, _ in sd], np.int64), np.array([line for _, line, _ in sd], np.int64),
                      np.array([float(d) for d in depth.values()], np.float64))


def _as_doc(res: TileResult) -> dict[str, Any]:
    return {f.name: getattr(res, f.name) for f in dataclasses.fields(res)}  # flat fields: no deep copy


def _journal_result(out_dir: str, key: str, res: TileResult) -> None:
    """Record a finished tile (its glb, when it has content, is written before)."""
    journal.append(_journal_dir(out_dir), "done/" + key, json.dumps(_as_doc(res)).encode())


def _read_result(out_dir: Path, key: str, idx: dict[str, journal.Entry]) -> TileResult | None:
    """A finished tile's result (its glb exists), or None."""
    entry = idx.get("done/" + key)
    if entry is None:
        return None
    try:
        res = TileResult(**json.loads(entry.read()))
    except (OSError, ValueError, TypeError):
        return None
    if res.has_content and not (out_dir / "tiles" / f"{key}.glb").exists():
        return None
    return res


def _read_stage1(key: str, idx: dict[str, journal.Entry]) -> TileResult | None:
    """A tile's stage-1 result, journalled with its TIN, or None."""
    entry = idx.get("tin/" + key)
    if entry is None:
        return None
    try:
        return _decode_tin(entry.read())[0]
    except (OSError, ValueError, TypeError, KeyError):
        return None


def plan_levels(info: RasterInfo, tile_size: int) -> int:
    """Number of levels below the root: leaves at level L have stride 1."""
    cells = tile_size - 1
    n = max(math.ceil(max(info.width - 1, 1) / cells), math.ceil(max(info.height - 1, 1) / cells))
    return max(0, math.ceil(math.log2(n))) if n > 1 else 0


@discard_partial_on_refusal
def build_dsm(raster: str | os.PathLike[str], out_dir: str | os.PathLike[str], *, ortho: str | os.PathLike[str] | None = None,
              max_error: float | None = None, tile_size: int = 129, workers: int | None = None,
              scheduler: str | None = None, progress: bool = True, texture_size: int | None = None,
              certify_leaves: bool = False, metric: str = "hausdorff",
              _stop_after: int | None = None) -> DsmBuildReport:
    """Build a 3D Tiles quadtree from a DSM raster. See the module docstring for the method.

    Parameters
    ----------
    raster
        Any raster GDAL reads, with a CRS and a geotransform.
    out_dir
        Tileset folder to create (replaced when it already holds a citylod tileset).
    ortho
        Orthophoto to texture the tiles with (any CRS; resampled per tile by averaging).
    texture_size
        Pixels per side of each tile's texture, default 256; rounded up to a power of two, the only size glTF
        clients mipmap (the glTF validator reports any other).
    max_error
        Leaf target in metres; default half the sample spacing. Level d above the leaves targets 2^d times it.
    tile_size
        Samples per tile side, 2^k + 1.
    workers, scheduler
        None (default): one worker process per CPU forked from this one where that is safe (Linux, no
        other Python thread), else one thread per CPU for rasters under 6 M samples and one spawned
        worker process per CPU above; N: N spawned local worker processes (0: this process, no
        threads); or a Dask scheduler address (``tcp://host:port``).
    certify_leaves
        Certify the leaves against the raster as well (coarser tiles always are). By default a leaf's error
        is the TIN kernel's own exact bound on the full-resolution grid plus the float32 rounding of its
        heights, and only the faces stage 2 changed are certified: the same guarantee, a fraction of the
        time, a bound instead of the measured maximum (at most the target).
    metric
        What ``geometricError`` bounds: ``"hausdorff"`` (default), the symmetric 3D Hausdorff distance between a
        tile and the raster surface over its footprint (:mod:`citylod.lod.kernels.hausdorff`), or
        ``"vertical"``, the vertical L∞ distance (which bounds Hausdorff too, but counts a façade between two
        coarse samples at its full height, so that on cities the coarse levels certify at tens of metres and
        views refine to the leaves; terrain users may prefer it, and it builds faster). Leaves keep the TIN
        kernel's vertical bound under both, and geographic rasters are certified vertically under both.

    Returns
    -------
    DsmBuildReport
        Tiles, levels, triangles and certified errors per level, timings; ``summary()`` is what the CLI
        prints.

    Examples
    --------
    >>> report = build_dsm("dsm.tif", "tiles", ortho="ortho.tif", workers=2)      # doctest: +SKIP
    >>> print(report.summary())                                                   # doctest: +SKIP
    >>> build_dsm("dsm.tif", "tiles_v", metric="vertical")                       # doctest: +SKIP
    >>> build_dsm("dsm.tif", "tiles", scheduler="tcp://127.0.0.1:8786")          # doctest: +SKIP
    """
    if metric not in ("hausdorff", "vertical"):
        raise ValueError(f"metric must be 'hausdorff' or 'vertical', got {metric!r}")
    t0 = time.perf_counter()
    if tile_size < 3 or (tile_size - 1) & (tile_size - 2):
        raise ValueError(f"tile_size must be 2^k + 1 (e.g. 65, 129, 257), got {tile_size}")
    src = RasterSource(raster)
    info = src.info
    if info.width < 2 or info.height < 2:
        src.close()
        raise InputError(f"raster is {info.width}×{info.height} samples; a surface needs at least 2×2", raster)
    if info.geographic:
        # Corners outside ±180°/±90° are metres under a degree CRS: projecting them would place the data
        # nowhere (and fail only when the tileset is written).
        xs, ys = info.sample_xy([0, 0, info.height - 1, info.height - 1], [0, info.width - 1, 0, info.width - 1])
        if np.abs(xs).max() > 180 or np.abs(ys).max() > 90:
            src.close()
            raise GeoreferenceError(f"the raster declares {info.crs.name} (degrees) but its corners reach "
                                    f"({xs.max():.1f}, {ys.max():.1f}), which are not degrees; fix its CRS", raster)
    check_has_data(src)
    src.close()
    if ortho is not None:
        from citylod.io.raster import read_info as _ri

        try:
            _ri(ortho)
        except InputError as exc:
            raise InputError(f"orthophoto: {exc.message}", ortho) from exc
    leaf = float(max_error) if max_error is not None else 0.5 * info.spacing_m
    if not leaf > 0:
        raise ValueError("max_error must be positive")
    levels = plan_levels(info, tile_size)
    out = Path(out_dir)
    partial = out.with_name(out.name + ".partial")
    partial.mkdir(parents=True, exist_ok=True)
    metric_crs = info.metric_crs()
    tex = 1 << max(0, int(texture_size or 256) - 1).bit_length()
    cells = tile_size - 1
    stage1: list[DsmJob] = []
    all_jobs: dict[str, DsmJob] = {}
    results: dict[str, TileResult] = {}  # finished tiles
    borders: dict[str, TileResult] = {}  # stage-1 results (their border vertices) of tiles with content
    jdir = _journal_dir(partial)
    idx = journal.index(jdir)  # what an interrupted build finished (empty for a new one)
    metric_wkt = metric_crs.to_wkt()
    for d in range(levels + 1):
        stride = 2 ** (levels - d)
        nr = math.ceil(max(info.height - 1, 1) / (cells * stride))
        nc = math.ceil(max(info.width - 1, 1) / (cells * stride))
        for i in range(nr):
            for j in range(nc):
                key = f"{d}/{i}/{j}"
                job = DsmJob(src, str(partial), d, i, j, levels, tile_size, leaf * 2 ** (levels - d),
                             None if ortho is None else str(ortho), tex, metric_wkt,
                             certify_leaves=certify_leaves, metric=metric)
                all_jobs[key] = job
                prev = _read_result(partial, key, idx)
                tin = _read_stage1(key, idx)
                if prev is not None and (tin is not None or not prev.has_content):
                    # finished; its stage-1 borders are what its neighbours are fitted to
                    results[key] = prev
                    if tin is not None:
                        borders[key] = tin
                elif tin is not None:
                    borders[key] = tin
                else:
                    stage1.append(job)
    resumed = len(results) + sum(1 for k in borders if k not in results)
    if _stop_after is not None:
        stage1 = stage1[:_stop_after]
    # Coarse tiles first: they take longest, so starting them first keeps the workers busy to the end.
    stage1.sort(key=lambda j: j.level)
    from citylod.lod.build.executor import describe, fork_is_safe, make_executor

    # The default executor: worker processes forked from this one where that is safe (Linux, no other
    # thread here). They start at once with everything imported, and each task has a GIL of its own: on
    # threads, the Python around the kernels (a third of a tile's time) holds the GIL. Otherwise a raster
    # below _THREADS_BELOW_SAMPLES builds on threads (no worker has to start: imports and numba's cache),
    # larger ones on spawned processes.
    default = workers is None and scheduler is None
    fork = default and fork_is_safe()
    threads = default and not fork and info.width * info.height < _THREADS_BELOW_SAMPLES
    # Tasks on the main thread of a process (inline, forked or spawned workers) run the compiled-ahead
    # kernels where they are built; threads and Dask workers run the JIT ones (see citylod.lod.kernels.aot).
    compiled_ahead = aot.available() and not threads and scheduler is None
    if fork and not compiled_ahead:
        _preload_kernels()
    where = describe(workers, scheduler, threads=threads, fork=fork)
    try:
        with make_executor(workers=workers, scheduler=scheduler, threads=threads, fork=fork) as ex:
            for r in _run_batched(ex, build_tile, stage1, progress, "dsm tiles"):
                if r.has_content:
                    borders[r.key] = r
                else:
                    results[r.key] = r
            if _stop_after is not None:
                raise KeyboardInterrupt("stopped on request (test hook)")
            # Stage 2: every tile takes the border vertices its neighbours chose and it lacks (one round: the
            # insertions add no vertex elsewhere), then is certified and written.
            extra = _border_additions(borders)
            reach = _skirt_reach(borders)
            journal.close(jdir)  # this thread's records (inline builds) are on disk; index all of them
            idx = journal.index(jdir)
            stage2 = [dataclasses.replace(all_jobs[k], stage1=borders[k], stage1_tin=idx.get("tin/" + k),
                                          border_extra=tuple(
                (s, tuple(v)) for s, v in sorted(extra.get(k, {}).items())), skirt_reach=reach.get(k))
                      for k in sorted(borders, key=lambda k: int(k.split("/")[0])) if k not in results]
            for r in _run_batched(ex, finish_tile, stage2, progress, "dsm borders"):
                results[r.key] = r
    finally:
        src.close()  # builds on threads or inline opened it in this thread too
        journal.close(jdir)
    root = _assemble(results, levels, info, cells)
    if root is None:
        raise InputError("no tile has valid data", raster)
    write_tileset(partial, root, metric_crs, extras={"citylod": {
        "kind": "dsm", "source": str(Path(raster).name), "source_crs": info.crs_wkt,
        "leaf_target_m": leaf, "tile_size": tile_size, "levels": levels + 1,
        # the source grid, so the leaves' vertices map back to raster rows and columns (flooding a tileset)
        "grid": {"width": info.width, "height": info.height, "transform": [float(v) for v in info.transform[:6]]},
        "error_metric": _METRIC_TEXT["hausdorff" if metric == "hausdorff" and not info.geographic else "vertical"],
    }})
    _replace_dir(partial, out)
    seconds = time.perf_counter() - t0
    written: dict[int, float] = {}  # the geometricError as written (raised to the children's where needed)
    stack = [root]
    while stack:
        sp = stack.pop()
        if sp.content is not None:
            written[sp.level] = max(written.get(sp.level, 0.0), sp.geometric_error)
        stack.extend(sp.children)
    per_level = []
    for d in range(levels + 1):
        lv = [r for r in results.values() if r.level == d and r.has_content]
        per_level.append({"level": d, "tiles": len(lv), "triangles": sum(r.triangles for r in lv),
                          "target": leaf * 2 ** (levels - d),
                          "max_error": written.get(d, 0.0),
                          "max_certified": max((r.geometric_error for r in lv), default=0.0)})
    return DsmBuildReport(
        output=str(out), raster=str(raster), width=info.width, height=info.height, levels=levels + 1,
        tiles=sum(1 for r in results.values() if r.has_content), seconds=seconds,
        samples_per_s=info.width * info.height / max(seconds, 1e-9), peak_rss_mb=_peak_rss_mb(),
        leaf_target=leaf, per_level=per_level, resumed=resumed, executor=where,
        kernels="compiled-ahead" if compiled_ahead else "JIT",
        # In the summary, not as a warning: a raster's heights are plausibly orthometric but the user cannot
        # name the datum on the command line, so this says once what was assumed.
        heights=missing_vertical_datum(info.crs) or "",
    )


# The tiles of a level with many go to the executor four to a task: every process-pool task costs the
# builder CPU in its queue and result threads, on the cores the workers need. Levels with few tiles (the
# long ones at the top) stay one to a task, so that they start first and spread over the workers.
_BATCH = 4
_BATCH_FROM = 64  # tiles in a level, from which it is batched


def _tile_batch(fn: Callable[[DsmJob], TileResult], jobs: list[DsmJob]) -> list[TileResult]:
    """Run ``fn`` on each job, in order (one executor task for several small tiles)."""
    return [fn(job) for job in jobs]


def _run_batched(ex: Any, fn: Callable[[DsmJob], TileResult], jobs: list[DsmJob], progress: bool,
                 desc: str) -> Iterator[TileResult]:
    """``run_tasks`` over ``jobs`` in their order, the tiles of a level with `_BATCH_FROM` or more in
    consecutive batches of `_BATCH`; yields each tile's result."""
    from citylod.lod.build.executor import run_tasks

    per_level: dict[int, int] = {}
    for j in jobs:
        per_level[j.level] = per_level.get(j.level, 0) + 1
    batches: list[tuple[Any, ...]] = []
    run: list[DsmJob] = []
    for j in jobs:
        if per_level[j.level] < _BATCH_FROM:
            batches.append((fn, [j]))
            continue
        if run and (len(run) == _BATCH or run[0].level != j.level):
            batches.append((fn, run))
            run = []
        run.append(j)
    if run:
        batches.append((fn, run))
    for rs in run_tasks(ex, _tile_batch, batches, progress=progress, desc=desc):
        yield from rs


_PRELOADED = False


def _preload_kernels() -> None:
    """:func:`exercise_kernels` once per process, so that every JIT kernel a tile task calls is loaded here
    before workers are forked: they inherit them. Otherwise every forked worker starts numba's runtime and
    loads them itself (≈0.5 s), again at every build of the process. Not needed where the compiled-ahead
    kernels are loaded (:mod:`citylod.lod.kernels.aot`)."""
    global _PRELOADED
    if _PRELOADED:
        return
    exercise_kernels()
    _PRELOADED = True


def exercise_kernels() -> None:
    """Build a 40×40 raster inline, in a temporary folder: every compiled kernel a tile task calls runs
    once, with the argument types a build passes (coarse levels, façades, no-data, border fans), under
    both metrics."""
    import tempfile

    import rasterio
    from rasterio.transform import from_origin

    yy, xx = np.mgrid[0:40, 0:40]
    z = (20.0 + 0.1 * xx + 3.0 * np.sin(yy / 5.0)).astype(np.float32)
    z[10:20, 12:25] += 15.0  # a building: façades, a coarse level certified by its grid
    z[30:33, 2:5] = -9999.0  # no-data
    with tempfile.TemporaryDirectory(prefix="citylod-preload-") as tmp:
        path = Path(tmp) / "z.tif"
        with rasterio.open(path, "w", driver="GTiff", width=40, height=40, count=1, dtype="float32",
                           crs="EPSG:32632", transform=from_origin(500_000.0, 5_400_000.0, 1.0, 1.0),
                           nodata=-9999.0) as ds:
            ds.write(z, 1)
        for metric in ("vertical", "hausdorff"):  # each metric's certifier
            build_dsm(path, Path(tmp) / metric, tile_size=17, workers=0, progress=False, metric=metric)


def _assemble(results: dict[str, TileResult], levels: int, info: RasterInfo, cells: int) -> TileSpec | None:
    """The tile tree bottom-up: a tile exists when it or a descendant has content."""
    specs: dict[str, TileSpec] = {}
    for d in range(levels, -1, -1):
        for key, r in results.items():
            if r.level != d:
                continue
            kids = [specs[k] for k in (f"{d + 1}/{2 * r.row + a}/{2 * r.col + b}" for a in (0, 1) for b in (0, 1))
                    if k in specs]
            if not r.has_content and not kids:
                continue
            if r.has_content:
                lo, hi, center = np.array(r.lo), np.array(r.hi), np.array(r.center)
            else:
                lo = np.min([k.lo for k in kids], axis=0)
                hi = np.max([k.hi for k in kids], axis=0)
                center = 0.5 * (lo + hi)
            for k in kids:
                lo, hi = np.minimum(lo, k.lo), np.maximum(hi, k.hi)
            # A parent without content must refine at once: its error is that of its worst child. A parent
            # is never shown as more exact than a child (3D Tiles expects errors to shrink downwards; a
            # coarse city tile built at its grid's façade-bound error can certify above its parent's).
            err = r.geometric_error if r.has_content else max(k.geometric_error for k in kids) * 2.0
            err = max([err, *(k.geometric_error for k in kids)])
            specs[key] = TileSpec(key, d, center, lo, hi, err, f"tiles/{key}.glb" if r.has_content else None,
                                  kids, extras={"triangles": r.triangles} if r.has_content else None)
    return specs.get("0/0/0")


def _replace_dir(partial: Path, out: Path) -> None:
    shutil.rmtree(_journal_dir(partial), ignore_errors=True)
    for pattern in ("tiles/**/*.json", "tiles/**/*.tin"):  # sidecars of builds before the journal
        for side in partial.glob(pattern):
            side.unlink()
    publish_dir(partial, out)


def _peak_rss_mb() -> float:
    """Peak resident memory of this process and of its worker processes, MB.

    The own peak is the kernel's high-water mark of the current address space (``VmHWM``): ``ru_maxrss``
    survives ``exec``, so a build started from a large process (the benchmark suite) reported that
    process's size (1841 MB for a build whose processes peaked at 402 MB).
    """
    import resource

    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    try:
        with open("/proc/self/status") as f:
            own = next(int(line.split()[1]) for line in f if line.startswith("VmHWM:"))
    except (OSError, StopIteration, ValueError, IndexError):
        pass
    kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return max(own, kids) / 1024.0


