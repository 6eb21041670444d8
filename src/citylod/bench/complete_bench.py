"""How complete a LiDAR render looks against a city model of the same houses (``build points --complete``).

The measure of issue #25, on Delft (AHN3 points + the CityJSON model made from the same sources):

* **wall coverage** — from oblique cameras (30-45° down) over the model's area, the wall pixels are the
  pixels where the city model's walls are the nearest surface (the model is rendered in the same run,
  every object, walls apart); a wall pixel is covered when the LiDAR render's surface there lies
  within ``tol_m`` of the model's depth. Measured for the plain build and the completed one;
* **wall accuracy** — the distance from every added wall point to the model's nearest wall, computed
  on densely sampled wall triangles (``scipy.spatial.cKDTree``; independent of the augmentation);
* **cost** — build times plain and completed, interleaved in one run, and the frame time of each
  from the same cameras.

``python -m citylod.bench.complete_bench OUT_DIR --data ../shared/data/delft`` writes ``complete.json`` and before/after pictures.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import statistics
import time
from collections.abc import Sequence
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from citylod.core.camera import Camera
from citylod.io.city import read_city_model
from citylod.io.city.model import CityModel
from citylod.render import _vtk
from citylod.render.offscreen import OffscreenRenderer, save_png

F64 = npt.NDArray[np.float64]

__all__ = ["ModelMesh", "RoofGrid", "model_mesh", "oblique_cameras", "pictures", "splat_coverage", "street_camera",
           "wall_coverage", "wall_distances"]


@dataclass(frozen=True)
class ModelMesh:
    """A city model as triangles in its CRS: ``walls`` and ``others`` (T, 3, 3) float64."""

    walls: F64
    others: F64


def _triangulate(polys: Sequence[list[F64]]) -> F64:
    """Exterior rings (K, 3) to triangles (T, 3, 3), by VTK's polygon triangulation (concave rings too)."""
    if not polys:
        return np.zeros((0, 3, 3))
    rings = [np.asarray(p[0], np.float64)[:-1] for p in polys]  # closed rings: drop the repeated vertex
    rings = [r for r in rings if len(r) >= 3]
    base = np.mean([r.mean(axis=0) for r in rings], axis=0)
    pts = np.concatenate(rings) - base
    sizes = np.array([len(r) for r in rings])
    offs = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    conn = np.concatenate([np.concatenate([[n], o + np.arange(n)]) for n, o in zip(sizes, offs, strict=True)])
    data = _vtk.vtkPolyData()
    vp = _vtk.vtkPoints()
    vp.SetData(_vtk.numpy_to_vtk(pts, deep=True))
    data.SetPoints(vp)
    cells = _vtk.vtkCellArray()
    cells.ImportLegacyFormat(_vtk.numpy_to_vtkIdTypeArray(conn.astype(np.int64), deep=True))
    data.SetPolys(cells)
    tri = _vtk.vtkTriangleFilter()
    tri.SetInputData(data)
    tri.Update()
    out = tri.GetOutput()
    verts = _vtk.vtk_to_numpy(out.GetPoints().GetData()).astype(np.float64) + base
    ids = _vtk.vtk_to_numpy(out.GetPolys().GetConnectivityArray()).reshape(-1, 3)
    return verts[ids]


def model_mesh(model: CityModel) -> ModelMesh:
    """Triangles of every object's surfaces; walls are the building surfaces that stand vertical
    (|n_z| < 0.1 by Newell's normal) or are labelled ``WallSurface``."""
    walls, others = [], []
    for obj in model.objects:
        is_bldg = obj.type in ("Building", "BuildingPart")
        sem = obj.semantics or [None] * len(obj.surfaces)
        for poly, s in zip(obj.surfaces, sem, strict=False):
            ring = np.asarray(poly[0], np.float64)
            d = ring[1:] - ring[:1]
            n = np.cross(d[:-1], d[1:]).sum(axis=0)
            nz = abs(n[2]) / max(float(np.linalg.norm(n)), 1e-12)
            (walls if is_bldg and (s == "WallSurface" or (s is None and nz < 0.1)) else others).append(poly)
    return ModelMesh(_triangulate(walls), _triangulate(others))


