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
    ("validWith64byteExtrasInZipFileHeader.3tz", "not a readable 3TZ (ZIP) archive"),
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
