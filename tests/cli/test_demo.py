"""`citylod demo` (what `make demo` runs) on a small sample: everything built, the report written, and the
sample's height datum said once rather than by every builder."""

from __future__ import annotations

import warnings

from citylod.cli import main


def test_the_demo_builds_reports_and_says_the_datum_once(tmp_path, capfd) -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main(["-q", "demo", str(tmp_path / "d"), "--no-gui", "--size", "65"]) == 0
    out, err = capfd.readouterr()
    for name in ("dsm_tiles/tileset.json", "point_tiles/tileset.json", "city.gpkg", "report/report.md",
                 "report/report.png"):
        assert (tmp_path / "d" / name).exists(), name
    assert (out + err).count("vertical datum") == 1, out + err
    assert not [w for w in caught if "vertical datum" in str(w.message)]
    assert "τ = 1 px: median frame" in out


def test_a_too_small_demo_sample_is_refused_and_writes_nothing(tmp_path, capsys) -> None:
    assert main(["-q", "demo", str(tmp_path / "d"), "--no-gui", "--size", "5"]) == 2
    assert "at least 33" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()
