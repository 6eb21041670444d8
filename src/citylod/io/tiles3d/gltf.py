"""Reading glTF tile content written by any client: glb 2.0 and 1.0, glTF JSON, Draco, quantized positions.

Produces :class:`~citylod.io.tiles3d.content.TileContent` with z-up positions relative to the content's origin
(glTF is y-up; 3D Tiles turns it z-up when it places content). Node transforms and ``EXT_mesh_gpu_instancing``
are applied; vertex colours (linear in glTF) and material base colours come back as sRGB bytes
(:mod:`.colour`). ``KHR_draco_mesh_compression`` is decoded with DracoPy (Google's Draco decoder),
``KHR_mesh_quantization`` by the accessors' own normalisation, ``EXT_meshopt_compression`` by meshoptimizer's
decoders, ``EXT_texture_webp`` by OpenImageIO, ``KHR_texture_basisu`` (KTX2) by Binomial's Basis Universal
transcoder, ``KHR_texture_transform`` on the UVs. Any other required extension is one :class:`~citylod.core.errors.InputError` naming it, never geometry read wrong.

glTF 1.0 (3D Tiles 1.0 b3dm) is read by lifting its document to the 2.0 layout first, the way CesiumJS and
gltf-pipeline's ``updateVersion`` do (id-keyed objects become arrays, ``KHR_binary_glTF`` becomes buffer 0,
``values.diffuse`` becomes ``baseColorFactor``).

Knows what a tile *is*, never how it was chosen. No VTK and no Qt here.
"""

from __future__ import annotations

import base64
import json
import math
import struct
import urllib.parse
from collections.abc import Callable
from typing import Any

import numpy as np

from citylod.core.errors import InputError
from citylod.core.geometry import F64
from citylod.io.tiles3d.colour import linear_colors_to_srgb8, linear_to_srgb, srgb_to_linear
from citylod.io.tiles3d.content import _POINT_ATTRS, MeshData, PointData, TileContent, recentre
from citylod.io.tiles3d.features import FeatureIdSet, decode_property_tables

#: Reads a URI relative to the content (external buffers and images); raises InputError when it cannot.
Resolver = Callable[[str], bytes]

_COMPONENT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_Z_UP_TO_Y_UP = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])

#: Required extensions whose absence from the reader would not change the geometry or its colours much:
#: decoded here, or appearance-only (lighting models, metadata) that citylod draws unlit anyway.
_HONOURED = {
    "KHR_draco_mesh_compression", "KHR_mesh_quantization", "EXT_mesh_gpu_instancing", "CESIUM_RTC",
    "KHR_materials_unlit", "KHR_materials_pbrSpecularGlossiness", "KHR_materials_emissive_strength",
    "EXT_mesh_features", "EXT_structural_metadata", "EXT_instance_features", "CESIUM_primitive_outline",
    "KHR_binary_glTF", "KHR_techniques_webgl", "EXT_meshopt_compression", "EXT_texture_webp",
    "KHR_texture_transform", "KHR_texture_basisu",
}


def decode_glb(data: bytes, source: str = "", *, rtc_center: F64 | None = None, y_up: bool = True,
               resolve: Resolver | None = None) -> TileContent:
    """Decode a glb (glTF 2.0, or 1.0 as in 3D Tiles 1.0 b3dm) into :class:`TileContent`.

    ``rtc_center`` is a b3dm's ``RTC_CENTER`` (z-up, added to every position); ``y_up`` False reads a tileset
    whose ``asset.gltfUpAxis`` is Z; ``resolve`` reads URIs of external buffers and images.
    """
    if len(data) < 20:
        raise InputError("content is truncated (shorter than a glb header)", source)
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != b"glTF":
        raise InputError(f"not a glb file (magic {magic!r})", source)
    if length > len(data):
        raise InputError(f"glb is truncated ({len(data)} of {length} bytes)", source)
    if version == 1:
        json_len, fmt = struct.unpack_from("<II", data, 12)
        if fmt != 0:
            raise InputError(f"glTF 1.0 content format {fmt} is not JSON", source)
        gltf = _json(data[20: 20 + json_len], source)
        return decode_gltf(_gltf1_to_2(gltf, source), [bytes(data[20 + json_len: length])], source,
                           rtc_center=rtc_center, y_up=y_up, resolve=resolve)
    if version != 2:
        raise InputError(f"glTF version {version} is not supported (1 and 2 are)", source)
    off, doc, binary = 12, None, b""
    while off + 8 <= length:
        clen, ctype = struct.unpack_from("<I4s", data, off)
        chunk = data[off + 8: off + 8 + clen]
        if len(chunk) != clen:
            raise InputError("glb chunk is truncated", source)
        if ctype == b"JSON":
            doc = _json(chunk, source)
        elif ctype == b"BIN\x00" and not binary:
            binary = chunk
        off += 8 + clen + (-clen % 4)
    if not isinstance(doc, dict):
        raise InputError("glb has no JSON chunk", source)
    return decode_gltf(doc, [binary], source, rtc_center=rtc_center, y_up=y_up, resolve=resolve)


