"""Ground truth of the synthetic sample city: an analytic scene that ``citylod sample`` samples into files.

The scene (hilly terrain cut by a river valley with steep banks, a lake, straight roads with a bridge,
buildings with flat, gable and hip roofs, L-shaped and courtyard footprints, chimneys, trees) is defined
by closed-form height functions. Tests of the DSM tiler, the point octree and the semantic proxies compare
against these exact values instead of against a second implementation. :func:`make_city` builds the scene
without writing anything; :mod:`citylod.sample.files` writes the files. This module imports numpy only and
does no I/O.

Coordinates are metres in EPSG:32632 (UTM zone 32N), northings near 5.4e6, so every consumer meets large
coordinates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from citylod.core.errors import CitylodError

F64 = npt.NDArray[np.float64]
I64 = npt.NDArray[np.int64]
Bool = npt.NDArray[np.bool_]

CRS = "EPSG:32632"
#: South-west corner of the sample grid (easting, northing), metres.
ORIGIN = (512_000.0, 5_403_000.0)

#: What :meth:`SampleCity.surface_with_kind` says the surface is at a point.
KIND_TERRAIN, KIND_BRIDGE, KIND_BUILDING, KIND_CHIMNEY, KIND_TREE = 0, 1, 2, 3, 4
#: CityGML roof type codes (SIG3D code list) of the three roof shapes.
ROOF_CODES = {"flat": "1000", "gable": "1030", "hip": "1040"}
_ROOF_INDEX = {"flat": 0, "gable": 1, "hip": 2}

_CELL = 8.0  # bucket size of the primitive index: a few primitives per bucket at typical sizes
_CHUNK = 1 << 19  # points per evaluation chunk; bounds temporary memory on 2049² grids

_STREETS = (
    "Lindenstraße", "Am Rheinufer", "Mühlenweg", "Schulstraße", "Gartenstraße", "Kirchplatz",
    "Bahnhofstraße", "Eichenallee", "Brückenstraße", "Rosenweg", "Marktstraße", "Auf dem Hügel",
)


def _smoothstep(t: F64) -> F64:
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


# --------------------------------------------------------------------------------------------------
# Terrain
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Terrain:
    """The bare-earth height function: hills, a river valley with a steep-banked channel, a lake basin.

    Lengths are metres; ``bumps`` and ``ripples`` are relative to the south-west corner ``(x0, y0)``.
    """

    x0: float
    y0: float
    extent: float
    base: float
    side_slope: float
    bumps: F64  # (K, 4) cx, cy, sigma, amplitude
    ripples: F64  # (R, 4) kx, ky, phase, amplitude
    river_x: float  # mean x of the river centre line, relative
    river_amp: float
    river_wavelength: float
    river_phase: float
    channel_half_width: float
    bank_width: float
    valley_half_width: float
    valley_depth: float
    channel_depth: float
    lake: tuple[float, float, float]  # cx, cy, radius (relative)
    hole: tuple[float, float, float, float]  # cx, cy, radius, phase (relative): an irregular no-data gap

    def river_center_x(self, y: F64) -> F64:
        """Absolute x of the river centre line at northing ``y`` (any shape)."""
        v = np.asarray(y, dtype=np.float64) - self.y0
        w = 2.0 * math.pi / self.river_wavelength
        return self.x0 + self.river_x + self.river_amp * np.sin(w * v + self.river_phase)

    def river_distance(self, x: F64, y: F64) -> F64:
        """Approximate perpendicular distance to the river centre line, metres.

        The horizontal offset scaled by the cosine of the centre line's heading; exact for a straight
        river and within a fraction of a percent for the gentle meander used here.
        """
        v = y - self.y0
        w = 2.0 * math.pi / self.river_wavelength
        slope = self.river_amp * w * np.cos(w * v + self.river_phase)
        xc = self.x0 + self.river_x + self.river_amp * np.sin(w * v + self.river_phase)
        return np.abs(x - xc) / np.sqrt(1.0 + slope * slope)

    def water_level(self, y: F64) -> F64:
        """River water surface (the channel bed of the DSM) at northing ``y``."""
        return self._floor(np.asarray(y, dtype=np.float64)) - self.channel_depth

    def _floor(self, y: F64) -> F64:
        # The valley floor falls gently to the south so the river has a direction.
        return self.base - self.valley_depth + 0.002 * (y - self.y0)

    def height(self, x: F64, y: F64) -> F64:
        """Terrain height at ``x``, ``y`` (same-shape float64 arrays), metres."""
        u = x - self.x0
        v = y - self.y0
        d = self.river_distance(x, y)
        z = self.base + self.side_slope * np.minimum(d, 0.25 * self.extent)
        for cx, cy, sigma, amp in self.bumps:
            z += amp * np.exp(-((u - cx) ** 2 + (v - cy) ** 2) / (2.0 * sigma * sigma))
        for kx, ky, phase, amp in self.ripples:
            z += amp * np.sin(kx * u + ky * v + phase)
        inner = self.channel_half_width + self.bank_width
        floor = self._floor(y)
        z += (floor - z) * _smoothstep((self.valley_half_width - d) / (self.valley_half_width - inner))
        # The channel banks rise over bank_width only: the steep step that tests crack-free tiling.
        z += (floor - self.channel_depth - z) * _smoothstep((inner - d) / self.bank_width)
        lx, ly, lr = self.lake
        dl = np.hypot(u - lx, v - ly)
        z += (self.base - 2.0 - z) * _smoothstep((lr + 3.0 - dl) / 3.0)
        return z

    def water_mask(self, x: F64, y: F64) -> Bool:
        """True on open water (river channel or lake)."""
        lx, ly, lr = self.lake
        lake = np.hypot(x - self.x0 - lx, y - self.y0 - ly) < lr
        return (self.river_distance(x, y) < self.channel_half_width) | lake

    def nodata_mask(self, x: F64, y: F64) -> Bool:
        """True where the DSM has no data: the lake (no laser returns) and an irregular gap."""
        u = x - self.x0
        v = y - self.y0
        lx, ly, lr = self.lake
        lake = np.hypot(u - lx, v - ly) < lr
        hx, hy, hr, hp = self.hole
        theta = np.arctan2(v - hy, u - hx)
        r = hr * (1.0 + 0.35 * np.sin(3.0 * theta + hp) + 0.2 * np.cos(5.0 * theta))
        return lake | (np.hypot(u - hx, v - hy) < r)


# --------------------------------------------------------------------------------------------------
# Objects
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Building:
    """One building of the ground truth.

    The footprint is a union of up to two rectangles (``parts``) minus at most one rectangular courtyard
    (``hole``), all given in the building's own frame: origin ``center``, axis u rotated ``angle_deg``
    counter-clockwise from east. Gable and hip roofs sit on a single rectangle with the ridge along u.
    Heights are absolute metres.

    Attributes
    ----------
    footprint
        (K, 2) float64 exterior ring in CRS coordinates, counter-clockwise, not closed.
    holes
        Interior rings, each (M, 2) float64 clockwise, not closed.
    parts
        (P, 4) float64 rectangles ``cu, cv, half_u, half_v`` in the building frame, P in {1, 2}.
    hole
        (4,) float64 courtyard rectangle in the building frame, or None.
    """

    index: int
    id: str
    name: str
    function: str
    roof: str
    shape: str
    street: str
    center: tuple[float, float]
    angle_deg: float
    parts: F64
    hole: F64 | None
    ground: float
    eave: float
    ridge: float
    storeys: int
    footprint: F64
    holes: tuple[F64, ...]

    @property
    def measured_height(self) -> float:
        """Ridge minus ground, metres (CityGML ``bldg:measuredHeight``)."""
        return self.ridge - self.ground

    @property
    def lod1_top(self) -> float:
        """Top of the LoD1 block: the mean of eave and ridge (the usual LoD1 height rule)."""
        return 0.5 * (self.eave + self.ridge)

    @property
    def roof_type_code(self) -> str:
        return ROOF_CODES[self.roof]

    @property
    def footprint_area(self) -> float:
        """Footprint area in m², holes subtracted."""
        area = float((self.parts[:, 2] * self.parts[:, 3]).sum() * 4.0)
        if len(self.parts) == 2:  # the two wings of an L overlap in one corner square
            area -= _overlap(self.parts[0], self.parts[1])
        if self.hole is not None:
            area -= 4.0 * float(self.hole[2] * self.hole[3])
        return area

    def to_world(self, uv: F64) -> F64:
        """Building-frame (N, 2) coordinates to CRS (N, 2)."""
        c, s = math.cos(math.radians(self.angle_deg)), math.sin(math.radians(self.angle_deg))
        uv = np.asarray(uv, dtype=np.float64)
        return np.column_stack([self.center[0] + c * uv[:, 0] - s * uv[:, 1],
                                self.center[1] + s * uv[:, 0] + c * uv[:, 1]])

    def solid(self, lod: int = 2) -> tuple[F64, list[tuple[str, list[I64]]]]:
        """The closed boundary of the building as an indexed polygon mesh.

        Parameters
        ----------
        lod
            1: the footprint extruded from ``ground`` to :attr:`lod1_top`; 2: the roof shape.

        Returns
        -------
        vertices
            (V, 3) float64 CRS coordinates.
        faces
            ``(kind, rings)`` per planar polygon, kind one of ``"GroundSurface"``, ``"WallSurface"``,
            ``"RoofSurface"``; ``rings[0]`` the exterior, the rest holes, each an int64 index array
            ordered counter-clockwise seen from outside the solid (outward normals). Every edge is shared
            by exactly two polygons, once in each direction.
        """
        if lod == 1 or self.roof == "flat":
            top = self.lod1_top if lod == 1 else self.eave
            rings = [self._local_ring(self.footprint)] + [self._local_ring(h) for h in self.holes]
            uvz, faces = _extrude(rings, self.ground, top)
        else:
            uvz, faces = _pitched(float(self.parts[0, 2]), float(self.parts[0, 3]), self.ground, self.eave,
                                  self.ridge, self.roof)
        xy = self.to_world(uvz[:, :2])
        return np.column_stack([xy, uvz[:, 2]]), faces

    def _local_ring(self, ring: F64) -> F64:
        c, s = math.cos(math.radians(self.angle_deg)), math.sin(math.radians(self.angle_deg))
        d = ring - np.asarray(self.center)
        return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])


def _overlap(p: F64, q: F64) -> float:
    w = min(p[0] + p[2], q[0] + q[2]) - max(p[0] - p[2], q[0] - q[2])
    h = min(p[1] + p[3], q[1] + q[3]) - max(p[1] - p[3], q[1] - q[3])
    return max(w, 0.0) * max(h, 0.0)


def _extrude(rings: list[F64], z0: float, z1: float) -> tuple[F64, list[tuple[str, list[I64]]]]:
    """Prism over planar rings (exterior CCW, holes CW) from z0 to z1; faces oriented outward."""
    verts, walls, bottom, top = [], [], [], []
    n = 0
    for ring in rings:
        k = len(ring)
        verts += [np.column_stack([ring, np.full(k, z0)]), np.column_stack([ring, np.full(k, z1)])]
        b = np.arange(n, n + k)
        t = b + k
        n += 2 * k
        bottom.append(b[::-1].copy())
        top.append(t)
        nxt = np.roll(np.arange(k), -1)
        # A wall over edge i -> i+1 of a CCW ring, listed bottom-forward then top-backward, faces outward.
        walls += [("WallSurface", [np.array([b[i], b[j], t[j], t[i]])]) for i, j in enumerate(nxt)]
    faces = [("GroundSurface", bottom), *walls, ("RoofSurface", top)]
    return np.concatenate(verts), faces


def _pitched(a: float, b: float, z0: float, eave: float, ridge: float,
             roof: str) -> tuple[F64, list[tuple[str, list[I64]]]]:
    """Gable or hip roof house on the rectangle |u| <= a, |v| <= b, ridge along u."""
    r = a if roof == "gable" else a - b
    corners = np.array([[-a, -b], [a, -b], [a, b], [-a, b]])
    uvz = np.vstack([np.column_stack([corners, np.full(4, z0)]), np.column_stack([corners, np.full(4, eave)]),
                     [[-r, 0.0, ridge], [r, 0.0, ridge]]])
    ground = [("GroundSurface", [np.array([3, 2, 1, 0])])]
    if roof == "gable":
        faces = [("WallSurface", [np.array([0, 1, 5, 4])]), ("WallSurface", [np.array([1, 2, 6, 9, 5])]),
                 ("WallSurface", [np.array([2, 3, 7, 6])]), ("WallSurface", [np.array([3, 0, 4, 8, 7])]),
                 ("RoofSurface", [np.array([4, 5, 9, 8])]), ("RoofSurface", [np.array([6, 7, 8, 9])])]
    else:
        faces = [("WallSurface", [np.array([0, 1, 5, 4])]), ("WallSurface", [np.array([1, 2, 6, 5])]),
                 ("WallSurface", [np.array([2, 3, 7, 6])]), ("WallSurface", [np.array([3, 0, 4, 7])]),
                 ("RoofSurface", [np.array([4, 5, 9, 8])]), ("RoofSurface", [np.array([5, 6, 9])]),
                 ("RoofSurface", [np.array([6, 7, 8, 9])]), ("RoofSurface", [np.array([7, 4, 8])])]
    return uvz, ground + faces


@dataclass(frozen=True)
class Chimneys:
    """Chimneys: small boxes on pitched roofs, 1–2 samples wide, in the frame of their building.

    Arrays: ``center`` (C, 2) CRS, ``half`` (C, 2) half sizes along the building's u and v, ``angle_deg``
    (C,), ``top`` (C,) absolute height, ``building`` (C,) int64 building index.
    """

    center: F64
    half: F64
    angle_deg: F64
    top: F64
    building: I64

    def __len__(self) -> int:
        return len(self.top)


@dataclass(frozen=True)
class Trees:
    """Trees with ellipsoidal crowns.

    Arrays: ``position`` (T, 2) CRS, ``crown_radius`` (T,), ``height`` (T,) above ``ground`` (T,),
    ``crown_depth`` (T,) vertical semi-axis of the crown. The surface over a crown is
    ``ground + height - crown_depth * (1 - sqrt(1 - (d / crown_radius)²))``.
    """

    position: F64
    crown_radius: F64
    height: F64
    ground: F64
    crown_depth: F64

    def __len__(self) -> int:
        return len(self.height)


@dataclass(frozen=True)
class Road:
    """A straight road: ``axis`` 'x' (runs east–west at northing ``center``) or 'y' (north–south)."""

    axis: str
    center: float
    half_width: float
    start: float
    end: float


@dataclass(frozen=True)
class Bridge:
    """A flat deck over the river, axis-aligned, height linear in x from ``z_west`` to ``z_east``."""

    xmin: float
    xmax: float
    ymin: float
    ymax: float
    z_west: float
    z_east: float


# --------------------------------------------------------------------------------------------------
# Vectorised evaluation: a bucket index of primitive boxes and one kernel per primitive family
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _BoxIndex:
    """Primitive bounding boxes bucketed on a uniform grid (CSR: bucket -> primitive ids)."""

    boxes: F64  # (P, 4) xmin, ymin, xmax, ymax
    x0: float
    y0: float
    ncx: int
    ncy: int
    ptr: I64
    items: I64

    @staticmethod
    def build(boxes: F64, x0: float, y0: float, ncx: int, ncy: int) -> _BoxIndex:
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        ix0 = np.clip(np.floor((boxes[:, 0] - x0) / _CELL), 0, ncx - 1).astype(np.int64)
        iy0 = np.clip(np.floor((boxes[:, 1] - y0) / _CELL), 0, ncy - 1).astype(np.int64)
        ix1 = np.clip(np.floor((boxes[:, 2] - x0) / _CELL), 0, ncx - 1).astype(np.int64)
        iy1 = np.clip(np.floor((boxes[:, 3] - y0) / _CELL), 0, ncy - 1).astype(np.int64)
        nx = ix1 - ix0 + 1
        counts = nx * (iy1 - iy0 + 1)
        prim = np.repeat(np.arange(len(boxes)), counts)
        k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        cell = (iy0[prim] + k // nx[prim]) * ncx + ix0[prim] + k % nx[prim]
        order = np.argsort(cell, kind="stable")
        ptr = np.zeros(ncx * ncy + 1, dtype=np.int64)
        np.cumsum(np.bincount(cell, minlength=ncx * ncy), out=ptr[1:])
        return _BoxIndex(boxes, x0, y0, ncx, ncy, ptr, prim[order])

    def pairs(self, x: F64, y: F64) -> tuple[I64, I64]:
        """(point, primitive) index pairs whose box contains the point; ``x``, ``y`` flat (N,)."""
        if len(self.boxes) == 0 or len(x) == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        cx = np.clip(np.floor((x - self.x0) / _CELL), 0, self.ncx - 1).astype(np.int64)
        cy = np.clip(np.floor((y - self.y0) / _CELL), 0, self.ncy - 1).astype(np.int64)
        c = cy * self.ncx + cx
        start = self.ptr[c]
        cnt = self.ptr[c + 1] - start
        pi = np.repeat(np.arange(len(x)), cnt)
        off = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        ki = self.items[start[pi] + off]
        b = self.boxes[ki]
        xp, yp = x[pi], y[pi]
        keep = (xp >= b[:, 0]) & (xp <= b[:, 2]) & (yp >= b[:, 1]) & (yp <= b[:, 3])
        return pi[keep], ki[keep]


class _BuildingKernel:
    """Footprint containment and roof height of all buildings, vectorised over (point, building) pairs."""

    def __init__(self, buildings: tuple[Building, ...]) -> None:
        n = len(buildings)
        self.center = np.array([b.center for b in buildings], dtype=np.float64).reshape(n, 2)
        ang = np.radians([b.angle_deg for b in buildings]) if n else np.zeros(0)
        self.cos, self.sin = np.cos(ang), np.sin(ang)
        self.roof = np.array([_ROOF_INDEX[b.roof] for b in buildings], dtype=np.int64)
        self.parts = np.full((n, 2, 4), [0.0, 0.0, -np.inf, -np.inf])  # an empty slot contains nothing
        self.hole = np.full((n, 4), [0.0, 0.0, -np.inf, -np.inf])
        for i, b in enumerate(buildings):
            self.parts[i, : len(b.parts)] = b.parts
            if b.hole is not None:
                self.hole[i] = b.hole
        self.half = self.parts[:, 0, 2:].copy()  # a, b of the main rectangle: the roof's extent
        self.ground = np.array([b.ground for b in buildings], dtype=np.float64)
        self.eave = np.array([b.eave for b in buildings], dtype=np.float64)
        self.ridge = np.array([b.ridge for b in buildings], dtype=np.float64)
        self.boxes = np.array([[*b.footprint.min(axis=0), *b.footprint.max(axis=0)] for b in buildings],
                              dtype=np.float64).reshape(n, 4)

    def local(self, x: F64, y: F64, k: I64) -> tuple[F64, F64]:
        dx = x - self.center[k, 0]
        dy = y - self.center[k, 1]
        return self.cos[k] * dx + self.sin[k] * dy, -self.sin[k] * dx + self.cos[k] * dy

    def contains(self, u: F64, v: F64, k: I64, grow: float = 0.0) -> Bool:
        p = self.parts[k]
        inside = np.zeros(len(k), dtype=bool)
        for j in range(2):
            inside |= (np.abs(u - p[:, j, 0]) <= p[:, j, 2] + grow) & (np.abs(v - p[:, j, 1]) <= p[:, j, 3] + grow)
        h = self.hole[k]
        in_hole = (np.abs(u - h[:, 0]) < h[:, 2] - grow) & (np.abs(v - h[:, 1]) < h[:, 3] - grow)
        return inside & ~in_hole

    def roof_height(self, u: F64, v: F64, k: I64) -> F64:
        a, b = self.half[k, 0], self.half[k, 1]
        # Clamping to the main rectangle gives inflated proxies a roof beyond the eaves.
        au = np.minimum(np.abs(u), a)
        av = np.minimum(np.abs(v), b)
        gable = (b - av) / b
        hip = np.minimum(b - av, a - au) / b
        t = np.where(self.roof[k] == 1, gable, np.where(self.roof[k] == 2, hip, 0.0))
        return self.eave[k] + (self.ridge[k] - self.eave[k]) * t

    def height(self, x: F64, y: F64, k: I64) -> F64:
        u, v = self.local(x, y, k)
        return np.where(self.contains(u, v, k), self.roof_height(u, v, k), np.nan)


class _ChimneyKernel:
    def __init__(self, ch: Chimneys) -> None:
        self.ch = ch
        ang = np.radians(ch.angle_deg)
        self.cos, self.sin = np.cos(ang), np.sin(ang)
        ext = np.abs(np.column_stack([self.cos, self.sin])) * ch.half[:, :1] + \
            np.abs(np.column_stack([self.sin, self.cos])) * ch.half[:, 1:]
        self.boxes = np.column_stack([ch.center - ext, ch.center + ext]).reshape(len(ch), 4)

    def height(self, x: F64, y: F64, k: I64) -> F64:
        dx = x - self.ch.center[k, 0]
        dy = y - self.ch.center[k, 1]
        u = self.cos[k] * dx + self.sin[k] * dy
        v = -self.sin[k] * dx + self.cos[k] * dy
        inside = (np.abs(u) <= self.ch.half[k, 0]) & (np.abs(v) <= self.ch.half[k, 1])
        return np.where(inside, self.ch.top[k], np.nan)


class _TreeKernel:
    def __init__(self, t: Trees) -> None:
        self.t = t
        r = t.crown_radius[:, None]
        self.boxes = np.column_stack([t.position - r, t.position + r]).reshape(len(t), 4)

    def height(self, x: F64, y: F64, k: I64) -> F64:
        t = self.t
        q = ((x - t.position[k, 0]) ** 2 + (y - t.position[k, 1]) ** 2) / t.crown_radius[k] ** 2
        cap = t.crown_depth[k] * (np.sqrt(np.clip(1.0 - q, 0.0, None)) - 1.0)
        return np.where(q <= 1.0, t.ground[k] + t.height[k] + cap, np.nan)


class _BridgeKernel:
    def __init__(self, bridges: tuple[Bridge, ...]) -> None:
        self.b = np.array([[b.xmin, b.ymin, b.xmax, b.ymax, b.z_west, b.z_east] for b in bridges],
                          dtype=np.float64).reshape(len(bridges), 6)
        self.boxes = self.b[:, :4]

    def height(self, x: F64, y: F64, k: I64) -> F64:
        b = self.b[k]
        t = (x - b[:, 0]) / (b[:, 2] - b[:, 0])
        return b[:, 4] + (b[:, 5] - b[:, 4]) * t


def _flat(*arrays: npt.ArrayLike) -> tuple[tuple[int, ...], list[F64]]:
    arrs = np.broadcast_arrays(*[np.asarray(a, dtype=np.float64) for a in arrays])
    return arrs[0].shape, [np.ascontiguousarray(a).reshape(-1) for a in arrs]


# --------------------------------------------------------------------------------------------------
# The city
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class SampleCity:
    """The analytic ground truth of a sample: terrain, buildings, chimneys, trees, roads, bridges.

    All query methods take coordinates in the CRS as arrays of any (broadcastable) shape and return arrays
    of the broadcast shape; they evaluate closed forms, so a DSM sampled from :meth:`surface_height` is
    exact to float rounding.
    """

    size: int
    seed: int
    spacing: float
    origin: tuple[float, float]
    terrain: Terrain
    roads: tuple[Road, ...]
    bridges: tuple[Bridge, ...]
    buildings: tuple[Building, ...]
    chimneys: Chimneys
    trees: Trees
    crs: str = CRS
    _families: tuple = field(init=False, repr=False, compare=False)
    _bindex: _BoxIndex = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        x0, y0 = self.origin
        n = max(1, math.ceil(self.extent / _CELL))
        fams = []
        for kind, kern in ((KIND_BRIDGE, _BridgeKernel(self.bridges)), (KIND_BUILDING, _BuildingKernel(self.buildings)),
                           (KIND_CHIMNEY, _ChimneyKernel(self.chimneys)), (KIND_TREE, _TreeKernel(self.trees))):
            fams.append((kind, kern, _BoxIndex.build(kern.boxes, x0, y0, n, n)))
        object.__setattr__(self, "_families", tuple(fams))
        object.__setattr__(self, "_bindex", fams[1][2])

    @property
    def extent(self) -> float:
        """Side length of the square scene, metres (``size * spacing``)."""
        return self.size * self.spacing

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the grid, pixel edges included."""
        x0, y0 = self.origin
        return (x0, y0, x0 + self.extent, y0 + self.extent)

    @property
    def _bk(self) -> _BuildingKernel:
        return self._families[1][1]

    def pixel_centers(self) -> tuple[F64, F64]:
        """Pixel-centre coordinates of the DSM grid, each (size, size), row 0 in the north."""
        x0, y0 = self.origin
        c = (np.arange(self.size) + 0.5) * self.spacing
        return np.meshgrid(x0 + c, y0 + self.extent - c)

    def terrain_height(self, x: npt.ArrayLike, y: npt.ArrayLike) -> F64:
        """Bare-earth height (no buildings, trees or bridges), metres."""
        shape, (xf, yf) = _flat(x, y)
        out = np.empty(len(xf))
        for s in range(0, len(xf), _CHUNK):
            out[s : s + _CHUNK] = self.terrain.height(xf[s : s + _CHUNK], yf[s : s + _CHUNK])
        return out.reshape(shape)

    def surface_with_kind(self, x: npt.ArrayLike, y: npt.ArrayLike) -> tuple[F64, npt.NDArray[np.int8], I64]:
        """The DSM surface and what it is.

        Returns
        -------
        z
            float64 surface height (terrain, bridge decks, roofs, chimneys, tree crowns: the highest).
        kind
            int8, one of ``KIND_TERRAIN``, ``KIND_BRIDGE``, ``KIND_BUILDING``, ``KIND_CHIMNEY``, ``KIND_TREE``.
        index
            int64 index of the bridge, building, chimney or tree that forms the surface; -1 on terrain.
        """
        shape, (xf, yf) = _flat(x, y)
        z = np.empty(len(xf))
        kind = np.zeros(len(xf), dtype=np.int8)
        ident = np.full(len(xf), -1, dtype=np.int64)
        for s in range(0, len(xf), _CHUNK):
            sl = slice(s, s + _CHUNK)
            z[sl], kind[sl], ident[sl] = self._surface(xf[sl], yf[sl])
        return z.reshape(shape), kind.reshape(shape), ident.reshape(shape)

    def _surface(self, x: F64, y: F64) -> tuple[F64, npt.NDArray[np.int8], I64]:
        z = self.terrain.height(x, y)
        kind = np.zeros(len(x), dtype=np.int8)
        ident = np.full(len(x), -1, dtype=np.int64)
        for fam_kind, kern, index in self._families:
            pi, ki = index.pairs(x, y)
            h = kern.height(x[pi], y[pi], ki)
            ok = ~np.isnan(h)
            pi, ki, h = pi[ok], ki[ok], h[ok]
            best = np.full(len(x), -np.inf)
            np.maximum.at(best, pi, h)
            win = (h == best[pi]) & (h > z[pi])
            z[pi[win]] = h[win]
            kind[pi[win]] = fam_kind
            ident[pi[win]] = ki[win]
        return z, kind, ident

    def surface_height(self, x: npt.ArrayLike, y: npt.ArrayLike) -> F64:
        """The DSM surface: the highest of terrain, bridge decks, roofs, chimneys and tree crowns."""
        return self.surface_with_kind(x, y)[0]

    def _building_pairs(self, x: F64, y: F64, grow: float) -> tuple[I64, I64, F64, F64]:
        index = self._bindex
        if grow > 0.0:  # a grown footprint can reach buckets its box was not filed under
            index = _BoxIndex.build(index.boxes + np.array([-grow, -grow, grow, grow]), index.x0, index.y0,
                                    index.ncx, index.ncy)
        pi, ki = index.pairs(x, y)
        u, v = self._bk.local(x[pi], y[pi], ki)
        inside = self._bk.contains(u, v, ki, grow)
        return pi[inside], ki[inside], u[inside], v[inside]

    def building_id_at(self, x: npt.ArrayLike, y: npt.ArrayLike) -> I64:
        """Index into :attr:`buildings` of the footprint containing each point, -1 outside all."""
        shape, (xf, yf) = _flat(x, y)
        out = np.full(len(xf), -1, dtype=np.int64)
        for s in range(0, len(xf), _CHUNK):
            pi, ki, _, _ = self._building_pairs(xf[s : s + _CHUNK], yf[s : s + _CHUNK], 0.0)
            out[s + pi] = ki
        return out.reshape(shape)

    def roof_height(self, x: npt.ArrayLike, y: npt.ArrayLike) -> F64:
        """Height of the LoD2 roof (chimneys excluded) over each point, NaN outside all footprints."""
        shape, (xf, yf) = _flat(x, y)
        out = np.full(len(xf), np.nan)
        for s in range(0, len(xf), _CHUNK):
            pi, ki, u, v = self._building_pairs(xf[s : s + _CHUNK], yf[s : s + _CHUNK], 0.0)
            out[s + pi] = self._bk.roof_height(u, v, ki)
        return out.reshape(shape)

    def inside_building(self, x: npt.ArrayLike, y: npt.ArrayLike, z: npt.ArrayLike, inflate: float = 0.0) -> I64:
        """Index of the building whose LoD2 solid, inflated by ``inflate`` metres, contains each point.

        Inflation grows every footprint rectangle by ``inflate`` in the building frame (corners stay
        square), shrinks a courtyard by it, lowers the ground and raises the roof by it; over the grown
        margin the roof continues at its eave height. Chimneys are not part of the solid (as in the
        CityGML). Returns -1 outside all buildings.
        """
        shape, (xf, yf, zf) = _flat(x, y, z)
        out = np.full(len(xf), -1, dtype=np.int64)
        bk = self._bk
        for s in range(0, len(xf), _CHUNK):
            sl = slice(s, s + _CHUNK)
            pi, ki, u, v = self._building_pairs(xf[sl], yf[sl], float(inflate))
            zp = zf[sl][pi]
            ok = (zp >= bk.ground[ki] - inflate) & (zp <= bk.roof_height(u, v, ki) + inflate)
            out[s + pi[ok]] = ki[ok]
        return out.reshape(shape)

    def water_mask(self, x: npt.ArrayLike, y: npt.ArrayLike) -> Bool:
        """True on open water (river channel, lake)."""
        shape, (xf, yf) = _flat(x, y)
        return self.terrain.water_mask(xf, yf).reshape(shape)

    def nodata_mask(self, x: npt.ArrayLike, y: npt.ArrayLike) -> Bool:
        """True where the DSM and the point cloud have no data (lake, an irregular gap)."""
        shape, (xf, yf) = _flat(x, y)
        return self.terrain.nodata_mask(xf, yf).reshape(shape)

    def road_mask(self, x: npt.ArrayLike, y: npt.ArrayLike) -> tuple[Bool, F64]:
        """(on a road, distance to the nearest road centre line) for each point."""
        shape, (xf, yf) = _flat(x, y)
        dist = np.full(len(xf), np.inf)
        on = np.zeros(len(xf), dtype=bool)
        for r in self.roads:
            across, along = (yf, xf) if r.axis == "x" else (xf, yf)
            d = np.where((along >= r.start) & (along <= r.end), np.abs(across - r.center), np.inf)
            on |= d <= r.half_width
            dist = np.minimum(dist, d)
        return on.reshape(shape), dist.reshape(shape)


