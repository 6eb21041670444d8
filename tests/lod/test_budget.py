"""Budget mode: the PID controller holds a target frame time over the default flight.

The plant is the real selection (:func:`~citylod.lod.runtime.selection.select`) on a synthetic point
quadtree along :func:`~citylod.bench.flight.default_flight`: a frame's time is a fixed cost plus a cost per
drawn point, with ±5 % noise, so the frame time responds to τ and the point budget as a renderer's does.
The assertion is the issue's: within ±20 % of the target in at least 90 % of the frames. No clock is read.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from citylod.bench.flight import default_flight
from citylod.lod.runtime.budget import FrameTimeController
from citylod.lod.runtime.selection import Budget, select
from tests.lod.test_selection import quadtree, walk


def fly(target_ms: float, n: int, seed: int = 0, per_point_ms: float = 0.0004) -> tuple[list[float], list[int]]:
    root = quadtree(levels=7)
    resident = {node.key for node in walk(root)}
    rng = np.random.default_rng(seed)
    ctl = FrameTimeController(target_ms, base_tau_px=0.5, base_points=2_000_000)
    times, budgets = [], []
    for cam in default_flight((0, 0, 0), (1000, 1000, 20), n=n):
        from citylod.core.camera import View

        sel = select(root, View(cam, 1280, 720), tau_px=ctl.tau_px, budget=Budget(max_points=ctl.point_budget),
                     resident=resident)
        drawn = sum(node.point_count for node in sel.render)
        ms = (2.0 + per_point_ms * drawn) * float(np.exp(rng.normal(0, 0.05)))
        times.append(ms)
        budgets.append(ctl.point_budget)
        ctl.update(ms, drawn, sel.stats.budget_limited)
    return times, budgets


@pytest.mark.parametrize(("target_ms", "per_point_ms"), [(16.0, 0.00014), (33.0, 0.0004), (60.0, 0.0004)])
def test_frame_time_held_within_20_percent_for_90_percent_of_frames(target_ms: float, per_point_ms: float) -> None:
    times, budgets = fly(target_ms, 90, per_point_ms=per_point_ms)
    within = np.abs(np.asarray(times) / target_ms - 1.0) <= 0.2
    assert within.mean() >= 0.9, (within.mean(), [round(t, 1) for t in times])
    assert max(budgets[5:]) < 2_000_000 / 4  # it steered: the user's budget would have drawn far more


def test_fixed_tau_misses_the_target() -> None:
    """Without the controller the same flight's frame times spread far beyond ±20 % (the test can fail)."""
    root = quadtree(levels=7)
    resident = {node.key for node in walk(root)}
    from citylod.core.camera import View

    times = [2.0 + 0.0004 * sum(n.point_count for n in select(root, View(c, 1280, 720), tau_px=2.0,
                                                            resident=resident).render)
             for c in default_flight((0, 0, 0), (1000, 1000, 20), n=90)]
    assert (np.abs(np.asarray(times) / np.median(times) - 1.0) <= 0.2).mean() < 0.9


def test_refinement_is_smooth_and_limits_hold() -> None:
    c = FrameTimeController(16.0, base_tau_px=1.0, max_scale=8.0)
    prev = c.tau_px
    for ms in [200.0] * 40 + [1.0] * 80:
        tau = c.update(ms)
        # coarser quickly (max_step_coarser), finer by at most max_step per frame: detail never jumps up
        assert tau / prev <= np.exp(c.max_step_coarser) + 1e-9 and prev / tau <= np.exp(c.max_step) + 1e-9
        prev = tau
    assert c.tau_px == pytest.approx(0.25)  # min_scale after a long run of fast frames
    assert c.point_budget is None
    c.reset()
    assert c.tau_px == 1.0


