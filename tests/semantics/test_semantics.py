"""Proxies, the GeoPackage store, queries and plugins, feature state, point linking."""

from __future__ import annotations

import sqlite3
import warnings
from importlib.metadata import EntryPoint
from itertools import pairwise
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest
import shapely

from citylod.core.errors import InputError, PluginError
from citylod.io.city.model import CityModel, CityObject
from citylod.io.gpkg import decode_geometry
from citylod.semantics import queries
from citylod.semantics.link import link_command, link_points
from citylod.semantics.proxy import ProxySet, prism_mesh
from citylod.semantics.state import FeatureState
from citylod.semantics.store import CityStore, build_city

CRS = pyproj.CRS.from_epsg(32632)
X0, Y0 = 500_000.0, 5_400_000.0  # large coordinates on purpose


def box(oid: str, x0: float, y0: float, x1: float, y1: float, z0: float, z1: float, **attrs: object) -> CityObject:
    c = [(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)]
    ground = np.array([(x, y, z0) for x, y in c[::-1]], dtype=float)
    roof = np.array([(x, y, z1) for x, y in c], dtype=float)
    walls = [np.array([(ax, ay, z0), (bx, by, z0), (bx, by, z1), (ax, ay, z1), (ax, ay, z0)], dtype=float)
             for (ax, ay), (bx, by) in pairwise(c)]
    surfaces = [[ground], [roof]] + [[w] for w in walls]
    sem = ["GroundSurface", "RoofSurface"] + ["WallSurface"] * 4
    return CityObject(oid, "Building", dict(attrs), surfaces, 1, None, sem)


def gable(oid: str, x0: float, y0: float, x1: float, y1: float, z0: float, eave: float, ridge: float) -> CityObject:
    """LoD2 house with a gable roof, ridge along x at the middle of y."""
    ym = (y0 + y1) / 2
    south = np.array([(x0, y0, eave), (x1, y0, eave), (x1, ym, ridge), (x0, ym, ridge), (x0, y0, eave)])
    north = np.array([(x0, ym, ridge), (x1, ym, ridge), (x1, y1, eave), (x0, y1, eave), (x0, ym, ridge)])
    ground = np.array([(x0, y0, z0), (x0, y1, z0), (x1, y1, z0), (x1, y0, z0), (x0, y0, z0)])
    return CityObject(oid, "Building", {"measuredHeight": ridge - z0}, [[ground], [south], [north]], 2, None,
                      ["GroundSurface", "RoofSurface", "RoofSurface"])


def courtyard(oid: str) -> CityObject:
    x0, y0 = X0 + 100, Y0
    outer = [(x0, y0), (x0 + 30, y0), (x0 + 30, y0 + 30), (x0, y0 + 30), (x0, y0)]
    inner = [(x0 + 10, y0 + 10), (x0 + 10, y0 + 20), (x0 + 20, y0 + 20), (x0 + 20, y0 + 10), (x0 + 10, y0 + 10)]
    roof = [np.array([(x, y, 12.0) for x, y in outer]), np.array([(x, y, 12.0) for x, y in inner])]
    ground = [np.array([(x, y, 0.0) for x, y in outer[::-1]]), np.array([(x, y, 0.0) for x, y in inner[::-1]])]
    return CityObject(oid, "Building", {"measuredHeight": 12.0, "function": "office"}, [roof, ground], 1, None,
                      ["RoofSurface", "GroundSurface"])


def model() -> CityModel:
    objs = [
        box("A", X0, Y0, X0 + 10, Y0 + 10, 0, 8, measuredHeight=8.0, function="residential", name="Alpha"),
        box("B", X0 + 10, Y0, X0 + 20, Y0 + 10, 0, 25, measuredHeight=25.0, storeysAboveGround=8),
        gable("G", X0 + 40, Y0, X0 + 50, Y0 + 10, 0, 6, 10),
        courtyard("C"),
        CityObject("T", "SolitaryVegetationObject", {"species": "oak"}, [], -1, None, []),
    ]
    return CityModel(objs, CRS, "test-model", ["A: a test warning"], "test")


