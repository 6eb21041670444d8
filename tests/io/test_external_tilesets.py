"""Tilesets of many external tileset files (as photogrammetry exports write them, one file per tile): they open
without reading every file, a view reads only the files it refines into, and what is drawn is what the same
tiles in one file draw. A tile whose content is an external tileset is traversed whatever its error, as
CesiumJS does."""

from __future__ import annotations

import copy
import itertools
import json
import shutil
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import citylod
from citylod.core.errors import InputError
from citylod.io.tiles3d import open_tileset
from citylod.io.tiles3d import tileset as tileset_mod
from tests.cli_harness import run_cli


@pytest.fixture(scope="module")
def single(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The sample city's DSM as one tileset file (21 tiles on 3 levels) and its camera."""
    from citylod.lod.build.dsm import build_dsm
    from citylod.sample.files import make_sample

    out = tmp_path_factory.mktemp("ext")
    info = make_sample(out / "src", size=129)
    build_dsm(info.files["dsm"], out / "single", workers=0, progress=False, tile_size=33)
    return {"tiles": out / "single", "camera": info.files["camera"], "root": out}


def _split(src: Path, dst: Path, stub_error: float | None = None) -> int:
    """``src`` rewritten with every tile below the root in a file of its own, referenced from a stub tile in
    its parent (no transform; the box moved by the tile's translation into the parent's frame). Returns the
    number of external files."""
    dst.mkdir()
    shutil.copytree(src / "tiles", dst / "tiles")
    doc = json.loads((src / "tileset.json").read_text())
    count = 0

    def stubbed(tile: dict[str, Any], name: str) -> dict[str, Any]:
        nonlocal count
        tile = copy.deepcopy(tile)
        kids = tile.pop("children", [])
        stubs = []
        for i, child in enumerate(kids):
            cname = f"{name}_{i}"
            box = list(child["boundingVolume"]["box"])
            t = child.get("transform")
            if t is not None:  # the builder's children transforms are translations
                box[0:3] = [box[0] + t[12], box[1] + t[13], box[2] + t[14]]
            sub = {"asset": doc["asset"], "geometricError": child["geometricError"], "root": stubbed(child, cname)}
            (dst / f"{cname}.json").write_text(json.dumps(sub))
            count += 1
            err = child["geometricError"] if stub_error is None else stub_error
            stubs.append({"boundingVolume": {"box": box}, "geometricError": err, "content": {"uri": f"{cname}.json"}})
        if stubs:
            tile["children"] = stubs
        return tile

    out = dict(doc)
    out["root"] = stubbed(doc["root"], "t")
    (dst / "tileset.json").write_text(json.dumps(out))
    return count


def _known(root):  # type: ignore[no-untyped-def]
    """The tiles read so far, without reading more (``Tileset.walk`` would)."""
    out, stack = [], [root]
    while stack:
        t = stack.pop()
        out.append(t)
        stack.extend(t.children)
    return out


def _count_reads(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The names of the files the reader reads from now on, in order."""
    reads: list[str] = []
    real = tileset_mod.Tileset.read_file

    def counting(self, path, *a, **k):  # type: ignore[no-untyped-def]
        reads.append(path.name)
        return real(self, path, *a, **k)

    monkeypatch.setattr(tileset_mod.Tileset, "read_file", counting)
    return reads


def _contents(ts) -> dict[str, np.ndarray]:  # type: ignore[no-untyped-def]
    return {t.content_path.relative_to(ts.folder).as_posix(): t.load().vertices
            for t in ts.walk() if t.content_path is not None}


def test_opening_reads_the_root_only_and_a_walk_reads_the_rest(single, tmp_path, monkeypatch) -> None:
    files = _split(single["tiles"], tmp_path / "split")
    assert files == 20
    monkeypatch.setattr(tileset_mod, "EAGER_EXTERNAL_FILES", 0)
    reads = _count_reads(monkeypatch)
    ts = open_tileset(tmp_path / "split")
    stubs = ts.root.children
    assert reads == [] and len(stubs) == 4
    assert all(s.external and s.pending is not None and not s.children for s in stubs)
    got = _contents(ts)  # the walk reads every file
    assert sum(name.endswith(".json") for name in reads) == files
    want = _contents(open_tileset(single["tiles"]))
    assert got.keys() == want.keys() and all(np.array_equal(got[k], want[k]) for k in want)


def test_a_view_reads_only_what_it_refines_into_and_draws_the_same(single, tmp_path, monkeypatch) -> None:
    from citylod.render.offscreen import render_images

    files = _split(single["tiles"], tmp_path / "split")
    monkeypatch.setattr(tileset_mod, "EAGER_EXTERNAL_FILES", 0)
    expanded: list[str] = []
    real = tileset_mod.Tileset.expand

    def counting(self, tile):  # type: ignore[no-untyped-def]
        expanded.append(tile.key)
        return real(self, tile)

    monkeypatch.setattr(tileset_mod.Tileset, "expand", counting)
    lo, hi = open_tileset(single["tiles"]).bounds
    near = citylod.Camera(position=(lo[0] + 10, lo[1] + 10, hi[2] + 25), focal_point=(lo[0] + 30, lo[1] + 30, lo[2]),
                          view_up=(0, 0, 1))
    far = citylod.orbit_cameras(lo, hi, n=1, aspect=320 / 240)[0]
    for cam, tau in ((far, 1.0), (near, 1.0), (far, 8.0)):
        expanded.clear()
        (a, _), = render_images([tmp_path / "split"], [cam], size=(320, 240), tau_px=tau)
        (b, _), = render_images([single["tiles"]], [cam], size=(320, 240), tau_px=tau)
        assert np.array_equal(a, b), (cam, tau)
        assert (a != a[0, 0]).any(axis=-1).mean() > 0.05
        assert len(set(expanded)) <= files
    # close to one corner, only the files of that corner's branch are read (the root draws the far view)
    expanded.clear()
    render_images([tmp_path / "split"], [near], size=(320, 240), tau_px=1.0)
    assert 0 < len(set(expanded)) < files


def test_a_stub_with_a_small_error_is_still_traversed(single, tmp_path) -> None:
    """Stub tiles with geometricError 0 (their error says "stop here"): the external roots are drawn anyway."""
    from citylod.render.offscreen import render_images

    _split(single["tiles"], tmp_path / "split0", stub_error=0.0)
    cam = citylod.load_cameras(single["camera"])[0]
    (a, _), = render_images([tmp_path / "split0"], [cam], size=(320, 240), tau_px=1.0)
    (b, _), = render_images([single["tiles"]], [cam], size=(320, 240), tau_px=1.0)
    assert (b != b[0, 0]).any(axis=-1).mean() > 0.05 and np.array_equal(a, b)


def test_a_missing_external_file(single, tmp_path, monkeypatch) -> None:
    """Read by a walk (``info``): one line, exit 2. Reached by a view: one warning, the rest drawn."""
    from citylod.render.offscreen import render_images

    _split(single["tiles"], tmp_path / "split")
    (tmp_path / "split" / "t_3.json").unlink()
    r = run_cli(["info", tmp_path / "split"])
    assert r.returncode == 2 and "t_3.json" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    monkeypatch.setattr(tileset_mod, "EAGER_EXTERNAL_FILES", 0)
    cam = citylod.orbit_cameras(*open_tileset(single["tiles"]).bounds, n=1, aspect=320 / 240)[0]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        (a, _), = render_images([tmp_path / "split"], [cam], size=(320, 240), tau_px=1.0)
    assert any("t_3.json" in str(w.message) for w in caught)
    assert (a != a[0, 0]).any(axis=-1).mean() > 0.05  # three quarters of the city
    with pytest.raises(InputError, match="t_3.json"):
        list(open_tileset(tmp_path / "split").walk())


def test_over_http_a_view_fetches_only_its_files(single, tmp_path, monkeypatch) -> None:
    import http.server
    import threading

    from citylod.render.offscreen import render_images

    files = _split(single["tiles"], tmp_path / "split")
    got: list[str] = []

    class Handler(http.server.SimpleHTTPRequestHandler):
        def __init__(self, *a, **k):  # type: ignore[no-untyped-def]
            super().__init__(*a, directory=str(tmp_path / "split"), **k)

        def log_message(self, *a) -> None:  # type: ignore[no-untyped-def]
            pass

        def do_GET(self) -> None:
            got.append(self.path)
            super().do_GET()

    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    monkeypatch.setattr(tileset_mod, "EAGER_EXTERNAL_REMOTE", 0)
    try:
        url = f"http://127.0.0.1:{httpd.server_address[1]}/tileset.json"
        assert open_tileset(url).root.children and got == ["/tileset.json"]
        lo, hi = open_tileset(single["tiles"]).bounds
        near = citylod.Camera(position=(lo[0] + 10, lo[1] + 10, hi[2] + 25),
                              focal_point=(lo[0] + 30, lo[1] + 30, lo[2]), view_up=(0, 0, 1))
        got.clear()
        (a, _), = render_images([url], [near], size=(320, 240), tau_px=1.0)
        (b, _), = render_images([single["tiles"]], [near], size=(320, 240), tau_px=1.0)
    finally:
        httpd.shutdown()
    assert np.array_equal(a, b)
    fetched = [p for p in got if p.endswith(".json") and p != "/tileset.json"]
    assert 0 < len(fetched) < files and len(set(fetched)) == len(fetched)  # each file once


def test_implicit_subtrees_are_read_when_reached(monkeypatch) -> None:
    """An implicit quadtree (3d-tiles-tools' sample, 5 subtree files): with nothing read eagerly, opening reads
    the root subtree only, and a walk reaches every content tile the fully read tree has."""
    from tests.paths import ROOT

    folder = ROOT / "tests" / "data" / "3dtiles" / "implicit" / "QuadtreeSubtrees"
    want = _contents(open_tileset(folder))
    monkeypatch.setattr(tileset_mod, "EAGER_EXTERNAL_FILES", 0)
    reads = _count_reads(monkeypatch)
    ts = open_tileset(folder)
    assert [r for r in reads if r.endswith(".subtree")] == ["0.0.0.subtree"]
    stubs = [t for t in _known(ts.root) if t.pending is not None]
    assert stubs and all(t.external and not t.children and t.content_path is None for t in stubs)
    got = _contents(ts)
    assert sorted(r for r in reads if r.endswith(".subtree")) == sorted(
        p.name for p in (folder / "subtrees").glob("*.subtree"))
    assert got.keys() == want.keys() and all(np.array_equal(got[k], want[k]) for k in want)
    from citylod.render.offscreen import render_images

    cam = citylod.orbit_cameras(*open_tileset(folder).bounds, n=1, aspect=1.0)[0]
    (a, _), = render_images([folder], [cam], size=(200, 200), tau_px=0.5)
    monkeypatch.setattr(tileset_mod, "EAGER_EXTERNAL_FILES", 1000)
    (b, _), = render_images([folder], [cam], size=(200, 200), tau_px=0.5)
    assert (b != b[0, 0]).any(axis=-1).sum() > 500 and np.array_equal(a, b)


def test_interactive_frames_read_in_the_background_without_holes(single, tmp_path, monkeypatch) -> None:
    """With the scene's background reader (what the app turns on), a frame never reads a file: the tiles above
    a tileset being read stay drawn, so no frame shows less of the city than the one before; the frames end
    complete, with the picture the one-file tileset gives."""
    import time

    from citylod.render.offscreen import OffscreenRenderer, render_images

    _split(single["tiles"], tmp_path / "split")
    monkeypatch.setattr(tileset_mod, "EAGER_EXTERNAL_FILES", 0)
    lo, hi = open_tileset(single["tiles"]).bounds
    near = citylod.Camera(position=(lo[0] + 10, lo[1] + 10, hi[2] + 25), focal_point=(lo[0] + 30, lo[1] + 30, lo[2]),
                          view_up=(0, 0, 1))
    import threading

    on_frame_thread: list[str] = []
    real = tileset_mod.Tileset.read_file

    def watched(self, path, *a, **k):  # type: ignore[no-untyped-def]
        if threading.current_thread() is threading.main_thread():
            on_frame_thread.append(path.name)
        return real(self, path, *a, **k)

    with OffscreenRenderer([tmp_path / "split"], size=(320, 240), tau_px=1.0) as r:
        monkeypatch.setattr(tileset_mod.Tileset, "read_file", watched)  # after the tileset JSON is read
        scene = r.scene
        scene.expand_in_background()
        with r.gl:
            scene.set_camera(near)
        view = scene.view(near, r.size)
        covered, frames, background = [], 0, None
        deadline = time.monotonic() + 60
        while True:
            with r.gl:
                stats = scene.update(view)
                r.renderer.ResetCameraClippingRange()
            r.draw()
            rgb = r.grab_rgb()
            background = rgb[0, 0] if background is None else background
            if scene.layers[0].root.key in scene.cache:  # from the frame the root is in, nothing may vanish
                covered.append(int((rgb != background).any(axis=-1).sum()))
            frames += 1
            if stats.complete:
                break
            assert time.monotonic() < deadline
            time.sleep(0.02)
    (want, _), = render_images([single["tiles"]], [near], size=(320, 240), tau_px=1.0)
    assert frames > 2 and np.array_equal(rgb, want)
    assert [n for n in on_frame_thread if n.endswith(".json")] == []  # every tileset file was read off the frame
    assert covered[0] > 0 and all(b >= a * 0.98 for a, b in itertools.pairwise(covered)), covered
