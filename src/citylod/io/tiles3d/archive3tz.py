"""The 3D Tiles Archive format (3TZ, v1.3): reading through its index, and writing it.

A 3TZ is a ZIP whose last central-directory entry, ``@3dtilesIndex1@``, stored uncompressed, lists every
other entry as 24 bytes: the MD5 of its normalised path (16 bytes) and the offset of its local file header
(8 bytes, little endian), sorted by the hash read as two little-endian unsigned 64-bit integers. A reader
finds a file by hashing its path and searching the index, then reads that one local header, so opening an
archive of a million tiles reads the end of the file and 24 MB of index, not the whole central directory
(which Python's :mod:`zipfile` parses into an object per entry). Entries are stored, deflated, or compressed
with Zstandard (method 93); local headers carry sizes and CRC (the format requires it), and the CRC is
checked.

:func:`write_3tz` packs a tileset folder into such an archive. Layout and index follow the format's
specification (3D Tiles Archive Format v1.3, which 3d-tiles-tools and CesiumJS's package server implement);
:func:`write_3dtiles` writes the other package format, an SQLite database; :func:`write_package` picks one by the
output's suffix.
"""

from __future__ import annotations

import hashlib
import os
import struct
import zipfile
import zlib
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

from citylod.core.errors import InputError
from citylod.core.fileio import atomic_write

INDEX_NAME = "@3dtilesIndex1@"
_EOCD = b"PK\x05\x06"
_EOCD64_LOCATOR = b"PK\x06\x07"
_EOCD64 = b"PK\x06\x06"
_CENTRAL = b"PK\x01\x02"
_LOCAL = b"PK\x03\x04"
_INDEX_DTYPE = np.dtype([("hi", "<u8"), ("lo", "<u8"), ("offset", "<u8")])
MAX_ENTRY_BYTES = 1 << 30  # 1 GiB: more than any tile or tileset JSON; a larger declared size is hostile


def normalise(name: str) -> str:
    """A path as the index hashes it: forward slashes, no leading slash."""
    return name.replace("\\", "/").lstrip("/")


def _hash(name: str) -> tuple[int, int]:
    digest = hashlib.md5(normalise(name).encode("utf-8")).digest()  # the format's hash, not a security one
    hi, lo = struct.unpack("<QQ", digest)
    return hi, lo


class NeedsCentralDirectory(Exception):
    """An entry the index finds but whose local header lacks its sizes: read it through the central directory."""


