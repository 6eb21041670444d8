"""Which way of drawing many tiles is faster here: one actor per tile, or one composite actor.

The renderer (:mod:`citylod.render.tileset_actor`) keeps one ``vtkActor`` per tile. The alternative is
one actor with a ``vtkCompositePolyDataMapper`` over a ``vtkMultiBlockDataSet`` whose block visibility
follows the selection. :func:`compare_actor_strategies` draws the same grid of tiles both ways, with
the visible set changing every frame as during a flight, interleaving the two so machine noise hits both
alike. Run ``python -m citylod.bench.actors`` to print the numbers.

Measured (VTK 9.7, Mesa llvmpipe through EGL, 2 cores, 960×540), median ms per frame over 20 frames,
80 % of the tiles visible and the visible set changing every frame:

===============================  ==========  ===========
tiles × triangles per tile       per tile    composite
===============================  ==========  ===========
256 × 2 048 (0.5 M triangles)    76.0        69.7
64 × 32 768 (2.1 M triangles)    141.6       164.9
===============================  ==========  ===========

The composite mapper wins by 8 % only with many tiny tiles; with tiles of the size citylod builds
(129 × 129 grids, 32 768 triangles) one actor per tile is 14 % faster, and only per-tile actors can give
each tile its own texture. citylod keeps one actor per tile.
"""

from __future__ import annotations

import time

import numpy as np

from citylod.render import _vtk


def _grid(n: int, x0: float, y0: float, size: float) -> tuple[np.ndarray, np.ndarray]:
    g = np.linspace(0, size, n)
    xx, yy = np.meshgrid(g, g)
    zz = 20 * np.sin(xx / 50 + x0) * np.cos(yy / 70 + y0)
    pts = np.stack([xx.ravel(), yy.ravel(), zz.ravel()], 1).astype(np.float32)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1))
    a = (j * n + i).ravel()
    b, c = a + 1, a + n
    faces = np.concatenate([np.stack([a, b, c + 1], 1), np.stack([a, c + 1, c], 1)]).astype(np.int64)
    return pts, faces


def _poly(pts: np.ndarray, faces: np.ndarray) -> object:
    pd = _vtk.vtkPolyData()
    p = _vtk.vtkPoints()
    p.SetData(_vtk.numpy_to_vtk(pts, deep=True))
    pd.SetPoints(p)
    ca = _vtk.vtkCellArray()
    off = np.arange(0, 3 * len(faces) + 1, 3, dtype=np.int64)
    ca.SetData(_vtk.numpy_to_vtkIdTypeArray(off, deep=True),
               _vtk.numpy_to_vtkIdTypeArray(faces.reshape(-1).copy(), deep=True))
    pd.SetPolys(ca)
    return pd


def compare_actor_strategies(tiles: int = 256, n: int = 33, size: tuple[int, int] = (960, 540),
                             frames: int = 20, visible_fraction: float = 0.8, seed: int = 0) -> dict[str, float]:
    """Median ms per frame of both strategies on the same tiles, views and visible sets.

    Returns
    -------
    dict
        ``{"per_tile_ms": ..., "composite_ms": ..., "triangles": ...}``.
    """
    side = int(np.sqrt(tiles))
    extent = 500.0
    data = []
    for k in range(side * side):
        i, j = divmod(k, side)
        pts, faces = _grid(n, i, j, extent)
        data.append((pts, faces, (i * extent, j * extent)))
    window = _vtk.offscreen_window(*size)
    ren_a, ren_b = _vtk.vtkRenderer(), _vtk.vtkRenderer()
    actors = []
    for pts, faces, (ox, oy) in data:
        m = _vtk.vtkPolyDataMapper()
        m.SetInputData(_poly(pts, faces))
        m.StaticOn()
        a = _vtk.vtkActor()
        a.SetMapper(m)
        mat = np.eye(4)
        mat[:2, 3] = ox, oy
        vm = _vtk.vtkMatrix4x4()
        vm.DeepCopy(mat.ravel().tolist())
        a.SetUserMatrix(vm)
        ren_a.AddActor(a)
        actors.append(a)
    mb = _vtk.vtkMultiBlockDataSet()
    mb.SetNumberOfBlocks(len(data))
    for k, (pts, faces, (ox, oy)) in enumerate(data):
        mb.SetBlock(k, _poly(pts + np.array([ox, oy, 0], np.float32), faces))
    cm = _vtk.vtkCompositePolyDataMapper()
    cm.SetInputDataObject(mb)
    cm.StaticOn()
    attrs = _vtk.vtkCompositeDataDisplayAttributes()
    cm.SetCompositeDataDisplayAttributes(attrs)
    comp = _vtk.vtkActor()
    comp.SetMapper(cm)
    ren_b.AddActor(comp)
    rng = np.random.default_rng(seed)
    times: dict[str, list[float]] = {"per_tile": [], "composite": []}
    cams = []
    for ren in (ren_a, ren_b):
        ren.ResetCamera()
        cam = ren.GetActiveCamera()
        cam.Elevation(-40)
        cams.append(cam)
    for f in range(frames + 1):
        vis = rng.random(len(data)) < visible_fraction
        for name, ren in (("per_tile", ren_a), ("composite", ren_b)):
            if name == "per_tile":
                for a, v in zip(actors, vis, strict=True):
                    a.SetVisibility(bool(v))
            else:
                for k, v in enumerate(vis):
                    cm.SetBlockVisibility(k + 1, bool(v))  # flat index: block k is k + 1
            ren.GetActiveCamera().Azimuth(2)
            ren.ResetCameraClippingRange()
            window.AddRenderer(ren)
            t0 = time.perf_counter()
            window.Render()
            window.WaitForCompletion()
            if f > 0:  # frame 0 uploads the geometry
                times[name].append(time.perf_counter() - t0)
            window.RemoveRenderer(ren)
    window.Finalize()
    return {"per_tile_ms": 1000 * float(np.median(times["per_tile"])),
            "composite_ms": 1000 * float(np.median(times["composite"])),
            "triangles": float(visible_fraction * len(data) * 2 * (n - 1) ** 2)}


if __name__ == "__main__":
    for t, n in ((256, 33), (64, 129)):
        r = compare_actor_strategies(t, n)
        print(f"{t} tiles × {2 * (n - 1) ** 2} triangles: per tile {r['per_tile_ms']:.1f} ms, "
              f"composite {r['composite_ms']:.1f} ms")
