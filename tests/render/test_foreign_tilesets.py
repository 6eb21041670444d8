"""Tilesets written by other tools draw: ECEF content (RTC centres, regions) seen from 30 m, which the float32
rounding of ECEF positions and a relative camera tolerance both used to break."""

from __future__ import annotations

import numpy as np
import pytest

from citylod.core.camera import Camera
from citylod.io.tiles3d import open_tileset
from citylod.render.offscreen import OffscreenRenderer
from tests.paths import ROOT

DATA = ROOT / "tests" / "data" / "3dtiles"


@pytest.mark.parametrize("name", ["Batched/BatchedWithoutBatchTable", "Instanced/InstancedOrientation",
                                  "PointCloud/PointCloudDraco", "Composite/CompositeOfInstanced"])
def test_foreign_ecef_tileset_draws(name: str) -> None:
    ts = open_tileset(DATA / name)
    lo, hi = ts.bounds
    centre = (lo + hi) / 2.0
    up = centre / np.linalg.norm(centre)
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    extent = float(np.linalg.norm(hi - lo))
    eye = centre + up * extent * 0.8 - north * extent * 0.8
    with OffscreenRenderer([DATA / name], size=(192, 128), point_size_px=3.0, workers=1) as r:
        frame = r.render(Camera(tuple(eye), tuple(centre), tuple(up)), full_resolution=True)
    background = frame.rgb[0, 0]
    drawn = np.any(frame.rgb != background, axis=2)
    assert drawn.mean() > 0.003, name
    rows, cols = np.nonzero(drawn)
    # the content lies around the focal point: the drawn pixels straddle the image centre
    assert rows.min() < 64 < rows.max() and cols.min() < 96 < cols.max()


def test_foreign_ecef_tileset_renders_without_a_camera(tmp_path) -> None:
    """``citylod render DIR -o OUT`` on another tool's ECEF tileset: the content framed, nothing cut."""
    from citylod.cli import main

    d = tmp_path / "d.npy"
    assert main(["-q", "render", str(DATA / "Batched/BatchedWithoutBatchTable"), "-o", str(tmp_path / "o.png"),
                 "--size", "192x128", "--depth", str(d)]) == 0
    seen = np.isfinite(np.load(d))
    assert seen.mean() > 0.003
    rows, cols = np.nonzero(seen)
    assert 0 < rows.min() and rows.max() < 127 and 0 < cols.min() and cols.max() < 191
