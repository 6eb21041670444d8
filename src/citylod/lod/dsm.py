"""DSM raster → quadtree of bounded-error TIN tiles, written as 3D Tiles (Wahl et al., WSCG 2004).

The tile tree: leaves sit on the raster's own grid, ``tile_size`` samples a side (129 by default, 128 cells,
borders shared with neighbours); each coarser level covers 2×2 tiles of the level below on the same number
of samples (every second sample), so a level-d tile has a sample stride of ``2^(L−d)``. Each tile is one TIN
whose vertices lie on its grid, simplified to a target that doubles per level (the leaf target defaults to
half the sample spacing).

The guarantee: every tile's TIN is certified against the *full-resolution* raster, exactly, by
:mod:`citylod.lod.certify` (vertical L∞ at every sample and every crossing of a TIN edge with a grid edge),
after quantisation to float32. Where the certificate exceeds the level's target, the builder forces the grid
vertices of the offending cells into the TIN and tries again; ``geometricError`` is the certified value plus
the horizontal quantisation error, so it is a true bound even where a coarse grid cannot reach its target
(a one-sample chimney cannot be represented on a grid of stride 16). This is provably conservative, which is
what the issue allows in place of Wahl's l−2 reference bookkeeping; it reads each footprint in blocks, so
memory does not grow with the raster.

Skirts (Wahl 2004: "a triangle strip along the border that reaches down") hang from each tile's outer
border by twice its error: two neighbours differ along a shared border by at most the sum of their errors,
so the skirt of the coarser one closes the crack. Skirt triangles are marked in the glb and are not part of
the certified surface.

Every tile is an independent task (decision 5): it reads its own windows, so tasks run on a local process
pool or a Dask cluster. Output goes to ``OUT.partial/`` and is renamed when complete; finished tiles leave a
sidecar, so an interrupted build resumes without redoing them.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

from citylod.core.errors import InputError
from citylod.core.fileio import atomic_write_text, publish_dir
from citylod.io.raster import RasterInfo, RasterSource, check_has_data, read_image_window
from citylod.io.tiles3d import MeshData, TileContent, TileSpec, write_content, write_tileset
from citylod.lod.certify import certify

# Coarse levels may need several passes of "force the vertices of bad cells"; after this many the
# certified error is accepted as it is (and written as the tile's bound).
_MAX_REFINE_PASSES = 4
# Rasters smaller than this build in the calling process unless workers are asked for.
_INLINE_BELOW_SAMPLES = 1_500_000


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
    # Border vertices (grid index along the side) forced in so neighbours match: side -> indices,
    # sides "n" (row 0), "s" (row cells), "w" (col 0), "e" (col cells).
    border_must: tuple[tuple[str, tuple[int, ...]], ...] = ()


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

    def summary(self) -> str:
        lines = [f"{self.output}: {self.tiles} tiles on {self.levels} levels from {self.width}×{self.height} "
                 f"samples in {self.seconds:.1f} s ({self.samples_per_s / 1e6:.2f} M samples/s, "
                 f"peak {self.peak_rss_mb:.0f} MB){f', {self.resumed} tiles resumed' if self.resumed else ''}"]
        lines.append("level  tiles   triangles   target_m   max_error_m")
        for lv in self.per_level:
            lines.append(f"{lv['level']:5d} {lv['tiles']:6d} {lv['triangles']:11d} {lv['target']:10.3f} "
                         f"{lv['max_error']:13.3f}")
        return "\n".join(lines)


def _triangulate(heights: np.ndarray, valid: np.ndarray, max_error: float,
                 must_include: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    from citylod.lod.tin import triangulate

    return triangulate(heights, valid, max_error, must_include=must_include)


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


def build_tile(job: DsmJob) -> TileResult:
    """Build, certify and write one tile. Runs on a worker."""
    t0 = time.perf_counter()
    src, info = job.source, job.source.info
    n = job.tile_size
    cells = n - 1
    stride = 2 ** (job.levels - job.level)
    key = f"{job.level}/{job.row}/{job.col}"
    res = TileResult(key, job.level, job.row, job.col, False, target=job.target)
    r_start, c_start = job.row * cells * stride, job.col * cells * stride
    rpos, rex = _grid_positions(r_start, n, stride, info.height - 1)
    cpos, cex = _grid_positions(c_start, n, stride, info.width - 1)
    if not rex.any() or not cex.any():
        return res
    # Tiles at the raster's far edges are cropped to the grid lines that exist rather than padded with
    # no-data: the TIN kernel forces every sample on a no-data boundary, which would waste triangles.
    rpos, cpos = rpos[rex], cpos[cex]
    heights, valid = _read_grid(src, rpos, cpos)
    last_r, last_c = len(rpos) - 1, len(cpos) - 1
    if valid.sum() < 3:
        return res
    footprint = (int(rpos[0]), int(cpos[0]), int(rpos[-1]), int(cpos[-1]))

    # Certification passes (refinement, coarsening) read the same full-resolution blocks again: keep a
    # few in memory (8 blocks of 1025² ≈ 75 MB at most) so a tile reads its footprint from disk once when
    # it is small enough, and memory stays bounded when it is not.
    blocks: dict[tuple[int, int, int, int], tuple[np.ndarray, np.ndarray]] = {}

    def read_block(r: int, c: int, nr: int, nc: int) -> tuple[np.ndarray, np.ndarray]:
        k = (r, c, nr, nc)
        if k not in blocks:
            if len(blocks) >= 8:
                blocks.pop(next(iter(blocks)))
            blocks[k] = src.read(r, c, nr, nc)
        return blocks[k]

    # Geographic rasters: vertical errors are metres already; vertices are projected afterwards.
    to_metric = None
    if info.geographic:
        to_metric = pyproj.Transformer.from_crs(info.crs, pyproj.CRS.from_wkt(job.metric_crs_wkt), always_xy=True)

    must: np.ndarray | None = _border_vertices(job.border_must, last_r, last_c, valid)
    tol = job.target
    border_must = must

    def attempt(tol: float, must: np.ndarray | None) -> tuple[float, np.ndarray, np.ndarray, np.ndarray,
                                                             np.ndarray, float, np.ndarray]:
        vij, faces = _triangulate(heights, valid, tol, must)
        if len(faces) == 0:
            return 0.0, vij, faces, np.zeros((0, 3), np.float32), np.zeros(3), 0.0, np.zeros((cells, cells))
        vr = rpos[vij[:, 0]].astype(np.float64)
        vc = cpos[vij[:, 1]].astype(np.float64)
        vz = heights[vij[:, 0], vij[:, 1]]
        x, y = info.sample_xy(vr, vc)
        if to_metric is not None:
            x, y = to_metric.transform(x, y)
        xyz = np.column_stack([x, y, vz])
        center = 0.5 * (xyz.min(axis=0) + xyz.max(axis=0))
        local = (xyz - center).astype(np.float32)
        back = local.astype(np.float64) + center
        q_xy = float(np.max(np.hypot(back[:, 0] - xyz[:, 0], back[:, 1] - xyz[:, 1]), initial=0.0))
        err, cell_err, _ = certify(read_block, footprint, vr, vc, back[:, 2], faces.astype(np.int64),
                                   (cells, cells), stride)
        return err, vij, faces, local, center, q_xy, cell_err

    tol = job.target
    best = attempt(tol, must)
    if len(best[2]) == 0:
        return res
    cell_err = best[6]
    passes = 1
    while passes < _MAX_REFINE_PASSES and best[0] > job.target and stride > 1:
        bad = np.argwhere(cell_err > job.target)
        # Force the grid corners of offending interior cells; border vertices stay as the border
        # simplification chose them, so neighbours keep matching.
        corners = np.concatenate([bad, bad + [0, 1], bad + [1, 0], bad + [1, 1]])
        interior = (corners[:, 0] > 0) & (corners[:, 0] < last_r) & (corners[:, 1] > 0) & (corners[:, 1] < last_c)
        corners = corners[interior]
        corners = corners[valid[corners[:, 0], corners[:, 1]]]
        new = np.unique(np.concatenate([corners, must]) if must is not None else corners, axis=0)
        if must is not None and len(new) == len(must):
            break
        must = new.astype(np.int32)
        tol *= 0.5
        passes += 1
        trial = attempt(tol, must)
        cell_err = trial[6]
        # Forcing vertices only pays when it lowers the certified error: façades between the samples of
        # a coarse grid cannot be fixed on that grid.
        if trial[0] >= best[0] * 0.98:
            break
        best = trial
    if best[0] > 2.0 * job.target and stride > 1:
        # The target is out of reach on this grid; the tile's bound is best[0] wherever it is shown, so a
        # TIN that stays under that bound everywhere looks the same at the distances where it is drawn.
        coarse = attempt(0.8 * best[0], border_must)
        if len(coarse[2]) and coarse[0] <= best[0] and len(coarse[2]) < len(best[2]):
            best = coarse
    err, vij, faces, local, center, q_xy, _ = best
    res.passes = passes
    res.certified = err
    res.quantisation = q_xy
    res.projection = 0.0 if to_metric is None else _projection_bound(info, to_metric, rpos, cpos, vij, faces)
    res.geometric_error = err + q_xy + res.projection
    skirt_depth = 2.0 * max(res.geometric_error, job.target)
    if info.transform[0] * info.transform[4] > 0:  # south-up raster: the grid's orientation is mirrored
        faces = faces[:, ::-1]
    positions, faces_all, skirt, skirt_src = _add_skirts(local, faces, vij, last_r, last_c, skirt_depth)
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
    mesh = MeshData(positions, faces_all.astype(np.uint32), skirt=skirt, uv=uv, texture=texture, name="surface")
    write_content(job.out_dir, key, TileContent([mesh]))
    surf = local.astype(np.float64) + center
    lo = surf.min(axis=0)
    hi = surf.max(axis=0)
    lo[2] -= skirt_depth  # the skirt hangs below the surface; bounding volumes must hold it
    res.has_content = True
    res.center, res.lo, res.hi = center.tolist(), lo.tolist(), hi.tolist()
    res.triangles = len(faces)
    res.vertices = len(vij)
    res.samples = int(valid.sum()) * stride * stride
    r_, c_ = vij[:, 0], vij[:, 1]
    res.borders = {"n": sorted(int(v) for v in c_[r_ == 0]), "s": sorted(int(v) for v in c_[r_ == last_r]),
                   "w": sorted(int(v) for v in r_[c_ == 0]), "e": sorted(int(v) for v in r_[c_ == last_c])}
    res.seconds = time.perf_counter() - t0
    _write_sidecar(job.out_dir, key, res)
    return res


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


def _border_vertices(border_must: tuple[tuple[str, tuple[int, ...]], ...], last_r: int, last_c: int,
                     valid: np.ndarray) -> np.ndarray | None:
    pts = []
    for side, idx in border_must:
        k = np.asarray(idx, np.int32)
        k = k[k <= (last_c if side in "ns" else last_r)]
        fixed = np.full(len(k), {"n": 0, "s": last_r, "w": 0, "e": last_c}[side], np.int32)
        pts.append(np.column_stack([fixed, k]) if side in "ns" else np.column_stack([k, fixed]))
    if not pts:
        return None
    ij = np.unique(np.concatenate(pts), axis=0)
    return ij[valid[ij[:, 0], ij[:, 1]]].astype(np.int32)


def _reconcile_borders(results: dict[str, TileResult], jobs: dict[str, DsmJob]) -> list[DsmJob]:
    """Rebuild jobs for same-level neighbours whose shared border vertices differ.

    The TIN kernel derives most border vertices from the border samples alone (identical on both sides),
    but may add a border vertex that the tile's interior needs for the bound. Each tile of such a pair is
    rebuilt with the union forced in; sets only grow, so a few rounds converge.
    """
    extra: dict[str, dict[str, set[int]]] = {}
    for key, r in results.items():
        if not r.has_content:
            continue
        for side, (dr, dc), other_side in (("e", (0, 1), "w"), ("s", (1, 0), "n")):
            nkey = f"{r.level}/{r.row + dr}/{r.col + dc}"
            n = results.get(nkey)
            if n is None or not n.has_content:
                continue
            a, b = set(r.borders.get(side, [])), set(n.borders.get(other_side, []))
            if a != b:
                union = a | b
                extra.setdefault(key, {}).setdefault(side, set()).update(union)
                extra.setdefault(nkey, {}).setdefault(other_side, set()).update(union)
    out = []
    for key, sides in extra.items():
        job = jobs[key]
        merged = {s: set(v) for s, v in job.border_must}
        for side, idx in sides.items():
            merged.setdefault(side, set()).update(idx)
        out.append(dataclasses.replace(job, border_must=tuple((s, tuple(sorted(v))) for s, v in sorted(merged.items()))))
    return out


def _read_grid(src: RasterSource, rpos: np.ndarray, cpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Samples at the given full-resolution rows × columns."""
    if len(rpos) > 1 and np.all(np.diff(rpos) == 1) and np.all(np.diff(cpos) == 1):
        return src.read(int(rpos[0]), int(cpos[0]), len(rpos), len(cpos))
    heights = np.zeros((len(rpos), len(cpos)))
    valid = np.zeros((len(rpos), len(cpos)), bool)
    c0 = int(cpos[0])
    span = int(cpos[-1]) - c0 + 1
    for i, r in enumerate(rpos):
        h, v = src.read(int(r), c0, 1, span)
        heights[i] = h[0, cpos - c0]
        valid[i] = v[0, cpos - c0]
    return heights, valid


