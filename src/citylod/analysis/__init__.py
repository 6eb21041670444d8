"""Analyses over the data citylod shows: flood scenarios (:mod:`.flood`) and the polygon layer (:mod:`.polygons`).

Above semantics (it reads city stores), below render; no VTK, no Qt.
"""
