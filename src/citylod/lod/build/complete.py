"""Visually complete airborne LiDAR: ground under canopy and building walls, added at build time.

Airborne LiDAR is 2.5D: walls get almost no returns and the ground under tree canopies few, so seen
obliquely a city's point cloud is roofs floating over holes. Gao (City-scale aerial LiDAR point cloud
visualization, USC 2014, ch. 3-4) makes it visually complete from the classification alone; this module
does the same on a 2D cell grid:

1. *scan* — the input is streamed once (:func:`~citylod.io.las.iter_points`, bounded chunks) into per-cell
   accumulators (counts, height sums, extents) of a grid of ``cell_m`` cells, so memory grows with the
   area, not the number of points (out-of-core inputs work as long as the 2D grid fits: 112 bytes per
   cell: 14 float64 planes, 450 MB per km² at 0.5 m);
2. *ground* — a terrain model: cells with ground returns (ASPRS class 2) keep their mean height, the
   others are filled from the ground around them (pull-push, see :func:`terrain`). Cells under canopy (classes
   3-5, or unclassified returns more than ``canopy_m`` above the terrain: AHN puts vegetation in class 1)
   with no ground return get ground points at the density of the real ground;
3. *walls* — building cells (class 6, small gaps closed, specks dropped) are labelled; every edge between
   a building cell and a non-building cell is a wall from the roof height of that cell down to the
   terrain outside, placed at the outermost roof return of the cell, then moved onto the mean line of the
   boundary around it (:func:`_regularise`) and ``eave_m`` inwards (walls stand under the eaves, not
   beyond them), and every edge between two building cells whose roof heights differ by more than
   ``step_m`` is a wall between the two roofs. Wall normals are the boundary direction, taken from the
   gradient of the smoothed building mask (Gao: normal from the boundary, not from the sparse returns).
   Walls become points at the roof's point spacing, or quads (one per edge; both of Gao's variants).
   With building footprints (``CompleteOptions.footprints``, e.g. the BGT) the outer walls stand on the
   footprints' outline instead (:func:`footprint_edges`): the roof's returns overhang the wall by the
   eaves, which the scan alone cannot tell from wall; steps between roofs stop at the footprints
   (:func:`_drop_overhanging_steps`).

The in-memory point build decodes its input once and completes the decoded records
(:func:`complete_records`); the out-of-core build scans the files in a pre-pass (:func:`complete_inputs`).
In the in-memory build the footprints' outline is cut while the points decode
(:func:`start_footprint_outline`) and wall quads, which add no points, are computed and written as tiles on
a thread of their own while the octree is built (``quads_later`` of :func:`augment_grid`): the same walls,
less of the build's time.

Added points keep the class they stand for (2 ground, 6 building) and carry the LAS *synthetic* flag,
which the point build keeps as a per-point ``SYNTHETIC`` glTF attribute, so they can be hidden, coloured
or exported; input points are not touched. Input without ground and building classes is not augmented:
:func:`augment` says so in :attr:`Augmentation.skipped` and a warning.

No VTK, no Qt. The per-point accumulation is one compiled pass; everything after it works per cell,
vectorised.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from citylod.core.errors import InputError
from citylod.core.fileio import atomic_write

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]
I64 = npt.NDArray[np.int64]

#: ASPRS classes the augmentation reads.
GROUND, BUILDING, WATER, UNCLASSIFIED = 2, 6, 9, 1
VEGETATION = (3, 4, 5)

#: What an added point is, in :attr:`Augmentation.kind`.
KIND_GROUND, KIND_WALL, KIND_STEP, KIND_ROOF = 1, 2, 3, 4

WALL_MODES = ("points", "quads", "none")

#: How far a regularised roof-edge wall quad reaches past its part of the wall at either end (see
#: :func:`wall_edges`): on Delft the slits between the parts left 15 % of the wall pixels below the eaves
#: open (ray coverage of roof-edge quads 57.2 %; 0.1 m: 66.7 %, 0.2 m: 68.9 %, docs/PERFORMANCE_LOG.md).
QUAD_PAD_M = 0.2

#: Most cells a completion grid may have (5.6 GB of accumulators; 12.5 km² at 0.5 m).
MAX_CELLS = 50_000_000

# Accumulator planes of the scan grid (float64, one per quantity, (ny, nx) each).
_G_N, _G_Z, _B_N, _B_Z, _B_ZMAX, _B_XLO, _B_XHI, _B_YLO, _B_YHI, _V_N, _U_N, _U_ZMAX, _W_N, _A_N = range(14)
_PLANES = 14
# Per-class sums of intensity and counts (for the intensity added points get).
_NCLASS = 256


@dataclass(frozen=True)
class CompleteOptions:
    """How to complete a cloud.

    Attributes
    ----------
    walls
        "points" (wall points at the roof spacing), "quads" (one quad per boundary edge) or "none".
    ground
        Add ground points under canopy.
    roof_fill
        Add roof points in the building cells with no return (dark or glass roofs, which the building mask
        closes), on the roof interpolated from the returns around them (pull-push, as the terrain), at the
        roof's density (Gao's gap up-sampling, ch. 5). Off by default.
    cell_m
        Grid cell: about twice the point spacing (0.5 m for AHN3's 10-20 points/m²).
    min_wall_m
        Walls lower than this are not added (garden walls, cars at a roof edge).
    step_m
        A height jump between adjacent roof cells above this is a wall between the roofs.
    canopy_m
        Unclassified returns this far above the terrain count as canopy.
    min_building_m2
        Building components smaller than this are noise, not buildings.
    seed
        Jitter of the added points (reproducible builds).
    wall_density
        Wall points per m² as a fraction of the roof's (1: the roof's spacing, as Gao samples them).
    regularise_m
        Walls from the roof edge stand on the mean line of the boundary within this radius (see
        :func:`_regularise`; 0: each at its own cell's outermost return, a staircase on walls at an angle
        to the grid).
    sink_m
        Wall quads reach this far below the terrain outside them: the terrain is a mean over cells, the
        ground's points are sparse, and a quad ending at the mean leaves a seam at the wall's foot where
        the ground lies a little lower (below ground, the ground's points hide the rest).
    eave_m
        Walls from the roof edge stand this far inside the roof's outermost returns, along their normal:
        the eaves' overhang (the roof overhangs the wall; 0: at the roof edge, as Gao places them). The
        default is a typical overhang of pitched roofs: on Delft, AHN3's building returns overhang the BGT
        footprints by a median 0.18 m, p75 0.43 m (docs/PERFORMANCE_LOG.md). Flat roofs without eaves get
        their walls this much too far in.
    footprints
        A GeoPackage / OGR SQLite file of building footprints in the points' CRS (e.g. the BGT): outer
        walls then stand on the footprints' outlines (see :func:`footprint_edges`) instead of under the
        scanned roof's edge; buildings the file lacks keep the walls from the roof edge.
    """

    walls: str = "points"
    ground: bool = True
    roof_fill: bool = False
    cell_m: float = 0.5
    min_wall_m: float = 1.0
    step_m: float = 2.5
    canopy_m: float = 2.0
    min_building_m2: float = 4.0
    seed: int = 0
    footprints: str | None = None
    eave_m: float = 0.25
    wall_density: float = 1.0
    sink_m: float = 0.3
    regularise_m: float = 1.5

    def __post_init__(self) -> None:
        if self.walls not in WALL_MODES:
            raise ValueError(f"walls must be one of {', '.join(WALL_MODES)}, not {self.walls!r}")
        if not self.cell_m > 0:
            raise ValueError("cell_m must be positive")


@dataclass(frozen=True)
class CellGrid:
    """What the scan keeps per cell: ``planes`` (14, ny, nx) float64 accumulators, the grid's lower-left
    corner ``lo`` (2,) and cell size; ``class_n`` / ``class_intensity`` (256,) per-class counts and
    intensity sums."""

    lo: F64
    cell: float
    planes: F64
    class_n: F64
    class_intensity: F64

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.planes.shape[1]), int(self.planes.shape[2])

    def centers(self) -> tuple[F64, F64]:
        """Cell-centre coordinates: x (nx,) and y (ny,)."""
        ny, nx = self.shape
        return self.lo[0] + (np.arange(nx) + 0.5) * self.cell, self.lo[1] + (np.arange(ny) + 0.5) * self.cell


@dataclass
class Augmentation:
    """Points and quads that complete a cloud.

    Attributes
    ----------
    xyz
        (N, 3) float64 added points, in the source CRS.
    normals
        (N, 3) float32 unit normals (walls: horizontal, outwards; ground: the terrain's).
    kind
        (N,) uint8 :data:`KIND_GROUND`, :data:`KIND_WALL` (outer walls, roof down to the ground) or
        :data:`KIND_STEP` (walls between two roofs).
    classification
        (N,) uint8 ASPRS class the point stands for (2 or 6).
    intensity
        (N,) uint16: the mean intensity of its class in the input.
    quads
        (Q, 4, 3) float64 wall quads (corners counter-clockwise seen from outside), when walls are quads.
    quad_normals
        (Q, 3) float32.
    ground_spacing_m, wall_spacing_m
        Spacing of the added points.
    skipped
        Why nothing was added, or None.
    seconds
        Wall time of the scan and of the augmentation.
    walls_pending
        The wall quads while they are still being computed (:func:`augment_grid` with ``quads_later``);
        :meth:`wait_walls` waits for them. None once they are in ``quads``.
    wall_tiles
        The wall tiles already written with the quads (:func:`write_wall_tiles`; ``tiles_dir`` of
        :func:`augment_grid`), or None.
    """

    xyz: F64
    normals: F32
    kind: npt.NDArray[np.uint8]
    classification: npt.NDArray[np.uint8]
    intensity: npt.NDArray[np.uint16]
    quads: F64 = field(default_factory=lambda: np.zeros((0, 4, 3)))
    quad_normals: F32 = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    ground_spacing_m: float = 0.0
    wall_spacing_m: float = 0.0
    skipped: str | None = None
    seconds: dict[str, float] = field(default_factory=dict)
    walls_pending: Future[tuple[F64, F32, float, list[Any] | None]] | None = field(default=None, repr=False)
    wall_tiles: list[Any] | None = field(default=None, repr=False)

    def wait_walls(self) -> None:
        """Wait for the wall quads computed in the background, if any, and put them in ``quads`` (an error
        there is raised here)."""
        if self.walls_pending is not None:
            pending, self.walls_pending = self.walls_pending, None
            self.quads, self.quad_normals, self.seconds["walls"], self.wall_tiles = pending.result()

    @property
    def counts(self) -> dict[str, int]:
        self.wait_walls()
        return {"ground": int(np.sum(self.kind == KIND_GROUND)),
                "wall": int(np.sum((self.kind == KIND_WALL) | (self.kind == KIND_STEP))),
                "roof": int(np.sum(self.kind == KIND_ROOF)), "quads": len(self.quads)}

    def summary(self) -> str:
        if self.skipped:
            return f"complete   skipped: {self.skipped}"
        c = self.counts  # waits for the walls
        return (f"complete   {c['ground']:,} ground points under canopy ({self.ground_spacing_m:.2f} m), "
                f"{c['wall']:,} wall points ({self.wall_spacing_m:.2f} m), {c['quads']:,} wall quads, "
                + (f"{c['roof']:,} roof points in gaps, " if c["roof"] else "")
                + f"{sum(self.seconds.values()):.2f} s")


def _empty(skipped: str | None = None) -> Augmentation:
    return Augmentation(np.zeros((0, 3)), np.zeros((0, 3), np.float32), np.zeros(0, np.uint8),
                        np.zeros(0, np.uint8), np.zeros(0, np.uint16), skipped=skipped)


# ----------------------------------------------------------------------------------------------- scan
@numba.njit(cache=True, nogil=True)
def _accumulate(X: np.ndarray, Y: np.ndarray, Z: np.ndarray, scales: F64, offsets: F64, cls: np.ndarray,
                inten: np.ndarray, x0: float, y0: float, inv_cell: float, planes: F64, class_n: F64,
                class_int: F64) -> None:  # pragma: no cover - compiled
    """Add decoded LAS columns (:func:`~citylod.io.las.point_fields`) to the cell accumulators, in one pass."""
    ny, nx = planes.shape[1], planes.shape[2]
    for i in range(X.shape[0]):
        x = X[i] * scales[0] + offsets[0]
        y = Y[i] * scales[1] + offsets[1]
        z = Z[i] * scales[2] + offsets[2]
        c = cls[i]
        class_n[c] += 1.0
        class_int[c] += inten[i]
        ix = min(max(int((x - x0) * inv_cell), 0), nx - 1)
        iy = min(max(int((y - y0) * inv_cell), 0), ny - 1)
        planes[_A_N, iy, ix] += 1.0
        if c == GROUND:
            planes[_G_N, iy, ix] += 1.0
            planes[_G_Z, iy, ix] += z
        elif c == BUILDING:
            if planes[_B_N, iy, ix] == 0.0:
                planes[_B_ZMAX, iy, ix] = z
                planes[_B_XLO, iy, ix] = x
                planes[_B_XHI, iy, ix] = x
                planes[_B_YLO, iy, ix] = y
                planes[_B_YHI, iy, ix] = y
            else:
                planes[_B_ZMAX, iy, ix] = max(planes[_B_ZMAX, iy, ix], z)
                planes[_B_XLO, iy, ix] = min(planes[_B_XLO, iy, ix], x)
                planes[_B_XHI, iy, ix] = max(planes[_B_XHI, iy, ix], x)
                planes[_B_YLO, iy, ix] = min(planes[_B_YLO, iy, ix], y)
                planes[_B_YHI, iy, ix] = max(planes[_B_YHI, iy, ix], y)
            planes[_B_N, iy, ix] += 1.0
            planes[_B_Z, iy, ix] += z
        elif c == 3 or c == 4 or c == 5:
            planes[_V_N, iy, ix] += 1.0
        elif c == UNCLASSIFIED:
            if planes[_U_N, iy, ix] == 0.0 or z > planes[_U_ZMAX, iy, ix]:
                planes[_U_ZMAX, iy, ix] = z
            planes[_U_N, iy, ix] += 1.0
        elif c == WATER:
            planes[_W_N, iy, ix] += 1.0


def scan_grid(files: Sequence[str | PathLike[str]], lo: F64, hi: F64, cell_m: float, *,
              chunk_points: int = 1_000_000) -> CellGrid:
    """Stream ``files`` once into the cell accumulators of the grid over ``lo``..``hi`` (x, y).

    Memory: one decoded chunk plus the grid.
    """
    from citylod.io.las import iter_points, point_fields

    lo2, planes, class_n, class_int = _new_grid(lo, hi, cell_m, files[0] if files else None)
    for f in files:
        for pts in iter_points(f, chunk_points=chunk_points, raw=True):
            X, Y, Z, scales, offsets, inten, cls, *_ = point_fields(pts)
            _accumulate(X, Y, Z, scales, offsets, cls, inten, float(lo2[0]), float(lo2[1]), 1.0 / cell_m,
                        planes, class_n, class_int)
    return CellGrid(lo2, float(cell_m), planes, class_n, class_int)


def _new_grid(lo: F64, hi: F64, cell_m: float, source: Any) -> tuple[F64, F64, F64, F64]:
    lo2 = np.asarray(lo, np.float64)[:2]
    hi2 = np.asarray(hi, np.float64)[:2]
    nx = max(1, int(np.ceil((hi2[0] - lo2[0]) / cell_m)) + 1)
    ny = max(1, int(np.ceil((hi2[1] - lo2[1]) / cell_m)) + 1)
    if nx * ny > MAX_CELLS:
        raise InputError(f"completing {hi2[0] - lo2[0]:.0f} × {hi2[1] - lo2[1]:.0f} m at {cell_m} m cells needs "
                         f"{nx * ny:,} cells ({nx * ny * _PLANES * 8 / 1e9:.1f} GB), over the {MAX_CELLS:,} "
                         "allowed; complete the area in tiles or use larger cells", source)
    return lo2, np.zeros((_PLANES, ny, nx)), np.zeros(_NCLASS), np.zeros(_NCLASS)


def scan_records(recs: np.ndarray, lo: F64, hi: F64, cell_m: float, source: Any = None) -> CellGrid:
    """:func:`scan_grid` over points already decoded (:data:`citylod.io.las.POINT_DTYPE` records): the
    in-memory point build decodes its input once and completes it from these records, so the LAZ is not
    decoded a second time (the decode is most of the completion's cost)."""
    lo2, planes, class_n, class_int = _new_grid(lo, hi, cell_m, source)
    one, zero = np.ones(3), np.zeros(3)
    _accumulate(recs["x"], recs["y"], recs["z"], one, zero, recs["classification"], recs["intensity"],
                float(lo2[0]), float(lo2[1]), 1.0 / cell_m, planes, class_n, class_int)
    return CellGrid(lo2, float(cell_m), planes, class_n, class_int)


# ---------------------------------------------------------------------------------------------- ground
def terrain(grid: CellGrid) -> F64:
    """Terrain height per cell, (ny, nx): the mean of its ground returns, else filled by pull-push.

    Pull-push (Gortler et al., "The Lumigraph", 1996): the ground cells are averaged into coarser and
    coarser grids until every coarse cell has ground, and each gap takes the bilinear upsampling of the
    next coarser level, so a gap is filled from the ground around it, smoothly, at a cost linear in the
    cells. Written here rather than ``scipy.interpolate.griddata`` over the cells bordering the gaps:
    qhull is slow on grid-aligned, co-circular points (docs/PERFORMANCE_LOG.md).
    """
    gn = grid.planes[_G_N]
    has = gn > 0
    if not has.any():
        return np.zeros(grid.shape)
    return _pull_push(np.where(has, grid.planes[_G_Z] / np.maximum(gn, 1.0), 0.0), has)


def _pull_push(z: F64, has: npt.NDArray[np.bool_]) -> F64:
    """``z`` where ``has``, the gaps filled by pull-push (see :func:`terrain`); ``has`` not all False."""
    from scipy import ndimage

    if has.all():
        return z
    # Pull: weights and weighted sums, 2×2 at a time.
    levels = [(has.astype(np.float64), z * has)]
    while levels[-1][0].shape[0] > 1 or levels[-1][0].shape[1] > 1:
        w, v = levels[-1]
        if np.all(w > 0):
            break
        ph, pw = w.shape[0] % 2, w.shape[1] % 2
        w = np.pad(w, ((0, ph), (0, pw)))
        v = np.pad(v, ((0, ph), (0, pw)))
        levels.append((_sum2x2(w), _sum2x2(v)))
    # Push: from the coarsest level down, gaps take the upsampled coarser level.
    w, v = levels[-1]
    filled = np.where(w > 0, v / np.maximum(w, 1e-300), 0.0)
    for w, v in reversed(levels[:-1]):
        h, wd = w.shape
        zoom = (2 * filled.shape[0] / filled.shape[0], 2 * filled.shape[1] / filled.shape[1])
        up = ndimage.zoom(filled, zoom, order=1, mode="nearest", grid_mode=True)[:h, :wd]
        filled = np.where(w > 0, v / np.maximum(w, 1e-300), up)
    return filled


def _sum2x2(a: F64) -> F64:
    """Sums of the 2×2 blocks of an array of even shape, in the order ``a.reshape(h, 2, w, 2).sum(axis=(1, 3))``
    adds them (each row's pair, then the two rows: the same floating-point result), ten times faster."""
    return (a[0::2, 0::2] + a[0::2, 1::2]) + (a[1::2, 0::2] + a[1::2, 1::2])


def _bilinear(field_: F64, grid: CellGrid, x: F64, y: F64) -> F64:
    from scipy import ndimage

    fx = (x - grid.lo[0]) / grid.cell - 0.5
    fy = (y - grid.lo[1]) / grid.cell - 0.5
    return ndimage.map_coordinates(field_, [fy, fx], order=1, mode="nearest")


def _jittered(cells_y: I64, cells_x: I64, per_cell: int, grid: CellGrid, rng: np.random.Generator
              ) -> tuple[F64, F64]:
    """``per_cell`` stratified, jittered positions in each of the given cells: a k×k sub-grid (k = ⌈√n⌉)
    of which the first ``per_cell`` strata are used, each point uniform in its stratum."""
    k = int(np.ceil(np.sqrt(per_cell)))
    sub = np.arange(per_cell)
    sx, sy = sub % k, sub // k
    n = len(cells_x)
    jx = rng.random((n, per_cell))
    jy = rng.random((n, per_cell))
    x = grid.lo[0] + (cells_x[:, None] + (sx[None, :] + jx) / k) * grid.cell
    y = grid.lo[1] + (cells_y[:, None] + (sy[None, :] + jy) / k) * grid.cell
    return x.reshape(-1), y.reshape(-1)


def _ground_fill(grid: CellGrid, dtm: F64, building: npt.NDArray[np.bool_], opts: CompleteOptions,
                 rng: np.random.Generator) -> tuple[F64, F32, float]:
    """Ground points where canopy hides the ground: (M, 3) positions, (M, 3) normals, their spacing."""
    from scipy import ndimage

    p = grid.planes
    has_ground = p[_G_N] > 0
    if not has_ground.any():
        return np.zeros((0, 3)), np.zeros((0, 3), np.float32), 0.0
    canopy = (p[_V_N] > 0) | ((p[_U_N] > 0) & (p[_U_ZMAX] > dtm + opts.canopy_m))
    near_building = ndimage.maximum_filter(building, 3, mode="constant", cval=0)  # binary_dilation, 3×3, faster
    fill = canopy & ~has_ground & ~near_building & (p[_W_N] == 0)
    # The ground's own density: points per ground cell (median, robust to the cells a canopy half hides).
    per_cell = max(1, int(round(float(np.median(p[_G_N][has_ground])))))
    spacing = grid.cell / np.sqrt(per_cell)
    fy, fx = np.nonzero(fill)
    if len(fy) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.float32), spacing
    x, y = _jittered(fy, fx, per_cell, grid, rng)
    z = _bilinear(dtm, grid, x, y)
    gy, gx = np.gradient(dtm, grid.cell)
    nxv, nyv = -_bilinear(gx, grid, x, y), -_bilinear(gy, grid, x, y)
    nrm = np.column_stack([nxv, nyv, np.ones_like(x)])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return np.column_stack([x, y, z]), nrm.astype(np.float32), spacing


def _roof_fill(grid: CellGrid, mask: npt.NDArray[np.bool_], rng: np.random.Generator) -> tuple[F64, F32]:
    """Roof points in the building cells without a return: (M, 3) positions on the roof interpolated by
    pull-push from the cells with returns, at their median count per cell, and (M, 3) normals of that
    surface."""
    bn = grid.planes[_B_N]
    has = bn > 0
    gaps = mask & ~has
    if not gaps.any() or not has.any():
        return np.zeros((0, 3)), np.zeros((0, 3), np.float32)
    roof = _pull_push(np.where(has, grid.planes[_B_Z] / np.maximum(bn, 1.0), 0.0), has)
    per_cell = max(1, int(round(float(np.median(bn[has])))))
    fy, fx = np.nonzero(gaps)
    x, y = _jittered(fy, fx, per_cell, grid, rng)
    z = _bilinear(roof, grid, x, y)
    gy, gx = np.gradient(roof, grid.cell)
    nrm = np.column_stack([-_bilinear(gx, grid, x, y), -_bilinear(gy, grid, x, y), np.ones_like(x)])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return np.column_stack([x, y, z]), nrm.astype(np.float32)


# ----------------------------------------------------------------------------------------------- walls
def building_mask(grid: CellGrid, opts: CompleteOptions) -> npt.NDArray[np.bool_]:
    """Building cells: cells with class-6 returns, one-cell gaps closed and small holes filled (dark or
    glass roofs return nothing), components smaller than ``min_building_m2`` dropped."""
    from scipy import ndimage

    raw = grid.planes[_B_N] > 0
    m = raw | ndimage.binary_closing(raw, np.ones((3, 3), bool), border_value=0)
    # Holes: the components of the rest (4-connected, as ``ndimage.binary_fill_holes`` fills) that do not
    # touch the grid's border; one labelling instead of filling, then labelling the holes.
    lab, n = ndimage.label(~m)
    if n:
        small = np.bincount(lab.ravel(), minlength=n + 1) * grid.cell ** 2 <= 4.0 * opts.min_building_m2
        small[np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]])] = False
        small[0] = False
        m |= small[lab]
    lab, n = ndimage.label(m)
    if n:
        keep = np.bincount(lab.ravel(), minlength=n + 1) * grid.cell ** 2 >= opts.min_building_m2
        keep[0] = False
        m = keep[lab]
    return m


