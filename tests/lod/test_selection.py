"""View-dependent selection on a synthetic quadtree: assertions on counters and sets, never on timings."""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
import pytest

from citylod.core.camera import Camera, View
from citylod.core.geometry import Box
from citylod.lod.runtime.cache import ResidentInfo, TileCache
from citylod.lod.runtime.loader import TileLoader, resolve
from citylod.lod.runtime.selection import Budget, TileNode, select

SIZE_M = 1000.0
LEVELS = 5  # 0..4: 1 + 4 + 16 + 64 + 256 tiles
ROOT_ERROR_M = 32.0
POINTS_PER_TILE = 1000


@dataclass
class Node:
    key: str
    level: int
    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    geometric_error: float
    refine: str = "REPLACE"
    content_uri: str | None = "x.glb"
    content_bytes: int = 10_000
    point_count: int = POINTS_PER_TILE
    triangle_count: int = 0
    children: list[Node] = field(default_factory=list)
    box: Box = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.box = Box.from_bounds(self.lo, self.hi)


def quadtree(levels: int = LEVELS, refine: str = "REPLACE", empty_levels: Sequence[int] = ()) -> Node:
    """Tiles over [0, 1000]² × [0, 20] m; error halves per level, leaves have error 0."""

    def make(level: int, ix: int, iy: int) -> Node:
        step = SIZE_M / 2**level
        err = 0.0 if level == levels - 1 else ROOT_ERROR_M / 2**level
        empty = level in empty_levels
        return Node(
            key=f"{level}/{ix}/{iy}",
            level=level,
            lo=(ix * step, iy * step, 0.0),
            hi=((ix + 1) * step, (iy + 1) * step, 20.0),
            geometric_error=err,
            refine=refine,
            content_uri=None if empty else f"tiles/{level}/{ix}/{iy}.glb",
            content_bytes=0 if empty else 10_000,
            point_count=0 if empty else POINTS_PER_TILE,
        )

    root = make(0, 0, 0)
    stack = [root]
    while stack:
        node = stack.pop()
        if node.level == levels - 1:
            continue
        ix, iy = (int(v) for v in node.key.split("/")[1:])
        node.children = [make(node.level + 1, 2 * ix + dx, 2 * iy + dy) for dy in (0, 1) for dx in (0, 1)]
        stack.extend(node.children)
    return root


def walk(root: Node) -> list[Node]:
    out, stack = [], [root]
    while stack:
        n = stack.pop()
        out.append(n)
        stack.extend(n.children)
    return out


def all_keys(root: Node) -> set[str]:
    return {n.key for n in walk(root)}


def overview_view() -> View:
    """Low over the centre looking straight down, every tile in view and close."""
    cam = Camera((500.0, 500.0, 600.0), (500.0, 500.0, 0.0), (0.0, 1.0, 0.0), 100.0)
    return View(cam, 800, 600)


def far_view() -> View:
    cam = Camera((500.0, -100_000.0, 50_000.0), (500.0, 500.0, 0.0), (0.0, 0.0, 1.0), 45.0)
    return View(cam, 800, 600)


def corner_view() -> View:
    """Low near the (0, 0) corner looking across the area."""
    cam = Camera((-50.0, -50.0, 100.0), (500.0, 500.0, 0.0), (0.0, 0.0, 1.0), 60.0)
    return View(cam, 800, 600)


def footprint_area(nodes: Sequence[Any]) -> float:
    return sum((n.hi[0] - n.lo[0]) * (n.hi[1] - n.lo[1]) for n in nodes)


def no_ancestor_pairs(nodes: Sequence[Any]) -> bool:
    keys = {n.key for n in nodes}
    for n in nodes:
        level, ix, iy = (int(v) for v in n.key.split("/"))
        while level > 0:
            level, ix, iy = level - 1, ix // 2, iy // 2
            if f"{level}/{ix}/{iy}" in keys:
                return False
    return True


def test_node_satisfies_protocol() -> None:
    assert isinstance(quadtree(), TileNode)


