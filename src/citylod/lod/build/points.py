"""Point clouds (LAS/LAZ) to a 3D Tiles octree with exact per-node error and hybrid plane quads.

The build is out-of-core, after PotreeConverter 2 (Schütz, Ohrhallinger, Wimmer, "Fast out-of-core
octree generation for massive point clouds", 2020):

1. *scan* — tasks decode the input in segments, count points per cell of a 128³ grid over the bounding
   cube and park the decoded segments as raw ``.npy`` (so LAZ is decoded once, not twice);
2. *chunking* — cells are merged top-down into octree nodes ("chunks") of at most ``max_chunk_points``
   points (counting sort over the count pyramid);
3. *distribution* — tasks counting-sort each parked segment by chunk, in place, so a chunk is one slice
   of each segment file (one file per segment, not one per segment and chunk: creating files is slow);
4. *subtrees* — one independent task per chunk builds the chunk's subtree in memory: one compiled
   counting-sort pass partitions the chunk so every node is a contiguous slice, then nodes are built
   children first;
5. *upper levels* — the nodes above the chunks are built from the chunks' representatives;
6. *upper errors* — one task per chunk measures the exact error of its ancestors on its input points.

Memory is bounded by the segment and chunk sizes, not by the input. A cloud under :data:`INLINE_BELOW`
points skips steps 2, 3 and 5: it is decoded (one task per file) into memory and built as one chunk whose
nodes are tasks on threads of the calling process, each submitted once its children are built. The per-node level of detail is
Wahl, Guthe, Klein, "Identifying planes in point-clouds for efficient hybrid rendering", PG 2005: vertex
clustering on a 64³ grid per node, whose representatives are real input points (nearest the mean of the
input points of the cell), and RANSAC planes replaced by textured quads (:mod:`citylod.lod.build.planes`).
Leaves hold every input point exactly once (refinement REPLACE, geometric error 0). An internal node's
``geometricError`` is exact: the largest distance from an input point of its subtree to what the node
draws for it (the representative of its cell, or the quad texel that representative was splatted into),
raised to its children's errors so errors never grow downwards.

Output is written in ``<out>.partial/`` and renamed when complete; an interrupted build resumes there
(a finished chunk is not redone). Node contents are ``tiles/<level>/<x>-<y>-<z>.glb`` (one folder per
level). No VTK, no Qt.
"""

from __future__ import annotations

import json
import os
import pickle
import shutil
import time
import warnings
import zlib
from collections.abc import Iterator, Sequence
from concurrent.futures import Executor
from contextlib import contextmanager
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numba
import numpy as np
import numpy.typing as npt

from citylod._version import __version__
from citylod.core.fileio import atomic_write, atomic_write_bytes, discard_partial_on_refusal, publish_dir
from citylod.core.palette import ASPRS_CLASS_RGB
from citylod.io.crs import missing_vertical_datum
from citylod.io.image import encode_png
from citylod.io.las import POINT_DTYPE, iter_points, point_fields, read_metadata
from citylod.io.tiles3d import (
    MeshData,
    PointData,
    TileContent,
    TileSpec,
    content_path,
    write_content,
    write_tileset,
)
from citylod.lod.build.complete import (
    CompleteOptions,
    add_wall_tiles,
    complete_inputs,
    complete_records,
    start_footprint_outline,
)
from citylod.lod.build.executor import Completions, make_executor, progress_bar, run_tasks
from citylod.lod.build.planes import find_planes, quad_mesh_arrays, splat_colors
from citylod.lod.build.refine import REFINED, RefineOptions, refine_records
from citylod.lod.kernels.octree import (
    CLUSTER_BITS,
    MAX_LEVEL,
    QBITS,
    bounds,
    cluster,
    gather_points,
    grid_coord,
    lookup_error,
    morton_order,
    partition,
    point_columns,
    quantize,
    shuffled_runs,
)
from citylod.lod.kernels.sort import counting_sort

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Recs = npt.NDArray[np.void]

#: Points per run of the shuffled order within a node (see :func:`~citylod.lod.kernels.octree.shuffled_runs`).
_BATCH = 32

#: Levels of the scan grid: 2^7 = 128 cells per axis.
SCAN_BITS = 7
#: Below this many points a build runs in the calling process when no worker count is given: starting
#: spawned workers (each imports numpy, numba and laspy) costs more than two cores save.
INLINE_BELOW = 3_000_000


@dataclass(frozen=True)
class PointBuildReport:
    """What a point-cloud build produced and how fast.

    Attributes
    ----------
    output
        The tileset folder.
    points
        Input points (each is in exactly one leaf).
    nodes, leaves, levels, chunks
        Octree nodes, leaf nodes, depth + 1, out-of-core chunks.
    quads
        Plane quads over all internal nodes; ``quad_points`` representatives they replaced.
    seconds, points_per_s
        Wall time of the whole build and input points per second.
    bytes
        Size of the written tile contents.
    decode_floor_s
        Time plain laspy takes to decode the same files in this process, when measured.
    """

    output: Path
    points: int
    nodes: int
    leaves: int
    levels: int
    chunks: int
    quads: int
    quad_points: int
    seconds: float
    points_per_s: float
    bytes: int
    hybrid: bool
    root_error: float
    decode_floor_s: float | None = None
    complete: str | None = None
    refined: int | None = None  # roof points moved by --refine-roofs (None: not asked)

    def summary(self) -> str:
        lines = [
            f"points     {self.points:,} -> {self.output}",
            f"octree     {self.nodes:,} nodes ({self.leaves:,} leaves), {self.levels} levels, "
            f"{self.chunks} chunks, root error {self.root_error:.3g} m",
            f"hybrid     {'on' if self.hybrid else 'off'}: {self.quads:,} quads replacing "
            f"{self.quad_points:,} points",
            f"size       {self.bytes / 1e6:.1f} MB",
            f"time       {self.seconds:.2f} s, {self.points_per_s / 1e6:.2f} M points/s",
        ]
        if self.decode_floor_s:
            lines.append(f"floor      laspy decode {self.decode_floor_s:.2f} s "
                         f"(build = {self.seconds / self.decode_floor_s:.1f}× decode)")
        if self.complete:
            lines.append(self.complete)
        if self.refined is not None:
            lines.append(f"refined    {self.refined:,} roof points (flagged synthetic = 2)")
        return "\n".join(lines)


