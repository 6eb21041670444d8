"""Point tiles describe class, intensity and return number with EXT_structural_metadata (the class also as
an EXT_mesh_features feature ID), and a cloud without RGB carries the class colours its coarse quads are
baked with, so other clients show one look at every level."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from citylod.core.palette import ASPRS_CLASS_RGB
from citylod.io.tiles3d import open_tileset
from citylod.lod.build.points import build_points
from tests.lod.test_points_cloud import make_cloud


def _gltf(path) -> tuple[dict, bytes]:
    data = path.read_bytes()
    jlen = struct.unpack_from("<I", data, 12)[0]
    return json.loads(data[20:20 + jlen]), data[20 + jlen + 8:]


def _column(gltf: dict, binary: bytes, index: int, dtype, ncomp: int) -> np.ndarray:
    acc = gltf["accessors"][index]
    view = gltf["bufferViews"][acc["bufferView"]]
    stride = view.get("byteStride", np.dtype(dtype).itemsize * ncomp)
    raw = np.frombuffer(binary, np.uint8, acc["count"] * stride, view.get("byteOffset", 0))
    return raw.reshape(acc["count"], stride)[:, :np.dtype(dtype).itemsize * ncomp].copy().view(dtype)


@pytest.fixture(scope="module")
def no_rgb(tmp_path_factory: pytest.TempPathFactory):
    d = tmp_path_factory.mktemp("points_no_rgb")
    make_cloud(d / "cloud.laz", n_terrain=8_000, rgb=False)
    build_points([d / "cloud.laz"], d / "tiles", workers=0, progress=False, max_leaf_points=2_000)
    return d / "tiles"


def test_point_attributes_are_property_attributes(no_rgb) -> None:
    ts = open_tileset(no_rgb)
    leaf = next(t for t in ts.walk() if t.content_paths and not t.children)
    gltf, binary = _gltf(leaf.content_paths[0])
    meta = gltf["extensions"]["EXT_structural_metadata"]
    props = meta["schema"]["classes"]["point"]["properties"]
    assert props["classification"]["componentType"] == "UINT8" and props["intensity"]["componentType"] == "UINT16"
    assert "EXT_structural_metadata" in gltf["extensionsUsed"]
    prim = next(p for p in gltf["meshes"][0]["primitives"] if p["mode"] == 0)
    (index,) = prim["extensions"]["EXT_structural_metadata"]["propertyAttributes"]
    attrs = meta["propertyAttributes"][index]["properties"]
    cls = _column(gltf, binary, prim["attributes"][attrs["classification"]["attribute"]], np.uint8, 1)[:, 0]
    # the property attribute is the point's LAS class, as citylod reads it back
    assert np.array_equal(cls, leaf.load_content().points.classification)
    assert set(np.unique(cls)) <= {1, 2, 6}
    # the class is also the EXT_mesh_features feature ID, one feature per class present
    (fid,) = prim["extensions"]["EXT_mesh_features"]["featureIds"]
    assert prim["attributes"][f"_FEATURE_ID_{fid['attribute']}"] == prim["attributes"]["_CLASSIFICATION"]
    assert fid["featureCount"] == len(np.unique(cls))


def test_cloud_without_rgb_carries_its_class_colours(no_rgb) -> None:
    for tile in open_tileset(no_rgb).walk():
        if not tile.content_paths:
            continue
        gltf, binary = _gltf(tile.content_paths[0])
        prim = next((p for p in gltf["meshes"][0]["primitives"] if p["mode"] == 0), None)
        if prim is None:
            continue
        acc = gltf["accessors"][prim["attributes"]["COLOR_0"]]
        assert acc["normalized"] and acc["componentType"] == 5121
        lin = _column(gltf, binary, prim["attributes"]["COLOR_0"], np.uint8, 3) / 255.0
        cls = _column(gltf, binary, prim["attributes"]["_CLASSIFICATION"], np.uint8, 1)[:, 0]
        srgb = np.where(lin <= 0.0031308, lin * 12.92, 1.055 * lin ** (1 / 2.4) - 0.055) * 255.0
        assert np.abs(srgb - ASPRS_CLASS_RGB[cls]).max() < 6  # 8-bit linear: coarse in the darkest steps
        assert tile.load_content().points.rgb is None  # citylod keeps colouring by class itself
