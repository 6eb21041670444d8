"""The Hausdorff certificate of DSM tiles, checked by an independent measurement.

Every tile of hard rasters is built with ``metric="hausdorff"`` and read back from its glb; points sampled
densely on both surfaces (the tile's TIN without skirts, and the raster's own triangulated cells under it)
are measured against the other surface with an exact point–triangle distance written here (projection on
the plane, else the nearest edge: not the kernel's Voronoi-region method), candidates found with a KD-tree.
No measured distance may exceed the tile's ``geometricError``, in either direction.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin
from scipy.spatial import cKDTree

from citylod.io.tiles3d import open_tileset
from citylod.lod.build.dsm import build_dsm
from citylod.lod.kernels.certify import certify
from citylod.lod.kernels.hausdorff import certify_hausdorff

NODATA = -9999.0


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def point_triangle_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Row-wise exact distance from points p (K, 3) to triangles (a, b, c) (K, 3 each)."""
    n = np.cross(b - a, c - a)
    nn = np.linalg.norm(n, axis=1)
    unit = n / np.maximum(nn, 1e-300)[:, None]
    h = np.einsum("ij,ij->i", p - a, unit)
    q = p - h[:, None] * unit  # projection on the plane
    inside = nn > 1e-12
    for u, v in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("ij,ij->i", np.cross(v - u, q - u), n) >= 0.0
    edges = np.minimum(_segment_distance(p, a, b), np.minimum(_segment_distance(p, b, c), _segment_distance(p, c, a)))
    return np.where(inside, np.abs(h), edges)