def decode_gltf_json(data: bytes, source: str = "", *, y_up: bool = True,
                     resolve: Resolver | None = None) -> TileContent:
    """Decode a ``.gltf`` (JSON) file; its buffers are data URIs or files read through ``resolve``."""
    doc = _json(data, source)
    if str(doc.get("asset", {}).get("version", "2.0")).startswith("1"):
        doc = _gltf1_to_2(doc, source)
    return decode_gltf(doc, [], source, y_up=y_up, resolve=resolve)


def decode_gltf(gltf: dict[str, Any], chunks: list[bytes], source: str, *, rtc_center: F64 | None = None,
                y_up: bool = True, resolve: Resolver | None = None) -> TileContent:
    """Decode a parsed glTF 2.0 document; ``chunks`` holds a glb's binary chunk (buffer 0 without a URI)."""
    missing = sorted(set(gltf.get("extensionsRequired", [])) - _HONOURED)
    if missing:
        raise InputError(f"glTF content needs extensions citylod does not decode: {'; '.join(missing)}", source)
    try:
        buffers = _buffers(gltf, chunks, source, resolve)
        if rtc_center is None and "CESIUM_RTC" in gltf.get("extensions", {}):
            rtc_center = np.asarray(gltf["extensions"]["CESIUM_RTC"]["center"], float)
        images = _images(gltf, buffers, resolve, source)
        content = TileContent()
        point_parts: list[PointData] = []
        for mesh_index, node_m, instances in _node_matrices(gltf, buffers):
            prims = gltf["meshes"][mesh_index]["primitives"]
            for group in _primitive_groups(prims):
                _decode_group(gltf, buffers, group, node_m, instances, rtc_center, y_up, images, source,
                              content, point_parts)
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise InputError(f"glTF content is invalid ({type(exc).__name__}: {exc})", source) from exc
    if point_parts:
        content.points = _concat_points(point_parts)
    ext = gltf.get("extensions", {}).get("EXT_structural_metadata")
    if isinstance(ext, dict) and ext.get("propertyTables"):
        content.property_tables = decode_property_tables(
            ext, lambda i: _view_bytes(gltf, buffers, i, source), source)
    # Positions were kept float64 (z-up, without the RTC centre): one origin for all, float32 relative to it.
    parts = [m.positions for m in content.meshes] + ([content.points.positions] if content.points else [])
    bounds = np.array([[p.min(axis=0), p.max(axis=0)] for p in parts if len(p)]).reshape(-1, 3)
    _, shift = recentre(bounds)
    for m in content.meshes:
        m.positions = (m.positions - shift).astype(np.float32)
    if content.points is not None:
        content.points.positions = (content.points.positions - shift).astype(np.float32)
    content.origin = shift + (np.zeros(3) if rtc_center is None else np.asarray(rtc_center, np.float64))
    return content


