"""Picking on the Delft CityJSON's tileset returns the building an independent parse puts at that place.

The expected building and its attributes come from the file read with the json module and shapely (the
roof polygon's interior point), never from citylod's reader, tiles or proxies.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import shapely

from citylod.core.camera import Camera
from citylod.lod.build.city import build_city_tiles
from citylod.render.offscreen import OffscreenRenderer
from citylod.render.semantic import SemanticOverlay
from citylod.semantics.store import CityStore, build_city
from tests.paths import SHARED_DATA

pytestmark = [
    pytest.mark.realdata, pytest.mark.render,
    pytest.mark.skipif(not SHARED_DATA.is_dir(), reason=f"real data folder {SHARED_DATA} is absent"),
]


def _roofs(doc: dict) -> list[tuple[str, shapely.Polygon, float, dict]]:
    """(id, top face as a 2D polygon, its height, attributes) of each Building with a horizontal top."""
    v = np.asarray(doc["vertices"], float)
    tr = doc.get("transform")
    if tr:
        v = v * tr["scale"] + tr["translate"]
    out = []
    for oid, obj in doc["CityObjects"].items():
        if obj["type"] != "Building":
            continue
        for g in obj.get("geometry", []):
            shells = g["boundaries"] if g["type"] == "Solid" else [g["boundaries"]]
            faces = [f for shell in shells for f in shell]
            tops = []
            for face in faces:
                ring = v[np.asarray(face[0])]
                if np.ptp(ring[:, 2]) < 1e-6:
                    tops.append((float(ring[0, 2]), ring))
            if tops:
                z = max(t[0] for t in tops)  # the top may be split into many faces (triangulated)
                poly = shapely.union_all([shapely.Polygon(ring[:, :2]).buffer(0) for zt, ring in tops
                                          if zt > z - 1e-3])
                if poly.geom_type == "Polygon" and poly.area > 40:
                    out.append((oid, poly, z, obj.get("attributes", {})))
            break
    return out


def test_pick_on_delft_tiles_matches_an_independent_parse(tmp_path: Path) -> None:
    src = SHARED_DATA / "delft" / "testarea.city.json"
    build_city_tiles(src, tmp_path / "tiles", leaf_triangles=4000, progress=False)
    build_city(src, tmp_path / "city.gpkg", progress=False)
    roofs = _roofs(json.loads(src.read_text()))
    assert len(roofs) > 50
    store = CityStore.open(tmp_path / "city.gpkg")
    size = (320, 240)
    picked = 0
    with OffscreenRenderer([tmp_path / "tiles"], size=size) as r:
        overlay = SemanticOverlay(r.scene, store)
        for oid, poly, z, attrs in roofs[::8]:
            p = poly.buffer(-1.0)
            if p.is_empty:
                continue
            q = p.representative_point()
            target = np.array([q.x, q.y, z])
            r.render(Camera(tuple(target + [0.0, -20.0, 60.0]), tuple(target), (0.0, 0.0, 1.0), 40.0))
            ren = r.renderer
            ren.SetWorldPoint(*(target - r.scene.origin), 1.0)
            ren.WorldToDisplay()
            x, y, _ = ren.GetDisplayPoint()
            hit = overlay.pick(ren, int(round(x)), int(round(y)))
            assert hit.object_id == oid
            assert hit.attributes.get("measured_height") == pytest.approx(attrs.get("measuredHeight"))
            assert np.linalg.norm(hit.point_xyz - target) < 1.0
            picked += 1
        overlay.close()
    store.close()
    assert picked >= 10
