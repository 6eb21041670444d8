from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from citylod.core.camera import Camera, View, load_cameras, screen_space_error
from citylod.core.errors import InputError
from citylod.core.geometry import Box, Sphere


def test_sse_formula_matches_hand_computation() -> None:
    # 1 m error at 100 m, 1000 px high, 90° fov: 1000 / (2·100·tan 45°) = 5 px
    assert screen_space_error(1.0, 100.0, 1000, math.pi / 2) == pytest.approx(5.0)
    assert screen_space_error(1.0, 0.0, 1000, 1.0) == math.inf


def test_frustum_culls_behind_and_keeps_in_front() -> None:
    cam = Camera((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), 60.0)
    view = View(cam, 800, 600)
    assert not view.cull_box(Box.from_bounds([-1, 9, -1], [1, 11, 1]))
    assert view.cull_box(Box.from_bounds([-1, -11, -1], [1, -9, 1]))
    assert view.cull_box(Box.from_bounds([100, 9, -1], [102, 11, 1]))  # far off to the right
    assert not view.cull_sphere(Sphere(np.array([0.0, 5.0, 0.0]), 1.0))
    assert view.cull_sphere(Sphere(np.array([0.0, -5.0, 0.0]), 1.0))


def test_box_3dtiles_roundtrip_and_distance() -> None:
    box = Box.from_bounds([0, 0, 0], [2, 4, 6])
    again = Box.from_3dtiles(box.to_3dtiles())
    np.testing.assert_allclose(again.center, box.center)
    np.testing.assert_allclose(again.half_axes, box.half_axes)
    assert box.distance([1, 2, 3]) == 0.0
    assert box.distance([5, 2, 3]) == pytest.approx(3.0)
    lo, hi = box.bounds()
    np.testing.assert_allclose(lo, [0, 0, 0])
    np.testing.assert_allclose(hi, [2, 4, 6])


def test_camera_file_roundtrip_and_errors(tmp_path) -> None:
    cam = Camera((500000.0, 5.4e6, 300.0), (500100.0, 5.4e6 + 100, 0.0), fovy_deg=40)
    p = tmp_path / "cam.json"
    cam.save(p)
    assert load_cameras(p) == [cam]
    (tmp_path / "path.json").write_text(json.dumps({"cameras": [cam.to_dict(), cam.to_dict()]}))
    assert len(load_cameras(tmp_path / "path.json")) == 2
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(InputError, match="bad.json"):
        load_cameras(tmp_path / "bad.json")
    (tmp_path / "bad2.json").write_text('{"position": [1, 2]}')
    with pytest.raises(InputError, match="bad2.json"):
        load_cameras(tmp_path / "bad2.json")


def test_camera_close_to_its_focal_point_at_ecef_coordinates() -> None:
    """A camera 10 m (and 1 mm) from its focal point at ECEF magnitude is a camera, not a coincidence:
    the closeness test is absolute, in metres, not numpy's relative tolerance."""
    foc = np.array([3924000.0, 301000.0, 5002000.0])
    for offset_m in (10.0, 1e-3):
        cam = Camera(tuple(foc + [0.0, 0.0, offset_m]), tuple(foc))
        assert np.allclose(cam.direction, [0, 0, -1])
    with pytest.raises(ValueError, match="coincide"):
        Camera(tuple(foc), tuple(foc))


BOXES = [
    ((500_000.0, 5_400_000.0, 0.0), (504_000.0, 5_404_000.0, 50.0)),  # a flat city at UTM coordinates
    ((0.0, 0.0, 0.0), (10.0, 10.0, 300.0)),  # a tower
    ((-5.0, -5.0, -5.0), (5.0, 5.0, 5.0)),  # a cube
]


