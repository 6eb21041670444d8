"""Tilesets over HTTP: a local web server (Python's http.server) serves tests/data/3dtiles, and what citylod reads
from the URL equals what it reads from the folder; servers that fail, stall, redirect away or send too much are
one line naming the URL."""

from __future__ import annotations

import http.server
import json
import threading
import time
import urllib.parse
from collections.abc import Iterator
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest

from citylod.core.errors import InputError, UnsafePathError
from citylod.io.tiles3d import open_tileset
from citylod.io.tiles3d import remote as remote_mod
from tests.cli_harness import run_cli
from tests.paths import ROOT

DATA = ROOT / "tests" / "data" / "3dtiles"
TILESETS = sorted(p.parent.relative_to(DATA).as_posix() for p in DATA.rglob("tileset.json"))


class _Handler(http.server.SimpleHTTPRequestHandler):
    log: ClassVar[list[str]] = []
    seen: ClassVar[dict[str, int]] = {}
    lock = threading.Lock()

    def __init__(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        super().__init__(*args, directory=str(DATA), **kwargs)

    def log_message(self, *args) -> None:  # type: ignore[no-untyped-def]
        pass

    def do_GET(self) -> None:
        _Handler.log.append(self.path)
        path = urllib.parse.urlsplit(self.path).path
        if path.startswith("/redirect/"):
            self.send_response(302)
            self.send_header("Location", "http://example.invalid/elsewhere/tileset.json")
            self.end_headers()
        elif path.startswith("/stall/"):
            time.sleep(3)
            self.send_error(500)
        elif path.startswith("/crafted/"):
            host = f"http://{self.headers['Host']}"
            uri = {"relative": "../Batched/BatchedColors/batchedColors.b3dm?v=2",
                   "rooted": "/Batched/BatchedColors/batchedColors.b3dm?v=2",
                   "absolute": f"{host}/Batched/BatchedColors/batchedColors.b3dm?v=2",
                   "elsewhere": "http://example.invalid/x.b3dm",
                   "above": "../../../x.b3dm"}[path.rsplit("/", 1)[1].removesuffix(".json")]
            body = json.dumps({"asset": {"version": "1.1"}, "geometricError": 1, "root": {
                "boundingVolume": {"box": [0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1]}, "geometricError": 0,
                "content": {"uri": uri}}}).encode()
            self.send_response(200)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)
        elif path.startswith("/v1/3dtiles/"):
            # Google's Photorealistic 3D Tiles, as their layout goes: root.json?key=K names a root-relative JSON
            # with a session in its query; that JSON names its glb relative to itself, with the session. Every
            # request must carry the key, and every one after the root the session.
            query = urllib.parse.parse_qs(urllib.parse.urlsplit(self.path).query)
            name = path.rsplit("/", 1)[1]
            if query.get("key") != ["K"] or (name != "root.json" and query.get("session") != ["S"]):
                self.send_error(403)
                return
            box = {"box": [0, 0, 0, 100, 0, 0, 0, 100, 0, 0, 0, 100]}
            if name == "root.json":
                doc = {"asset": {"version": "1.0"}, "geometricError": 100, "root": {
                    "boundingVolume": box, "geometricError": 100, "refine": "REPLACE",
                    "children": [{"boundingVolume": box, "geometricError": 50,
                                  "content": {"uri": "/v1/3dtiles/datasets/CgA/files/UlRP.json?session=S"}}]}}
            elif name == "UlRP.json":
                doc = {"asset": {"version": "1.0"}, "geometricError": 50, "root": {
                    "boundingVolume": box, "geometricError": 0, "content": {"uri": "Qk9Y.glb?session=S"}}}
            else:
                self.path = "/meshopt/dsm.glb"
                super().do_GET()
                return
            body = json.dumps(doc).encode()
            self.send_response(200)
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)
        elif path.startswith(("/busy/", "/overloaded/")):
            # "/busy/N/rest": 429 (Retry-After 1) for the first N requests of each path, then the file at rest;
            # "/overloaded/rest": 503 always.
            with _Handler.lock:
                _Handler.seen[path] = _Handler.seen.get(path, 0) + 1
                count = _Handler.seen[path]
            parts = path.split("/")
            if parts[1] == "overloaded" or count <= int(parts[2]):
                self.send_response(503 if parts[1] == "overloaded" else 429)
                if parts[1] == "busy":
                    self.send_header("Retry-After", "1")
                self.send_header("Content-Length", "0")
                self.end_headers()
                return
            self.path = "/" + "/".join(parts[3:])
            super().do_GET()
        elif path.startswith("/huge/"):
            self.send_response(200)
            self.send_header("Content-Length", str(remote_mod.MAX_ENTRY_BYTES + 1))
            self.end_headers()
        else:
            super().do_GET()


