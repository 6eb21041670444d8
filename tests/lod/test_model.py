"""City models from a DSM: shapes, shape map, constrained simplification, outputs, hard cases.

The certified bound is checked by independent computations: citylod's DSM certifier
(``lod.kernels.certify``, its own overlay walk) and pymeshlab's sampled Hausdorff distance, never by the
collapse kernel's own error test. Scenes are small analytic grids whose planes are known.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from citylod.lod.build.model import ShapeParams, build_model, detect_shapes, extract_buildings, simplify_grid
from citylod.lod.kernels.certify import certify
from citylod.lod.kernels.collapse import grid_triangles
from citylod.lod.kernels.hausdorff import certify_hausdorff

D = 0.5  # sample spacing, metres


def _scene(n: int = 96) -> tuple[np.ndarray, np.ndarray, dict]:
    """A gable house (ridge along columns), a flat block with a courtyard, a tree touching the block, a
    one-sample spike and a no-data hole on gently sloping ground. Row 0 is north; x = col·D, y = -row·D."""
    r, c = np.mgrid[0:n, 0:n].astype(float)
    F = 10.0 + 0.02 * c * D
    truth: dict = {}
    # gable house: rows 8..27, cols 8..43, ridge at row 17.5, eave 16 m, ridge 19 m
    house = (r >= 8) & (r <= 27) & (c >= 8) & (c <= 43)
    roof = 19.0 - 3.0 * np.abs(r - 17.5) / 10.0
    F = np.where(house, roof, F)
    truth["house"] = house
    # flat block with a courtyard: rows 40..79, cols 10..49, courtyard rows 52..67, cols 22..37, 12 m
    block = (r >= 40) & (r <= 79) & (c >= 10) & (c <= 49) & ~((r >= 52) & (r <= 67) & (c >= 22) & (c <= 37))
    F = np.where(block, 22.0, F)
    truth["block"] = block
    # a tree crown (a cap of radius 5 m) touching the block's east wall
    tr = np.hypot((r - 60) * D, (c - 55) * D)
    crown = 10.0 + 0.02 * c * D + 9.0 * np.sqrt(np.clip(1 - (tr / 5.0) ** 2, 0, None))
    F = np.where((tr < 5.0) & ~block, np.maximum(F, crown), F)
    truth["tree"] = (tr < 5.0) & ~block
    # a one-sample spike on the ground and a no-data hole
    F[88, 80] += 15.0
    V = np.ones_like(F, bool)
    V[30:36, 70:78] = False
    return F, V, truth


@pytest.fixture(scope="module")
def scene():
    return _scene()


@pytest.fixture(scope="module")
def model(scene):
    F, V, _ = scene
    return simplify_grid(F, V, D, D, 0.3)


def _read(F, V):
    def read_block(r0, c0, nr, nc):
        return (np.ascontiguousarray(F[r0:r0 + nr, c0:c0 + nc]), np.ascontiguousarray(V[r0:r0 + nr, c0:c0 + nc]))
    return read_block


def test_certified_bound_holds_by_independent_checks(scene, model) -> None:
    F, V, _ = scene
    H, W = F.shape
    faces = model.faces
    assert len(faces) < 0.25 * len(grid_triangles(V))
    vr, vc = np.divmod(np.arange(H * W), W)
    # the DSM tile tree's 3D Hausdorff certifier (its own overlay and candidate search) bounds it by ε
    err, _, _ = certify_hausdorff(_read(F, V), (0, 0, H - 1, W - 1), vr.astype(float), vc.astype(float),
                                  F.reshape(-1), faces, (1, 1), 1, (D, 0.0, 0.0, -D), per_cell=False)
    assert err <= 0.3 + 1e-9
    # the vertical distance is not what is bounded: walls between samples are cut (that is what pays)
    verr, _, _ = certify(_read(F, V), (0, 0, H - 1, W - 1), vr.astype(float), vc.astype(float), F.reshape(-1),
                         faces, (1, 1), 1, per_cell=False)
    assert verr > 0.3
    # with metric="vertical" the vertical certifier's bound holds, at more triangles
    vert = simplify_grid(F, V, D, D, 0.3, metric="vertical")
    verr2, _, _ = certify(_read(F, V), (0, 0, H - 1, W - 1), vr.astype(float), vc.astype(float), F.reshape(-1),
                          vert.faces, (1, 1), 1, per_cell=False)
    assert verr2 <= 0.3 + 1e-9 and len(vert.faces) > len(faces)
    # no triangle covers the no-data hole: its samples are no vertex and lie in no triangle's box interior
    ids = np.unique(faces)
    assert not np.isin(ids, np.flatnonzero(~V.reshape(-1))).any()
    # pymeshlab's sampled Hausdorff distance to the full grid surface is below the vertical bound
    import pymeshlab

    pos = np.column_stack([vc * D, -vr * D, F.reshape(-1)])
    g = grid_triangles(V)
    ms = pymeshlab.MeshSet()
    for f in (faces, g):  # each mesh with only the vertices it uses (the no-data samples are in neither)
        used, inv = np.unique(f, return_inverse=True)
        ms.add_mesh(pymeshlab.Mesh(pos[used], inv.reshape(-1, 3).astype(np.int32)))
    for a, b in ((0, 1), (1, 0)):
        hd = ms.get_hausdorff_distance(sampledmesh=a, targetmesh=b, samplevert=True, sampleedge=True,
                                       sampleface=True, samplenum=50_000)["max"]
        assert hd <= 0.3 * (1 + 1e-6)


def test_roof_planes_match_the_analytic_roof(scene) -> None:
    F, V, truth = scene
    sh = detect_shapes(F, V, D, D)
    lab = sh.roof_label
    # the two gable faces are found as two planes whose normals match the truth within 2 degrees
    north = lab[(np.arange(96)[:, None] >= 9) & (np.arange(96)[:, None] <= 16) & truth["house"]]
    south = lab[(np.arange(96)[:, None] >= 19) & (np.arange(96)[:, None] <= 26) & truth["house"]]
    kn = np.bincount(north[north >= 0]).argmax()
    ks = np.bincount(south[south >= 0]).argmax()
    assert kn != ks
    slope = 3.0 / (10.0 * D)  # rise per metre across the ridge
    for k, sign in ((kn, 1.0), (ks, -1.0)):  # north face rises southwards: dz/dy_north < 0
        n = sh.roof_planes[k, :3]
        expect = np.array([0.0, sign * slope, 1.0]) / math.hypot(slope, 1.0)
        assert math.degrees(math.acos(min(1.0, float(n @ expect)))) < 2.0
    # ridge samples carry both planes (edge vertices); eave corners carry roof and two façades (corners)
    S = sh.shape_map.reshape(96, 96, -1)
    ridge = [(17, cc) for cc in range(12, 40)] + [(18, cc) for cc in range(12, 40)]
    both = [set(S[rr, cc]) >= {kn, ks} for rr, cc in ridge]
    assert np.mean(both) > 0.9
    corner_ids = (S[8, 8] >= 0).sum()
    assert corner_ids >= 3


def test_constrained_collapse_keeps_ridge_and_courtyard(scene, model) -> None:
    F, V, _truth = scene
    W = F.shape[1]
    ids = set(np.unique(model.faces).tolist())
    # the ridge (rows 17/18) is still there: the mesh has vertices on it at both ends of the house
    on_ridge = [cc for cc in range(8, 44) if (17 * W + cc) in ids or (18 * W + cc) in ids]
    assert min(on_ridge) <= 9 and max(on_ridge) >= 42
    # planar roofs collapse to a few triangles each: the gable house's two faces, the courtyard block's ring
    r, c = np.divmod(model.faces, W)
    z = F.reshape(-1)[model.faces]
    for name, eave, most in (("house", 15.5, 12), ("block", 21.5, 20)):
        on_roof = _truth[name][r, c].all(axis=1) & (z > eave).all(axis=1)
        assert 2 <= on_roof.sum() <= most, (name, on_roof.sum())
    # without shapes the same bound gives fewer triangles (the constraints cost triangles, not accuracy)
    plain = simplify_grid(F, V, D, D, 0.3, constrained=False)
    assert len(plain.faces) <= len(model.faces)


def test_buildings_courtyard_tree_and_spike(scene) -> None:
    F, V, truth = scene
    sh = detect_shapes(F, V, D, D)
    ground = 10.0 + 0.02 * np.mgrid[0:96, 0:96][1] * D
    fps = extract_buildings(F, V, (D, 0.0, 0.0, 0.0, -D, 0.0), D, sh.roof_label, sh.roof_planes, ground=ground)
    areas = sorted(round(fp.polygon.area) for fp in fps)
    # two buildings: the tree crown is cut off the block, the spike is too small, the hole is no building
    assert len(fps) == 2, areas
    block = max(fps, key=lambda f: f.polygon.area)
    true_area = truth["block"].sum() * D * D
    assert abs(block.polygon.area - true_area) / true_area < 0.1
    assert len(block.polygon.interiors) == 1  # the courtyard
    assert abs(block.height - 12.0) < 0.5
    house = min(fps, key=lambda f: f.polygon.area)
    assert len(house.roof_planes) >= 2


def _write_tif(path: Path, F: np.ndarray, V: np.ndarray, crs: str, transform) -> Path:
    import rasterio

    data = np.where(V, F, -9999.0).astype(np.float32)
    with rasterio.open(path, "w", driver="GTiff", width=F.shape[1], height=F.shape[0], count=1, dtype="float32",
                       crs=crs, transform=transform, nodata=-9999.0) as ds:
        ds.write(data, 1)
    return path


@pytest.mark.parametrize("geographic", [False, True])
def test_build_model_writes_tiles_and_cityjson_read_back(tmp_path: Path, scene, geographic: bool) -> None:
    from affine import Affine

    from citylod.io.city.read import read_city_model
    from citylod.io.tiles3d.tileset import open_tileset

    F, V, _ = scene
    if geographic:  # about 0.5 m at 49° N
        tr = Affine(0.5 / 73000.0, 0, 8.4, 0, -0.5 / 111200.0, 49.0)
        dsm = _write_tif(tmp_path / "deg.tif", F, V, "EPSG:4326", tr)
    else:
        dsm = _write_tif(tmp_path / "m.tif", F, V, "EPSG:32632", Affine(D, 0, 512000.0, 0, -D, 5403000.0))
    ortho = None
    if not geographic:  # an orthophoto whose red channel is the column: the texture must follow x
        import rasterio

        rgb = np.zeros((3, 96, 96), np.uint8)
        rgb[0] = (np.arange(96) * 2.5).astype(np.uint8)[None, :]
        ortho = tmp_path / "ortho.tif"
        with rasterio.open(ortho, "w", driver="GTiff", width=96, height=96, count=3, dtype="uint8", crs="EPSG:32632",
                           transform=Affine(D, 0, 512000.0, 0, -D, 5403000.0)) as ds:
            ds.write(rgb)
    rep = build_model(dsm, tmp_path / "out", max_error=0.3, cell=48, workers=0, progress=False, ortho=ortho)
    assert rep.cells == 4 and rep.triangles < rep.grid_triangles / 4
    ts = open_tileset(tmp_path / "out")
    assert len(ts.root.children) == 4
    doc = json.loads((tmp_path / "out" / "buildings.city.json").read_text())
    assert len(doc["CityObjects"]) >= 2
    model = read_city_model(tmp_path / "out" / "buildings.city.json")
    heights = sorted(o.attributes["measuredHeight"] for o in model.objects)
    assert any(abs(h - 12.0) < 0.7 for h in heights)
    if geographic:  # positions projected to the UTM zone: metres, not degrees
        assert ts.root.children[0].box.center[0] > 1000.0
    else:
        # no cracks: neighbouring cells have the same vertices on the row/column they share (locked)
        tiles = {t.content_path.stem: t.load().vertices for t in ts.root.children}
        xb = 512000.0 + (48 + 0.5) * D
        yb = 5403000.0 - (48 + 0.5) * D
        for a, b, axis, val in (("0_0", "0_1", 0, xb), ("0_0", "1_0", 1, yb)):
            ea = {round(float(v), 3) for v in tiles[a][np.abs(tiles[a][:, axis] - val) < 1e-3][:, 1 - axis]}
            eb = {round(float(v), 3) for v in tiles[b][np.abs(tiles[b][:, axis] - val) < 1e-3][:, 1 - axis]}
            assert len(ea) > 40 and ea == eb
        # textured: the red of the texel under each vertex grows with its x like the orthophoto's
        from citylod.io.image import decode_image

        t = ts.root.children[0]
        mesh = t.load_content().meshes[0]
        img = decode_image(mesh.texture)
        px = np.clip((mesh.uv * (np.array(img.shape[1::-1]) - 1)).round().astype(int), 0, img.shape[0] - 1)
        red = img[px[:, 1], px[:, 0], 0].astype(float)
        xw = t.load().vertices[:, 0]
        assert np.corrcoef(red, xw)[0, 1] > 0.95
        # the command line reads the buildings back into a semantic store
        from citylod.cli import main

        assert main(["-q", "build", "city", str(tmp_path / "out" / "buildings.city.json"), "-o",
                     str(tmp_path / "city.gpkg")]) == 0
        assert (tmp_path / "city.gpkg").stat().st_size > 0


def test_build_model_bad_input(tmp_path: Path) -> None:
    from citylod.cli import main

    bad = tmp_path / "bad.tif"
    bad.write_bytes(b"not a raster")
    assert main(["-q", "build", "model", str(bad), "-o", str(tmp_path / "o")]) == 2
    assert not (tmp_path / "o").exists()
    F, V, _ = _scene()
    from affine import Affine

    empty = _write_tif(tmp_path / "empty.tif", F, np.zeros_like(V), "EPSG:32632", Affine(D, 0, 0, 0, -D, 0))
    assert main(["-q", "build", "model", str(empty), "-o", str(tmp_path / "o")]) == 2
    assert not (tmp_path / "o").exists()


def test_sample_city_ridges_and_eaves_kept() -> None:
    from citylod.bench.model_bench import kept_fraction
    from citylod.sample.city import make_city

    city = make_city(257, seed=7, spacing=0.5)
    x, y = city.pixel_centers()
    F = city.surface_height(x, y)
    V = ~city.nodata_mask(x, y)
    m = simplify_grid(np.where(V, F, 0.0), V, D, D, 1.0, params=ShapeParams())
    ids, inv = np.unique(m.faces, return_inverse=True)
    pos = np.column_stack([x.reshape(-1)[ids], y.reshape(-1)[ids], F.reshape(-1)[ids]])
    frac, n = kept_fraction(city, pos, inv.reshape(-1, 3))
    assert n >= 4 and frac >= 0.95
    # the bound holds by the tile tree's independent 3D certifier, rotated walls and all
    H, W = F.shape
    vr, vc = np.divmod(np.arange(H * W), W)
    err, _, _ = certify_hausdorff(_read(np.where(V, F, 0.0), V), (0, 0, H - 1, W - 1), vr.astype(float),
                                  vc.astype(float), np.where(V, F, 0.0).reshape(-1), m.faces, (1, 1), 1,
                                  (D, 0.0, 0.0, -D), per_cell=False)
    assert err <= 1.0 + 1e-9
    # pymeshlab's quadric edge collapse at the same triangle count loses ridges or eaves on more buildings
    from citylod.bench.model_bench import pymeshlab_decimate

    g = grid_triangles(V)
    gids, ginv = np.unique(g, return_inverse=True)
    gpos = np.column_stack([x.reshape(-1)[gids], y.reshape(-1)[gids], F.reshape(-1)[gids]])
    ppos, pfaces = pymeshlab_decimate(gpos, ginv.reshape(-1, 3), len(m.faces))
    pfrac, _ = kept_fraction(city, ppos, pfaces)
    assert pfrac < frac


def _terrace() -> tuple[np.ndarray, np.ndarray]:
    """Four houses in a row on flat ground at 0 m (rows 10..29): three gables 8 m wide whose ridges run
    across the row (valleys between them), then a flat roof 3 m higher than their eaves (a step)."""
    n_r, n_c = 40, 80
    r, c = np.mgrid[0:n_r, 0:n_c].astype(float)
    F = np.zeros((n_r, n_c))
    row = (r >= 10) & (r <= 29)
    for k in range(3):
        c0 = 8 + 16 * k  # 16 samples = 8 m per house
        house = row & (c >= c0) & (c < c0 + 16)
        F = np.where(house, 8.0 + 3.0 * (1 - np.abs(c - (c0 + 7.5)) / 8.0), F)
    F = np.where(row & (c >= 56) & (c < 72), 11.0, F)
    return F, np.ones_like(F, bool)


def test_terraced_houses_come_apart_at_valleys_and_steps() -> None:
    F, V = _terrace()
    sh = detect_shapes(F, V, D, D)
    ground = np.zeros_like(F)
    classes = np.where(F > 1.0, 6.0, 2.0)
    fps = extract_buildings(F, V, (D, 0.0, 0.0, 0.0, -D, 0.0), D, sh.roof_label, sh.roof_planes, ground=ground,
                            classes=classes)
    xs = sorted(round(fp.polygon.centroid.x / D) for fp in fps)
    # four buildings, one per house: each gable's two faces are joined at its ridge (convex), the houses are
    # cut at the valleys between gables and at the step to the flat roof
    assert len(fps) == 4, xs
    assert all(abs(x - e) <= 2 for x, e in zip(xs, (16, 32, 48, 64), strict=True)), xs
    for fp in fps:
        assert abs(fp.polygon.area - 8.0 * 10.0) / 80.0 < 0.15
    flat = max(fps, key=lambda f: f.polygon.centroid.x)
    assert abs(flat.height - 11.0) < 0.3
    # without the roof split (one plane map of nothing) the row is one building
    none = extract_buildings(F, V, (D, 0.0, 0.0, 0.0, -D, 0.0), D, None, None, ground=ground, classes=classes)
    assert len(none) == 1


def test_low_annex_and_shed_are_buildings_of_their_own() -> None:
    """A gable house (rows 10..29, cols 10..29: 10 m square, eaves 6 m, ridge 9 m), a flat garage 3 m high
    touching its east wall (rows 12..16, cols 30..35: 2.5 × 3 m, too small for a roof plane), and a free
    standing shed 2.5 m high (rows 34..38, cols 50..54: 6.25 m²), all building points (class 6). The garage
    stands 3 m below the house's eave, so it is not the house's wall or chimney: a building of its own (the
    code before joined every sample on no plane to the nearest plane's building); the shed is under 12 m²
    but carries building points, so it is kept."""
    r, c = np.mgrid[0:48, 0:64].astype(float)
    F = np.zeros_like(r)
    house = (r >= 10) & (r <= 29) & (c >= 10) & (c <= 29)
    F = np.where(house, 6.0 + 3.0 * (1 - np.abs(r - 19.5) / 10.0), F)
    garage = (r >= 12) & (r <= 16) & (c >= 30) & (c <= 35)
    shed = (r >= 34) & (r <= 38) & (c >= 50) & (c <= 54)
    F = np.where(garage, 3.0, np.where(shed, 2.5, F))
    V = np.ones_like(F, bool)
    sh = detect_shapes(F, V, D, D)
    classes = np.where(F > 1.0, 6.0, 2.0)
    fps = extract_buildings(F, V, (D, 0.0, 0.0, 0.0, -D, 0.0), D, sh.roof_label, sh.roof_planes,
                            ground=np.zeros_like(F), classes=classes, min_area=5.0)
    got = sorted((round(fp.polygon.area, 1), round(fp.height, 1)) for fp in fps)
    assert len(fps) == 3, got
    (a_shed, h_shed), (a_garage, h_garage), (a_house, h_house) = got
    assert abs(a_shed - 6.25) < 2.0 and abs(h_shed - 2.5) < 0.2, got
    assert abs(a_garage - 7.5) < 2.5 and abs(h_garage - 3.0) < 0.2, got
    assert abs(a_house - 100.0) < 12.0 and abs(h_house - 8.7) < 0.5, got


def test_lower_back_half_joins_its_house() -> None:
    """A gable house (rows 10..29, cols 10..29, eaves 6 m, ridge 9 m) with a flat back half 3.5 m high along
    its whole south side (rows 30..37): the roof split cuts it off at the 2.5 m step, and as it shares a third
    of its outline with the house it is joined back (one building, as a cadastre counts it). With
    ``annex_share=0`` the two stay apart; so they did before the annex rule."""
    r, c = np.mgrid[0:48, 0:40].astype(float)
    F = np.zeros_like(r)
    house = (r >= 10) & (r <= 29) & (c >= 10) & (c <= 29)
    F = np.where(house, 6.0 + 3.0 * (1 - np.abs(r - 19.5) / 10.0), F)
    back = (r >= 30) & (r <= 37) & (c >= 10) & (c <= 29)
    F = np.where(back, 3.5, F)
    V = np.ones_like(F, bool)
    sh = detect_shapes(F, V, D, D)
    args = (F, V, (D, 0.0, 0.0, 0.0, -D, 0.0), D, sh.roof_label, sh.roof_planes)
    kw = {"ground": np.zeros_like(F), "classes": np.where(F > 1.0, 6.0, 2.0)}
    one = extract_buildings(*args, **kw)
    assert len(one) == 1, [round(fp.polygon.area) for fp in one]
    assert abs(one[0].polygon.area - 140.0) < 12.0 and abs(one[0].height - 8.7) < 0.5
    two = extract_buildings(*args, **kw, annex_share=0.0)
    assert sorted(round(fp.polygon.area) for fp in two) == pytest.approx([40, 100], abs=8)


def test_tree_over_a_roof_with_point_classes() -> None:
    """A flat house 8 m high (rows 10..29, cols 10..29) and a tree crown of radius 4 m, 12 m high, whose
    centre stands just outside its north-east corner, with the classes a LAZ gives (6 roof, 1 crown, 2
    ground): one building, no larger than the house, its height the roof's and not the crown's."""
    r, c = np.mgrid[0:48, 0:48].astype(float)
    house = (r >= 10) & (r <= 29) & (c >= 10) & (c <= 29)
    F = np.where(house, 8.0, 0.0)
    crown = np.hypot((r - 8) * D, (c - 31) * D) < 4.0
    cap = 12.0 - 4.0 * (np.hypot((r - 8) * D, (c - 31) * D) / 4.0) ** 2
    F = np.where(crown, np.maximum(F, cap), F)
    classes = np.where(crown & (cap >= F - 1e-9), 1.0, np.where(house, 6.0, 2.0))
    V = np.ones_like(F, bool)
    sh = detect_shapes(F, V, D, D)
    fps = extract_buildings(F, V, (D, 0.0, 0.0, 0.0, -D, 0.0), D, sh.roof_label, sh.roof_planes,
                            ground=np.zeros_like(F), classes=classes)
    assert len(fps) == 1, [round(fp.polygon.area) for fp in fps]
    assert 80.0 <= fps[0].polygon.area <= 100.0 + 2.0
    assert abs(fps[0].height - 8.0) < 0.2


def test_rasterize_las_writes_ground_and_class_bands(tmp_path: Path) -> None:
    import laspy
    import rasterio

    from citylod.lod.build.model import rasterize_las

    rng = np.random.default_rng(3)
    # ground at 1 m (class 2) on a 20 m square, a 6 m box of roof points at 9 m (class 6), a noise point (7)
    gx, gy = rng.uniform(0, 20, 4000), rng.uniform(0, 20, 4000)
    inside = (gx > 7) & (gx < 13) & (gy > 7) & (gy < 13)
    gz = np.where(inside, 9.0, 1.0)
    cls = np.where(inside, 6, 2).astype(np.uint8)
    x = np.concatenate([gx, [10.0]]) + 85000.0
    y = np.concatenate([gy, [10.0]]) + 447000.0
    z = np.concatenate([gz, [50.0]])
    cls = np.concatenate([cls, [7]]).astype(np.uint8)
    hdr = laspy.LasHeader(point_format=1, version="1.2")
    hdr.scales = np.array([0.001, 0.001, 0.001])
    hdr.offsets = np.array([85000.0, 447000.0, 0.0])
    las = laspy.LasData(hdr)
    las.x, las.y, las.z, las.classification = x, y, z, cls
    las.write(tmp_path / "p.las")
    tif = rasterize_las([tmp_path / "p.las"], tmp_path / "dsm.tif", spacing=1.0, crs="EPSG:28992")
    with rasterio.open(tif) as ds:
        assert ds.descriptions == ("dsm", "ground", "class")
        dsm, ground, klass = ds.read(1), ds.read(2), ds.read(3)
    assert dsm.max() < 10.0  # the noise point is dropped
    centre = (slice(9, 12), slice(9, 12))
    assert np.all(klass[centre] == 6) and np.allclose(dsm[centre], 9.0)
    # the ground under the roof is filled from the ground around it, not taken from the roof
    assert np.allclose(ground[centre], 1.0, atol=0.01)
    assert np.all(klass[0:3, 0:3] == 2)
