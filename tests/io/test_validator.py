"""citylod's tilesets pass CesiumGS's 3d-tiles-validator: no errors, no warnings, no infos about textures.

The validator is built by ``scripts/validator.sh`` (``make test`` runs it) into ``.validator/``; where it could
not be built (no node, no npm registry) these tests skip with the reason the script recorded.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from citylod.bench.synthetic import make_terrain_tileset
from citylod.lod.build.points import build_points
from tests.lod.test_points_cloud import make_cloud
from tests.paths import ROOT

VALIDATOR = ROOT / ".validator" / "build" / "main.js"


@pytest.fixture(scope="module")
def validator() -> Path:
    if not VALIDATOR.exists():
        why = ROOT / ".validator.skipped"
        reason = why.read_text().strip() if why.exists() else "not built (run scripts/validator.sh)"
        pytest.skip(f"3d-tiles-validator unavailable: {reason}")
    if shutil.which("node") is None:
        pytest.skip("3d-tiles-validator unavailable: node is not installed")
    return VALIDATOR


def _validate(validator: Path, tileset: Path, tmp_path: Path) -> list[str]:
    """Every error and warning the validator reports for ``tileset``, and every message about its textures,
    with their causes, as lines."""
    report = tmp_path / f"{tileset.name}-report.json"
    proc = subprocess.run(["node", str(validator), "--tilesetFile", str(tileset / "tileset.json"),
                           "--reportFile", str(report)], capture_output=True, text=True, timeout=600)
    assert report.exists(), proc.stdout + proc.stderr
    doc = json.loads(report.read_text())
    lines: list[str] = []

    def walk(issues: list[dict], depth: int) -> None:
        for issue in issues:
            # INFO too where it is about an image or texture: the glTF validator's IMAGE_NPOT_DIMENSIONS (a
            # side that is not a power of two, which WebGL 1 clients cannot mipmap) is an INFO
            if issue["severity"] in ("ERROR", "WARNING") or _about_textures(issue):
                lines.append("  " * depth + f"{issue['severity']} {issue['type']}: {issue['message']}")
            walk(issue.get("causes", []), depth + 1)

    walk(doc.get("issues", []), 0)
    assert doc["numErrors"] + doc["numWarnings"] == 0 or lines
    return lines


def _about_textures(issue: dict) -> bool:
    """An issue the validator raises about an image or a texture (its glTF validator code or its wording)."""
    text = f"{issue['type']} {issue['message']}"
    return any(word in text for word in ("IMAGE_", "TEXTURE_", "power-of-two", "mipmap"))


def test_dsm_and_points_of_the_sample_city_validate(validator, sample_built, tmp_path) -> None:
    """The textured DSM and the RGB point octree (with plane quads) of the sample city."""
    assert _validate(validator, sample_built.dsm, tmp_path) == []
    assert _validate(validator, sample_built.points, tmp_path) == []


def test_points_without_rgb_validate(validator, tmp_path) -> None:
    """A cloud without RGB: class, intensity and return number only, as EXT_structural_metadata."""
    las = tmp_path / "cloud.laz"
    make_cloud(las, n_terrain=8_000, rgb=False)
    build_points([las], tmp_path / "tiles", workers=0, progress=False, max_leaf_points=2_000)
    assert _validate(validator, tmp_path / "tiles", tmp_path) == []


def test_vertex_coloured_mesh_validates(validator, tmp_path) -> None:
    """Meshes with linear COLOR_0 and no texture (the colour path of other writers' content)."""
    out = make_terrain_tileset(tmp_path / "terrain", levels=2, n=9, texture_px=None, vertex_colors=True)
    assert _validate(validator, out, tmp_path) == []


def test_city_model_mesh_validates(validator, tmp_path) -> None:
    """The textured, shape-constrained city mesh of ``build model`` (cells as tiles under an empty root)."""
    from citylod.lod.build.model import build_model
    from citylod.sample import make_sample

    info = make_sample(tmp_path / "s", size=65, seed=7)
    build_model(info.files["dsm"], tmp_path / "model", ortho=info.files["ortho"], cell=32, workers=0,
                progress=False)
    assert _validate(validator, tmp_path / "model", tmp_path) == []


def test_city_tilesets_validate(validator, sample_city, tmp_path) -> None:
    """CityGML buildings as tiles with feature IDs and property tables (building LOD: blocks, merged
    blocks), and a textured model with multiresolution atlases."""
    from citylod.lod.build.city import build_city_tiles
    from citylod.sample.textured import make_textured_city

    build_city_tiles(sample_city.files["city"], tmp_path / "city", leaf_triangles=20, progress=False)
    assert _validate(validator, tmp_path / "city", tmp_path) == []
    textured = make_textured_city(tmp_path / "t", buildings=6, image_px=32)
    build_city_tiles(textured.path, tmp_path / "textured", atlas_px=128, progress=False)
    assert _validate(validator, tmp_path / "textured", tmp_path) == []
