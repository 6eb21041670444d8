"""3D Tiles I/O: glb round trips, tileset placement, safe paths, corrupt content."""

from __future__ import annotations

import json
import struct

import numpy as np
import pyproj
import pytest

from citylod.core.errors import InputError, UnsafePathError
from citylod.io.tiles3d import (
    MeshData,
    PointData,
    TileContent,
    TileSpec,
    decode_content,
    decode_glb,
    encode_glb,
    open_tileset,
    write_content,
    write_tileset,
)

UTM = pyproj.CRS.from_epsg(32632)


def _mesh(rng: np.random.Generator) -> MeshData:
    pos = rng.uniform(-50, 50, (10, 3)).astype(np.float32)
    faces = np.array([[0, 1, 2], [2, 3, 4], [5, 6, 7], [7, 8, 9]], np.uint32)
    return MeshData(pos, faces, skirt=np.array([False, False, True, True]),
                    uv=rng.uniform(0, 1, (10, 2)).astype(np.float32), texture=b"\xff\xd8\xff\xe0fakejpeg")


def test_glb_roundtrip_mesh_and_points() -> None:
    rng = np.random.default_rng(1)
    mesh = _mesh(rng)
    pts = PointData(rng.uniform(-5, 5, (100, 3)).astype(np.float32),
                    rgb=rng.integers(0, 255, (100, 3), dtype=np.uint8),
                    intensity=rng.integers(0, 60000, 100, dtype=np.uint16),
                    classification=rng.integers(0, 20, 100, dtype=np.uint8),
                    extra={"object_id": rng.integers(-1, 5000, 100).astype(np.int32)})
    data = encode_glb(TileContent([mesh], pts))
    assert data[:4] == b"glTF" and len(data) % 4 == 0
    back = decode_glb(data, "x.glb")
    assert len(back.meshes) == 1
    m = back.meshes[0]
    # surface and skirt primitives come back as one mesh with the skirt flags
    order = np.argsort(m.skirt, kind="stable")
    np.testing.assert_array_equal(m.skirt[order], mesh.skirt)
    np.testing.assert_array_equal(m.positions, mesh.positions)
    np.testing.assert_array_equal(np.sort(m.faces, axis=0), np.sort(mesh.faces, axis=0))
    assert m.texture == mesh.texture
    np.testing.assert_array_equal(back.points.positions, pts.positions)
    np.testing.assert_array_equal(back.points.rgb, pts.rgb)
    np.testing.assert_array_equal(back.points.intensity, pts.intensity)
    np.testing.assert_array_equal(back.points.classification, pts.classification)
    np.testing.assert_array_equal(back.points.extra["object_id"], pts.extra["object_id"])
    assert back.points.extra["object_id"].dtype == np.int32


def _vertex_attribute_layout_errors(data: bytes) -> list[str]:
    """glTF 2.0 §3.6.2.4 data alignment, checked from the file's own JSON: every vertex attribute element
    starts on a 4-byte boundary of the buffer (accessor and bufferView offsets, effective stride), and the
    view holds every element."""
    jlen = struct.unpack_from("<I", data, 12)[0]
    gltf = json.loads(data[20:20 + jlen])
    sizes = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
    ncomp = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
    errors = []
    for mesh in gltf["meshes"]:
        for prim in mesh["primitives"]:
            for name, index in prim["attributes"].items():
                acc = gltf["accessors"][index]
                bv = gltf["bufferViews"][acc["bufferView"]]
                elem = sizes[acc["componentType"]] * ncomp[acc["type"]]
                stride = bv.get("byteStride", elem)
                start = bv.get("byteOffset", 0) + acc.get("byteOffset", 0)
                if start % 4 or stride % 4 or stride < elem:
                    errors.append(f"{name}: offset {start}, stride {stride}, element {elem} bytes")
                if acc.get("byteOffset", 0) + stride * (acc["count"] - 1) + elem > bv["byteLength"]:
                    errors.append(f"{name}: view too short")
    return errors