def _tri_polydata(tris: F64, origin: F64, dtype: type = np.float32) -> Any:
    """(T, 3, 3) triangles, shifted by ``origin``, as a vtkPolyData of unshared vertices."""
    data = _vtk.vtkPolyData()
    vp = _vtk.vtkPoints()
    vp.SetData(_vtk.numpy_to_vtk(np.ascontiguousarray((tris.reshape(-1, 3) - origin).astype(dtype)), deep=True))
    data.SetPoints(vp)
    n = len(tris)
    conn = np.column_stack([np.full(n, 3), np.arange(3 * n).reshape(n, 3)]).reshape(-1)
    cells = _vtk.vtkCellArray()
    cells.ImportLegacyFormat(_vtk.numpy_to_vtkIdTypeArray(conn.astype(np.int64), deep=True))
    data.SetPolys(cells)
    return data


def _mesh_actor(tris: F64, origin: F64) -> Any:
    data = _tri_polydata(tris, origin)
    mapper = _vtk.vtkPolyDataMapper()
    mapper.SetInputData(data)
    actor = _vtk.vtkActor()
    actor.SetMapper(mapper)
    actor.GetProperty().BackfaceCullingOff()
    actor.VisibilityOff()
    return actor


def oblique_cameras(lo: F64, hi: F64, *, pitches_deg: Sequence[float] = (30.0, 45.0), azimuths: int = 4,
                    distance: float | None = None, ground_z: float = 0.0, fovy_deg: float = 45.0) -> list[Camera]:
    """Cameras looking ``pitches_deg`` down at the centre of the box ``lo``..``hi`` from ``azimuths``
    directions, at ``distance`` (default: 0.6 × the box's horizontal diagonal)."""
    c = (np.asarray(lo, np.float64) + np.asarray(hi, np.float64)) / 2.0
    d = distance or 0.6 * float(np.hypot(hi[0] - lo[0], hi[1] - lo[1]))
    cams = []
    for pitch in pitches_deg:
        for k in range(azimuths):
            az = 2.0 * math.pi * (k + 0.5) / azimuths
            p = math.radians(pitch)
            eye = (c[0] - d * math.cos(p) * math.sin(az), c[1] - d * math.cos(p) * math.cos(az),
                   ground_z + d * math.sin(p))
            cams.append(Camera(position=eye, focal_point=(float(c[0]), float(c[1]), ground_z), fovy_deg=fovy_deg))
    return cams


@dataclass
class CoverageFrame:
    """One camera: wall pixels, how many of them the LiDAR covers, how many a tree of the LiDAR hides
    (the model has none: such a wall pixel cannot be covered, and the tree is right), its draw time
    and its picture."""

    wall_px: int
    covered_px: int
    tree_px: int
    draw_s: float
    rgb: npt.NDArray[np.uint8]
    scanned_px: int = 0
    scanned_covered_px: int = 0

    @property
    def share_scanned(self) -> float:
        """Covered share of the wall pixels no tree hides that stand below a roof the scan saw there."""
        return self.scanned_covered_px / self.scanned_px if self.scanned_px else float("nan")

    @property
    def share(self) -> float:
        """Covered share of the wall pixels no tree hides."""
        n = self.wall_px - self.tree_px
        return self.covered_px / n if n else float("nan")

    @property
    def share_all(self) -> float:
        """Covered share of all wall pixels."""
        return self.covered_px / self.wall_px if self.wall_px else float("nan")


