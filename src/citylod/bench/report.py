"""Speed against error: fly a camera path once per τ and once at full resolution, and write a report.

For every camera the full-resolution frame (every leaf tile, no LOD) is drawn first, in the same run and
the same window, as the baseline; then the LOD frame for each τ. Per frame: the draw time with the
selection resolved and resident (median of ``repeats`` draws, after one warm-up draw that uploads new
geometry), the selection time, what was drawn, and the measured screen-space error against the baseline
(:func:`citylod.render.sse.measure_error`). Per τ the report gives median and p95 over cameras.

Outputs in ``out_dir`` (each written under a temporary name and renamed): ``frames.csv`` (one row per
camera and τ), ``report.csv`` (one row per τ and the baseline), ``report.md`` (the table), ``report.png``
(frame time and triangles against error) and, for one representative camera, ``lod_tau1.png``,
``full.png`` and ``diff.png``. Timings go to the report only, never into tests.
"""

from __future__ import annotations

import argparse
import csv
import io
import math
import os
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from citylod.bench.flight import default_flight, default_flight_legs
from citylod.core.camera import Camera, in_local_frame, load_cameras, local_up, overview_camera
from citylod.core.errors import CitylodError
from citylod.core.fileio import atomic_write_bytes
from citylod.render import _vtk
from citylod.render.offscreen import OffscreenRenderer, save_png
from citylod.render.sse import measure_error

__all__ = ["BenchResult", "FrameRow", "TauRow", "bench_command", "run_bench"]


@dataclass
class FrameRow:
    """One camera at one τ (``tau_px`` = 0 for the full-resolution baseline)."""

    tau_px: float
    camera: int
    frame_ms: float
    select_ms: float
    tiles: int
    triangles: int
    points: int
    bytes_drawn: int
    bytes_resident: int
    max_sse_px: float
    err_max_px: float
    err_p99_px: float
    err_near_max_px: float
    err_near_p99_px: float
    valid_px: int
    lod_only_px: int
    full_only_px: int


@dataclass
class TauRow:
    """Summary of one τ over the path."""

    label: str
    tau_px: float
    frames: int
    frame_ms_median: float
    frame_ms_p95: float
    select_ms_median: float
    tiles_median: float
    triangles_median: float
    points_median: float
    bytes_resident_max: int
    err_max_px: float
    err_p99_px: float
    err_near_max_px: float
    err_near_p99_px: float
    lod_only_px: int
    full_only_px: int


@dataclass
class BenchResult:
    """What :func:`run_bench` measured and wrote."""

    rows: list[TauRow]
    frames: list[FrameRow]
    out_dir: Path
    files: dict[str, Path] = field(default_factory=dict)
    size: tuple[int, int] = (0, 0)
    cameras: int = 0
    gl_backend: str | None = None
    #: The same summaries for the overview camera alone (the whole dataset in view), not part of ``rows``.
    overview: list[TauRow] = field(default_factory=list)
    #: The default flight's legs (name, camera indices); empty for a user's path.
    legs: list[tuple[str, range]] = field(default_factory=list)

    def row(self, tau_px: float | None) -> TauRow:
        """The summary for ``tau_px`` (None for the full-resolution baseline)."""
        for r in self.rows:
            if (tau_px is None and r.label == "full") or (tau_px is not None and r.label != "full"
                                                          and abs(r.tau_px - tau_px) < 1e-9):
                return r
        raise KeyError(tau_px)


def _summarise(label: str, tau: float, frames: list[FrameRow]) -> TauRow:
    ft = np.array([f.frame_ms for f in frames])
    return TauRow(
        label=label, tau_px=tau, frames=len(frames),
        frame_ms_median=float(np.median(ft)), frame_ms_p95=float(np.percentile(ft, 95)),
        select_ms_median=float(np.median([f.select_ms for f in frames])),
        tiles_median=float(np.median([f.tiles for f in frames])),
        triangles_median=float(np.median([f.triangles for f in frames])),
        points_median=float(np.median([f.points for f in frames])),
        bytes_resident_max=int(max(f.bytes_resident for f in frames)),
        # Worst frame: the bound a τ promises must hold in every frame, not on average.
        err_max_px=float(max(f.err_max_px for f in frames)),
        err_p99_px=float(max(f.err_p99_px for f in frames)),
        err_near_max_px=float(max(f.err_near_max_px for f in frames)),
        err_near_p99_px=float(max(f.err_near_p99_px for f in frames)),
        lod_only_px=int(sum(f.lod_only_px for f in frames)),
        full_only_px=int(sum(f.full_only_px for f in frames)),
    )