def test_vertex_attributes_are_4_byte_aligned() -> None:
    """Point tiles carry 1-, 2- and 3-byte attributes (classification, intensity, RGB8), which glTF only
    allows padded to 4-byte elements; they round-trip unchanged."""
    rng = np.random.default_rng(3)
    for n in (1, 7, 100):
        pts = PointData(rng.uniform(-5, 5, (n, 3)).astype(np.float32),
                        rgb=rng.integers(0, 255, (n, 3), dtype=np.uint8),
                        intensity=rng.integers(0, 65535, n, dtype=np.uint16),
                        classification=rng.integers(0, 20, n, dtype=np.uint8),
                        return_number=rng.integers(1, 5, n, dtype=np.uint8),
                        extra={"flag": rng.integers(0, 2, n).astype(np.uint8),
                               "w": rng.integers(0, 999, n).astype(np.uint16)})
        data = encode_glb(TileContent([_mesh(rng)], pts))
        assert _vertex_attribute_layout_errors(data) == []
        back = decode_glb(data, "x.glb").points
        assert back is not None
        for attr in ("positions", "rgb", "intensity", "classification", "return_number"):
            np.testing.assert_array_equal(getattr(back, attr), getattr(pts, attr))
        for name in ("flag", "w"):
            np.testing.assert_array_equal(back.extra[name], pts.extra[name])


def test_point_attributes_absent_or_converted() -> None:
    """Point content with only some attributes, given in other dtypes (int64 intensity, a column slice of
    positions): the absent ones are not written, the others come back converted as ``np.asarray`` would,
    and POSITION's min/max are the extremes of the stored y-up positions."""
    rng = np.random.default_rng(4)
    n = 257
    block = rng.uniform(-1e3, 1e3, (n, 5))
    pts = PointData(block[:, 1:4],  # type: ignore[arg-type]  # float64, not contiguous: the encoder converts
                    intensity=rng.integers(0, 65535, n), classification=rng.integers(0, 20, n).astype(np.int32))
    data = encode_glb(TileContent(points=pts))
    assert _vertex_attribute_layout_errors(data) == []
    jlen = struct.unpack_from("<I", data, 12)[0]
    gltf = json.loads(data[20:20 + jlen])
    attrs = gltf["meshes"][0]["primitives"][0]["attributes"]
    assert set(attrs) == {"POSITION", "_INTENSITY", "_CLASSIFICATION", "_FEATURE_ID_0"}
    assert attrs["_FEATURE_ID_0"] == attrs["_CLASSIFICATION"]  # the class is the feature ID, no extra bytes
    back = decode_glb(data, "x.glb").points
    assert back is not None and back.rgb is None and back.return_number is None
    np.testing.assert_array_equal(back.positions, block[:, 1:4].astype(np.float32))
    np.testing.assert_array_equal(back.intensity, pts.intensity.astype(np.uint16))
    np.testing.assert_array_equal(back.classification, pts.classification.astype(np.uint8))
    p32 = block[:, 1:4].astype(np.float32)
    y_up = np.stack([p32[:, 0], p32[:, 2], -p32[:, 1]], axis=1)
    acc = gltf["accessors"][attrs["POSITION"]]
    assert acc["min"] == [float(v) for v in y_up.min(axis=0)]
    assert acc["max"] == [float(v) for v in y_up.max(axis=0)]


