"""``citylod render … --camera PATH.json --target-ms MS [--point-budget N]``: budget mode over a fly-through.

The frames are written, the per-frame log holds one row per frame with the budget budget mode set, the
points drawn and the frame time it measured; the summary line is recomputed from the log. The steering is
checked against the fixed budget of the same path: with a target far below any frame's cost the budget
falls under the fixed one and fewer points are drawn. Frame times are reported, never asserted."""

from __future__ import annotations

import csv
import json
import re
import statistics
from pathlib import Path

import numpy as np
import pytest

CORNER = np.array([500000.0, 5400000.0, 0.0])
EXTENT = 256.0


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    from citylod.bench.flight import default_flight
    from citylod.bench.synthetic import make_point_tileset

    out = tmp_path_factory.mktemp("budget_cli")
    tiles = make_point_tileset(out / "pts", levels=4, points_per_tile=4000, extent=EXTENT, corner=CORNER)
    cams = default_flight(CORNER, CORNER + np.array([EXTENT, EXTENT, 30.0]), n=12)
    path = out / "flight.json"
    path.write_text(json.dumps({"cameras": [c.to_dict() for c in cams]}))
    return tiles, path


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return list(csv.DictReader(f))


def test_render_path_on_a_frame_time_budget(flight, tmp_path: Path, capsys) -> None:
    from citylod.cli import main

    tiles, cams = flight
    n = len(json.loads(cams.read_text())["cameras"])
    base = ["-q", "render", str(tiles), "--camera", str(cams), "--size", "320x180", "--point-budget", "200000"]
    # Fixed budget: frames, no log.
    assert main([*base, "-o", str(tmp_path / "fixed.png")]) == 0
    assert len(list(tmp_path.glob("fixed_*.png"))) == n
    assert not (tmp_path / "fixed_budget.csv").exists()
    capsys.readouterr()
    # Budget mode: a target no frame of 340k points reaches, so the budget must go down.
    assert main([*base, "-o", str(tmp_path / "held.png"), "--target-ms", "0.5"]) == 0
    out = capsys.readouterr().out
    assert len(list(tmp_path.glob("held_*.png"))) == n
    rows = _rows(tmp_path / "held_budget.csv")
    assert [int(r["frame"]) for r in rows] == list(range(n))
    budgets = [int(r["point_budget"]) for r in rows]
    drawn = [int(r["points_drawn"]) for r in rows]
    ms = [float(r["frame_ms"]) for r in rows]
    assert all(float(r["target_ms"]) == 0.5 for r in rows) and all(m > 0 for m in ms)
    assert budgets[0] <= 200_000 and min(budgets) < 200_000
    assert all(d <= b for d, b in zip(drawn, budgets, strict=True))
    line = next(s for s in out.splitlines() if s.startswith("budget mode:"))
    m = re.search(r"median frame ([\d.]+) ms vs target 0.5 ms, (\d+) % of (\d+) frames within", line)
    assert m is not None, line
    assert float(m.group(1)) == pytest.approx(statistics.median(ms), abs=0.051)
    share = np.mean([abs(t / 0.5 - 1) <= 0.2 for t in ms])
    assert int(m.group(2)) == round(100 * share) and int(m.group(3)) == n
    # The fixed path drew more on its heaviest frame than budget mode drew on any frame after it settled.
    fixed = _rows_fixed(tiles, cams)
    assert max(drawn[n // 2:]) < max(fixed)


def _rows_fixed(tiles: Path, cams: Path) -> list[int]:
    """Points the fixed budget draws per frame of the path (an independent off-screen render)."""
    from citylod.core.camera import load_cameras
    from citylod.lod.runtime.selection import Budget
    from citylod.render.offscreen import OffscreenRenderer

    with OffscreenRenderer([tiles], size=(320, 180)) as r:
        r.scene.layers[0].budget = Budget(max_points=200_000)
        return [r.prepare(c).points for c in load_cameras(cams)]


def test_bad_target_is_one_line_and_exit_2(flight, tmp_path: Path, capsys) -> None:
    from citylod.cli import main

    tiles, cams = flight
    for flag, val in (("--target-ms", "0"), ("--target-ms", "fast"), ("--point-budget", "-3")):
        with pytest.raises(SystemExit) as exc:
            main(["render", str(tiles), "--camera", str(cams), "-o", str(tmp_path / "x.png"), flag, val])
        assert exc.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert flag in err[-1] and "Traceback" not in "\n".join(err)
    assert not list(tmp_path.iterdir())