# -- the point-budget controller (feed-forward cost model + PI on the residual) ----------------------------
def loaded_plant(n: int, seed: int) -> tuple[list, object, np.ndarray, np.ndarray]:
    """The real selection over the default flight, with what a loaded machine adds: a cost per point that
    drifts ±40 % with the view (fill), 7 % noise per frame (log-normal) and one frame in fifty 2–4× slow."""
    from citylod.core.camera import View

    root = quadtree(levels=6)
    rng = np.random.default_rng(seed)
    cams = default_flight((0, 0, 0), (1000, 1000, 20), n=n)
    drift = 1.0 + 0.4 * np.sin(np.linspace(0, 3 * np.pi, n))
    noise = np.exp(rng.normal(0, 0.07, n)) * np.where(rng.random(n) < 0.02, rng.uniform(2, 4, n), 1.0)
    return [View(c, 1280, 720) for c in cams], root, drift, noise


def fly_points(ctl, views, root, drift, noise, per_point_ms: float = 0.0004) -> tuple[list[float], list[bool],
                                                                                       list[int]]:
    resident = {node.key for node in walk(root)}
    times, reachable, budgets = [], [], []
    for view, d, z in zip(views, drift, noise, strict=True):
        full = sum(nd.point_count for nd in select(root, view, tau_px=ctl.tau_px, resident=resident).render)
        sel = select(root, view, tau_px=ctl.tau_px, budget=Budget(max_points=ctl.point_budget), resident=resident)
        drawn = sum(nd.point_count for nd in sel.render)
        ms = (1.0 + per_point_ms * d * drawn) * z
        times.append(ms)
        reachable.append((1.0 + per_point_ms * d * full) >= 0.8 * ctl.target_ms)
        budgets.append(ctl.point_budget)
        ctl.update(ms, drawn, sel.stats.budget_limited)
    return times, reachable, budgets


def test_point_controller_holds_the_target_on_a_loaded_machine() -> None:
    """≥ 90 % of the reachable frames within ±20 % with ±40 % cost drift and 2–4× spikes, where the PID
    alone (same plant, same noise) holds fewer: the test tells the two apart."""
    from citylod.lod.runtime.budget import PointBudgetController

    target_ms = 33.0
    plant = loaded_plant(90, seed=1)
    new, reach, _ = fly_points(PointBudgetController(target_ms, base_points=2_000_000, base_tau_px=0.5), *plant)
    old, _, _ = fly_points(FrameTimeController(target_ms, base_tau_px=0.5, base_points=2_000_000), *plant)
    r = np.asarray(reach)
    assert r.mean() > 0.8  # the target is reachable on most of the flight

    def share(ts: list[float]) -> float:
        return float((np.abs(np.asarray(ts)[r] / target_ms - 1.0) <= 0.2).mean())

    assert share(new) >= 0.9, (share(new), [round(t) for t in new])
    assert share(new) > share(old)


def test_point_controller_refines_smoothly_and_follows_a_cut() -> None:
    """While the budget binds it grows by at most max_growth a frame; after frames whose budget did not bind
    (a sparse view) it goes straight to the model's budget, never past the user's."""
    from citylod.lod.runtime.budget import PointBudgetController

    c = PointBudgetController(100.0, base_points=1_000_000, max_growth=1.25)
    for _ in range(8):
        c.update(0.4e-3 * c.point_budget, c.point_budget, True)  # 0.4 µs a point: 250 k points cost 100 ms
    assert c.point_budget == pytest.approx(250_000, rel=0.1)
    prev = c.point_budget
    for _ in range(8):  # the machine got 4× faster: the budget rises, 25 % a frame at most
        b = c.update(0.1e-3 * c.point_budget, c.point_budget, True)
        assert b <= prev * 1.25 + 1
        prev = b
    assert prev == 1_000_000  # and stops at the user's budget
    c.reset()
    for _ in range(8):
        c.update(0.4e-3 * c.point_budget, c.point_budget, True)
    c.update(4.0, 10_000, False)  # a sparse view: everything it holds costs 4 ms
    assert c.point_budget == pytest.approx(250_000, rel=0.1)  # ready for the next dense view, not 12 500
    assert c.tau_px == c.base_tau_px  # τ stays the user's
    for _ in range(5):  # far, sparse views whose points are 4× cheaper each (they cover few pixels) ...
        c.update(1.0, 10_000, False)
    assert c.point_budget == pytest.approx(250_000, rel=0.1)  # ... do not raise it past the dense views' cost


