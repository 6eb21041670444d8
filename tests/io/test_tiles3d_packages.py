""".3tz and .3dtiles packages written by CesiumGS's 3d-tiles-tools (tests/data/3dtiles/SOURCE.md) open in place and
give what the same files give from a folder, unpacked here by Python's zipfile and sqlite3 (independent of the
reader); damaged or hostile packages are one line and exit code 2."""

from __future__ import annotations

import multiprocessing
import sqlite3
import zipfile
from pathlib import Path

import numpy as np
import pytest

from citylod.core.errors import InputError, UnsafePathError
from citylod.io.tiles3d import open_tileset
from citylod.io.tiles3d.package import MAX_ENTRY_BYTES
from tests.cli_harness import run_cli
from tests.paths import ROOT

DATA = ROOT / "tests" / "data" / "3dtiles"
PACKAGES = DATA / "packages"


def _unpack(package: Path, out: Path) -> Path:
    """The package's files in a folder: a ZIP's entries or a database's rows, by the standard library."""
    out.mkdir()
    if package.suffix == ".3tz":
        with zipfile.ZipFile(package) as z:
            z.extractall(out)
    else:
        with sqlite3.connect(package) as db:
            for key, content in db.execute("SELECT key, content FROM media"):
                (out / key).parent.mkdir(parents=True, exist_ok=True)
                (out / key).write_bytes(content)
    return out


def _tiles(path: Path) -> list[tuple[str, float, int, np.ndarray, np.ndarray]]:
    ts = open_tileset(path)
    out = []
    for t in ts.walk():
        m = t.load()
        out.append((t.key, t.geometric_error, t.content_bytes, m.vertices, m.faces))
    return out


@pytest.mark.parametrize("name", ["tileset.3tz", "basicProcessing.3tz", "basicProcessing.3dtiles",
                                  "implicitProcessing.3tz"])
def test_package_reads_as_its_unpacked_folder(name: str, tmp_path: Path) -> None:
    package = PACKAGES / name
    folder = _unpack(package, tmp_path / "unpacked")
    got, want = _tiles(package), _tiles(folder)
    assert len(got) == len(want) > 1
    loaded = 0
    for (k1, e1, b1, v1, f1), (k2, e2, b2, v2, f2) in zip(got, want, strict=True):
        assert (k1, e1, b1) == (k2, e2, b2)
        assert np.array_equal(v1, v2) and np.array_equal(f1, f2)
        loaded += len(f1) > 0
    assert loaded >= 4


def test_header_extras_python_zipfile_refuses_read_through_the_index() -> None:
    """3d-tiles-tools' regression archive with 64 bytes of extras in its ZIP headers: Python's zipfile refuses
    its central directory; the 3TZ index reads it (as 3d-tiles-tools does). It holds only ``empty.json``."""
    from citylod.io.tiles3d.package import Package

    path = PACKAGES / "validWith64byteExtrasInZipFileHeader.3tz"
    with pytest.raises(zipfile.BadZipFile):
        zipfile.ZipFile(path)
    package = Package(path, "3tz")
    assert package.read("empty.json") == b"{}" and package.size("empty.json") == 2
    with pytest.raises(InputError, match="no such entry"):
        open_tileset(path)


def test_implicit_package_matches_the_folder_of_the_same_data() -> None:
    """The implicit-tiling package against tests/data's folder copy of the same tileset (subtrees read in place)."""
    got = _tiles(PACKAGES / "implicitProcessing.3tz")
    want = _tiles(DATA / "implicit" / "QuadtreeSubtrees")
    assert [g[0] for g in got] == [w[0] for w in want]
    assert all(np.array_equal(g[3], w[3]) for g, w in zip(got, want, strict=True))


def _read_in_child(path: str, queue: multiprocessing.Queue) -> None:  # type: ignore[type-arg]
    ts = open_tileset(path)  # opened in the parent, pickled, reopened here
    queue.put(sum(len(t.load().faces) for t in ts.walk()))


