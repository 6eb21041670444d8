"""``citylod demo`` (what ``make demo`` runs): the main job on the built-in sample city.

1. writes the synthetic sample city (DSM, orthophoto, LAZ, CityGML),
2. builds the DSM tile tree (textured), the point octree and the semantic city store,
3. with a display, opens the desktop application on all three with one building highlighted;
   without one, renders the fly-through off-screen and writes the speed-against-error report, and says where.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
import warnings
from pathlib import Path


def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _step(msg: str) -> float:
    print(f"==> {msg}", flush=True)
    return time.perf_counter()


def _build(out: Path, files: dict[str, Path], progress: bool) -> tuple[list[Path], Path | None]:
    """The sample's DSM tiles, point octree and city store; returns the tilesets built and the store."""
    from citylod.lod.build.dsm import build_dsm

    _step("DSM tile tree (3D Tiles, guaranteed error, textured)")
    rep = build_dsm(files["dsm"], out / "dsm_tiles", ortho=files["ortho"], progress=progress)
    print(dataclasses.replace(rep, heights="").summary())

    built = [out / "dsm_tiles"]
    try:
        from citylod.lod.build.points import build_points

        _step("point octree (hybrid points + plane quads)")
        prep = build_points([files["points"]], out / "point_tiles", progress=progress)
        print(prep.summary())
        built.append(out / "point_tiles")
    except ImportError as exc:
        print(f"    skipped: {exc}")
    store = None
    try:
        from citylod.semantics.store import build_city

        _step("semantic city store (GeoPackage)")
        crep = build_city(files["city"], out / "city.gpkg", progress=progress)
        print(crep.summary())
        store = out / "city.gpkg"
    except ImportError as exc:
        print(f"    skipped: {exc}")
    return built, store


def run_demo(out_dir: str | os.PathLike[str], *, no_gui: bool = False, progress: bool = True,
             size: int = 513) -> int:
    out = Path(out_dir)
    from citylod.sample.files import make_sample

    t = _step(f"sample city ({size}×{size} m) into {out / 'sample'}")
    info = make_sample(out / "sample", size=size, seed=7)
    files = info.files
    print(f"    {time.perf_counter() - t:.1f} s; its heights are ellipsoidal (UTM 32N names no vertical datum)")
    # Each builder warns when the CRS leaves the height datum unsaid: right for a user's data, noise for the
    # sample's, whose heights are ellipsoidal by construction.
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".*has no vertical datum")
        built, store = _build(out, files, progress)

    if _has_display() and not no_gui:
        try:
            from citylod.app.main import run_app
        except ImportError as exc:
            print(f"    desktop application unavailable: {exc}")
        else:
            _step("desktop application")
            sources = [*built, *([store] if store else [])]
            return run_app(sources, camera=files.get("camera"), highlight_first=True)
    from citylod.bench.report import run_bench
    from citylod.core.camera import load_cameras

    t = _step("no display: off-screen fly-through and speed-against-error report")
    cams = load_cameras(files["path"])[::4]  # a shorter flight than `make bench`: the demo should be quick
    result = run_bench([out / "dsm_tiles"], cams, taus=[0.5, 1, 2, 4, 8], size=(960, 540),
                       out_dir=out / "report", progress=progress, repeats=3)
    best = result.row(1.0)
    full = result.row(None)
    # On a sample this small a frame is mostly the GL's fixed cost per frame: the triangles say what LOD saved.
    print(f"    τ = 1 px: median frame {best.frame_ms_median:.0f} ms, {best.triangles_median:,.0f} triangles, against "
          f"{full.frame_ms_median:.0f} ms, {full.triangles_median:,.0f} triangles at full resolution; measured "
          f"error p99 {best.err_near_p99_px:.2f} px")
    print(f"    report: {out / 'report' / 'report.md'} (figure {out / 'report' / 'report.png'})")
    return 0


if __name__ == "__main__":
    sys.exit(run_demo(sys.argv[1] if len(sys.argv) > 1 else "demo_out"))


def add_parser(sub: argparse._SubParsersAction) -> None:
    dm = sub.add_parser("demo", help="the main job on a built-in sample (what `make demo` runs)")
    dm.add_argument("out_dir", type=Path)
    dm.add_argument("--no-gui", action="store_true", help="render off-screen even when a display exists")
    dm.add_argument("--size", type=int, default=513, help="sample DSM samples per side (default 513)")


def run(args: argparse.Namespace, progress: bool) -> int:
    return run_demo(args.out_dir, no_gui=args.no_gui, progress=progress, size=args.size)