# --------------------------------------------------------------------------------------------------
# Generation
# --------------------------------------------------------------------------------------------------


def make_city(size: int = 513, seed: int = 7, *, spacing: float = 1.0) -> SampleCity:
    """Build the ground truth of a sample city without writing anything.

    Parameters
    ----------
    size
        Samples per side of the DSM grid (at least 33); the scene is ``size * spacing`` metres square.
    seed
        Seed of every random choice; the same seed gives the same city.
    spacing
        Sample spacing in metres.

    Examples
    --------
    >>> city = make_city(65, seed=7)
    >>> city.crs, city.bounds[:2]
    ('EPSG:32632', (512000.0, 5403000.0))
    >>> x, y = 512_030.5, 5_403_030.5
    >>> bool(city.surface_height(x, y) >= city.terrain_height(x, y))
    True
    """
    if size < 33:
        raise CitylodError(f"sample size must be at least 33 samples, got {size}")
    if not spacing > 0.0:
        raise CitylodError(f"sample spacing must be positive, got {spacing}")
    rng = np.random.default_rng(seed)
    x0, y0 = ORIGIN
    ext = size * spacing
    terrain = _make_terrain(rng, x0, y0, ext)
    roads, xblocks, yblocks = _make_roads(terrain, ext)
    terrain = _place_lake(rng, terrain, xblocks, yblocks)
    buildings = _make_buildings(rng, terrain, roads, xblocks, yblocks)
    kernel = _BuildingKernel(buildings)
    chimneys = _make_chimneys(rng, buildings, kernel)
    bridges = _make_bridges(terrain, roads)
    trees = _make_trees(rng, terrain, roads, buildings, kernel, xblocks, yblocks)
    return SampleCity(size=size, seed=seed, spacing=spacing, origin=(x0, y0), terrain=terrain, roads=roads,
                      bridges=bridges, buildings=buildings, chimneys=chimneys, trees=trees)


