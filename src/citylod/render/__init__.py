"""The VTK side: LOD actors, semantic shading, off-screen rendering. No Qt here.

Every VTK import goes through :mod:`citylod.render._vtk`.
"""
