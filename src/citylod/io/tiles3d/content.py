"""Tile content: the in-memory model (:class:`TileContent`) and the glb citylod writes.

glTF is y-up and 3D Tiles turns it z-up when it places content; the writer turns z-up positions into glTF
axes, (x, y, z)_gltf = (x, z, −y)_zup (3D Tiles spec, "y-up to z-up"), and the readers (:mod:`.gltf`,
:mod:`.legacy`) turn them back, so callers only see z-up coordinates. Vertex colours are sRGB in memory and
linear on disk (:mod:`.colour`); per-point LAS attributes are described with ``EXT_structural_metadata``. Skirt triangles are stored as a separate primitive marked
``extras.citylod_skirt`` so standard clients draw them and citylod can tell them apart.

Knows what a tile *is*, never how it was chosen (no LOD logic). No VTK and no Qt here.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from citylod._version import __version__
from citylod.core.geometry import F64
from citylod.io.tiles3d.colour import SRGB8_TO_LINEAR8, SRGB8_TO_LINEAR16
from citylod.io.tiles3d.features import FeatureIdSet, PropertyTable, encode_property_tables

_COMPONENT = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_POINT_ATTRS = {"_INTENSITY": "intensity", "_CLASSIFICATION": "classification", "_RETURN_NUMBER": "return_number"}


# --------------------------------------------------------------------------------------------- content model
@dataclass
class MeshData:
    """One triangle mesh of a tile. ``positions`` (N, 3) float32 relative to the tile centre, z up;
    ``faces`` (M, 3) uint32; ``skirt`` (M,) bool or None; ``uv`` (N, 2) float32 (origin top-left);
    ``texture`` encoded JPEG/PNG bytes; ``colors`` (N, 4) uint8; ``features`` the feature ID sets
    (``EXT_mesh_features``), the k-th written as vertex attribute ``_FEATURE_ID_k``. ``double_sided``
    False: only the faces wound counter-clockwise seen from outside are to be drawn (glTF's
    ``material.doubleSided``; clients cull the back faces). Builders set it only where every triangle is
    wound that way: a height field's surface faces up and its skirts outward."""

    positions: npt.NDArray[np.float32]
    faces: npt.NDArray[np.uint32]
    skirt: npt.NDArray[np.bool_] | None = None
    uv: npt.NDArray[np.float32] | None = None
    texture: bytes | None = None
    colors: npt.NDArray[np.uint8] | None = None
    name: str = "surface"
    features: list[FeatureIdSet] = field(default_factory=list)
    double_sided: bool = True

    @property
    def nbytes(self) -> int:
        n = self.positions.nbytes + self.faces.nbytes
        for a in (self.uv, self.colors, self.skirt, *(f.ids for f in self.features)):
            n += 0 if a is None else a.nbytes
        return n + (len(self.texture) if self.texture else 0)


