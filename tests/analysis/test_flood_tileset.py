"""Flooding a built DSM tileset against flooding its source raster, through the API and the command line.

The bound under test (argued in citylod.analysis.tileset_heights): with ε the leaves' largest
geometricError, the tileset's flood at level L lies between the source raster's floods at L − ε and L + ε,
and where both hold water the depths differ by at most ε. The source floods come from the plain breadth-first
fill of tests/analysis/test_flood.py on the raster as rasterio reads it, independent of the tileset reader,
of the rasterisation and of scipy's labelling. Each test also checks that the bound is not vacuous: ε is
small against the relief, and the floods at L − ε and L + ε differ, so the sandwich has something to hold.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import rasterio
from affine import Affine
from scipy.ndimage import gaussian_filter

from citylod.analysis.flood import DEPTH_NODATA, FloodSources, flood_tileset
from citylod.analysis.tileset_heights import rasterise_tileset
from citylod.cli import main
from citylod.lod.build.dsm import build_dsm
from tests.analysis.test_flood import bfs_flood, edge_cells, read_depth, write_raster

X0, Y0 = 500_000.0, 5_400_000.0


def terrain(shape: tuple[int, int], seed: int) -> np.ndarray:
    """Rough terrain with a dyke, a one-cell breach in it and no-data holes (NaN)."""
    rng = np.random.default_rng(seed)
    h = gaussian_filter(rng.normal(size=shape), 3.0) * 40.0
    col = shape[1] // 2
    h[:, col] += 8.0
    h[shape[0] // 3, col] -= 8.0
    h[gaussian_filter(rng.normal(size=shape), 4.0) > 0.25] = np.nan
    return h


def built(tmp_path: Path, h: np.ndarray, **raster_kw) -> tuple[Path, Path]:
    raster = write_raster(tmp_path / "dsm.tif", np.where(np.isnan(h), -9999.0, h), **raster_kw)
    build_dsm(raster, tmp_path / "tiles", workers=0, progress=False, tile_size=33)
    return raster, tmp_path / "tiles"


def source_heights(raster: Path) -> tuple[np.ndarray, np.ndarray]:
    with rasterio.open(raster) as ds:
        h = ds.read(1).astype(np.float64)
        return h, h != ds.nodata


def check_sandwich(tmp_path: Path, raster: Path, tiles: Path, levels: list[float]) -> float:
    h, valid = source_heights(raster)
    rep = flood_tileset(tiles, levels, tmp_path / "out", sources=FloodSources(edge=True), strip_rows=40)
    doc = json.loads((tmp_path / "out" / "flood.json").read_text())
    eps = doc["tileset_error_m"]
    assert doc["tileset"].endswith("tileset.json") and eps > 0
    relief = float(h[valid].max() - h[valid].min())
    assert eps < 0.05 * relief  # the bound says something
    seeds = edge_cells(h.shape)
    differ = False
    for r in rep.levels:
        got = read_depth(tmp_path / "out" / r.depth_file)
        wet = got != DEPTH_NODATA
        lo = bfs_flood(h, valid, seeds, r.level - eps)
        hi = bfs_flood(h, valid, seeds, r.level + eps)
        assert not (lo & ~wet).any(), f"level {r.level}: dry where the source floods at L − ε"
        assert not (wet & ~hi).any(), f"level {r.level}: wet where the source stays dry at L + ε"
        both = wet & lo
        assert np.abs(got[both] - (r.level - h[both])).max() <= eps + 1e-5
        differ |= bool((hi & ~lo).any())
    assert differ  # the band between L ± ε holds cells: the sandwich is a real constraint
    assert not list(tmp_path.glob(".out.heights.*"))  # the temporary heights are gone
    return eps


def test_projected_tileset_floods_within_its_error(tmp_path: Path) -> None:
    h = terrain((150, 200), 1)
    raster, tiles = built(tmp_path, h)
    # the rasterised leaves: same valid samples, heights within ε (an independent look at the certificate)
    th = rasterise_tileset(tiles, tmp_path / "h.tif", strip_rows=40)  # strips cut through rows of leaves
    with rasterio.open(tmp_path / "h.tif") as ds:
        hp = ds.read(1)
        assert ds.crs.to_epsg() == 32632 and ds.transform == Affine(1.0, 0, X0, 0, -1.0, Y0)
    src, valid = source_heights(raster)
    assert np.array_equal(np.isfinite(hp), valid)
    assert np.abs(hp[valid] - src[valid]).max() <= th.max_error_m
    assert th.leaves > 20
    lv = [float(np.nanpercentile(h, p)) for p in (20, 45, 70)]
    check_sandwich(tmp_path, raster, tiles, lv)


def test_tileset_in_degrees_floods_within_its_error(tmp_path: Path) -> None:
    """Leaves of a raster in degrees are stored projected to UTM; they map back through the inverse."""
    h = terrain((90, 110), 2)
    t = Affine(1e-5, 0, 8.4, 0, -1e-5, 49.02)
    raster, tiles = built(tmp_path, h, crs="EPSG:4326", transform=t)
    check_sandwich(tmp_path, raster, tiles, [float(np.nanpercentile(h, 40))])


def test_command_line_floods_a_tileset_and_refuses_bad_ones(tmp_path: Path, capsys) -> None:
    h = terrain((80, 80), 3)
    _, tiles = built(tmp_path, h)
    level = float(np.nanpercentile(h, 50))
    out = tmp_path / "o"
    assert main(["-q", "flood", str(tiles), "--level", f"{level}", "--edge", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "heights: the tileset's" in text and (out / "depth_000.tif").exists()
    with rasterio.open(out / "depth_000.tif") as ds:
        assert ds.crs.to_epsg() == 32632 and ds.shape == h.shape

    def refused(args: list[str], target: Path) -> str:
        assert main(["-q", *args]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "Traceback" not in err
        assert not target.exists() and not list(target.parent.glob(f".{target.name}.heights.*"))
        return err

    bad = tmp_path / "bad"
    err = refused(["flood", str(tiles), "--level", "1", "--seed", "0,0", "-o", str(bad)], bad)
    assert "tileset.json" in err and "outside the raster" in err  # names the tileset, not a temporary file
    doc = json.loads((tiles / "tileset.json").read_text())
    del doc["extras"]["citylod"]["grid"]
    old = tmp_path / "old"
    old.mkdir()
    (old / "tileset.json").write_text(json.dumps(doc))
    assert "rebuild it" in refused(["flood", str(old), "--level", "1", "--edge", "-o", str(bad)], bad)
    doc["extras"]["citylod"]["kind"] = "points"
    (old / "tileset.json").write_text(json.dumps(doc))
    assert "not a DSM tileset" in refused(["flood", str(old), "--level", "1", "--edge", "-o", str(bad)], bad)


@pytest.mark.parametrize("strip_rows", [7, 1000])
def test_strips_do_not_change_the_heights(tmp_path: Path, strip_rows: int) -> None:
    """Strips of 7 rows cut every row of leaves several times; one strip holds them all: same heights."""
    h = terrain((70, 90), 4)
    _, tiles = built(tmp_path, h)
    rasterise_tileset(tiles, tmp_path / "a.tif", strip_rows=strip_rows)
    rasterise_tileset(tiles, tmp_path / "b.tif", strip_rows=64)
    with rasterio.open(tmp_path / "a.tif") as a, rasterio.open(tmp_path / "b.tif") as b:
        np.testing.assert_array_equal(a.read(1), b.read(1))
