"""On-the-fly reprojection of a layer in another CRS (citylod.render.reproject, issue #21).

The sample DSM (UTM 32N) and a copy warped by GDAL (rasterio) into EPSG:3035 are built as two tilesets. The
3035 one, drawn in a UTM scene, must land where GDAL puts it: every drawn point, taken back to 3035 by GDAL's
own transformation, lies on the warped raster within its certified error; and its depth image coincides with
the UTM layer's. The old Scene.add refused a second CRS, so each of these tests failed there.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pyproj
import pytest

from citylod.core.camera import Camera
from citylod.core.errors import CitylodError
from citylod.core.geometry import Box
from citylod.io.tiles3d import open_tileset
from citylod.lod.build.dsm import build_dsm
from citylod.render.reproject import reprojection_for
from citylod.render.tile_data import prepare_tile
from citylod.render.tileset_actor import Scene, _load_node
from citylod.sample.files import make_sample
from tests.cli_harness import assert_clean_refusal, run_cli

rasterio = pytest.importorskip("rasterio")
from rasterio.warp import Resampling, calculate_default_transform, reproject  # noqa: E402
from rasterio.warp import transform as gdal_transform  # noqa: E402

WARPED_CRS = "EPSG:3035"
CX, CY = 512064.5, 5403064.5  # centre of the size-129 sample (make_sample's UTM 32N grid)
CAMERA = Camera(position=(CX - 40, CY - 120, 260.0), focal_point=(CX, CY, 90.0), view_up=(0, 0, 1), fovy_deg=40)
SIZE = (400, 300)


@pytest.fixture(scope="module")
def two_crs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("reproject")
    info = make_sample(out / "sample", size=129)
    dsm = info.files["dsm"]
    warped = out / "dsm3035.tif"
    with rasterio.open(dsm) as ds:
        tr, w, h = calculate_default_transform(ds.crs, WARPED_CRS, ds.width, ds.height, *ds.bounds, resolution=0.5)
        with rasterio.open(warped, "w", **(ds.profile | {"crs": WARPED_CRS, "transform": tr, "width": w,
                                                         "height": h})) as dst:
            # Nearest: every warped cell holds a source height (no blur), at half the source spacing.
            reproject(rasterio.band(ds, 1), rasterio.band(dst, 1), resampling=Resampling.nearest)
    utm = build_dsm(dsm, out / "utm", tile_size=65, workers=0, progress=False)
    laea = build_dsm(warped, out / "laea", tile_size=65, workers=0, progress=False)
    return {"utm": out / "utm", "laea": out / "laea", "warped": warped, "dir": out,
            "utm_leaf": utm.per_level[-1]["max_certified"], "laea_leaf": laea.per_level[-1]["max_certified"]}


def _render(sources: list[Path], hide_first: bool) -> tuple[np.ndarray, np.ndarray, object]:
    from citylod.render.offscreen import OffscreenRenderer

    with OffscreenRenderer(sources, size=SIZE) as r:
        if hide_first:
            r.scene.layers[0].visible = False
        frame = r.render(CAMERA, depth=True, full_resolution=True)
        layers = [(lay.reprojection is not None) for lay in r.scene.layers]
    assert frame.depth is not None
    return frame.depth, frame.rgb, layers


def test_reprojected_points_lie_on_the_gdal_warped_raster(two_crs: dict[str, Path]) -> None:
    """Independent check: GDAL takes each drawn point (UTM) back to 3035; the raster there must hold its height
    within the leaf's certified error (3×3 cells around it: the mesh interpolates between cell centres)."""
    from citylod.render.depth import points_from_distance

    depth, _rgb, reprojected = _render([two_crs["utm"], two_crs["laea"]], hide_first=True)
    assert reprojected == [False, True]
    seen = np.isfinite(depth)
    assert seen.mean() > 0.3  # the layer is drawn, and in view
    pts = points_from_distance(depth, CAMERA, relative=False)[seen]
    xs, ys = gdal_transform("EPSG:32632", WARPED_CRS, pts[:, 0].tolist(), pts[:, 1].tolist())
    with rasterio.open(two_crs["warped"]) as ds:
        band, nodata = ds.read(1), ds.nodata
        rows, cols = rasterio.transform.rowcol(ds.transform, xs, ys)
    rows, cols = np.asarray(rows), np.asarray(cols)
    padded = np.pad(band, 2, constant_values=nodata)
    near = np.stack([padded[rows + 2 + a, cols + 2 + b] for a in (-1, 0, 1) for b in (-1, 0, 1)])
    valid = (near != nodata).all(axis=0)
    assert valid.mean() > 0.97  # only pixels at the data's edge touch no-data cells
    z = pts[:, 2][valid]
    excess = np.maximum(near.min(axis=0)[valid] - z, z - near.max(axis=0)[valid])
    # Certified leaf error plus the depth buffer's resolution at ≈ 250 m (24 bits over the clipping range).
    tol = two_crs["laea_leaf"] + 0.05
    assert excess.max() <= tol, (float(excess.max()), tol)


