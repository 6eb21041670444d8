"""Tilesets written by other tools (CesiumGS's 3d-tiles-tools test data, tests/data/3dtiles/SOURCE.md) open,
load every tile and put the content inside its bounding volume; formats that encode the same data differently
(Draco, quantized, oct-encoded, legacy headers, glTF 1.0, gzip, up axes) give the same geometry, compared
with CesiumGS's own reference outputs or the plain encoding; what citylod cannot decode is one clear line.
"""

from __future__ import annotations

import json
import math
import shutil
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from citylod.core.errors import InputError
from citylod.io.tiles3d import MeshData, PointData, TileContent, decode_content, encode_glb, open_tileset
from tests.paths import ROOT

DATA = ROOT / "tests" / "data" / "3dtiles"
TILESETS = sorted(p.parent.relative_to(DATA).as_posix() for p in DATA.rglob("tileset.json"))
#: Samples whose content leaves its volume by design: unit cubes turned 22.5° stick out of the box drawn
#: around the unturned ones (by 0.39 here); the WEB3D sample's box is flat at y = 0.00625, its plane at y = 0.
OVERHANG = {"InstancedAxes/InstancedAxesRotated": 0.5, "Web3dQuantized/input": 0.007, "Web3dQuantized/golden": 0.007}


def _world(path: Path) -> tuple[np.ndarray, list[np.ndarray]]:
    """All vertices and points of a tileset in its CRS (N, 3), and the point colours of each tile."""
    ts = open_tileset(path)
    parts, colours = [], []
    for t in ts.walk():
        m = t.load()
        if len(m.vertices):
            parts.append(m.vertices)
        if m.points is not None:
            parts.append(m.points)
            if m.content.points is not None and m.content.points.rgb is not None:
                colours.append(m.content.points.rgb)
    return np.concatenate(parts), colours


def _hausdorff(a: np.ndarray, b: np.ndarray) -> float:
    return float(max(cKDTree(b).query(a)[0].max(), cKDTree(a).query(b)[0].max()))


@pytest.mark.parametrize("name", TILESETS)
def test_every_tile_loads_inside_its_volume(name: str) -> None:
    ts = open_tileset(DATA / name)
    loaded = 0
    for tile in ts.walk():
        if not tile.content_paths:
            continue
        m = tile.load()
        pts = np.concatenate([a for a in (m.vertices, m.points) if a is not None and len(a)])
        assert len(pts) and np.all(np.isfinite(pts)), tile
        lo, hi = tile.box.bounds()
        outside = float(np.maximum(np.maximum(lo - pts, pts - hi), 0.0).max())
        assert outside <= OVERHANG.get(name, 1e-3 * max(1.0, float(np.linalg.norm(hi - lo)))), (tile, outside)
        loaded += 1
    assert loaded >= 1


def test_draco_point_cloud_matches_the_plain_one() -> None:
    """3DTILES_draco_point_compression: the same 1000 points and colours as the uncompressed sample, positions
    to Draco's quantization (14 bits over the 10 m cloud: 0.6 mm), colours exactly, in the same order."""
    a, ca = _world(DATA / "PointCloud/PointCloudNormals")
    b, cb = _world(DATA / "PointCloud/PointCloudDraco")
    assert len(a) == len(b) == 1000
    assert np.abs(a - b).max() < 1e-3
    assert np.array_equal(ca[0], cb[0])


def test_quantized_and_rgb565_point_clouds_match_the_plain_one() -> None:
    a, ca = _world(DATA / "PointCloud/PointCloudRGB")
    q, cq = _world(DATA / "PointCloud/PointCloudQuantized")
    assert np.abs(a - q).max() < 8.0 / 65535 * 2  # 16-bit positions over the 8 m volume
    assert np.array_equal(ca[0], cq[0])
    _, c5 = _world(DATA / "PointCloud/PointCloudRGB565")
    # 5 bits for red and blue: one step is 255/31 ≈ 8.2, and the sample's writer truncates
    assert np.abs(ca[0].astype(int) - c5[0].astype(int)).max() <= 255 / 31 + 1


