"""citylod's off-screen (EGL) renderers next to a PyVista window (GLX) in one process, as a scripting user has
them: each must draw into its own context and leave the other's alone (see citylod.render.gl_context).

Each scenario runs as a user's script in a fresh process: a broken GL context (or the X error that ends a
process) must not spill into the test worker, and the reference is the same render in a process that never
opened a plotter, so the independent computation is the same code path without the neighbour.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from citylod.bench.synthetic import make_terrain_tileset
from tests.paths import ROOT

pytestmark = [pytest.mark.render, pytest.mark.skipif(not os.environ.get("DISPLAY"),
                                                     reason="a PyVista window needs an X display (xvfb-run)")]

CORNER = np.array([500000.0, 5400000.0, 0.0])

SCRIPT = r'''
import sys
import numpy as np
from pathlib import Path
from citylod.core.camera import Camera
from citylod.render.offscreen import OffscreenRenderer

tiles, scenario, out = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
c = np.array([500000.0, 5400000.0, 0.0])
cam = Camera((c[0] + 200.0, c[1] - 300.0, 600.0), (c[0] + 512.0, c[1] + 512.0, 0.0), (0.0, 0.0, 1.0), 50.0)
res = {}


def plotter():
    import pyvista as pv
    p = pv.Plotter(off_screen=False, window_size=(320, 240))  # a real window on the display
    p.add_mesh(pv.Sphere(), color="tomato")
    p.show(auto_close=False, interactive=False)
    return p


if scenario == "fresh":
    with OffscreenRenderer([tiles], size=(240, 160), tau_px=1.0) as r:
        f = r.render(cam, depth=True)
    res.update(rgb=f.rgb, depth=f.depth)
    import pyvista as pv
    p = plotter()
    res["shot"] = p.screenshot()
elif scenario == "edl_next_to_plotter":
    p = plotter()
    with OffscreenRenderer([tiles], size=(240, 160), tau_px=1.0, edl=True) as r:
        r.render(cam)
    with OffscreenRenderer([tiles], size=(240, 160), tau_px=1.0) as r:
        f = r.render(cam, depth=True)
    res.update(rgb=f.rgb, depth=f.depth, shot=p.screenshot())
elif scenario == "plotter_next_to_open_renderer":
    with OffscreenRenderer([tiles], size=(240, 160), tau_px=1.0) as r:
        r.render(cam)
        p = plotter()  # created and drawn while citylod's renderer is open
        shot = p.screenshot()
        f = r.render(cam, depth=True)
    res.update(rgb=f.rgb, depth=f.depth, shot=shot, shot_after=p.screenshot())
np.savez(out, **res)
'''


@pytest.fixture(scope="module")
def hills(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_terrain_tileset(tmp_path_factory.mktemp("hills"), levels=3, n=9, extent=1024.0, corner=CORNER,
                                texture_px=None)


def _run(tmp: Path, tiles: Path, scenario: str) -> dict[str, np.ndarray]:
    script = tmp / "script.py"
    script.write_text(SCRIPT, encoding="utf-8")
    out = tmp / f"{scenario}.npz"
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.run([sys.executable, str(script), str(tiles), scenario, str(out)], env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, f"{scenario} exited {proc.returncode}:\n{proc.stderr[-2000:]}"
    with np.load(out) as z:
        return dict(z)


@pytest.fixture(scope="module")
def fresh(hills: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, np.ndarray]:
    ref = _run(tmp_path_factory.mktemp("fresh"), hills, "fresh")
    assert len(np.unique(ref["rgb"].reshape(-1, 3), axis=0)) > 100, "the reference render is blank"
    assert np.isfinite(ref["depth"]).mean() > 0.5
    return ref


def _same_render(got: dict[str, np.ndarray], ref: dict[str, np.ndarray]) -> None:
    colours = len(np.unique(got["rgb"].reshape(-1, 3), axis=0))
    assert colours > 100, f"the render is blank ({colours} colours)"
    np.testing.assert_array_equal(np.isfinite(got["depth"]), np.isfinite(ref["depth"]))
    assert int(np.abs(got["rgb"].astype(int) - ref["rgb"].astype(int)).max()) <= 1


def test_renderer_after_an_edl_renderer_next_to_a_pyvista_window(hills: Path, fresh, tmp_path: Path) -> None:
    # The bug: with the window's GLX context current, the EGL renderers drew into it, and after an EDL one
    # closed, the next drew only the background.
    got = _run(tmp_path, hills, "edl_next_to_plotter")
    _same_render(got, fresh)
    np.testing.assert_array_equal(got["shot"], fresh["shot"])  # the user's window still draws its sphere


def test_pyvista_window_drawn_while_a_renderer_is_open(hills: Path, fresh, tmp_path: Path) -> None:
    # The other way round: citylod's EGL context left current made the plotter's glXMakeCurrent fail with an
    # X BadAccess error, which ends the process.
    got = _run(tmp_path, hills, "plotter_next_to_open_renderer")
    np.testing.assert_array_equal(got["shot"], fresh["shot"])
    np.testing.assert_array_equal(got["shot_after"], fresh["shot"])
    _same_render(got, fresh)
