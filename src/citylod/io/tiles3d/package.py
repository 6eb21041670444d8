"""3D Tiles packages read in place: ``.3tz`` archives and ``.3dtiles`` databases.

Both hold a tileset folder in one file, as CesiumGS's 3d-tiles-tools write them (``convert -o X.3tz`` and
``-o X.3dtiles``) and Cesium ion exports them:

* **3TZ** is a ZIP archive (ZIP64 where large) whose entries are the folder's files under their relative
  paths, ``tileset.json`` at the top; its last entry ``@3dtilesIndex1@`` indexes the entries by the MD5 of
  their paths, which :mod:`.archive3tz` reads, so an archive of a million tiles opens without parsing its
  central directory. A ZIP without the index is read through :mod:`zipfile` instead.
* **3DTILES** is an SQLite database with one table ``media(key TEXT PRIMARY KEY, content BLOB)``, a row per
  file (gzip-compressed content is unpacked by the content decoder, as for files).

A package is opened read-only and read entry by entry, so a viewer loads only the tiles a view needs. An
entry whose declared size exceeds :data:`MAX_ENTRY_BYTES` is refused before anything is decompressed (a
small ZIP can declare gigabytes). Handles are reopened after a fork and are not pickled, so worker
processes each read through their own.
"""

from __future__ import annotations

import os
import sqlite3
import threading
import urllib.parse
import zipfile
import zlib
from pathlib import Path
from typing import Any

from citylod.core.errors import InputError
from citylod.io.tiles3d.archive3tz import MAX_ENTRY_BYTES, Index3tz, NeedsCentralDirectory, normalise
from citylod.io.tiles3d.remote import is_url

PACKAGE_SUFFIXES = (".3tz", ".3dtiles")

_ZIP_MAGIC = b"PK\x03\x04"
_SQLITE_MAGIC = b"SQLite format 3\x00"


