"""Append-only journals of build results, so that a build can resume without a file per task.

A build records what each task finished (a tile's stage-1 TIN, a tile's result) to resume from it after an
interruption. One small file per record costs an inode each, and creating files is serialised in the
kernel: with two per tile it was a large share of a DSM build (docs/PERFORMANCE_LOG.md). A journal is one
file per writing thread and build, appended to record by record:

    record = magic "CLJ1" | key length u32 | payload length u32 | crc32(key + payload) u32 | key | payload

Each record is written with one ``write`` and flushed, so an interrupted process leaves whole records and
at most one torn record at the end of its own file; a reader stops at the first record whose length or
checksum does not hold. A resumed build appends to new files (names are unique per thread and run), never
after a torn tail. Readers get an index (key → file, offset, length) and read payloads on demand, so the
memory of a resume does not grow with the number of records. No VTK, no Qt.
"""

from __future__ import annotations

import os
import struct
import threading
import uuid
import zlib
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from citylod.core.perthread import PerThread

MAGIC = b"CLJ1"
_HEAD = struct.Struct("<4sIII")
_HANDLES = PerThread()  # folder -> open journal file, per thread; a forked child starts files of its own
_MAX_OPEN = 4  # journals a thread keeps open (a long-lived Dask worker thread serves many builds)


@dataclass(frozen=True)
class Entry:
    """Where one record's payload lies."""

    path: Path
    offset: int
    length: int

    def read(self) -> bytes:
        with open(self.path, "rb") as f:
            f.seek(self.offset)
            data = f.read(self.length)
        if len(data) != self.length:
            raise OSError(f"{self.path}: journal record cut short")
        return data


def _handles() -> OrderedDict[str, BinaryIO]:
    return _HANDLES.get()


def append(folder: str | os.PathLike[str], key: str, payload: bytes) -> None:
    """Append one record to this thread's journal file in ``folder`` (created on first use)."""
    folder = os.fspath(folder)
    handles = _handles()
    fh = handles.get(folder)
    if fh is None or fh.closed:
        os.makedirs(folder, exist_ok=True)
        name = f"{os.getpid()}-{threading.get_ident()}-{uuid.uuid4().hex[:8]}.log"
        fh = open(os.path.join(folder, name), "ab")
        handles[folder] = fh
        while len(handles) > _MAX_OPEN:
            handles.popitem(last=False)[1].close()
    kb = key.encode()
    fh.write(_HEAD.pack(MAGIC, len(kb), len(payload), zlib.crc32(kb + payload)) + kb + payload)
    fh.flush()


def close(folder: str | os.PathLike[str]) -> None:
    """Close this thread's journal file in ``folder``, if open (other threads close theirs on exit)."""
    fh = _handles().pop(os.fspath(folder), None)
    if fh is not None:
        fh.close()


def index(folder: str | os.PathLike[str]) -> dict[str, Entry]:
    """Every whole record in ``folder``'s journal files: key → where its payload lies (a later record of
    the same key, in file-name order, wins)."""
    out: dict[str, Entry] = {}
    root = Path(folder)
    if not root.is_dir():
        return out
    for p in sorted(root.glob("*.log")):
        with open(p, "rb") as f:
            at = 0
            while True:
                head = f.read(_HEAD.size)
                if len(head) < _HEAD.size:
                    break
                magic, kl, pl, crc = _HEAD.unpack(head)
                if magic != MAGIC:
                    break
                kb = f.read(kl)
                crc_now = zlib.crc32(kb)
                left = pl
                while left > 0:  # the payload in pieces: a resume reads the whole journal, holds none of it
                    piece = f.read(min(left, 1 << 20))
                    if not piece:
                        break
                    crc_now = zlib.crc32(piece, crc_now)
                    left -= len(piece)
                if len(kb) < kl or left > 0 or crc_now != crc:
                    break  # a torn tail: nothing after it in this file is trusted
                out[kb.decode()] = Entry(p, at + _HEAD.size + kl, pl)
                at += _HEAD.size + kl + pl
    return out


__all__ = ["MAGIC", "Entry", "append", "close", "index"]