@pytest.fixture(scope="module")
def server() -> Iterator[str]:
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Handler)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}"
    httpd.shutdown()


def _geometry(ts) -> list[tuple[str, np.ndarray]]:  # type: ignore[no-untyped-def]
    out = []
    for t in ts.walk():
        m = t.load()
        out.append((t.key, np.concatenate([m.vertices.ravel(), m.points.ravel() if m.points is not None else []])))
    return out


@pytest.mark.parametrize("name", TILESETS)
def test_tileset_over_http_reads_as_from_the_folder(server: str, name: str) -> None:
    url = open_tileset(f"{server}/{urllib.parse.quote(name)}/tileset.json")
    local = open_tileset(DATA / name)
    got, want = _geometry(url), _geometry(local)
    assert [k for k, _ in got] == [k for k, _ in want]
    assert all(np.array_equal(a, b) for (_, a), (_, b) in zip(got, want, strict=True))
    assert url.source.startswith("http://") and str(url.crs) == str(local.crs)


def test_the_query_string_goes_with_every_request(server: str) -> None:
    _Handler.log.clear()
    ts = open_tileset(f"{server}/implicit/QuadtreeSubtrees/tileset.json?token=abc")
    _geometry(ts)
    assert len(_Handler.log) > 5  # the tileset, subtrees and contents
    assert all(p.endswith("?token=abc") for p in _Handler.log)


def test_a_path_folded_by_pathlib_still_opens(server: str) -> None:
    """``Path("http://h/x")`` is ``http:/h/x``: sources that went through Path (the app, argparse) still open."""
    ts = open_tileset(Path(f"{server}/Batched/BatchedColors/tileset.json"))
    assert ts.source == f"{server}/Batched/BatchedColors/tileset.json"
    # and a URL with ".." in its path names the folder the server reads it as
    ts = open_tileset(f"{server}/packages/../meshopt/dsm_tileset/tileset.json")
    assert len(ts.root.load().faces) > 500


