"""Cesium ion assets (``ion:ID``): two local web servers stand for ion's API and its asset server, on different
ports as ion's are on different hosts. The API answers the asset endpoint as ion does (the tileset's URL, a
short-lived token, attributions); the asset server serves tests/data/3dtiles only with the newest token, and lets
each token expire after a few requests, so a walk over a tileset must renew it. What citylod reads equals what
it reads from the folder."""

from __future__ import annotations

import http.server
import json
import threading
import urllib.parse
from collections.abc import Iterator
from typing import ClassVar

import numpy as np
import pytest

from citylod.core.errors import InputError
from citylod.io.tiles3d import open_tileset
from citylod.io.tiles3d.remote import is_ion, is_url
from tests.cli_harness import assert_clean_refusal, run_cli
from tests.paths import ROOT

DATA = ROOT / "tests" / "data" / "3dtiles"
ASSET = "implicit/QuadtreeSubtrees"  # a tileset of many files: subtrees and contents
USER_TOKEN = "user-token"
REQUESTS_PER_TOKEN = 4


class _State:
    """What the two servers share: the newest asset token, its uses, and what was asked."""

    lock = threading.Lock()
    token = ""
    issued = 0
    uses = 0
    log: ClassVar[list[str]] = []
    asset_url = ""
    external_url = ""


class _Assets(http.server.SimpleHTTPRequestHandler):
    def __init__(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        super().__init__(*args, directory=str(DATA), **kwargs)

    def log_message(self, *args) -> None:  # type: ignore[no-untyped-def]
        pass

    def do_GET(self) -> None:
        path = urllib.parse.urlsplit(self.path)
        if path.path.startswith("/google/"):  # an external asset: a key in the query, no bearer token
            ok = urllib.parse.parse_qs(path.query).get("key") == ["google-key"]
            _State.log.append(f"google {ok}")
            if not ok:
                self.send_error(403)
                return
            self.path = path.path.removeprefix("/google") + ("?" + path.query if path.query else "")
            super().do_GET()
            return
        with _State.lock:
            ok = self.headers.get("Authorization") == f"Bearer {_State.token}" and _State.uses < REQUESTS_PER_TOKEN
            _State.uses += ok
            _State.log.append(f"asset {ok}")
        if not ok:
            self.send_error(401)
            return
        super().do_GET()


class _Api(http.server.BaseHTTPRequestHandler):
    def log_message(self, *args) -> None:  # type: ignore[no-untyped-def]
        pass

    def do_GET(self) -> None:
        path = urllib.parse.urlsplit(self.path)
        if urllib.parse.parse_qs(path.query).get("access_token") != [USER_TOKEN]:
            self.send_error(401)
            return
        asset = path.path.removeprefix("/v1/assets/").removesuffix("/endpoint")
        with _State.lock:
            _State.issued += 1
            _State.token, _State.uses = f"asset-token-{_State.issued}", 0
            _State.log.append("endpoint")
        if asset == "7":
            doc = {"type": "3DTILES", "url": _State.asset_url, "accessToken": _State.token,
                   "attributions": [{"html": "<span>Data &copy; <a href='x'>Example City</a></span>",
                                     "collapsible": False}]}
        elif asset == "8":
            doc = {"type": "3DTILES", "externalType": "3DTILES", "options": {"url": _State.external_url},
                   "attributions": []}
        elif asset == "9":
            doc = {"type": "TERRAIN", "url": _State.asset_url, "accessToken": _State.token}
        else:
            self.send_error(404)
            return
        body = json.dumps(doc).encode()
        self.send_response(200)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)


def _serve(handler: type) -> tuple[http.server.ThreadingHTTPServer, str]:
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    return httpd, f"http://127.0.0.1:{httpd.server_address[1]}"


