"""SIGKILL of a build at any moment leaves no process behind within 5 s, and the rerun is byte-identical.

The build runs as the user runs it (``citylod build ...`` in a subprocess); the test waits until it has
worker processes, lets it work a while, kills it with SIGKILL (no clean-up runs), and then watches every
process the build had started: all must be gone within 5 s. The rerun resumes from what the killed build
left and must write exactly the files, byte for byte, of a build that was never interrupted.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.cli_harness import alive, descendants, run_cli, start_cli
from tests.inputs import write_las

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")]


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _raster(path: Path, n: int = 513) -> Path:
    import rasterio
    from rasterio.transform import from_origin

    y, x = np.mgrid[0:n, 0:n].astype(np.float32)
    z = 20 * np.sin(x / 37) * np.cos(y / 23) + 5 * np.sin(x / 5.3 + y / 7.1)
    z += np.random.default_rng(0).normal(0, 0.3, (n, n)).astype(np.float32)
    with rasterio.open(path, "w", driver="GTiff", width=n, height=n, count=1, dtype="float32", crs="EPSG:25832",
                       transform=from_origin(500000, 5400000, 1.0, 1.0)) as ds:
        ds.write(z[None])
    return path


def _cloud(path: Path, n: int = 300_000) -> Path:
    noise = np.random.default_rng(1).normal(0, 0.05, n)
    return write_las(path, n, extent=300.0, z=lambda x: 10 * np.sin(x / 20) + noise)


def _kill_and_watch(args: list, delay_s: float) -> tuple[int, float] | None:
    """Start the build, SIGKILL it ``delay_s`` after its first worker appears; (workers seen, seconds to clear),
    or None when the build finished before the kill (the caller tries an earlier moment)."""
    proc = start_cli(args)
    seen: set[int] = set()
    deadline = time.monotonic() + 120
    while not seen and proc.poll() is None and time.monotonic() < deadline:
        seen = descendants(proc.pid)
        time.sleep(0.05)
    assert seen, "the build finished or stalled before it had worker processes"
    end = time.monotonic() + delay_s
    while time.monotonic() < end and proc.poll() is None:
        seen |= descendants(proc.pid)
        time.sleep(0.05)
    seen |= descendants(proc.pid)
    if proc.poll() is not None:
        return None
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    t0 = time.monotonic()
    while alive(seen) and time.monotonic() - t0 < 5.0:
        time.sleep(0.05)
    left = alive(seen)
    for pid in left:  # do not leave them to the next test
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    assert not left, f"{len(left)} of {len(seen)} worker processes outlived the killed build by 5 s"
    return len(seen), time.monotonic() - t0


@pytest.mark.parametrize("kind", ["dsm", "points"])
def test_sigkill_leaves_no_workers_and_rerun_is_identical(tmp_path: Path, kind: str) -> None:
    if kind == "dsm":
        src = _raster(tmp_path / "dsm.tif")
        extra: list = ["--tile-size", "65"]  # default executor: forked workers
    else:
        src = _cloud(tmp_path / "cloud.laz")
        extra = ["--workers", "2"]  # spawned workers
    ref = tmp_path / "ref"
    r = run_cli(["build", kind, src, "-o", ref, *extra], timeout_s=300)
    assert r.returncode == 0, r.stderr
    out = tmp_path / "out"
    for delay in (0.0, 1.5):  # at once (workers starting) and while tiles are being written
        # On a fast or idle machine the build may finish before the later moment: kill it earlier then.
        while _kill_and_watch(["build", kind, src, "-o", out, *extra], delay) is None:
            assert delay > 0.1, "the build finished before it could be killed"
            delay /= 2
            shutil.rmtree(out, ignore_errors=True)
        r = run_cli(["build", kind, src, "-o", out, *extra], timeout_s=300)
        assert r.returncode == 0, r.stderr
        a, b = _tree(ref), _tree(out)
        assert a.keys() == b.keys() and all(a[k] == b[k] for k in a), sorted(
            k for k in a.keys() | b.keys() if a.get(k) != b.get(k))[:10]
        assert not out.with_name("out.partial").exists()
