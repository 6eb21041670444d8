"""Tile cache (LRU, hard byte budget, in-use pinning), memory-adjusted τ and the background loader.

Assertions are on counters and sets; synchronisation uses events, never sleeps or timings.
"""

from __future__ import annotations

import itertools
import random
import threading
from dataclasses import dataclass
from typing import Any

import pytest

from citylod.lod.runtime.cache import ResidentInfo, TauController, TileCache
from citylod.lod.runtime.loader import TileLoader


@dataclass(frozen=True)
class Stub:
    key: str
    point_count: int = 10


# -- TileCache --------------------------------------------------------------------------------------


def test_lru_evicts_least_recently_used_first() -> None:
    cache = TileCache(300)
    assert cache.put("a", 1, 100) and cache.put("b", 2, 100) and cache.put("c", 3, 100)
    assert cache.get("a") == 1  # a becomes most recent
    assert cache.put("d", 4, 100)
    assert "b" not in cache and {"a", "c", "d"} <= set(cache)
    assert cache.evict() == ["b"]
    assert cache.evict() == []  # reported once
    assert cache.bytes_used == 300


def test_in_use_tiles_are_never_evicted() -> None:
    cache = TileCache(300)
    for k in "abc":
        cache.put(k, k, 100)
    cache.touch(["a", "b"])
    assert cache.put("d", "d", 100)
    assert set(cache) == {"a", "b", "d"}
    assert cache.evict(target_bytes=0) == ["c", "d"]
    assert set(cache) == {"a", "b"}  # even asked to free everything, the frame's tiles stay


def test_put_refused_when_in_use_fills_the_budget() -> None:
    cache = TileCache(250)
    cache.put("a", "a", 100)
    cache.put("b", "b", 100)
    cache.touch(["a", "b"])
    assert not cache.can_fit("c", 100)
    assert cache.put("c", "c", 100) is False
    assert "c" not in cache and cache.bytes_used == 200
    assert cache.put("c", "c", 50)
    assert cache.put("big", 0, 1000) is False or cache.budget_bytes >= 1000
    cache.touch([])
    assert cache.put("e", "e", 250)  # nothing pinned: everything else may go
    assert set(cache) == {"e"}


def test_cache_never_exceeds_budget_under_random_use() -> None:
    rng = random.Random(7)
    budget = 5_000
    cache = TileCache(budget)
    refused = 0
    for step in range(2_000):
        op = rng.random()
        key = f"t{rng.randrange(60)}"
        if op < 0.6:
            refused += int(not cache.put(key, step, rng.randrange(0, 1_500)))
        elif op < 0.8:
            cache.get(key)
        elif op < 0.95:
            cache.touch(rng.sample([f"t{i}" for i in range(60)], rng.randrange(0, 20)))
        else:
            cache.evict()
        assert cache.bytes_used <= budget
        assert cache.bytes_used == sum(cache.residency()[k].bytes for k in cache)
        assert cache.in_use_bytes <= budget
    assert refused > 0  # the hard cap was exercised


def test_residency_reports_measured_costs() -> None:
    cache = TileCache(1_000)
    cache.put("a", object(), 123, points=45, triangles=6)
    res = cache.residency()
    assert res["a"] == ResidentInfo(bytes=123, triangles=6, points=45)
    with pytest.raises(TypeError):
        res["b"] = ResidentInfo()  # type: ignore[index]


def test_lowering_the_budget_evicts_but_keeps_in_use() -> None:
    cache = TileCache(400)
    for k in "abcd":
        cache.put(k, k, 100)
    cache.touch(["d"])
    evicted = cache.set_budget(150)
    assert evicted == ["a", "b", "c"]
    assert set(cache) == {"d"}


# -- TauController ----------------------------------------------------------------------------------


def test_tau_rises_under_pressure_and_eases_back() -> None:
    ctl = TauController(1.0, raise_factor=1.05, ease_factor=1.02, high_water=0.9, low_water=0.7)
    taus = [ctl.update(950, 1000) for _ in range(20)]
    assert all(b > a for a, b in itertools.pairwise(taus))  # rises every frame over 90 %
    assert taus[-1] == pytest.approx(1.05**20)
    peak = taus[-1]
    held = [ctl.update(800, 1000) for _ in range(10)]
    assert held == [peak] * 10  # hysteresis band: no thrashing between 70 % and 90 %
    eased = [ctl.update(500, 1000) for _ in range(200)]
    assert all(b <= a for a, b in itertools.pairwise(eased))
    assert eased[-1] == 1.0  # back to the user's τ, never below


def test_tau_is_capped() -> None:
    ctl = TauController(0.5, max_tau_px=4.0)
    for _ in range(1_000):
        ctl.update(2_000, 1_000)
    assert ctl.tau_px == 4.0
    ctl.reset()
    assert ctl.tau_px == 0.5


def test_tau_controller_rejects_bad_bands() -> None:
    with pytest.raises(ValueError):
        TauController(1.0, high_water=0.5, low_water=0.7)
    with pytest.raises(ValueError):
        TauController(0.0)


# -- TileLoader -------------------------------------------------------------------------------------


