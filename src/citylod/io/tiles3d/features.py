"""Feature IDs and property tables in glTF: ``EXT_mesh_features`` and ``EXT_structural_metadata``.

A mesh vertex carries, per feature ID set, the row of a property table (``_FEATURE_ID_<k>`` vertex attribute);
the tables live once per glb. This is how 3D Tiles 1.1 content says which city object a triangle belongs to
and what its attributes are, so that any client (CesiumJS, the 3D Tiles validator, citylod) can pick and
style by attribute.

Property values are typed columns: float arrays become ``FLOAT64`` (NaN written as the class's ``noData``),
integer arrays ``INT32``/``INT64`` (same), and lists of strings ``STRING`` (None written as the empty string,
the ``noData`` of string properties). Buffer views of property values are aligned to 8 bytes, as the
extension requires.

Knows only the encoding; what a feature is (a city object, a surface class) is the builder's business.
No VTK and no Qt here.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from citylod.core.errors import InputError

__all__ = ["FeatureIdSet", "PropertyTable", "decode_property_tables", "encode_property_tables"]

Column = npt.NDArray[np.float64] | npt.NDArray[np.int32] | npt.NDArray[np.int64] | list[str | None]

_FLOAT_NODATA = -1.7976931348623157e308  # the most negative float64: no attribute value is that
_INT_NODATA = {"INT32": -(2**31), "INT64": -(2**63)}
_ID_RE = re.compile(r"^[a-zA-Z_][a-zA-Z0-9_]*$")


@dataclass
class PropertyTable:
    """One ``EXT_structural_metadata`` property table: ``class_name`` and its ``columns``, each of
    ``count`` rows (float64 / int32 / int64 arrays with NaN or the integer minimum for no value, or lists of
    str with None for no value)."""

    class_name: str
    columns: dict[str, Column] = field(default_factory=dict)

    @property
    def count(self) -> int:
        return len(next(iter(self.columns.values()))) if self.columns else 0

    def row(self, i: int) -> dict[str, Any]:
        """Row ``i`` as a dict (no-data values as None)."""
        out: dict[str, Any] = {}
        for name, col in self.columns.items():
            v: Any = col[i]
            if isinstance(col, np.ndarray):
                if col.dtype.kind == "f":
                    v = None if np.isnan(v) else float(v)
                else:
                    v = None if int(v) == int(np.iinfo(col.dtype).min) else int(v)  # type: ignore[type-var]
            out[name] = v
        return out


@dataclass
class FeatureIdSet:
    """One feature ID set of a mesh: ``ids`` (N,) uint32 per vertex, the ``table`` (index into the content's
    property tables) they index, or None, and ``count`` distinct features (default: ``max(ids) + 1``)."""

    ids: npt.NDArray[np.uint32]
    table: int | None = None
    count: int | None = None
    label: str | None = None

    @property
    def feature_count(self) -> int:
        if self.count is not None:
            return int(self.count)
        return int(self.ids.max()) + 1 if len(self.ids) else 0


class _Builder(Protocol):  # the part of content._GlbBuilder used here
    def view(self, data: bytes | np.ndarray, target: int | None = None, stride: int | None = None,
             align: int = 4) -> int: ...


def _kind(col: Column) -> str:
    if isinstance(col, np.ndarray):
        if col.dtype.kind == "f":
            return "FLOAT64"
        if col.dtype.kind in "iub":
            return "INT64" if col.dtype.itemsize == 8 else "INT32"
        raise ValueError(f"unsupported column dtype {col.dtype}")
    return "STRING"


def encode_property_tables(b: _Builder, tables: list[PropertyTable], schema_id: str = "citylod") -> dict[str, Any]:
    """The glTF-level ``EXT_structural_metadata`` object for ``tables``; their bytes go into ``b``.

    Tables of the same class must have the same columns (the class is defined once, from the first).
    """
    classes: dict[str, Any] = {}
    out_tables = []
    for t in tables:
        if not _ID_RE.match(t.class_name):
            raise ValueError(f"class name {t.class_name!r} is not an identifier")
        props_def = classes.setdefault(t.class_name, {"properties": {}})["properties"]
        props: dict[str, Any] = {}
        for name, col in t.columns.items():
            if not _ID_RE.match(name):
                raise ValueError(f"property name {name!r} is not an identifier")
            kind = _kind(col)
            if kind == "STRING":
                strs = ["" if s is None else str(s) for s in col]
                enc = [s.encode("utf-8") for s in strs]
                offsets = np.zeros(len(enc) + 1, np.uint32)
                offsets[1:] = np.cumsum([len(e) for e in enc], dtype=np.uint64).astype(np.uint32)
                props_def.setdefault(name, {"type": "STRING", "noData": ""})
                if not offsets[-1]:
                    # No value at all: the property is left out of the table (it is not required, so a
                    # reader takes its noData), since a buffer view cannot be empty.
                    continue
                props[name] = {"values": b.view(b"".join(enc), align=8),
                               "stringOffsets": b.view(offsets, align=8), "stringOffsetType": "UINT32"}
            elif kind == "FLOAT64":
                col64 = np.asarray(col, np.float64)
                vals = np.where(np.isnan(col64), _FLOAT_NODATA, col64)
                props_def.setdefault(name, {"type": "SCALAR", "componentType": kind, "noData": _FLOAT_NODATA})
                props[name] = {"values": b.view(vals.astype("<f8"), align=8)}
            else:
                dt = "<i8" if kind == "INT64" else "<i4"
                props_def.setdefault(name, {"type": "SCALAR", "componentType": kind, "noData": _INT_NODATA[kind]})
                props[name] = {"values": b.view(np.asarray(col).astype(dt), align=8)}
        out_tables.append({"class": t.class_name, "count": t.count, "properties": props})
    return {"schema": {"id": schema_id, "classes": classes}, "propertyTables": out_tables}


def decode_property_tables(ext: dict[str, Any], view_bytes: Any, source: str) -> list[PropertyTable]:
    """Property tables from a glTF-level ``EXT_structural_metadata`` object; ``view_bytes(i)`` gives the
    bytes of buffer view ``i``. Only the scalar, string and integer properties citylod writes are read;
    others are skipped."""
    try:
        classes = ext.get("schema", {}).get("classes", {})
        out = []
        for t in ext.get("propertyTables", []):
            cls = classes.get(t["class"], {}).get("properties", {})
            count = int(t["count"])
            table = PropertyTable(str(t["class"]))
            for name, prop in t.get("properties", {}).items():
                d = cls.get(name, {})
                kind = d.get("type")
                raw = view_bytes(int(prop["values"]))
                if kind == "STRING":
                    ot = {"UINT8": "<u1", "UINT16": "<u2", "UINT32": "<u4", "UINT64": "<u8"}[
                        prop.get("stringOffsetType", "UINT32")]
                    off = np.frombuffer(view_bytes(int(prop["stringOffsets"])), ot, count=count + 1)
                    nodata = d.get("noData")
                    strs: list[str | None] = [bytes(raw[off[i]:off[i + 1]]).decode("utf-8") for i in range(count)]
                    table.columns[name] = [None if s == nodata else s for s in strs]
                elif kind == "SCALAR" and d.get("componentType") in ("FLOAT64", "FLOAT32", "INT32", "INT64"):
                    ct = d["componentType"]
                    dt = {"FLOAT64": "<f8", "FLOAT32": "<f4", "INT32": "<i4", "INT64": "<i8"}[ct]
                    arr = np.frombuffer(raw, dt, count=count).copy()
                    if ct.startswith("FLOAT"):
                        arr = arr.astype(np.float64)
                        if "noData" in d:
                            arr[arr == d["noData"]] = np.nan
                    elif "noData" in d:
                        arr[arr == d["noData"]] = np.iinfo(arr.dtype).min
                    table.columns[name] = arr
            for name, d in cls.items():  # properties left out of the table: no value in any row
                if name in table.columns:
                    continue
                if d.get("type") == "STRING":
                    table.columns[name] = [None] * count
                elif d.get("componentType") in ("FLOAT64", "FLOAT32"):
                    table.columns[name] = np.full(count, np.nan)
                elif d.get("componentType") in ("INT32", "INT64"):
                    int_type: type[np.signedinteger[Any]] = np.int32 if d["componentType"] == "INT32" else np.int64
                    table.columns[name] = np.full(count, np.iinfo(int_type).min, int_type)
            out.append(table)
        return out
    except (KeyError, TypeError, ValueError, UnicodeDecodeError) as exc:
        raise InputError(f"EXT_structural_metadata is invalid ({exc})", source) from exc