def _roof(grid: CellGrid, mask: npt.NDArray[np.bool_]) -> F64:
    """Mean roof height per building cell; cells added by closing take the nearest cell with returns."""
    from scipy import ndimage

    bn = grid.planes[_B_N]
    z = np.where(bn > 0, grid.planes[_B_Z] / np.maximum(bn, 1.0), np.nan)
    empty = bn == 0
    if empty.all():
        return z
    iy, ix = ndimage.distance_transform_edt(empty, return_distances=False, return_indices=True)
    z = np.where(mask & empty, z[iy, ix], z)
    return np.where(mask, z, np.nan)


@dataclass
class _Edges:
    """Wall edges of the cell grid: a straight horizontal segment (x0, y0)-(x1, y1), its outward normal,
    its bottom and top heights, whether it is a step between two roofs. ``(E,)`` arrays. ``top`` is the
    top at (x0, y0); ``top1``, where given, the top at (x1, y1) (footprint walls, whose top follows the
    roof along the wall), else the top is level."""

    x0: F64
    y0: F64
    x1: F64
    y1: F64
    nx: F64
    ny: F64
    bottom: F64
    top: F64
    step: npt.NDArray[np.bool_]
    top1: F64 | None = None

    def tops(self) -> tuple[F64, F64]:
        """The top at (x0, y0) and at (x1, y1): ``top`` both, unless ``top1`` gives the second."""
        return self.top, (self.top if self.top1 is None else self.top1)


