"""Stored triangle order against vertex-cache order (:mod:`citylod.render.mesh_order`), in one process.

``python -m citylod.bench.order_bench TILESET PATH.json [STEP] [NAME=VALUE]``: two off-screen renderers
(960×540) load the same tileset, one with ``CITYLOD_MESH_ORDER=file`` (the order the tiles store), one in
cache order; with ``NAME=VALUE`` the first loads with that setting instead (for example
``CITYLOD_FACE_COLORS=cells``, the cell-scalar colours of :mod:`citylod.render.flat_colors`), and with
``layer.NAME=VALUE`` its tileset layers get that attribute instead (``layer.skirts_where_needed=0`` draws
every skirt, ``layer.refine_to_cull=0`` refines by error alone; 0/1 are read as booleans). For every
STEP-th camera of the path, camera by camera in turns (the order of the two renderers alternating), each
draws the full-resolution frame and the τ = 1 px frame: median of 3 draws after a warm-up, timed as
``citylod bench`` times them (:meth:`~citylod.render.offscreen.OffscreenRenderer.draw`). Prints per camera,
then the bench's headline per renderer (median full / median τ = 1) and whether the two τ = 1 depth images
differ. Timings are printed, never asserted.
"""

from __future__ import annotations

import os
import sys

import numpy as np

from citylod.core.camera import load_cameras
from citylod.render.mesh_order import ENV
from citylod.render.offscreen import OffscreenRenderer


def _parse(value: str) -> object:
    """A layer attribute's value: 0/1 and true/false as booleans, else a number, else the text."""
    low = value.strip().lower()
    if low in ("0", "false", "1", "true"):
        return low in ("1", "true")
    try:
        return float(value)
    except ValueError:
        return value


def _timed(r: OffscreenRenderer) -> float:
    r.draw()  # warm-up: uploads
    return 1000.0 * float(np.median([r.draw() for _ in range(3)]))


def compare_orders(tileset: str, path: str, step: int = 1, size: tuple[int, int] = (960, 540),
                   setting: tuple[str, str] = (ENV, "file")) -> dict[str, float]:
    """Run the comparison; returns each renderer's median full and τ = 1 frame (ms) and speed-up.

    The renderer called "file" loads with the environment ``setting`` (name, value), the one called
    "cache" without it (the defaults)."""
    cams = load_cameras(path)[::max(1, step)]
    renderers = {}
    name, value = setting
    before = os.environ.get(name)
    attribute = name[len("layer."):] if name.startswith("layer.") else None
    try:
        for mode in ("file", "cache"):
            # Read by the loader threads while the tiles load.
            if attribute is None and mode == "file":
                os.environ[name] = value
            elif attribute is None:
                os.environ.pop(name, None)
            r = OffscreenRenderer([tileset], size=size, tau_px=1.0, cache_bytes=4 << 30)
            if attribute is not None and mode == "file":
                for layer in r.scene.layers:
                    setattr(layer, attribute, _parse(value))
            r.prepare(cams[0], full_resolution=True)
            for c in cams:
                r.prepare(c)
            renderers[mode] = r
    finally:
        if attribute is None and before is None:
            os.environ.pop(name, None)
        elif attribute is None:
            os.environ[name] = before
    times: dict[tuple[str, str], list[float]] = {(m, k): [] for m in renderers for k in ("full", "tau1")}
    differ = 0
    try:
        for ci, cam in enumerate(cams):
            depth = {}
            for kind in ("full", "tau1"):
                for mode in (("file", "cache") if ci % 2 else ("cache", "file")):
                    r = renderers[mode]
                    r.prepare(cam, full_resolution=kind == "full")
                    times[(mode, kind)].append(_timed(r))
                    if kind == "tau1":
                        depth[mode] = r.grab_depth()
            a, b = depth["file"], depth["cache"]
            both = np.isfinite(a) & np.isfinite(b)
            differ += int((np.isfinite(a) != np.isfinite(b)).sum() + (np.abs(a[both] - b[both]) > 0).sum())
            print(ci * max(1, step), {m: (round(times[(m, 'full')][-1], 1), round(times[(m, 'tau1')][-1], 1))
                                      for m in renderers}, flush=True)
    finally:
        for r in renderers.values():
            r.close()
    out: dict[str, float] = {"tau1_pixels_differing": float(differ)}
    for mode in renderers:
        full, tau1 = float(np.median(times[(mode, "full")])), float(np.median(times[(mode, "tau1")]))
        out.update({f"{mode}_full_ms": full, f"{mode}_tau1_ms": tau1, f"{mode}_speedup": full / tau1})
        label = f"{name}={value}" if mode == "file" else "defaults"
        print(f"{mode} ({label}): full median {full:.1f} ms, τ = 1 median {tau1:.1f} ms, speed-up {full / tau1:.2f}×")
    print(f"τ = 1 depth pixels that differ between the two orders, all cameras: {differ}")
    return out


if __name__ == "__main__":
    env = tuple(sys.argv[4].split("=", 1)) if len(sys.argv) > 4 else (ENV, "file")
    compare_orders(sys.argv[1], sys.argv[2], int(sys.argv[3]) if len(sys.argv) > 3 else 1,
                   setting=(env[0], env[1]))
