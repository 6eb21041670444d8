"""Buchholz's texture budget in the renderer: a flight over a textured city never holds more GL texture
memory than the budget, counted from the GL texture objects of the tile actors, not from the plan.

The same flight without the budget holds more than the budget (so the cap is what keeps it under), and
with it the view falls back to coarser atlases where the budget is too small, never to holes: every frame
draws tiles, and the drawn atlases are those of the selected tiles or their ancestors.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from citylod.bench.flight import default_flight
from citylod.io.tiles3d import open_tileset
from citylod.lod.build.city import build_city_tiles
from citylod.render.offscreen import OffscreenRenderer
from citylod.render.texture_residency import gl_texture_bytes, texture_nbytes
from citylod.sample.textured import make_textured_city

pytestmark = pytest.mark.render

ATLAS_PX = 128
ATLAS_BYTES = texture_nbytes(ATLAS_PX, ATLAS_PX, 3)
SIZE = (480, 270)


@pytest.fixture(scope="module")
def tiles(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("texture_residency")
    city = make_textured_city(d, buildings=48, image_px=64, seed=11)
    build_city_tiles(city.path, d / "tiles", atlas_px=ATLAS_PX, progress=False)
    return d / "tiles"


def _fly(tiles: Path, budget: int | None) -> list[dict[str, float]]:
    lo, hi = open_tileset(tiles).bounds
    out = []
    with OffscreenRenderer([tiles], size=SIZE, tau_px=1.0, cache_bytes=1 << 30, texture_budget_bytes=budget) as r:
        for cam in default_flight(lo, hi, n=15):
            stats = r.prepare(cam)
            r.draw()
            res = r.scene.textures
            out.append({"gl": gl_texture_bytes(r.scene), "tiles": stats.tiles, "sse": stats.max_sse_px,
                        "refused": len(res.refused) if res is not None else 0})
    return out


def test_a_flight_never_holds_more_texture_memory_than_the_budget(tiles: Path) -> None:
    assert len(open_tileset(tiles).root.children) == 4
    budget = 6 * ATLAS_BYTES
    free = _fly(tiles, None)
    assert max(f["gl"] for f in free) > budget  # without the cap the flight needs more than the budget
    capped = _fly(tiles, budget)
    for f, g in zip(capped, free, strict=True):
        assert 0 < f["gl"] <= budget
        assert f["tiles"] >= min(g["tiles"], 1)  # a coarser atlas, never nothing where there is something
    assert any(f["refused"] for f in capped)  # the cap did refuse loads
    # Where nothing was refused the frame is as fine as the unbudgeted one.
    for f, g in zip(capped, free, strict=True):
        if not f["refused"]:
            assert f["sse"] <= max(g["sse"], 1.0) + 1e-9


def test_render_command_takes_a_texture_budget(tiles: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import json

    from citylod.cli import main

    lo, hi = open_tileset(tiles).bounds
    cam = default_flight(lo, hi, n=15)[10]  # an orbit view: more atlases than the budget below holds
    (tmp_path / "cam.json").write_text(json.dumps(cam.to_dict()))
    args = [str(tiles), "--camera", str(tmp_path / "cam.json"), "--size", "480x270"]
    assert main(["render", *args, "-o", str(tmp_path / "free.png")]) == 0
    assert main(["render", *args, "-o", str(tmp_path / "capped.png"),
                 "--texture-budget", str(3 * ATLAS_BYTES / 2**20)]) == 0
    assert (tmp_path / "free.png").read_bytes() != (tmp_path / "capped.png").read_bytes()  # coarser atlases
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        main(["render", *args, "-o", str(tmp_path / "bad.png"), "--texture-budget", "-5"])
    assert exc.value.code == 2 and "more than 0 MB" in capsys.readouterr().err
    assert not (tmp_path / "bad.png").exists()


def test_interactive_frames_stay_under_the_budget_while_tiles_stream_in(tiles: Path) -> None:
    """Scene.update never waits for loads: tiles arrive between frames, some while the next plan is made.
    After every frame the GL textures stay within the budget."""
    lo, hi = open_tileset(tiles).bounds
    budget = 6 * ATLAS_BYTES
    frames = 0
    with OffscreenRenderer([tiles], size=SIZE, tau_px=1.0, cache_bytes=1 << 30, texture_budget_bytes=budget) as r:
        for cam in default_flight(lo, hi, n=15):
            view = r.scene.view(cam, SIZE)
            r.scene.set_camera(cam)
            for step in range(6):
                r.scene.update(view)
                r.draw()
                frames += 1
                assert gl_texture_bytes(r.scene) <= budget
                if step % 2:  # every other frame, let the loads finish; else plan while they are under way
                    assert r.scene.loader.wait_idle(60)
        assert r.scene.uploads > 4  # tiles did stream in and get drawn
    assert frames == 90