def wall_edges(grid: CellGrid, dtm: F64, mask: npt.NDArray[np.bool_], opts: CompleteOptions,
               footprints: Sequence[Any] | FootprintOutline | None = None) -> _Edges:
    """The walls: boundary edges (roof down to the terrain outside) and roof steps (higher roof down to
    the lower one), with normals from the boundary direction. With ``footprints`` (shapely polygons or their
    :class:`FootprintOutline`), outer
    walls near a footprint come from :func:`footprint_edges` instead."""
    from scipy import ndimage

    p = grid.planes
    roof = _roof(grid, mask)
    c = grid.cell
    ny_, nx_ = grid.shape
    # The neighbour of every cell in each of four directions (dy, dx): slices ``ys, xs`` of the neighbours
    # of the cells ``yd, xd`` (a border cell has none that way). Only shifted views and boolean planes over
    # the whole grid; values are gathered for the selected cells only.
    shifts = []
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        ys = slice(max(dy, 0), ny_ + min(dy, 0))
        xs = slice(max(dx, 0), nx_ + min(dx, 0))
        yd = slice(max(-dy, 0), ny_ + min(-dy, 0))
        xd = slice(max(-dx, 0), nx_ + min(-dx, 0))
        nb_mask = np.zeros_like(mask)
        nb_mask[yd, xd] = mask[ys, xs]
        shifts.append((dy, dx, ys, xs, yd, xd, mask & ~nb_mask))
    near_fp = np.zeros(mask.shape, bool)
    fp_edges = None
    if footprints and not isinstance(footprints, FootprintOutline):
        footprints = footprint_outline(footprints, c)
    if footprints:
        boundary = np.logical_or.reduce([s_[-1] for s_ in shifts])
        fp_edges, near_fp = footprint_edges(footprints, grid, dtm, roof, opts, where=boundary)
    has = p[_B_N] > 0
    outer_parts: list[tuple[Any, ...]] = []
    # Boundary direction: the gradient of the smoothed building mask points inwards.
    smooth = ndimage.gaussian_filter(mask.astype(np.float64), 1.5)
    gy, gx = np.gradient(smooth)
    parts: list[tuple[Any, ...]] = []
    # Four directions: (dy, dx), the cell extent that places the wall, the edge's endpoints.
    for dy, dx, ys, xs, yd, xd, edge in shifts:
        outer = edge & ~near_fp
        step = np.zeros_like(mask)
        step[yd, xd] = mask[yd, xd] & mask[ys, xs] & (roof[yd, xd] - roof[ys, xs] > opts.step_m)
        if fp_edges is not None and isinstance(footprints, FootprintOutline):
            _drop_overhanging_steps(step, dy, dx, grid, footprints)
        for sel in (outer, step):
            cy, cx = np.nonzero(sel)
            if len(cy) == 0:
                continue
            top = roof[cy, cx]
            if sel is outer:  # down to the terrain of the neighbour (of the cell itself at the grid's border)
                bottom = dtm[np.clip(cy + dy, 0, ny_ - 1), np.clip(cx + dx, 0, nx_ - 1)]
            else:  # down to the neighbour's roof
                bottom = roof[cy + dy, cx + dx]
            x0c, y0c = grid.lo[0] + cx * c, grid.lo[1] + cy * c
            if sel is outer:
                # At the outermost roof return of the cell (less the eaves' overhang ``eave_m``, below).
                ext = {(0, 1): _B_XHI, (0, -1): _B_XLO, (1, 0): _B_YHI, (-1, 0): _B_YLO}[(dy, dx)]
                e = np.where(has[cy, cx], p[ext][cy, cx], (x0c if dy == 0 else y0c) + (c if dx + dy > 0 else 0))
                nrm_x = -gx[cy, cx]
                nrm_y = -gy[cy, cx]
            else:
                e = (x0c if dy == 0 else y0c) + (c if dx + dy > 0 else 0)
                nrm_x = np.full(len(cy), float(dx))
                nrm_y = np.full(len(cy), float(dy))
            if dy == 0:  # an edge along y at x = e
                seg = (e, y0c, e, y0c + c)
            else:
                seg = (x0c, e, x0c + c, e)
            # The smoothed gradient can vanish or point sideways on thin parts: keep the normal within
            # 90° of the edge's own outward direction, else use that.
            dot = nrm_x * dx + nrm_y * dy
            bad = dot <= 0.2 * np.hypot(nrm_x, nrm_y) + 1e-12
            nrm_x = np.where(bad, float(dx), nrm_x)
            nrm_y = np.where(bad, float(dy), nrm_y)
            norm = np.hypot(nrm_x, nrm_y)
            if sel is outer:
                outer_parts.append((*seg, nrm_x / norm, nrm_y / norm, bottom, top, 0.0))
            else:
                parts.append((*seg, nrm_x / norm, nrm_y / norm, bottom, top, 1.0, top))
    if outer_parts:
        cols_ = [np.concatenate([np.broadcast_to(np.asarray(pt[k], np.float64), (len(pt[7]),)) for pt in outer_parts])
                 for k in range(8)]
        if opts.regularise_m > 0:
            # Quads reach QUAD_PAD_M past their part of the wall at either end: the cell edges' outermost
            # returns scatter along the wall too, and the parts, turned, leave slits between them that an
            # opaque quad shows and jittered points drawn a few pixels wide mostly do not.
            pad = QUAD_PAD_M if opts.walls == "quads" else 0.0
            x0, y0, x1, y1, nx, ny = cols_[:6]
            cols_[:4] = _regularise(x0, y0, x1, y1, nx, ny, opts.regularise_m, pad)
        if opts.eave_m:  # inwards, along the wall's normal
            for k, nk in ((0, 4), (1, 5), (2, 4), (3, 5)):
                cols_[k] = cols_[k] - opts.eave_m * cols_[nk]
        parts.append((*cols_, 0.0, cols_[7]))
    if fp_edges is not None and len(fp_edges.x0):
        fe = fp_edges
        parts.append((fe.x0, fe.y0, fe.x1, fe.y1, fe.nx, fe.ny, fe.bottom, fe.top, 0.0, fe.tops()[1]))
    if not parts:
        z = np.zeros(0)
        return _Edges(z, z, z, z, z, z, z, z, np.zeros(0, bool))
    cols = [np.concatenate([np.broadcast_to(np.asarray(pt[k], np.float64), (len(pt[7]),)) for pt in parts])
            for k in range(10)]
    keep = (cols[7] + cols[9]) / 2.0 - cols[6] >= opts.min_wall_m
    x0, y0, x1, y1, nx, ny, bottom, top = (a[keep] for a in cols[:8])
    return _Edges(x0, y0, x1, y1, nx, ny, bottom, top, cols[8][keep] > 0, cols[9][keep])