@pytest.fixture(scope="module")
def store_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("store") / "city.gpkg"
    report = build_city(model(), out, progress=False)
    assert report.objects == 5 and report.buildings == 4 and report.proxies == 4
    assert "5 city objects" in report.summary()
    return out


# --- proxies -------------------------------------------------------------------------------------------

def test_contains_matches_independent_shapely_computation() -> None:
    objs = model().objects
    ps = ProxySet.from_objects(objs, inflate=0.5)
    rng = np.random.default_rng(1)
    n = 3000
    pts = np.column_stack([rng.uniform(X0 - 5, X0 + 135, n), rng.uniform(Y0 - 5, Y0 + 35, n), rng.uniform(-2, 28, n)])
    got = ps.contains(pts)
    # Independent: buffered footprint polygons built here, point by point, with the box heights.
    polys = {"A": shapely.box(X0, Y0, X0 + 10, Y0 + 10), "B": shapely.box(X0 + 10, Y0, X0 + 20, Y0 + 10),
             "C": shapely.box(X0 + 100, Y0, X0 + 130, Y0 + 30).difference(shapely.box(X0 + 110, Y0 + 10, X0 + 120, Y0 + 20))}
    tops = {"A": 8.0, "B": 25.0, "C": 12.0}
    for k, (x, y, z) in enumerate(pts):
        p = shapely.Point(x, y)
        want = []
        for oid, poly in polys.items():
            if poly.buffer(0.5, join_style="mitre").contains(p) and -0.5 <= z <= tops[oid] + 0.5:
                want.append((poly.distance(p), oid))
        g = shapely.box(X0 + 40, Y0, X0 + 50, Y0 + 10)
        if g.buffer(0.5, join_style="mitre").contains(p) and z >= -0.5:
            yy = min(max(y, Y0), Y0 + 10)
            roof = 6 + 4 * (1 - abs(yy - (Y0 + 5)) / 5)  # gable: 6 at the eaves, 10 at the ridge
            if (g.contains(p) and z <= roof + 0.5) or (not g.contains(p) and z <= 10.5):
                want.append((g.distance(p), "G"))
        expect = min(want)[1] if want else None
        assert (ps.object_ids[got[k]] if got[k] >= 0 else None) == expect, (k, x, y, z)
    assert (got >= 0).sum() > 100  # the sample is not trivially empty


def test_roof_following_top_excludes_points_over_the_eaves() -> None:
    ps = ProxySet.from_objects([gable("G", 0, 0, 10, 10, 0, 6, 10)], inflate=0.5)
    inside_ridge = ps.contains([[5, 5, 10.3]])
    over_eave = ps.contains([[5, 0.5, 9.0]])  # under the ridge height but above the roof near the eave
    assert inside_ridge[0] == 0 and over_eave[0] == -1


def test_prism_mesh_is_closed_and_outward() -> None:
    shape = shapely.box(0, 0, 10, 10).difference(shapely.box(3, 3, 6, 6))
    v, f = prism_mesh(shape, 1.0, 4.0)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert (counts == 2).all()
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    vol = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
    assert vol == pytest.approx((100 - 9) * 3.0)


def test_footprint_map_agrees_with_contains() -> None:
    ps = ProxySet.from_objects(model().objects, inflate=0.5)
    fm = ps.rasterize_footprints((X0 - 2, Y0 - 2, X0 + 132, Y0 + 32), 0.5)
    ids, zmin, zmax = fm
    assert ids.dtype == np.int32 and ids.shape == (68, 268)
    # Independent check at cell centres: which un-inflated box holds the centre.
    row, col = 10, 10  # x = X0 + 3.25, y = Y0 + 32 - 5.25 -> outside (y > Y0 + 10.5)
    assert ids[row, col] == -1 and np.isnan(zmin[row, col])
    i, j = int((32 - 5.0) / 0.5), int((2 + 5.0) / 0.5)  # centre (X0 + 5.25, Y0 + 4.75): inside A
    assert ps.object_ids[ids[i, j]] == "A" and zmax[i, j] == pytest.approx(8.5) and zmin[i, j] == pytest.approx(-0.5)
    i, j = int((32 - 15.0) / 0.5), int((2 + 115.0) / 0.5)  # courtyard centre: no object
    assert ids[i, j] == -1


