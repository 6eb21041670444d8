"""Roof refinement (:mod:`citylod.lod.build.refine`) on a gabled roof made here: two planes at 35° meeting
at a ridge, ≈ 10 points/m² with 5 cm of range noise. The error is measured against the two planes."""

from __future__ import annotations

import math

import numpy as np

from citylod.lod.build.refine import RefineOptions, refine_roofs

SLOPE = math.tan(math.radians(35.0))
RIDGE_Z = 10.0


def _roof_distance(xyz: np.ndarray) -> np.ndarray:
    """Distance from points to the gabled roof z = RIDGE_Z - SLOPE·|y| (the nearer of its two planes,
    extended: near the ridge that is the ridge's own error)."""
    y, z = xyz[:, 1], xyz[:, 2]
    d1 = np.abs(z - (RIDGE_Z - SLOPE * y)) / math.hypot(1.0, SLOPE)
    d2 = np.abs(z - (RIDGE_Z + SLOPE * y)) / math.hypot(1.0, SLOPE)
    return np.minimum(d1, d2)


def _gable(seed: int = 0, n: int = 1200) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    xy = rng.uniform([0.0, -5.0], [12.0, 5.0], (n, 2))
    true = np.column_stack([xy, RIDGE_Z - SLOPE * np.abs(xy[:, 1])])
    noisy = true + np.column_stack([np.zeros((n, 2)), rng.normal(0.0, 0.05, n)])
    return noisy + [85_000.0, 447_500.0, 0.0], true


def test_refinement_removes_noise_and_keeps_the_ridge() -> None:
    noisy, _ = _gable()
    off = [85_000.0, 447_500.0, 0.0]
    ref, normals = refine_roofs(noisy)
    before, after = _roof_distance(noisy - off), _roof_distance(ref - off)
    inner = (ref[:, 0] - off[0] > 1.5) & (ref[:, 0] - off[0] < 10.5)  # away from the gable ends
    ridge = np.abs(noisy[:, 1] - off[1]) < 0.5
    # Range noise halved or better on the planes ...
    assert np.sqrt(np.mean(after[inner & ~ridge] ** 2)) <= 0.5 * np.sqrt(np.mean(before[inner & ~ridge] ** 2))
    # ... and the ridge no rounder than it was, where isotropic smoothing (normal weights off) rounds it.
    iso, _ = refine_roofs(noisy, opts=RefineOptions(sigma_n=1e6))
    iso_err = _roof_distance(iso - off)
    assert np.median(after[inner & ridge]) <= np.median(before[inner & ridge])
    assert np.median(after[inner & ridge]) < 0.5 * np.median(iso_err[inner & ridge])
    # Normals: up, and on each side within 5° of that plane's.
    side = np.sign(noisy[:, 1] - off[1])
    true_n = np.column_stack([np.zeros(len(side)), side * SLOPE, np.ones(len(side))]) / math.hypot(1.0, SLOPE)
    ang = np.degrees(np.arccos(np.clip(np.sum(normals * true_n, axis=1), -1, 1)))
    assert np.all(normals[:, 2] > 0) and np.percentile(ang[inner & ~ridge], 95) <= 5.0


def test_points_move_only_along_their_normal_and_buildings_do_not_mix() -> None:
    noisy, _ = _gable(1, 600)
    opts = RefineOptions(max_move_m=0.02)
    ref, normals = refine_roofs(noisy, opts=opts)
    move = ref - noisy
    along = np.sum(move * normals, axis=1)
    assert np.abs(along).max() <= 0.02 + 1e-9
    assert np.allclose(move, along[:, None] * normals, atol=1e-9)
    # A second building 1 m above the first (its own label): with labels, each refines as if alone.
    other = noisy + [0.0, 0.0, 1.0]
    both = np.concatenate([noisy, other])
    labels = np.repeat([1, 2], len(noisy))
    ref2, _ = refine_roofs(both, labels, opts)
    alone, _ = refine_roofs(other, opts=opts)
    assert np.allclose(ref2[: len(noisy)], ref, atol=1e-6) and np.allclose(ref2[len(noisy):], alone, atol=1e-6)
