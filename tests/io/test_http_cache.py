"""The disk cache of remote tilesets: a local server that counts what it is asked, answering with the headers a
tile server sends (max-age, ETag, no-store); a second open reads from disk or revalidates, and reads as the
folder; keys in URLs never reach the file; the size cap holds; a broken file only turns the cache off."""

from __future__ import annotations

import hashlib
import http.server
import threading
import urllib.parse
from collections.abc import Iterator
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

from citylod.io.tiles3d import open_tileset
from citylod.io.tiles3d.http_cache import HttpCache, default_cache
from tests.paths import ROOT

DATA = ROOT / "tests" / "data" / "3dtiles"
NAME = "implicit/QuadtreeSubtrees"


class _Counting(http.server.BaseHTTPRequestHandler):
    """Serves tests/data/3dtiles under /<policy>/…: ``maxage`` (max-age=600 and an ETag), ``etag`` (an ETag
    only), ``nostore``. Counts full answers and 304s."""

    full: ClassVar[int] = 0
    not_modified: ClassVar[int] = 0
    lock = threading.Lock()

    def log_message(self, *args) -> None:  # type: ignore[no-untyped-def]
        pass

    def do_GET(self) -> None:
        path = urllib.parse.unquote(urllib.parse.urlsplit(self.path).path)
        policy, _, rest = path.lstrip("/").partition("/")
        file = DATA / rest
        if not file.is_file():
            self.send_error(404)
            return
        body = file.read_bytes()
        tag = '"' + hashlib.sha1(body).hexdigest() + '"'
        if policy != "nostore" and self.headers.get("If-None-Match") == tag:
            with _Counting.lock:
                _Counting.not_modified += 1
            self.send_response(304)
            self.send_header("ETag", tag)
            self.end_headers()
            return
        with _Counting.lock:
            _Counting.full += 1
        self.send_response(200)
        self.send_header("Content-Length", str(len(body)))
        if policy == "maxage":
            self.send_header("Cache-Control", "public, max-age=600")
        if policy == "nostore":
            self.send_header("Cache-Control", "no-store")
        else:
            self.send_header("ETag", tag)
        self.end_headers()
        self.wfile.write(body)


@pytest.fixture()
def server(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    monkeypatch.setenv("CITYLOD_HTTP_CACHE", str(tmp_path / "cache.sqlite"))
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Counting)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    _Counting.full = _Counting.not_modified = 0
    yield f"http://127.0.0.1:{httpd.server_address[1]}"
    httpd.shutdown()


def _walk(url: str) -> list[np.ndarray]:
    return [t.load().vertices for t in open_tileset(url).walk()]


def _counts() -> tuple[int, int]:
    full, nm = _Counting.full, _Counting.not_modified
    _Counting.full = _Counting.not_modified = 0
    return full, nm


def test_fresh_answers_come_from_disk(server: str) -> None:
    want = [t.load().vertices for t in open_tileset(DATA / NAME).walk()]
    first = _walk(f"{server}/maxage/{NAME}/tileset.json?key=s3cret")
    full, _ = _counts()
    assert full > 5
    second = _walk(f"{server}/maxage/{NAME}/tileset.json?key=s3cret")
    assert _counts() == (0, 0)  # nothing asked: every file within its max-age
    assert all(np.array_equal(a, b) for a, b in zip(first, want, strict=True))
    assert all(np.array_equal(a, b) for a, b in zip(second, want, strict=True))
    cache = default_cache()
    assert cache is not None and b"s3cret" not in cache.path.read_bytes()


def test_validated_answers_are_revalidated(server: str) -> None:
    first = _walk(f"{server}/etag/{NAME}/tileset.json")
    full, _ = _counts()
    second = _walk(f"{server}/etag/{NAME}/tileset.json")
    assert _counts() == (0, full)  # each file asked again, each answered 304
    assert all(np.array_equal(a, b) for a, b in zip(first, second, strict=True))


def test_no_store_is_not_kept(server: str) -> None:
    _walk(f"{server}/nostore/{NAME}/tileset.json")
    full, _ = _counts()
    _walk(f"{server}/nostore/{NAME}/tileset.json")
    assert _counts() == (full, 0)
    cache = default_cache()
    assert cache is not None and cache.total_bytes() == 0


def test_the_size_cap_holds(tmp_path: Path) -> None:
    cache = HttpCache(tmp_path / "c.sqlite", max_bytes=10_000)
    for i in range(30):
        cache.put(f"http://h/{i}", bytes(1000), {"cache-control": "max-age=60"})
    assert cache.total_bytes() <= 10_000
    assert cache.get("http://h/29") is not None and cache.get("http://h/0") is None  # least recently used out


def test_a_broken_cache_file_turns_the_cache_off(server: str, tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    broken = tmp_path / "broken.sqlite"
    broken.write_bytes(b"not a database" * 100)
    monkeypatch.setenv("CITYLOD_HTTP_CACHE", str(broken))
    with pytest.warns(UserWarning, match="HTTP cache cannot be used"):
        got = _walk(f"{server}/maxage/{NAME}/tileset.json")
    full, _ = _counts()
    assert len(got) > 5 and full > 5  # read from the server, as without a cache
    monkeypatch.setenv("CITYLOD_HTTP_CACHE", "off")
    assert default_cache() is None