def _drop_overhanging_steps(step: npt.NDArray[np.bool_], dy: int, dx: int, grid: CellGrid,
                            outline: FootprintOutline) -> None:
    """Clear the roof steps (``step`` cells and their neighbours ``(dy, dx)`` away) of which a cell lies
    under the eaves of a footprint: outside its outline but within its reach. There the step between two
    roofs is the roof's overhang over the street, not a wall: a step wall there would stand in front of
    the facade on the footprint. Steps wholly inside the footprints (a higher house beside a lower one)
    and far from any footprint (buildings the file lacks) stay."""
    import shapely

    if outline.union is None:
        return
    sy, sx = np.nonzero(step)
    if len(sy) == 0:
        return
    c = grid.cell
    bad = np.zeros(len(sy), bool)
    for oy, ox in ((0, 0), (dy, dx)):
        x = grid.lo[0] + (sx + ox + 0.5) * c
        y = grid.lo[1] + (sy + oy + 0.5) * c
        bad |= ~shapely.contains_xy(outline.union, x, y) & shapely.contains_xy(outline.grown, x, y)
    step[sy[bad], sx[bad]] = False


def _regularise(x0: F64, y0: F64, x1: F64, y1: F64, nx: F64, ny: F64, radius: float, pad: float = 0.0
                ) -> tuple[F64, F64, F64, F64]:
    """Roof-edge walls moved onto the local line of their boundary: each cell edge's midpoint moves along
    its normal by the mean offset, along that normal, of the edges within ``radius`` whose normals are
    within 15° of its own, and the edge turns to run along the wall (perpendicular to its normal), over
    the part of the wall it faces (a monotone staircase's edges, so turned, tile the wall's line). Edges
    with fewer than six such neighbours (corners, where the smoothed normal turns; short walls) stay as
    they are: there the mean would cut the corner. ``pad``: how far a turned edge reaches past its part of
    the wall at either end.

    Why: each cell edge stands at its own cell's outermost roof return, which lies up to a point spacing
    inside the roof's edge, and a wall at an angle to the grid is a staircase of such edges; the mean
    over a few metres of the same wall averages the spacing's jitter and the staircase's teeth into the
    line they scatter about (Gao's boundary regularisation, ch. 5, done here on the edges rather than on
    the points). The mean of offsets measured along one normal is exact for a straight wall.
    """
    from scipy.spatial import cKDTree

    mx, my = (x0 + x1) / 2.0, (y0 + y1) / 2.0
    length = np.hypot(x1 - x0, y1 - y0)
    facing = np.abs(nx * (y1 - y0) - ny * (x1 - x0)) / np.maximum(length, 1e-12)
    mid = np.column_stack([mx, my])
    _, idx = cKDTree(mid).query(mid, k=min(len(mid), 16), distance_upper_bound=radius)
    idx = idx.reshape(len(mid), -1)
    ok = idx < len(mid)
    j = np.where(ok, idx, 0)
    w = ok & (nx[:, None] * nx[j] + ny[:, None] * ny[j] >= np.cos(np.radians(15.0)))
    off = (mx[j] - mx[:, None]) * nx[:, None] + (my[j] - my[:, None]) * ny[:, None]
    count = w.sum(axis=1)
    shift = np.sum(np.where(w, off, 0.0), axis=1) / np.maximum(count, 1)
    cx, cy = mx + shift * nx, my + shift * ny
    half = 0.5 * length * facing + pad
    tx, ty = -ny, nx
    keep = count < 6
    return (np.where(keep, x0, cx - half * tx), np.where(keep, y0, cy - half * ty),
            np.where(keep, x1, cx + half * tx), np.where(keep, y1, cy + half * ty))


