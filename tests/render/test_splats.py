"""Splats close a sampled surface where fixed-size points leave holes: rendered off screen, compared with
the true surface's silhouette rendered in the same window."""

from __future__ import annotations

import numpy as np

from citylod.core.camera import Camera
from citylod.render import _vtk
from citylod.render.depth import zbuffer_to_distance
from citylod.render.splats import estimate_splats, splat_actor
from citylod.render.tileset_actor import camera_to_vtk

SIZE = (320, 240)
ORIGIN = np.array([85_000.0, 447_500.0, 0.0])  # large coordinates, shifted by the scene origin


def _height(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return 0.8 * np.sin(x / 3.0) * np.cos(y / 4.0)


def _surface_actor(n: int = 200) -> object:
    """The true surface (a fine triangle grid over 0..20 m) as an actor, shifted by the origin."""
    g = np.linspace(0.0, 20.0, n)
    x, y = np.meshgrid(g, g)
    pts = np.column_stack([x.ravel(), y.ravel(), _height(x, y).ravel()])
    data = _vtk.vtkPolyData()
    vp = _vtk.vtkPoints()
    vp.SetData(_vtk.numpy_to_vtk(pts.astype(np.float32), deep=True))
    data.SetPoints(vp)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1))
    a = (j * n + i).ravel()
    tris = np.concatenate([np.stack([a, a + 1, a + n + 1], 1), np.stack([a, a + n + 1, a + n], 1)])
    conn = np.column_stack([np.full(len(tris), 3), tris]).reshape(-1)
    cells = _vtk.vtkCellArray()
    cells.ImportLegacyFormat(_vtk.numpy_to_vtkIdTypeArray(conn.astype(np.int64), deep=True))
    data.SetPolys(cells)
    mapper = _vtk.vtkPolyDataMapper()
    mapper.SetInputData(data)
    actor = _vtk.vtkActor()
    actor.SetMapper(mapper)
    return actor


def _points_actor(xyz: np.ndarray, size_px: float) -> object:
    data = _vtk.vtkPolyData()
    vp = _vtk.vtkPoints()
    vp.SetData(_vtk.numpy_to_vtk((xyz - ORIGIN).astype(np.float32), deep=True))
    data.SetPoints(vp)
    n = len(xyz)
    cells = _vtk.vtkCellArray()
    cells.ImportLegacyFormat(_vtk.numpy_to_vtkIdTypeArray(np.column_stack([np.ones(n, np.int64), np.arange(n)]).reshape(-1),
                                                   deep=True))
    data.SetVerts(cells)
    mapper = _vtk.vtkPolyDataMapper()
    mapper.SetInputData(data)
    actor = _vtk.vtkActor()
    actor.SetMapper(mapper)
    actor.GetProperty().SetPointSize(size_px)
    return actor


def _drawn(actor: object, camera: Camera) -> np.ndarray:
    """Pixels where ``actor`` draws anything, (H, W) bool, from a fresh off-screen window."""
    win = _vtk.offscreen_window(*SIZE)
    ren = _vtk.vtkOpenGLRenderer()
    win.AddRenderer(ren)
    ren.AddActor(actor)
    camera_to_vtk(camera, ren.GetActiveCamera(), np.zeros(3))
    ren.ResetCameraClippingRange()
    win.Render()
    arr = _vtk.vtkFloatArray()
    win.GetZbufferData(0, 0, SIZE[0] - 1, SIZE[1] - 1, arr)
    cam = ren.GetActiveCamera()
    near, far = cam.GetClippingRange()
    d = zbuffer_to_distance(_vtk.vtk_to_numpy(arr).reshape(SIZE[1], SIZE[0]), near, far, cam.GetViewAngle())
    win.Finalize()
    return np.isfinite(d)