@pytest.fixture()
def ion(monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    api, api_url = _serve(_Api)
    assets, assets_url = _serve(_Assets)
    _State.asset_url = f"{assets_url}/{ASSET}/tileset.json"
    _State.external_url = f"{assets_url}/google/{ASSET}/tileset.json?key=google-key"
    _State.log.clear()
    _State.issued = 0
    monkeypatch.setenv("CESIUM_ION_API", api_url + "/")
    monkeypatch.setenv("CESIUM_ION_TOKEN", USER_TOKEN)
    yield api_url
    api.shutdown()
    assets.shutdown()


def _geometry(ts) -> list[tuple[str, np.ndarray]]:  # type: ignore[no-untyped-def]
    return [(t.key, t.load().vertices) for t in ts.walk()]


def test_ion_asset_reads_as_its_folder_renewing_the_token(ion: str) -> None:
    ts = open_tileset("ion:7")
    got, want = _geometry(ts), _geometry(open_tileset(DATA / ASSET))
    assert [k for k, _ in got] == [k for k, _ in want] and len(got) > 2 * REQUESTS_PER_TOKEN
    assert all(np.array_equal(a, b) for (_, a), (_, b) in zip(got, want, strict=True))
    assert ts.source == "ion:7" and is_url(ts.source)
    assert ts.attributions == ["Data © Example City"]
    # Every expired token was answered by one 401, one new endpoint call and the same request again.
    assert _State.log.count("endpoint") >= 3 and _State.log.count("asset False") == _State.log.count("endpoint") - 1


def test_external_asset_opens_at_its_own_url(ion: str) -> None:
    """Google's Photorealistic 3D Tiles through ion: the endpoint names another URL with its key, no token."""
    ts = open_tileset("ion://8")
    assert len(_geometry(ts)) > 2 and set(_State.log) == {"endpoint", "google True"}


def test_ion_refusals_are_one_line(ion: str, monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(InputError, match="not a 3D Tiles tileset"):
        open_tileset("ion:9")
    with pytest.raises(InputError, match="HTTP 404"):
        open_tileset("ion:12")
    monkeypatch.setenv("CESIUM_ION_TOKEN", "wrong")
    with pytest.raises(InputError, match="refused the access token"):
        open_tileset("ion:7")
    monkeypatch.delenv("CESIUM_ION_TOKEN")
    r = run_cli(["info", "ion:7"])
    assert_clean_refusal(r, "ion:7")
    assert "CESIUM_ION_TOKEN" in r.stderr


def test_ion_source_forms() -> None:
    assert is_ion("ion:7") and is_ion("ion://7") and is_ion("ion:/7") and is_url("ion:7")
    assert not is_ion("ion:x") and not is_ion("ion:") and not is_ion("lion:7")


def test_info_shows_the_credit(ion: str) -> None:
    r = run_cli(["info", "ion:7"])  # the API and the token from the environment, as a user sets them
    assert r.returncode == 0, r.stderr
    assert "ion:7: 3D Tiles" in r.stdout and "credit   Data © Example City" in r.stdout


def test_rendered_images_carry_the_credit(ion: str) -> None:
    """``citylod render`` of an ion asset writes its attribution into the image's bottom left corner; the same
    tileset from its folder has none there."""
    from citylod.core.camera import overview_camera
    from citylod.render.offscreen import render_images

    local = DATA / "meshopt" / "dsm_tileset"
    _State.asset_url = _State.asset_url.replace(ASSET, "meshopt/dsm_tileset")
    lo, hi = open_tileset(local).bounds
    cam = overview_camera(lo, hi, aspect=320 / 200)
    (with_credit, _), = render_images(["ion:7"], [cam], size=(320, 200))
    (without, _), = render_images([local], [cam], size=(320, 200))
    corner = (slice(200 - 22, 200), slice(0, 140))  # rows from the top: the bottom left
    differs = np.abs(with_credit.astype(int) - without.astype(int)).sum(axis=2) > 60
    assert differs[corner].sum() > 50 and differs.sum() == differs[corner].sum()
