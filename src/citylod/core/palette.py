"""The one ASPRS classification palette, shared by what builds tiles and what draws them.

Coarse point-cloud nodes bake class colours into their plane-quad textures (:mod:`citylod.lod.build.planes`),
point tiles of clouds without RGB carry the same colours for other 3D Tiles clients, and the renderer colours
points by class (:mod:`citylod.render.colors`): with one table, a class looks the same at every level and in
every client. Pure numpy.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

# ASPRS LAS 1.4 standard classes (R14 table 17); colours as in common viewers (CloudCompare, Potree).
_ASPRS = {
    0: (180, 180, 180),  # created, never classified
    1: (200, 200, 200),  # unclassified
    2: (166, 118, 70),  # ground
    3: (144, 238, 144),  # low vegetation
    4: (60, 179, 60),  # medium vegetation
    5: (0, 110, 0),  # high vegetation
    6: (220, 60, 50),  # building
    7: (255, 0, 255),  # low point (noise)
    8: (255, 255, 0),  # model key / reserved
    9: (40, 110, 230),  # water
    10: (150, 90, 40),  # rail
    11: (90, 90, 90),  # road surface
    12: (255, 200, 0),  # overlap / reserved
    13: (250, 250, 120),  # wire guard
    14: (250, 220, 80),  # wire conductor
    15: (200, 120, 250),  # transmission tower
    16: (120, 250, 250),  # wire connector
    17: (120, 120, 200),  # bridge deck
    18: (255, 0, 0),  # high noise
}

#: (256, 3) uint8 sRGB colour of each ASPRS class code; user-defined classes (19+) one visible pink.
ASPRS_CLASS_RGB: npt.NDArray[np.uint8] = np.full((256, 3), 255, dtype=np.uint8)
ASPRS_CLASS_RGB[19:] = (255, 160, 200)
for _code, _rgb in _ASPRS.items():
    ASPRS_CLASS_RGB[_code] = _rgb
ASPRS_CLASS_RGB[26] = _ASPRS[17]  # AHN (Netherlands) bridge decks, as class 17
ASPRS_CLASS_RGB.setflags(write=False)

__all__ = ["ASPRS_CLASS_RGB"]
