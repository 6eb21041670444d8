"""Flood extent, depth, area and volume against an independent flood fill; affected buildings against shapely;
bad input through the real command line.

The reference is a breadth-first flood fill written here in plain Python (a queue over cells), independent of
scipy's labelling and of the strip merging that the code under test uses; areas on the ellipsoid come from
pyproj's geodesic polygon areas (GeographicLib), independent of the closed-form band areas in the code.
"""

from __future__ import annotations

import csv
import json
import sqlite3
from collections import deque
from pathlib import Path

import numpy as np
import pyproj
import pytest
import rasterio
import shapely
from affine import Affine

from citylod.analysis.flood import DEPTH_NODATA, FloodModel, FloodSources, flood_raster
from citylod.analysis.polygons import EditPolygon, PolygonLayer, save_polygons
from citylod.cli import main

UTM = "EPSG:32632"
X0, Y0 = 500_000.0, 5_400_000.0


def write_raster(path: Path, h: np.ndarray, *, crs: str = UTM, transform: Affine | None = None,
                 nodata: float | None = -9999.0) -> Path:
    t = transform or Affine(1.0, 0, X0, 0, -1.0, Y0)
    with rasterio.open(path, "w", driver="GTiff", width=h.shape[1], height=h.shape[0], count=1,
                       dtype="float32", crs=crs, transform=t, nodata=nodata) as ds:
        ds.write(h.astype(np.float32), 1)
    return path


def bfs_flood(h: np.ndarray, valid: np.ndarray, seeds: list[tuple[int, int]], level: float,
              eight: bool = False) -> np.ndarray:
    """Reference: cells reached from the seeds through valid cells below the level (plain BFS)."""
    rows, cols = h.shape
    wet = np.zeros(h.shape, bool)
    steps = [(-1, 0), (1, 0), (0, -1), (0, 1)] + ([(-1, -1), (-1, 1), (1, -1), (1, 1)] if eight else [])
    q = deque()
    for r, c in seeds:
        if valid[r, c] and h[r, c] < level and not wet[r, c]:
            wet[r, c] = True
            q.append((r, c))
    while q:
        r, c = q.popleft()
        for dr, dc in steps:
            rr, cc = r + dr, c + dc
            if 0 <= rr < rows and 0 <= cc < cols and not wet[rr, cc] and valid[rr, cc] and h[rr, cc] < level:
                wet[rr, cc] = True
                q.append((rr, cc))
    return wet


def read_depth(path: Path) -> np.ndarray:
    with rasterio.open(path) as ds:
        d = ds.read(1)
        assert ds.nodata == DEPTH_NODATA
    return d


def cell_xy(r: int, c: int) -> tuple[float, float]:
    return X0 + c + 0.5, Y0 - r - 0.5


def edge_cells(shape: tuple[int, int]) -> list[tuple[int, int]]:
    rows, cols = shape
    return [(r, c) for r in range(rows) for c in range(cols) if r in (0, rows - 1) or c in (0, cols - 1)]


def run_flood(tmp_path: Path, h: np.ndarray, levels: list[float], **kw) -> tuple[list[np.ndarray], object]:
    tmp_path.mkdir(parents=True, exist_ok=True)
    raster = write_raster(tmp_path / "dsm.tif", np.where(np.isnan(h), -9999.0, h))
    out = tmp_path / "out"
    rep = flood_raster(raster, levels, out, **kw)
    return [read_depth(out / r.depth_file) for r in rep.levels], rep


def check_against_reference(depths: list[np.ndarray], h: np.ndarray, levels: list[float],
                            seeds: list[tuple[int, int]], eight: bool = False) -> None:
    valid = ~np.isnan(h)
    for d, level in zip(depths, levels, strict=True):
        ref = bfs_flood(np.nan_to_num(h), valid, seeds, level, eight)
        got = d != DEPTH_NODATA
        assert np.array_equal(got, ref), f"level {level}: {np.argwhere(got != ref)[:5]}"
        np.testing.assert_allclose(d[ref], (level - h)[ref], atol=1e-5)


def dyke(breach: bool) -> np.ndarray:
    h = np.zeros((12, 20))
    h[:, 10] = 5.0  # a dyke across the raster
    if breach:
        h[6, 10] = 0.5  # one cell wide
    return h


