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
