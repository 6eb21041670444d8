"""Texture residency under a byte budget (Buchholz §4.6): never over budget, priority order, parents drawn
while children load; checked by simulating frames."""

from __future__ import annotations

import numpy as np

from citylod.lod.runtime.texture_budget import TextureNeed, plan_textures


def _tree(depth: int) -> dict[str, str | None]:
    parents: dict[str, str | None] = {"0": None}
    level = ["0"]
    for _ in range(depth):
        nxt = []
        for k in level:
            for i in range(4):
                parents[f"{k}/{i}"] = k
                nxt.append(f"{k}/{i}")
        level = nxt
    return parents


def test_simulated_flight_never_exceeds_the_budget_and_always_draws_something() -> None:
    parents = _tree(3)
    rng = np.random.default_rng(5)
    size = {k: int(rng.integers(1, 4)) * 1000 for k in parents}
    budget = 12_000
    resident: set[str] = set()
    for _frame in range(200):
        leaves = [k for k in parents if k.count("/") == 3]
        needed = set(rng.choice(leaves, size=int(rng.integers(1, 9)), replace=False))
        culled = set(rng.choice(leaves, size=3, replace=False)) - needed
        ancestors = {parents[k] for k in needed} - {None}
        needs = []
        for k, p in parents.items():
            role = "needed" if k in needed else "culled" if k in culled else "parent" if k in ancestors else "unused"
            needs.append(TextureNeed(k, p, size[k], role, float(rng.uniform(10, 500)), k.count("/"), k in resident))
        plan = plan_textures(needs, budget)
        assert plan.bytes <= budget
        assert sum(size[k] for k in plan.keep) == plan.bytes
        assert set(plan.evict) <= resident and not (set(plan.load) & resident)
        for k, d in plan.draw.items():
            assert d is None or (d in plan.keep and (d == k or k.startswith(d + "/")))
        resident = set(plan.keep)  # loads complete before the next frame
        # the root stays resident once loaded unless needed atlases push it out: something is drawn
        if "0" in resident:
            assert all(v is not None for v in plan_textures(
                [TextureNeed(n.key, n.parent, n.nbytes, n.role, n.distance_m, n.level, n.key in resident)
                 for n in needs], budget).draw.values())


def test_priority_order_needed_then_culled_then_parent_then_unused() -> None:
    needs = [TextureNeed("u", None, 10, "unused", 1.0, 0), TextureNeed("p", None, 10, "parent", 1.0, 0),
             TextureNeed("c", None, 10, "culled", 1.0, 0), TextureNeed("n2", None, 10, "needed", 9.0, 1),
             TextureNeed("n1", None, 10, "needed", 5.0, 1)]
    for budget, expect in ((10, ["n1"]), (20, ["n1", "n2"]), (30, ["n1", "n2", "c"]), (40, ["n1", "n2", "c", "p"]),
                           (50, ["n1", "n2", "c", "p", "u"])):
        plan = plan_textures(needs, budget)
        assert list(plan.load) == expect and plan.bytes == 10 * len(expect)
