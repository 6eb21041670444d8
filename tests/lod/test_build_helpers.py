"""The small pieces builds share: completion order of tasks, the shuffled point order, the quad atlas."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from citylod.lod.build import dsm
from citylod.lod.build.executor import Completions, fork_is_safe, make_executor, run_tasks
from citylod.lod.build.planes import PlaneResult, quad_mesh_arrays
from citylod.lod.kernels.octree import shuffled_runs


def test_completions_hand_back_futures_in_the_order_they_finish() -> None:
    gate = threading.Event()
    with ThreadPoolExecutor(2) as pool:
        done: Completions[str] = Completions()
        done.add(pool.submit(lambda: gate.wait(10) and "slow"))
        done.add(pool.submit(lambda: "fast"))
        assert done.next().result() == "fast"
        assert len(done) == 1
        gate.set()
        assert done.next().result() == "slow"
        assert not done


def _fail_on(k: int) -> int:
    if k == 3:
        raise ValueError("task 3")
    return k


def test_run_tasks_yields_every_result_and_reraises_a_failure() -> None:
    with ThreadPoolExecutor(2) as pool:
        assert sorted(run_tasks(pool, _fail_on, [(k,) for k in range(3)], progress=False)) == [0, 1, 2]
        with pytest.raises(ValueError, match="task 3"):
            list(run_tasks(pool, _fail_on, [(k,) for k in range(8)], progress=False, max_in_flight=2))


class _Job:
    """The two fields of a DsmJob that batching looks at."""

    def __init__(self, level: int, key: str) -> None:
        self.level, self.key = level, key


def _tile_key(job: _Job) -> tuple[str, int]:
    import os

    return job.key, os.getpid()


@pytest.mark.parametrize("workers", [0, 2])
def test_batched_tiles_run_once_each_crowded_levels_in_batches(workers: int) -> None:
    # a level of 3 tiles, one of 2 and one of 70: every job's result comes back exactly once, whatever the
    # executor; the 70 go four (consecutive ones) to a task, the others one to a task
    jobs = ([_Job(0, "0/0/0")] + [_Job(1, f"1/0/{k}") for k in range(3)] + [_Job(2, f"2/0/{k}") for k in range(70)]
            + [_Job(3, f"3/0/{k}") for k in range(2)])
    fork = workers > 0 and fork_is_safe()  # else threads (a spawned worker could not import this module)
    with make_executor(workers=workers, fork=fork, threads=workers > 0 and not fork) as ex:
        out = list(dsm._run_batched(ex, _tile_key, jobs, False, "test"))
    assert sorted(k for k, _ in out) == sorted(j.key for j in jobs)
    assert dsm._BATCH == 4 and dsm._BATCH_FROM == 64
    # consecutive tiles of the crowded level run in one task: in order, on one process
    crowded = [(k, pid) for k, pid in out if k.startswith("2/")]
    for b in range(0, 70, dsm._BATCH):
        chunk = [f"2/0/{k}" for k in range(b, min(b + dsm._BATCH, 70))]
        got = [x for x in crowded if x[0] in chunk]
        assert [k for k, _ in got] == chunk and len({pid for _, pid in got}) == 1


def test_batches_are_the_crowded_levels_only(monkeypatch: pytest.MonkeyPatch) -> None:
    import citylod.lod.build.executor as executor

    seen: list[list[str]] = []
    real = executor.run_tasks

    def recording(ex, fn, tasks, **kw):  # type: ignore[no-untyped-def]
        tasks = list(tasks)
        seen.extend([j.key for j in t[1]] for t in tasks)
        return real(ex, fn, tasks, **kw)

    monkeypatch.setattr(executor, "run_tasks", recording)
    jobs = [_Job(0, "0/0/0")] + [_Job(1, f"1/0/{k}") for k in range(3)] + [_Job(2, f"2/0/{k}") for k in range(66)]
    with make_executor(workers=0) as ex:
        list(dsm._run_batched(ex, _tile_key, jobs, False, "test"))
    assert seen[:4] == [["0/0/0"], ["1/0/0"], ["1/0/1"], ["1/0/2"]]
    assert [len(b) for b in seen[4:]] == [4] * 16 + [2]
    assert [k for b in seen[4:] for k in b] == [f"2/0/{k}" for k in range(66)]


@pytest.mark.parametrize("n_runs", [1, 2, 7, 1000])
def test_shuffled_runs_is_a_reproducible_permutation(n_runs: int) -> None:
    batch = 64
    runs = shuffled_runs(n_runs * batch - 5, seed=12345, batch=batch)
    assert np.array_equal(np.sort(runs), np.arange(n_runs))
    assert np.array_equal(runs, shuffled_runs(n_runs * batch - 5, seed=12345, batch=batch))
    if n_runs >= 7:
        assert not np.array_equal(runs, shuffled_runs(n_runs * batch - 5, seed=54321, batch=batch))
        assert not np.array_equal(runs, np.arange(n_runs))


def test_a_prefix_of_the_shuffled_runs_spreads_over_the_node() -> None:
    # what a renderer drawing the first k points relies on: any prefix is a near-uniform subsample
    runs = shuffled_runs(64 * 1000, seed=7, batch=64)
    for k in (50, 200):
        counts = np.bincount(runs[:k] * 10 // 1000, minlength=10)  # how many land in each tenth
        assert counts.min() >= k / 10 / 3 and counts.max() <= k / 10 * 3


def _plane_result(rng: np.random.Generator, n: int) -> PlaneResult:
    sizes = np.stack([rng.integers(1, 30, n), rng.integers(1, 30, n)], axis=1).astype(np.int64)
    tex_off = np.concatenate([[0], np.cumsum(4 * sizes[:, 0] * sizes[:, 1])]).astype(np.int64)
    tex = rng.integers(1, 256, tex_off[-1]).astype(np.uint8)
    corners = rng.normal(size=(n, 4, 3))
    return PlaneResult(corners, sizes, np.full(n, 40, np.int64), tex, tex_off, 0.5, np.zeros(0, bool),
                       np.zeros((0, 3)))


@pytest.mark.parametrize("n", [1, 5, 60])
def test_quad_atlas_holds_every_texture_once_where_its_uvs_point(n: int) -> None:
    res = _plane_result(np.random.default_rng(n), n)
    pos, faces, uv, atlas = quad_mesh_arrays(res)
    ah, aw = atlas.shape[:2]
    assert ah & (ah - 1) == 0 and aw & (aw - 1) == 0, (ah, aw)  # glTF clients mipmap only these
    assert np.array_equal(pos, res.corners.reshape(-1, 3).astype(np.float32))
    assert faces.shape == (2 * n, 3) and faces.max() == 4 * n - 1
    cover = np.zeros((ah, aw), int)
    for q in range(n):
        w, h = (int(v) for v in res.sizes[q])
        # the quad's uv corners, back in texels: (x, y), (x + w, y), (x + w, y + h), (x, y + h)
        t = np.rint(uv[4 * q:4 * q + 4].astype(np.float64) * [aw, ah]).astype(int)
        x, y = t[0]
        assert np.array_equal(t, [[x, y], [x + w, y], [x + w, y + h], [x, y + h]])
        assert np.array_equal(atlas[y:y + h, x:x + w], res.quad(q).rgba)
        cover[y:y + h, x:x + w] += 1
    assert cover.max() == 1  # no two textures overlap
    assert (atlas[cover == 0] == 0).all()  # the rest is transparent
