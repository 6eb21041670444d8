"""The DSM tile tree on hard cases, checked by an independent computation.

The builder certifies its tiles with :mod:`citylod.lod.kernels.certify`; these tests do not use it. They load every
tile through the public reader, interpolate its TIN at every valid full-resolution sample with matplotlib's
triangle interpolator, and compare with the raster.
"""

from __future__ import annotations

import json
import sys

import numpy as np
import pyproj
import pytest
import rasterio
from matplotlib.tri import LinearTriInterpolator, Triangulation
from rasterio.transform import from_origin

from citylod.core.errors import EmptyInputError, GeoreferenceError, InputError
from citylod.io.tiles3d import open_tileset
from citylod.lod.build.dsm import build_dsm

NODATA = -9999.0


def write_raster(path, z, *, x0=500_000.0, y0=5_400_000.0, res=1.0, crs="EPSG:32632", nodata=NODATA):
    z = np.asarray(z, np.float32)
    with rasterio.open(path, "w", driver="GTiff", width=z.shape[1], height=z.shape[0], count=1,
                       dtype="float32", crs=crs, transform=from_origin(x0, y0, res, res), nodata=nodata) as ds:
        ds.write(z, 1)
    return path


def city_like(n, m, seed=0):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:n, 0:m].astype(float)
    z = 40 + 5 * np.sin(xx / 17.0) * np.cos(yy / 23.0) + 0.02 * xx
    for _ in range(max(3, n * m // 900)):  # buildings: façades are one-sample vertical steps
        r, c = rng.integers(0, n), rng.integers(0, m)
        h, w = rng.integers(4, 15), rng.integers(4, 15)
        z[r:r + h, c:c + w] += rng.uniform(6, 25)
    z[rng.integers(0, n, 5), rng.integers(0, m, 5)] += 3.0  # chimneys one sample wide
    return z


def _interp_with_boundary(v, faces, px, py, tol=1e-7):
    """TIN heights at points, including points on the TIN's outer edges (which trifinder may miss).

    Returns (heights, found) with found False outside every triangle. Independent of the builder."""
    tri = Triangulation(v[:, 0], v[:, 1], faces)
    zi = LinearTriInterpolator(tri, v[:, 2])(px, py)
    found = ~np.ma.getmaskarray(zi)
    out = np.ma.getdata(zi).astype(np.float64).copy()
    miss = np.flatnonzero(~found)
    if len(miss):
        p0, p1, p2 = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
        det = (p1[:, 0] - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (p2[:, 0] - p0[:, 0]) * (p1[:, 1] - p0[:, 1])
        ok = np.abs(det) > 1e-12
        p0, p1, p2, det = p0[ok], p1[ok], p2[ok], det[ok]
        for k in np.array_split(miss, max(1, len(miss) // 64)):
            qx, qy = px[k][:, None], py[k][:, None]
            l1 = ((qx - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (p2[:, 0] - p0[:, 0]) * (qy - p0[:, 1])) / det
            l2 = ((p1[:, 0] - p0[:, 0]) * (qy - p0[:, 1]) - (qx - p0[:, 0]) * (p1[:, 1] - p0[:, 1])) / det
            l0 = 1 - l1 - l2
            inside = (l0 >= -tol) & (l1 >= -tol) & (l2 >= -tol)
            has = inside.any(axis=1)
            t = np.argmax(inside, axis=1)
            zz = p0[t, 2] * l0[np.arange(len(k)), t] + p1[t, 2] * l1[np.arange(len(k)), t] + p2[t, 2] * l2[np.arange(len(k)), t]
            out[k[has]] = zz[has]
            found[k[has]] = True
    return out, found


def check_tileset(out, z, valid, *, x0=500_000.0, y0=5_400_000.0, res=1.0, transform_xy=None, inverse_xy=None):
    """Independent checks: bound at every valid sample, leaf coverage, neighbour borders."""
    ts = open_tileset(out)
    rows, cols = np.nonzero(valid)
    sx = x0 + (cols + 0.5) * res
    sy = y0 - (rows + 0.5) * res
    src_x, src_y = sx, sy
    if transform_xy is not None:
        sx, sy = transform_xy(sx, sy)
    sz = np.asarray(z, np.float32)[rows, cols].astype(np.float64)  # the raster stores float32
    leaves, checked = [], 0
    worst_ratio = 0.0
    for tile in ts.walk():
        # errors shrink downwards, as 3D Tiles clients expect
        assert all(c.geometric_error <= tile.geometric_error for c in tile.children), tile.key
        if tile.content_uri is None:
            continue
        mesh = tile.load()
        surf = mesh.faces[~mesh.skirt]
        assert len(surf) > 0
        v = mesh.vertices
        lo, hi = tile.bounds
        inside = (sx >= lo[0] - 1e-6) & (sx <= hi[0] + 1e-6) & (sy >= lo[1] - 1e-6) & (sy <= hi[1] + 1e-6)
        zi, hit = _interp_with_boundary(v, surf, sx[inside], sy[inside])
        if hit.any():
            err = np.abs(zi[hit] - sz[inside][hit])
            assert err.max() <= tile.geometric_error + 1e-6, (tile.key, err.max(), tile.geometric_error)
            worst_ratio = max(worst_ratio, err.max() / max(tile.geometric_error, 1e-12))
            checked += int(hit.sum())
        if not tile.children:
            if inverse_xy is not None:  # coverage is exact in the raster's own coordinates
                v = v.copy()
                v[:, 0], v[:, 1] = inverse_xy(v[:, 0], v[:, 1])
            leaves.append((tile, v, surf))
    assert checked > 0
    # Leaves: every valid sample is inside some leaf triangle, and the leaves' areas add up to the valid
    # cells' area (so nothing is covered twice and nothing invalid is covered).
    covered = np.zeros(len(sx), bool)
    area = 0.0
    for _tile, v, surf in leaves:
        lo, hi = v.min(axis=0), v.max(axis=0)
        m = 1e-6  # metres: float32 positions relative to the tile centre move vertices by nanometres
        inside = np.flatnonzero((src_x >= lo[0] - m) & (src_x <= hi[0] + m) & (src_y >= lo[1] - m)
                                & (src_y <= hi[1] + m))
        # vertices went through float32 (positions relative to the tile centre: ~4e-6 m at 32 m) and, for
        # rasters in degrees, back through the projection: a sample on the raster's outer edge can fall
        # that far outside the edge, so allow 1e-5 of a triangle
        _, found = _interp_with_boundary(v, surf, src_x[inside], src_y[inside], tol=1e-5)
        covered[inside[found]] = True
        p = v[surf]
        a = 0.5 * ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1]))
        assert np.all(a > -1e-9), "leaf triangles must be counter-clockwise seen from above"
        area += a.sum()
    assert covered.all(), f"{(~covered).sum()} valid samples not covered by any leaf"
    if transform_xy is None:
        cell_valid = valid[:-1, :-1] & valid[1:, :-1] & valid[:-1, 1:] & valid[1:, 1:]
        assert area == pytest.approx(cell_valid.sum() * res * res, rel=1e-6)
    return ts, worst_ratio


def test_city_with_cliffs_holes_and_large_coordinates(tmp_path) -> None:
    z = city_like(300, 270)  # not a power of two
    z[100:130, 40:90] = NODATA  # an inner no-data hole
    z[:, :7] = NODATA  # a no-data border
    valid = z != NODATA
    write_raster(tmp_path / "dsm.tif", z, y0=5_500_000.0)
    rep = build_dsm(tmp_path / "dsm.tif", tmp_path / "out", tile_size=65, workers=1, progress=False, metric="vertical")
    assert rep.levels == 4
    ts, _ = check_tileset(tmp_path / "out", z, valid, y0=5_500_000.0)
    leaves = [t for t in ts.walk() if not t.children and t.content_uri]
    assert all(t.geometric_error <= 0.5 + 1e-3 for t in leaves)  # the leaf target (half a 1 m spacing)
    errors = {t.level: t.geometric_error for t in ts.walk()}
    assert errors[0] > errors[max(errors)]  # coarser levels carry larger errors
    # same-level neighbours share identical border vertices
    by_key = {t.key: t for t in ts.walk()}
    assert _borders_match(by_key, ts)
    # nothing half-written is left next to the output
    assert not (tmp_path / "out.partial").exists()
    assert not list((tmp_path / "out").rglob("*.json"))[1:]


def test_leaf_bound_from_the_kernel_holds_against_the_certifier(tmp_path) -> None:
    """By default a leaf's error is the TIN kernel's bound (its target) plus the float32 rounding of its heights,
    with only the faces stage 2 changed certified; ``certify_leaves`` measures the same TINs with the certifier
    instead (exact: every sample and grid-edge crossing). The bound must hold against that measurement."""
    z = city_like(260, 230, seed=5)
    z[90:120, 30:80] = NODATA
    valid = z != NODATA
    write_raster(tmp_path / "dsm.tif", z)
    build_dsm(tmp_path / "dsm.tif", tmp_path / "kernel", tile_size=65, workers=0, progress=False, metric="vertical")
    build_dsm(tmp_path / "dsm.tif", tmp_path / "certified", tile_size=65, workers=0, progress=False, metric="vertical",
              certify_leaves=True)
    a = {t.key: t for t in check_tileset(tmp_path / "kernel", z, valid)[0].walk()}
    b = {t.key: t for t in check_tileset(tmp_path / "certified", z, valid)[0].walk()}
    assert a.keys() == b.keys()
    leaves = [k for k, t in a.items() if not t.children and t.content_uri]
    assert len(leaves) > 4
    for k in leaves:
        ma, mb = a[k].load(), b[k].load()
        assert np.array_equal(ma.faces, mb.faces) and np.array_equal(ma.vertices, mb.vertices)  # the same TIN
        assert b[k].geometric_error <= a[k].geometric_error <= 0.5 + 1e-3, k
    assert any(b[k].geometric_error < a[k].geometric_error for k in leaves)  # measured, not bounded


def _borders_match(by_key, ts) -> bool:
    """Same-level tiles side by side (east-west) carry the same surface vertices on their shared border."""
    pairs = 0
    for level in sorted({t.level for t in ts.walk()}):
        tiles = [t for t in by_key.values() if t.level == level and t.content_uri]
        surf = {}
        for t in tiles:
            m = t.load()
            surf[t.key] = m.vertices[np.unique(m.faces[~m.skirt])]
        for a in tiles:
            alo, ahi = a.bounds
            for b in tiles:
                blo, bhi = b.bounds
                ylo, yhi = max(alo[1], blo[1]), min(ahi[1], bhi[1])
                if b is a or yhi - ylo <= 1e-6:
                    continue
                x_edge = surf[a.key][:, 0].max()
                if abs(surf[b.key][:, 0].min() - x_edge) > 1e-6:
                    continue
                sa, sb = (np.unique(np.round(v[(np.abs(v[:, 0] - x_edge) < 1e-6) & (v[:, 1] >= ylo - 1e-6)
                                                 & (v[:, 1] <= yhi + 1e-6)], 4), axis=0)
                          for v in (surf[a.key], surf[b.key]))
                np.testing.assert_array_equal(sa, sb)
                pairs += 1
    return pairs > 0


def test_flat_constant_and_thin_rasters(tmp_path) -> None:
    flat = np.full((130, 130), 12.5)
    write_raster(tmp_path / "flat.tif", flat)
    build_dsm(tmp_path / "flat.tif", tmp_path / "flat", tile_size=65, workers=1, progress=False, metric="vertical")
    ts, _ = check_tileset(tmp_path / "flat", flat, np.ones_like(flat, bool))
    assert sum(len(t.load().faces[~t.load().skirt]) for t in ts.walk() if not t.children) <= 2 * 9
    thin = np.linspace(0, 10, 40)[None, :].repeat(2, axis=0)  # 2×N: the thinnest raster with area
    write_raster(tmp_path / "thin.tif", thin)
    build_dsm(tmp_path / "thin.tif", tmp_path / "thin", tile_size=65, workers=1, progress=False, metric="vertical")
    check_tileset(tmp_path / "thin", thin, np.ones_like(thin, bool))


def test_one_row_raster_is_a_clear_error_or_empty(tmp_path) -> None:
    write_raster(tmp_path / "row.tif", np.arange(20.0)[None, :])
    with pytest.raises(InputError, match="row.tif"):
        build_dsm(tmp_path / "row.tif", tmp_path / "row", workers=1, progress=False)
    assert not (tmp_path / "row").exists()


def test_the_empty_raster_check_scans_every_strip(tmp_path) -> None:
    """check_has_data reads strips of the file's block height (64 rows at least) until one holds a valid
    sample: data in the last row only is found, in a tiled file and in a striped one (1-row blocks)."""
    from citylod.io.raster import RasterSource, check_has_data

    z = np.full((300, 40), NODATA, np.float32)
    z[-1, 7] = 12.0
    tiled = tmp_path / "tiled.tif"
    with rasterio.open(tiled, "w", driver="GTiff", width=40, height=300, count=1, dtype="float32",
                       crs="EPSG:32632", transform=from_origin(500_000.0, 5_400_000.0, 1.0, 1.0), nodata=NODATA,
                       tiled=True, blockxsize=16, blockysize=16) as ds:
        ds.write(z, 1)
    striped = write_raster(tmp_path / "striped.tif", z)
    for path in (tiled, striped):
        check_has_data(RasterSource(path))  # no error: the last strip has the sample
    z[-1, 7] = NODATA
    with pytest.raises(EmptyInputError, match="empty.tif"):
        check_has_data(RasterSource(write_raster(tmp_path / "empty.tif", z)))


def test_bad_input_is_a_clear_error(tmp_path) -> None:
    write_raster(tmp_path / "nodata.tif", np.full((50, 50), NODATA))
    with pytest.raises(EmptyInputError, match="nodata.tif"):
        build_dsm(tmp_path / "nodata.tif", tmp_path / "o1", workers=1, progress=False)
    with rasterio.open(tmp_path / "nogeo.tif", "w", driver="GTiff", width=10, height=10, count=1,
                       dtype="float32") as ds:
        ds.write(np.zeros((10, 10), np.float32), 1)
    with pytest.raises(GeoreferenceError, match="nogeo.tif"):
        build_dsm(tmp_path / "nogeo.tif", tmp_path / "o2", workers=1, progress=False)
    (tmp_path / "junk.tif").write_bytes(b"II*\x00garbage")
    with pytest.raises(InputError, match="junk.tif"):
        build_dsm(tmp_path / "junk.tif", tmp_path / "o3", workers=1, progress=False)
    for name in ("o1", "o2", "o3"):
        assert not (tmp_path / name).exists() and not (tmp_path / f"{name}.partial").exists()


def test_degrees_raster_jacksboro(tmp_path) -> None:
    """matplotlib's real DEM, in degrees: the bound holds in metres and vertices land in UTM."""
    from matplotlib import cbook

    dem = cbook.get_sample_data("jacksboro_fault_dem.npz")
    z = np.asarray(dem["elevation"], np.float64)  # row 0 is the northern edge
    dx = dy = float(dem["dx"])  # 3 arc-seconds
    x0 = float(dem["xmin"])
    y0 = max(float(dem["ymin"]), float(dem["ymax"]))
    with rasterio.open(tmp_path / "jb.tif", "w", driver="GTiff", width=z.shape[1], height=z.shape[0], count=1,
                       dtype="float32", crs="EPSG:4326", transform=from_origin(x0, y0, dx, dy)) as ds:
        ds.write(z.astype(np.float32), 1)
    rep = build_dsm(tmp_path / "jb.tif", tmp_path / "jb", workers=1, progress=False)
    ts = open_tileset(tmp_path / "jb")
    assert ts.crs.is_projected and "UTM" in ts.crs.name
    cy = y0 - dy * z.shape[0] / 2
    assert rep.leaf_target == pytest.approx(0.5 * 0.5 * (dx * 111_320 * np.cos(np.radians(cy)) + dy * 111_320),
                                            rel=1e-6)
    to_utm = pyproj.Transformer.from_crs("EPSG:4326", ts.crs, always_xy=True)

    to_deg = pyproj.Transformer.from_crs(ts.crs, "EPSG:4326", always_xy=True)
    f32 = z.astype(np.float32).astype(np.float64)
    check_tileset(tmp_path / "jb", f32, np.ones_like(z, bool), x0=x0, y0=y0, res=dx,
                  transform_xy=to_utm.transform, inverse_xy=to_deg.transform)


def test_resume_after_interruption(tmp_path) -> None:
    z = city_like(200, 200, seed=3)
    write_raster(tmp_path / "dsm.tif", z)
    with pytest.raises(KeyboardInterrupt):
        build_dsm(tmp_path / "dsm.tif", tmp_path / "out", tile_size=65, workers=1, progress=False, metric="vertical", _stop_after=5)
    assert not (tmp_path / "out").exists() and (tmp_path / "out.partial").exists()
    rep = build_dsm(tmp_path / "dsm.tif", tmp_path / "out", tile_size=65, workers=1, progress=False, metric="vertical")
    assert rep.resumed == 5
    check_tileset(tmp_path / "out", z, np.ones_like(z, bool))


def test_tileset_is_standard_3dtiles(tmp_path) -> None:
    z = city_like(130, 130)
    write_raster(tmp_path / "dsm.tif", z)
    build_dsm(tmp_path / "dsm.tif", tmp_path / "out", tile_size=65, workers=1, progress=False)
    doc = json.loads((tmp_path / "out" / "tileset.json").read_text())
    assert doc["asset"]["version"] == "1.1"
    stack = [doc["root"]]
    while stack:
        t = stack.pop()
        assert t["refine"] == "REPLACE" and "box" in t["boundingVolume"] and t["geometricError"] >= 0
        stack.extend(t.get("children", []))
    assert doc["extras"]["citylod"]["kind"] == "dsm"
    assert pyproj.CRS.from_wkt(doc["extras"]["citylod"]["crs"]).to_epsg() == 32632


def test_dask_localcluster_builds_the_same_tileset(tmp_path) -> None:
    """The --scheduler path for real: a Dask LocalCluster on loopback gives the same tiles as inline."""
    distributed = pytest.importorskip("distributed")
    z = city_like(140, 140, seed=9)
    write_raster(tmp_path / "dsm.tif", z)
    build_dsm(tmp_path / "dsm.tif", tmp_path / "inline", tile_size=65, workers=0, progress=False)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp://",
                                  host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        build_dsm(tmp_path / "dsm.tif", tmp_path / "dask", tile_size=65, scheduler=cluster.scheduler_address,
                  progress=False)
    a = open_tileset(tmp_path / "inline")
    b = open_tileset(tmp_path / "dask")
    ta, tb = list(a.walk()), list(b.walk())
    assert [t.geometric_error for t in ta] == [t.geometric_error for t in tb]
    for x, y in zip(ta, tb, strict=True):
        if x.content_uri:
            assert (tmp_path / "inline" / x.content_uri).read_bytes() == (tmp_path / "dask" / y.content_uri).read_bytes()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="forked workers are a Linux default only")
def test_threads_and_forked_workers_build_the_same_tileset_as_one_process(tmp_path, monkeypatch) -> None:
    """The default build runs its tiles on forked worker processes where that is safe, else on threads
    sharing one raster source: the same tiles as inline, either way. The parent has the raster open (and
    a journal) when it forks: the workers must open their own."""
    import citylod.lod.build.executor as executor

    z = city_like(300, 260, seed=4)
    z[100:120, 30:50] = NODATA
    write_raster(tmp_path / "dsm.tif", z)
    reports = {"inline": build_dsm(tmp_path / "dsm.tif", tmp_path / "inline", tile_size=33, workers=0,
                                   progress=False)}
    for name, safe in (("threads", False), ("fork", True)):
        monkeypatch.setattr(executor, "fork_is_safe", lambda safe=safe: safe)
        reports[name] = build_dsm(tmp_path / "dsm.tif", tmp_path / name, tile_size=33, progress=False)
    assert reports["inline"].executor == "inline"
    assert reports["threads"].executor.endswith("threads")
    assert reports["threads"].kernels == "JIT"  # the compiled-ahead wrappers would hold the GIL
    assert reports["fork"].executor.endswith("forked processes")
    a = list(open_tileset(tmp_path / "inline").walk())
    assert len(a) > 50
    for name in ("threads", "fork"):
        b = list(open_tileset(tmp_path / name).walk())
        assert [t.geometric_error for t in a] == [t.geometric_error for t in b]
        for x, y in zip(a, b, strict=True):
            if x.content_uri:
                assert (tmp_path / "inline" / x.content_uri).read_bytes() == (tmp_path / name / y.content_uri).read_bytes()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork")
def test_forked_worker_opens_its_own_raster_and_journal(tmp_path) -> None:
    """A forked child does not inherit the forking thread's open datasets or journal files (it would
    share their file offsets with the parent, or write into the parent's journal)."""
    import multiprocessing

    from citylod.core import journal
    from citylod.io.raster import RasterSource

    write_raster(tmp_path / "dsm.tif", city_like(40, 40, seed=1))
    src = RasterSource(tmp_path / "dsm.tif")
    src.read_window(0, 0, 8, 8)
    journal.append(tmp_path / "j", "k", b"parent")
    with multiprocessing.get_context("fork").Pool(1) as pool:
        opened, handles = pool.apply(_inherited_handles)
    assert opened == 0 and handles == 0
    assert _inherited_handles() != (0, 0)  # the parent's thread has both
    journal.close(tmp_path / "j")
    src.close()


def _inherited_handles() -> tuple[int, int]:
    from citylod.core import journal
    from citylod.io import raster

    return len(raster._DATASETS), len(journal._HANDLES)


def test_one_raster_source_read_from_many_threads(tmp_path) -> None:
    """Build tasks on threads share one RasterSource; a GDAL handle used by two threads at once fails
    or returns wrong blocks (it did: "Read failed" on the 2049² city)."""
    from concurrent.futures import ThreadPoolExecutor

    from citylod.io.raster import RasterSource

    rng = np.random.default_rng(2)
    z = rng.normal(100, 10, (1024, 1024)).astype(np.float32)
    with rasterio.open(tmp_path / "dsm.tif", "w", driver="GTiff", width=1024, height=1024, count=1,
                       dtype="float32", crs="EPSG:32632", transform=from_origin(500_000.0, 5_400_000.0, 1, 1),
                       tiled=True, blockxsize=128, blockysize=128, compress="deflate") as ds:
        ds.write(z, 1)
    src = RasterSource(tmp_path / "dsm.tif")
    windows = [(r, c) for r in range(0, 800, 97) for c in range(0, 800, 89)] * 2

    def read(rc):
        h, v = src.read_window(rc[0], rc[1], 200, 200)
        return bool(v.all()) and np.array_equal(h, z[rc[0]:rc[0] + 200, rc[1]:rc[1] + 200])

    with ThreadPoolExecutor(4) as ex:
        assert all(ex.map(read, windows))


def _border_strips(mesh, inv):
    """Per side line of a tile, ``{("r"|"c", line): (along, top, bottom)}``: the surface border's heights and
    its skirt's bottom heights at the border vertices (sorted along the line), from the tile's triangles."""
    cols, rows = inv @ (mesh.vertices[:, 0], mesh.vertices[:, 1])
    rc = np.column_stack([np.round(rows - 0.5), np.round(cols - 0.5)]).astype(int)
    surface = np.unique(mesh.faces[~mesh.skirt])
    out = {}
    for tri in mesh.faces[mesh.skirt]:
        for axis, name in ((0, "r"), (1, "c")):
            if len(set(rc[tri, axis])) == 1:  # the strip's line
                for v in tri:
                    if v not in surface:  # a bottom vertex hangs below the border vertex at its position
                        out.setdefault((name, int(rc[v, axis])), {})[int(rc[v, 1 - axis])] = v
    strips = {}
    for (name, line), bottoms in out.items():
        axis = 0 if name == "r" else 1
        on = surface[rc[surface, axis] == line]
        order = np.argsort(rc[on, 1 - axis])
        along = rc[on, 1 - axis][order]
        top = mesh.vertices[on, 2][order]
        bot = np.array([mesh.vertices[bottoms[a], 2] if a in bottoms else np.nan for a in along])
        strips[(name, line)] = (along, top, bot, (rc[surface, axis] < line).any())
    return strips


@pytest.mark.parametrize("metric", ["vertical", "hausdorff"])
def test_skirts_close_the_crack_to_any_neighbour(tmp_path, metric) -> None:
    """Wherever a tile's border lies above the border of a tile across the same line, of any level, its skirt
    reaches down to that border (measured on the written tiles, at every sample of every shared segment)."""
    z = city_like(150, 140, seed=8)
    write_raster(tmp_path / "dsm.tif", z)
    build_dsm(tmp_path / "dsm.tif", tmp_path / "out", tile_size=33, workers=0, progress=False, metric=metric)
    inv = ~from_origin(500_000.0, 5_400_000.0, 1.0, 1.0)
    strips = {t.key: _border_strips(t.load(), inv) for t in open_tileset(tmp_path / "out").walk()
              if t.content_uri is not None}
    cracks = checked = 0
    worst = 0.0
    for key, mine in strips.items():
        for (name, line), (along, top, bot, inside_before) in mine.items():
            for other, theirs in strips.items():
                if other == key or (name, line) not in theirs:
                    continue
                a2, top2, _, before2 = theirs[(name, line)]
                if before2 == inside_before:
                    continue  # the same side of the line: not across it
                x = np.arange(max(along[0], a2[0]), min(along[-1], a2[-1]) + 1)
                if len(x) == 0:
                    continue
                h, h2 = np.interp(x, along, top), np.interp(x, a2, top2)
                b = np.interp(x, along, bot)
                above = h > h2 + 1e-3
                cracks += int(above.sum())
                checked += len(x)
                worst = max(worst, float(np.max(b[above] - h2[above], initial=-np.inf)))
    assert checked > 0 and cracks > 0  # borders across lines do differ: there are cracks to close
    assert worst <= 1e-3, worst  # every one of them is closed by the higher border's skirt


def test_skirts_only_where_a_neighbour_can_be(tmp_path) -> None:
    """Skirts hang on tile borders inside the raster (cracks between levels); along the raster's own edges
    no tile lies beyond, so none hangs there (it would be a curtain under the data's outline)."""
    z = city_like(150, 140, seed=8)
    write_raster(tmp_path / "dsm.tif", z)
    build_dsm(tmp_path / "dsm.tif", tmp_path / "out", tile_size=33, workers=0, progress=False)
    # sample centres: x0 + 0.5 .. x0 + 139.5, y0 - 0.5 .. y0 - 149.5 (1 m pixels)
    xmin, xmax, ymax, ymin = 500_000.5, 500_139.5, 5_400_000 - 0.5, 5_400_000 - 149.5
    inner = 0
    for tile in open_tileset(tmp_path / "out").walk():
        if tile.content_uri is None:
            continue
        mesh = tile.load()
        f = mesh.faces[mesh.skirt]
        x, y = mesh.vertices[f, 0], mesh.vertices[f, 1]  # (K, 3) per skirt triangle
        along_edge = ((np.abs(x - xmin) < 1e-3).all(axis=1) | (np.abs(x - xmax) < 1e-3).all(axis=1)
                      | (np.abs(y - ymin) < 1e-3).all(axis=1) | (np.abs(y - ymax) < 1e-3).all(axis=1))
        assert not along_edge.any(), tile.key  # no skirt triangle runs along the raster's edge
        inner += int(mesh.skirt.sum())
    assert inner > 0


def _winding(out) -> tuple[int, int, int, int, set[bool]]:
    """Counts over every written tile: surface triangles facing up / not, skirt triangles facing away from
    their tile / not (the horizontal normal against the direction from the tile's surface centre), and the
    materials' ``doubleSided`` values (read from the glb, not through the decoder)."""
    import struct

    up = down = out_ = in_ = 0
    sides: set[bool] = set()
    for t in open_tileset(out).walk():
        if t.content_uri is None:
            continue
        data = t.content_path.read_bytes()
        (json_len,) = struct.unpack_from("<I", data, 12)  # the glb's first chunk is its JSON
        gltf = json.loads(data[20:20 + json_len])
        sides |= {bool(m.get("doubleSided", False)) for m in gltf.get("materials", [])}
        mesh = t.load()  # in the tileset's CRS, as a client places it
        p, f, sk = mesh.vertices - mesh.vertices.mean(axis=0), mesh.faces, mesh.skirt
        n = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
        big = np.linalg.norm(n, axis=1) > 1e-9  # degenerate slivers have no side
        up += int((n[~sk & big, 2] > 0).sum())
        down += int((n[~sk & big, 2] <= 0).sum())
        if sk.any():
            surf = p[np.unique(f[~sk])]
            mid = (surf.min(axis=0) + surf.max(axis=0)) / 2
            cen = p[f[sk & big]].mean(axis=1)
            away = ((cen[:, :2] - mid[:2]) * n[sk & big, :2]).sum(axis=1)
            out_ += int((away > 0).sum())
            in_ += int((away <= 0).sum())
    return up, down, out_, in_, sides


@pytest.mark.parametrize(("case", "metric"), [("north-up", "hausdorff"), ("north-up", "vertical"),
                                              ("south-up", "hausdorff"), ("holes", "hausdorff")])
def test_tiles_are_single_sided_surface_up_skirts_outward(tmp_path, case, metric) -> None:
    """The tiles are written single-sided (clients cull back faces), so every surface triangle must be
    wound counter-clockwise seen from above and every skirt triangle must face away from its tile: a
    skirt facing in would be culled where it closes a crack. Rows running south (a positive y step)
    reverse the raster's own orientation; no-data holes add inner borders. The control: the test finds
    skirts at all."""
    from rasterio.transform import Affine

    z = city_like(130, 120, seed=4)
    if case == "holes":
        z[40:60, 30:55] = NODATA
        z[:, :6] = NODATA
    path = tmp_path / "dsm.tif"
    if case == "south-up":
        with rasterio.open(path, "w", driver="GTiff", width=z.shape[1], height=z.shape[0], count=1,
                           dtype="float32", crs="EPSG:32632", nodata=NODATA,
                           transform=Affine(1.0, 0.0, 500_000.0, 0.0, 1.0, 5_400_000.0)) as ds:
            ds.write(z[::-1].astype(np.float32), 1)
    else:
        write_raster(path, z)
    build_dsm(path, tmp_path / "out", tile_size=33, workers=0, progress=False, metric=metric)
    up, down, outward, inward, sides = _winding(tmp_path / "out")
    assert up > 1000 and outward > 50, (up, outward)
    assert down == 0 and inward == 0, (down, inward)
    assert sides == {False}
