"""Benchmark of semantic shading: picking latency and the frame-time cost of highlighting and hiding.

For each camera the same resident tiles are drawn first without any semantics (no shader replacement),
then with a :class:`~citylod.render.semantic.SemanticOverlay` attached and idle, then with 1, 10 and 1000
objects (or all, when fewer) highlighted, and hidden: the objects nearest the camera's focal point, so
that they are on screen. Everything is measured in one run on one machine, so the columns compare. The
picking latency is that of :meth:`SemanticOverlay.pick` (one depth read-back, one proxy test, one
attribute row) at pixels spread over the frames.

Timings go to the report (markdown + csv), never into assertions (docs/STYLE.md).

Run: ``python -m citylod.bench.semantic_bench SAMPLE_DIR [-o OUT] [--size WxH] [--cameras N]`` where
SAMPLE_DIR holds ``dsm/`` (or ``--tiles``), ``city.gpkg`` and ``path.json``.
"""

from __future__ import annotations

import argparse
import csv
import io
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from citylod.core.camera import Camera, load_cameras
from citylod.core.fileio import atomic_write_text
from citylod.render.offscreen import OffscreenRenderer
from citylod.render.semantic import SemanticOverlay
from citylod.semantics.store import CityStore

__all__ = ["run_semantic_bench"]


def _timed(r: OffscreenRenderer, repeats: int) -> float:
    r.draw()  # warm-up: a changed shader or state table is compiled / uploaded here
    return 1000.0 * float(np.median([r.draw() for _ in range(max(1, repeats))]))


def _paired(r: OffscreenRenderer, overlay: SemanticOverlay, repeats: int) -> tuple[float, float]:
    """Median ms of the frame without and with semantics, drawn alternately so that the load of a
    shared machine hits both alike; the first draw after each switch (new shader source) is not timed."""
    off: list[float] = []
    on: list[float] = []
    for _ in range(max(1, repeats)):
        for enabled, times in ((False, off), (True, on)):
            overlay.set_enabled(enabled)
            r.draw()
            times.append(r.draw())
    overlay.set_enabled(True)
    return 1000.0 * float(np.median(off)), 1000.0 * float(np.median(on))