def test_far_away_selects_root_only() -> None:
    root = quadtree()
    sel = select(root, far_view(), tau_px=1.0, resident=all_keys(root))
    assert [n.key for n in sel.render] == ["0/0/0"]
    assert sel.request == []
    assert sel.stats.selected == 1
    assert sel.stats.depth == 0
    assert sel.stats.points == POINTS_PER_TILE
    assert sel.stats.max_sse_px <= 1.0


def test_close_up_selects_every_leaf() -> None:
    root = quadtree()
    sel = select(root, overview_view(), tau_px=0.5, resident=all_keys(root))
    assert sel.stats.culled == 0
    assert sel.stats.selected == 4 ** (LEVELS - 1)
    assert all(not n.children for n in sel.render)
    assert sel.stats.depth == LEVELS - 1
    assert sel.stats.points == 4 ** (LEVELS - 1) * POINTS_PER_TILE
    assert sel.stats.max_sse_px == 0.0  # leaves are exact
    assert sel.request == []
    assert footprint_area(sel.render) == pytest.approx(SIZE_M**2)


def test_selection_is_pure_and_deterministic() -> None:
    root = quadtree()
    resident = all_keys(root)
    a = select(root, corner_view(), tau_px=2.0, resident=resident)
    b = select(root, corner_view(), tau_px=2.0, resident=resident)
    assert [n.key for n in a.render] == [n.key for n in b.render]
    assert a.stats == b.stats


def test_nothing_behind_the_camera_is_selected() -> None:
    root = quadtree()
    cam = Camera((500.0, 500.0, 30.0), (1000.0, 500.0, 0.0), (0.0, 0.0, 1.0), 60.0)
    view = View(cam, 800, 600)
    sel = select(root, view, tau_px=1.0, resident=all_keys(root))
    assert sel.stats.culled > 0
    assert sel.stats.selected > 0
    fwd = cam.direction
    for n in sel.render + [n for n in walk(root) if n.key in sel.request]:
        # Independent check: some corner of every drawn or requested box lies in front of the eye.
        depth = (n.box.corners() - view.eye) @ fwd
        assert depth.max() > 0.0, n.key
    # Tiles wholly at x < 450 (behind, given the 60° fov) are never drawn.
    assert all(n.hi[0] > 450.0 for n in cast(list[Node], sel.render))


def test_point_budget_is_respected() -> None:
    root = quadtree()
    unlimited = select(root, overview_view(), tau_px=0.5, resident=all_keys(root))
    budget = Budget(max_points=20_000)
    sel = select(root, overview_view(), tau_px=0.5, budget=budget, resident=all_keys(root))
    assert unlimited.stats.points > 20_000
    assert sel.stats.budget_limited
    assert 0 < sel.stats.points <= 20_000
    assert sel.stats.selected < unlimited.stats.selected
    assert no_ancestor_pairs(sel.render)
    assert footprint_area(sel.render) == pytest.approx(SIZE_M**2)  # budget never makes holes
    # Measured costs from the resident mapping take precedence over the hints.
    info = {k: ResidentInfo(bytes=1, points=100, triangles=0) for k in all_keys(root)}
    measured = select(root, overview_view(), tau_px=0.5, budget=budget, resident=info)
    assert measured.stats.points <= 20_000
    assert measured.stats.selected > sel.stats.selected


def test_root_is_drawn_even_over_budget() -> None:
    root = quadtree()
    sel = select(root, overview_view(), tau_px=0.5, budget=Budget(max_points=10), resident=all_keys(root))
    assert [n.key for n in sel.render] == ["0/0/0"]
    assert sel.stats.budget_limited
    assert sel.request == []  # what the budget forbids to draw is not loaded either


def test_triangle_and_byte_budgets() -> None:
    root = quadtree()
    sel = select(root, overview_view(), tau_px=0.5, budget=Budget(max_bytes=100_000), resident=all_keys(root))
    assert sel.stats.bytes <= 100_000
    assert sel.stats.budget_limited