def test_forked_worker_reads_through_its_own_handle() -> None:
    ts = open_tileset(PACKAGES / "tileset.3tz")
    want = sum(len(t.load().faces) for t in ts.walk())
    ctx = multiprocessing.get_context("fork")
    queue = ctx.Queue()
    p = ctx.Process(target=_read_in_child, args=(str(PACKAGES / "tileset.3tz"), queue))
    p.start()
    got = queue.get(timeout=60)
    p.join(timeout=60)
    assert got == want > 0
    # the parent's handle still reads after the child used its own
    assert sum(len(t.load().faces) for t in ts.walk()) == want


def test_render_from_a_package_draws_what_the_folder_draws(tmp_path: Path) -> None:
    import citylod
    from citylod.render.offscreen import render_images

    folder = _unpack(PACKAGES / "tileset.3tz", tmp_path / "unpacked")
    cam = citylod.orbit_cameras(*open_tileset(folder).bounds, n=1, aspect=200 / 150)[0]
    (a, _), = render_images([PACKAGES / "tileset.3tz"], [cam], size=(200, 150))
    (b, _), = render_images([folder], [cam], size=(200, 150))
    assert (a != a[0, 0]).any(axis=-1).sum() > 300  # the buildings are in view
    assert np.array_equal(a, b)


@pytest.mark.parametrize(("name", "says"), [
    ("validSmall.3tz", "no such entry in the package"),  # a valid archive holding no tileset.json
    ("invalidTableName.3dtiles", "must have columns key TEXT and content BLOB (found: none)"),
    ("missingColumn.3dtiles", "(found: key TEXT)"),
    ("invalidColumnType0.3dtiles", "(found: key INTEGER, content BLOB)"),
])
def test_damaged_packages_are_one_line(name: str, says: str) -> None:
    r = run_cli(["info", PACKAGES / name])
    assert r.returncode == 2
    assert says in r.stderr and name in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr


def test_package_entries_cannot_reach_outside_or_inflate(tmp_path: Path) -> None:
    tileset = ('{"asset": {"version": "1.1"}, "geometricError": 1, "root": {"boundingVolume": {"box": '
               '[0,0,0,1,0,0,0,1,0,0,0,1]}, "geometricError": 0, "content": {"uri": "%s"}}}')
    escape = tmp_path / "escape.3tz"
    with zipfile.ZipFile(escape, "w") as z:
        z.writestr("tileset.json", tileset % "../outside.glb")
    with pytest.raises(UnsafePathError, match="outside"):
        open_tileset(escape)

    # A ZIP entry that declares more than the limit is refused before anything is decompressed.
    bomb = tmp_path / "bomb.3tz"
    with zipfile.ZipFile(bomb, "w", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr("tileset.json", tileset % "big.glb")
        z.writestr("big.glb", b"\0" * 1024)
    raw = bytearray(bomb.read_bytes())
    # patch the central directory's uncompressed size of big.glb (offset 24 in its record)
    cd = raw.rfind(b"PK\x01\x02")
    raw[cd + 24: cd + 28] = (MAX_ENTRY_BYTES + 1).to_bytes(4, "little")
    bomb.write_bytes(bytes(raw))
    ts = open_tileset(bomb)
    with pytest.raises(InputError, match="refused"):
        ts.root.load()

    r = run_cli(["render", bomb, "-o", tmp_path / "x.png", "--size", "64x48"])
    assert r.returncode == 2 and "big.glb" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "x.png").exists()


def _zip_by_hand(entries: list[tuple[str, bytes, int, bytes]]) -> bytes:
    """A ZIP of (name, stored bytes, method, original bytes) entries, the 3TZ index last: what Python's zipfile
    cannot write for method 93 (Zstandard), which the 3TZ format allows."""
    import hashlib
    import struct
    import zlib

    body, central, index = b"", b"", []
    for name, data, method, original in entries:
        n = name.encode()
        crc = zlib.crc32(original)
        index.append((*struct.unpack("<QQ", hashlib.md5(n).digest()), len(body)))
        central += struct.pack("<4sHHHHHHIIIHHHHHII", b"PK\x01\x02", 63, 63, 0, method, 0, 0x21, crc, len(data),
                               len(original), len(n), 0, 0, 0, 0, 0, len(body)) + n
        body += struct.pack("<4sHHHHHIIIHH", b"PK\x03\x04", 63, 0, method, 0, 0x21, crc, len(data), len(original),
                            len(n), 0) + n + data
    raw = b"".join(struct.pack("<QQQ", *e) for e in sorted(index))
    n = b"@3dtilesIndex1@"
    crc = zlib.crc32(raw)
    central += struct.pack("<4sHHHHHHIIIHHHHHII", b"PK\x01\x02", 63, 20, 0, 0, 0, 0x21, crc, len(raw), len(raw),
                           len(n), 0, 0, 0, 0, 0, len(body)) + n
    body += struct.pack("<4sHHHHHIIIHH", b"PK\x03\x04", 20, 0, 0, 0, 0x21, crc, len(raw), len(raw), len(n), 0) \
        + n + raw
    count = len(entries) + 1
    return body + central + struct.pack("<4sHHHHIIH", b"PK\x05\x06", 0, 0, count, count, len(central), len(body), 0)


