"""The synthetic sample city: files open, georeferencing is right, and the files agree with the analytic
ground truth, checked by computations independent of the generator (shoelace/Newell volumes, edge
counting, pixel centres from the GeoTIFF transform)."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import laspy
import numpy as np
import pytest
import rasterio
from lxml import etree
from shapely.geometry import Polygon

from citylod.cli import main
from citylod.core.camera import load_cameras
from citylod.sample.files import NODATA, SampleInfo, make_city, make_sample

BLDG = "{http://www.opengis.net/citygml/building/2.0}"
GML = "{http://www.opengis.net/gml}"


@pytest.fixture(scope="module")
def sample(sample_city: SampleInfo) -> SampleInfo:
    return sample_city


def _rings(poly: etree._Element) -> list[np.ndarray]:
    out = []
    for tag in ("exterior", "interior"):
        for pl in poly.iterfind(f"{GML}{tag}/{GML}LinearRing/{GML}posList"):
            pts = np.array(pl.text.split(), dtype=np.float64).reshape(-1, 3)
            assert np.array_equal(pts[0], pts[-1]), "GML rings repeat their first position"
            out.append(pts[:-1])
    return out


def _area_vector(rings: list[np.ndarray], origin: np.ndarray) -> np.ndarray:
    """Newell's area vector of a planar polygon with holes (holes oppositely oriented subtract)."""
    total = np.zeros(3)
    for r in rings:
        p = r - origin
        total += 0.5 * np.cross(p, np.roll(p, -1, axis=0)).sum(axis=0)
    return total


def _volume(polys: list[list[np.ndarray]]) -> float:
    """Divergence theorem: V = 1/3 Σ (p0 · A) over planar faces with outward area vectors A."""
    origin = polys[0][0][0]
    return sum(float((rings[0][0] - origin) @ _area_vector(rings, origin)) for rings in polys) / 3.0


def _buildings(path: Path) -> list[etree._Element]:
    return etree.parse(str(path)).getroot().findall(f".//{BLDG}Building")


def test_files_exist_and_are_georeferenced(sample: SampleInfo) -> None:
    assert set(sample.files) == {"dsm", "ortho", "points", "city", "camera", "path", "metadata"}
    for p in sample.files.values():
        assert p.is_file() and p.stat().st_size > 0
    assert not list(sample.files["dsm"].parent.glob(".*.part")), "temporary files were left behind"
    assert sample.crs == "EPSG:32632"
    for name in ("dsm", "ortho"):
        with rasterio.open(sample.files[name]) as src:
            assert src.crs.to_epsg() == 32632
            assert (src.width, src.height) == (129, 129)
            assert src.res == (1.0, 1.0)
            assert src.bounds == pytest.approx(sample.bounds)
            assert src.bounds.bottom > 5.3e6 and src.bounds.left > 5.0e5
            assert src.profile["tiled"] and src.profile["compress"] == "deflate"
    with rasterio.open(sample.files["ortho"]) as src:
        rgb = src.read()
        assert src.dtypes == ("uint8",) * 3 and rgb.std() > 10


def test_dsm_matches_ground_truth(sample: SampleInfo) -> None:
    city = sample.city
    with rasterio.open(sample.files["dsm"]) as src:
        dsm = src.read(1)
        assert src.nodata == NODATA and src.dtypes[0] == "float32"
        rows, cols = np.mgrid[0 : src.height, 0 : src.width]
        xs, ys = rasterio.transform.xy(src.transform, rows.ravel(), cols.ravel(), offset="center")
    x, y = np.asarray(xs).reshape(dsm.shape), np.asarray(ys).reshape(dsm.shape)
    hole = dsm == NODATA
    assert 0 < hole.sum() < 0.2 * hole.size
    np.testing.assert_array_equal(hole, city.nodata_mask(x, y))
    err = np.abs(dsm[~hole] - city.surface_height(x, y)[~hole])
    assert err.max() < 1e-3
    # Façades are vertical steps: some neighbouring samples differ by a storey or more.
    assert np.nanmax(np.abs(np.diff(np.where(hole, np.nan, dsm), axis=1))) > 3.0


