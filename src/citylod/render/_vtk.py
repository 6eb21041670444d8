"""The one module of citylod that imports VTK (pyvista's ``plotting/_vtk.py`` pattern).

Everything in :mod:`citylod.render` takes its VTK classes from here, so that the set of VTK modules loaded
is known (importing ``vtkmodules.vtkRenderingOpenGL2`` registers the OpenGL factory overrides) and so that
the rest of citylod imports without VTK. No Qt here.

Off-screen rendering without a display
--------------------------------------
The pip VTK wheel (9.4 and later) is built with EGL and OSMesa support beside X. A plain
``vtkRenderWindow()`` tries X first and, with no ``DISPLAY``, logs a "bad X server connection" warning
before falling back to EGL. :func:`offscreen_window` therefore creates a ``vtkEGLRenderWindow`` directly:
it works with and without a display (on this project's machines through Mesa's llvmpipe, the EGL
"surfaceless" platform). When EGL cannot make a context it tries OSMesa (``vtkOSOpenGLRenderWindow``, needs
``libOSMesa``, which Debian does not install by default), then an X window kept off screen (works under
``xvfb-run``). The choice is logged in :data:`WINDOW_BACKEND`.
"""

from __future__ import annotations

import os

# Importing the OpenGL2 module registers the object factory overrides (vtkOpenGLActor, ...).
import vtkmodules.vtkRenderingOpenGL2  # noqa: F401
from vtkmodules.util.misc import calldata_type
from vtkmodules.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray, vtk_to_numpy
from vtkmodules.util.vtkConstants import VTK_FLOAT, VTK_OBJECT
from vtkmodules.vtkCommonCore import (
    VTK_UNSIGNED_CHAR,
    vtkBitArray,
    vtkCommand,
    vtkDoubleArray,
    vtkFloatArray,
    vtkLogger,
    vtkObject,
    vtkPoints,
    vtkUnsignedCharArray,
)
from vtkmodules.vtkCommonDataModel import (
    vtkCellArray,
    vtkImageData,
    vtkMultiBlockDataSet,
    vtkPlane,
    vtkPlaneCollection,
    vtkPolyData,
)
from vtkmodules.vtkCommonMath import vtkMatrix4x4
from vtkmodules.vtkFiltersCore import vtkImplicitPolyDataDistance, vtkTriangleFilter
from vtkmodules.vtkFiltersHybrid import vtkRenderLargeImage
from vtkmodules.vtkFiltersSources import vtkRegularPolygonSource
from vtkmodules.vtkIOCore import vtkMemoryResourceStream
from vtkmodules.vtkIOImage import vtkImageReader2, vtkJPEGReader, vtkPNGReader, vtkPNGWriter
from vtkmodules.vtkRenderingCore import (
    vtkActor,
    vtkActor2D,
    vtkCamera,
    vtkCompositeDataDisplayAttributes,
    vtkCompositePolyDataMapper,
    vtkGlyph3DMapper,
    vtkLight,
    vtkPolyDataMapper,
    vtkPolyDataMapper2D,
    vtkProperty,
    vtkRenderer,
    vtkRenderWindow,
    vtkTextActor,
    vtkTexture,
    vtkWindowToImageFilter,
)
from vtkmodules.vtkRenderingOpenGL2 import (
    vtkEDLShading,
    vtkEGLRenderWindow,
    vtkOpenGLRenderer,
    vtkOpenGLTexture,
    vtkOSOpenGLRenderWindow,
    vtkOverlayPass,
    vtkRenderPassCollection,
    vtkRenderStepsPass,
    vtkSequencePass,
    vtkTextureObject,
    vtkXOpenGLRenderWindow,
)

