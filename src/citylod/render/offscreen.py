"""Off-screen rendering of tilesets: images and eye-distance depth, and the ``citylod render`` command.

:class:`OffscreenRenderer` owns an off-screen window (EGL, see :mod:`citylod.render._vtk`) and a
:class:`~citylod.render.tileset_actor.Scene`. For each camera it resolves the selection (waits until
every selected tile is loaded), renders and reads back the colour and, on request, the depth converted
to the distance from the eye along each pixel ray (``inf`` where nothing was drawn).

Semantic styling (``--city``, ``--highlight``, ``--hide``) is applied through a hook: a callable
``hook(scene, city=..., highlight=..., hide=...)``; the command finds it as ``semantic_hook`` in
``citylod.render.semantic`` when that module exists.
"""

from __future__ import annotations

import argparse
import importlib
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from citylod.core.camera import Camera, built_in_camera, cameras_for, load_cameras, local_up
from citylod.core.errors import CitylodError, InputError
from citylod.core.fileio import atomic_write, atomic_write_bytes
from citylod.io.tiles3d.package import is_tileset_path
from citylod.io.tiles3d.remote import is_url
from citylod.render import _vtk
from citylod.render.depth import zbuffer_to_distance
from citylod.render.gl_context import guard
from citylod.render.hud import Hud, set_edl
from citylod.render.tileset_actor import FrameStats, Scene

__all__ = ["OffscreenRenderer", "RenderedFrame", "render_command", "render_images", "save_png"]

SemanticHook = Callable[..., None]


@dataclass
class RenderedFrame:
    """One off-screen frame: ``rgb`` (H, W, 3) uint8 (row 0 = top), ``depth`` (H, W) float32 distance
    from the eye or None, ``stats`` what was drawn."""

    rgb: npt.NDArray[np.uint8]
    depth: npt.NDArray[np.float32] | None
    stats: FrameStats


def _tileset_sources(sources: Sequence[str | os.PathLike[str]]) -> tuple[list[Path], list[Path]]:
    tilesets, cities = [], []
    for s in sources:
        p = Path(s)
        if p.suffix.lower() == ".gpkg":
            cities.append(p)
        elif is_tileset_path(p):
            if not p.exists() and not is_url(s):
                raise InputError("no such tileset", p)
            tilesets.append(p)
        elif not p.exists():
            raise InputError("no such file or folder", p)
        else:
            raise InputError("not a tileset folder, tileset.json, .3tz / .3dtiles package or .gpkg city store", p)
    return tilesets, cities


