"""``build points --complete``: walls and ground under canopy on a small classified cloud made here.

The scene: flat ground (class 2) at z = 0, a 12 m × 8 m flat-roofed house 6 m high (class 6) turned by
30°, and a tree (class 5 canopy at 5-8 m) whose crown hid the ground under it. Every check is computed
from the scene's own geometry (the rectangle, the disc), never from the augmentation.
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import laspy
import numpy as np
import pytest

from citylod.io.tiles3d import open_tileset
from citylod.lod.build.complete import (
    KIND_GROUND,
    KIND_STEP,
    KIND_WALL,
    CompleteOptions,
    augment,
)
from citylod.lod.build.points import build_points

X0, Y0 = 85_000.0, 447_500.0  # RD New, as Delft: large coordinates
ANGLE = math.radians(30.0)
HALF = np.array([6.0, 4.0])  # the house's half extents
CENTER = np.array([20.0, 20.0])
ROOF_Z = 6.0
TREE = np.array([8.0, 30.0])
TREE_R = 4.0


def _to_house(xy: np.ndarray) -> np.ndarray:
    """Scene xy -> the house's frame (axis-aligned rectangle ±HALF)."""
    c, s = math.cos(ANGLE), math.sin(ANGLE)
    d = xy - CENTER
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])


def _from_house(uv: np.ndarray) -> np.ndarray:
    c, s = math.cos(ANGLE), math.sin(ANGLE)
    return np.column_stack([c * uv[:, 0] - s * uv[:, 1], s * uv[:, 0] + c * uv[:, 1]]) + CENTER


def _write(path: Path, xyz: np.ndarray, cls: np.ndarray) -> None:
    hdr = laspy.LasHeader(point_format=1, version="1.2")
    hdr.scales = np.array([0.001, 0.001, 0.001])
    hdr.offsets = np.array([X0, Y0, 0.0])
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = xyz[:, 0] + X0, xyz[:, 1] + Y0, xyz[:, 2]
    las.classification = cls.astype(np.uint8)
    las.intensity = np.full(len(xyz), 1000, np.uint16)
    las.return_number = np.ones(len(xyz), np.uint8)
    las.number_of_returns = np.ones(len(xyz), np.uint8)
    las.write(str(path))


def scene(path: Path, seed: int = 1, classified: bool = True) -> np.ndarray:
    """Write the scene (≈ 11 points/m²) to ``path``; returns its (N, 4) x, y, z, class (scene frame)."""
    rng = np.random.default_rng(seed)
    n = int(40 * 40 * 11)
    g = rng.uniform(0, 40, (n, 2))
    in_house = np.all(np.abs(_to_house(g)) <= HALF, axis=1)
    in_tree = np.hypot(*(g - TREE).T) <= TREE_R
    ground = g[~in_house & ~in_tree]
    roof = _from_house(rng.uniform(-HALF, HALF, (int(4 * HALF.prod() * 11), 2)))
    crown = TREE + TREE_R * np.sqrt(rng.random(600))[:, None] * np.column_stack(
        [np.cos(t := rng.uniform(0, 2 * np.pi, 600)), np.sin(t)])
    xyz = np.concatenate([
        np.column_stack([ground, np.zeros(len(ground))]),
        np.column_stack([roof, np.full(len(roof), ROOF_Z)]),
        np.column_stack([crown, rng.uniform(5, 8, len(crown))]),
    ])
    cls = np.concatenate([np.full(len(ground), 2), np.full(len(roof), 6), np.full(len(crown), 5)])
    if not classified:
        cls = np.ones_like(cls)
    _write(path, xyz, cls)
    return np.column_stack([xyz, cls])


def _house_distance(xy: np.ndarray) -> np.ndarray:
    """Horizontal distance from points to the house's outline (the walls), by the rectangle."""
    uv = np.abs(_to_house(xy))
    out = np.hypot(np.maximum(uv[:, 0] - HALF[0], 0), np.maximum(uv[:, 1] - HALF[1], 0))
    inside = np.all(uv <= HALF, axis=1)
    return np.where(inside, np.min(HALF - uv, axis=1), out)


def _signed_distance(xy: np.ndarray) -> np.ndarray:
    """:func:`_house_distance`, negative inside the house."""
    inside = np.all(np.abs(_to_house(xy)) <= HALF, axis=1)
    return np.where(inside, -1.0, 1.0) * _house_distance(xy)


@pytest.fixture(scope="module")
def cloud(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray]:
    path = tmp_path_factory.mktemp("complete") / "scene.las"
    return path, scene(path)