def test_glb_is_y_up_on_disk() -> None:
    """3D Tiles clients turn glTF y-up into z-up: a z-up point (1, 2, 3) is stored as (1, 3, -2)."""
    mesh = MeshData(np.array([[1, 2, 3], [0, 0, 0], [1, 0, 0]], np.float32), np.array([[0, 1, 2]], np.uint32))
    data = encode_glb(TileContent([mesh]))
    jlen = struct.unpack_from("<I", data, 12)[0]
    gltf = json.loads(data[20:20 + jlen])
    acc = gltf["accessors"][gltf["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]
    assert acc["max"] == [1.0, 3.0, 0.0] and acc["min"] == [0.0, 0.0, -2.0]


def _tree(tmp_path, x0=500_000.0, y0=5_400_000.0):
    rng = np.random.default_rng(2)
    children = []
    for i in range(2):
        c = np.array([x0 + 50 + 100 * i, y0 + 50, 100.0])
        content = TileContent([MeshData(rng.uniform(-50, 50, (3, 3)).astype(np.float32),
                                        np.array([[0, 1, 2]], np.uint32))])
        uri = write_content(tmp_path, f"1/{i}/0", content)
        children.append(TileSpec(f"1/{i}/0", 1, c, c - 50, c + 50, 0.5, uri))
    rc = np.array([x0 + 100, y0 + 50, 100.0])
    root_content = TileContent([MeshData(np.array([[-100, -50, 0], [100, -50, 0], [0, 50, 0]], np.float32),
                                         np.array([[0, 1, 2]], np.uint32))])
    uri = write_content(tmp_path, "0/0/0", root_content)
    root = TileSpec("0/0/0", 0, rc, rc - [100, 50, 50], rc + [100, 50, 50], 2.0, uri, children)
    return write_tileset(tmp_path, root, UTM, extras={"citylod": {"kind": "dsm"}})


def test_tileset_roundtrip_in_source_crs(tmp_path) -> None:
    _tree(tmp_path)
    ts = open_tileset(tmp_path)
    assert ts.crs.to_epsg() == 32632
    assert ts.kind == "dsm"
    tiles = list(ts.walk())
    assert [t.level for t in tiles] == [0, 1, 1]
    assert [t.geometric_error for t in tiles] == [2.0, 0.5, 0.5]
    lo, hi = ts.root.bounds
    # bounds come back in the source CRS at large coordinates, to well under a millimetre
    np.testing.assert_allclose(lo, [500_000.0, 5_400_000.0, 50.0], atol=1e-6)
    np.testing.assert_allclose(hi, [500_200.0, 5_400_100.0, 150.0], atol=1e-6)
    mesh = ts.root.load()
    np.testing.assert_allclose(mesh.vertices[0], [500_000.0, 5_400_000.0, 100.0], atol=1e-6)
    assert mesh.faces.shape == (1, 3) and not mesh.skirt.any()
    child_lo, _ = tiles[2].bounds
    np.testing.assert_allclose(child_lo, [500_100.0, 5_400_000.0, 50.0], atol=1e-6)


def test_root_transform_places_data_on_the_globe(tmp_path) -> None:
    path = _tree(tmp_path)
    doc = json.loads(path.read_text())
    m = np.asarray(doc["root"]["transform"]).reshape(4, 4).T
    ecef = m[:3, 3]
    lon, lat, h = pyproj.Transformer.from_crs(4978, 4326, always_xy=True).transform(*ecef)
    elon, elat = pyproj.Transformer.from_crs(UTM, 4326, always_xy=True).transform(500_100.0, 5_400_050.0)
    assert abs(lon - elon) < 1e-7 and abs(lat - elat) < 1e-7 and abs(h - 100.0) < 1e-3


@pytest.mark.parametrize("uri", ["../outside.glb", "/etc/passwd", "http://example.com/a.glb",
                                 "file:///etc/passwd", "tiles/../../x.glb", "%2e%2e/x.glb"])
def test_uris_outside_the_folder_are_refused(tmp_path, uri) -> None:
    doc = {"asset": {"version": "1.1"}, "geometricError": 1,
           "root": {"boundingVolume": {"box": [0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1]}, "geometricError": 1,
                    "content": {"uri": uri}}}
    (tmp_path / "tileset.json").write_text(json.dumps(doc))
    with pytest.raises(UnsafePathError, match="tileset.json"):
        open_tileset(tmp_path)


def test_bad_tilesets_and_content_are_clear_errors(tmp_path) -> None:
    with pytest.raises(InputError, match="not found"):
        open_tileset(tmp_path / "nothing")
    (tmp_path / "tileset.json").write_text("{broken")
    with pytest.raises(InputError, match="not valid JSON"):
        open_tileset(tmp_path)
    with pytest.raises(InputError, match="truncated"):
        decode_glb(encode_glb(TileContent([_mesh(np.random.default_rng(0))]))[:50], "cut.glb")
    with pytest.raises(InputError, match="unknown tile content"):
        decode_content(b"junkjunkjunk", "junk.bin")


def test_foreign_tileset_with_region_and_b3dm(tmp_path) -> None:
    """A tileset another tool wrote: ECEF, region volume, b3dm content with RTC_CENTER."""
    mesh = MeshData(np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0]], np.float32), np.array([[0, 1, 2]], np.uint32))
    glb = encode_glb(TileContent([mesh]))
    ft = json.dumps({"BATCH_LENGTH": 0, "RTC_CENTER": [4_000_000.0, 600_000.0, 4_900_000.0]}).encode()
    ft += b" " * (-(28 + len(ft)) % 8)
    b3dm = struct.pack("<4sIIIIII", b"b3dm", 1, 28 + len(ft) + len(glb), len(ft), 0, 0, 0) + ft + glb
    (tmp_path / "a.b3dm").write_bytes(b3dm)
    doc = {"asset": {"version": "1.0"}, "geometricError": 100,
           "root": {"boundingVolume": {"region": [0.15, 0.87, 0.1501, 0.8701, 0, 50]}, "geometricError": 10,
                    "refine": "ADD", "content": {"uri": "a.b3dm"}}}
    (tmp_path / "tileset.json").write_text(json.dumps(doc))
    ts = open_tileset(tmp_path)
    assert ts.crs.to_epsg() == 4978 and ts.root.refine == "ADD"
    v = ts.root.load().vertices
    np.testing.assert_allclose(v[1], [4_000_010.0, 600_000.0, 4_900_000.0], atol=1e-6)
    lo, hi = ts.root.bounds
    assert np.all(hi - lo > 0) and np.linalg.norm(lo) > 6e6


