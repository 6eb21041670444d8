"""Build time of ``build points --complete --refine-roofs`` against the same build without refinement, on Delft.

``python -m citylod.bench.refine_bench OUT --data ../shared/data/delft --repeats 5`` builds Delft AHN3 three
ways in interleaved rounds (so the machine's load hits each alike): plain, completed (walls as quads on the
BGT footprints, ground under canopy), and completed with roof refinement. It reports each variant's median
build time and the median over rounds of the ratio to the completed build of the same round, plus one
out-of-core build of each completed variant (``workers=0``, chunks of 200 000 points).

A second measure of what refinement does: the roughness of the building points the tileset's leaves draw —
the RMS distance of each class-6 input point to the least-squares plane of its 12 nearest neighbours
(``scipy.spatial.cKDTree``), computed here from the leaves, for the completed build with and without
refinement. It is not a distance to a true roof (Delft has none at that precision), only a measure of local
scatter: on a plane it is the range noise, at a ridge it grows with the neighbourhood's bend.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np


def leaf_points(tileset: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions, classes and ``synthetic`` values of every point the leaves of a point tileset draw."""
    from citylod.io.tiles3d import open_tileset

    got, cls, syn = [], [], []
    for t in open_tileset(tileset).walk():
        if t.children or t.content_uri is None or "walls" in t.content_uri:
            continue
        p = t.load_content().points
        if p is None:
            continue
        got.append(p.positions.astype(np.float64) + t.matrix[:3, 3])
        cls.append(p.classification)
        syn.append(p.extra.get("synthetic", np.zeros(len(p.positions), np.uint8)))
    return np.concatenate(got), np.concatenate(cls), np.concatenate(syn)


def roughness(xyz: np.ndarray, k: int = 12) -> float:
    """RMS distance of points to the least-squares plane of their ``k`` nearest neighbours."""
    from scipy.spatial import cKDTree

    p = xyz - xyz.mean(axis=0)
    _, j = cKDTree(p).query(p, k=k)
    nb = p[j]
    c = nb - nb.mean(axis=1, keepdims=True)
    _, vecs = np.linalg.eigh(np.einsum("nki,nkj->nij", c, c))
    n = vecs[:, :, 0]
    d = np.einsum("ni,ni->n", p - nb.mean(axis=1), n)
    return float(np.sqrt(np.mean(d ** 2)))


def run(data_dir: Path, out_dir: Path, repeats: int = 5) -> dict[str, Any]:
    from citylod.lod.build.complete import CompleteOptions
    from citylod.lod.build.points import build_points

    files = [data_dir / "ahn3_cropped_1.laz", data_dir / "ahn3_cropped_2.laz"]
    done = CompleteOptions(walls="quads", footprints=str(data_dir / "bgt_pand.sqlite"))
    variants: dict[str, dict[str, Any]] = {"plain": {}, "complete": {"complete": done},
                                           "complete+refine": {"complete": done, "refine_roofs": True}}
    out_dir.mkdir(parents=True, exist_ok=True)

    def build(name: str, **extra: Any) -> tuple[float, Any]:
        t0 = time.perf_counter()
        rep = build_points(files, out_dir / name, crs="EPSG:28992", progress=False, **variants[name], **extra)
        return time.perf_counter() - t0, rep

    for name in variants:  # warm-up: kernels, file cache
        build(name)
    times: dict[str, list[float]] = {n: [] for n in variants}
    reports: dict[str, Any] = {}
    for _ in range(repeats):
        for name in variants:
            s, reports[name] = build(name)
            times[name].append(s)
    ratio = [r / c for r, c in zip(times["complete+refine"], times["complete"], strict=True)]
    ooc = {}
    for name in ("complete", "complete+refine"):  # out of core: parked segments, several chunks
        t0 = time.perf_counter()
        rep = build_points(files, out_dir / (name + "-ooc"), crs="EPSG:28992", progress=False, workers=0,
                           max_chunk_points=200_000, **variants[name])
        ooc[name] = {"seconds": time.perf_counter() - t0, "chunks": rep.chunks, "refined": rep.refined}
    rough = {}
    for name in ("complete", "complete+refine", "complete+refine-ooc"):
        xyz, cls, syn = leaf_points(out_dir / name)
        rough[name] = roughness(xyz[(cls == 6) & (syn != 1)])
    res = {"points": reports["plain"].points, "refined": reports["complete+refine"].refined,
           "seconds": {n: statistics.median(v) for n, v in times.items()}, "rounds": times,
           "refine_over_complete_median": statistics.median(ratio), "refine_over_complete": ratio,
           "out_of_core": ooc, "roof_roughness_m": rough}
    (out_dir / "refine.json").write_text(json.dumps(res, indent=1))
    return res


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    print(json.dumps(run(args.data, args.out, args.repeats), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
