"""The desktop application's plain models (no Qt, no window): every user action as a method call."""

from __future__ import annotations

import math

import numpy as np
import pytest
from geographiclib.geodesic import Geodesic

from citylod.app.models import (
    Bookmarks,
    QueryHistory,
    build_plan,
    fly,
    focus_on,
    measure,
    overview_camera,
    parse_progress,
    source_kind,
    tau_from_slider,
    tau_to_slider,
)
from citylod.core.camera import Camera


# ------------------------------------------------------------------------------------------ measuring
def test_planar_distance_height_area() -> None:
    pts = np.array([[500000.0, 5400000.0, 10.0], [500003.0, 5400004.0, 10.0], [500003.0, 5400004.0, 22.0]])
    d = measure("distance", pts)
    assert d.value == pytest.approx(5.0 + 12.0)
    assert d.horizontal == pytest.approx(5.0)
    assert not d.geodesic
    h = measure("height", pts[[0, 2]])
    assert h.value == pytest.approx(12.0)
    assert h.horizontal == pytest.approx(5.0)
    square = np.array([[0, 0, 0], [10, 0, 5], [10, 20, 0], [0, 20, 1]], float) + [5e5, 5.4e6, 0]
    a = measure("area", square)
    assert a.value == pytest.approx(200.0)  # horizontal area: z does not count
    assert a.horizontal == pytest.approx(60.0)
    assert "200.0 m²" in a.text()


def test_geodesic_matches_geographiclib() -> None:
    # x = longitude, y = latitude (degrees), z metres; checked against geographiclib called directly.
    pts = np.array([[7.0, 50.0, 100.0], [7.01, 50.005, 130.0], [7.02, 50.0, 100.0]])
    g = Geodesic.WGS84
    s01 = g.Inverse(50.0, 7.0, 50.005, 7.01)["s12"]
    s12 = g.Inverse(50.005, 7.01, 50.0, 7.02)["s12"]
    d = measure("distance", pts, geographic=True)
    assert d.geodesic
    assert d.horizontal == pytest.approx(s01 + s12, rel=1e-12)
    assert d.value == pytest.approx(math.hypot(s01, 30.0) + math.hypot(s12, 30.0), rel=1e-12)
    poly = g.Polygon()
    for lon, lat, _ in pts:
        poly.AddPoint(lat, lon)
    _, perim, area = poly.Compute(False, True)
    a = measure("area", pts, geographic=True)
    assert a.value == pytest.approx(abs(area), rel=1e-12)
    assert a.horizontal == pytest.approx(perim, rel=1e-12)
    # Sanity against a planar approximation: ~1.1 km by 0.55 km triangle -> ~0.28 km².
    assert 2.0e5 < a.value < 4.0e5


def test_measure_rejects_unknown_kind() -> None:
    with pytest.raises(ValueError):
        measure("volume", np.zeros((2, 3)))


# ------------------------------------------------------------------------------------ camera maths
def test_fly_keeps_direction_and_moves_by_step() -> None:
    cam = Camera((0.0, -100.0, 50.0), (0.0, 0.0, 0.0))
    for direction in ("forward", "backward", "left", "right", "up", "down"):
        moved = fly(cam, direction, 10.0)
        delta = np.subtract(moved.position, cam.position)
        assert np.linalg.norm(delta) == pytest.approx(10.0)
        np.testing.assert_allclose(moved.direction, cam.direction, atol=1e-12)
    assert fly(cam, "up", 3.0).position[2] == pytest.approx(53.0)
    assert fly(cam, "right", 3.0).position[0] == pytest.approx(3.0)


def test_overview_and_focus() -> None:
    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([200.0, 100.0, 30.0])
    cam = overview_camera(lo, hi)
    np.testing.assert_allclose(cam.focal_point, (lo + hi) / 2)
    assert cam.position[2] > hi[2]
    f = focus_on(cam, (10.0, 10.0, 5.0))
    assert f.focal_point == (10.0, 10.0, 5.0)
    np.testing.assert_allclose(f.direction, cam.direction, atol=1e-9)


def test_tau_slider_is_log_scale() -> None:
    assert tau_to_slider(0.25) == 0 and tau_to_slider(16) == 1000
    assert tau_to_slider(2.0) == 500  # geometric middle of [0.25, 16]
    for t in (0.25, 0.5, 1.0, 3.0, 16.0):
        assert tau_from_slider(tau_to_slider(t)) == pytest.approx(t, rel=0.005)


# ---------------------------------------------------------------------------------- persisted values
def test_bookmarks_roundtrip_json() -> None:
    b = Bookmarks()
    cam = Camera((1.0, 2.0, 3.0), (4.0, 5.0, 6.0), fovy_deg=30.0)
    assert b.add("north", cam) == "north"
    assert b.add("", cam) == "View 2"
    again = Bookmarks.from_json(b.to_json())
    assert again.names() == ["north", "View 2"]
    assert again.get("north") == cam
    assert Bookmarks.from_json("not json").names() == []
    assert Bookmarks.from_json('{"bad": {"position": 1}}').names() == []


