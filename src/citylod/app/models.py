"""Plain models of the desktop application: every user action is a method here (no Qt).

The widgets in ``citylod.app.qt_*`` only hold these models and call their methods, so each action (toggle a
layer, change τ, run a query, highlight its result, measure, bookmark a camera) can be scripted and tested
without a window (docs/STYLE.md, "Model, adapter, widget").

* :class:`Document` — what is open: the render :class:`~citylod.render.tileset_actor.Scene` (tilesets), an
  optional :class:`~citylod.semantics.store.CityStore` and its :class:`~citylod.semantics.state.FeatureState`;
  layer display state (visibility, opacity, colour mode) and LOD settings; queries and picking.
* camera maths (:func:`overview_camera`, :func:`fly`, :func:`focus_on`, :func:`frame_box`);
* :func:`measure` — distance, height difference, area; geodesic (geographiclib, WGS84) for geographic CRSs;
* :class:`Bookmarks`, :class:`QueryHistory` — what the settings persist, as JSON-able values;
* :func:`source_kind`, :func:`build_plan`, :func:`parse_progress` — opening raw inputs through a build
  subprocess (``python -m citylod.cli build ...``).

Nothing here imports Qt; VTK only through :mod:`citylod.render`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import sys
import warnings
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from citylod.core.camera import Camera, enu_axes, framing_camera, local_up, overview_camera
from citylod.core.errors import CitylodError, InputError
from citylod.io.tiles3d.package import PACKAGE_SUFFIXES
from citylod.io.tiles3d.remote import is_ion, is_url

__all__ = [
    "ASPRS_CLASSES",
    "COLOR_MODES",
    "POINT_SHAPES",
    "SHORTCUTS",
    "Bookmarks",
    "BuildPlan",
    "Document",
    "LayerEntry",
    "Measurement",
    "QueryHistory",
    "build_plan",
    "crs_label",
    "fly",
    "focus_on",
    "format_cursor",
    "format_status",
    "frame_box",
    "geodesic_distances",
    "measure",
    "overview_camera",
    "parse_progress",
    "source_kind",
    "tau_from_slider",
    "tau_to_slider",
]

COLOR_MODES = ("auto", "rgb", "classification", "elevation", "intensity", "level")
#: How point layers draw their points (:meth:`Document.set_point_shape`).
POINT_SHAPES = ("square", "round", "splat")

#: A far-field layer keeps its decoded fields within this fraction of the memory budget (1 / FAR_FIELD_SHARE).
FAR_FIELD_SHARE = 4

#: (key sequence, what it does): the Help → Shortcuts dialog and the actions read this one list.
SHORTCUTS: tuple[tuple[str, str], ...] = (
    ("Ctrl+O", "Open a tileset, city store, raster, LAS/LAZ or city model"),
    ("W / S", "Fly forward / backward"),
    ("A / D", "Fly left / right"),
    ("Q / E", "Fly down / up"),
    ("R", "Reset the view to the data"),
    ("F", "Focus on the point under the cursor"),
    ("M", "Measure distance (click points; Esc ends)"),
    ("H", "Measure height difference"),
    ("G", "Measure area"),
    ("P", "Height profile (click two points)"),
    ("T", "Turntable / fly navigation"),
    ("Esc", "End the measurement / clear the pick"),
    ("Ctrl+B", "Add a camera bookmark"),
    ("Ctrl+S", "Save the project (layers, styles, camera, bookmarks, object state)"),
    ("Ctrl+Shift+S", "Save the camera as JSON for `citylod render`"),
    ("Ctrl+E", "Export an image of the view as drawn"),
    ("Ctrl+Return", "Run the query"),
    ("F1", "This list of shortcuts"),
    ("Ctrl+Q", "Quit"),
)

TAU_MIN_PX, TAU_MAX_PX = 0.25, 16.0
_SLIDER_STEPS = 1000


def tau_to_slider(tau_px: float) -> int:
    """Position 0..1000 of a log-scale slider over τ in [0.25, 16] px."""
    t = min(max(float(tau_px), TAU_MIN_PX), TAU_MAX_PX)
    return round(_SLIDER_STEPS * math.log(t / TAU_MIN_PX) / math.log(TAU_MAX_PX / TAU_MIN_PX))


def tau_from_slider(pos: int) -> float:
    """τ in pixels of a slider position (inverse of :func:`tau_to_slider`)."""
    return TAU_MIN_PX * (TAU_MAX_PX / TAU_MIN_PX) ** (min(max(pos, 0), _SLIDER_STEPS) / _SLIDER_STEPS)


# ------------------------------------------------------------------------------------------- camera maths
_FLY = {"forward": (0, 0, 1), "backward": (0, 0, -1), "left": (-1, 0, 0), "right": (1, 0, 0),
        "up": (0, 1, 0), "down": (0, -1, 0)}


def fly(camera: Camera, direction: str, step: float, up: npt.ArrayLike = (0.0, 0.0, 1.0)) -> Camera:
    """The camera moved by ``step`` along ``direction`` (forward, backward, left, right, up, down).

    Forward moves along the view direction, up/down along the vertical ``up`` (world z; the local vertical
    of geocentric data), left/right horizontally; the focal point moves with the eye so the view direction
    is kept.
    """
    if direction not in _FLY:
        raise ValueError(f"direction must be one of {', '.join(_FLY)}, got {direction!r}")
    right, _up, fwd = camera.basis()
    r, u, f = _FLY[direction]
    vertical = np.asarray(up, np.float64) / np.linalg.norm(up)
    horiz = right - (right @ vertical) * vertical
    n = np.linalg.norm(horiz)
    horiz = horiz / n if n > 1e-9 else right
    move = (r * horiz + u * vertical + f * fwd) * float(step)
    return Camera(tuple(np.add(camera.position, move)), tuple(np.add(camera.focal_point, move)),  # type: ignore[arg-type]
                  camera.view_up, camera.fovy_deg)


def focus_on(camera: Camera, point: npt.ArrayLike, *, zoom: float = 0.5, min_distance: float = 5.0) -> Camera:
    """Look at ``point`` from the same direction, ``zoom`` times as far as the eye is from it now."""
    p = np.asarray(point, np.float64)
    dist = max(float(np.linalg.norm(np.subtract(camera.position, p))) * zoom, min_distance)
    eye = p - camera.direction * dist
    return Camera(tuple(eye), tuple(p), camera.view_up, camera.fovy_deg)  # type: ignore[arg-type]


def frame_box(camera: Camera, lo: npt.ArrayLike, hi: npt.ArrayLike, *, margin: float = 1.6) -> Camera:
    """Look at the box ``lo``–``hi`` from the camera's direction, at a distance that shows all of it."""
    lo_a, hi_a = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    centre = (lo_a + hi_a) / 2.0
    radius = max(float(np.linalg.norm(hi_a - lo_a)) / 2.0, 2.0)
    dist = radius * margin / math.tan(math.radians(camera.fovy_deg) / 2.0)
    eye = centre - camera.direction * dist
    return Camera(tuple(eye), tuple(centre), camera.view_up, camera.fovy_deg)  # type: ignore[arg-type]