def test_walls_stand_on_the_outline_and_cover_it(cloud: tuple[Path, np.ndarray]) -> None:
    path, _ = cloud
    aug = augment([path], CompleteOptions(eave_m=0.0))  # this house has no eaves: walls at the roof edge
    walls = aug.xyz[aug.kind == KIND_WALL] - [X0, Y0, 0]
    assert len(walls) > 0 and not np.any(aug.kind == KIND_STEP)  # one flat roof: no steps
    d = _house_distance(walls[:, :2])
    # A wall at 30° to the grid is a staircase of cell edges, each at the outermost return of its cell
    # (within a cell diagonal, 0.71 m, of the outline: 0.68 m max, p95 0.33 m measured); regularised onto
    # the mean line of the boundary around it, max 0.45 m, p95 0.23 m.
    assert d.max() <= 0.5 and np.percentile(d, 95) <= 0.28
    assert walls[:, 2].min() >= -0.05 and walls[:, 2].max() <= ROOF_Z + 0.05
    # Complete: every sample of the true walls (10 cm grid over the four faces, 0.2-5.8 m high) has a
    # wall point within 0.5 m.
    samples = []
    for sx, sy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        t = np.linspace(-1, 1, 200)
        uv = np.column_stack([np.full_like(t, sx * HALF[0]) if sx else t * HALF[0],
                              np.full_like(t, sy * HALF[1]) if sy else t * HALF[1]])
        samples.append(_from_house(uv))
    xy = np.concatenate(samples)
    zs = np.linspace(0.2, 5.8, 29)
    true = np.column_stack([np.repeat(xy, len(zs), axis=0), np.tile(zs, len(xy))])
    from scipy.spatial import cKDTree

    gap, _ = cKDTree(walls).query(true)
    assert gap.max() <= 0.5


def test_eaves_inset_moves_walls_in_along_their_normal(cloud: tuple[Path, np.ndarray]) -> None:
    path, _ = cloud
    med = {}
    for eave in (0.0, 0.25, 0.5):
        aug = augment([path], CompleteOptions(eave_m=eave))
        walls = aug.xyz[aug.kind == KIND_WALL] - [X0, Y0, 0]
        med[eave] = float(np.median(_signed_distance(walls[:, :2])))
    # The house's outline is the rectangle: the inset shows as the signed distance's shift, by the inset.
    assert abs((med[0.0] - med[0.25]) - 0.25) <= 0.05 and abs((med[0.0] - med[0.5]) - 0.5) <= 0.05


def test_wall_normals_point_out_of_the_house(cloud: tuple[Path, np.ndarray]) -> None:
    path, _ = cloud
    aug = augment([path])
    sel = aug.kind == KIND_WALL
    p = aug.xyz[sel, :2] - [X0, Y0]
    n = aug.normals[sel]
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5) and np.all(n[:, 2] == 0)
    # The true outward normal of the nearest face, in the house frame.
    uv = _to_house(p)
    face_x = np.abs(uv[:, 0]) - HALF[0] > np.abs(uv[:, 1]) - HALF[1]
    nu = np.where(face_x, np.sign(uv[:, 0]), 0.0)
    nv = np.where(face_x, 0.0, np.sign(uv[:, 1]))
    c, s = math.cos(ANGLE), math.sin(ANGLE)
    true = np.column_stack([c * nu - s * nv, s * nu + c * nv])
    cos = np.sum(n[:, :2] * true, axis=1)
    # Which face is nearest is ambiguous within a cell diagonal of a corner: judged away from them.
    corner = np.min(np.hypot(np.abs(uv[:, 0:1]) - HALF[0], np.abs(uv[:, 1:2]) - HALF[1]), axis=1) < 0.75
    assert np.all(cos[~corner] > 0)  # never inwards
    assert np.percentile(cos, 50) > math.cos(math.radians(20))  # boundary direction, not the grid's


def test_ground_fills_under_the_canopy_only(cloud: tuple[Path, np.ndarray]) -> None:
    path, pts = cloud
    aug = augment([path])
    g = aug.xyz[aug.kind == KIND_GROUND] - [X0, Y0, 0]
    r = np.hypot(*(g[:, :2] - TREE).T)
    assert np.all(r <= TREE_R + 0.75)  # a cell beyond the crown at most
    assert np.all(np.abs(g[:, 2]) <= 0.01)  # the flat ground, interpolated
    # At the density of the real ground (points per m² within 25 %).
    real = np.sum(pts[:, 3] == 2) / (40 * 40 - 4 * HALF.prod() - np.pi * TREE_R ** 2)
    added = np.sum(r <= TREE_R - 0.5) / (np.pi * (TREE_R - 0.5) ** 2)
    assert abs(added / real - 1.0) <= 0.25
    assert np.all(_house_distance(g[:, :2]) > 0.5)  # nothing under the house


def test_build_flags_added_points_and_keeps_input(cloud: tuple[Path, np.ndarray], tmp_path: Path) -> None:
    path, pts = cloud
    out = tmp_path / "ts"
    # workers=0 and small chunks: the out-of-core path (parked segments, several chunks), in this process.
    rep = build_points([path], out, crs="EPSG:28992", progress=False, workers=0, max_chunk_points=5_000,
                       complete=CompleteOptions(walls="points"))
    assert rep.chunks > 1
    aug = augment([path])
    assert "complete" in (rep.complete or "")
    ts = open_tileset(out)
    got, syn = [], []
    stack = [ts.root]
    while stack:
        t = stack.pop()
        stack.extend(t.children)
        if t.children or t.content_uri is None:
            continue
        c = t.load_content()
        p = c.points
        got.append(p.positions.astype(np.float64) + t.matrix[:3, 3])
        syn.append(p.extra.get("synthetic", np.zeros(len(p.positions), np.uint8)))
    xyz, flag = np.concatenate(got), np.concatenate(syn)
    assert len(xyz) == len(pts) + len(aug.xyz)
    assert int(flag.sum()) == len(aug.xyz)
    # The input as the file holds it (LAS quantum 1 mm), and only it, is unflagged; float32 in the tile
    # adds micrometres.
    from scipy.spatial import cKDTree

    back = laspy.read(str(path))
    theirs = np.column_stack([back.x - X0, back.y - Y0, back.z])
    mine = xyz[flag == 0] - [X0, Y0, 0]
    assert len(mine) == len(theirs)
    assert cKDTree(theirs).query(mine)[0].max() < 1e-4 and cKDTree(mine).query(theirs)[0].max() < 1e-4
    assert not list(tmp_path.rglob("*.las"))  # the added points' scratch file went with the build folder


