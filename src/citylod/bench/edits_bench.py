"""Frame time with polygon edits against the same frames without, in one run.

``python -m citylod.bench.edits_bench [REPEATS]`` writes a synthetic point tileset (4 levels, 20 000 points
a tile), and renders the default flight over it off screen, alternating per repeat a scene without edits
and a scene with 10 polygons (8 recolour, 1 discard, 1 displace; :mod:`citylod.render.edits`). A frame's
time is the draw (``Render`` + GL finish, which includes the edits' work before the render), after its
tiles are resident. Prints per-mode medians and the ratio; not an assertion (machine load varies).
"""

from __future__ import annotations

import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np


def run(repeats: int = 2, frames: int = 30) -> dict[str, list[float]]:
    import pyproj
    import shapely

    from citylod.analysis.polygons import EditPolygon, PolygonLayer
    from citylod.bench.flight import default_flight
    from citylod.bench.synthetic import make_point_tileset
    from citylod.render.edits import PolygonEdits
    from citylod.render.offscreen import OffscreenRenderer

    corner = np.array([500000.0, 5400000.0, 0.0])
    ext = 512.0
    polys = []
    for i in range(8):
        cx, cy = corner[0] + 60 + (i % 4) * 110, corner[1] + 80 + (i // 4) * 120
        polys.append(EditPolygon(shapely.Point(cx, cy).buffer(35.0, 8), "recolor", (255, 0, 255)))
    polys.append(EditPolygon(shapely.box(corner[0] + 40, corner[1] + 340, corner[0] + 180, corner[1] + 460),
                             "discard"))
    polys.append(EditPolygon(shapely.box(corner[0] + 300, corner[1] + 340, corner[0] + 460, corner[1] + 470),
                             "displace", height_m=30.0))
    layer = PolygonLayer(tuple(polys), pyproj.CRS("EPSG:25832"))
    times: dict[str, list[float]] = {"plain": [], "edits": []}
    with tempfile.TemporaryDirectory() as tmp:
        tiles = make_point_tileset(Path(tmp) / "pts", levels=4, points_per_tile=20000, extent=ext, corner=corner)
        cams = default_flight(corner, corner + np.array([ext, ext, 30.0]), n=frames)
        for _ in range(repeats):
            for mode in ("plain", "edits"):
                with OffscreenRenderer([tiles], size=(1280, 720), tau_px=0.5) as r:
                    if mode == "edits":
                        PolygonEdits(r.scene, layer)
                    for cam in cams:
                        r.prepare(cam)
                        times[mode].append(r.draw() * 1000.0)
    return times


def main(argv: list[str]) -> None:
    times = run(int(argv[0]) if argv else 2)
    med = {k: statistics.median(v) for k, v in times.items()}
    mean = {k: statistics.fmean(v) for k, v in times.items()}
    print(f"frames per mode: {len(times['plain'])}")
    for k in times:
        print(f"  {k:6s} median {med[k]:7.2f} ms  mean {mean[k]:7.2f} ms")
    print(f"  ratio edits/plain: median {med['edits'] / med['plain']:.3f}, mean {mean['edits'] / mean['plain']:.3f}")


if __name__ == "__main__":
    main(sys.argv[1:])