@dataclass
class PointData:
    """Points of a tile: ``positions`` (N, 3) float32 relative to the tile centre and per-point attributes.

    ``rgb_from_class``: ``rgb`` holds class colours for other 3D Tiles clients (a cloud without RGB), not
    measured colour; citylod writes them and reads them back as no RGB, keeping its own colour modes.
    """

    positions: npt.NDArray[np.float32]
    rgb: npt.NDArray[np.uint8] | None = None
    rgb_from_class: bool = False
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
    (``EXT_structural_metadata``) that the meshes' feature IDs index.

    Positions are float32 relative to ``origin`` (3,) float64, in the tile's z-up frame. A reader puts a
    content's large offset there (``RTC_CENTER``, a far node translation) instead of adding it to float32
    positions, which at ECEF magnitudes (≈6e6 m) would round them to half a metre.
    """

    meshes: list[MeshData] = field(default_factory=list)
    points: PointData | None = None
    origin: F64 = field(default_factory=lambda: np.zeros(3))
    property_tables: list[PropertyTable] = field(default_factory=list)

    def rebased(self, origin: npt.ArrayLike) -> TileContent:
        """This content with positions relative to ``origin`` (shifted in float64, stored float32)."""
        new = np.asarray(origin, np.float64)
        delta = self.origin - new
        if not delta.any():
            return self

        def shift(p: np.ndarray) -> np.ndarray:
            return (p.astype(np.float64) + delta).astype(np.float32)

        meshes = [replace(m, positions=shift(m.positions)) for m in self.meshes]
        points = None if self.points is None else replace(self.points, positions=shift(self.points.positions))
        return TileContent(meshes=meshes, points=points, origin=new, property_tables=self.property_tables)

    @staticmethod
    def merged(parts: list[TileContent]) -> TileContent:
        """One content holding every part's meshes and points, relative to the first part's origin."""
        if len(parts) == 1:
            return parts[0]
        origin = parts[0].origin if parts else np.zeros(3)
        parts = [p.rebased(origin) for p in parts]
        out = TileContent(meshes=[m for p in parts for m in p.meshes], origin=origin)
        pts = [p.points for p in parts if p.points is not None]
        if pts:
            out.points = PointData(np.concatenate([p.positions for p in pts]))
            for attr in ("rgb", "intensity", "classification", "return_number"):
                vals = [getattr(p, attr) for p in pts]
                if all(v is not None for v in vals):
                    setattr(out.points, attr, np.concatenate(vals))
        return out

    @property
    def nbytes(self) -> int:
        return sum(m.nbytes for m in self.meshes) + (self.points.nbytes if self.points is not None else 0)

    @property
    def triangle_count(self) -> int:
        return sum(len(m.faces) for m in self.meshes)

    @property
    def point_count(self) -> int:
        return 0 if self.points is None else len(self.points.positions)


def recentre(pos: np.ndarray, origin: npt.ArrayLike | None = None) -> tuple[npt.NDArray[np.float32], F64]:
    """(float32 positions, float64 origin) of float64 positions (N, 3): ``origin`` (default zero) plus, where
    the positions lie far from it (over 10 km), the centre of their bounding box, so float32 keeps them exact
    to well under a millimetre."""
    o = np.zeros(3) if origin is None else np.asarray(origin, np.float64).copy()
    pos = np.asarray(pos, np.float64).reshape(-1, 3)
    if len(pos) and float(np.abs(pos).max()) > 1e4:
        mid = np.round((pos.min(axis=0) + pos.max(axis=0)) / 2.0)
        pos = pos - mid
        o = o + mid
    return pos.astype(np.float32), o


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
        material: dict[str, Any] = {"name": mesh.name, "doubleSided": bool(mesh.double_sided),
                                    "pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 1.0}}
        if mesh.uv is not None and mesh.texture:
            attrs["TEXCOORD_0"] = b.accessor(np.asarray(mesh.uv, dtype=np.float32), "VEC2")
            mime = "image/png" if mesh.texture[:8] == b"\x89PNG\r\n\x1a\n" else "image/jpeg"
            img = b.add("images", {"bufferView": b.view(mesh.texture), "mimeType": mime})
            # Mipmaps only for power-of-two images: WebGL 1 clients cannot mipmap others; LINEAR then, which
            # they sample as is. citylod's own builders write power-of-two textures only (the validator
            # reports any other, whatever the sampler); other sizes come from re-encoding others' content.
            w, h = _image_size(mesh.texture)
            pot = w > 0 and h > 0 and not (w & (w - 1)) and not (h & (h - 1))
            smp = b.add("samplers", {"magFilter": 9729, "minFilter": 9987 if pot else 9729,
                                     "wrapS": 33071, "wrapT": 33071})
            tex = b.add("textures", {"source": img, "sampler": smp})
            material["pbrMetallicRoughness"]["baseColorTexture"] = {"index": tex}
            if mime == "image/png":
                material["alphaMode"] = "MASK"
            material["extensions"] = {"KHR_materials_unlit": {}}
            unlit = True
        if mesh.colors is not None:
            attrs["COLOR_0"] = b.accessor(_linear_rgba16(mesh.colors), "VEC4", normalized=True)
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
        props = {prop: _METADATA_TYPES[gl_name] for gl_name, prop in _POINT_ATTRS.items()
                 if getattr(pts, prop) is not None}
        for name, arr in pts.extra.items():
            a = np.asarray(arr)
            dtypes[name] = a.dtype.str
            stored = a if a.dtype in (np.uint8, np.uint16, np.float32) else a.astype(np.float32)
            attrs["_" + name.upper()] = b.accessor(stored, "SCALAR")
            props[name] = {"UINT8": "UINT8", "UINT16": "UINT16"}.get(stored.dtype.name.upper(), "FLOAT32")
        mat = b.add("materials", {"name": "points", "extensions": {"KHR_materials_unlit": {}},
                                  "pbrMetallicRoughness": {"metallicFactor": 0.0}})
        unlit = True
        prim = {"attributes": attrs, "mode": 0, "material": mat,
                "extras": {"citylod_name": "points", "citylod_extra_dtypes": dtypes}}
        if pts.rgb is not None and pts.rgb_from_class:
            prim["extras"]["citylod_rgb_from_class"] = True
        if props:
            _point_metadata(b, prim, props)
        if pts.classification is not None:
            _class_features(b, prim, np.asarray(pts.classification))
        primitives.append(prim)
    if primitives:
        b.gltf["meshes"] = [{"primitives": primitives}]
        b.gltf["nodes"] = [{"mesh": 0}]
        b.gltf["scenes"] = [{"nodes": [0]}]
        b.gltf["scene"] = 0
    used = b.gltf.setdefault("extensionsUsed", [])
    if any("EXT_mesh_features" in p.get("extensions", {}) for p in primitives) and "EXT_mesh_features" not in used:
        used.append("EXT_mesh_features")
    if content.property_tables:
        ext = b.gltf.setdefault("extensions", {})
        if "EXT_structural_metadata" in ext:
            raise ValueError("property tables and point attributes in one content are not supported")
        ext["EXT_structural_metadata"] = encode_property_tables(b, content.property_tables)
        used.append("EXT_structural_metadata")
    if unlit:
        used.insert(0, "KHR_materials_unlit")
    if not used:
        del b.gltf["extensionsUsed"]
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


#: 3D Tiles metadata component type of each LAS attribute citylod writes on points.
_METADATA_TYPES = {"_INTENSITY": "UINT16", "_CLASSIFICATION": "UINT8", "_RETURN_NUMBER": "UINT8"}
_METADATA_DESCRIPTIONS = {
    "classification": "ASPRS LAS point classification (2 ground, 6 building, ...)",
    "intensity": "LAS return intensity",
    "return_number": "LAS return number (1 = first return)",
}


def _point_metadata(b: _GlbBuilder, prim: dict[str, Any], props: dict[str, str]) -> None:
    """Describe the per-point attributes with ``EXT_structural_metadata`` property attributes (3D Tiles 1.1),
    so any client can style or pick by class, intensity or return: a schema with one class ``point`` whose
    properties name the ``_``-prefixed vertex attributes that hold them."""
    properties = {}
    for name, ctype in props.items():
        properties[name] = {"type": "SCALAR", "componentType": ctype}
        if name in _METADATA_DESCRIPTIONS:
            properties[name]["description"] = _METADATA_DESCRIPTIONS[name]
    b.gltf["extensions"] = {"EXT_structural_metadata": {
        "schema": {"id": "citylod_points", "classes": {"point": {"properties": properties}}},
        "propertyAttributes": [{"class": "point", "properties": {
            name: {"attribute": "_" + name.upper()} for name in props}}],
    }}
    prim["extensions"] = {"EXT_structural_metadata": {"propertyAttributes": [0]}}
    b.gltf.setdefault("extensionsUsed", []).append("EXT_structural_metadata")


def _class_features(b: _GlbBuilder, prim: dict[str, Any], classification: np.ndarray) -> None:
    """The LAS class as an ``EXT_mesh_features`` feature ID: clients that pick or style by feature (CesiumJS's
    ``feature.featureId``) see one feature per class. ``_FEATURE_ID_0`` names the classification accessor
    itself, so no bytes are added."""
    count = int(np.count_nonzero(np.bincount(classification, minlength=1)))
    prim["attributes"]["_FEATURE_ID_0"] = prim["attributes"]["_CLASSIFICATION"]
    prim.setdefault("extensions", {})["EXT_mesh_features"] = {
        "featureIds": [{"featureCount": max(count, 1), "attribute": 0, "label": "classification"}]}
    if "EXT_mesh_features" not in b.gltf.setdefault("extensionsUsed", []):
        b.gltf["extensionsUsed"].append("EXT_mesh_features")


def _linear_rgba16(colors: npt.ArrayLike) -> npt.NDArray[np.uint16]:
    """(N, 4) normalized uint16 linear RGBA of (N, 3 or 4) sRGB bytes (:mod:`.colour`); alpha rescaled only."""
    c = np.asarray(colors, np.uint8).reshape(len(np.asarray(colors)), -1)
    out = np.empty((len(c), 4), np.uint16)
    out[:, :3] = SRGB8_TO_LINEAR16[c[:, :3]]
    out[:, 3] = c[:, 3].astype(np.uint16) * 257 if c.shape[1] == 4 else 65535
    return out


def _image_size(data: bytes) -> tuple[int, int]:
    """(width, height) of PNG or JPEG bytes from their header; (0, 0) when neither."""
    if data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) >= 24:
        w, h = struct.unpack_from(">II", data, 16)
        return int(w), int(h)
    i = 2
    while data[:2] == b"\xff\xd8" and i + 9 < len(data):
        if data[i] != 0xFF:
            break
        marker, seglen = data[i + 1], struct.unpack_from(">H", data, i + 2)[0]
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):  # start of frame
            h, w = struct.unpack_from(">HH", data, i + 5)
            return int(w), int(h)
        i += 2 + seglen
    return 0, 0


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

    pos_out, rgb_out, ret_out = np.empty((n, 3), np.float32), np.empty((n, 4), np.uint16), np.empty((n, 4), np.uint8)
    int_out, cls_out = np.empty((n, 2), np.uint16), np.empty((n, 4), np.uint8)
    lo, hi = np.empty(3, np.float32), np.empty(3, np.float32)
    measured = None if pts.rgb_from_class else pts.rgb
    point_vertex_columns(pos, column(measured, np.uint8, 3), SRGB8_TO_LINEAR16, column(pts.intensity, np.uint16, 1),
                         column(pts.classification, np.uint8, 1), column(pts.return_number, np.uint8, 1),
                         pos_out, rgb_out, int_out, cls_out, ret_out, lo, hi)

    attrs = {"POSITION": b.register(b.view(pos_out, 34962), 5126, n, "VEC3", lo=[float(v) for v in lo],
                                    hi=[float(v) for v in hi])}
    if measured is not None:
        attrs["COLOR_0"] = b.register(b.view(rgb_out, 34962, 8), 5123, n, "VEC3", normalized=True)
    elif pts.rgb is not None:  # class colours for other clients: 8-bit linear is enough for a palette
        lin8 = np.zeros((n, 4), np.uint8)
        lin8[:, :3] = SRGB8_TO_LINEAR8[np.asarray(pts.rgb, np.uint8).reshape(n, 3)]
        attrs["COLOR_0"] = b.register(b.view(lin8, 34962, 4), 5121, n, "VEC3", normalized=True)
    outs: tuple[np.ndarray, ...] = (int_out, cls_out, ret_out)
    for (gl_name, attr), out, ctype in zip(_POINT_ATTRS.items(), outs, (5123, 5121, 5121), strict=True):
        if getattr(pts, attr) is not None:
            attrs[gl_name] = b.register(b.view(out, 34962, 4), ctype, n, "SCALAR")
    return attrs
