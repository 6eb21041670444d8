"""Open a city model file with the reader its content calls for (constant-time check of suffix and bytes)."""

from __future__ import annotations

from os import PathLike
from pathlib import Path

from citylod.core.errors import InputError
from citylod.io.city.model import CityModel


def read_city_model(path: str | PathLike[str], *, lod: int = 2) -> CityModel:
    """Read CityGML, CityJSON or CityJSONSeq (``.jsonl``), told apart by suffix and first bytes (constant time)."""
    p = Path(path)
    if not p.is_file():
        raise InputError("no such file", p)
    with open(p, "rb") as fh:
        head = fh.read(256).lstrip(b"\xef\xbb\xbf \t\r\n")
    if p.suffix.lower() == ".jsonl":
        from citylod.io.city.cityjson import read_cityjsonseq

        return read_cityjsonseq(p, lod=lod)
    if p.suffix.lower() in (".json", ".cityjson") or head.startswith(b"{"):
        from citylod.io.city.cityjson import read_cityjson

        return read_cityjson(p, lod=lod)
    if not head.startswith((b"<", b"\xff\xfe", b"\xfe\xff")):  # a raster, a point cloud, a glb (UTF-16 XML passes)
        raise InputError("not a city model: CityGML (XML), CityJSON or CityJSONSeq expected", p)
    from citylod.io.city.citygml import read_citygml

    return read_citygml(p, lod=lod)