def test_points_agree_with_ground_truth(sample: SampleInfo) -> None:
    city = sample.city
    las = laspy.read(sample.files["points"])
    assert las.header.version.major == 1 and las.header.version.minor == 4
    assert las.header.point_format.id in (6, 7)
    assert las.header.parse_crs().to_epsg() == 32632
    n_first = int((las.return_number == 1).sum())
    assert 1.0 * 129**2 < n_first < 3.0 * 129**2
    cls = np.asarray(las.classification)
    assert set(np.unique(cls)) <= {2, 5, 6, 9, 17} and {2, 5, 6} <= set(np.unique(cls))
    x, y, z = np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)
    b = cls == 6
    assert (city.building_id_at(x[b], y[b]) >= 0).mean() > 0.98
    assert (city.building_id_at(x[cls == 2], y[cls == 2]) >= 0).mean() < 0.02
    first = las.return_number == 1
    dz = np.abs(z[first] - city.surface_height(x[first], y[first]))
    assert np.quantile(dz, 0.99) < 0.1
    assert not city.nodata_mask(x, y).any()
    assert np.asarray(las.red).max() > 255  # 16-bit colour


def test_citygml_lod2_solids_are_closed(sample: SampleInfo) -> None:
    city = sample.city
    elems = _buildings(sample.files["city"])
    assert len(elems) == len(city.buildings) > 0
    holes = 0
    for el, b in zip(elems, city.buildings, strict=True):
        assert el.get(f"{GML}id") == b.id
        assert float(el.findtext(f"{BLDG}measuredHeight")) == pytest.approx(b.ridge - b.ground, abs=0.01)
        assert el.find(f"{BLDG}measuredHeight").get("uom") == "m"
        assert el.findtext(f"{BLDG}function") == b.function
        polys, kinds = [], []
        for surf in el.iterfind(f"{BLDG}boundedBy/*"):
            for poly in surf.iterfind(f".//{GML}Polygon"):
                polys.append(_rings(poly))
                kinds.append(etree.QName(surf).localname)
        assert {"GroundSurface", "WallSurface", "RoofSurface"} == set(kinds)
        holes += sum(len(r) - 1 for r in polys)
        # Closed and consistently oriented: every directed edge once, and its reverse once.
        edges = Counter()
        for rings in polys:
            for r in rings:
                keys = [tuple(p) for p in r]
                edges.update(zip(keys, keys[1:] + keys[:1], strict=True))
        assert all(n == 1 for n in edges.values())
        assert all(edges[(q, p)] == 1 for p, q in edges)
        # Outward orientation: positive volume, no larger than footprint × measured height.
        vol = _volume(polys)
        fp = Polygon(b.footprint, list(b.holes)).area
        assert 0.0 < vol <= fp * (b.ridge - b.ground) * 1.001  # 1 mm coordinate rounding
        # Roof polygons lie on the analytic roof.
        for rings, kind in zip(polys, kinds, strict=True):
            if kind != "RoofSurface":
                continue
            origin = rings[0][0]
            n = _area_vector(rings, origin)
            assert n[2] > 0  # roofs face up
            pt = Polygon(rings[0][:, :2], [r[:, :2] for r in rings[1:]]).representative_point()
            zp = origin[2] - (n[0] * (pt.x - origin[0]) + n[1] * (pt.y - origin[1])) / n[2]
            assert float(city.roof_height(pt.x, pt.y)) == pytest.approx(zp, abs=0.01)
    assert holes > 0, "the courtyard building has interior rings"


def test_citygml_lod1_volume(sample: SampleInfo) -> None:
    for el, b in zip(_buildings(sample.files["city"]), sample.city.buildings, strict=True):
        polys = [_rings(p) for p in el.iterfind(f"{BLDG}lod1Solid//{GML}Polygon")]
        z = np.concatenate([r[:, 2] for rings in polys for r in rings])
        expected = Polygon(b.footprint, list(b.holes)).area * (z.max() - z.min())
        assert _volume(polys) == pytest.approx(expected, rel=0.01)