# --- store ---------------------------------------------------------------------------------------------

def test_geopackage_structure(store_path: Path) -> None:
    c = sqlite3.connect(store_path)
    assert c.execute("PRAGMA application_id").fetchone()[0] == 0x47504B47
    contents = dict(c.execute("SELECT table_name, data_type FROM gpkg_contents").fetchall())
    assert contents["city_objects"] == "features" and contents["proxies"] == "features"
    assert c.execute("SELECT geometry_type_name, srs_id FROM gpkg_geometry_columns WHERE table_name='city_objects'"
                     ).fetchone() == ("MULTIPOLYGON", 32632)
    assert c.execute("SELECT organization_coordsys_id FROM gpkg_spatial_ref_sys WHERE srs_id=32632").fetchone() == (32632,)
    n_geom = c.execute("SELECT COUNT(*) FROM city_objects WHERE fid IN (SELECT fid FROM proxies)").fetchone()[0]
    assert c.execute("SELECT COUNT(*) FROM rtree_city_objects_footprint").fetchone()[0] == n_geom == 4
    assert c.execute("SELECT COUNT(*) FROM rtree_proxies_proxy_footprint").fetchone()[0] == 4
    assert c.execute("SELECT extension_name FROM gpkg_extensions WHERE table_name='city_objects'").fetchone() == (
        "gpkg_rtree_index",)
    # The R-tree bounds equal the geometry envelopes.
    blob = c.execute("SELECT footprint FROM city_objects WHERE object_id='C'").fetchone()[0]
    g = decode_geometry(blob)
    assert g.geom_type == "MultiPolygon" and g.area == pytest.approx(800.0, rel=1e-6)
    fid = c.execute("SELECT fid FROM city_objects WHERE object_id='C'").fetchone()[0]
    r = c.execute("SELECT minx, maxx, miny, maxy FROM rtree_city_objects_footprint WHERE id=?", (fid,)).fetchone()
    assert r == pytest.approx((X0 + 100, X0 + 130, Y0, Y0 + 30), abs=0.01)
    assert c.execute("SELECT COUNT(*) FROM citylod_warnings").fetchone()[0] == 1
    c.close()


def test_store_queries(store_path: Path) -> None:
    with CityStore.open(store_path) as s:
        assert s.crs.to_epsg() == 32632 and len(s) == 5
        assert s.query("measured_height > 10") == ["B", "C"]
        assert s.query("type = ?", ("SolitaryVegetationObject",)) == ["T"]
        assert s.query("json_extract(attributes, '$.species') = 'oak'") == ["T"]
        a = s.attributes("A")
        assert a["function"] == "residential" and a["name"] == "Alpha" and a["measured_height"] == 8.0
        assert s.within_distance((X0 + 25, Y0 + 5), 6) == ["B"]
        assert s.within_polygon([(X0 + 5, Y0 + 5), (X0 + 45, Y0 + 5), (X0 + 45, Y0 + 6)]) == ["A", "B", "G"]
        assert s.within_polygon(shapely.box(X0 - 1, Y0 - 1, X0 + 21, Y0 + 11), predicate="within") == ["A", "B"]
        b = s.bounds
        assert b[0] == pytest.approx(X0) and b[5] == pytest.approx(25.0)
        v, f = s.mesh("A")
        assert len(v) and f.dtype == np.int32
        assert s.object_id(s.fid("G")) == "G"


@pytest.mark.parametrize("where", ["1=1; DROP TABLE city_objects", "1=1) ; DELETE FROM city_objects; --",
                                   "fid IN (SELECT load_extension('x'))", "no_such_column = 1"])