def _make_terrain(rng: np.random.Generator, x0: float, y0: float, ext: float) -> Terrain:
    relief = min(1.0, ext / 500.0)  # a 64 m scene gets gentle hills, not 20 m cliffs
    bumps = np.column_stack([
        rng.uniform(-0.1, 1.1, 6) * ext, rng.uniform(-0.1, 1.1, 6) * ext,
        rng.uniform(0.12, 0.3, 6) * ext, rng.uniform(3.0, 18.0, 6) * relief,
    ])
    wl = rng.uniform(60.0, 220.0, 2)
    heading = rng.uniform(0.0, 2.0 * math.pi, 2)
    ripples = np.column_stack([2 * np.pi / wl * np.cos(heading), 2 * np.pi / wl * np.sin(heading),
                               rng.uniform(0.0, 2 * np.pi, 2), rng.uniform(0.3, 0.9, 2)])
    channel = float(np.clip(0.02 * ext, 3.0, 25.0))
    bank = 2.5
    valley = channel + bank + float(np.clip(0.06 * ext, 6.0, 80.0))
    hole = (rng.uniform(0.4, 0.6) * ext, rng.uniform(0.08, 0.16) * ext, float(np.clip(0.012 * ext, 2.0, 10.0)),
            rng.uniform(0.0, 2 * np.pi))
    return Terrain(
        x0=x0, y0=y0, extent=ext, base=float(rng.uniform(95.0, 140.0)), side_slope=0.03, bumps=bumps,
        ripples=ripples, river_x=0.72 * ext, river_amp=0.03 * ext, river_wavelength=float(rng.uniform(0.8, 1.3) * ext),
        river_phase=float(rng.uniform(0.0, 2 * np.pi)), channel_half_width=channel, bank_width=bank,
        valley_half_width=valley, valley_depth=float(np.clip(0.01 * ext, 2.0, 8.0)), channel_depth=2.5,
        lake=(0.0, 0.0, 0.0), hole=hole,
    )