def test_instance_encodings_agree() -> None:
    """i3dm: oct-encoded orientations give the float ones to the encoding's precision (2 mm on these models);
    the legacy b3dm headers give the current header's geometry."""
    a, _ = _world(DATA / "Instanced/InstancedOrientation")
    b, _ = _world(DATA / "Instanced/InstancedOct32POrientation")
    assert len(a) == len(b) and np.abs(a - b).max() < 2e-3
    ref, _ = _world(DATA / "Batched/BatchedWithoutBatchTable")
    for legacy in ("Batched/BatchedDeprecated1", "Batched/BatchedDeprecated2"):
        assert _hausdorff(ref, _world(DATA / legacy)[0]) < 1e-4


def test_instance_rotation_against_scipy() -> None:
    """InstancedAxesRotated: the instance at p is the one of InstancedAxesSimple turned by 22.5° about the axis
    along p (the sample's documentation), computed here with scipy's rotations."""
    simple = open_tileset(DATA / "InstancedAxes/InstancedAxesSimple").root.load_content().meshes
    rotated = open_tileset(DATA / "InstancedAxes/InstancedAxesRotated").root.load_content().meshes
    raw = next((DATA / "InstancedAxes/InstancedAxesSimple").glob("*.i3dm")).read_bytes()
    ft_len = struct.unpack_from("<I", raw, 12)[0]
    ft = json.loads(raw[32:32 + ft_len])
    positions = np.frombuffer(raw, np.float32, 3 * ft["INSTANCES_LENGTH"],
                              32 + ft_len + ft["POSITION"]["byteOffset"]).reshape(-1, 3).astype(float)
    assert len(simple) == len(rotated) > 0
    for a, b in zip(simple, rotated, strict=True):  # each mesh of the model, instance after instance
        blocks = a.positions.astype(float).reshape(len(positions), -1, 3)
        expected = [blk if not p.any() else
                    Rotation.from_rotvec(math.radians(22.5) * p / np.linalg.norm(p)).apply(blk - p) + p
                    for p, blk in zip(positions, blocks, strict=True)]
        assert np.abs(np.concatenate(expected) - b.positions).max() < 1e-5


def test_gzip_and_multiple_contents() -> None:
    """Gzip-compressed tileset JSON and content read as the plain ones; a tile's two contents both load."""
    plain, gz = open_tileset(DATA / "gzip/plain"), open_tileset(DATA / "gzip/gzipped")
    for a, b in zip(plain.walk(), gz.walk(), strict=True):
        assert np.array_equal(a.load().vertices, b.load().vertices)
    two = plain.root.children[0]
    assert len(two.content_paths) == 2
    each = [decode_content(p.read_bytes(), str(p)).triangle_count for p in two.content_paths]
    assert two.load_content().triangle_count == sum(each) > max(each)


def test_up_axis_and_web3d_quantization_match_cesium_upgrades() -> None:
    """gltfUpAxis X and glTF 1.0 WEB3D_quantized_attributes read as 3d-tiles-tools' upgraded tilesets."""
    for name in ("upAxis/input-x-up", "Web3dQuantized/input"):
        golden = name.replace("input", "golden")
        a, b = _world(DATA / name)[0], _world(DATA / golden)[0]
        assert len(a) == len(b) and _hausdorff(a, b) < 1e-5 * max(1.0, float(np.ptp(a, axis=0).max()))


def test_implicit_quadtree_has_every_available_content() -> None:
    ts = open_tileset(DATA / "implicit/QuadtreeSubtrees")
    names = sorted(p.name for t in ts.walk() for p in t.content_paths)
    assert names == sorted(p.name for p in (DATA / "implicit/QuadtreeSubtrees/content").iterdir())


