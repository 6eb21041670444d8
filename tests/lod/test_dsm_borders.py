"""Stage 2 of the DSM build: neighbours' border vertices inserted into a finished TIN without re-meshing."""

from __future__ import annotations

import numpy as np
import pytest

from citylod.lod.build.dsm import _border_sets, _insert_border_vertices
from citylod.lod.kernels.tin import coverage_check, max_vertical_error, triangulate


def _signed_areas(vij: np.ndarray, faces: np.ndarray) -> np.ndarray:
    x, y = vij[:, 1].astype(float), -vij[:, 0].astype(float)  # counter-clockwise in (x = col, y = -row)
    a, b, c = faces[:, 0], faces[:, 1], faces[:, 2]
    return 0.5 * ((x[b] - x[a]) * (y[c] - y[a]) - (x[c] - x[a]) * (y[b] - y[a]))


@pytest.mark.parametrize("seed", range(6))
def test_inserted_border_vertices_keep_a_valid_tin(seed) -> None:
    rng = np.random.default_rng(seed)
    n = 33
    yy, xx = np.mgrid[0:n, 0:n].astype(float)
    z = 3 * np.sin(xx / 5.0) * np.cos(yy / 7.0) + rng.normal(0, 0.05, (n, n))
    valid = np.ones((n, n), bool)
    if seed % 2:
        valid[10:20, 25:] = False  # no-data reaching the east border
        valid[:4, 8:12] = False  # and the north border
    vij, faces = triangulate(z, valid, 0.8)
    last = n - 1
    extra = {s: tuple(int(v) for v in rng.choice(n, 9, replace=False)) for s in ("n", "s", "w", "e")}
    vij2, faces2, replaced = _insert_border_vertices(vij, faces, extra, last, last)
    assert np.array_equal(faces2[:len(faces) - len(replaced)], faces[~(faces[:, None, :] == replaced[None, :, :]).all(2).any(1)])
    assert np.array_equal(vij2[:len(vij)], vij)
    area = _signed_areas(vij2, faces2)
    assert np.all(area > 0)  # counter-clockwise, none degenerate
    cov = coverage_check(valid, vij2, faces2)
    cell_valid = valid[:-1, :-1] & valid[1:, :-1] & valid[:-1, 1:] & valid[1:, 1:]
    np.testing.assert_allclose(cov, cell_valid.astype(float), atol=1e-9)  # same cover, nothing twice
    # every requested sample on a border stretch with surface is now a vertex there, and no other
    before, after = _border_sets(vij, last, last), _border_sets(vij2, last, last)
    for side, idx in extra.items():
        lo_hi = np.array(before[side])
        for p in idx:
            spanned = False
            # spanned iff some surface border edge of the old TIN passes over p
            r, c = vij[:, 0], vij[:, 1]
            for k in range(3):
                a, b = faces[:, k], faces[:, (k + 1) % 3]
                line = {"n": 0, "s": last, "w": 0, "e": last}[side]
                if side in "ns":
                    on = (r[a] == line) & (r[b] == line)
                    u, w = c[a], c[b]
                else:
                    on = (c[a] == line) & (c[b] == line)
                    u, w = r[a], r[b]
                spanned |= bool(np.any(on & (np.minimum(u, w) < p) & (np.maximum(u, w) > p)))
            assert (p in after[side]) == (spanned or p in lo_hi), (side, p)
    err, _ = max_vertical_error(z, valid, vij2, faces2)
    assert np.isfinite(err)


def test_nothing_to_insert_returns_the_input() -> None:
    z = np.zeros((9, 9))
    vij, faces = triangulate(z, None, 0.1)
    out_v, out_f, replaced = _insert_border_vertices(vij, faces, {"n": (0, 8)}, 8, 8)  # corners: vertices already
    assert out_v is vij and out_f is faces and len(replaced) == 0


def _finish_or_interrupt(job):
    """Stage 2 that finishes some leaves and interrupts the build at the others (module level and stateless,
    so it behaves the same inline, on threads and on forked workers)."""
    import citylod.lod.build.dsm as dsm

    if job.level > 0 and (job.row + 2 * job.col) % 3 == 0:
        raise KeyboardInterrupt("simulated interruption")
    return dsm._real_finish_tile(job)


def _no_stage_one(job):
    raise AssertionError(f"stage 1 of tile {job.level}/{job.row}/{job.col} redone on resume")