def distances_to_mesh(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, reach: float,
                      guess: np.ndarray | None = None) -> np.ndarray:
    """For each point, its distance to the mesh where that is at most ``reach`` (without ``guess``: exact;
    with it: possibly the distance to the guessed triangle, an upper bound, which is what a check against
    ``reach`` needs), and a value above ``reach`` elsewhere.

    ``guess`` (one triangle index per point, -1 for none) is tried first, usually the triangle straight above
    or below. Other candidates come from a KD-tree of triangle centroids: a triangle within distance r of a
    point has its centroid within r + its radius.
    """
    tri = vertices[faces]
    centroid = tri.mean(axis=1)
    radius = float(np.linalg.norm(tri - centroid[:, None, :], axis=2).max())
    tree = cKDTree(centroid)
    out = np.full(len(points), np.inf)
    if guess is not None:
        g = guess >= 0
        out[g] = point_triangle_distance(points[g], tri[guess[g], 0], tri[guess[g], 1], tri[guess[g], 2])
    todo = np.flatnonzero(out > reach)
    for r in (min(0.5, reach), reach):
        for chunk in np.array_split(todo, max(1, len(todo) // 500)):
            if len(chunk) == 0:
                continue
            near = tree.query_ball_point(points[chunk], r + radius)
            counts = np.array([len(n) for n in near])
            if counts.sum() == 0:
                continue
            pi = np.repeat(chunk, counts)
            ti = np.concatenate([np.asarray(n, np.int64) for n in near])
            d = point_triangle_distance(points[pi], tri[ti, 0], tri[ti, 1], tri[ti, 2])
            has = counts > 0
            starts = np.concatenate([[0], np.cumsum(counts)[:-1]])[has]
            out[chunk[has]] = np.minimum(out[chunk[has]], np.minimum.reduceat(d, starts))
        todo = todo[out[todo] > r]
    return out


def sample_triangles(tri: np.ndarray, k: int) -> np.ndarray:
    """Points on a barycentric grid of k subdivisions per triangle, (M·(k+1)(k+2)/2, 3)."""
    i, j = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
    keep = i + j <= k
    u, v = (i[keep] / k)[:, None], (j[keep] / k)[:, None]
    pts = tri[:, None, 0] + u[None] * (tri[:, None, 1] - tri[:, None, 0]) + v[None] * (tri[:, None, 2] - tri[:, None, 0])
    return pts.reshape(-1, 3)


def _write(path: Path, z: np.ndarray, crs: str = "EPSG:32632", origin=(500_000.0, 5_400_000.0), step=1.0) -> Path:
    with rasterio.open(path, "w", driver="GTiff", width=z.shape[1], height=z.shape[0], count=1, dtype="float32",
                       crs=crs, transform=from_origin(origin[0], origin[1], step, step), nodata=NODATA) as ds:
        ds.write(z.astype(np.float32), 1)
    return path


def hard_raster(kind: str) -> np.ndarray:
    n = 65
    yy, xx = np.mgrid[0:n, 0:n].astype(float)
    z = 40.0 + 0.05 * xx + 1.5 * np.sin(yy / 6.0)
    if kind in ("walls", "nodata"):
        z[9:30, 13:40] += 18.0  # a block: façades between coarse samples
        z[40:47, 45:50] += 25.0  # a tower narrower than the coarsest stride
        z[33, 5:60] += 9.0  # a one-sample wall
        z[52, 2:62] -= 7.0  # a one-sample trench
    if kind == "nodata":
        z[20:26, 50:57] = NODATA  # a hole
        z[:, :3] = NODATA  # a no-data border
        z[60:, :] = NODATA
    return z


def _raster_surface(z: np.ndarray, step: float, origin: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """The raster's valid cells as triangles (diagonal (i, j)–(i+1, j+1)) at sample centres."""
    n, m = z.shape
    rr, cc = np.mgrid[0:n, 0:m]
    verts = np.column_stack([origin[0] + (cc.ravel() + 0.5) * step, origin[1] - (rr.ravel() + 0.5) * step,
                             z.ravel()])
    idx = np.arange(n * m).reshape(n, m)
    ok = z != NODATA
    cell = ok[:-1, :-1] & ok[:-1, 1:] & ok[1:, :-1] & ok[1:, 1:]
    a, b, c, d = idx[:-1, :-1][cell], idx[:-1, 1:][cell], idx[1:, :-1][cell], idx[1:, 1:][cell]
    return verts, np.concatenate([np.column_stack([a, c, d]), np.column_stack([a, d, b])])


def _check_tiles(out: Path, z: np.ndarray, step: float, origin: tuple[float, float]) -> tuple[int, float]:
    sv, sf = _raster_surface(z, step, origin)
    ok = z != NODATA
    cell_ok = ok[:-1, :-1] & ok[:-1, 1:] & ok[1:, :-1] & ok[1:, 1:]
    checked, worst_ratio = 0, 0.0
    for tile in open_tileset(out / "tileset.json").walk():
        if tile.content_path is None:
            continue
        mesh = tile.load()
        tf = mesh.faces[~mesh.skirt]
        tv = mesh.vertices
        bound = tile.geometric_error
        lo, hi = tv[tf].reshape(-1, 3).min(axis=0), tv[tf].reshape(-1, 3).max(axis=0)
        # tile → raster: points on the tile over valid raster cells
        pt = sample_triangles(tv[tf], 8)
        col = np.floor((pt[:, 0] - origin[0]) / step - 0.5).astype(int)
        row = np.floor((origin[1] - pt[:, 1]) / step - 0.5).astype(int)
        inside = (row >= 0) & (row < z.shape[0] - 1) & (col >= 0) & (col < z.shape[1] - 1)
        over = np.zeros(len(pt), bool)
        over[inside] = cell_ok[row[inside], col[inside]]
        d_ts = distances_to_mesh(pt[over], sv, sf, bound + 1e-6, guess=_covering(pt[over][:, :2], sv[sf][:, :, :2]))
        # raster → tile: points on the raster's cells inside the tile's footprint and under its surface
        cen = sv[sf].mean(axis=1)
        foot = np.all((cen[:, :2] >= lo[:2]) & (cen[:, :2] <= hi[:2]), axis=1)
        ps = sample_triangles(sv[sf[foot]], 4)
        under = _covering(ps[:, :2], tv[tf][:, :, :2])
        d_st = distances_to_mesh(ps[under >= 0], tv, tf, bound + 1e-6, guess=under[under >= 0])
        worst = max(float(d_ts.max(initial=0.0)), float(d_st.max(initial=0.0)))
        assert worst <= bound + 1e-4, (tile.key, worst, bound)
        checked += 1
        worst_ratio = max(worst_ratio, worst / max(bound, 1e-9))
    return checked, worst_ratio


def _covering(xy: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Index of a triangle whose projection holds each point (any orientation), -1 for none."""
    cen = tri.mean(axis=1)
    radius = float(np.linalg.norm(tri - cen[:, None, :], axis=2).max())
    near = cKDTree(cen).query_ball_point(xy, radius + 1e-9)
    out = np.full(len(xy), -1, np.int64)
    counts = np.array([len(n) for n in near])
    if counts.sum() == 0:
        return out
    pi = np.repeat(np.arange(len(xy)), counts)
    ti = np.concatenate([np.asarray(n, np.int64) for n in near])
    a, b, c, p = tri[ti, 0], tri[ti, 1], tri[ti, 2], xy[pi]

    def cross(u, v, w):
        return (v[:, 0] - u[:, 0]) * (w[:, 1] - u[:, 1]) - (v[:, 1] - u[:, 1]) * (w[:, 0] - u[:, 0])

    s1, s2, s3 = cross(a, b, p), cross(b, c, p), cross(c, a, p)
    tol = 1e-9
    hit = ((s1 >= -tol) & (s2 >= -tol) & (s3 >= -tol)) | ((s1 <= tol) & (s2 <= tol) & (s3 <= tol))
    out[pi[hit]] = ti[hit]
    return out


@pytest.mark.parametrize("kind", ["walls", "nodata"])
def test_every_tile_within_its_geometric_error_both_ways(tmp_path: Path, kind: str) -> None:
    z = hard_raster(kind)
    origin = (500_000.0, 5_400_000.0)  # 5e6 m coordinates: tile-local arithmetic must hold
    raster = _write(tmp_path / "z.tif", z, origin=origin)
    out = tmp_path / "tiles"
    build_dsm(raster, out, tile_size=17, workers=0, progress=False, metric="hausdorff")
    checked, _ = _check_tiles(out, z, 1.0, origin)
    assert checked == 21


def test_hausdorff_tiles_certify_lower_than_vertical_on_facades(tmp_path: Path) -> None:
    z = hard_raster("walls")
    raster = _write(tmp_path / "z.tif", z)
    errs = {}
    for metric in ("vertical", "hausdorff"):
        build_dsm(raster, tmp_path / metric, tile_size=17, workers=0, progress=False, metric=metric)
        ts = open_tileset(tmp_path / metric / "tileset.json")
        errs[metric] = {t.key: t.geometric_error for t in ts.walk() if t.content_path is not None}
        assert ("Hausdorff distance vs" in ts.extras["citylod"]["error_metric"]) == (metric == "hausdorff")
    # the coarsest tiles, where the block's façades fall between samples, certify far lower
    coarse = [k for k in errs["vertical"] if k.count("/") == 0]  # the root
    assert coarse
    assert all(errs["hausdorff"][k] < 0.7 * errs["vertical"][k] for k in coarse), (errs, coarse)


def test_certificate_never_above_vertical_and_at_least_measured() -> None:
    """On a random TIN over a raster with a block: the Hausdorff bound is at most the exact vertical one of
    the same TIN, and at least the distances measured independently."""
    rng = np.random.default_rng(3)
    n = 41
    z = rng.normal(0, 0.2, (n, n)).cumsum(axis=1) * 0.3
    z[12:25, 8:30] += 15.0
    ok = np.ones_like(z, bool)

    def read(r, c, nr, nc):
        return z[r:r + nr, c:c + nc], ok[r:r + nr, c:c + nc]

    from scipy.spatial import Delaunay

    pts = np.unique(np.concatenate([rng.integers(0, n, (60, 2)), [[0, 0], [0, n - 1], [n - 1, 0], [n - 1, n - 1]]]),
                    axis=0).astype(float)
    faces = Delaunay(pts).simplices.astype(np.int64)
    vz = z[pts[:, 0].astype(int), pts[:, 1].astype(int)]
    step = 0.5
    h, _, _ = certify_hausdorff(read, (0, 0, n - 1, n - 1), pts[:, 0], pts[:, 1], vz, faces, (1, 1), n - 1,
                                (step, 0.0, 0.0, -step), block=16)
    v, _, _ = certify(read, (0, 0, n - 1, n - 1), pts[:, 0], pts[:, 1], vz, faces, (1, 1), n - 1)
    assert h <= v + 1e-9
    tv = np.column_stack([pts[:, 1] * step, -pts[:, 0] * step, vz])
    sv, sf = _raster_surface(z, step, (-0.5 * step, 0.5 * step))
    d1 = distances_to_mesh(sample_triangles(tv[faces], 5), sv, sf, h + 1e-6)
    d2 = distances_to_mesh(sample_triangles(sv[sf], 2), tv, faces, h + 1e-6)
    measured = max(d1.max(), d2.max())
    assert measured <= h + 1e-6
    assert measured >= 0.5 * h  # and not vacuous
    assert h < 0.8 * v  # the façades cost less than their height


def test_a_slope_beside_a_facade_certifies_at_its_measured_distance() -> None:
    """A TIN slope three samples wide beside a raster façade that continues into a roof: no single raster
    triangle is near every vertex of the pieces over the roof's edge, so a bound of whole pieces is about 3×
    the true distance (2.99 m against 0.96 m before pieces were split); the split pieces' bound is the
    measured distance, and never below it."""
    n = 21
    z = np.zeros((n, n))
    z[:, 10:] = 10.0  # a façade between columns 9 and 10, a roof to the east
    ok = np.ones_like(z, bool)

    def read(r, c, nr, nc):
        return z[r:r + nr, c:c + nc], ok[r:r + nr, c:c + nc]

    cols = [0, 8, 11, 20]  # ground to column 8, a slope from 8 to 11, roof from 11
    pts = np.array([[r, c] for c in cols for r in (0, n - 1)], float)
    vz = z[pts[:, 0].astype(int), pts[:, 1].astype(int)]
    faces = np.array([f for k in range(3) for f in ([2 * k, 2 * k + 3, 2 * k + 1], [2 * k, 2 * k + 2, 2 * k + 3])],
                     np.int64)
    h, _, _ = certify_hausdorff(read, (0, 0, n - 1, n - 1), pts[:, 0], pts[:, 1], vz, faces, (1, 1), n - 1,
                                (1.0, 0.0, 0.0, -1.0))
    tv = np.column_stack([pts[:, 1] + 0.5, -pts[:, 0] - 0.5, vz])
    sv, sf = _raster_surface(z, 1.0, (0.0, 0.0))
    d1 = distances_to_mesh(sample_triangles(tv[faces], 40), sv, sf, 20.0)
    d2 = distances_to_mesh(sample_triangles(sv[sf], 4), tv, faces, 20.0)
    measured = max(d1.max(), d2.max())
    assert measured <= h + 1e-6
    assert h <= 1.1 * measured, (h, measured)


def test_a_subset_of_faces_bounds_its_own_pieces() -> None:
    """``evaluate`` (stage 2 certifies only the faces its border fans touched): the bound of a subset of faces
    is at least the distances measured independently from points on those faces to the raster and from raster
    points under them to the whole TIN, no subset is needed for the empty one, and a subset away from the worst
    piece certifies lower than the whole TIN (only its faces were bounded)."""
    rng = np.random.default_rng(5)
    n = 41
    z = rng.normal(0, 0.2, (n, n)).cumsum(axis=1) * 0.3
    z[12:25, 8:30] += 15.0
    ok = np.ones_like(z, bool)

    def read(r, c, nr, nc):
        return z[r:r + nr, c:c + nc], ok[r:r + nr, c:c + nc]

    from scipy.spatial import Delaunay

    pts = np.unique(np.concatenate([rng.integers(0, n, (60, 2)), [[0, 0], [0, n - 1], [n - 1, 0], [n - 1, n - 1]]]),
                    axis=0).astype(float)
    faces = Delaunay(pts).simplices.astype(np.int64)
    vz = z[pts[:, 0].astype(int), pts[:, 1].astype(int)]
    step = 0.5
    args = (read, (0, 0, n - 1, n - 1), pts[:, 0], pts[:, 1], vz, faces, (1, 1), n - 1, (step, 0.0, 0.0, -step))
    whole = certify_hausdorff(*args, block=16)[0]
    assert certify_hausdorff(*args, block=16, evaluate=np.zeros(len(faces), bool))[0] == 0.0
    tv = np.column_stack([pts[:, 1] * step, -pts[:, 0] * step, vz])
    sv, sf = _raster_surface(z, step, (-0.5 * step, 0.5 * step))
    ps = sample_triangles(sv[sf], 2)
    under = _covering(ps[:, :2], tv[faces][:, :, :2])
    far = (pts[faces, 0] >= 30).all(axis=1)  # faces away from the block
    assert far.any()
    masks = [np.random.default_rng(k).random(len(faces)) < 0.3 for k in range(5)] + [far]
    for k, mask in enumerate(masks):
        bound = certify_hausdorff(*args, block=16, evaluate=mask)[0]
        d1 = distances_to_mesh(sample_triangles(tv[faces[mask]], 5), sv, sf, bound + 1e-6)
        mine = (under >= 0) & mask[np.maximum(under, 0)]
        d2 = distances_to_mesh(ps[mine], tv, faces, bound + 1e-6)
        assert max(d1.max(initial=0.0), d2.max(initial=0.0)) <= bound + 1e-6, k
    assert bound < 0.5 * whole, (bound, whole)  # the far faces' own bound, not the whole TIN's


def test_heights_off_the_raster_samples_certify_at_least_measured() -> None:
    """Coarse vertices may carry heights that are no raster sample (issue #20: a height between a roof and the
    ground next to it bounds the error better than either): the certificate of a TIN whose every vertex is
    moved off its sample, some by more than the façades' height, is still at least the distance measured
    independently in both directions, and tight on it (within 1.1×)."""
    rng = np.random.default_rng(11)
    n = 41
    z = rng.normal(0, 0.2, (n, n)).cumsum(axis=1) * 0.3
    z[12:25, 8:30] += 15.0  # a block
    z[30, 4:36] += 6.0  # a one-sample wall
    ok = np.ones_like(z, bool)

    def read(r, c, nr, nc):
        return z[r:r + nr, c:c + nc], ok[r:r + nr, c:c + nc]

    from scipy.spatial import Delaunay

    pts = np.unique(np.concatenate([rng.integers(0, n, (80, 2)), [[0, 0], [0, n - 1], [n - 1, 0], [n - 1, n - 1]]]),
                    axis=0).astype(float)
    faces = Delaunay(pts).simplices.astype(np.int64)
    sample = z[pts[:, 0].astype(int), pts[:, 1].astype(int)]
    step = 0.5
    tv_at = np.column_stack([pts[:, 1] * step, -pts[:, 0] * step])
    sv, sf = _raster_surface(z, step, (-0.5 * step, 0.5 * step))
    for shift in (rng.uniform(-1.0, 1.0, len(pts)), rng.uniform(-20.0, 20.0, len(pts))):
        vz = sample + shift
        h, _, _ = certify_hausdorff(read, (0, 0, n - 1, n - 1), pts[:, 0], pts[:, 1], vz, faces, (1, 1), n - 1,
                                    (step, 0.0, 0.0, -step), block=16)
        tv = np.column_stack([tv_at, vz])
        d1 = distances_to_mesh(sample_triangles(tv[faces], 12), sv, sf, h + 1e-6)
        d2 = distances_to_mesh(sample_triangles(sv[sf], 4), tv, faces, h + 1e-6)
        measured = max(d1.max(), d2.max())
        assert measured <= h + 1e-6, (measured, h)
        assert h <= 1.1 * measured, (h, measured)


def test_blocks_bounded_at_once_still_bound_every_piece() -> None:
    """The block test of ``hausdorff_block`` (`_block_planes`, `_block_bound`): a face's cells in a block whose
    bound is under the threshold are recorded at that bound without their pieces. With a floor above every
    vertical error, every block goes through the test and none is clipped, so the result is the blocks'
    bounds alone. The raster is a steep plane with a mound and a pit (the largest errors above and below the
    TIN), a no-data hole whose samples hold -500 m, and blocks cut by its edges (45 samples, not a multiple
    of the block); the TIN's heights lie near the plane, off the samples. The blocks' result must be at least
    the exact vertical L∞ of the same TIN (which every piece's bound is) and at least the distances measured
    independently, and not vacuous; with no floor the pieces are bounded one by one, and that result is a
    bound too."""
    rng = np.random.default_rng(17)
    n = 45
    yy, xx = np.mgrid[0:n, 0:n].astype(float)
    z = 100.0 + 0.8 * xx - 0.5 * yy + 0.05 * rng.standard_normal((n, n))
    z += 3.0 * np.exp(-((yy - 11.0) ** 2 + (xx - 30.0) ** 2) / 4.0)  # a mound: the raster above the TIN
    z -= 2.5 * np.exp(-((yy - 33.0) ** 2 + (xx - 14.0) ** 2) / 3.0)  # a pit: below it
    ok = np.ones_like(z, bool)
    ok[20:24, 5:9] = False
    z[20:24, 5:9] = -500.0  # no-data samples: they must not enter any block's range

    def read(r, c, nr, nc):
        return z[r:r + nr, c:c + nc], ok[r:r + nr, c:c + nc]

    from scipy.spatial import Delaunay

    pts = np.unique(np.concatenate([rng.integers(0, n, (70, 2)), [[0, 0], [0, n - 1], [n - 1, 0], [n - 1, n - 1]]]),
                    axis=0).astype(float)
    faces = Delaunay(pts).simplices.astype(np.int64)
    vz = 100.0 + 0.8 * pts[:, 1] - 0.5 * pts[:, 0] + rng.uniform(-0.2, 0.2, len(pts))
    step = 0.5
    args = (read, (0, 0, n - 1, n - 1), pts[:, 0], pts[:, 1], vz, faces, (1, 1), n - 1, (step, 0.0, 0.0, -step))
    v, _, _ = certify(*args[:8])
    blocks = certify_hausdorff(*args, floor=1e6, per_cell=False)[0]  # per-cell maps bound piece by piece
    pieces = certify_hausdorff(*args, per_cell=False)[0]
    assert blocks >= v - 1e-9, (blocks, v)
    assert blocks <= 2.0 * v, (blocks, v)  # a bound of the block's range, not a vacuous one
    assert certify_hausdorff(*args, floor=1e6)[0] <= v + 1e-9  # with the map: each piece at its vertical bound
    sv, sf = _raster_surface(np.where(ok, z, NODATA), step, (-0.5 * step, 0.5 * step))
    tv = np.column_stack([pts[:, 1] * step, -pts[:, 0] * step, vz])
    ps = sample_triangles(sv[sf], 3)
    d2 = distances_to_mesh(ps[_covering(ps[:, :2], tv[faces][:, :, :2]) >= 0], tv, faces, v + 1e-6)
    pt = sample_triangles(tv[faces], 6)
    col = np.floor(pt[:, 0] / step).astype(int)
    row = np.floor(-pt[:, 1] / step).astype(int)
    cell_ok = ok[:-1, :-1] & ok[:-1, 1:] & ok[1:, :-1] & ok[1:, 1:]
    over = cell_ok[np.clip(row, 0, n - 2), np.clip(col, 0, n - 2)]
    d1 = distances_to_mesh(pt[over], sv, sf, v + 1e-6)
    measured = max(d1.max(), d2.max())
    assert measured <= pieces + 1e-6 and pieces <= blocks + 1e-9, (measured, pieces, blocks)