def _add_skirts(local: np.ndarray, faces: np.ndarray, vij: np.ndarray, last_r: int, last_c: int,
                depth: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Append a vertical strip below each TIN edge on the tile's outer border.

    Returns positions, faces, the skirt mask per face, and for each appended vertex the surface vertex it
    hangs from (so attributes such as texture coordinates can be copied).
    """
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).astype(np.int64)
    n = len(local)
    undirected = np.minimum(e[:, 0], e[:, 1]) * n + np.maximum(e[:, 0], e[:, 1])  # 1D keys: fast unique
    _, inverse, counts = np.unique(undirected, return_inverse=True, return_counts=True)
    bd = e[counts[inverse] == 1]
    r, c = vij[:, 0], vij[:, 1]
    a, b = bd[:, 0], bd[:, 1]
    on_border = (((r[a] == r[b]) & ((r[a] == 0) | (r[a] == last_r)))
                 | ((c[a] == c[b]) & ((c[a] == 0) | (c[a] == last_c))))
    bd = bd[on_border]
    sources = np.unique(bd)
    dup = np.full(len(local), -1, np.int64)
    dup[sources] = len(local) + np.arange(len(sources))
    a, b = bd[:, 0], bd[:, 1]
    a2, b2 = dup[a], dup[b]
    # The surface runs a→b counter-clockwise seen from above, so outside is to the right: these two
    # triangles are counter-clockwise seen from outside.
    nf = np.concatenate([np.column_stack([b, a, a2]), np.column_stack([b, a2, b2])])
    skirt_pos = local[sources].copy()
    skirt_pos[:, 2] -= np.float32(depth)
    positions = np.concatenate([local, skirt_pos]).astype(np.float32)
    faces_all = np.concatenate([faces.astype(np.int64), nf])
    skirt = np.concatenate([np.zeros(len(faces), bool), np.ones(len(nf), bool)])
    return positions, faces_all, skirt, sources


def _write_sidecar(out_dir: str, key: str, res: TileResult) -> None:
    atomic_write_text(Path(out_dir) / "tiles" / f"{key}.json", json.dumps(asdict(res)))


def _read_sidecar(out_dir: Path, key: str) -> TileResult | None:
    p = out_dir / "tiles" / f"{key}.json"
    if not p.exists():
        return None
    try:
        res = TileResult(**json.loads(p.read_text()))
    except (OSError, ValueError, TypeError):
        return None
    if res.has_content and not (out_dir / "tiles" / f"{key}.glb").exists():
        return None
    return res


def plan_levels(info: RasterInfo, tile_size: int) -> int:
    """Number of levels below the root: leaves at level L have stride 1."""
    cells = tile_size - 1
    n = max(math.ceil(max(info.width - 1, 1) / cells), math.ceil(max(info.height - 1, 1) / cells))
    return max(0, math.ceil(math.log2(n))) if n > 1 else 0


def build_dsm(raster: str | os.PathLike[str], out_dir: str | os.PathLike[str], *, ortho: str | os.PathLike[str] | None = None,
              max_error: float | None = None, tile_size: int = 129, workers: int | None = None,
              scheduler: str | None = None, progress: bool = True, texture_size: int | None = None,
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
    max_error
        Leaf target in metres; default half the sample spacing. Level d above the leaves targets 2^d times it.
    tile_size
        Samples per tile side, 2^k + 1.
    workers, scheduler
        Local processes, or a Dask scheduler address (``tcp://host:port``).
    """
    t0 = time.perf_counter()
    if tile_size < 3 or (tile_size - 1) & (tile_size - 2):
        raise ValueError(f"tile_size must be 2^k + 1 (e.g. 65, 129, 257), got {tile_size}")
    src = RasterSource(raster)
    info = src.info
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
    metric = info.metric_crs()
    tex = texture_size or 256
    cells = tile_size - 1
    jobs: list[DsmJob] = []
    all_jobs: dict[str, DsmJob] = {}
    done: list[TileResult] = []
    for d in range(levels + 1):
        stride = 2 ** (levels - d)
        nr = math.ceil(max(info.height - 1, 1) / (cells * stride))
        nc = math.ceil(max(info.width - 1, 1) / (cells * stride))
        for i in range(nr):
            for j in range(nc):
                job = DsmJob(src, str(partial), d, i, j, levels, tile_size, leaf * 2 ** (levels - d),
                             None if ortho is None else str(ortho), tex, metric.to_wkt())
                all_jobs[f"{d}/{i}/{j}"] = job
                prev = _read_sidecar(partial, f"{d}/{i}/{j}")
                if prev is not None:
                    done.append(prev)
                    continue
                jobs.append(job)
    resumed = len(done)
    if _stop_after is not None:
        jobs = jobs[:_stop_after]
    # Leaves first: they are the most numerous and the cheapest, which keeps the progress bar honest.
    jobs.sort(key=lambda j: -j.level)
    from citylod.lod.executor import make_executor, run_tasks

    if workers is None and scheduler is None and info.width * info.height < _INLINE_BELOW_SAMPLES:
        workers = 0  # starting worker processes (imports, numba cache) costs more than it saves here
    with make_executor(workers=workers, scheduler=scheduler) as ex:
        for r in run_tasks(ex, build_tile, jobs, progress=progress, desc="dsm tiles"):
            done.append(r)
        if _stop_after is not None:
            raise KeyboardInterrupt("stopped on request (test hook)")
        results = {r.key: r for r in done}
        for _round in range(6):
            again = _reconcile_borders(results, all_jobs)
            if not again:
                break
            for job in again:
                all_jobs[f"{job.level}/{job.row}/{job.col}"] = job
            for r in run_tasks(ex, build_tile, again, progress=progress, desc="dsm borders"):
                results[r.key] = r
    root = _assemble(results, levels, info, cells)
    if root is None:
        raise InputError("no tile has valid data", raster)
    write_tileset(partial, root, metric, extras={"citylod": {
        "kind": "dsm", "source": str(Path(raster).name), "source_crs": info.crs_wkt,
        "leaf_target_m": leaf, "tile_size": tile_size, "levels": levels + 1,
        "error_metric": "vertical L-infinity vs full-resolution grid, exact (samples + edge crossings), "
                        "plus float32 horizontal quantisation; bounds the symmetric Hausdorff distance",
    }})
    _replace_dir(partial, out)
    seconds = time.perf_counter() - t0
    per_level = []
    for d in range(levels + 1):
        lv = [r for r in results.values() if r.level == d and r.has_content]
        per_level.append({"level": d, "tiles": len(lv), "triangles": sum(r.triangles for r in lv),
                          "target": leaf * 2 ** (levels - d),
                          "max_error": max((r.geometric_error for r in lv), default=0.0)})
    return DsmBuildReport(
        output=str(out), raster=str(raster), width=info.width, height=info.height, levels=levels + 1,
        tiles=sum(1 for r in results.values() if r.has_content), seconds=seconds,
        samples_per_s=info.width * info.height / max(seconds, 1e-9), peak_rss_mb=_peak_rss_mb(),
        leaf_target=leaf, per_level=per_level, resumed=resumed,
    )


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
            # A parent without content must refine at once: its error is that of its worst child.
            err = r.geometric_error if r.has_content else max(k.geometric_error for k in kids) * 2.0
            specs[key] = TileSpec(key, d, center, lo, hi, err, f"tiles/{key}.glb" if r.has_content else None,
                                  kids, extras={"triangles": r.triangles} if r.has_content else None)
    return specs.get("0/0/0")


def _replace_dir(partial: Path, out: Path) -> None:
    for side in partial.glob("tiles/**/*.json"):
        side.unlink()
    publish_dir(partial, out)


def _peak_rss_mb() -> float:
    import resource

    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return max(own, kids) / 1024.0