# ----------------------------------------------------------------------------------------------- parts
def _json(raw: bytes, source: str) -> dict[str, Any]:
    try:
        doc = json.loads(bytes(raw).decode("utf-8").rstrip(" \x00"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"glTF JSON is corrupt ({exc})", source) from exc
    if not isinstance(doc, dict):
        raise InputError("glTF JSON is not an object", source)
    return doc


def _uri_bytes(uri: str, resolve: Resolver | None, source: str) -> bytes:
    if uri.startswith("data:"):
        head, _, payload = uri.partition(",")
        return base64.b64decode(payload) if head.endswith(";base64") else urllib.parse.unquote_to_bytes(payload)
    if resolve is None:
        raise InputError(f"glTF refers to an external file {uri!r} that cannot be read here", source)
    return resolve(uri)


def _buffers(gltf: dict[str, Any], chunks: list[bytes], source: str, resolve: Resolver | None) -> list[bytes]:
    out: list[bytes] = []
    for i, buf in enumerate(gltf.get("buffers", [])):
        if "uri" in buf:
            out.append(_uri_bytes(buf["uri"], resolve, source))
        elif buf.get("extensions", {}).get("EXT_meshopt_compression", {}).get("fallback"):
            out.append(b"")  # read only through EXT_meshopt_compression
        else:
            out.append(chunks[0] if i == 0 and chunks else b"")
    return out


def _view_bytes(gltf: dict[str, Any], buffers: list[bytes], index: int, source: str) -> bytes:
    bv = gltf["bufferViews"][index]
    if "EXT_meshopt_compression" in bv.get("extensions", {}):
        cache = gltf.setdefault("_meshopt_views", {})  # views shared by interleaved accessors decode once
        if index not in cache:
            cache[index] = _meshopt_view(bv["extensions"]["EXT_meshopt_compression"], buffers, index, source)
        return cache[index]
    data = buffers[int(bv.get("buffer", 0))]
    start, n = int(bv.get("byteOffset", 0)), int(bv["byteLength"])
    if start + n > len(data):
        raise InputError(f"buffer view {index} reaches past the end of its buffer", source)
    return data[start: start + n]


_MESHOPT_FILTERS = {"NONE", "OCTAHEDRAL", "QUATERNION", "EXPONENTIAL"}


def _meshopt_view(ext: dict[str, Any], buffers: list[bytes], index: int, source: str) -> bytes:
    """A buffer view compressed by ``EXT_meshopt_compression``, decoded by meshoptimizer's own decoders.

    The extension's bitstreams (vertex codec, index codec, filters) are meshoptimizer's, and so is the decoder
    here: its C++ library through the binding its repository publishes. The decoders check every read
    against the input's end, so a damaged stream is an error code, never a read past the buffer.
    """
    import meshoptimizer as mo

    try:
        data = buffers[int(ext.get("buffer", 0))]
        start, n = int(ext.get("byteOffset", 0)), int(ext["byteLength"])
        count, stride = int(ext["count"]), int(ext["byteStride"])
        mode, filt = str(ext["mode"]), str(ext.get("filter", "NONE"))
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise InputError(f"buffer view {index}: EXT_meshopt_compression is incomplete ({exc!r})", source) from exc
    if start < 0 or n < 0 or start + n > len(data):
        raise InputError(f"buffer view {index}: its meshopt stream reaches past the end of its buffer", source)
    if filt not in _MESHOPT_FILTERS or (filt != "NONE" and mode != "ATTRIBUTES"):
        raise InputError(f"buffer view {index}: meshopt filter {filt!r} with mode {mode!r} is not part of "
                         "EXT_meshopt_compression", source)
    # The extension's constraints, checked here: the C decoders assert them (an abort, not an error).
    if (mode == "ATTRIBUTES" and not (0 < stride <= 256 and stride % 4 == 0)) or (mode == "TRIANGLES" and count % 3) \
            or (filt == "OCTAHEDRAL" and stride not in (4, 8)) or (filt == "QUATERNION" and stride != 8) \
            or count < 0:
        raise InputError(f"buffer view {index}: meshopt {mode} {filt} with byteStride {stride} and count {count} "
                         "breaks EXT_meshopt_compression's rules", source)
    stream = np.frombuffer(data, np.uint8, count=n, offset=start)
    try:
        if mode == "ATTRIBUTES":
            out = mo.decode_vertex_buffer(count, stride, stream).view(np.uint8).reshape(-1)
            if filt == "OCTAHEDRAL":
                out = mo.decode_filter_oct(out, count, stride)
            elif filt == "QUATERNION":
                out = mo.decode_filter_quat(out, count, stride)
            elif filt == "EXPONENTIAL":
                out = mo.decode_filter_exp(out, count, stride)
        elif mode in ("TRIANGLES", "INDICES"):
            if stride not in (2, 4):
                raise ValueError(f"index byteStride {stride} is not 2 or 4")
            # Decoded as 4-byte indices: the stream does not depend on the index size, and the binding returns
            # a uint32 array whatever size it is asked to write.
            decode = mo.decode_index_buffer if mode == "TRIANGLES" else mo.decode_index_sequence
            out = decode(count, 4, stream).astype(np.uint16 if stride == 2 else np.uint32)
        else:
            raise ValueError(f"mode {mode!r} is not ATTRIBUTES, TRIANGLES or INDICES")
    except (ValueError, RuntimeError) as exc:
        raise InputError(f"buffer view {index}: meshopt stream cannot be decoded ({exc})", source) from exc
    return out.tobytes()


def _normalize(arr: np.ndarray) -> np.ndarray:
    """glTF normalized integers as float32: unsigned c/max, signed max(c/max, −1) (glTF 2.0 §3.11)."""
    info = np.iinfo(arr.dtype)
    out = arr.astype(np.float32) / np.float32(info.max)
    return np.maximum(out, -1.0) if info.min < 0 else out


def _read_accessor(gltf: dict[str, Any], buffers: list[bytes], index: int, source: str) -> np.ndarray:
    """An accessor's values: (count,) for scalars, else (count, ncomp); normalized integers as float32."""
    acc = gltf["accessors"][index]
    dtype = np.dtype(_COMPONENT[acc["componentType"]])
    ncomp = _NCOMP[acc["type"]]
    count = int(acc["count"])
    if "sparse" in acc:
        raise InputError("sparse glTF accessors are not supported", source)
    if "bufferView" not in acc:
        arr = np.zeros((count, ncomp), dtype)
    else:
        view = _view_bytes(gltf, buffers, acc["bufferView"], source)
        start = int(acc.get("byteOffset", 0))
        stride = int(gltf["bufferViews"][acc["bufferView"]].get("byteStride", 0) or acc.get("byteStride", 0)) \
            or dtype.itemsize * ncomp
        end = start + stride * (count - 1) + dtype.itemsize * ncomp if count else start
        if end > len(view) or start < 0:
            raise InputError(f"glTF accessor {index} reaches past the end of its buffer view", source)
        raw = np.frombuffer(view, np.uint8, count=end - start, offset=start)
        if stride == dtype.itemsize * ncomp:
            arr = raw.view(dtype).reshape(count, ncomp)
        else:
            rows = np.lib.stride_tricks.as_strided(raw, (count, dtype.itemsize * ncomp), (stride, 1))
            arr = np.ascontiguousarray(rows).view(dtype).reshape(count, ncomp)
    if acc.get("normalized") and dtype.kind in "ui":
        arr = _normalize(arr)
    if "_decodeMatrix" in acc:  # glTF 1.0 WEB3D_quantized_attributes: v = M · (q, 1), M column-major
        m = np.asarray(acc["_decodeMatrix"], np.float64).reshape(ncomp + 1, ncomp + 1).T
        arr = arr.astype(np.float64) @ m[:ncomp, :ncomp].T + m[:ncomp, ncomp]
    return arr[:, 0] if ncomp == 1 else arr


def _quat_matrix(q: np.ndarray) -> np.ndarray:
    """(K, 3, 3) rotation matrices of (K, 4) unit quaternions (x, y, z, w)."""
    x, y, z, w = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], axis=1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], axis=1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=1),
    ], axis=1)


