"""Bounded-error TINs of height grids: the per-tile kernel of the DSM tile tree (Wahl et al. 2004).

A tile is a local grid of heights (typically 129×129). Its full-resolution surface is the grid
triangulated with the fixed diagonal from sample (i, j) to (i+1, j+1) in every cell whose four corners
are valid. `triangulate` returns a TIN whose vertices are grid samples and whose vertical L∞ distance
to that surface, over every valid cell, is at most ``max_error``. The bound is exact: the maximum of
|TIN − grid| is attained at a vertex of the overlay of the two piecewise-linear surfaces, i.e. at a
grid sample or where a TIN edge crosses a grid row, column or cell diagonal, and all of those are
evaluated. A vertical bound of ε puts every point of either surface within vertical distance ε of the
other, so it also bounds the symmetric Hausdorff distance.

Conventions
-----------
* Vertices are returned as grid indices ``(row, col)``; row 0 is the north edge, as in rasters.
* Faces are counter-clockwise seen from above (+z) in the frame x = col (east), y = −row (north).
* A cell (i, j) spans samples i..i+1 × j..j+1 and is valid iff its four corners are valid.

Algorithm
---------
Greedy insertion into a Delaunay triangulation (Garland & Heckbert 1995, "Fast polygonal
approximation of terrains and height fields", algorithm III; half-edge layout after mapbox/delatin),
then bounded vertex removal, compiled with numba in `citylod.lod.kernels.tin_kernels`:

1. Forced vertices, inserted first: the four corners; along each of the four grid borders a 1D
   bounded-error simplification (to half the bound) of each run of valid samples (`simplify_polyline`; depends only on
   the border's own samples, so neighbouring tiles sharing that border choose the same vertices);
   every sample on the boundary of the valid region R (the union of valid cells); ``must_include``.
2. Seeds: every interior sample at an even row and column whose 3×3 neighbourhood departs from the
   bilinear interpolation of its corners by more than ``SEED_DEVIATION`` times the bound (roofs' ridges
   and edges, façades, trees) is inserted before any error is evaluated. The greedy phase would insert
   such samples, or their neighbours, one at a time, rescanning ever smaller triangles after each; seeded,
   it starts from small triangles where the surface is rough. Seeds are not forced: step 4 removes those
   the bound does not need. On the benchmark city a quarter of the kernel's time goes, for 0.1 % more
   triangles. With ``lattice``, the samples on a regular lattice of that step are seeds too: a TIN with
   few vertices (a coarse tile whose target is out of reach on its grid) otherwise rescans large
   triangles at every insertion (`SEED_LATTICE`).
3. Greedy phase: every triangle keeps its exact error (samples + edge crossings) and its candidate
   sample in a max-heap; the worst triangle's candidate is inserted and the touched triangles are
   re-evaluated, until no triangle exceeds ``max_error``. While a sample of a triangle is above the
   bound, its worst sample is the candidate and its crossings are not evaluated (they could only
   raise its key); they are once its samples are within the bound.
4. Decimation (``decimate=True``, the default; without it, no seeds either unless asked for): greedy
   insertion overshoots, mostly near façades where the crossings force vertices that later insertions
   make redundant. Each vertex that is neither forced nor on the grid border is removed, newest first,
   when its hole can be re-triangulated with every new triangle within the bound, samples and crossings
   evaluated exactly as in step 3 (a dynamic programme over the hole's triangulations, `tin_kernels._decimate`). On the
   benchmark city rasters (0.5 m on 1 m samples) it removes a quarter of the triangles, leaving 0.9×
   what pydelatin makes with its samples-only bound, in about the time the lazy crossings of step 3
   save.

Ties in the Delaunay criterion (every grid cell is cocircular) are broken by a symbolic perturbation
under which the Delaunay triangulation of a full grid is exactly the grid surface; so inserting every
sample of a region reproduces it and the greedy phase always terminates. The result of step 4 is no
longer Delaunay; nothing downstream needs it to be.

No-data, and why the result is correct: every unit edge of ∂R has both ends forced, and a unit-length
edge between two vertices is always Delaunay (its diametral disk holds no other lattice point), so all
of ∂R consists of TIN edges (on the grid border, hull edges, whose adjacent-cell validity is constant
because every validity change along the border is a forced vertex). Hence no triangle's interior
meets ∂R: each triangle lies wholly in R or wholly outside, and the cell of its centroid tells which.
Triangles outside are dropped and never evaluated; those inside cover every valid cell exactly once.
Step 4 keeps this: the forced vertices (∂R among them) stay, so a removed vertex's star, and the
triangles that replace it, lie inside R, and every edge of ∂R stays a TIN edge.

Borders: the border vertex set of a tile is the 1D simplification of its border samples, plus (i)
samples where the validity of the adjacent cells changes (no-data touching the border) and (ii) the
rare border samples that the greedy phase needs when the exact 2D bound cannot be met otherwise
(e.g. a wall running along the row next to a flat border: no TIN with a long border edge can follow
it within ε). (i) and (ii) depend on a tile's interior, so a builder that wants bitwise-identical
borders passes each tile the union of its neighbours' border vertices on the shared border as
``must_include`` (the greedy phase then restores the bound around them; repeat until no border set
grows, which takes one or two rounds and converges because the sets only grow).
`TinResult.border_added` counts (ii). Step 4 never removes a border vertex, so the border vertex set
is that of the greedy phase.

This module does no I/O and imports neither VTK nor Qt.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from citylod.lod.kernels import tin_kernels as _k
from citylod.lod.kernels.aot import kernel

I32 = npt.NDArray[np.int32]
I64 = npt.NDArray[np.int64]
F64 = npt.NDArray[np.float64]
B = npt.NDArray[np.bool_]

#: Borders are simplified to this fraction of the bound (see `forced_vertices`).
BORDER_ERROR_FRACTION = 0.5

#: Seeds (step 2 of the module docstring): a sample at an even row and column whose 3×3 neighbourhood departs
#: from the bilinear interpolation of its corners by more than this many times the bound. Measured on the
#: leaves of the 2049² benchmark city (0.5 m bound, one process, call by call against unseeded), kernel
#: time and triangles: 0.5× 0.76 and +0.5 %, 1× 0.76 and +0.3 %, 2× 0.77 and +0.1 %, 4× 0.78 and +0.1 %;
#: every 8th sample without a test 0.87–0.89; the test at every sample, not every second, 1.14× this.
SEED_DEVIATION = 2.0

#: The lattice seeds of the DSM builder's coarse tiles whose target is out of reach on their grid (a façade
#: between two samples; step 2 of the module docstring; ``lattice=``): every 16th row and column. Measured
#: call by call over the 87 coarse-tile TINs of the 2049² benchmark city (one process, alternating): kernel
#: time 0.73× for 5.6 % fewer triangles (8: 0.80×, 32: 0.82×). Not for the others: on the city's leaves,
#: whose rough seeds are dense already, 1.03× for +0.2 %; on the natural terrain's coarse tiles (built to
#: their target) 8–19 % more triangles, the removal pass keeping many of them on smooth ground.
SEED_LATTICE = 16

#: Largest grid side for which the integer Delaunay predicates are exact in int64.
MAX_GRID_SIDE = 32768


@dataclass(frozen=True)
class TinResult:
    """A triangulated tile.

    Attributes
    ----------
    vertices_ij
        (V, 2) int32 grid indices (row, col) of the vertices.
    faces
        (F, 3) int32 vertex indices, counter-clockwise in (x = col, y = −row).
    border_added
        Border samples the greedy phase added beyond the 1D-simplified and validity-change ones.
    stuck
        Triangles left above the bound for want of a sample to insert; 0 unless there is a bug.
    """

    vertices_ij: I32
    faces: I32
    border_added: int
    stuck: int


def _valid_mask(heights: F64, valid: npt.ArrayLike | None) -> B:
    finite = np.isfinite(heights)
    if valid is None:
        return finite
    v = np.asarray(valid, dtype=bool)
    if v.shape != heights.shape:
        raise ValueError(f"valid has shape {v.shape}, heights {heights.shape}")
    return v & finite


def _check_error(max_error: float) -> float:
    e = float(max_error)
    if not e >= 0.0:
        raise ValueError(f"max_error must be >= 0, got {max_error!r}")
    return e


def cell_validity(valid: npt.ArrayLike) -> B:
    """(H−1, W−1) bool: cell (i, j) is valid iff samples (i..i+1, j..j+1) all are."""
    v = np.asarray(valid, dtype=bool)
    return v[:-1, :-1] & v[1:, :-1] & v[:-1, 1:] & v[1:, 1:]


def simplify_polyline(z: npt.ArrayLike, max_error: float, *, valid: npt.ArrayLike | None = None) -> I64:
    """Indices of a bounded-error simplification of the polyline through (k, z[k]).

    The linear interpolation of ``z`` between consecutive kept indices is within ``max_error``
    (vertically) of every sample; in 1D that bounds the whole polyline exactly. With ``valid``, each
    maximal run of valid samples is simplified on its own (its ends are kept; no-data is skipped).
    Depends only on ``z``, ``valid`` and ``max_error`` (scanned in index order), so two tiles sharing a
    border get the same indices.

    Parameters
    ----------
    z
        (N,) heights.
    max_error
        Vertical bound, >= 0.
    valid
        Optional (N,) bool; non-finite heights are invalid anyway.

    Returns
    -------
    (K,) int64 increasing indices; the first and last valid samples are always included.

    Examples
    --------
    >>> simplify_polyline([0.0, 1.0, 2.0, 3.0, 0.0], 0.1).tolist()
    [0, 3, 4]
    """
    za = np.ascontiguousarray(z, dtype=np.float64).reshape(-1)
    v = _valid_mask(za, valid)
    keep = kernel(_k.simplify_runs, np.where(v, za, 0.0), v, _check_error(max_error))
    return np.flatnonzero(keep).astype(np.int64)


def forced_vertices(heights: npt.ArrayLike, valid: npt.ArrayLike | None, max_error: float) -> B:
    """(H, W) bool: the samples `triangulate` inserts before the greedy phase (``must_include`` aside).

    The four corners, the 1D simplification of each border's valid runs to
    ``BORDER_ERROR_FRACTION * max_error`` (the slack left makes the 2D bound reachable near the
    border without adding border samples in most tiles), and every sample on the boundary of the
    valid region. On a border with valid cells along it, the border part depends only
    on that border's samples.
    """
    h = np.ascontiguousarray(heights, dtype=np.float64)
    v = _valid_mask(h, valid)
    e = _check_error(max_error) * BORDER_ERROR_FRACTION
    return kernel(_k.forced_mask, np.where(v, h, 0.0), v, cell_validity(v), e)


def build(
    heights: npt.ArrayLike,
    valid: npt.ArrayLike | None,
    max_error: float,
    *,
    must_include: npt.ArrayLike | None = None,
    decimate: bool = True,
    seed: bool | None = None,
    lattice: int = 0,
    plane: tuple[float, float] | None = None,
) -> TinResult:
    """`triangulate`, returning a `TinResult` with diagnostics. See `triangulate`.

    ``plane``: (metres per column, per row). Given, a triangle's error is the distance of the samples to its
    plane (the vertical error times the plane's |n_z|), not the vertical one, so steep triangles along
    façades stop attracting insertions; there is then no bound (the caller certifies), and no seeds but the
    ``lattice`` (the rough-sample test is built on the vertical bound and would seed façades). The DSM
    builder's Hausdorff metric uses it."""
    h = np.ascontiguousarray(heights, dtype=np.float64)
    if h.ndim != 2 or h.shape[0] < 1 or h.shape[1] < 1:
        raise ValueError(f"heights must be a non-empty 2D grid, got shape {h.shape}")
    H, W = h.shape
    if max(H, W) > MAX_GRID_SIDE:
        raise ValueError(f"grid side {max(H, W)} exceeds {MAX_GRID_SIDE}; split it into tiles")
    e = _check_error(max_error)
    if lattice < 0 or lattice % 2:
        raise ValueError(f"lattice must be even and >= 0, got {lattice}")
    v = _valid_mask(h, valid)
    empty_faces = np.zeros((0, 3), dtype=np.int32)
    if not v.any():
        return TinResult(np.zeros((0, 2), dtype=np.int32), empty_faces, 0, 0)
    if H == 1 or W == 1:
        # No area: a polyline. Its vertices are returned (useful as a border), with no faces.
        keep = simplify_polyline(h.reshape(-1), e, valid=v.reshape(-1))
        rows, cols = (np.zeros_like(keep), keep) if H == 1 else (keep, np.zeros_like(keep))
        return TinResult(np.stack([rows, cols], axis=1).astype(np.int32), empty_faces, 0, 0)
    cv = cell_validity(v)
    if not cv.any():
        return TinResult(np.zeros((0, 2), dtype=np.int32), empty_faces, 0, 0)

    hz = np.where(v, h, 0.0)
    forced = kernel(_k.forced_mask, hz, v, cv, e * BORDER_ERROR_FRACTION)  # forced_vertices
    if must_include is not None:
        mi = np.asarray(must_include, dtype=np.int64).reshape(-1, 2)
        if mi.size and (mi.min() < 0 or (mi[:, 0] >= H).any() or (mi[:, 1] >= W).any()):
            raise ValueError("must_include holds indices outside the grid")
        forced[mi[:, 0], mi[:, 1]] = True
    fx, fy = kernel(_k.z_ordered, forced)
    seeded = (decimate if seed is None else seed) and plane is None
    sx, sy = (0.0, 0.0) if plane is None else (float(plane[0]), float(plane[1]))
    if plane is not None and not (sx > 0 and sy > 0):
        raise ValueError(f"plane spacings must be > 0, got {plane}")
    vx, vy, tris, stuck, border_added = kernel(_k.build_tin, hz, np.ascontiguousarray(cv), fx, fy, e, True,
                                               bool(decimate), SEED_DEVIATION * e if seeded else math.inf,
                                               int(lattice) if seeded or plane is not None else 0, sx, sy)
    # keep the triangles inside R (centroid cell valid; see the module docstring for why that suffices),
    # and the vertices in some face, in index order, the faces renumbered
    vertices, faces = kernel(_k.live_mesh, vx, vy, tris, cv)
    return TinResult(vertices, faces, border_added, stuck)


def triangulate(
    heights: npt.ArrayLike,
    valid: npt.ArrayLike | None,
    max_error: float,
    *,
    must_include: npt.ArrayLike | None = None,
    decimate: bool = True,
    seed: bool | None = None,
    lattice: int = 0,
) -> tuple[I32, I32]:
    """Bounded-error TIN of a height grid (greedy insertion, then vertex removal; exact bound).

    Parameters
    ----------
    heights
        (H, W) float64 heights, any H, W >= 1.
    valid
        (H, W) bool, False for no-data; None means "all finite samples". Non-finite heights are
        no-data regardless.
    max_error
        Bound on the vertical distance to the grid surface over every valid cell, >= 0 (``inf``
        gives the Delaunay triangulation of the forced vertices only).
    must_include
        Optional (K, 2) (row, col) samples that must be vertices, e.g. a neighbour's border vertices
        or the vertices of a previous triangulation (then the result refines it; see `refine`).
    decimate
        Remove the vertices the bound does not need after the greedy phase (module docstring, step
        4). False gives the plain greedy-insertion Delaunay TIN.
    seed
        Insert the seeds (module docstring, step 2) before the greedy phase. Default: when decimating
        (without decimation, every seed would stay a vertex).
    lattice
        With the seeds, also seed every interior sample whose row and column are multiples of this (even;
        0: none; the DSM builder's coarse tiles use `SEED_LATTICE`).

    Returns
    -------
    vertices_ij
        (V, 2) int32 (row, col) grid indices. Vertex heights are ``heights[row, col]``.
    faces
        (F, 3) int32, counter-clockwise seen from above in (x = col, y = −row). Empty when no cell is
        valid; for a 1×N or N×1 grid, empty too, with the vertices of the simplified polyline.

    Notes
    -----
    Guarantees, for ``stuck == 0`` (always observed): |TIN − grid| <= max_error at every sample and
    every grid-line crossing of every valid cell, hence everywhere on them; the faces cover each valid
    cell exactly once and no invalid cell; the four corners are vertices when valid; the border
    vertices include the 1D simplification of each border (see the module docstring).
    """
    r = build(heights, valid, max_error, must_include=must_include, decimate=decimate, seed=seed, lattice=lattice)
    return r.vertices_ij, r.faces


def refine(
    heights: npt.ArrayLike,
    valid: npt.ArrayLike | None,
    vertices_ij: npt.ArrayLike,
    extra_vertices: npt.ArrayLike,
    max_error: float = np.inf,
) -> tuple[I32, I32]:
    """Re-triangulate with ``extra_vertices`` added to an existing vertex set.

    The result is the (perturbed) Delaunay triangulation of ``vertices_ij`` ∪ ``extra_vertices`` ∪ the
    forced vertices, further refined by greedy insertion while its error exceeds ``max_error`` (the
    default ``inf`` inserts nothing else); the vertices given are kept, those the greedy phase adds
    may be removed again if the bound does not need them. Use it when a certification against a finer
    grid fails somewhere: add samples there and re-run. Adding vertices re-flips the Delaunay
    triangulation around them, which can raise the error elsewhere: pass the bound as ``max_error``
    to restore it.

    Parameters
    ----------
    heights, valid
        As for `triangulate`, on the same grid as ``vertices_ij``.
    vertices_ij
        (V, 2) (row, col) of the current vertices.
    extra_vertices
        (K, 2) (row, col) to add.
    max_error
        Bound for the greedy phase.

    Returns
    -------
    vertices_ij, faces
        As for `triangulate`.
    """
    mi = np.concatenate(
        [
            np.asarray(vertices_ij, dtype=np.int64).reshape(-1, 2),
            np.asarray(extra_vertices, dtype=np.int64).reshape(-1, 2),
        ]
    )
    return triangulate(heights, valid, max_error, must_include=mi)


def max_vertical_error(
    heights: npt.ArrayLike,
    valid: npt.ArrayLike | None,
    vertices_ij: npt.ArrayLike,
    faces: npt.ArrayLike,
    vertex_z: npt.ArrayLike | None = None,
) -> tuple[float, tuple[float, float]]:
    """Exact vertical L∞ distance between a TIN and the grid surface, over what the TIN covers.

    Evaluated at every valid grid sample in a face and at every crossing of a face edge with a grid
    row, column or cell diagonal whose grid triangle is valid; that is where the maximum of the
    difference of two piecewise-linear surfaces lies. Independent of `triangulate`'s bookkeeping (its
    own float barycentrics and crossing enumeration), so it can certify any TIN on the grid.

    Parameters
    ----------
    heights
        (H, W) grid heights.
    valid
        (H, W) bool or None.
    vertices_ij
        (V, 2) integer (row, col) vertex positions on the grid.
    faces
        (F, 3) vertex indices.
    vertex_z
        Optional (V,) vertex heights (e.g. quantised); default ``heights`` at the vertices.

    Returns
    -------
    err
        The maximum vertical distance (0.0 for no faces).
    where
        (row, col) float of a point where it is attained (NaN, NaN when there is none).
    """
    h = np.ascontiguousarray(heights, dtype=np.float64)
    v = np.ascontiguousarray(_valid_mask(h, valid))
    vij = np.asarray(vertices_ij, dtype=np.int64).reshape(-1, 2)
    f = np.ascontiguousarray(np.asarray(faces, dtype=np.int64).reshape(-1, 3))
    if vertex_z is None:
        vz = h[vij[:, 0], vij[:, 1]] if len(vij) else np.zeros(0)
    else:
        vz = np.asarray(vertex_z, dtype=np.float64).reshape(-1)
    if len(f) == 0:
        return 0.0, (float("nan"), float("nan"))
    err, wr, wc = _k.eval_max_error(
        np.where(v, h, 0.0), v, vij[:, 0].copy(), vij[:, 1].copy(), np.ascontiguousarray(vz), f
    )
    return float(err), (float(wr), float(wc))


def coverage_check(valid: npt.ArrayLike, vertices_ij: npt.ArrayLike, faces: npt.ArrayLike) -> F64:
    """Area of each cell covered by the faces, summed over faces: (H−1, W−1) float64.

    A correct tile has 1 on every valid cell and 0 on every invalid one (up to rounding); a value
    above 1 means overlapping faces.
    """
    v = np.asarray(valid, dtype=bool)
    vij = np.asarray(vertices_ij, dtype=np.float64).reshape(-1, 2)
    f = np.ascontiguousarray(np.asarray(faces, dtype=np.int64).reshape(-1, 3))
    shape = (max(v.shape[0] - 1, 0), max(v.shape[1] - 1, 0))
    if len(f) == 0 or 0 in shape:
        return np.zeros(shape)
    return _k.cell_coverage(shape, vij[:, 0].copy(), vij[:, 1].copy(), f)