def test_quads_become_a_walls_tile(cloud: tuple[Path, np.ndarray], tmp_path: Path) -> None:
    path, _ = cloud
    out = tmp_path / "ts"
    build_points([path], out, crs="EPSG:28992", progress=False, workers=0, complete=CompleteOptions(walls="quads"))
    doc = json.loads((out / "tileset.json").read_text())
    kids = doc["root"]["children"]
    walls = [k for k in kids if k.get("extras", {}).get("walls")]
    assert len(walls) == 1 and walls[0]["extras"]["quads"] > 0
    ts = open_tileset(out)
    tile = next(t for t in ts.root.children if t.content_uri and "walls" in t.content_uri)
    mesh = tile.load_content().meshes[0]
    v = mesh.positions.astype(np.float64) + tile.matrix[:3, 3]
    tri = v[mesh.faces.astype(np.int64)]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    mid = tri.mean(axis=1)[:, :2] - [X0, Y0]
    # Faces wind counter-clockwise seen from outside: a step along the winding's normal leaves the house.
    step = 0.05 * n[:, :2] / np.linalg.norm(n[:, :2], axis=1, keepdims=True)
    uv = _to_house(mid)
    corner = np.min(np.hypot(np.abs(uv[:, 0:1]) - HALF[0], np.abs(uv[:, 1:2]) - HALF[1]), axis=1) < 0.75
    out_ = _signed_distance(mid + step) > _signed_distance(mid - step)
    assert np.all(out_[~corner]), np.c_[uv, n[:, :2]][~corner & ~out_]
    assert np.allclose(n[:, 2], 0.0, atol=1e-6)


def test_unclassified_input_warns_and_adds_nothing(tmp_path: Path) -> None:
    path = tmp_path / "raw.las"
    pts = scene(path, classified=False)
    with pytest.warns(UserWarning, match="no ground"):
        aug = augment([path])
    assert len(aug.xyz) == 0 and aug.skipped
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rep = build_points([path], tmp_path / "ts", crs="EPSG:28992", progress=False, workers=0,
                           complete=CompleteOptions())
    assert rep.points == len(pts) and "skipped" in (rep.complete or "")


