"""Heights in a CRS without a vertical datum are written as ellipsoidal: ``build points`` warns once, on one
line ``citylod: warning: ...`` naming the compound CRS to pass instead; ``build dsm`` and ``build model`` say
so in their summary.
Every warning the command line prints is one line."""

from __future__ import annotations

import io
import warnings

import numpy as np
import pyproj
import pytest
import rasterio
from rasterio.transform import from_origin

from citylod.cli import main, show_warning
from tests.cli_harness import run_cli
from tests.lod.test_points_cloud import make_cloud


def _stderr_lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip()]


def _geoid_warning_expected() -> bool:
    """True when PROJ has no exact NAP -> ellipsoid transformation here (its grid is not installed), so the
    tileset writer warns about the geoid model it used instead; decided by PROJ, not by citylod."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        group = pyproj.transformer.TransformerGroup("EPSG:7415", "EPSG:4979", always_xy=True)
    return not [t for t in group.transformers if "ballpark vertical" not in t.description.lower()]


def test_points_in_a_horizontal_crs_warn_once_on_one_line(tmp_path) -> None:
    las = tmp_path / "delft.laz"
    make_cloud(las, n_terrain=4_000, rgb=False, crs="EPSG:28992")  # as AHN tiles come: RD New, NAP heights
    r = run_cli(["build", "points", las, "-o", tmp_path / "rd", "--workers", "0"], timeout_s=300)
    assert r.returncode == 0, r.stderr[-2000:]
    lines = _stderr_lines(r.stderr)
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("citylod: warning: Amersfoort / RD New has no vertical datum"), lines
    assert "ellipsoidal" in lines[0] and "EPSG:7415" in lines[0], lines

    # Naming the compound CRS silences it; what is left is at most the geoid line, one line too.
    r = run_cli(["build", "points", las, "-o", tmp_path / "nap", "--workers", "0", "--crs", "EPSG:7415"],
                timeout_s=300)
    assert r.returncode == 0, r.stderr[-2000:]
    lines = _stderr_lines(r.stderr)
    assert "vertical datum" not in r.stderr
    if _geoid_warning_expected():
        assert len(lines) == 1 and lines[0].startswith("citylod: warning: heights in NAP"), r.stderr
    else:
        assert lines == [], r.stderr


def _raster(path, crs: str):
    z = np.add.outer(np.arange(40.0), np.arange(50.0)).astype(np.float32)
    with rasterio.open(path, "w", driver="GTiff", width=50, height=40, count=1, dtype="float32", crs=crs,
                       transform=from_origin(85_000, 447_000, 1, 1)) as ds:
        ds.write(z, 1)
    return path


@pytest.mark.parametrize("kind", ["dsm", "model"])
def test_raster_in_a_horizontal_crs_says_so_in_the_summary(tmp_path, capsys, kind: str) -> None:
    args = ["-q", "build", kind, "--workers", "0", "-o"]
    assert main([*args, str(tmp_path / "rd"), str(_raster(tmp_path / "rd.tif", "EPSG:28992"))]) == 0
    out, err = capsys.readouterr()
    heights = [ln for ln in out.splitlines() if ln.startswith("heights:")]
    assert len(heights) == 1 and "no vertical datum" in heights[0] and "EPSG:7415" in heights[0], out
    assert "warning" not in err  # a summary line, not a warning: the user cannot name the datum here

    assert main([*args, str(tmp_path / "nap"), str(_raster(tmp_path / "nap.tif", "EPSG:7415"))]) == 0
    out, err = capsys.readouterr()
    assert "heights:" not in out and "vertical datum" not in err, out
    assert all(ln.startswith("citylod: warning: ") for ln in _stderr_lines(err)), err


def test_a_warning_prints_as_one_line() -> None:
    f = io.StringIO()
    show_warning(UserWarning("heights in NAP\n  raised"), UserWarning, "/x/crs.py", 12, f, "warnings.warn(w)")
    show_warning(RuntimeWarning("overflow"), RuntimeWarning, "/x/a.py", 3, f)
    assert f.getvalue().splitlines() == ["citylod: warning: heights in NAP raised",
                                         "citylod: warning: RuntimeWarning: overflow"]