def test_sql_injection_and_errors_are_input_errors(store_path: Path, where: str) -> None:
    with CityStore.open(store_path) as s:
        with pytest.raises(InputError):
            s.query(where)
        assert len(s.query("1=1")) == 5  # table intact
    c = sqlite3.connect(store_path)
    assert c.execute("SELECT COUNT(*) FROM city_objects").fetchone()[0] == 5


def test_not_a_store_and_atomic_failure(tmp_path: Path) -> None:
    junk = tmp_path / "junk.gpkg"
    junk.write_bytes(b"not sqlite at all" * 100)
    with pytest.raises(InputError, match=r"junk\.gpkg"):
        CityStore.open(junk)
    dup = CityModel([box("A", 0, 0, 1, 1, 0, 1), box("A", 2, 2, 3, 3, 0, 1)], CRS, "dups.gml")
    out = tmp_path / "dups.gpkg"
    with pytest.raises(InputError, match="duplicate"):
        build_city(dup, out, progress=False)
    assert list(tmp_path.iterdir()) == [junk]  # nothing half-written


# --- queries and plugins -------------------------------------------------------------------------------

def test_builtin_and_entry_point_queries(store_path: Path) -> None:
    reg = queries.QueryRegistry()
    names = {q.name: q.source for q in reg.registered()}
    assert {"sql", "polygon", "distance", "tall_buildings"} <= set(names)
    assert names["sql"] == "citylod (built-in)" and names["tall_buildings"].startswith("citylod")
    with CityStore.open(store_path) as s:
        assert reg.run(s, "tall_buildings", min_height=20) == ["B"]
        assert reg.run(s, "tall_buildings", min_height=9) == ["B", "G", "C"]  # fid order
        assert reg.run(s, "sql", where="type = 'Building'") == ["A", "B", "G", "C"]
        assert reg.run(s, "distance", point=(X0 + 25, Y0 + 5), distance=6) == ["B"]


def test_rows_agree_with_attributes_and_parameter_hints(store_path: Path) -> None:
    with CityStore.open(store_path) as s:
        ids = ["C", "A", "nope", "B"]
        rows = s.rows(ids, ("type", "measured_height"))
        assert rows[2] == (None, None)
        for oid, row in zip(ids, rows, strict=True):
            if oid != "nope":
                a = s.attributes(oid)
                assert row == (a["type"], a["measured_height"])
        with pytest.raises(InputError, match="no column"):
            s.rows(ids, ("type; DROP TABLE city_objects",))
    assert queries.parameter_hint("sql") == ""
    assert queries.parameter_hint("polygon") == '{"polygon": null, "predicate": "intersects"}'
    assert queries.parameter_hint("distance") == '{"point": null, "distance": null}'


def test_broken_plugin_is_a_warning(monkeypatch: pytest.MonkeyPatch, store_path: Path) -> None:
    broken = EntryPoint("broken", "citylod.no_such_module:Nothing", queries.GROUP)
    not_query = EntryPoint("not_query", "citylod.core.errors:CitylodError", queries.GROUP)
    monkeypatch.setattr(queries, "entry_points", lambda group: [broken, not_query] if group == queries.GROUP else [])
    reg = queries.QueryRegistry()
    assert {"broken", "not_query", "sql"} <= {q.name for q in reg.registered()}
    with pytest.warns(UserWarning, match="'broken'"):
        assert reg.get("broken") is None
    with pytest.warns(UserWarning, match="not_query"):
        assert reg.get("not_query") is None
    with CityStore.open(store_path) as s, warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(PluginError, match="broken"):
            reg.run(s, "broken")
        assert reg.run(s, "sql", where="fid = 1") == ["A"]


# --- state ---------------------------------------------------------------------------------------------

