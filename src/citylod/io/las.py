"""LAS / LAZ input: headers first, then points in bounded chunks.

What this module is for: everything the point-cloud builder needs to know about its input files
(count, bounds, CRS, point format) read from the headers alone, and a chunked decoder that turns
LAS records into one fixed in-memory layout (:data:`POINT_DTYPE`) whatever the point format. Bad input
becomes an :class:`~citylod.core.errors.InputError` that names the file: a truncated or corrupt LAZ
stream (also when it breaks mid-way), a file with no points, a file without CRS when none was given,
files whose CRSs disagree.

What it must not do: hold a whole file in memory (reads go through ``laspy.open(...).chunk_iterator``
or ``read_points``), import anything heavier than laspy, or touch VTK / Qt.
"""

from __future__ import annotations

import os
import struct
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pyproj

from citylod.core.errors import CitylodError, EmptyInputError, GeoreferenceError, InputError
from citylod.io.crs import parse_crs

#: The one in-memory layout of a point, whatever the LAS point format: float64 coordinates in the source
#: CRS, 8-bit RGB (0 when the format has no colour), the attributes the renderer uses, and the LAS
#: *synthetic* flag (1 for points a tool added, e.g. the walls of :mod:`citylod.lod.build.complete`).
POINT_DTYPE = np.dtype([
    ("x", "f8"), ("y", "f8"), ("z", "f8"),
    ("intensity", "u2"), ("classification", "u1"), ("return_number", "u1"),
    ("red", "u1"), ("green", "u1"), ("blue", "u1"),
    ("synthetic", "u1"),
])

_SUFFIXES = {".las", ".laz"}
_RGB_FORMATS = {2, 3, 5, 7, 8, 10}


@dataclass(frozen=True)
class LasInfo:
    """What the header of one LAS/LAZ file says.

    Attributes
    ----------
    path
        The file.
    point_count
        Number of point records the header announces.
    lo, hi
        (3,) float64 bounds from the header, in the source CRS.
    scale, offset
        (3,) float64 quantisation of the stored integer coordinates.
    crs
        The CRS from the header's VLRs, or None when the header has none.
    point_format
        LAS point data record format id (0–10).
    version
        LAS version, e.g. "1.2".
    """

    path: Path
    point_count: int
    lo: npt.NDArray[np.float64]
    hi: npt.NDArray[np.float64]
    scale: npt.NDArray[np.float64]
    offset: npt.NDArray[np.float64]
    crs: pyproj.CRS | None
    point_format: int
    version: str

    @property
    def has_rgb(self) -> bool:
        return self.point_format in _RGB_FORMATS


@dataclass(frozen=True)
class LasMetadata:
    """Several LAS/LAZ files read as one cloud (headers only).

    Attributes
    ----------
    files
        Per-file header information, in the order given.
    crs
        The common CRS (the override when one was given).
    point_count
        Sum of the files' point counts.
    lo, hi
        (3,) float64 union of the header bounds.
    has_rgb
        True when every file's point format carries RGB.
    """

    files: tuple[LasInfo, ...]
    crs: pyproj.CRS
    point_count: int
    lo: npt.NDArray[np.float64]
    hi: npt.NDArray[np.float64]
    has_rgb: bool


def supports(path: str | PathLike[str]) -> bool:
    """True when ``path`` looks like LAS/LAZ: by suffix, else by the 4-byte ``LASF`` signature.

    Constant time: at most four bytes are read.
    """
    p = Path(path)
    if p.suffix.lower() in _SUFFIXES:
        return True
    try:
        with open(p, "rb") as f:
            return f.read(4) == b"LASF"
    except OSError:
        return False


# Public header fields (LAS 1.0-1.4, little endian) that say how much follows, read before laspy is: laspy
# reads as many VLR headers as the count says, past the end of the file, so a 260-byte file claiming 4e9
# VLRs keeps it busy for ever and growing. Each VLR header is 54 bytes, each extended VLR header 60.
_HEADER_MIN = 227
_VLR_HEADER_BYTES = 54
_EVLR_HEADER_BYTES = 60


