"""Camera navigation of the 3D view as plain functions and one state machine (no Qt, no VTK).

GIS users expect a *turntable*: the horizon stays level whatever the mouse does, left drag turns the
camera about the vertical axis through the focal point and tilts it up and down, never past the zenith
(QGIS 3D, Potree's "orbit" control). VTK's trackball rolls the horizon, and its interactor style grabs the
mouse on press so an application never sees the release; the view therefore handles the mouse itself and
calls :class:`Navigator`, which calls these functions.

* :func:`orbit` — turntable about the vertical (world z, or the local vertical of geocentric data);
  :func:`look` — the same about the eye (fly mode);
* :func:`pan` — the point under the cursor follows the cursor; :func:`dolly` — towards the focal point
  or towards a picked point;
* :class:`Navigator` — mouse press / move / release / wheel to camera changes, click detection, wheel
  steps coalesced into one change per frame, and whether the camera is moving (the view draws coarser
  while it is, :meth:`citylod.app.models.Document.set_moving`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from citylod.core.camera import Camera, enu_axes

__all__ = ["NAV_MODES", "Navigator", "dolly", "look", "orbit", "pan"]

NAV_MODES = ("turntable", "fly")
_MAX_ELEVATION_DEG = 89.0
_Z = np.array([0.0, 0.0, 1.0])


def _spherical(v: npt.NDArray[np.float64]) -> tuple[float, float, float]:
    r = float(np.linalg.norm(v))
    if r == 0.0:
        return 0.0, 0.0, 0.0
    return r, math.atan2(v[1], v[0]), math.asin(max(-1.0, min(1.0, v[2] / r)))


def _cartesian(r: float, az: float, el: float) -> npt.NDArray[np.float64]:
    return r * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def _turn(v: npt.NDArray[np.float64], d_az_deg: float, d_el_deg: float,
          up: npt.ArrayLike = _Z) -> npt.NDArray[np.float64]:
    """``v`` turned by d_az about ``up`` and tilted by d_el towards it, the tilt clamped below ±89°."""
    rot = enu_axes(up)
    r, az, el = _spherical(rot.T @ v)
    lim = math.radians(_MAX_ELEVATION_DEG)
    el = min(max(el + math.radians(d_el_deg), -lim), lim)
    return rot @ _cartesian(r, az + math.radians(d_az_deg), el)


def orbit(camera: Camera, d_azimuth_deg: float, d_elevation_deg: float, up: npt.ArrayLike = _Z) -> Camera:
    """Turntable orbit: the eye turns about the vertical axis through the focal point by ``d_azimuth_deg``
    and rises by ``d_elevation_deg``; view up stays the vertical ``up`` (world z; the local vertical of
    geocentric data), so the horizon never rolls.

    The elevation is clamped to ±89°: at the zenith the view direction would be parallel to view up.

    Examples
    --------
    >>> cam = orbit(Camera((0.0, -10.0, 0.0), (0.0, 0.0, 0.0)), 90.0, 0.0)
    >>> [float(round(v, 6)) + 0.0 for v in cam.position], cam.view_up
    ([10.0, 0.0, 0.0], (0.0, 0.0, 1.0))
    """
    f = np.asarray(camera.focal_point, np.float64)
    eye = f + _turn(np.subtract(camera.position, f), d_azimuth_deg, d_elevation_deg, up)
    return Camera(tuple(eye), camera.focal_point, _vertical(up), camera.fovy_deg)  # type: ignore[arg-type]


def look(camera: Camera, d_yaw_deg: float, d_pitch_deg: float, up: npt.ArrayLike = _Z) -> Camera:
    """Fly-mode look: the view direction turns about the eye (yaw about ``up``, pitch towards it), horizon
    level."""
    eye = np.asarray(camera.position, np.float64)
    focal = eye + _turn(np.subtract(camera.focal_point, eye), d_yaw_deg, d_pitch_deg, up)
    return Camera(camera.position, tuple(focal), _vertical(up), camera.fovy_deg)  # type: ignore[arg-type]


def _vertical(up: npt.ArrayLike) -> tuple[float, float, float]:
    """``up`` as a unit view-up tuple (the third axis of its east / north / up frame)."""
    return tuple(float(v) for v in enu_axes(up)[:, 2])  # type: ignore[return-value]


def pan(camera: Camera, dx_px: float, dy_px: float, height_px: int) -> Camera:
    """Move eye and focal point in the view plane so that a point at the focal distance follows a mouse
    motion of (dx_px right, dy_px down) on a view ``height_px`` tall."""
    right, up, _fwd = camera.basis()
    dist = float(np.linalg.norm(np.subtract(camera.position, camera.focal_point)))
    metres_per_px = 2.0 * dist * math.tan(math.radians(camera.fovy_deg) / 2.0) / max(height_px, 1)
    move = (-dx_px * right + dy_px * up) * metres_per_px
    return Camera(tuple(np.add(camera.position, move)), tuple(np.add(camera.focal_point, move)),  # type: ignore[arg-type]
                  camera.view_up, camera.fovy_deg)


def dolly(camera: Camera, factor: float, toward: npt.ArrayLike | None = None, *,
          min_distance: float = 0.5) -> Camera:
    """Scale the eye's distance by ``factor`` (< 1 moves closer): about the focal point, or about ``toward``
    (the surface point under the cursor, so that point stays under it: eye and focal point both scale)."""
    eye = np.asarray(camera.position, np.float64)
    focal = np.asarray(camera.focal_point, np.float64)
    centre = focal if toward is None else np.asarray(toward, np.float64)
    dist = float(np.linalg.norm(eye - centre))
    if dist * factor < min_distance:
        factor = min_distance / max(dist, 1e-9)
    new_eye = centre + (eye - centre) * factor
    new_focal = focal if toward is None else centre + (focal - centre) * factor
    return Camera(tuple(new_eye), tuple(new_focal), camera.view_up, camera.fovy_deg)  # type: ignore[arg-type]


class Navigator:
    """Mouse input to camera changes, with click detection, wheel coalescing and a motion clock.

    Parameters
    ----------
    get_camera, set_camera
        Read and write the view's camera.
    clock
        Seconds (monotonic); replaceable in tests.

    Buttons are ``"left"``, ``"middle"``, ``"right"``. Turntable mode: left drag orbits, middle drag (or
    shift + left) pans, right drag dollies, the wheel dollies towards the point under the cursor. Fly
    mode: left drag looks around from the eye, the wheel moves forward and back. A press and release
    within :attr:`click_px` pixels is a click, not a drag.
    """

    click_px = 4
    degrees_per_px = 0.35
    wheel_factor = 0.85  # distance kept per wheel notch
    settle_s = 0.25  # no motion for this long: the camera has stopped, refine

    def __init__(self, get_camera: Callable[[], Camera | None], set_camera: Callable[[Camera], None], *,
                 clock: Callable[[], float] = time.monotonic,
                 get_up: Callable[[], npt.ArrayLike] | None = None) -> None:
        self.get_camera = get_camera
        self.set_camera = set_camera
        self.clock = clock
        self.mode = "turntable"
        self._button: str | None = None
        self._press = (0, 0)
        self._last = (0, 0)
        self._dragging = False
        self._pan = False
        self._wheel_steps = 0.0
        self._wheel_toward: npt.NDArray[np.float64] | None = None
        self.last_motion_s = -math.inf  # clock() of the last camera change
        self.get_up = get_up  # the turntable's axis, the data's vertical (None: world z)

    def set_mode(self, mode: str) -> None:
        if mode not in NAV_MODES:
            raise ValueError(f"navigation mode must be one of {', '.join(NAV_MODES)}, got {mode!r}")
        self.mode = mode

    # -- motion clock ----------------------------------------------------------------------------
    def _moved(self) -> None:
        self.last_motion_s = self.clock()

    @property
    def moving(self) -> bool:
        """A drag is under way, a wheel step is pending, or the camera moved less than ``settle_s`` ago."""
        return (self._dragging or self._wheel_steps != 0.0
                or self.clock() - self.last_motion_s < self.settle_s)

    # -- mouse ------------------------------------------------------------------------------------
    def press(self, button: str, x: int, y: int, *, shift: bool = False) -> None:
        self._button = button
        self._press = self._last = (x, y)
        self._dragging = False
        self._pan = button == "middle" or (button == "left" and shift)

    def move(self, x: int, y: int, height_px: int) -> bool:
        """Mouse at widget (x, y); returns True when the camera changed."""
        if self._button is None:
            return False
        if not self._dragging:
            if max(abs(x - self._press[0]), abs(y - self._press[1])) <= self.click_px:
                return False
            self._dragging = True
        dx, dy = x - self._last[0], y - self._last[1]
        self._last = (x, y)
        cam = self.get_camera()
        if cam is None or (dx == 0 and dy == 0):
            return False
        k = self.degrees_per_px
        if self._pan:
            cam = pan(cam, dx, dy, height_px)
        elif self._button == "left":
            # Dragging right turns the scene right (the eye goes left); dragging up tilts towards the horizon.
            up = _Z if self.get_up is None else self.get_up()
            cam = (orbit(cam, -dx * k, dy * k, up) if self.mode == "turntable"
                   else look(cam, -dx * k * 0.5, -dy * k * 0.5, up))
        elif self._button == "right":
            cam = dolly(cam, math.exp(dy * 0.01))
        else:
            return False
        self.set_camera(cam)
        self._moved()
        return True

    def release(self, button: str, x: int, y: int) -> bool:
        """Button released; True when press and release made a click."""
        if self._button != button:
            return False
        click = not self._dragging and max(abs(x - self._press[0]), abs(y - self._press[1])) <= self.click_px
        if self._dragging:
            self._moved()
        self._button = None
        self._dragging = False
        return click

    def wheel(self, notches: float, toward: npt.ArrayLike | None = None) -> None:
        """Queue wheel notches (positive: zoom in); :meth:`flush` applies all queued notches as one step."""
        self._wheel_steps += float(notches)
        if toward is not None:
            self._wheel_toward = np.asarray(toward, np.float64)

    def flush(self) -> bool:
        """Apply the queued wheel notches in one camera change (once per frame); True when it changed."""
        steps, toward = self._wheel_steps, self._wheel_toward
        self._wheel_steps, self._wheel_toward = 0.0, None
        if steps == 0.0:
            return False
        cam = self.get_camera()
        if cam is None:
            return False
        if self.mode == "fly":
            dist = float(np.linalg.norm(np.subtract(cam.position, cam.focal_point)))
            move = cam.direction * dist * 0.1 * steps
            cam = Camera(tuple(np.add(cam.position, move)), tuple(np.add(cam.focal_point, move)),  # type: ignore[arg-type]
                         cam.view_up, cam.fovy_deg)
        else:
            cam = dolly(cam, self.wheel_factor ** steps, toward)
        self.set_camera(cam)
        self._moved()
        return True