class OffscreenRenderer:
    """A scene drawn into an off-screen window.

    Parameters
    ----------
    sources
        Tileset folders or ``tileset.json`` files.
    size
        (width, height) in pixels.
    tau_px
        Screen-space error threshold.
    color_by
        See :data:`citylod.render.colors.COLOR_MODES`.
    cache_bytes
        Tile cache budget (hard cap).
    edl
        Eye-Dome Lighting (``vtkEDLShading``) for point clouds.
    point_size_px
        Size of drawn points.
    point_shape
        "points" or "splat" (oriented disks sized by the local spacing: :mod:`citylod.render.splats`).
    workers
        Loader threads.
    texture_budget_bytes
        Cap on the tiles' GL texture memory (Buchholz's priority); None: only ``cache_bytes`` limits it.

    The methods below make the window's context current and give the thread's previous one back (a
    PyVista window's, say); wrap direct VTK calls on ``window`` or ``renderer`` in ``with r.gl:`` too
    (:mod:`citylod.render.gl_context`).
    """

    def __init__(self, sources: Sequence[str | os.PathLike[str]], *, size: tuple[int, int] = (1280, 720),
                 tau_px: float = 1.0, color_by: str = "auto", cache_bytes: int = 2 << 30, edl: bool = False,
                 point_size_px: float = 2.0, workers: int = 2, origin: npt.ArrayLike | None = None,
                 point_shape: str = "points", texture_budget_bytes: int | None = None) -> None:
        tilesets, cities = _tileset_sources(sources)
        if cities:
            raise CitylodError(f"{cities[0]}: city stores are drawn through the semantic hook; pass them "
                               "with --city")
        if not tilesets:
            raise CitylodError("nothing to render: give at least one tileset")
        self.size = (int(size[0]), int(size[1]))
        self.window = _vtk.offscreen_window(*self.size)
        # Every GL use below goes through this guard, so a PyVista window's GLX context current in the same
        # thread neither receives our drawing nor is left displaced (citylod.render.gl_context).
        self.gl = guard(self.window)
        self.renderer = _vtk.vtkOpenGLRenderer()
        self.window.AddRenderer(self.renderer)
        self.scene = Scene(self.renderer, cache_bytes=cache_bytes, tau_px=tau_px, color_by=color_by,
                           workers=workers, origin=origin, texture_budget_bytes=texture_budget_bytes)
        for t in tilesets:
            layer = self.scene.add(t)
            layer.point_size_px = point_size_px
            layer.point_shape = point_shape
        if edl:
            set_edl(self.renderer, True)
        # Credits the data's servers ask for (a Cesium ion asset's attributions) go into every image, bottom left.
        credits = [c for layer in self.scene.layers for c in layer.tileset.attributions]
        if credits:
            Hud(self.renderer).set_credits(credits)

    # -- frames -----------------------------------------------------------------------------------
    def prepare(self, camera: Camera, *, full_resolution: bool = False) -> FrameStats:
        """Place the camera and make the frame's tiles resident and shown (no drawing)."""
        with self.gl:  # evicted tiles free their GL textures here
            self.scene.set_camera(camera)
            view = self.scene.view(camera, self.size)
            stats = self.scene.show_full_resolution(view) if full_resolution else self.scene.resolve(view)
            self.renderer.ResetCameraClippingRange()
        return stats

    def draw(self) -> float:
        """Render the prepared frame and wait for the GL to finish; returns the seconds it took."""
        t0 = time.perf_counter()
        with self.gl:
            self.window.Render()
            self.window.WaitForCompletion()
        return time.perf_counter() - t0

    def grab_rgb(self) -> npt.NDArray[np.uint8]:
        """Colour of the last frame, (H, W, 3) uint8, row 0 at the top."""
        w, h = self.size
        arr = _vtk.vtkUnsignedCharArray()
        with self.gl:
            self.window.GetPixelData(0, 0, w - 1, h - 1, 0, arr, 0)
        rgb = _vtk.vtk_to_numpy(arr).reshape(h, w, 3)
        return np.ascontiguousarray(rgb[::-1])

    def grab_depth(self) -> npt.NDArray[np.float32]:
        """Distance from the eye per pixel of the last frame, (H, W) float32, ``inf`` for background."""
        w, h = self.size
        arr = _vtk.vtkFloatArray()
        with self.gl:
            self.window.GetZbufferData(0, 0, w - 1, h - 1, arr)
        zb = _vtk.vtk_to_numpy(arr).reshape(h, w)[::-1]
        cam = self.renderer.GetActiveCamera()
        near, far = cam.GetClippingRange()
        return zbuffer_to_distance(zb, near, far, cam.GetViewAngle())

    def render(self, camera: Camera, *, depth: bool = False, full_resolution: bool = False) -> RenderedFrame:
        """Resolve, draw and read back one frame."""
        with self.gl:  # one context switch for the frame: the guards inside nest
            stats = self.prepare(camera, full_resolution=full_resolution)
            self.draw()
            return RenderedFrame(self.grab_rgb(), self.grab_depth() if depth else None, stats)

    def close(self) -> None:
        with self.gl:
            self.scene.close()
            self.window.Finalize()

    def __enter__(self) -> OffscreenRenderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def render_images(sources: Sequence[str | os.PathLike[str]], cameras: Sequence[Camera], *,
                  size: tuple[int, int] = (1280, 720), tau_px: float = 1.0, depth: bool = False,
                  color_by: str = "auto", cache_bytes: int = 2 << 30, edl: bool = False,
                  point_size_px: float = 2.0, semantic_hook: SemanticHook | None = None,
                  semantic_args: dict[str, Any] | None = None,
                  progress: bool = False, point_shape: str = "points") -> list[tuple[npt.NDArray[np.uint8], npt.NDArray[np.float32] | None]]:
    """Render ``sources`` from each camera off screen.

    Parameters
    ----------
    sources
        Tileset folders or ``tileset.json`` files (one scene, in the first one's CRS; the others are
        reprojected on the fly).
    cameras
        Cameras in the data's CRS.
    size
        (width, height) pixels.
    tau_px
        Screen-space error threshold; every selected tile is loaded before the frame is grabbed.
    depth
        Also return the distance from the eye per pixel.
    semantic_hook, semantic_args
        ``semantic_hook(scene, **semantic_args)`` is called once before the first frame.
    point_shape
        "points" or "splat" (see :class:`OffscreenRenderer`).

    Returns
    -------
    list of (rgb, depth)
        ``rgb`` (H, W, 3) uint8 with row 0 at the top; ``depth`` (H, W) float32 (``inf`` = background) or
        None.

    Examples
    --------
    >>> import citylod
    >>> cams = citylod.load_cameras("path.json")                              # doctest: +SKIP
    >>> frames = render_images(["TILES"], cams, size=(960, 540), tau_px=1.0)  # doctest: +SKIP
    >>> frames[0][0].shape                                                    # doctest: +SKIP
    (540, 960, 3)
    """
    from tqdm import tqdm

    out = []
    with OffscreenRenderer(sources, size=size, tau_px=tau_px, color_by=color_by, cache_bytes=cache_bytes,
                           edl=edl, point_size_px=point_size_px, point_shape=point_shape) as r:
        if semantic_hook is not None:
            semantic_hook(r.scene, **(semantic_args or {}))
        for cam in tqdm(cameras, desc="render", unit="frame", disable=not progress or len(cameras) < 2):
            f = r.render(cam, depth=depth)
            out.append((f.rgb, f.depth))
    return out


