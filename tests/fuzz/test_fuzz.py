"""Seeded fuzzing of every reader: a mutated valid input gives a clean CitylodError or a valid result.

Each reader gets ``CASES`` mutations of a small valid input (byte flips, cuts, repeats and insertions; for
JSON also structure-aware replacements with hostile values), from a fixed seed so a failure reproduces.
Anything but a :class:`~citylod.core.errors.CitylodError` fails, as does a case running longer than
``CASE_LIMIT_S`` (an interval timer interrupts it). The failing input is written next to the report.
"""

from __future__ import annotations

import copy
import json
import os
import random
import shutil
import signal
import struct
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from citylod.core.camera import Camera, load_cameras
from citylod.core.errors import CitylodError
from tests.inputs import write_las

# Cases per reader: 25 in CI (the whole file runs in a few seconds); set CITYLOD_FUZZ_CASES for a deeper run.
CASES = int(os.environ.get("CITYLOD_FUZZ_CASES", "25"))
CASE_LIMIT_S = 10.0
SEED = 20261202

HOSTILE_VALUES: list[Any] = [
    None, True, -1, 0, 1.5, -1e308, 1e308, 10**30, "", "x" * 1000, "NaN", [], {}, [[[]]], {"a": {}},
    [1, 2], [-1, -1, -1], "urn:ogc:def:crs:EPSG:6.12:25833", "tiles/\u0000.glb", "../../etc/passwd", 2**63,
]


class _Hang(BaseException):
    """Raised by the interval timer; a BaseException, so no reader's ``except Exception`` swallows it."""


@contextmanager
def _time_limit(seconds: float) -> Iterator[None]:
    def on_alarm(signum: int, frame: Any) -> None:
        raise _Hang(f"no answer within {seconds} s")

    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


# --- mutations ------------------------------------------------------------------------------------------

def mutate_bytes(data: bytes, rng: random.Random) -> bytes:
    b = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        op = rng.randrange(5)
        if not b:
            b += bytes([rng.randrange(256)])
            continue
        i = rng.randrange(len(b))
        if op == 0:  # flip bytes
            for k in range(i, min(len(b), i + rng.randint(1, 8))):
                b[k] = rng.randrange(256)
        elif op == 1:  # cut the end
            del b[i:]
        elif op == 2:  # repeat a slice
            j = min(len(b), i + rng.randint(1, 64))
            b[i:i] = b[i:j] * rng.randint(1, 50)
        elif op == 3:  # insert random bytes
            b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 16)))
        else:  # extreme integers in binary headers
            val = rng.choice([0, 1, 0xFFFFFFFF, 0x7FFFFFFF, 0x80000000])
            b[i:i + 4] = struct.pack("<I", val)[: len(b[i:i + 4])]
    return bytes(b)