@pytest.mark.parametrize("box", BOXES)
@pytest.mark.parametrize("azimuth, elevation", [(200.0, 40.0), (0.0, 90.0), (77.0, 5.0), (315.0, 60.0)])
@pytest.mark.parametrize("width, height", [(960, 540), (300, 600)])
def test_framing_camera_holds_the_box_tightly(box, azimuth, elevation, width, height) -> None:
    """Every corner is in the frustum (the view's own planes, computed apart from the framing), and 10 %
    closer some corner would not be: the box fills the frame."""
    from citylod.core.camera import framing_camera

    lo, hi = np.array(box[0]), np.array(box[1])
    cam = framing_camera(lo, hi, azimuth_deg=azimuth, elevation_deg=elevation, aspect=width / height)
    b = Box.from_bounds(lo, hi)
    assert View(cam, width, height, near=1e-6).box_in_frustum(b) == (False, True)
    centre = (lo + hi) / 2
    eye = np.array(cam.position)
    closer = Camera(tuple(centre + 0.9 * (eye - centre)), cam.focal_point, cam.view_up, cam.fovy_deg)
    assert not View(closer, width, height, near=1e-6).box_in_frustum(b)[1]


def test_built_in_cameras_and_their_errors(tmp_path, monkeypatch) -> None:
    from citylod.core.camera import built_in_camera, cameras_for

    lo, hi = np.zeros(3), np.array([100.0, 80.0, 20.0])
    assert built_in_camera(None) == ("overview", 1)
    assert built_in_camera("orbit") == ("orbit", 36)
    assert built_in_camera("orbit:5") == ("orbit", 5)
    orbit = cameras_for("orbit:4", lo, hi)
    assert len(orbit) == 4 and len({c.position for c in orbit}) == 4
    # One distance (no zooming in and out), every frame holding the whole box.
    assert len({round(float(np.linalg.norm(np.subtract(c.position, c.focal_point))), 6) for c in orbit}) == 1
    for c in cameras_for("orbit:8", lo, hi, aspect=960 / 540):
        assert View(c, 960, 540, near=1e-6).box_in_frustum(Box.from_bounds(lo, hi)) == (False, True)
    for bad in ("orbit:0", "overview:2", "orbit:1000001"):
        with pytest.raises(InputError, match=r"--camera"):
            built_in_camera(bad)
    monkeypatch.chdir(tmp_path)  # a camera file called "orbit" wins over the keyword
    Path("orbit").write_text(json.dumps(orbit[1].to_dict()))
    assert built_in_camera("orbit") is None
    assert cameras_for("orbit", lo, hi) == [orbit[1]]


def test_framing_a_geocentric_box_looks_down_the_local_vertical() -> None:
    """Data in ECEF (other tools' tilesets): azimuth and elevation are taken around the local vertical, so
    the overview looks down on the data at 40° from the south-south-west, not along the Earth's axis."""
    import pyproj

    from citylod.core.camera import cameras_for, local_up

    ecef = pyproj.CRS("EPSG:4978")
    to_ecef = pyproj.Transformer.from_crs("EPSG:4979", ecef, always_xy=True)
    lon, lat = -75.6, 40.0
    centre = np.array(to_ecef.transform(lon, lat, 10.0))
    lo, hi = centre - 150.0, centre + 150.0
    up = local_up(ecef, lo, hi)
    lam, phi = math.radians(lon), math.radians(lat)
    normal = np.array([math.cos(phi) * math.cos(lam), math.cos(phi) * math.sin(lam), math.sin(phi)])
    assert math.degrees(math.acos(float(up @ normal))) < 0.2  # the ellipsoid's normal, to 0.2°
    cam = cameras_for(None, lo, hi, aspect=1.5, up=up)[0]
    d = np.subtract(cam.position, cam.focal_point)
    assert math.degrees(math.asin(float(d @ up) / float(np.linalg.norm(d)))) == pytest.approx(40.0, abs=1e-6)
    assert np.allclose(cam.view_up, up)
    assert View(cam, 960, 640, near=1e-3).box_in_frustum(Box.from_bounds(lo, hi)) == (False, True)
    assert np.allclose(local_up(pyproj.CRS("EPSG:25832"), lo, hi), [0.0, 0.0, 1.0])