# -------------------------------------------------------------------------------------------- measuring
@dataclass(frozen=True)
class Measurement:
    """One measurement of picked points.

    ``value`` is in metres (distance, height) or square metres (area); ``geodesic`` says whether it was
    computed on the WGS84 ellipsoid (geographic CRS) or in the plane of a projected CRS.
    ``horizontal`` is the horizontal length (distance) or the perimeter (area).
    """

    kind: str
    value: float
    horizontal: float
    geodesic: bool
    points: tuple[tuple[float, float, float], ...]

    @property
    def unit(self) -> str:
        return "m²" if self.kind == "area" else "m"

    def text(self) -> str:
        """One line for the view and the clipboard."""
        how = "geodesic" if self.geodesic else "planar"
        if self.kind == "distance":
            return (f"distance {self.value:.2f} m (horizontal {self.horizontal:.2f} m, {how}, "
                    f"{len(self.points)} points)")
        if self.kind == "height":
            return f"height difference {self.value:+.2f} m (horizontal {self.horizontal:.2f} m, {how})"
        return f"area {self.value:.1f} m² (perimeter {self.horizontal:.2f} m, {how}, {len(self.points)} points)"


MEASURE_KINDS = ("distance", "height", "area")


def geodesic_distances(xyz: npt.ArrayLike, crs: Any, geographic: bool = False) -> npt.NDArray[np.float64]:
    """Distance (N,) in metres from the first of the points (N, 3) along the polyline through them, on the
    ellipsoid of ``crs`` (pyproj's ``Geod``, Karney's algorithm): the profile's axis when the project CRS
    is geographic or Tools > Ellipsoidal distances is on. ``geographic``: x, y are already longitude and
    latitude in degrees; else they are taken there by ``crs``'s own geodetic CRS.

    >>> import pyproj
    >>> d = geodesic_distances([[4.0, 52.0, 0.0], [4.0, 53.0, 0.0]], pyproj.CRS("EPSG:4326"), True)
    >>> round(float(d[-1]))  # one degree of latitude at 52.5°N on WGS84
    111277
    """
    import pyproj

    p = np.asarray(xyz, np.float64).reshape(-1, 3)
    crs = pyproj.CRS(crs)
    if geographic:
        lon, lat = p[:, 0], p[:, 1]
    else:
        lon, lat = pyproj.Transformer.from_crs(crs, crs.geodetic_crs, always_xy=True).transform(p[:, 0], p[:, 1])
    _f, _b, step = crs.get_geod().inv(lon[:-1], lat[:-1], lon[1:], lat[1:])
    return np.concatenate([[0.0], np.cumsum(np.abs(np.asarray(step, np.float64)))])


