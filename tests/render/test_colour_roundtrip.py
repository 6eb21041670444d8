"""A point of known sRGB colour, written by citylod and drawn by citylod, has that pixel value; the file holds
its linear equivalent, as glTF 2.0 defines COLOR_0 (so every conformant client shows the same colour)."""

from __future__ import annotations

import json
import struct

import numpy as np
import pyproj

from citylod.core.camera import Camera
from citylod.io.tiles3d import PointData, TileContent, TileSpec, write_content, write_tileset
from citylod.render.offscreen import OffscreenRenderer

COLOURS = np.array([[203, 182, 107], [10, 20, 30], [250, 128, 3]], np.uint8)  # a field, dark, saturated


def _srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1, written out here independently of citylod.io.tiles3d.colour."""
    s = c / 255.0
    return np.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4)


def _write(tmp_path, rgb: np.ndarray):
    g = np.stack(np.meshgrid(np.linspace(-5, 5, 120), np.linspace(-5, 5, 120)), -1).reshape(-1, 2)
    pos = np.column_stack([g, np.zeros(len(g))]).astype(np.float32)
    centre = np.array([500000.0, 5400000.0, 100.0])
    uri = write_content(tmp_path, "0", TileContent(points=PointData(pos, rgb=np.tile(rgb, (len(pos), 1)))))
    spec = TileSpec("0", 0, centre, centre - [5, 5, 1], centre + [5, 5, 1], 0.0, content=uri)
    write_tileset(tmp_path, spec, pyproj.CRS.from_epsg(32632), extras={"citylod": {"kind": "points"}})
    return tmp_path / uri, centre


def test_stored_colour_is_linear(tmp_path) -> None:
    for i, rgb in enumerate(COLOURS):
        path, _ = _write(tmp_path / str(i), rgb)
        data = path.read_bytes()
        jlen = struct.unpack_from("<I", data, 12)[0]
        gltf = json.loads(data[20:20 + jlen])
        prim = gltf["meshes"][0]["primitives"][0]
        acc = gltf["accessors"][prim["attributes"]["COLOR_0"]]
        view = gltf["bufferViews"][acc["bufferView"]]
        assert acc["normalized"] and acc["componentType"] == 5123 and acc["type"] == "VEC3"
        start = 20 + jlen + 8 + view.get("byteOffset", 0)
        first = np.frombuffer(data, np.uint16, 3, start) / 65535.0
        assert np.abs(first - _srgb_to_linear(rgb.astype(float))).max() < 1 / 65535


def test_drawn_colour_is_the_written_srgb(tmp_path) -> None:
    for i, rgb in enumerate(COLOURS):
        _, centre = _write(tmp_path / str(i), rgb)
        with OffscreenRenderer([tmp_path / str(i)], size=(64, 64), point_size_px=6.0, workers=1) as r:
            cam = Camera(tuple(centre + [0.0, -0.01, 8.0]), tuple(centre))
            frame = r.render(cam, full_resolution=True)
        assert np.array_equal(frame.rgb[32, 32], rgb), (frame.rgb[32, 32], rgb)