@pytest.mark.parametrize("breach", [False, True])
def test_dyke_holds_and_one_cell_breach_floods(tmp_path: Path, breach: bool) -> None:
    h = dyke(breach)
    seeds = [(3, 2)]
    levels = [1.0, 4.9, 5.5]
    depths, _ = run_flood(tmp_path, h, levels, sources=FloodSources(seeds_xy=(cell_xy(*seeds[0]),)))
    check_against_reference(depths, h, levels, seeds)
    behind = depths[1][:, 11:] != DEPTH_NODATA
    assert behind.all() if breach else not behind.any()
    assert (depths[2] != DEPTH_NODATA).sum() == 12 * 19 + 12  # over the dyke at 5.5: everything


def test_diagonal_dyke_holds_under_four_connectivity_only(tmp_path: Path) -> None:
    h = np.zeros((15, 15))
    for i in range(15):
        h[i, 14 - i] = 5.0  # a dyke one cell thick along the anti-diagonal
    seeds = [(0, 0)]
    for eight in (False, True):
        depths, _ = run_flood(tmp_path / str(eight), h, [1.0], sources=FloodSources(seeds_xy=(cell_xy(0, 0),)),
                              eight=eight)
        check_against_reference(depths, h, [1.0], seeds, eight)
        assert (depths[0][14, 14] != DEPTH_NODATA) == eight


def test_enclosed_depression_stays_dry_unless_flagged(tmp_path: Path) -> None:
    h = np.full((16, 16), 2.0)
    h[:, :4] = 0.0  # the sea on the left
    h[6:11, 8:13] = 3.0  # a ring wall
    h[7:10, 9:12] = -1.0  # the pit it encloses, lower than the sea
    seeds = [(0, 0)]
    depths, _ = run_flood(tmp_path / "a", h, [1.0, 2.5], sources=FloodSources(seeds_xy=(cell_xy(0, 0),)))
    check_against_reference(depths, h, [1.0, 2.5], seeds)
    assert (depths[1][7:10, 9:12] == DEPTH_NODATA).all()  # 2.5: the land floods, the pit behind its wall not
    flagged, _ = run_flood(tmp_path / "b", h, [1.0], sources=FloodSources(), depressions=True)
    np.testing.assert_allclose(flagged[0][7:10, 9:12], 2.0)
    assert (flagged[0][:, :4] == 1.0).all()


def test_nodata_holes_are_neither_wet_nor_passable(tmp_path: Path) -> None:
    h = np.zeros((10, 14))
    h[:, 7] = np.nan  # a no-data column cuts the basin in two
    h[2:4, 2:4] = np.nan
    seeds = [(0, 0)]
    depths, _ = run_flood(tmp_path, h, [1.0], sources=FloodSources(seeds_xy=(cell_xy(0, 0),)))
    check_against_reference(depths, h, [1.0], seeds)
    assert (depths[0][:, 8:] == DEPTH_NODATA).all() and (depths[0][2:4, 2:4] == DEPTH_NODATA).all()