def test_mipmaps_only_for_power_of_two_textures() -> None:
    """WebGL 1 clients cannot mipmap a 131×126 plane-quad atlas: such textures get a LINEAR sampler."""
    from citylod.io.image import encode_image

    for (h, w), fmt, min_filter in (((126, 131), "png", 9729), ((64, 128), "png", 9987),
                                    ((100, 130), "jpg", 9729), ((256, 256), "jpg", 9987)):
        png = encode_image(np.zeros((h, w, 3), np.uint8), fmt)
        mesh = MeshData(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32), np.array([[0, 1, 2]], np.uint32),
                        uv=np.array([[0, 0], [1, 0], [0, 1]], np.float32), texture=png)
        data = encode_glb(TileContent([mesh]))
        jlen = struct.unpack_from("<I", data, 12)[0]
        sampler = json.loads(data[20:20 + jlen])["samplers"][0]
        assert sampler["minFilter"] == min_filter, (w, h)


def _with_json(data: bytes, edit) -> bytes:
    """The glb ``data`` with its JSON chunk replaced by ``edit(json)`` (padded; the binary chunk kept)."""
    jlen = struct.unpack_from("<I", data, 12)[0]
    doc = edit(json.loads(data[20:20 + jlen]))
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    rest = data[20 + jlen:]
    body = struct.pack("<I4s", len(js), b"JSON") + js + rest
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def _up_normals(mesh: MeshData) -> np.ndarray:
    p = mesh.positions.astype(np.float64)
    f = mesh.faces.astype(np.int64)
    return np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])[:, 2]


def test_single_sided_materials_round_trip_and_mirrored_nodes_keep_their_front() -> None:
    """``double_sided`` is the glTF material's ``doubleSided`` both ways; a primitive without a material is
    single-sided (glTF's default material). A node that mirrors (scale −1 on x) turns its front faces
    clockwise (glTF 2.0 §3.7.4): decoded with the transform baked into the positions, the triangles come
    back reversed, so the side that faced up still faces up."""
    tri = MeshData(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32), np.array([[0, 1, 2]], np.uint32),
                   double_sided=False)
    assert _up_normals(tri)[0] > 0  # counter-clockwise seen from above
    one = encode_glb(TileContent([tri]))
    both = encode_glb(TileContent([MeshData(tri.positions, tri.faces)]))
    assert decode_glb(one).meshes[0].double_sided is False
    assert decode_glb(both).meshes[0].double_sided is True

    def no_material(doc):
        for prim in doc["meshes"][0]["primitives"]:
            prim.pop("material", None)
        return doc

    assert decode_glb(_with_json(both, no_material)).meshes[0].double_sided is False

    def mirror(doc):
        doc["nodes"][0]["scale"] = [-1.0, 1.0, 1.0]
        return doc

    mirrored = decode_glb(_with_json(one, mirror)).meshes[0]
    assert mirrored.positions[:, 0].min() == -1.0  # the mirror was applied
    assert _up_normals(mirrored)[0] > 0, mirrored.faces  # and the front still faces up
