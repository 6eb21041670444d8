"""Budget mode in the app ("hold frame time" next to the fixed point budget): real keys type a target into
the LOD panel, real mouse drags move the camera, and the layers' point budget follows the measured frames;
turning it off gives the fixed budget back. The project file keeps the target; old files without it load
with the fixed budgets. Run under ``xvfb-run -a -s "-screen 0 1600x1200x24"`` (xdotool sends the input)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from tests.app.test_real_input import X, _wait_resolved, pytestmark, window, xin  # noqa: F401

__all__ = ["pytestmark"]

CORNER = np.array([500000.0, 5400000.0, 0.0])
EXTENT = 256.0


@pytest.fixture(scope="module")
def points(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small point quadtree (4 levels, 85 tiles × 4000 points)."""
    from citylod.bench.synthetic import make_point_tileset

    out = tmp_path_factory.mktemp("budget_points")
    return make_point_tileset(out / "pts", levels=4, points_per_tile=4000, extent=EXTENT, corner=CORNER)


def _camera():
    from citylod.bench.flight import default_flight

    cams = default_flight(CORNER, CORNER + np.array([EXTENT, EXTENT, 30.0]), n=30)
    return cams[len(cams) // 2]  # the low pass: most of the tiles in view


def _type_into(xin: X, widget, text: str) -> None:  # noqa: F811
    """A real click into ``widget``, select all, type ``text``, Return (as a user edits a spin box)."""
    widget.window().activateWindow()
    gx, gy = xin._global(widget, widget.width() // 2, widget.height() // 2)
    xin._run("mousemove", "--sync", str(gx), str(gy), "click", "1")
    xin._run("key", "--clearmodifiers", "ctrl+a")
    xin._run("type", "--delay", "20", text)
    xin._run("key", "Return")


def _budgets(doc) -> list[int]:
    return [int(e.layer.budget.max_points) for e in doc.entries]


def test_hold_frame_time_steers_the_budget_and_off_restores_it(qtbot, window, xin, points) -> None:  # noqa: F811
    doc, view, panel = window.document, window.view, window.lod
    assert window.open_path(points)
    qtbot.waitUntil(lambda: view.is_resolved() and doc.scene.last_stats.points > 0, timeout=120000)
    fixed = doc.lod.point_budget
    assert _budgets(doc) == [fixed] and doc.frame_budget is None
    full_points = doc.scene.last_stats.points
    window.docks["lod"].raise_()  # its tab (it shares the dock area with the point and clip panels)
    qtbot.waitUntil(lambda: panel.hold.isVisible(), timeout=5000)
    # A target far below what this view costs on any renderer (a software GL draws 340k points in tens of ms).
    _type_into(xin, panel.hold, "1")
    qtbot.waitUntil(lambda: doc.lod.target_ms == pytest.approx(1.0), timeout=10000)
    assert doc.frame_budget is not None and panel.hold.text() == "1.0 ms"
    mode = doc.frame_budget
    vw, vh = view.vtk.width(), view.vtk.height()
    path = [(vw // 4 + int(vw / 2 * i / 40), vh // 2 + int(30 * math.sin(i / 6))) for i in range(41)]
    before = view.camera()
    seen: list[int] = []
    view.frame.connect(lambda _ms: seen.append(sum(_budgets(doc))))
    xin.drag(view.vtk, path, step_s=0.03)
    qtbot.waitUntil(lambda: not view.navigator.moving, timeout=30000)
    assert np.linalg.norm(np.subtract(view.camera().position, before.position)) > 1.0  # the drag orbited
    xin.drag(view.vtk, path[::-1], step_s=0.03)
    qtbot.waitUntil(lambda: not view.navigator.moving and len(mode.frame_ms) >= 5, timeout=30000)
    # Every drawn frame was timed by budget mode, and it lowered the point budget below the fixed one.
    assert len(mode.frame_ms) >= 5 and all(ms > 0 for ms in mode.frame_ms)
    assert seen and min(seen) < fixed
    assert sum(_budgets(doc)) < fixed
    view.request_render()
    qtbot.waitUntil(lambda: doc.scene.last_stats.points < full_points, timeout=10000)
    qtbot.waitUntil(lambda: window.status.text().startswith("hold 1 ms: frame "), timeout=5000)
    assert "budget" in window.status.text()
    # Off (0 shows as "off"): the fixed budget again, and nothing steers it any more.
    _type_into(xin, panel.hold, "0")
    qtbot.waitUntil(lambda: doc.frame_budget is None, timeout=10000)
    assert panel.hold.text() == "off" and doc.lod.target_ms == 0.0
    assert _budgets(doc) == [fixed]
    n = len(mode.frame_ms)
    xin.drag(view.vtk, path, step_s=0.03)
    _wait_resolved(qtbot, window, 60000)
    assert len(mode.frame_ms) == n and _budgets(doc) == [fixed]
    assert not window.status.text().startswith("hold")


def test_project_keeps_the_frame_time_target(tmp_path, points) -> None:
    from citylod.app.models import Bookmarks, Document
    from citylod.app.project import apply_project, read_project, save_project
    from citylod.core.errors import InputError

    doc = Document(workers=1)
    try:
        doc.open(points)
        doc.set_point_budget(200_000)
        doc.set_target_ms(25.0)
        assert doc.frame_budget is not None
        path = save_project(tmp_path / "p.citylod", doc, None, Bookmarks())
    finally:
        doc.close()
    assert json.loads(path.read_text())["lod"]["target_ms"] == 25.0
    again = Document(workers=1)
    try:
        apply_project(again, read_project(path))
        assert again.lod.target_ms == 25.0 and again.lod.point_budget == 200_000
        assert again.frame_budget is not None and again.scene.before_select is not None
        again.set_target_ms(0)
        assert again.frame_budget is None and again.scene.before_select is None
        assert [int(layer.budget.max_points) for layer in again.scene.layers] == [200_000]
    finally:
        again.close()
    # A project written before budget mode (no "target_ms") opens with the fixed budgets.
    data = json.loads(path.read_text())
    del data["lod"]["target_ms"]
    old = tmp_path / "old.citylod"
    old.write_text(json.dumps(data))
    third = Document(workers=1)
    try:
        apply_project(third, read_project(old))
        assert third.lod.target_ms == 0.0 and third.frame_budget is None
        assert [int(layer.budget.max_points) for layer in third.scene.layers] == [200_000]
    finally:
        third.close()
    data["lod"]["target_ms"] = "fast"
    old.write_text(json.dumps(data))
    with pytest.raises(InputError, match="target_ms"):
        read_project(old)


def test_status_line_names_target_frame_and_budget(points) -> None:
    from citylod.app.models import Document, format_budget_status

    doc = Document(workers=1)
    try:
        assert format_budget_status(doc) == ""
        doc.open(points)
        doc.set_target_ms(16.0)
        assert format_budget_status(doc) == f"hold 16 ms: frame –, budget {doc.lod.point_budget:,} pts"
        doc.frame_budget.frame_ms.append(21.4)
        assert format_budget_status(doc).startswith("hold 16 ms: frame 21 ms")
    finally:
        doc.close()