@pytest.mark.parametrize("workers", [0, None], ids=["inline", "default"])
def test_interrupted_in_stage_two_resumes_with_matching_borders(tmp_path, monkeypatch, workers) -> None:
    """Stop after some tiles were finished: the resumed build redoes no stage-1 work and neighbours still
    match (finished tiles and the rest were fitted to the same stage-1 borders). With the default executor
    (threads, or forked workers), the records journalled by the pool's workers are what the resume reads."""
    import citylod.lod.build.dsm as dsm
    from citylod.io.tiles3d import open_tileset
    from tests.lod.test_dsm import _borders_match, check_tileset, city_like, write_raster

    z = city_like(200, 200, seed=4)
    write_raster(tmp_path / "dsm.tif", z)
    dsm._preload_kernels()  # a fork build preloads with an inline build, which must not meet the patches
    monkeypatch.setattr(dsm, "_real_finish_tile", dsm.finish_tile, raising=False)
    monkeypatch.setattr(dsm, "finish_tile", _finish_or_interrupt)
    with pytest.raises(KeyboardInterrupt):
        dsm.build_dsm(tmp_path / "dsm.tif", tmp_path / "out", tile_size=65, workers=workers, progress=False, metric="vertical")
    monkeypatch.setattr(dsm, "finish_tile", dsm._real_finish_tile)
    monkeypatch.setattr(dsm, "build_tile", _no_stage_one)
    rep = dsm.build_dsm(tmp_path / "dsm.tif", tmp_path / "out", tile_size=65, workers=workers, progress=False, metric="vertical")
    assert 0 < rep.resumed == rep.tiles
    check_tileset(tmp_path / "out", z, np.ones_like(z, bool))
    ts = open_tileset(tmp_path / "out")
    assert _borders_match({t.key: t for t in ts.walk()}, ts)
    assert not list((tmp_path / "out").rglob("*.tin"))


def test_block_wise_footprints_build_the_same_tiles(tmp_path, monkeypatch) -> None:
    """Footprints too large to hold are read in blocks (bounded memory); the tiles come out identical."""
    import citylod.lod.build.dsm as dsm
    from citylod.io.tiles3d import open_tileset
    from tests.lod.test_dsm import NODATA, city_like, write_raster

    z = city_like(150, 170, seed=2)
    z[60:80, 100:120] = NODATA
    write_raster(tmp_path / "dsm.tif", z)
    dsm.build_dsm(tmp_path / "dsm.tif", tmp_path / "whole", tile_size=33, workers=0, progress=False, metric="vertical")
    monkeypatch.setattr(dsm, "_WHOLE_FOOTPRINT_SAMPLES", 0)
    monkeypatch.setattr(dsm, "_BLOCK", 40)
    dsm.build_dsm(tmp_path / "dsm.tif", tmp_path / "blocks", tile_size=33, workers=0, progress=False, metric="vertical")
    a, b = list(open_tileset(tmp_path / "whole").walk()), list(open_tileset(tmp_path / "blocks").walk())
    assert [t.key for t in a] == [t.key for t in b]
    assert [t.geometric_error for t in a] == [t.geometric_error for t in b]
    for x in a:
        if x.content_uri:
            assert (tmp_path / "whole" / x.content_uri).read_bytes() == (tmp_path / "blocks" / x.content_uri).read_bytes()


def test_refit_keeps_every_vertex_and_the_border() -> None:
    from citylod.lod.build.dsm import _refit

    rng = np.random.default_rng(3)
    n = 33
    yy, xx = np.mgrid[0:n, 0:n].astype(float)
    z = 3 * np.sin(xx / 4.0) * np.cos(yy / 6.0) + rng.normal(0, 0.05, (n, n))
    valid = np.ones((n, n), bool)
    vij, faces = triangulate(z, valid, 0.3)
    vij2, _, _ = _insert_border_vertices(vij, faces, {"n": (3, 9, 17, 25), "e": (5, 6, 7)}, n - 1, n - 1)
    got = _refit(z, valid, vij2, 0.3, n - 1, n - 1)
    if got is not None:  # None only when the kernel needed one more border vertex
        v3, f3 = got
        assert {tuple(v) for v in vij2.tolist()} <= {tuple(v) for v in v3.tolist()}
        assert _border_sets(v3, n - 1, n - 1) == _border_sets(vij2, n - 1, n - 1)
        assert max_vertical_error(z, valid, v3, f3)[0] <= 0.3 + 1e-9
