"""Fixtures shared by the whole suite, built once per test process (session scope).

The sample city is the expensive one: written once at 129² and, for the tests that need them, its DSM
tileset (textured), its city store and its point octree built once beside it.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
from types import SimpleNamespace

import pytest

from citylod.sample import SampleInfo, make_sample

_XVFB: subprocess.Popen[bytes] | None = None


def _die_with_parent() -> None:
    import ctypes

    ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


def pytest_configure(config: pytest.Config) -> None:
    """Give each xdist worker its own Xvfb display.

    Under ``pytest -n 2`` inside one ``xvfb-run`` both workers would share a display, and the real-input GUI
    tests of one worker (xdotool keys and clicks go to the focused window) would land in the other
    worker's windows. A private server per worker keeps X input where its test sent it.
    """
    global _XVFB
    # Remote reads go through a disk cache (citylod.io.tiles3d.http_cache): one of this process's own, never the
    # user's ~/.cache, and not one a previous run left (its answers would hide the requests the tests count).
    import tempfile

    os.environ["CITYLOD_HTTP_CACHE"] = os.path.join(tempfile.mkdtemp(prefix="citylod-http-"), "cache.sqlite")
    if not os.environ.get("PYTEST_XDIST_WORKER") or not os.environ.get("DISPLAY") or not shutil.which("Xvfb"):
        return
    r, w = os.pipe()
    _XVFB = subprocess.Popen(["Xvfb", "-displayfd", str(w), "-screen", "0", "1600x1200x24", "-nolisten", "tcp"],
                             pass_fds=(w,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                             preexec_fn=_die_with_parent)
    os.close(w)
    with os.fdopen(r) as f:
        number = f.readline().strip()
    if number:
        os.environ["DISPLAY"] = f":{number}"
        os.environ.pop("XAUTHORITY", None)
    else:  # the server did not start: keep the shared display
        _XVFB.kill()
        _XVFB = None


def pytest_unconfigure(config: pytest.Config) -> None:
    if _XVFB is not None:
        _XVFB.terminate()
        _XVFB.wait(timeout=10)


@pytest.fixture(scope="session")
def sample_city(tmp_path_factory: pytest.TempPathFactory) -> SampleInfo:
    """The 129² synthetic sample city (seed 7): DSM, orthophoto, LAZ, CityGML, camera and flight files."""
    return make_sample(tmp_path_factory.mktemp("sample129"), size=129, seed=7)


@pytest.fixture(scope="session")
def sample_built(sample_city: SampleInfo, tmp_path_factory: pytest.TempPathFactory) -> SimpleNamespace:
    """:func:`sample_city` with its products: ``dsm`` (textured tileset), ``gpkg`` (city store), ``points``."""
    from citylod.lod.build.dsm import build_dsm
    from citylod.lod.build.points import build_points
    from citylod.semantics.store import build_city

    out = tmp_path_factory.mktemp("sample129_built")
    info = sample_city
    build_dsm(info.files["dsm"], out / "dsm", ortho=info.files["ortho"], workers=0, progress=False)
    build_city(info.files["city"], out / "city.gpkg", progress=False)
    build_points([info.files["points"]], out / "points", workers=0, progress=False)
    return SimpleNamespace(dir=out, info=info, truth=info.city, gpkg=out / "city.gpkg", dsm=out / "dsm",
                           points=out / "points")
