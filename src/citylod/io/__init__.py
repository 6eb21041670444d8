"""Readers and writers: rasters, images, LAS/LAZ, CityGML/CityJSON, 3D Tiles, GeoPackage.

io/ imports neither VTK nor Qt; heavy optional libraries are imported inside the reader that needs them.
"""
