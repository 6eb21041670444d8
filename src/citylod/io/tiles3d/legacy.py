"""3D Tiles 1.0 tile formats (b3dm, i3dm, cmpt, pnts) and the content dispatcher :func:`decode_content`.

Each format is a header, a feature table (JSON + binary) and a batch table around a glb or a point body
(3D Tiles 1.0 specification, "Tile formats"). What CesiumJS reads, citylod reads: the two legacy b3dm
headers of early writers, gzip-compressed content, quantized and oct-encoded instance attributes, Draco
point clouds (``3DTILES_draco_point_compression``, decoded with DracoPy) and RGB565 colours. pnts colours
are sRGB bytes, as CesiumJS takes them. No VTK and no Qt here.
"""

from __future__ import annotations

import gzip
import json
import struct
import zlib
from typing import Any

import numpy as np
import pyproj

from citylod.core.errors import InputError
from citylod.core.frames import enu_to_ecef_matrix
from citylod.io.tiles3d.content import MeshData, PointData, TileContent, recentre
from citylod.io.tiles3d.gltf import Resolver, decode_glb, decode_gltf_json

#: CesiumJS's test for the legacy b3dm headers: a JSON length this large is really the start of the glb.
_LEGACY_LIMIT = 570425344
_FT_TYPES = {"BYTE": np.int8, "UNSIGNED_BYTE": np.uint8, "SHORT": np.int16, "UNSIGNED_SHORT": np.uint16,
             "INT": np.int32, "UNSIGNED_INT": np.uint32, "FLOAT": np.float32, "DOUBLE": np.float64}


def decode_content(data: bytes, source: str, *, y_up: bool = True, resolve: Resolver | None = None) -> TileContent:
    """Decode tile content by its first bytes: glb, glTF JSON, b3dm, i3dm, cmpt or pnts, gzip-compressed or not.

    ``resolve`` reads URIs the content refers to (external glTF buffers, an i3dm's external glb), relative to
    the content's folder. Unknown content is one :class:`InputError` naming its magic bytes.
    """
    if data[:2] == b"\x1f\x8b":
        try:
            data = gzip.decompress(data)
        except (OSError, EOFError, zlib.error) as exc:
            raise InputError(f"gzip-compressed content is corrupt ({exc})", source) from exc
    magic = bytes(data[:4])
    if magic == b"glTF":
        return decode_glb(data, source, y_up=y_up, resolve=resolve)
    if data[:1] == b"{" or data.lstrip()[:1] == b"{":
        return decode_gltf_json(data, source, y_up=y_up, resolve=resolve)
    if magic == b"b3dm":
        return _decode_b3dm(data, source, y_up, resolve)
    if magic == b"i3dm":
        return _decode_i3dm(data, source, y_up, resolve)
    if magic == b"cmpt":
        return _decode_cmpt(data, source, y_up, resolve)
    if magic == b"pnts":
        return _decode_pnts(data, source)
    if magic == b"PK\x03\x04" or data[:16] == b"SQLite format 3\x00":
        raise InputError("a 3D Tiles package (.3tz, .3dtiles) as tile content is not supported; open the package "
                         "itself as a tileset", source)
    if magic == b"vctr" or magic == b"geom":
        raise InputError(f"{magic.decode()} (vector / geometry) content is not supported", source)
    raise InputError(f"unknown tile content (magic {magic!r}); expected glb, glTF, b3dm, i3dm, cmpt or pnts", source)


def _feature_json(raw: bytes, source: str) -> dict[str, Any]:
    try:
        doc = json.loads(bytes(raw).decode("utf-8").rstrip(" \x00")) if bytes(raw).strip(b" \x00") else {}
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"feature table is corrupt ({exc})", source) from exc
    if not isinstance(doc, dict):
        raise InputError("feature table is not a JSON object", source)
    return doc


