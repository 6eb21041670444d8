"""Appearances of city models: CityGML ParameterizedTexture / X3DMaterial, CityJSON appearance, and
hostile image references (outside the folder, missing, corrupt, huge declared size)."""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import numpy as np

from citylod.io.city import read_city_model
from citylod.io.city.appearance import check_image, read_appearances
from citylod.io.image import encode_png
from citylod.sample.textured import make_textured_city


def _png_header(width: int, height: int) -> bytes:
    """A PNG whose header declares width × height but which holds one empty row only."""
    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\x00")) + chunk(b"IEND", b"")


def test_citygml_textures_and_materials_reach_every_surface(tmp_path: Path) -> None:
    city = make_textured_city(tmp_path, buildings=3, image_px=32)
    apps = read_appearances(city.path)
    assert apps.warnings == []
    model = read_city_model(city.path)
    for obj, house in zip(model.objects, city.houses, strict=True):
        for poly, sem in zip(obj.surfaces, obj.semantics, strict=True):
            app = apps.lookup(poly[0])
            if sem == "GroundSurface":
                assert app is None
                continue
            assert app is not None and app.image is not None and app.rgb is not None
            assert app.image.name == Path(house.roof if sem == "RoofSurface" else house.facade).name
            uv = app.uv_of(poly[0][:-1])
            assert uv is not None and np.all((uv >= 0) & (uv <= 1))
            # the eaves (the ring's highest vertices) are at the top of the image: v = 1 in CityGML
            top = poly[0][:-1, 2] >= poly[0][:, 2].max() - 1e-6
            if sem == "WallSurface" and top.sum() == 2 and len(uv) == 4:
                assert np.all(uv[top, 1] == 1.0)


def test_hostile_image_references_are_warnings_naming_the_file(tmp_path: Path) -> None:
    (tmp_path / "model").mkdir()
    (tmp_path / "outside.png").write_bytes(encode_png(np.zeros((4, 4, 3), np.uint8)))
    (tmp_path / "model" / "corrupt.jpg").write_bytes(b"\xff\xd8\xff\xe0 not really a jpeg")
    (tmp_path / "model" / "huge.png").write_bytes(_png_header(20_000, 20_000))
    (tmp_path / "model" / "ok.png").write_bytes(encode_png(np.zeros((4, 4, 3), np.uint8)))
    base = tmp_path / "model"
    for uri, words in (("../outside.png", "outside"), ("missing.jpg", "missing"), ("corrupt.jpg", "cannot be read"),
                       ("huge.png", "1144 MB"), ("http://example.org/a.jpg", "URL"),
                       ("/etc/passwd", "outside")):
        path, warning = check_image(uri, base)
        assert path is None and warning is not None and words in warning and uri in warning
    assert check_image("ok.png", base) == ((base / "ok.png").resolve(), None)
    # a header within OpenImageIO's sanity limits but above ours
    path, warning = check_image("ok.png", base, max_pixels=15)
    assert path is None and warning is not None and "4×4" in warning


def test_cityjson_appearance_and_a_missing_texture(tmp_path: Path) -> None:
    (tmp_path / "wall.png").write_bytes(encode_png(np.full((8, 8, 3), 200, np.uint8)))
    doc = {
        "type": "CityJSON", "version": "1.0", "metadata": {"referenceSystem": "urn:ogc:def:crs:EPSG::7415"},
        "vertices": [[0, 0, 0], [10, 0, 0], [10, 0, 5], [0, 0, 5], [10, 8, 0], [10, 8, 5]],
        "appearance": {
            "textures": [{"type": "PNG", "image": "wall.png"}, {"type": "PNG", "image": "gone.png"}],
            "vertices-texture": [[0, 0], [1, 0], [1, 1], [0, 1]],
            "materials": [{"name": "red", "diffuseColor": [0.9, 0.1, 0.1]}],
        },
        "CityObjects": {"b1": {"type": "Building", "attributes": {"h": 5}, "geometry": [{
            "type": "MultiSurface", "lod": 2, "boundaries": [[[0, 1, 2, 3]], [[1, 4, 5, 2]]],
            "texture": {"photo": {"values": [[[0, 0, 1, 2, 3]], [[1, 0, 1, 2, 3]]]}},
            "material": {"paint": {"values": [0, 0]}},
        }]}},
    }
    path = tmp_path / "m.city.json"
    path.write_text(json.dumps(doc))
    apps = read_appearances(path)
    assert len(apps.warnings) == 1 and "gone.png" in apps.warnings[0]
    verts = np.array(doc["vertices"], float)
    first = apps.lookup(verts[[0, 1, 2, 3]])
    second = apps.lookup(verts[[1, 4, 5, 2]])
    assert first is not None and first.image == (tmp_path / "wall.png").resolve() and first.rgb == (0.9, 0.1, 0.1)
    np.testing.assert_array_equal(first.uv_of(verts[[0, 1, 2, 3]]), [[0, 0], [1, 0], [1, 1], [0, 1]])
    # the missing image: no texture, the material stays
    assert second is not None and second.image is None and second.rgb == (0.9, 0.1, 0.1)


MONTREAL = Path(__file__).parents[1] / "data" / "cityjsonseq" / "montreal_b4.city.jsonl"


def _seq_features(path: Path) -> list[dict]:
    lines = [json.loads(x) for x in path.read_text(encoding="utf-8").splitlines() if x.strip()]
    return lines