def _node_matrix(node: dict[str, Any]) -> F64:
    if "matrix" in node:
        return np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T
    m = np.eye(4)
    m[:3, :3] = _quat_matrix(np.asarray([node.get("rotation", [0, 0, 0, 1])], float))[0] \
        * np.asarray(node.get("scale", [1, 1, 1]), float)
    m[:3, 3] = node.get("translation", [0, 0, 0])
    return m


def _node_matrices(gltf: dict[str, Any], buffers: list[bytes]) -> list[tuple[int, F64, F64 | None]]:
    """(mesh index, 4×4 node-to-scene matrix, (K, 4, 4) ``EXT_mesh_gpu_instancing`` instance matrices or None)
    for every mesh instance of the default scene, in glTF axes."""
    nodes = gltf.get("nodes", [])
    scenes = gltf.get("scenes") or [{"nodes": list(range(len(nodes)))}]
    roots = scenes[gltf.get("scene", 0)].get("nodes", [])
    out: list[tuple[int, F64, F64 | None]] = []
    stack = [(int(i), np.eye(4), 0) for i in roots]
    while stack:
        i, parent, depth = stack.pop()
        if depth > 64 or len(out) > 100000:
            raise InputError("glTF node hierarchy is cyclic or too deep", "")
        node = nodes[i]
        world = parent @ _node_matrix(node)
        if "mesh" in node:
            out.append((int(node["mesh"]), world, _instances(gltf, node, buffers)))
        stack.extend((int(c), world, depth + 1) for c in node.get("children", []))
    return out


def _instances(gltf: dict[str, Any], node: dict[str, Any], buffers: list[bytes]) -> F64 | None:
    ext = node.get("extensions", {}).get("EXT_mesh_gpu_instancing")
    if not ext:
        return None
    attrs = ext["attributes"]
    k = int(gltf["accessors"][next(iter(attrs.values()))]["count"])
    m = np.tile(np.eye(4), (k, 1, 1))
    t = _read_accessor(gltf, buffers, attrs["TRANSLATION"], "") if "TRANSLATION" in attrs else np.zeros((k, 3))
    r = _read_accessor(gltf, buffers, attrs["ROTATION"], "") if "ROTATION" in attrs else np.tile([0, 0, 0, 1.0], (k, 1))
    s = _read_accessor(gltf, buffers, attrs["SCALE"], "") if "SCALE" in attrs else np.ones((k, 3))
    m[:, :3, :3] = _quat_matrix(np.asarray(r, float)) * np.asarray(s, float)[:, None, :]
    m[:, :3, 3] = t
    return m