@dataclass(frozen=True)
class _Params:
    """Everything a task needs; small and picklable (tasks run in other processes or on Dask workers)."""

    out: str
    tmp: str
    cube_lo: tuple[float, float, float]
    cube_size: float
    has_rgb: bool
    hybrid: bool
    phi: float
    max_leaf_points: int
    intensity_scale: float = 255.0
    memory: bool = False  # intermediates live in this process (threads), not in files (processes)
    refine: RefineOptions | None = None  # roof refinement (citylod.lod.build.refine), per chunk

    def node_size(self, level: int) -> float:
        return self.cube_size / (1 << level)


@dataclass
class _Summary:
    """A built node as its parent needs it: its tile and its representatives (with cell sums)."""

    level: int
    idx: tuple[int, int, int]
    spec: TileSpec
    recs: Recs           # (K,) POINT_DTYPE representatives (a leaf: all its points)
    q: I64               # (K, 3)
    xyz: F64             # (K, 3) their positions
    sums: F64            # (K, 3) sum of the input positions each representative stands for
    counts: I64          # (K,)
    lo: F64
    hi: F64


@dataclass
class _Stats:
    nodes: int = 0
    leaves: int = 0
    quads: int = 0
    quad_points: int = 0
    max_level: int = 0
    bytes: int = 0
    refined: int = 0

    def add(self, other: _Stats) -> None:
        self.nodes += other.nodes
        self.leaves += other.leaves
        self.quads += other.quads
        self.quad_points += other.quad_points
        self.max_level = max(self.max_level, other.max_level)
        self.bytes += other.bytes
        self.refined += other.refined


@dataclass
class _ChunkResult:
    cid: int
    root: _Summary
    stats: _Stats = field(default_factory=_Stats)


# ------------------------------------------------------------------------------------------ node kernels
def _xyz(recs: Recs) -> F64:
    """(N, 3) float64 positions of POINT_DTYPE records.

    Column by column: a strided copy over the unaligned records was slower and far less steady.
    """
    out = np.empty((len(recs), 3))
    for k, name in enumerate("xyz"):
        out[:, k] = recs[name]
    return out


def _concat_recs(parts: Sequence[Recs]) -> Recs:
    """``np.concatenate`` of record arrays, as opaque bytes: numpy concatenates records field by field,
    an order of magnitude slower."""
    if len(parts) == 1:
        return parts[0]
    dt = parts[0].dtype
    void = np.dtype((np.void, dt.itemsize))
    return np.concatenate([np.ascontiguousarray(a).view(void) for a in parts]).view(dt)


def _take(a: np.ndarray, idx: I64) -> np.ndarray:
    """``a[idx]`` along the first axis, for (N,) records or (N, k) arrays.

    numpy's fancy indexing copies record by record through the dtype's fields, and (N, 3) rows
    element by element; gathering the records as opaque bytes, and rows with ``take``, is several times
    faster.
    """
    if a.dtype.names is not None:
        return np.ascontiguousarray(a).view(np.dtype((np.void, a.dtype.itemsize)))[idx].view(a.dtype)
    return np.take(a, idx, axis=0)


def _key(level: int, idx: tuple[int, int, int]) -> str:
    return f"{level}/{idx[0]}/{idx[1]}/{idx[2]}"


def _file_key(level: int, idx: tuple[int, int, int]) -> str:
    # One folder per level, not per (level, x, y) as the key would give: creating a folder costs as much
    # as writing a node, and a deep octree has nearly a folder per node.
    return f"{level}/{idx[0]}-{idx[1]}-{idx[2]}"


def _seed(key: str) -> int:
    return zlib.crc32(key.encode())


def _write(p: _Params, key: str, content: TileContent, stats: _Stats) -> str:
    path = str(content_path(p.out, key))
    if not p.memory and os.path.exists(path):  # resumed build: this node was finished before the interruption
        stats.bytes += os.path.getsize(path)
        return Path(path).relative_to(p.out).as_posix()
    uri = write_content(p.out, key, content, atomic=not p.memory)
    stats.bytes += os.path.getsize(path)
    return uri


def _columns(recs: Recs, xyz: F64, order: I64, key: str, center: F64, has_rgb: bool) -> PointData:
    """The drawn points ``order`` of a node, shuffled in runs (:func:`~citylod.lod.kernels.octree.shuffled_runs`)."""
    runs = shuffled_runs(len(order), _seed(key), _BATCH)
    pos, rgb, inten, cls, ret, syn = point_columns(recs, np.ascontiguousarray(xyz), order, runs, _BATCH, center)
    # Added points (citylod.lod.build.complete, or another tool) are flagged; a tile without any has no flag.
    extra = {"synthetic": syn} if syn.any() else {}
    if has_rgb:
        return PointData(positions=pos, rgb=rgb, intensity=inten, classification=cls, return_number=ret,
                         extra=extra)
    # Without RGB, the class colours of the quads (planes.splat_colors) for other clients, so a cloud looks
    # the same at every level there too; citylod reads them back as no RGB (PointData.rgb_from_class).
    return PointData(positions=pos, rgb=ASPRS_CLASS_RGB[cls], rgb_from_class=True, intensity=inten,
                     classification=cls, return_number=ret, extra=extra)


def _leaf(p: _Params, recs: Recs, q: I64, xyz: F64, level: int, idx: tuple[int, int, int],
          stats: _Stats) -> _Summary:
    key = _key(level, idx)
    lo, hi = bounds(xyz)
    center = (lo + hi) / 2.0
    points = _columns(recs, xyz, morton_order(q, level), key, center, p.has_rgb)
    uri = _write(p, _file_key(level, idx), TileContent(points=points), stats)
    stats.nodes += 1
    stats.leaves += 1
    stats.max_level = max(stats.max_level, level)
    spec = TileSpec(key=key, level=level, center=center, lo=lo, hi=hi, geometric_error=0.0, content=uri,
                    extras={"points": len(recs), "triangles": 0, "quads": 0})
    return _Summary(level, idx, spec, recs, q, xyz, xyz, np.ones(len(recs), np.int64), lo, hi)


