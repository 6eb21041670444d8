"""Plane quads of the hybrid point octree (`citylod.lod.build.planes`): a quad's rectangle hugs its patch.

The quad's size, its corners and where each replaced point went are checked against the patch's known
geometry, computed here from how the points were made.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from citylod.lod.build.planes import find_planes


def _patch(rng: np.random.Generator, length: float, width: float, angle_deg: float, n: int,
           diagonal_share: float = 0.0) -> np.ndarray:
    """Points on a flat rectangle ``length`` × ``width`` turned by ``angle_deg`` about the vertical, centred
    at the origin; ``diagonal_share`` of them on a band along the rectangle's diagonal (which pulls the
    principal axes of a square off its sides)."""
    k = int(n * diagonal_share)
    uv = rng.uniform(-0.5, 0.5, (n - k, 2))
    d = rng.uniform(-0.5, 0.5, k)
    band = np.column_stack([d, d + rng.uniform(-0.02, 0.02, k)])
    uv = np.clip(np.concatenate([uv, band]), -0.5, 0.5) * [length, width]
    a = math.radians(angle_deg)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    xy = uv @ rot.T
    return np.column_stack([xy, np.zeros(len(xy))])


def _quad_area(corners: np.ndarray) -> float:
    return float(np.linalg.norm(np.cross(corners[1] - corners[0], corners[3] - corners[0])))


def test_a_square_patch_gets_a_square_quad() -> None:
    """A square whose points crowd along its diagonal has principal axes at 45° to its sides; the quad
    follows the sides (the smallest rectangle), so its corners stay within a texel border of the square.
    Along the principal axes it would be twice the square, corners 20 m outside."""
    rng = np.random.default_rng(5)
    side, texel = 100.0, 1.0
    p = _patch(rng, side, side, 0.0, 40_000, diagonal_share=0.3)
    res = find_planes(p, np.full((len(p), 3), 128, np.uint8), texel, max_planes=1)
    assert res.n_quads == 1
    corners = res.corners[0]
    border = 2.5 * texel  # a texel of border each side, up to one of cell rounding, the hull edge's tilt
    assert np.all(np.abs(corners[:, :2]) <= side / 2 + border), corners
    assert _quad_area(corners) <= (side + 2 * border) ** 2


@pytest.mark.parametrize("angle", [0.0, 17.0, 30.0, 45.0, 72.0])
def test_a_turned_rectangle_gets_its_own_rectangle(angle: float) -> None:
    """Whatever its heading, a 120 × 40 m patch gets a quad of its own size, every point lies on the quad,
    and every replaced point moved to a texel centre no farther than the documented bound."""
    rng = np.random.default_rng(int(angle))
    length, width, texel = 120.0, 40.0, 1.0
    p = _patch(rng, length, width, angle, 30_000)
    res = find_planes(p, np.full((len(p), 3), 200, np.uint8), texel, max_planes=1)
    assert res.n_quads == 1
    corners = res.corners[0]
    assert _quad_area(corners) <= (length + 4 * texel) * (width + 4 * texel)
    # Every replaced point inside the quad: its coordinates along the quad's two edges within [0, 1].
    o, e1, e2 = corners[0], corners[1] - corners[0], corners[3] - corners[0]
    q = p[res.replaced] - o
    a = q @ e1 / (e1 @ e1)
    b = q @ e2 / (e2 @ e2)
    assert res.replaced.mean() > 0.99
    assert a.min() >= 0 and a.max() <= 1 and b.min() >= 0 and b.max() <= 1
    moved = np.linalg.norm(res.elem[res.replaced] - p[res.replaced], axis=1)
    assert moved.max() <= math.sqrt(texel ** 2 / 4 + texel ** 2 / 2) + 1e-9
