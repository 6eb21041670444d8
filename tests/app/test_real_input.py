"""The desktop application driven the way a user drives it: X input events from ``xdotool`` (through the X
server into Qt's event loop, into the real VTK widget), never direct handler calls.

Run under ``xvfb-run -a -s "-screen 0 1600x1200x24"``; skipped without a display or without xdotool
(``scripts/sysdeps.sh`` installs it).
"""

from __future__ import annotations

import math
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from tests.app.test_qt import _store, sample  # noqa: F401  (the session fixture)

pytestmark = pytest.mark.skipif(not os.environ.get("DISPLAY") or shutil.which("xdotool") is None,
                                reason="needs an X display (xvfb-run) and xdotool")


# ------------------------------------------------------------------------------------------- input
class X:
    """Mouse and keyboard through the X server (XTEST) at positions of a Qt widget."""

    def __init__(self, qtbot) -> None:
        self.qtbot = qtbot

    def _run(self, *args: str) -> None:
        proc = subprocess.Popen(["xdotool", *args])
        # Qt must keep processing events while xdotool sends them (drags wait between steps).
        self.qtbot.waitUntil(lambda: proc.poll() is not None, timeout=30000)
        assert proc.returncode == 0
        self.qtbot.wait(50)

    @staticmethod
    def _global(widget, x: int, y: int) -> tuple[int, int]:
        from PySide6.QtCore import QPoint

        g = widget.mapToGlobal(QPoint(int(x), int(y)))
        return g.x(), g.y()

    def click(self, widget, x: int, y: int, button: int = 1) -> None:
        gx, gy = self._global(widget, x, y)
        self._run("mousemove", "--sync", str(gx), str(gy), "click", str(button))

    def drag(self, widget, path: list[tuple[int, int]], button: int = 1, step_s: float = 0.03) -> None:
        args = ["mousemove", "--sync", *map(str, self._global(widget, *path[0])), "mousedown", str(button)]
        for x, y in path[1:]:
            args += ["sleep", f"{step_s}", "mousemove", *map(str, self._global(widget, x, y))]
        args += ["sleep", f"{step_s}", "mouseup", str(button)]
        self._run(*args)

    def key(self, widget, keys: str) -> None:
        widget.window().activateWindow()
        widget.setFocus()
        self.qtbot.wait(50)
        self._run("key", "--clearmodifiers", keys)


@pytest.fixture()
def xin(qtbot) -> X:
    return X(qtbot)


@pytest.fixture()
def window(qtbot, tmp_path: Path):
    from PySide6.QtCore import QSettings

    from citylod.app.qt_main_window import MainWindow

    settings = QSettings(str(tmp_path / "citylod.ini"), QSettings.Format.IniFormat)
    win = MainWindow(settings_=settings, interactive=False)
    qtbot.addWidget(win)
    win.move(0, 0)
    win.resize(1200, 800)
    win.show()
    qtbot.waitExposed(win)
    win.activateWindow()
    yield win
    win.close()


def _wait_resolved(qtbot, win, timeout_ms: int = 60000) -> None:
    def done() -> None:
        assert not win.document.semantics_pending
        assert not win.view.navigator.moving and not win.document.moving
        assert win.view.is_resolved()

    qtbot.waitUntil(done, timeout=timeout_ms)
    win.view.render_now()


# ---------------------------------------------------------------------------- independent geometry
def _dsm(path: Path):
    import rasterio

    with rasterio.open(path) as ds:
        return ds.read(1).astype(np.float64), ds.transform


