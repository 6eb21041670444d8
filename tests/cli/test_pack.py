"""``citylod pack``: a tileset folder as a 3D Tiles Archive that CesiumGS's 3d-tiles-tools unpacks to the same
files and its validator accepts; its index checked independently (MD5 of each path, sorted as two little-endian
64-bit integers, pointing at the entry's local header)."""

from __future__ import annotations

import hashlib
import shutil
import struct
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest

from citylod.io.tiles3d import open_tileset
from tests.cli_harness import run_cli
from tests.paths import ROOT

SOURCE = ROOT / "tests" / "data" / "3dtiles" / "meshopt" / "dsm_tileset"
TOOLS = ROOT / ".validator" / "node_modules" / "3d-tiles-tools" / "build" / "src" / "cli.mjs"
VALIDATOR = ROOT / ".validator" / "build" / "main.js"


def _files(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


@pytest.mark.parametrize("deflate", [False, True])
def test_pack_writes_an_indexed_archive_of_the_folder(tmp_path: Path, deflate: bool) -> None:
    out = tmp_path / "city.3tz"
    r = run_cli(["pack", SOURCE, "-o", out, *(["--deflate"] if deflate else [])])
    assert r.returncode == 0, r.stderr
    want = _files(SOURCE)
    with zipfile.ZipFile(out) as z:
        infos = z.infolist()
        assert infos[-1].filename == "@3dtilesIndex1@" and infos[-1].compress_type == zipfile.ZIP_STORED
        assert {i.filename: z.read(i) for i in infos[:-1]} == want
        assert all(i.compress_type == (zipfile.ZIP_DEFLATED if deflate else zipfile.ZIP_STORED) for i in infos[:-1])
        raw = z.read(infos[-1])
    entries = [struct.unpack_from("<QQQ", raw, k) for k in range(0, len(raw), 24)]
    assert entries == sorted(entries) and len(entries) == len(want)
    by_hash = {(hi, lo): off for hi, lo, off in entries}
    for info in infos[:-1]:
        hi, lo = struct.unpack("<QQ", hashlib.md5(info.filename.encode()).digest())
        assert by_hash[(hi, lo)] == info.header_offset
    # citylod reads it back through the index, tile by tile
    ts, plain = open_tileset(out), open_tileset(SOURCE)
    assert ts.store is not None and ts.store._index is not None  # type: ignore[union-attr]
    for a, b in zip(ts.walk(), plain.walk(), strict=True):
        assert np.array_equal(a.load().vertices, b.load().vertices) and a.content_bytes == b.content_bytes
    # packing is reproducible
    again = tmp_path / "again.3tz"
    assert run_cli(["pack", SOURCE, "-o", again, *(["--deflate"] if deflate else [])]).returncode == 0
    assert again.read_bytes() == out.read_bytes()


def test_pack_writes_a_3dtiles_database(tmp_path: Path) -> None:
    import sqlite3

    out = tmp_path / "city.3dtiles"
    assert run_cli(["pack", SOURCE, "-o", out]).returncode == 0
    with sqlite3.connect(out) as db:
        rows = dict(db.execute("SELECT key, content FROM media"))
    assert {k: bytes(v) for k, v in rows.items()} == _files(SOURCE)
    ts, plain = open_tileset(out), open_tileset(SOURCE)
    for a, b in zip(ts.walk(), plain.walk(), strict=True):
        assert np.array_equal(a.load().vertices, b.load().vertices)


@pytest.mark.parametrize("suffix", [".3tz", ".3dtiles"])
def test_3d_tiles_tools_unpack_it_and_the_validator_accepts_it(tmp_path: Path, suffix: str) -> None:
    if not (TOOLS.exists() and VALIDATOR.exists() and shutil.which("node")):
        pytest.skip("3d-tiles-tools / 3d-tiles-validator not built (scripts/validator.sh)")
    out = tmp_path / f"city{suffix}"
    assert run_cli(["pack", SOURCE, "-o", out]).returncode == 0
    unpacked = tmp_path / "unpacked"
    proc = subprocess.run(["node", str(TOOLS), "convert", "-i", str(out), "-o", str(unpacked)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert _files(unpacked) == _files(SOURCE)
    report = tmp_path / "report.json"
    subprocess.run(["node", str(VALIDATOR), "--tilesetFile", str(out), "--reportFile", str(report)],
                   capture_output=True, text=True, timeout=300)
    import json

    doc = json.loads(report.read_text())
    assert doc["numErrors"] == 0 and doc["numWarnings"] == 0, doc


def test_pack_refuses_what_is_not_a_tileset_folder(tmp_path: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "a.glb").write_bytes(b"x")
    r = run_cli(["pack", empty, "-o", tmp_path / "x.3tz"])
    assert r.returncode == 2 and "no tileset.json" in r.stderr and "Traceback" not in r.stderr
    r = run_cli(["pack", SOURCE, "-o", tmp_path / "x.zip"])
    assert r.returncode == 2 and "*.3tz" in r.stderr and "*.3dtiles" in r.stderr
    assert not list(tmp_path.glob("x.*"))


def test_build_writes_a_package_when_the_output_is_named_so(tmp_path: Path) -> None:
    """``build dsm RASTER -o CITY.3tz``: the build runs in CITY.3tz.build/ and is packed when complete; the
    package holds the files a folder build writes."""
    from citylod.sample.files import make_sample

    info = make_sample(tmp_path / "src", size=65)
    dsm = str(info.files["dsm"])
    assert run_cli(["build", "dsm", dsm, "-o", tmp_path / "folder", "--tile-size", "33"],
                   timeout_s=300).returncode == 0
    r = run_cli(["build", "dsm", dsm, "-o", tmp_path / "city.3tz", "--tile-size", "33"], timeout_s=300)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "city.3tz").is_file() and not (tmp_path / "city.3tz.build").exists()
    with zipfile.ZipFile(tmp_path / "city.3tz") as z:
        packed = {i.filename: z.read(i) for i in z.infolist() if i.filename != "@3dtilesIndex1@"}
    assert packed == _files(tmp_path / "folder")