def _internal(p: _Params, level: int, idx: tuple[int, int, int], children: list[_Summary],
              stats: _Stats, candidates: tuple[Recs, I64, F64, F64, I64] | None = None
              ) -> tuple[_Summary, I64, F64]:
    """Build an internal node from its children's representatives; write its content.

    ``candidates`` (records, q, xyz, sums, counts) are the children's representatives concatenated in
    order, when the caller has them without copying (the points of leaf children lying side by side).

    Returns the node's summary (its ``geometric_error`` still to be set by the caller), and its error
    table: the sorted occupied cells (C,) of its 64³ grid and what it draws for each, (C, 3) float64.
    """
    key = _key(level, idx)
    if candidates is None:
        candidates = (_concat_recs([c.recs for c in children]), np.concatenate([c.q for c in children]),
                      np.concatenate([c.xyz for c in children]), np.concatenate([c.sums for c in children]),
                      np.concatenate([c.counts for c in children]))
    recs, q, xyz, sums, counts = candidates
    cells, rep, csums, ccounts = cluster(q, xyz, sums, counts, level)
    rrecs, rq, rxyz = _take(recs, rep), _take(q, rep), _take(xyz, rep)
    lo = np.min([c.lo for c in children], axis=0)
    hi = np.max([c.hi for c in children], axis=0)
    center = (lo + hi) / 2.0
    texel = p.node_size(level) / (1 << CLUSTER_BITS)
    m = morton_order(rq, level)
    elem = rxyz
    drawn = m
    meshes: list[MeshData] = []
    nquads = 0
    if p.hybrid and len(m) >= 32:
        colors = splat_colors(np.stack([rrecs["red"], rrecs["green"], rrecs["blue"]], axis=1)[m] if p.has_rgb
                              else None, rrecs["classification"][m], rrecs["intensity"][m], p.intensity_scale)
        res = find_planes(_take(rxyz, m) - center, colors, texel, phi=p.phi, seed=_seed(key))
        if res.n_quads:
            elem = rxyz.copy()
            elem[m] = res.elem + center
            drawn = m[~res.replaced]
            pos, faces, uv, atlas = quad_mesh_arrays(res)
            meshes.append(MeshData(positions=pos, faces=faces, uv=uv, texture=encode_png(atlas), name="quads"))
            corners = pos.astype(np.float64) + center
            lo, hi = np.minimum(lo, corners.min(axis=0)), np.maximum(hi, corners.max(axis=0))
            nquads = res.n_quads
            stats.quads += nquads
            stats.quad_points += int(res.replaced.sum())
    points = _columns(rrecs, rxyz, drawn, key, center, p.has_rgb) if len(drawn) else None
    uri = _write(p, _file_key(level, idx), TileContent(meshes=meshes, points=points), stats)
    stats.nodes += 1
    spec = TileSpec(key=key, level=level, center=center, lo=lo, hi=hi, geometric_error=0.0, content=uri,
                    children=[c.spec for c in children],
                    extras={"points": len(drawn), "triangles": 2 * nquads, "quads": nquads,
                            "texel_m": texel})
    return _Summary(level, idx, spec, rrecs, rq, rxyz, csums, ccounts, lo, hi), cells, elem


def _subtree(p: _Params, recs: Recs, q: I64, xyz: F64, level: int, idx: tuple[int, int, int],
             stats: _Stats, pool: Executor | None = None, progress: bool = False) -> _Summary:
    """Build the octree under one node from all its points (in memory: the points of one chunk).

    One compiled pass partitions the points (:func:`~citylod.lod.kernels.octree.partition`), after which every
    node is a contiguous slice; nodes are then built children first. With ``pool`` (threads of this
    process), every node is a task of its own, submitted as soon as its children are built: a small
    cloud built as one chunk keeps both cores busy to the root, which one task per chunk did not (the
    largest chunk held one core for a third of the build while the other idled).
    """
    order, nodes = partition(q, level, idx, p.max_leaf_points, MAX_LEVEL, pool)
    recs, q, xyz = gather_points(recs, q, xyz, order, pool)
    children: list[list[int]] = [[] for _ in range(len(nodes))]
    for k in range(1, len(nodes)):
        children[int(nodes[k, 6])].append(k)
    built: list[_Summary | None] = [None] * len(nodes)

    def build(k: int) -> tuple[int, _Summary, _Stats]:
        st = _Stats()
        lv, x, y, z, a, b, _ = (int(v) for v in nodes[k])
        if not children[k]:
            return k, _leaf(p, recs[a:b], q[a:b], xyz[a:b], lv, (x, y, z), st), st
        kids = [built[c] for c in children[k]]
        # Leaf children hold all their points, side by side in [a, b): their concatenation is a slice.
        cand = ((recs[a:b], q[a:b], xyz[a:b], xyz[a:b], np.ones(b - a, np.int64))
                if all(not children[c] for c in children[k]) else None)
        node, cells, elem = _internal(p, lv, (x, y, z), kids, st, cand)  # type: ignore[arg-type]
        _set_error(node.spec, lookup_error(q[a:b], xyz[a:b], lv, cells, elem))
        return k, node, st

    def done(k: int, node: _Summary, st: _Stats) -> None:
        built[k] = node
        stats.add(st)
        for c in children[k]:
            built[c] = None  # the children's representatives are not needed any more

    if pool is None:
        for k in range(len(nodes) - 1, -1, -1):  # pre-order reversed: children before their parent
            done(*build(k))
    else:
        waiting = [len(c) for c in children]
        bar = progress_bar(total=len(nodes), desc="nodes", disable=not progress, unit="node", leave=False)
        todo: Completions[tuple[int, _Summary, _Stats]] = Completions()
        for k in range(len(nodes) - 1, -1, -1):
            if not children[k]:
                todo.add(pool.submit(build, k))
        try:
            while todo:
                k, node, st = todo.next().result()
                done(k, node, st)
                bar.update(1)
                parent = int(nodes[k, 6])
                if parent >= 0:
                    waiting[parent] -= 1
                    if waiting[parent] == 0:
                        todo.add(pool.submit(build, parent))
        finally:
            todo.cancel()
            bar.close()
    root = built[0]
    assert root is not None
    return root