def test_cityjsonseq_feature_appearances_written_by_another_tool(tmp_path: Path) -> None:
    """A CityJSONSeq stream written by bertt/cityjson (Montréal, four textured LoD2 buildings, each feature with
    its own ``appearance``): every textured ring's texture coordinates, checked against a plain json parse."""
    src = tmp_path / "m.city.jsonl"
    src.write_bytes(MONTREAL.read_bytes())
    apps = read_appearances(src)
    docs = _seq_features(src)
    header, features = docs[0], docs[1:]
    # The stream names its images but does not ship them: one warning per missing image, naming it.
    uris = [t["image"] for f in features for t in f["appearance"]["textures"]]
    assert len(apps.warnings) == len(set(uris)) == 4
    assert all(any(u in w and "missing" in w for w in apps.warnings) for u in uris)
    scale, translate = np.array(header["transform"]["scale"]), np.array(header["transform"]["translate"])
    checked = degenerate = 0
    for f in features:
        verts = np.array(f["vertices"], float) * scale + translate
        tex = np.array(f["appearance"]["vertices-texture"], float)
        for obj in f["CityObjects"].values():
            for g in obj["geometry"]:
                values = next(iter(g["texture"].values()))["values"]
                for surface, tv in zip(g["boundaries"], values, strict=True):
                    ring = verts[surface[0]]
                    app = apps.lookup(ring)
                    assert app is not None and app.image is None  # the image is missing
                    uv = app.uv_of(ring)
                    assert uv is not None
                    if len(np.unique(np.round(ring / 1e-3), axis=0)) < len(ring):
                        # Two corners within a millimetre: appearances are tied to vertices by position
                        # (io/city/appearance.py), so such a degenerate ring keeps one of their coordinates.
                        degenerate += 1
                        continue
                    np.testing.assert_allclose(uv, tex[tv[0][1:]], atol=1e-12)
                    checked += 1
    assert checked + degenerate == len(apps.surfaces) > 500 and degenerate < 0.02 * checked


def test_cityjsonseq_textures_reach_the_tileset(tmp_path: Path) -> None:
    """With the stream's images present (stand-ins made here), its buildings come out textured: one atlas per
    tile, every building of the stream in the tileset."""
    from citylod.io.image import encode_image
    from citylod.io.tiles3d import open_tileset
    from citylod.lod.build.city import build_city_tiles

    src = tmp_path / "m.city.jsonl"
    src.write_bytes(MONTREAL.read_bytes())
    features = _seq_features(src)[1:]
    for k, f in enumerate(features):
        for t in f["appearance"]["textures"]:
            img = tmp_path / t["image"]
            img.parent.mkdir(parents=True, exist_ok=True)
            img.write_bytes(encode_image(np.full((64, 64, 3), 60 * k, np.uint8), "jpg", 90))
    apps = read_appearances(src)
    assert apps.warnings == [] and len(apps.images) == 4
    report = build_city_tiles(src, tmp_path / "tiles", progress=False)
    ts = open_tileset(tmp_path / "tiles")
    assert ts.extras["citylod"]["textured"] is True
    content = ts.root.load_content()
    textured = [m for m in content.meshes if m.texture]
    assert textured and all(m.uv is not None for m in textured)
    ids = {i for f in features for i in f["CityObjects"]}
    assert report.objects == len(ids) == 4


def test_hostile_cityjsonseq_appearances_are_warnings(tmp_path: Path) -> None:
    """A feature's textures pointing outside the model's folder or declaring a huge image are refused with a
    warning naming them; the surfaces keep their texture coordinates and fall back to their material."""
    (tmp_path / "model").mkdir()
    (tmp_path / "secret.png").write_bytes(encode_png(np.zeros((4, 4, 3), np.uint8)))
    (tmp_path / "model" / "huge.png").write_bytes(_png_header(30_000, 30_000))
    header = {"type": "CityJSON", "version": "2.0", "CityObjects": {}, "vertices": [],
              "transform": {"scale": [0.01, 0.01, 0.01], "translate": [500000.0, 5400000.0, 0.0]},
              "metadata": {"referenceSystem": "https://www.opengis.net/def/crs/EPSG/0/32632"}}
    lines = [json.dumps(header)]
    for k, uri in enumerate(("../secret.png", "huge.png")):
        feature = {"type": "CityJSONFeature", "id": f"b{k}", "vertices": [[0, 0, 0], [1000, 0, 0], [1000, 1000, 0],
                                                                          [0, 1000, 0]],
                   "CityObjects": {f"b{k}": {"type": "Building", "geometry": [{
                       "type": "MultiSurface", "lod": "2", "boundaries": [[[0, 1, 2, 3]]],
                       "texture": {"t": {"values": [[[0, 0, 1, 2, 3]]]}},
                       "material": {"m": {"values": [0]}}}]}},
                   "appearance": {"textures": [{"type": "PNG", "image": uri}],
                                  "materials": [{"name": "red", "diffuseColor": [0.8, 0.1, 0.1]}],
                                  "vertices-texture": [[0, 0], [1, 0], [1, 1], [0, 1]]}}
        lines.append(json.dumps(feature))
    src = tmp_path / "model" / "hostile.city.jsonl"
    src.write_text("\n".join(lines) + "\n")
    apps = read_appearances(src)
    assert len(apps.warnings) == 2
    assert "../secret.png" in apps.warnings[0] and "outside" in apps.warnings[0]
    assert "huge.png" in apps.warnings[1] and "2574 MB" in apps.warnings[1]  # OpenImageIO refuses the header
    assert len(apps.surfaces) == 1  # both features have the same square, offset only in id
    only = next(iter(apps.surfaces.values()))
    assert only.image is None and only.rgb == (0.8, 0.1, 0.1) and len(only.uv) == 4
