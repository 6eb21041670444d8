"""Camera, view and the one screen-space-error function.

The camera file that ``citylod render`` reads is this JSON (coordinates in the source CRS of the data,
angles in degrees)::

    {"position": [x, y, z], "focal_point": [x, y, z], "view_up": [0, 0, 1], "fovy_deg": 45.0}

A camera path is a JSON list of such objects, or ``{"cameras": [...]}``. Instead of a file, ``citylod render
--camera`` also takes ``overview`` (the default: the whole dataset in view) or
``orbit[:N]`` (N cameras around it, :func:`orbit_cameras`), built by :func:`framing_camera`;
:func:`cameras_for` reads either.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from citylod.core.errors import InputError
from citylod.core.geometry import F64, Box, Sphere

_COINCIDE_M = 1e-6  # position and focal point closer than this (CRS units, metres) are one point


def screen_space_error(geometric_error: float, distance: float, height_px: int, fovy_rad: float) -> float:
    """The screen-space error in pixels of a tile seen at ``distance``.

    ``sse_px = geometricError · H_px / (2 · d · tan(fovy/2))`` (Wahl et al. 2004 with the isotropic
    bound; the same formula as CesiumJS). A viewer inside the bounding volume (d = 0) sees an infinite
    error, so the tile always refines.
    """
    if distance <= 0.0:
        return math.inf if geometric_error > 0 else 0.0
    return geometric_error * height_px / (2.0 * distance * math.tan(fovy_rad / 2.0))


@dataclass(frozen=True)
class Camera:
    """A perspective camera in the source CRS (metres unless the CRS says otherwise)."""

    position: tuple[float, float, float]
    focal_point: tuple[float, float, float]
    view_up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fovy_deg: float = 45.0

    def __post_init__(self) -> None:
        pos = np.asarray(self.position, dtype=np.float64)
        foc = np.asarray(self.focal_point, dtype=np.float64)
        if pos.shape != (3,) or foc.shape != (3,) or not (np.all(np.isfinite(pos)) and np.all(np.isfinite(foc))):
            raise ValueError("camera position and focal_point must be three finite numbers each")
        # An absolute tolerance in CRS units (metres): np.allclose's relative one called a camera 40 m from its
        # focal point "coincident" at UTM or ECEF coordinates. A micrometre is far above float64 resolution at
        # ECEF magnitudes (≈1 nm), so the view direction of any accepted camera is well defined.
        if float(np.linalg.norm(pos - foc)) <= _COINCIDE_M:
            raise ValueError("camera position and focal_point coincide")
        if not 0.0 < self.fovy_deg < 180.0:
            raise ValueError(f"fovy_deg must be in (0, 180), got {self.fovy_deg}")
        up = np.asarray(self.view_up, dtype=np.float64)
        if up.shape != (3,) or not np.all(np.isfinite(up)) or not np.any(up):
            raise ValueError("camera view_up must be three finite numbers, not all zero")

    @property
    def direction(self) -> F64:
        """Unit view direction (3,)."""
        d = np.subtract(self.focal_point, self.position, dtype=np.float64)
        return d / np.linalg.norm(d)

    def basis(self) -> tuple[F64, F64, F64]:
        """Orthonormal (right, up, forward) of the camera; ``up`` is ``view_up`` made orthogonal."""
        fwd = self.direction
        up = np.asarray(self.view_up, dtype=np.float64)
        right = np.cross(fwd, up)
        if np.linalg.norm(right) < 1e-9:  # looking along view_up: pick any perpendicular
            right = np.cross(fwd, [1.0, 0.0, 0.0] if abs(fwd[0]) < 0.9 else [0.0, 1.0, 0.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, fwd).astype(np.float64)
        return right.astype(np.float64), up, fwd

    def to_dict(self) -> dict[str, Any]:
        return {
            "position": [float(v) for v in self.position],
            "focal_point": [float(v) for v in self.focal_point],
            "view_up": [float(v) for v in self.view_up],
            "fovy_deg": float(self.fovy_deg),
        }

    @staticmethod
    def from_dict(d: dict[str, Any], source: str | None = None) -> Camera:
        try:
            return Camera(
                position=tuple(float(v) for v in d["position"]),  # type: ignore[arg-type]
                focal_point=tuple(float(v) for v in d["focal_point"]),  # type: ignore[arg-type]
                view_up=tuple(float(v) for v in d.get("view_up", (0.0, 0.0, 1.0))),  # type: ignore[arg-type]
                fovy_deg=float(d.get("fovy_deg", 45.0)),
            )
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise InputError(f"not a camera ({str(exc)[:200]})", source) from exc

    def save(self, path: str | PathLike[str]) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")


def load_cameras(path: str | PathLike[str]) -> list[Camera]:
    """Read a camera file: one camera object, a list of them, or ``{"cameras": [...]}``."""
    try:
        data = json.loads(Path(path).read_bytes())
    except OSError as exc:
        raise InputError(f"cannot read camera file ({exc.strerror})", path) from exc
    except RecursionError as exc:
        raise InputError("camera file is not readable JSON (nested too deeply)", path) from exc
    except (ValueError, UnicodeDecodeError) as exc:  # JSONDecodeError, numbers of thousands of digits
        raise InputError(f"camera file is not JSON ({str(exc)[:200]})", path) from exc
    if isinstance(data, dict) and "cameras" in data:
        data = data["cameras"]
    items = data if isinstance(data, list) else [data]
    if not items:
        raise InputError("camera path is empty", path)
    return [Camera.from_dict(item, str(path)) if isinstance(item, dict) else _bad(path) for item in items]


def _bad(path: str | PathLike[str]) -> Camera:
    raise InputError("camera entries must be JSON objects", path)


@dataclass(frozen=True)
class View:
    """A camera with a viewport: what selection needs to know about a frame.

    ``planes`` are the six frustum planes (6, 4) as ``n·x + d >= 0`` inside, near and far included.
    """

    camera: Camera
    width_px: int
    height_px: int
    near: float = 0.1
    far: float = 1e7
    planes: F64 = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.width_px <= 0 or self.height_px <= 0:
            raise ValueError("viewport must be at least 1×1 pixels")
        object.__setattr__(self, "planes", _frustum_planes(self))

    @property
    def fovy_rad(self) -> float:
        return math.radians(self.camera.fovy_deg)

    @property
    def eye(self) -> F64:
        return np.asarray(self.camera.position, dtype=np.float64)

    def sse(self, geometric_error: float, distance: float) -> float:
        """Screen-space error of ``geometric_error`` at ``distance`` in this view, pixels."""
        return screen_space_error(geometric_error, distance, self.height_px, self.fovy_rad)

    def pixel_footprint(self, distance: float) -> float:
        """Object-space size of one pixel at ``distance`` along the view axis."""
        return 2.0 * distance * math.tan(self.fovy_rad / 2.0) / self.height_px

    def cull_box(self, box: Box) -> bool:
        """True if ``box`` lies entirely outside the frustum (conservative: False when unsure)."""
        return self.box_in_frustum(box)[0]

    def box_in_frustum(self, box: Box) -> tuple[bool, bool]:
        """(entirely outside, entirely inside) the frustum for ``box``, both conservative: False when unsure.
        The first is :meth:`cull_box`."""
        # Projected radius of an oriented box on a plane normal: sum |n · half_axis_i|.
        n = self.planes[:, :3]
        dist = n @ box.center + self.planes[:, 3]
        radius = np.abs(n @ box.half_axes).sum(axis=1)
        return bool((dist < -radius).any()), bool((dist >= radius).all())

    def cull_sphere(self, sphere: Sphere) -> bool:
        """True if ``sphere`` lies entirely outside the frustum."""
        dist = self.planes[:, :3] @ sphere.center + self.planes[:, 3]
        return bool(np.any(dist < -sphere.radius))

    def depth_of(self, points: npt.ArrayLike) -> F64:
        """Distance along the view axis of ``points`` (N, 3)."""
        return (np.asarray(points, dtype=np.float64) - self.eye) @ self.camera.direction


def _frustum_planes(view: View) -> F64:
    right, up, fwd = view.camera.basis()
    eye = view.eye
    ty = math.tan(view.fovy_rad / 2.0)
    tx = ty * view.width_px / view.height_px
    normals = [
        fwd,  # near
        -fwd,  # far
        _unit(fwd * tx + right),  # left: inward normal
        _unit(fwd * tx - right),  # right
        _unit(fwd * ty + up),  # bottom
        _unit(fwd * ty - up),  # top
    ]
    planes = np.empty((6, 4))
    for i, nrm in enumerate(normals):
        planes[i, :3] = nrm
        planes[i, 3] = -float(nrm @ eye)
    planes[0, 3] = -float(fwd @ eye) - view.near
    planes[1, 3] = float(fwd @ eye) + view.far
    return planes


def _unit(v: F64) -> F64:
    return v / np.linalg.norm(v)


def overview_camera(lo: npt.ArrayLike, hi: npt.ArrayLike, *, fovy_deg: float = 45.0, azimuth_deg: float = 200.0,
                    elevation_deg: float = 40.0, aspect: float = 1.5) -> Camera:
    """A camera that sees the whole box ``lo``–``hi`` (3,), from the south-south-west, looking down.

    The distance makes the bounding sphere fit the narrower field of view.
    """
    lo_a, hi_a = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    centre = (lo_a + hi_a) / 2.0
    radius = max(float(np.linalg.norm(hi_a - lo_a)) / 2.0, 1.0)
    half = math.radians(fovy_deg) / 2.0
    half = min(half, math.atan(math.tan(half) * aspect))
    dist = radius / math.sin(half) * 0.85
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    offset = np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)]) * dist
    return Camera(tuple(centre + offset), tuple(centre), (0.0, 0.0, 1.0), fovy_deg)  # type: ignore[arg-type]


def framing_camera(lo: npt.ArrayLike, hi: npt.ArrayLike, *, fovy_deg: float = 45.0, azimuth_deg: float = 200.0,
                   elevation_deg: float = 40.0, aspect: float = 1.5, margin: float = 0.05,
                   up: npt.ArrayLike = (0.0, 0.0, 1.0)) -> Camera:
    """A camera looking at the centre of the box ``lo``–``hi`` from ``azimuth_deg`` (clockwise from north)
    and ``elevation_deg``, as close as it can be with all eight corners in view, ``margin`` of the view's
    half-size kept free at each side: what a user means by "show all of it".

    ``up``: the local vertical in the data's frame (z for projected CRSs; away from the Earth's centre for
    geocentric ones, where azimuth and elevation are taken in the local east / north / up frame).

    :func:`overview_camera` fits the bounding sphere instead, which leaves a flat city small in the frame;
    the benchmarks keep it (their overview rows are measured from it).
    """
    back, dist = _framing(lo, hi, fovy_deg, azimuth_deg, elevation_deg, aspect, margin, up)
    centre = (np.asarray(lo, np.float64) + np.asarray(hi, np.float64)) / 2.0
    return Camera(tuple(centre + back * dist), tuple(centre), tuple(_unit(np.asarray(up, np.float64))),  # type: ignore[arg-type]
                  fovy_deg)


def _framing(lo: npt.ArrayLike, hi: npt.ArrayLike, fovy_deg: float, azimuth_deg: float, elevation_deg: float,
             aspect: float, margin: float, up: npt.ArrayLike = (0.0, 0.0, 1.0)) -> tuple[F64, float]:
    """The unit vector from the box's centre to the eye, and the least distance that holds the box.

    Each corner ``p`` (relative to the centre, in the camera's right / up / forward axes) is in view from
    distance ``D`` when ``|p·right| ≤ tan(h_x)·(D + p·forward)``, and likewise for ``up`` with ``h_y``:
    ``D`` is the largest of these bounds over the corners (and puts every corner in front of the eye).
    """
    lo_a, hi_a = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    centre = (lo_a + hi_a) / 2.0
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    east, north, vertical = enu_axes(up).T
    back = (math.sin(az) * math.cos(el)) * east + (math.cos(az) * math.cos(el)) * north + math.sin(el) * vertical
    # The axes the renderer will use (straight down, view_up is along the view and basis() picks one).
    right, up, forward = Camera(tuple(centre + back), tuple(centre), tuple(vertical), fovy_deg).basis()  # type: ignore[arg-type]
    ty = math.tan(math.radians(fovy_deg) / 2.0) * (1.0 - margin)
    tx = math.tan(math.radians(fovy_deg) / 2.0) * aspect * (1.0 - margin)
    corners = np.array([[x, y, z] for x in (lo_a[0], hi_a[0]) for y in (lo_a[1], hi_a[1])
                        for z in (lo_a[2], hi_a[2])]) - centre
    pr, pu, pf = corners @ right, corners @ up, corners @ forward
    dist = float(max(np.max(np.abs(pr) / tx - pf), np.max(np.abs(pu) / ty - pf), np.max(-pf) * 1.001, 1.0))
    return back, dist


def orbit_cameras(lo: npt.ArrayLike, hi: npt.ArrayLike, n: int = 36, *, fovy_deg: float = 45.0,
                  elevation_deg: float = 40.0, aspect: float = 1.5, margin: float = 0.05,
                  up: npt.ArrayLike = (0.0, 0.0, 1.0)) -> list[Camera]:
    """``n`` cameras once around the box ``lo``–``hi`` (a turntable), starting from the overview's azimuth,
    all at one distance: the least that holds the whole box from every one of them
    (:func:`framing_camera`'s, at its largest), so the frames do not zoom in and out."""
    if n < 1:
        raise ValueError(f"an orbit needs at least one camera, got {n}")
    centre = (np.asarray(lo, np.float64) + np.asarray(hi, np.float64)) / 2.0
    ways = [_framing(lo, hi, fovy_deg, 200.0 + 360.0 * i / n, elevation_deg, aspect, margin, up) for i in range(n)]
    dist = max(d for _, d in ways)
    vertical = tuple(_unit(np.asarray(up, np.float64)))
    return [Camera(tuple(centre + back * dist), tuple(centre), vertical, fovy_deg)  # type: ignore[arg-type]
            for back, _ in ways]


_BUILT_IN = re.compile(r"(overview|orbit)(?::(\d+))?")


def built_in_camera(spec: str | PathLike[str] | None) -> tuple[str, int] | None:
    """``(kind, n)`` when ``spec`` names built-in cameras (None: the overview), None when it is a file.

    A file of that name wins over the keyword (a camera file called ``overview``). ``orbit`` alone is 36
    cameras, 10° apart."""
    if spec is None:
        return "overview", 1
    text = str(spec)
    m = _BUILT_IN.fullmatch(text)
    if m is None or Path(text).exists():
        return None
    kind, count = m.group(1), m.group(2)
    if kind == "overview":
        if count is not None:
            raise InputError(f"--camera {text}: 'overview' is one camera; for several use 'orbit:N'")
        return kind, 1
    n = 36 if count is None else int(count)
    if not 1 <= n <= 100_000:
        raise InputError(f"--camera {text}: an orbit needs 1 to 100000 cameras")
    return kind, n


def cameras_for(spec: str | PathLike[str] | None, lo: npt.ArrayLike, hi: npt.ArrayLike, *,
                aspect: float = 1.5, up: npt.ArrayLike = (0.0, 0.0, 1.0)) -> list[Camera]:
    """The cameras ``--camera spec`` asks for over data in the box ``lo``–``hi``: a camera file
    (:func:`load_cameras`), or the built-in ``overview`` / ``orbit[:N]`` (:func:`built_in_camera`) around
    the local vertical ``up``."""
    kind = built_in_camera(spec)
    if kind is None:
        assert spec is not None
        return load_cameras(spec)
    if kind[0] == "overview":
        return [framing_camera(lo, hi, aspect=aspect, up=up)]
    return orbit_cameras(lo, hi, kind[1], aspect=aspect, up=up)


def local_up(crs: Any, lo: npt.ArrayLike, hi: npt.ArrayLike) -> F64:
    """The vertical at the centre of the box ``lo``–``hi`` in ``crs`` (a pyproj CRS or None): z, but for a
    geocentric (ECEF) frame the direction away from the Earth's centre, within 0.2° of the ellipsoid's
    normal (ample for placing a camera)."""
    if crs is not None and getattr(crs, "is_geocentric", False):
        c = (np.asarray(lo, np.float64) + np.asarray(hi, np.float64)) / 2.0
        if np.linalg.norm(c) > 1e6:
            return _unit(c)
    return np.array([0.0, 0.0, 1.0])


def in_local_frame(make: Any, lo: npt.ArrayLike, hi: npt.ArrayLike, up: npt.ArrayLike) -> list[Camera]:
    """Cameras that ``make(lo', hi')`` places over a z-up box, for data whose vertical is ``up``: the box is
    taken into the east / north / up frame at its centre (its bounds there), ``make`` runs on those, and
    its cameras come back into the data's frame. For z-up data, ``make(lo, hi)`` itself."""
    rot = enu_axes(up)  # local -> data
    if np.allclose(rot, np.eye(3)):
        return list(make(lo, hi))
    lo_a, hi_a = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    centre = (lo_a + hi_a) / 2.0
    corners = np.array([[x, y, z] for x in (lo_a[0], hi_a[0]) for y in (lo_a[1], hi_a[1])
                        for z in (lo_a[2], hi_a[2])]) - centre
    local = corners @ rot
    out = []
    for cam in make(local.min(axis=0), local.max(axis=0)):
        out.append(Camera(tuple(centre + rot @ np.asarray(cam.position)),  # type: ignore[arg-type]
                          tuple(centre + rot @ np.asarray(cam.focal_point)),  # type: ignore[arg-type]
                          tuple(rot @ np.asarray(cam.view_up, np.float64)), cam.fovy_deg))  # type: ignore[arg-type]
    return out


def enu_axes(up: npt.ArrayLike) -> F64:
    """(3, 3) whose columns are east, north and ``up`` (made a unit vector) of the local frame with that
    vertical: the identity for z; else east is square to z and ``up``, north completes the frame."""
    vertical = _unit(np.asarray(up, np.float64))
    east = np.cross([0.0, 0.0, 1.0], vertical)
    east = _unit(np.asarray(east, np.float64)) if np.linalg.norm(east) > 1e-9 else np.array([1.0, 0.0, 0.0])
    return np.column_stack([east, np.cross(vertical, east), vertical])