# How far a drawn quad texel can be from the input (the other direction of the Hausdorff distance): a
# texel filled by the one-texel dilation against cracks lies within a texel diagonal of a splatted texel,
# whose inliers are within half a texel diagonal in the plane and half a texel off it; any point of the
# drawn texel's square adds half a diagonal: (√2/2 + √2 + √(1/2 + 1/4)) · texel ≈ 2.99 · texel.
QUAD_DRAWN_BOUND_TEXELS = 3.0


def _set_error(spec: TileSpec, exact: float) -> None:
    # The exact error of this node's content (input → what is drawn), and for nodes with quads the bound
    # of what is drawn → input; raised to the children's so that refining never increases the error a
    # view sees (3D Tiles clients assume errors shrink downwards). All are true bounds.
    assert spec.extras is not None
    drawn = 0.0
    if spec.extras.get("quads", 0):
        drawn = QUAD_DRAWN_BOUND_TEXELS * float(spec.extras["texel_m"])
    spec.geometric_error = max([exact, drawn, *(c.geometric_error for c in spec.children)])
    spec.extras["exact_error_m"] = exact
    spec.extras["quad_drawn_bound_m"] = drawn


# ----------------------------------------------------------------------------------------------- tasks
@numba.njit(cache=True, nogil=True)
def _scan_kernel(X: np.ndarray, Y: np.ndarray, Z: np.ndarray, scales: F64, offsets: F64, inten: np.ndarray,
                 cls: np.ndarray, ret: np.ndarray, red: np.ndarray, green: np.ndarray, blue: np.ndarray,
                 syn: np.ndarray, recs: Recs, xyz: F64, q: I64, cube_lo: F64, qscale: float, hist: I64,
                 lo: F64, hi: F64) -> None:  # pragma: no cover - compiled
    """Pass 1 over decoded LAS columns (:func:`~citylod.io.las.point_fields`) in one compiled pass,
    without the GIL: POINT_DTYPE records, positions, grid coordinates (as
    :func:`~citylod.lod.kernels.octree.quantize`), the intensity histogram and the bounds, written into the
    given arrays. Done with numpy, the conversion and the four passes after it took 3–4 times as long
    as the compiled pass beyond laspy's decoding of the Delft cloud."""
    sx, sy, sz = scales[0], scales[1], scales[2]
    ox, oy, oz = offsets[0], offsets[1], offsets[2]
    has_rgb = red.shape[0] > 0
    for i in range(X.shape[0]):
        x = X[i] * sx + ox
        y = Y[i] * sy + oy
        z = Z[i] * sz + oz
        r = recs[i]
        r.x, r.y, r.z = x, y, z
        r.intensity = inten[i]
        r.classification = cls[i]
        r.return_number = ret[i]
        r.synthetic = syn[i]
        if has_rgb:
            r.red, r.green, r.blue = red[i] >> 8, green[i] >> 8, blue[i] >> 8
        else:
            r.red, r.green, r.blue = 0, 0, 0
        hist[inten[i]] += 1
        xyz[i, 0], xyz[i, 1], xyz[i, 2] = x, y, z
        for a in range(3):
            v = xyz[i, a]
            lo[a] = min(lo[a], v)
            hi[a] = max(hi[a], v)
            q[i, a] = grid_coord(v, cube_lo[a], qscale)


def _scan_segment(cube_lo: tuple[float, float, float], cube_size: float, path: str, start: int, count: int,
                  raw: str, into: tuple[Recs, F64, I64] | None = None
                  ) -> tuple[I64, I64, F64, F64, I64]:
    """Pass 1: decode a segment, park it as raw records, count it on the 128³ grid.

    Returns the occupied grid cells (sorted), their counts, the tight bounds and the histogram of
    intensities (65536 bins). For an in-memory build (a thread of the calling process, which builds the
    cloud as one chunk), ``into`` are the segment's slices of the cloud's records, positions and grid
    coordinates: they are filled instead of parking a file, and no cells are counted.
    """
    if into is None:
        recs, xyz, q = np.empty(count, POINT_DTYPE), np.empty((count, 3)), np.empty((count, 3), np.int64)
    else:
        recs, xyz, q = into
    # The histogram, not a percentile: segments' percentiles do not combine, histograms add up, so the
    # intensity scale does not depend on how the input was cut into segments.
    hist = np.zeros(1 << 16, np.int64)
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    qscale = float(1 << QBITS) / cube_size  # as quantize() scales
    got = 0
    for pts in iter_points(path, start=start, count=count, chunk_points=min(count, 1_000_000), raw=True):
        n = len(pts)
        X, Y, Z, scales, offsets, inten, cls, ret, red, green, blue, syn = point_fields(pts)
        _scan_kernel(X, Y, Z, scales, offsets, inten, cls, ret, red, green, blue, syn, recs[got:got + n],
                     xyz[got:got + n], q[got:got + n], np.asarray(cube_lo, np.float64), qscale, hist, lo, hi)
        got += n
    if into is not None:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), lo, hi, hist
    _save_npy(raw, recs)
    g = q >> (QBITS - SCAN_BITS)
    flat = g[:, 0] | (g[:, 1] << SCAN_BITS) | (g[:, 2] << (2 * SCAN_BITS))
    cnt = np.bincount(flat, minlength=1 << (3 * SCAN_BITS))
    cells = np.flatnonzero(cnt)
    return cells, cnt[cells].astype(np.int64), lo, hi, hist


def _percentile99(hist: I64) -> float:
    """The smallest value at or below which 99 % of the values of a histogram lie."""
    n = int(hist.sum())
    return float(np.searchsorted(np.cumsum(hist), 0.99 * n)) if n else 0.0


def _segment_path(p: _Params, sid: int) -> Path:
    return Path(p.tmp) / "raw" / f"{sid:06d}.npy"


