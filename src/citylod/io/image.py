"""Image encoding and decoding: the one place citylod turns pixels into JPEG/PNG bytes and back.

JPEG and decoding go through OpenImageIO, whose Python API works on files, so they pass through a private
temporary file (tiles are a few hundred kB; about a millisecond). PNG is written by :func:`encode_png`, a
minimal zlib writer: twice as fast as OpenImageIO on the sparse quad atlases, for files no larger. KTX2
textures (glTF's ``KHR_texture_basisu``) are transcoded to RGBA8 by Binomial's Basis Universal transcoder
(:func:`decode_ktx2`, through ``opengl_basisu``), which OpenImageIO does not read.
"""

from __future__ import annotations

import os
import tempfile
import zlib

import numpy as np
import numpy.typing as npt

from citylod.core.errors import InputError


def encode_image(pixels: npt.NDArray[np.uint8], fmt: str = "jpg", quality: int = 88) -> bytes:
    """Encode (H, W, 1|3|4) uint8 pixels, row 0 at the top, as JPEG (``fmt="jpg"``), PNG (``fmt="png"``) or
    WebP (``fmt="webp"``, lossless)."""
    if fmt == "png":
        return encode_png(pixels)
    import OpenImageIO as oiio

    arr = np.ascontiguousarray(pixels, dtype=np.uint8)
    if arr.ndim != 3 or arr.shape[2] not in (1, 3, 4):
        raise ValueError(f"pixels must be (H, W, 1|3|4), got {arr.shape}")
    h, w, c = arr.shape
    spec = oiio.ImageSpec(w, h, c, "uint8")
    if fmt == "jpg":
        spec.attribute("Compression", f"jpeg:{quality}")
    elif fmt == "webp":
        spec.attribute("Compression", "lossless")
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


#: The first 12 bytes of every KTX 2 file (KTX 2.0 specification, section 3.1).
KTX2_MAGIC = b"\xabKTX 20\xbb\r\n\x1a\n"


def decode_ktx2(data: bytes, source: str = "") -> npt.NDArray[np.uint8]:
    """Decode a KTX2 texture with a Basis Universal payload (ETC1S or UASTC, what ``KHR_texture_basisu``
    allows) to (H, W, 3|4) uint8, row 0 at the top: its largest mip level, transcoded to RGBA8 (the alpha
    channel kept only where the file has one). The values are the file's (sRGB for a colour texture), as a
    PNG of the same image would decode.

    Raises
    ------
    InputError
        If the bytes are not such a file (truncated, corrupt, another vkFormat, a high dynamic range codec).
    """
    import opengl_basisu

    try:
        texture = opengl_basisu.open(bytes(data))
        image = texture.transcode(opengl_basisu.Target.RGBA8, level=0)
    except opengl_basisu.BasisuError as exc:
        raise InputError(f"cannot decode KTX2 texture ({exc})", source) from exc
    pixels = np.asarray(image.data, np.uint8).reshape(image.height, image.width, 4)
    return pixels if texture.has_alpha else np.ascontiguousarray(pixels[:, :, :3])


def decode_image(data: bytes, source: str = "") -> npt.NDArray[np.uint8]:
    """Decode JPEG, PNG, WebP or KTX2 (Basis Universal) bytes to (H, W, C) uint8, row 0 at the top."""
    if data[:12] == KTX2_MAGIC:
        return decode_ktx2(data, source)
    import OpenImageIO as oiio

    suffix = (".png" if data[:8] == b"\x89PNG\r\n\x1a\n" else
              ".webp" if data[:4] == b"RIFF" and data[8:12] == b"WEBP" else ".jpg")
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


_PNG_COLOUR_TYPE = {1: 0, 2: 4, 3: 2, 4: 6}  # channels -> grey, grey+alpha, RGB, RGBA


def encode_png(pixels: npt.NDArray[np.uint8], level: int = 1) -> bytes:
    """PNG bytes of (H, W) or (H, W, 1|2|3|4) uint8 pixels, row 0 at the top.

    Filter 0 on every row and zlib ``level`` 1 by default: on quad atlases (sparse texels, transparent
    gaps) level 1 is 3× faster than level 6 for files within 1 % of the size.

    Examples
    --------
    >>> data = encode_png(np.zeros((2, 3, 4), np.uint8))
    >>> data[:8] == b"\\x89PNG\\r\\n\\x1a\\n", decode_image(data).shape
    (True, (2, 3, 4))
    """
    arr = np.ascontiguousarray(pixels, dtype=np.uint8)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    if arr.ndim != 3 or arr.shape[2] not in _PNG_COLOUR_TYPE or 0 in arr.shape:
        raise ValueError(f"pixels must be (H, W, 1|2|3|4) and non-empty, got {pixels.shape}")
    h, w, c = arr.shape
    raw = np.zeros((h, w * c + 1), np.uint8)
    raw[:, 1:] = arr.reshape(h, w * c)

    def chunk(tag: bytes, data: bytes) -> bytes:
        return len(data).to_bytes(4, "big") + tag + data + zlib.crc32(tag + data).to_bytes(4, "big")

    ihdr = w.to_bytes(4, "big") + h.to_bytes(4, "big") + bytes([8, _PNG_COLOUR_TYPE[c], 0, 0, 0])
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw.tobytes(), level))
            + chunk(b"IEND", b""))


def read_image(path: str | os.PathLike[str]) -> npt.NDArray[np.uint8]:
    """Decode an image file (JPEG, PNG, TIFF, ...) to (H, W, 3) uint8 RGB (grey repeated, alpha dropped)."""
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(str(path))
    pixels = buf.get_pixels(oiio.UINT8)
    if pixels is None or buf.has_error:
        raise InputError(f"cannot decode image ({buf.geterror()})", path)
    arr = np.asarray(pixels, dtype=np.uint8)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    if arr.shape[2] < 3:
        arr = np.repeat(arr[:, :, :1], 3, axis=2)
    return np.ascontiguousarray(arr[:, :, :3])


def resize_image(pixels: npt.NDArray[np.uint8], width: int, height: int) -> npt.NDArray[np.uint8]:
    """(H, W, C) uint8 resampled to (height, width, C) with OpenImageIO's filtered resize (a Lanczos-like
    filter when shrinking, so detail finer than the new texel averages out instead of aliasing)."""
    import OpenImageIO as oiio

    arr = np.ascontiguousarray(pixels, np.uint8)
    h, w, c = arr.shape
    src = oiio.ImageBuf(oiio.ImageSpec(w, h, c, "uint8"))
    src.set_pixels(oiio.ROI(), arr)
    dst = oiio.ImageBufAlgo.resize(src, roi=oiio.ROI(0, int(width), 0, int(height), 0, 1, 0, c))
    return np.asarray(dst.get_pixels(oiio.UINT8), np.uint8).reshape(int(height), int(width), c)
