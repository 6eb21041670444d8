"""The water surface through ``citylod render --flood``: water shows exactly over the flooded cells.

Independent check: the depth image of the same render gives the 3D point seen in each pixel (the water is
translucent and writes no depth, so the point lies on the ground); its raster cell, looked up in the flood's
depth GeoTIFF, says whether the pixel should be blue. Pixels near a flood edge or where the LOD surface and
the level are closer than the tiles' error are left out.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import rasterio

from citylod.analysis.flood import DEPTH_NODATA, FloodSources, flood_raster
from citylod.cli import main
from citylod.core.camera import Camera
from citylod.io.image import decode_image
from citylod.render.depth import points_from_distance

pytestmark = pytest.mark.render


@pytest.fixture(scope="module")
def flooded(sample_built: SimpleNamespace, tmp_path_factory: pytest.TempPathFactory) -> SimpleNamespace:
    out = tmp_path_factory.mktemp("water")
    dsm = sample_built.info.files["dsm"]
    with rasterio.open(dsm) as ds:
        h = ds.read(1, masked=True)
        b = ds.bounds
    levels = [float(np.percentile(h.compressed(), p)) for p in (25, 45)]
    flood_raster(dsm, levels, out / "flood", sources=FloodSources(edge=True))
    cx, cy = (b.left + b.right) / 2, (b.bottom + b.top) / 2
    cam = Camera((cx, cy - 1.0, float(h.max()) + 180.0), (cx, cy, float(h.min())), (0.0, 1.0, 0.0), 40.0)
    cam.save(out / "cam.json")
    return SimpleNamespace(dir=out, dsm=dsm, tiles=sample_built.dsm, levels=levels, cam=cam)


def _render(f: SimpleNamespace, name: str, *extra: str) -> tuple[np.ndarray, np.ndarray]:
    png, npy = f.dir / f"{name}.png", f.dir / f"{name}.npy"
    assert main(["-q", "render", str(f.tiles), "-o", str(png), "--camera", str(f.dir / "cam.json"),
                 "--size", "320x240", "--tau", "0.5", "--depth", str(npy), *extra]) == 0
    return decode_image(png.read_bytes()), np.load(npy)


@pytest.mark.parametrize("index", [0, 1])
def test_water_is_drawn_over_the_flooded_cells_only(flooded: SimpleNamespace, index: int) -> None:
    plain, dist = _render(flooded, "plain")
    wet_img, _ = _render(flooded, f"water{index}", "--flood", str(flooded.dir / "flood"),
                         "--flood-index", str(index))
    changed = np.abs(wet_img.astype(int) - plain.astype(int)).sum(axis=-1) > 12
    pts = points_from_distance(dist, flooded.cam, relative=False)
    with rasterio.open(flooded.dir / "flood" / f"depth_{index:03d}.tif") as ds:
        depth = ds.read(1)
        t = ds.transform
    with rasterio.open(flooded.dsm) as ds:
        heights = ds.read(1)
    ok = np.isfinite(pts[..., 0])
    col = (pts[..., 0][ok] - t.c) / t.a
    row = (pts[..., 1][ok] - t.f) / t.e
    r = np.clip(np.floor(row).astype(int), 0, depth.shape[0] - 1)
    c = np.clip(np.floor(col).astype(int), 0, depth.shape[1] - 1)
    wet = depth != DEPTH_NODATA
    # away from flood edges (all 3×3 neighbours agree) and from the level by more than the tiles' error
    from scipy.ndimage import maximum_filter, minimum_filter

    interior = maximum_filter(wet, 3) == minimum_filter(wet, 3)
    clear = np.abs(heights - flooded.levels[index]) > 0.6
    use = interior[r, c] & clear[r, c]
    expect = wet[r, c][use]
    got = changed[ok][use]
    assert expect.sum() > 500 and (~expect).sum() > 500  # both kinds of pixel are in view
    assert (got == expect).mean() > 0.995, f"{(got != expect).sum()} of {use.sum()} pixels disagree"
    blue = wet_img[ok][use][expect].astype(int)
    assert (blue[:, 2] > blue[:, 0] + 30).mean() > 0.95  # the water is blue where it is drawn