def _primitive_groups(prims: list[dict[str, Any]]) -> list[list[dict[str, Any]]]:
    """Primitives sharing POSITION, mode and material (citylod's surface + skirt pair) form one mesh."""
    groups: dict[tuple[Any, ...], list[dict[str, Any]]] = {}
    for n, prim in enumerate(prims):
        if "POSITION" not in prim.get("attributes", {}):
            continue
        draco = prim.get("extensions", {}).get("KHR_draco_mesh_compression")
        key = ("draco", n) if draco else (prim["attributes"]["POSITION"], prim.get("mode", 4), prim.get("material"))
        groups.setdefault(key, []).append(prim)
    return list(groups.values())


def _draco_attributes(gltf: dict[str, Any], buffers: list[bytes], prim: dict[str, Any],
                      source: str) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
    """The attributes and triangle indices of a ``KHR_draco_mesh_compression`` primitive."""
    try:
        import DracoPy
    except ImportError as exc:  # a dependency, but keep the message clear where it is missing
        raise InputError("Draco-compressed glTF needs the DracoPy package", source) from exc
    ext = prim["extensions"]["KHR_draco_mesh_compression"]
    try:
        decoded = DracoPy.decode(_view_bytes(gltf, buffers, ext["bufferView"], source))
    except Exception as exc:  # DracoPy raises its own and ValueError types
        raise InputError(f"Draco data is corrupt ({exc})", source) from exc
    out: dict[str, np.ndarray] = {}
    for name, uid in ext["attributes"].items():
        att = decoded.get_attribute_by_unique_id(int(uid))
        if att is None or name not in prim["attributes"]:
            continue
        acc = gltf["accessors"][prim["attributes"][name]]
        data = np.asarray(att["data"])
        if acc.get("normalized") and data.dtype.kind in "ui":
            data = _normalize(data.astype(_COMPONENT[acc["componentType"]]))
        out[name] = data[:, 0] if data.ndim == 2 and data.shape[1] == 1 else data
    faces = getattr(decoded, "faces", None)
    return out, None if faces is None else np.asarray(faces, np.uint32).reshape(-1)


def _decode_group(gltf: dict[str, Any], buffers: list[bytes], group: list[dict[str, Any]], node_m: F64,
                  instances: F64 | None, rtc_center: F64 | None, y_up: bool, images: list[bytes | None],
                  source: str, content: TileContent, point_parts: list[PointData]) -> None:
    first = group[0]
    mode = first.get("mode", 4)
    draco_idx = None
    if "KHR_draco_mesh_compression" in first.get("extensions", {}):
        attrs, draco_idx = _draco_attributes(gltf, buffers, first, source)

        def attribute(name: str) -> np.ndarray:
            return attrs[name] if name in attrs else _read_accessor(gltf, buffers, first["attributes"][name], source)
    else:
        def attribute(name: str) -> np.ndarray:
            return _read_accessor(gltf, buffers, first["attributes"][name], source)
    names = first["attributes"]
    local = np.asarray(attribute("POSITION"), np.float64).reshape(-1, 3)
    mats = [node_m] if instances is None else [node_m @ m for m in instances]
    pos = np.concatenate([local @ m[:3, :3].T + m[:3, 3] for m in mats])
    pos32 = pos @ _Z_UP_TO_Y_UP if y_up else pos  # y-up -> z-up (p_zup = M^T p_yup); float64 until the end
    nv, k = len(local), len(mats)

    def repeat(a: np.ndarray) -> np.ndarray:
        return a if k == 1 else np.concatenate([a] * k)

    colors = None
    if "COLOR_0" in names:
        colors = repeat(linear_colors_to_srgb8(_with_factor(attribute("COLOR_0"), gltf, first)))
    if mode == 0:
        pts = PointData(positions=pos32, rgb=None if colors is None else colors[:, :3].copy())
        if colors is None:
            pts.rgb = _material_rgb(gltf, first, len(pos32))
        if first.get("extras", {}).get("citylod_rgb_from_class"):
            pts.rgb = None  # class colours citylod wrote for other clients; it colours by class itself
        for gl_name, attr in _POINT_ATTRS.items():
            if gl_name in names:
                setattr(pts, attr, repeat(np.asarray(attribute(gl_name))).copy())
        for name, dt in first.get("extras", {}).get("citylod_extra_dtypes", {}).items():
            if "_" + name.upper() in names:
                pts.extra[name] = repeat(np.asarray(attribute("_" + name.upper()))).astype(np.dtype(dt))
        point_parts.append(pts)
        return
    if mode not in (4, 5, 6):
        return  # lines are not drawn by citylod
    # A node or instance whose matrix mirrors (negative determinant) turns the front faces clockwise (glTF
    # 2.0 §3.7.4); the positions are baked here, so such copies get their triangles reversed, and the faces
    # seen as front stay the ones the material means.
    mirrored = np.array([np.linalg.det(m[:3, :3]) < 0.0 for m in mats])
    faces_list, skirt_list = [], []
    for prim in group:
        if draco_idx is not None:
            idx = draco_idx
        elif "indices" in prim:
            idx = _read_accessor(gltf, buffers, prim["indices"], source).astype(np.uint32)
        else:
            idx = np.arange(nv, dtype=np.uint32)
        tri = _triangles(idx, prim.get("mode", 4))
        if len(tri) and int(tri.max()) >= nv:
            raise InputError("triangle indices point past the vertices", source)
        if k > 1:
            tri = tri[None, :, :] + (np.arange(k, dtype=np.uint32) * nv)[:, None, None]
            tri[mirrored] = tri[mirrored][..., ::-1]
            tri = tri.reshape(-1, 3)
        elif mirrored[0]:
            tri = tri[:, ::-1]
        faces_list.append(np.ascontiguousarray(tri))
        skirt_list.append(np.full(len(tri), bool(prim.get("extras", {}).get("citylod_skirt", False))))
    uv = None
    texture, tex_info = _material_texture(gltf, first, images)
    coords = f"TEXCOORD_{_texcoord_set(tex_info)}"
    if texture is not None and coords in names:
        uv = repeat(_texture_transform(np.asarray(attribute(coords), np.float32), tex_info))
    else:
        texture = None
    if colors is None and texture is None:
        rgb = _material_rgb(gltf, first, len(pos32))
        if rgb is not None:
            colors = np.concatenate([rgb, np.full((len(rgb), 1), 255, np.uint8)], axis=1)
    content.meshes.append(MeshData(
        positions=pos32, faces=np.concatenate(faces_list), skirt=np.concatenate(skirt_list),
        uv=uv, texture=texture, colors=colors,
        name=str(first.get("extras", {}).get("citylod_name", "surface")),
        features=_feature_ids(first, lambda name: repeat(np.asarray(attribute(name)))),
        double_sided=_double_sided(gltf, first),
    ))


