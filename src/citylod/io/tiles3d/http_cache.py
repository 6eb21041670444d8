"""A disk cache of the files remote tilesets are read from, so a tileset opened again comes from disk.

Responses are kept in one SQLite file (``$XDG_CACHE_HOME/citylod/http-cache.sqlite``; ``CITYLOD_HTTP_CACHE``
names another file, or ``off``), up to ``CITYLOD_HTTP_CACHE_MB`` (2048 by default), least recently used out
first. HTTP's rules decide what is reused (RFC 9111, the parts a tile client needs): a response whose
``Cache-Control`` says ``no-store`` is not kept; one with ``max-age`` is reused without asking until it is that
old; one with an ``ETag`` or ``Last-Modified`` and no ``max-age`` is asked for again with ``If-None-Match`` /
``If-Modified-Since``, and a 304 answer serves the kept body; anything else is not kept. Entries are keyed by the
URL with its keys and tokens redacted (:func:`citylod.io.tiles3d.remote.redact`), so no secret is written to disk.
A cache file that cannot be opened (corrupt, read-only) turns the cache off for the process, with one warning:
tiles are then read from the server as without it.
"""

from __future__ import annotations

import os
import re
import sqlite3
import threading
import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

__all__ = ["CachedResponse", "HttpCache", "default_cache"]

_MAX_AGE = re.compile(r"(?:^|,)\s*max-age\s*=\s*(\d+)", re.IGNORECASE)


@dataclass(frozen=True)
class CachedResponse:
    body: bytes
    etag: str | None
    modified: str | None
    expires: float

    @property
    def fresh(self) -> bool:
        """Reusable without asking the server."""
        return time.time() < self.expires

    def validators(self) -> dict[str, str]:
        """The conditional request headers that ask the server whether the kept body is still current."""
        out = {}
        if self.etag:
            out["If-None-Match"] = self.etag
        if self.modified:
            out["If-Modified-Since"] = self.modified
        return out


def _expiry(headers: Mapping[str, str]) -> float | None:
    """When a response stops being fresh (now: ask again before reuse), or None when it must not be kept
    (``headers`` with names in lower case)."""
    control = headers.get("cache-control", "") or ""
    if "no-store" in control.lower():
        return None
    match = _MAX_AGE.search(control)
    if match and "no-cache" not in control.lower():
        return time.time() + int(match.group(1))
    if headers.get("etag") or headers.get("last-modified"):
        return time.time()
    return None


class HttpCache:
    """The cache file; safe to use from the tile loader's threads (one connection behind a lock)."""

    def __init__(self, path: str | os.PathLike[str], max_bytes: int) -> None:
        self.path = Path(path)
        self.max_bytes = int(max_bytes)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self._db = sqlite3.connect(str(self.path), check_same_thread=False, isolation_level=None, timeout=10.0)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("CREATE TABLE IF NOT EXISTS entry (key TEXT PRIMARY KEY, body BLOB NOT NULL, etag TEXT, "
                         "modified TEXT, expires REAL NOT NULL, used REAL NOT NULL, size INTEGER NOT NULL)")
        self._db.execute("CREATE INDEX IF NOT EXISTS entry_used ON entry (used)")
        # Bytes held, kept up to date by put (a SUM over the table per stored tile would scan it each time);
        # counted again from the file before trimming, since other processes share it.
        self._total = self._sum()

    def _sum(self) -> int:
        return int(self._db.execute("SELECT COALESCE(SUM(size), 0) FROM entry").fetchone()[0])

    def get(self, key: str) -> CachedResponse | None:
        with self._lock:
            row = self._db.execute("SELECT body, etag, modified, expires FROM entry WHERE key = ?", (key,)).fetchone()
            if row is None:
                return None
            self._db.execute("UPDATE entry SET used = ? WHERE key = ?", (time.time(), key))
        return CachedResponse(bytes(row[0]), row[1], row[2], float(row[3]))

    def put(self, key: str, body: bytes, headers: Mapping[str, str]) -> None:
        """Keep ``body`` if its headers allow it (module docstring), then trim the file to its size."""
        expires = _expiry(headers)
        if expires is None or len(body) > self.max_bytes:
            return
        with self._lock:
            was = self._db.execute("SELECT size FROM entry WHERE key = ?", (key,)).fetchone()
            self._db.execute("INSERT OR REPLACE INTO entry VALUES (?, ?, ?, ?, ?, ?, ?)",
                             (key, body, headers.get("etag"), headers.get("last-modified"), expires, time.time(),
                              len(body)))
            self._total += len(body) - (was[0] if was else 0)
            if self._total > self.max_bytes:  # least recently used out, down to 90 % of the cap
                self._total = self._sum()
                drop = self._total - int(0.9 * self.max_bytes)
                for old, size in self._db.execute("SELECT key, size FROM entry ORDER BY used").fetchall():
                    if drop <= 0:
                        break
                    self._db.execute("DELETE FROM entry WHERE key = ?", (old,))
                    drop -= size
                    self._total -= size

    def refresh(self, key: str, headers: Mapping[str, str]) -> None:
        """After a 304: the kept body is current; its freshness follows the new headers."""
        expires = _expiry(headers)
        with self._lock:
            self._db.execute("UPDATE entry SET expires = ?, used = ? WHERE key = ?",
                             (expires if expires is not None else time.time(), time.time(), key))

    def total_bytes(self) -> int:
        with self._lock:
            return self._sum()


_default: HttpCache | None = None
_default_for: tuple[str, str] | None = None
_default_lock = threading.Lock()


def default_cache() -> HttpCache | None:
    """The process's cache as the environment configures it (module docstring); None when it is off."""
    global _default, _default_for
    setting = os.environ.get("CITYLOD_HTTP_CACHE", "")
    size = os.environ.get("CITYLOD_HTTP_CACHE_MB", "2048")
    if setting.strip().lower() in ("off", "0", "no", "false"):
        return None
    with _default_lock:
        if _default_for == (setting, size):
            return _default
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "citylod" / "http-cache.sqlite"
        path = Path(setting) if setting.strip() else base
        _default_for = (setting, size)
        try:
            _default = HttpCache(path, int(float(size) * (1 << 20)))
        except (sqlite3.Error, OSError, ValueError) as exc:
            warnings.warn(f"{path}: the HTTP cache cannot be used ({exc}); tiles are read from the server",
                          stacklevel=2)
            _default = None
        return _default