def measure(kind: str, points: npt.ArrayLike, *, geographic: bool = False, crs: Any = None,
            ellipsoidal: bool = False) -> Measurement:
    """Measure picked points (N, 3) float64 in the data's CRS.

    Parameters
    ----------
    kind
        ``distance`` (length of the polyline through the points, 3D), ``height`` (z of the last point minus
        z of the first) or ``area`` (horizontal area of the polygon of the points).
    geographic
        The CRS is geographic: x = longitude, y = latitude in degrees, z in metres. Lengths and areas are
        then geodesics on WGS84 (geographiclib ``Inverse`` and ``PolygonArea``); otherwise planar.
    crs, ellipsoidal
        With ``ellipsoidal`` and a projected ``crs`` (pyproj), the points are taken to longitude/latitude of
        the CRS's own datum and measured as geodesics too: the true length on the ellipsoid rather than the
        projection's grid length (they differ by the scale factor, e.g. up to 4e-4 in UTM).
    """
    if kind not in MEASURE_KINDS:
        raise ValueError(f"kind must be one of {', '.join(MEASURE_KINDS)}, got {kind!r}")
    p = np.asarray(points, np.float64).reshape(-1, 3)
    pts = tuple(tuple(float(v) for v in row) for row in p)
    if ellipsoidal and not geographic and crs is not None and len(p):
        import pyproj

        to_lonlat = pyproj.Transformer.from_crs(crs, crs.geodetic_crs, always_xy=True)
        lon, lat = to_lonlat.transform(p[:, 0], p[:, 1])
        p = np.column_stack([lon, lat, p[:, 2]])
        geographic = True
    if geographic:
        from geographiclib.geodesic import Geodesic

        geod = Geodesic.WGS84

        def horiz(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> float:
            return float(geod.Inverse(a[1], a[0], b[1], b[0])["s12"])
    else:
        def horiz(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> float:
            return float(math.hypot(b[0] - a[0], b[1] - a[1]))

    if kind == "distance":
        seg_h = [horiz(p[i], p[i + 1]) for i in range(len(p) - 1)]
        seg_3d = [math.hypot(h, p[i + 1, 2] - p[i, 2]) for i, h in enumerate(seg_h)]
        return Measurement(kind, float(sum(seg_3d)), float(sum(seg_h)), geographic, pts)
    if kind == "height":
        if len(p) < 2:
            return Measurement(kind, 0.0, 0.0, geographic, pts)
        return Measurement(kind, float(p[-1, 2] - p[0, 2]), horiz(p[0], p[-1]), geographic, pts)
    if len(p) < 3:
        return Measurement(kind, 0.0, 0.0, geographic, pts)
    if geographic:
        from geographiclib.geodesic import Geodesic

        poly = Geodesic.WGS84.Polygon()
        for x, y, _z in p:
            poly.AddPoint(y, x)
        _n, perimeter, area = poly.Compute(False, True)
        return Measurement(kind, abs(float(area)), float(perimeter), True, pts)
    x, y = p[:, 0] - p[:, 0].mean(), p[:, 1] - p[:, 1].mean()  # centred: no cancellation at 5e6 m
    area = 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
    closed = np.vstack([p, p[:1]])
    perim = float(np.hypot(np.diff(closed[:, 0]), np.diff(closed[:, 1])).sum())
    return Measurement(kind, area, perim, False, pts)


# ---------------------------------------------------------------------------------- persisted values
class Bookmarks:
    """Named cameras; :meth:`to_json` / :meth:`from_json` is what the settings store."""

    def __init__(self, items: dict[str, Camera] | None = None) -> None:
        self.items: dict[str, Camera] = dict(items or {})

    def add(self, name: str, camera: Camera) -> str:
        """Store ``camera`` under ``name`` (a unique name is made if it is empty); returns the name."""
        name = name.strip() or f"View {len(self.items) + 1}"
        self.items[name] = camera
        return name

    def remove(self, name: str) -> None:
        self.items.pop(name, None)

    def get(self, name: str) -> Camera:
        return self.items[name]

    def names(self) -> list[str]:
        return list(self.items)

    def to_json(self) -> str:
        return json.dumps({k: c.to_dict() for k, c in self.items.items()})

    @classmethod
    def from_json(cls, text: str | None) -> Bookmarks:
        """Bookmarks from :meth:`to_json` text; entries that are not cameras are dropped."""
        out = cls()
        try:
            data = json.loads(text) if text else {}
        except (TypeError, json.JSONDecodeError):
            return out
        if isinstance(data, dict):
            for k, v in data.items():
                try:
                    out.items[str(k)] = Camera.from_dict(v)
                except (InputError, AttributeError):
                    continue
        return out


class QueryHistory:
    """Recent WHERE clauses, newest first, without duplicates, at most ``limit``."""

    def __init__(self, items: Iterable[str] = (), limit: int = 30) -> None:
        self.limit = limit
        self.items: list[str] = []
        for it in reversed(list(items)):
            self.add(it)

    def add(self, where: str) -> None:
        w = where.strip()
        if not w:
            return
        if w in self.items:
            self.items.remove(w)
        self.items.insert(0, w)
        del self.items[self.limit:]


# ---------------------------------------------------------------------------------- sources and builds
_RASTER = {".tif", ".tiff", ".vrt", ".asc", ".img"}
_POINTS = {".las", ".laz"}
_CITY = {".gml", ".xml", ".citygml", ".cityjson"}


def source_kind(path: str | os.PathLike[str]) -> str | None:
    """What a path is, by suffix or folder content (constant time, no reading): ``tileset``, ``store``,
    ``raster``, ``points``, ``citymodel``, or None."""
    if is_url(path):
        return "tileset"
    p = Path(path)
    suf = p.suffix.lower()
    if p.is_dir():
        return "tileset" if (p / "tileset.json").is_file() else None
    if p.name.lower() == "tileset.json" or (suf == ".json" and p.name.lower().endswith("tileset.json")):
        return "tileset"
    if suf in PACKAGE_SUFFIXES:
        return "tileset"
    if suf == ".gpkg":
        return "store"
    if suf in _RASTER:
        return "raster"
    if suf in _POINTS:
        return "points"
    if suf in _CITY or p.name.lower().endswith(".city.json"):
        return "citymodel"
    if suf == ".json":
        # CityJSON files are JSON without a fixed suffix; a short look at the head tells.
        try:
            with open(p, "rb") as fh:
                head = fh.read(256)
        except OSError:
            return None
        return "citymodel" if b"CityJSON" in head else "tileset"
    return None


@dataclass(frozen=True)
class BuildPlan:
    """How to turn a raw input into something the viewer opens: ``argv`` of the build subprocess and the
    ``output`` it writes (a tileset folder or a .gpkg)."""

    source: Path
    kind: str
    output: Path
    argv: tuple[str, ...]

    @property
    def label(self) -> str:
        return {"raster": "DSM tile tree", "points": "point octree", "citymodel": "city store"}[self.kind]


def build_plan(path: str | os.PathLike[str], out_dir: str | os.PathLike[str] | None = None,
               python: str = sys.executable, *, crs: str | None = None) -> BuildPlan:
    """The build that makes ``path`` (raster, LAS/LAZ, CityGML/CityJSON) viewable.

    The output goes beside the input (``<stem>_tiles``, ``<stem>_points``, ``<stem>.gpkg``), or into
    ``out_dir``, or, when the input's folder is read-only (shared data), into the user's cache
    (``$XDG_CACHE_HOME/citylod/builds``). The command runs ``python -m citylod.cli build ...`` so that
    cancelling kills one process and leaves nothing half written (builds write to a temporary name and
    rename). ``crs`` is passed as ``--crs`` (a LAS/LAZ without one in its header, a city model to project).
    """
    p = Path(path)
    kind = source_kind(p)
    if out_dir is not None:
        base = Path(out_dir)
    elif os.access(p.parent, os.W_OK):
        base = p.parent
    else:
        cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
        base = cache / "citylod" / "builds"
        base.mkdir(parents=True, exist_ok=True)
    if kind == "raster":
        out = base / f"{p.stem}_tiles"
        args = ["dsm", str(p), "-o", str(out)]
    elif kind == "points":
        out = base / f"{p.stem}_points"
        args = ["points", str(p), "-o", str(out)]
    elif kind == "citymodel":
        out = base / f"{p.stem.removesuffix('.city')}.gpkg"
        args = ["city", str(p), "-o", str(out)]
    else:
        raise InputError("not a raster, LAS/LAZ or CityGML/CityJSON file", p)
    if crs and kind in ("points", "citymodel"):
        args += ["--crs", crs]
    return BuildPlan(p, kind, out, (python, "-m", "citylod.cli", "build", *args))


def missing_crs(path: str | os.PathLike[str]) -> bool:
    """A LAS/LAZ whose header declares no CRS (the build then needs one from the user). Reads the header
    only; False for other kinds and for files that cannot be read (the build reports those)."""
    if source_kind(path) != "points":
        return False
    from citylod.io.las import read_info

    try:
        return read_info(path).crs is None
    except CitylodError:
        return False


def check_crs(text: str) -> str:
    """``text`` if it names a CRS pyproj knows (``EPSG:28992``, a WKT, a PROJ string); InputError if not."""
    from citylod.io.crs import parse_crs

    parse_crs(text.strip(), "the CRS entered")
    return text.strip()


_TQDM = re.compile(r"(?:([^\r\n:|]{1,40}):\s*)?(\d{1,3})%\|")


def parse_progress(text: str) -> tuple[str, int] | None:
    """The last tqdm progress in a chunk of stderr: (description, percent), or None.

    >>> parse_progress("tiles:  40%|####      | 4/10 [00:01<00:01]\\rtiles:  50%|#####")
    ('tiles', 50)
    """
    last = None
    for m in _TQDM.finditer(text):
        last = ((m.group(1) or "").strip(), min(int(m.group(2)), 100))
    return last


def format_status(stats: Any, frame_ms: float, pending: int, loading: bool = True) -> str:
    """The status bar line of a :class:`~citylod.render.tileset_actor.FrameStats`."""
    mb = stats.bytes_resident / 1e6
    # Short: it shares the status bar with the cursor position and the temporary messages.
    text = (f"{frame_ms:.0f} ms · {stats.triangles:,} tri · {stats.points:,} pts · {stats.tiles} tiles · "
            f"{mb:.0f} MB · τ {stats.tau_px:.2f} px")
    if pending:
        text += f" · {pending} loading"
    elif loading:
        text += " · complete"
    return text


def format_far_status(document: Document) -> str:
    """The status bar's far-field part (empty without one): cells drawn as light fields and cells whose
    buildings are drawn, over the open far-field tilesets, in the last frame."""
    frames = [e.far.last_frame for e in document.entries if e.far is not None and e.far.visible]
    frames = [f for f in frames if f is not None]
    if not frames:
        return ""
    fields = sum(f.cells for f in frames)
    houses = sum(f.geometry_cells for f in frames)
    return f"far field: {fields} light-field cells, {houses} cells of buildings"


def format_budget_status(document: Document) -> str:
    """The status bar's budget-mode part (empty when it is off): the target, the last frame as budget
    mode measured it (draw until the GL finished) and the point budget it set, summed over the layers."""
    fb = document.frame_budget
    if fb is None:
        return ""
    ms = f"{fb.frame_ms[-1]:.0f} ms" if fb.frame_ms else "–"
    points = sum(int(e.layer.budget.max_points) for e in document.entries
                 if e.layer is not None and e.layer.budget is not None and e.layer.budget.max_points)
    return f"hold {document.lod.target_ms:g} ms: frame {ms}, budget {points:,} pts"


#: ASPRS LAS 1.4 class names (the legend); codes without a name are shown as "class N".
ASPRS_CLASSES = {0: "never classified", 1: "unclassified", 2: "ground", 3: "low vegetation",
                 4: "medium vegetation", 5: "high vegetation", 6: "building", 7: "low point (noise)",
                 8: "reserved", 9: "water", 10: "rail", 11: "road surface", 12: "reserved",
                 13: "wire guard", 14: "wire conductor", 15: "transmission tower", 16: "wire connector",
                 17: "bridge deck", 18: "high noise", 26: "bridge deck (AHN)"}


def crs_label(crs: Any) -> str:
    """Short name of a CRS for the status bar: ``EPSG:28992`` when it has a code, else its name."""
    if crs is None:
        return "no CRS"
    if isinstance(crs, str):
        return crs or "no CRS"
    try:
        epsg = crs.to_epsg()
    except Exception:  # pyproj raises several types for odd CRSs; the name is good enough then
        epsg = None
    return f"EPSG:{epsg}" if epsg else str(getattr(crs, "name", crs))


def format_cursor(point: npt.ArrayLike | None, crs: Any, geographic: bool = False) -> str:
    """The status bar's cursor text: coordinates of the surface point under the mouse and the CRS.

    >>> format_cursor((85000.123, 447500.5, 1.25), None)
    'x 85000.12  y 447500.50  z 1.25 m  (no CRS)'
    """
    if point is None:
        return f"cursor off the data  ({crs_label(crs)})"
    x, y, z = (float(v) for v in np.asarray(point, np.float64)[:3])
    if geographic:
        return f"lon {x:.7f}°  lat {y:.7f}°  h {z:.2f} m  ({crs_label(crs)})"
    return f"x {x:.2f}  y {y:.2f}  z {z:.2f} m  ({crs_label(crs)})"


# --------------------------------------------------------------------------------------------- document
@dataclass
class LayerEntry:
    """A row of the layer panel: a tileset layer (``layer`` set), a far-field tileset drawn with its light
    fields (``far`` set: a :class:`~citylod.render.slf.SlfView` in the view's renderer) or the city store
    (neither)."""

    name: str
    kind: str  # tileset | far field | store
    path: Path
    layer: Any = None
    far: Any = None
    visible: bool = True
    opacity: float = 1.0
    color_by: str = "auto"


Listener = Callable[[str], None]


@dataclass
class LodSettings:
    tau_px: float = 1.0
    point_budget: int = 5_000_000
    memory_mb: int = 1024
    frozen: bool = False
    color_by_level: bool = False
    #: While the camera moves τ is multiplied by this and point budgets divided by it (Potree and Cesium
    #: coarsen during motion the same way); the view refines to ``tau_px`` when the camera stops.
    motion_factor: float = 4.0
    #: ... and at most this many points per layer while moving: a software or small GPU spends its frame
    #: filling point sprites, so a moving frame needs a bound that does not grow with the budget.
    motion_point_budget: int = 100_000
    #: Budget mode: hold this frame time (ms) by steering τ and the point budgets every frame
    #: (:class:`~citylod.render.frame_budget.FrameBudget`); 0 = off, the fixed budgets above apply.
    target_ms: float = 0.0


class Document:
    """Everything open in one window and every action on it.

    Parameters
    ----------
    scene
        The render scene (tilesets); created with its own renderer when omitted.
    """

    def __init__(self, scene: Any = None, *, workers: int = 2) -> None:
        from citylod.render.tileset_actor import Scene
        from citylod.semantics.state import FeatureState

        self.lod = LodSettings()
        self.scene = scene if scene is not None else Scene(cache_bytes=self.lod.memory_mb << 20, workers=workers)
        self.entries: list[LayerEntry] = []
        self.store: Any = None
        self.state = FeatureState()
        self.results: list[str] = []
        #: Measure on the ellipsoid (geodesics) even in a projected CRS; Tools > Ellipsoidal distances.
        self.ellipsoidal = False
        self.semantic: Any = None
        # In the GUI the semantic overlay's height map (hundreds of ms for a city) is built on a worker
        # thread and attached by poll_semantics() on the GUI thread; scripts and tests attach at once.
        self.async_semantics = False
        self._semantic_future: Any = None
        self._listeners: list[Listener] = []
        self.moving = False
        self.last_profile: Any = None
        self.edl = False
        self.clip_box: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None = None
        self.class_filter: frozenset[int] | None = None
        self._class_counts: dict[str, dict[int, int]] = {}
        #: The budget mode's controller while :attr:`LodSettings.target_ms` is set and a layer is open.
        self.frame_budget: Any = None

    # -- events -----------------------------------------------------------------------------------
    def on_change(self, listener: Listener) -> Callable[[], None]:
        """Call ``listener(kind)`` after a change: layers, style, lod, results, store."""
        self._listeners.append(listener)
        return lambda: self._listeners.remove(listener) if listener in self._listeners else None

    def _emit(self, kind: str) -> None:
        for cb in list(self._listeners):
            cb(kind)

    def notify(self, kind: str) -> None:
        """Tell the listeners that ``kind`` changed (after state was restored in bulk, e.g. a project)."""
        self._emit(kind)

    # -- opening ----------------------------------------------------------------------------------
    def open(self, path: str | os.PathLike[str]) -> LayerEntry:
        """Open a tileset (folder or tileset.json) or a city store (.gpkg).

        Raw inputs (rasters, LAS/LAZ, city models) must be built first (:func:`build_plan`).
        """
        p = Path(path)
        kind = source_kind(p)
        if kind == "tileset":
            from citylod.render.slf import is_far_field

            if is_far_field(p):
                return self._open_far_field(p)
            layer = self.scene.add(p)
            layer.tau_px = self.effective_tau()
            self._apply_budget(layer)
            if self.lod.target_ms > 0:
                self._restart_frame_budget()  # the new layer is steered too
            entry = LayerEntry(layer.name if p.is_dir() else p.name if p.suffix.lower() in PACKAGE_SUFFIXES
                               else layer.tileset.source if is_ion(layer.tileset.source) else p.parent.name,
                               "tileset", p, layer)
            if p.is_dir():
                entry.name = p.name
            self.entries.append(entry)
            self._attach_semantics()
            self._emit("layers")
            return entry
        elif kind == "store":
            if self.store is not None:
                raise CitylodError("a city store is already open; close the window to open another", p)
            from citylod.semantics.store import CityStore

            self.store = CityStore.open(p)
            if self.scene.origin is None:
                b = self.store.bounds
                self.scene.origin = np.round(np.array([(b[0] + b[3]) / 2, (b[1] + b[4]) / 2, (b[2] + b[5]) / 2]))
            entry = LayerEntry(p.stem, "store", p)
            self._attach_semantics()
        elif kind in ("raster", "points", "citymodel"):
            raise InputError(f"a {kind} file must be built before it can be viewed (File → Open builds it)", p)
        else:
            raise InputError("not a tileset folder, tileset.json, .3tz / .3dtiles package or .gpkg city store", p)
        self.entries.append(entry)
        self._emit("layers")
        return entry

    def _open_far_field(self, p: Path) -> LayerEntry:
        """A far-field tileset (``citylod build slf``): its city drawn with the light fields evaluated for
        the view's direction before every render, buildings where the fields hand over (Ruiters) at twice the
        view's τ (``FIELD_TAU_SCALE``). It has no tiles in the scene, so the point tools do not see it; with a
        city store open, a click picks through it along the sight line (:meth:`pick`) and highlights are drawn
        over it as translucent proxies."""
        from citylod.render.slf import FIELD_TAU_SCALE, SlfView

        far = SlfView(p, renderer=self.scene.renderer, origin=self.scene.origin,
                      tau_px=FIELD_TAU_SCALE * self.effective_tau(),
                      cache_mb=self.lod.memory_mb / FAR_FIELD_SHARE)
        if self.scene.origin is None:  # the far field's own origin (its actors are made from the first frame)
            self.scene.origin = far.origin
        far.attach()
        entry = LayerEntry(p.name if p.is_dir() else p.parent.name, "far field", p, far=far)
        self.entries.append(entry)
        self._emit("layers")
        return entry

    def far_pending(self) -> int:
        """City tiles the far-field layers are reading for their buildings."""
        return sum(e.far.pending() for e in self.entries if e.far is not None)

    def far_loads_ready(self) -> bool:
        """A far-field layer has read a city tile that the next frame draws."""
        return any(e.far.loads_ready() for e in self.entries if e.far is not None)

    def _attach_semantics(self) -> None:
        """Semantic shading of the drawn geometry inside proxies (``citylod.render.semantic``), once a store
        and a tileset are both open. Without it the view falls back to drawing proxies."""
        if self.semantic is not None or self.store is None or not self.scene.layers:
            return
        try:
            from citylod.render.semantic import SemanticOverlay
        except ImportError:
            return
        if self.async_semantics:
            if self._semantic_future is None:
                import concurrent.futures

                from citylod.render.semantic import build_contour_map, overlay_map_args

                pool = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="citylod-map")
                self._semantic_future = pool.submit(_on_own_connection, self.store.path, build_contour_map,
                                                    **overlay_map_args(self.scene))
                pool.shutdown(wait=False)
            return
        try:
            self.semantic = SemanticOverlay(self.scene, self.store, self.state)
        except Exception as exc:  # a renderer-side failure must not stop the viewer: fall back
            warnings.warn(f"semantic shading unavailable: {type(exc).__name__}: {exc}", stacklevel=2)
            self.semantic = None

    @property
    def semantics_pending(self) -> bool:
        """The overlay's map is still being built in the background."""
        return self._semantic_future is not None

    def poll_semantics(self) -> bool:
        """Attach the overlay once its map, built in the background, is ready; True when it attached."""
        fut = self._semantic_future
        if fut is None or not fut.done():
            return False
        self._semantic_future = None
        if self.store is None or self.semantic is not None:
            return False
        from citylod.render.semantic import SemanticOverlay

        try:
            self.semantic = SemanticOverlay(self.scene, self.store, self.state, contour_map=fut.result())
            entry = next((e for e in self.entries if e.kind == "store"), None)
            if entry is not None and not entry.visible:  # unchecked before the overlay was ready
                self.semantic.set_enabled(False)
        except Exception as exc:  # a renderer-side failure must not stop the viewer: fall back
            warnings.warn(f"semantic shading unavailable: {type(exc).__name__}: {exc}", stacklevel=2)
            self.semantic = None
            return False
        self._emit("semantics")
        return True

    @property
    def crs(self) -> Any:
        """The data's CRS (the tilesets', else the city store's), or None."""
        if self.scene.crs is not None:
            return self.scene.crs
        return None if self.store is None else self.store.crs

    @property
    def geographic(self) -> bool:
        """The data's CRS is geographic (degrees): measurements are geodesic."""
        crs = self.scene.crs if self.scene.crs is not None else (self.store.crs if self.store else None)
        return bool(crs is not None and getattr(crs, "is_geographic", False))

    def bounds(self, *, store: bool = True) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None:
        """(lo, hi) of every layer and (``store``) the city store, in the data's CRS; None when nothing is
        open."""
        boxes = [e.far.bounds() for e in self.entries if e.far is not None]
        if self.scene.layers:
            boxes.append(self.scene.bounds)
        if store and self.store is not None:
            b = np.asarray(self.store.bounds, np.float64)
            if np.all(np.isfinite(b)):
                boxes.append((b[:3], b[3:]))
        if not boxes:
            return None
        return np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)

    def up(self) -> npt.NDArray[np.float64]:
        """The data's vertical: z, or for a geocentric scene (other tools' ECEF tilesets) the direction away
        from the Earth's centre at the data (:func:`citylod.core.camera.local_up`). Asked for on every mouse
        move and frame, so it reads only the layers' boxes, and only for a geocentric scene (a city store's
        bounds are an SQL scan)."""
        if not self.scene.layers or not getattr(self.scene.crs, "is_geocentric", False):
            return np.array([0.0, 0.0, 1.0])
        return local_up(self.scene.crs, *self.scene.bounds)

    def north(self) -> npt.NDArray[np.float64]:
        """The data's north for the view's arrow: +y, or the local north of a geocentric scene."""
        return enu_axes(self.up())[:, 1]

    def home_camera(self, aspect: float = 1.5) -> Camera | None:
        """What is drawn, all in view, as close as its box's corners allow (``citylod render``'s overview):
        a city is flat, and the bounding sphere fitted before left it in the middle third. A city store is
        drawn only through the other layers, and its model can reach far past them (Delft's covers twice
        the LiDAR's area), so it counts only when nothing else is open."""
        b = self.bounds(store=False) or self.bounds()
        if b is None:
            return None
        return framing_camera(*b, aspect=aspect, up=self.up())

    # -- layer display ----------------------------------------------------------------------------
    def entry(self, index: int) -> LayerEntry:
        return self.entries[index]

    def set_visible(self, index: int, on: bool) -> None:
        e = self.entries[index]
        e.visible = bool(on)
        if e.far is not None:
            e.far.visible = e.visible
        elif e.layer is not None:
            e.layer.visible = e.visible
        elif self.semantic is not None:
            self.semantic.set_enabled(e.visible)
        self._emit("style")

    def set_opacity(self, index: int, opacity: float) -> None:
        e = self.entries[index]
        e.opacity = float(min(max(opacity, 0.0), 1.0))
        self._emit("style")

    def set_color_by(self, index: int, mode: str) -> None:
        if mode not in COLOR_MODES:
            raise CitylodError(f"unknown colour mode {mode!r}; choose one of {', '.join(COLOR_MODES)}")
        e = self.entries[index]
        e.color_by = mode
        if e.layer is not None and not self.lod.color_by_level:
            e.layer.color_by = mode
            e.layer.restyle()
        self._emit("style")

    def apply_opacity(self) -> None:
        """Give the actors of every drawn tile their layer's opacity (after each update: pooled actors move
        between layers)."""
        for e in self.entries:
            if e.layer is None:
                continue
            for slot in e.layer._slots.values():
                for actor in slot.actors():
                    prop = actor.GetProperty()
                    if prop.GetOpacity() != e.opacity:
                        prop.SetOpacity(e.opacity)

    # -- points ---------------------------------------------------------------------------------------
    def drawn_points(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.uint8], npt.NDArray[np.uint8]]:
        """The points the view draws now, with the colours it draws them in: positions (N, 3) float64 in the
        data's CRS, RGB (N, 3) uint8 and ASPRS class (N,) uint8 (0 where a tile has none).

        Over the drawn tiles of every visible point layer, with the layer's colour mode (classification,
        elevation, …), the class filter and the clipping box applied; points inside a hidden object's proxy
        are left out (or outside the isolated ones), and points inside a highlighted object's proxy take
        its colour, blended by its alpha, as the semantic shader tints them."""
        xyz, rgb, cls = [], [], []
        for e in self.entries:
            layer = e.layer
            if layer is None or not e.visible or not layer.visible:
                continue
            mode = layer.effective_color_by
            for key in sorted(layer.shown_keys):
                slot = layer._slots.get(key)
                pts = None if slot is None or slot.prepared is None else slot.prepared.points
                if pts is None or not len(pts.positions):
                    continue
                tile = layer.node(key)  # its matrix maps the prepared positions (reprojected or not)
                world = pts.positions.astype(np.float64) @ tile.matrix[:3, :3].T + tile.matrix[:3, 3]
                colours = layer._point_rgb(pts, mode, slot.level, tile)
                if colours is None:  # colour by level: one colour per tile
                    from citylod.render.colors import level_color

                    colours = np.tile((np.asarray(level_color(slot.level)) * 255).round().astype(np.uint8),
                                      (len(world), 1))
                c = pts.classification if pts.classification is not None else np.zeros(len(world), np.uint8)
                keep = np.ones(len(world), bool)
                if self.class_filter is not None and pts.classification is not None:
                    keep &= np.isin(pts.classification, np.fromiter(self.class_filter, np.int64))
                if self.clip_box is not None:
                    lo, hi = self.clip_box
                    keep &= np.all((world >= lo) & (world <= hi), axis=1)
                xyz.append(world[keep])
                rgb.append(np.asarray(colours, np.uint8)[keep])
                cls.append(np.asarray(c, np.uint8)[keep])
        if not xyz:
            return np.empty((0, 3)), np.empty((0, 3), np.uint8), np.empty(0, np.uint8)
        p, col, k = np.vstack(xyz), np.vstack(rgb), np.concatenate(cls)
        st = self.state
        if self.store is not None and (st.colors or st.hidden or st.isolated is not None) and len(p):
            idx = self.store.proxies.contains(p)
            ids = self.store.proxies.object_ids
            owner = np.array([ids[i] if i >= 0 else "" for i in idx], object)
            visible = np.array([o == "" or st.is_visible(o) for o in owner], bool)
            for oid, rgba in st.colors.items():
                m = owner == oid
                if m.any():
                    a = float(rgba[3])
                    tint = np.asarray(rgba[:3], np.float64) * 255.0
                    col[m] = np.round(col[m] * (1.0 - a) + tint * a).astype(np.uint8)
            p, col, k = p[visible], col[visible], k[visible]
        return p, col, k

    def export_points(self, path: str | os.PathLike[str]) -> int:
        """Write :meth:`drawn_points` to a LAS 1.4 file (point format 7: RGB and class; the CRS in the
        header), atomically; returns the number of points."""
        import laspy

        from citylod.core.fileio import atomic_write

        p, col, k = self.drawn_points()
        if not len(p):
            raise CitylodError("no points are drawn: open a point cloud and let it load", path)
        header = laspy.LasHeader(point_format=7, version="1.4")
        header.scales = np.array([0.001, 0.001, 0.001])
        header.offsets = np.floor(p.min(axis=0))
        if self.crs is not None:
            header.add_crs(self.crs)
        las = laspy.LasData(header)
        las.x, las.y, las.z = p[:, 0], p[:, 1], p[:, 2]
        las.red, las.green, las.blue = (col[:, i].astype(np.uint16) * 257 for i in range(3))
        las.classification = k
        atomic_write(path, lambda tmp: las.write(str(tmp)), suffix=Path(path).suffix or ".las")
        return len(p)

    def set_point_size(self, index: int, size_px: float, round_points: bool | None = None) -> None:
        """Point size in pixels (1–20) and shape (round or square) of a point layer."""
        e = self.entries[index]
        if e.layer is None:
            return
        e.layer.point_size_px = float(min(max(size_px, 1.0), 20.0))
        if round_points is not None:
            e.layer.point_round = bool(round_points)
        e.layer.restyle()
        self._emit("style")

    def set_point_shape(self, index: int, shape: str) -> None:
        """Shape of a point layer's points: "square", "round" (sphere-shaded) or "splat" (oriented disks
        sized by the local spacing, :mod:`citylod.render.splats`; hole-free up close)."""
        if shape not in POINT_SHAPES:
            raise ValueError(f"point shape must be one of {', '.join(POINT_SHAPES)}, not {shape!r}")
        e = self.entries[index]
        if e.layer is None:
            return
        e.layer.point_round = shape == "round"
        e.layer.point_shape = "splat" if shape == "splat" else "points"
        e.layer.restyle()
        self._emit("style")

    def point_classes(self) -> dict[int, int]:
        """ASPRS classes of the points of the resident tiles: {class: points}, over every layer."""
        out: dict[int, int] = {}
        for e in self.entries:
            if e.layer is None:
                continue
            for key, slot in list(e.layer._slots.items()):
                counts = self._class_counts.get(key)
                if counts is None:
                    pts = None if slot.prepared is None else slot.prepared.points
                    if pts is None or pts.classification is None:
                        counts = {}
                    else:
                        u, c = np.unique(pts.classification, return_counts=True)
                        counts = {int(a): int(b) for a, b in zip(u, c, strict=True)}
                    self._class_counts[key] = counts
                for k, v in counts.items():
                    out[k] = out.get(k, 0) + v
        return dict(sorted(out.items()))

    def set_class_filter(self, classes: Iterable[int] | None) -> None:
        """Draw only points of these ASPRS classes in every layer (None: all classes)."""
        self.class_filter = None if classes is None else frozenset(int(c) for c in classes)
        for e in self.entries:
            if e.layer is not None:
                e.layer.class_filter = self.class_filter
                e.layer.restyle()
        self._emit("style")

    def set_edl(self, on: bool) -> None:
        """Eye-Dome Lighting (depth-edge shading that makes point clouds read as surfaces) on or off."""
        self.edl = bool(on)
        self._emit("display")

    def set_clip_box(self, box: tuple[npt.ArrayLike, npt.ArrayLike] | None) -> None:
        """Draw only what lies inside the axis-aligned box (lo (3,), hi (3,)) in the data's CRS; None: all."""
        if box is None:
            self.clip_box = None
        else:
            lo, hi = np.asarray(box[0], np.float64), np.asarray(box[1], np.float64)
            self.clip_box = (np.minimum(lo, hi), np.maximum(lo, hi))
        self._emit("display")

    # -- LOD ----------------------------------------------------------------------------------------
    def set_tau(self, tau_px: float) -> None:
        """Screen-space error threshold of every layer, pixels."""
        self.lod.tau_px = float(min(max(tau_px, TAU_MIN_PX), TAU_MAX_PX))
        if self.frame_budget is not None:
            self._restart_frame_budget()
        else:
            self._apply_lod()
        self._emit("lod")

    def effective_tau(self) -> float:
        """τ the layers use now: :attr:`LodSettings.tau_px`, times the motion factor while moving (not in
        budget mode, where the controller coarsens a moving view itself)."""
        coarse = self.moving and not self.lod.target_ms > 0
        return self.lod.tau_px * (self.lod.motion_factor if coarse else 1.0)

    def _apply_lod(self) -> None:
        tau = self.effective_tau()
        self.scene.tau_px = tau
        for e in self.entries:
            if e.far is not None:
                from citylod.render.slf import FIELD_TAU_SCALE

                e.far.tau_px = FIELD_TAU_SCALE * tau
            if e.layer is not None:
                e.layer.tau_px = tau
                self._apply_budget(e.layer)

    def set_moving(self, on: bool) -> bool:
        """The camera started (on) or stopped moving: coarser τ and point budget while it moves, full
        quality when it stops. Returns True when the state changed (the view then re-renders)."""
        if bool(on) == self.moving:
            return False
        self.moving = bool(on)
        if self.frame_budget is None:  # budget mode steers τ and the budgets itself
            self._apply_lod()
        return True

    def _apply_budget(self, layer: Any) -> None:
        from citylod.lod.runtime.selection import Budget

        points = self.lod.point_budget
        if self.moving and not self.lod.target_ms > 0:
            cap = self.lod.motion_point_budget
            points = min(int(points / self.lod.motion_factor), cap) if points > 0 else cap
        layer.budget = Budget(max_points=int(points)) if points > 0 else None

    def set_point_budget(self, points: int) -> None:
        """Most points drawn per frame per layer (0 = unlimited)."""
        self.lod.point_budget = max(int(points), 0)
        if self.frame_budget is not None:
            self._restart_frame_budget()  # the new budget is budget mode's most detail
        else:
            for e in self.entries:
                if e.layer is not None:
                    self._apply_budget(e.layer)
        self._emit("lod")

    def set_target_ms(self, target_ms: float) -> None:
        """Budget mode: hold ``target_ms`` per frame (0 = off, back to the fixed τ and point budget).

        A :class:`~citylod.render.frame_budget.FrameBudget` on the scene times every render of the view
        and sets the next frame's point budget (and τ) from it; the fixed τ and point budget are the most
        detail it draws. Turning it off gives the layers their fixed budgets back.
        """
        self.lod.target_ms = max(float(target_ms), 0.0)
        self._restart_frame_budget()
        self._emit("lod")

    def _restart_frame_budget(self) -> None:
        if self.frame_budget is not None:
            self.frame_budget.close()
            self.frame_budget = None
        self._apply_lod()  # the fixed budgets: what budget mode starts from, or what it leaves
        if self.lod.target_ms > 0 and any(e.layer is not None for e in self.entries):
            from citylod.render.frame_budget import FrameBudget

            self.frame_budget = FrameBudget(self.scene, self.lod.target_ms)

    def set_memory_budget(self, megabytes: int) -> None:
        """Byte budget of the tile cache; tiles that no longer fit are released. Far-field layers keep their
        decoded fields within a quarter of it (from their next frame)."""
        self.lod.memory_mb = max(int(megabytes), 16)
        for key in self.scene.cache.set_budget(self.lod.memory_mb << 20):
            self.scene._layer_of(key)._release(key)
        for e in self.entries:
            if e.far is not None:
                e.far.cache_bytes = (self.lod.memory_mb << 20) // FAR_FIELD_SHARE
        self._emit("lod")

    def set_frozen(self, on: bool) -> None:
        """Freeze the LOD selection: the drawn tiles stay while the camera moves (to inspect culling)."""
        self.lod.frozen = bool(on)
        self.scene.frozen = self.lod.frozen
        self._emit("lod")

    def set_color_by_level(self, on: bool) -> None:
        """Colour every layer by tile level (on) or by its own colour mode (off)."""
        self.lod.color_by_level = bool(on)
        for e in self.entries:
            if e.layer is not None:
                e.layer.color_by = "level" if on else e.color_by
                e.layer.restyle()
        self._emit("lod")

    # -- city objects -------------------------------------------------------------------------------
    def object_groups(self) -> dict[str, list[tuple[str, str]]]:
        """Objects of the store grouped by type: {type: [(object_id, name), ...]} in store order."""
        if self.store is None:
            return {}
        groups: dict[str, list[tuple[str, str]]] = {}
        for oid, typ, name in self.store._conn.execute(
                "SELECT object_id, type, name FROM city_objects ORDER BY fid"):
            groups.setdefault(typ or "CityObject", []).append((oid, name or ""))
        return groups

    def attributes(self, object_id: str) -> dict[str, Any]:
        return {} if self.store is None else self.store.attributes(object_id)

    def select(self, ids: Iterable[str], mode: str = "replace") -> None:
        self.state.select(ids, mode)

    def object_at(self, point: npt.ArrayLike) -> str | None:
        """The object whose proxy contains ``point`` (3,) in the data's CRS, or None."""
        if self.store is None:
            return None
        idx = self.store.proxies.contains(np.asarray(point, np.float64).reshape(1, 3))[0]
        return None if idx < 0 else self.store.proxies.object_ids[int(idx)]

    def object_along(self, eye: npt.ArrayLike, point: npt.ArrayLike, step_m: float = 0.25) -> str | None:
        """The first object whose proxy the sight line from ``eye`` to a picked ``point`` enters, or None.

        A far field draws its buildings into the terrain's texture, so the depth under the cursor is the
        ground, behind the roof the pixel shows (by the building's height times the view's slope). The line is
        sampled every ``step_m`` over the part of it within the proxies' heights (at most 20,000 samples);
        a wall thinner than the step may be stepped over at a grazing angle."""
        if self.store is None:
            return None
        px = self.store.proxies
        if len(px) == 0 or not np.isfinite(px.zmin).any():
            return None
        e, d = np.asarray(eye, np.float64), np.asarray(point, np.float64) - np.asarray(eye, np.float64)
        lo, hi = float(np.nanmin(px.zmin)), float(np.nanmax(px.zmax))
        if abs(d[2]) > 1e-12:
            ta, tb = (hi - e[2]) / d[2], (lo - e[2]) / d[2]
            t0, t1 = max(min(ta, tb), 0.0), min(max(ta, tb), 1.0)
        else:
            t0, t1 = (0.0, 1.0) if lo <= e[2] <= hi else (1.0, 0.0)
        if t1 <= t0:
            return None
        n = int(min(20000, max(2, np.linalg.norm(d) * (t1 - t0) / step_m + 1)))
        idx = px.contains(e + np.linspace(t0, t1, n)[:, None] * d)
        hit = np.flatnonzero(idx >= 0)
        return None if not len(hit) else px.object_ids[int(idx[hit[0]])]

    def pick(self, point: npt.ArrayLike | None, eye: npt.ArrayLike | None = None) -> str | None:
        """Select the object at a picked point (nothing picked or no object: clear the selection). With the
        ``eye`` and a far field shown, a point in no proxy is followed back along the sight line
        (:meth:`object_along`): the building the far field draws there."""
        oid = None if point is None else self.object_at(point)
        if (oid is None and point is not None and eye is not None
                and any(e.far is not None and e.visible for e in self.entries)):
            oid = self.object_along(eye, point)
        self.state.select([] if oid is None else [oid])
        return oid

    def object_box(self, ids: Sequence[str]) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None:
        """Bounding box of objects (their proxies)."""
        if self.store is None or not ids:
            return None
        px = self.store.proxies
        idx = [px.index_of(i) for i in ids]
        import shapely

        x0, y0, x1, y1 = shapely.total_bounds(px.shapes[idx])
        z = np.concatenate([px.zmin[idx], px.zmax[idx]])
        z = z[np.isfinite(z)]
        if not np.isfinite([x0, y0, x1, y1]).all() or not len(z):
            return None
        return np.array([x0, y0, z.min()]), np.array([x1, y1, z.max()])

    def tallest_building(self) -> str | None:
        """The building with the largest height (``zmax - zmin``), for ``highlight_first``."""
        if self.store is None:
            return None
        ids = self.store.query("type IN ('Building', 'BuildingPart') AND (zmax - zmin) = "
                               "(SELECT MAX(zmax - zmin) FROM city_objects WHERE type IN ('Building', 'BuildingPart'))")
        return ids[0] if ids else None

    # -- queries ------------------------------------------------------------------------------------
    def run_sql(self, where: str) -> list[str]:
        """Ids of objects matching an SQL WHERE clause; they become :attr:`results`."""
        if self.store is None:
            raise CitylodError("open a city store (.gpkg) to run queries")
        self.results = list(self.store.query(where))
        self._emit("results")
        return self.results

    def run_named(self, name: str, **params: Any) -> list[str]:
        """Run a registered query (:func:`citylod.semantics.queries.list_queries`)."""
        if self.store is None:
            raise CitylodError("open a city store (.gpkg) to run queries")
        from citylod.semantics.queries import run_query

        self.results = list(run_query(self.store, name, **params))
        self._emit("results")
        return self.results

    def proxy_meshes(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        """Every object's proxy mesh stacked into one: vertices (V, 3), faces (F, 3), the store index of
        each face's object (F,). Drawn when a city store is open without a tileset to shade. Reads one
        row per object (the store keeps one mesh per object) on a connection of its own, so it may run
        on a worker thread while the GUI queries the store."""
        if self.store is None:
            from citylod.render.store_actor import stack_meshes

            return stack_meshes([])
        return _on_own_connection(self.store.path, _stacked_proxy_meshes)

    @property
    def store_alone(self) -> bool:
        """A city store is open and nothing else draws the city (no tileset, no far field): its proxies are
        what the view draws. Beside a far field they would cover its light fields with grey boxes (and cost
        8,000 solids a frame); they still pick through the depth the far field leaves."""
        return self.store is not None and not self.scene.layers and not any(e.far for e in self.entries)

    # -- profile ------------------------------------------------------------------------------------
    def profile(self, a: npt.ArrayLike, b: npt.ArrayLike, samples: int = 256) -> Any:
        """Height profile of the drawn surface along the line ``a``–``b`` (a
        :class:`~citylod.render.profile.Profile`, also kept as :attr:`last_profile`); emits ``profile``."""
        from citylod.render.profile import surface_profile

        prof = surface_profile(self.scene, a, b, samples)
        if self.geographic or (self.ellipsoidal and self.crs is not None):
            prof = dataclasses.replace(prof, distance=geodesic_distances(prof.xyz, self.crs, self.geographic),
                                       ellipsoidal=True)
        self.last_profile = prof
        self._emit("profile")
        return self.last_profile

    def highlight(self, ids: Iterable[str] | None = None, color: str = "#ffcc00") -> None:
        self.state.highlight(self.results if ids is None else ids, color)

    def hide(self, ids: Iterable[str] | None = None) -> None:
        self.state.hide(self.results if ids is None else ids)

    def isolate(self, ids: Iterable[str] | None = None) -> None:
        self.state.isolate(self.results if ids is None else ids)

    def clear_state(self) -> None:
        self.state.clear()

    def close(self) -> None:
        for e in self.entries:
            if e.far is not None:
                e.far.close()
        if self.frame_budget is not None:
            self.frame_budget.close()
            self.frame_budget = None
        if self.semantic is not None:
            self.semantic.close()
            self.semantic = None
        self.scene.close()
        if self.store is not None:
            self.store.close()
            self.store = None


def _on_own_connection(path: Path, fn: Callable[..., Any], **kwargs: Any) -> Any:
    """``fn(store, **kwargs)`` on a city store opened here, for worker threads: the store's SQLite
    connection runs Python callbacks (the query authorizer and time limit), and two threads sharing it
    deadlock (one holds the connection's mutex waiting for the GIL, the other holds the GIL waiting for the
    mutex)."""
    from citylod.semantics.store import CityStore

    with CityStore.open(path) as store:
        return fn(store, **kwargs)


def _stacked_proxy_meshes(store: Any) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64],
                                                 npt.NDArray[np.int64]]:
    from citylod.render.store_actor import stack_meshes

    meshes = []
    for i, oid in enumerate(store.ids):
        v, f = store.mesh(oid)
        if len(f):
            meshes.append((i, v, f))
    return stack_meshes(meshes)


@dataclass
class GuiTimings:
    """Longest and count of GUI-thread handler runs, per handler name (filled by the Qt profiler)."""

    max_ms: dict[str, float] = field(default_factory=dict)
    calls: dict[str, int] = field(default_factory=dict)
    slow: list[tuple[str, float]] = field(default_factory=list)

    def record(self, name: str, ms: float, threshold_ms: float = 100.0) -> bool:
        self.max_ms[name] = max(self.max_ms.get(name, 0.0), ms)
        self.calls[name] = self.calls.get(name, 0) + 1
        if ms > threshold_ms:
            self.slow.append((name, ms))
            return True
        return False

    def report(self) -> str:
        rows = sorted(self.max_ms.items(), key=lambda kv: -kv[1])
        return "\n".join(f"{name:32s} max {ms:8.1f} ms  calls {self.calls[name]}" for name, ms in rows)