def _double_sided(gltf: dict[str, Any], prim: dict[str, Any]) -> bool:
    """The primitive's ``material.doubleSided``; False (the default material's) without one (glTF 2.0 §3.9)."""
    if "material" not in prim:
        return False
    try:
        return bool(gltf["materials"][prim["material"]].get("doubleSided", False))
    except (KeyError, IndexError, TypeError, AttributeError):
        return True  # a broken reference: draw both sides rather than guess


def _feature_ids(prim: dict[str, Any], attribute: Any) -> list[FeatureIdSet]:
    """The attribute-based feature ID sets of a primitive (``EXT_mesh_features``); implicit and texture
    feature IDs are not read."""
    out = []
    ext = prim.get("extensions", {}).get("EXT_mesh_features", {})
    for fid in ext.get("featureIds", []) if isinstance(ext, dict) else []:
        name = f"_FEATURE_ID_{fid.get('attribute')}"
        if "attribute" not in fid or name not in prim.get("attributes", {}):
            continue
        ids = np.asarray(attribute(name))
        out.append(FeatureIdSet(np.round(ids).astype(np.uint32).reshape(-1), fid.get("propertyTable"),
                                int(fid.get("featureCount", 0)), fid.get("label")))
    return out


def _base_color_factor(gltf: dict[str, Any], prim: dict[str, Any]) -> list[float] | None:
    try:
        return list(gltf["materials"][prim["material"]]["pbrMetallicRoughness"]["baseColorFactor"])
    except (KeyError, IndexError, TypeError):
        return None


def _with_factor(c: np.ndarray, gltf: dict[str, Any], prim: dict[str, Any]) -> np.ndarray:
    """Vertex colours times the material's base colour factor (both linear, glTF 2.0 §3.9.2)."""
    f = _base_color_factor(gltf, prim)
    if f is None or np.allclose(f, 1.0):
        return c
    c = np.asarray(c)
    lin = c.astype(np.float64) / (65535.0 if c.dtype == np.uint16 else 255.0 if c.dtype == np.uint8 else 1.0)
    lin = lin if lin.ndim == 2 else lin[:, None].repeat(3, axis=1)
    return lin * np.asarray(f[: lin.shape[1]], float)


def _material_rgb(gltf: dict[str, Any], prim: dict[str, Any], n: int) -> np.ndarray | None:
    """(n, 3) sRGB bytes of the material's base colour factor, or None when there is none."""
    f = _base_color_factor(gltf, prim)
    if f is None:
        return None
    rgb = np.round(linear_to_srgb(np.asarray(f[:3], float)) * 255.0).astype(np.uint8)
    return np.tile(rgb, (n, 1))


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


