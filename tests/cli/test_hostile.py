"""Broken and hostile input through the command line: one line naming the file, exit 2, nothing left behind.

Every case runs ``citylod`` in a subprocess under a time-out and a memory cap set by the test harness
(tests/cli_harness.py), never by the product: a hang or unbounded growth fails the test.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from citylod.bench.synthetic import make_terrain_tileset
from citylod.core.camera import Camera
from tests.cli_harness import Result, assert_clean_refusal, run_cli, run_cli_batch
from tests.inputs import CORNER, write_las


def cube_cityjson() -> dict:
    """A 10 m cube near CORNER as a CityJSON 2.0 Solid, quantised, in EPSG:25832."""
    v = [[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0], [0, 0, 10], [10, 0, 10], [10, 10, 10], [0, 10, 10]]
    shell = [[[0, 3, 2, 1]], [[4, 5, 6, 7]], [[0, 1, 5, 4]], [[1, 2, 6, 5]], [[2, 3, 7, 6]], [[3, 0, 4, 7]]]
    return {"type": "CityJSON", "version": "2.0",
            "transform": {"scale": [1.0, 1.0, 1.0], "translate": [CORNER[0] + 500, CORNER[1] + 500, 0.0]},
            "metadata": {"referenceSystem": "https://www.opengis.net/def/crs/EPSG/0/25832"},
            "CityObjects": {"B": {"type": "Building", "geometry": [{"type": "Solid", "lod": "2",
                                                                    "boundaries": [shell]}]}},
            "vertices": v}


def _mutate(doc: dict, path: str, value: object) -> dict:
    doc = json.loads(json.dumps(doc))
    node = doc
    keys = path.split("/")
    for k in keys[:-1]:
        node = node[int(k)] if isinstance(node, list) else node[k]
    last = keys[-1]
    if isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value
    return doc


GEOM = "CityObjects/B/geometry/0"
HOSTILE_CITYJSON: dict[str, object] = {
    "objects_list": _mutate(cube_cityjson(), "CityObjects", [{"type": "Building"}]),
    "scalar_boundaries": _mutate(cube_cityjson(), f"{GEOM}/boundaries", 7),
    "geometry_dict": _mutate(cube_cityjson(), "CityObjects/B/geometry", {"type": "Solid"}),
    "string_scale": _mutate(cube_cityjson(), "transform/scale", "1,1,1"),
    "index_1e30": _mutate(cube_cityjson(), f"{GEOM}/boundaries/0/0/0/0", 10**30),
    "index_negative": _mutate(cube_cityjson(), f"{GEOM}/boundaries/0/0/0/0", -1),
    "index_fraction": _mutate(cube_cityjson(), f"{GEOM}/boundaries/0/0/0/0", 1.5),
    "lod_string": _mutate(cube_cityjson(), f"{GEOM}/lod", "two"),
    "vertex_string": _mutate(cube_cityjson(), "vertices/0", ["a", 0, 0]),
    "object_not_dict": _mutate(cube_cityjson(), "CityObjects/B", "Building"),
}


def _write_hostile_cityjson(folder: Path) -> list[Path]:
    paths = []
    for name, doc in HOSTILE_CITYJSON.items():
        p = folder / f"{name}.city.json"
        p.write_text(json.dumps(doc))
        paths.append(p)
    text = json.dumps(cube_cityjson())
    p = folder / "digits_5000.city.json"
    p.write_text(text.replace('"vertices": [[0, 0, 0]', '"vertices": [[' + "7" * 5000 + ", 0, 0]"))
    paths.append(p)
    p = folder / "nested_200k.city.json"
    p.write_text(text.replace('"CityObjects": {', '"deep": ' + "[" * 200_000 + "]" * 200_000 + ', "CityObjects": {'))
    paths.append(p)
    return paths


def _check_batch(results: list[Result], paths: list[Path], folder: Path) -> None:
    failures = []
    for p, r in zip(paths, results, strict=True):
        try:
            assert_clean_refusal(r, p.name, folder)
        except AssertionError as exc:
            failures.append(f"{p.name}: {exc}")
    assert not failures, "\n".join(failures)


def test_hostile_cityjson_is_refused_cleanly(tmp_path: Path) -> None:
    paths = _write_hostile_cityjson(tmp_path)
    out = tmp_path / "out" / "city.gpkg"
    results = run_cli_batch([["build", "city", p, "-o", out] for p in paths])
    _check_batch(results, paths, tmp_path)
    assert not out.exists() and not any(out.parent.glob("*")) if out.parent.exists() else True
    # Control: the unmutated document builds.
    good = tmp_path / "good.city.json"
    good.write_text(json.dumps(cube_cityjson()))
    r = run_cli(["build", "city", good, "-o", out])
    assert r.returncode == 0 and out.exists(), r.stderr


# --- tilesets -------------------------------------------------------------------------------------------

def _tile(children: list | None = None, uri: str | None = None) -> dict:
    t: dict = {"boundingVolume": {"box": [0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1]}, "geometricError": 1.0}
    if uri is not None:
        t["content"] = {"uri": uri}
    if children:
        t["children"] = children
    return t


def _tileset(root: dict) -> str:
    return json.dumps({"asset": {"version": "1.1"}, "geometricError": 10.0, "root": root})


def _hostile_tilesets(folder: Path) -> list[Path]:
    out = []
    deep = folder / "deep"
    deep.mkdir()
    # 5000 levels: build the JSON text directly (json.dumps of it would itself recurse too deeply).
    leaf = json.dumps(_tile())
    head, tail = leaf[:-1] + ', "children": [', "]}"
    (deep / "tileset.json").write_text('{"asset": {"version": "1.1"}, "geometricError": 10, "root": '
                                       + head * 5000 + leaf + tail * 5000 + "}")
    out.append(deep / "tileset.json")
    # A tileset with 70 levels (JSON shallow enough to parse): refused by the level limit.
    d70 = folder / "levels70"
    d70.mkdir()
    (d70 / "tileset.json").write_text('{"asset": {"version": "1.1"}, "geometricError": 10, "root": '
                                      + head * 70 + leaf + tail * 70 + "}")
    out.append(d70 / "tileset.json")
    nul = folder / "nul"
    nul.mkdir()
    (nul / "tileset.json").write_text(_tileset(_tile(uri="tiles/a\u0000.glb")))
    out.append(nul / "tileset.json")
    # Nine external tilesets, eight children each pointing at the next: 8^9 tiles if expanded.
    chain = folder / "chain"
    chain.mkdir()
    for k in range(9):
        nxt = f"t{k + 1}.json" if k < 8 else None
        children = [_tile(uri=nxt) for _ in range(8)] if nxt else None
        (chain / ("tileset.json" if k == 0 else f"t{k}.json")).write_text(_tileset(_tile(children)))
    out.append(chain / "tileset.json")
    selfref = folder / "self"
    selfref.mkdir()
    (selfref / "tileset.json").write_text(_tileset(_tile([_tile(uri="other.json")])))
    (selfref / "other.json").write_text(_tileset(_tile([_tile(uri="tileset.json")])))
    out.append(selfref / "tileset.json")
    bad_error = folder / "baderror"
    bad_error.mkdir()
    (bad_error / "tileset.json").write_text(_tileset(_tile() | {"geometricError": "big"}))
    out.append(bad_error / "tileset.json")
    return out


def test_hostile_tilesets_are_refused_cleanly(tmp_path: Path) -> None:
    paths = _hostile_tilesets(tmp_path)
    results = run_cli_batch([["info", p] for p in paths], timeout_s=60)
    # The line names the tileset file where the problem is (in the chain, the external one that refers on).
    for p, r in zip(paths, results, strict=True):
        assert_clean_refusal(r, f"/{p.parent.name}/", tmp_path)
    msgs = {p.parent.name: r.stderr for p, r in zip(paths, results, strict=True)}
    assert "refers to itself" in msgs["self"] and "other.json -> tileset.json" in msgs["self"]
    assert "NUL" in msgs["nul"] and "64 levels" in msgs["levels70"]
    assert "referenced" in msgs["chain"]


# --- render ---------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def terrain(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("render")
    ts = make_terrain_tileset(folder / "ts", levels=2, n=9, corner=CORNER, texture_px=None)
    cam = folder / "cam.json"
    Camera((CORNER[0] + 512, CORNER[1] + 512, 900.0), (CORNER[0] + 512, CORNER[1] + 512, 0.0),
           (0.0, 1.0, 0.0)).save(cam)
    return ts, cam


def test_render_refuses_garbage_cameras_and_broken_tiles(tmp_path: Path, terrain: tuple[Path, Path]) -> None:
    import shutil

    ts, cam = terrain
    cams = {
        "binary.json": b"\xff\xfe\x00garbage",
        "nested.json": b"[" * 100_000 + b"]" * 100_000,
        "digits.json": b'{"position": [' + b"9" * 5000 + b', 0, 0], "focal_point": [0, 0, 0]}',
        "zero_up.json": json.dumps({"position": [0, 0, 1], "focal_point": [0, 0, 0], "view_up": [0, 0, 0]}).encode(),
        "nan.json": b'{"position": [NaN, 0, 1], "focal_point": [0, 0, 0]}',
        "strings.json": b'{"position": "abc", "focal_point": [0, 0, 0]}',
        "number.json": b"42",
    }
    argvs, names = [], []
    for name, data in cams.items():
        (tmp_path / name).write_bytes(data)
        argvs.append(["render", ts, "-o", tmp_path / "o.png", "--camera", tmp_path / name, "--size", "64x48"])
        names.append(name)
    missing = tmp_path / "missing"
    shutil.copytree(ts, missing)
    next((missing / "tiles").rglob("*.glb")).unlink()
    truncated = tmp_path / "truncated"
    shutil.copytree(ts, truncated)
    for f in (truncated / "tiles").rglob("*.glb"):
        f.write_bytes(f.read_bytes()[:100])
    for folder in (missing, truncated):
        argvs.append(["render", folder, "-o", tmp_path / "o.png", "--camera", cam, "--size", "64x48",
                      "--tau", "0.05"])
        names.append(".glb")
    results = run_cli_batch(argvs, timeout_s=180)
    for name, r in zip(names, results, strict=True):
        assert_clean_refusal(r, name, tmp_path)
    assert not (tmp_path / "o.png").exists()


def test_render_highlight_with_recursive_cte_stops(tmp_path: Path, terrain: tuple[Path, Path]) -> None:
    ts, cam = terrain
    city = tmp_path / "c.city.json"
    city.write_text(json.dumps(cube_cityjson()))
    store = tmp_path / "city.gpkg"
    assert run_cli(["build", "city", city, "-o", store]).returncode == 0
    forever = "object_id IN (WITH RECURSIVE c(x) AS (SELECT 1 UNION ALL SELECT x + 1 FROM c) SELECT x FROM c)"
    r = run_cli(["render", ts, "-o", tmp_path / "o.png", "--camera", cam, "--size", "64x48", "--city", store,
                 "--highlight", forever], timeout_s=90)
    assert_clean_refusal(r, "city.gpkg", tmp_path)
    assert "longer than" in r.stderr and not (tmp_path / "o.png").exists()


# --- point clouds ---------------------------------------------------------------------------------------

def _las(path: Path, n: int) -> Path:
    return write_las(path, n, x0=CORNER[0] + 495, y0=CORNER[1] + 495)


def test_broken_point_clouds_are_refused_by_link_and_build(tmp_path: Path) -> None:
    city = tmp_path / "c.city.json"
    city.write_text(json.dumps(cube_cityjson()))
    store = tmp_path / "city.gpkg"
    assert run_cli(["build", "city", city, "-o", store]).returncode == 0
    good_laz = _las(tmp_path / "good.laz", 5000)
    data = good_laz.read_bytes()
    (tmp_path / "truncated.laz").write_bytes(data[: len(data) * 2 // 3])
    (tmp_path / "header_only.laz").write_bytes(_las(tmp_path / "h.laz", 0).read_bytes())
    (tmp_path / "h.laz").unlink()
    las = _las(tmp_path / "g.las", 3000).read_bytes()
    (tmp_path / "g.las").unlink()
    (tmp_path / "claims_more.las").write_bytes(las[: len(las) - 1000 * 28])  # point format 1: 28 bytes a point
    (tmp_path / "garbage.laz").write_bytes(b"LASF" + bytes(range(256)) * 2)
    bad = ["truncated.laz", "header_only.laz", "claims_more.las", "garbage.laz"]
    out = tmp_path / "out"
    out.mkdir()
    argvs = [["link", store, tmp_path / b, "-o", out / "linked.laz"] for b in bad]
    argvs += [["build", "points", tmp_path / b, "-o", out / "pts", "--workers", "0"] for b in bad]
    results = run_cli_batch(argvs, timeout_s=240)
    for name, r in zip(bad + bad, results, strict=True):
        assert_clean_refusal(r, name, out)
    assert sorted(p.name for p in out.iterdir()) == []
    # The claimed and held counts in the message are the file's: 3000 claimed, 2000 there.
    claims = [r.stderr for name, r in zip(bad + bad, results, strict=True) if name == "claims_more.las"]
    assert all("2,000" in m and "3,000" in m for m in claims), claims
    # Control: the intact file links.
    r = run_cli(["link", store, good_laz, "-o", out / "linked.laz"])
    assert r.returncode == 0 and "of 5,000 points" in r.stdout, r.stderr


# --- rasters --------------------------------------------------------------------------------------------

def test_degenerate_and_mislabelled_rasters_leave_nothing(tmp_path: Path) -> None:
    import rasterio
    from rasterio.transform import from_origin

    def raster(name: str, h: int, w: int, crs: str = "EPSG:25832") -> Path:
        p = tmp_path / name
        with rasterio.open(p, "w", driver="GTiff", width=w, height=h, count=1, dtype="float32", crs=crs,
                           transform=from_origin(CORNER[0], CORNER[1], 1.0, 1.0)) as ds:
            ds.write(np.ones((1, h, w), np.float32))
        return p

    paths = [raster("one_by_n.tif", 1, 40), raster("n_by_one.tif", 40, 1), raster("one.tif", 1, 1),
             raster("metres_in_degrees.tif", 40, 40, crs="EPSG:4326")]
    out = tmp_path / "out"
    out.mkdir()
    results = run_cli_batch([["build", "dsm", p, "-o", out / "ts", "--workers", "0"] for p in paths])
    _check_batch(results, paths, out)
    assert list(out.iterdir()) == []
