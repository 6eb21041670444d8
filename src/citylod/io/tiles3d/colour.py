"""sRGB and linear colour for glTF vertex colours.

glTF 2.0 (§3.7.2.1, "COLOR_n") defines vertex colours as *linear* RGB, while LAS RGB, textures and what
citylod draws are sRGB. citylod keeps sRGB uint8 in memory (:class:`~citylod.io.tiles3d.content.PointData`,
:class:`~citylod.io.tiles3d.content.MeshData`) and converts at the file boundary: sRGB → linear when it writes
``COLOR_0``, linear → sRGB when it reads one, so every conformant client shows the colour citylod shows.

Linear values are stored as normalized uint16: the darkest sRGB steps are 1/(255·12.92) ≈ 3.0e-4 apart in
linear light, about 20 uint16 steps, so every 8-bit sRGB value survives the round trip exactly; 8-bit linear
storage would merge the darkest 20 or so values.

The transfer function is IEC 61966-2-1 (sRGB), as the glTF specification quotes it. No VTK and no Qt here.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt


def srgb_to_linear(c: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Linear light in [0, 1] of sRGB values in [0, 1] (IEC 61966-2-1)."""
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """sRGB values in [0, 1] of linear light in [0, 1] (IEC 61966-2-1)."""
    c = np.clip(np.asarray(c, np.float64), 0.0, 1.0)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1.0 / 2.4) - 0.055)


#: sRGB byte -> linear normalized uint16 (what citylod writes into COLOR_0).
SRGB8_TO_LINEAR16: npt.NDArray[np.uint16] = np.round(
    srgb_to_linear(np.arange(256) / 255.0) * 65535.0).astype(np.uint16)
#: sRGB byte -> linear normalized uint8 (palette colours written for other clients only; dark steps merge).
SRGB8_TO_LINEAR8: npt.NDArray[np.uint8] = np.round(srgb_to_linear(np.arange(256) / 255.0) * 255.0).astype(np.uint8)
#: linear normalized uint16 -> sRGB byte (what citylod reads from COLOR_0 of any component type).
LINEAR16_TO_SRGB8: npt.NDArray[np.uint8] = np.round(
    linear_to_srgb(np.arange(65536) / 65535.0) * 255.0).astype(np.uint8)


def linear_colors_to_srgb8(c: np.ndarray) -> npt.NDArray[np.uint8]:
    """sRGB bytes (N, 3 or 4) of a glTF ``COLOR_0`` accessor's values (N,), (N, 3) or (N, 4).

    Float values are linear in [0, 1]; uint8 and uint16 are normalized linear (divided by 255 or 65535).
    Alpha is not gamma-encoded in glTF, so it is only rescaled. A scalar colour becomes grey.

    Examples
    --------
    A yellow field as citylod writes it (linear uint16) and reads it back:

    >>> import numpy as np
    >>> stored = SRGB8_TO_LINEAR16[np.array([[203, 182, 107]])]
    >>> (stored / 65535).round(3)
    array([[0.597, 0.468, 0.147]])
    >>> linear_colors_to_srgb8(stored)
    array([[203, 182, 107]], dtype=uint8)
    """
    c = np.asarray(c)
    if c.dtype.kind == "f":
        lin16 = np.round(np.clip(c, 0.0, 1.0) * 65535.0).astype(np.uint16)
    elif c.dtype == np.uint16:
        lin16 = c
    else:
        lin16 = c.astype(np.uint16) * np.uint16(257)  # 255 -> 65535 exactly
    if lin16.ndim == 1:
        lin16 = lin16[:, None].repeat(3, axis=1)
    out = LINEAR16_TO_SRGB8[lin16]
    if out.shape[1] == 4:
        out[:, 3] = (lin16[:, 3].astype(np.uint32) * 255 + 32767) // 65535
    return out


__all__ = ["LINEAR16_TO_SRGB8", "SRGB8_TO_LINEAR8", "SRGB8_TO_LINEAR16", "linear_colors_to_srgb8", "linear_to_srgb", "srgb_to_linear"]