def check_header(path: str | PathLike[str]) -> None:
    """Refuse a LAS/LAZ header whose record counts cannot fit in the file, before laspy reads it.

    Raises
    ------
    InputError
        Missing file, no ``LASF`` signature, a header shorter than LAS 1.0's, or more (extended) variable
        length records than the file has bytes for.
    """
    p = Path(path)
    try:
        size = p.stat().st_size
        with open(p, "rb") as fh:
            head = fh.read(375)
    except FileNotFoundError:
        raise InputError("no such file", p) from None
    except OSError as exc:
        raise InputError(f"cannot read ({exc.strerror})", p) from exc
    if head[:4] != b"LASF":
        raise InputError("not a LAS/LAZ file (no LASF signature)", p)
    if len(head) < _HEADER_MIN:
        raise InputError(f"LAS header is cut short ({len(head)} bytes)", p)
    header_size, point_offset, n_vlrs = struct.unpack_from("<HII", head, 94)
    if n_vlrs * _VLR_HEADER_BYTES > size or point_offset > size or header_size > size:
        raise InputError(f"LAS header claims {n_vlrs:,} variable length records and point data at byte "
                         f"{point_offset:,}, but the file has {size:,} bytes", p)
    n_points = struct.unpack_from("<I", head, 107)[0]
    if head[24:26] >= b"\x01\x04" and len(head) >= 255:
        evlr_start, n_evlrs, n_points64 = struct.unpack_from("<QIQ", head, 235)
        n_points = n_points64 or n_points
        if n_evlrs and (evlr_start > size or n_evlrs * _EVLR_HEADER_BYTES > size - min(evlr_start, size)):
            raise InputError(f"LAS header claims {n_evlrs:,} extended records at byte {evlr_start:,}, but the "
                             f"file has {size:,} bytes", p)
    if head[104] & 0x80 and n_points:  # LAZ: bit 7 of the point format marks compressed points
        _check_chunk_table(p, point_offset, size, n_points)


def _check_chunk_table(p: Path, point_offset: int, size: int, n_points: int) -> None:
    """Refuse a LAZ chunk table that cannot be right; lazrs allocates 16 bytes per chunk the table claims
    before reading it, and aborts the process (no exception) when that allocation fails."""
    with open(p, "rb") as fh:
        fh.seek(point_offset)
        raw = fh.read(8)
        if len(raw) < 8:
            raise InputError("LAZ point data is cut short", p)
        table = struct.unpack("<q", raw)[0]
        if table == -1:  # written by a streaming writer that never came back to fill it in: no table
            return
        if not point_offset + 8 <= table <= size - 8:
            raise InputError(f"LAZ chunk table offset {table:,} lies outside the file ({size:,} bytes)", p)
        fh.seek(table)
        version, n_chunks = struct.unpack("<II", fh.read(8))
    # Each chunk holds at least one point and takes at least a byte of the file.
    if version != 0 or n_chunks > min(n_points, size):
        raise InputError(f"LAZ chunk table is corrupt (version {version}, {n_chunks:,} chunks for {n_points:,} "
                         "points)", p)


def _laspy_errors() -> tuple[type[BaseException], ...]:
    # laspy wraps most failures in LaspyException, but lazrs raises its own error type, and a stream that
    # ends early surfaces as ValueError / EOFError / OSError from numpy or the decompressor.
    import laspy

    errs: list[type[BaseException]] = [laspy.errors.LaspyException, ValueError, EOFError, OSError, RuntimeError]
    try:
        import lazrs

        errs.append(lazrs.LazrsError)
    except (ImportError, AttributeError):
        pass
    return tuple(errs)


def read_info(path: str | PathLike[str]) -> LasInfo:
    """Read the header of one LAS/LAZ file (no point data).

    Raises
    ------
    InputError
        The file is missing, not LAS/LAZ, or its header is corrupt.
    """
    import laspy

    p = Path(path)
    check_header(p)
    try:
        with laspy.open(p) as reader:
            h = reader.header
            try:
                crs = h.parse_crs()
            except Exception:
                crs = None
            return LasInfo(
                path=p, point_count=int(h.point_count),
                lo=np.asarray(h.mins, np.float64).copy(), hi=np.asarray(h.maxs, np.float64).copy(),
                scale=np.asarray(h.scales, np.float64).copy(), offset=np.asarray(h.offsets, np.float64).copy(),
                crs=crs, point_format=int(h.point_format.id), version=str(h.version),
            )
    except FileNotFoundError:
        raise InputError("no such file", p) from None
    except _laspy_errors() as exc:
        raise InputError(f"not a readable LAS/LAZ file ({exc})", p) from exc


def read_metadata(files: Sequence[str | PathLike[str]], crs: Any = None) -> LasMetadata:
    """Read the headers of ``files`` and check they form one cloud.

    Parameters
    ----------
    files
        LAS/LAZ paths.
    crs
        CRS override (EPSG code, WKT, ``pyproj.CRS``); needed when the headers carry none.

    Raises
    ------
    EmptyInputError
        No files, or a file with zero points.
    GeoreferenceError
        A file has no CRS and no override was given, or the files' CRSs differ.
    InputError
        A header cannot be read.
    """
    if not files:
        raise EmptyInputError("no input point files given")
    infos = tuple(read_info(f) for f in files)
    for info in infos:
        if info.point_count == 0:
            raise EmptyInputError("the file holds no points", info.path)
    if crs is not None:
        common = parse_crs(crs)
    else:
        missing = [i for i in infos if i.crs is None]
        if missing:
            raise GeoreferenceError("the header has no CRS; pass one with --crs, with its height datum "
                                    "(e.g. --crs EPSG:7415 for RD New + NAP heights)",
                                    missing[0].path)
        first = infos[0].crs
        assert first is not None
        common = first
        for info in infos[1:]:
            assert info.crs is not None
            if not info.crs.equals(common, ignore_axis_order=True):
                raise GeoreferenceError(
                    f"CRS {info.crs.name!r} differs from {common.name!r} of {infos[0].path}; "
                    "reproject the files to one CRS or pass --crs to override", info.path)
    lo = np.min([i.lo for i in infos], axis=0)
    hi = np.max([i.hi for i in infos], axis=0)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise InputError("header bounds are not finite", infos[0].path)
    return LasMetadata(files=infos, crs=common, point_count=sum(i.point_count for i in infos), lo=lo, hi=hi,
                       has_rgb=all(i.has_rgb for i in infos))


