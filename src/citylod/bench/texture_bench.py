"""Textured city flight: Buchholz's multiresolution atlases against the model's original textures.

Both tilesets come from one :func:`~citylod.sample.textured.make_textured_city` model and are flown along the
same :func:`~citylod.bench.flight.default_flight` in one process, camera by camera in turns, so that the
machine's load falls on both alike. The atlas tileset is drawn under a GL texture budget
(:class:`~citylod.render.texture_residency.TextureResidency`), at each τ of ``taus``; the original
textures (one mesh per image, every image as it is) are drawn without a budget and are the full-resolution
reference.

Per frame: median draw time of three draws of the resolved frame; distinct textures bound (textured meshes
drawn); GL texture memory counted from the renderer's texture objects
(:func:`~citylod.render.texture_residency.gl_texture_bytes`); the measured screen error of the atlas frame
against the original frame's depth (:func:`~citylod.render.sse.measure_error`, the same surfaces at full
resolution); and the largest atlas texel on screen: for inner tiles with triangles in view, their certified
texel size projected at their distance (above τ an atlas texel would be magnified); for leaves, the
original images' own texels (magnified by the data, not by the atlas).

Run: ``python -m citylod.bench.texture_bench OUT_DIR [HOUSES] [--blocks] [--taus 1,2,4] [--anisotropy A]
[--smaller-budgets 64,16]``;
writes ``texture_flight.json`` and ``texture_flight.md`` (``_blocks`` with ``--blocks``: far atlas tiles as
coloured blocks) and prints the table. Timings belong in reports, never in tests.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import numpy as np

from citylod.bench.flight import default_flight
from citylod.core.fileio import atomic_write_text
from citylod.io.tiles3d import open_tileset
from citylod.lod.build.city import build_city_tiles
from citylod.render.offscreen import OffscreenRenderer
from citylod.render.sse import measure_error
from citylod.render.texture_residency import gl_texture_bytes
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


def _frame(r: OffscreenRenderer, cam: Any, tau_px: float) -> tuple[dict[str, Any], np.ndarray]:
    r.scene.tau_px = tau_px
    stats = r.prepare(cam)
    r.draw()  # uploads of new tiles are not part of a frame's time
    times = [r.draw() for _ in range(3)]
    depth = r.grab_depth()
    inner_px, leaf_px = _atlas_sse(r, r.scene.view(cam, r.size))
    res = r.scene.textures
    return {"ms": 1000 * statistics.median(times), "textures": _textures_bound(r),
            "texture_mb": gl_texture_bytes(r.scene) / 2**20, "tiles": stats.tiles, "triangles": stats.triangles,
            "cache_mb": stats.bytes_resident / 2**20, "sse_px": stats.max_sse_px, "inner_texel_px": inner_px,
            "leaf_texel_px": leaf_px, "refused": 0 if res is None else len(res.refused),
            "levels": {str(k): v for k, v in stats.levels.items()}}, depth


def _summary(frames: list[dict[str, Any]], tau_px: float) -> dict[str, Any]:
    ms = np.array([f["ms"] for f in frames])
    out = {"tau_px": tau_px, "frames": frames, "median_ms": float(np.median(ms)),
           "max_textures": int(max(f["textures"] for f in frames)),
           "max_texture_mb": float(max(f["texture_mb"] for f in frames)),
           "max_cache_mb": float(max(f["cache_mb"] for f in frames)),
           "max_inner_texel_px": float(max(f["inner_texel_px"] for f in frames)),
           # Where the budget refused loads the view shows coarser atlases on purpose (Buchholz §4.6): the
           # texel promise holds for the frames the budget did not limit.
           "max_inner_texel_px_within_budget": float(max([f["inner_texel_px"] for f in frames if not f["refused"]],
                                                         default=0.0)),
           "frames_with_leaf_magnified": int(sum(f["leaf_texel_px"] > tau_px for f in frames)),
           "frames_refused": int(sum(f["refused"] > 0 for f in frames))}
    if "err_p99_px" in frames[0]:
        out["p99_err_px"] = float(np.percentile([f["err_p99_px"] for f in frames], 99))
        out["max_err_p99_px"] = float(max(f["err_p99_px"] for f in frames))
        out["p99_near_err_px"] = float(np.percentile([f["err_near_p99_px"] for f in frames], 99))
    return out


def texture_flight(out_dir: str | Path, houses: int = 1000, *, image_px: int = 256, atlas_px: int = 1024,
                   budget_mb: float = 256.0, frames: int = 24, size: tuple[int, int] = (960, 540),
                   taus: tuple[float, ...] = (1.0, 2.0, 4.0), texture_blocks: bool = False,
                   anisotropy: float = 1.0, smaller_budgets_mb: tuple[float, ...] = ()) -> dict[str, Any]:
    """Build both tilesets of a textured sample (reused when present) and fly them; the report dict.

    ``budget_mb``: the atlas renderer's GL texture budget (its tile cache holds twice that, geometry and
    decoded images). ``texture_blocks``: the atlas tileset's far tiles are coloured blocks (folder
    ``atlas_blocks``). ``anisotropy``: the renderers' texture filtering (1 is isotropic).
    ``smaller_budgets_mb``: further atlas renderers under these budgets, flown at the first τ (what a
    smaller texture memory costs in texel size)."""
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
    budget = int(budget_mb * 2**20)
    orig_frames: list[dict[str, Any]] = []
    atlas_frames: dict[float, list[dict[str, Any]]] = {tau: [] for tau in taus}
    small_frames: dict[float, list[dict[str, Any]]] = {mb: [] for mb in smaller_budgets_mb}

    def measured(r: OffscreenRenderer, cam: Any, tau: float, depth_full: np.ndarray) -> dict[str, Any]:
        f, depth = _frame(r, cam, tau)
        err = measure_error(depth, depth_full, cam)
        assert not isinstance(err, tuple)
        f.update(err_p99_px=err.p99_px, err_max_px=err.max_px, err_near_p99_px=err.near_p99_px)
        return f

    with ExitStack() as stack:
        ro = stack.enter_context(OffscreenRenderer([out / "original"], size=size, cache_bytes=64 << 30))
        ra = stack.enter_context(OffscreenRenderer([out / name], size=size, cache_bytes=2 * budget,
                                                   texture_budget_bytes=budget))
        small = {mb: stack.enter_context(OffscreenRenderer(
            [out / name], size=size, cache_bytes=2 * budget, texture_budget_bytes=int(mb * 2**20)))
            for mb in smaller_budgets_mb}
        for r in (ro, ra, *small.values()):
            r.scene.texture_anisotropy = anisotropy
        for cam in cams:
            f, depth_full = _frame(ro, cam, 1.0)
            orig_frames.append(f)
            for tau in taus:
                atlas_frames[tau].append(measured(ra, cam, tau, depth_full))
            for mb, r in small.items():
                small_frames[mb].append(measured(r, cam, taus[0], depth_full))
    raw_mb = 2 * houses * image_px * image_px * 3 / 2**20
    orig = _summary(orig_frames, 1.0)
    atlas = {str(tau): _summary(fr, tau) for tau, fr in atlas_frames.items()}
    smaller = {str(mb): {**_summary(fr, taus[0]), "budget_mb": mb} for mb, fr in small_frames.items()}
    report = {"houses": houses, "image_px": image_px, "atlas_px": atlas_px, "budget_mb": budget_mb,
              "texture_blocks": texture_blocks, "anisotropy": anisotropy, "raw_texture_mb": raw_mb,
              "size": list(size), "build_s": {"atlas": t_atlas, "original": t_orig}, "original": orig,
              "atlas": atlas, "speedup_median": {k: orig["median_ms"] / a["median_ms"] for k, a in atlas.items()},
              "smaller_budgets": smaller}
    stem = f"texture_flight{'_blocks' if texture_blocks else ''}"
    atomic_write_text(out / f"{stem}.json", json.dumps(report, indent=1))
    atomic_write_text(out / f"{stem}.md", table(report) + "\n")
    return report


def table(rep: dict[str, Any]) -> str:
    """The report as a markdown table: speed against error, texture memory as a column."""
    lines = [f"{rep['houses']} houses, {2 * rep['houses']} images of {rep['image_px']} px "
             f"({rep['raw_texture_mb']:.0f} MB raw), {rep['size'][0]}×{rep['size'][1]}, atlas budget "
             f"{rep['budget_mb']:.0f} MB, anisotropy {rep['anisotropy']:g}", "",
             "| variant | τ px | median frame ms | speed-up | measured error p99 px (ray / near) | largest atlas texel px "
             "| frames leaf > τ | textures bound (max) | texture memory MB (max) | frames budget-limited"
             " (their largest texel px) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    o = rep["original"]
    # The original images are the leaves' images at their own resolution: where a leaf magnifies, they do.
    lines.append(f"| original | – | {o['median_ms']:.1f} | 1.00× | 0 (reference) | – | as the leaves | "
                 f"{o['max_textures']} | {o['max_texture_mb']:.2f} | – |")
    for k, a in rep["atlas"].items():
        lines.append(f"| atlas | {float(k):g} | {a['median_ms']:.1f} | {rep['speedup_median'][k]:.2f}× | "
                     f"{a['p99_err_px']:.2f} / {a['p99_near_err_px']:.2f} | {a['max_inner_texel_px_within_budget']:.3f} | "
                     f"{a['frames_with_leaf_magnified']} | {a['max_textures']} | {a['max_texture_mb']:.2f} | "
                     f"{a['frames_refused']} ({a['max_inner_texel_px']:.2f}) |")
    for mb, a in rep.get("smaller_budgets", {}).items():
        lines.append(f"| atlas, {float(mb):g} MB budget | {a['tau_px']:g} | {a['median_ms']:.1f} | "
                     f"{o['median_ms'] / a['median_ms']:.2f}× | "
                     f"{a['p99_err_px']:.2f} / {a['p99_near_err_px']:.2f} | {a['max_inner_texel_px_within_budget']:.3f} | "
                     f"{a['frames_with_leaf_magnified']} | {a['max_textures']} | {a['max_texture_mb']:.2f} | "
                     f"{a['frames_refused']} ({a['max_inner_texel_px']:.2f}) |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    blocks = "--blocks" in args
    args = [a for a in args if a != "--blocks"]
    kw: dict[str, Any] = {}
    for opt, kwarg in (("--taus", "taus"), ("--anisotropy", "anisotropy"), ("--smaller-budgets", "smaller_budgets_mb")):
        if opt in args:
            i = args.index(opt)
            value = args[i + 1]
            del args[i:i + 2]
            kw[kwarg] = float(value) if opt == "--anisotropy" else tuple(float(x) for x in value.split(","))
    rep = texture_flight(args[0], int(args[1]) if len(args) > 1 else 1000, texture_blocks=blocks, **kw)
    print(table(rep))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
