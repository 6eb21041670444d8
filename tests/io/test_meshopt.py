"""EXT_meshopt_compression content written by other tools (gltfpack 1.3.0, glTF-Transform; tests/data/3dtiles/SOURCE.md)
gives the geometry of the uncompressed original, within the quantization those tools chose."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from citylod.core.errors import InputError
from citylod.io.tiles3d import decode_content, open_tileset
from citylod.io.tiles3d.gltf import _read_accessor
from tests.paths import ROOT

DATA = ROOT / "tests" / "data" / "3dtiles"
MO = DATA / "meshopt"


def _content(path: Path):  # type: ignore[no-untyped-def]
    return decode_content(path.read_bytes(), str(path), resolve=lambda uri: (path.parent / uri).read_bytes())


def _positions(content) -> np.ndarray:  # type: ignore[no-untyped-def]
    return np.concatenate([m.positions.astype(np.float64) for m in content.meshes]) + content.origin


def _same_triangles(a, b, tol: float) -> bool:  # type: ignore[no-untyped-def]
    """Whether ``b`` has ``a``'s triangles with the same winding, each vertex of ``b`` taken as ``a``'s nearest."""
    pa, pb = _positions(a), _positions(b)
    dist, near = cKDTree(pa).query(pb)
    assert dist.max() <= tol

    def faces(content, index):  # type: ignore[no-untyped-def]
        out, offset = set(), 0
        for m in content.meshes:
            for f in index[m.faces.astype(np.int64) + offset]:
                k = int(np.argmin(f))
                out.add(tuple(np.roll(f, -k).tolist()))
            offset += len(m.positions)
        return out

    return bool(faces(a, np.arange(len(pa))) == faces(b, near))


def _hausdorff(a: np.ndarray, b: np.ndarray) -> float:
    return float(max(cKDTree(b).query(a)[0].max(), cKDTree(a).query(b)[0].max()))


@pytest.mark.parametrize(("packed", "bound"), [
    ("dsm_cc.glb", 64 / 2 ** 14),     # 14-bit integer positions over the 64 m tile
    ("dsm_ccvpf.glb", 64 / 2 ** 15),  # float positions, EXPONENTIAL filter
])
def test_gltfpack_dsm_tile_matches_the_original(packed: str, bound: float) -> None:
    plain, mo = _content(MO / "dsm.glb"), _content(MO / packed)
    assert mo.triangle_count == plain.triangle_count > 500
    tol = bound * np.sqrt(3) / 2 + 1e-6
    assert _hausdorff(_positions(plain), _positions(mo)) <= tol
    assert _same_triangles(plain, mo, tol)  # the same triangles, wound the same way


def test_gltfpack_batched_model_positions_and_normals() -> None:
    """Cesium's batched buildings, repacked by gltfpack: positions and OCTAHEDRAL-filtered normals."""
    plain, mo = _content(MO / "batched.glb"), _content(MO / "batched_cc.glb")
    assert mo.triangle_count == plain.triangle_count == 120
    extent = np.ptp(_positions(plain), axis=0).max()
    assert _hausdorff(_positions(plain), _positions(mo)) <= extent / 2 ** 14
    # NORMAL (int8 with the OCTAHEDRAL filter), read through the accessor: on these flat-shaded boxes every vertex
    # normal is its triangle's geometric normal, computed from the decoded positions
    raw = (MO / "batched_cc.glb").read_bytes()
    n = struct.unpack_from("<I", raw, 12)[0]
    gltf = json.loads(raw[20: 20 + n])
    body = raw[20 + n + 8:]
    checked = 0
    for prim in gltf["meshes"][0]["primitives"]:
        pos = _read_accessor(gltf, [body], prim["attributes"]["POSITION"], "p").astype(np.float64)
        nrm = _read_accessor(gltf, [body], prim["attributes"]["NORMAL"], "n").astype(np.float64)
        tri = _read_accessor(gltf, [body], prim["indices"], "i").astype(np.int64).reshape(-1, 3)
        assert np.allclose(np.linalg.norm(nrm, axis=1), 1, atol=0.01)
        g = np.cross(pos[tri[:, 1]] - pos[tri[:, 0]], pos[tri[:, 2]] - pos[tri[:, 0]])
        g /= np.linalg.norm(g, axis=1, keepdims=True)
        for k in range(3):
            assert np.all(np.einsum("ij,ij->i", g, nrm[tri[:, k]]) > np.cos(np.radians(5)))  # int8 normals, 14-bit positions
        checked += len(tri)
    assert checked == 120