def run_semantic_bench(dsm_tiles: str | os.PathLike[str], store: CityStore | str | os.PathLike[str],
                       cameras: Sequence[Camera], size: tuple[int, int], out_dir: str | os.PathLike[str], *,
                       counts: Sequence[int] = (1, 10, 1000), repeats: int = 5, picks: int = 50,
                       resolution: float = 0.5, seed: int = 0) -> dict[str, Any]:
    """Measure picking latency and the frame-time cost of highlighting and hiding; write the report.

    Parameters
    ----------
    dsm_tiles
        A tileset folder (DSM tiles; any tileset works).
    store
        The city store (or its path).
    cameras
        Cameras in the data's CRS.
    size
        (width, height) pixels.
    out_dir
        Folder for ``semantic_bench.md`` and ``semantic_bench.csv``.
    counts
        Numbers of objects highlighted / hidden (capped at the store's size).
    repeats
        Draws per measurement (median).
    picks
        Number of picks for the latency.
    resolution
        Contour-map texel size in metres.

    Returns
    -------
    dict
        ``rows`` (per camera and configuration), ``summary`` (per configuration), ``pick_ms_median``,
        ``pick_ms_p95``, ``pick_hits``, ``map`` (texels, resolution, build seconds), ``paths``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    own = not isinstance(store, CityStore)
    st: CityStore = store if isinstance(store, CityStore) else CityStore.open(store)
    n_obj = len(st.ids)
    ns = sorted({min(int(c), n_obj) for c in counts if c > 0})
    rows: list[dict[str, Any]] = []
    rng = np.random.default_rng(seed)
    pick_ms: list[float] = []
    hits = 0
    with OffscreenRenderer([dsm_tiles], size=size) as r:
        # Pass 1: no semantics at all (the shader is the renderer's own).
        base: list[float] = []
        stats = []
        for cam in cameras:
            stats.append(r.prepare(cam))
            base.append(_timed(r, repeats))
        t0 = time.perf_counter()
        overlay = SemanticOverlay(r.scene, st, resolution=resolution)
        build_s = time.perf_counter() - t0
        state = overlay.state
        for ci, cam in enumerate(cameras):
            r.prepare(cam)
            frame = {"baseline": base[ci]}
            paired = {"baseline": base[ci]}
            paired["attached_idle"], frame["attached_idle"] = _paired(r, overlay, repeats)
            near = st.within_distance(np.asarray(cam.focal_point)[:2], 1e12)
            update_ms: dict[str, float] = {}
            for k in ns:
                for kind in ("highlight", "hide"):
                    ids = near[:k]
                    t1 = time.perf_counter()
                    if kind == "highlight":
                        state.highlight(ids)
                    else:
                        state.hide(ids)
                    update_ms[f"{kind}_{k}"] = 1000.0 * (time.perf_counter() - t1)
                    paired[f"{kind}_{k}"], frame[f"{kind}_{k}"] = _paired(r, overlay, repeats)
                    state.clear()
            # Picks at random pixels showing geometry (row 0 of the depth image is the top).
            r.draw()
            rows_px, cols_px = np.nonzero(np.isfinite(r.grab_depth()))
            h = size[1]
            for _ in range(max(1, picks // max(len(cameras), 1)) if len(rows_px) else 0):
                j = int(rng.integers(0, len(rows_px)))
                x, y = int(cols_px[j]), h - 1 - int(rows_px[j])
                t1 = time.perf_counter()
                res = overlay.pick(r.renderer, x, y)
                pick_ms.append(1000.0 * (time.perf_counter() - t1))
                hits += res.object_id is not None
            for name, ms in frame.items():
                b = paired[name]
                rows.append({"camera": ci, "config": name, "objects": _objects(name), "frame_ms": ms,
                             "baseline_ms": b, "overhead_ms": ms - b, "overhead_pct": 100.0 * (ms - b) / b,
                             "state_update_ms": update_ms.get(name, 0.0), "tiles": stats[ci].tiles,
                             "triangles": stats[ci].triangles})
        texels = overlay.map.shape
        overlay.close()
    if own:
        st.close()
    configs = list(dict.fromkeys(row["config"] for row in rows))
    summary = []
    for c in configs:
        sel = [row for row in rows if row["config"] == c]
        summary.append({"config": c, "objects": sel[0]["objects"],
                        "frame_ms_median": float(np.median([s["frame_ms"] for s in sel])),
                        "baseline_ms_median": float(np.median([s["baseline_ms"] for s in sel])),
                        "overhead_ms_median": float(np.median([s["overhead_ms"] for s in sel])),
                        "overhead_pct_median": float(np.median([s["overhead_pct"] for s in sel])),
                        "state_update_ms_median": float(np.median([s["state_update_ms"] for s in sel]))})
    result: dict[str, Any] = {
        "rows": rows, "summary": summary,
        "pick_ms_median": float(np.median(pick_ms)) if pick_ms else float("nan"),
        "pick_ms_p95": float(np.percentile(pick_ms, 95)) if pick_ms else float("nan"),
        "picks": len(pick_ms), "pick_hits": hits, "objects": n_obj,
        "map": {"texels": texels, "resolution_m": overlay.map.resolution, "build_s": build_s,
                "bytes": int(texels[0] * texels[1] * 16)},
        "size": tuple(size), "cameras": len(cameras),
    }
    csv_path, md_path = out / "semantic_bench.csv", out / "semantic_bench.md"
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
    writer.writeheader()
    for row in rows:
        writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
    atomic_write_text(csv_path, buf.getvalue())
    atomic_write_text(md_path, _markdown(result))
    result["paths"] = {"csv": csv_path, "md": md_path}
    return result


def _objects(config: str) -> int:
    tail = config.rsplit("_", 1)[-1]
    return int(tail) if tail.isdigit() else 0


def _markdown(res: dict[str, Any]) -> str:
    m = res["map"]
    lines = [
        "# Semantic shading benchmark",
        "",
        f"{res['cameras']} cameras, {res['size'][0]}×{res['size'][1]} px, {res['objects']} city objects; "
        f"contour map {m['texels'][1]}×{m['texels'][0]} texels at {m['resolution_m']:.3g} m "
        f"({m['bytes'] / 2**20:.1f} MiB, built in {m['build_s']:.2f} s).",
        "Frame times are medians over the cameras of the median of repeated draws of the same resident tiles.",
        "`baseline`: a first pass before the overlay existed. Other rows: each draw with the overlay enabled",
        "alternates with one of the same frame with it disabled (the renderer's own shader), and the overhead",
        "is against those. `attached_idle`: overlay attached, no object has a state.",
        "",
        "| configuration | objects | frame ms | without ms | overhead ms | overhead % | state update ms |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for s in res["summary"]:
        lines.append(f"| {s['config']} | {s['objects']} | {s['frame_ms_median']:.1f} | "
                     f"{s['baseline_ms_median']:.1f} | "
                     f"{s['overhead_ms_median']:+.1f} | {s['overhead_pct_median']:+.1f} | "
                     f"{s['state_update_ms_median']:.2f} |")
    lines += ["", f"Picking ({res['picks']} picks, {res['pick_hits']} on an object): median "
              f"{res['pick_ms_median']:.2f} ms, p95 {res['pick_ms_p95']:.2f} ms.", ""]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m citylod.bench.semantic_bench", description=__doc__.split("\n")[0])
    p.add_argument("sample", type=Path, help="folder with dsm/, city.gpkg and path.json")
    p.add_argument("-o", "--output", type=Path, default=None)
    p.add_argument("--tiles", type=Path, default=None)
    p.add_argument("--size", default="960x540")
    p.add_argument("--cameras", type=int, default=6)
    p.add_argument("--repeats", type=int, default=5)
    a = p.parse_args(argv)
    w, h = (int(v) for v in a.size.lower().split("x"))
    cams = load_cameras(a.sample / "path.json")
    step = max(1, len(cams) // max(a.cameras, 1))
    res = run_semantic_bench(a.tiles or a.sample / "dsm", a.sample / "city.gpkg", cams[::step][:a.cameras], (w, h),
                             a.output or a.sample / "semantic_bench", repeats=a.repeats)
    print(res["paths"]["md"].read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