@pytest.mark.parametrize("eight", [False, True])
def test_random_terrain_in_thin_strips_matches_reference(tmp_path: Path, eight: bool) -> None:
    """Strips of 5 rows: components cross many seams, so the seam merging is what is tested."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(3)
    h = gaussian_filter(rng.normal(size=(61, 47)), 2.0) * 20.0
    h[rng.random(h.shape) < 0.03] = np.nan
    levels = [float(np.nanpercentile(h, p)) for p in (30, 50, 70)]
    seeds = edge_cells(h.shape)
    depths, rep = run_flood(tmp_path, h, levels, sources=FloodSources(edge=True), eight=eight, strip_rows=5)
    check_against_reference(depths, h, levels, seeds, eight)
    for d, r, level in zip(depths, rep.levels, levels, strict=True):
        wet = d != DEPTH_NODATA
        assert r.cells == wet.sum()
        assert r.area_m2 == pytest.approx(wet.sum())  # 1 m cells
        assert r.volume_m3 == pytest.approx(float((level - h)[wet].sum()), rel=1e-6)  # float32 depths
    # the same result with the whole raster in one strip and in memory
    whole = FloodModel(np.nan_to_num(h), ~np.isnan(h), np.pad(np.zeros((59, 45), bool), 1, constant_values=True),
                       eight=eight)
    assert np.array_equal(whole.mask(levels[1]), depths[1] != DEPTH_NODATA)


def test_source_polygon_and_level_series_outputs(tmp_path: Path) -> None:
    h = dyke(breach=False)
    river = shapely.box(X0 + 15, Y0 - 12, X0 + 17, Y0)  # a river right of the dyke
    layer = PolygonLayer((EditPolygon(river, "source", name="river"),), pyproj.CRS(UTM))
    depths, _ = run_flood(tmp_path, h, [1.0, 6.0], sources=FloodSources(polygons=layer))
    seeds = [(r, c) for r in range(12) for c in (15, 16)]
    check_against_reference(depths, h, [1.0, 6.0], seeds)
    out = tmp_path / "out"
    rows = list(csv.DictReader(open(out / "levels.csv")))
    assert [float(r["level"]) for r in rows] == [1.0, 6.0]
    assert int(rows[0]["cells"]) == 12 * 9
    assert json.loads((out / "flood.json").read_text())["connectivity"] == 4
    assert not (tmp_path / "out.partial").exists()


def test_raster_in_degrees_area_on_the_ellipsoid(tmp_path: Path) -> None:
    step = 1e-4
    lon0, lat0 = 8.4, 49.02
    h = dyke(breach=False)
    t = Affine(step, 0, lon0, 0, -step, lat0)
    raster = write_raster(tmp_path / "geo.tif", h, crs="EPSG:4326", transform=t)
    seed = (lon0 + 2.5 * step, lat0 - 3.5 * step)
    rep = flood_raster(raster, [1.0], tmp_path / "out", sources=FloodSources(seeds_xy=(seed,)))
    d = read_depth(tmp_path / "out" / rep.levels[0].depth_file)
    ref = bfs_flood(h, np.ones(h.shape, bool), [(3, 2)], 1.0)
    assert np.array_equal(d != DEPTH_NODATA, ref)
    geod = pyproj.Geod(ellps="WGS84")
    area = 0.0
    for r, c in np.argwhere(ref):
        x0, y1 = lon0 + c * step, lat0 - r * step
        x1, y0 = x0 + step, y1 - step
        a, _ = geod.polygon_area_perimeter([x0, x1, x1, x0], [y0, y0, y1, y1])
        area += abs(a)
    assert rep.levels[0].area_m2 == pytest.approx(area, rel=1e-6)
    assert rep.levels[0].volume_m3 == pytest.approx(area * 1.0, rel=1e-6)


def test_coarse_preview_covers_the_full_result() -> None:
    """The block-minimum preview never shows dry what the full result floods."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(5)
    h = gaussian_filter(rng.normal(size=(80, 72)), 3.0) * 30.0
    src = np.zeros(h.shape, bool)
    src[0] = True
    m = FloodModel(h, np.ones(h.shape, bool), src)
    level = float(np.percentile(h, 50))
    full = m.mask(level)
    coarse = np.repeat(np.repeat(m.coarse(level), 4, axis=0), 4, axis=1)[:80, :72]
    assert full.any() and not (full & ~coarse).any()


# -- affected buildings --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def city_flood(sample_city, tmp_path_factory: pytest.TempPathFactory):
    from citylod.semantics.store import build_city

    d = tmp_path_factory.mktemp("flood_city")
    gpkg = build_city(sample_city.files["city"], d / "city.gpkg", progress=False).path
    with rasterio.open(sample_city.files["dsm"]) as ds:
        h = ds.read(1, masked=True)
        level = float(np.percentile(h.compressed(), 40))
    rep = flood_raster(sample_city.files["dsm"], [level], d / "out", sources=FloodSources(edge=True), city=gpkg,
                       touch_m=1.5)
    return rep, gpkg, d / "out"


def test_affected_buildings_match_an_independent_footprint_test(city_flood) -> None:
    from citylod.semantics.store import CityStore

    rep, gpkg, out = city_flood
    with rasterio.open(out / rep.levels[0].depth_file) as ds:
        d = ds.read(1)
        t = ds.transform
    rows, cols = np.nonzero(d != DEPTH_NODATA)
    x0 = t.c + cols * t.a
    y1 = t.f + rows * t.e
    boxes = shapely.box(x0, y1 + t.e, x0 + t.a, y1)
    tree = shapely.STRtree(boxes)
    con = sqlite3.connect(gpkg)
    expected = {}
    for oid, kind in con.execute("SELECT object_id, type FROM city_objects"):
        if kind != "Building":
            continue
        with CityStore.open(gpkg) as store:
            foot = dict(store.footprints())[oid]
        hit = tree.query(foot.buffer(1.5), predicate="intersects")
        if len(hit):
            vals = d[rows[hit], cols[hit]]
            expected[oid] = (float(vals.max()), float(vals.mean()), len(hit))
    got = {a.object_id: (a.max_depth_m, a.mean_depth_m, a.flooded_cells) for a in rep.affected}
    assert expected and set(got) == set(expected)
    for oid, (mx, mean, n) in expected.items():
        assert got[oid][0] == pytest.approx(mx, abs=1e-5)
        assert got[oid][1] == pytest.approx(mean, abs=1e-5)
        assert got[oid][2] == n
    assert rep.buildings_checked > len(got)  # some stay dry: the test can tell them apart
    # the GeoPackage layer and the CSV list the same buildings
    g = sqlite3.connect(out / "affected_buildings.gpkg")
    assert g.execute("PRAGMA application_id").fetchone()[0] == 0x47504B47
    assert {r[0] for r in g.execute("SELECT object_id FROM affected_buildings")} == set(got)
    assert {r["object_id"] for r in csv.DictReader(open(out / "affected_buildings.csv"))} == set(got)