def _timed_draws(r: OffscreenRenderer, repeats: int) -> float:
    r.draw()  # warm-up: uploads the geometry of tiles shown for the first time
    return 1000.0 * float(np.median([r.draw() for _ in range(max(1, repeats))]))


def run_bench(sources: Sequence[str | os.PathLike[str]], cameras: Sequence[Camera] | None,
              taus: Sequence[float], size: tuple[int, int], out_dir: str | os.PathLike[str],
              progress: bool = False, *, repeats: int = 3, cache_bytes: int = 4 << 30,
              representative: int | None = None) -> BenchResult:
    """Fly ``cameras`` once at full resolution and once per τ; measure and write the report.

    Parameters
    ----------
    sources
        Tileset folders or ``tileset.json`` files.
    cameras
        The path; None for :func:`citylod.bench.flight.default_flight` over the data's bounds.
    taus
        Screen-space error thresholds to compare, pixels.
    size
        (width, height) of the frames.
    out_dir
        Report folder (created).
    repeats
        Timed draws per camera and τ (the median is kept).
    cache_bytes
        Tile cache budget; must hold the full-resolution data of a frame.
    representative
        Index of the camera whose images go into the report (default: the middle one).
    """
    from tqdm import tqdm

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    taus = sorted(float(t) for t in taus)
    if not taus or min(taus) <= 0:
        raise CitylodError("--tau needs positive thresholds, e.g. 0.5,1,2,4,8")
    frames: list[FrameRow] = []
    files: dict[str, Path] = {}
    with OffscreenRenderer(sources, size=size, tau_px=taus[0], cache_bytes=cache_bytes) as r:
        scene = r.scene
        lo, hi = scene.bounds
        up = local_up(scene.crs, lo, hi)  # another tool's ECEF tileset: flown around its own vertical
        cams = list(cameras) if cameras else in_local_frame(default_flight, lo, hi, up)
        rep = len(cams) // 2 if representative is None else representative
        rep_tau = min(taus, key=lambda t: abs(t - 1.0))
        bar = tqdm(total=(len(cams) + 1) * (len(taus) + 1), desc="bench", unit="frame", disable=not progress)
        # The flight, then the overview camera (the whole dataset in view; camera -1 in frames.csv), whose
        # triangle counts show whether frames are output-sensitive: summarised apart from the flight.
        overview = in_local_frame(lambda a, b: [overview_camera(a, b, aspect=size[0] / size[1])], lo, hi, up)[0]
        for ci, cam in [*enumerate(cams), (-1, overview)]:
            # Baseline: every leaf drawn, same window, same camera.
            st = r.prepare(cam, full_resolution=True)
            ms = _timed_draws(r, repeats)
            depth_full = r.grab_depth()
            rgb_full = r.grab_rgb() if ci == rep else None
            frames.append(FrameRow(0.0, ci, ms, 0.0, st.tiles, st.triangles, st.points, st.bytes_drawn,
                                   scene.cache.bytes_used, 0.0, 0.0, 0.0, 0.0, 0.0,
                                   int(np.isfinite(depth_full).sum()), 0, 0))
            bar.update()
            for tau in taus:
                scene.tau_px = tau
                st = r.prepare(cam)
                view = scene.view(cam, r.size)
                t0 = time.perf_counter()
                for _ in range(max(1, repeats)):
                    scene.select_all(view)
                sel_ms = 1000.0 * (time.perf_counter() - t0) / max(1, repeats)
                ms = _timed_draws(r, repeats)
                depth = r.grab_depth()
                err = measure_error(depth, depth_full, cam)
                assert not isinstance(err, tuple)
                frames.append(FrameRow(tau, ci, ms, sel_ms, st.tiles, st.triangles, st.points, st.bytes_drawn,
                                       st.bytes_resident, st.max_sse_px, err.max_px, err.p99_px,
                                       err.near_max_px, err.near_p99_px, err.valid, err.lod_only,
                                       err.full_only))
                if ci == rep and tau == rep_tau and rgb_full is not None:
                    rgb = r.grab_rgb()
                    files["lod"] = save_png(out / f"lod_tau{tau:g}.png", rgb)
                    files["full"] = save_png(out / "full.png", rgb_full)
                    diff = np.abs(rgb.astype(np.int16) - rgb_full.astype(np.int16))
                    # Amplified so a one-pixel shift of an edge is visible; white = no difference.
                    files["diff"] = save_png(out / "diff.png",
                                             (255 - np.clip(diff * 4, 0, 255)).astype(np.uint8))
                bar.update()
        bar.close()
    flight = [f for f in frames if f.camera >= 0]
    rows = [_summarise("full", 0.0, [f for f in flight if f.tau_px == 0.0])]
    rows += [_summarise(f"tau={t:g}", t, [f for f in flight if f.tau_px == t]) for t in taus]
    over = [f for f in frames if f.camera < 0]
    overview_rows = [_summarise("full", 0.0, [f for f in over if f.tau_px == 0.0])]
    overview_rows += [_summarise(f"tau={t:g}", t, [f for f in over if f.tau_px == t]) for t in taus]
    result = BenchResult(rows, frames, out, files, tuple(size), len(cams), _vtk.WINDOW_BACKEND, overview_rows,
                         [] if cameras else default_flight_legs(len(cams)))
    _write_csv(out / "frames.csv", [asdict(f) for f in frames])
    _write_csv(out / "report.csv", [asdict(rw) for rw in rows])
    files["frames_csv"], files["csv"] = out / "frames.csv", out / "report.csv"
    files["png"] = _plot(out / "report.png", rows)
    files["md"] = _write_md(out / "report.md", result, [str(s) for s in sources])
    return result


