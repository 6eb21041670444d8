"""Keep citylod's EGL contexts apart from the GLX contexts of the user's windows in the same thread.

Why this exists
---------------
With libglvnd (every current Linux distribution) a thread has at most one current context across the
window-system APIs: ``eglMakeCurrent`` fails with ``EGL_BAD_ACCESS`` while a GLX context is current, and
``glXMakeCurrent`` fails with an X ``BadAccess`` error (which ends the process under Xlib's default
handler) while an EGL context is current. A PyVista plotter (on screen or ``off_screen=True`` under X)
leaves its GLX context current after each render, and VTK's ``vtkEGLRenderWindow`` only warns when its
``eglMakeCurrent`` fails (a warning citylod silences, :mod:`citylod.render._vtk`) and goes on drawing; its
``IsCurrent()`` always answers true. So, with a plotter open, every citylod off-screen renderer silently
drew into the *plotter's* context: its framebuffers, textures and VTK's per-window GL state cache all
landed on one context shared by windows that each believed it owned it, and after an EDL renderer was
opened and closed next to the plotter the next renderer drew only the background. The other way round, a plotter
rendering while citylod's EGL context was still current killed the process with ``BadAccess``.

:class:`ContextGuard` therefore brackets everything citylod does with an EGL window: it releases a GLX
context current in the thread, makes the window's context current, and at the end releases it and makes
current again whatever was current before (the user's GLX context, or another EGL context), so the thread
is left as it was found. :func:`guard` gives each window one guard, so guards taken in different places
(a renderer's frame, an overlay's pick) nest: only the outermost one switches.
"""

from __future__ import annotations

import ctypes
import os
import weakref
from typing import Any

__all__ = ["ContextGuard", "guard"]

_EGL_DRAW, _EGL_READ = 0x3059, 0x305A
_LIBS: dict[str, Any] = {}


def _loaded(names: tuple[str, ...], kind: str) -> Any:
    """The GL library ``kind`` if the process has already loaded it, else None (never loads one: a
    library nobody loaded cannot have a current context)."""
    lib = _LIBS.get(kind)
    if lib is not None:
        return lib
    mode = getattr(os, "RTLD_NOLOAD", 0) | getattr(os, "RTLD_LAZY", 1)
    for name in names:
        try:
            lib = ctypes.CDLL(name, mode=mode)
        except OSError:
            continue
        vp = ctypes.c_void_p
        if kind == "egl":
            lib.eglGetCurrentContext.restype = vp
            lib.eglGetCurrentDisplay.restype = vp
            lib.eglGetCurrentSurface.restype = vp
            lib.eglGetCurrentSurface.argtypes = [ctypes.c_int32]
            lib.eglMakeCurrent.restype = ctypes.c_uint
            lib.eglMakeCurrent.argtypes = [vp, vp, vp, vp]
        else:
            lib.glXGetCurrentContext.restype = vp
            lib.glXGetCurrentDisplay.restype = vp
            lib.glXGetCurrentDrawable.restype = ctypes.c_ulong
            lib.glXGetCurrentReadDrawable.restype = ctypes.c_ulong
            lib.glXMakeContextCurrent.restype = ctypes.c_int
            lib.glXMakeContextCurrent.argtypes = [vp, ctypes.c_ulong, ctypes.c_ulong, vp]
        _LIBS[kind] = lib
        return lib
    return None


def _egl() -> Any:
    return _loaded(("libEGL.so.1", "libEGL.so"), "egl")


def _glx() -> Any:
    # glvnd's libGLX holds the GLX entry points; a non-glvnd libGL has them itself.
    return _loaded(("libGLX.so.0", "libGL.so.1"), "glx")


class ContextGuard:
    """``with guard:`` makes ``window``'s EGL context current for the block and restores the thread's
    previous context after it (see the module docstring). A no-op for windows that are not EGL windows:
    VTK's X window switches GLX contexts itself. Take it through :func:`guard`."""

    def __init__(self, window: Any) -> None:
        self._ref = weakref.ref(window)  # not kept alive by its own entry in _GUARDS
        self.active = bool(window.IsA("vtkEGLRenderWindow"))
        self._depth = 0
        self._glx: tuple[int, int, int, int] | None = None
        self._egl: tuple[int | None, int | None, int | None, int] | None = None

    def __enter__(self) -> ContextGuard:
        self._depth += 1
        if self._depth > 1 or not self.active:
            return self
        self._glx = self._egl = None
        glx = _glx()
        if glx is not None and glx.glXGetCurrentContext():
            self._glx = (glx.glXGetCurrentDisplay(), glx.glXGetCurrentDrawable(),
                         glx.glXGetCurrentReadDrawable(), glx.glXGetCurrentContext())
            glx.glXMakeContextCurrent(self._glx[0], 0, 0, None)
        egl = _egl()
        if egl is not None and egl.eglGetCurrentContext():
            self._egl = (egl.eglGetCurrentDisplay(), egl.eglGetCurrentSurface(_EGL_DRAW),
                         egl.eglGetCurrentSurface(_EGL_READ), egl.eglGetCurrentContext())
        self.window().MakeCurrent()  # a window not yet initialised makes its context current in Render()
        return self

    def __exit__(self, *exc: object) -> None:
        self._depth -= 1
        if self._depth > 0 or not self.active:
            return
        egl = _egl()
        ours = egl.eglGetCurrentContext() if egl is not None else None
        if self._egl is not None and self._egl[3] != ours:
            egl.eglMakeCurrent(*self._egl)  # another EGL context was current: give it back
        else:
            self.window().ReleaseCurrent()  # nothing was, or it was ours, left current by VTK
        if self._glx is not None and not (egl is not None and egl.eglGetCurrentContext()):
            # Only with no EGL context current: otherwise glvnd would answer with an X error.
            glx = _glx()
            glx.glXMakeContextCurrent(*self._glx)
        self._glx = self._egl = None

    def window(self) -> Any:
        return self._ref()


_GUARDS: weakref.WeakKeyDictionary[Any, ContextGuard] = weakref.WeakKeyDictionary()


def guard(window: Any) -> ContextGuard:
    """The one :class:`ContextGuard` of ``window`` (a VTK render window), made on first use."""
    g = _GUARDS.get(window)
    if g is None:
        g = _GUARDS[window] = ContextGuard(window)
    return g
