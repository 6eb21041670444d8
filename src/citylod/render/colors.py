"""Colour tables for the renderer: level palette, ASPRS classification, elevation and intensity ramps.

Pure numpy (no VTK): every function maps a whole attribute array to ``(N, 3) uint8`` RGB in one
vectorised lookup, so colouring a tile costs one table index per tile upload, never a Python loop per
point.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from citylod.core.palette import ASPRS_CLASS_RGB

U8 = npt.NDArray[np.uint8]

#: Modes accepted by ``--color-by``.
COLOR_MODES = ("auto", "rgb", "classification", "elevation", "intensity", "level")

# Tableau-10: distinct hues for consecutive levels, so a crack between two levels is easy to see.
LEVEL_PALETTE = np.array(
    [[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189],
     [140, 86, 75], [227, 119, 194], [127, 127, 127], [188, 189, 34], [23, 190, 207]], dtype=np.uint8)

#: ASPRS class colours: the table the point builder bakes into quad textures too (one look at every level).
CLASSIFICATION_PALETTE = ASPRS_CLASS_RGB

# A perceptually ordered ramp (viridis anchors), interpolated to 256 entries once at import.
_VIRIDIS = np.array([[68, 1, 84], [71, 44, 122], [59, 81, 139], [44, 113, 142], [33, 144, 141],
                     [39, 173, 129], [92, 200, 99], [170, 220, 50], [253, 231, 37]], dtype=np.float64)
ELEVATION_RAMP = np.stack(
    [np.interp(np.linspace(0, 1, 256), np.linspace(0, 1, len(_VIRIDIS)), _VIRIDIS[:, c]) for c in range(3)],
    axis=1).round().astype(np.uint8)


def level_color(level: int) -> tuple[float, float, float]:
    """RGB in [0, 1] of a tile level (the debug colouring)."""
    r, g, b = LEVEL_PALETTE[int(level) % len(LEVEL_PALETTE)]
    return r / 255.0, g / 255.0, b / 255.0


def classification_rgb(classification: npt.ArrayLike) -> U8:
    """ASPRS classification codes (N,) to RGB (N, 3) uint8."""
    codes = np.asarray(classification).astype(np.uint8, copy=False)
    return CLASSIFICATION_PALETTE[codes]


def ramp_rgb(values: npt.ArrayLike, lo: float, hi: float, ramp: U8 = ELEVATION_RAMP) -> U8:
    """Values (N,) mapped linearly from [lo, hi] onto ``ramp`` (256, 3); outside values clamp."""
    v = np.asarray(values, dtype=np.float64)
    span = hi - lo if hi > lo else 1.0
    idx = np.clip((v - lo) * (255.0 / span), 0, 255).astype(np.intp)
    return ramp[idx]


def intensity_rgb(intensity: npt.ArrayLike, lo: float, hi: float) -> U8:
    """Intensity (N,) as grey (N, 3) uint8 between ``lo`` and ``hi`` (e.g. the 2nd and 98th percentile)."""
    v = np.asarray(intensity, dtype=np.float64)
    span = hi - lo if hi > lo else 1.0
    g = np.clip((v - lo) * (255.0 / span), 0, 255).astype(np.uint8)
    return np.repeat(g[:, None], 3, axis=1)