# ------------------------------------------------------------------------------------------ writing
def save_png(path: str | os.PathLike[str], rgb: npt.NDArray[np.uint8]) -> Path:
    """Write (H, W, 3|4) uint8 as PNG atomically (temporary name, then rename)."""
    from citylod.io.image import encode_png

    p = Path(path)
    data = encode_png(np.asarray(rgb, np.uint8))
    if not data:
        raise CitylodError("cannot encode PNG", p)
    try:
        return atomic_write_bytes(p, data)
    except OSError as exc:
        raise CitylodError(f"cannot write PNG ({exc.strerror})", p) from exc


def _save_npy(path: Path, arr: np.ndarray) -> None:
    atomic_write(path, lambda t: np.save(t, arr), suffix=".npy")


def frame_path(pattern: Path, index: int, count: int) -> Path:
    """The file of frame ``index``: ``pattern`` itself for one frame, else ``stem_0007.suffix`` (or the
    pattern formatted, when it holds ``{}``/``{:04d}``)."""
    if count == 1:
        return pattern
    if "{" in pattern.name:
        return pattern.with_name(pattern.name.format(index))
    return pattern.with_name(f"{pattern.stem}_{index:04d}{pattern.suffix}")


def _find_semantic_hook() -> SemanticHook | None:
    try:
        mod = importlib.import_module("citylod.render.semantic")
    except ImportError:
        return None
    hook = getattr(mod, "semantic_hook", None)
    return hook if callable(hook) else None


def render_command(args: argparse.Namespace, progress: bool = True) -> int:
    """``citylod render SOURCES... -o IMAGE.png [--camera CAMERA.json | overview | orbit:N] [--tau PX]
    [--size WxH] [--depth D.npy] [--color-by MODE] [--city STORE.gpkg --highlight SQL --hide SQL]``."""
    from tqdm import tqdm

    spec = getattr(args, "camera", None)
    built_in = built_in_camera(spec)  # the overview or an orbit, made once the data's bounds are known
    cameras = load_cameras(spec) if built_in is None else []
    tilesets, cities = _tileset_sources(args.sources)
    city = getattr(args, "city", None) or (cities[0] if cities else None)
    highlight, hide = getattr(args, "highlight", None), getattr(args, "hide", None)
    hook = None
    if city is not None or highlight or hide:
        hook = _find_semantic_hook()
        if hook is None:
            raise CitylodError("--city/--highlight/--hide and .gpkg sources are not available yet "
                               "(the semantic renderer is not installed)")
    out = Path(args.output)
    if out.suffix.lower() != ".png":
        raise CitylodError(f"output must be a .png file, got {out.name!r}")
    budget_mb = getattr(args, "texture_budget", None)
    with OffscreenRenderer(tilesets, size=tuple(args.size), tau_px=args.tau,
                           color_by=getattr(args, "color_by", "auto") or "auto",
                           point_shape="splat" if getattr(args, "splats", False) else "points",
                           texture_budget_bytes=None if budget_mb is None else int(budget_mb * 2**20)) as r:
        if built_in is not None:
            lo, hi = r.scene.bounds
            cameras = cameras_for(spec, lo, hi, aspect=r.size[0] / r.size[1], up=local_up(r.scene.crs, lo, hi))
        n = len(cameras)
        if hook is not None:
            hook(r.scene, city=city, highlight=highlight, hide=hide)
        water = None
        if getattr(args, "flood", None) is not None:
            from citylod.render.water import WaterSurface

            series = bool(getattr(args, "flood_series", False))
            water = WaterSurface.from_flood(r.scene, args.flood, 0 if series else getattr(args, "flood_index", -1))
        if getattr(args, "edits", None) is not None:
            from citylod.analysis.polygons import load_polygons
            from citylod.render.edits import PolygonEdits

            PolygonEdits(r.scene, load_polygons(args.edits))
        from citylod.render.budget_log import BudgetRun

        budget = BudgetRun.from_args(r.scene, args)  # --point-budget, --target-ms
        last = None
        for i, cam in enumerate(tqdm(cameras, desc="render", unit="frame", disable=not progress or n < 2)):
            if water is not None and series and i > 0:
                water.load_level(args.flood, i)
            frame = r.render(cam, depth=args.depth is not None)
            if r.scene.loader.failed:
                # A picture with tiles missing looks plausible and is wrong: refuse it rather than warn.
                key, msg = next(iter(r.scene.loader.failed.items()))
                raise InputError(f"tile {key} could not be drawn: {msg}")
            budget.frame(i, frame.stats)
            save_png(frame_path(out, i, n), frame.rgb)
            if args.depth is not None and frame.depth is not None:
                _save_npy(frame_path(Path(args.depth), i, n), frame.depth)
            last = frame.stats
        summary = budget.finish(out)
    if summary is not None:
        print(summary)
    if last is not None:
        where = out if n == 1 else out.with_name(f"{out.stem}_NNNN{out.suffix}")
        print(f"{where}: {n} frame(s), last: {last.tiles} tiles, {last.triangles} triangles, "
              f"{last.points} points, max error {last.max_sse_px:.2f} px")
    return 0