def _distribute_segment(p: _Params, sid: int, lut_path: str, n_chunks: int) -> tuple[int, I64]:
    """Pass 2: counting-sort a parked segment by chunk, in place.

    The segment file is replaced by its records sorted by chunk (one file per segment rather than one per
    segment and chunk: file creation is what this pass spent its time on); a chunk is then one slice of
    each segment. Sorting a sorted segment again changes nothing, so an interrupted pass is simply rerun.

    Returns the segment id and the offsets (n_chunks + 1,) of the chunks' slices.
    """
    raw = _segment_path(p, sid)
    recs = np.load(raw)
    lut = np.load(lut_path, mmap_mode="r")
    g = quantize(_xyz(recs), np.asarray(p.cube_lo), p.cube_size) >> (QBITS - SCAN_BITS)
    cid = np.asarray(lut[g[:, 0] | (g[:, 1] << SCAN_BITS) | (g[:, 2] << (2 * SCAN_BITS))], np.int64)
    order, offs = counting_sort(cid, n_chunks)
    if np.any(np.diff(order) < 0):
        _save_npy(raw, _take(recs, order))
    return sid, offs


def _load_chunk(p: _Params, cid: int) -> Recs:
    offs = np.load(Path(p.tmp) / "pieces.npy")
    parts = []
    for sid in np.flatnonzero(offs[:, cid + 1] > offs[:, cid]):
        seg = np.load(_segment_path(p, int(sid)), mmap_mode="r")
        parts.append(seg[offs[sid, cid]:offs[sid, cid + 1]])
    if len(parts) > 1:
        return _concat_recs(parts)
    return np.array(parts[0])  # a copy of the map


def _build_chunk(p: _Params, cid: int, level: int, idx: tuple[int, int, int]) -> _ChunkResult:
    """Pass 3: the subtree of one chunk. The result is kept on disk, so a resumed build skips it."""
    done = Path(p.tmp) / "results" / f"{cid}.pkl"
    if done.exists():
        with open(done, "rb") as f:
            res: _ChunkResult = pickle.load(f)
        return res
    recs = _load_chunk(p, cid)
    xyz = _xyz(recs)
    q = quantize(xyz, np.asarray(p.cube_lo), p.cube_size)
    stats = _Stats()
    if p.refine is not None:
        # The chunk's roofs are refined before they are binned; ``q`` stays that of the input position, so a
        # moved point keeps its node and cell (errors are measured on ``xyz``, the refined positions). The
        # refined positions are kept for pass 5, which measures the upper nodes' errors on them.
        stats.refined = refine_records(recs, xyz, p.refine)
        moved = np.flatnonzero(recs["synthetic"] == REFINED)
        atomic_write(Path(p.tmp) / "refined" / f"{cid}.npz",
                     lambda t: np.savez(t, idx=moved, xyz=xyz[moved]), suffix=".npz")
    root = _subtree(p, recs, q, xyz, level, idx, stats)
    res = _ChunkResult(cid, root, stats)
    atomic_write_bytes(done, pickle.dumps(res, protocol=pickle.HIGHEST_PROTOCOL))
    return res


def _chunk_errors(p: _Params, cid: int, ancestors: list[tuple[int, str]]) -> dict[str, float]:
    """Pass 5: exact error of the upper nodes above one chunk, measured on the chunk's input points."""
    recs = _load_chunk(p, cid)
    xyz = _xyz(recs)
    q = quantize(xyz, np.asarray(p.cube_lo), p.cube_size)
    if p.refine is not None:  # what the chunk's leaves draw: the refined roofs (_build_chunk)
        r = np.load(Path(p.tmp) / "refined" / f"{cid}.npz")
        xyz[r["idx"]] = r["xyz"]
    out = {}
    for level, key in ancestors:
        t = np.load(Path(p.tmp) / "tables" / (key.replace("/", "_") + ".npz"))
        out[key] = lookup_error(q, xyz, level, t["cells"], t["elem"])
    return out


# --------------------------------------------------------------------------------------------- helpers
def _save_npy(path: str | Path, arr: np.ndarray) -> None:
    atomic_write(path, lambda t: np.save(t, arr), suffix=".npy")  # np.save appends .npy otherwise


@contextmanager
def _executor(workers: int | None, scheduler: Any, memory: bool, partial: Path) -> Iterator[Executor]:
    """The build's executor; an in-memory build (threads of this process) cannot resume, so when it fails
    it leaves nothing behind."""
    if not memory:
        with make_executor(workers, scheduler) as ex:
            yield ex
        return
    try:
        with make_executor(None, None, threads=True) as ex:
            yield ex
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise


def _chunks_from_counts(counts: I64, max_chunk_points: int) -> list[tuple[int, int, int, int, int]]:
    """Merge 128³ grid cells into octree nodes of at most ``max_chunk_points`` (top-down on the pyramid).

    Returns (level, x, y, z, count) per chunk; a single 128³ cell with more points is a chunk anyway.
    """
    n = 1 << SCAN_BITS
    pyr = [counts.reshape(n, n, n)]  # [z, y, x]
    for lv in range(SCAN_BITS - 1, -1, -1):
        c = pyr[0]
        s = 1 << lv
        pyr.insert(0, c.reshape(s, 2, s, 2, s, 2).sum(axis=(1, 3, 5)))
    out = []
    stack = [(0, 0, 0, 0)]
    while stack:
        lv, x, y, z = stack.pop()
        cnt = int(pyr[lv][z, y, x])
        if cnt == 0:
            continue
        if cnt <= max_chunk_points or lv == SCAN_BITS:
            out.append((lv, x, y, z, cnt))
            continue
        for o in range(7, -1, -1):
            stack.append((lv + 1, 2 * x + (o & 1), 2 * y + ((o >> 1) & 1), 2 * z + ((o >> 2) & 1)))
    return out


def _fingerprint(files: Sequence[Path], **params: Any) -> str:
    items = [[str(f.resolve()), f.stat().st_size, f.stat().st_mtime_ns] for f in files]
    return json.dumps({"files": items, "version": __version__, **params}, sort_keys=True, default=str)