def test_splat_normals_follow_the_surface(surface_cloud: np.ndarray) -> None:
    cloud = surface_cloud
    s = estimate_splats(cloud)
    x, y = (cloud - ORIGIN)[:, 0], (cloud - ORIGIN)[:, 1]
    # The analytic normal of z = h(x, y): (-h_x, -h_y, 1), normalised.
    hx = 0.8 / 3.0 * np.cos(x / 3.0) * np.cos(y / 4.0)
    hy = -0.8 / 4.0 * np.sin(x / 3.0) * np.sin(y / 4.0)
    true = np.column_stack([-hx, -hy, np.ones_like(x)])
    true /= np.linalg.norm(true, axis=1, keepdims=True)
    cos = np.abs(np.sum(s.normals * true, axis=1))
    assert np.median(cos) > np.cos(np.radians(5)) and np.percentile(cos, 95) > np.cos(np.radians(15))


def test_close_view_has_no_holes_with_splats(surface_cloud: np.ndarray) -> None:
    cloud = surface_cloud
    # Close: 6 m from the surface, one pixel ≈ 2 cm where the points are ≈ 22 cm apart.
    # The camera in the scene frame (the data shifted by ORIGIN), as the renderer places it.
    cam = Camera(position=(10.0, 2.0, 5.0), focal_point=(10.0, 8.0, 0.0), fovy_deg=45.0)
    inner = _drawn(_surface_actor(), cam)
    assert inner.mean() > 0.5  # the surface fills most of the frame
    splats = _drawn(splat_actor(estimate_splats(cloud), ORIGIN), cam)
    points = _drawn(_points_actor(cloud, 2.0), cam)
    # The silhouette's border pixels depend on where the last samples fall: judged one pixel inside it.
    from scipy import ndimage

    core = ndimage.binary_erosion(inner, iterations=2)
    holes_splats = float(np.mean(~splats[core]))
    holes_points = float(np.mean(~points[core]))
    assert holes_splats <= 0.01, holes_splats
    assert holes_points > 0.5, holes_points  # the same points as 2-pixel dots: mostly background


# ------------------------------------------------------------------- splats in the tile renderer
def _write_las(path, xyz: np.ndarray) -> None:
    import laspy

    hdr = laspy.LasHeader(point_format=1, version="1.2")
    hdr.scales = np.array([0.001, 0.001, 0.001])
    hdr.offsets = ORIGIN.copy()
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.classification = np.full(len(xyz), 2, np.uint8)
    las.write(str(path))


#: Looking down steeply at the middle of the surface: every pixel of the frame is surface.
CLOSE = Camera(position=tuple(ORIGIN + [10.0, 9.0, 5.0]), focal_point=tuple(ORIGIN + [10.0, 11.0, 0.0]),
               fovy_deg=45.0)


def test_render_command_draws_splats_without_holes(surface_tiles, tmp_path) -> None:
    """``citylod render --splats``: from close, the surface fills the frame (≤ 1 % background), where the
    same tiles drawn as 2-pixel points leave most of it background."""
    import json

    from citylod.cli import main

    cam = tmp_path / "cam.json"
    cam.write_text(json.dumps(CLOSE.to_dict()))
    share = {}
    for tag, extra in (("points", []), ("splats", ["--splats"])):
        rc = main(["render", str(surface_tiles), "--camera", str(cam), "-o", str(tmp_path / f"{tag}.png"),
                   "--size", "320x240", "--depth", str(tmp_path / f"{tag}.npy"), *extra])
        assert rc == 0
        share[tag] = float(np.mean(~np.isfinite(np.load(tmp_path / f"{tag}.npy"))))
    assert share["splats"] <= 0.01, share
    assert share["points"] > 0.3, share


def test_splat_layer_restyles_back_to_points(surface_tiles) -> None:
    from citylod.render.offscreen import OffscreenRenderer

    with OffscreenRenderer([surface_tiles], size=(320, 240), point_shape="splat") as r:
        splat = r.render(CLOSE, depth=True)
        layer = r.scene.layers[0]
        assert layer.shown_keys
        assert all(layer._slots[k].points.actor.GetMapper().IsA("vtkGlyph3DMapper") for k in layer.shown_keys)
        layer.point_shape = "points"
        layer.restyle()
        plain = r.render(CLOSE, depth=True)
    assert np.mean(~np.isfinite(splat.depth)) <= 0.01
    assert np.mean(~np.isfinite(plain.depth)) > 0.3