@dataclass(frozen=True)
class FootprintOutline:
    """The outline of the union of building footprints, cut into pieces of at most one ``cell`` (``p0`` to
    ``p1``, (P, 2) each, with ``n`` the outward unit normals: the union's inside is on each piece's left),
    and the union grown by ``reach_m`` (a shapely geometry). Depends on the footprints and the cell size
    only, so the point build computes it while it decodes the points (:func:`start_footprint_outline`)."""

    p0: F64
    p1: F64
    n: F64
    grown: Any
    cell: float
    reach_m: float
    union: Any = None


def footprint_outline(footprints: Sequence[Any], cell: float, reach_m: float = 1.5) -> FootprintOutline:
    """:class:`FootprintOutline` of ``footprints`` (shapely polygons) for cells of ``cell`` metres."""
    import shapely

    c = cell
    union = shapely.union_all(shapely.make_valid(np.asarray(footprints, dtype=object)))
    polys = [g for g in getattr(union, "geoms", [union]) if g.geom_type == "Polygon" and not g.is_empty]
    xs, ys = [], []
    for poly in polys:
        poly = shapely.geometry.polygon.orient(poly, 1.0)  # exterior CCW, holes CW: inside on the left
        for ring in (poly.exterior, *poly.interiors):
            q = np.asarray(ring.coords)[:, :2]
            xs.append(q[:-1])
            ys.append(q[1:])
    if not xs:
        z = np.zeros((0, 2))
        return FootprintOutline(z, z, z, union.buffer(reach_m), float(cell), float(reach_m), union)
    a, b = np.concatenate(xs), np.concatenate(ys)
    seg = b - a
    length = np.hypot(seg[:, 0], seg[:, 1])
    ok = length > 1e-6
    a, seg, length = a[ok], seg[ok], length[ok]
    npc = np.maximum(1, np.ceil(length / c).astype(np.int64))
    e = np.repeat(np.arange(len(a)), npc)
    k = np.arange(len(e)) - np.repeat(np.cumsum(npc) - npc, npc)
    t0, t1 = k / npc[e], (k + 1) / npc[e]
    p0 = a[e] + t0[:, None] * seg[e]
    p1 = a[e] + t1[:, None] * seg[e]
    d = seg[e] / length[e][:, None]
    n = np.column_stack([d[:, 1], -d[:, 0]])  # right of the direction: outwards
    shapely.prepare(union)
    return FootprintOutline(p0, p1, n, union.buffer(reach_m), float(cell), float(reach_m), union)


def start_footprint_outline(opts: CompleteOptions) -> Future[FootprintOutline] | None:
    """Read ``opts.footprints`` now (a bad file is refused at once) and compute their
    :func:`footprint_outline` on a thread of its own; None without footprints or walls."""
    from citylod.io.footprints import read_footprints

    if not opts.footprints or opts.walls == "none":
        return None
    footprints = read_footprints(opts.footprints)
    pool = ThreadPoolExecutor(1, thread_name_prefix="citylod-footprints")
    try:
        return pool.submit(footprint_outline, footprints, opts.cell_m)
    finally:
        pool.shutdown(wait=False)


