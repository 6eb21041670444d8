"""Geometry shared by every layer: boxes, frusta, local frames, cameras, the screen-space error.

core/ imports numpy and the standard library only: no VTK, no Qt, no I/O libraries.
"""
