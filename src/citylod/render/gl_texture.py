"""Rewrite a texture that changes every few frames, with its mip chain, straight into GL.

Why: the far field (:mod:`citylod.render.slf`) writes a new 64² texture into every cell whose view direction
moved, every frame of a moving view. Through VTK (``vtkTexture.Modified()``) each such write is a
``glTexImage2D`` and a ``glGenerateMipmap``, and on Mesa's llvmpipe the mip generation is a blit per level,
each a pass of the rasteriser: 0.35–0.55 ms a texture, 8–14 ms for the 25 cells of the whole-city view,
against 0.01 ms for the upload itself (docs/PERFORMANCE_LOG.md). The chain of a 64² image costs microseconds
on the CPU, so :class:`TextureWriter` averages it there (2 × 2 boxes, as ``glGenerateMipmap`` of a
power-of-two texture does; :func:`citylod.lod.kernels.slf.mip_levels`) and writes every level into the existing texture with ``glTexSubImage2D``.

How it stays in step with VTK: a texture is first loaded by VTK (``vtkOpenGLTexture.Load``: allocation, its
own mip chain, sampler state), and again whenever VTK would reload it (the texture or its image changed
under VTK's eyes: another size, another anisotropy); right after such a load the writer overwrites the
whole chain, so a texture's levels are always the writer's, however it got there. The image VTK holds is
written in place too, so a reload by VTK (a new GL context) shows the same picture. The GL entry points come
from glvnd's ``libOpenGL``, which dispatches to the context current in the thread (the EGL context of an
off-screen window, the GLX context of the application's window). Where that is not available (no glvnd, no
current context, a pixel-unpack buffer bound, a texture that is not a plain 2D one of the image's size)
:meth:`TextureWriter.write` answers False and the caller falls back to VTK's path.
"""

from __future__ import annotations

import ctypes
from typing import Any

import numpy as np
import numpy.typing as npt

from citylod.lod.kernels.slf import mip_levels

__all__ = ["TextureWriter"]

U8 = npt.NDArray[np.uint8]

_GL_TEXTURE_2D = 0x0DE1
_GL_RGBA = 0x1908
_GL_UNSIGNED_BYTE = 0x1401
_GL_RENDERER = 0x1F01
_GL_UNPACK_ROW_LENGTH = 0x0CF2
_GL_UNPACK_SKIP_ROWS = 0x0CF3
_GL_UNPACK_SKIP_PIXELS = 0x0CF4
_GL_PIXEL_UNPACK_BUFFER_BINDING = 0x88EF

_LIB: list[Any] = []  # [libOpenGL] or [None] once looked up


def _gl() -> Any:
    """glvnd's libOpenGL (never a non-glvnd libGL: without glvnd's dispatch its calls could reach no context)."""
    if not _LIB:
        lib = None
        try:
            lib = ctypes.CDLL("libOpenGL.so.0")
        except OSError:
            pass
        if lib is not None:
            lib.glGetString.restype = ctypes.c_char_p
            lib.glGetString.argtypes = [ctypes.c_uint]
            lib.glGetIntegerv.argtypes = [ctypes.c_uint, ctypes.POINTER(ctypes.c_int)]
            lib.glGetError.restype = ctypes.c_uint
            lib.glTexSubImage2D.argtypes = [ctypes.c_uint, ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_int,
                                            ctypes.c_int, ctypes.c_uint, ctypes.c_uint, ctypes.c_void_p]
        _LIB.append(lib)
    return _LIB[0]


def _int(gl: Any, name: int) -> int:
    v = ctypes.c_int(0)
    gl.glGetIntegerv(name, ctypes.byref(v))
    return int(v.value)


class TextureWriter:
    """Writes images into VTK textures with a CPU mip chain (see the module docstring). One per window:
    call :meth:`write` with that window's GL context current (inside its render, or its context guard)."""

    def __init__(self) -> None:
        self._loaded: dict[int, int] = {}  # id(texture) -> its and its image's MTime at the writer's last load
        self._ok: bool | None = None
        self.writes = 0  #: textures written directly (tests and benchmarks read it)

    def _available(self) -> bool:
        if self._ok is None:
            gl = _gl()
            self._ok = bool(gl is not None and gl.glGetString(_GL_RENDERER))  # NULL: no context reachable
        return self._ok

    def write(self, tex: Any, rgb: U8, renderer: Any) -> bool:
        """Put ``rgb`` (n, n, 3), row 0 the top, into ``tex``, whose input image must already hold it (VTK's
        row order, written in place, not marked modified); False where this cannot be done here (the caller
        then marks the image modified and VTK uploads it)."""
        n = rgb.shape[0]
        if rgb.shape != (n, n, 3) or n & (n - 1) or not tex.GetMipmap() or not self._available():
            return False
        gl = _gl()
        img = tex.GetInput()
        if img is None or tuple(img.GetDimensions()) != (n, n, 1):
            return False
        key = id(tex)
        stamp = max(tex.GetMTime(), img.GetMTime())
        if self._loaded.get(key) != stamp:  # VTK would (re)load it at its next render: load it now
            tex.Load(renderer)
            tex.PostRender(renderer)
            self._loaded[key] = max(tex.GetMTime(), img.GetMTime())
        to = tex.GetTextureObject()
        if (to is None or not to.GetHandle() or to.GetTarget() != _GL_TEXTURE_2D
                or (to.GetWidth(), to.GetHeight()) != (n, n)
                or _int(gl, _GL_PIXEL_UNPACK_BUFFER_BINDING) or _int(gl, _GL_UNPACK_ROW_LENGTH)
                or _int(gl, _GL_UNPACK_SKIP_ROWS) or _int(gl, _GL_UNPACK_SKIP_PIXELS)):
            self._loaded.pop(key, None)
            return False
        levels = mip_levels(np.ascontiguousarray(rgb))  # packed, GL's row order
        while gl.glGetError():  # errors left by others are not this write's
            pass
        to.Activate()
        try:
            k, m, ptr = 0, n, levels.ctypes.data
            while m >= 1:
                gl.glTexSubImage2D(_GL_TEXTURE_2D, k, 0, 0, m, m, _GL_RGBA, _GL_UNSIGNED_BYTE, ptr)
                ptr += m * m * 4
                k, m = k + 1, m // 2
        finally:
            to.Deactivate()
        if gl.glGetError():
            self._loaded.pop(key, None)  # VTK's next load rewrites it whole
            return False
        self.writes += 1
        return True