# -- bad input through the command line ----------------------------------------------------------------
def _cli_error(capsys, args: list[str], out: Path) -> str:
    code = main(["-q", *args])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert not out.exists() and not out.with_name(out.name + ".partial").exists()
    return err


def test_bad_input_is_one_line_and_writes_nothing(tmp_path: Path, capsys) -> None:
    h = dyke(breach=False)
    h[0, 0] = np.nan
    raster = write_raster(tmp_path / "dsm.tif", np.nan_to_num(h, nan=-9999.0))
    out = tmp_path / "out"
    base = [str(raster), "-o", str(out)]
    assert "below the raster's lowest height 0" in _cli_error(capsys, ["flood", *base, "--level", "-1", "--edge"], out)
    assert "outside the raster" in _cli_error(capsys, ["flood", *base, "--level", "1", "--seed", "0,0"], out)
    x, y = cell_xy(0, 0)
    assert "no-data" in _cli_error(capsys, ["flood", *base, "--level", "1", "--seed", f"{x},{y}"], out)
    assert "water source" in _cli_error(capsys, ["flood", *base, "--level", "1"], out)
    assert "not a number" in _cli_error(capsys, ["flood", *base, "--levels", "1,nan", "--edge"], out)
    bowtie = shapely.Polygon([(X0, Y0), (X0 + 5, Y0 - 5), (X0 + 5, Y0), (X0, Y0 - 5)])
    gj = tmp_path / "bad.geojson"
    gj.write_text(json.dumps({"type": "FeatureCollection", "crs": {"type": "name", "properties": {"name": UTM}},
                              "features": [{"type": "Feature", "properties": {"name": "bow"},
                                            "geometry": shapely.geometry.mapping(bowtie)}]}))
    err = _cli_error(capsys, ["flood", *base, "--level", "1", "--source", str(gj)], out)
    assert "bad.geojson" in err and "Self-intersection" in err and "'bow'" in err
    gj.write_text(json.dumps({"type": "Feature", "properties": {},
                              "geometry": {"type": "Polygon", "coordinates": []}}))
    assert "is empty" in _cli_error(capsys, ["flood", *base, "--level", "1", "--source", str(gj)], out)
    kml = tmp_path / "bomb.kml"
    kml.write_text('<?xml version="1.0"?>\n<!DOCTYPE kml [<!ENTITY a "aaaaaaaa"><!ENTITY b "&a;&a;&a;">]>\n'
                   '<kml xmlns="http://www.opengis.net/kml/2.2"><Placemark><name>&b;</name></Placemark></kml>')
    assert "entities" in _cli_error(capsys, ["flood", *base, "--level", "1", "--source", str(kml)], out)


def test_cli_writes_results(tmp_path: Path, capsys) -> None:
    raster = write_raster(tmp_path / "dsm.tif", dyke(breach=True))
    x, y = cell_xy(3, 2)
    assert main(["-q", "flood", str(raster), "--levels", "1,2", "--seed", f"{x},{y}", "-o", str(tmp_path / "o")]) == 0
    assert "level 2 m: 229 m² flooded, 458 m³" in capsys.readouterr().out
    assert (tmp_path / "o" / "depth_001.tif").exists()


def test_polygon_layer_round_trips(tmp_path: Path) -> None:
    from citylod.analysis.polygons import load_polygons

    crs = pyproj.CRS(UTM)
    polys = (EditPolygon(shapely.box(X0, Y0, X0 + 30, Y0 + 20), "displace", (10, 20, 30), 2.5, "", "dyke"),
             EditPolygon(shapely.Polygon([(X0 + 50, Y0), (X0 + 80, Y0), (X0 + 60, Y0 + 40)]), "discard", name="cut"))
    layer = PolygonLayer(polys, crs)
    for suffix in (".geojson", ".kml", ".gpkg"):
        back = load_polygons(save_polygons(layer, tmp_path / f"edits{suffix}")).to_crs(crs)
        assert [(p.action, p.color, p.height_m, p.name) for p in back.polygons] == \
            [(p.action, p.color, p.height_m, p.name) for p in polys], suffix
        for a, b in zip(back.polygons, polys, strict=True):
            # KML stores lon/lat: the round trip through WGS 84 is exact to a millimetre
            assert a.geometry.symmetric_difference(b.geometry).area < 0.05, suffix


