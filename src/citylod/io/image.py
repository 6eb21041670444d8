"""Image encoding and decoding through OpenImageIO (textures for tiles).

OpenImageIO's Python API writes to files, so encoding goes through a private temporary file; tiles are small
(a few hundred kB) and this costs about a millisecond.
"""

from __future__ import annotations

import os
import tempfile

import numpy as np
import numpy.typing as npt

from citylod.core.errors import InputError


def encode_image(pixels: npt.NDArray[np.uint8], fmt: str = "jpg", quality: int = 88) -> bytes:
    """Encode (H, W, 3|4) uint8 pixels as JPEG (``fmt="jpg"``) or PNG (``fmt="png"``)."""
    import OpenImageIO as oiio

    arr = np.ascontiguousarray(pixels, dtype=np.uint8)
    if arr.ndim != 3 or arr.shape[2] not in (1, 3, 4):
        raise ValueError(f"pixels must be (H, W, 1|3|4), got {arr.shape}")
    h, w, c = arr.shape
    spec = oiio.ImageSpec(w, h, c, "uint8")
    if fmt == "jpg":
        spec.attribute("Compression", f"jpeg:{quality}")
    buf = oiio.ImageBuf(spec)
    buf.set_pixels(oiio.ROI(), arr)
    fd, tmp = tempfile.mkstemp(suffix="." + fmt)
    os.close(fd)
    try:
        if not buf.write(tmp):
            raise RuntimeError(f"OpenImageIO could not encode {fmt}: {buf.geterror()}")
        with open(tmp, "rb") as f:
            return f.read()
    finally:
        os.unlink(tmp)


def decode_image(data: bytes, source: str = "") -> npt.NDArray[np.uint8]:
    """Decode JPEG/PNG bytes to (H, W, C) uint8."""
    import OpenImageIO as oiio

    suffix = ".png" if data[:8] == b"\x89PNG\r\n\x1a\n" else ".jpg"
    fd, tmp = tempfile.mkstemp(suffix=suffix)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        buf = oiio.ImageBuf(tmp)
        pixels = buf.get_pixels(oiio.UINT8)
        if pixels is None or buf.has_error:
            raise InputError(f"cannot decode image ({buf.geterror()})", source)
        return np.asarray(pixels, dtype=np.uint8)
    finally:
        os.unlink(tmp)
