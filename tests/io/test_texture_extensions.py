"""Texture extensions of glTF content, rendered as ``citylod render`` draws them: ``EXT_texture_webp`` (an image
libwebp wrote), ``KHR_texture_transform`` (the quadrant its transform selects, reasoned from the extension's
definition) and ``KHR_texture_basisu`` (KTX2 files Binomial's ``basisu`` encoder wrote, ETC1S and UASTC, against
the PNG they were encoded from)."""

from __future__ import annotations

import base64
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from citylod.core.errors import InputError
from citylod.io.image import decode_image, encode_image
from citylod.io.tiles3d import TileSpec, decode_content, write_tileset

# KTX2 files written by basisu (Basis Universal 2.x) from quadrants.png, which is _texture() (SOURCE.md there).
KTX2_DIR = Path(__file__).resolve().parents[1] / "data" / "ktx2"

# The texture's quadrants, row 0 (v = 0) at the top: red | green over blue | yellow.
QUADRANTS = {"red": (230, 20, 20), "green": (20, 200, 20), "blue": (20, 20, 230), "yellow": (230, 230, 20)}
MAGENTA = (1.0, 0.0, 1.0, 1.0)  # the material's baseColorFactor: what shows without a texture


def _texture() -> np.ndarray:
    px = np.zeros((64, 64, 3), np.uint8)
    px[:32, :32], px[:32, 32:] = QUADRANTS["red"], QUADRANTS["green"]
    px[32:, :32], px[32:, 32:] = QUADRANTS["blue"], QUADRANTS["yellow"]
    return px


def _quad_gltf(texture: dict[str, Any], image: dict[str, Any], info: dict[str, Any] | None = None,
               required: tuple[str, ...] = ()) -> dict[str, Any]:
    """A 100 m horizontal quad (glTF y-up) with UVs (0,0) … (1,1), textured by ``texture``."""
    pos = np.array([[-50, 0, 50], [50, 0, 50], [50, 0, -50], [-50, 0, -50]], np.float32)  # counter-clockwise from +y
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32)  # v = 0 at the north edge (−z in glTF)
    idx = np.array([0, 1, 2, 0, 2, 3], np.uint16)
    blob = pos.tobytes() + uv.tobytes() + idx.tobytes()
    return {
        "asset": {"version": "2.0"},
        "extensionsUsed": sorted({*required, *texture.get("extensions", {}),
                                  *(info or {}).get("extensions", {})}),
        "extensionsRequired": list(required),
        "buffers": [{"byteLength": len(blob),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48},
                        {"buffer": 0, "byteOffset": 48, "byteLength": 32},
                        {"buffer": 0, "byteOffset": 80, "byteLength": 12}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
                       "min": [-50, 0, -50], "max": [50, 0, 50]},
                      {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
                      {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}],
        "images": [image],
        "samplers": [{"magFilter": 9728, "minFilter": 9728}],
        "textures": [texture | {"sampler": 0}],
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": list(MAGENTA),
                                                "baseColorTexture": {"index": 0, **(info or {})}},
                       "extensions": {"KHR_materials_unlit": {}}}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
    }


def _data_uri(mime: str, data: bytes) -> str:
    return f"data:{mime};base64," + base64.b64encode(data).decode()


def _labels(doc: dict[str, Any], tmp_path: Path) -> np.ndarray:
    """The nearest of the quadrant colours and magenta (indices 0–4, 5 for none) at each pixel of a view from
    straight above the quad (the tile as its own tileset)."""
    from citylod.core.camera import Camera
    from citylod.render.offscreen import render_images

    out = tmp_path / "ts"
    out.mkdir(parents=True)
    (out / "quad.gltf").write_text(json.dumps(doc))
    c = np.array([500_000.0, 5_400_000.0, 100.0])
    write_tileset(out, TileSpec("0", 0, c, c - [50, 50, 1], c + [50, 50, 1], 0.0, content="quad.gltf"), "EPSG:32632")
    cam = Camera(position=tuple(c + [0, 0, 300]), focal_point=tuple(c), view_up=(0, 1, 0))
    (rgb, _), = render_images([out], [cam], size=(160, 160))
    ref = np.array([*QUADRANTS.values(), (255, 0, 255)], float)
    d = np.linalg.norm(rgb.reshape(-1, 1, 3).astype(float) - ref[None], axis=2)
    near = d.min(axis=1) < 80  # shading darkens an untextured face by up to about a fifth
    return np.where(near, d.argmin(axis=1), len(ref)).reshape(rgb.shape[:2])


def _render(doc: dict[str, Any], tmp_path: Path) -> dict[str, int]:
    """Pixels of each colour in the view of :func:`_labels`."""
    counts = np.bincount(_labels(doc, tmp_path).reshape(-1), minlength=len(QUADRANTS) + 2)
    return {n: int(k) for n, k in zip([*QUADRANTS, "magenta"], counts, strict=False)}