# -- the feed-forward controller (cost model on the next frame's candidates + PI on the residual) ----------
def mixed_plant(n: int, seed: int) -> tuple[list, object, np.ndarray, np.ndarray, np.ndarray]:
    """The real selection over the default flight, plus what the point budget does not control: a mesh
    layer whose triangles ramp up over the low pass and jump at the cut into the orbit (a sudden view
    change), a cost per point drifting ±40 % (the machine's load), 7 % noise per frame and one frame in
    fifty 2–4× slow."""
    from citylod.core.camera import View

    root = quadtree(levels=6)
    rng = np.random.default_rng(seed)
    views = [View(c, 1280, 720) for c in default_flight((0, 0, 0), (1000, 1000, 20), n=n)]
    drift = 1.0 + 0.4 * np.sin(np.linspace(0, 3 * np.pi, n))
    noise = np.exp(rng.normal(0, 0.07, n)) * np.where(rng.random(n) < 0.02, rng.uniform(2, 4, n), 1.0)
    k = n // 3
    triangles = np.zeros(n)
    triangles[k:2 * k] = np.linspace(0, 75_000, k)
    triangles[2 * k:] = 150_000  # the cut: the orbit sees the whole mesh at once
    return views, root, drift, noise, triangles


def fly_mixed(ctl, views, root, drift, noise, triangles) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """ms = 2 + 0.1 µs·drift per point + 0.1 µs per triangle + 0.02 µs per point drawn for the first time."""
    from citylod.lod.runtime.budget import FeedForwardBudgetController

    resident = {nd.key for nd in walk(root)}
    times, reachable, budgets = [], [], []
    shown: set[str] = set()
    for view, d, z, tri in zip(views, drift, noise, triangles, strict=True):
        cand = select(root, view, tau_px=0.5, budget=Budget(max_points=ctl.base_points), resident=resident)
        if isinstance(ctl, FeedForwardBudgetController):
            curve, new = [], 0
            for pts, _, keys in cand.admitted:  # the candidates' cost curve, known before drawing
                new += sum(1000 for k in keys if k not in shown)
                curve.append((pts, int(tri), new))
            ctl.plan(curve)
        sel = select(root, view, tau_px=0.5, budget=Budget(max_points=ctl.point_budget), resident=resident)
        pts = sel.stats.points
        fresh = sum(nd.point_count for nd in sel.render if nd.key not in shown)
        shown = {nd.key for nd in sel.render}
        ms = (2.0 + 1e-4 * d * pts + 1e-4 * tri + 2e-5 * fresh) * z
        times.append(ms)
        reachable.append(2.0 + 1e-4 * d * cand.stats.points + 1e-4 * tri >= 0.8 * ctl.target_ms)
        budgets.append(ctl.point_budget)
        if isinstance(ctl, FeedForwardBudgetController):
            ctl.update(ms, pts, int(tri), fresh, sel.stats.budget_limited)
        else:
            ctl.update(ms, pts, sel.stats.budget_limited)
    return np.asarray(times), np.asarray(reachable), budgets


def test_feed_forward_holds_the_target_through_drift_and_a_view_change() -> None:
    """Over six seeds, on average ≥ 90 % of the reachable frames within ±20 % where the previous controller (a cost
    per point from the last frames, reacting after the fact) holds fewer than 90 %: it charges the mesh's
    triangles to the points and learns each change one frame late."""
    from citylod.lod.runtime.budget import FeedForwardBudgetController, PointBudgetController

    target_ms = 33.0
    new, old = [], []
    for seed in range(1, 7):
        plant = mixed_plant(90, seed)
        t, r, _ = fly_mixed(FeedForwardBudgetController(target_ms, base_points=2_000_000), *plant)
        assert r.mean() > 0.7
        new.append(float((np.abs(t[r] / target_ms - 1.0) <= 0.2).mean()))
        t, r, _ = fly_mixed(PointBudgetController(target_ms, base_points=2_000_000), *plant)
        old.append(float((np.abs(t[r] / target_ms - 1.0) <= 0.2).mean()))
    assert np.mean(new) >= 0.9, (new, old)
    assert np.mean(old) < 0.9, (new, old)
    assert np.mean(new) > np.mean(old) + 0.03, (new, old)


