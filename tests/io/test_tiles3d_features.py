"""EXT_mesh_features / EXT_structural_metadata round trips, checked in the glb's own JSON and bytes."""

from __future__ import annotations

import json
import struct

import numpy as np

from citylod.io.tiles3d import FeatureIdSet, MeshData, PropertyTable, TileContent, decode_glb, encode_glb


def test_feature_ids_and_property_tables_round_trip() -> None:
    ids = np.array([0, 0, 1, 1], np.uint32)
    mesh = MeshData(np.zeros((4, 3), np.float32), np.array([[0, 1, 2], [1, 2, 3]], np.uint32),
                    features=[FeatureIdSet(ids, 0, 2, "city_object")])
    table = PropertyTable("city_object", {
        "object_id": ["a", "bé"], "height": np.array([1.5, np.nan]), "storeys": np.array([3, -(2**31)], np.int32),
        "name": [None, None],  # no value in any row: left out of the table, read back as None
    })
    data = encode_glb(TileContent([mesh], property_tables=[table]))
    jlen = struct.unpack_from("<I", data, 12)[0]
    gltf = json.loads(data[20:20 + jlen])
    ext = gltf["extensions"]["EXT_structural_metadata"]
    assert set(gltf["extensionsUsed"]) >= {"EXT_mesh_features", "EXT_structural_metadata"}
    assert set(ext["propertyTables"][0]["properties"]) == {"object_id", "height", "storeys"}
    for prop in ext["propertyTables"][0]["properties"].values():  # 8-byte aligned values, as the spec asks
        assert gltf["bufferViews"][prop["values"]].get("byteOffset", 0) % 8 == 0
    prim = gltf["meshes"][0]["primitives"][0]
    assert prim["extensions"]["EXT_mesh_features"]["featureIds"] == [
        {"featureCount": 2, "attribute": 0, "propertyTable": 0, "label": "city_object"}]
    back = decode_glb(data, "x.glb")
    np.testing.assert_array_equal(back.meshes[0].features[0].ids, ids)
    t = back.property_tables[0]
    assert t.row(0) == {"object_id": "a", "height": 1.5, "storeys": 3, "name": None}
    assert t.row(1) == {"object_id": "bé", "height": None, "storeys": None, "name": None}