_ROAD_HALF = 4.0  # 6 m carriageway and 1 m pavements
_SETBACK = 3.0  # front gardens between pavement and lot
_MIN_LOT = 20.0


def _intervals(lo: float, hi: float, cuts: list[float]) -> list[tuple[float, float]]:
    edges = [lo, *[c for cut in cuts for c in (cut - _ROAD_HALF - _SETBACK, cut + _ROAD_HALF + _SETBACK)], hi]
    return [(a, b) for a, b in zip(edges[::2], edges[1::2], strict=True) if b - a >= _MIN_LOT]


def _make_roads(t: Terrain, ext: float) -> tuple[tuple[Road, ...], list[tuple[float, float]], list[tuple[float, float]]]:
    """Straight roads and the blocks between them (relative coordinates)."""
    n_h = max(1, round(ext / 180.0))
    ys = [(j + 0.5) * ext / n_h for j in range(n_h)]
    city_end = t.river_x - t.river_amp - t.valley_half_width - 4.0
    n_v = max(1, round(city_end / 150.0)) if city_end >= 2 * _MIN_LOT + 2 * (_ROAD_HALF + _SETBACK) + 4 else 0
    xs = [(j + 0.5) * city_end / n_v for j in range(n_v)]
    roads = [Road("x", t.y0 + y, _ROAD_HALF, t.x0, t.x0 + ext) for y in ys]
    roads += [Road("y", t.x0 + x, _ROAD_HALF, t.y0, t.y0 + ext) for x in xs]
    return tuple(roads), _intervals(2.0, city_end, xs), _intervals(2.0, ext - 2.0, ys)