class _FeatureTable:
    """A feature table's JSON and binary body; :meth:`get` reads one per-feature property."""

    def __init__(self, data: bytes, start: int, json_len: int, bin_len: int, count_key: str, source: str):
        if start + json_len + bin_len > len(data):
            raise InputError("feature table reaches past the end of the content", source)
        self.json = _feature_json(data[start: start + json_len], source)
        self.body = data[start + json_len: start + json_len + bin_len]
        self.source = source
        try:
            self.n = int(self.json.get(count_key, 0))
        except (TypeError, ValueError) as exc:
            raise InputError(f"feature table {count_key} is not a number", source) from exc

    def positions(self, kind: str, decoded: dict[str, np.ndarray] | None = None) -> np.ndarray:
        """(n, 3) float64 ``POSITION``, or ``POSITION_QUANTIZED`` dequantized by the quantized volume
        (``decoded``: properties a Draco body already holds)."""
        decoded = decoded or {}
        pos = decoded.get("POSITION")
        if pos is None:
            pos = self.get("POSITION", np.float32, 3)
        if pos is not None:
            return np.asarray(pos, np.float64)
        q = decoded.get("POSITION_QUANTIZED")
        if q is None:
            q = self.get("POSITION_QUANTIZED", np.uint16, 3)
        if q is None:
            raise InputError(f"{kind} has neither POSITION nor POSITION_QUANTIZED", self.source)
        try:
            scale = np.asarray(self.json["QUANTIZED_VOLUME_SCALE"], float)
            offset = np.asarray(self.json["QUANTIZED_VOLUME_OFFSET"], float)
        except KeyError as exc:
            raise InputError(f"{kind} quantized positions lack {exc}", self.source) from exc
        return q.astype(np.float64) / 65535.0 * scale + offset

    def get(self, name: str, dtype: Any, ncomp: int) -> np.ndarray | None:
        if name not in self.json:
            return None
        ref = self.json[name]
        try:
            if isinstance(ref, list):  # a global value given inline
                return np.asarray(ref, dtype)
            dt = np.dtype(_FT_TYPES.get(ref.get("componentType", ""), dtype))
            off = int(ref["byteOffset"])
            if off + self.n * ncomp * dt.itemsize > len(self.body):
                raise InputError(f"feature table property {name} reaches past the binary body", self.source)
            return np.frombuffer(self.body, dt, count=self.n * ncomp, offset=off).reshape(self.n, ncomp)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"feature table property {name} is invalid ({exc})", self.source) from exc


def _decode_b3dm(data: bytes, source: str, y_up: bool, resolve: Resolver | None) -> TileContent:
    if len(data) < 28:
        raise InputError("b3dm header is truncated", source)
    _, _, length, ftj, ftb, btj, btb = struct.unpack_from("<4sIIIIII", data, 0)
    start = 28
    if btj >= _LEGACY_LIMIT:  # legacy header 1: [batchLength, batchTableByteLength], 20 bytes
        start, ftj, ftb, btj, btb = 20, 0, 0, struct.unpack_from("<I", data, 16)[0], 0
    elif btb >= _LEGACY_LIMIT:  # legacy header 2: [batchTableJson, batchTableBinary, batchLength], 24 bytes
        start, btj, btb = 24, ftj, ftb
        ftj = ftb = 0
    ft = _FeatureTable(data, start, ftj, ftb, "BATCH_LENGTH", source)
    rtc = np.asarray(ft.json["RTC_CENTER"], float) if "RTC_CENTER" in ft.json else None
    glb = data[start + ftj + ftb + btj + btb: min(length, len(data))]
    return decode_glb(glb, source, rtc_center=rtc, y_up=y_up, resolve=resolve)