def _to_records(pts: Any, has_rgb: bool) -> npt.NDArray[np.void]:
    """laspy ScaleAwarePointRecord (n points) -> (n,) :data:`POINT_DTYPE`."""
    n = len(pts)
    out = np.empty(n, POINT_DTYPE)
    out["x"] = pts.x
    out["y"] = pts.y
    out["z"] = pts.z
    out["intensity"] = pts.intensity
    out["classification"] = pts.classification
    out["return_number"] = pts.return_number
    out["synthetic"] = pts.synthetic
    if has_rgb:
        # LAS stores 16-bit colour; the spec asks writers to scale 8-bit colour up, so the high byte is it.
        out["red"] = np.asarray(pts.red) >> 8
        out["green"] = np.asarray(pts.green) >> 8
        out["blue"] = np.asarray(pts.blue) >> 8
    else:
        out["red"] = out["green"] = out["blue"] = 0
    return out


def point_fields(pts: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                    np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The raw columns of a laspy point record behind :data:`POINT_DTYPE`, whatever the point format,
    for a caller that converts them in a compiled pass of its own (no copies: views where laspy has them).

    Returns
    -------
    X, Y, Z
        (n,) int32 unscaled coordinates; position = ``X * scales[0] + offsets[0]`` (as laspy scales).
    scales, offsets
        (3,) float64.
    intensity
        (n,) uint16.
    classification, return_number
        (n,) uint8.
    red, green, blue
        (n,) uint16 (LAS colour is 16-bit; its high byte is the 8-bit colour), or (0,) when the format
        has none.
    synthetic
        (n,) uint8, 1 where the point's *synthetic* flag is set.
    """
    a = pts.array
    names = a.dtype.names or ()
    empty = np.zeros(0, np.uint16)
    red, green, blue = (a[c] if c in names else empty for c in ("red", "green", "blue"))
    return (a["X"], a["Y"], a["Z"], np.asarray(pts.scales, np.float64), np.asarray(pts.offsets, np.float64),
            a["intensity"], np.asarray(pts.classification, np.uint8), np.asarray(pts.return_number, np.uint8),
            red, green, blue, np.asarray(pts.synthetic, np.uint8))


def iter_points(path: str | PathLike[str], *, start: int = 0, count: int | None = None,
                chunk_points: int = 1_000_000, raw: bool = False) -> Iterator[Any]:
    """Decode points ``[start, start + count)`` of one file in chunks of at most ``chunk_points``.

    ``raw``: yield laspy's point records as decoded, for a caller that converts them itself (see
    :func:`point_fields`).

    Yields
    ------
    (n,) POINT_DTYPE arrays, n ≤ ``chunk_points`` (laspy ``ScaleAwarePointRecord`` with ``raw``).

    Raises
    ------
    InputError
        Naming the file, when the stream is corrupt or ends before the header's point count (a truncated
        LAZ), also when that happens after some chunks were already yielded.
    """
    import laspy

    p = Path(path)
    check_header(p)
    errors = _laspy_errors()
    got = 0
    try:
        with laspy.open(p) as reader:
            total = int(reader.header.point_count)
            count = total - start if count is None else min(count, total - start)
            has_rgb = int(reader.header.point_format.id) in _RGB_FORMATS
            if start:
                reader.seek(start)
            while got < count:
                pts = reader.read_points(min(chunk_points, count - got))
                if len(pts) == 0:
                    break
                got += len(pts)
                yield pts if raw else _to_records(pts, has_rgb)
    except CitylodError:
        raise
    except FileNotFoundError:
        raise InputError("no such file", p) from None
    except errors as exc:
        raise InputError(f"corrupt or truncated point data after {start + got:,} points ({exc})", p) from exc
    if got < count:
        raise InputError(f"file ends after {start + got:,} of {start + count:,} points (truncated?)", p)


def decode_seconds(files: Sequence[str | PathLike[str]], chunk_points: int = 1_000_000) -> float:
    """Wall time to decode every point of ``files`` with plain laspy, in this process.

    The floor a build's throughput is compared with: a build reads all points at least once.
    """
    import laspy

    t0 = time.perf_counter()
    for f in files:
        with laspy.open(os.fspath(f)) as reader:
            for pts in reader.chunk_iterator(chunk_points):
                # Touch the scaled coordinates, as a build must.
                _ = (pts.x, pts.y, pts.z)
    return time.perf_counter() - t0