def test_parent_kept_while_children_load() -> None:
    root = quadtree()
    resident = {n.key for n in walk(root) if n.level <= 1}
    sel = select(root, overview_view(), tau_px=0.5, resident=resident)
    assert sorted(n.key for n in sel.render) == sorted(c.key for c in root.children)
    level2 = {c.key for c in walk(root) if c.level == 2}
    assert set(sel.request) == level2
    assert footprint_area(sel.render) == pytest.approx(SIZE_M**2)  # no holes
    assert sel.stats.max_sse_px > 0.5  # the frame's effective error shows the parents drawn too coarse
    # Once one parent's children arrive, that parent (and only it) is replaced.
    first = root.children[0]
    sel2 = select(root, overview_view(), tau_px=0.5, resident=resident | {c.key for c in first.children})
    keys2 = {n.key for n in sel2.render}
    assert first.key not in keys2
    assert {c.key for c in first.children} <= keys2
    assert footprint_area(sel2.render) == pytest.approx(SIZE_M**2)


def test_nothing_resident_requests_root_first() -> None:
    root = quadtree()
    sel = select(root, overview_view(), tau_px=0.5, resident=set())
    assert sel.render == []
    assert sel.request[0] == "0/0/0"
    assert set(sel.request[1:]) == {c.key for c in root.children}


def test_requests_ordered_nearest_first() -> None:
    root = quadtree()
    view = corner_view()
    sel = select(root, view, tau_px=0.5, resident={"0/0/0"})
    assert [n.key for n in sel.render] == ["0/0/0"]
    assert len(sel.request) == 4
    nodes = {c.key: c for c in root.children}

    def aabb_distance(n: Node) -> float:  # independent of Box.distance
        p = view.eye
        q = np.clip(p, n.lo, n.hi)
        return float(np.linalg.norm(p - q))

    distances = [aabb_distance(nodes[k]) for k in sel.request]
    assert distances == sorted(distances)
    assert sel.request[0] == "1/0/0"


def test_add_refinement_draws_parent_and_children() -> None:
    root = quadtree(levels=3, refine="ADD")
    sel = select(root, overview_view(), tau_px=0.5, resident=all_keys(root))
    assert sel.stats.selected == 1 + 4 + 16
    assert sel.stats.points == 21 * POINTS_PER_TILE
    # Children missing: parent still drawn, children requested, grandchildren not visited yet.
    sel2 = select(root, overview_view(), tau_px=0.5, resident={"0/0/0"})
    assert [n.key for n in sel2.render] == ["0/0/0"]
    assert set(sel2.request) == {c.key for c in root.children}


def test_add_budget_counts_parent_and_children() -> None:
    root = quadtree(levels=3, refine="ADD")
    sel = select(root, overview_view(), tau_px=0.5, budget=Budget(max_points=10_000), resident=all_keys(root))
    assert sel.stats.points <= 10_000
    # Root, its four children, then one sibling set of grandchildren (largest on screen first);
    # a second set would make 13 000.
    assert sel.stats.selected == 9
    assert sel.stats.budget_limited


def test_empty_interior_nodes_are_looked_through() -> None:
    # Level 1 has no content: the root must stay until the level-2 tiles that replace it are resident.
    root = quadtree(levels=3, empty_levels=(1,))
    sel = select(root, overview_view(), tau_px=0.5, resident={"0/0/0"})
    assert [n.key for n in sel.render] == ["0/0/0"]
    assert set(sel.request) == {n.key for n in walk(root) if n.level == 2}
    everything = select(root, overview_view(), tau_px=0.5, resident=all_keys(root))
    assert all(n.content_uri is not None for n in everything.render)
    assert everything.stats.selected == 16
    assert footprint_area(everything.render) == pytest.approx(SIZE_M**2)


