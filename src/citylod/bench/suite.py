"""``citylod bench-suite OUT_DIR`` (``make bench``): every benchmark behind the README's results table.

Each section measures citylod beside its baseline in the same run, on the same machine:

- DSM build: the sample city and a 2049×2049 raster, beside pydelatin and pymartini meshing the same
  raster at the same bound (true errors of all three measured by the exact certifier);
- rendering: the speed-against-error report (``citylod bench``) on the sample city and on a 4097×4097
  raster, beside the full-resolution render of the same cameras;
- points: the Delft AHN3 build (hybrid on and off) beside laspy's decode time of the same files, and the
  point report, when ``../shared/data`` is present;
- semantics: picking latency and the frame-time cost of highlighting and hiding, when available.

Timings are reported, never asserted. The results go to ``OUT_DIR/RESULTS.md`` (and per-section folders).
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

SHARED = Path(__file__).resolve().parents[3].parent / "shared" / "data"


def _dsm_from_city(size: int, path: Path) -> Path:
    """A DSM GeoTIFF of the analytic sample city (no LAZ, no CityGML): for large benchmark rasters."""
    import rasterio
    from rasterio.transform import from_origin

    from citylod.sample.city import make_city

    city = make_city(size, seed=11)
    x, y = city.pixel_centers()
    z = city.surface_height(x, y).astype(np.float32)
    nod = city.nodata_mask(x, y) if hasattr(city, "nodata_mask") else np.zeros_like(z, bool)
    z[nod] = -9999.0
    x0, y0 = city.origin
    path.parent.mkdir(parents=True, exist_ok=True)
    with rasterio.open(path, "w", driver="GTiff", width=size, height=size, count=1, dtype="float32",
                       crs="EPSG:32632", transform=from_origin(x0, y0 + city.extent, city.spacing, city.spacing),
                       nodata=-9999.0, tiled=True, blockxsize=256, blockysize=256, compress="deflate") as ds:
        ds.write(z, 1)
    return path


def _terrain_raster(size: int, path: Path, seed: int = 5) -> Path:
    """Natural terrain, no buildings: fractal (spectral fBm, β = 2.2) hills, 1 m samples, UTM 32N."""
    import rasterio
    from rasterio.transform import from_origin

    rng = np.random.default_rng(seed)
    n = 1 << int(np.ceil(np.log2(size)))
    k = np.fft.fftfreq(n)[:, None] ** 2 + np.fft.rfftfreq(n)[None, :] ** 2
    k[0, 0] = np.inf
    spec = (rng.normal(size=k.shape) + 1j * rng.normal(size=k.shape)) * k ** (-2.2 / 2)
    z = np.fft.irfft2(spec, s=(n, n))[:size, :size]
    z = (z - z.min()) / (z.max() - z.min()) * 300.0 + 100.0
    path.parent.mkdir(parents=True, exist_ok=True)
    with rasterio.open(path, "w", driver="GTiff", width=size, height=size, count=1, dtype="float32",
                       crs="EPSG:32632", transform=from_origin(480_000.0, 5_420_000.0, 1.0, 1.0), tiled=True,
                       blockxsize=256, blockysize=256, compress="deflate") as ds:
        ds.write(z.astype(np.float32), 1)
    return path


def _section(title: str) -> None:
    print(f"\n=== {title}", flush=True)


def _build_in_child(raster: Path, tiles: Path, progress: bool) -> dict[str, Any]:
    """``build_dsm`` (the default executor) in a child process, so its peak memory is the build's own (this
    process holds rasters and render state by then)."""
    from citylod.bench.dsm_bench import json_from_child

    return json_from_child("import dataclasses, json; from citylod.lod.build.dsm import build_dsm; "
                           f"r = build_dsm({str(raster)!r}, {str(tiles)!r}, progress={progress}); "
                           "print('@@' + json.dumps(dataclasses.asdict(r)))")


def run_suite(out_dir: str | os.PathLike[str], *, quick: bool = False, progress: bool = True) -> int:
    from citylod.bench.dsm_bench import bench_dsm, dsm_markdown
    from citylod.bench.report import run_bench
    from citylod.core.camera import load_cameras
    from citylod.lod.build.dsm import build_dsm
    from citylod.sample.files import make_sample

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    md: list[str] = ["# citylod benchmark results", "",
                     f"Machine: {os.cpu_count()} cores; OpenGL: Mesa llvmpipe unless stated. "
                     f"Date: {time.strftime('%Y-%m-%d')}. Reproduce with `make bench` "
                     f"(`citylod bench-suite {out}`{' --quick' if quick else ''}).", ""]
    results: dict[str, Any] = {}

    def flush() -> None:  # results so far, so a long run can be read while it goes on
        (out / "RESULTS.md").write_text("\n".join(md) + "\n")
        (out / "results.json").write_text(json.dumps(results, indent=1, default=str) + "\n")

    _section("sample city")
    size = 257 if quick else 513
    sample = make_sample(out / "sample", size=size, seed=7)

    _section("DSM build vs pydelatin / pymartini")
    rasters = [sample.files["dsm"]]
    if not quick:
        rasters.append(_dsm_from_city(2049, out / "raster2049" / "dsm.tif"))
    dsm_results = [bench_dsm(Path(r), out / "dsm", progress=progress) for r in rasters]
    results["dsm"] = dsm_results
    md.append("## DSM tile tree\n")
    md.append(dsm_markdown(dsm_results))
    flush()

    _section("speed against error: sample city")
    tiles = out / "sample_tiles"
    build_dsm(sample.files["dsm"], tiles, ortho=sample.files["ortho"], progress=progress)
    cams = load_cameras(sample.files["path"])
    cams = cams[::4] if quick else cams[::2]
    taus = [0.5, 1, 2, 4, 8]
    rep = run_bench([tiles], cams, taus, (960, 540), out / "render_sample", progress)
    md.append(_render_md("Sample city DSM tiles, camera path of the sample", rep))
    results["render_sample"] = _render_json(rep)
    flush()

    if not quick:
        for name, title, make in (
                ("4097", "4097×4097 city raster", lambda p: _dsm_from_city(4097, p)),
                ("terrain", "4097×4097 natural terrain (no façades)", lambda p: _terrain_raster(4097, p))):
            _section(f"speed against error: {title}")
            raster = make(out / f"raster_{name}" / "dsm.tif")
            brep = _build_in_child(raster, out / f"tiles_{name}", progress)
            results[f"build_{name}"] = {k: brep[k] for k in ("seconds", "tiles", "per_level", "peak_rss_mb")}
            md.append(f"{title} built by default ({brep['executor']}) in {brep['seconds']:.0f} s ({brep['tiles']} tiles, "
                      f"peak {brep['peak_rss_mb']:.0f} MB).\n")
            rep4 = run_bench([out / f"tiles_{name}"], None, taus, (960, 540), out / f"render_{name}", progress,
                             repeats=1)
            md.append(_render_md(f"{title}, default flight (approach, low pass, orbit)", rep4))
            results[f"render_{name}"] = _render_json(rep4)
            flush()

    if (SHARED / "delft").exists():
        _section("points: Delft AHN3")
        md.append(_points_section(out, progress, results, quick))
        flush()
    else:
        md.append(f"Points: `{SHARED}` not found; the Delft section was skipped.\n")

    try:
        from citylod.bench.semantic_bench import run_semantic_bench
        from citylod.semantics.store import build_city
    except ImportError:
        pass
    else:
        _section("semantics")
        build_city(sample.files["city"], out / "city.gpkg", progress=progress)
        sem = run_semantic_bench(tiles, out / "city.gpkg", cams[:8], (960, 540), out / "semantics")
        md.append("## Semantics\n")
        md_path = sem.get("paths", {}).get("md") if isinstance(sem, dict) else None
        if md_path is not None and Path(md_path).exists():
            md.append(Path(md_path).read_text())
        else:
            md.append(f"picking median {sem['pick_ms_median']:.2f} ms, p95 {sem['pick_ms_p95']:.2f} ms\n")
        results["semantics"] = {k: v for k, v in sem.items() if k in ("summary", "pick_ms_median", "pick_ms_p95")}

    flush()
    print(f"\nresults: {out / 'RESULTS.md'}")
    return 0


def _render_json(rep: Any) -> list[dict[str, Any]]:
    from dataclasses import asdict

    return [asdict(r) for r in rep.rows]


def _render_md(title: str, rep: Any) -> str:
    full = rep.row(None)
    lines = [f"### {title}\n", f"{rep.cameras} cameras, {rep.size[0]}×{rep.size[1]} px; figure: "
             f"`{rep.files.get('png', 'report.png')}`\n",
             "| run | frame ms median | p95 | speed-up vs full | triangles | points | error p99 (px) | "
             "error max (px) | nearest-point p99 (px) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rep.rows:
        label = "full resolution (baseline)" if r.label == "full" else f"τ = {r.tau_px:g} px"
        lines.append(f"| {label} | {r.frame_ms_median:.1f} | {r.frame_ms_p95:.1f} | "
                     f"{full.frame_ms_median / max(r.frame_ms_median, 1e-9):.1f}× | {r.triangles_median:,.0f} | "
                     f"{r.points_median:,.0f} | {r.err_p99_px:.2f} | {r.err_max_px:.1f} | {r.err_near_p99_px:.2f} |")
    return "\n".join(lines) + "\n"


def _points_section(out: Path, progress: bool, results: dict[str, Any], quick: bool) -> str:
    from citylod.bench.report import run_bench

    files = sorted((SHARED / "delft").glob("*.laz"))
    # Floor and builds in a fresh child process, as a user's `citylod build points` runs: in this process,
    # by now holding the DSM and render sections' memory, the same build measured 1.4x slower.
    meas = _points_in_child(files, out, 1 if quick else 3)
    floor = meas["floor"]
    lines = ["## Points: Delft AHN3 (849 k points, RD New)\n",
             "Decode floor and builds measured in one fresh process, best of 3 each (the first build in a "
             "process also loads the compiled kernels).\n",
             "| build | seconds | × laspy decode floor | points/s | nodes | quads | size MB |",
             "|---|---:|---:|---:|---:|---:|---:|",
             f"| laspy + lazrs decode only (floor) | {floor:.2f} | 1.0 | {sum(_count(f) for f in files) / floor:,.0f} "
             "| | | |"]
    for hybrid in (True, False):
        name = "hybrid" if hybrid else "points"
        r = meas[name]
        secs = r["seconds"]
        size_mb = sum(p.stat().st_size for p in (out / f"delft_{name}").rglob("*") if p.is_file()) / 1e6
        lines.append(f"| octree, {'hybrid points + quads' if hybrid else 'points only'} | {secs:.2f} | "
                     f"{secs / floor:.1f} | {r['points'] / secs:,.0f} | {r['nodes']} | {r['quads']} | {size_mb:.1f} |")
    results["points_build"] = {"floor_s": floor}
    lines.append("")
    for name in ("hybrid", "points"):
        rep = run_bench([out / f"delft_{name}"], None, [0.5, 1, 2, 4], (960, 540), out / f"render_delft_{name}",
                        progress, repeats=1 if quick else 3)
        lines.append(_render_md(f"Delft point octree ({name}), default flight", rep))
        results[f"render_delft_{name}"] = _render_json(rep)
    return "\n".join(lines) + "\n"


def _points_measure(files: list[str], out: str, repeats: int) -> dict[str, Any]:
    """Best-of-``repeats`` decode floor and hybrid / points-only builds (what the child process runs).

    The three are taken in turns (floor, hybrid, points, floor, ...), so a slow spell of this shared
    machine falls on all of them alike rather than on whichever was measured during it; the first
    builds also load the kernels, which the later turns do not repeat.
    """
    from citylod.io.las import decode_seconds
    from citylod.lod.build.points import build_points

    floor = math.inf
    res: dict[str, Any] = {}
    for _ in range(repeats):
        floor = min(floor, decode_seconds(files))
        for name, hybrid in (("hybrid", True), ("points", False)):
            t0 = time.perf_counter()
            r = build_points(files, Path(out) / f"delft_{name}", crs="EPSG:28992", hybrid=hybrid, progress=False)
            seconds = time.perf_counter() - t0
            if name not in res or seconds < res[name]["seconds"]:
                res[name] = {"seconds": seconds, "points": r.points, "nodes": r.nodes, "quads": r.quads}
    res["floor"] = floor
    return res


def _points_in_child(files: list[Path], out: Path, repeats: int) -> dict[str, Any]:
    """:func:`_points_measure` in a fresh process."""
    from citylod.bench.dsm_bench import json_from_child

    return json_from_child("import json; from citylod.bench.suite import _points_measure; "
                           f"print('@@' + json.dumps(_points_measure({[str(f) for f in files]!r}, {str(out)!r}, "
                           f"{repeats})))")


def _count(path: Path) -> int:
    import laspy

    with laspy.open(path) as f:
        return int(f.header.point_count)