def _prepare_partial(partial: Path, fingerprint: str) -> None:
    fp = partial / ".build" / "fingerprint.json"
    if partial.exists() and (not fp.exists() or fp.read_text() != fingerprint):
        shutil.rmtree(partial)  # another build's leftovers: resuming it would mix two builds
    fp.parent.mkdir(parents=True, exist_ok=True)
    if not fp.exists():
        fp.write_text(fingerprint)


def _finish(partial: Path, out: Path) -> None:
    shutil.rmtree(partial / ".build", ignore_errors=True)
    publish_dir(partial, out)


def _build_chunked(ex: Executor, params: _Params, segments: list[tuple[str, int, int, str]],
                   chunks: list[tuple[int, int, int, int, int]], stats: _Stats, progress: bool) -> _Summary:
    """Passes 2 to 5 of an out-of-core build: distribute, one subtree per chunk, upper levels, errors."""
    tmp = Path(params.tmp)
    # Pass 2: distribute segments into chunk pieces.
    if not (tmp / "distributed.done").exists():
        n = 1 << SCAN_BITS
        lut = np.full((n, n, n), -1, np.int32)
        for cid, (lv, x, y, z, _c) in enumerate(chunks):
            w = 1 << (SCAN_BITS - lv)
            lut[z * w:(z + 1) * w, y * w:(y + 1) * w, x * w:(x + 1) * w] = cid
        _save_npy(tmp / "lut.npy", lut.reshape(-1))
        pieces = np.zeros((len(segments), len(chunks) + 1), np.int64)
        for sid, offs in run_tasks(ex, _distribute_segment,
                                   [(params, sid, str(tmp / "lut.npy"), len(chunks))
                                    for sid in range(len(segments))], progress=progress, desc="distribute"):
            pieces[sid] = offs
        _save_npy(tmp / "pieces.npy", pieces)
        (tmp / "distributed.done").touch()
    # Pass 3: one subtree per chunk.
    roots: dict[tuple[int, tuple[int, int, int]], _Summary] = {}
    for res in run_tasks(ex, _build_chunk, [(params, cid, lv, (x, y, z)) for cid, (lv, x, y, z, _c)
                                             in enumerate(chunks)], progress=progress, desc="subtrees"):
        stats.add(res.stats)
        roots[(res.root.level, res.root.idx)] = res.root
    # Pass 4: upper levels, bottom-up from the chunk roots (in this process: few nodes).
    tables = tmp / "tables"
    upper: dict[str, _Summary] = {}
    max_chunk_level = max(lv for lv, *_ in chunks)
    for lv in range(max_chunk_level, 0, -1):
        groups: dict[tuple[int, int, int], list[_Summary]] = {}
        for (l2, idx), node in sorted(roots.items(), key=lambda kv: (kv[0][0], kv[0][1])):
            if l2 == lv:
                groups.setdefault((idx[0] >> 1, idx[1] >> 1, idx[2] >> 1), []).append(node)
        for pidx, kids in sorted(groups.items()):
            # Children in octant order (bit 0 = x), as partition() orders them: a cloud built as one
            # chunk in memory then writes the same bytes.
            kids.sort(key=lambda nd: (nd.idx[0] & 1) | ((nd.idx[1] & 1) << 1) | ((nd.idx[2] & 1) << 2))
            node, cells, elem = _internal(params, lv - 1, pidx, kids, stats)
            _save_npy_z(tables / (node.spec.key.replace("/", "_") + ".npz"), cells, elem)
            upper[node.spec.key] = node
            roots[(lv - 1, pidx)] = node
            for k in kids:  # the children's representatives are not needed any more
                del roots[(k.level, k.idx)]
    # Pass 5: exact errors of the upper nodes, measured on the input points chunk by chunk.
    if upper:
        exact = dict.fromkeys(upper, 0.0)
        tasks = []
        for cid, (lv, x, y, z, _c) in enumerate(chunks):
            anc = [(a, _key(a, (x >> (lv - a), y >> (lv - a), z >> (lv - a)))) for a in range(lv)]
            tasks.append((params, cid, anc))
        for errs in run_tasks(ex, _chunk_errors, tasks, progress=progress, desc="errors"):
            for nkey, err in errs.items():
                exact[nkey] = max(exact[nkey], err)
        for node in sorted(upper.values(), key=lambda nd: -nd.level):  # children first
            _set_error(node.spec, exact[node.spec.key])
    return roots[(0, (0, 0, 0))]