def test_query_history_dedup_and_limit() -> None:
    h = QueryHistory(limit=3)
    for q in ("a", "b", "a", "c", "d", " "):
        h.add(q)
    assert h.items == ["d", "c", "a"]
    assert QueryHistory(h.items).items == ["d", "c", "a"]


# ------------------------------------------------------------------------------ sources and builds
def test_source_kind_and_build_plan(tmp_path) -> None:
    (tmp_path / "ts").mkdir()
    (tmp_path / "ts" / "tileset.json").write_text("{}")
    (tmp_path / "model.json").write_text('{"type": "CityJSON", "version": "2.0"}')
    assert source_kind(tmp_path / "ts") == "tileset"
    assert source_kind(tmp_path / "ts" / "tileset.json") == "tileset"
    assert source_kind(tmp_path / "x.gpkg") == "store"
    assert source_kind(tmp_path / "x.TIF") == "raster"
    assert source_kind(tmp_path / "x.laz") == "points"
    assert source_kind(tmp_path / "x.gml") == "citymodel"
    assert source_kind(tmp_path / "model.json") == "citymodel"
    assert source_kind(tmp_path / "empty_dir_missing") is None
    plan = build_plan(tmp_path / "dsm.tif", python="py")
    assert plan.argv == ("py", "-m", "citylod.cli", "build", "dsm", str(tmp_path / "dsm.tif"), "-o",
                         str(tmp_path / "dsm_tiles"))
    assert build_plan(tmp_path / "c.gml", python="py").output == tmp_path / "c.gpkg"
    assert build_plan(tmp_path / "p.laz", python="py").kind == "points"


def test_parse_tqdm_progress() -> None:
    assert parse_progress("tiles:  40%|####      | 4/10\rtiles:  70%|#######   | 7/10") == ("tiles", 70)
    assert parse_progress("no progress here") is None
    assert parse_progress(" 100%|##########| 3/3") == ("", 100)


def test_document_up_and_home_camera_follow_ecef_data() -> None:
    """Another tool's geocentric tileset opened in the app: the home view looks down the local vertical
    (40° from south-south-west, like a projected dataset's), and that vertical is the turntable's axis."""
    from citylod.app.models import Document
    from tests.paths import ROOT

    doc = Document(workers=1)
    try:
        assert np.allclose(doc.up(), [0.0, 0.0, 1.0])  # nothing open
        doc.open(ROOT / "tests" / "data" / "3dtiles" / "Batched" / "BatchedWithoutBatchTable")
        lo, hi = doc.bounds()
        centre = (lo + hi) / 2
        up = doc.up()
        assert float(up @ (centre / np.linalg.norm(centre))) == pytest.approx(1.0)
        cam = doc.home_camera(aspect=1.5)
        d = np.subtract(cam.position, cam.focal_point)
        assert np.allclose(cam.view_up, up)
        assert math.degrees(math.asin(float(d @ up) / float(np.linalg.norm(d)))) == pytest.approx(40.0, abs=1e-6)
        # North: square to the vertical, towards the pole (the sample lies in the northern hemisphere), and
        # up on screen when looking north-north-east from the home view.
        from citylod.render.hud import north_on_screen

        north = doc.north()
        assert abs(float(north @ up)) < 1e-9 and north[2] > 0
        assert north_on_screen(cam, north)[1] > 0.8
    finally:
        doc.close()


def test_home_camera_frames_what_is_drawn_not_the_store(sample_built, tmp_path) -> None:
    """A city store is drawn only through the other layers; its model may cover far more ground than the
    LiDAR (Delft: twice the area). The home view fits the drawn layers' box, corners and all, not the sphere."""
    from citylod.app.models import Document
    from citylod.bench.synthetic import make_point_tileset
    from citylod.semantics.store import CityStore

    sb = np.asarray(CityStore.open(sample_built.gpkg).bounds, np.float64)
    centre = (sb[:3] + sb[3:]) / 2
    tiles = make_point_tileset(tmp_path / "pts", levels=2, points_per_tile=500, extent=30.0,
                               corner=(centre[0] - 15.0, centre[1] - 15.0, sb[2]), crs="EPSG:32632")
    doc = Document(workers=1)
    try:
        doc.open(sample_built.gpkg)
        doc.open(tiles)
        cam = doc.home_camera(aspect=1.5)
        lo, hi = doc.scene.bounds
        right, up, forward = (np.asarray(v) for v in cam.basis())
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        rel = corners - np.asarray(cam.position)
        t = math.tan(math.radians(cam.fovy_deg) / 2)
        sx = np.abs(rel @ right) / (rel @ forward) / (t * 1.5)
        sy = np.abs(rel @ up) / (rel @ forward) / t
        assert max(sx.max(), sy.max()) <= 1.0  # all of it in view
        assert max(sx.max(), sy.max()) >= 0.9  # and filling it, the 5 % margin aside
    finally:
        doc.close()