class Index3tz:
    """Reads entries of one 3TZ through its index; :meth:`open` returns None when the file has no index."""

    def __init__(self, fd: int, index: np.ndarray, file_size: int, source: str) -> None:
        self.fd = fd
        self.index = index
        self.file_size = file_size
        self.source = source

    @classmethod
    def open(cls, path: Path) -> Index3tz | None:
        fd = os.open(path, os.O_RDONLY)
        try:
            index = _read_index(fd, os.fstat(fd).st_size)
        except (InputError, struct.error, ValueError):
            index = None
        if index is None:
            os.close(fd)
            return None
        return cls(fd, index, os.fstat(fd).st_size, str(path))

    def close(self) -> None:
        os.close(self.fd)

    def _pread(self, n: int, offset: int) -> bytes:
        if offset < 0 or n < 0 or offset + n > self.file_size:
            raise InputError("the archive's index points past the end of the file", self.source)
        return os.pread(self.fd, n, offset)

    def _entry(self, name: str) -> tuple[int, int, int, int, int] | None:
        """(data offset, method, compressed size, size, crc) of the entry ``name``, or None."""
        hi, lo = _hash(name)
        i = int(np.searchsorted(self.index["hi"], np.uint64(hi)))
        want = normalise(name).encode("utf-8")
        while i < len(self.index) and int(self.index["hi"][i]) == hi:
            if int(self.index["lo"][i]) != lo:
                i += 1
                continue
            offset = int(self.index["offset"][i])
            head = self._pread(30, offset)
            if head[:4] != _LOCAL:
                raise InputError("the archive's index points at no local file header", self.source)
            _, _, flags, method, _, _, crc, csize, usize, nlen, xlen = struct.unpack("<4sHHHHHIIIHH", head)
            got = self._pread(nlen, offset + 30)
            if got == want:
                if flags & 0x08 and not (csize or usize):
                    raise NeedsCentralDirectory(name)  # sizes only in a data descriptor, against the format
                extra = self._pread(xlen, offset + 30 + nlen)
                if 0xFFFFFFFF in (csize, usize):
                    usize, csize = _zip64(extra, usize, csize)
                return offset + 30 + nlen + xlen, method, csize, usize, crc
            i += 1  # a hash collision: the next entry with the same hash
        return None

    def size(self, name: str) -> int | None:
        entry = self._entry(name)
        return None if entry is None else entry[3]

    def read(self, name: str) -> bytes | None:
        """The entry's bytes, None when the index does not list it."""
        entry = self._entry(name)
        if entry is None:
            return None
        start, method, csize, usize, crc = entry
        source = f"{self.source} ({normalise(name)})"
        if usize > MAX_ENTRY_BYTES or csize > MAX_ENTRY_BYTES:
            raise InputError(f"entry declares {max(usize, csize):,} bytes (more than {MAX_ENTRY_BYTES:,}); refused",
                             source)
        raw = self._pread(csize, start)
        try:
            if method == 0:
                data = raw
            elif method == 8:
                d = zlib.decompressobj(-15)
                data = d.decompress(raw, usize + 1)
            elif method == 93:
                import zstandard

                data = zstandard.ZstdDecompressor().decompress(raw, max_output_size=usize + 1)
            else:
                raise InputError(f"entry uses ZIP compression method {method}, which 3TZ does not allow", source)
        except (zlib.error, ValueError) as exc:
            raise InputError(f"package entry is damaged ({exc})", source) from exc
        except Exception as exc:  # zstandard.ZstdError has no common base with the others
            if type(exc).__name__ == "ZstdError":
                raise InputError(f"package entry is damaged ({exc})", source) from exc
            raise
        if len(data) != usize or zlib.crc32(data) != crc:
            raise InputError("package entry is damaged (its size or CRC does not match its header)", source)
        return data


def _zip64(extra: bytes, *fields: int) -> list[int]:
    """``fields`` (sizes, then the local header offset) with those saturated at 0xFFFFFFFF taken, in order,
    from the ZIP64 extra field (tag 1) of ``extra``."""
    out = list(fields)
    pos = 0
    while pos + 4 <= len(extra):
        tag, n = struct.unpack_from("<HH", extra, pos)
        if tag == 1:
            vals = list(struct.unpack_from(f"<{min(n, len(extra) - pos - 4) // 8}Q", extra, pos + 4))
            for k, v in enumerate(out):
                if v == 0xFFFFFFFF and vals:
                    out[k] = vals.pop(0)
            break
        pos += 4 + n
    return out


def _read_index(fd: int, file_size: int) -> np.ndarray | None:
    """The index of a 3TZ (sorted as the format requires), or None when its last entry is not the index."""
    tail_n = min(file_size, 65_557)  # the EOCD record and a comment of at most 65 535 bytes
    tail = os.pread(fd, tail_n, file_size - tail_n)
    at = tail.rfind(_EOCD)
    if at < 0:
        return None
    (_, _, _, _, count, cd_size, cd_offset, _) = struct.unpack_from("<4sHHHHIIH", tail, at)
    eocd_pos = file_size - tail_n + at
    if 0xFFFFFFFF in (cd_size, cd_offset) or count == 0xFFFF:  # ZIP64: its locator sits before the EOCD
        loc = os.pread(fd, 20, eocd_pos - 20)
        if loc[:4] != _EOCD64_LOCATOR:
            return None
        (eocd64_pos,) = struct.unpack_from("<Q", loc, 8)
        rec = os.pread(fd, 56, eocd64_pos)
        if rec[:4] != _EOCD64:
            return None
        count, cd_size, cd_offset = struct.unpack_from("<QQQ", rec, 32)
    if count == 0 or cd_offset + cd_size > file_size:
        return None
    # The last central-directory entry is the index: its fixed 46 bytes and name end the directory (the
    # format forbids a comment on it; a ZIP64 extra field may follow the name).
    look = min(cd_size, 46 + len(INDEX_NAME) + 64)
    block = os.pread(fd, look, cd_offset + cd_size - look)
    at = block.rfind(_CENTRAL)
    while at >= 0:
        fields = struct.unpack_from("<4sHHHHHHIIIHHHHHII", block, at)
        method, csize, usize, nlen, xlen, clen, local = fields[4], fields[8], fields[9], fields[10], fields[11], \
            fields[12], fields[16]
        name = block[at + 46: at + 46 + nlen]
        if name == INDEX_NAME.encode() and at + 46 + nlen + xlen + clen == len(block):
            if 0xFFFFFFFF in (csize, usize, local):
                extra = block[at + 46 + nlen: at + 46 + nlen + xlen]
                usize, csize, local = _zip64(extra, usize, csize, local)
            if method != 0 or usize % 24 or usize != csize:
                raise InputError("the 3TZ index is not stored uncompressed in 24-byte entries", "")
            head = os.pread(fd, 30, local)
            if head[:4] != _LOCAL:
                return None
            nl, xl = struct.unpack_from("<HH", head, 26)
            raw = os.pread(fd, usize, local + 30 + nl + xl)
            if len(raw) != usize:
                return None
            index = np.frombuffer(raw, _INDEX_DTYPE).copy()
            hi, lo = index["hi"], index["lo"]
            if not np.all((hi[:-1] < hi[1:]) | ((hi[:-1] == hi[1:]) & (lo[:-1] <= lo[1:]))):
                return None  # not sorted as the format requires: let the central directory answer
            return index
        at = block.rfind(_CENTRAL, 0, at)
    return None