def _images(gltf: dict[str, Any], buffers: list[bytes], resolve: Resolver | None,
            source: str) -> list[bytes | None]:
    out: list[bytes | None] = []
    for img in gltf.get("images", []):
        if "bufferView" in img:
            out.append(_view_bytes(gltf, buffers, img["bufferView"], source))
        elif "uri" in img:
            try:
                out.append(_uri_bytes(img["uri"], resolve, source))
            except InputError:
                out.append(None)  # an untextured mesh still shows its geometry
        else:
            out.append(None)
    return out


def _material_texture(gltf: dict[str, Any], prim: dict[str, Any], images: list[bytes | None]
                      ) -> tuple[bytes | None, dict[str, Any]]:
    """The base colour texture's image bytes (None when there is none or it cannot be decoded) and its
    ``textureInfo`` (``texCoord``, ``KHR_texture_transform``).

    The image is the texture's ``source`` (the fallback a writer must give when the extension is optional),
    else its ``EXT_texture_webp`` source (OpenImageIO reads WebP) or its ``KHR_texture_basisu`` source (a KTX2
    file, transcoded by Basis Universal: `citylod.io.image.decode_ktx2`).
    """
    try:
        mat = gltf["materials"][prim["material"]]
    except (KeyError, IndexError, TypeError):
        return None, {}
    info = mat.get("pbrMetallicRoughness", {}).get("baseColorTexture", {})
    index = info.get("index") if isinstance(info, dict) else None
    if index is None:  # KHR_techniques_webgl (glTF 1.0 shaders carried into 2.0): its first texture value
        values = mat.get("extensions", {}).get("KHR_techniques_webgl", {}).get("values", {})
        info = next((v for v in values.values() if isinstance(v, dict) and "index" in v), {})
        index = info.get("index")
    try:
        tex = gltf["textures"][index] if index is not None else {}
        ext = tex.get("extensions", {})
        src = tex.get("source", ext.get("EXT_texture_webp", ext.get("KHR_texture_basisu", {})).get("source"))
        return (None if src is None else images[src]), info
    except (KeyError, IndexError, TypeError, AttributeError):
        return None, {}


def _texcoord_set(info: dict[str, Any]) -> int:
    """Which TEXCOORD_n a texture reads: ``KHR_texture_transform.texCoord`` overrides ``texCoord``."""
    t = info.get("extensions", {}).get("KHR_texture_transform", {}) if isinstance(info, dict) else {}
    try:
        return int(t.get("texCoord", info.get("texCoord", 0)))
    except (TypeError, ValueError):
        return 0


def _texture_transform(uv: np.ndarray, info: dict[str, Any]) -> np.ndarray:
    """UVs mapped by ``KHR_texture_transform``: uv' = offset + R(r) · S(scale) · uv with u' = u cos r + v sin r and
    v' = v cos r − u sin r, the extension's counter-clockwise turn as CesiumJS, cesium-native and three.js apply it
    (v grows downwards in glTF's UV space)."""
    t = info.get("extensions", {}).get("KHR_texture_transform") if isinstance(info, dict) else None
    if not t:
        return uv
    try:
        ox, oy = (float(v) for v in t.get("offset", (0.0, 0.0)))
        sx, sy = (float(v) for v in t.get("scale", (1.0, 1.0)))
        r = float(t.get("rotation", 0.0))
    except (TypeError, ValueError):
        return uv
    c, s = math.cos(r), math.sin(r)
    u, v = uv[:, 0].astype(np.float64) * sx, uv[:, 1].astype(np.float64) * sy
    return np.stack([c * u + s * v + ox, -s * u + c * v + oy], axis=1).astype(np.float32)


def _concat_points(parts: list[PointData]) -> PointData:
    if len(parts) == 1:
        return parts[0]
    out = PointData(positions=np.concatenate([p.positions for p in parts]))
    for attr in ("rgb", "intensity", "classification", "return_number"):
        vals = [getattr(p, attr) for p in parts]
        if all(v is not None for v in vals):
            setattr(out, attr, np.concatenate(vals))
    return out


