"""citylod's LOD layers in a ``pyvista.Plotter``: the scripting path for PyVista users.

:func:`add_lod_layer` puts one or more tilesets into a plotter's renderer as a :class:`LodLayer`: the
tiles are chosen per frame by screen-space error (``tau_px``) and loaded in the background, before every
render. Off-screen scripts call :meth:`LodLayer.resolve` before a screenshot, so the frame is complete.

Examples
--------
>>> import pyvista as pv
>>> from citylod.render.pyvista_layer import add_lod_layer
>>> pl = pv.Plotter(off_screen=True, window_size=(800, 600))           # doctest: +SKIP
>>> layer = add_lod_layer(pl, "TILES", tau_px=1.0)                        # doctest: +SKIP
>>> layer.resolve()                                                       # doctest: +SKIP
>>> pl.screenshot("city.png")                                             # doctest: +SKIP
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

from citylod.core.camera import Camera, overview_camera
from citylod.render.tileset_actor import FrameStats, Scene


class LodLayer:
    """Tilesets drawn with LOD into a plotter's renderer (see :func:`add_lod_layer`).

    Attributes
    ----------
    scene
        The :class:`~citylod.render.tileset_actor.Scene` doing selection, loading and drawing; its
        ``origin`` is subtracted from every position drawn (the plotter works in scene coordinates).
    """

    def __init__(self, plotter: Any, scene: Scene) -> None:
        self.plotter = plotter
        self.scene = scene

    @property
    def stats(self) -> FrameStats:
        """The last frame's statistics: tiles, triangles, points, levels."""
        return self.scene.last_stats

    def set_camera(self, camera: Camera) -> None:
        """Place the plotter's camera; ``camera`` is in the data's CRS."""
        self.scene.set_camera(camera)

    def resolve(self) -> FrameStats:
        """Load every tile the current camera needs at ``tau_px`` and show them (blocks; for screenshots)."""
        w, h = self.plotter.window_size
        view = self.scene.view(self.scene.view().camera, (w, h))
        stats = self.scene.resolve(view)
        self.plotter.renderer.ResetCameraClippingRange()
        return stats

    def close(self) -> None:
        """Stop the loader threads and stop updating before renders."""
        self.scene.close()


def add_lod_layer(plotter: Any, *sources: str | os.PathLike[str], tau_px: float = 1.0,
                  camera: Camera | None = None, color_by: str = "auto", cache_bytes: int = 1 << 30,
                  point_shape: str = "points") -> LodLayer:
    """Add tilesets (folders or ``tileset.json`` paths, any 3D Tiles 1.x) to ``plotter`` with LOD.

    ``point_shape="splat"`` draws point clouds as oriented disks sized by the local spacing
    (:mod:`citylod.render.splats`), hole-free up close; "points" draws fixed-size points.

    The plotter's camera is set to ``camera`` (data CRS) or, by default, to a view of the whole data.
    Before every render the tiles are selected for the plotter's camera and missing ones requested.

    Examples
    --------
    >>> layer = add_lod_layer(pv.Plotter(off_screen=True), "TILES", tau_px=2.0)  # doctest: +SKIP
    """
    scene = Scene(plotter.renderer, tau_px=tau_px, color_by=color_by, cache_bytes=cache_bytes)
    if point_shape not in ("points", "splat"):
        raise ValueError(f"point_shape must be 'points' or 'splat', not {point_shape!r}")
    for source in _as_list(sources):
        scene.add(source).point_shape = point_shape
    if camera is None:
        w, h = plotter.window_size
        camera = overview_camera(*scene.bounds, aspect=w / max(h, 1))
    scene.set_camera(camera)
    # PyVista resets an unset camera to its own view of the bounds at the first render; this one is set.
    plotter.camera_set = True
    scene.attach()
    return LodLayer(plotter, scene)


def _as_list(sources: Sequence[str | os.PathLike[str]]) -> list[str | os.PathLike[str]]:
    if not sources:
        raise ValueError("add_lod_layer needs at least one tileset")
    return list(sources)
