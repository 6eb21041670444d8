"""glTF/glb, b3dm and pnts tile content: encoding what citylod writes and decoding what any client writes.

glTF is y-up and 3D Tiles turns it z-up when it places content; this module does that turn both ways, so
callers only see z-up coordinates. Skirt triangles are stored as a separate primitive marked
``extras.citylod_skirt`` so standard clients draw them and citylod can tell them apart.

Knows what a tile *is*, never how it was chosen (no LOD logic). No VTK and no Qt here.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from citylod._version import __version__
from citylod.core.errors import InputError
from citylod.core.geometry import F64
from citylod.io.tiles3d.features import (
    FeatureIdSet,
    PropertyTable,
    decode_property_tables,
    encode_property_tables,
)

# glTF y-up -> 3D Tiles z-up: (x, y, z)_gltf = (x, z, -y)_zup (3D Tiles spec, "y-up to z-up").
_Y_UP_TO_Z_UP = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
_Z_UP_TO_Y_UP = np.linalg.inv(_Y_UP_TO_Z_UP)

_COMPONENT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_POINT_ATTRS = {"_INTENSITY": "intensity", "_CLASSIFICATION": "classification", "_RETURN_NUMBER": "return_number"}


# --------------------------------------------------------------------------------------------- content model
@dataclass
class MeshData:
    """One triangle mesh of a tile. ``positions`` (N, 3) float32 relative to the tile centre, z up;
    ``faces`` (M, 3) uint32; ``skirt`` (M,) bool or None; ``uv`` (N, 2) float32 (origin top-left);
    ``texture`` encoded JPEG/PNG bytes; ``colors`` (N, 4) uint8; ``features`` the feature ID sets
    (``EXT_mesh_features``), the k-th written as vertex attribute ``_FEATURE_ID_k``."""

    positions: npt.NDArray[np.float32]
    faces: npt.NDArray[np.uint32]
    skirt: npt.NDArray[np.bool_] | None = None
    uv: npt.NDArray[np.float32] | None = None
    texture: bytes | None = None
    colors: npt.NDArray[np.uint8] | None = None
    name: str = "surface"
    features: list[FeatureIdSet] = field(default_factory=list)

    @property
    def nbytes(self) -> int:
        n = self.positions.nbytes + self.faces.nbytes
        for a in (self.uv, self.colors, self.skirt, *(f.ids for f in self.features)):
            n += 0 if a is None else a.nbytes
        return n + (len(self.texture) if self.texture else 0)


@dataclass
class PointData:
    """Points of a tile: ``positions`` (N, 3) float32 relative to the tile centre and per-point attributes."""

    positions: npt.NDArray[np.float32]
    rgb: npt.NDArray[np.uint8] | None = None
    intensity: npt.NDArray[np.uint16] | None = None
    classification: npt.NDArray[np.uint8] | None = None
    return_number: npt.NDArray[np.uint8] | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def nbytes(self) -> int:
        n = self.positions.nbytes
        for a in (self.rgb, self.intensity, self.classification, self.return_number, *self.extra.values()):
            n += 0 if a is None else a.nbytes
        return n


@dataclass
class TileContent:
    """What one content file holds: meshes (surfaces, quads) and/or points, and the property tables
    (``EXT_structural_metadata``) that the meshes' feature IDs index."""

    meshes: list[MeshData] = field(default_factory=list)
    points: PointData | None = None
    property_tables: list[PropertyTable] = field(default_factory=list)

    @property
    def nbytes(self) -> int:
        return sum(m.nbytes for m in self.meshes) + (self.points.nbytes if self.points is not None else 0)

    @property
    def triangle_count(self) -> int:
        return sum(len(m.faces) for m in self.meshes)

    @property
    def point_count(self) -> int:
        return 0 if self.points is None else len(self.points.positions)