@pytest.mark.parametrize("name", ["TriangleMeshopt.gltf", "TriangleMeshoptNoByteOffset.gltf"])
def test_gltf_transform_triangle_matches_the_plain_one(name: str) -> None:
    plain, mo = _content(MO / "Triangle.gltf"), _content(MO / name)
    assert mo.triangle_count == plain.triangle_count == 1
    assert _hausdorff(_positions(plain), _positions(mo)) <= 1.0 / 32767


def test_meshopt_tileset_renders_its_tiles() -> None:
    """A citylod DSM tileset whose every glb gltfpack recompressed opens and loads like any other."""
    ts = open_tileset(MO / "dsm_tileset")
    plain = _content(MO / "dsm.glb")
    root = ts.root.load_content()
    assert root.triangle_count == plain.triangle_count
    for t in ts.walk():
        m = t.load()
        lo, hi = t.box.bounds()
        assert len(m.faces) and np.all(m.vertices >= lo - 0.01) and np.all(m.vertices <= hi + 0.01)


def test_damaged_meshopt_streams_are_one_line(tmp_path: Path) -> None:
    doc = json.loads((MO / "TriangleMeshopt.gltf").read_text())
    bin_ = (MO / "TriangleMeshopt.bin").read_bytes()

    def decode(d: dict, data: bytes = bin_) -> None:  # type: ignore[type-arg]
        decode_content(json.dumps(d).encode(), "t.gltf", resolve=lambda uri: data)

    broken = bytearray(bin_)
    broken[20:80] = bytes(60)  # the vertex stream zeroed: its header byte is wrong
    with pytest.raises(InputError, match="meshopt stream cannot be decoded"):
        decode(doc, bytes(broken))
    long = json.loads(json.dumps(doc))
    long["bufferViews"][1]["extensions"]["EXT_meshopt_compression"]["byteLength"] = 10_000
    with pytest.raises(InputError, match="past the end"):
        decode(long)
    bad = json.loads(json.dumps(doc))
    bad["bufferViews"][0]["extensions"]["EXT_meshopt_compression"]["filter"] = "OCTAHEDRAL"
    with pytest.raises(InputError, match="not part of EXT_meshopt_compression"):
        decode(bad)
    for view, change in ((0, {"count": 4}), (1, {"byteStride": 12, "filter": "OCTAHEDRAL"}),
                         (1, {"byteStride": 12, "filter": "QUATERNION"}), (1, {"byteStride": 6})):
        odd = json.loads(json.dumps(doc))  # indices not in triangles; strides the decoders assert on
        odd["bufferViews"][view]["extensions"]["EXT_meshopt_compression"].update(change)
        with pytest.raises(InputError, match="rules"):
            decode(odd)
    huge = json.loads(json.dumps(doc))
    huge["bufferViews"][1]["extensions"]["EXT_meshopt_compression"]["count"] = 10 ** 9
    with pytest.raises(InputError, match="meshopt"):
        decode(huge)


def test_indices_mode_reads_as_an_index_list() -> None:
    """INDICES mode (index sequences, e.g. of points) through a glTF the meshoptimizer encoder wrote."""
    import meshoptimizer as mo

    idx = np.array([0, 2, 1, 3, 3, 1, 2, 0, 1], np.uint32)
    stream = mo.encode_index_sequence(idx)
    from citylod.io.tiles3d.gltf import _meshopt_view

    ext = {"buffer": 0, "byteLength": len(stream), "byteStride": 2, "count": len(idx), "mode": "INDICES"}
    got = np.frombuffer(_meshopt_view(ext, [bytes(stream)], 0, "t"), np.uint16)
    assert got.tolist() == idx.tolist()
