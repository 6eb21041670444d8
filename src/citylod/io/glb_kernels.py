"""Compiled encoding of a point tile's vertex attributes for glb (what :func:`citylod.io.tiles3d.content.glb_buffer`
calls for point content).

Why compiled: a point build encodes its tiles on two threads of one process. Encoded with numpy (the axis
turn to y-up, sRGB to linear colour, the padding of RGB16, uint16 and uint8 attributes to multiples of 4 bytes,
the position min/max), every pass holds the GIL, which kept the other build thread waiting; this one pass runs
without the GIL. No library writes glTF vertex buffers from
numpy columns in one pass (pygltflib and trimesh assemble them with numpy as the code this replaces did).

Every attribute is in its own buffer view: positions tightly packed float32, the others padded with zeros to
a stride that is a multiple of 4 bytes (glTF 2.0 §3.6.2.4).

Imported only when point content is encoded, so reading tiles does not start numba.
"""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

from citylod.core.jit import defer_blas_probe

defer_blas_probe()  # before any kernel loads: numba starts without importing scipy.linalg


@numba.njit(cache=True, nogil=True)
def point_vertex_columns(pos: npt.NDArray[np.float32], rgb: npt.NDArray[np.uint8], rgb_lut: npt.NDArray[np.uint16],
                         intensity: npt.NDArray[np.uint16], classification: npt.NDArray[np.uint8],
                         return_number: npt.NDArray[np.uint8], pos_out: npt.NDArray[np.float32],
                         rgb_out: npt.NDArray[np.uint16], intensity_out: npt.NDArray[np.uint16],
                         classification_out: npt.NDArray[np.uint8], return_out: npt.NDArray[np.uint8],
                         lo: npt.NDArray[np.float32], hi: npt.NDArray[np.float32]) -> None:  # pragma: no cover
    """Fill the glb columns of ``n`` points in one pass.

    ``pos`` (n, 3) z-up positions become ``pos_out`` (n, 3) in glTF's y-up axes, (x, z, −y), with their
    per-axis minimum and maximum in ``lo`` / ``hi`` (3,). Each of the other inputs, when it has n rows
    (an absent attribute is passed with 0 rows and its output is not touched), is copied into its output
    padded with zeros to a multiple of 4 bytes a point. ``rgb`` sRGB bytes go through ``rgb_lut`` (256,) into
    ``rgb_out`` (n, 4) uint16 (glTF colours are linear: :mod:`citylod.io.tiles3d.colour`); ``intensity_out`` (n, 2) uint16,
    ``classification_out`` and ``return_out`` (n, 4) uint8.
    """
    n = pos.shape[0]
    has_rgb = rgb.shape[0] == n
    has_int = intensity.shape[0] == n
    has_cls = classification.shape[0] == n
    has_ret = return_number.shape[0] == n
    for a in range(3):
        lo[a] = np.inf
        hi[a] = -np.inf
    for i in range(n):
        x, y, z = pos[i, 0], pos[i, 2], -pos[i, 1]
        pos_out[i, 0] = x
        pos_out[i, 1] = y
        pos_out[i, 2] = z
        lo[0] = min(lo[0], x)
        lo[1] = min(lo[1], y)
        lo[2] = min(lo[2], z)
        hi[0] = max(hi[0], x)
        hi[1] = max(hi[1], y)
        hi[2] = max(hi[2], z)
        if has_rgb:
            rgb_out[i, 0] = rgb_lut[rgb[i, 0]]
            rgb_out[i, 1] = rgb_lut[rgb[i, 1]]
            rgb_out[i, 2] = rgb_lut[rgb[i, 2]]
            rgb_out[i, 3] = 0
        if has_int:
            intensity_out[i, 0] = intensity[i]
            intensity_out[i, 1] = 0
        if has_cls:
            classification_out[i, 0] = classification[i]
            classification_out[i, 1] = 0
            classification_out[i, 2] = 0
            classification_out[i, 3] = 0
        if has_ret:
            return_out[i, 0] = return_number[i]
            return_out[i, 1] = 0
            return_out[i, 2] = 0
            return_out[i, 3] = 0


__all__ = ["point_vertex_columns"]