def _write_csv(path: Path, rows: list[dict[str, object]]) -> None:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
    writer.writeheader()
    for row in rows:
        writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
    atomic_write_bytes(path, buf.getvalue().encode())


def _size_panel(full: TauRow) -> tuple[str, str]:
    """What the figure's right panel counts: the primitives the data is mostly made of at full resolution
    (points for a point cloud, triangles for surfaces; a hybrid point octree's few quads are not what its
    cost is made of). Its counts of 0 are left out of the plot: a log axis has no place for them."""
    if full.points_median > full.triangles_median:
        return "points_median", "points drawn, median"
    return "triangles_median", "triangles drawn, median"


def _coinciding(rows: list[TauRow], xs: list[float], ys: list[float]) -> dict[tuple[float, float], list[float]]:
    """The τ of each plotted point, points that coincide (to a thousandth of a decade on both log axes)
    labelled once: overlapping labels ("τ=2" over "τ=0.5") read as garbage."""
    groups: dict[tuple[float, float], list[float]] = {}
    seen: dict[tuple[int, int], tuple[float, float]] = {}
    for r, x, y in zip(rows, xs, ys, strict=True):
        cell = (round(math.log10(max(x, 1e-300)) * 1000), round(math.log10(max(abs(y), 1e-300)) * 1000))
        at = seen.setdefault(cell, (x, y))
        groups.setdefault(at, []).append(r.tau_px)
    return {k: sorted(v) for k, v in groups.items()}


def _plot(path: Path, rows: list[TauRow]) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lod = [r for r in rows if r.label != "full"]
    full = next(r for r in rows if r.label == "full")
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    size_key, size_label = _size_panel(full)
    for ax, key, label in ((axes[0], "frame_ms_median", "frame time, median (ms)"), (axes[1], size_key, size_label)):
        shown = [r for r in lod if ax is axes[0] or getattr(r, key) > 0]  # no 0 on the log axis
        ys = [getattr(r, key) for r in shown]
        # Log axis: a floor keeps an exact (0 px) frame on the plot.
        err = [max(r.err_near_p99_px, 0.01) for r in shown]
        err_ray = [max(r.err_p99_px, 0.01) for r in shown]
        ax.plot(err, ys, "o-", label="LOD (error: nearest point, p99)")
        ax.plot(err_ray, ys, "s--", alpha=0.6, label="LOD (error: along the ray, p99)")
        for (x, y), taus in _coinciding(shown, err, ys).items():
            ax.annotate("τ=" + ", ".join(f"{t:g}" for t in taus), (x, y), textcoords="offset points",
                        xytext=(4, 4), fontsize=8)
        ax.axhline(getattr(full, key), color="k", ls=":", label="full resolution")
        ax.set_xlabel("measured screen-space error, worst frame p99 (px)")
        ax.set_ylabel(label)
        ax.set_xscale("log")
        ax.grid(True, alpha=0.3)
    axes[1].set_yscale("log")
    # Frame times from zero: a speed-up reads as the ratio of heights, and the scatter of a small scene's few
    # milliseconds does not fill the panel.
    axes[0].set_ylim(0, 1.08 * max([full.frame_ms_median, *(r.frame_ms_median for r in lod)]))
    axes[0].legend(fontsize=8)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
    return path