def test_zstandard_entries_read_and_damage_is_caught(tmp_path: Path) -> None:
    import zstandard

    folder = _unpack(PACKAGES / "tileset.3tz", tmp_path / "unpacked")
    files = {p.name: p.read_bytes() for p in folder.iterdir() if p.name != "@3dtilesIndex1@"}
    z = zstandard.ZstdCompressor()
    archive = tmp_path / "zstd.3tz"
    archive.write_bytes(_zip_by_hand([(k, z.compress(v), 93, v) for k, v in sorted(files.items())]))
    got, want = _tiles(archive), _tiles(folder)
    assert [g[:3] for g in got] == [w[:3] for w in want]
    assert all(np.array_equal(g[3], w[3]) for g, w in zip(got, want, strict=True))
    # one byte of a tile flipped: the CRC in its header catches it
    name = next(k for k in sorted(files) if k.endswith(".b3dm"))
    bad = dict(files)
    bad[name] = bytes([files[name][0] ^ 1]) + files[name][1:]
    entries = [(k, z.compress(bad[k]), 93, files[k]) for k in sorted(files)]
    broken = tmp_path / "broken.3tz"
    broken.write_bytes(_zip_by_hand(entries))
    ts = open_tileset(broken)
    tile = next(t for t in ts.walk() if t.content_uri == name)
    with pytest.raises(InputError, match="CRC"):
        tile.load()


def test_zip64_archives_read_through_the_index(tmp_path: Path) -> None:
    """More than 65,535 entries (the ZIP64 end record) and entries with ZIP64 local headers (sizes in the
    extra field): what a large photogrammetry export is. Written by Python's zipfile, index by hand."""
    import hashlib
    import struct

    from citylod.io.tiles3d.package import Package

    folder = _unpack(PACKAGES / "tileset.3tz", tmp_path / "unpacked")
    files = {p.name: p.read_bytes() for p in folder.iterdir() if p.name != "@3dtilesIndex1@"}
    big = tmp_path / "big.3tz"
    index = []
    with zipfile.ZipFile(big, "w", allowZip64=True) as z:
        for name, data in sorted(files.items()):
            info = zipfile.ZipInfo(name)
            with z.open(info, "w", force_zip64=True) as fh:  # sizes 0xFFFFFFFF in the local header
                fh.write(data)
            index.append((*struct.unpack("<QQ", hashlib.md5(name.encode()).digest()), z.getinfo(name).header_offset))
        for k in range(70_000):
            name = f"pad/{k}.bin"
            z.writestr(name, b"")
            index.append((*struct.unpack("<QQ", hashlib.md5(name.encode()).digest()), z.getinfo(name).header_offset))
        z.writestr("@3dtilesIndex1@", b"".join(struct.pack("<QQQ", *e) for e in sorted(index)))
    tail = big.read_bytes()[-200:]
    assert b"PK\x06\x06" in tail  # the ZIP64 end record is there
    package = Package(big, "3tz")
    assert package._index is not None and len(package._index.index) == len(files) + 70_000
    assert all(package.read(name) == data for name, data in files.items())
    assert package.read("pad/69999.bin") == b""
    got, want = _tiles(big), _tiles(folder)
    assert all(np.array_equal(g[3], w[3]) for g, w in zip(got, want, strict=True))
