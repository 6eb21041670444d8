"""Point-cloud octree build: completeness, bounds, exact error (checked independently), planes, executors."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from citylod.core.errors import EmptyInputError, GeoreferenceError, InputError
from citylod.io.tiles3d import Tile, open_tileset
from citylod.lod.build.points import build_points
from tests.io.test_tiles3d import _vertex_attribute_layout_errors
from tests.lod.test_points_cloud import ROOF_NORMAL, WALL_NORMAL, X0, Y0, make_cloud
from tests.paths import DELFT

SMALL = {"max_chunk_points": 20_000, "max_leaf_points": 4_000, "segment_points": 30_000}


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray, Path]:
    d = tmp_path_factory.mktemp("points")
    las = d / "cloud.laz"
    pts = make_cloud(las)
    out = d / "tiles"
    report = build_points([las], out, workers=0, progress=False, **SMALL)
    assert report.points == len(pts) and report.chunks > 1 and report.quads > 0
    assert "points" in report.summary()
    return las, pts, out


def _read_png(data: bytes) -> np.ndarray:
    import OpenImageIO as oiio

    fd, name = tempfile.mkstemp(suffix=".png")
    try:
        os.write(fd, data)
        os.close(fd)
        inp = oiio.ImageInput.open(name)
        img = inp.read_image("uint8")
        inp.close()
        return np.asarray(img)
    finally:
        os.unlink(name)


def _texels(tile: Tile) -> tuple[np.ndarray, np.ndarray]:
    """Centres (T, 3) float64 of the opaque quad texels of a tile, and the quads' normals (Q, 3)."""
    mesh = tile.load()
    quads = [m for m in mesh.content.meshes if m.name == "quads"]
    if not quads:
        return np.zeros((0, 3)), np.zeros((0, 3))
    q = quads[0]
    img = _read_png(q.texture)
    ah, aw = img.shape[:2]
    v = mesh.vertices  # the tile's only mesh: quads, in the source CRS
    centres, normals = [], []
    for k in range(len(v) // 4):
        c0, c1, _, c3 = v[4 * k:4 * k + 4]
        x0, y0 = np.rint(q.uv[4 * k] * [aw, ah]).astype(int)
        w = int(np.rint((q.uv[4 * k + 1, 0] - q.uv[4 * k, 0]) * aw))
        h = int(np.rint((q.uv[4 * k + 3, 1] - q.uv[4 * k, 1]) * ah))
        r, col = np.nonzero(img[y0:y0 + h, x0:x0 + w, 3] > 0)
        centres.append(c0 + ((col + 0.5) / w)[:, None] * (c1 - c0) + ((r + 0.5) / h)[:, None] * (c3 - c0))
        n = np.cross(c1 - c0, c3 - c0)
        normals.append(n / np.linalg.norm(n))
    return np.concatenate(centres), np.array(normals)


def _leaf_points(tile: Tile) -> np.ndarray:
    """(N, 6) x, y, z, intensity, classification, return number of a leaf's points."""
    m = tile.load()
    p = m.content.points
    assert p is not None and m.points is not None
    return np.column_stack([m.points, p.intensity, p.classification, p.return_number])


def _subtree_points(tile: Tile, memo: dict[int, np.ndarray]) -> np.ndarray:
    if id(tile) not in memo:
        memo[id(tile)] = (_leaf_points(tile) if not tile.children
                          else np.concatenate([_subtree_points(c, memo) for c in tile.children]))
    return memo[id(tile)]


def _rows(a: np.ndarray) -> np.ndarray:
    r = np.column_stack([np.rint(a[:, :3] * 1000).astype(np.int64), a[:, 3:].astype(np.int64)])
    return r[np.lexsort(r.T[::-1])]


def test_every_point_in_exactly_one_leaf_with_attributes(built: tuple[Path, np.ndarray, Path]) -> None:
    _, pts, out = built
    ts = open_tileset(out)
    leaves = [t for t in ts.walk() if not t.children]
    got = np.concatenate([_leaf_points(t) for t in leaves])
    assert len(got) == len(pts)
    np.testing.assert_array_equal(_rows(got), _rows(pts))
    assert all(t.geometric_error == 0.0 for t in leaves)
    assert all(t.refine == "REPLACE" for t in ts.walk())
    doc = json.loads((out / "tileset.json").read_text())
    assert doc["extras"]["citylod"]["kind"] == "points"
    assert not out.with_name(out.name + ".partial").exists()
    # Every content file keeps glTF's 4-byte alignment of vertex attributes (RGB8, uint16 intensity, ...).
    for f in sorted((out / "tiles").rglob("*.glb")):
        assert _vertex_attribute_layout_errors(f.read_bytes()) == [], f


def test_node_content_inside_bounds_and_errors_shrink(built: tuple[Path, np.ndarray, Path]) -> None:
    _, _, out = built
    for t in open_tileset(out).walk():
        lo, hi = t.bounds
        m = t.load()
        for arr in (m.points, m.vertices):
            if arr is not None and len(arr):
                assert np.all(arr >= lo - 1e-3) and np.all(arr <= hi + 1e-3), t.key
        for c in t.children:
            assert c.geometric_error <= t.geometric_error


def test_geometric_error_bounds_every_input_point(built: tuple[Path, np.ndarray, Path]) -> None:
    """Independent check: each input point of a node's subtree is within the node's geometricError of
    the nearest point or opaque quad texel the node draws."""
    _, _, out = built
    ts = open_tileset(out)
    memo: dict[int, np.ndarray] = {}
    checked = 0
    for t in ts.walk():
        if not t.children:
            continue
        m = t.load()
        texels, _ = _texels(t)
        drawn = np.concatenate([m.points if m.points is not None else np.zeros((0, 3)), texels])
        inputs = _subtree_points(t, memo)[:, :3]
        dist, _ = cKDTree(drawn).query(inputs)
        assert dist.max() <= t.geometric_error + 1e-4, (t.key, dist.max(), t.geometric_error)
        # The error is a bound, not a loose one: the worst distance, either way (input → drawn, and drawn
        # quad texels → input), is not far inside it.
        back = cKDTree(inputs).query(texels)[0].max() if len(texels) else 0.0
        assert max(dist.max(), back) >= 0.25 * t.geometric_error or t.children[0].geometric_error > 0
        # Vertex clustering on 64³: the node draws far fewer points than its subtree holds.
        assert len(drawn) < len(inputs)
        checked += 1
    assert checked >= 3


def test_planted_planes_become_quads(built: tuple[Path, np.ndarray, Path]) -> None:
    _, pts, out = built
    ts = open_tileset(out)
    tree = cKDTree(pts[:, :3])
    roof = wall = False
    for t in ts.walk():
        texels, normals = _texels(t)
        if not len(normals):
            continue
        # What is drawn lies on the input: every opaque texel centre, the crack border included, is within
        # the node's geometricError of an input point (the other direction of the Hausdorff bound).
        dist, _ = tree.query(texels)
        assert dist.max() <= t.geometric_error + 1e-4, t.key
        v = t.load().vertices.reshape(-1, 4, 3).mean(axis=1)
        for n, c in zip(normals, v, strict=True):
            if abs(n @ ROOF_NORMAL) > 0.98 and 40 < c[0] - X0 < 60 and 40 < c[1] - Y0 < 52:
                roof = True
            if abs(n @ WALL_NORMAL) > 0.98 and abs(c[0] - X0 - 70) < 0.5:
                wall = True
    assert roof and wall


def _texel_size(t: Tile) -> float:
    m = t.load()
    q = next(mm for mm in m.content.meshes if mm.name == "quads")
    img = _read_png(q.texture)
    w_px = (q.uv[1, 0] - q.uv[0, 0]) * img.shape[1]
    return float(np.linalg.norm(m.vertices[1] - m.vertices[0]) / w_px)


def test_points_only_build_has_no_quads(tmp_path: Path, built: tuple[Path, np.ndarray, Path]) -> None:
    las, _, out = built
    report = build_points([las], tmp_path / "plain", hybrid=False, workers=0, progress=False, **SMALL)
    assert report.quads == 0
    ts = open_tileset(tmp_path / "plain")
    assert all(not t.load_content().meshes for t in ts.walk())
    hybrid_pts = sum(t.load_content().point_count for t in open_tileset(out).walk() if t.children)
    plain_pts = sum(t.load_content().point_count for t in ts.walk() if t.children)
    assert hybrid_pts < plain_pts


def test_local_pool_dask_and_in_memory_threads_write_the_same_tileset(tmp_path: Path) -> None:
    distributed = pytest.importorskip("distributed")
    las = tmp_path / "c.laz"
    make_cloud(las, n_terrain=20_000, rgb=False, crs=None)
    small = {"max_chunk_points": 12_000, "max_leaf_points": 3_000, "segment_points": 20_000}
    a = build_points([las], tmp_path / "pool", crs="EPSG:28992", workers=2, progress=False, **small)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp://",
                                  host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        b = build_points([las], tmp_path / "dask", crs="EPSG:28992", scheduler=cluster.scheduler_address,
                         progress=False, **small)
    # workers=None on a small cloud: threads in this process, intermediates in memory, one segment per file.
    c = build_points([las], tmp_path / "mem", crs="EPSG:28992", progress=False, **small)
    assert not (tmp_path / "mem.partial").exists()
    assert a.nodes == b.nodes == c.nodes and a.quads == b.quads == c.quads and a.quads > 0
    files_a = sorted(p.relative_to(tmp_path / "pool") for p in (tmp_path / "pool").rglob("*.glb"))
    for other in ("dask", "mem"):
        assert (tmp_path / "pool/tileset.json").read_text() == (tmp_path / other / "tileset.json").read_text()
        files_b = sorted(p.relative_to(tmp_path / other) for p in (tmp_path / other).rglob("*.glb"))
        assert files_a == files_b
        for f in files_a:
            assert (tmp_path / "pool" / f).read_bytes() == (tmp_path / other / f).read_bytes(), (other, f)


def test_interrupted_build_resumes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import citylod.lod.build.points as mod

    las = tmp_path / "c.laz"
    make_cloud(las, n_terrain=15_000, rgb=False)
    calls = {"n": 0}
    real = mod._build_chunk

    def failing(*args: object) -> object:
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt
        return real(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(mod, "_build_chunk", failing)
    with pytest.raises(KeyboardInterrupt):
        build_points([las], tmp_path / "out", workers=0, progress=False, **SMALL)
    assert not (tmp_path / "out").exists() and (tmp_path / "out.partial").exists()
    done = list((tmp_path / "out.partial/.build/results").glob("*.pkl"))
    assert len(done) >= 2  # the chunks that finished before the interruption
    monkeypatch.setattr(mod, "_build_chunk", real)
    before = {p: p.stat().st_mtime_ns for p in (tmp_path / "out.partial/tiles").rglob("*.glb")}
    report = build_points([las], tmp_path / "out", workers=0, progress=False, **SMALL)
    for p, mtime in before.items():  # finished nodes were not rewritten
        q = tmp_path / "out" / p.relative_to(tmp_path / "out.partial")
        assert q.stat().st_mtime_ns == mtime
    fresh = build_points([las], tmp_path / "fresh", workers=0, progress=False, **SMALL)
    assert (tmp_path / "out/tileset.json").read_text() == (tmp_path / "fresh/tileset.json").read_text()
    assert report.nodes == fresh.nodes


def test_bad_inputs_fail_cleanly(tmp_path: Path) -> None:
    las = tmp_path / "c.laz"
    make_cloud(las, n_terrain=3_000)
    data = las.read_bytes()
    cut = tmp_path / "cut.laz"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"cut\.laz"):
        build_points([cut], tmp_path / "o1", workers=0, progress=False)
    assert not (tmp_path / "o1").exists()
    # the default for small clouds: threads, intermediates in memory; nothing to resume, nothing left
    with pytest.raises(InputError, match=r"cut\.laz"):
        build_points([cut], tmp_path / "o4", progress=False)
    assert not (tmp_path / "o4").exists() and not (tmp_path / "o4.partial").exists()
    nocrs = tmp_path / "nocrs.laz"
    make_cloud(nocrs, n_terrain=3_000, crs=None)
    with pytest.raises(GeoreferenceError, match=r"nocrs\.laz"):
        build_points([nocrs], tmp_path / "o2", workers=0, progress=False)
    with pytest.raises(EmptyInputError):
        build_points([], tmp_path / "o3", workers=0, progress=False)


@pytest.mark.realdata
@pytest.mark.slow
def test_delft_build_counts_and_quads(tmp_path: Path) -> None:
    files = sorted(DELFT.glob("ahn3_cropped_*.laz"))
    if len(files) != 2:
        pytest.skip(f"real data not found in {DELFT}")
    hybrid = build_points(files, tmp_path / "hybrid", crs="EPSG:28992", progress=False, measure_floor=True)
    plain = build_points(files, tmp_path / "plain", crs="EPSG:28992", progress=False, hybrid=False)
    print("\n" + hybrid.summary() + "\n--- points only\n" + plain.summary())
    assert hybrid.points == plain.points == 848_942
    assert hybrid.quads > 0 and plain.quads == 0
    ts = open_tileset(tmp_path / "hybrid")
    assert sum(t.load_content().point_count for t in ts.walk() if not t.children) == 848_942


def test_partition_on_threads_equals_one_pass() -> None:
    """The root split first and its octants partitioned side by side give the same order and node table
    as one compiled pass (clustered points: deep, uneven subtrees; a single-point octant; a leaf root)."""
    from concurrent.futures import ThreadPoolExecutor

    from citylod.lod.kernels.octree import MAX_LEVEL, QBITS, partition

    rng = np.random.default_rng(5)
    top = 1 << QBITS
    blobs = [rng.normal(c, s, (n, 3)) for c, s, n in ((0.2 * top, 1e6, 30_000), (0.7 * top, 1e8, 20_000),
                                                      (0.4 * top, 1e3, 5_000))]
    q = np.clip(np.concatenate(blobs + [np.full((1, 3), 0.9 * top)]), 0, top - 1).astype(np.int64)
    with ThreadPoolExecutor(2) as pool:
        for max_leaf in (500, 4_000, 100_000):
            o1, n1 = partition(q, 0, (0, 0, 0), max_leaf, MAX_LEVEL)
            o2, n2 = partition(q, 0, (0, 0, 0), max_leaf, MAX_LEVEL, pool)
            np.testing.assert_array_equal(o1, o2)
            np.testing.assert_array_equal(n1, n2)
            assert len(n1) > 1 or max_leaf >= len(q)
