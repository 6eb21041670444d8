"""A textured sample city: many LoD2 houses, each with its own procedural façade and roof images.

Written as CityGML 2.0 with ``app:ParameterizedTexture`` (image + texture coordinates per ring) and
``app:X3DMaterial`` fallbacks, images as JPEG files in ``textures/`` beside the model: the layout of textured
LoD2 models as cities publish them. Façades show one row of windows per storey on a plastered wall; roofs
show rows of tiles. Each image is ``image_px`` square, so 5,000 houses hold 10,000 images (about 2 GB of
texture memory at 256²): more than a modest texture budget, which is what multiresolution atlases are for.

Houses stand on a jittered grid (rectangular footprint, 1–6 storeys of 3 m, gable or flat roof); everything
comes from ``seed``. No VTK, no Qt.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
from lxml import etree

from citylod.core.errors import CitylodError, InputError
from citylod.core.fileio import atomic_write, atomic_write_bytes
from citylod.io.image import encode_image
from citylod.sample.gml import BLDG, CORE, GEN, GML, _q

__all__ = ["TexturedCity", "TexturedHouse", "make_textured_city"]

APP = "http://www.opengis.net/citygml/appearance/2.0"
_NSMAP = {"core": CORE, "bldg": BLDG, "gml": GML, "gen": GEN, "app": APP}
SRS_NAME = "urn:ogc:def:crs:EPSG::32632"
ORIGIN = (500_000.0, 5_400_000.0)
STOREY_M = 3.0


@dataclass(frozen=True)
class TexturedHouse:
    """One house: ``id``, footprint centre (x, y), width (x) and depth (y) in m, storeys, ``gable`` roof or
    flat, ridge height above the eaves, and the relative paths of its two images."""

    id: str
    x: float
    y: float
    width: float
    depth: float
    storeys: int
    gable: bool
    ridge_m: float
    facade: str
    roof: str

    @property
    def eave(self) -> float:
        return self.storeys * STOREY_M


@dataclass(frozen=True)
class TexturedCity:
    """What :func:`make_textured_city` wrote: the CityGML ``path``, its ``houses`` and the image size."""

    path: Path
    houses: list[TexturedHouse]
    image_px: int


def _facade_image(rng: np.random.Generator, storeys: int, px: int) -> npt.NDArray[np.uint8]:
    """Plaster of a random colour, one row of windows per storey (frames, dark glass, a sill)."""
    wall = rng.uniform(150, 235, 3)
    img = np.empty((px, px, 3), np.float64)
    img[:] = wall
    img += rng.normal(0, 4, (px, px, 1))  # plaster grain
    y, x = np.mgrid[0:px, 0:px] / px
    ncol = int(rng.integers(3, 7))
    fy = (y * storeys) % 1.0  # position inside the storey (row 0 at the top)
    fx = (x * ncol) % 1.0
    window = (fy > 0.25) & (fy < 0.75) & (fx > 0.25) & (fx < 0.75)
    frame = (fy > 0.22) & (fy < 0.78) & (fx > 0.22) & (fx < 0.78) & ~window
    glass = rng.uniform(40, 90, 3) * np.array([0.8, 0.9, 1.2])
    img[window] = glass + 40 * (1 - fy[window, None])  # a sky reflection, brighter at the top
    img[frame] = (245, 245, 240)
    img[(fy > 0.78) & (fy < 0.82) & (fx > 0.18) & (fx < 0.82)] = wall * 0.6
    return np.clip(img, 0, 255).astype(np.uint8)


def _roof_image(rng: np.random.Generator, px: int) -> npt.NDArray[np.uint8]:
    """Rows of tiles: a random terracotta or slate colour, staggered joints, shading per row."""
    base = rng.choice([np.array([170, 70, 50]), np.array([120, 60, 45]), np.array([80, 85, 95])])
    y, x = np.mgrid[0:px, 0:px] / px
    rows = 24
    fy = (y * rows) % 1.0
    row = np.floor(y * rows)
    fx = (x * rows * 0.75 + 0.5 * (row % 2)) % 1.0
    shade = 0.75 + 0.35 * fy  # each tile darker where the next row overlaps it
    img = base[None, None, :] * shade[..., None] * rng.uniform(0.9, 1.1, (px, px, 1)) ** 0.3
    img[(fx < 0.05)] *= 0.6
    return np.clip(img, 0, 255).astype(np.uint8)


def _poly(parent: etree._Element, pid: str, ring: npt.NDArray[np.float64]) -> None:
    poly = etree.SubElement(parent, _q(GML, "Polygon"))
    poly.set(_q(GML, "id"), pid)
    lr = etree.SubElement(etree.SubElement(poly, _q(GML, "exterior")), _q(GML, "LinearRing"))
    lr.set(_q(GML, "id"), pid + "_r")
    closed = np.vstack([ring, ring[:1]])
    etree.SubElement(lr, _q(GML, "posList"), srsDimension="3").text = " ".join(f"{v:.3f}" for v in closed.ravel())


def _house_surfaces(h: TexturedHouse, z0: float) -> list[tuple[str, str, npt.NDArray[np.float64],
                                                               npt.NDArray[np.float64] | None]]:
    """(kind, image key, ring (K, 3), uv (K, 2)) of every surface, counter-clockwise from outside."""
    x0, x1, y0, y1 = h.x - h.width / 2, h.x + h.width / 2, h.y - h.depth / 2, h.y + h.depth / 2
    ze, zr = z0 + h.eave, z0 + h.eave + (h.ridge_m if h.gable else 0.0)
    corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    out: list[tuple[str, str, npt.NDArray[np.float64], npt.NDArray[np.float64] | None]] = []
    out.append(("GroundSurface", "", np.array([(x, y, z0) for x, y in corners[::-1]]), None))
    # CityGML texture coordinates: (0, 0) is the image's lower left corner, so the eaves get v = 1.
    wall_uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    for k in range(4):
        (ax, ay), (bx, by) = corners[k], corners[(k + 1) % 4]
        out.append(("WallSurface", "facade", np.array([(ax, ay, z0), (bx, by, z0), (bx, by, ze), (ax, ay, ze)]),
                    wall_uv))
    if not h.gable:
        out.append(("RoofSurface", "roof", np.array([(x, y, ze) for x, y in corners]),
                    wall_uv))
        return out
    ym = h.y  # ridge along x at the middle of the depth; gable triangles on the east and west walls
    out.append(("RoofSurface", "roof", np.array([(x0, y0, ze), (x1, y0, ze), (x1, ym, zr), (x0, ym, zr)]),
                wall_uv))
    out.append(("RoofSurface", "roof", np.array([(x1, y1, ze), (x0, y1, ze), (x0, ym, zr), (x1, ym, zr)]),
                wall_uv))
    gable_uv = np.array([[0, 0], [1, 0], [0.5, 1]], float)
    out.append(("WallSurface", "facade", np.array([(x1, y0, ze), (x1, y1, ze), (x1, ym, zr)]), gable_uv))
    out.append(("WallSurface", "facade", np.array([(x0, y1, ze), (x0, y0, ze), (x0, ym, zr)]), gable_uv))
    return out


def make_textured_city(out_dir: str | os.PathLike[str], buildings: int = 5000, seed: int = 7, *,
                       image_px: int = 256, spacing_m: float = 24.0, ground_z: float = 100.0,
                       progress: bool = True) -> TexturedCity:
    """Write ``textured.gml`` and ``textures/*.jpg`` into ``out_dir``.

    Parameters
    ----------
    out_dir
        Output folder (created).
    buildings
        Number of houses, on a square grid ``spacing_m`` apart.
    seed
        Seed of every random choice.
    image_px
        Side of each façade and roof image in pixels.
    progress
        A progress bar on stderr for 200 houses or more (the command line's ``--quiet`` turns it off).

    Returns
    -------
    TexturedCity

    Examples
    --------
    >>> import tempfile
    >>> city = make_textured_city(tempfile.mkdtemp(), buildings=2, image_px=32)
    >>> len(city.houses), sorted(p.name for p in (city.path.parent / "textures").iterdir())[:2]
    (2, ['BLDG_T0000_facade.jpg', 'BLDG_T0000_roof.jpg'])
    """
    if buildings < 1 or image_px < 8 or image_px > 4096:
        raise CitylodError(f"need at least one building and 8..4096 px images, got {buildings}, {image_px}")
    out = Path(out_dir)
    tex = out / "textures"
    try:
        tex.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create the output folder ({exc.strerror})", out) from exc
    rng = np.random.default_rng(seed)
    cols = int(np.ceil(np.sqrt(buildings)))
    root = etree.Element(_q(CORE, "CityModel"), nsmap=_NSMAP)
    etree.SubElement(root, _q(GML, "name")).text = f"citylod textured sample ({buildings} houses, seed {seed})"
    houses = []
    app = etree.Element(_q(APP, "Appearance"))
    etree.SubElement(app, _q(APP, "theme")).text = "rgbTexture"
    from tqdm import tqdm

    for i in tqdm(range(buildings), desc="textured houses", unit="house", disable=not progress or buildings < 200):
        r, c = divmod(i, cols)
        hid = f"BLDG_T{i:04d}"
        h = TexturedHouse(
            id=hid, x=ORIGIN[0] + c * spacing_m + float(rng.uniform(-2, 2)),
            y=ORIGIN[1] + r * spacing_m + float(rng.uniform(-2, 2)),
            width=float(rng.uniform(9, 16)), depth=float(rng.uniform(8, 13)), storeys=int(rng.integers(1, 7)),
            gable=bool(rng.random() < 0.7), ridge_m=float(rng.uniform(3, 5)),
            facade=f"textures/{hid}_facade.jpg", roof=f"textures/{hid}_roof.jpg")
        houses.append(h)
        for key, img in (("facade", _facade_image(rng, h.storeys, image_px)), ("roof", _roof_image(rng, image_px))):
            atomic_write_bytes(out / getattr(h, key), encode_image(img, "jpg", 85))
        bld = etree.SubElement(etree.SubElement(root, _q(CORE, "cityObjectMember")), _q(BLDG, "Building"))
        bld.set(_q(GML, "id"), hid)
        etree.SubElement(bld, _q(GML, "name")).text = f"House {i}"
        etree.SubElement(bld, _q(BLDG, "function")).text = "1000"
        etree.SubElement(bld, _q(BLDG, "measuredHeight"), uom="m").text = f"{h.eave + (h.ridge_m if h.gable else 0):.2f}"
        etree.SubElement(bld, _q(BLDG, "storeysAboveGround")).text = str(h.storeys)
        targets: dict[str, list[tuple[str, npt.NDArray[np.float64]]]] = {"facade": [], "roof": []}
        for k, (kind, image, ring, uv) in enumerate(_house_surfaces(h, ground_z)):
            pid = f"{hid}_p{k}"
            surf = etree.SubElement(etree.SubElement(bld, _q(BLDG, "boundedBy")), _q(BLDG, kind))
            ms = etree.SubElement(etree.SubElement(surf, _q(BLDG, "lod2MultiSurface")), _q(GML, "MultiSurface"))
            _poly(etree.SubElement(ms, _q(GML, "surfaceMember")), pid, ring)
            if image and uv is not None:
                targets[image].append((pid, uv))
        for key, (rgb, tlist) in (("facade", ("0.85 0.82 0.75", targets["facade"])),
                                  ("roof", ("0.62 0.30 0.22", targets["roof"]))):
            pt = etree.SubElement(etree.SubElement(app, _q(APP, "surfaceDataMember")), _q(APP, "ParameterizedTexture"))
            etree.SubElement(pt, _q(APP, "imageURI")).text = getattr(h, key)
            etree.SubElement(pt, _q(APP, "wrapMode")).text = "none"
            for pid, uv in tlist:
                t = etree.SubElement(pt, _q(APP, "target"), uri=f"#{pid}")
                tcl = etree.SubElement(t, _q(APP, "TexCoordList"))
                closed = np.vstack([uv, uv[:1]])
                etree.SubElement(tcl, _q(APP, "textureCoordinates"), ring=f"#{pid}_r").text = " ".join(
                    f"{v:g}" for v in closed.ravel())
            mat = etree.SubElement(etree.SubElement(app, _q(APP, "surfaceDataMember")), _q(APP, "X3DMaterial"))
            etree.SubElement(mat, _q(APP, "diffuseColor")).text = rgb
            for pid, _ in tlist:
                etree.SubElement(mat, _q(APP, "target")).text = f"#{pid}"
    etree.SubElement(root, _q(APP, "appearanceMember")).append(app)
    xs = [h.x for h in houses]
    ys = [h.y for h in houses]
    env = etree.Element(_q(GML, "Envelope"), srsName=SRS_NAME, srsDimension="3")
    etree.SubElement(env, _q(GML, "lowerCorner")).text = f"{min(xs) - 10:.3f} {min(ys) - 10:.3f} {ground_z:.3f}"
    etree.SubElement(env, _q(GML, "upperCorner")).text = f"{max(xs) + 10:.3f} {max(ys) + 10:.3f} {ground_z + 30:.3f}"
    bounded = etree.Element(_q(GML, "boundedBy"))
    bounded.append(env)
    root.insert(1, bounded)  # after gml:name, as the schema orders them
    path = out / "textured.gml"
    atomic_write(path, lambda p: etree.ElementTree(root).write(str(p), xml_declaration=True, encoding="UTF-8"))
    return TexturedCity(path, houses, image_px)