def test_reprojected_layer_coincides_with_the_utm_render(two_crs: dict[str, Path]) -> None:
    """The 3035 layer drawn in the UTM scene against the UTM layer alone, same camera: depths agree within
    both certified errors once a pixel of shift is allowed, except where the warp moved building walls."""
    da, rgb_a, _ = _render([two_crs["utm"]], hide_first=False)
    db, rgb_b, _ = _render([two_crs["utm"], two_crs["laea"]], hide_first=True)
    both = np.isfinite(da) & np.isfinite(db)
    assert both.mean() > 0.45 and abs(np.isfinite(da).mean() - np.isfinite(db).mean()) < 0.02
    padded = np.pad(da, 1, constant_values=np.inf)
    best = np.full(da.shape, np.inf)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            with np.errstate(invalid="ignore"):
                best = np.minimum(best, np.abs(db - padded[1 + dy:1 + dy + da.shape[0], 1 + dx:1 + dx + da.shape[1]]))
    tol = two_crs["utm_leaf"] + two_crs["laea_leaf"]
    # Nearest resampling moves a wall by up to half a source cell (0.7 m); those pixels are the rest.
    share = float((best[both] <= tol).mean())
    assert share >= 0.99, (share, np.percentile(best[both], [50, 99, 100]))
    assert float(np.median(best[both])) < 0.1
    # The pictures match too (same sun, same surface): mean colour difference of a few grey levels.
    diff = np.abs(rgb_a.astype(int) - rgb_b.astype(int))[both]
    assert diff.mean() < 12, diff.mean()


def test_transformed_boxes_contain_transformed_vertices(two_crs: dict[str, Path]) -> None:
    """Every tile of the reprojected layer: all its transformed vertices inside its transformed box, and its
    geometric error at least the source's (the map is close to an isometry here)."""
    with Scene() as scene:
        scene.add(two_crs["utm"])
        layer = scene.add(two_crs["laea"])
        assert layer.reprojection is not None and "EPSG:3035 reprojected on the fly to EPSG:32632" in \
            layer.reprojection.label
        checked = 0
        to_utm = pyproj.Transformer.from_crs("EPSG:3035", "EPSG:32632", always_xy=True)
        for node in layer._nodes.values():
            assert node.geometric_error >= node.tile.geometric_error * 0.999
            if node.content_uri is None:
                continue
            prepared, _ = _load_node(node)
            raw, _ = prepare_tile(node.tile)  # the tile's own positions, transformed here independently
            lo, hi = node.box.bounds()
            for mesh, own in zip(prepared.meshes, raw.meshes, strict=True):
                world = mesh.positions.astype(np.float64) + node.matrix[:3, 3]
                src = own.positions.astype(np.float64) @ node.tile.matrix[:3, :3].T + node.tile.matrix[:3, 3]
                x, y = to_utm.transform(src[:, 0], src[:, 1])
                assert np.abs(world[:, 0] - x).max() < 0.01 and np.abs(world[:, 1] - y).max() < 0.01
                assert np.array_equal(world[:, 2].round(2), src[:, 2].round(2))  # 2D pair: heights unchanged
                assert (world >= lo).all() and (world <= hi).all(), node.key
                checked += len(world)
        assert checked > 10_000


@pytest.mark.parametrize("dst", ["EPSG:3857", "EPSG:4978"])
def test_box_bound_holds_for_large_curved_tiles(dst: str) -> None:
    """A 40 km × 40 km × 200 m UTM box into Web Mercator (scale changes by 0.6 %) and into geocentric ECEF
    (the Earth's curvature bends it by ≈ 30 m): the padded box holds 20 000 transformed points of the box, and
    distances grow by at most the returned scale bound."""
    rep = reprojection_for(pyproj.CRS("EPSG:32632"), pyproj.CRS(dst), "test")
    assert rep is not None
    box = Box.from_bounds([480_000, 5_380_000, 0], [520_000, 5_420_000, 200])
    (out,), errors, scale = rep.boxes([box], [2.0])
    rng = np.random.default_rng(1)
    u = rng.uniform(-1, 1, (20_000, 3))
    u[:5000, 0] = np.sign(u[:5000, 0])  # points on the faces, where the bulge is largest
    u[5000:10_000, 2] = np.sign(u[5000:10_000, 2])
    p = box.center + u @ box.half_axes.T
    q = rep.points(p)
    lo, hi = out.bounds()
    assert (q >= lo).all() and (q <= hi).all()
    if dst == "EPSG:4978":  # the bulge is real: the corners alone would miss points
        corners = rep.points(box.corners())
        assert (q.max(axis=0) > corners.max(axis=0) + 1.0).any() or (q.min(axis=0) < corners.min(axis=0) - 1.0).any()
    d_src = np.linalg.norm(p[1:] - p[:-1], axis=1)
    d_dst = np.linalg.norm(q[1:] - q[:-1], axis=1)
    assert (d_dst <= scale[0] * d_src + 1e-6).all()
    assert errors[0] >= 2.0 * (d_dst / d_src).max()


