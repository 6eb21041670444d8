"""City models written by others (tests/data, see its README): what citylod reads, checked against an
independent parse of the same file with lxml or json in the test."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyproj
import shapely
from lxml import etree

from citylod.io.city.citygml import read_citygml
from citylod.io.city.read import read_city_model
from citylod.semantics.proxy import footprint_of
from tests.cli_harness import run_cli
from tests.paths import ROOT

DATA = ROOT / "tests" / "data"
NS = {"gml": "http://www.opengis.net/gml", "bldg": "http://www.opengis.net/citygml/building/2.0",
      "dem": "http://www.opengis.net/citygml/relief/2.0", "core": "http://www.opengis.net/citygml/2.0"}


def _ring_xyz(ring: etree._Element) -> np.ndarray:
    return np.array(ring.xpath(".//gml:posList", namespaces=NS)[0].text.split(), float).reshape(-1, 3)


def _area3d(ring: np.ndarray) -> float:
    c = ring - ring[:-1].mean(axis=0)
    return float(np.linalg.norm(0.5 * np.cross(c[:-1], c[1:]).sum(axis=0)))


def test_citygml4j_lod4_building_xlinks_openings_and_tin_relief() -> None:
    path = DATA / "citygml4j" / "lod4_building_v2_excerpt.gml"
    model = read_citygml(path, lod=4)
    tree = etree.parse(str(path))
    # Objects: one per cityObjectMember here (no parts).
    members = tree.xpath("/*/*[local-name()='cityObjectMember']/*")
    assert [o.id for o in model.objects] == [m.get("{http://www.opengis.net/gml}id") for m in members]
    srs = tree.xpath("//gml:Envelope/@srsName", namespaces=NS)[0]
    assert srs == "urn:ogc:def:crs,crs:EPSG::25832,crs:EPSG::5783"
    assert model.crs.is_compound
    assert model.crs.sub_crs_list[0].equals(pyproj.CRS.from_epsg(25832))
    assert model.crs.sub_crs_list[1].equals(pyproj.CRS.from_epsg(5783))
    assert not [w for w in model.warnings if "xlink" in w]
    building, relief = model.objects
    # The building's outside: every polygon under its boundedBy (walls as CompositeSurfaces, the roof,
    # windows and the door in openings, which the lod4Solid names by xlink), each exactly once.
    polys = tree.xpath("//bldg:Building/bldg:boundedBy//gml:Polygon", namespaces=NS)
    expected = sorted(round(_area3d(_ring_xyz(p.xpath("gml:exterior", namespaces=NS)[0])), 6) for p in polys)
    got = sorted(round(_area3d(poly[0]), 6) for poly in building.surfaces)
    assert building.lod == 4 and got == expected
    assert building.semantics.count("Window") == 2 and building.semantics.count("Door") == 1
    # The relief: its gml:Triangle patches, at the LoD its dem:lod says.
    tris = [_ring_xyz(t) for t in tree.xpath("//dem:TINRelief//gml:Triangle", namespaces=NS)]
    lod = int(tree.xpath("//dem:TINRelief/dem:lod", namespaces=NS)[0].text)
    assert relief.type == "ReliefFeature" and relief.lod == lod == 3 and len(relief.surfaces) == len(tris) == 9
    assert np.isclose(sum(_area3d(p[0]) for p in relief.surfaces), sum(_area3d(t) for t in tris))


def test_cityjsonseq_matches_an_independent_parse(tmp_path: Path) -> None:
    path = DATA / "citygml4j" / "lod2_buildings_3.city.jsonl"
    model = read_city_model(path)
    lines = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    header, features = lines[0], lines[1:]
    scale, translate = np.array(header["transform"]["scale"]), np.array(header["transform"]["translate"])
    expected: dict[str, np.ndarray] = {}
    for f in features:
        verts = np.array(f["vertices"], float) * scale + translate
        for oid, co in f["CityObjects"].items():
            idx = [i for g in co.get("geometry", []) for i in np.ravel(_flatten(g["boundaries"]))]
            expected[oid] = verts[np.unique(idx)] if idx else np.zeros((0, 3))
    assert model.version == "CityJSONSeq 2.0" and model.crs is None
    assert sorted(o.id for o in model.objects) == sorted(expected)
    for o in model.objects:
        pts = np.unique(np.round(o.points(), 6), axis=0)
        assert np.array_equal(pts, np.unique(np.round(expected[o.id], 6), axis=0)), o.id
    # The header names no CRS: build city asks for one, and builds with it.
    out = tmp_path / "c.gpkg"
    r = run_cli(["build", "city", path, "-o", out])
    assert r.returncode == 2 and "--crs" in r.stderr
    r = run_cli(["build", "city", path, "-o", out, "--crs", "EPSG:3068"])
    assert r.returncode == 0 and f"{len(expected)} city objects" in r.stdout, r.stderr


def _flatten(b: object) -> list[int]:
    return [i for x in b for i in _flatten(x)] if isinstance(b, list) else [b]  # type: ignore[list-item]


def test_steep_tree_crowns_keep_their_footprint() -> None:
    path = DATA / "cjio" / "delft_trees.city.json"
    model = read_city_model(path)
    doc = json.loads(path.read_text())
    assert model.crs.equals(pyproj.CRS.from_epsg(7415))
    assert sorted(o.id for o in model.objects) == sorted(doc["CityObjects"])
    verts = np.array(doc["vertices"], float) * doc["transform"]["scale"] + doc["transform"]["translate"]
    trees = [o for o in model.objects if o.type == "PlantCover"]
    assert len(trees) == 4
    for o in trees:
        # Independent: the xy projection of every surface of the object's geometry, unioned.
        shapes = [shapely.make_valid(shapely.Polygon(verts[np.array(s[0])][:, :2]))
                  for g in doc["CityObjects"][o.id]["geometry"] for s in _surfaces_of(g)]
        ref = shapely.union_all(shapes, grid_size=1e-3)
        ref_area = sum(p.area for p in shapely.get_parts(ref) if p.geom_type == "Polygon")
        assert ref_area > 1.0
        assert footprint_of(o).area >= 0.995 * ref_area, (o.id, footprint_of(o).area, ref_area)


def _surfaces_of(g: dict) -> list:
    depth = {"MultiSurface": 1, "CompositeSurface": 1, "Solid": 2, "MultiSolid": 3, "CompositeSolid": 3}[g["type"]]
    level = [g["boundaries"]]
    for _ in range(depth - 1):
        level = [x for node in level for x in node]
    return [s for node in level for s in node]


_GML = """<?xml version="1.0" encoding="UTF-8"?>
<core:CityModel xmlns:core="http://www.opengis.net/citygml/2.0" xmlns:bldg="http://www.opengis.net/citygml/building/2.0"
 xmlns:gml="http://www.opengis.net/gml" xmlns:xlink="http://www.w3.org/1999/xlink">
 <gml:boundedBy><gml:Envelope srsName="urn:ogc:def:crs:EPSG:6.12:25833" srsDimension="3"/></gml:boundedBy>
 <core:cityObjectMember>{member}</core:cityObjectMember>
