"""Level-of-detail builders and selection: quadtree (DSM), octree (points), TIN kernels, selection, cache.

lod/ imports neither VTK nor Qt, so builds run on Dask workers with no display.
"""