def test_servers_that_fail_are_one_line(server: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(InputError, match="HTTP 404"):
        open_tileset(f"{server}/nowhere/tileset.json")
    with pytest.raises(InputError, match="HTTP 404") as info:  # a key in the URL is not printed
        open_tileset(f"{server}/nowhere/tileset.json?v=2&key=s3cret&access_token=t0k")
    assert "s3cret" not in str(info.value) and "t0k" not in str(info.value) and "v=2&key=…" in str(info.value)
    with pytest.raises(InputError, match="another server"):
        open_tileset(f"{server}/redirect/tileset.json")
    with pytest.raises(InputError, match="refused"):
        open_tileset(f"{server}/huge/tileset.json")
    monkeypatch.setattr(remote_mod, "TIMEOUT_S", 0.5)
    t0 = time.perf_counter()
    with pytest.raises(InputError, match="no answer within 0.5 s"):
        open_tileset(f"{server}/stall/tileset.json")
    assert time.perf_counter() - t0 < 2.5
    with pytest.raises(InputError, match="cannot reach the server"):
        open_tileset("http://127.0.0.1:9/tileset.json")  # the discard port: nothing listens

    r = run_cli(["render", f"{server}/nowhere/tileset.json", "-o", tmp_path / "x.png", "--size", "64x48"])
    assert r.returncode == 2 and "HTTP 404" in r.stderr and f"{server}/nowhere/tileset.json" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and not (tmp_path / "x.png").exists()


def test_content_uris_resolve_as_a_browser_does_on_the_same_server_only(server: str) -> None:
    """Relative URIs may climb to sibling folders, root-relative and absolute URLs on the tileset's server are
    read (OGC API servers write absolute ones), a URI's own query is kept with the tileset URL's; another server
    is refused."""
    _Handler.log.clear()
    for kind in ("relative", "rooted", "absolute"):
        ts = open_tileset(f"{server}/crafted/{kind}.json?token=abc")
        m = ts.root.load()
        assert len(m.vertices) > 100
    fetched = [p for p in _Handler.log if "batchedColors" in p]
    assert fetched == ["/Batched/BatchedColors/batchedColors.b3dm?v=2&token=abc"] * 3
    with pytest.raises(UnsafePathError, match="another server"):
        open_tileset(f"{server}/crafted/elsewhere.json")
    # climbing above the root stops there, as a browser resolves it: a file the server does not have
    with pytest.raises(InputError, match="HTTP 404"):
        open_tileset(f"{server}/crafted/above.json").root.load()


def test_render_over_http_draws_what_the_folder_draws(server: str) -> None:
    import citylod
    from citylod.render.offscreen import render_images

    local = DATA / "meshopt" / "dsm_tileset"
    cam = citylod.orbit_cameras(*open_tileset(local).bounds, n=1, aspect=200 / 150)[0]
    (a, _), = render_images([f"{server}/meshopt/dsm_tileset/tileset.json"], [cam], size=(200, 150))
    (b, _), = render_images([local], [cam], size=(200, 150))
    assert (a != a[0, 0]).any(axis=-1).sum() > 2000 and np.array_equal(a, b)


def test_a_busy_server_is_asked_again(server: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """429 with Retry-After (a burst of tile requests to Google's or ion's servers) is waited out, as long as it
    says, and the tileset reads as from the folder; a server that stays overloaded is one line after four tries."""
    monkeypatch.setattr(remote_mod, "RETRY_PAUSES_S", (0.01, 0.01, 0.01))
    t0 = time.perf_counter()
    ts = open_tileset(f"{server}/busy/2/Batched/BatchedColors/tileset.json")
    assert time.perf_counter() - t0 >= 2.0  # two answers of Retry-After: 1
    got, want = _geometry(ts), _geometry(open_tileset(DATA / "Batched/BatchedColors"))
    assert all(np.array_equal(a, b) for (_, a), (_, b) in zip(got, want, strict=True))
    with pytest.raises(InputError, match="HTTP 503 Service Unavailable, 4 times"):
        open_tileset(f"{server}/overloaded/Batched/BatchedColors/tileset.json")


def test_google_photorealistic_layout_reads(server: str) -> None:
    """The key of root.json's URL goes with every request, each URI's session with its own, root-relative and
    relative URIs resolve on the same server: the glb at the end is the one served."""
    from citylod.io.tiles3d import decode_content

    _Handler.log.clear()
    ts = open_tileset(f"{server}/v1/3dtiles/root.json?key=K")
    leaves = [t for t in ts.walk() if t.content_uri and t.content_uri.endswith(".glb?session=S")]
    assert len(leaves) == 1
    got = leaves[0].load()
    want = decode_content((DATA / "meshopt" / "dsm.glb").read_bytes(), "dsm.glb")
    assert len(got.faces) == want.triangle_count > 100
    assert _Handler.log == ["/v1/3dtiles/root.json?key=K", "/v1/3dtiles/datasets/CgA/files/UlRP.json?session=S&key=K",
                            "/v1/3dtiles/datasets/CgA/files/Qk9Y.glb?session=S&key=K"]
