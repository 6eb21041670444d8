"""A one-box city tileset for the far-field tests: a 10 × 8 × 15 m box with one colour per face on a
60 × 60 m ground (the ground's triangles lie on the terrain plane and only set the field's extent).

Every face is textured from one PNG atlas of solid blocks (citylod draws textured city tiles unlit, so the
geometry's picture holds exactly these colours)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from citylod.io.image import encode_image
from citylod.io.tiles3d import MeshData, TileContent, TileSpec, write_content, write_tileset
from citylod.lod.build.slf import GROUND_RGB

X0, Y0, Z0 = 500_000.0, 5_400_000.0, 100.0
BOX = (np.array([X0 + 25.0, Y0 + 26.0, Z0]), np.array([X0 + 35.0, Y0 + 34.0, Z0 + 15.0]))
#: face colours: roof, south (−y), north (+y), west (−x), east (+x)
ROOF, SOUTH, NORTH, WEST, EAST = (200, 50, 50), (50, 200, 50), (50, 50, 200), (50, 200, 200), (200, 200, 50)


def _quad(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, rgb: tuple[int, int, int]
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.array([a, b, c, d]), np.array([[0, 1, 2], [0, 2, 3]]), np.array([rgb] * 4)


def box_faces() -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    (x0, y0, z0), (x1, y1, z1) = BOX
    return [
        _quad(np.array([x0, y0, z1]), np.array([x1, y0, z1]), np.array([x1, y1, z1]), np.array([x0, y1, z1]), ROOF),
        _quad(np.array([x0, y0, z0]), np.array([x1, y0, z0]), np.array([x1, y0, z1]), np.array([x0, y0, z1]), SOUTH),
        _quad(np.array([x1, y1, z0]), np.array([x0, y1, z0]), np.array([x0, y1, z1]), np.array([x1, y1, z1]), NORTH),
        _quad(np.array([x0, y1, z0]), np.array([x0, y0, z0]), np.array([x0, y0, z1]), np.array([x0, y1, z1]), WEST),
        _quad(np.array([x1, y0, z0]), np.array([x1, y1, z0]), np.array([x1, y1, z1]), np.array([x1, y0, z1]), EAST),
        _quad(np.array([X0, Y0, Z0]), np.array([X0 + 60, Y0, Z0]), np.array([X0 + 60, Y0 + 60, Z0]),
              np.array([X0, Y0 + 60, Z0]), GROUND_RGB),
    ]


def write_box_city(out: Path) -> Path:
    """The tileset (one tile) in EPSG:32632; returns its folder."""
    faces_ = box_faces()
    atlas = np.zeros((8, 8 * 8, 3), np.uint8)  # block k: columns 8k..8k+7
    verts, faces, uvs = [], [], []
    for k, (v, f, c) in enumerate(faces_):
        atlas[:, 8 * k:8 * k + 8] = c[0]
        faces.append(f + sum(len(x) for x in verts))
        verts.append(v)
        uvs.append(np.array([[(8 * k + 2 + 4 * a) / 64.0, 0.25 + 0.5 * b] for a, b in ((0, 0), (1, 0), (1, 1), (0, 1))]))
    v = np.concatenate(verts)
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    content = TileContent([MeshData((v - centre).astype(np.float32), np.concatenate(faces).astype(np.uint32),
                                    uv=np.concatenate(uvs).astype(np.float32), texture=encode_image(atlas, "png"),
                                    name="city_textured")])
    out.mkdir(parents=True, exist_ok=True)
    uri = write_content(out, "0", content)
    write_tileset(out, TileSpec("0", 0, centre, v.min(axis=0), v.max(axis=0), 0.0, uri), "EPSG:32632",
                  extras={"citylod": {"kind": "city"}})
    return out


def ray_colour(qx: np.ndarray, qy: np.ndarray, d: np.ndarray, ground: tuple[int, int, int]) -> np.ndarray:
    """What a viewer far along ``d`` sees at ground points (qx, qy) at Z0: slab intersection of the ray
    q + s·d with the box, the exit point being the surface nearest the viewer. (N, 3) uint8."""
    lo, hi = BOX
    q = np.stack([qx, qy, np.full_like(qx, Z0)], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (lo - q) / d
        t1 = (hi - q) / d
    tlo, thi = np.minimum(t0, t1), np.maximum(t0, t1)
    tlo[:, d == 0] = np.where(((q >= lo) & (q <= hi))[:, d == 0], -np.inf, np.inf)
    thi[:, d == 0] = np.where(((q >= lo) & (q <= hi))[:, d == 0], np.inf, -np.inf)
    enter, leave = tlo.max(axis=1), thi.min(axis=1)
    hit = leave >= np.maximum(enter, 0.0)
    axis = np.argmin(thi, axis=1)  # the slab the ray leaves by
    out = np.empty((len(qx), 3), np.uint8)
    out[:] = ground
    side = {0: (WEST, EAST), 1: (SOUTH, NORTH), 2: (ROOF, ROOF)}
    for a in range(3):
        m = hit & (axis == a)
        out[m] = side[a][1] if d[a] > 0 else side[a][0]
    return out