def test_feature_state_events_and_arrays() -> None:
    s = FeatureState()
    seen = []
    unsubscribe = s.on_change(seen.append)
    s.select(["A", "B"])
    s.select(["B"], mode="toggle")
    s.highlight(["C"], (255, 0, 0))
    s.hide(["B"])
    s.isolate(["A", "B", "C"])
    assert [c.kind for c in seen] == ["select", "select", "highlight", "hide", "isolate"]
    assert seen[1].ids == {"B"} and s.version == 5 and s.selection == {"A"}
    rgba, visible, selected = s.as_arrays(["A", "B", "C", "D"])
    assert rgba[2].tolist() == [1, 0, 0, 1] and rgba[0, 3] == 0
    assert visible.tolist() == [True, False, True, False] and selected.tolist() == [True, False, False, False]
    s.set_hover("A")
    unsubscribe()
    s.clear()
    assert len(seen) == 6 and s.version == 7 and s.is_visible("D") and s.color("C") is None
    with pytest.raises(ValueError):
        s.highlight(["A"], "#12")


# --- linking -------------------------------------------------------------------------------------------

def write_las(path: Path, xyz: np.ndarray, cls: np.ndarray) -> None:
    h = laspy.LasHeader(point_format=1, version="1.2")
    h.offsets, h.scales = [X0, Y0, 0.0], [0.001, 0.001, 0.001]
    las = laspy.LasData(h)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.classification = cls
    las.write(path)


def test_link_command_writes_object_id(tmp_path: Path, store_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(5)
    n = 5000
    xyz = np.column_stack([rng.uniform(X0 - 5, X0 + 135, n), rng.uniform(Y0 - 5, Y0 + 35, n), rng.uniform(-2, 28, n)])
    src = tmp_path / "pts.laz"
    write_las(src, xyz, np.full(n, 1, np.uint8))
    out = tmp_path / "linked.laz"
    import citylod.semantics.link as link

    old = link.CHUNK_POINTS
    try:
        assert link_command(store_path, src, out, progress=False) == 0
    finally:
        link.CHUNK_POINTS = old
    assert "points" in capsys.readouterr().out
    las = laspy.read(out)
    assert las.object_id.dtype == np.int32 and len(las.object_id) == n
    with CityStore.open(store_path) as s:
        expect = link_points(s, np.column_stack([las.x, las.y, las.z]))
        assert np.array_equal(np.asarray(las.object_id), expect)
        hit = expect[expect >= 0]
        assert {s.object_id(f) for f in hit} <= {"A", "B", "G", "C"}
    assert np.array_equal(np.asarray(las.classification), np.full(n, 1))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["linked.laz", "pts.laz"]


def test_link_missing_file_is_input_error(tmp_path: Path, store_path: Path) -> None:
    with pytest.raises(InputError, match=r"nothing\.laz"):
        link_command(store_path, tmp_path / "nothing.laz", tmp_path / "o.laz", progress=False)
    assert not (tmp_path / "o.laz").exists()


# --- the synthetic sample (analytic ground truth) ------------------------------------------------------

def test_proxies_against_sample_ground_truth(tmp_path: Path) -> None:
    sample_city = pytest.importorskip("citylod.sample.city")
    sample_gml = pytest.importorskip("citylod.sample.gml")
    city = sample_city.make_city(129, 3)
    gml = tmp_path / "city.gml"
    sample_gml.write_citygml(city, gml)
    out = tmp_path / "city.gpkg"
    report = build_city(gml, out, progress=False)
    assert report.buildings == len(city.buildings)
    x0, y0, x1, y1 = city.bounds
    rng = np.random.default_rng(0)
    n = 100_000
    pts = np.column_stack([rng.uniform(x0, x1, n), rng.uniform(y0, y1, n), rng.uniform(110, 160, n)])
    truth = city.inside_building(pts[:, 0], pts[:, 1], pts[:, 2], inflate=0.5)
    with CityStore.open(out) as s:
        got = link_points(s, pts)
        ids = np.array([s.object_id(f) if f >= 0 else "" for f in got])
    names = np.array([b.id for b in city.buildings])
    want = np.where(truth >= 0, names[np.maximum(truth, 0)], "")
    assert (truth >= 0).sum() > 1000
    # The analytic solid keeps the eave height over the inflation margin; the proxy keeps its top there.
    assert (ids == want).mean() > 0.995