class GatedLoad:
    """A load_fn that blocks until released and records the order of calls."""

    def __init__(self, fail: set[str] | None = None) -> None:
        self.release = threading.Event()
        self.started = threading.Event()
        self.calls: list[str] = []
        self.fail = fail or set()
        self._lock = threading.Lock()

    def __call__(self, node: Any) -> tuple[str, int]:
        with self._lock:
            self.calls.append(node.key)
        self.started.set()
        assert self.release.wait(10.0), "test never released the loader"
        if node.key in self.fail:
            raise ValueError(f"corrupt tile {node.key}")
        return f"content of {node.key}", 100


def test_loader_decodes_in_background() -> None:
    load = GatedLoad()
    cache = TileCache(10_000)
    with TileLoader(load, cache, workers=2) as loader:
        assert loader.request([Stub("a"), Stub("b"), Stub("c")]) == 3
        assert load.started.wait(10.0)
        # request() returned while load_fn is still blocked: the caller's thread was not used.
        assert loader.poll() == []
        assert "a" not in cache
        load.release.set()
        assert loader.wait_idle(10.0)
        assert sorted(loader.poll()) == ["a", "b", "c"]
        assert cache.get("b") == "content of b"
        assert cache.info("b") == ResidentInfo(bytes=100, triangles=0, points=10)
        assert loader.request([Stub("a"), Stub("b")]) == 0  # resident: not loaded again
        assert loader.stats().loaded == 3


def test_loader_follows_priority_and_drops_stale_requests() -> None:
    load = GatedLoad()
    with TileLoader(load, TileCache(10_000), workers=1) as loader:
        loader.request([Stub("first")])
        assert load.started.wait(10.0)  # the single worker is now busy with "first"
        loader.request([Stub("x"), Stub("y"), Stub("z")])
        loader.request([Stub("z"), Stub("x")])  # the next frame: y no longer needed, z most needed
        load.release.set()
        assert loader.wait_idle(10.0)
        assert load.calls == ["first", "z", "x"]
        stats = loader.stats()
        assert stats.dropped == 1 and stats.pending == 0 and stats.in_flight == 0


def test_loader_records_failures_without_raising_and_never_retries() -> None:
    load = GatedLoad(fail={"bad"})
    load.release.set()
    cache = TileCache(10_000)
    with TileLoader(load, cache, workers=2) as loader:
        loader.request([Stub("good"), Stub("bad")])
        assert loader.wait_idle(10.0)
        assert loader.poll() == ["good"]
        assert set(loader.failed) == {"bad"}
        assert "corrupt tile bad" in loader.failed["bad"]
        assert loader.failed_keys() == frozenset({"bad"})
        for _ in range(5):  # later frames ask again: the failed tile is not retried
            loader.request([Stub("bad")])
            assert loader.wait_idle(10.0)
        assert load.calls.count("bad") == 1
        assert loader.stats().failed == 1


def test_loader_does_not_reload_what_the_cache_refused_until_it_fits() -> None:
    load = GatedLoad()
    load.release.set()
    cache = TileCache(150)
    cache.put("pinned", 0, 100)
    cache.touch(["pinned"])
    with TileLoader(load, cache, workers=1) as loader:
        loader.request([Stub("t")])
        assert loader.wait_idle(10.0)
        assert loader.poll() == []  # 100 + 100 > 150: refused
        assert loader.stats().refused == 1
        assert loader.request([Stub("t")]) == 0  # would be refused again
        cache.touch([])
        assert loader.request([Stub("t")]) == 1  # room now
        assert loader.wait_idle(10.0)
        assert loader.poll() == ["t"]
        assert load.calls == ["t", "t"]


def test_loader_stores_measured_counts_when_load_fn_gives_them() -> None:
    cache = TileCache(10_000)
    with TileLoader(lambda n: (n.key, 64, ResidentInfo(points=321, triangles=7)), cache) as loader:
        loader.request([Stub("m")])
        assert loader.wait_idle(10.0)
        assert loader.poll() == ["m"]
    assert cache.residency()["m"] == ResidentInfo(bytes=64, triangles=7, points=321)


def test_closed_loader_refuses_requests() -> None:
    loader = TileLoader(lambda n: (n.key, 1), TileCache(10))
    loader.close()
    loader.close()
    with pytest.raises(RuntimeError):
        loader.request([Stub("a")])


def test_eviction_order_hook_evicts_the_given_keys_first_and_never_in_use_ones() -> None:
    cache = TileCache(400)
    for k in "abcd":
        assert cache.put(k, k, 100)
    cache.get("a")  # LRU order now b, c, d, a
    cache.set_eviction_order(["d", "a", "b"])  # e.g. a texture priority, least important first
    cache.touch(["d"])  # in use: skipped though first in the order
    assert cache.put("e", "e", 200)
    assert cache.evict() == ["a", "b"]
    assert set(cache) == {"c", "d", "e"}
    cache.set_eviction_order(None)  # back to LRU
    cache.touch([])
    assert cache.put("f", "f", 100)
    assert cache.evict() == ["c"]


def test_peek_does_not_change_the_lru_order() -> None:
    cache = TileCache(200)
    assert cache.put("a", 1, 100) and cache.put("b", 2, 100)
    assert cache.peek("a") == 1 and cache.peek("zz", 5) == 5
    assert cache.put("c", 3, 100)
    assert cache.evict() == ["a"]  # a stayed least recently used