# ----------------------------------------------------------------------------------------------- glb writer
class _GlbBuilder:
    """A glb assembled once: the binary chunk's parts are remembered (no copies) and laid out by
    :meth:`buffer` in one preallocated array, where numpy copies them without the GIL. Joining them into
    a growing ``bytearray`` copied every byte three times under the GIL: half a point tile's encoding time,
    which held back the other build thread."""

    def __init__(self) -> None:
        self.parts: list[tuple[int, npt.NDArray[np.uint8]]] = []  # (offset in the binary chunk, bytes)
        self.size = 0
        self.gltf: dict[str, Any] = {
            "asset": {"version": "2.0", "generator": f"citylod {__version__}"},
            "buffers": [], "bufferViews": [], "accessors": [], "meshes": [], "nodes": [], "scenes": [],
        }

    def view(self, data: bytes | np.ndarray, target: int | None = None, stride: int | None = None,
             align: int = 4) -> int:
        raw = (np.frombuffer(data, np.uint8) if isinstance(data, bytes)
               else np.ascontiguousarray(data).reshape(-1).view(np.uint8))
        self.size += -self.size % align
        bv: dict[str, Any] = {"buffer": 0, "byteOffset": self.size, "byteLength": int(raw.size)}
        if target is not None:
            bv["target"] = target
        if stride is not None:
            bv["byteStride"] = stride
        self.parts.append((self.size, raw))
        self.size += int(raw.size)
        self.gltf["bufferViews"].append(bv)
        return len(self.gltf["bufferViews"]) - 1

    def accessor(self, array: np.ndarray, kind: str, *, normalized: bool = False, target: int | None = 34962,
                 minmax: bool = False) -> int:
        ctype = _COMPONENT_TYPE[array.dtype]
        arr = np.ascontiguousarray(array)
        n = int(arr.shape[0])
        size = arr.dtype.itemsize * (arr.size // n if n else 1)
        if target == 34962 and size % 4:
            # glTF 2.0 §3.6.2.4: every element of a vertex attribute starts on a 4-byte boundary (the
            # validator's MESH_PRIMITIVE_ACCESSOR_UNALIGNED). RGB8, uint16 and uint8 attributes are written
            # padded to a stride of 4 bytes instead of tightly packed.
            stride = size + (-size % 4)
            padded = np.empty((n, stride), np.uint8)
            padded[:, :size] = arr.reshape(n, -1).view(np.uint8)
            padded[:, size:] = 0
            bv = self.view(padded, target, stride)
        else:
            bv = self.view(arr, target)
        lo = hi = None
        if minmax and len(arr):
            flat = arr.reshape(len(arr), -1)
            # column by column: numpy's reductions along axis 0 of (N, 3) arrays are many times slower
            lo = [float(flat[:, i].min()) for i in range(flat.shape[1])]
            hi = [float(flat[:, i].max()) for i in range(flat.shape[1])]
        return self.register(bv, ctype, n, kind, normalized=normalized, lo=lo, hi=hi)

    def register(self, view: int, ctype: int, count: int, kind: str, *, normalized: bool = False,
                 lo: list[float] | None = None, hi: list[float] | None = None) -> int:
        """An accessor over buffer view ``view`` (elements laid out as the view says); its index."""
        acc: dict[str, Any] = {"bufferView": view, "componentType": ctype, "count": count, "type": kind}
        if normalized:
            acc["normalized"] = True
        if lo is not None and hi is not None:
            acc["min"], acc["max"] = lo, hi
        self.gltf["accessors"].append(acc)
        return len(self.gltf["accessors"]) - 1

    def add(self, key: str, item: dict[str, Any]) -> int:
        self.gltf.setdefault(key, []).append(item)
        return len(self.gltf[key]) - 1

    def buffer(self) -> npt.NDArray[np.uint8]:
        """The glb file's bytes."""
        nbin = self.size + (-self.size % 4)
        self.gltf["buffers"] = [{"byteLength": nbin}]
        for k in [k for k, v in self.gltf.items() if isinstance(v, list) and not v]:
            del self.gltf[k]
        js = json.dumps(self.gltf, separators=(",", ":")).encode()
        js += b" " * (-len(js) % 4)
        total = 12 + 8 + len(js) + (8 + nbin if nbin else 0)
        out = np.empty(total, np.uint8)
        head = struct.pack("<4sII", b"glTF", 2, total) + struct.pack("<I4s", len(js), b"JSON") + js
        if nbin:
            head += struct.pack("<I4s", nbin, b"BIN\x00")
        out[:len(head)] = np.frombuffer(head, np.uint8)
        end = len(head)
        for off, raw in self.parts:
            out[end:len(head) + off] = 0  # alignment padding
            end = len(head) + off + raw.size
            out[len(head) + off:end] = raw
        out[end:] = 0
        return out


_COMPONENT_TYPE = {np.dtype(v): k for k, v in _COMPONENT.items()}


def _to_gltf_axes(p: np.ndarray) -> np.ndarray:
    out = np.empty_like(p, dtype=np.float32)
    out[:, 0], out[:, 1], out[:, 2] = p[:, 0], p[:, 2], -p[:, 1]
    return out


def _from_gltf_axes(p: np.ndarray) -> np.ndarray:
    out = np.empty_like(p, dtype=np.float32)
    out[:, 0], out[:, 1], out[:, 2] = p[:, 0], -p[:, 2], p[:, 1]
    return out


def encode_glb(content: TileContent) -> bytes:
    """Encode ``content`` as a binary glTF 2.0 (glb) with y-up positions, as 3D Tiles expects."""
    return glb_buffer(content).tobytes()


def glb_buffer(content: TileContent) -> npt.NDArray[np.uint8]:
    """:func:`encode_glb`'s bytes as a uint8 array (what a writer takes without another copy)."""
    b = _GlbBuilder()
    primitives: list[dict[str, Any]] = []
    unlit = False
    for mesh in content.meshes:
        pos = np.asarray(mesh.positions, dtype=np.float32).reshape(-1, 3)
        faces = np.asarray(mesh.faces, dtype=np.uint32).reshape(-1, 3)
        if len(pos) == 0 or len(faces) == 0:
            continue
        attrs = {"POSITION": b.accessor(_to_gltf_axes(pos), "VEC3", minmax=True)}
        material: dict[str, Any] = {"name": mesh.name, "doubleSided": True,
                                    "pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 1.0}}
        if mesh.uv is not None and mesh.texture:
            attrs["TEXCOORD_0"] = b.accessor(np.asarray(mesh.uv, dtype=np.float32), "VEC2")
            mime = "image/png" if mesh.texture[:8] == b"\x89PNG\r\n\x1a\n" else "image/jpeg"
            img = b.add("images", {"bufferView": b.view(mesh.texture), "mimeType": mime})
            smp = b.add("samplers", {"magFilter": 9729, "minFilter": 9987, "wrapS": 33071, "wrapT": 33071})
            tex = b.add("textures", {"source": img, "sampler": smp})
            material["pbrMetallicRoughness"]["baseColorTexture"] = {"index": tex}
            if mime == "image/png":
                material["alphaMode"] = "MASK"
            material["extensions"] = {"KHR_materials_unlit": {}}
            unlit = True
        if mesh.colors is not None:
            attrs["COLOR_0"] = b.accessor(np.asarray(mesh.colors, dtype=np.uint8), "VEC4", normalized=True)
        mesh_features = _feature_id_attributes(b, mesh.features, attrs)
        mat = b.add("materials", material)
        skirt = np.zeros(len(faces), bool) if mesh.skirt is None else np.asarray(mesh.skirt, bool)
        for is_skirt in (False, True):
            sel = faces[skirt == is_skirt]
            if len(sel) == 0:
                continue
            prim: dict[str, Any] = {"attributes": attrs, "mode": 4, "material": mat,
                                    "indices": b.accessor(sel.reshape(-1), "SCALAR", target=34963)}
            prim["extras"] = {"citylod_name": mesh.name, "citylod_skirt": is_skirt}
            if mesh_features:
                prim["extensions"] = {"EXT_mesh_features": mesh_features}
            primitives.append(prim)
    if content.points is not None and len(content.points.positions):
        attrs = _point_attributes(b, content.points)
        pts = content.points
        dtypes = {}
        for name, arr in pts.extra.items():
            a = np.asarray(arr)
            dtypes[name] = a.dtype.str
            stored = a if a.dtype in (np.uint8, np.uint16, np.float32) else a.astype(np.float32)
            attrs["_" + name.upper()] = b.accessor(stored, "SCALAR")
        mat = b.add("materials", {"name": "points", "extensions": {"KHR_materials_unlit": {}},
                                  "pbrMetallicRoughness": {"metallicFactor": 0.0}})
        unlit = True
        primitives.append({"attributes": attrs, "mode": 0, "material": mat,
                           "extras": {"citylod_name": "points", "citylod_extra_dtypes": dtypes}})
    if primitives:
        b.gltf["meshes"] = [{"primitives": primitives}]
        b.gltf["nodes"] = [{"mesh": 0}]
        b.gltf["scenes"] = [{"nodes": [0]}]
        b.gltf["scene"] = 0
    used = ["KHR_materials_unlit"] if unlit else []
    if any(p.get("extensions", {}).get("EXT_mesh_features") for p in primitives):
        used.append("EXT_mesh_features")
    if content.property_tables:
        b.gltf.setdefault("extensions", {})["EXT_structural_metadata"] = encode_property_tables(
            b, content.property_tables)
        used.append("EXT_structural_metadata")
    if used:
        b.gltf["extensionsUsed"] = used
    return b.buffer()


def _feature_id_attributes(b: _GlbBuilder, sets: list[FeatureIdSet], attrs: dict[str, int]) -> dict[str, Any]:
    """Write each feature ID set as vertex attribute ``_FEATURE_ID_k`` into ``attrs``; the primitive's
    ``EXT_mesh_features`` object (empty without sets).

    glTF forbids 32-bit integer vertex attributes, so IDs are uint16 while they fit and float32 beyond
    (exact up to 2^24, far more features than one tile holds).
    """
    ids_json = []
    for k, fs in enumerate(sets):
        ids = np.asarray(fs.ids, np.uint32)
        count = fs.feature_count
        stored = ids.astype(np.uint16) if count <= 65535 else ids.astype(np.float32)
        attrs[f"_FEATURE_ID_{k}"] = b.accessor(stored, "SCALAR")
        entry: dict[str, Any] = {"featureCount": count, "attribute": k}
        if fs.table is not None:
            entry["propertyTable"] = int(fs.table)
        if fs.label:
            entry["label"] = fs.label
        ids_json.append(entry)
    return {"featureIds": ids_json} if ids_json else {}


def _point_attributes(b: _GlbBuilder, pts: PointData) -> dict[str, int]:
    """POSITION, COLOR_0 and the LAS attributes of point content, encoded by one compiled pass
    (:mod:`citylod.io.glb_kernels`); the bytes :meth:`_GlbBuilder.accessor` would write for each."""
    from citylod.io.glb_kernels import point_vertex_columns

    pos = np.ascontiguousarray(pts.positions, np.float32).reshape(-1, 3)
    n = len(pos)

    def column(arr: np.ndarray | None, dt: type, ncomp: int) -> np.ndarray:
        if arr is None:
            return np.zeros((0, ncomp) if ncomp > 1 else 0, dt)
        return np.ascontiguousarray(arr, dt).reshape((n, ncomp) if ncomp > 1 else n)

    pos_out, rgb_out, ret_out = np.empty((n, 3), np.float32), np.empty((n, 4), np.uint8), np.empty((n, 4), np.uint8)
    int_out, cls_out = np.empty((n, 2), np.uint16), np.empty((n, 4), np.uint8)
    lo, hi = np.empty(3, np.float32), np.empty(3, np.float32)
    point_vertex_columns(pos, column(pts.rgb, np.uint8, 3), column(pts.intensity, np.uint16, 1),
                         column(pts.classification, np.uint8, 1), column(pts.return_number, np.uint8, 1),
                         pos_out, rgb_out, int_out, cls_out, ret_out, lo, hi)

    attrs = {"POSITION": b.register(b.view(pos_out, 34962), 5126, n, "VEC3", lo=[float(v) for v in lo],
                                    hi=[float(v) for v in hi])}
    if pts.rgb is not None:
        attrs["COLOR_0"] = b.register(b.view(rgb_out, 34962, 4), 5121, n, "VEC3", normalized=True)
    outs: tuple[np.ndarray, ...] = (int_out, cls_out, ret_out)
    for (gl_name, attr), out, ctype in zip(_POINT_ATTRS.items(), outs, (5123, 5121, 5121), strict=True):
        if getattr(pts, attr) is not None:
            attrs[gl_name] = b.register(b.view(out, 34962, 4), ctype, n, "SCALAR")
    return attrs


# ----------------------------------------------------------------------------------------------- glb reader
def _parse_glb(data: bytes, source: str) -> tuple[dict[str, Any], bytes]:
    if len(data) < 20:
        raise InputError("content is truncated (shorter than a glb header)", source)
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != b"glTF":
        raise InputError(f"not a glb file (magic {magic!r})", source)
    if version != 2:
        raise InputError(f"glTF version {version} is not supported (only 2)", source)
    if length > len(data):
        raise InputError(f"glb is truncated ({len(data)} of {length} bytes)", source)
    off, gltf, binary = 12, None, b""
    while off + 8 <= length:
        clen, ctype = struct.unpack_from("<I4s", data, off)
        chunk = data[off + 8: off + 8 + clen]
        if len(chunk) != clen:
            raise InputError("glb chunk is truncated", source)
        if ctype == b"JSON":
            try:
                gltf = json.loads(chunk.decode("utf-8"))
            except (UnicodeDecodeError, json.JSONDecodeError) as exc:
                raise InputError(f"glb JSON chunk is corrupt ({exc})", source) from exc
        elif ctype == b"BIN\x00" and not binary:
            binary = chunk
        off += 8 + clen + (-clen % 4)
    if not isinstance(gltf, dict):
        raise InputError("glb has no JSON chunk", source)
    return gltf, binary


def _read_accessor(gltf: dict[str, Any], binary: bytes, index: int, source: str) -> np.ndarray:
    try:
        acc = gltf["accessors"][index]
        dtype = np.dtype(_COMPONENT[acc["componentType"]])
        ncomp = _NCOMP[acc["type"]]
        count = int(acc["count"])
        if "sparse" in acc:
            raise InputError("sparse accessors are not supported", source)
        if "bufferView" not in acc:
            return np.zeros((count, ncomp), dtype).squeeze()
        bv = gltf["bufferViews"][acc["bufferView"]]
        if bv.get("buffer", 0) != 0:
            raise InputError("external glTF buffers are not supported", source)
        start = int(bv.get("byteOffset", 0)) + int(acc.get("byteOffset", 0))
        stride = int(bv.get("byteStride", 0)) or dtype.itemsize * ncomp
        end = start + stride * (count - 1) + dtype.itemsize * ncomp if count else start
        if end > len(binary) or start < 0:
            raise InputError("accessor reaches past the end of the binary chunk", source)
        raw = np.frombuffer(binary, np.uint8, count=end - start, offset=start)
        if stride == dtype.itemsize * ncomp:
            arr = raw.view(dtype).reshape(count, ncomp)
        else:
            rows = np.lib.stride_tricks.as_strided(raw, (count, dtype.itemsize * ncomp), (stride, 1))
            arr = np.ascontiguousarray(rows).view(dtype).reshape(count, ncomp)
        if acc.get("normalized") and dtype.kind in "ui" and acc["type"] != "SCALAR" and dtype != np.uint8:
            arr = arr.astype(np.float32) / float(np.iinfo(dtype.type).max)  # type: ignore[type-var]
        return arr[:, 0] if ncomp == 1 else arr
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise InputError(f"glTF accessor {index} is invalid ({exc})", source) from exc


def _node_matrices(gltf: dict[str, Any]) -> list[tuple[int, F64]]:
    """(mesh index, 4×4 node-to-scene matrix in glTF axes) for every mesh instance of the default scene."""
    nodes = gltf.get("nodes", [])
    scenes = gltf.get("scenes") or [{"nodes": list(range(len(nodes)))}]
    roots = scenes[gltf.get("scene", 0)].get("nodes", [])
    out: list[tuple[int, F64]] = []
    stack = [(int(i), np.eye(4)) for i in roots]
    seen = 0
    while stack:
        i, parent = stack.pop()
        seen += 1
        if seen > 100000:
            break
        node = nodes[i]
        m = np.eye(4)
        if "matrix" in node:
            m = np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T
        else:
            t = np.asarray(node.get("translation", [0, 0, 0]), float)
            x, y, z, w = node.get("rotation", [0, 0, 0, 1])
            r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                          [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                          [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
            s = np.asarray(node.get("scale", [1, 1, 1]), float)
            m[:3, :3] = r * s
            m[:3, 3] = t
        world = parent @ m
        if "mesh" in node:
            out.append((int(node["mesh"]), world))
        stack.extend((int(c), world) for c in node.get("children", []))
    return out


def decode_glb(data: bytes, source: str = "", *, rtc_center: F64 | None = None,
               y_up: bool = True) -> TileContent:
    """Decode a glb into :class:`TileContent` with z-up positions relative to the content's origin.

    Node transforms are applied. Draco or meshopt compressed content is refused with a clear error.
    """
    gltf, binary = _parse_glb(data, source)
    required = set(gltf.get("extensionsRequired", []))
    unsupported = required & {"KHR_draco_mesh_compression", "EXT_meshopt_compression", "KHR_mesh_quantization"}
    if unsupported:
        raise InputError(f"glTF extension {sorted(unsupported)} is not supported", source)
    if rtc_center is None and "CESIUM_RTC" in gltf.get("extensions", {}):
        rtc_center = np.asarray(gltf["extensions"]["CESIUM_RTC"]["center"], float)
    content = TileContent()
    images = _images(gltf, binary)
    for mesh_index, node_m in _node_matrices(gltf):
        try:
            prims = gltf["meshes"][mesh_index]["primitives"]
        except (KeyError, IndexError) as exc:
            raise InputError(f"glTF mesh {mesh_index} is missing", source) from exc
        # Group primitives sharing a POSITION accessor (our surface + skirt pair) into one MeshData.
        groups: dict[tuple[int, int], list[dict[str, Any]]] = {}
        for prim in prims:
            if "POSITION" not in prim.get("attributes", {}):
                continue
            groups.setdefault((prim["attributes"]["POSITION"], prim.get("mode", 4)), []).append(prim)
        for (pos_idx, mode), group in groups.items():
            pos = _read_accessor(gltf, binary, pos_idx, source).astype(np.float64)
            pos = pos @ node_m[:3, :3].T + node_m[:3, 3]
            if rtc_center is not None:
                pos = pos + (_Z_UP_TO_Y_UP[:3, :3] @ rtc_center if y_up else rtc_center)
            pos32 = _from_gltf_axes(pos) if y_up else pos.astype(np.float32)
            attrs = group[0]["attributes"]
            if mode == 0:
                content.points = _decode_points(gltf, binary, attrs, group[0], pos32, source)
                continue
            if mode not in (4, 5, 6):
                continue  # lines are not drawn by citylod
            faces_list, skirt_list = [], []
            for prim in group:
                if "indices" in prim:
                    idx = _read_accessor(gltf, binary, prim["indices"], source).astype(np.uint32)
                else:
                    idx = np.arange(len(pos32), dtype=np.uint32)
                tri = _triangles(idx, prim.get("mode", 4))
                if len(tri) and int(tri.max()) >= len(pos32):
                    raise InputError("triangle indices point past the vertices", source)
                faces_list.append(tri)
                skirt_list.append(np.full(len(tri), bool(prim.get("extras", {}).get("citylod_skirt", False))))
            uv = texture = colors = None
            if "TEXCOORD_0" in attrs:
                uv = _read_accessor(gltf, binary, attrs["TEXCOORD_0"], source).astype(np.float32)
                texture = _material_texture(gltf, group[0], images)
                if texture is None:
                    uv = None
            if "COLOR_0" in attrs:
                colors = _colors_rgba(_read_accessor(gltf, binary, attrs["COLOR_0"], source))
            content.meshes.append(MeshData(
                positions=pos32, faces=np.concatenate(faces_list), skirt=np.concatenate(skirt_list),
                uv=uv, texture=texture, colors=colors,
                name=str(group[0].get("extras", {}).get("citylod_name", "surface")),
                features=_decode_feature_ids(gltf, binary, group[0], source),
            ))
    ext = gltf.get("extensions", {}).get("EXT_structural_metadata")
    if isinstance(ext, dict):
        def view_bytes(i: int) -> bytes:
            bv = gltf["bufferViews"][i]
            start = int(bv.get("byteOffset", 0))
            return binary[start:start + int(bv["byteLength"])]

        content.property_tables = decode_property_tables(ext, view_bytes, source)
    return content


def _decode_feature_ids(gltf: dict[str, Any], binary: bytes, prim: dict[str, Any], source: str) -> list[FeatureIdSet]:
    """The attribute-based feature ID sets of a primitive (``EXT_mesh_features``); implicit and texture
    feature IDs are not read."""
    out = []
    ext = prim.get("extensions", {}).get("EXT_mesh_features", {})
    for fid in ext.get("featureIds", []) if isinstance(ext, dict) else []:
        name = f"_FEATURE_ID_{fid.get('attribute')}"
        if "attribute" not in fid or name not in prim.get("attributes", {}):
            continue
        ids = _read_accessor(gltf, binary, prim["attributes"][name], source)
        out.append(FeatureIdSet(np.round(ids).astype(np.uint32), fid.get("propertyTable"),
                                int(fid.get("featureCount", 0)), fid.get("label")))
    return out


def _triangles(idx: np.ndarray, mode: int) -> np.ndarray:
    if mode == 4:
        return idx[: len(idx) // 3 * 3].reshape(-1, 3)
    n = len(idx) - 2
    if n <= 0:
        return np.zeros((0, 3), np.uint32)
    k = np.arange(n)
    if mode == 5:  # strip: alternate winding
        a, b = np.where(k % 2 == 0, idx[k], idx[k + 1]), np.where(k % 2 == 0, idx[k + 1], idx[k])
        return np.stack([a, b, idx[k + 2]], axis=1)
    return np.stack([np.full(n, idx[0]), idx[k + 1], idx[k + 2]], axis=1)  # fan


def _colors_rgba(c: np.ndarray) -> np.ndarray:
    c = np.asarray(c)
    if c.dtype.kind == "f":
        c = np.clip(np.round(c * 255), 0, 255).astype(np.uint8)
    elif c.dtype == np.uint16:
        c = (c >> 8).astype(np.uint8)
    if c.ndim == 1:
        c = c[:, None].repeat(3, axis=1)
    if c.shape[1] == 3:
        c = np.concatenate([c, np.full((len(c), 1), 255, np.uint8)], axis=1)
    return c.astype(np.uint8)


def _images(gltf: dict[str, Any], binary: bytes) -> list[bytes | None]:
    out: list[bytes | None] = []
    for img in gltf.get("images", []):
        if "bufferView" in img:
            bv = gltf["bufferViews"][img["bufferView"]]
            start = int(bv.get("byteOffset", 0))
            out.append(bytes(binary[start: start + int(bv["byteLength"])]))
        else:
            out.append(None)  # external or data-URI images are not fetched
    return out


def _material_texture(gltf: dict[str, Any], prim: dict[str, Any], images: list[bytes | None]) -> bytes | None:
    try:
        mat = gltf["materials"][prim["material"]]
        tex = gltf["textures"][mat["pbrMetallicRoughness"]["baseColorTexture"]["index"]]
        return images[tex["source"]]
    except (KeyError, IndexError, TypeError):
        return None


def _decode_points(gltf: dict[str, Any], binary: bytes, attrs: dict[str, int], prim: dict[str, Any],
                   pos32: np.ndarray, source: str) -> PointData:
    pts = PointData(positions=pos32)
    if "COLOR_0" in attrs:
        pts.rgb = _colors_rgba(_read_accessor(gltf, binary, attrs["COLOR_0"], source))[:, :3].copy()
    for gl_name, attr in _POINT_ATTRS.items():
        if gl_name in attrs:
            setattr(pts, attr, _read_accessor(gltf, binary, attrs[gl_name], source).copy())
    dtypes = prim.get("extras", {}).get("citylod_extra_dtypes", {})
    for name, dt in dtypes.items():
        key = "_" + name.upper()
        if key in attrs:
            pts.extra[name] = _read_accessor(gltf, binary, attrs[key], source).astype(np.dtype(dt))
    return pts


# ------------------------------------------------------------------------------------- legacy 1.0 content
def decode_content(data: bytes, source: str, *, y_up: bool = True) -> TileContent:
    """Decode glb, b3dm or pnts content by its magic bytes."""
    magic = data[:4]
    if magic == b"glTF":
        return decode_glb(data, source, y_up=y_up)
    if magic == b"b3dm":
        if len(data) < 28:
            raise InputError("b3dm header is truncated", source)
        _, _, length, ftj, ftb, btj, btb = struct.unpack_from("<4sIIIIII", data, 0)
        ft = _feature_json(data[28: 28 + ftj], source)
        start = 28 + ftj + ftb + btj + btb
        rtc = np.asarray(ft["RTC_CENTER"], float) if "RTC_CENTER" in ft else None
        return decode_glb(data[start:length], source, rtc_center=rtc, y_up=y_up)
    if magic == b"pnts":
        return _decode_pnts(data, source)
    raise InputError(f"unknown tile content (magic {magic!r}); expected glb, b3dm or pnts", source)


def _feature_json(raw: bytes, source: str) -> dict[str, Any]:
    try:
        return json.loads(raw.decode("utf-8").rstrip(" \x00")) if raw.strip(b" \x00") else {}
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"feature table is corrupt ({exc})", source) from exc


def _decode_pnts(data: bytes, source: str) -> TileContent:
    if len(data) < 28:
        raise InputError("pnts header is truncated", source)
    _, _, _, ftj, ftb, _, _ = struct.unpack_from("<4sIIIIII", data, 0)
    ft = _feature_json(data[28: 28 + ftj], source)
    body = data[28 + ftj: 28 + ftj + ftb]
    try:
        n = int(ft["POINTS_LENGTH"])

        def prop(name: str, dtype: Any, ncomp: int) -> np.ndarray | None:
            if name not in ft:
                return None
            off = int(ft[name]["byteOffset"])
            return np.frombuffer(body, dtype, count=n * ncomp, offset=off).reshape(n, ncomp)

        pos = prop("POSITION", np.float32, 3)
        if pos is None:
            q = prop("POSITION_QUANTIZED", np.uint16, 3)
            if q is None:
                raise InputError("pnts has no POSITION", source)
            scale = np.asarray(ft["QUANTIZED_VOLUME_SCALE"], float)
            offset = np.asarray(ft["QUANTIZED_VOLUME_OFFSET"], float)
            pos = (q.astype(np.float64) / 65535.0 * scale + offset).astype(np.float32)
        rtc = np.asarray(ft.get("RTC_CENTER", [0, 0, 0]), float)
        pos64 = pos.astype(np.float64) + rtc
        rgb = prop("RGB", np.uint8, 3)
        rgba = prop("RGBA", np.uint8, 4)
    except (KeyError, ValueError, TypeError) as exc:
        raise InputError(f"pnts feature table is invalid ({exc})", source) from exc
    colours = rgb if rgb is not None else (rgba[:, :3] if rgba is not None else None)
    return TileContent(points=PointData(positions=pos64.astype(np.float32),
                                        rgb=None if colours is None else colours.copy()))
