"""Textured city flight: Buchholz's multiresolution atlases against the model's original textures.

Both tilesets come from one :func:`~citylod.sample.textured.make_textured_city` model and are flown along the
same :func:`~citylod.bench.flight.default_flight` in the same process. Per frame: median draw time of three
draws of the resolved frame, distinct textures bound (textured meshes drawn), resident bytes of the tile
cache (geometry and decoded textures: an upper bound of texture memory), and the largest screen-space error
of the drawn tiles (for atlas tiles their certified texel size projected at their distance: above 1 px an
atlas texel would be magnified).

Run: ``python -m citylod.bench.texture_bench OUT_DIR [HOUSES] [--blocks]``; writes ``texture_flight.json``
(``texture_flight_blocks.json`` with ``--blocks``: far atlas tiles as coloured blocks) and prints a table. Timings belong in reports, never in tests.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from citylod.bench.flight import default_flight
from citylod.io.tiles3d import open_tileset
from citylod.lod.build.city import build_city_tiles
from citylod.render.offscreen import OffscreenRenderer
from citylod.sample.textured import make_textured_city

__all__ = ["texture_flight"]


def _textures_bound(renderer: OffscreenRenderer) -> int:
    n = 0
    for layer in renderer.scene.layers:
        for key in layer.shown_keys:
            slot = layer._slots.get(key)
            if slot is not None and slot.prepared is not None:
                n += sum(m.texture is not None for m in slot.prepared.meshes)
    return n


def _atlas_sse(renderer: OffscreenRenderer, view: Any) -> tuple[float, float]:
    """Largest projected texel (px) of the drawn inner tiles with triangles in view (an atlas texel; above τ
    it is magnified) and of the drawn leaves (the original images' own texels: magnified by the data, not by
    the atlas)."""
    inner = leaf = 0.0
    for layer in renderer.scene.layers:
        for key in layer.shown_keys:
            tile = layer.node(key).tile
            px = view.sse(tile.geometric_error, max(tile.box.distance(view.eye), 1e-9))
            if tile.children:
                # Selection keeps a tile whose children are all outside the view (CesiumJS does too); its
                # triangles all lie in those children, so none of them is on screen.
                if all(view.cull_box(c.box) for c in tile.children):
                    continue
                inner = max(inner, px)
            else:
                leaf = max(leaf, px)
    return inner, leaf


def _fly(tiles: Path, cameras: list[Any], *, size: tuple[int, int], tau_px: float,
         cache_bytes: int) -> dict[str, Any]:
    frames = []
    with OffscreenRenderer([tiles], size=size, tau_px=tau_px, cache_bytes=cache_bytes) as r:
        r.prepare(cameras[0])
        r.draw()  # warm-up: shader compilation and first uploads are not part of a frame
        for cam in cameras:
            stats = r.prepare(cam)
            inner_px, leaf_px = _atlas_sse(r, r.scene.view(cam, r.size))
            times = [r.draw() for _ in range(3)]
            frames.append({"ms": 1000 * statistics.median(times), "textures": _textures_bound(r),
                           "tiles": stats.tiles, "triangles": stats.triangles,
                           "resident_mb": stats.bytes_resident / 2**20, "sse_px": stats.max_sse_px,
                           "inner_texel_px": inner_px, "leaf_texel_px": leaf_px,
                           "levels": {str(k): v for k, v in stats.levels.items()}})
    ms = np.array([f["ms"] for f in frames])
    sse = np.array([f["sse_px"] for f in frames])
    inner = np.array([f["inner_texel_px"] for f in frames])
    return {"frames": frames, "median_ms": float(np.median(ms)), "p99_sse_px": float(np.percentile(sse, 99)),
            "p99_inner_texel_px": float(np.percentile(inner, 99)),
            "max_inner_texel_px": float(inner.max()),
            "frames_with_leaf_magnified": int(sum(f["leaf_texel_px"] > tau_px for f in frames)),
            "max_textures": int(max(f["textures"] for f in frames)),
            "max_resident_mb": float(max(f["resident_mb"] for f in frames))}


def texture_flight(out_dir: str | Path, houses: int = 1000, *, image_px: int = 256, atlas_px: int = 1024,
                   budget_mb: float = 256.0, frames: int = 24, size: tuple[int, int] = (960, 540),
                   tau_px: float = 1.0, texture_blocks: bool = False) -> dict[str, Any]:
    """Build both tilesets of a textured sample (reused when present) and fly them; the report dict.
    ``texture_blocks``: the atlas tileset's far tiles are coloured blocks (folder ``atlas_blocks``)."""
    out = Path(out_dir)
    name = "atlas_blocks" if texture_blocks else "atlas"
    model = out / "textured.gml"
    if not model.exists():
        make_textured_city(out, buildings=houses, image_px=image_px)
    t = time.perf_counter()
    if not (out / name / "tileset.json").exists():
        build_city_tiles(model, out / name, atlas_px=atlas_px, texture_blocks=texture_blocks, progress=False)
    t_atlas = time.perf_counter() - t
    t = time.perf_counter()
    if not (out / "original" / "tileset.json").exists():
        build_city_tiles(model, out / "original", textures="original", progress=False)
    t_orig = time.perf_counter() - t
    lo, hi = open_tileset(out / name).bounds
    cams = default_flight(lo, hi, n=frames)
    raw_mb = 2 * houses * image_px * image_px * 3 / 2**20
    atlas = _fly(out / name, cams, size=size, tau_px=tau_px, cache_bytes=int(budget_mb * 2**20))
    orig = _fly(out / "original", cams, size=size, tau_px=tau_px, cache_bytes=64 << 30)
    report = {"houses": houses, "image_px": image_px, "atlas_px": atlas_px, "budget_mb": budget_mb,
              "texture_blocks": texture_blocks, "raw_texture_mb": raw_mb, "tau_px": tau_px, "size": list(size), "build_s": {"atlas": t_atlas,
                                                                                        "original": t_orig},
              "atlas": atlas, "original": orig, "speedup_median": orig["median_ms"] / atlas["median_ms"]}
    (out / f"texture_flight{'_blocks' if texture_blocks else ''}.json").write_text(json.dumps(report, indent=1))
    return report


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    blocks = "--blocks" in args
    args = [a for a in args if a != "--blocks"]
    rep = texture_flight(args[0], int(args[1]) if len(args) > 1 else 1000, texture_blocks=blocks)
    print(f"{rep['houses']} houses, {2 * rep['houses']} images of {rep['image_px']} px "
          f"({rep['raw_texture_mb']:.0f} MB raw), tau {rep['tau_px']} px, budget {rep['budget_mb']:.0f} MB")
    print("variant   median ms  max textures/frame  max resident MB  max atlas texel px  frames leaf>tau")
    for name in ("original", "atlas"):
        r = rep[name]
        print(f"{name:9s} {r['median_ms']:9.1f}  {r['max_textures']:18d}  {r['max_resident_mb']:15.1f}  "
              f"{r['max_inner_texel_px']:18.2f}  {r['frames_with_leaf_magnified']:15d}")
    print(f"speed-up of the median frame: {rep['speedup_median']:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