def _oct_decode(e: np.ndarray) -> np.ndarray:
    """(K, 3) unit vectors of (K, 2) uint16 oct-encoded normals (Cigolle et al. 2014, as 3D Tiles stores them)."""
    f = e.astype(np.float64) / 65535.0 * 2.0 - 1.0
    v = np.column_stack([f[:, 0], f[:, 1], 1.0 - np.abs(f[:, 0]) - np.abs(f[:, 1])])
    neg = v[:, 2] < 0
    x, y = v[neg, 0].copy(), v[neg, 1].copy()
    v[neg, 0] = (1.0 - np.abs(y)) * np.where(x >= 0, 1.0, -1.0)
    v[neg, 1] = (1.0 - np.abs(x)) * np.where(y >= 0, 1.0, -1.0)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _decode_i3dm(data: bytes, source: str, y_up: bool, resolve: Resolver | None) -> TileContent:
    if len(data) < 32:
        raise InputError("i3dm header is truncated", source)
    _, _, length, ftj, ftb, btj, btb, fmt = struct.unpack_from("<4sIIIIIII", data, 0)
    ft = _FeatureTable(data, 32, ftj, ftb, "INSTANCES_LENGTH", source)
    body = data[32 + ftj + ftb + btj + btb: min(length, len(data))]
    if fmt == 0:
        uri = bytes(body).decode("utf-8", "replace").rstrip(" \x00")
        if resolve is None:
            raise InputError(f"i3dm refers to an external model {uri!r} that cannot be read here", source)
        body = resolve(uri)
    model = decode_glb(body, source, y_up=y_up, resolve=resolve)
    n = ft.n
    pos = ft.positions("i3dm")
    rtc = np.asarray(ft.json.get("RTC_CENTER", [0.0, 0.0, 0.0]), float)
    up, right = ft.get("NORMAL_UP", np.float32, 3), ft.get("NORMAL_RIGHT", np.float32, 3)
    if up is None and "NORMAL_UP_OCT32P" in ft.json:
        up = _oct_decode(ft.get("NORMAL_UP_OCT32P", np.uint16, 2))  # type: ignore[arg-type]
        right = _oct_decode(ft.get("NORMAL_RIGHT_OCT32P", np.uint16, 2))  # type: ignore[arg-type]
    rot = np.tile(np.eye(3), (n, 1, 1))
    if up is not None and right is not None:
        up, right = up.astype(np.float64), right.astype(np.float64)
        rot = np.stack([right, up, np.cross(right, up)], axis=2)  # columns: x = right, y = up, z = right × up
    elif ft.json.get("EAST_NORTH_UP"):
        e = pos + rtc
        lon, lat, _ = pyproj.Transformer.from_crs(4978, 4979, always_xy=True).transform(e[:, 0], e[:, 1], e[:, 2])
        rot = np.stack([enu_to_ecef_matrix(a, b, 0.0)[:3, :3] for a, b in zip(lon, lat, strict=True)])
    scale = np.ones((n, 3))
    s = ft.get("SCALE", np.float32, 1)
    if s is not None:
        scale = np.repeat(s.astype(np.float64), 3, axis=1)
    s3 = ft.get("SCALE_NON_UNIFORM", np.float32, 3)
    if s3 is not None:
        scale = scale * s3
    lin = rot * scale[:, None, :]
    # The model (z-up, positions + its origin) placed at every instance, one array operation per mesh; the
    # instances' mean position becomes the content's origin (with RTC_CENTER), keeping float32 small.
    centre = pos.mean(axis=0) if n else np.zeros(3)
    out = TileContent(origin=rtc + centre)
    for m in model.meshes:
        local = m.positions.astype(np.float64) + model.origin
        p = np.einsum("kij,vj->kvi", lin, local) + (pos - centre)[:, None, :]
        nv = len(m.positions)
        faces = m.faces[None].astype(np.int64) + (np.arange(n) * nv)[:, None, None]
        mirrored = np.linalg.det(lin) < 0.0  # a mirroring instance turns its front faces clockwise
        faces[mirrored] = faces[mirrored][..., ::-1]
        out.meshes.append(MeshData(
            positions=p.reshape(-1, 3).astype(np.float32), faces=faces.reshape(-1, 3).astype(np.uint32),
            skirt=None if m.skirt is None else np.tile(m.skirt, n),
            uv=None if m.uv is None else np.tile(m.uv, (n, 1)), texture=m.texture,
            colors=None if m.colors is None else np.tile(m.colors, (n, 1)), name=m.name,
            double_sided=m.double_sided))
    if model.points is not None:
        local = model.points.positions.astype(np.float64) + model.origin
        p = np.einsum("kij,vj->kvi", lin, local) + (pos - centre)[:, None, :]
        out.points = PointData(positions=p.reshape(-1, 3).astype(np.float32),
                               rgb=None if model.points.rgb is None else np.tile(model.points.rgb, (n, 1)))
    return out


