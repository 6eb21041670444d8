"""The compiled-ahead DSM kernels: the same results as the JIT kernels, used only where they may be."""

from __future__ import annotations

import shutil
import threading
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

import citylod.lod.kernels.tin_kernels as tk
from citylod.io.tiles3d import open_tileset
from citylod.lod.build.dsm import build_dsm, exercise_kernels
from citylod.lod.kernels import aot
from tests.lod.test_dsm import NODATA, city_like, write_raster


@pytest.fixture(scope="module")
def compiled() -> Path:
    """The compiled-ahead module for this source (``make`` builds it; built here when it is missing)."""
    folder = aot.build(exercise_kernels, log=lambda m: None)
    assert folder is not None, "numba.pycc could not compile the kernels on this machine"
    assert aot.load(), "the module built is not loaded"
    return folder


@pytest.fixture
def counted(compiled, monkeypatch) -> Counter[str]:
    """Calls of each compiled-ahead kernel, by name, while the test runs."""
    calls: Counter[str] = Counter()
    table = {}
    for jit, variants in aot._table.items():
        def wrap(fn, name=jit.__name__):
            def counting(*args):
                calls[name] += 1
                return fn(*args)
            return counting
        table[jit] = [(wrap(fn), spec) for fn, spec in variants]
    monkeypatch.setattr(aot, "_table", table)
    return calls


# The kernels each metric's build must run compiled ahead (the Hausdorff builds' leaves keep the vertical path).
_USED = {
    "vertical": ("build_tin", "forced_mask", "z_ordered", "live_mesh", "certify_block", "skirt_strip",
                 "_grid_sample_error", "_bounds", "border_fans"),
    "hausdorff": ("build_tin", "z_ordered", "live_mesh", "skirt_strip", "_bounds", "hausdorff_block"),
}


@pytest.mark.parametrize("metric", ["vertical", "hausdorff"])
def test_hard_rasters_build_to_the_same_bytes_either_way(tmp_path, counted, metric) -> None:
    z = city_like(150, 133, seed=7)  # façades, chimneys, not a power of two
    z[40:60, 20:45] = NODATA  # an inner hole
    z[:, :5] = NODATA  # a no-data border
    write_raster(tmp_path / "dsm.tif", z, y0=5_500_000.0)
    rep = build_dsm(tmp_path / "dsm.tif", tmp_path / "aot", tile_size=33, workers=0, progress=False,
                    metric=metric)
    assert rep.kernels == "compiled-ahead" and "compiled-ahead kernels" in rep.summary()
    used = dict(counted)
    with aot.disabled():
        rep = build_dsm(tmp_path / "dsm.tif", tmp_path / "jit", tile_size=33, workers=0, progress=False,
                        metric=metric)
    assert rep.kernels == "JIT"
    assert dict(counted) == used  # nothing compiled ahead ran in the second build
    for name in _USED[metric]:
        assert used.get(name, 0) > 0, (name, used)
    tiles = [t for t in open_tileset(tmp_path / "aot").walk() if t.content_uri]
    assert len(tiles) > 10
    for t in tiles:
        assert (tmp_path / "aot" / t.content_uri).read_bytes() == (tmp_path / "jit" / t.content_uri).read_bytes()
    assert (tmp_path / "aot" / "tileset.json").read_bytes() == (tmp_path / "jit" / "tileset.json").read_bytes()


def test_other_argument_types_and_other_threads_run_the_jit_kernel(counted) -> None:
    mask = np.zeros((9, 12), bool)
    mask[::3, 1::4] = True
    want = tk.z_ordered(mask)
    for args in ((mask,), (mask.view(np.int8),), (np.asfortranarray(mask),)):
        got = aot.kernel(tk.z_ordered, *args)
        assert all(np.array_equal(a, b) for a, b in zip(got, want, strict=True))
    assert counted["z_ordered"] == 1  # the C-contiguous bool array only (an int8 one would be read as bool)
    assert not aot._matches((("f",),), (np.float32(1.0),)) and aot._matches((("f",),), (np.float64(1.0),))
    assert not aot._matches((("i",),), (np.int32(1),)) and not aot._matches((("i",),), (True,))
    assert aot._matches((("i",),), (np.int64(1),)) and aot._matches((("i",),), (7,))
    ro = mask.copy()
    ro.flags.writeable = False
    aot.kernel(tk.z_ordered, ro)
    assert counted["z_ordered"] == 1  # read-only: a different numba type
    out = []
    th = threading.Thread(target=lambda: out.append(aot.kernel(tk.z_ordered, mask)))
    th.start()
    th.join()
    assert counted["z_ordered"] == 1  # not on another thread (the compiled-ahead wrappers hold the GIL)
    assert np.array_equal(out[0][0], want[0])