def _md_row(r: TauRow) -> str:
    return (f"| {r.label} | {r.frame_ms_median:.1f} / {r.frame_ms_p95:.1f} | {r.select_ms_median:.2f} "
            f"| {r.tiles_median:.0f} | {r.triangles_median:.0f} | {r.points_median:.0f} "
            f"| {r.bytes_resident_max / 1e6:.1f} | {r.err_max_px:.2f} / {r.err_p99_px:.2f} "
            f"| {r.err_near_max_px:.2f} / {r.err_near_p99_px:.2f} | {r.full_only_px} | {r.lod_only_px} |")


def _legs_table(res: BenchResult) -> list[str]:
    """Markdown lines: per leg of the default flight, the median frame time of each run and its speed-up
    against full resolution, and the median triangles. Where the LOD pays off depends on the leg: far
    views draw coarse tiles, a low pass draws the leaves near the camera at any τ."""
    taus = [r.tau_px for r in res.rows if r.label != "full"]
    lines = ["By leg of the default flight (medians over the leg's cameras; ×: full-resolution frame time over "
             "the LOD frame's):", "",
             "| leg | cameras | full ms (triangles) | " + " | ".join(f"τ = {t:g} px ms (triangles), ×" for t in taus) + " |",
             "|---|---|---|" + "---|" * len(taus)]
    for name, idx in res.legs:
        cams = set(idx)

        def med(tau: float, attr: str, cams: set[int] = cams) -> float:
            return float(np.median([getattr(f, attr) for f in res.frames if f.camera in cams and f.tau_px == tau]))

        if not any(f.camera in cams for f in res.frames):
            continue
        full = med(0.0, "frame_ms")
        cells = [f"{med(t, 'frame_ms'):.1f} ({med(t, 'triangles'):.0f}), {full / med(t, 'frame_ms'):.1f}×"
                 for t in taus]
        lines.append(f"| {name} | {len(idx)} | {full:.1f} ({med(0.0, 'triangles'):.0f}) | " + " | ".join(cells) + " |")
    return lines


def _write_md(path: Path, res: BenchResult, sources: list[str]) -> Path:
    w, h = res.size
    lines = [
        "# citylod benchmark: speed against measured error",
        "",
        f"Sources: {', '.join(sources)}. {res.cameras} cameras, {w}×{h} px, OpenGL through "
        f"{res.gl_backend or '?'}. Frame time: median of repeated draws with the selection resolved and "
        "resident (GPU finished); selection time: one `select` over all layers. Error: measured against "
        "the full-resolution frame of the same camera, in pixels; *ray* compares the two surface points on "
        "the same pixel ray, *near* the nearest full-resolution point within ±2 px (closer to the "
        "Hausdorff distance the geometric error bounds; it cannot resolve less than the spacing of pixel "
        "samples on the surface, which at grazing angles is several footprints). Max and p99 are of the "
        "worst frame. *holes* counts pixels the full-resolution frame covers and the LOD frame does not "
        "(cracks, and silhouettes that moved), *extra* the reverse (skirts at the data's border, moved "
        "silhouettes), summed over the path.",
        "",
        "| run | frame ms (median / p95) | select ms | tiles | triangles | points | resident MB "
        "| err ray max / p99 (px) | err near max / p99 (px) | holes | extra |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    header = lines[-2:]
    lines += [_md_row(r) for r in res.rows]
    if res.legs:
        lines += ["", *_legs_table(res)]
    if res.overview:
        lines += ["", "Overview camera (the whole dataset in view; not part of the flight above):", "", *header]
        lines += [_md_row(r) for r in res.overview]
    lines += ["", "![speed against error](report.png)", ""]
    if "lod" in res.files:
        lines += [
            "Representative camera: LOD frame, full-resolution frame, and their difference (×4, white = equal):",
            "",
            f"![LOD]({res.files['lod'].name}) ![full resolution](full.png) ![difference](diff.png)",
            "",
        ]
    lines += ["Per-frame numbers: [frames.csv](frames.csv); summary: [report.csv](report.csv).", ""]
    atomic_write_bytes(path, "\n".join(lines).encode())
    return path


def bench_command(args: argparse.Namespace, progress: bool = True) -> int:
    """``citylod bench SOURCES... [--path PATH.json] -o REPORT_DIR [--tau 0.5,1,2,4,8] [--size WxH]``."""
    cameras = load_cameras(args.path) if getattr(args, "path", None) else None
    res = run_bench(args.sources, cameras, args.tau, tuple(args.size), args.output, progress)
    for r in res.rows:
        print(f"{r.label:>9s}: {r.frame_ms_median:8.1f} ms median, {r.triangles_median:10.0f} triangles, "
              f"error p99 {r.err_near_p99_px:.2f} px (ray {r.err_p99_px:.2f} px)")
    print(f"report: {res.files['md']}")
    return 0