def _dsm_z(dsm, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear height of the raster at (x, y), pixel centres as samples (rasterio's convention)."""
    z, t = dsm
    col, row = ~t * (np.asarray(x), np.asarray(y))
    col, row = np.asarray(col) - 0.5, np.asarray(row) - 0.5
    c0 = np.clip(np.floor(col).astype(int), 0, z.shape[1] - 2)
    r0 = np.clip(np.floor(row).astype(int), 0, z.shape[0] - 2)
    fc, fr = np.clip(col - c0, 0, 1), np.clip(row - r0, 0, 1)
    top = z[r0, c0] * (1 - fc) + z[r0, c0 + 1] * fc
    bot = z[r0 + 1, c0] * (1 - fc) + z[r0 + 1, c0 + 1] * fc
    return top * (1 - fr) + bot * fr


def _ray_hit(camera, width: int, height: int, x: int, y: int, dsm) -> np.ndarray:
    """Where the pixel ray through widget (x, y) first meets the raster surface: the camera model and
    the raster only, nothing of the renderer or the picker."""
    right, up, fwd = camera.basis()
    t = math.tan(math.radians(camera.fovy_deg) / 2.0)
    u = (2.0 * (x + 0.5) / width - 1.0) * t * width / height
    v = (1.0 - 2.0 * (y + 0.5) / height) * t
    d = fwd + u * right + v * up
    d /= np.linalg.norm(d)
    eye = np.asarray(camera.position, np.float64)
    s = np.arange(0.0, 5000.0, 0.05)
    pts = eye + s[:, None] * d
    above = pts[:, 2] - _dsm_z(dsm, pts[:, 0], pts[:, 1])
    i = int(np.argmax(above <= 0))
    assert above[i] <= 0, "the ray misses the raster"
    # Linear refinement of the crossing between the last sample above and the first below.
    a0, a1 = above[i - 1], above[i]
    return pts[i - 1] + (pts[i] - pts[i - 1]) * (a0 / (a0 - a1))


def _flat_pixel(camera, width: int, height: int, x: int, y: int, dsm) -> tuple[int, int]:
    """The pixel nearest (x, y) whose rays within 2 px all meet the raster within 0.5 m of height: a tile
    drawn within 1 px may show a roof or the ground beside it at a pixel next to a façade, so the pick is
    compared with the ray only where the surface is continuous."""
    for r in range(0, 40, 3):
        for dx, dy in ((0, r), (r, 0), (0, -r), (-r, 0), (r, r), (-r, -r), (r, -r), (-r, r)):
            px, py = x + dx, y + dy
            z = [_ray_hit(camera, width, height, px + i, py + j, dsm)[2] for i in (-2, 0, 2) for j in (-2, 0, 2)]
            if max(z) - min(z) < 0.5:
                return px, py
    raise AssertionError(f"no continuous surface near pixel {x}, {y}")


def _start_tool(qtbot, window, xin, sample, key: str, kind: str) -> None:  # noqa: F811
    """Open the sample's DSM at its camera, wait for the full frame, press a tool's key."""
    from citylod.core.camera import load_cameras

    window.open_path(sample["tiles"])
    window.view.set_camera(load_cameras(sample["camera"])[0])
    _wait_resolved(qtbot, window)
    xin.key(window.view.vtk, key)
    qtbot.waitUntil(lambda: window.view.measure_kind == kind, timeout=3000)


def _roof(doc, object_id: str) -> tuple[float, float, float]:
    """A point on the roof of an object's proxy (inside its footprint, at its un-inflated top)."""
    import shapely

    px = doc.store.proxies
    i = px.index_of(object_id)
    inside = shapely.point_on_surface(px.footprints[i])
    return inside.x, inside.y, float(px.zmax[i] - px.inflate)


# -------------------------------------------------------------------------------------------- tests
def test_click_building_fills_inspector_and_tree(qtbot, window, xin, sample) -> None:  # noqa: F811
    store_path = _store(sample)
    window.open_path(sample["tiles"])
    window.open_path(store_path)
    doc = window.document
    tallest = doc.tallest_building()
    from citylod.app.models import focus_on

    assert window.view.frame_objects([tallest])
    window.view.set_camera(focus_on(window.view.camera(), _roof(doc, tallest)))
    _wait_resolved(qtbot, window)
    vw, vh = window.view.vtk.width(), window.view.vtk.height()
    assert doc.state.selection == set()
    xin.click(window.view.vtk, vw // 2, vh // 2)
    qtbot.waitUntil(lambda: doc.state.selection == {tallest}, timeout=5000)
    assert window.tree.selected_ids() == [tallest]
    assert window.inspector.object_id == tallest
    assert tallest in window.inspector.as_text()
    # A drag (an orbit) does not pick.
    xin.drag(window.view.vtk, [(vw // 2, vh // 2), (vw // 2 + 60, vh // 2), (vw // 2 + 120, vh // 2)])
    assert doc.state.selection == {tallest}


def test_measure_distance_with_clicks(qtbot, window, xin, sample) -> None:  # noqa: F811
    _start_tool(qtbot, window, xin, sample, "m", "distance")  # Tools → Measure distance
    vw, vh = window.view.vtk.width(), window.view.vtk.height()
    cam = window.view.camera()
    dsm = _dsm(sample["dsm"])
    clicks = [_flat_pixel(cam, vw, vh, vw // 2, int(vh * 0.75), dsm),
              _flat_pixel(cam, vw, vh, vw // 3, int(vh * 0.85), dsm)]
    for x, y in clicks:
        xin.click(window.view.vtk, x, y)
    qtbot.waitUntil(lambda: window.view.measurement is not None and len(window.view.measurement.points) == 2,
                    timeout=5000)
    m = window.view.measurement
    # Each picked point is where the pixel's ray meets the raster (the tile error is ≤ 1 px on screen).
    hits = np.array([_ray_hit(cam, vw, vh, x, y, dsm) for x, y in clicks])
    picked = np.array(m.points)
    for p, h in zip(picked, hits, strict=True):
        assert np.linalg.norm(p - h) < 0.01 * np.linalg.norm(h - np.asarray(cam.position)) + 0.5
    expected = float(np.linalg.norm(hits[1] - hits[0]))
    assert m.value == pytest.approx(expected, rel=0.01)
    assert window.measure.text.startswith("distance")


def test_ellipsoidal_distance_switch_from_the_menu(qtbot, window, xin, sample) -> None:  # noqa: F811
    """Tools → Ellipsoidal distances (keyboard through the menu), then two clicks: the distance is the
    geodesic between the picked points, computed independently with pyproj's Geod on WGS84."""
    import pyproj

    _start_tool(qtbot, window, xin, sample, "m", "distance")
    xin.key(window.view.vtk, "alt+t")
    qtbot.waitUntil(lambda: window.menuBar().activeAction() is not None, timeout=3000)
    xin.key(window.menuBar(), "e")
    qtbot.waitUntil(lambda: window.document.ellipsoidal, timeout=3000)
    vw, vh = window.view.vtk.width(), window.view.vtk.height()
    for x, y in [(vw // 2, int(vh * 0.75)), (vw // 3, int(vh * 0.85))]:
        xin.click(window.view.vtk, x, y)
    qtbot.waitUntil(lambda: window.view.measurement is not None and len(window.view.measurement.points) == 2,
                    timeout=5000)
    m = window.view.measurement
    assert m.geodesic and "geodesic" in window.measure.text
    p = np.array(m.points)
    crs = window.document.crs
    lon, lat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(p[:, 0], p[:, 1])
    _az, _baz, s = pyproj.Geod(ellps="WGS84").inv(lon[0], lat[0], lon[1], lat[1])
    assert m.horizontal == pytest.approx(s, rel=1e-6)
    assert m.value == pytest.approx(float(np.hypot(s, p[1, 2] - p[0, 2])), rel=1e-6)
    # The projection's grid length differs by UTM's scale factor (about 4e-4 near the central meridian).
    grid = float(np.hypot(*(p[1, :2] - p[0, :2])))
    assert abs(grid / s - 1.0) > 1e-5


def test_profile_distance_on_the_ellipsoid(qtbot, window, xin, sample) -> None:  # noqa: F811
    """Tools → Ellipsoidal distances (through the menu), then a profile drawn with two clicks: the plot's
    distance axis is the geodesic length along the line (pyproj's Geod on WGS84, computed here from the
    plotted positions), not the projection's grid length."""
    import pyproj

    _start_tool(qtbot, window, xin, sample, "p", "profile")
    xin.key(window.view.vtk, "alt+t")
    qtbot.waitUntil(lambda: window.menuBar().activeAction() is not None, timeout=3000)
    xin.key(window.menuBar(), "e")
    qtbot.waitUntil(lambda: window.document.ellipsoidal, timeout=3000)
    vw, vh = window.view.vtk.width(), window.view.vtk.height()
    for x, y in ((vw // 4, int(vh * 0.8)), (3 * vw // 4, int(vh * 0.6))):
        xin.click(window.view.vtk, x, y)
    qtbot.waitUntil(lambda: window.document.last_profile is not None, timeout=5000)
    prof = window.document.last_profile
    d, _z = window.profile.plotted()
    assert prof.ellipsoidal and "ellipsoid" in window.profile.axes.get_xlabel()
    lon, lat = pyproj.Transformer.from_crs(window.document.crs, "EPSG:4326", always_xy=True).transform(
        prof.xyz[:, 0], prof.xyz[:, 1])
    geod = pyproj.Geod(ellps="WGS84")
    steps = [geod.inv(lon[i], lat[i], lon[i + 1], lat[i + 1])[2] for i in range(len(lon) - 1)]
    np.testing.assert_allclose(d, np.concatenate([[0.0], np.cumsum(steps)]), rtol=1e-7, atol=1e-6)
    grid = float(np.hypot(*(prof.xyz[-1, :2] - prof.xyz[0, :2])))
    assert abs(grid / d[-1] - 1.0) > 1e-5  # UTM's scale factor: the axis is not the grid length


def test_profile_heights_agree_with_raster(qtbot, window, xin, sample) -> None:  # noqa: F811
    import rasterio

    _start_tool(qtbot, window, xin, sample, "p", "profile")  # Tools → Height profile
    vw, vh = window.view.vtk.width(), window.view.vtk.height()
    for x, y in ((vw // 4, int(vh * 0.8)), (3 * vw // 4, int(vh * 0.6))):
        xin.click(window.view.vtk, x, y)
    qtbot.waitUntil(lambda: window.document.last_profile is not None, timeout=5000)
    prof = window.document.last_profile
    d, z = window.profile.plotted()
    assert len(z) == len(prof.xyz) and np.isfinite(z).mean() > 0.5
    a, b = np.array(window.view.measurement.points)[:, :2]
    assert d[-1] == pytest.approx(np.linalg.norm(b - a), rel=1e-6)
    # The raster along the same line, sampled by rasterio at each plotted position.
    xy = a + (d / d[-1])[:, None] * (b - a)
    with rasterio.open(sample["dsm"]) as ds:
        nearest = np.array([v[0] for v in ds.sample(xy)], np.float64)
        res = max(abs(ds.res[0]), abs(ds.res[1]))
        # Between raster samples any interpolation lies within the surrounding samples' range, so the
        # drawn surface must lie within that range widened by the tiles' certified error.
        neigh = []
        for ox in (-res, 0.0, res):
            for oy in (-res, 0.0, res):
                neigh.append([v[0] for v in ds.sample(xy + [ox, oy])])
        nodata = ds.nodata
    neigh = np.array(neigh, np.float64)
    # The sample city has no-data holes: the surface has a gap there (NaN in the plot); compare where the
    # raster is valid around the sample, and there every sample must have a height.
    valid = np.all(neigh != nodata, axis=0)
    assert valid.mean() > 0.5
    assert np.isfinite(z[valid]).all()
    ok = valid
    tol = prof.bound_m + 1e-3
    assert np.all(z[ok] >= neigh.min(axis=0)[ok] - tol)
    assert np.all(z[ok] <= neigh.max(axis=0)[ok] + tol)
    # And on most samples (all but cliffs) the plotted height is the raster's to within that error.
    close = np.abs(z[ok] - nearest[ok]) <= tol + 0.25
    assert close.mean() > 0.8, f"median |Δz| {np.median(np.abs(z[ok] - nearest[ok])):.3f} m"


def _orbit_sources(sample) -> tuple[list[Path], Path | None]:  # noqa: F811
    """The test's tiny sample, or a bigger built city from ``CITYLOD_ORBIT_CITY`` (a folder with
    ``dsm_tiles`` and optionally ``city.gpkg``, ``points_tiles``, ``camera.json``) for the measurement."""
    city = os.environ.get("CITYLOD_ORBIT_CITY")
    if not city:
        return [sample["tiles"]], sample["camera"]
    root = Path(city)
    srcs = [root / n for n in ("dsm_tiles", "city.gpkg", "points_tiles") if (root / n).exists()]
    cam = root / "camera.json"
    return srcs, cam if cam.exists() else None


def test_orbit_coarsens_while_moving_and_refines_after(qtbot, window, xin, sample) -> None:  # noqa: F811
    """Orbit with a real drag: frames during motion use τ × motion factor, the camera keeps a level
    horizon, and once the mouse is released a full-quality (τ) frame is drawn. Prints the frame times
    (run with ``-s``; ``CITYLOD_ORBIT_CITY`` selects a bigger city) — timings are reported, not asserted."""
    import time

    from citylod.app import qt_profile
    from citylod.core.camera import load_cameras

    sources, camera = _orbit_sources(sample)
    for s in sources:
        assert window.open_path(s)
    if camera is not None:
        window.view.set_camera(load_cameras(camera)[0])
    _wait_resolved(qtbot, window, 180000)
    doc, view = window.document, window.view
    tau = doc.lod.tau_px
    frames: list[tuple[float, float, bool, float, bool, float]] = []
    # CPU time of the whole process per frame (GUI thread and llvmpipe's threads): unlike wall time it
    # hardly depends on what else the machine runs.
    cpu0 = [0.0]
    view.window.AddObserver("StartEvent", lambda *_: cpu0.__setitem__(0, time.process_time()))

    def on_frame(ms: float) -> None:
        frames.append((time.perf_counter(), ms, doc.moving, doc.scene.last_stats.tau_px,
                       bool(doc.scene.last_stats.complete and view.pending() == 0),
                       (time.process_time() - cpu0[0]) * 1e3))

    view.frame.connect(on_frame)
    qt_profile.TIMINGS.max_ms.clear()
    qt_profile.TIMINGS.slow.clear()
    vw, vh = view.vtk.width(), view.vtk.height()
    path = [(vw // 4 + int(vw / 2 * i / 80), vh // 2 + int(40 * math.sin(i / 8))) for i in range(81)]
    before = view.camera()
    xin.drag(view.vtk, path, step_s=0.025)
    qtbot.waitUntil(lambda: frames and not frames[-1][2] and frames[-1][4], timeout=30000)
    view.frame.disconnect(on_frame)
    after = view.camera()
    # The orbit turned the camera about the vertical and kept the horizon level.
    # (No roll: the camera's right vector stays horizontal.)
    assert abs(after.basis()[0][2]) < 1e-9 and after.basis()[1][2] > 0
    assert np.linalg.norm(np.subtract(after.position, before.position)) > 1.0
    np.testing.assert_allclose(after.focal_point, before.focal_point, atol=1e-6)
    moving = [f for f in frames if f[2]]
    assert len(moving) >= 5, "the view must render while the camera moves"
    assert all(f[3] == pytest.approx(tau * doc.lod.motion_factor) for f in moving)
    assert frames[-1][3] == pytest.approx(tau) and not frames[-1][2]
    t_moving = np.array([f[0] for f in moving])
    ms = np.array([f[1] for f in moving])
    cpu_ms = np.array([f[5] for f in moving])
    handlers_moving = dict(qt_profile.TIMINGS.max_ms)
    period = np.diff(t_moving) * 1e3 if len(t_moving) > 1 else np.array([np.nan])
    # From the last camera change (the navigator's clock is time.monotonic) to the full-quality frame.
    full = frames[-1][0] - (view.navigator.last_motion_s - time.monotonic() + time.perf_counter())
    worst = sorted(handlers_moving.items(), key=lambda kv: -kv[1])[:3]
    # Baselines in the same run: the same drag drawn at full quality while moving (what the view did
    # before motion coarsening), and the same window rendering nothing (clear and present only), which on
    # a software-GL machine is a floor.
    factor, cap = doc.lod.motion_factor, doc.lod.motion_point_budget
    doc.lod.motion_factor, doc.lod.motion_point_budget = 1.0, doc.lod.point_budget
    frames.clear()
    view.frame.connect(on_frame)
    xin.drag(view.vtk, path[::-1], step_s=0.025)
    qtbot.waitUntil(lambda: frames and not frames[-1][2] and frames[-1][4], timeout=60000)
    view.frame.disconnect(on_frame)
    doc.lod.motion_factor, doc.lod.motion_point_budget = factor, cap
    full_ms = np.array([f[1] for f in frames if f[2]])
    for layer in doc.scene.layers:
        layer.visible = False
    empty = []
    for _ in range(7):
        t0 = time.perf_counter()
        view.window.Render()
        empty.append((time.perf_counter() - t0) * 1e3)
    for layer in doc.scene.layers:
        layer.visible = True
    print(f"\norbit over {', '.join(s.name for s in sources)}: {len(moving)} frames while moving at "
          f"τ {tau * doc.lod.motion_factor:g} px, ≤{doc.lod.motion_point_budget} points a layer "
          f"(load average {os.getloadavg()[0]:.1f}): render median {np.median(ms):.1f} ms (max {ms.max():.1f}; "
          f"process CPU median {np.median(cpu_ms):.1f} ms), "
          f"frame interval median {np.median(period):.1f} ms; full quality (τ {tau:g} px, all tiles) "
          f"{full * 1e3:.0f} ms after release; longest GUI-thread handlers: "
          + ", ".join(f"{n} {v:.0f} ms" for n, v in worst)
          + f"; baselines: the same drag at full quality {np.median(full_ms):.1f} ms median "
          f"(motion frame = {np.median(ms) / np.median(full_ms):.2f}× that), the empty {vw}×{vh} view "
          f"{np.median(empty):.1f} ms")


def test_city_store_alone_is_drawn_and_pickable(qtbot, window, xin, sample) -> None:  # noqa: F811
    """A city model opened without a tileset shows its objects (lit proxies), the layer checkbox hides
    them, and a click picks the object under the cursor."""
    store_path = _store(sample)
    assert window.open_path(store_path)
    view, doc = window.view, window.document
    qtbot.waitUntil(lambda: view.store_actor is not None, timeout=30000)
    view.render_now()
    from tests.app.test_qt import _rgb

    def drawn_fraction() -> float:
        rgb = _rgb(view.framebuffer()).astype(int)
        background = np.array([0.72, 0.80, 0.90]) * 255
        return float((np.abs(rgb - background).sum(axis=2) > 40).mean())

    shown = drawn_fraction()
    assert shown > 0.02, "the city objects must be visible"
    # Lit: roofs and the walls facing and facing away from the sun differ (≥ 3 shades besides the sky).
    image = view.framebuffer()
    if os.environ.get("CITYLOD_TEST_IMAGES"):
        image.save(str(Path(os.environ["CITYLOD_TEST_IMAGES"]) / "store_alone.png"))
    rgb = _rgb(image).astype(int).reshape(-1, 3)
    assert len(np.unique(rgb // 8, axis=0)) >= 4
    # The layer's checkbox (a real click on it) hides the objects.
    check = window.layers.rows[0][0]
    assert check.isEnabled()
    xin.click(check, 8, check.height() // 2)
    qtbot.waitUntil(lambda: not doc.entries[0].visible, timeout=3000)
    assert drawn_fraction() < min(0.01, shown / 4)  # only the scale bar and north arrow remain
    xin.click(check, 8, check.height() // 2)
    qtbot.waitUntil(lambda: doc.entries[0].visible, timeout=3000)
    # Click the tallest building from above.
    tallest = doc.tallest_building()
    from citylod.app.models import focus_on

    assert view.frame_objects([tallest])
    view.set_camera(focus_on(view.camera(), _roof(doc, tallest)))
    qtbot.waitUntil(lambda: not view.navigator.moving and not doc.moving, timeout=3000)
    view.render_now()
    xin.click(view.vtk, view.vtk.width() // 2, view.vtk.height() // 2)
    qtbot.waitUntil(lambda: doc.state.selection == {tallest}, timeout=5000)
    assert window.inspector.object_id == tallest


def _write_las_without_crs(path: Path, n: int = 3000) -> None:
    import laspy

    rng = np.random.default_rng(3)
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales = np.array([0.01, 0.01, 0.01])
    header.offsets = np.array([85000.0, 447500.0, 0.0])
    las = laspy.LasData(header)
    las.x = 85000.0 + rng.random(n) * 40.0
    las.y = 447500.0 + rng.random(n) * 40.0
    las.z = rng.random(n) * 5.0
    las.classification = rng.choice(np.array([2, 6], np.uint8), n)
    las.write(str(path))


def type_into_dialog(dialog, text: str, *, delay_ms: int, first_ms: int, give_up_ms: int) -> list[bool]:
    """Once ``dialog()`` shows a dialog, type ``text`` into it with real keys (select all, type, Return).

    The timers run inside the dialog's own event loop (the call that opens it blocks there). Returns the
    list that gets True once the keys are sent; the dialog is rejected after ``give_up_ms`` so the suite
    never hangs on one that did not get them."""
    from PySide6.QtCore import QTimer

    typed: list[bool] = []

    def answer() -> None:
        dlg = dialog()
        if dlg is None:
            QTimer.singleShot(200, answer)
            return
        dlg.activateWindow()
        dlg.raise_()
        for args in (["key", "--clearmodifiers", "ctrl+a"], ["type", "--delay", str(delay_ms), text],
                     ["key", "Return"]):
            subprocess.run(["xdotool", *args], check=True, timeout=30)
        typed.append(True)

    def give_up() -> None:
        dlg = dialog()
        if dlg is not None:
            dlg.reject()

    QTimer.singleShot(first_ms, answer)
    QTimer.singleShot(give_up_ms, give_up)
    return typed


def test_laz_without_crs_prompts_and_builds(qtbot, window, xin, tmp_path) -> None:
    """Opening a LAS without a CRS asks for one (typed on the keyboard), builds and opens the octree; a
    build that fails leaves no progress dialog behind."""
    from PySide6.QtWidgets import QApplication, QInputDialog, QProgressDialog

    las = tmp_path / "nocrs.las"
    _write_las_without_crs(las)
    window.interactive = True

    def dialog():
        return next((w for w in QApplication.topLevelWidgets()
                     if isinstance(w, QInputDialog) and w.isVisible()), None)

    typed = type_into_dialog(dialog, "EPSG:28992", delay_ms=20, first_ms=500, give_up_ms=20000)
    assert window.open_path(las), window.errors
    assert typed and dialog() is None
    qtbot.waitUntil(lambda: any(e.kind == "tileset" for e in window.document.entries), timeout=120000)
    entry = next(e for e in window.document.entries if e.kind == "tileset")
    assert window.document.crs.to_epsg() == 28992
    assert entry.layer.kind == "points"
    # A build that fails at once (not a LAS file) reports the error and no progress dialog stays.
    window.interactive = False
    bad = tmp_path / "broken.laz"
    bad.write_bytes(b"not a point cloud" * 10)
    errors = len(window.errors)
    assert window.open_path(bad)
    qtbot.waitUntil(lambda: len(window.errors) > errors, timeout=60000)
    qtbot.wait(800)  # longer than the dialog's minimum duration (300 ms)
    assert not [w for w in QApplication.topLevelWidgets() if isinstance(w, QProgressDialog) and w.isVisible()]


# ------------------------------------------------------------------------------- README pictures
def _picture_dir(tmp_path: Path) -> Path:
    """Where the pictures go: ``CITYLOD_README_IMAGES`` (docs/images when refreshing the README) or tmp."""
    out = Path(os.environ.get("CITYLOD_README_IMAGES") or tmp_path)
    out.mkdir(parents=True, exist_ok=True)
    return out


def test_picture_picked_building_with_measurement(qtbot, window, xin, sample, tmp_path) -> None:  # noqa: F811
    """README picture: a building picked with a click (inspector and tree filled), a distance measured
    with two clicks. ``CITYLOD_ORBIT_CITY`` selects a bigger built city."""
    window.resize(1600, 1000)
    sources, _camera = _orbit_sources(sample)
    if not any(s.suffix == ".gpkg" for s in sources):
        sources.append(_store(sample))
    for s in sources:
        assert window.open_path(s)
    doc, view = window.document, window.view
    tallest = doc.tallest_building()
    from citylod.app.models import focus_on
    from citylod.app.navigation import orbit

    assert view.frame_objects([tallest])
    # Look at the roof from a little to the side: the building is in the middle of the view.
    view.set_camera(orbit(focus_on(view.camera(), _roof(doc, tallest), zoom=1.0), 25.0, 0.0))
    _wait_resolved(qtbot, window, 180000)
    vw, vh = view.vtk.width(), view.vtk.height()
    xin.click(view.vtk, vw // 2, vh // 2)
    qtbot.waitUntil(lambda: doc.state.selection == {tallest}, timeout=5000)
    xin.key(view.vtk, "m")
    qtbot.waitUntil(lambda: view.measure_kind == "distance", timeout=3000)
    for x, y in ((vw // 2, vh // 2), (int(vw * 0.56), int(vh * 0.62))):  # from the roof down its side
        xin.click(view.vtk, x, y)
    qtbot.waitUntil(lambda: view.measurement is not None and len(view.measurement.points) == 2, timeout=5000)
    assert window.inspector.object_id == tallest
    _wait_resolved(qtbot, window, 60000)
    # The segment runs from the roof down the wall, inside the house: it is drawn over it all the same.
    from tests.app.test_qt import _rgb

    rgb = _rgb(view.framebuffer()).astype(int)
    seen = 0
    for f in (0.3, 0.5, 0.7):
        x, y = _on_screen(view, (1 - f) * np.asarray(view.measurement.points[0]) + f * np.asarray(
            view.measurement.points[1]))
        patch = rgb[y - 1: y + 2, x - 1: x + 2].reshape(-1, 3)
        seen += bool(((patch[:, 0] > 200) & (patch[:, 1] > 170) & (patch[:, 2] < 90)).any())
    assert seen == 3
    out = window.save_screenshot(_picture_dir(tmp_path) / "app_pick_measure.png")
    assert out.is_file()


def _on_screen(view, world) -> tuple[int, int]:
    """Widget pixel (x right, y down) of a world point, through VTK's own projection of the view."""
    w = np.asarray(world, np.float64) - view.scene.origin
    view.renderer.SetWorldPoint(*w, 1.0)
    view.renderer.WorldToDisplay()
    dx, dy, _ = view.renderer.GetDisplayPoint()
    return int(round(dx)), int(round(view.vtk.height() - 1 - dy))


@pytest.mark.realdata
def test_picture_delft_classes_and_clip_box(qtbot, window, xin, tmp_path_factory, tmp_path) -> None:
    """README picture on real data: Delft AHN3 points coloured by class, the class legend with one class
    unchecked by a click (those points disappear), and a clipping box set with a click."""
    from tests.paths import DELFT

    files = [DELFT / "ahn3_cropped_1.laz", DELFT / "ahn3_cropped_2.laz"]
    if not all(f.is_file() for f in files):
        pytest.skip(f"Delft data not found under {DELFT}")
    from citylod.lod.build.points import build_points

    out = tmp_path_factory.mktemp("delft") / "points"
    build_points(files, out, crs="EPSG:28992", progress=False, workers=1)
    window.resize(1600, 1000)
    assert window.open_path(out)
    doc, view = window.document, window.view
    window.layers.rows[0][2].setCurrentText("classification")
    from citylod.app.navigation import dolly, orbit

    view.set_camera(dolly(orbit(view.camera(), 0.0, 5.0), 0.6))
    _wait_resolved(qtbot, window, 180000)
    window.docks["points"].raise_()
    qtbot.wait(100)
    xin.click(panel_edl := window.points.edl, 8, panel_edl.height() // 2)
    qtbot.waitUntil(lambda: window.document.edl, timeout=3000)
    panel = window.points
    qtbot.waitUntil(lambda: {1, 2, 6} <= set(panel._classes), timeout=5000)
    drawn_before = doc.scene.last_stats.points
    # Uncheck "unclassified" with a click on its box in the legend.
    item = panel._classes[1]
    rect = panel.legend.visualItemRect(item)
    xin.click(panel.legend.viewport(), rect.left() + 10, rect.center().y())
    qtbot.waitUntil(lambda: doc.class_filter is not None and 1 not in doc.class_filter, timeout=5000)
    # The clipping box: "Around the view" in the Clipping dock.
    window.docks["clip"].raise_()
    from PySide6.QtWidgets import QPushButton

    button = next(b for b in window.clip.findChildren(QPushButton) if b.text() == "Around the view")
    qtbot.wait(100)
    xin.click(button, button.width() // 2, button.height() // 2)
    qtbot.waitUntil(lambda: doc.clip_box is not None, timeout=5000)
    view.set_camera(orbit(view.camera(), 0.0, -5.0))
    _wait_resolved(qtbot, window, 120000)
    lo, hi = doc.clip_box
    assert np.all(hi - lo > 1.0)
    # Unclassified points are no longer drawn: no drawn vertex of any point tile has class 1.
    layer = doc.scene.layers[0]
    for key in layer.shown_keys:
        slot = layer._slots[key]
        if slot.points is not None and slot.points.keep is not None:
            cls = slot.prepared.points.classification
            assert not np.any(slot.points.keep & (cls == 1))
    window.docks["points"].raise_()
    qtbot.wait(100)
    shot = window.save_screenshot(_picture_dir(tmp_path) / "app_delft_classes_clip.png")
    assert shot.is_file() and drawn_before > 0


def test_cli_view_profile_gui(sample, tmp_path) -> None:  # noqa: F811
    """``citylod view --profile-gui`` (documented, once rejected by the parser) runs, times every GUI event
    and prints the longest per handler at exit, with exit code 0."""
    import sys

    out = tmp_path / "shot.png"
    env = dict(os.environ, XDG_CONFIG_HOME=str(tmp_path / "config"))
    r = subprocess.run([sys.executable, "-m", "citylod.cli", "view", str(sample["tiles"]), "--camera",
                        str(sample["camera"]), "--screenshot", str(out), "--exit", "--profile-gui"],
                       capture_output=True, text=True, timeout=180, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    assert out.is_file()
    assert "GUI-thread handlers (longest run):" in r.stderr
    assert "SceneView.render" in r.stderr and "event." in r.stderr


def _box_far_field(tmp_path: Path) -> Path:
    from citylod.lod.build.slf import build_slf
    from tests.lod.slf_scene import write_box_city

    out = tmp_path / "far"
    build_slf(write_box_city(tmp_path / "city"), out, texel_m=0.5, texels=128, grid=11, oversample=2, clusters=64,
              progress=False)
    return out


def _far_camera(dist: float, az_deg: float, el_deg: float):
    from citylod.core.camera import Camera
    from tests.lod.slf_scene import X0, Y0, Z0

    c = np.array([X0 + 30.0, Y0 + 30.0, Z0])
    az, el = math.radians(az_deg), math.radians(el_deg)
    eye = c + dist * np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])
    return Camera(tuple(eye), tuple(c), (0.0, 0.0, 1.0), 20.0)


def _offscreen_far(path: Path, camera, size: tuple[int, int], tau: float):
    """The same camera drawn by an off-screen SlfView of its own: (picture, field pixels)."""
    from citylod.render.slf import SlfView

    with SlfView(path, size=size, tau_px=tau) as sv:
        sv.prepare(camera)
        sv.draw()
        return sv.grab_rgb().astype(int), sv.field_mask()


def _box_store(tmp_path: Path) -> Path:
    """The far-field box as a one-building city store (CityJSON → ``build_city``)."""
    import json

    from citylod.semantics.store import build_city
    from tests.lod.slf_scene import BOX, X0, Y0, Z0

    lo, hi = BOX
    corners = [(x, y, z) for z in (lo[2], hi[2]) for x, y in ((lo[0], lo[1]), (hi[0], lo[1]), (hi[0], hi[1]),
                                                               (lo[0], hi[1]))]
    verts = [[round((x - X0) * 1000), round((y - Y0) * 1000), round((z - Z0) * 1000)] for x, y, z in corners]
    shell = [[[0, 3, 2, 1]], [[4, 5, 6, 7]], [[0, 1, 5, 4]], [[1, 2, 6, 5]], [[2, 3, 7, 6]], [[3, 0, 4, 7]]]
    doc = {"type": "CityJSON", "version": "1.1",
           "transform": {"scale": [0.001, 0.001, 0.001], "translate": [X0, Y0, Z0]},
           "metadata": {"referenceSystem": "https://www.opengis.net/def/crs/EPSG/0/32632"},
           "CityObjects": {"BOX": {"type": "Building", "attributes": {"name": "the box"},
                                   "geometry": [{"type": "Solid", "lod": "1", "boundaries": [shell]}]}},
           "vertices": verts}
    (tmp_path / "box.city.json").write_text(json.dumps(doc))
    build_city(tmp_path / "box.city.json", tmp_path / "box.gpkg", progress=False)
    return tmp_path / "box.gpkg"


def test_a_click_on_a_far_field_building_selects_it(qtbot, window, xin, tmp_path) -> None:
    """The far field draws its buildings into the terrain's texture, so the depth under a roof's pixel is the
    ground behind it. An X click on the box's roof, as the field shows it from 2 km at 40°, selects the box
    (its store opened beside the field); a click on open ground beside it selects nothing."""
    from tests.app.test_qt import _rgb
    from tests.lod.slf_scene import ROOF

    far_dir = _box_far_field(tmp_path)
    assert window.open_path(far_dir) and window.open_path(_box_store(tmp_path))
    doc, view = window.document, window.view
    doc.set_tau(8.0)
    view.set_camera(_far_camera(2000.0, 200.0, 40.0))
    _wait_resolved(qtbot, window)
    far = doc.entries[0].far
    assert far.last_frame is not None and far.last_frame.geometry_cells == 0  # the box is in the field
    rgb = _rgb(view.framebuffer()).astype(int)
    roof = np.all(np.abs(rgb - ROOF) < 40, axis=2)
    h, w = roof.shape
    roof[: h // 3], roof[2 * h // 3:], roof[:, : w // 3], roof[:, 2 * w // 3:] = False, False, False, False  # the box
    assert roof.sum() >= 4  # is in the middle (the north arrow's red is near the roof's)
    ys, xs = np.nonzero(roof)
    k = int(np.argmin((ys - ys.mean()) ** 2 + (xs - xs.mean()) ** 2))  # the roof pixel nearest its middle
    xin.click(view.vtk, int(xs[k]), int(ys[k]))
    qtbot.waitUntil(lambda: doc.state.selection == {"BOX"}, timeout=5000)
    ground = (int(xs[k]) + 60, int(ys[k]))  # 70 m east of the box, on the field's open ground
    assert not roof[ground[1], ground[0]]
    xin.click(view.vtk, *ground)
    qtbot.waitUntil(lambda: not doc.state.selection, timeout=5000)


def test_far_field_tileset_is_drawn_with_its_fields_and_follows_a_drag(qtbot, window, xin, sample,  # noqa: F811
                                                                        tmp_path) -> None:
    """A far-field tileset opened in the app is drawn with its light fields, evaluated for the view's
    direction: the app's picture of the field equals an off-screen SlfView's for the same camera, before and
    after an orbit by a real mouse drag, and the drag re-evaluates the field for the new direction. The field
    hands over to buildings at twice the view's τ: at the default 1 px, from 1.5 km, the app draws the field
    where a far field switched at 1 px draws the box."""
    from citylod.render.slf import FIELD_TAU_SCALE, SlfView
    from tests.app.test_qt import _rgb

    far_dir = _box_far_field(tmp_path)
    assert window.open_path(far_dir)
    doc = window.document
    entry = doc.entries[-1]
    assert entry.kind == "far field" and entry.far is not None and entry.layer is None
    view = window.view
    view.set_camera(_far_camera(1500.0, 200.0, 40.0))
    _wait_resolved(qtbot, window)
    assert doc.effective_tau() == 1.0 and entry.far.tau_px == FIELD_TAU_SCALE * 1.0
    assert entry.far.last_frame is not None and entry.far.last_frame.geometry_cells == 0
    with SlfView(far_dir, size=(view.vtk.width(), view.vtk.height()), tau_px=1.0) as at_tau:
        assert at_tau.prepare(view.camera()).geometry_cells >= 1
    doc.set_tau(8.0)
    view.set_camera(_far_camera(2000.0, 200.0, 40.0))
    _wait_resolved(qtbot, window)
    far = entry.far

    def compare() -> tuple[float, int]:
        got = _rgb(view.framebuffer()).astype(int)
        h, w = got.shape[:2]
        want, mask = _offscreen_far(far_dir, view.camera(), (w, h), FIELD_TAU_SCALE * 8.0)
        d = np.abs(got - want).mean(axis=2)[mask]
        return float(d.mean()), int(mask.sum())

    frame = far.last_frame
    assert frame is not None and frame.cells >= 1 and frame.geometry_cells == 0
    err, pixels = compare()
    assert pixels > 300 and err < 2.0, (err, pixels)
    cell = next(c for c in far.cells.values() if c.actor.GetVisibility())
    before = cell.last_dir.copy()
    cam_before = view.camera()
    w, h = view.vtk.width(), view.vtk.height()
    xin.drag(view.vtk, [(w // 2 + dx, h // 2) for dx in range(0, 241, 20)])
    _wait_resolved(qtbot, window)
    assert np.linalg.norm(np.subtract(view.camera().position, cam_before.position)) > 100.0  # it orbited
    assert math.degrees(math.acos(min(1.0, float(before @ cell.last_dir)))) > 5.0  # evaluated again
    assert cell.gpu_patch is not None  # evaluated per pixel by the cell's shader in the window's context
    assert far.cache_bytes == (doc.lod.memory_mb << 20) // 4
    doc.set_memory_budget(64)
    assert far.cache_bytes == 16 << 20  # a quarter of the memory budget
    err, pixels = compare()
    assert pixels > 300 and err < 2.0, (err, pixels)
    window._update_status()
    assert "light-field cells" in window.status.text() and "τ 0.00" not in window.status.text()
    # A city store opened beside it is not drawn as proxy solids over the fields (it picks through them).
    assert window.open_path(_store(sample))
    _wait_resolved(qtbot, window)
    qtbot.wait(300)  # a store drawn alone has its proxies meshed on a worker, then attached by a frame
    view.render_now()
    qtbot.waitUntil(lambda: view._store_future is None, timeout=20000)
    view.render_now()
    assert view.store_actor is None or not view.store_actor.actor.GetVisibility()
    assert any(c.actor.GetVisibility() for c in far.cells.values())
    doc.set_visible(0, False)
    view.render_now()
    assert not any(c.actor.GetVisibility() for c in far.cells.values())


def test_an_ecef_tileset_turns_about_its_local_vertical(qtbot, window, xin) -> None:
    """Another tool's geocentric tileset (Cesium's Composite sample): the home view stands on the local
    vertical, and a real mouse drag turns the camera about it: the horizon stays level (the camera's right
    vector square to that vertical) and the eye keeps its height over the focal point."""
    from tests.paths import ROOT

    assert window.open_path(ROOT / "tests" / "data" / "3dtiles" / "Composite" / "CompositeOfInstanced")
    view = window.view
    view.reset_view()
    _wait_resolved(qtbot, window)
    up = window.document.up()
    before = view.camera()
    assert abs(float(up[2])) < 0.99  # not world z
    assert abs(float(before.basis()[0] @ up)) < 1e-6 and float(np.asarray(before.view_up) @ up) > 0
    w, h = view.vtk.width(), view.vtk.height()
    xin.drag(view.vtk, [(w // 2 + dx, h // 2) for dx in range(0, 241, 20)])
    _wait_resolved(qtbot, window)
    after = view.camera()
    assert np.linalg.norm(np.subtract(after.position, before.position)) > 1.0  # it orbited
    assert abs(float(after.basis()[0] @ up)) < 1e-6
    height = [float(np.subtract(c.position, c.focal_point) @ up) for c in (before, after)]
    assert height[1] == pytest.approx(height[0], rel=1e-6)