def test_same_crs_layers_are_untouched(two_crs: dict[str, Path]) -> None:
    """Two layers in one CRS: no reprojection, the proxies keep the tile's matrix, box and error, and the
    loader hands over the decoded arrays themselves."""
    with Scene() as scene:
        scene.add(two_crs["utm"])
        layer = scene.add(two_crs["utm"])
        assert layer.reprojection is None
        node = next(n for n in layer._nodes.values() if n.content_uri is not None)
        assert node.matrix is node.tile.matrix and node.box is node.tile.box
        assert node.geometric_error == node.tile.geometric_error
        a, _ = _load_node(node)
        b, _ = prepare_tile(node)
        assert a.meshes[0].positions.tobytes() == b.meshes[0].positions.tobytes()


def _with_crs(src: Path, dst: Path, wkt: str) -> Path:
    shutil.copytree(src, dst)
    doc = json.loads((dst / "tileset.json").read_text())
    doc["extras"]["citylod"]["crs"] = wkt
    (dst / "tileset.json").write_text(json.dumps(doc))
    return dst


ENGINEERING = ('ENGCRS["site grid",EDATUM["site"],CS[Cartesian,2],AXIS["x",east,LENGTHUNIT["metre",1]],'
               'AXIS["y",north,LENGTHUNIT["metre",1]]]')


def test_unrelated_crs_is_one_clear_error(two_crs: dict[str, Path]) -> None:
    site = _with_crs(two_crs["utm"], two_crs["dir"] / "site", ENGINEERING)
    with Scene() as scene:
        scene.add(two_crs["utm"])
        with pytest.raises(CitylodError, match="no transformation from site grid"):
            scene.add(site)
        assert len(scene.layers) == 1
    geo = _with_crs(two_crs["utm"], two_crs["dir"] / "geo", pyproj.CRS("EPSG:4979").to_wkt())
    with Scene() as scene:
        scene.add(geo)
        with pytest.raises(CitylodError, match="geographic"):
            scene.add(two_crs["utm"])
    assert open_tileset(site).crs.is_engineering


def test_cli_renders_two_crs_and_refuses_an_unrelated_one(two_crs: dict[str, Path], tmp_path: Path) -> None:
    cam = tmp_path / "camera.json"
    CAMERA.save(cam)
    png = tmp_path / "two.png"
    r = run_cli(["render", two_crs["utm"], two_crs["laea"], "-o", png, "--camera", cam, "--size", "160x120"])
    assert r.returncode == 0 and png.is_file(), r.stderr[-2000:]
    site = two_crs["dir"] / "site_cli"
    if not site.exists():
        _with_crs(two_crs["utm"], site, ENGINEERING)
    bad = tmp_path / "bad.png"
    r = run_cli(["render", two_crs["utm"], site, "-o", bad, "--camera", cam, "--size", "160x120"])
    assert_clean_refusal(r, "site_cli")
    assert not bad.exists()


def _without_crs(src: Path, dst: Path, local: bool) -> Path:
    """A copy as another tool would write it: no citylod CRS (so 3D Tiles' ECEF), placed on the globe by
    its root transform, or (``local``) left in a local frame with no transform at all."""
    shutil.copytree(src, dst)
    doc = json.loads((dst / "tileset.json").read_text())
    del doc["extras"]["citylod"]
    if local:
        del doc["root"]["transform"]
    (dst / "tileset.json").write_text(json.dumps(doc))
    return dst