def _decode_cmpt(data: bytes, source: str, y_up: bool, resolve: Resolver | None) -> TileContent:
    if len(data) < 16:
        raise InputError("cmpt header is truncated", source)
    _, _, length, count = struct.unpack_from("<4sIII", data, 0)
    parts: list[TileContent] = []
    off = 16
    for i in range(count):
        if off + 12 > min(length, len(data)):
            raise InputError(f"cmpt inner tile {i} is truncated", source)
        inner_len = struct.unpack_from("<I", data, off + 8)[0]
        if inner_len < 12:
            raise InputError(f"cmpt inner tile {i} has an invalid length {inner_len}", source)
        parts.append(decode_content(data[off: off + inner_len], f"{source} (inner tile {i})", y_up=y_up,
                                    resolve=resolve))
        off += inner_len
    return TileContent.merged(parts) if parts else TileContent()


def _decode_pnts(data: bytes, source: str) -> TileContent:
    if len(data) < 28:
        raise InputError("pnts header is truncated", source)
    _, _, _, ftj, ftb, _, _ = struct.unpack_from("<4sIIIIII", data, 0)
    ft = _FeatureTable(data, 28, ftj, ftb, "POINTS_LENGTH", source)
    draco = ft.json.get("extensions", {}).get("3DTILES_draco_point_compression")
    decoded = _draco_points(ft, draco, source) if draco else {}
    pos = ft.positions("pnts", decoded)
    if not np.all(np.isfinite(pos)):
        raise InputError("pnts positions are not finite numbers (corrupt or misread data)", source)
    pos32, origin = recentre(np.asarray(pos, np.float64), ft.json.get("RTC_CENTER"))
    rgb = decoded.get("RGB")
    if rgb is None:
        rgb = decoded.get("RGBA")
    if rgb is None:
        rgb = ft.get("RGB", np.uint8, 3)
    if rgb is None:
        rgb = ft.get("RGBA", np.uint8, 4)
    if rgb is None and "RGB565" in ft.json:
        c = ft.get("RGB565", np.uint16, 1)[:, 0].astype(np.uint32)  # type: ignore[index]
        rgb = np.column_stack([(c >> 11) * 255 // 31, ((c >> 5) & 63) * 255 // 63, (c & 31) * 255 // 31])
    if rgb is None and "CONSTANT_RGBA" in ft.json:
        rgb = np.tile(np.asarray(ft.json["CONSTANT_RGBA"], np.uint8)[:3], (len(pos32), 1))
    colours = None if rgb is None else np.ascontiguousarray(np.asarray(rgb)[:, :3], np.uint8)
    return TileContent(points=PointData(positions=pos32, rgb=colours), origin=origin)


def _draco_points(ft: _FeatureTable, ext: dict[str, Any], source: str) -> dict[str, np.ndarray]:
    """The feature-table properties a ``3DTILES_draco_point_compression`` body holds, by name."""
    try:
        import DracoPy
    except ImportError as exc:
        raise InputError("Draco-compressed pnts needs the DracoPy package", source) from exc
    try:
        off, n = int(ext["byteOffset"]), int(ext["byteLength"])
        decoded = DracoPy.decode(bytes(ft.body[off: off + n]))
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"3DTILES_draco_point_compression is invalid ({exc})", source) from exc
    except Exception as exc:  # DracoPy's own decoding errors
        raise InputError(f"Draco point data is corrupt ({exc})", source) from exc
    out: dict[str, np.ndarray] = {}
    for name, uid in ext.get("properties", {}).items():
        att = decoded.get_attribute_by_unique_id(int(uid))
        if att is None:
            # The feature table's own entry for a Draco property points into the compressed bytes: reading
            # it there is what returned ±3e38 and NaN before.
            raise InputError(f"Draco point data lacks its {name} attribute (id {uid}): corrupt", source)
        out[name] = np.asarray(att["data"])
    if "POSITION" in out:
        out["POSITION"] = out["POSITION"].astype(np.float64)
    for name in ("RGB", "RGBA"):
        if name in out:
            out[name] = np.clip(np.round(out[name]), 0, 255).astype(np.uint8) if out[name].dtype.kind == "f" \
                else out[name].astype(np.uint8)
    return out


__all__ = ["decode_content"]