@dataclass(frozen=True)
class RoofGrid:
    """Highest building return per ``cell`` (m) square, (ny, nx) float64 (-inf: none), from ``lo`` (2,)."""

    lo: F64
    cell: float
    zmax: F64

    @staticmethod
    def from_las(files: Sequence[Path], cell: float = 0.5, building: int = 6) -> RoofGrid:
        import laspy

        xyz = []
        for f in files:
            las = laspy.read(str(f))
            sel = np.asarray(las.classification) == building
            xyz.append(np.column_stack([np.asarray(las.x)[sel], np.asarray(las.y)[sel], np.asarray(las.z)[sel]]))
        p = np.concatenate(xyz)
        lo = p[:, :2].min(axis=0)
        ij = ((p[:, :2] - lo) / cell).astype(np.int64)
        z = np.full(tuple(ij.max(axis=0)[::-1] + 1), -np.inf)
        np.maximum.at(z, (ij[:, 1], ij[:, 0]), p[:, 2])
        return RoofGrid(lo, cell, z)

    def local_max(self, xy: F64, radius_cells: int = 2) -> F64:
        """Highest building return within ``radius_cells`` cells of each point (x, y)."""
        from scipy import ndimage

        z = ndimage.maximum_filter(self.zmax, size=2 * radius_cells + 1, mode="constant", cval=-np.inf)
        ij = np.floor((np.asarray(xy)[:, :2] - self.lo) / self.cell).astype(np.int64)
        ok = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < z.shape[1]) & (ij[:, 1] < z.shape[0])
        out = np.full(len(ij), -np.inf)
        out[ok] = z[ij[ok, 1], ij[ok, 0]]
        return out


def wall_coverage(tileset: str | PathLike[str], mesh: ModelMesh, cameras: Sequence[Camera], *,
                  size: tuple[int, int] = (960, 540), tol_m: float = 0.5, tau_px: float = 1.0,
                  point_size_px: float = 2.0, repeats: int = 3, roofs: RoofGrid | None = None
                  ) -> list[CoverageFrame]:
    """Render ``tileset`` (as a user sees it: view-dependent selection at ``tau_px``) and the model from
    each camera; count wall pixels and those the LiDAR covers within ``tol_m`` of depth.

    Points are coloured by class (unlit, so a pixel's colour is its point's class): a wall pixel whose
    LiDAR surface lies more than ``tol_m`` in front of the wall in the colour of vegetation (class 1,
    where AHN puts trees, or 3-5) is counted as hidden by a tree.

    With ``roofs`` (the input's building returns), a wall pixel is also *scanned* when a building return
    within 1 m (horizontally) stands at least as high as the wall point: an LOD1 block's wall goes up to
    one height per building, above the eaves of a pitched roof, where the real building has roof, not
    wall."""
    from citylod.render.colors import classification_rgb

    veg = classification_rgb(np.array([1, 3, 4, 5])).astype(np.int16)
    out = []
    with OffscreenRenderer([tileset], size=size, tau_px=tau_px, point_size_px=point_size_px,
                           color_by="classification") as r:
        origin = np.asarray(r.scene.origin, np.float64)
        walls, others = _mesh_actor(mesh.walls, origin), _mesh_actor(mesh.others, origin)
        r.renderer.AddActor(walls)
        r.renderer.AddActor(others)
        for cam in cameras:
            r.prepare(cam)
            r.draw()
            draw_s = statistics.median(r.draw() for _ in range(repeats))
            rgb, lidar = r.grab_rgb(), r.grab_depth()
            shown = [(a, a.GetVisibility()) for a in r.scene.tile_actors]
            for a, _ in shown:
                a.VisibilityOff()
            walls.VisibilityOn()
            others.VisibilityOn()
            r.renderer.ResetCameraClippingRange()
            r.draw()
            d_all = r.grab_depth()
            others.VisibilityOff()
            r.draw()
            d_wall = r.grab_depth()
            walls.VisibilityOff()
            for a, v in shown:
                a.SetVisibility(v)
            is_veg = np.any(np.all(rgb[:, :, None, :].astype(np.int16) == veg[None, None], axis=-1), axis=-1)
            out.append(_frame(cam, lidar, d_all, d_wall, is_veg, draw_s, rgb, tol_m, roofs))
    return out


