"""Far-field surface light fields against the building geometry (issue 28), in one run at one τ.

Cameras over the city: the whole-city overview (:func:`~citylod.core.camera.overview_camera`), the far
legs of a flight (the approach of :func:`~citylod.bench.flight.default_flight`, from 4 down to 1.5 city
extents), and a slow orbit (0.3° per frame at 3 extents) for temporal flicker. For every camera:

* frame time: the draw of :class:`~citylod.render.slf.SlfView` plus the fields' per-frame work in its
  ``prepare`` (``eval_s``: the shader's uniforms of every cell whose direction moved, by default; with
  ``lookup="cpu"`` their ray march and blend on the CPU and their textures written into GL) against the draw of
  :class:`~citylod.render.slf.GeometryView` (the city tileset at the same τ, same ground); loading is left out
  of both (the geometry's reading and upload of tiles, the fields' reading and reconstruction of the stored
  directions, reported apart);
* bytes: what the frame needs (SLF: the field files of the cells drawn and the leaves of buildings drawn;
  geometry: the content bytes of the tiles drawn);
* colour error against the full geometry rendered at 3 × 3 the pixels and box-filtered (the
  anti-aliased picture: a 1× render of thousands of 2-pixel houses is itself aliased; every triangle, with
  textures finer than its pixels, ``REFERENCE_TAU_PX``), over the pixels of cells drawn with their field: the
  mean over pixels of the mean absolute channel difference, and its 99th percentile (0..255); the same for
  the geometry at τ drawn at 1×, and against the 1× full-geometry render;
* flicker: the mean absolute channel difference between consecutive frames of the slow orbit, over the
  pixels that are field pixels in both frames, for the SLF and for the geometry at τ.

``python -m citylod.bench.slf_bench SLF_DIR OUT_DIR [--tau 2]`` or ``citylod bench-slf``; writes
``slf_report.json``, ``slf_report.md`` and the pictures ``{overview,far}_{geometry,slf,difference}.png``
(the geometry anti-aliased, the difference 4× amplified).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from citylod.bench.flight import default_flight
from citylod.core.camera import Camera, overview_camera
from citylod.render.offscreen import save_png
from citylod.render.slf import TEXEL_PX, GeometryView, SlfView

__all__ = ["main", "slf_bench"]

U8 = npt.NDArray[np.uint8]

#: The references draw every triangle (the city's tiles carry all of them) with textures selected at this
#: screen error of their own view: finer than any pixel of the 1× frames (a sixth of a pixel for the 3×
#: reference). Full resolution (every house's own images) does not fit in memory for a city of 8,000
#: textured houses (over 23 GB on this machine).
REFERENCE_TAU_PX = 0.5

#: The overview is one camera: its time is the median of this many arrivals (every field evaluated again, both
#: views drawn), as one frame's draw scatters by 1.5× on a software rasteriser.
OVERVIEW_ARRIVALS = 5


def _err(a: U8, b: U8, mask: npt.NDArray[np.bool_]) -> tuple[float, float]:
    d = np.abs(a.astype(np.int16) - b.astype(np.int16)).mean(axis=2)[mask]
    return (float(d.mean()), float(np.percentile(d, 99))) if d.size else (float("nan"), float("nan"))


def _orbit(lo: Any, hi: Any, n: int, step_deg: float, dist_ext: float) -> list[Camera]:
    lo, hi = np.asarray(lo), np.asarray(hi)
    c = 0.5 * (lo + hi)
    c[2] = lo[2]
    ext = float(max(hi[0] - lo[0], hi[1] - lo[1]))
    out = []
    for i in range(n):
        az = math.radians(200.0 + i * step_deg)
        el = math.radians(35.0)
        eye = c + dist_ext * ext * np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])
        out.append(Camera(tuple(eye), tuple(c), (0.0, 0.0, 1.0), 45.0))  # type: ignore[arg-type]
    return out


def slf_bench(slf_dir: str | Path, out_dir: str | Path, *, tau_px: float = 2.0, size: tuple[int, int] = (960, 540),
              orbit_frames: int = 12, texel_px: float | None = TEXEL_PX, lookup: str = "gpu",
              antialias: bool = True, progress: bool = True) -> dict[str, Any]:
    """Run the comparison; returns (and writes) the report. ``texel_px`` None or 0: fields refined by the
    switching error alone."""
    texel_px = texel_px or None
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    big = (3 * size[0], 3 * size[1])
    with (SlfView(slf_dir, size=size, tau_px=tau_px, texel_px=texel_px, lookup=lookup,
                  antialias=antialias) as sv, GeometryView(slf_dir, size=size, tau_px=tau_px) as gv,
          GeometryView(slf_dir, size=big, tau_px=tau_px) as bv):
        lo, hi = sv.city.root.box.bounds()
        flight = default_flight(lo, hi, n=30)[:10]
        ext = float(max(hi[0] - lo[0], hi[1] - lo[1]))
        far = [c for c in flight if np.linalg.norm(np.subtract(c.position, c.focal_point)) >= 1.5 * ext]
        sets = {"overview": [overview_camera(lo, hi, aspect=size[0] / size[1])], "far flight": far,
                "slow orbit": _orbit(lo, hi, orbit_frames, 0.3, 3.0)}
        frames: dict[str, list[tuple[U8, U8, npt.NDArray[np.bool_]]]] = {}
        # Not timed: the first frame compiles the shaders and loads the overview's fields and tiles. The timed
        # overview then evaluates every cell again, as a view arriving from elsewhere does.
        sv.prepare(sets["overview"][0])
        sv.draw()
        gv.prepare(sets["overview"][0])
        gv.draw()
        for name, cams in sets.items():
            frames[name] = []
            for k, cam in enumerate(cams):
                # Both views: the faster of two draws (the first after another window drew pays for the
                # switch, which one window does not). A frame's own GL work is in prepare (``eval_s``): the
                # shader's uniforms, or the CPU lookup's texture writes (render.gl_texture), never in the draw.
                # The overview, a single frame, is timed as the median of five arrivals.
                timings = []
                for _ in range(OVERVIEW_ARRIVALS if name == "overview" else 1):
                    if name == "overview":
                        sv.invalidate()
                    f = sv.prepare(cam)
                    t_draw = min(sv.draw() for _ in range(2))
                    gstats = gv.prepare(cam)
                    timings.append((t_draw + f.eval_s, t_draw, f.eval_s, min(gv.draw() for _ in range(2))))
                t_frame, t_slf, t_eval, t_geo = (float(np.median(c)) for c in zip(*timings, strict=True))
                img = sv.grab_rgb()
                mask = sv.field_mask()
                geo_bytes = gv.file_bytes()
                geo = gv.grab_rgb()
                gv.prepare(cam, tau_px=REFERENCE_TAU_PX)
                gv.draw()
                ref = gv.grab_rgb()
                gv.prepare(cam)  # back to τ for the next frame's timing
                bv.prepare(cam, tau_px=REFERENCE_TAU_PX)
                bv.draw()
                aa = np.rint(bv.grab_rgb().reshape(size[1], 3, size[0], 3, 3).astype(np.float32).mean(axis=(1, 3)))
                aa = aa.astype(np.uint8)
                mean, p99 = _err(img, aa, mask)
                gmean, gp99 = _err(geo, aa, mask)
                mean1, _ = _err(img, ref, mask)
                rows.append({"set": name, "frame": k, "slf_ms": 1e3 * t_frame, "slf_draw_ms": 1e3 * t_slf,
                             "slf_eval_ms": 1e3 * t_eval, "slf_load_ms": 1e3 * f.load_s,
                             "geometry_ms": 1e3 * t_geo, "geometry_triangles": int(gstats.triangles),
                             "slf_bytes": f.bytes_drawn, "geometry_bytes": geo_bytes,
                             "slf_field_bytes": f.bytes_fields, "slf_building_bytes": f.bytes_buildings,
                             "field_cells": f.cells, "building_cells": f.geometry_cells, "levels": f.levels,
                             "field_pixels": int(mask.sum()), "slf_mean_err": mean, "slf_p99_err": p99,
                             "geometry_tau_mean_err": gmean, "geometry_tau_p99_err": gp99,
                             "slf_mean_err_vs_1x": mean1})
                frames[name].append((img, geo, mask))
                if name == "overview" or (name == "far flight" and k == 0):
                    tag = "overview" if name == "overview" else "far"
                    save_png(out / f"{tag}_geometry.png", aa)
                    save_png(out / f"{tag}_slf.png", img)
                    d = np.abs(img.astype(np.int16) - aa.astype(np.int16)).mean(axis=2)
                    save_png(out / f"{tag}_difference.png",
                             np.repeat(np.clip(4 * d, 0, 255).astype(np.uint8)[..., None], 3, axis=2))
                if progress:
                    print(f"{name} {k}: slf {1e3 * t_frame:.0f} ms {f.bytes_drawn / 1e6:.2f} MB err {mean:.1f}/{p99:.0f}"
                          f" | geometry {1e3 * t_geo:.0f} ms {geo_bytes / 1e6:.2f} MB", flush=True)
        orbit = frames["slow orbit"]
        fl_s, fl_g = [], []
        for (a, ga, ma), (b, gb, mb) in itertools.pairwise(orbit):
            m = ma & mb
            if m.any():
                fl_s.append(float(np.abs(a.astype(np.int16) - b.astype(np.int16)).mean(axis=2)[m].mean()))
                fl_g.append(float(np.abs(ga.astype(np.int16) - gb.astype(np.int16)).mean(axis=2)[m].mean()))
    summary: dict[str, Any] = {"tau_px": tau_px, "texel_px": texel_px, "lookup": lookup, "antialias": antialias,
                               "size": list(size)}
    for name in sets:
        r = [x for x in rows if x["set"] == name]
        if not r:
            continue
        summary[name] = {
            "frames": len(r),
            "slf_ms_median": float(np.median([x["slf_ms"] for x in r])),
            "slf_draw_ms_median": float(np.median([x["slf_draw_ms"] for x in r])),
            "slf_eval_ms_median": float(np.median([x["slf_eval_ms"] for x in r])),
            "slf_load_ms_median": float(np.median([x["slf_load_ms"] for x in r])),
            "geometry_ms_median": float(np.median([x["geometry_ms"] for x in r])),
            "geometry_triangles_median": float(np.median([x["geometry_triangles"] for x in r])),
            "speedup": float(np.median([x["geometry_ms"] / x["slf_ms"] for x in r])),
            "slf_bytes_median": float(np.median([x["slf_bytes"] for x in r])),
            "slf_building_bytes_median": float(np.median([x["slf_building_bytes"] for x in r])),
            "building_cells_median": float(np.median([x["building_cells"] for x in r])),
            "geometry_bytes_median": float(np.median([x["geometry_bytes"] for x in r])),
            "data_ratio": float(np.median([x["geometry_bytes"] / max(x["slf_bytes"], 1) for x in r])),
            "slf_mean_err": float(np.nanmean([x["slf_mean_err"] for x in r])),
            "slf_p99_err": float(np.nanmax([x["slf_p99_err"] for x in r])),
            "geometry_tau_mean_err": float(np.nanmean([x["geometry_tau_mean_err"] for x in r])),
            "slf_mean_err_vs_1x": float(np.nanmean([x["slf_mean_err_vs_1x"] for x in r])),
        }
    summary["flicker"] = {"slf": float(np.mean(fl_s)) if fl_s else float("nan"),
                          "geometry": float(np.mean(fl_g)) if fl_g else float("nan"), "pairs": len(fl_s)}
    report = {"summary": summary, "frames": rows}
    (out / "slf_report.json").write_text(json.dumps(report, indent=1, default=str) + "\n")
    lines = [f"# Far-field SLF against building geometry (τ = {tau_px} px, "
             f"{f'texels ≤ {texel_px:g} px' if texel_px else 'fields by switching error alone'}, "
             f"{size[0]}×{size[1]}, lookup on the {lookup.upper()}{'' if antialias else ', aliased'})", "",
             "| cameras | frames | SLF frame ms (draw + evaluation; loading) | geometry ms (triangles) | speed-up |"
             " SLF MB (of it buildings) |"
             " geometry MB | less data | mean err | p99 err | geometry@τ mean err | building cells |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name in sets:
        s = summary.get(name)
        if s:
            lines.append(f"| {name} | {s['frames']} | {s['slf_ms_median']:.0f} ({s['slf_draw_ms_median']:.0f} + "
                         f"{s['slf_eval_ms_median']:.0f}; {s['slf_load_ms_median']:.0f}) | "
                         f"{s['geometry_ms_median']:.0f} ({s['geometry_triangles_median'] / 1e3:.0f} k) | "
                         f"{s['speedup']:.1f}× | {s['slf_bytes_median'] / 1e6:.2f} "
                         f"({s['slf_building_bytes_median'] / 1e6:.2f}) | "
                         f"{s['geometry_bytes_median'] / 1e6:.2f} | {s['data_ratio']:.1f}× | {s['slf_mean_err']:.1f} | "
                         f"{s['slf_p99_err']:.0f} | {s['geometry_tau_mean_err']:.1f} | "
                         f"{s['building_cells_median']:.0f} |")
    fl = summary["flicker"]
    lines += ["", f"Flicker (slow orbit, {fl['pairs']} frame pairs, field pixels): SLF {fl['slf']:.2f}, "
              f"geometry {fl['geometry']:.2f} (mean |Δ| per channel, 0..255)."]
    (out / "slf_report.md").write_text("\n".join(lines) + "\n")
    return report


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m citylod.bench.slf_bench", description=__doc__.splitlines()[0])
    p.add_argument("slf_dir", type=Path)
    p.add_argument("out_dir", type=Path)
    p.add_argument("--tau", type=float, default=2.0)
    p.add_argument("--orbit-frames", type=int, default=12)
    p.add_argument("--texel-px", type=float, default=TEXEL_PX,
                   help=f"also refine fields while a texel covers more pixels (default {TEXEL_PX}; 0: never)")
    p.add_argument("--lookup", choices=("gpu", "cpu"), default="gpu")
    p.add_argument("--no-antialias", action="store_true")
    a = p.parse_args(argv)
    t0 = time.perf_counter()
    slf_bench(a.slf_dir, a.out_dir, tau_px=a.tau, orbit_frames=a.orbit_frames, texel_px=a.texel_px, lookup=a.lookup,
              antialias=not a.no_antialias)
    print((a.out_dir / "slf_report.md").read_text())
    print(f"{time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
