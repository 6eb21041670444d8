"""Tiles drawn in vertex-cache order (render/mesh_order.py): the same triangles, the same picture, and
far fewer vertex shader runs per triangle than the builder's order."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest

from citylod.core.camera import Camera
from citylod.io.tiles3d import open_tileset
from citylod.lod.build.dsm import build_dsm
from citylod.render.mesh_order import ENV, cache_order
from citylod.render.offscreen import render_images
from citylod.sample.files import make_sample


def _acmr(faces: np.ndarray, cache: int = 32) -> float:
    """Vertex shader runs per triangle with a FIFO post-transform cache of ``cache`` entries (computed
    here, independently of the module, the way llvmpipe's draw module reuses vertices)."""
    q: deque[int] = deque()
    held: set[int] = set()
    miss = 0
    for v in faces.ravel().tolist():
        if v not in held:
            miss += 1
            if len(q) == cache:
                held.discard(q.popleft())
            q.append(v)
            held.add(v)
    return miss / (len(faces.ravel()) / 3)


def _grid_in_random_order(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    g = np.arange(n, dtype=np.float32)
    xx, yy = np.meshgrid(g, g)
    pos = np.stack([xx.ravel(), yy.ravel(), np.sin(xx.ravel()) * 3], 1).astype(np.float32)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1))
    a = (j * n + i).ravel()
    faces = np.concatenate([np.stack([a, a + 1, a + n + 1], 1), np.stack([a, a + n + 1, a + n], 1)])
    rng = np.random.default_rng(seed)
    return pos, faces[rng.permutation(len(faces))]


def _oriented(pos: np.ndarray, faces: np.ndarray) -> list[tuple[float, ...]]:
    """Each triangle as its corner coordinates, rotated to start at its smallest corner (winding kept), in
    the faces' order."""
    out = []
    for tri in pos[faces.reshape(-1, 3)].tolist():
        k = min(range(3), key=lambda i: tri[i])
        out.append(tuple(v for c in tri[k:] + tri[:k] for v in c))
    return out


def _triangles(pos: np.ndarray, faces: np.ndarray) -> set[tuple[float, ...]]:
    """The triangles of :func:`_oriented`, in any order."""
    return set(_oriented(pos, faces))


def test_same_triangles_and_winding_in_cache_order() -> None:
    pos, faces = _grid_in_random_order(60)
    surface, skirt = faces[:-200].ravel(), faces[-200:].ravel()
    perm, (s2, k2) = cache_order(pos, surface, skirt)
    assert sorted(perm.tolist()) == list(range(len(pos)))
    new = pos[perm]
    assert _triangles(new, s2) == _triangles(pos, surface)
    assert _triangles(new, k2) == _triangles(pos, skirt)
    before, after = _acmr(surface.reshape(-1, 3)), _acmr(s2.reshape(-1, 3))
    assert before > 2.0  # random order: nearly every corner shaded again
    assert after < 0.9, (before, after)


def test_every_vertex_is_kept_and_attributes_follow() -> None:
    """Unused vertices stay (per-vertex arrays keep their length), and ``perm`` maps the triangles."""
    pos = np.random.default_rng(1).random((10, 3)).astype(np.float32)
    faces = np.array([7, 3, 5, 3, 7, 9])
    perm, (f,) = cache_order(pos, faces)
    assert sorted(perm.tolist()) == list(range(10))
    assert _triangles(pos[perm], f) == _triangles(pos, faces)


@pytest.mark.render
def test_tiles_in_cache_order_draw_the_same_picture(tmp_path, monkeypatch) -> None:
    info = make_sample(tmp_path / "sample", size=129, seed=3)
    build_dsm(info.files["dsm"], tmp_path / "tiles", tile_size=33, workers=0, progress=False)
    lo, hi = open_tileset(tmp_path / "tiles").bounds
    c, ext = (lo + hi) / 2, hi[0] - lo[0]
    cam = Camera((c[0] - ext, c[1] - 0.8 * ext, hi[2] + 0.5 * ext), (c[0], c[1], lo[2]), fovy_deg=50)
    frames = {}
    for mode in ("file", "cache"):
        monkeypatch.setenv(ENV, mode)
        frames[mode] = render_images([tmp_path / "tiles"], [cam], size=(320, 240), tau_px=1.0, depth=True)[0]
    (rgb_a, depth_a), (rgb_b, depth_b) = frames["file"], frames["cache"]
    assert np.isfinite(depth_a).mean() > 0.2  # the city fills a good part of the frame
    # Same triangles: the same pixels covered, at the same depth; colours equal but for ties on shared
    # edges, where the rasteriser may pick the other of two equal-depth triangles.
    assert np.array_equal(np.isfinite(depth_a), np.isfinite(depth_b))
    both = np.isfinite(depth_a)
    assert np.abs(depth_a[both] - depth_b[both]).max() <= 1e-4 * depth_a[both].max()
    assert (np.abs(rgb_a.astype(int) - rgb_b.astype(int)).max(axis=2) > 2).mean() < 1e-3