def _place_lake(rng: np.random.Generator, t: Terrain, xb: list[tuple[float, float]],
                yb: list[tuple[float, float]]) -> Terrain:
    # The lake lies in the north-west block, in a park, so no road or building crosses it.
    if not xb or not yb:
        return t
    (xa, xe), (ya, ye) = xb[0], yb[-1]
    r = float(np.clip(0.3 * min(xe - xa, ye - ya), 4.0, 70.0))
    cx = 0.5 * (xa + xe) + rng.uniform(-0.1, 0.1) * (xe - xa)
    cy = 0.5 * (ya + ye) + rng.uniform(-0.1, 0.1) * (ye - ya)
    return _replace(t, lake=(cx, cy, r))


def _replace(t: Terrain, **kw: object) -> Terrain:
    from dataclasses import replace

    return replace(t, **kw)  # type: ignore[arg-type]


def _fit(half_u: float, half_v: float, angle: float, avail: tuple[float, float]) -> float:
    """Scale factor (<= 1) that makes a rotated box of these halves fit the lot's half extents."""
    c, s = abs(math.cos(angle)), abs(math.sin(angle))
    ex, ey = c * half_u + s * half_v, s * half_u + c * half_v
    return min(1.0, avail[0] / ex, avail[1] / ey)


def _design(rng: np.random.Generator, kind: str, avail: tuple[float, float],
            rotate: bool) -> tuple[str, str, float, F64, F64 | None, F64, list[F64]] | None:
    """Shape of one building in a lot with half extents ``avail``; None if it does not fit."""
    quarter = float(rng.integers(0, 4)) * math.pi / 2
    jitter = math.radians(rng.uniform(8.0, 28.0) * rng.choice([-1.0, 1.0])) if rotate else 0.0
    if kind in ("gable", "hip", "flat"):
        along_x = avail[0] >= avail[1]
        long_half = rng.uniform(0.6, 0.92) * max(avail)
        short_half = min(rng.uniform(4.0, 7.5), 0.85 * min(avail), long_half / 1.25)
        angle = (0.0 if along_x else math.pi / 2) + (math.pi if quarter >= math.pi else 0.0) + jitter
        f = _fit(long_half, short_half, angle, avail)
        a, b = long_half * f, short_half * f
        if b < 3.0 or (kind == "hip" and a - b < 1.0):
            return None
        parts = np.array([[0.0, 0.0, a, b]])
        ring = np.array([[-a, -b], [a, -b], [a, b], [-a, b]])
        return kind, "rect", angle, parts, None, ring, []
    if kind == "L":
        big_a, big_b = rng.uniform(0.75, 0.95) * avail[0], rng.uniform(0.75, 0.95) * avail[1]
        angle = quarter + jitter
        if quarter % math.pi:  # a quarter turn swaps which lot extent the u axis spans
            big_a, big_b = big_b, big_a
        f = _fit(big_a, big_b, angle, avail)
        big_a, big_b = big_a * f, big_b * f
        w1, w2 = min(rng.uniform(7.0, 10.0), big_b), min(rng.uniform(7.0, 10.0), big_a)
        if big_a < 8.0 or big_b < 8.0 or w1 > 1.2 * big_b or w2 > 1.2 * big_a:
            return None
        parts = np.array([[0.0, -big_b + w1 / 2, big_a, w1 / 2], [-big_a + w2 / 2, 0.0, w2 / 2, big_b]])
        ring = np.array([[-big_a, -big_b], [big_a, -big_b], [big_a, -big_b + w1], [-big_a + w2, -big_b + w1],
                         [-big_a + w2, big_b], [-big_a, big_b]])
        return "flat", "L", angle, parts, None, ring, []
    # courtyard: a perimeter block around a rectangular yard
    big_a, big_b = rng.uniform(0.85, 0.97) * avail[0], rng.uniform(0.85, 0.97) * avail[1]
    wall = rng.uniform(5.5, 8.0)
    if big_a - wall < 2.5 or big_b - wall < 2.5:
        return None
    ha, hb = big_a - wall, big_b - wall
    parts = np.array([[0.0, 0.0, big_a, big_b]])
    hole = np.array([0.0, 0.0, ha, hb])
    ring = np.array([[-big_a, -big_b], [big_a, -big_b], [big_a, big_b], [-big_a, big_b]])
    hole_ring = np.array([[-ha, -hb], [-ha, hb], [ha, hb], [ha, -hb]])  # clockwise: an interior ring
    return "flat", "courtyard", 0.0, parts, hole, ring, [hole_ring]