def test_empty_root_draws_children_as_they_arrive() -> None:
    root = quadtree(levels=3, empty_levels=(0,))
    sel = select(root, far_view(), tau_px=1.0, resident=all_keys(root))
    assert sel.render == [] and sel.request == []  # an empty root that needs no refinement draws nothing
    sel2 = select(root, overview_view(), tau_px=0.5, resident={"1/0/0"})
    assert "1/0/0" in {n.key for n in sel2.render}
    assert {"1/1/0", "1/0/1", "1/1/1"} <= set(sel2.request)


def test_failed_tile_is_skipped_not_requested() -> None:
    root = quadtree(levels=3)
    bad = root.children[0].key
    resident = all_keys(root) - {bad}
    sel = select(root, overview_view(), tau_px=0.5, resident=resident, unavailable={bad})
    keys = {n.key for n in sel.render}
    assert bad not in keys and bad not in sel.request
    assert "0/0/0" not in keys  # the failure does not pin the parent for ever
    assert {c.key for c in root.children[0].children} <= keys  # what lies below the failed tile renders


def test_culled_root_selects_nothing() -> None:
    root = quadtree()
    cam = Camera((500.0, 500.0, 600.0), (500.0, 500.0, 1200.0), (0.0, 1.0, 0.0), 60.0)  # looking up
    sel = select(root, View(cam, 800, 600), tau_px=1.0, resident=all_keys(root))
    assert sel.render == [] and sel.request == []
    assert sel.stats.culled == 1 and sel.stats.visited == 1



@pytest.mark.parametrize("refine", ["REPLACE", "ADD"])
def test_a_tile_whose_children_are_all_out_of_view(refine: str) -> None:
    # The parent's box reaches past its children's (as a point octree's quads can): a camera near that
    # margin, looking into it and away from the children, sees the parent's box and none of the children.
    kids = [Node(f"1/{i}", 1, (i * 10.0, 0.0, 0.0), (i * 10.0 + 10.0, 10.0, 5.0), 0.0) for i in range(2)]
    parent = Node("0", 0, (-30.0, 0.0, 0.0), (20.0, 10.0, 5.0), 8.0, refine=refine, children=kids)
    cam = Camera((-5.0, 5.0, 3.0), (-25.0, 5.0, 3.0), (0.0, 0.0, 1.0), 40.0)  # inside the margin, looking -x
    view = View(cam, 800, 600)
    assert not view.cull_box(parent.box) and all(view.cull_box(k.box) for k in kids)
    sel = select(parent, view, tau_px=1.0, resident=all_keys(parent))
    # REPLACE: the children stand for the parent, and none is in view, so nothing is (CesiumJS would draw
    # the parent, here at an error of hundreds of pixels); ADD: the parent is drawn whatever its children.
    assert [n.key for n in sel.render] == ([] if refine == "REPLACE" else ["0"])
    assert sel.request == []

# -- resolve: the off-screen loop -----------------------------------------------------------------


def test_resolve_loads_until_complete() -> None:
    root = quadtree()
    calls: list[str] = []
    lock = threading.Lock()

    def load(node: Any) -> tuple[str, int]:
        with lock:
            calls.append(node.key)
        return node.key, 1000

    with TileLoader(load, TileCache(10_000_000), workers=2) as loader:
        sel = resolve(root, overview_view(), 0.5, None, loader)
    assert sel.request == []
    assert sel.stats.selected == 4 ** (LEVELS - 1)
    assert len(calls) == len(set(calls))  # nothing loaded twice


def test_resolve_reports_corrupt_tile_and_renders_the_rest() -> None:
    root = quadtree(levels=3)
    bad = "2/1/1"

    def load(node: Any) -> tuple[str, int]:
        if node.key == bad:
            raise ValueError("corrupt glb")
        return node.key, 1000

    with TileLoader(load, TileCache(10_000_000), workers=2) as loader:
        sel = resolve(root, overview_view(), 0.5, None, loader)
        failed = loader.failed
    assert set(failed) == {bad} and "corrupt glb" in failed[bad]
    keys = {n.key for n in sel.render}
    assert bad not in keys and sel.request == []
    assert len(keys) == 15


