"""Axis-aligned and oriented boxes, spheres, planes and 4×4 transforms in float64.

Bounding volumes follow 3D Tiles: an oriented box is a centre and three half-axis vectors. All maths is
float64; nothing here ever sees float32.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Box:
    """An oriented box: ``center`` (3,) and ``half_axes`` (3, 3), one half-axis per *column*.

    This is the 3D Tiles ``boundingVolume.box`` layout (centre, then x, y, z half-axis vectors), with the
    vectors stored as columns so that ``center + half_axes @ u`` for ``u`` in [-1, 1]³ spans the box.
    """

    center: F64
    half_axes: F64

    @staticmethod
    def from_bounds(lo: npt.ArrayLike, hi: npt.ArrayLike) -> Box:
        """Axis-aligned box from corners ``lo`` (3,) and ``hi`` (3,)."""
        lo_a = np.asarray(lo, dtype=np.float64)
        hi_a = np.asarray(hi, dtype=np.float64)
        return Box((lo_a + hi_a) / 2.0, np.diag((hi_a - lo_a) / 2.0))

    @staticmethod
    def from_3dtiles(values: npt.ArrayLike) -> Box:
        """From the 12 numbers of a 3D Tiles ``box``."""
        v = np.asarray(values, dtype=np.float64).reshape(12)
        return Box(v[:3].copy(), v[3:].reshape(3, 3).T.copy())

    @staticmethod
    def aabb_3dtiles(lo: Sequence[float], hi: Sequence[float]) -> list[float]:
        """``Box.from_bounds(lo, hi).to_3dtiles()`` in plain float arithmetic (the same numbers, without
        the numpy objects: a tileset writer calls it once per tile)."""
        mid = [(a + b) / 2.0 for a, b in zip(lo, hi, strict=True)]
        half = [(b - a) / 2.0 for a, b in zip(lo, hi, strict=True)]
        return [*mid, half[0], 0.0, 0.0, 0.0, half[1], 0.0, 0.0, 0.0, half[2]]

    def to_3dtiles(self) -> list[float]:
        """The 12 numbers of a 3D Tiles ``box``."""
        return [float(x) for x in np.concatenate([self.center, self.half_axes.T.reshape(9)])]

    def corners(self) -> F64:
        """The 8 corners, (8, 3) float64."""
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
        return self.center + signs @ self.half_axes.T

    def bounds(self) -> tuple[F64, F64]:
        """Axis-aligned (lo, hi) enclosing the box."""
        ext = np.abs(self.half_axes).sum(axis=1)
        return self.center - ext, self.center + ext

    def transformed(self, matrix: F64) -> Box:
        """The box under an affine 4×4 ``matrix`` (exact for affine maps)."""
        m = np.asarray(matrix, dtype=np.float64)
        c = m[:3, :3] @ self.center + m[:3, 3]
        return Box(c, m[:3, :3] @ self.half_axes)

    def distance(self, point: npt.ArrayLike) -> float:
        """Euclidean distance from ``point`` (3,) to the box (0 inside)."""
        p = np.asarray(point, dtype=np.float64) - self.center
        d = 0.0
        for i in range(3):
            axis = self.half_axes[:, i]
            length = float(np.linalg.norm(axis))
            if length == 0.0:
                continue
            t = float(p @ axis) / length
            excess = abs(t) - length
            if excess > 0:
                d += excess * excess
        return float(np.sqrt(d))

    def radius(self) -> float:
        """Radius of the bounding sphere about the centre (exact for orthogonal half-axes)."""
        return float(np.sqrt((self.half_axes**2).sum()))


@dataclass(frozen=True)
class Sphere:
    """A sphere: ``center`` (3,), ``radius`` in metres (of the frame it lives in)."""

    center: F64
    radius: float

    def distance(self, point: npt.ArrayLike) -> float:
        """Distance from ``point`` (3,) to the sphere (0 inside)."""
        return max(0.0, float(np.linalg.norm(np.asarray(point, dtype=np.float64) - self.center)) - self.radius)

    def transformed(self, matrix: F64) -> Sphere:
        """The sphere under an affine 4×4 ``matrix``; the radius scales with the largest axis scale."""
        m = np.asarray(matrix, dtype=np.float64)
        scale = float(np.max(np.linalg.norm(m[:3, :3], axis=0)))
        return Sphere(m[:3, :3] @ self.center + m[:3, 3], self.radius * scale)

    def bounds(self) -> tuple[F64, F64]:
        """Axis-aligned (lo, hi) enclosing the sphere."""
        return self.center - self.radius, self.center + self.radius


def translation(offset: npt.ArrayLike) -> F64:
    """A 4×4 translation matrix."""
    m = np.eye(4)
    m[:3, 3] = np.asarray(offset, dtype=np.float64)
    return m


def transform_points(matrix: F64, points: npt.ArrayLike) -> F64:
    """Apply an affine 4×4 ``matrix`` to ``points`` (N, 3); float64 result."""
    p = np.asarray(points, dtype=np.float64)
    return p @ matrix[:3, :3].T + matrix[:3, 3]
