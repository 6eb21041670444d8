"""The command line: info on each kind of source, and errors as one line with exit code 2."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rasterio
from rasterio.transform import from_origin

from citylod.cli import main


def _raster(path):
    z = np.add.outer(np.arange(40.0), np.arange(50.0)).astype(np.float32)
    with rasterio.open(path, "w", driver="GTiff", width=50, height=40, count=1, dtype="float32",
                       crs="EPSG:32632", transform=from_origin(500_000, 5_400_000, 1, 1)) as ds:
        ds.write(z, 1)
    return path


def test_info_on_raster_and_tileset(tmp_path, capsys) -> None:
    r = _raster(tmp_path / "d.tif")
    assert main(["info", str(r)]) == 0
    assert "50×40" in capsys.readouterr().out
    assert main(["-q", "build", "dsm", str(r), "-o", str(tmp_path / "t"), "--workers", "0"]) == 0
    capsys.readouterr()
    assert main(["info", str(tmp_path / "t")]) == 0
    out = capsys.readouterr().out
    assert "kind dsm" in out and "EPSG:32632" in out


def test_info_gives_a_rasters_heights_and_writes_nothing(tmp_path, capsys, monkeypatch) -> None:
    """The range of heights (what a flood level is chosen from): exact from the samples, no-data left out;
    past the size read whole, GDAL's approximate statistics, said so. No .aux.xml appears beside the file."""
    import citylod.cli.info as info

    z = np.add.outer(np.arange(40.0), np.arange(50.0)).astype(np.float32) + 100.0
    z[:5, :5] = -9999.0
    r = tmp_path / "h.tif"
    with rasterio.open(r, "w", driver="GTiff", width=50, height=40, count=1, dtype="float32", nodata=-9999.0,
                       crs="EPSG:32632", transform=from_origin(500_000, 5_400_000, 1, 1)) as ds:
        ds.write(z, 1)
    valid = z[z > -9999.0]
    assert main(["info", str(r)]) == 0
    out = capsys.readouterr().out
    assert f"heights  {valid.min():.2f} … {valid.max():.2f}" in out and f"{100 * valid.size / z.size:.1f} %" in out
    assert "x 500000.00 … 500050.00, y 5399960.00 … 5400000.00" in out
    assert f"(mean {valid.astype(np.float64).mean():.2f})" in out
    monkeypatch.setattr(info, "_STRIP_SAMPLES", 120)  # strips of 2 rows: the same exact figures
    assert main(["info", str(r)]) == 0
    assert f"heights  {valid.min():.2f} … {valid.max():.2f} (mean {valid.astype(np.float64).mean():.2f})" \
        in capsys.readouterr().out
    monkeypatch.setattr(info, "_EXACT_HEIGHTS_SAMPLES", 100)
    assert main(["info", str(r)]) == 0
    out = capsys.readouterr().out
    assert "heights  ≈" in out and "approximate" in out
    assert sorted(f.name for f in tmp_path.iterdir()) == ["h.tif"]


def test_a_closed_pipe_ends_the_command_quietly(tmp_path) -> None:
    """``citylod info X | head``: the reader closes the pipe before the command writes; no traceback."""
    import subprocess
    import sys

    r = _raster(tmp_path / "d.tif")
    p = subprocess.Popen([sys.executable, "-m", "citylod.cli", "info", str(r)], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE)
    assert p.stdout is not None and p.stderr is not None
    p.stdout.close()  # long before the interpreter has started and written anything
    err = p.stderr.read().decode()
    assert p.wait(timeout=120) == 141 and "Traceback" not in err and err == "", err


def test_errors_are_one_line_with_exit_code_2(tmp_path, capsys) -> None:
    assert main(["info", str(tmp_path / "missing.tif")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing.tif" in err[0] and "Traceback" not in err[0]
    (tmp_path / "bad.laz").write_bytes(b"LASF" + b"\0" * 50)
    assert main(["build", "points", str(tmp_path / "bad.laz"), "-o", str(tmp_path / "p")]) == 2
    assert "bad.laz" in capsys.readouterr().err
    assert not (tmp_path / "p").exists()


def test_build_city_writes_the_store_and_the_tileset_beside_it(sample_city, tmp_path: Path, capsys) -> None:
    from citylod.io.tiles3d import open_tileset

    out = tmp_path / "city.gpkg"
    assert main(["-q", "build", "city", str(sample_city.files["city"]), "-o", str(out)]) == 0
    assert out.is_file()
    ts = open_tileset(tmp_path / "city_tiles")
    assert ts.kind == "city" and ts.citylod["objects"] == len(sample_city.city.buildings)
    assert "city objects in" in capsys.readouterr().out
    assert main(["-q", "build", "city", str(sample_city.files["city"]), "-o", str(tmp_path / "b.gpkg"),
                 "--no-tiles"]) == 0
    assert not (tmp_path / "b_tiles").exists()
    # a broken model: exit 2, nothing written
    bad = tmp_path / "bad.gml"
    bad.write_text("<CityModel><cityObjectMember><Building")
    assert main(["-q", "build", "city", str(bad), "-o", str(tmp_path / "c.gpkg")]) == 2
    assert not (tmp_path / "c.gpkg").exists() and not (tmp_path / "c_tiles").exists()


def test_quiet_silences_the_textured_sample(tmp_path: Path, capfd) -> None:
    args = ["sample", str(tmp_path / "s"), "--textured", "200", "--image-px", "8"]
    assert main(["-q", *args]) == 0
    assert "textured houses" not in capfd.readouterr().err
    assert main([*args[:1], str(tmp_path / "t"), *args[2:]]) == 0  # the bar shows without -q
    assert "textured houses" in capfd.readouterr().err


def test_build_city_textured_warns_about_a_missing_image(tmp_path: Path, capsys) -> None:
    from citylod.io.tiles3d import open_tileset

    assert main(["-q", "sample", str(tmp_path / "s"), "--textured", "3", "--image-px", "32"]) == 0
    (tmp_path / "s" / "textures" / "BLDG_T0001_roof.jpg").unlink()
    assert main(["-q", "build", "city", str(tmp_path / "s" / "textured.gml"), "-o", str(tmp_path / "c.gpkg"),
                 "--atlas-px", "256"]) == 0
    out = capsys.readouterr().out
    assert "BLDG_T0001_roof.jpg" in out and "missing" in out
    ts = open_tileset(tmp_path / "c_tiles")
    assert ts.citylod["textured"] and ts.citylod["atlas_px"] == 256


def test_python_dash_m_citylod_runs_the_command_line() -> None:
    import subprocess
    import sys

    import citylod

    r = subprocess.run([sys.executable, "-m", "citylod", "--version"], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f"citylod {citylod.__version__}"