def test_ecef_tileset_is_reprojected_in_3d(two_crs: dict[str, Path]) -> None:
    """A tileset without a CRS of its own is ECEF (EPSG:4978): next to the UTM layer it is transformed in 3D
    (geocentric → easting, northing, ellipsoidal height) and its vertices land on the UTM layer's within the
    ECEF placement's approximation (a tangent frame at the origin, millimetres over 64 m)."""
    ecef = _without_crs(two_crs["utm"], two_crs["dir"] / "ecef", local=False)
    with Scene() as scene:
        utm = scene.add(two_crs["utm"])
        layer = scene.add(ecef)
        assert layer.reprojection is not None and layer.reprojection.use_z
        assert "EPSG:4978 reprojected on the fly to EPSG:32632" in layer.reprojection.label
        for key in ("0", "0/1"):
            a, _ = _load_node(utm.node(f"0:{key}"))
            node = layer.node(f"1:{key}")
            b, _ = _load_node(node)
            wa = a.meshes[0].positions.astype(np.float64) @ utm.node(f"0:{key}").matrix[:3, :3].T \
                + utm.node(f"0:{key}").matrix[:3, 3]
            wb = b.meshes[0].positions.astype(np.float64) + node.matrix[:3, 3]
            assert np.abs(wa - wb).max() < 0.02, np.abs(wa - wb).max(axis=0)
            lo, hi = node.box.bounds()
            assert (wb >= lo).all() and (wb <= hi).all()


def test_tileset_in_a_local_frame_is_refused(two_crs: dict[str, Path]) -> None:
    local = _without_crs(two_crs["utm"], two_crs["dir"] / "local", local=True)
    with Scene() as scene:
        scene.add(two_crs["utm"])
        with pytest.raises(CitylodError, match="local.*without a CRS"):
            scene.add(local)
    with Scene() as scene:  # and the other way round: a UTM layer next to a local one
        scene.add(local)
        with pytest.raises(CitylodError, match="in a scene without one"):
            scene.add(two_crs["utm"])


def test_heights_are_transformed_only_where_both_crs_state_them() -> None:
    pairs = {("EPSG:32632", "EPSG:3035"): False, ("EPSG:7415", "EPSG:28992"): False,
             ("EPSG:7415", "EPSG:25831+5783"): True, ("EPSG:32632", "EPSG:4978"): True}
    for (src, dst), use_z in pairs.items():
        rep = reprojection_for(pyproj.CRS(src), pyproj.CRS(dst), "test")
        assert rep is not None and rep.use_z is use_z, (src, dst)


def test_reprojected_point_cloud_lands_on_the_original_points(tmp_path: Path) -> None:
    """The sample's LiDAR (UTM 32N) rewritten in EPSG:3035 (LAS scale 1 mm) and built: drawn in the UTM scene,
    every point of every tile is within 2 mm of an original point and inside its tile's box."""
    import laspy
    from scipy.spatial import cKDTree

    from citylod.lod.build.points import build_points

    info = make_sample(tmp_path / "sample", size=65)
    las = laspy.read(info.files["points"])
    x, y = pyproj.Transformer.from_crs(32632, 3035, always_xy=True).transform(np.asarray(las.x), np.asarray(las.y))
    header = laspy.LasHeader(point_format=las.header.point_format, version=las.header.version)
    header.offsets = [np.floor(x.min()), np.floor(y.min()), las.header.offsets[2]]
    header.scales = [0.001, 0.001, las.header.scales[2]]
    header.add_crs(pyproj.CRS(3035))
    warped = laspy.LasData(header)
    warped.points = laspy.ScaleAwarePointRecord.zeros(len(las.points), header=header)
    warped.x, warped.y, warped.z = x, y, np.asarray(las.z)
    for dim in las.point_format.dimension_names:
        if dim not in ("X", "Y", "Z"):
            warped[dim] = las[dim]
    warped.write(tmp_path / "points3035.laz")
    with pytest.warns(UserWarning, match="no vertical datum"):
        build_points([info.files["points"]], tmp_path / "utm", workers=0, progress=False)
        build_points([tmp_path / "points3035.laz"], tmp_path / "laea", workers=0, progress=False)
    tree = cKDTree(np.c_[las.x, las.y, las.z])
    with Scene() as scene:
        scene.add(tmp_path / "utm")
        layer = scene.add(tmp_path / "laea")
        assert layer.kind == "points" and layer.reprojection is not None
        drawn = 0
        for node in layer._nodes.values():
            if node.content_uri is None:
                continue
            prepared, _ = _load_node(node)
            assert prepared.points is not None
            world = prepared.points.positions.astype(np.float64) + node.matrix[:3, 3]
            lo, hi = node.box.bounds()
            assert (world >= lo).all() and (world <= hi).all(), node.key
            dist, _ = tree.query(world)
            assert dist.max() < 0.002, (node.key, float(dist.max()))
            drawn += len(world)
        assert drawn >= len(las.points)