def footprint_edges(footprints: Sequence[Any] | FootprintOutline, grid: CellGrid, dtm: F64, roof: F64, opts: CompleteOptions,
                    reach_m: float = 1.5, where: npt.NDArray[np.bool_] | None = None
                    ) -> tuple[_Edges, npt.NDArray[np.bool_]]:
    """Outer walls on the outline of the union of ``footprints`` (shapely polygons, or their
    :class:`FootprintOutline` for this grid's cells and ``reach_m``; walls shared by two
    footprints, as in a terrace, are inside the union and get none), cut into pieces of at most one cell
    so the top follows the roof: each piece rises from the terrain half a cell outside to the scanned roof
    a quarter of a cell inside (the roof above the wall's line, under the eaves), its top sloping from the
    roof at one end to the roof at the other (:func:`_roof_bilinear`). Pieces with no scanned
    roof there get no wall: the footprint is not backed by the scan. Also returns the cells within
    ``reach_m`` of a footprint, whose roof-edge walls these replace, among the cells of the mask ``where``
    (default: all cells; :func:`wall_edges` asks only about the building cells at the mask's boundary, the
    only ones that can have a roof-edge wall: a few percent of the grid, and the point-in-polygon test is
    most of this function's cost).

    A footprint is where the wall meets the ground; the roof's outer returns overhang it by the eaves
    (on Delft's AHN3 against the BGT, median 0.18 m, p75 0.43 m: docs/PERFORMANCE_LOG.md), so walls from
    the roof edge stand that far outside the real wall."""
    import shapely

    c = grid.cell
    if not isinstance(footprints, FootprintOutline):
        footprints = footprint_outline(footprints, c, reach_m)
    elif footprints.cell != c or footprints.reach_m != reach_m:
        raise ValueError(f"the outline was cut for {footprints.cell} m cells and {footprints.reach_m} m of reach, "
                         f"not {c} and {reach_m}")
    p0, p1, n = footprints.p0, footprints.p1, footprints.n
    if len(p0) == 0:
        z = np.zeros(0)
        return _Edges(z, z, z, z, z, z, z, z, np.zeros(0, bool)), np.zeros(grid.shape, bool)
    mid = (p0 + p1) / 2.0
    ny_, nx_ = grid.shape

    def cell_of(xy: F64) -> tuple[I64, I64, npt.NDArray[np.bool_]]:
        ix = np.floor((xy[:, 0] - grid.lo[0]) / c).astype(np.int64)
        iy = np.floor((xy[:, 1] - grid.lo[1]) / c).astype(np.int64)
        inside = (ix >= 0) & (iy >= 0) & (ix < nx_) & (iy < ny_)
        return np.clip(iy, 0, ny_ - 1), np.clip(ix, 0, nx_ - 1), inside

    ri, rj, rin = cell_of(mid - 0.25 * c * n)
    oi, oj, oin = cell_of(mid + 0.5 * c * n)
    top = np.where(rin, roof[ri, rj], np.nan)
    # Where the cell just inside has no roof (a gutter or a dark roof edge returned nothing, the building
    # mask stops short of the footprint), the roof further in, up to ``reach_m``: else the wall would have
    # a gap there, though the roof is scanned.
    for k in range(1, int(reach_m / c) + 1):
        gap = ~np.isfinite(top)
        if not gap.any():
            break
        gi, gj, gin = cell_of(mid[gap] - (0.25 + k) * c * n[gap])
        top[gap] = np.where(gin, roof[gi, gj], np.nan)
    # The top follows the roof along the wall: at either end of the piece, the cell means interpolated
    # bilinearly a quarter cell inside, as above (cells off the roof left out), so the pieces' tops join
    # into one line. One value per piece, the mean of one cell, left a sawtooth along gable walls (the roof
    # rising along the wall) and notches where that cell was a low one: on Delft, tops 0.55 m below the
    # local plane of the roof's returns at p10 against 0.29 m now (docs/PERFORMANCE_LOG.md).
    t0 = _roof_bilinear(roof, grid, p0 - 0.25 * c * n)
    t1 = _roof_bilinear(roof, grid, p1 - 0.25 * c * n)
    ends = rin & np.isfinite(t0) & np.isfinite(t1)
    top1 = np.where(ends, t1, top)
    top = np.where(ends, t0, top)
    bottom = dtm[oi, oj]
    keep = oin & np.isfinite(top) & ((top + top1) / 2.0 - bottom >= opts.min_wall_m)
    iy, ix = np.nonzero(np.ones(grid.shape, bool) if where is None else where)
    near = np.zeros(grid.shape, bool)
    near[iy, ix] = shapely.contains_xy(footprints.grown, grid.lo[0] + (ix + 0.5) * c, grid.lo[1] + (iy + 0.5) * c)
    edges = _Edges(p0[keep, 0], p0[keep, 1], p1[keep, 0], p1[keep, 1], n[keep, 0], n[keep, 1], bottom[keep],
                   top[keep], np.zeros(int(keep.sum()), bool), top1[keep])
    return edges, near


def _roof_bilinear(roof: F64, grid: CellGrid, xy: F64) -> F64:
    """``roof`` (per cell, NaN off the roof) interpolated bilinearly between the cell centres at ``xy`` (P, 2),
    the weights of the cells off the roof left out (renormalised); NaN where all four are off. Exact on a
    plane roof; at the roof's edge it is the mean of the cells on the roof. (``scipy.ndimage.map_coordinates``
    interpolates too, but cannot leave out the NaN cells.)"""
    c = grid.cell
    fx = (xy[:, 0] - grid.lo[0]) / c - 0.5
    fy = (xy[:, 1] - grid.lo[1]) / c - 0.5
    x0 = np.floor(fx).astype(np.int64)
    y0 = np.floor(fy).astype(np.int64)
    ax, ay = fx - x0, fy - y0
    num = np.zeros(len(xy))
    den = np.zeros(len(xy))
    ny_, nx_ = roof.shape
    for dy, dx, w in ((0, 0, (1 - ax) * (1 - ay)), (0, 1, ax * (1 - ay)), (1, 0, (1 - ax) * ay), (1, 1, ax * ay)):
        v = roof[np.clip(y0 + dy, 0, ny_ - 1), np.clip(x0 + dx, 0, nx_ - 1)]
        ok = np.isfinite(v)
        num += np.where(ok, w * v, 0.0)
        den += np.where(ok, w, 0.0)
    return np.where(den > 1e-9, num / np.maximum(den, 1e-12), np.nan)