def _make_buildings(rng: np.random.Generator, t: Terrain, roads: tuple[Road, ...],
                    xb: list[tuple[float, float]], yb: list[tuple[float, float]]) -> tuple[Building, ...]:
    lots = []
    for (ya, ye) in yb:
        ny = max(1, int((ye - ya) // _MIN_LOT))
        for (xa, xe) in xb:
            nx = max(1, int((xe - xa) // _MIN_LOT))
            px, py = (xe - xa) / nx, (ye - ya) / ny
            for j in range(ny):
                for i in range(nx):
                    lots.append((xa + (i + 0.5) * px, ya + (j + 0.5) * py, px / 2 - 1.5, py / 2 - 1.5))
    lx, ly, lr = t.lake
    park = lr + 0.15 * t.extent if lr > 0 else -1.0
    lots = [lot for lot in lots if math.hypot(lot[0] - lx, lot[1] - ly) > park + min(lot[2], lot[3])]
    order = rng.permutation(len(lots))
    # The first buildings take every shape once so that small samples still hold all the hard cases.
    pending = ["courtyard", "L", "hip", "gable", "flat"]
    kinds = np.array(["gable", "hip", "flat", "L", "courtyard"])
    probs = np.array([0.36, 0.2, 0.24, 0.12, 0.08])
    designs = []
    for li in order:
        cx, cy, hx, hy = lots[li]
        if not pending and rng.random() < 0.08:  # an empty lot: a garden
            continue
        choices = pending + list(rng.choice(kinds, size=3, p=probs)) + ["flat"]
        for kind in choices:
            rotate = (kind == "hip" and "hip" in pending) or (kind in ("gable", "hip", "flat", "L") and rng.random() < 0.3)
            d = _design(rng, str(kind), (hx, hy), rotate)
            if d is not None:
                if kind in pending:
                    pending.remove(str(kind))
                designs.append((cx + t.x0, cy + t.y0, d))
                break
    designs.sort(key=lambda item: (-item[1], item[0]))  # ids run north to south, west to east
    grounds = _ground_heights(t, designs)
    out = []
    for i, ((cx, cy, (roof, shape, angle, parts, hole, ring, holes)), ground) in enumerate(zip(designs, grounds,
                                                                                                strict=True)):
        if shape == "courtyard":
            storeys, storey_h, func = int(rng.integers(4, 7)), 3.3, str(rng.choice(["31001_1000", "31001_3000"]))
        elif shape == "L":
            storeys, storey_h, func = int(rng.integers(3, 6)), 3.3, str(rng.choice(["31001_1000", "31001_2000"]))
        elif roof == "flat":
            storeys, storey_h = int(rng.integers(2, 7)), 3.3
            func = str(rng.choice(["31001_1000", "31001_2000", "31001_3000"], p=[0.4, 0.4, 0.2]))
        else:
            storeys, storey_h = int(rng.integers(1, 4)), 2.9
            func = "31001_1000" if rng.random() < 0.85 else "31001_2000"
        eave = round(ground + 0.4 + storeys * storey_h, 2)
        rise = float(parts[0, 3]) * math.tan(math.radians(rng.uniform(30.0, 48.0))) if roof != "flat" else 0.0
        ridge = round(eave + rise, 2)
        bid = f"BLDG_{i + 1:04d}"
        street = _STREETS[int(rng.integers(len(_STREETS)))]
        name = f"{street} {int(rng.integers(1, 120))}"
        c, s = math.cos(angle), math.sin(angle)
        rot = np.array([[c, -s], [s, c]])
        out.append(Building(
            index=i, id=bid, name=name, function=func, roof=roof, shape=shape, street=street, center=(cx, cy),
            angle_deg=math.degrees(angle), parts=parts, hole=hole, ground=ground, eave=eave, ridge=ridge,
            storeys=storeys, footprint=ring @ rot.T + np.array([cx, cy]),
            holes=tuple(h @ rot.T + np.array([cx, cy]) for h in holes),
        ))
    return tuple(out)


def _ground_heights(t: Terrain, designs: list) -> list[float]:
    """Lowest terrain under each footprint (9×9 samples of its rectangle), rounded down to cm.

    The solid reaches the lowest point so that it never floats above the terrain on a slope.
    """
    if not designs:
        return []
    g = np.linspace(-1.0, 1.0, 9)
    gu, gv = (a.ravel() for a in np.meshgrid(g, g))
    xs, ys = [], []
    for cx, cy, (_, _, angle, parts, _, _, _) in designs:
        a = float((np.abs(parts[:, 0]) + parts[:, 2]).max())
        b = float((np.abs(parts[:, 1]) + parts[:, 3]).max())
        c, s = math.cos(angle), math.sin(angle)
        xs.append(cx + c * gu * a - s * gv * b)
        ys.append(cy + s * gu * a + c * gv * b)
    z = t.height(np.concatenate(xs), np.concatenate(ys)).reshape(len(designs), -1).min(axis=1)
    return [math.floor(v * 100.0) / 100.0 for v in z]


def _make_chimneys(rng: np.random.Generator, buildings: tuple[Building, ...], kernel: _BuildingKernel) -> Chimneys:
    rows: list[tuple[float, ...]] = []
    for b in buildings:
        if b.roof == "flat":
            continue
        n = int(rng.choice([0, 1, 2], p=[0.35, 0.5, 0.15]))
        n = n if rows else max(n, 1)  # every sample with a pitched roof has at least one chimney
        a, bb = float(b.parts[0, 2]), float(b.parts[0, 3])
        for _ in range(n):
            hu, hv = rng.choice([0.5, 0.75, 1.0], size=2)
            span = a - hu - 1.0 - (bb if b.roof == "hip" else 0.0)  # keep hip chimneys off the hip faces
            if span <= 0 or bb * 0.6 - hv <= 0.3:
                continue
            u = rng.uniform(-span, span)
            v = rng.choice([-1.0, 1.0]) * rng.uniform(hv + 0.3, bb * 0.6)
            rows.append((b.index, u, v, hu, hv, rng.uniform(0.8, 1.5)))
    if not rows:
        e = np.zeros(0)
        return Chimneys(np.zeros((0, 2)), np.zeros((0, 2)), e, e, np.zeros(0, np.int64))
    r = np.array(rows)
    k = r[:, 0].astype(np.int64)
    # Top: highest roof point under the chimney (5×5 samples of its rectangle) plus its own height.
    g = np.linspace(-1.0, 1.0, 5)
    gu, gv = (a.ravel() for a in np.meshgrid(g, g))
    su = (r[:, 1:2] + gu * r[:, 3:4]).ravel()
    sv = (r[:, 2:3] + gv * r[:, 4:5]).ravel()
    kk = np.repeat(k, len(gu))
    top = kernel.roof_height(su, sv, kk).reshape(len(r), -1).max(axis=1) + r[:, 5]
    center = kernel.center[k] + np.column_stack([kernel.cos[k] * r[:, 1] - kernel.sin[k] * r[:, 2],
                                                 kernel.sin[k] * r[:, 1] + kernel.cos[k] * r[:, 2]])
    angle = np.array([buildings[i].angle_deg for i in k])
    return Chimneys(center, r[:, 3:5].copy(), angle, np.round(top, 2), k)


def _make_bridges(t: Terrain, roads: tuple[Road, ...]) -> tuple[Bridge, ...]:
    out = []
    for r in roads:
        if r.axis != "x":
            continue
        y = np.array([r.center])
        w = 2 * math.pi / t.river_wavelength
        slope = t.river_amp * w * math.cos(w * (r.center - t.y0) + t.river_phase)
        half = (t.channel_half_width + t.bank_width + 3.0) * math.sqrt(1.0 + slope * slope)
        xc = float(t.river_center_x(y)[0])
        zw, ze = t.height(np.array([xc - half, xc + half]), np.array([r.center, r.center]))
        # The deck sits a little above the valley floor at both abutments: a small step, then the span.
        out.append(Bridge(xc - half, xc + half, r.center - r.half_width + 1.0, r.center + r.half_width - 1.0,
                          float(zw) + 0.6, float(ze) + 0.6))
    return tuple(out)


def _make_trees(rng: np.random.Generator, t: Terrain, roads: tuple[Road, ...], buildings: tuple[Building, ...],
                kernel: _BuildingKernel, xb: list[tuple[float, float]], yb: list[tuple[float, float]]) -> Trees:
    ext = t.extent
    step = 7.0
    n = max(1, int(ext // step))
    g = (np.arange(n) + 0.5) * step
    gx, gy = (a.ravel() for a in np.meshgrid(g, g))
    x = t.x0 + gx + rng.uniform(-0.45, 0.45, gx.size) * step
    y = t.y0 + gy + rng.uniform(-0.45, 0.45, gy.size) * step
    d = t.river_distance(x, y)
    lx, ly, lr = t.lake
    dl = np.hypot(x - t.x0 - lx, y - t.y0 - ly)
    east = x - t.river_center_x(y) > t.valley_half_width
    forest_c = np.array([0.9, 0.25]) * ext
    forest = np.hypot(x - t.x0 - forest_c[0], y - t.y0 - forest_c[1]) < 0.14 * ext
    park = (dl < lr + 0.15 * ext) if lr > 0 else np.zeros(x.shape, bool)
    riparian = (d > t.channel_half_width + t.bank_width + 1.0) & (d < t.valley_half_width)
    p = np.where(forest, 0.9, np.where(park, 0.55, np.where(riparian, 0.35, np.where(east, 0.01, 0.1))))
    keep = rng.random(x.size) < p
    # Street trees: a row along each east–west road in the town, one pavement side.
    sx, sy = [], []
    for r in roads:
        if r.axis == "x":
            xs = np.arange(t.x0 + 6.0, t.river_center_x(np.array([r.center]))[0] - t.valley_half_width, 12.0)
            sx.append(xs)
            sy.append(np.full(xs.shape, r.center + r.half_width + 1.8))
    x = np.concatenate([x[keep], *sx])
    y = np.concatenate([y[keep], *sy])
    street = np.concatenate([np.zeros(int(keep.sum()), bool), *[np.ones(len(a), bool) for a in sx]])
    radius = np.where(street, rng.uniform(2.0, 3.2, x.size), rng.uniform(2.2, 5.0, x.size))
    height = radius * rng.uniform(2.0, 3.4, x.size) + 2.0
    depth = np.minimum(radius * rng.uniform(1.0, 1.5, x.size), height - 2.0)
    # Reject crowns over water, roads, buildings (centre plus 8 rim points) and beyond the edge.
    ok = ~t.water_mask(x, y) & (t.river_distance(x, y) > t.channel_half_width + t.bank_width + radius)
    ok &= np.hypot(x - t.x0 - lx, y - t.y0 - ly) > lr + radius + 1.0
    for r in roads:
        # Street trees may overhang the pavement; others keep most of the crown off the road.
        across = y if r.axis == "x" else x
        ok &= np.abs(across - r.center) > r.half_width + np.where(street, -0.5, radius * 0.6)
    theta = np.linspace(0.0, 2 * np.pi, 8, endpoint=False)
    px = np.concatenate([x, (x[:, None] + (radius[:, None] + 0.5) * np.cos(theta)).ravel()])
    py = np.concatenate([y, (y[:, None] + (radius[:, None] + 0.5) * np.sin(theta)).ravel()])
    hit = _any_building(kernel, px, py, t)
    ok &= ~hit[: x.size] & ~hit[x.size :].reshape(x.size, 8).any(axis=1)
    ok &= (x - t.x0 > 1.0) & (x - t.x0 < ext - 1.0) & (y - t.y0 > 1.0) & (y - t.y0 < ext - 1.0)
    x, y, radius, height, depth = x[ok], y[ok], radius[ok], height[ok], depth[ok]
    ground = t.height(x, y)
    return Trees(np.column_stack([x, y]), radius, np.round(height, 2), ground, depth)


def _any_building(kernel: _BuildingKernel, x: F64, y: F64, t: Terrain) -> Bool:
    if len(kernel.boxes) == 0:
        return np.zeros(x.shape, bool)
    n = max(1, math.ceil(t.extent / _CELL))
    pi, ki = _BoxIndex.build(kernel.boxes, t.x0, t.y0, n, n).pairs(x, y)
    u, v = kernel.local(x[pi], y[pi], ki)
    out = np.zeros(x.shape, bool)
    out[pi[kernel.contains(u, v, ki, 0.5)]] = True
    return out