def test_plain_png_shows_the_four_quadrants(tmp_path: Path) -> None:
    """The control: the same quad with a PNG source shows every quadrant, about equally."""
    doc = _quad_gltf({"source": 0}, {"uri": _data_uri("image/png", encode_image(_texture(), "png"))})
    counts = _render(doc, tmp_path)
    quads = [counts[n] for n in QUADRANTS]
    assert min(quads) > 0.2 * sum(quads) and counts["magenta"] == 0


def test_webp_texture_is_decoded(tmp_path: Path) -> None:
    webp = encode_image(_texture(), "webp")
    assert webp[:4] == b"RIFF" and webp[8:12] == b"WEBP"
    doc = _quad_gltf({"extensions": {"EXT_texture_webp": {"source": 0}}},
                     {"uri": _data_uri("image/webp", webp)}, required=("EXT_texture_webp",))
    counts = _render(doc, tmp_path)
    quads = [counts[n] for n in QUADRANTS]
    assert min(quads) > 0.2 * sum(quads) and counts["magenta"] == 0


def test_texture_transform_selects_the_quadrant_it_names(tmp_path: Path) -> None:
    """uv' = offset + R(r) S(scale) uv with u' = u cos r + v sin r, v' = v cos r − u sin r (as 3D Tiles clients apply
    it). Scale ½ and offset (½, 0) map the quad onto u ∈ [½, 1], v ∈ [0, ½]: the image's top right, green. A quarter
    turn with offset (0, ½) maps it onto u' = v/2 ∈ [0, ½], v' = ½ − u/2 ∈ [0, ½]: the top left, red (the opposite
    turn would give yellow)."""
    png = {"uri": _data_uri("image/png", encode_image(_texture(), "png"))}
    shift = {"extensions": {"KHR_texture_transform": {"offset": [0.5, 0.0], "scale": [0.5, 0.5]}}}
    counts = _render(_quad_gltf({"source": 0}, png, shift, required=("KHR_texture_transform",)), tmp_path / "a")
    assert counts["green"] > 0.95 * sum(counts[n] for n in QUADRANTS)
    turn = {"extensions": {"KHR_texture_transform": {"offset": [0.0, 0.5], "scale": [0.5, 0.5],
                                                     "rotation": float(np.pi / 2)}}}
    counts = _render(_quad_gltf({"source": 0}, png, turn, required=("KHR_texture_transform",)), tmp_path / "b")
    assert counts["red"] > 0.95 * sum(counts[n] for n in QUADRANTS)


@pytest.mark.parametrize("codec", ["etc1s", "uastc"])
def test_ktx2_texture_decodes_to_its_source_image(codec: str) -> None:
    """The transcoded pixels against the PNG basisu encoded: every quadrant's colour within a few levels (both
    codecs are lossy, but a flat 32×32 block is what they keep best), rows in the same order."""
    data = (KTX2_DIR / f"quadrants_{codec}.ktx2").read_bytes()
    px = decode_image(data, "quadrants.ktx2")
    truth = decode_image((KTX2_DIR / "quadrants.png").read_bytes())
    assert px.shape == truth.shape == (64, 64, 3)
    assert np.abs(px.astype(int) - truth.astype(int)).max() <= 12
    assert np.abs(px.astype(int) - _texture().astype(int)).mean() <= 3


@pytest.mark.parametrize("codec", ["etc1s", "uastc"])
def test_ktx2_texture_is_drawn_as_its_png_is(codec: str, tmp_path: Path) -> None:
    """The quad textured through ``KHR_texture_basisu`` (the extension required, no fallback source) is the
    picture of the same quad with the PNG: the same quadrant under each pixel, none in the material's colour."""
    png = (KTX2_DIR / "quadrants.png").read_bytes()
    control = _labels(_quad_gltf({"source": 0}, {"uri": _data_uri("image/png", png)}), tmp_path / "png")
    ktx2 = (KTX2_DIR / f"quadrants_{codec}.ktx2").read_bytes()
    doc = _quad_gltf({"extensions": {"KHR_texture_basisu": {"source": 0}}},
                     {"uri": _data_uri("image/ktx2", ktx2)}, required=("KHR_texture_basisu",))
    content = decode_content(json.dumps(doc).encode(), "quad.gltf")
    assert content.triangle_count == 2 and content.meshes[0].texture == ktx2
    labels = _labels(doc, tmp_path / "ktx2")
    textured = control < len(QUADRANTS)
    assert textured.sum() > 0.1 * control.size and set(np.unique(control[textured])) == set(range(len(QUADRANTS)))
    assert (labels[textured] == control[textured]).mean() > 0.99 and not (labels == len(QUADRANTS)).any()


def test_broken_ktx2_is_one_clear_error() -> None:
    """A cut file, or the KTX2 identifier followed by nothing valid, is an InputError naming the file."""
    data = (KTX2_DIR / "quadrants_etc1s.ktx2").read_bytes()
    for bad in (data[:100], data[:12] + bytes(200)):
        with pytest.raises(InputError, match="KTX2") as info:
            decode_image(bad, "bad.ktx2")
        assert "bad.ktx2" in str(info.value)