def _meshed(levels: int = LEVELS) -> Node:
    """The quadtree with triangles: each level holds twice the triangles of the level above (as a DSM tree
    does: a child has half its parent's), every error halving per level."""
    root = quadtree(levels)
    for n in walk(root):
        n.point_count = 0
        n.triangle_count = 40_000 // 2**n.level
    return root


def _corner_down() -> View:
    """2 km above the (0, 0) corner, looking down (80×60 px, so coarse tiles are fine enough from there)."""
    return View(Camera((0.0, 0.0, 2000.0), (0.0, 1.0, 0.0), (0.0, 1.0, 0.0), 30.0), 80, 60)


def _covers_visible_leaves(root: Node, drawn: Sequence[Any], view: View) -> bool:
    """Every leaf the frustum does not cull lies under exactly one drawn tile (no hole, no overlap)."""
    keys = {n.key for n in drawn}
    for leaf in (n for n in walk(root) if not n.children and not view.cull_box(n.box)):
        level, ix, iy = (int(v) for v in leaf.key.split("/"))
        above = 0
        while level >= 0:
            above += f"{level}/{ix}/{iy}" in keys
            level, ix, iy = level - 1, ix // 2, iy // 2
        if above != 1:
            return False
    return True


def test_refining_to_cull_draws_fewer_triangles_and_no_coarser_tile() -> None:
    # Above the (0, 0) corner looking down: the coarse tiles at the corner are mostly outside the view, and
    # their visible children hold fewer triangles than they do.
    root = _meshed()
    view = _corner_down()
    resident = all_keys(root)
    plain = select(root, view, tau_px=1.0, resident=resident, refine_to_cull=False)
    culled = select(root, view, tau_px=1.0, resident=resident)
    assert culled.stats.triangles < plain.stats.triangles
    # Independent of the rule's own bookkeeping: the drawn triangles are counted from the tiles.
    assert sum(n.triangle_count for n in culled.render) == culled.stats.triangles
    # Finer only: every tile drawn now lies at or below a tile drawn before, so no error rises.
    before = {n.key: n.level for n in plain.render}
    for n in cast(list[Node], culled.render):
        level, ix, iy = (int(v) for v in n.key.split("/"))
        while f"{level}/{ix}/{iy}" not in before:
            assert level > 0, n.key
            level, ix, iy = level - 1, ix // 2, iy // 2
    assert culled.stats.max_sse_px <= plain.stats.max_sse_px
    assert no_ancestor_pairs(culled.render)
    assert _covers_visible_leaves(root, culled.render, view)
    assert _covers_visible_leaves(root, plain.render, view)
    assert not any(view.cull_box(n.box) for n in culled.render)


def test_refining_to_cull_keeps_a_tile_wholly_in_view() -> None:
    # From far above the centre everything is in view: the rule never refines, whatever the counts.
    root = _meshed()
    view = View(Camera((500.0, 500.0, 20_000.0), (500.0, 500.0, 0.0), (0.0, 1.0, 0.0), 45.0), 80, 60)
    resident = all_keys(root)
    a = select(root, view, tau_px=1.0, resident=resident, refine_to_cull=False)
    b = select(root, view, tau_px=1.0, resident=resident)
    assert [n.key for n in a.render] == [n.key for n in b.render] == ["0/0/0"]


def test_refining_to_cull_waits_for_the_children() -> None:
    # REPLACE without holes holds for this rule too: the parent stays drawn until its visible children load.
    root = _meshed()
    view = _corner_down()
    plain = select(root, view, tau_px=1.0, resident=all_keys(root), refine_to_cull=False)
    only = {n.key for n in plain.render}
    ancestors = set()
    for k in only:
        level, ix, iy = (int(v) for v in k.split("/"))
        while level > 0:
            level, ix, iy = level - 1, ix // 2, iy // 2
            ancestors.add(f"{level}/{ix}/{iy}")
    sel = select(root, view, tau_px=1.0, resident=only | ancestors)
    assert {n.key for n in sel.render} == only
    assert sel.request  # the finer tiles the rule wants
    assert _covers_visible_leaves(root, sel.render, view)
