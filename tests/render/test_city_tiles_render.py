"""City tilesets drawn and picked like any other geometry: the sample city's buildings as 3D Tiles.

The building expected under a pixel comes from the sample city's analytic geometry (its roof centre), never
from the tiles or the proxies under test.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from citylod.core.camera import Camera
from citylod.lod.build.city import build_city_tiles
from citylod.render.offscreen import OffscreenRenderer, save_png
from citylod.render.semantic import SemanticOverlay
from citylod.sample import SampleInfo
from citylod.semantics.store import CityStore, build_city

pytestmark = pytest.mark.render

SIZE = (320, 240)


@pytest.fixture(scope="module")
def city(sample_city: SampleInfo, tmp_path_factory: pytest.TempPathFactory) -> SimpleNamespace:
    out = tmp_path_factory.mktemp("city_tiles_render")
    build_city_tiles(sample_city.files["city"], out / "tiles", leaf_triangles=20, progress=False)
    build_city(sample_city.files["city"], out / "city.gpkg", progress=False)
    return SimpleNamespace(tiles=out / "tiles", gpkg=out / "city.gpkg", truth=sample_city.city)


def test_pick_on_city_tiles_returns_the_building_under_its_roof(city: SimpleNamespace, tmp_path: Path) -> None:
    store = CityStore.open(city.gpkg)
    picked = 0
    with OffscreenRenderer([city.tiles], size=SIZE) as r:
        overlay = SemanticOverlay(r.scene, store)
        for b in city.truth.buildings:
            cx, cy = b.center
            cz = float(city.truth.roof_height(np.array([cx]), np.array([cy]))[0])
            if b.hole is not None or not np.isfinite(cz):  # the centre is not on the roof
                continue
            eye = (cx + 30.0, cy - 40.0, cz + 45.0)
            frame = r.render(Camera(eye, (cx, cy, cz), (0.0, 0.0, 1.0), 45.0))
            assert frame.stats.tiles >= 1 and frame.stats.max_sse_px <= 1.0
            ren = r.renderer
            ren.SetWorldPoint(*(np.array([cx, cy, cz]) - r.scene.origin), 1.0)
            ren.WorldToDisplay()
            x, y, _ = ren.GetDisplayPoint()
            hit = overlay.pick(ren, int(round(x)), int(round(y)))
            assert hit.object_id == b.id
            assert hit.attributes["name"] == b.name
            # The hit lies on the drawn roof (the tiles carry the model's own surfaces), up to the depth
            # buffer's resolution at ~70 m and half a pixel (~0.15 m) along a roof sloped up to 45°.
            assert np.linalg.norm(hit.point_xyz - [cx, cy, cz]) < 1.0
            # ... drawn in the roof colour (brick red: red well above green and blue).
            rgb = frame.rgb[SIZE[1] - 1 - int(round(y)), int(round(x))].astype(int)
            assert rgb[0] > rgb[1] + 30 and rgb[0] > rgb[2] + 30
            picked += 1
            save_png(tmp_path / f"{b.id}.png", frame.rgb)
        overlay.close()
    store.close()
    assert picked >= 3


def test_closed_houses_drawn_single_sided_look_the_same(city: SimpleNamespace) -> None:
    """The sample's houses are written single-sided and drawn with back faces culled. From outside (an oblique
    view over the city, and one down a street) the picture is the one drawn with back faces: the same pixels
    at the same depth."""
    from citylod.io.tiles3d import open_tileset
    from tests.render.test_dsm import _frame

    lo, hi = open_tileset(city.tiles).bounds
    c = (lo + hi) / 2
    ext = float(hi[0] - lo[0])
    cams = [Camera((c[0] - ext, c[1] - ext, hi[2] + 0.6 * ext), tuple(c), (0.0, 0.0, 1.0), 45.0),
            Camera((lo[0] - 5.0, c[1], lo[2] + 3.0), (hi[0], c[1], lo[2] + 3.0), (0.0, 0.0, 1.0), 60.0)]
    with OffscreenRenderer([city.tiles], size=SIZE) as r:
        for cam in cams:
            rgb, depth, share = _frame(r, cam, None)
            assert share == 1.0
            rgb2, depth2, _ = _frame(r, cam, False)
            covered = np.isfinite(depth2)
            assert covered.mean() > 0.05
            assert np.array_equal(np.isfinite(depth), covered)
            assert np.abs(depth[covered] - depth2[covered]).max() <= 1e-3 * depth2[covered].max()
            assert (np.abs(rgb - rgb2).max(axis=2) > 8).mean() < 2e-3