def test_ground_truth_queries() -> None:
    city = make_city(129, seed=7)
    shapes = {b.shape for b in city.buildings}
    roofs = {b.roof for b in city.buildings}
    assert shapes == {"rect", "L", "courtyard"} and roofs == {"flat", "gable", "hip"}
    assert any(b.angle_deg % 90.0 != 0.0 for b in city.buildings), "some buildings are rotated"
    assert len(city.chimneys) > 0 and len(city.trees) > 0
    for b in city.buildings:
        # A point just inside the first footprint corner, by the footprint polygon not the generator.
        poly = Polygon(b.footprint, list(b.holes))
        p = poly.representative_point()
        assert city.building_id_at(p.x, p.y) == b.index
        assert float(city.roof_height(p.x, p.y)) <= b.ridge + 1e-9
        assert city.inside_building(p.x, p.y, b.ground + 1.0) == b.index
        top = float(city.roof_height(p.x, p.y))
        assert city.inside_building(p.x, p.y, top + 0.5) == -1
        assert city.inside_building(p.x, p.y, top + 0.5, inflate=1.0) == b.index
        # 0.5 m outside the middle of the first footprint edge, along its outward normal (CCW ring).
        e0, e1 = b.footprint[0], b.footprint[1]
        normal = np.array([e1[1] - e0[1], e0[0] - e1[0]]) / np.linalg.norm(e1 - e0)
        away = 0.5 * (e0 + e1) + 0.5 * normal
        assert city.building_id_at(*away) == -1
        assert city.inside_building(*away, b.ground + 1.0, inflate=1.0) == b.index
        if b.roof == "gable":  # the ridge line, by the building's own geometry
            mid = b.to_world(np.array([[0.0, 0.0]]))[0]
            assert float(city.roof_height(*mid)) == pytest.approx(b.ridge, abs=1e-6)
    # Chimneys stick out of their roofs.
    ch = city.chimneys
    roof = city.roof_height(ch.center[:, 0], ch.center[:, 1])
    assert np.all(city.surface_height(ch.center[:, 0], ch.center[:, 1]) == ch.top)
    assert np.all(ch.top > roof + 0.5)
    # Query shapes broadcast.
    x0, y0, x1, y1 = city.bounds
    xx, yy = np.meshgrid(np.linspace(x0, x1, 7), np.linspace(y0, y1, 5))
    assert city.surface_height(xx, yy).shape == (5, 7)
    assert city.building_id_at(xx, yy).shape == (5, 7)


def test_cameras_load(sample: SampleInfo) -> None:
    (overview,) = load_cameras(sample.files["camera"])
    path = load_cameras(sample.files["path"])
    assert 24 <= len(path) <= 60
    x0, y0, x1, y1 = sample.bounds
    assert x0 <= overview.focal_point[0] <= x1 and y0 <= overview.focal_point[1] <= y1
    heights = sample.city.surface_height([c.position[0] for c in path], [c.position[1] for c in path])
    assert all(c.position[2] > h for c, h in zip(path, heights, strict=True))


def test_same_seed_same_bytes(tmp_path: Path) -> None:
    a = make_sample(tmp_path / "a", size=65, seed=3)
    b = make_sample(tmp_path / "b", size=65, seed=3)
    c = make_sample(tmp_path / "c", size=65, seed=4)
    for name in ("dsm", "ortho", "points", "city", "metadata"):
        assert a.files[name].read_bytes() == b.files[name].read_bytes(), name
    assert a.files["dsm"].read_bytes() != c.files["dsm"].read_bytes()


def test_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["sample", str(tmp_path / "s"), "--size", "65", "--seed", "1"]) == 0
    assert "dsm.tif" in capsys.readouterr().out
    assert main(["sample", str(tmp_path / "t"), "--size", "8"]) == 2
    assert "at least 33" in capsys.readouterr().err
    (tmp_path / "file").write_text("x")
    assert main(["sample", str(tmp_path / "file"), "--size", "65"]) == 2