def _frame(cam: Camera, lidar: npt.NDArray[np.float32], d_all: npt.NDArray[np.float32],
           d_wall: npt.NDArray[np.float32], is_veg: npt.NDArray[np.bool_], draw_s: float,
           rgb: npt.NDArray[np.uint8], tol_m: float, roofs: RoofGrid | None) -> CoverageFrame:
    """Classify one camera's wall pixels from the LiDAR depth, the model's (all, walls only) and where the
    LiDAR's nearest surface is vegetation."""
    from citylod.render.depth import points_from_distance

    fin = np.isfinite(d_all)
    wall = fin & np.isfinite(d_wall) & (d_wall <= d_all + 1e-3 * np.where(fin, d_all, 0) + 0.01)
    gap = np.where(np.isfinite(lidar) & fin, lidar - np.where(fin, d_all, 0.0), np.inf)
    covered = wall & (np.abs(gap) <= tol_m)
    tree = wall & (gap < -tol_m) & is_veg
    frame = CoverageFrame(int(wall.sum()), int(covered.sum()), int(tree.sum()), draw_s, rgb)
    if roofs is not None:
        pts = points_from_distance(np.where(wall, d_all, 0.0), cam, relative=False)[wall]
        ok = np.zeros_like(wall)
        ok[wall] = roofs.local_max(pts[:, :2]) >= pts[:, 2] - tol_m
        scanned = ok & ~tree
        frame.scanned_px = int(scanned.sum())
        frame.scanned_covered_px = int((scanned & covered).sum())
    return frame


def _grab_depth(window: Any, renderer: Any, size: tuple[int, int]) -> npt.NDArray[np.float32]:
    from citylod.render.depth import zbuffer_to_distance

    w, h = size
    arr = _vtk.vtkFloatArray()
    window.GetZbufferData(0, 0, w - 1, h - 1, arr)
    cam = renderer.GetActiveCamera()
    near, far = cam.GetClippingRange()
    return zbuffer_to_distance(_vtk.vtk_to_numpy(arr).reshape(h, w)[::-1], near, far, cam.GetViewAngle())


def splat_coverage(xyz: F64, classification: npt.NDArray[np.uint8], normals: npt.NDArray[np.float32] | None,
                   mesh: ModelMesh, cameras: Sequence[Camera], *, size: tuple[int, int] = (960, 540),
                   tol_m: float = 0.5, roofs: RoofGrid | None = None) -> list[CoverageFrame]:
    """:func:`wall_coverage` for the full-resolution cloud drawn as splats (:mod:`citylod.render.splats`).

    ``normals`` (N, 3) where known (added walls: their boundary normal), rows of zeros elsewhere (then
    estimated from the neighbours); None: all estimated. Vegetation (class 1, 3-5) is drawn by an actor
    of its own, so a pixel whose nearest splat is vegetation is known without reading colours.
    """
    from citylod.render.colors import classification_rgb
    from citylod.render.splats import Splats, estimate_splats, splat_actor
    from citylod.render.tileset_actor import camera_to_vtk

    origin = np.round(xyz.mean(axis=0))
    s = estimate_splats(xyz)
    if normals is not None:
        known = np.any(normals != 0, axis=1)
        nrm = np.where(known[:, None], normals, s.normals).astype(np.float32)
        s = Splats(s.centers, nrm, s.radii)
    veg_mask = np.isin(classification, [1, 3, 4, 5])
    rgb = classification_rgb(classification)

    def part(m: npt.NDArray[np.bool_]) -> Any:
        return splat_actor(Splats(s.centers[m], s.normals[m], s.radii[m]), origin, rgb[m])

    veg, rest = part(veg_mask), part(~veg_mask)
    walls, others = _mesh_actor(mesh.walls, origin), _mesh_actor(mesh.others, origin)
    window = _vtk.offscreen_window(*size)
    ren = _vtk.vtkOpenGLRenderer()
    window.AddRenderer(ren)
    for a in (veg, rest, walls, others):
        ren.AddActor(a)
    out = []
    try:
        for cam in cameras:
            camera_to_vtk(cam, ren.GetActiveCamera(), origin)

            def depth(*shown: Any) -> npt.NDArray[np.float32]:
                for a in (veg, rest, walls, others):
                    a.SetVisibility(a in shown)
                ren.ResetCameraClippingRange()
                window.Render()
                return _grab_depth(window, ren, size)

            lidar = depth(veg, rest)
            t0 = time.perf_counter()
            window.Render()
            window.WaitForCompletion()
            draw_s = time.perf_counter() - t0
            arr = _vtk.vtkUnsignedCharArray()
            window.GetPixelData(0, 0, size[0] - 1, size[1] - 1, 0, arr, 0)
            img = np.ascontiguousarray(_vtk.vtk_to_numpy(arr).reshape(size[1], size[0], 3)[::-1])
            d_veg = depth(veg)
            d_all = depth(walls, others)
            d_wall = depth(walls)
            is_veg = np.isfinite(d_veg) & (d_veg <= lidar + 1e-3 * np.where(np.isfinite(lidar), lidar, 0) + 0.01)
            out.append(_frame(cam, lidar, d_all, d_wall, is_veg, draw_s, img, tol_m, roofs))
    finally:
        window.Finalize()
    return out