def _wall_points(edges: _Edges, spacing: float, rng: np.random.Generator
                 ) -> tuple[F64, F32, npt.NDArray[np.uint8]]:
    """Points on every wall edge at ``spacing``: a jittered grid along the edge and down its height.
    Returns positions, normals and kinds (:data:`KIND_WALL` or :data:`KIND_STEP`)."""
    length = np.hypot(edges.x1 - edges.x0, edges.y1 - edges.y0)
    # A wall at an angle to the grid is a staircase of x- and y-edges; each edge stands for the part of
    # the wall it faces, |cos| of the angle between the wall's normal and its own, so a 45° wall gets
    # the density of an axis-aligned one rather than √2 times it.
    facing = np.abs(edges.nx * (edges.y1 - edges.y0) - edges.ny * (edges.x1 - edges.x0)) / np.maximum(length, 1e-12)
    n_h = np.maximum(1, np.ceil(facing * length / spacing - 1e-9)).astype(np.int64)
    t0, t1 = edges.tops()
    n_v = np.maximum(1, np.ceil((np.maximum(t0, t1) - edges.bottom) / spacing - 1e-9)).astype(np.int64)
    per = n_h * n_v
    total = int(per.sum())
    e = np.repeat(np.arange(len(per)), per)
    k = np.arange(total) - np.repeat(np.cumsum(per) - per, per)
    a = (k % n_h[e] + rng.random(total) * 0.8 + 0.1) / n_h[e]  # along the edge, jitter inside the stratum
    b = (k // n_h[e] + rng.random(total) * 0.8 + 0.1) / n_v[e]  # down from the top
    x = edges.x0[e] + a * (edges.x1[e] - edges.x0[e])
    y = edges.y0[e] + a * (edges.y1[e] - edges.y0[e])
    top = t0[e] + a * (t1[e] - t0[e])  # the top along the edge (footprint walls follow the roof)
    z = top - b * (top - edges.bottom[e])
    nrm = np.column_stack([edges.nx[e], edges.ny[e], np.zeros(total)]).astype(np.float32)
    kind = np.where(edges.step[e], KIND_STEP, KIND_WALL).astype(np.uint8)
    return np.column_stack([x, y, z]), nrm, kind


def _wall_quads(edges: _Edges, sink_m: float = 0.0) -> tuple[F64, F32]:
    """One quad per edge, corners counter-clockwise seen from outside (along the normal); outer walls
    (not roof steps) reach ``sink_m`` below their bottom."""
    p0 = np.column_stack([edges.x0, edges.y0])
    p1 = np.column_stack([edges.x1, edges.y1])
    # Seen from outside, counter-clockwise runs bottom-left, bottom-right, top-right, top-left with
    # "right" = normal × up... order the edge's endpoints so that (p1 - p0) × up points along the normal.
    d = p1 - p0
    flip = (d[:, 1] * edges.nx - d[:, 0] * edges.ny) < 0  # (d × z)·n = d_y n_x − d_x n_y
    a = np.where(flip[:, None], p1, p0)
    b = np.where(flip[:, None], p0, p1)
    q = np.empty((len(a), 4, 3))
    bottom = edges.bottom - np.where(edges.step, 0.0, sink_m)
    q[:, 0, :2], q[:, 0, 2] = a, bottom
    q[:, 1, :2], q[:, 1, 2] = b, bottom
    t0, t1 = edges.tops()
    q[:, 2, :2], q[:, 2, 2] = b, np.where(flip, t0, t1)
    q[:, 3, :2], q[:, 3, 2] = a, np.where(flip, t1, t0)
    nrm = np.column_stack([edges.nx, edges.ny, np.zeros(len(a))]).astype(np.float32)
    return q, nrm


# ------------------------------------------------------------------------------------------------ API
def augment_grid(grid: CellGrid, opts: CompleteOptions = CompleteOptions(), *,
                 quads_later: bool = False, tiles_dir: str | PathLike[str] | None = None,
                 outline: Future[FootprintOutline] | None = None) -> Augmentation:
    """Ground under canopy and walls from a scanned grid (see the module docstring).

    ``quads_later``: wall quads are computed on a thread of their own and the augmentation returned with
    the added points at once (:attr:`Augmentation.walls_pending`; :meth:`Augmentation.wait_walls`), so the
    point build can build its octree meanwhile: quads add no points, and take no random numbers, so they
    are the same either way. The footprints are read before returning, so a bad file is refused first.
    With ``tiles_dir`` too, that thread also writes the wall tiles there (:attr:`Augmentation.wall_tiles`,
    which :func:`add_wall_tiles` then uses). ``outline``: the footprints' outline being computed
    (:func:`start_footprint_outline`), used instead of reading ``opts.footprints`` here.
    """
    t0 = time.perf_counter()
    n_ground = grid.class_n[GROUND]
    n_building = grid.class_n[BUILDING]
    if n_ground == 0 and n_building == 0:
        msg = "the input has no ground (class 2) or building (class 6) points: nothing is added"
        warnings.warn(msg, stacklevel=2)
        return _empty(msg)
    rng = np.random.default_rng(opts.seed)
    pool = ThreadPoolExecutor(1, thread_name_prefix="citylod-complete")
    try:
        # The building mask on the helper thread while this one fills the terrain (independent; scipy's
        # filters let go of the GIL for much of it).
        masking = pool.submit(building_mask, grid, opts) if n_building else None
        dtm = terrain(grid)
        mask = masking.result() if masking is not None else np.zeros(grid.shape, bool)
        pieces: list[tuple[F64, F32, npt.NDArray[np.uint8], int]] = []
        g_sp = w_sp = 0.0
        if opts.ground and n_ground:
            gxyz, gn, g_sp = _ground_fill(grid, dtm, mask, opts, rng)
            pieces.append((gxyz, gn, np.full(len(gxyz), KIND_GROUND, np.uint8), GROUND))
        quads, qn = np.zeros((0, 4, 3)), np.zeros((0, 3), np.float32)
        pending = None
        if opts.walls != "none" and mask.any():
            footprints: Any = None
            if outline is not None:
                footprints = outline.result()
            elif opts.footprints:
                from citylod.io.footprints import read_footprints

                footprints = read_footprints(opts.footprints)
            has = grid.planes[_B_N] > 0
            w_sp = grid.cell / np.sqrt(max(1.0, float(np.median(grid.planes[_B_N][has]))) * opts.wall_density)
            if opts.walls == "points":
                wxyz, wn, wk = _wall_points(wall_edges(grid, dtm, mask, opts, footprints), w_sp, rng)
                pieces.append((wxyz, wn, wk, BUILDING))
            elif quads_later:
                pending = pool.submit(_quads_of, grid, dtm, mask, opts, footprints, tiles_dir)
            else:
                quads, qn, *_ = _quads_of(grid, dtm, mask, opts, footprints)
        if opts.roof_fill and mask.any():
            rxyz, rn = _roof_fill(grid, mask, rng)
            pieces.append((rxyz, rn, np.full(len(rxyz), KIND_ROOF, np.uint8), BUILDING))
        mean_int = grid.class_intensity / np.maximum(grid.class_n, 1.0)
        if pieces:
            xyz = np.concatenate([pc[0] for pc in pieces])
            nrm = np.concatenate([pc[1] for pc in pieces])
            kind = np.concatenate([pc[2] for pc in pieces])
            cls = np.concatenate([np.full(len(pc[0]), pc[3], np.uint8) for pc in pieces])
        else:
            xyz, nrm = np.zeros((0, 3)), np.zeros((0, 3), np.float32)
            kind, cls = np.zeros(0, np.uint8), np.zeros(0, np.uint8)
        inten = np.clip(np.round(mean_int[cls]), 0, 65535).astype(np.uint16)
    finally:
        pool.shutdown(wait=False)  # its thread ends with the walls' task, if there is one
    return Augmentation(xyz, nrm, kind, cls, inten, quads, qn, g_sp, w_sp,
                        seconds={"augment": time.perf_counter() - t0}, walls_pending=pending)


def _quads_of(grid: CellGrid, dtm: F64, mask: npt.NDArray[np.bool_], opts: CompleteOptions,
              footprints: Sequence[Any] | FootprintOutline | None, tiles_dir: str | PathLike[str] | None = None
              ) -> tuple[F64, F32, float, list[Any] | None]:
    """The wall quads and normals, the seconds they took, and their tiles when written to ``tiles_dir``."""
    t0 = time.perf_counter()
    quads, qn = _wall_quads(wall_edges(grid, dtm, mask, opts, footprints), opts.sink_m)
    tiles = None
    if tiles_dir is not None:
        walls = _empty()
        walls.quads, walls.quad_normals = quads, qn
        tiles = write_wall_tiles(tiles_dir, walls)
    return quads, qn, time.perf_counter() - t0, tiles


def augment(files: Sequence[str | PathLike[str]], opts: CompleteOptions = CompleteOptions(), *,
            lo: F64 | None = None, hi: F64 | None = None) -> Augmentation:
    """Scan ``files`` and compute what completes them. ``lo``/``hi``: the cloud's bounds (from the headers
    when not given)."""
    if lo is None or hi is None:
        from citylod.io.las import read_metadata

        meta = read_metadata(files, crs="EPSG:4978")  # the CRS does not matter for bounds
        lo, hi = meta.lo, meta.hi
    t0 = time.perf_counter()
    grid = scan_grid(files, lo, hi, opts.cell_m)
    t_scan = time.perf_counter() - t0
    aug = augment_grid(grid, opts)
    aug.seconds = {"scan": t_scan, **aug.seconds}
    return aug


def write_las(aug: Augmentation, path: str | PathLike[str], template: str | PathLike[str]) -> Path:
    """Write the added points as a LAS file with the header (point format, scale, offset, CRS) of
    ``template``, every point flagged *synthetic* (ASPRS LAS 1.2+ classification bit 5).

    Written to a temporary name and renamed, so a half-written file never exists.
    """
    import laspy

    out = Path(path)
    try:
        with laspy.open(template) as reader:
            header = reader.header
    except Exception as exc:
        raise InputError(f"cannot read the header to copy ({exc})", template) from exc
    new = laspy.LasHeader(point_format=header.point_format.id, version=str(header.version))
    new.scales = header.scales
    new.offsets = header.offsets
    for vlr in header.vlrs:
        new.vlrs.append(vlr)
    las = laspy.LasData(new)
    las.x, las.y, las.z = aug.xyz[:, 0], aug.xyz[:, 1], aug.xyz[:, 2]
    las.classification = aug.classification
    las.intensity = aug.intensity
    las.return_number = np.ones(len(aug.xyz), np.uint8)
    las.number_of_returns = np.ones(len(aug.xyz), np.uint8)
    las.synthetic = np.ones(len(aug.xyz), bool)
    atomic_write(out, lambda t: las.write(str(t)), suffix=out.suffix)
    return out


def wall_mesh(aug: Augmentation, center: F64, rgb: tuple[int, int, int] = (214, 206, 192)) -> Any:
    """The wall quads as a :class:`~citylod.io.tiles3d.MeshData` relative to ``center`` (two triangles per
    quad, one colour)."""
    from citylod.io.tiles3d import MeshData

    q = len(aug.quads)
    pos = (aug.quads.reshape(-1, 3) - np.asarray(center)).astype(np.float32)
    base = (np.arange(q, dtype=np.uint32) * 4)[:, None]
    faces = np.concatenate([base + np.array([0, 1, 2], np.uint32), base + np.array([0, 2, 3], np.uint32)])
    colors = np.empty((4 * q, 4), np.uint8)
    colors[:, :3] = rgb
    colors[:, 3] = 255
    return MeshData(positions=pos, faces=faces.astype(np.uint32), colors=colors, name="walls")


# ---------------------------------------------------------------------------------- the build's hooks
def complete_inputs(paths: Sequence[Path], meta: Any, target: Path, opts: CompleteOptions, crs: Any = None
                    ) -> tuple[Augmentation, list[Path], Any]:
    """The point build's pre-pass: scan ``paths``, write the added points to ``target`` (a LAS file in the
    build's scratch folder), and return the augmentation with the file list and metadata the build then
    reads (input files first, unchanged)."""
    from citylod.io.las import read_metadata

    refused = _geographic(meta)
    if refused:
        return _empty(refused), list(paths), meta
    aug = augment(paths, opts, lo=meta.lo, hi=meta.hi)
    extra = _write_added(aug, meta, target, paths[0])
    if extra is None:
        return aug, list(paths), meta
    files = [*paths, extra]
    return aug, files, read_metadata(files, crs if crs is not None else meta.crs)


def _geographic(meta: Any) -> str | None:
    from citylod.io.crs import is_geographic

    if not is_geographic(meta.crs):
        return None
    msg = (f"the points are in degrees ({meta.crs.name}): completion needs metric coordinates; "
           "reproject the files (e.g. to UTM) to complete them")
    warnings.warn(msg, stacklevel=3)
    return msg


def _write_added(aug: Augmentation, meta: Any, target: Path, template: Any) -> Path | None:
    """Write the added points (kept inside the input's bounds, which the octree's cube was sized to) as
    ``target``; None when there are none."""
    if len(aug.xyz) == 0:
        return None
    t0 = time.perf_counter()
    aug.xyz = np.clip(aug.xyz, meta.lo, meta.hi)
    target.parent.mkdir(parents=True, exist_ok=True)
    out = write_las(aug, target, template)
    aug.seconds["write"] = time.perf_counter() - t0
    return out


def complete_records(recs: np.ndarray, meta: Any, target: Path, opts: CompleteOptions, *,
                     quads_later: bool = False, tiles_dir: str | PathLike[str] | None = None,
                     outline: Future[FootprintOutline] | None = None) -> tuple[Augmentation, Path | None]:
    """The in-memory point build's hook, after it decoded its input into ``recs``: complete them
    (:func:`scan_records`, :func:`augment_grid`) and write the added points to ``target`` (None: nothing
    added). ``quads_later``, ``tiles_dir``: wall quads (and their tiles) are still being computed on return;
    ``outline``: the footprints' outline started earlier (see :func:`augment_grid`)."""
    refused = _geographic(meta)
    if refused:
        return _empty(refused), None
    t0 = time.perf_counter()
    grid = scan_records(recs, meta.lo, meta.hi, opts.cell_m, meta.files[0].path if meta.files else None)
    t_scan = time.perf_counter() - t0
    aug = augment_grid(grid, opts, quads_later=quads_later, tiles_dir=tiles_dir, outline=outline)
    aug.seconds = {"scan": t_scan, **aug.seconds}
    return aug, _write_added(aug, meta, target, meta.files[0].path)


def add_wall_tiles(out_dir: str | PathLike[str], root: Any, aug: Augmentation, block_m: float = 128.0) -> Any:
    """Write the wall quads as tiles of ``block_m`` square blocks (:func:`write_wall_tiles`, unless
    :attr:`Augmentation.wall_tiles` holds them, written to ``out_dir``) and return a new root whose children
    are the point octree's root and the wall tiles (3D Tiles REPLACE: a root without content that always
    refines, so the walls show at every level of the points). Waits for quads still being computed."""
    from citylod.io.tiles3d import TileSpec

    aug.wait_walls()
    if len(aug.quads) == 0:
        return root
    walls = aug.wall_tiles if aug.wall_tiles is not None else write_wall_tiles(out_dir, aug, block_m)
    children = [root, *walls]
    lo = np.min([c.lo for c in children], axis=0)
    hi = np.max([c.hi for c in children], axis=0)
    return TileSpec(key="complete", level=0, center=(lo + hi) / 2.0, lo=lo, hi=hi,
                    geometric_error=max(float(root.geometric_error), float(np.linalg.norm(hi - lo))),
                    children=children, extras={"points": 0, "triangles": 0, "quads": 0})


def _col_min(a: F64) -> F64:
    """``a.min(axis=0)`` of an (N, k) array, column by column: numpy reduces a few columns of many rows
    twenty times slower along axis 0."""
    return np.array([a[:, k].min() for k in range(a.shape[1])])


def write_wall_tiles(out_dir: str | PathLike[str], aug: Augmentation, block_m: float = 128.0) -> list[Any]:
    """Write the wall quads of ``aug`` as tiles of ``block_m`` square blocks (``walls/X-Y``) and return their
    :class:`~citylod.io.tiles3d.TileSpec` (none without quads)."""
    from citylod.io.tiles3d import TileContent, TileSpec, write_content

    if len(aug.quads) == 0:
        return []
    q = aug.quads[:, :, :2]
    mid = (((q[:, 0] + q[:, 1]) + q[:, 2]) + q[:, 3]) / 4.0  # the corners' mean (numpy's ``mean`` is slower)
    b = np.floor((mid - _col_min(mid)) / block_m).astype(np.int64)
    keys = b[:, 0] * (1 << 20) + b[:, 1]
    order = np.argsort(keys, kind="stable")
    bounds_ = np.flatnonzero(np.diff(keys[order])) + 1
    tiles = []
    for part in np.split(order, bounds_):
        sub = Augmentation(aug.xyz[:0], aug.normals[:0], aug.kind[:0], aug.classification[:0],
                           aug.intensity[:0], aug.quads[part], aug.quad_normals[part])
        corners = sub.quads.reshape(-1, 3)
        lo, hi = _col_min(corners), -_col_min(-corners)
        center = (lo + hi) / 2.0
        bx, by = (int(v) for v in b[part[0]])
        key = f"walls/{bx}-{by}"
        uri = write_content(out_dir, key, TileContent(meshes=[wall_mesh(sub, center)]))
        tiles.append(TileSpec(key=key, level=1, center=center, lo=lo, hi=hi, geometric_error=0.0,
                              content=uri, extras={"points": 0, "triangles": 2 * len(part),
                                                   "quads": len(part), "walls": True}))
    return tiles


__all__ = [
    "KIND_GROUND",
    "KIND_ROOF",
    "KIND_STEP",
    "KIND_WALL",
    "MAX_CELLS",
    "WALL_MODES",
    "Augmentation",
    "CellGrid",
    "CompleteOptions",
    "FootprintOutline",
    "add_wall_tiles",
    "augment",
    "augment_grid",
    "building_mask",
    "complete_inputs",
    "complete_records",
    "footprint_edges",
    "footprint_outline",
    "scan_grid",
    "scan_records",
    "start_footprint_outline",
    "terrain",
    "wall_edges",
    "wall_mesh",
    "write_las",
    "write_wall_tiles",
]
