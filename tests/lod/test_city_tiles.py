"""City model -> 3D Tiles: every object with its attributes, feature IDs on every vertex, certified errors.

Expectations come from the sample city's analytic buildings (:class:`citylod.sample.city.SampleCity`) and from
an independent dense sampling of the surfaces (scipy), never from the builder under test.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial import cKDTree

from citylod.core.errors import CitylodError
from citylod.io.tiles3d import Tile, open_tileset
from citylod.lod.build.city import build_city_tiles
from citylod.sample import SampleInfo


@pytest.fixture(scope="module")
def tiles(sample_city: SampleInfo, tmp_path_factory: pytest.TempPathFactory) -> SimpleNamespace:
    out = tmp_path_factory.mktemp("city_tiles") / "tiles"
    report = build_city_tiles(sample_city.files["city"], out, leaf_triangles=20, progress=False)
    return SimpleNamespace(report=report, ts=open_tileset(out), truth=sample_city.city, out=out)


def _leaves(ts: object) -> list[Tile]:
    return [t for t in ts.walk() if not t.children]  # type: ignore[attr-defined]


def _world(tile: Tile) -> tuple[np.ndarray, np.ndarray, list]:
    """The tile's mesh in the tileset's CRS, its object feature IDs and its property tables."""
    c = tile.load_content()
    m = c.meshes[0]
    v = m.positions.astype(np.float64) @ tile.matrix[:3, :3].T + tile.matrix[:3, 3]
    return v, m.faces.astype(np.int64), [m, c.property_tables]


def test_every_building_is_in_one_leaf_with_its_attributes(tiles: SimpleNamespace) -> None:
    assert tiles.report.levels >= 3 and tiles.ts.kind == "city"
    rows: dict[str, dict] = {}
    for t in _leaves(tiles.ts):
        table = t.load_content().property_tables[0]
        assert table.class_name == "city_object"
        for i in range(table.count):
            row = table.row(i)
            assert row["object_id"] not in rows, "an object is in two leaves"
            rows[row["object_id"]] = row
    truth = {b.id: b for b in tiles.truth.buildings}
    assert set(rows) == set(truth)
    for oid, b in truth.items():
        r = rows[oid]
        assert r["type"] == "Building" and r["name"] == b.name and r["function"] == b.function
        assert r["measured_height"] == pytest.approx(round(b.measured_height, 2))
        assert r["storeys"] == b.storeys
        attrs = json.loads(r["attributes"])
        assert attrs["street"] == b.street and attrs["shape"] == b.shape


def test_feature_ids_and_surface_classes_follow_the_geometry(tiles: SimpleNamespace) -> None:
    truth = {b.id: b for b in tiles.truth.buildings}
    for t in _leaves(tiles.ts):
        v, f, (mesh, tables) = _world(t)
        obj, surf = mesh.features[0], mesh.features[1]
        assert obj.table == 0 and surf.table == 1 and obj.feature_count == tables[0].count
        ids = tables[0].columns["object_id"]
        for row in range(tables[0].count):
            verts, _ = truth[ids[row]].solid(lod=2)
            pts = v[obj.ids == row]
            # every vertex of the object's feature ID lies on the object's own LoD2 solid (its box here)
            assert len(pts) and np.all(pts >= verts.min(axis=0) - 1e-2) and np.all(pts <= verts.max(axis=0) + 1e-2)
        classes = np.array(tables[1].columns["surface_class"], dtype=object)[surf.ids[f[:, 0]]]
        n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        nz = n[:, 2] / np.linalg.norm(n, axis=1)
        assert set(classes) >= {"RoofSurface", "WallSurface", "GroundSurface"}
        assert np.all(nz[classes == "RoofSurface"] > 0.05)  # roofs face up, grounds down, walls sideways
        assert np.all(nz[classes == "GroundSurface"] < -0.99)
        assert np.all(np.abs(nz[classes == "WallSurface"]) < 0.01)


def _samples(v: np.ndarray, f: np.ndarray, spacing: float) -> tuple[np.ndarray, float]:
    """Points on every triangle, no point of a triangle farther than the returned radius from one."""
    out, radius = [], 0.0
    for tri in v[f]:
        longest = max(np.linalg.norm(tri[0] - tri[1]), np.linalg.norm(tri[1] - tri[2]), np.linalg.norm(tri[2] - tri[0]))
        n = max(1, int(np.ceil(longest / spacing)))
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        k = i + j <= n
        a, b = i[k] / n, j[k] / n
        out.append(tri[0] * (1 - a - b)[:, None] + tri[1] * a[:, None] + tri[2] * b[:, None])
        radius = max(radius, longest / n)
    return np.concatenate(out), radius


def test_coarse_errors_bound_an_independent_hausdorff_estimate(tiles: SimpleNamespace) -> None:
    inner = [t for t in tiles.ts.walk() if t.children]
    assert inner
    for t in inner:
        assert all(c.geometric_error <= t.geometric_error for c in t.children)
        v, f, _ = _world(t)
        leaves = [x for x in tiles.ts.walk_from(t) if not x.children]
        full = [_world(x)[:2] for x in leaves]
        fv = np.concatenate([a for a, _ in full])
        ff = np.concatenate([b + o for (_, b), o in zip(full, np.cumsum([0] + [len(a) for a, _ in full[:-1]]), strict=True)])
        ps, rs = _samples(v, f, 0.5)
        pf, rf = _samples(fv, ff, 0.5)
        # Point-to-samples distances exceed point-to-surface distances by at most the other side's radius.
        est = max(cKDTree(pf).query(ps)[0].max() - rf, cKDTree(ps).query(pf)[0].max() - rs)
        assert est <= t.geometric_error + 1e-6
        # ... and the bound is tight: the true distance is at most est + 2 radii, the bound within 5 cm or 2 %.
        assert t.geometric_error <= est + rs + rf + max(0.05, 0.02 * t.geometric_error) + 1e-3
    assert tiles.ts.root.triangle_count < tiles.report.leaf_triangles


def test_broken_input_leaves_nothing(tmp_path: Path) -> None:
    bad = tmp_path / "empty.city.json"
    bad.write_text(json.dumps({"type": "CityJSON", "version": "1.0", "CityObjects": {}, "vertices": [],
                               "metadata": {"referenceSystem": "urn:ogc:def:crs:EPSG::7415"}}))
    with pytest.raises(CitylodError):
        build_city_tiles(bad, tmp_path / "out", progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.city.json"]


def _cube(offset: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """A unit cube at UTM-sized coordinates, every face counter-clockwise seen from outside."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
    f = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5],
                  [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])
    return v + np.array([500_000.0, 5_400_000.0, 40.0]) + offset, f