def wall_distances(points: F64, wall_tris: F64) -> F64:
    """Exact distance from each point to the nearest wall triangle (VTK's ``vtkImplicitPolyDataDistance``
    over the triangles, evaluated for all points in one call; unsigned)."""
    org = wall_tris.reshape(-1, 3).mean(axis=0)
    data = _tri_polydata(wall_tris, org, np.float64)
    dist = _vtk.vtkImplicitPolyDataDistance()
    dist.SetInput(data)
    src = _vtk.numpy_to_vtk(np.ascontiguousarray(np.asarray(points, np.float64) - org), deep=True)
    out = _vtk.vtkDoubleArray()
    dist.FunctionValue(src, out)
    return np.abs(_vtk.vtk_to_numpy(out).astype(np.float64))


def pictures(before: str | PathLike[str], after: str | PathLike[str], camera: Camera, out_dir: Path, *,
             size: tuple[int, int] = (960, 540), stem: str = "complete") -> list[Path]:
    """The same oblique view of two tilesets, coloured by elevation: ``<stem>_before.png``, ``_after.png``."""
    paths = []
    for tag, ts in (("before", before), ("after", after)):
        with OffscreenRenderer([ts], size=size, color_by="elevation") as r:
            paths.append(save_png(out_dir / f"{stem}_{tag}.png", r.render(camera).rgb))
    return paths


def street_camera(lo: F64, hi: F64, ground_z: float) -> Camera:
    """A close oblique view (35° down, 70 m away) of the middle of ``lo``..``hi``, from the south-west."""
    return oblique_cameras(lo, hi, pitches_deg=(35.0,), azimuths=1, distance=70.0, ground_z=ground_z)[0]


def _timed_build(files: Sequence[Path], out: Path, complete: Any) -> tuple[float, Any]:
    from citylod.lod.build.points import build_points

    t0 = time.perf_counter()
    rep = build_points(files, out, crs="EPSG:28992", progress=False, complete=complete)
    return time.perf_counter() - t0, rep


def _totals(frames: Sequence[CoverageFrame]) -> dict[str, Any]:
    """The report entry of one variant: pixel counts and shares over all cameras, median frame time."""
    wall_px = sum(f.wall_px for f in frames)
    tree_px = sum(f.tree_px for f in frames)
    cov = sum(f.covered_px for f in frames)
    scanned = sum(f.scanned_px for f in frames)
    return {
        "wall_px": wall_px, "tree_px": tree_px, "covered_px": cov,
        "coverage": cov / (wall_px - tree_px) if wall_px > tree_px else None,
        "coverage_all": cov / wall_px if wall_px else None,
        "scanned_px": scanned,
        "coverage_scanned": sum(f.scanned_covered_px for f in frames) / scanned if scanned else None,
        "coverage_per_camera": [f.share for f in frames],
        "draw_s_median": statistics.median(f.draw_s for f in frames),
    }


