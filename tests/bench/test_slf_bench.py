"""The far-field bench (issue 28) end to end on the one-box scene: it runs through the command line, writes
its report and pictures, and its numbers are consistent with what it measured."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from citylod.cli import main
from citylod.lod.build.slf import build_slf
from tests.lod.slf_scene import write_box_city


@pytest.mark.parametrize("lookup", ["gpu", "cpu"])
def test_bench_slf_command(tmp_path: Path, capsys: pytest.CaptureFixture[str], lookup: str) -> None:
    city = write_box_city(tmp_path / "city")
    slf = tmp_path / "slf"
    build_slf(city, slf, texel_m=0.5, texels=64, grid=7, oversample=2, clusters=32, progress=False)
    out = tmp_path / "report"
    assert main(["-q", "bench-slf", str(slf), "-o", str(out), "--tau", "8", "--orbit-frames", "3",
                 "--lookup", lookup]) == 0
    assert f"lookup on the {lookup.upper()}" in capsys.readouterr().out
    report = json.loads((out / "slf_report.json").read_text())
    assert report["summary"]["lookup"] == lookup
    for name in ("overview_geometry.png", "overview_slf.png", "overview_difference.png", "slf_report.md"):
        assert (out / name).stat().st_size > 0
    frames = report["frames"]
    assert {f["set"] for f in frames} >= {"overview", "slow orbit"}
    for f in frames:
        assert f["slf_ms"] > 0 and f["geometry_ms"] > 0 and f["geometry_bytes"] > 0
        assert 0 < f["geometry_triangles"] <= 12  # the box: six faces, two triangles each
        assert f["slf_bytes"] == f["slf_field_bytes"] + f["slf_building_bytes"]
        if f["building_cells"] == 0:  # fields only: the bytes are the drawn cells' files, no city tile
            assert f["slf_building_bytes"] == 0
            assert 0 < f["slf_bytes"] <= sum(p.stat().st_size for p in (slf / "slf").rglob("*.bin"))
    s = report["summary"]
    assert 0 <= s["flicker"]["pairs"] <= 2  # consecutive orbit frames whose field pixels overlap
    assert s["overview"]["frames"] == 1