# ----------------------------------------------------------------------------------------------- build
@discard_partial_on_refusal
def build_points(files: Sequence[str | PathLike[str]], out_dir: str | PathLike[str], *, crs: Any = None,
                 hybrid: bool = True, workers: int | None = None, scheduler: Any = None,
                 progress: bool = True, phi: float = 8.0, max_leaf_points: int = 20_000,
                 max_chunk_points: int = 500_000, segment_points: int = 500_000,
                 measure_floor: bool = False, complete: CompleteOptions | None = None,
                 refine_roofs: RefineOptions | bool = False) -> PointBuildReport:
    """Build a 3D Tiles point octree from LAS/LAZ files.

    Parameters
    ----------
    files
        LAS/LAZ files of one cloud (one CRS).
    out_dir
        The tileset folder to write (replaced when it exists, only once the build has succeeded).
    crs
        CRS override, needed when the headers carry none.
    hybrid
        Replace planes of internal nodes by textured quads (Wahl et al. 2005); False: points only.
    workers
        Local worker processes; None: CPU count, or the calling process for inputs below
        :data:`INLINE_BELOW` points; 0: the calling process.
    scheduler
        Dask scheduler address (``tcp://HOST:PORT``) or ``distributed.Client``: run the tasks there.
    progress
        Progress bars on stderr.
    phi
        Compactness factor of the plane rule ``texels < φ · (inliers − 4)``.
    max_leaf_points
        A node with at most this many points is a leaf.
    max_chunk_points
        Out-of-core chunk size: bounds the memory of one subtree task.
    segment_points
        Points decoded per scan task: bounds the memory of one scan or distribution task.
    measure_floor
        Also time plain laspy decoding the same files, for the report.
    complete
        Add ground under canopy and walls first (:mod:`citylod.lod.build.complete`); added points are
        flagged ``synthetic``.
    refine_roofs
        True or :class:`~citylod.lod.build.refine.RefineOptions`: smooth the roofs' range noise, ridges kept
        (Gao ch. 5, :mod:`citylod.lod.build.refine`), per building, before the points are binned, in
        memory and out of core alike (per chunk). The input files are not touched; in the tileset the
        refined points replace their originals and carry ``synthetic`` = 2.

    Returns
    -------
    PointBuildReport

    Raises
    ------
    InputError
        Unreadable, truncated, empty or un-georeferenced input (naming the file).

    Warns
    -----
    UserWarning
        The CRS names no vertical datum, so heights were written as ellipsoidal (with the compound CRSs
        to pass as ``crs`` instead, :func:`citylod.io.crs.missing_vertical_datum`).
    """
    t_start = time.perf_counter()
    paths = [Path(f) for f in files]
    meta = read_metadata(paths, crs)
    floor = None
    if measure_floor:
        from citylod.io.las import decode_seconds

        floor = decode_seconds(paths)
        t_start = time.perf_counter()
    out = Path(out_dir)
    inputs, aug = paths, None
    refine = (RefineOptions() if refine_roofs is True else refine_roofs) or None
    # Small clouds are built in this process, on threads (the kernels release the GIL), with the
    # intermediates in memory: worker processes and parked files cost more than they save there.
    # Such a build is redone whole when interrupted (seconds); large builds resume from their files.
    memory = workers is None and scheduler is None and meta.point_count < INLINE_BELOW
    if memory:
        segment_points = max(segment_points, INLINE_BELOW)  # one segment per file: seeking in LAZ decodes
    # The footprints' outline (completion) depends on them alone: computed while pass 1 decodes the points.
    outline = start_footprint_outline(complete) if memory and complete is not None else None
    partial = out.with_name(out.name + ".partial")
    tmp = partial / ".build"
    if memory:
        shutil.rmtree(partial, ignore_errors=True)  # an interrupted in-memory build left nothing to resume
    _prepare_partial(partial, _fingerprint(inputs, crs=meta.crs.to_wkt(), hybrid=hybrid, phi=phi,
                                           max_leaf=max_leaf_points, max_chunk=max_chunk_points,
                                           segment=segment_points, complete=complete,
                                           **({} if refine is None else {"refine": refine})))
    if complete is not None and not memory:
        # The added points join the input as one more LAS file in the build's scratch folder (removed
        # with it); the same options write the same points, so a resumed build reads the same file.
        # (An in-memory build completes the records it decoded in pass 1 instead: one decode, not two.)
        aug, paths, meta = complete_inputs(paths, meta, tmp / "complete.las", complete, crs)
    extent = float(np.max(meta.hi - meta.lo))
    cube_size = extent * (1.0 + 1e-9) + 1e-6 if extent > 0 else 1.0
    cube_lo = (meta.lo + meta.hi) / 2.0 - cube_size / 2.0
    segments: list[tuple[str, int, int, str]] = []
    for info in meta.files:
        for start in range(0, info.point_count, segment_points):
            sid = len(segments)
            segments.append((str(info.path), start, min(segment_points, info.point_count - start),
                             str(tmp / "raw" / f"{sid:06d}.npy")))
    with _executor(workers, scheduler, memory, partial) as ex:
        # Pass 1: scan.
        scan = tmp / "scan.npz"
        if memory or not scan.exists():
            counts = np.zeros(1 << (3 * SCAN_BITS), np.int64)
            lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
            ihist = np.zeros(1 << 16, np.int64)
            lo_t = tuple(float(v) for v in cube_lo)
            into: list[tuple[Recs, F64, I64] | None] = [None] * len(segments)
            if memory:  # the whole cloud, each segment decoded into its slice (in order: as on disk)
                # With completion, room for added points (ground under canopy fits; walls as points may not,
                # then the cloud is copied once): the added points are decoded after the input's.
                cap = meta.point_count + (meta.point_count // 20 + 1024 if complete is not None else 0)
                cloud = (np.empty(cap, POINT_DTYPE), np.empty((cap, 3)), np.empty((cap, 3), np.int64))
                ends = np.cumsum([s_[2] for s_ in segments])
                into = [(cloud[0][e - s_[2]:e], cloud[1][e - s_[2]:e], cloud[2][e - s_[2]:e])
                        for e, s_ in zip(ends, segments, strict=True)]
            for cells, cnt, slo, shi, sp in run_tasks(ex, _scan_segment,
                                                      [(lo_t, cube_size, *s, dst) for s, dst in zip(segments, into, strict=True)],
                                                      progress=progress, desc="scan"):
                counts[cells] += cnt
                lo, hi = np.minimum(lo, slo), np.maximum(hi, shi)
                ihist += sp
            if memory and complete is not None:
                n_in = meta.point_count
                # Wall quads add no points: they are computed and written as tiles on a thread of their own
                # while the octree is built, and waited for at the end (add_wall_tiles).
                aug, extra = complete_records(cloud[0][:n_in], meta, tmp / "complete.las", complete,
                                              quads_later=True, tiles_dir=partial, outline=outline)
                n_add = 0 if extra is None else read_metadata([extra], meta.crs).point_count
                if n_in + n_add > len(cloud[0]):
                    r0, x0, q0 = cloud
                    cloud = (np.concatenate([r0[:n_in], np.empty(n_add, POINT_DTYPE)]),
                             np.concatenate([x0[:n_in], np.empty((n_add, 3))]),
                             np.concatenate([q0[:n_in], np.empty((n_add, 3), np.int64)]))
                n_all = n_in + n_add
                cloud = (cloud[0][:n_all], cloud[1][:n_all], cloud[2][:n_all])
                if extra is not None:
                    add = (cloud[0][n_in:], cloud[1][n_in:], cloud[2][n_in:])
                    _, _, slo, shi, sp = _scan_segment((lo_t[0], lo_t[1], lo_t[2]), cube_size, str(extra), 0,
                                                       n_add, "", add)
                    lo, hi = np.minimum(lo, slo), np.maximum(hi, shi)
                    ihist += sp
                    paths = [*paths, extra]
                    meta = read_metadata(paths, crs if crs is not None else meta.crs)
            p99 = _percentile99(ihist)
            if not memory:
                occupied = np.flatnonzero(counts)  # sparse: the dense grid is 16 MB
                np.savez(tmp / "scan.tmp.npz", cells=occupied, counts=counts[occupied], lo=lo, hi=hi, p99=p99)
                os.replace(tmp / "scan.tmp.npz", scan)
        else:
            s = np.load(scan)
            counts = np.zeros(1 << (3 * SCAN_BITS), np.int64)
            counts[s["cells"]] = s["counts"]
            p99 = float(s["p99"])
        params = _Params(out=str(partial), tmp=str(tmp),
                         cube_lo=(float(cube_lo[0]), float(cube_lo[1]), float(cube_lo[2])),
                         cube_size=cube_size, has_rgb=meta.has_rgb, hybrid=hybrid, phi=phi,
                         max_leaf_points=max_leaf_points, intensity_scale=max(p99, 1.0), memory=memory,
                         refine=refine)
        stats = _Stats()
        if memory:
            # One chunk, the whole cloud: its nodes are tasks on this process's threads (passes 2 and 5
            # exist to bound memory, which a cloud this small does not need).
            recs, xyz, q = cloud
            del cloud, into
            if refine is not None:  # before binning; q stays that of the input positions (_build_chunk)
                stats.refined = refine_records(recs, xyz, refine)
            root = _subtree(params, recs, q, xyz, 0, (0, 0, 0), stats, pool=ex, progress=progress)
            del recs, xyz, q
            n_chunks = 1
        else:
            chunks = _chunks_from_counts(counts, max_chunk_points)
            root = _build_chunked(ex, params, segments, chunks, stats, progress)
            n_chunks = len(chunks)
    stats.max_level = max(stats.max_level, 0)
    top = root.spec if aug is None else add_wall_tiles(partial, root.spec, aug)
    write_tileset(partial, top, meta.crs, extras={"citylod": {
        "kind": "points", "points": meta.point_count, "hybrid": hybrid, "phi": phi, "quads": stats.quads,
        "has_rgb": meta.has_rgb, "max_leaf_points": max_leaf_points, "cluster_grid": 1 << CLUSTER_BITS,
        **({} if aug is None else {"complete": aug.counts}),
        **({} if refine is None else {"refined_roof_points": stats.refined})}})
    _finish(partial, out)
    seconds = time.perf_counter() - t_start
    if refine is not None and stats.refined == 0:
        warnings.warn(f"{paths[0]}: no building-class (6) points to refine (unclassified input?): roofs left as "
                      "scanned", stacklevel=2)
    note = missing_vertical_datum(meta.crs)
    if note:
        # The user can know better (--crs EPSG:7415): said once, after the build, where the progress bars do
        # not scroll it away and a refused input keeps its one error line alone.
        warnings.warn(note, stacklevel=2)
    return PointBuildReport(
        output=out, points=meta.point_count, nodes=stats.nodes, leaves=stats.leaves, levels=stats.max_level + 1,
        chunks=n_chunks, quads=stats.quads, quad_points=stats.quad_points, seconds=seconds,
        points_per_s=meta.point_count / seconds if seconds > 0 else 0.0, bytes=stats.bytes, hybrid=hybrid,
        root_error=float(root.spec.geometric_error), decode_floor_s=floor,
        complete=None if aug is None else aug.summary(), refined=None if refine is None else stats.refined)


def _save_npy_z(path: Path, cells: I64, elem: F64) -> None:
    atomic_write(path, lambda t: np.savez(t, cells=cells, elem=elem), suffix=".npz")


def exercise_kernels() -> None:
    """Build two small clouds inline, in a temporary folder, so that numba's on-disk cache holds the kernels a
    points build compiles (what ``citylod build-kernels`` runs after the DSM kernels).

    A first build otherwise spends about 20 s compiling on this project's machine, which a user reads as the
    build's speed (the demo's 0.5 M points reported 0.03 M points/s). The clouds are LAS point formats 7 (RGB)
    and 1 (no colour), the two ways points are coloured; ground, a gable roof and scattered vegetation give
    internal nodes with planes, so the quads' kernels run too.
    """
    import tempfile

    import laspy

    rng = np.random.default_rng(0)
    n = 12_000
    x, y = rng.uniform(0.0, 80.0, n), rng.uniform(0.0, 80.0, n)
    z = 100.0 + rng.normal(0.0, 0.02, n)
    house = (np.abs(x - 40.0) < 10.0) & (np.abs(y - 40.0) < 6.0)
    z[house] += 8.0 + 3.0 * (1.0 - np.abs(y[house] - 40.0) / 6.0)  # a gable roof: two planes
    tree = rng.random(n) < 0.1
    z[tree & ~house] += rng.uniform(2.0, 12.0, int((tree & ~house).sum()))
    cls = np.where(house, 6, np.where(tree, 5, 2)).astype(np.uint8)
    with tempfile.TemporaryDirectory(prefix="citylod-preload-") as tmp:
        for fmt in (7, 1):
            las = laspy.LasData(laspy.LasHeader(point_format=fmt, version="1.4" if fmt >= 6 else "1.2"))
            las.header.scales, las.header.offsets = np.array([0.01, 0.01, 0.01]), np.array([500_000.0, 5_400_000.0, 0.0])
            las.x, las.y, las.z = x + 500_000.0, y + 5_400_000.0, z
            las.classification = cls
            if fmt == 7:
                las.red = las.green = las.blue = (cls.astype(np.uint16) * 8000)
            path = Path(tmp) / f"f{fmt}.laz"
            las.write(path)
            build_points([path], Path(tmp) / f"t{fmt}", crs="EPSG:32632", workers=0, progress=False,
                         max_leaf_points=1000)


__all__ = ["INLINE_BELOW", "PointBuildReport", "build_points"]