def run(data_dir: Path, out_dir: Path, *, repeats: int = 3, size: tuple[int, int] = (960, 540)) -> dict[str, Any]:
    """The whole measurement on Delft; returns the report (also written as ``complete.json``)."""
    from citylod.io.las import read_metadata
    from citylod.lod.build.complete import KIND_WALL, CompleteOptions, augment

    files = [data_dir / "ahn3_cropped_1.laz", data_dir / "ahn3_cropped_2.laz"]
    out_dir.mkdir(parents=True, exist_ok=True)
    work = out_dir / "tilesets"
    variants = {"plain": None, "walls-points": CompleteOptions(walls="points"),
                "walls-quads": CompleteOptions(walls="quads")}
    times: dict[str, list[float]] = {k: [] for k in variants}
    reports: dict[str, Any] = {}
    for _ in range(repeats):  # interleaved, so load on the machine hits every variant alike
        for name, opts in variants.items():
            s, rep = _timed_build(files, work / name, opts)
            times[name].append(s)
            reports[name] = rep
    model = read_city_model(data_dir / "testarea.city.json", lod=1)
    mesh = model_mesh(model)
    blo = mesh.walls.reshape(-1, 3).min(axis=0)
    bhi = mesh.walls.reshape(-1, 3).max(axis=0)
    cams = oblique_cameras(blo, bhi, ground_z=float(np.percentile(mesh.walls[..., 2], 5)))
    result: dict[str, Any] = {"cameras": [c.to_dict() for c in cams], "size": list(size), "variants": {}}
    roofs = RoofGrid.from_las(files)
    for name in variants:
        frames = wall_coverage(work / name, mesh, cams, size=size, roofs=roofs)
        result["variants"][name] = {
            **_totals(frames), "build_s_median": statistics.median(times[name]), "build_s": times[name],
            "summary": reports[name].summary(),
        }
        save_png(out_dir / f"delft_{name}.png", frames[0].rgb)
    pictures(work / "plain", work / "walls-points", street_camera(blo, bhi, float(np.percentile(mesh.walls[..., 2], 5))),
             out_dir, size=size)
    plain = result["variants"]["plain"]
    for name in ("walls-points", "walls-quads"):
        v = result["variants"][name]
        v["build_overhead"] = v["build_s_median"] / plain["build_s_median"] - 1.0
        v["frame_ratio"] = v["draw_s_median"] / plain["draw_s_median"]
    meta = read_metadata(files, "EPSG:28992")
    aug = augment(files, CompleteOptions(walls="points"), lo=meta.lo, hi=meta.hi)
    # The same measure with every point drawn as a splat (full resolution), before and after.
    import laspy

    clouds = [laspy.read(str(f)) for f in files]
    xyz = np.concatenate([np.column_stack([c.x, c.y, c.z]) for c in clouds])
    cls = np.concatenate([np.asarray(c.classification) for c in clouds])
    for name, (px, pc, pn) in {
        "splats-plain": (xyz, cls, None),
        "splats-walls-points": (np.concatenate([xyz, aug.xyz]), np.concatenate([cls, aug.classification]),
                                np.concatenate([np.zeros((len(xyz), 3), np.float32), aug.normals])),
    }.items():
        frames = splat_coverage(px, pc, pn, mesh, cams, size=size, roofs=roofs)
        result["variants"][name] = _totals(frames)
        save_png(out_dir / f"delft_{name}.png", frames[0].rgb)
    wall_pts = aug.xyz[aug.kind == KIND_WALL]
    d = wall_distances(wall_pts, mesh.walls)
    # Walls of buildings the model has: points within 5 m of one of its walls (class-6 points of
    # buildings outside the model's extent have no wall to compare with).
    near = d <= 5.0
    result["wall_points"] = {
        "count": len(wall_pts), "near_model": int(near.sum()),
        "p50_m": float(np.percentile(d[near], 50)), "p95_m": float(np.percentile(d[near], 95)),
        "share_within_0.5m": float(np.mean(d[near] <= 0.5)),
    }
    (out_dir / "complete.json").write_text(json.dumps(result, indent=1, default=float))
    shutil.rmtree(work, ignore_errors=True)
    return result


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--data", type=Path, required=True, help="the Delft folder of ../shared/data")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    res = run(args.data, args.out, repeats=args.repeats)
    for name, v in res["variants"].items():
        extra = ""
        if "build_overhead" in v:
            extra = f"  (+{100 * v['build_overhead']:.0f} %, frame x{v['frame_ratio']:.2f})"
        build = f"build {v['build_s_median']:.2f} s  " if "build_s_median" in v else ""
        print(f"{name:20s} coverage {v['coverage_all']:.3f}, trees apart {v['coverage']:.3f}, "
              f"below scanned roofs {v['coverage_scanned']:.3f}  "
              f"{build}frame {1e3 * v['draw_s_median']:.1f} ms{extra}")
    w = res["wall_points"]
    print(f"wall points  {w['count']:,}, {w['near_model']:,} within 5 m of a model wall: p50 {w['p50_m']:.2f} m, "
          f"p95 {w['p95_m']:.2f} m, {100 * w['share_within_0.5m']:.1f} % within 0.5 m")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