def test_the_folder_follows_the_sources(tmp_path) -> None:
    here = Path(aot.__file__).parent
    for name in aot.SOURCES:
        shutil.copy(here / name, tmp_path / name)
    assert aot._key(tmp_path) == aot._key()
    with open(tmp_path / "tin_kernels.py", "a") as f:
        f.write("\n# an edit\n")
    assert aot._key(tmp_path) != aot._key()


def test_a_broken_folder_is_ignored_with_a_warning(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("CITYLOD_KERNEL_DIR", str(tmp_path))
    folder = aot.kernel_dir()
    folder.mkdir(parents=True)
    (folder / "manifest.json").write_text('{"file": "missing.so", "exports": []}')
    monkeypatch.setattr(aot, "_loaded", False)
    monkeypatch.setattr(aot, "_table", {})
    with pytest.warns(RuntimeWarning, match="JIT kernels run instead"):
        assert not aot.load()
    mask = np.ones((4, 4), bool)
    assert np.array_equal(aot.kernel(tk.z_ordered, mask)[0], tk.z_ordered(mask)[0])


def test_an_unwritable_folder_is_reported_and_nothing_is_built(tmp_path, monkeypatch) -> None:
    (tmp_path / "a_file").write_text("")
    monkeypatch.setenv("CITYLOD_KERNEL_DIR", str(tmp_path / "a_file"))
    said: list[str] = []
    assert aot.build(exercise_kernels, log=said.append) is None
    assert "CITYLOD_KERNEL_DIR" in said[-1] and "JIT kernels will run" in said[-1]


def test_a_folder_built_meanwhile_by_another_process_stays(tmp_path, monkeypatch) -> None:
    folder, tmp = tmp_path / "key", tmp_path / "key.tmp"
    tmp.mkdir()
    (tmp / "manifest.json").write_text("mine")
    real = aot.os.replace

    def racing(src, dst):  # the other process renames its folder in first
        (tmp_path / "theirs").mkdir()
        (tmp_path / "theirs" / "manifest.json").write_text("theirs")
        real(tmp_path / "theirs", dst)
        real(src, dst)  # a non-empty folder is not replaced: OSError

    monkeypatch.setattr(aot.os, "replace", racing)
    aot._install(tmp, folder, force=False)
    assert (folder / "manifest.json").read_text() == "theirs" and not tmp.exists()
    monkeypatch.setattr(aot.os, "replace", real)
    tmp.mkdir()
    (tmp / "manifest.json").write_text("mine")
    aot._install(tmp, folder, force=True)
    assert (folder / "manifest.json").read_text() == "mine" and not tmp.exists()


def test_old_kernel_folders_are_pruned(tmp_path) -> None:
    import os

    for i in range(11):
        d = tmp_path / f"{i:020x}"
        d.mkdir()
        (d / "manifest.json").write_text("{}")
        os.utime(d / "manifest.json", (1000.0 + i, 1000.0 + i))
    (tmp_path / "not-ours").mkdir()
    (tmp_path / f"{0:020x}.tmpdead").mkdir()
    os.utime(tmp_path / f"{0:020x}.tmpdead", (1000.0, 1000.0))
    (tmp_path / f"{1:020x}.tmplive").mkdir()  # a build in progress
    aot._prune(tmp_path, keep=8)
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == sorted([f"{i:020x}" for i in range(3, 11)] + ["not-ours", f"{1:020x}.tmplive"])


def test_a_process_that_looked_before_the_build_loads_it_after(compiled, monkeypatch) -> None:
    """A process that called load() before the module existed (an earlier build here, another worker's
    build) picks it up once build() reports it, instead of keeping the JIT kernels for good."""
    monkeypatch.setattr(aot, "_table", {})
    monkeypatch.setattr(aot, "_loaded", True)  # looked earlier and found nothing
    assert not aot.load()
    assert aot.build(exercise_kernels, log=lambda m: None) == compiled
    assert aot.load()
