"""Generated LAS/LAZ clouds shared by test_points.py and test_las.py (helpers only, no tests here)."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pyproj

ROOF_NORMAL = np.array([0.0, -np.sin(np.radians(30)), np.cos(np.radians(30))])
WALL_NORMAL = np.array([1.0, 0.0, 0.0])
X0, Y0 = 85_000.0, 447_000.0


def make_cloud(path: Path, *, n_terrain: int = 60_000, seed: int = 3, rgb: bool = True,
               crs: pyproj.CRS | str | None = "EPSG:28992") -> np.ndarray:
    """Write a LAZ/LAS cloud and return its points as an (N, 6) float64 array (x, y, z, intensity, class, rn)."""
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(0, 100, n_terrain), rng.uniform(0, 100, n_terrain)
    z = 2 * np.sin(x / 15) + 1.5 * np.cos(y / 11) + rng.normal(0, 0.02, n_terrain)
    nr = 15_000  # a 30° roof, 20 m × 12 m, at 10–17 m
    rx, ry = rng.uniform(40, 60, nr), rng.uniform(40, 52, nr)
    rz = 10 + np.tan(np.radians(30)) * (ry - 40) + rng.normal(0, 0.01, nr)
    nw = 10_000  # a wall in the plane x = 70, 25 m × 9 m
    wx, wy, wz = 70 + rng.normal(0, 0.01, nw), rng.uniform(20, 45, nw), rng.uniform(0, 9, nw)
    nn = 2_000  # scattered noise
    nx, ny, nz = rng.uniform(0, 100, nn), rng.uniform(0, 100, nn), rng.uniform(0, 30, nn)
    xs = np.concatenate([x, rx, wx, nx]) + X0
    ys = np.concatenate([y, ry, wy, ny]) + Y0
    zs = np.concatenate([z, rz, wz, nz])
    n = len(xs)
    hdr = laspy.LasHeader(point_format=3 if rgb else 1, version="1.2")
    hdr.scales = np.array([0.001, 0.001, 0.001])
    hdr.offsets = np.array([X0, Y0, 0.0])
    if crs is not None:
        hdr.add_crs(pyproj.CRS.from_user_input(crs))
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = xs, ys, zs
    las.intensity = rng.integers(0, 4000, n).astype(np.uint16)
    las.classification = np.concatenate([np.full(n_terrain, 2), np.full(nr + nw, 6), np.full(nn, 1)]).astype(np.uint8)
    las.return_number = rng.integers(1, 4, n).astype(np.uint8)
    las.number_of_returns = np.full(n, 3, np.uint8)
    if rgb:
        las.red = rng.integers(0, 65536, n).astype(np.uint16)
        las.green = rng.integers(0, 65536, n).astype(np.uint16)
        las.blue = rng.integers(0, 65536, n).astype(np.uint16)
    las.write(path)
    back = laspy.read(path)  # quantised coordinates, as a reader sees them
    return np.stack([back.x, back.y, back.z, back.intensity, back.classification, back.return_number], axis=1)
