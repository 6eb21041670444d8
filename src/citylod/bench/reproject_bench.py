"""Cost of on-the-fly reprojection per tile (:mod:`citylod.render.reproject`) against the untransformed path.

``python -m citylod.bench.reproject_bench OUT_DIR [SIZE]`` makes the sample DSM (UTM 32N), warps a copy into
EPSG:3035 with rasterio (0.5 m, nearest), builds both, adds the 3035 one to a UTM scene and times, per round
over all its tiles, reading+decoding+preparing each tile and then reprojecting it. Prints medians in ms per
million vertices (alternated per tile, so machine load affects both alike) and the time to transform the
layer's boxes. The numbers go in docs/PERFORMANCE_LOG.md.
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path


def run(out: Path, size: int = 513, rounds: int = 7) -> dict[str, float]:
    import rasterio
    from rasterio.warp import Resampling, calculate_default_transform, reproject

    from citylod.lod.build.dsm import build_dsm
    from citylod.render.tile_data import prepare_tile
    from citylod.render.tileset_actor import Scene
    from citylod.sample.files import make_sample

    out.mkdir(parents=True, exist_ok=True)
    dsm = make_sample(out / "sample", size=size).files["dsm"]
    warped = out / "dsm3035.tif"
    with rasterio.open(dsm) as ds:
        tr, w, h = calculate_default_transform(ds.crs, "EPSG:3035", ds.width, ds.height, *ds.bounds, resolution=0.5)
        with rasterio.open(warped, "w", **(ds.profile | {"crs": "EPSG:3035", "transform": tr, "width": w,
                                                         "height": h})) as dst:
            reproject(rasterio.band(ds, 1), rasterio.band(dst, 1), resampling=Resampling.nearest)
    build_dsm(dsm, out / "utm", tile_size=129, workers=0, progress=False)
    build_dsm(warped, out / "laea", tile_size=129, workers=0, progress=False)
    with Scene() as scene:
        scene.add(out / "utm")
        t0 = time.perf_counter()
        layer = scene.add(out / "laea")
        add_ms = (time.perf_counter() - t0) * 1e3
        rep = layer.reprojection
        assert rep is not None
        nodes = [n for n in layer._nodes.values() if n.content_uri is not None]
        plain, extra = [], []
        vertices = 0
        for _ in range(rounds):
            tp = tr_ = 0.0
            vertices = 0
            for n in nodes:
                a = time.perf_counter()
                prepared, _ = prepare_tile(n)
                b = time.perf_counter()
                rep.prepared(prepared, n.tile.matrix, n.matrix[:3, 3])
                c = time.perf_counter()
                tp += b - a
                tr_ += c - b
                vertices += sum(len(m.positions) for m in prepared.meshes)
            plain.append(tp / vertices * 1e9)
            extra.append(tr_ / vertices * 1e9)
    return {"tiles": len(nodes), "vertices": vertices, "prepare_ms_per_mvert": statistics.median(plain),
            "reproject_ms_per_mvert": statistics.median(extra), "add_layer_ms": add_ms}


if __name__ == "__main__":  # pragma: no cover - a manual benchmark
    res = run(Path(sys.argv[1]), int(sys.argv[2]) if len(sys.argv) > 2 else 513)
    print(", ".join(f"{k} {v:.1f}" if isinstance(v, float) else f"{k} {v}" for k, v in res.items()))