#: Wraps the list of files a writer packs, to show progress (``lambda files: tqdm(files)``); None: nothing.
Progress = Callable[[list[Path]], Iterable[Path]] | None


def _tileset_files(folder: Path) -> tuple[list[Path], list[str]]:
    """Every file under ``folder`` and its name in a package, sorted; InputError without a tileset.json."""
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    names = [p.relative_to(folder).as_posix() for p in files]
    if "tileset.json" not in names:
        raise InputError("no tileset.json at the top of the folder", folder)
    return files, names


def write_package(folder: Path, out: Path, *, compress: bool = False, progress: Progress = None) -> int:
    """Pack the tileset folder ``folder`` into ``out``, a ``.3tz`` (:func:`write_3tz`) or ``.3dtiles``
    (:func:`write_3dtiles`) by its suffix; returns the number of files."""
    if out.suffix.lower() == ".3dtiles":
        return write_3dtiles(folder, out, progress=progress)
    return write_3tz(folder, out, compress=compress, progress=progress)


def write_3tz(folder: Path, out: Path, *, compress: bool = False, progress: Progress = None) -> int:
    """Pack every file under ``folder`` into the 3TZ ``out``, atomically; returns the number of files.
    ``compress`` deflates the entries (smaller, slower to read); by default they are stored, as the format
    recommends for read speed."""
    files, names = _tileset_files(folder)
    bad = [n for n in names if ".3tz" in n or n == INDEX_NAME]
    if bad:
        raise InputError(f"{bad[0]!r}: a 3TZ may not hold names containing '.3tz' or its index's name", folder)
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED

    def write(tmp: Path) -> None:
        with zipfile.ZipFile(tmp, "w", compression=method, allowZip64=True) as z:
            entries = []
            for p, name in zip(files if progress is None else progress(files), names, strict=True):
                info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))  # reproducible bytes
                info.compress_type = method
                z.writestr(info, p.read_bytes())
                entries.append((*_hash(name), z.getinfo(name).header_offset))
            info = zipfile.ZipInfo(INDEX_NAME, date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_STORED
            z.writestr(info, np.array(sorted(entries), _INDEX_DTYPE).tobytes())

    atomic_write(out, write)
    return len(files)


def write_3dtiles(folder: Path, out: Path, *, progress: Progress = None) -> int:
    """Pack every file under ``folder`` into the 3DTILES package ``out`` (SQLite, one table
    ``media(key TEXT PRIMARY KEY, content BLOB)``, as 3d-tiles-tools writes it), atomically."""
    import sqlite3

    files, names = _tileset_files(folder)

    def write(tmp: Path) -> None:
        db = sqlite3.connect(tmp)
        try:
            db.execute("CREATE TABLE media (key TEXT PRIMARY KEY, content BLOB)")
            for p, name in zip(files if progress is None else progress(files), names, strict=True):
                db.execute("INSERT INTO media VALUES (?, ?)", (name, p.read_bytes()))
            db.commit()
        finally:
            db.close()

    atomic_write(out, write)
    return len(files)
