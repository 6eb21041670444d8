"""Speed of the flood analysis on a large raster: a new level interactively and a full result on disk.

``python -m citylod.bench.flood_bench [SIZE] [REPEATS]`` writes a SIZE² terrain GeoTIFF (rolling hills and a
river valley, 1 m cells) and times, per repeat, in the same process:

- ``read``: reading the whole raster through :class:`~citylod.io.raster.RasterSource` (the baseline);
- ``flood_raster``: the command's work for one level (read in strips, label, merge seams, write the depth
  GeoTIFF, area and volume);
- ``model.coarse`` / ``model.mask``: a new level on heights held in memory (the GUI's slider), the 4×
  decimated preview and the full-resolution extent.

Timings are printed as seconds and as ratios to ``read``; they are not assertions (machine load varies).
``--view [SIZE]`` times a new level from the slider to a drawn frame instead (:func:`view_latency`).
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def make_terrain(path: Path, size: int) -> Path:
    """A SIZE² float32 GeoTIFF in UTM 32N: hills, a valley along x and noise, no-data in one corner."""
    import rasterio
    from affine import Affine

    from citylod.bench.synthetic import rolling_hills

    y, x = np.mgrid[0:size, 0:size].astype(np.float32)
    h = rolling_hills(x, y).astype(np.float32) + 0.02 * np.abs(y - size / 2).astype(np.float32)
    h += np.random.default_rng(1).normal(0, 0.3, h.shape).astype(np.float32)
    h[: size // 16, : size // 16] = -9999.0
    with rasterio.open(path, "w", driver="GTiff", width=size, height=size, count=1, dtype="float32",
                       crs="EPSG:32632", transform=Affine(1.0, 0, 500_000.0, 0, -1.0, 5_400_000.0),
                       nodata=-9999.0, tiled=True, blockxsize=256, blockysize=256) as ds:
        ds.write(h, 1)
    return path


def run(size: int = 4097, repeats: int = 3) -> dict[str, list[float]]:
    from citylod.analysis.flood import FloodModel, FloodSources, flood_raster
    from citylod.io.raster import RasterSource

    times: dict[str, list[float]] = {"read": [], "flood_raster": [], "model.coarse": [], "model.mask": []}
    with tempfile.TemporaryDirectory() as tmp:
        raster = make_terrain(Path(tmp) / "terrain.tif", size)
        sources = FloodSources(edge=True)
        model = FloodModel.from_raster(raster, sources)
        levels = np.linspace(model.min_height + 5, model.min_height + 40, repeats)
        for k, level in enumerate(levels):
            t = time.perf_counter()
            src = RasterSource(raster)
            src.read_window(0, 0, size, size)
            src.close()
            times["read"].append(time.perf_counter() - t)
            t = time.perf_counter()
            flood_raster(raster, [float(level)], Path(tmp) / f"out{k}", sources=sources)
            times["flood_raster"].append(time.perf_counter() - t)
            t = time.perf_counter()
            model.coarse(float(level))
            times["model.coarse"].append(time.perf_counter() - t)
            t = time.perf_counter()
            model.mask(float(level))
            times["model.mask"].append(time.perf_counter() - t)
    return times


def view_latency(size: int = 4097, repeats: int = 5) -> dict[str, list[float]]:
    """Seconds from a new level to a rendered frame with the water (off screen, 1280×720): the coarse
    preview (:meth:`FloodScenario.preview`) and the full-resolution result (:meth:`FloodScenario.compute`),
    each including the water texture's rebuild and the draw."""
    from citylod.analysis.flood import FloodSources
    from citylod.analysis.scenario import FloodScenario
    from citylod.render import _vtk
    from citylod.render.tileset_actor import Scene
    from citylod.render.water import WaterSurface

    out: dict[str, list[float]] = {"coarse shown": [], "full shown": []}
    with tempfile.TemporaryDirectory() as tmp:
        sc = FloodScenario(make_terrain(Path(tmp) / "terrain.tif", size), FloodSources(edge=True))
        win = _vtk.offscreen_window(1280, 720)
        ren = _vtk.vtkOpenGLRenderer()
        win.AddRenderer(ren)
        scene = Scene(ren)
        x0, y0, x1, y1 = sc.bounds
        scene.origin = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
        water = WaterSurface(scene, sc.bounds)
        cam = ren.GetActiveCamera()
        cam.SetPosition(0, -0.7 * size, 0.7 * size)
        cam.SetFocalPoint(0, 0, 0)
        for level in np.linspace(sc.model.min_height + 5, sc.model.min_height + 40, repeats):
            t = time.perf_counter()
            res = sc.preview(float(level))
            water.set_mask(res.mask, None, float(level))
            ren.ResetCameraClippingRange()
            win.Render()
            win.WaitForCompletion()
            out["coarse shown"].append(time.perf_counter() - t)
            t = time.perf_counter()
            res = sc.compute(float(level))
            water.set_mask(res.mask, sc.model.heights, float(level))
            win.Render()
            win.WaitForCompletion()
            out["full shown"].append(time.perf_counter() - t)
        win.Finalize()
    return out


def main(argv: list[str]) -> None:
    if argv and argv[0] == "--view":
        for name, ts in view_latency(int(argv[1]) if len(argv) > 1 else 4097).items():
            print(f"  {name:13s} median {statistics.median(ts):.3f} s  all: {', '.join(f'{v:.3f}' for v in ts)}")
        return
    size = int(argv[0]) if argv else 4097
    repeats = int(argv[1]) if len(argv) > 1 else 3
    times = run(size, repeats)
    base = statistics.median(times["read"])
    print(f"flood on a {size}² raster, {repeats} levels; median seconds (ratio to reading the raster)")
    for name, ts in times.items():
        m = statistics.median(ts)
        print(f"  {name:14s} {m:7.3f} s  ({m / base:5.2f}x)  all: {', '.join(f'{v:.3f}' for v in ts)}")


if __name__ == "__main__":
    main(sys.argv[1:])
