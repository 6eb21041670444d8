"""The benchmark harness: error measurement on known depth images, and a tiny end-to-end report.

Asserts on files, counters and measured errors, never on timings.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from citylod.bench.flight import default_flight, default_flight_legs
from citylod.bench.synthetic import make_terrain_tileset
from citylod.core.camera import Camera
from citylod.io.tiles3d import open_tileset
from citylod.render.depth import world_rays
from citylod.render.sse import measure_error

CORNER = np.array([500000.0, 5400000.0, 0.0])


def _plane_depth(cam: Camera, w: int, h: int, z: float) -> np.ndarray:
    rays = world_rays(cam, w, h)
    with np.errstate(divide="ignore"):
        t = (z - cam.position[2]) / rays[..., 2]
    return np.where(t > 0, t, np.inf).astype(np.float32)


def test_measured_error_of_a_shifted_plane() -> None:
    # Straight down onto a plane; a copy 0.5 m lower. On the central ray the two points are 0.5 m
    # apart, i.e. 0.5 / footprint pixels.
    w, h = 64, 48
    cam = Camera((CORNER[0], CORNER[1], 1000.0), (CORNER[0], CORNER[1], 0.0), (0.0, 1.0, 0.0), 40.0)
    full = _plane_depth(cam, w, h, 0.0)
    lod = _plane_depth(cam, w, h, -0.5)
    same = measure_error(full, full, cam)
    assert same.max_px == 0 and same.near_max_px == 0 and same.valid == w * h
    err = measure_error(lod, full, cam)
    footprint = 2 * 1000.0 * math.tan(math.radians(20)) / h
    assert err.max_px == pytest.approx(0.5 / footprint, rel=0.05)
    assert err.near_max_px <= err.max_px + 1e-6
    assert err.lod_only == err.full_only == 0
    # A hole in the LOD frame is counted, not measured.
    lod[10:12, 10:12] = np.inf
    assert measure_error(lod, full, cam).full_only == 4


def test_default_flight_covers_the_three_legs() -> None:
    cams = default_flight(CORNER, CORNER + np.array([1000.0, 800.0, 50.0]), n=30)
    assert len(cams) == 30
    heights = np.array([c.position[2] for c in cams])
    assert heights[0] > heights[9]  # the approach descends
    assert np.all(heights[10:20] < 150)  # the low pass stays low


@pytest.mark.parametrize("n", [3, 7, 30, 31])
def test_default_flight_legs_split_its_cameras(n: int) -> None:
    """The legs cover every camera of the flight once, in order, and the approach descends, the low pass
    stays low, the orbit keeps its distance from the centre."""
    legs = default_flight_legs(n)
    assert [name for name, _ in legs] == ["approach", "low pass", "orbit"]
    assert [i for _, idx in legs for i in idx] == list(range(n))
    hi = CORNER + np.array([1000.0, 800.0, 50.0])
    cams = default_flight(CORNER, hi, n=n)
    z = np.array([c.position[2] for c in cams])
    (_, app), (_, low), (_, orb) = legs
    if len(app) > 1:
        assert z[app[0]] > z[app[-1]]
    assert np.all(z[list(low)] < z[app[0]])
    centre = (CORNER + hi) / 2
    d = [np.hypot(*(np.asarray(cams[i].position[:2]) - centre[:2])) for i in orb]
    assert max(d) - min(d) < 1.0


def test_report_gives_each_leg_its_speed_up() -> None:
    """The legs' table: per leg the median frame time of each run and full / LOD, computed here again from
    the frames."""
    from citylod.bench.report import BenchResult, FrameRow, _legs_table, _summarise

    rng = np.random.default_rng(3)
    frames = []
    for cam in range(9):
        for tau, scale in ((0.0, 1.0), (1.0, 0.25 if cam < 3 else 0.8)):
            ms = float(rng.uniform(50, 150)) * scale
            frames.append(FrameRow(tau, cam, ms, 0.0, 1, int(ms * 1000), 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0))
    rows = [_summarise("full", 0.0, [f for f in frames if f.tau_px == 0.0]),
            _summarise("tau=1", 1.0, [f for f in frames if f.tau_px == 1.0])]
    res = BenchResult(rows, frames, Path("."), legs=default_flight_legs(9))
    table = _legs_table(res)
    rows = [ln for ln in table if ln.startswith("| approach") or ln.startswith("| low pass") or ln.startswith("| orbit")]
    assert len(rows) == 3
    for (name, idx), line in zip(default_flight_legs(9), rows, strict=True):
        full = np.median([f.frame_ms for f in frames if f.camera in idx and f.tau_px == 0.0])
        lod = np.median([f.frame_ms for f in frames if f.camera in idx and f.tau_px == 1.0])
        assert line.startswith(f"| {name} | {len(idx)} | {full:.1f} (")
        assert f"| {lod:.1f} (" in line and line.endswith(f", {full / lod:.1f}× |")


@pytest.mark.render
def test_run_bench_writes_a_consistent_report(tmp_path: Path) -> None:
    from citylod.bench.report import run_bench

    ts = make_terrain_tileset(tmp_path / "ts", levels=3, n=9, extent=512.0, corner=CORNER, texture_px=16)
    target = CORNER + np.array([256.0, 256.0, 0.0])
    cams = [Camera(tuple(target + np.array([0.0, -d, d * 0.6])), tuple(target), (0.0, 0.0, 1.0), 45.0) for d in (300, 800, 2000)]
    res = run_bench([ts], cams, [1.0, 8.0], (160, 120), tmp_path / "report", repeats=1)
    for name in ("report.csv", "frames.csv", "report.md", "report.png", "full.png", "diff.png", "lod_tau1.png"):
        assert (tmp_path / "report" / name).stat().st_size > 0, name
    assert [r.label for r in res.rows] == ["full", "tau=1", "tau=8"]
    full, fine, coarse = res.rows
    assert full.err_max_px == 0
    assert full.triangles_median >= fine.triangles_median >= coarse.triangles_median
    assert coarse.triangles_median < full.triangles_median
    assert len(res.frames) == (3 + 1) * 3  # the flight and the overview camera, each at full resolution and two τ
    assert all(r.frames == 3 for r in res.rows)  # the overview camera is not summarised with the flight
    # The overview camera sees the whole dataset: at full resolution every leaf, and fewer at a coarse τ.
    o_full, _, o_coarse = res.overview
    assert o_full.tiles_median == sum(1 for t in open_tileset(ts).walk() if not t.children and t.content_uri)
    assert o_coarse.triangles_median < o_full.triangles_median
    md = (tmp_path / "report" / "report.md").read_text()
    assert "| tau=8 |" in md and "full.png" in md and "Overview camera" in md


def test_report_figure_counts_what_the_data_is_made_of(tmp_path: Path) -> None:
    """The right panel of the speed-against-error figure counts points for a point cloud (whose triangle
    counts are 0, which a log axis cannot show) and triangles for surfaces."""
    import dataclasses

    from citylod.bench.report import TauRow, _plot, _size_panel

    def row(label: str, tau: float, triangles: float, points: float, ms: float, err: float) -> TauRow:
        kw = {f.name: 0.0 for f in dataclasses.fields(TauRow)}
        kw.update(label=label, tau_px=tau, triangles_median=triangles, points_median=points, frame_ms_median=ms,
                  err_p99_px=err, err_near_p99_px=err)
        for f in dataclasses.fields(TauRow):
            if f.type in ("int", int):
                kw[f.name] = int(kw[f.name])
        return TauRow(**kw)

    cloud = [row("full", 0, 0, 8e5, 100, 0), row("tau=1", 1, 0, 6e5, 80, 0.5), row("tau=4", 4, 12, 2e5, 40, 3)]
    surface = [row("full", 0, 9e5, 0, 100, 0), row("tau=1", 1, 5e5, 0, 70, 0.4)]
    assert _size_panel(cloud[0])[0] == "points_median"
    assert _size_panel(surface[0])[0] == "triangles_median"
    for name, rows in (("cloud", cloud), ("surface", surface)):
        png = _plot(tmp_path / f"{name}.png", rows)
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_coinciding_points_of_the_figure_get_one_label() -> None:
    """τ values whose points fall on the same spot of the figure are labelled together, not over each other."""
    import dataclasses

    from citylod.bench.report import TauRow, _coinciding

    rows = [TauRow(**{**{f.name: 0 for f in dataclasses.fields(TauRow)}, "label": f"tau={t}", "tau_px": t})
            for t in (0.5, 1.0, 2.0, 4.0, 8.0)]
    xs = [0.01, 0.01, 0.01, 0.01, 3.2]
    ys = [61_000.0, 61_000.0, 61_020.0, 61_000.0, 61_000.0]  # 61,020 is within a thousandth of a decade
    groups = _coinciding(rows, xs, ys)
    assert groups == {(0.01, 61_000.0): [0.5, 1.0, 2.0, 4.0], (3.2, 61_000.0): [8.0]}
    assert _coinciding(rows, [0.01, 0.02, 0.04, 0.08, 0.16], ys) == {
        (x, y): [t] for x, y, t in zip([0.01, 0.02, 0.04, 0.08, 0.16], ys, (0.5, 1.0, 2.0, 4.0, 8.0), strict=True)}


def test_default_flight_over_ecef_data_flies_around_its_vertical() -> None:
    """Another tool's ECEF tileset: the default flight and the overview camera are placed in the east /
    north / up frame of the data (z-up data keep their cameras exactly)."""
    import pyproj

    from citylod.core.camera import View, in_local_frame, local_up, overview_camera
    from citylod.core.geometry import Box

    lo, hi = np.array([500_000.0, 5_400_000.0, 0.0]), np.array([501_000.0, 5_401_000.0, 40.0])
    assert in_local_frame(default_flight, lo, hi, [0.0, 0.0, 1.0]) == default_flight(lo, hi)
    to_ecef = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    c = np.array(to_ecef.transform(4.37, 52.0, 0.0))
    elo, ehi = c - 400.0, c + 400.0
    up = local_up(pyproj.CRS("EPSG:4978"), elo, ehi)
    cams = in_local_frame(default_flight, elo, ehi, up)
    assert len(cams) == 30 and all(np.allclose(cam.view_up, up) for cam in cams)
    centre = (elo + ehi) / 2
    heights = [float(np.subtract(cam.position, centre) @ up) for cam in cams]
    assert min(heights) > 0  # every camera above the data's middle
    orbit = default_flight_legs(30)[2][1]
    assert np.ptp([heights[i] for i in orbit]) < 1e-6  # the orbit at one height over the local ground
    over = in_local_frame(lambda a, b: [overview_camera(a, b)], elo, ehi, up)[0]
    d = np.subtract(over.position, over.focal_point)
    assert math.degrees(math.asin(float(d @ up) / float(np.linalg.norm(d)))) == pytest.approx(40.0, abs=1e-6)
    assert View(over, 960, 640, near=1e-3).box_in_frustum(Box.from_bounds(elo, ehi))[1]