def _nodes(doc: Any, path: tuple = ()) -> Iterator[tuple]:
    yield path
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _nodes(v, (*path, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _nodes(v, (*path, i))


def mutate_json(doc: Any, rng: random.Random) -> Any:
    doc = json.loads(json.dumps(doc))
    for _ in range(rng.randint(1, 3)):
        paths = [p for p in _nodes(doc) if p]
        if not paths:
            break
        path = rng.choice(paths)
        parent = doc
        for k in path[:-1]:
            parent = parent[k]
        op = rng.randrange(4)
        if op == 0 or not isinstance(parent, (dict, list)):
            parent[path[-1]] = copy.deepcopy(rng.choice(HOSTILE_VALUES))
        elif op == 1 and isinstance(parent, dict):
            del parent[path[-1]]
        elif op == 2:
            parent[path[-1]] = [parent[path[-1]]] * rng.randint(2, 5)  # wrap or repeat
        else:
            v = parent[path[-1]]
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                parent[path[-1]] = rng.choice([-v, v * 1e300, v + 0.5, int(v) + 2**40, -1])
            else:
                parent[path[-1]] = copy.deepcopy(rng.choice(HOSTILE_VALUES))
    return doc


def mutated_text(doc: Any, rng: random.Random) -> bytes:
    """A JSON document mutated by structure (two thirds of the cases) or by bytes."""
    if rng.random() < 0.67:
        return json.dumps(mutate_json(doc, rng)).encode()
    return mutate_bytes(json.dumps(doc).encode(), rng)


# --- the harness ----------------------------------------------------------------------------------------

def fuzz(name: str, tmp: Path, make_case: Callable[[random.Random, int], Path | Any],
         check: Callable[[Any], None]) -> None:
    """Run ``CASES`` cases; fail with every case that raised something else than a CitylodError or hung."""
    rng = random.Random(f"{SEED}-{name}")
    failures = []
    for i in range(CASES):
        case = make_case(rng, i)
        try:
            with _time_limit(CASE_LIMIT_S):
                check(case)
        except CitylodError:
            pass
        except (_Hang, Exception) as exc:
            failures.append(f"case {i} ({case}): {type(exc).__name__}: {exc}\n"
                            + "".join(traceback.format_exception(exc)[-3:]))
    assert not failures, f"{name}: {len(failures)} of {CASES} cases failed:\n" + "\n".join(failures[:5])


def _valid_model(model: Any) -> None:
    for o in model.objects:
        for poly in o.surfaces:
            for ring in poly:
                assert ring.ndim == 2 and ring.shape[1] == 3 and len(ring) >= 4 and np.isfinite(ring).all()
                assert np.array_equal(ring[0], ring[-1])
        assert len(o.semantics) == len(o.surfaces)


# --- seeds ----------------------------------------------------------------------------------------------

def cube_cityjson() -> dict:
    v = [[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0], [0, 0, 10], [10, 0, 10], [10, 10, 10], [0, 10, 10]]
    shell = [[[0, 3, 2, 1]], [[4, 5, 6, 7]], [[0, 1, 5, 4]], [[1, 2, 6, 5]], [[2, 3, 7, 6]], [[3, 0, 4, 7]]]
    return {"type": "CityJSON", "version": "2.0",
            "transform": {"scale": [0.5, 0.5, 0.5], "translate": [500000.0, 5400000.0, 0.0]},
            "metadata": {"referenceSystem": "https://www.opengis.net/def/crs/EPSG/0/25832"},
            "CityObjects": {
                "B": {"type": "Building", "children": ["P"], "attributes": {"measuredHeight": 5}},
                "P": {"type": "BuildingPart", "parents": ["B"], "geometry": [{
                    "type": "Solid", "lod": "2.2", "boundaries": [shell],
                    "semantics": {"surfaces": [{"type": "GroundSurface"}, {"type": "RoofSurface"}],
                                  "values": [[0, 1, None, None, None, None]]}}]},
                "T": {"type": "SolitaryVegetationObject", "geometry": [{
                    "type": "GeometryInstance", "template": 0, "boundaries": [2],
                    "transformationMatrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]}]},
            },
            "geometry-templates": {"templates": [{"type": "MultiSurface", "lod": 1, "boundaries": [[[0, 1, 2]]]}],
                                   "vertices-templates": [[0, 0, 0], [1, 0, 0], [0, 1, 2]]},
            "vertices": v}


CITYGML = """<?xml version="1.0" encoding="UTF-8"?>
<core:CityModel xmlns:core="http://www.opengis.net/citygml/2.0" xmlns:bldg="http://www.opengis.net/citygml/building/2.0"
 xmlns:gml="http://www.opengis.net/gml" xmlns:xlink="http://www.w3.org/1999/xlink" xmlns:dem="http://www.opengis.net/citygml/relief/2.0">
 <gml:boundedBy><gml:Envelope srsName="urn:adv:crs:ETRS89_UTM32*DE_DHHN2016_NH" srsDimension="3"/></gml:boundedBy>
 <core:cityObjectMember><bldg:Building gml:id="B"><bldg:measuredHeight>5</bldg:measuredHeight>
  <bldg:boundedBy><bldg:RoofSurface><bldg:lod2MultiSurface><gml:MultiSurface><gml:surfaceMember>
   <gml:Polygon gml:id="R"><gml:exterior><gml:LinearRing><gml:posList>
   500000 5400000 5 500010 5400000 5 500010 5400010 5 500000 5400010 5 500000 5400000 5</gml:posList>
   </gml:LinearRing></gml:exterior></gml:Polygon></gml:surfaceMember></gml:MultiSurface></bldg:lod2MultiSurface>
   <bldg:opening><bldg:Window gml:id="W"><bldg:lod3MultiSurface><gml:MultiSurface><gml:surfaceMember>
   <gml:Polygon><gml:exterior><gml:LinearRing><gml:pos>500000 5400000 1</gml:pos><gml:pos>500001 5400000 1</gml:pos>
   <gml:pos>500001 5400000 2</gml:pos><gml:pos>500000 5400000 1</gml:pos></gml:LinearRing></gml:exterior></gml:Polygon>
   </gml:surfaceMember></gml:MultiSurface></bldg:lod3MultiSurface></bldg:Window></bldg:opening>
  </bldg:RoofSurface></bldg:boundedBy>
  <bldg:lod2Solid><gml:Solid><gml:exterior><gml:CompositeSurface><gml:surfaceMember xlink:href="#R"/>
   <gml:surfaceMember><gml:OrientableSurface orientation="-"><gml:baseSurface xlink:href="#R"/></gml:OrientableSurface>
   </gml:surfaceMember></gml:CompositeSurface></gml:exterior></gml:Solid></bldg:lod2Solid>
  <bldg:consistsOfBuildingPart><bldg:BuildingPart gml:id="P"><bldg:lod2MultiSurface><gml:MultiSurface>
   <gml:surfaceMember xlink:href="#R"/></gml:MultiSurface></bldg:lod2MultiSurface></bldg:BuildingPart>
  </bldg:consistsOfBuildingPart></bldg:Building></core:cityObjectMember>
 <core:cityObjectMember><dem:ReliefFeature gml:id="G"><dem:lod>2</dem:lod><dem:reliefComponent><dem:TINRelief>
  <dem:lod>2</dem:lod><dem:tin><gml:TriangulatedSurface><gml:trianglePatches><gml:Triangle><gml:exterior>
  <gml:LinearRing><gml:posList>500000 5400000 0 500010 5400000 0 500000 5400010 1 500000 5400000 0</gml:posList>
  </gml:LinearRing></gml:exterior></gml:Triangle></gml:trianglePatches></gml:TriangulatedSurface></dem:tin>
  </dem:TINRelief></dem:reliefComponent></dem:ReliefFeature></core:cityObjectMember>
</core:CityModel>
"""


def _write(tmp: Path, name: str, data: bytes) -> Path:
    p = tmp / name
    p.write_bytes(data)
    return p


# --- one test per reader --------------------------------------------------------------------------------

def test_fuzz_citygml(tmp_path: Path) -> None:
    from citylod.io.city.citygml import read_citygml

    seed = CITYGML.encode()
    fuzz("citygml", tmp_path, lambda rng, i: _write(tmp_path, f"c{i}.gml", mutate_bytes(seed, rng)),
         lambda p: _valid_model(read_citygml(p)))


def test_fuzz_cityjson(tmp_path: Path) -> None:
    from citylod.io.city.read import read_city_model

    doc = cube_cityjson()
    fuzz("cityjson", tmp_path, lambda rng, i: _write(tmp_path, f"c{i}.city.json", mutated_text(doc, rng)),
         lambda p: _valid_model(read_city_model(p)))


def test_fuzz_cityjsonseq(tmp_path: Path) -> None:
    from citylod.io.city.read import read_city_model

    doc = cube_cityjson()
    header = {k: v for k, v in doc.items() if k not in ("CityObjects", "vertices")} | {"CityObjects": {},
                                                                                      "vertices": []}
    feature = {"type": "CityJSONFeature", "id": "B", "CityObjects": doc["CityObjects"], "vertices": doc["vertices"]}

    def case(rng: random.Random, i: int) -> Path:
        lines = [json.dumps(header), json.dumps(feature), json.dumps(feature | {"id": "C"})]
        k = rng.randrange(3)
        lines[k] = mutated_text(json.loads(lines[k]), rng).decode("utf-8", "replace")
        return _write(tmp_path, f"s{i}.city.jsonl", "\n".join(lines).encode())

    fuzz("cityjsonseq", tmp_path, case, lambda p: _valid_model(read_city_model(p)))


@pytest.fixture(scope="module")
def terrain(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from citylod.bench.synthetic import make_terrain_tileset

    return make_terrain_tileset(tmp_path_factory.mktemp("fuzz") / "ts", levels=1, n=5, texture_px=8)


def test_fuzz_tileset_json(tmp_path: Path, terrain: Path) -> None:
    from citylod.io.tiles3d import open_tileset

    doc = json.loads((terrain / "tileset.json").read_text())

    def case(rng: random.Random, i: int) -> Path:
        d = tmp_path / f"t{i}"
        shutil.copytree(terrain, d)
        (d / "tileset.json").write_bytes(mutated_text(doc, rng))
        return d

    def check(d: Path) -> None:
        ts = open_tileset(d)
        for t in ts.walk():
            t.load()

    fuzz("tileset", tmp_path, case, check)


def _b3dm(glb: bytes) -> bytes:
    ft = json.dumps({"BATCH_LENGTH": 0, "RTC_CENTER": [1.0, 2.0, 3.0]}).encode()
    ft += b" " * (-(28 + len(ft)) % 8)
    return struct.pack("<4sIIIIII", b"b3dm", 1, 28 + len(ft) + len(glb), len(ft), 0, 0, 0) + ft + glb


def _pnts(n: int = 16) -> bytes:
    pos = np.random.default_rng(0).random((n, 3), dtype=np.float32).tobytes()
    rgb = np.arange(n * 3, dtype=np.uint8).tobytes()
    ft = json.dumps({"POINTS_LENGTH": n, "POSITION": {"byteOffset": 0},
                     "RGB": {"byteOffset": len(pos)}}).encode()
    ft += b" " * (-(28 + len(ft)) % 8)
    body = pos + rgb
    body += b"\0" * (-len(body) % 8)
    return struct.pack("<4sIIIIII", b"pnts", 1, 28 + len(ft) + len(body), len(ft), len(body), 0, 0) + ft + body


def test_fuzz_tile_content(tmp_path: Path, terrain: Path) -> None:
    from citylod.io.tiles3d import decode_content

    glb = next((terrain / "tiles").rglob("*.glb")).read_bytes()
    seeds = [glb, _b3dm(glb), _pnts()]
    for s in seeds:  # the seeds themselves decode
        decode_content(s, "seed")
    fuzz("tile content", tmp_path, lambda rng, i: mutate_bytes(seeds[i % 3], rng)[:1 << 20],
         lambda data: decode_content(data, "fuzzed"))


def _las_bytes(tmp: Path, suffix: str) -> bytes:
    return write_las(tmp / f"seed{suffix}", 300, extent=50.0, point_format=3, seed=2).read_bytes()


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_fuzz_las(tmp_path: Path, suffix: str) -> None:
    from citylod.io.las import iter_points, read_info

    seed = _las_bytes(tmp_path, suffix)

    def check(p: Path) -> None:
        info = read_info(p)
        n = sum(len(c) for c in iter_points(p, chunk_points=100))
        assert n == info.point_count

    fuzz(f"las{suffix}", tmp_path, lambda rng, i: _write(tmp_path, f"p{i}{suffix}", mutate_bytes(seed, rng)), check)


def test_fuzz_geotiff(tmp_path: Path) -> None:
    import rasterio
    from rasterio.transform import from_origin

    from citylod.io.raster import RasterSource, read_info

    p = tmp_path / "seed.tif"
    with rasterio.open(p, "w", driver="GTiff", width=16, height=16, count=1, dtype="float32", crs="EPSG:25832",
                       transform=from_origin(500000, 5400000, 1.0, 1.0), nodata=-9999) as ds:
        ds.write(np.arange(256, dtype=np.float32).reshape(1, 16, 16))
    seed = p.read_bytes()

    def check(path: Path) -> None:
        info = read_info(path)
        src = RasterSource(path)
        try:
            src.read(0, 0, min(info.height, 16), min(info.width, 16))
        finally:
            src.close()

    fuzz("geotiff", tmp_path, lambda rng, i: _write(tmp_path, f"r{i}.tif", mutate_bytes(seed, rng)), check)


def test_fuzz_camera_and_path_json(tmp_path: Path) -> None:
    cam = Camera((500000.0, 5400000.0, 300.0), (500010.0, 5400010.0, 0.0), (0.0, 0.0, 1.0), 50.0).to_dict()
    seeds = [cam, [cam, cam | {"fovy_deg": 30.0}], {"cameras": [cam]}]
    fuzz("camera", tmp_path, lambda rng, i: _write(tmp_path, f"cam{i}.json", mutated_text(seeds[i % 3], rng)),
         lambda p: [c.basis() for c in load_cameras(p)])


SQL_TOKENS = [
    "object_id", "type", "measured_height", "storeys", "zmin", "attributes", "=", "<", ">", "<>", "AND", "OR",
    "NOT", "(", ")", ",", "'Building'", "'x''y'", "1", "-1", "1e308", "NULL", "LIKE", "GLOB", "'%'", "IN",
    "BETWEEN", "json_extract(attributes, '$.a')", "length(zeroblob(2000000000))", "randomblob(1000000000)",
    "printf('%.*c', 2000000000, 'x')", "(SELECT count(*) FROM city_objects)", "load_extension('x')",
    "(WITH RECURSIVE c(x) AS (SELECT 1 UNION ALL SELECT x + 1 FROM c) SELECT max(x) FROM c)",
    "--", "/*", "'", '"', "\x00", ";", "ATTACH 'x' AS y", "sqlite_master", "CASE", "WHEN", "THEN", "END",
]


def test_fuzz_sql_where_clauses(tmp_path: Path) -> None:
    from citylod.semantics.store import CityStore, build_city

    src = tmp_path / "c.city.json"
    src.write_text(json.dumps(cube_cityjson()))
    build_city(src, tmp_path / "c.gpkg", progress=False)
    with CityStore.open(tmp_path / "c.gpkg") as store:
        store.query_time_limit_s = 0.5
        fuzz("sql", tmp_path, lambda rng, i: " ".join(rng.choice(SQL_TOKENS) for _ in range(rng.randint(1, 8))),
             lambda where: store.query(where))
        assert store.query("type = 'Building'") == ["B"]  # the store still answers
