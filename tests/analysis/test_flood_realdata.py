"""Flooding Delft (AHN3 LiDAR + CityJSON, ../shared/data): a DSM gridded here from the points, water entering
where the LiDAR saw water (class 9), affected buildings of the city model against an independent footprint
test (shapely boxes of the flooded cells against each grown footprint)."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest
import rasterio
import shapely
from affine import Affine
from scipy import ndimage

from citylod.analysis.flood import DEPTH_NODATA, FloodSources, flood_raster
from citylod.analysis.polygons import EditPolygon, PolygonLayer
from citylod.semantics.store import CityStore, build_city
from tests.paths import SHARED_DATA

DELFT = SHARED_DATA / "delft"
pytestmark = [pytest.mark.realdata, pytest.mark.skipif(not DELFT.is_dir(), reason=f"{DELFT} is absent")]


def grid_dsm(path: Path) -> tuple[Path, shapely.Geometry]:
    """1 m DSM (highest return per cell, gaps filled from the nearest cell) and the cells with water returns."""
    xs, ys, zs, cs = [], [], [], []
    for name in ("ahn3_cropped_1.laz", "ahn3_cropped_2.laz"):
        las = laspy.read(DELFT / name)
        xs.append(np.asarray(las.x))
        ys.append(np.asarray(las.y))
        zs.append(np.asarray(las.z))
        cs.append(np.asarray(las.classification))
    x, y, z, c = (np.concatenate(v) for v in (xs, ys, zs, cs))
    x0, y1 = np.floor(x.min()), np.ceil(y.max())
    w, h = int(np.ceil(x.max() - x0)), int(np.ceil(y1 - y.min()))
    col = np.minimum((x - x0).astype(int), w - 1)
    row = np.minimum((y1 - y).astype(int), h - 1)
    dsm = np.full((h, w), -np.inf)
    np.maximum.at(dsm, (row, col), z)
    empty = ~np.isfinite(dsm)
    _, (ri, ci) = ndimage.distance_transform_edt(empty, return_indices=True)
    dsm = dsm[ri, ci]
    t = Affine(1.0, 0, x0, 0, -1.0, y1)
    with rasterio.open(path, "w", driver="GTiff", width=w, height=h, count=1, dtype="float32", crs="EPSG:28992",
                       transform=t, nodata=-9999.0) as ds:
        ds.write(dsm.astype(np.float32), 1)
    water = c == 9
    cells = shapely.union_all(shapely.box(x0 + col[water], y1 - row[water] - 1, x0 + col[water] + 1,
                                          y1 - row[water]))
    return path, cells


def test_delft_flood_reaches_the_buildings_an_independent_test_finds(tmp_path: Path) -> None:
    raster, water = grid_dsm(tmp_path / "delft_dsm.tif")
    gpkg = build_city(DELFT / "testarea.city.json", tmp_path / "delft.gpkg", progress=False).path
    polys = tuple(EditPolygon(g, "source") for g in shapely.get_parts(water) if g.area > 0)
    sources = FloodSources(polygons=PolygonLayer(polys, None, "class 9 cells"))
    rep = flood_raster(raster, [0.6, 1.0], tmp_path / "out", sources=sources, city=gpkg, touch_m=1.0)
    assert 0 < rep.levels[0].area_m2 < rep.levels[1].area_m2
    with CityStore.open(gpkg) as store:
        feet = dict(store.footprints())
    for r in rep.levels:
        with rasterio.open(tmp_path / "out" / r.depth_file) as ds:
            d = ds.read(1)
            t = ds.transform
        rows, cols = np.nonzero(d != DEPTH_NODATA)
        boxes = shapely.box(t.c + cols * t.a, t.f + (rows + 1) * t.e, t.c + (cols + 1) * t.a, t.f + rows * t.e)
        tree = shapely.STRtree(boxes)
        expected = {}
        for oid, foot in feet.items():
            hit = tree.query(foot.buffer(1.0), predicate="intersects")
            if len(hit):
                expected[oid] = float(d[rows[hit], cols[hit]].max())
        got = {a.object_id: a.max_depth_m for a in rep.affected if a.level == r.level}
        assert expected and set(got) == set(expected)
        assert len(got) < len(feet)  # the flood reaches some of the 160 buildings, not all
        for oid, mx in expected.items():
            assert got[oid] == pytest.approx(mx, abs=1e-5)
    print(f"\nDelft: {rep.summary()}")
