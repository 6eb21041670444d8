"""The city model every city reader produces, its geometry repairs, and projection to metres.

Geometry is repaired where that is safe (duplicate points dropped, rings closed, holes and shells oriented
by Newell normal and signed volume) and every repair or defect is reported as a warning carrying the object
id. Geographic (degree) input is projected to a metric CRS by :func:`to_metric` before anything metric happens.

No VTK, no Qt, and nothing about proxies or stores (semantics/ does that).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pyproj

from citylod.core.errors import GeoreferenceError
from citylod.io.crs import horizontal_crs, is_geographic, parse_crs, utm_crs_for

F64 = npt.NDArray[np.float64]
Ring = F64  # (K, 3) float64, closed: ring[0] == ring[-1]
Polygon = list[Ring]  # exterior ring first, then holes

__all__ = ["CityModel", "CityObject", "Polygon", "Ring", "open_edge_count", "orient_outward", "repair_polygon",
           "to_metric"]


@dataclass(frozen=True)
class CityObject:
    """One city object in a metric or source CRS.

    Attributes
    ----------
    id
        ``gml:id`` (CityGML) or the CityObjects key (CityJSON).
    type
        Local class name: ``Building``, ``BuildingPart``, ``Road``, ...
    attributes
        Thematic and generic attributes (``name``, ``class``, ``function``, ``usage``, ``measuredHeight``
        (float, m), ``storeysAboveGround`` (int), ``address`` (dict), generic attributes by their name).
    surfaces
        Polygons; each a list of rings, exterior first, each ring (K, 3) float64 and closed.
    lod
        The level of detail the surfaces come from (0..4), -1 without geometry.
    parent
        Id of the parent object (a BuildingPart's Building), or None.
    semantics
        Per surface, its semantic class (``RoofSurface``, ``WallSurface``, ``GroundSurface``, ...) or None;
        same length as ``surfaces``.
    """

    id: str
    type: str
    attributes: dict[str, Any]
    surfaces: list[Polygon]
    lod: int
    parent: str | None = None
    semantics: list[str | None] = field(default_factory=list)

    def points(self) -> F64:
        """All ring vertices, (M, 3) float64 (closing duplicates included)."""
        rings = [r for poly in self.surfaces for r in poly]
        return np.concatenate(rings) if rings else np.zeros((0, 3))


@dataclass(frozen=True)
class CityModel:
    """What a city reader returns: objects, their CRS, and what was repaired or could not be.

    Attributes
    ----------
    objects
        The city objects, parents before their parts.
    crs
        Source CRS (``pyproj.CRS``) or None when the file names none.
    source
        The file read.
    warnings
        ``"<object id>: <message>"`` for each repair and each defect left in place.
    version
        Format and version, e.g. ``"CityGML 2.0"``, ``"CityJSON 1.0"``.
    """

    objects: list[CityObject]
    crs: pyproj.CRS | None
    source: str
    warnings: list[str] = field(default_factory=list)
    version: str = ""


# --------------------------------------------------------------------------------------------------------
# Geometry repair (shared with the CityJSON reader)

def _newell(ring: F64) -> F64:
    """Newell's area vector of a closed ring (K, 3): normal times twice the area, robust for non-planar rings."""
    c = ring - ring[:-1].mean(axis=0)  # centring keeps the cross products small for large coordinates
    a, b = c[:-1], c[1:]
    return 0.5 * np.cross(a, b).sum(axis=0)


def _clean_ring(pts: F64, tol: float, implicit_close: bool = False) -> tuple[F64 | None, list[str]]:
    """Drop non-finite and consecutive duplicate points, close the ring; None when fewer than 3 remain."""
    notes: list[str] = []
    pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
    finite = np.isfinite(pts).all(axis=1)
    if not finite.all():
        notes.append(f"dropped {int((~finite).sum())} non-finite vertices")
        pts = pts[finite]
    if len(pts) == 0:
        return None, notes
    closed_in = len(pts) > 1 and bool(np.all(np.abs(pts[0] - pts[-1]) <= tol))
    if len(pts) > 1:
        # A step of (almost) zero length is a duplicate point; it breaks normals and triangulation.
        step = np.abs(np.diff(pts, axis=0)).max(axis=1)
        keep = np.concatenate([[True], step > tol])
        dups = int((~keep).sum()) - (1 if closed_in else 0)
        if dups > 0:
            notes.append(f"dropped {dups} duplicate consecutive vertices")
        pts = pts[keep]
    if len(pts) > 1 and np.all(np.abs(pts[0] - pts[-1]) <= tol):
        pts = pts[:-1]
    elif not closed_in and not implicit_close:
        notes.append("closed an unclosed ring")
    if len(pts) < 3:
        notes.append(f"dropped a degenerate ring ({len(pts)} distinct vertices)")
        return None, notes
    return np.vstack([pts, pts[:1]]), notes


def repair_polygon(rings: list[F64], *, tol: float = 1e-6, planarity_tol: float = 0.05,
                   implicit_close: bool = False) -> tuple[Polygon | None, list[str]]:
    """Repair one polygon: clean and close its rings, orient holes against the exterior, check planarity.

    Parameters
    ----------
    rings
        Exterior ring first, then holes; each (K, 3) float64, closed or not.
    tol
        Distance (m or source units) below which consecutive vertices are duplicates.
    planarity_tol
        Largest distance (source units) of a vertex from the polygon's plane before it is reported.
    implicit_close
        Rings are closed by definition (CityJSON): closing them is not a repair worth reporting.

    Returns
    -------
    polygon, notes
        The repaired polygon (None if the exterior is degenerate) and what was done or found.
    """
    notes: list[str] = []
    out: Polygon = []
    for i, r in enumerate(rings):
        clean, n = _clean_ring(r, tol, implicit_close)
        notes += n
        if clean is None:
            if i == 0:
                notes.append("dropped a polygon with a degenerate exterior ring")
                return None, notes
            continue
        out.append(clean)
    ext_n = _newell(out[0])
    area = float(np.linalg.norm(ext_n))
    if area <= tol * tol:
        notes.append("dropped a polygon of zero area")
        return None, notes
    unit = ext_n / area
    for j in range(1, len(out)):
        # Holes run against the exterior (ISO 19107); a hole that runs with it is reversed.
        if float(_newell(out[j]) @ unit) > 0:
            out[j] = out[j][::-1].copy()
            notes.append("reversed a hole that ran with its exterior")
    dev = float(np.abs((out[0] - out[0][:-1].mean(axis=0)) @ unit).max())
    if dev > planarity_tol:
        notes.append(f"non-planar polygon ({dev:.3f} off its plane), kept")
    return out, notes


def _fan_volume(polys: list[Polygon]) -> float:
    """Signed volume enclosed by polygons (divergence theorem over fans of the exterior rings minus holes)."""
    if not polys:
        return 0.0
    origin = polys[0][0][0]
    vol = 0.0
    for poly in polys:
        for ring in poly:
            p = ring[:-1] - origin
            if len(p) < 3:
                continue
            a, b, c = p[0], p[1:-1], p[2:]
            vol += float(np.einsum("ij,ij->i", np.broadcast_to(a, b.shape), np.cross(b, c)).sum()) / 6.0
    return vol


def open_edge_count(polys: list[Polygon], tol: float = 1e-3) -> int:
    """Number of undirected edges used once only: 0 for a closed (watertight) shell."""
    edges = []
    for poly in polys:
        for ring in poly:
            edges.append(np.stack([ring[:-1], ring[1:]], axis=1))
    if not edges:
        return 0
    e = np.round(np.concatenate(edges) / tol).astype(np.int64)  # (E, 2, 3), snapped to tol
    a, b = e[:, 0], e[:, 1]
    less = _lex_less(a, b)[:, None]
    keys = np.concatenate([np.where(less, a, b), np.where(less, b, a)], axis=1)
    _, counts = np.unique(keys, axis=0, return_counts=True)
    return int((counts == 1).sum())


def _lex_less(a: npt.NDArray[np.int64], b: npt.NDArray[np.int64]) -> npt.NDArray[np.bool_]:
    """Row-wise lexicographic a < b for (E, 3) integer arrays."""
    d = b - a
    first = np.argmax(d != 0, axis=1)
    return d[np.arange(len(d)), first] > 0


def orient_outward(polys: list[Polygon], semantics: list[str | None], *,
                   closed: bool = True) -> tuple[list[Polygon], list[str]]:
    """Orient an object's polygons outward.

    Roof surfaces must face up and ground surfaces down (their semantic class says so); a shell that is
    closed is flipped as a whole when its signed volume is negative. An open shell is reported, not
    repaired: its proxy is built from the footprint and height range, which do not need a closed shell.
    With ``closed=False`` (a MultiSurface that is not meant to bound a volume: roads, land use) only the
    semantic orientation is checked.
    """
    notes: list[str] = []
    polys = list(polys)
    for i, (poly, sem) in enumerate(zip(polys, semantics, strict=False)):
        if sem not in ("RoofSurface", "GroundSurface"):
            continue
        nz = _newell(poly[0])[2]
        if (sem == "RoofSurface" and nz < 0) or (sem == "GroundSurface" and nz > 0):
            polys[i] = [r[::-1].copy() for r in poly]
            notes.append(f"flipped an inverted {sem}")
    if not polys or not closed:
        return polys, notes
    open_edges = open_edge_count(polys)
    if open_edges:
        notes.append(f"surfaces do not close a solid ({open_edges} open edges); proxy from footprint")
        return polys, notes
    if _fan_volume(polys) < 0:
        polys = [[r[::-1].copy() for r in poly] for poly in polys]
        notes.append("inverted solid (negative volume) reoriented outward")
    return polys, notes


# --------------------------------------------------------------------------------------------------------
# Projection to metres

def _looks_like_gauss_krueger(xy: F64) -> int | None:
    """Zone (2..5) when positions are German Gauss-Krüger metres (easting with the zone as its first digit)."""
    x, y = xy[:, 0], xy[:, 1]
    zone = np.floor(x / 1e6)
    if zone.min() != zone.max() or not 2 <= zone[0] <= 5:
        return None
    inner = x - zone * 1e6
    if inner.min() < 200_000 or inner.max() > 800_000 or y.min() < 5_200_000 or y.max() > 6_150_000:
        return None
    return int(zone[0])


def to_metric(model: CityModel, crs: str | pyproj.CRS | None = None) -> CityModel:
    """The model in a metric CRS: unchanged if already metric, else projected to ``crs`` or its UTM zone.

    Geographic positions are read as longitude, latitude (the usual practice in CityGML and CityJSON files,
    whatever the EPSG axis order says); heights are kept. A file that declares a geographic CRS but holds
    positions far outside ±180/±90 is mislabelled: German Gauss-Krüger metres (the Karlsruhe sample) are
    recognised from their zone prefix and read as DHDN / 3-degree Gauss-Krüger, with a warning; anything
    else is a GeoreferenceError.

    Parameters
    ----------
    model
        As read.
    crs
        Target metric CRS; by default the source CRS if metric, else the UTM zone of the centroid.
    """
    pts = [r for o in model.objects for poly in o.surfaces for r in poly]
    if model.crs is None:
        if crs is None:
            return model
        return replace(model, crs=parse_crs(crs, model.source))
    if not pts:
        return model
    allxyz = np.concatenate(pts)
    src = model.crs
    warnings = list(model.warnings)
    target = None if crs is None else parse_crs(crs, model.source)
    if is_geographic(src):
        x, y = allxyz[:, 0], allxyz[:, 1]
        if np.abs(x).max() > 180 or np.abs(y).max() > 90:
            zone = _looks_like_gauss_krueger(allxyz[:, :2])
            if zone is None:
                raise GeoreferenceError(
                    f"the file declares {src.name} (degrees) but positions reach ({x.max():.1f}, {y.max():.1f}),"
                    " which are not degrees; fix the srsName", model.source)
            src = pyproj.CRS.from_epsg(31464 + zone)
            warnings.append(f"{Path(model.source).name}: declared {model.crs.name} but positions are Gauss-Krüger "
                            f"zone {zone} metres; read them as {src.name} (EPSG:{31464 + zone})")
    if target is None:
        if not is_geographic(model.crs):
            return replace(model, crs=src, warnings=warnings)
        # The UTM zone of the centroid keeps scale error below 0.04 % inside the zone.
        mid = np.median(allxyz[:, :2], axis=0)
        if is_geographic(src):
            lon, lat = float(mid[0]), float(mid[1])
        else:
            lon, lat = pyproj.Transformer.from_crs(horizontal_crs(src), "EPSG:4326", always_xy=True).transform(
                float(mid[0]), float(mid[1]))
        target = utm_crs_for(lon, lat)
    if is_geographic(target):
        raise GeoreferenceError(f"--crs must be metric, got {target.name}", model.source)
    tr = pyproj.Transformer.from_crs(horizontal_crs(src), horizontal_crs(target), always_xy=True)
    sizes = [len(r) for r in pts]
    nx, ny = tr.transform(allxyz[:, 0], allxyz[:, 1])
    out = np.column_stack([nx, ny, allxyz[:, 2]])
    if not np.isfinite(out).all():
        raise GeoreferenceError(f"positions cannot be projected from {src.name} to {target.name}", model.source)
    pieces = iter(np.split(out, np.cumsum(sizes)[:-1]))
    objects = []
    for o in model.objects:
        surfaces = [[next(pieces) for _ in poly] for poly in o.surfaces]
        objects.append(replace(o, surfaces=surfaces))
    return CityModel(objects, target, model.source, warnings, model.version)
