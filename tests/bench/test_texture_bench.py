"""The textured-city flight report: what it promises about error and texture memory, on a tiny city.

Asserts on the report's counters and measured errors, never on timings. The measured error compares the
atlas frames' depth with the original textures' frames (the model's own surfaces, drawn as they are): an
independent full-resolution reference.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from citylod.bench.texture_bench import texture_flight
from citylod.render.texture_residency import texture_nbytes

pytestmark = pytest.mark.render


def test_textured_flight_report_keeps_error_and_texture_memory(tmp_path: Path) -> None:
    budget_mb = 8 * texture_nbytes(64, 64, 3) / 2**20
    rep = texture_flight(tmp_path, 16, image_px=32, atlas_px=64, budget_mb=budget_mb, frames=6, size=(320, 180),
                         taus=(1.0, 4.0), smaller_budgets_mb=(budget_mb / 4,))
    assert json.loads((tmp_path / "texture_flight.json").read_text())["houses"] == 16
    md = (tmp_path / "texture_flight.md").read_text()
    assert "texture memory MB" in md and md.count("| atlas |") == 2
    orig = rep["original"]
    assert orig["max_textures"] == 32  # one texture per image, every frame that sees the whole city
    for tau, a in rep["atlas"].items():
        assert a["max_texture_mb"] <= budget_mb + 1e-9
        assert 0 < a["max_textures"] <= 64
        # Texture LOD keeps the full surfaces at every level: the depth matches the reference to a pixel.
        assert a["p99_err_px"] <= 1.0
        # An inner tile's atlas texel is at most τ pixels on screen (no magnification by the atlas), where
        # the budget let the view load what it asked for.
        assert a["max_inner_texel_px_within_budget"] <= float(tau) + 1e-9
    assert rep["atlas"]["1.0"]["frames_refused"] > 0  # the budget binds at τ = 1 px in this flight
    small = rep["smaller_budgets"][str(budget_mb / 4)]
    assert 0 < small["max_texture_mb"] <= budget_mb / 4 + 1e-9 and "MB budget" in md
    # Less texture memory, coarser atlases: the largest texel drawn grows, the geometry does not change.
    assert small["max_inner_texel_px"] >= rep["atlas"]["1.0"]["max_inner_texel_px"] and small["p99_err_px"] <= 1.0