def test_cli_complete(cloud: tuple[Path, np.ndarray], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from citylod.cli import main

    path, _ = cloud
    rc = main(["build", "points", str(path), "-o", str(tmp_path / "ts"), "--crs", "EPSG:28992", "--workers", "0",
               "--complete", "--no-ground-fill"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "complete" in text and "0 ground points" in text and "roof points" not in text
    # --roof-fill: the cells of the roof the random sampling left empty get roof points.
    assert main(["build", "points", str(path), "-o", str(tmp_path / "ts2"), "--crs", "EPSG:28992", "--workers",
                 "0", "--complete", "--no-ground-fill", "--roof-fill"]) == 0
    assert "roof points in gaps" in capsys.readouterr().out


def test_cli_eaves_moves_the_walls(cloud: tuple[Path, np.ndarray], tmp_path: Path) -> None:
    """``--eaves M``: the walls of the built tileset (its synthetic points above the ground) stand M further
    in than with ``--eaves 0`` (this house has no eaves: 0 puts them on its outline)."""
    from citylod.cli import main

    path, _ = cloud
    med = {}
    for eaves in ("0", "0.5"):
        out = tmp_path / f"ts{eaves}"
        assert main(["build", "points", str(path), "-o", str(out), "--crs", "EPSG:28992", "--workers", "0",
                     "--complete", "--no-ground-fill", "--eaves", eaves]) == 0
        xyz = []
        stack = [open_tileset(out).root]
        while stack:
            t = stack.pop()
            stack.extend(t.children)
            if t.children or t.content_uri is None:
                continue
            p = t.load_content().points
            syn = p.extra.get("synthetic", np.zeros(len(p.positions), np.uint8)) > 0
            xyz.append(p.positions[syn].astype(np.float64) + t.matrix[:3, 3])
        walls = np.concatenate(xyz) - [X0, Y0, 0]
        walls = walls[walls[:, 2] > 0.5]
        med[eaves] = float(np.median(_signed_distance(walls[:, :2])))
    assert abs(med["0"]) <= 0.15 and abs((med["0"] - med["0.5"]) - 0.5) <= 0.06


def test_degrees_are_not_completed(cloud: tuple[Path, np.ndarray], tmp_path: Path) -> None:
    # The same file read as degrees: a 0.5-"unit" grid would be half a degree; nothing is added, and
    # the warning says why.
    path, pts = cloud
    with pytest.warns(UserWarning, match="degrees"):
        rep = build_points([path], tmp_path / "ts", crs="EPSG:4326", progress=False, workers=0,
                           complete=CompleteOptions())
    assert rep.points == len(pts) and "degrees" in (rep.complete or "")


def test_an_area_too_large_for_the_grid_is_refused(tmp_path: Path) -> None:
    from citylod.core.errors import InputError
    from citylod.lod.build.complete import scan_grid

    with pytest.raises(InputError, match="cells"):
        scan_grid([tmp_path / "x.las"], np.array([0.0, 0.0]), np.array([100_000.0, 100_000.0]), 0.5)


# ------------------------------------------------------------------------------ footprints
INSET = 0.4  # the footprint lies this far inside the roof's outline: the roof overhangs it (eaves)


def _write_footprints(path: Path, half: np.ndarray) -> None:
    """An OGR SQLite file (as the BGT ships) with one polygon: the house's rectangle of half extents
    ``half``, in RD New coordinates."""
    import sqlite3

    import shapely

    corners = _from_house(np.array([[-1, -1], [1, -1], [1, 1], [-1, 1], [-1, -1]]) * half) + [X0, Y0]
    conn = sqlite3.connect(path)
    conn.execute("CREATE TABLE geometry_columns (f_table_name VARCHAR, f_geometry_column VARCHAR, "
                 "geometry_type INTEGER, coord_dimension INTEGER, srid INTEGER, geometry_format VARCHAR)")
    conn.execute("INSERT INTO geometry_columns VALUES ('pand', 'GEOMETRY', 3, 2, 28992, 'WKB')")
    conn.execute("CREATE TABLE pand (ogc_fid INTEGER PRIMARY KEY, GEOMETRY BLOB)")
    conn.execute("INSERT INTO pand (GEOMETRY) VALUES (?)", (shapely.to_wkb(shapely.Polygon(corners)),))
    conn.commit()
    conn.close()


def test_footprint_walls_stand_on_the_footprint(cloud: tuple[Path, np.ndarray], tmp_path: Path) -> None:
    path, _ = cloud
    fp = tmp_path / "pand.sqlite"
    _write_footprints(fp, HALF - INSET)
    aug = augment([path], CompleteOptions(footprints=str(fp)))
    walls = aug.xyz[aug.kind == KIND_WALL] - [X0, Y0, 0]
    # Distance to the footprint's outline, from the rectangle (not from the augmentation).
    uv = np.abs(_to_house(walls[:, :2]))
    inner = HALF - INSET
    out = np.hypot(np.maximum(uv[:, 0] - inner[0], 0), np.maximum(uv[:, 1] - inner[1], 0))
    d = np.where(np.all(uv <= inner, axis=1), np.min(inner - uv, axis=1), out)
    assert len(walls) > 0 and d.max() <= 0.01
    assert walls[:, 2].min() >= -0.05 and walls[:, 2].max() <= ROOF_Z + 0.05
    # From the roof edge alone the walls stand about INSET outside the footprint: the option moves them.
    plain = augment([path], CompleteOptions(eave_m=0.0))
    pw = plain.xyz[plain.kind == KIND_WALL] - [X0, Y0, 0]
    uv = np.abs(_to_house(pw[:, :2]))
    assert np.median(np.max(uv - inner, axis=1)) > 0.25


@pytest.mark.parametrize("walls", ["points", "quads"])  # quads are computed on a thread: read first
def test_bad_footprint_file_is_one_line_exit_2(cloud: tuple[Path, np.ndarray], tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str], walls: str) -> None:
    from citylod.cli import main

    path, _ = cloud
    bad = tmp_path / "pand.gpkg"
    bad.write_bytes(b"not a database" * 100)
    rc = main(["build", "points", str(path), "-o", str(tmp_path / "ts"), "--crs", "EPSG:28992",
               "--complete", walls, "--footprints", str(bad)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "pand.gpkg" in err and "Traceback" not in err, err
    assert not (tmp_path / "ts").exists()


def test_in_memory_build_completes_from_its_own_decode(cloud: tuple[Path, np.ndarray], tmp_path: Path) -> None:
    """The in-memory build (default for a small cloud) completes the records it decoded: the same added
    points as the out-of-core pre-pass, flagged, with the input unchanged."""
    path, pts = cloud
    rep = build_points([path], tmp_path / "ts", crs="EPSG:28992", progress=False,
                       complete=CompleteOptions(walls="points"))
    assert rep.chunks == 1
    aug = augment([path])
    ts = open_tileset(tmp_path / "ts")
    n = syn = 0
    for t in ts.walk():
        if t.children or t.content_uri is None:
            continue
        p = t.load_content().points
        n += len(p.positions)
        syn += int(p.extra.get("synthetic", np.zeros(0, np.uint8)).sum())
    assert n == len(pts) + len(aug.xyz) and syn == len(aug.xyz)


def _wall_corners(out: Path) -> np.ndarray:
    """Every wall tile's vertices, in the source CRS, sorted by rows."""
    ts = open_tileset(out)
    parts = [t.load_content().meshes[0].positions.astype(np.float64) + t.matrix[:3, 3]
             for t in ts.root.children if t.content_uri and "walls" in t.content_uri]
    v = np.concatenate(parts)
    return v[np.lexsort(v.T[::-1])]


def test_in_memory_quads_on_their_thread_match_the_pre_pass(cloud: tuple[Path, np.ndarray], tmp_path: Path) -> None:
    """The in-memory build computes and writes the wall quads on a thread of their own while it builds the
    octree: the same wall tiles as the out-of-core build's pre-pass, which computes them first, in line."""
    path, _ = cloud
    fp = tmp_path / "pand.sqlite"
    _write_footprints(fp, HALF - INSET)
    opts = CompleteOptions(walls="quads", footprints=str(fp))
    mem = build_points([path], tmp_path / "mem", crs="EPSG:28992", progress=False, complete=opts)
    pre = build_points([path], tmp_path / "pre", crs="EPSG:28992", progress=False, workers=0, complete=opts)
    quads = [r.complete.split(", ")[2] for r in (mem, pre) if r.complete]  # "N wall quads"
    assert len(quads) == 2 and quads[0] == quads[1] and quads[0].endswith("wall quads")
    a, b = _wall_corners(tmp_path / "mem"), _wall_corners(tmp_path / "pre")
    assert len(a) > 0 and a.shape == b.shape and np.allclose(a, b, atol=1e-3)
    doc = json.loads((tmp_path / "mem" / "tileset.json").read_text())
    assert doc["extras"]["citylod"]["complete"]["quads"] == len(a) // 4


def test_an_error_computing_quads_on_their_thread_is_raised_when_waited_for(
        cloud: tuple[Path, np.ndarray], monkeypatch: pytest.MonkeyPatch) -> None:
    from citylod.lod.build import complete as mod

    path, _ = cloud
    meta_lo, meta_hi = np.array([X0, Y0]), np.array([X0 + 40.0, Y0 + 40.0])
    grid = mod.scan_grid([path], meta_lo, meta_hi, 0.5)

    def broken(*args: object, **kwargs: object) -> None:
        raise RuntimeError("walls failed")

    monkeypatch.setattr(mod, "wall_edges", broken)
    aug = mod.augment_grid(grid, CompleteOptions(walls="quads"), quads_later=True)
    assert aug.walls_pending is not None and len(aug.xyz) > 0  # the ground points are there already
    with pytest.raises(RuntimeError, match="walls failed"):
        aug.wait_walls()


def test_near_footprint_cells_asked_only_where_needed(cloud: tuple[Path, np.ndarray], tmp_path: Path) -> None:
    """``footprint_edges(where=...)`` answers for the cells asked about as for the whole grid, and a cell
    is near when its centre is within ``reach_m`` of the footprint (distance to the rectangle computed
    here; the buffer's arcs are polygons, hence the small tolerance)."""
    from citylod.io.footprints import read_footprints
    from citylod.lod.build import complete as mod

    path, _ = cloud
    fp = tmp_path / "pand.sqlite"
    _write_footprints(fp, HALF - INSET)
    polys = read_footprints(fp)
    grid = mod.scan_grid([path], np.array([X0, Y0]), np.array([X0 + 40.0, Y0 + 40.0]), 0.5)
    opts = CompleteOptions(walls="quads", footprints=str(fp))
    dtm = mod.terrain(grid)
    roof = mod._roof(grid, mod.building_mask(grid, opts))
    rng = np.random.default_rng(3)
    where = rng.random(grid.shape) < 0.3
    e_all, near_all = mod.footprint_edges(polys, grid, dtm, roof, opts, reach_m=1.5)
    e_some, near_some = mod.footprint_edges(polys, grid, dtm, roof, opts, reach_m=1.5, where=where)
    assert np.array_equal(near_some, near_all & where) and np.array_equal(e_all.x0, e_some.x0)
    xs, ys = grid.centers()
    cx, cy = np.meshgrid(xs, ys)
    uv = np.abs(_to_house(np.column_stack([cx.ravel() - X0, cy.ravel() - Y0])))
    d = np.hypot(*np.maximum(uv - (HALF - INSET), 0.0).T).reshape(grid.shape)
    assert near_all.sum() > 100
    assert np.all(d[near_all] <= 1.5 + 1e-9) and np.all(d[~near_all] >= 1.5 - 0.02)


@pytest.mark.realdata
def test_delft_walls_on_the_bgt_footprints() -> None:
    """Delft AHN3 with the BGT footprints: the walls the footprints place stand on their outlines (shapely's
    distance to the union's boundary), reach no higher than the scanned roof, and the roof-edge walls
    stand outside them by about the eaves (median within 0.1-0.5 m: docs/PERFORMANCE_LOG.md)."""
    import shapely

    from citylod.io.footprints import read_footprints
    from tests.paths import DELFT

    files = sorted(DELFT.glob("ahn3_cropped_*.laz"))
    if len(files) != 2 or not (DELFT / "bgt_pand.sqlite").is_file():
        pytest.skip(f"real data not found in {DELFT}")
    union = shapely.union_all(read_footprints(DELFT / "bgt_pand.sqlite"))
    outline = union.boundary
    fp = augment(files, CompleteOptions(footprints=str(DELFT / "bgt_pand.sqlite")))
    w = fp.xyz[fp.kind == KIND_WALL]
    d = shapely.distance(outline, shapely.points(w[:, 0], w[:, 1]))
    on = d <= 0.01
    # Near the footprints every wall is on them (the roof-edge walls there are replaced); farther out are
    # the roof-edge walls of buildings the file does not cover (the points reach beyond the model's area).
    assert on[d <= 1.0].mean() >= 0.99 and on.sum() > 100_000
    assert np.all(np.isfinite(w)) and w[on, 2].max() <= 30.0
    plain = augment(files, CompleteOptions(eave_m=0.0))  # at the roof edge
    pw = plain.xyz[plain.kind == KIND_WALL]
    pts = shapely.points(pw[:, 0], pw[:, 1])
    dd = shapely.distance(outline, pts) * np.where(shapely.contains(union, pts), -1.0, 1.0)
    near = np.abs(dd) < 1.5
    assert 0.1 <= np.median(dd[near]) <= 0.5


# ------------------------------------------------------------------- a house of two heights, wide eaves
EAVES = 0.8  # the roof overhangs the footprint by this much
LOW_Z, HIGH_Z = 6.0, 10.0


def _two_level_scene(path: Path) -> None:
    """Ground at z = 0 and the house of :func:`scene` with its roof at LOW_Z for u < 0 and HIGH_Z for
    u >= 0 (a 4 m step across the middle, down to the eaves), ≈ 11 points/m²."""
    rng = np.random.default_rng(3)
    g = rng.uniform(0, 40, (40 * 40 * 11, 2))
    ground = g[~np.all(np.abs(_to_house(g)) <= HALF, axis=1)]
    uv = rng.uniform(-HALF, HALF, (int(4 * HALF.prod() * 11), 2))
    roof = np.column_stack([_from_house(uv), np.where(uv[:, 0] < 0, LOW_Z, HIGH_Z)])
    xyz = np.concatenate([np.column_stack([ground, np.zeros(len(ground))]), roof])
    _write(path, xyz, np.concatenate([np.full(len(ground), 2), np.full(len(roof), 6)]))


def _outside(xy: np.ndarray, half: np.ndarray) -> np.ndarray:
    """How far points lie outside the house-frame rectangle ±half (0 inside)."""
    uv = np.abs(_to_house(xy))
    return np.hypot(np.maximum(uv[:, 0] - half[0], 0), np.maximum(uv[:, 1] - half[1], 0))


def test_footprints_keep_roof_steps_out_of_the_eaves(tmp_path: Path) -> None:
    """The step between the two roofs runs on to the roof's edge, over the eaves; with footprints the
    step's wall stops at the footprint (within the half cell a cell edge reaches past its centre), where
    the facade is: beyond it, it would stand in front of the facade."""
    path, fp = tmp_path / "two.las", tmp_path / "pand.sqlite"
    _two_level_scene(path)
    inner = HALF - EAVES
    _write_footprints(fp, inner)
    for walls in ("points", "quads"):
        aug = augment([path], CompleteOptions(walls=walls, footprints=str(fp)))
        if walls == "points":
            step = aug.xyz[aug.kind == KIND_STEP, :2] - [X0, Y0]
        else:
            q = aug.quads - [X0, Y0, 0]
            is_step = q[:, 0, 2] > 1.0  # a step's quad stands on the lower roof; outer walls on the ground
            step = q[is_step][:, :, :2].reshape(-1, 2)
        assert len(step) > 0
        # At most half a cell diagonal (0.35 m) past the footprint; the eaves reach 0.8 m past it.
        assert _outside(step, inner).max() <= 0.36
        # ... and the step still spans the house, facade to facade.
        v = _to_house(step)[:, 1]
        assert v.min() <= -inner[1] + 0.5 and v.max() >= inner[1] - 0.5


def test_footprint_walls_where_the_roof_stops_short_of_the_footprint(tmp_path: Path) -> None:
    """A footprint reaching 0.6 m past the scanned roof on one side (the roof's edge returned nothing
    there): that side's wall takes its height from the roof further in instead of being left out."""
    path, fp = tmp_path / "scene.las", tmp_path / "pand.sqlite"
    scene(path)
    wide = HALF + np.array([0.6, 0.0])
    _write_footprints(fp, wide)
    aug = augment([path], CompleteOptions(footprints=str(fp)))
    w = aug.xyz[aug.kind == KIND_WALL] - [X0, Y0, 0]
    uv = _to_house(w[:, :2])
    side = np.abs(uv[:, 0] - wide[0]) <= 0.01  # on the footprint's side at u = +wide
    assert side.sum() > 100
    # Along that side (v in ±HALF[1]), every 0.5 m has wall points, up to the roof.
    bins = np.histogram(uv[side, 1], bins=16, range=(-HALF[1], HALF[1]))[0]
    assert np.all(bins > 0)
    assert np.allclose(w[side, 2].max(), ROOF_Z, atol=0.3)


def test_wall_quads_reach_below_the_terrain_steps_do_not(tmp_path: Path) -> None:
    path, fp = tmp_path / "two.las", tmp_path / "pand.sqlite"
    _two_level_scene(path)
    _write_footprints(fp, HALF - EAVES)
    for sink in (0.3, 0.0):
        aug = augment([path], CompleteOptions(walls="quads", footprints=str(fp), sink_m=sink))
        bottom = aug.quads[:, 0, 2]
        outer = bottom < 1.0
        assert outer.any() and (~outer).any()
        assert np.allclose(bottom[outer], -sink, atol=0.02)  # flat ground at 0
        # Steps end on the lower roof (a cell astride the step has a roof between the two), not below it.
        assert bottom[~outer].min() >= LOW_Z - 0.05 and abs(np.median(bottom[~outer]) - LOW_Z) <= 0.05


def test_roof_edge_quads_leave_no_slits(cloud: tuple[Path, np.ndarray]) -> None:
    """Along each face of the house (corners apart), the roof-edge wall quads that face it cover at least
    88 % of its length (seen along the face's normal: the union of the quads' extents along the face).
    Regularised parts that reached only their own part of the wall left 18-26 % open."""
    path, _ = cloud
    aug = augment([path], CompleteOptions(walls="quads", eave_m=0.0))
    q = aug.quads[:, [0, 1], :2] - [X0, Y0]
    uv = np.stack([_to_house(q[:, 0]), _to_house(q[:, 1])], axis=1)
    c, s = math.cos(ANGLE), math.sin(ANGLE)
    nrm = aug.quad_normals[:, :2]
    nuv = np.column_stack([c * nrm[:, 0] + s * nrm[:, 1], -s * nrm[:, 0] + c * nrm[:, 1]])
    for axis, sign in ((0, 1), (0, -1), (1, 1), (1, -1)):
        face = (nuv[:, axis] * sign > math.cos(math.radians(20))) & (
            np.abs(uv.mean(axis=1)[:, axis] - sign * HALF[axis]) < 0.7)
        lo, hi = np.sort(uv[face][:, :, 1 - axis], axis=1).T
        along = np.linspace(-HALF[1 - axis] + 0.75, HALF[1 - axis] - 0.75, 2000)
        covered = np.any((along[:, None] >= lo[None]) & (along[:, None] <= hi[None]), axis=1)
        assert covered.mean() >= 0.88, (axis, sign, covered.mean())


def test_roof_fill_closes_a_dark_patch_on_the_roof(tmp_path: Path) -> None:
    """A 2 m × 2 m patch of the flat roof returned nothing (a skylight): with ``roof_fill`` roof points fill
    it at the roof's height and about its density, flagged KIND_ROOF (class 6); without, none."""
    from citylod.lod.build.complete import KIND_ROOF

    pts = scene(tmp_path / "full.las")
    uv = _to_house(pts[:, :2])
    patch = (np.abs(uv[:, 0] - 2.0) <= 1.0) & (np.abs(uv[:, 1]) <= 1.0) & (pts[:, 3] == 6)
    path = tmp_path / "dark.las"
    _write(path, pts[~patch, :3], pts[~patch, 3])
    assert not np.any(augment([path]).kind == KIND_ROOF)
    aug = augment([path], CompleteOptions(roof_fill=True))
    roof = aug.kind == KIND_ROOF
    r = aug.xyz[roof] - [X0, Y0, 0]
    assert np.all(aug.classification[roof] == 6) and aug.counts["roof"] == int(roof.sum())
    ruv = _to_house(r[:, :2])
    # On the roof (within a cell diagonal of the house: the few cells the random sampling left empty get
    # points too, as the patch does) ...
    assert np.all(_outside(r[:, :2], HALF) <= 0.71) and np.allclose(r[:, 2], ROOF_Z, atol=0.02)
    # ... covering the patch: every 0.25 m of it has a point within 0.5 m ...
    g = np.stack(np.meshgrid(np.linspace(1.0, 3.0, 9), np.linspace(-1.0, 1.0, 9)), axis=-1).reshape(-1, 2)
    from scipy.spatial import cKDTree

    assert cKDTree(ruv).query(g)[0].max() <= 0.5
    # ... at about the roof's density (11 points/m²) over the cells the patch empties: 4 m² to (2 + 1)² m².
    inside = (np.abs(ruv[:, 0] - 2.0) <= 1.5) & (np.abs(ruv[:, 1]) <= 1.5)
    assert 4.0 * 11 * 0.7 <= inside.sum() <= 9.0 * 11 * 1.3
    # Nothing else changed: the same walls as without.
    plain = augment([path])
    assert np.array_equal(plain.xyz[plain.kind == KIND_WALL], aug.xyz[aug.kind == KIND_WALL])


# ------------------------------------------------------------------------------ a gabled house
PITCH = math.radians(40.0)
GABLE_EAVES = 0.5  # the roof overhangs the footprint by this much on every side


def _gable_z(uv: np.ndarray) -> np.ndarray:
    """The gabled roof's height over house-frame points: the ridge along u, down to ROOF_Z at the eaves."""
    return ROOF_Z + math.tan(PITCH) * (HALF[1] - np.abs(uv[:, 1]))


def _gable_scene(path: Path) -> None:
    """Ground at z = 0 and the house of :func:`scene` under a gabled roof (ridge along its long axis,
    40° pitch, ≈ 11 points/m² on the ground plan, 2 cm range noise)."""
    rng = np.random.default_rng(5)
    g = rng.uniform(0, 40, (40 * 40 * 11, 2))
    ground = g[~np.all(np.abs(_to_house(g)) <= HALF, axis=1)]
    uv = rng.uniform(-HALF, HALF, (int(4 * HALF.prod() * 11), 2))
    roof = np.column_stack([_from_house(uv), _gable_z(uv) + rng.normal(0, 0.02, len(uv))])
    xyz = np.concatenate([np.column_stack([ground, np.zeros(len(ground))]), roof])
    _write(path, xyz, np.concatenate([np.full(len(ground), 2), np.full(len(roof), 6)]))


def test_footprint_wall_tops_follow_a_gabled_roof(tmp_path: Path) -> None:
    """On the gable ends the roof rises along the wall, 0.84 m per metre. The footprint quads' top edge,
    sampled every 2 cm along each gable (corners and ridge ±0.5 m apart), lies within 0.2 m of the roof
    above the wall's line (the roof's formula), 0.06 m in the median; the wall points reach the roof
    without rising above it. One level top per 0.5 m piece (the cell's mean) left a sawtooth: 0.43 m at
    most, 0.12 m in the median."""
    path, fp = tmp_path / "gable.las", tmp_path / "pand.sqlite"
    _gable_scene(path)
    inner = HALF - GABLE_EAVES
    _write_footprints(fp, inner)
    aug = augment([path], CompleteOptions(walls="quads", footprints=str(fp)))
    q = aug.quads - [X0, Y0, 0]
    bottom_uv = np.stack([_to_house(q[:, 0, :2]), _to_house(q[:, 1, :2])], axis=1)
    errs = []
    for sign in (1, -1):
        face = np.all(np.abs(bottom_uv[:, :, 0] - sign * inner[0]) < 0.01, axis=1) & (q[:, 0, 2] < 1.0)
        assert face.sum() >= 12
        # Each quad's top edge runs from corner 3 (above corner 0) to corner 2 (above corner 1).
        v0, v1 = bottom_uv[face, 0, 1], bottom_uv[face, 1, 1]
        z0, z1 = q[face, 3, 2], q[face, 2, 2]
        for v in np.arange(-inner[1] + 0.5, inner[1] - 0.5, 0.02):
            if abs(v) < 0.5:
                continue
            k = np.flatnonzero((np.minimum(v0, v1) <= v) & (v <= np.maximum(v0, v1)))
            assert len(k), v  # no gap along the gable
            t = (v - v0[k]) / (v1[k] - v0[k])
            top = z0[k] + t * (z1[k] - z0[k])
            errs.append(np.max(np.abs(top - _gable_z(np.array([[inner[0], v]]))[0])))
    assert max(errs) <= 0.2 and np.median(errs) <= 0.06, (max(errs), np.median(errs))
    pts = augment([path], CompleteOptions(walls="points", footprints=str(fp)))
    w = pts.xyz[pts.kind == KIND_WALL] - [X0, Y0, 0]
    uv = _to_house(w[:, :2])
    gable = (np.abs(np.abs(uv[:, 0]) - inner[0]) < 0.01) & (np.abs(uv[:, 1]) < inner[1] - 0.5) & (np.abs(uv[:, 1]) > 0.5)
    above = w[gable, 2] - _gable_z(uv[gable])
    assert gable.sum() > 500 and above.max() <= 0.12 and np.percentile(above, 99) >= -0.3


def test_roof_interpolation_is_exact_on_a_plane_and_leaves_out_cells_off_the_roof() -> None:
    """:func:`_roof_bilinear` at random points of a tilted plane roof equals the plane (the cell means sit
    at the cell centres); a point with one roof cell among its four takes that cell's height; one with
    none is NaN."""
    from citylod.lod.build.complete import CellGrid, _roof_bilinear

    grid = CellGrid(np.array([100.0, 200.0]), 0.5, np.zeros((14, 20, 30)), np.zeros(256), np.zeros(256))
    xs, ys = grid.centers()
    cx, cy = np.meshgrid(xs, ys)
    roof = 3.0 + 0.4 * (cx - 100.0) - 0.7 * (cy - 200.0)
    rng = np.random.default_rng(0)
    xy = np.column_stack([rng.uniform(xs[0], xs[-1], 500), rng.uniform(ys[0], ys[-1], 500)])
    assert np.allclose(_roof_bilinear(roof, grid, xy), 3.0 + 0.4 * (xy[:, 0] - 100.0) - 0.7 * (xy[:, 1] - 200.0))
    off = np.full_like(roof, np.nan)
    off[10, 10] = 7.0
    near = np.array([[xs[10] + 0.2, ys[10] + 0.1], [xs[10] - 0.2, ys[10] - 0.2]])  # cell (10, 10) among the four
    assert np.allclose(_roof_bilinear(off, grid, near), 7.0)
    assert np.isnan(_roof_bilinear(off, grid, np.array([[xs[20], ys[5]]]))[0])