def test_polygons_as_other_tools_write_them(tmp_path: Path) -> None:
    """KML as Google Earth writes it (lon,lat,alt triples, styles, MultiGeometry, a hole) and GeoJSON as QGIS
    writes it (an OGC URN CRS, null properties)."""
    from citylod.analysis.polygons import load_polygons

    kml = tmp_path / "earth.kml"
    kml.write_text("""<?xml version="1.0" encoding="UTF-8"?>
<kml xmlns="http://www.opengis.net/kml/2.2" xmlns:gx="http://www.google.com/kml/ext/2.2">
<Document><name>edits</name><Style id="s"><PolyStyle><color>7f00ff00</color></PolyStyle></Style>
<Folder><Placemark><name>polder</name><styleUrl>#s</styleUrl>
<ExtendedData><Data name="action"><value>displace</value></Data><Data name="height_m"><value>1.5</value></Data>
</ExtendedData>
<MultiGeometry><Polygon><outerBoundaryIs><LinearRing><coordinates>
 4.35,52.01,0 4.36,52.01,0 4.36,52.02,0 4.35,52.02,0 4.35,52.01,0
</coordinates></LinearRing></outerBoundaryIs><innerBoundaryIs><LinearRing><coordinates>
 4.352,52.012,0 4.354,52.012,0 4.354,52.014,0 4.352,52.012,0</coordinates></LinearRing></innerBoundaryIs>
</Polygon><Polygon><outerBoundaryIs><LinearRing><coordinates>4.37,52.01 4.38,52.01 4.38,52.02 4.37,52.01
</coordinates></LinearRing></outerBoundaryIs></Polygon></MultiGeometry></Placemark></Folder></Document></kml>
""")
    layer = load_polygons(kml)
    (p,) = layer.polygons
    assert p.name == "polder" and p.action == "displace" and p.height_m == 1.5
    assert p.geometry.geom_type == "MultiPolygon" and len(p.geometry.geoms[0].interiors) == 1
    assert layer.crs.to_epsg() == 4326
    gj = tmp_path / "qgis.geojson"
    gj.write_text(json.dumps({
        "type": "FeatureCollection", "name": "edits",
        "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::28992"}},
        "features": [{"type": "Feature", "properties": {"fid": 1, "action": None, "color": None},
                      "geometry": {"type": "MultiPolygon", "coordinates": [[[[85000, 447500], [85010, 447500],
                                                                              [85010, 447510], [85000, 447500]]]]}}]}))
    g = load_polygons(gj)
    assert g.crs.to_epsg() == 28992 and g.polygons[0].action == "recolor"
    assert g.polygons[0].geometry.area == pytest.approx(50.0)


def test_more_bad_input_is_one_line_and_writes_nothing(tmp_path: Path, capsys) -> None:
    """A source polygon that misses the raster, a raster of no-data only, a seed given as one number."""
    raster = write_raster(tmp_path / "dsm.tif", dyke(breach=False))
    out = tmp_path / "out"
    far = PolygonLayer((EditPolygon(shapely.box(X0 + 500, Y0 + 500, X0 + 510, Y0 + 510), "source"),), pyproj.CRS(UTM))
    poly = save_polygons(far, tmp_path / "far.geojson")
    err = _cli_error(capsys, ["flood", str(raster), "-o", str(out), "--level", "1", "--source", str(poly)], out)
    assert "cover no valid cell" in err and "dsm.tif" in err
    empty = write_raster(tmp_path / "empty.tif", np.full((6, 6), -9999.0))
    err = _cli_error(capsys, ["flood", str(empty), "-o", str(out), "--level", "1", "--edge"], out)
    assert "no valid samples" in err and "empty.tif" in err
    with pytest.raises(SystemExit) as stop:  # argparse's usage error
        main(["-q", "flood", str(raster), "-o", str(out), "--level", "1", "--seed", "12"])
    assert stop.value.code == 2
    assert "seed must be X,Y" in capsys.readouterr().err and not out.exists()
