"""Small inputs written by code for the hostile-input, kill and fuzz tests (EPSG:25832, near 500000, 5400000)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt

CORNER = (500000.0, 5400000.0, 0.0)


def write_las(path: Path, n: int, *, x0: float = CORNER[0], y0: float = CORNER[1], extent: float = 20.0,
              z: npt.NDArray[np.float64] | None = None, point_format: int = 1, seed: int = 1) -> Path:
    """A LAS 1.4 (or LAZ, by suffix) of ``n`` points uniform in [x0, x0 + extent] x [y0, y0 + extent], with a
    CRS; heights ``z`` (default uniform 0..12 m)."""
    import laspy
    import pyproj

    rng = np.random.default_rng(seed)
    h = laspy.LasHeader(point_format=point_format, version="1.4")
    h.offsets = np.array(CORNER)
    h.scales = np.array([0.01, 0.01, 0.01])
    h.add_crs(pyproj.CRS.from_epsg(25832))
    las = laspy.LasData(h)
    las.x = x0 + rng.uniform(0, extent, n)
    las.y = y0 + rng.uniform(0, extent, n)
    las.z = rng.uniform(0, 12, n) if z is None else z(np.asarray(las.x)) if callable(z) else z
    las.write(path)
    return path