__all__ = [
    "VTK_FLOAT",
    "VTK_OBJECT",
    "VTK_UNSIGNED_CHAR",
    "WINDOW_BACKEND",
    "calldata_type",
    "numpy_to_vtk",
    "numpy_to_vtkIdTypeArray",
    "offscreen_window",
    "vtkActor",
    "vtkActor2D",
    "vtkBitArray",
    "vtkCamera",
    "vtkCellArray",
    "vtkCommand",
    "vtkCompositeDataDisplayAttributes",
    "vtkCompositePolyDataMapper",
    "vtkDoubleArray",
    "vtkEDLShading",
    "vtkFloatArray",
    "vtkGlyph3DMapper",
    "vtkImageData",
    "vtkImageReader2",
    "vtkImplicitPolyDataDistance",
    "vtkJPEGReader",
    "vtkLight",
    "vtkMatrix4x4",
    "vtkMemoryResourceStream",
    "vtkMultiBlockDataSet",
    "vtkOpenGLRenderer",
    "vtkOpenGLTexture",
    "vtkOverlayPass",
    "vtkPNGReader",
    "vtkPNGWriter",
    "vtkPlane",
    "vtkPlaneCollection",
    "vtkPoints",
    "vtkPolyData",
    "vtkPolyDataMapper",
    "vtkPolyDataMapper2D",
    "vtkProperty",
    "vtkRegularPolygonSource",
    "vtkRenderLargeImage",
    "vtkRenderPassCollection",
    "vtkRenderStepsPass",
    "vtkRenderWindow",
    "vtkRenderer",
    "vtkSequencePass",
    "vtkTextActor",
    "vtkTexture",
    "vtkTextureObject",
    "vtkTriangleFilter",
    "vtkUnsignedCharArray",
    "vtkWindowToImageFilter",
    "vtk_to_numpy",
]

#: Which window class :func:`offscreen_window` ended up with ("egl", "osmesa" or "x"); None before the first.
WINDOW_BACKEND: str | None = None


def _quiet_vtk_warnings() -> None:
    # VTK prints fallback warnings (X, OSMesa) through vtkLogger and the output window; citylod reports
    # its own errors, so keep stderr readable for users of the command line.
    vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_ERROR)
    vtkObject.GlobalWarningDisplayOff()


def _usable(window: vtkRenderWindow) -> bool:
    from citylod.render.gl_context import guard

    window.SetSize(2, 2)
    with guard(window):  # not into a PyVista window's GLX context, and none left current after
        try:
            window.Render()
        except Exception:  # pragma: no cover - depends on the machine's GL stack
            return False
        return bool(window.SupportsOpenGL())


def offscreen_window(width: int, height: int) -> vtkRenderWindow:
    """A render window that draws off screen, with or without an X display.

    Parameters
    ----------
    width, height
        Size in pixels.

    Returns
    -------
    vtkRenderWindow
        An EGL window where EGL works, else OSMesa, else an X window with off-screen rendering.
    """
    global WINDOW_BACKEND
    _quiet_vtk_warnings()
    order = {"egl": 0, "osmesa": 1, "x": 2}
    forced = os.environ.get("CITYLOD_GL_BACKEND", "").lower()
    candidates = sorted(order, key=lambda k: (k != forced, order[k]))
    if WINDOW_BACKEND is not None:  # the first success decides for the process
        candidates = [WINDOW_BACKEND]
    for name in candidates:
        if name == "x" and not os.environ.get("DISPLAY"):
            continue
        cls = {"egl": vtkEGLRenderWindow, "osmesa": vtkOSOpenGLRenderWindow, "x": vtkXOpenGLRenderWindow}[name]
        window = cls()
        window.SetOffScreenRendering(1)
        if WINDOW_BACKEND is None and not _usable(window):
            window.Finalize()
            continue
        WINDOW_BACKEND = name
        window.SetSize(int(width), int(height))
        window.SetMultiSamples(0)  # depth must be exact per pixel; MSAA would blend silhouettes
        return window
    from citylod.core.errors import CitylodError

    raise CitylodError("no OpenGL context for off-screen rendering: EGL, OSMesa and X all failed "
                       "(install Mesa's libegl1/libgl1-mesa-dri, or run under xvfb-run)")