def test_only_closed_outward_shells_count_as_single_sided() -> None:
    """The check behind single-sided city tiles: outward normals computed independently (each face's normal
    against the direction from the cube's centre) agree, and every way of breaking the property is refused:
    an inverted shell, an open one, one flipped face, a second shell inverted, duplicated vertices per face
    (welded, still closed), a T-junction (an edge split on one side only)."""
    from citylod.lod.build.city import _closed_outward

    v, f = _cube()
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert (np.einsum("ij,ij->i", n, v[f].mean(axis=1) - v.mean(axis=0)) > 0).all()  # the cube is outward
    assert _closed_outward(v, f)
    assert not _closed_outward(v, f[:, ::-1])
    assert not _closed_outward(v, f[2:])
    flipped = f.copy()
    flipped[5] = flipped[5][::-1]
    assert not _closed_outward(v, flipped)
    v2, _ = _cube((3.0, 0.0, 0.0))
    assert _closed_outward(np.vstack([v, v2]), np.vstack([f, f + 8]))
    assert not _closed_outward(np.vstack([v, v2]), np.vstack([f, (f + 8)[:, ::-1]]))
    unwelded = v[f].reshape(-1, 3)  # three vertices of its own per face, as polygon rings give
    assert _closed_outward(unwelded, np.arange(len(unwelded)).reshape(-1, 3))
    mid = np.vstack([v, [(v[0] + v[1]) / 2]])  # vertex 8 splits edge 0-1 in the bottom face (f[0]) only
    assert f[0].tolist() == [0, 2, 1]
    assert not _closed_outward(mid, np.vstack([f[1:], [[0, 2, 8], [8, 2, 1]]]))


def test_closed_buildings_are_written_single_sided(tiles: SimpleNamespace) -> None:
    """The sample city's houses are closed, outward solids: their tiles are single-sided (glTF
    ``doubleSided: false``, read back through the glb's own JSON), so clients cull their back faces."""
    import struct

    sides = set()
    for t in _leaves(tiles.ts):
        data = t.content_path.read_bytes()
        (jlen,) = struct.unpack_from("<I", data, 12)
        sides |= {bool(m.get("doubleSided", False)) for m in json.loads(data[20:20 + jlen])["materials"]}
    assert sides == {False}


def test_tiles_are_built_depth_first_so_few_atlases_wait():
    """Each tile comes after its children, and a subtree is finished before the next begins: the atlases made
    and not yet shrunk into a parent's stay a few per level, not one per leaf (as ordering by height did,
    22 GB of atlases for 32,000 textured houses)."""
    from citylod.lod.build.city import _build_tree, _post_order, _walk

    rng = np.random.default_rng(3)
    centres = rng.uniform(0, 1000, (4000, 3))
    root = _build_tree(np.arange(4000), centres, np.ones(4000), 3.0)
    order = _post_order(root)
    assert sorted(n.key for n in order) == sorted(n.key for n in _walk(root))
    seen: set[str] = set()
    waiting: set[str] = set()  # built, their parent not yet
    peak = 0
    for n in order:
        assert all(c.key in seen for c in n.children)
        waiting -= {c.key for c in n.children}
        waiting.add(n.key)
        seen.add(n.key)
        peak = max(peak, len(waiting))
    leaves = sum(not n.children for n in order)
    assert leaves > 1000
    assert peak <= 4 * (root.height + 1)
    by_height = sorted(_walk(root), key=lambda n: n.height)  # the control: every leaf waits
    waiting.clear()
    peak = 0
    for n in by_height:
        waiting -= {c.key for c in n.children}
        waiting.add(n.key)
        peak = max(peak, len(waiting))
    assert peak >= leaves
