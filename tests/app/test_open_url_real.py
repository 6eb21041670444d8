"""A tileset on a web server through the real menus: File > Open tileset URL…, the URL typed into the dialog
(xdotool under Xvfb), the tiles fetched and drawn; the project saved with it reopens it from the URL."""

from __future__ import annotations

import http.server
import json
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from tests.app.test_project_real import _menu_then_type, _new_window
from tests.app.test_qt import _rgb
from tests.app.test_real_input import X, _wait_resolved, pytestmark, window, xin  # noqa: F401
from tests.paths import ROOT

__all__ = ["pytestmark"]

DATA = ROOT / "tests" / "data" / "3dtiles" / "meshopt"


@pytest.fixture()
def served() -> Iterator[str]:
    class Quiet(http.server.SimpleHTTPRequestHandler):
        def __init__(self, *a, **k):  # type: ignore[no-untyped-def]
            super().__init__(*a, directory=str(DATA), **k)

        def log_message(self, *a) -> None:  # type: ignore[no-untyped-def]
            pass

    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Quiet)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}/dsm_tileset/tileset.json"
    httpd.shutdown()


def _drawn_share(win) -> float:  # type: ignore[no-untyped-def]
    rgb = _rgb(win.grab_window())
    pos, size = win.view.origin_in(win), win.view.vtk.size()
    view = rgb[pos.y(): pos.y() + size.height(), pos.x(): pos.x() + size.width()].astype(int)
    background = np.array([0.72, 0.80, 0.90]) * 255
    return float((np.abs(view - background).sum(axis=2) > 40).mean())


def test_open_url_from_the_file_menu_and_reopen_it_from_a_project(qtbot, window, xin, served,  # noqa: F811
                                                                   tmp_path: Path) -> None:
    _menu_then_type(xin, window, ["alt+f", "u"], served)
    qtbot.waitUntil(lambda: bool(window.document.entries), timeout=15000)
    _wait_resolved(qtbot, window)  # the tiles come over HTTP on the loader's threads
    entry = window.document.entries[0]
    assert entry.kind == "tileset" and entry.name == "dsm_tileset"
    assert window.document.scene.last_stats.triangles > 500 and _drawn_share(window) > 0.05
    assert served in window.recent_files()

    target = tmp_path / "remote.citylod"
    _menu_then_type(xin, window, ["alt+f", "s"], str(target))
    qtbot.waitUntil(target.exists, timeout=10000)
    assert json.loads(target.read_text())["layers"][0]["path"] == served
    other = _new_window(qtbot, tmp_path)
    try:
        _menu_then_type(xin, other, ["alt+f", "j"], str(target))
        qtbot.waitUntil(lambda: bool(other.document.entries), timeout=15000)
        _wait_resolved(qtbot, other)
        assert other.document.scene.last_stats.triangles > 500 and _drawn_share(other) > 0.05
    finally:
        other.close()


@pytest.fixture()
def ion_asset(monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    """A Cesium ion stand-in (tests/io/test_tiles3d_ion.py) whose asset 7 is the meshopt DSM tileset."""
    from tests.io import test_tiles3d_ion as ion

    api, api_url = ion._serve(ion._Api)
    assets, assets_url = ion._serve(ion._Assets)
    ion._State.asset_url = f"{assets_url}/meshopt/dsm_tileset/tileset.json"
    ion._State.log.clear()
    monkeypatch.setenv("CESIUM_ION_API", api_url)
    monkeypatch.setenv("CESIUM_ION_TOKEN", ion.USER_TOKEN)
    yield "ion:7"
    api.shutdown()
    assets.shutdown()


def test_ion_asset_from_the_file_menu_shows_its_credit(qtbot, window, xin, ion_asset,  # noqa: F811
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """``ion:7`` typed into File > Open tileset URL…, then the token into the dialog that asks for it (none is
    set): the tiles come with renewed tokens, and the asset's attribution stands in the view's bottom left
    corner."""
    from tests.io.test_tiles3d_ion import USER_TOKEN

    monkeypatch.delenv("CESIUM_ION_TOKEN")
    _menu_then_type(xin, window, ["alt+f", "u"], ion_asset, USER_TOKEN)
    qtbot.waitUntil(lambda: bool(window.document.entries), timeout=15000)
    _wait_resolved(qtbot, window)
    assert window.document.scene.last_stats.triangles > 500 and _drawn_share(window) > 0.05
    assert window.document.entries[0].name == "ion:7"
    qtbot.waitUntil(lambda: window.view.hud.credit_text.GetVisibility(), timeout=5000)
    assert window.view.hud.credit_text.GetInput() == "Data © Example City"
    rgb = _rgb(window.grab_window())
    pos, size = window.view.origin_in(window), window.view.vtk.size()
    corner = rgb[pos.y() + size.height() - 20: pos.y() + size.height() - 8, pos.x() + 10: pos.x() + 120].astype(int)
    assert (corner.sum(axis=2) < 200).any()  # the credit's dark letters
    assert ion_asset in window.recent_files()