def test_implicit_octree_from_json_subtrees(tmp_path: Path) -> None:
    """An octree of two levels, written here: the root and its 8 children, each content inside its octant."""
    (tmp_path / "c").mkdir()
    (tmp_path / "subtrees").mkdir()
    (tmp_path / "subtrees" / "0.0.0.0.json").write_text(json.dumps({
        "tileAvailability": {"constant": 1}, "contentAvailability": [{"constant": 1}],
        "childSubtreeAvailability": {"constant": 0}}))
    cube = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float32)
    for level, n in ((0, 1), (1, 2)):
        for x in range(n):
            for y in range(n):
                for z in range(n):
                    size = 8.0 / n
                    centre = (np.array([x, y, z]) + 0.5) * size
                    mesh = MeshData((cube * size * 0.4 + centre).astype(np.float32),
                                    np.array([[0, 1, 2], [5, 6, 7]], np.uint32))
                    (tmp_path / "c" / f"{level}-{x}-{y}-{z}.glb").write_bytes(encode_glb(TileContent([mesh])))
    (tmp_path / "tileset.json").write_text(json.dumps({"asset": {"version": "1.1"}, "geometricError": 8, "root": {
        "boundingVolume": {"box": [4, 4, 4, 4, 0, 0, 0, 4, 0, 0, 0, 4]}, "geometricError": 4, "refine": "REPLACE",
        "content": {"uri": "c/{level}-{x}-{y}-{z}.glb"},
        "implicitTiling": {"subdivisionScheme": "OCTREE", "subtreeLevels": 2, "availableLevels": 2,
                           "subtrees": {"uri": "subtrees/{level}.{x}.{y}.{z}.json"}}}}))
    ts = open_tileset(tmp_path)
    tiles = list(ts.walk())
    assert len(tiles) == 9 and [t.geometric_error for t in tiles] == [4.0] + [2.0] * 8
    for t in tiles:
        lo, hi = t.box.bounds()
        v = t.load().vertices
        assert np.all(v >= lo - 1e-4) and np.all(v <= hi + 1e-4), t
        assert np.allclose(hi - lo, 8.0 / 2 ** t.level)


def test_draco_and_json_gltf_content() -> None:
    """Draco (DracoPy) and meshopt (meshoptimizer) give the plain Box; a .gltf with a data-URI buffer reads."""
    plain = decode_content((DATA / "gltfJson/content.gltf").read_bytes(), "content.gltf")
    assert plain.triangle_count >= 1
    for name in ("BoxDraco.glb", "BoxMeshopt.glb"):  # KHR_draco_mesh_compression, EXT_meshopt_compression
        box = decode_content((DATA / "gltfJson" / name).read_bytes(), name)
        assert box.triangle_count == 12
        v = box.meshes[0].positions
        assert np.allclose(np.abs(v).max(axis=0), 0.5, atol=1e-3)  # the unit box of the glTF samples


def test_what_citylod_cannot_decode_is_one_clear_line(tmp_path: Path) -> None:
    doc = {"asset": {"version": "2.0"}, "extensionsRequired": ["EXT_primitive_voxels"],
           "extensionsUsed": ["EXT_primitive_voxels"]}
    with pytest.raises(InputError, match="EXT_primitive_voxels"):
        decode_content(json.dumps(doc).encode(), "voxels.gltf")
    with pytest.raises(InputError, match="package"):
        decode_content(b"PK\x03\x04" + bytes(40), "tileset.3tz")
    bad = bytearray((DATA / "PointCloud/PointCloudDraco/pointCloudDraco.pnts").read_bytes())
    ft_len = struct.unpack_from("<I", bad, 12)[0]
    bad[28 + ft_len + 8: 28 + ft_len + 64] = bytes(56)  # break the Draco stream
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no numpy warning on the way: the one line is the error
        with pytest.raises(InputError, match="Draco"):
            decode_content(bytes(bad), "broken.pnts")


def test_copied_sample_outside_its_folder_is_refused(tmp_path: Path) -> None:
    """A content URI with ../ is refused even though the file exists (safe paths stay enforced)."""
    shutil.copytree(DATA / "Composite/CompositeOfComposite", tmp_path / "t")
    doc = json.loads((tmp_path / "t/tileset.json").read_text())
    uri = doc["root"]["content"]["uri"]
    shutil.move(tmp_path / "t" / uri, tmp_path / uri)
    doc["root"]["content"]["uri"] = "../" + uri
    (tmp_path / "t/tileset.json").write_text(json.dumps(doc))
    with pytest.raises(Exception, match="outside"):
        open_tileset(tmp_path / "t")


def test_points_of_other_writers_keep_their_colour_bytes() -> None:
    """pnts RGB is sRGB (as CesiumJS draws it): read unchanged."""
    raw = (DATA / "PointCloud/PointCloudRGB/pointCloudRGB.pnts").read_bytes()
    ft_len = struct.unpack_from("<I", raw, 12)[0]
    ft = json.loads(raw[28:28 + ft_len])
    off = 28 + ft_len + ft["RGB"]["byteOffset"]
    rgb = np.frombuffer(raw, np.uint8, count=3000, offset=off).reshape(-1, 3)
    pts = decode_content(raw, "pointCloudRGB.pnts").points
    assert isinstance(pts, PointData) and np.array_equal(pts.rgb, rgb)