def test_feed_forward_meets_a_cut_in_the_frame_it_happens() -> None:
    """After a sparse view that drew everything it held, a cut to a dense view: the first dense frame's
    budget comes from its candidates and the fitted model (within ±20 % of the target at once), never past
    the budget before the sparse stretch × max_growth (no popping), and growth stays bounded a frame."""
    from citylod.lod.runtime.budget import FeedForwardBudgetController

    c = FeedForwardBudgetController(40.0, base_points=1_000_000)
    dense = [(k * 10_000, 0, k * 10_000) for k in range(1, 101)]  # 1 M points in view, all new
    cost = lambda pts, new: 3.0 + 1e-4 * pts + 1e-5 * new  # noqa: E731 (3 ms + 0.1 µs a point + uploads)
    drawn_before = 0
    for _ in range(10):  # settle on the dense view
        b = c.plan(dense)
        pts = max(p for p, _, _ in dense if p <= b)
        c.update(cost(pts, max(pts - drawn_before, 0)), pts, 0, max(pts - drawn_before, 0), True)
        drawn_before = pts
    settled = c.point_budget
    assert abs(cost(settled, 0) / 40.0 - 1.0) <= 0.2
    sparse = [(k * 10_000, 0, 0) for k in range(1, 5)]  # 40 k points: everything fits
    for _ in range(5):
        b = c.plan(sparse)
        assert b >= 40_000 and not c.reachable
        c.update(cost(40_000, 0), 40_000, 0, 0, False)
    assert c.point_budget <= settled * c.max_growth  # the sparse stretch did not raise it
    b = c.plan(dense)  # the cut
    pts = max(p for p, _, _ in dense if p <= b)
    assert abs(cost(pts, pts) / 40.0 - 1.0) <= 0.2, (b, cost(pts, pts))
    prev = b
    for _ in range(5):
        c.update(cost(pts, 0) * 0.5, pts, 0, 0, True)  # the machine got twice as fast
        b = c.plan(dense)
        assert b <= prev * c.max_growth + 1  # more detail arrives gradually
        prev = b
        pts = max(p for p, _, _ in dense if p <= b)


@pytest.mark.parametrize("cut_share", [0.7, 2.0])
def test_a_cut_into_a_costlier_view_is_priced_cautiously(cut_share: float) -> None:
    """Dense views cost 0.2 µs a point, then a sparse stretch at 0.1 µs a point (cheap far points), then a
    cut back to a new dense view. With cut handling (0.7) the cut frame is priced at the upper quartile of the
    recent speeds and the frame after it from the cut frame alone, so both land within ±20 %; without it
    (2.0: never a cut) the model carries the sparse stretch's speed into the dense view and the cut frame
    runs far over the target."""
    from citylod.lod.runtime.budget import FeedForwardBudgetController

    c = FeedForwardBudgetController(40.0, base_points=1_000_000, cut_share=cut_share)
    dense_a = [(k * 10_000, 0, 0) for k in range(1, 101)]
    for _ in range(12):
        b = c.plan(dense_a)
        pts = max(p for p, _, _ in dense_a if p <= b)
        c.update(2.0 + 2e-4 * pts, pts, 0, 0, True)
    for _ in range(6):  # 300 k cheap points, short of the target: drawn whole
        sparse = [(k * 10_000, 0, 0) for k in range(1, 31)]
        c.plan(sparse)
        c.update(2.0 + 1e-4 * 300_000, 300_000, 0, 0, False)
    dense_b = [(k * 10_000, 0, k * 10_000) for k in range(1, 101)]  # all new to the GL
    times = []
    for i in range(2):
        b = c.plan(dense_b if i == 0 else [(p, t, 0) for p, t, _ in dense_b])
        pts = max(p for p, _, _ in dense_b if p <= b)
        times.append(2.0 + 2e-4 * pts)
        c.update(times[-1], pts, 0, pts if i == 0 else 0, True)
    if cut_share < 1.0:
        assert all(abs(t / 40.0 - 1.0) <= 0.2 for t in times), times
    else:
        assert times[0] > 1.2 * 40.0, times  # the control: the failure the cut handling removes