# ------------------------------------------------------------------------------------------------ glTF 1.0
def _gltf1_to_2(doc: dict[str, Any], source: str) -> dict[str, Any]:
    """The parts of a glTF 1.0 document citylod draws, in glTF 2.0 layout (id-keyed dicts become arrays)."""
    try:
        ids = {key: {k: i for i, k in enumerate(doc.get(key, {}))}
               for key in ("buffers", "bufferViews", "accessors", "meshes", "nodes", "materials", "textures",
                           "images")}
        out: dict[str, Any] = {"asset": {"version": "2.0"}, "extensionsUsed": doc.get("extensionsUsed", [])}
        out["buffers"] = [({} if k == "binary_glTF" or "uri" not in b or b["uri"].startswith("data:,")
                           else {"uri": b["uri"]}) | {"byteLength": b.get("byteLength", 0)}
                          for k, b in doc.get("buffers", {}).items()]
        if "binary_glTF" in ids["buffers"] and ids["buffers"]["binary_glTF"] != 0:
            raise InputError("glTF 1.0 binary buffer must be the first buffer", source)
        out["bufferViews"] = [{"buffer": ids["buffers"][v["buffer"]], "byteOffset": v.get("byteOffset", 0),
                               "byteLength": v["byteLength"]} for v in doc.get("bufferViews", {}).values()]
        out["accessors"] = [{"bufferView": ids["bufferViews"][a["bufferView"]],
                             "byteOffset": a.get("byteOffset", 0), "byteStride": a.get("byteStride", 0),
                             "componentType": a["componentType"], "count": a["count"], "type": a["type"],
                             "normalized": bool(a.get("normalized", False))}
                            | ({"_decodeMatrix": a["extensions"]["WEB3D_quantized_attributes"]["decodeMatrix"]}
                               if "WEB3D_quantized_attributes" in a.get("extensions", {}) else {})
                            for a in doc.get("accessors", {}).values()]
        out["images"] = []
        for img in doc.get("images", {}).values():
            binary = img.get("extensions", {}).get("KHR_binary_glTF")
            out["images"].append({"bufferView": ids["bufferViews"][binary["bufferView"]]} if binary
                                 else {"uri": img.get("uri", "")})
        out["textures"] = [{"source": ids["images"][t["source"]]} for t in doc.get("textures", {}).values()]
        out["materials"] = []
        for m in doc.get("materials", {}).values():
            values = m.get("values", {}) or m.get("extensions", {}).get("KHR_materials_common", {}).get("values", {})
            diffuse = values.get("diffuse")
            pbr: dict[str, Any] = {}
            if isinstance(diffuse, str) and diffuse in ids["textures"]:
                pbr["baseColorTexture"] = {"index": ids["textures"][diffuse]}
            elif isinstance(diffuse, list) and len(diffuse) >= 3:
                # glTF 1.0 colours are sRGB; 2.0 factors linear (gltf-pipeline's updateVersion converts too)
                rgb = srgb_to_linear(np.clip(np.asarray(diffuse[:3], float), 0, 1))
                pbr["baseColorFactor"] = [*map(float, rgb), float(diffuse[3]) if len(diffuse) > 3 else 1.0]
            # glTF 1.0 culls through technique states, which are not read: draw both sides.
            out["materials"].append({"pbrMetallicRoughness": pbr, "doubleSided": True})
        out["meshes"] = []
        for mesh in doc.get("meshes", {}).values():
            prims = []
            for p in mesh.get("primitives", []):
                q: dict[str, Any] = {"attributes": {n: ids["accessors"][a] for n, a in p.get("attributes", {}).items()
                                                    if a in ids["accessors"]},
                                     "mode": p.get("mode", 4)}
                if "indices" in p:
                    q["indices"] = ids["accessors"][p["indices"]]
                if p.get("material") in ids["materials"]:
                    q["material"] = ids["materials"][p["material"]]
                prims.append(q)
            out["meshes"].append({"primitives": prims})
        # A 1.0 node holds a list of meshes: each becomes a child node of its own.
        nodes: list[dict[str, Any]] = []
        for n in doc.get("nodes", {}).values():
            node = {k: n[k] for k in ("matrix", "translation", "rotation", "scale") if k in n}
            node["children"] = [ids["nodes"][c] for c in n.get("children", [])]
            nodes.append(node)
        for i, n in enumerate(doc.get("nodes", {}).values()):
            for mid in n.get("meshes", []):
                nodes[i]["children"].append(len(nodes))
                nodes.append({"mesh": ids["meshes"][mid]})
        out["nodes"] = nodes
        scenes = doc.get("scenes", {})
        scene = scenes.get(doc.get("scene"), next(iter(scenes.values()), {"nodes": []}))
        out["scenes"] = [{"nodes": [ids["nodes"][n] for n in scene.get("nodes", [])]}]
        out["scene"] = 0
        if "CESIUM_RTC" in doc.get("extensions", {}):
            out["extensions"] = {"CESIUM_RTC": doc["extensions"]["CESIUM_RTC"]}
        return out
    except (KeyError, TypeError, AttributeError, StopIteration) as exc:
        raise InputError(f"glTF 1.0 document is invalid ({type(exc).__name__}: {exc})", source) from exc


__all__ = ["Resolver", "decode_glb", "decode_gltf", "decode_gltf_json"]