</core:CityModel>
"""


def _poly(pid: str, pts: list[tuple[float, float, float]], holes: list | None = None) -> str:
    def ring(p: list) -> str:
        return "<gml:LinearRing><gml:posList>" + " ".join(f"{x} {y} {z}" for x, y, z in [*p, p[0]]) + \
            "</gml:posList></gml:LinearRing>"
    inner = "".join(f"<gml:interior>{ring(h)}</gml:interior>" for h in holes or [])
    return f'<gml:Polygon gml:id="{pid}"><gml:exterior>{ring(pts)}</gml:exterior>{inner}</gml:Polygon>'


def _box_faces(x0: float, x1: float, z1: float) -> dict[str, list]:
    """Outward faces of [x0, x1] x [0, 10] x [0, z1]."""
    return {
        "ground": [(x0, 0, 0), (x0, 10, 0), (x1, 10, 0), (x1, 0, 0)],
        "roof": [(x0, 0, z1), (x1, 0, z1), (x1, 10, z1), (x0, 10, z1)],
        "south": [(x0, 0, 0), (x1, 0, 0), (x1, 0, z1), (x0, 0, z1)],
        "north": [(x1, 10, 0), (x0, 10, 0), (x0, 10, z1), (x1, 10, z1)],
        "west": [(x0, 10, 0), (x0, 0, 0), (x0, 0, z1), (x0, 10, z1)],
        "east": [(x1, 0, 0), (x1, 10, 0), (x1, 10, z1), (x1, 0, z1)],
    }


def test_buildingpart_links_to_its_parents_wall(tmp_path: Path) -> None:
    # The parent's east wall is the part's west wall (reversed): the part names it by xlink through an
    # OrientableSurface, as files do for shared walls. Without the link the part's shell is open.
    parent = _box_faces(0, 10, 4)
    part = _box_faces(10, 20, 4)
    parent_ms = "".join(f"<gml:surfaceMember>{_poly('A_' + k, v)}</gml:surfaceMember>" for k, v in parent.items())
    part_ms = "".join(f"<gml:surfaceMember>{_poly('B_' + k, v)}</gml:surfaceMember>" for k, v in part.items()
                      if k != "west")
    part_ms += ('<gml:surfaceMember><gml:OrientableSurface orientation="-"><gml:baseSurface xlink:href="#A_east"/>'
                "</gml:OrientableSurface></gml:surfaceMember>")
    member = (f'<bldg:Building gml:id="A"><bldg:lod2Solid><gml:Solid><gml:exterior><gml:CompositeSurface>{parent_ms}'
              "</gml:CompositeSurface></gml:exterior></gml:Solid></bldg:lod2Solid>"
              f'<bldg:consistsOfBuildingPart><bldg:BuildingPart gml:id="B"><bldg:lod2Solid><gml:Solid><gml:exterior>'
              f"<gml:CompositeSurface>{part_ms}</gml:CompositeSurface></gml:exterior></gml:Solid></bldg:lod2Solid>"
              "</bldg:BuildingPart></bldg:consistsOfBuildingPart></bldg:Building>")
    p = tmp_path / "parts.gml"
    p.write_text(_GML.format(member=member))
    m = read_citygml(p)
    a, b = m.objects
    assert (a.id, b.id, b.parent) == ("A", "B", "A")
    assert m.crs.equals(pyproj.CRS.from_epsg(25833))
    assert len(b.surfaces) == 6 and not m.warnings, m.warnings  # closed, outward, nothing unresolved
    # The shared wall faces -x in the part (reversed by orientation="-").
    west = [poly for poly in b.surfaces if np.allclose(poly[0][:, 0], 10)]
    c = west[0][0] - west[0][0][:-1].mean(axis=0)
    assert 0.5 * np.cross(c[:-1], c[1:]).sum(axis=0)[0] < 0


def test_windows_close_walls_with_holes_only(tmp_path: Path) -> None:
    faces = _box_faces(0, 10, 6)
    hole = [(3, 0, 2), (3, 0, 4), (6, 0, 4), (6, 0, 2)]
    window = [(3, 0, 2), (6, 0, 2), (6, 0, 4), (3, 0, 4)]

    def doc(south_holes: list) -> str:
        walls = ""
        for k, v in faces.items():
            kind = {"ground": "GroundSurface", "roof": "RoofSurface"}.get(k, "WallSurface")
            extra = ""
            if k == "south":
                extra = (f'<bldg:opening><bldg:Window gml:id="W"><bldg:lod3MultiSurface><gml:MultiSurface>'
                         f"<gml:surfaceMember>{_poly('W_p', window)}</gml:surfaceMember></gml:MultiSurface>"
                         "</bldg:lod3MultiSurface></bldg:Window></bldg:opening>")
            walls += (f"<bldg:boundedBy><bldg:{kind}><bldg:lod3MultiSurface><gml:MultiSurface><gml:surfaceMember>"
                      f"{_poly(k, v, south_holes if k == 'south' else None)}</gml:surfaceMember></gml:MultiSurface>"
                      f"</bldg:lod3MultiSurface>{extra}</bldg:{kind}></bldg:boundedBy>")
        return _GML.format(member=f'<bldg:Building gml:id="A">{walls}</bldg:Building>')

    p = tmp_path / "w.gml"
    p.write_text(doc([hole]))
    m = read_citygml(p, lod=3)
    assert m.objects[0].semantics.count("Window") == 1 and not m.warnings, m.warnings
    # The same window named by xlink from a second wall (as exporters write a window shared by two
    # surfaces) is still one window.
    text = doc([hole]).replace("</bldg:lod3MultiSurface></bldg:WallSurface>",
                               '</bldg:lod3MultiSurface><bldg:opening xlink:href="#W"/></bldg:WallSurface>', 1)
    assert 'xlink:href="#W"' in text
    p.write_text(text)
    m = read_citygml(p, lod=3)
    assert m.objects[0].semantics.count("Window") == 1 and not m.warnings, m.warnings
    # Control: a window drawn over a wall without a hole stays out (the shell is closed without it).
    p.write_text(doc([]))
    m = read_citygml(p, lod=3)
    assert "Window" not in m.objects[0].semantics and not m.warnings, m.warnings


def test_citygml3_samples_count_crs_and_missing_srsname(tmp_path: Path) -> None:
    ade = DATA / "citygml4j" / "test_ade_objects_v3.gml"
    model = read_citygml(ade)
    tree = etree.parse(str(ade))
    members = tree.xpath("/*/*[local-name()='cityObjectMember']/*")
    parts = tree.xpath("/*/*[local-name()='cityObjectMember']//*[local-name()='buildingPart']/*")
    assert len(model.objects) == len(members) + len(parts) and model.version == "CityGML 3.0"
    assert model.crs.sub_crs_list[0].equals(pyproj.CRS.from_epsg(25832))
    assert model.crs.sub_crs_list[1].equals(pyproj.CRS.from_epsg(5783))
    # A real file that names no CRS: build city says so in one line and asks for --crs; info describes it.
    bare = DATA / "citygml4j" / "invalid_building_v3.gml"
    assert not etree.parse(str(bare)).xpath("//@srsName")
    out = tmp_path / "b.gpkg"
    r = run_cli(["build", "city", bare, "-o", out])
    assert r.returncode == 2 and "invalid_building_v3.gml" in r.stderr and "--crs" in r.stderr
    assert r.stderr.count("\n") == 1 and not out.exists()
    assert run_cli(["info", bare]).returncode == 0
    r = run_cli(["build", "city", bare, "-o", out, "--crs", "EPSG:25832"])
    assert r.returncode == 0 and out.exists(), r.stderr
    r = run_cli(["info", out])
    n = len(etree.parse(str(bare)).xpath("/*/*[local-name()='cityObjectMember']/*"))
    assert r.returncode == 0 and f"{n} objects" in r.stdout and "UTM zone 32N" in r.stdout, r.stdout + r.stderr


def test_versioned_compound_urn_of_a_real_file() -> None:
    # citygml4j's lod2_buildings_v3.gml: "EPSG:6.12:3068" was read as EPSG:6 and the build stopped.
    path = DATA / "citygml4j" / "lod2_buildings_v3_excerpt.gml"
    model = read_citygml(path)
    tree = etree.parse(str(path))
    assert tree.xpath("//@srsName")[0] == "urn:ogc:def:crs,crs:EPSG:6.12:3068,crs:EPSG:6.12:5783"
    assert model.crs.sub_crs_list[0].equals(pyproj.CRS.from_epsg(3068))
    assert model.crs.sub_crs_list[1].equals(pyproj.CRS.from_epsg(5783))
    members = tree.xpath("/*/*[local-name()='cityObjectMember']/*")
    assert [o.id for o in model.objects] == [m.get("{http://www.opengis.net/gml/3.2}id") for m in members]
    # Every polygon, once, with the same vertices.
    xyz = [np.array(p.text.split(), float).reshape(-1, 3) for p in tree.xpath("//*[local-name()='posList']")]
    assert sum(len(o.surfaces) for o in model.objects) == len(xyz)
    got = np.unique(np.round(np.concatenate([o.points() for o in model.objects]), 6), axis=0)
    assert np.array_equal(got, np.unique(np.round(np.concatenate(xyz), 6), axis=0))


def test_textured_cityjson_by_others_reaches_the_atlas() -> None:
    """KIT's FZK-Haus as CityJSON 2.0 with its textures (bertt/cityjson test data, images downsampled): walls
    whose coordinates are whole periods off [0, 1] (u in [-1, 0]) show their image, and the roofs, whose
    shingle image repeats 21 × 14 times, fall back to their material with a warning. Checked against the
    json and the images read here: each wall's region of the tile's atlas has the colours of its image."""
    import tempfile

    from citylod.io.image import decode_image, read_image
    from citylod.io.tiles3d import open_tileset
    from citylod.lod.build.city import build_city_tiles

    path = DATA / "cityjson_textured" / "fzk_haus_lod2_tex.city.json"
    doc = json.loads(path.read_text(encoding="utf-8"))
    with tempfile.TemporaryDirectory() as tmp:
        report = build_city_tiles(path, Path(tmp) / "tiles", progress=False)
        ts = open_tileset(Path(tmp) / "tiles")
        content = ts.root.load_content()
    assert report.objects == len(doc["CityObjects"]) == 1
    assert any("2 surface(s) repeat their texture" in w for w in report.warnings)
    table = content.property_tables[0]
    assert json.loads(table.columns["attributes"][0])["name"] == "KIT FZK-Haus"
    mesh = next(m for m in content.meshes if m.texture)
    atlas = decode_image(mesh.texture).astype(float)  # rows top-down, as glTF's uv
    verts = np.array(doc["vertices"], float) * doc["transform"]["scale"] + doc["transform"]["translate"]
    tex = np.array(doc["appearance"]["vertices-texture"], float)
    geom = doc["CityObjects"]["KIT-Test-Building-01"]["geometry"][0]
    pos = mesh.positions.astype(float) + ts.root.matrix[:3, 3]
    walls = 0
    for surface, value in zip(geom["boundaries"][0], geom["texture"]["unnamed"]["values"][0], strict=True):
        t = value[0]
        if t[0] is None:
            continue
        uv = tex[t[1:]]
        uv = uv - np.floor(uv.min(axis=0) + 1e-4)
        if uv.max() > 1.0 + 1e-4:
            continue  # the repeating roofs
        ring = verts[surface[0]]
        # The tile's triangles of this wall: those in its plane (the house's walls lie in distinct planes).
        c = ring - ring.mean(axis=0)
        normal = np.cross(c[:-1], c[1:]).sum(axis=0)
        normal /= np.linalg.norm(normal)
        tri = pos[mesh.faces]
        on = (np.abs((tri - ring[0]) @ normal) < 1e-3).all(axis=1)
        assert on.sum() >= len(ring) - 2
        hit = np.unique(mesh.faces[on])
        image = read_image(path.parent / doc["appearance"]["textures"][t[0]]["image"]).astype(float)
        ih, iw = image.shape[:2]
        ah, aw = atlas.shape[:2]
        # Mean colour over the same central window of the surface's uv box, in the image (v up) and in the
        # atlas (glTF v down): the atlas holds this image there, possibly shrunk.
        lo, hi = uv.min(axis=0), uv.max(axis=0)
        a_lo, a_hi = mesh.uv[hit].min(axis=0), mesh.uv[hit].max(axis=0)
        f0, f1 = 0.3, 0.7
        img_win = image[int(ih * (1 - (lo[1] + f1 * (hi[1] - lo[1])))):int(ih * (1 - (lo[1] + f0 * (hi[1] - lo[1])))),
                        int(iw * (lo[0] + f0 * (hi[0] - lo[0]))):int(iw * (lo[0] + f1 * (hi[0] - lo[0])))]
        at_win = atlas[int(ah * (a_lo[1] + f0 * (a_hi[1] - a_lo[1]))):int(ah * (a_lo[1] + f1 * (a_hi[1] - a_lo[1]))),
                       int(aw * (a_lo[0] + f0 * (a_hi[0] - a_lo[0]))):int(aw * (a_lo[0] + f1 * (a_hi[0] - a_lo[0])))]
        assert img_win.size and at_win.size
        assert np.abs(img_win.reshape(-1, 3).mean(axis=0) - at_win.reshape(-1, 3).mean(axis=0)).max() < 12.0
        walls += 1
    assert walls == 4