@pytest.mark.parametrize("refine", ["ADD", "REPLACE"])
def test_admitted_curve_predicts_what_a_smaller_budget_draws(refine: str) -> None:
    """The planner's premise, checked against select itself: with a point budget B the drawn set has the
    points of the longest admitted prefix within B, for every B along the default flight."""
    from citylod.core.camera import View

    root = quadtree(levels=6, refine=refine)
    resident = {nd.key for nd in walk(root)}
    for cam in default_flight((0, 0, 0), (1000, 1000, 20), n=6):
        view = View(cam, 1280, 720)
        full = select(root, view, tau_px=0.5, resident=resident)
        curve = [p for p, _, _ in full.admitted]
        assert curve and curve[-1] == full.stats.points
        for b in sorted({curve[0], *curve[1::3], curve[-1] - 1, (curve[0] + curve[-1]) // 2}):
            expect = curve[0]
            for p in curve:
                if p > b:
                    break
                expect = p
            got = select(root, view, tau_px=0.5, budget=Budget(max_points=max(b, 1)), resident=resident)
            assert got.stats.points == expect, (b, got.stats.points, expect)


@pytest.mark.parametrize("one_time_ms", [60.0, 200.0, 0.0])
def test_a_first_frame_that_built_its_buffers_is_forgotten(one_time_ms: float) -> None:
    """A renderer's first draw builds every buffer (uploads, shader compiles: 1.1–2× the same frame drawn
    again on the budget bench). Fitted as the points' cost, that one-time cost shrinks the next budget
    (the second frame is planned 1.25× over the model to meet part of it); the second frame, drawn well
    under the model's prediction, shows it, and the third frame's budget goes straight to the target
    instead of growing by max_growth a frame. Growth is bounded again after that. The control (no
    one-time cost): the hedged second frame stays within ±20 %, and the bound holds from the start."""
    from citylod.lod.runtime.budget import FeedForwardBudgetController

    c = FeedForwardBudgetController(40.0, base_points=1_000_000)
    curve = [(k * 10_000, 0, k * 10_000) for k in range(1, 101)]  # 1 M points, all new at first

    def cost(pts: int, new: int) -> float:
        return 3.0 + 1e-4 * pts + 1e-5 * new  # 3 ms + 0.1 µs a point + uploads

    shown, budgets, times = 0, [], []
    for i in range(8):
        b = c.plan([(p, t, max(p - shown, 0)) for p, t, _ in curve])
        pts = max(p for p, _, _ in curve if p <= b)
        new = max(pts - shown, 0)
        ms = cost(pts, new) + (one_time_ms if i == 0 else 0.0)
        c.update(ms, pts, 0, new, pts < curve[-1][0])
        budgets.append(b)
        times.append(ms)
        shown = max(shown, pts)
    assert all(abs(t / 40.0 - 1.0) <= 0.2 for t in times[2:]), times  # recovered at once
    if one_time_ms:
        assert times[1] < 0.8 * 40.0, times  # the first frame's cost taken for the points'
        assert budgets[2] > budgets[1] * c.max_growth, budgets
    else:
        assert abs(times[1] / 40.0 - 1.0) <= 0.2, times
    for prev, b in itertools.pairwise(budgets[2:]):
        assert b <= prev * c.max_growth + 1, budgets  # smooth refinement from then on