def is_tileset_path(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` names a tileset by its form: a folder, a ``.json`` file, a ``.3tz`` / ``.3dtiles``
    package or an http(s) URL (existence is the reader's to check)."""
    if is_url(path):
        return True
    p = Path(path)
    return p.is_dir() or p.suffix.lower() in (".json", *PACKAGE_SUFFIXES)


def package_kind(path: Path) -> str | None:
    """``"3tz"`` or ``"3dtiles"`` when ``path`` is a package file (by suffix, else by its first bytes)."""
    if not path.is_file():
        return None
    suffix = path.suffix.lower()
    if suffix == ".3tz":
        return "3tz"
    if suffix == ".3dtiles":
        return "3dtiles"
    try:
        with open(path, "rb") as fh:
            head = fh.read(16)
    except OSError:
        return None
    if head.startswith(_ZIP_MAGIC):
        return "3tz"
    if head == _SQLITE_MAGIC:
        return "3dtiles"
    return None


class Package:
    """One package file; :meth:`read` returns an entry's bytes by its path inside the package."""

    def __init__(self, path: Path, kind: str) -> None:
        self.path = path
        self.root = path  # the tileset's files get paths below the package's own (Tileset.read_file)
        self.kind = kind
        self._lock = threading.Lock()
        self._pid = -1
        self._zip: zipfile.ZipFile | None = None
        self._entries: dict[str, zipfile.ZipInfo] = {}
        self._index: Index3tz | None = None
        self._db: sqlite3.Connection | None = None
        self._open()

    def __getstate__(self) -> dict[str, Any]:
        return {"path": self.path, "kind": self.kind}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["path"], state["kind"])  # type: ignore[misc]

    def _open(self) -> None:
        self._pid = os.getpid()
        try:
            if self.kind == "3tz":
                # Through the archive's index when it has one (the format requires it); the ZIP's central
                # directory, parsed whole by zipfile, only for archives without one or names it lacks.
                if self._index is not None:
                    self._index.close()
                self._index = Index3tz.open(self.path)
                self._zip = None
                if self._index is None:
                    self._central()
            else:
                uri = "file:" + urllib.parse.quote(str(self.path.resolve())) + "?mode=ro&immutable=1"
                self._db = sqlite3.connect(uri, uri=True, check_same_thread=False)
                columns = {str(r[1]): str(r[2]).upper() for r in self._db.execute("PRAGMA table_info(media)")}
                if columns.get("key") != "TEXT" or columns.get("content") != "BLOB":
                    found = ", ".join(f"{k} {v}" for k, v in columns.items()) or "none"
                    raise InputError("not a 3DTILES package: its table 'media' must have columns key TEXT and "
                                     f"content BLOB (found: {found})", self.path)
        except (zipfile.BadZipFile, zipfile.LargeZipFile, sqlite3.DatabaseError, OSError, ValueError) as exc:
            what = "3TZ (ZIP) archive" if self.kind == "3tz" else "3DTILES (SQLite) package"
            raise InputError(f"not a readable {what} ({str(exc)[:200]})", self.path) from exc

    def _central(self) -> zipfile.ZipFile:
        if self._zip is None:
            self._zip = zipfile.ZipFile(self.path)
            self._entries = {_norm(i.filename): i for i in self._zip.infolist() if not i.is_dir()}
        return self._zip

    def _handles(self) -> None:
        if self._pid != os.getpid():  # a forked worker: a ZIP offset or SQLite handle must not be shared
            self._open()

    def size(self, name: str) -> int:
        """The entry's size in bytes (uncompressed), 0 when absent."""
        name = _norm(name)
        with self._lock:
            self._handles()
            if self.kind == "3tz":
                try:
                    size = None if self._index is None else self._index.size(name)
                except NeedsCentralDirectory:
                    size = None
                if size is None and self._index is not None:
                    return 0
                if size is None:
                    try:
                        self._central()
                    except (zipfile.BadZipFile, OSError, ValueError):
                        return 0
                    info = self._entries.get(name)
                    size = 0 if info is None else int(info.file_size)
                return size
            assert self._db is not None
            row = self._db.execute("SELECT length(content) FROM media WHERE key = ?", (name,)).fetchone()
            return 0 if row is None or row[0] is None else int(row[0])

    def read(self, name: str) -> bytes:
        """The bytes of entry ``name``; :class:`InputError` naming it when absent, too large or damaged."""
        name = _norm(name)
        source = f"{self.path} ({name})"
        with self._lock:
            self._handles()
            try:
                if self.kind == "3tz":
                    if self._index is not None:
                        try:
                            data = self._index.read(name)
                        except NeedsCentralDirectory:
                            data = None
                        else:
                            if data is None:  # the index lists every file of the archive
                                raise InputError("no such entry in the package", source)
                            return data
                    self._central()
                    assert self._zip is not None
                    info = self._entries.get(name)
                    if info is None:
                        raise InputError("no such entry in the package", source)
                    if info.file_size > MAX_ENTRY_BYTES:
                        raise InputError(f"entry declares {info.file_size:,} bytes (more than "
                                         f"{MAX_ENTRY_BYTES:,}); refused", source)
                    return self._zip.read(info)
                assert self._db is not None
                row = self._db.execute("SELECT length(content) FROM media WHERE key = ?", (name,)).fetchone()
                if row is None:
                    raise InputError("no such entry in the package", source)
                if row[0] is not None and int(row[0]) > MAX_ENTRY_BYTES:
                    raise InputError(f"entry holds {int(row[0]):,} bytes (more than {MAX_ENTRY_BYTES:,}); refused",
                                     source)
                (content,) = self._db.execute("SELECT content FROM media WHERE key = ?", (name,)).fetchone()
            except (zipfile.BadZipFile, sqlite3.DatabaseError, OSError, EOFError, ValueError, zlib.error,
                    NotImplementedError, RuntimeError) as exc:  # CRC, truncation, unknown compression, encryption
                raise InputError(f"package entry is damaged ({str(exc)[:200]})", source) from exc
        if isinstance(content, str):
            return content.encode("utf-8")
        return bytes(content or b"")


def _norm(name: str) -> str:
    """An entry name as the 3TZ index hashes it, without a leading ``./`` (both tools and hand-made ZIPs vary)."""
    name = normalise(name)
    while name.startswith("./"):
        name = name[2:]
    return name
