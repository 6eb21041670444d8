"""Navigation maths and the Navigator state machine, without a window."""

from __future__ import annotations

import math

import numpy as np
import pytest

from citylod.app.navigation import Navigator, dolly, look, orbit, pan
from citylod.core.camera import Camera
from citylod.render.hud import box_planes, nice_length, north_on_screen


def _cam() -> Camera:
    return Camera((100.0, -200.0, 150.0), (100.0, 0.0, 0.0))


def test_orbit_is_a_turntable() -> None:
    cam = _cam()
    out = orbit(cam, 30.0, 10.0)
    # Focal point fixed, distance kept, right vector horizontal (no roll).
    assert out.focal_point == cam.focal_point
    d0 = np.linalg.norm(np.subtract(cam.position, cam.focal_point))
    assert np.linalg.norm(np.subtract(out.position, out.focal_point)) == pytest.approx(d0)
    assert abs(out.basis()[0][2]) < 1e-12
    # Azimuth about world z: the height of the eye changes only with the elevation step.
    flat = orbit(cam, 77.0, 0.0)
    assert flat.position[2] == pytest.approx(cam.position[2])
    # Never over the zenith.
    top = orbit(cam, 0.0, 500.0)
    el = math.degrees(math.asin((top.position[2] - top.focal_point[2]) / d0))
    assert el == pytest.approx(89.0)


def test_look_keeps_the_eye_and_pan_moves_both() -> None:
    cam = _cam()
    out = look(cam, 20.0, -5.0)
    assert out.position == cam.position and out.focal_point != cam.focal_point
    p = pan(cam, 100, 0, 500)
    shift = np.subtract(p.position, cam.position)
    np.testing.assert_allclose(shift, np.subtract(p.focal_point, cam.focal_point))
    # 100 px of 500 at the focal distance: 100/500 of the visible height there, opposite to the drag.
    d = np.linalg.norm(np.subtract(cam.position, cam.focal_point))
    visible = 2 * d * math.tan(math.radians(cam.fovy_deg) / 2)
    assert np.linalg.norm(shift) == pytest.approx(visible * 100 / 500)
    assert shift @ cam.basis()[0] < 0


def test_dolly_towards_a_point_keeps_it_fixed_on_the_view_ray() -> None:
    cam = _cam()
    target = np.array([120.0, 10.0, 5.0])
    out = dolly(cam, 0.5, target)
    before = target - np.asarray(cam.position)
    after = target - np.asarray(out.position)
    np.testing.assert_allclose(after / np.linalg.norm(after), before / np.linalg.norm(before), atol=1e-12)
    assert np.linalg.norm(after) == pytest.approx(np.linalg.norm(before) / 2)


def test_navigator_clicks_drags_and_coalesces_the_wheel() -> None:
    now = [0.0]
    cams = [_cam()]
    nav = Navigator(lambda: cams[-1], cams.append, clock=lambda: now[0])
    nav.press("left", 10, 10)
    nav.move(12, 11, 500)  # within the click tolerance: no camera change
    assert nav.release("left", 12, 11) and len(cams) == 1
    nav.press("left", 10, 10)
    assert nav.move(60, 10, 500) and nav.moving
    assert not nav.release("left", 60, 10)
    n = len(cams)
    for _ in range(5):
        nav.wheel(1.0)
    assert nav.moving and len(cams) == n  # queued, not applied per event
    assert nav.flush() and len(cams) == n + 1
    d0 = np.linalg.norm(np.subtract(cams[n - 1].position, cams[n - 1].focal_point))
    d1 = np.linalg.norm(np.subtract(cams[-1].position, cams[-1].focal_point))
    assert d1 == pytest.approx(d0 * nav.wheel_factor ** 5)
    now[0] += nav.settle_s + 0.01
    assert not nav.moving
    with pytest.raises(ValueError):
        nav.set_mode("trackball")


def test_hud_maths() -> None:
    assert nice_length(0.37, 120) == (20.0, pytest.approx(20 / 0.37))
    # Straight down with north up on screen, then turned: the arrow turns with the heading.
    down = Camera((0.0, 0.0, 100.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    assert north_on_screen(down) == pytest.approx((0.0, 1.0))
    east_up = Camera((0.0, 0.0, 100.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0))
    assert north_on_screen(east_up) == pytest.approx((-1.0, 0.0))
    planes = box_planes((0, 0, 0), (10, 20, 30), (5, 5, 5))
    inside = np.array([0.0, 0.0, 0.0])  # (5, 5, 5) shifted by the origin
    assert all((inside - p) @ n > 0 for p, n in planes)


@pytest.mark.parametrize("up", [(0.0, 0.0, 1.0), (0.6, -0.3, 0.74), (0.0, 1.0, 0.0)])
def test_orbit_turns_about_the_given_vertical(up: tuple[float, float, float]) -> None:
    """The turntable about the data's vertical (the local up of ECEF data): view up is that vertical, the
    eye's height along it is kept by an azimuth step, the right vector stays level, and it never passes
    the zenith. For z it is the world-z turntable exactly."""
    u = np.asarray(up) / np.linalg.norm(up)
    focal = np.array([10.0, 20.0, 30.0])
    side = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    cam = Camera(tuple(focal + 50.0 * side / np.linalg.norm(side) + 20.0 * u), tuple(focal), tuple(u))
    out = orbit(cam, 77.0, 0.0, up)
    assert np.allclose(out.view_up, u)
    assert np.subtract(out.position, focal) @ u == pytest.approx(20.0)
    assert np.linalg.norm(np.subtract(out.position, focal)) == pytest.approx(np.linalg.norm(np.subtract(cam.position, focal)))
    assert abs(out.basis()[0] @ u) < 1e-9  # no roll
    top = orbit(cam, 0.0, 200.0, up)
    elevation = math.degrees(math.asin(np.subtract(top.position, focal) @ u / np.linalg.norm(np.subtract(top.position, focal))))
    assert elevation == pytest.approx(89.0)
    back = orbit(orbit(orbit(orbit(cam, 90.0, 0.0, up), 90.0, 0.0, up), 90.0, 0.0, up), 90.0, 0.0, up)
    assert np.allclose(back.position, cam.position)
    turned = look(cam, 30.0, 0.0, up)
    assert turned.position == cam.position and np.allclose(turned.view_up, u)
    assert np.subtract(turned.focal_point, cam.position) @ u == pytest.approx(np.subtract(focal, cam.position) @ u)
    if np.allclose(u, [0, 0, 1]):
        assert orbit(cam, 33.0, 12.0, up) == orbit(cam, 33.0, 12.0)


def test_navigator_turns_about_the_data_vertical() -> None:
    up = np.array([0.6, -0.3, 0.74]) / np.linalg.norm([0.6, -0.3, 0.74])
    cams: list[Camera] = [Camera((50.0, 0.0, 0.0), (0.0, 0.0, 0.0), tuple(up))]
    nav = Navigator(lambda: cams[-1], cams.append, get_up=lambda: up)
    nav.press("left", 100, 100)
    assert nav.move(160, 100, 600)
    assert np.allclose(cams[-1].view_up, up)
    assert np.asarray(cams[-1].position) @ up == pytest.approx(np.asarray(cams[0].position) @ up)
