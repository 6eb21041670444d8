"""View-dependent LOD selection over a tile tree: what to draw and what to load for one frame.

:func:`select` is a pure function (CesiumJS ``Cesium3DTilesetTraversal.js`` split into traversal,
cache and statistics; see docs/STYLE.md): it reads the tree, the view, the budgets and which tiles are
resident, and returns a :class:`Selection` (tiles to render, keys to request, statistics). It does no
I/O of its own (a tree may read an external tileset when traversal enters it, below), keeps no state between calls, imports neither VTK nor Qt and never recurses (an explicit heap and
explicit stacks), so it can run in a test without a window and on trees of any depth.

The tree is anything satisfying :class:`TileNode` (``citylod.io.tiles3d.Tile`` does, and so do the
small dataclasses of the tests): nothing here imports io/.

Rules, in one place:

* **Screen-space error.** ``sse_px = view.sse(geometric_error, box.distance(eye))`` (docs/DESIGN.md, decision 2);
  a tile refines while ``sse_px > tau_px``.
* **Culling.** Tiles whose box lies outside the frustum (``View.cull_box``) are neither drawn nor
  requested, and a culled child never blocks its parent's refinement.
* **Refining to cull** (``refine_to_cull``): a REPLACE tile whose error is already small enough still
  refines when the tiles that would draw its *visible* part hold fewer triangles than it does (the
  children the frustum does not cull, each replaced in turn by its own visible children where that is
  cheaper still). Finer tiles have no larger error, so the frame's error can only fall; what it saves is
  the part of a coarse tile outside the view, which is drawn whole otherwise. Costs are the triangles
  of :meth:`_Frame.cost` (resident sizes or hints); a tile or child without a known triangle count never
  refines by this rule, and a tile wholly inside the frustum is not looked below (its children cover
  the same part of the view, with more triangles in a tree whose levels add detail).
* **REPLACE without holes** (CesiumJS base traversal, ``updateAndPushChildren``): a tile with content
  refines only when every visible child that has content is resident; until then it stays drawn and
  the missing children are requested. A visible child *without* content (an empty interior node) is
  looked through to the content tiles that would fill it (CesiumJS ``executeEmptyTraversal``). A tile
  without content of its own refines as soon as its error asks for it, since refining it cannot uncover
  anything it drew. A tile whose error asks for refinement and none of whose children is in view draws
  nothing: its children stand for it (CesiumJS draws it, at whatever error it has there).
* **ADD**: the tile stays drawn and its resident visible children are drawn with it; missing children
  are requested, and nothing below a missing child is visited.
* **External tilesets.** A tile whose content is an external tileset (``external``, optional) is traversed
  whatever its error, as CesiumJS's ``canTraverse`` does: it draws none of that content, the external root
  (its child) does. A tile whose children are not read yet (``pending``, optional) is expanded through its
  ``expand()`` when traversal enters it, so a tree of many tileset files is read as far as views reach.
* **Failed tiles** (``unavailable``) are treated as tiles without content: never drawn, never
  requested, never blocking a parent. A corrupt tile becomes a hole where nothing finer is available,
  while the rest of the frame renders.
* **Budgets** (Potree ``updatePointClouds``): tiles are taken from a priority queue, largest
  screen-space error first; refining a tile adds its visible children at once (a sibling set is the unit,
  so a region is never half refined) and the first refinement that would push the drawn set over any
  limit of :class:`Budget` stops all further refinement. The root is always drawn, even when it alone
  exceeds the budget; otherwise the drawn set never exceeds a limit. Costs are the resident sizes when
  ``resident`` is a mapping of :class:`ResidentInfo`, else the tile's hints (``content_bytes``,
  ``point_count``, ``triangle_count``); an unknown hint counts 0 and so cannot be limited.
* **Requests** are ordered most-needed first: by the tile's own screen-space error, descending (for
  tiles of one level that is nearest first), ties broken by distance to the eye and then by key.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Container, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

from citylod.core.camera import View
from citylod.core.geometry import Box
from citylod.lod.runtime.cache import ResidentInfo

__all__ = [
    "Budget",
    "Residency",
    "ResidentInfo",
    "Selection",
    "SelectionStats",
    "TileNode",
    "select",
]

REPLACE = "REPLACE"
#: Levels below a tile that refining to cull compares it with: its children only. The choice then repeats
#: tile by tile down the tree as refinement proceeds; looking further found 0.6 % fewer triangles on the
#: 4097² city's flight for 3–4× the selection time (docs/PERFORMANCE_LOG.md).
CULL_LOOKAHEAD = 1
ADD = "ADD"


@runtime_checkable
class TileNode(Protocol):
    """What selection needs of a tile (``citylod.io.tiles3d.Tile`` satisfies it).

    Optional hints that selection reads with ``getattr`` and treats as 0 when absent or unknown:
    ``point_count: int`` and ``triangle_count: int`` (of the tile's content).
    """

    @property
    def key(self) -> str:
        """Unique key of the tile in its tree (e.g. ``"3/5/2"``)."""
        ...

    @property
    def children(self) -> Sequence[TileNode]: ...

    @property
    def geometric_error(self) -> float:
        """Guaranteed object-space error of this tile's content, metres."""
        ...

    @property
    def refine(self) -> str:
        """``"REPLACE"`` or ``"ADD"`` (3D Tiles refinement of this tile's children)."""
        ...

    @property
    def box(self) -> Box:
        """Bounding volume in the world (CRS) frame of the view."""
        ...

    @property
    def content_uri(self) -> str | None:
        """``None`` for a tile without content (an empty interior node)."""
        ...

    @property
    def content_bytes(self) -> int:
        """Size of the content on disk, 0 when unknown or without content."""
        ...


Residency = Mapping[str, ResidentInfo] | Container[str]
"""Which tiles are resident. A ``Mapping[key, ResidentInfo]`` gives measured costs; any other
container supporting ``key in resident`` (a set, a :class:`~citylod.lod.runtime.cache.TileCache`) gives
membership only, and the tile hints are used as costs."""


@dataclass(frozen=True)
class Budget:
    """Limits on what one frame draws; ``None`` means unlimited.

    Parameters
    ----------
    max_bytes
        Total content bytes of the drawn tiles.
    max_points
        Total points of the drawn tiles (Potree's point budget).
    max_triangles
        Total triangles of the drawn tiles.
    """

    max_bytes: int | None = None
    max_points: int | None = None
    max_triangles: int | None = None

    @property
    def unlimited(self) -> bool:
        return self.max_bytes is None and self.max_points is None and self.max_triangles is None

    def admits(self, nbytes: int, points: int, triangles: int) -> bool:
        """True if a drawn set of these totals stays within every limit."""
        return (
            (self.max_bytes is None or nbytes <= self.max_bytes)
            and (self.max_points is None or points <= self.max_points)
            and (self.max_triangles is None or triangles <= self.max_triangles)
        )


UNLIMITED = Budget()


@dataclass(frozen=True)
class SelectionStats:
    """Counters of one :func:`select` call (what LOD tests assert on).

    Attributes
    ----------
    visited
        Tiles whose visibility and screen-space error were evaluated.
    culled
        Visited tiles outside the frustum.
    selected
        Tiles in ``render``.
    requested
        Keys in ``request``.
    triangles, points, bytes
        Totals over ``render`` (resident sizes when known, else hints).
    max_sse_px
        Largest screen-space error among the rendered tiles: the effective error of the frame. A tile
        drawn with ``sse > tau`` because its children are not loaded yet counts. 0 when nothing drawn.
    depth
        Deepest level (root = 0) among the rendered tiles; -1 when nothing is drawn.
    budget_limited
        True when a budget stopped refinement this frame.
    """

    visited: int = 0
    culled: int = 0
    selected: int = 0
    requested: int = 0
    triangles: int = 0
    points: int = 0
    bytes: int = 0
    max_sse_px: float = 0.0
    depth: int = -1
    budget_limited: bool = False


@dataclass(frozen=True)
class Selection:
    """The result of :func:`select` for one frame.

    Attributes
    ----------
    render
        Tiles to draw (resident, with content), highest screen-space error first.
    request
        Keys of tiles to load, most needed first.
    stats
        Counters of the traversal.
    request_nodes
        The tiles named by ``request``, same order (what a loader needs to load them).
    frame
        The frame number passed to :func:`select`, for the cache and loader bookkeeping.
    admitted
        The budget's admissions in order: ``(points, triangles, keys)`` per step, the totals of the drawn
        set after it and the content tiles it added (the root first). A smaller point budget ``B`` admits
        exactly the steps whose ``points`` stay within ``B``, up to the first that does not (refinement
        stops at the first refusal, and the order does not depend on the budget), so this is the frame's
        cost curve for a controller choosing the next budget (:mod:`citylod.lod.runtime.budget`).
    """

    render: list[TileNode]
    request: list[str]
    stats: SelectionStats
    request_nodes: list[TileNode] = field(default_factory=list, repr=False)
    frame: int = 0
    admitted: list[tuple[int, int, tuple[str, ...]]] = field(default_factory=list, repr=False)


@dataclass(frozen=True)
class _Cost:
    bytes: int = 0
    points: int = 0
    triangles: int = 0

    def __add__(self, other: _Cost) -> _Cost:
        return _Cost(self.bytes + other.bytes, self.points + other.points, self.triangles + other.triangles)

    def __sub__(self, other: _Cost) -> _Cost:
        return _Cost(self.bytes - other.bytes, self.points - other.points, self.triangles - other.triangles)


_ZERO = _Cost()


class _Frame:
    """Per-call lookups: residency, failures and a memo of per-tile visibility and error.

    Lives only for one :func:`select` call, so selection stays a pure function.
    """

    def __init__(self, view: View, resident: Residency, unavailable: Container[str]) -> None:
        self.view = view
        self.eye = view.eye
        self.resident = resident
        self.info = resident if isinstance(resident, Mapping) else None
        self.unavailable = unavailable
        self.visited = 0
        self.culled = 0
        # id(node) -> (culled, sse_px, distance); nodes are alive for the whole call.
        self._memo: dict[int, tuple[bool, float, float]] = {}
        # (id(node), depth) -> fewest triangles that draw the node's visible part (see cover_triangles), and
        # id(node) -> (outside, inside) the frustum, for the tiles that search looks at.
        self._cover: dict[tuple[int, int], int] = {}
        self._frustum: dict[int, tuple[bool, bool]] = {}
        self.refine_to_cull = False

    def evaluate(self, node: TileNode) -> tuple[bool, float, float]:
        """(culled, sse_px, distance) of ``node``, computed once per call."""
        hit = self._memo.get(id(node))
        if hit is not None:
            return hit
        self.visited += 1
        if self.frustum(node)[0]:  # View.cull_box, with the inside test refining to cull may ask for
            self.culled += 1
            result = (True, 0.0, math.inf)
        else:
            distance = node.box.distance(self.eye)
            result = (False, self.view.sse(float(node.geometric_error), distance), distance)
        self._memo[id(node)] = result
        return result

    def has_content(self, node: TileNode) -> bool:
        """Content that can be drawn: a uri and not known to fail."""
        return node.content_uri is not None and node.key not in self.unavailable

    def is_resident(self, node: TileNode) -> bool:
        return node.key in self.resident

    def cost(self, node: TileNode) -> _Cost:
        if not self.has_content(node):
            return _ZERO
        if self.info is not None:
            info = self.info.get(node.key)
            if info is not None:
                return _Cost(int(info.bytes), int(info.points), int(info.triangles))
        return _Cost(
            int(node.content_bytes or 0),
            int(getattr(node, "point_count", 0) or 0),
            int(getattr(node, "triangle_count", 0) or 0),
        )

    def refines(self, node: TileNode, tau_px: float) -> bool:
        culled, sse, _ = self.evaluate(node)
        if culled:
            return False
        # A tile whose content is an external tileset is traversed whatever its error (CesiumJS canTraverse):
        # it draws none of that content itself, its child (the external root) does.
        external = bool(getattr(node, "external", False))
        if (sse > tau_px or external) and getattr(node, "pending", False):
            # Children in external tilesets not read yet: read them now that the view refines into them
            # (optional hook ``expand()``; citylod's tileset proxies have it).
            node.expand()  # type: ignore[attr-defined]
        if not node.children:
            return False
        if sse > tau_px or external:
            return True
        return self.refine_to_cull and self.cover_triangles(node, CULL_LOOKAHEAD) < self.cost(node).triangles

    def frustum(self, node: TileNode) -> tuple[bool, bool]:
        """(wholly outside, wholly inside) the frustum for ``node``'s box (:meth:`View.box_in_frustum`, once per
        tile), without the distance and error :meth:`evaluate` adds."""
        key = id(node)
        hit = self._frustum.get(key)
        if hit is None:
            hit = self.view.box_in_frustum(node.box)
            self._frustum[key] = hit
        return hit

    def cover_triangles(self, node: TileNode, depth: int) -> int:
        """Fewest triangles that draw the visible part of ``node`` with it or tiles at most ``depth`` levels
        finer (refining to cull).

        The tile's own triangles, or the sum over its children not culled of their cover when every one
        of them has content and a known triangle count and the sum is smaller. Not looked below: ADD
        tiles, tiles without triangles, tiles none of whose children is visible, and tiles wholly inside
        the frustum. Memoised per call; the
        frustum tests are :meth:`frustum`'s, one per tile.
        """
        key = (id(node), depth)
        hit = self._cover.get(key)
        if hit is not None:
            return hit
        own = self.cost(node).triangles
        best = own
        if (depth > 0 and own > 0 and node.children and node.refine.upper() != ADD and self.has_content(node)
                and not self.frustum(node)[1]):
            total, seen = 0, False
            for c in node.children:
                if self.frustum(c)[0]:
                    continue
                seen = True
                if not self.has_content(c) or self.cost(c).triangles <= 0:
                    total = own
                    break
                total += self.cover_triangles(c, depth - 1)
                if total >= own:
                    break
            # No visible child: select() keeps such a tile as it is (its box test is conservative), so
            # drawing it costs its own triangles.
            best = min(own, total) if seen else own
        self._cover[key] = best
        return best


def _fits(budget: Budget, total: _Cost) -> bool:
    return budget.admits(total.bytes, total.points, total.triangles)


def _fill_set(child: TileNode, fr: _Frame, tau_px: float) -> tuple[list[TileNode], list[TileNode]]:
    """What would be drawn in place of visible ``child`` (CesiumJS ``executeEmptyTraversal``).

    Returns ``(fill, through)``: the content tiles drawn in its place, and the tiles without content
    that are looked through on the way (they refine as soon as they are reached). A child with content
    is its own fill; a child without content (or a failed one) is filled by its visible descendants,
    looked through while such empty tiles would refine themselves.
    """
    if fr.has_content(child):
        return [child], []
    fill: list[TileNode] = []
    through: list[TileNode] = []
    stack = [child]
    while stack:
        node = stack.pop()
        if fr.has_content(node):
            fill.append(node)
            continue
        if not fr.refines(node, tau_px):
            if getattr(node, "pending", False):
                fill.append(node)  # its tileset is being read: not ready, as a tile not loaded (no hole)
            continue  # an empty tile that stops here draws nothing, legitimately
        through.append(node)
        for grandchild in node.children:
            if not fr.evaluate(grandchild)[0]:
                stack.append(grandchild)
    return fill, through


def select(
    tree: TileNode,
    view: View,
    *,
    tau_px: float,
    budget: Budget | None = None,
    resident: Residency = frozenset(),
    unavailable: Container[str] = frozenset(),
    frame: int = 0,
    refine_to_cull: bool = True,
) -> Selection:
    """Choose the tiles to draw and to load for ``view``.

    Parameters
    ----------
    tree
        Root tile of the tree.
    view
        Camera and viewport of the frame (tiles' boxes are in the same world frame as the camera).
    tau_px
        Screen-space error threshold in pixels: a tile refines while its error is larger.
    budget
        Limits on the drawn set; ``None`` for none. See the module docstring for the root exception.
    resident
        Tiles whose content is loaded: a mapping key -> :class:`ResidentInfo` (measured costs) or any
        container of keys.
    unavailable
        Keys of tiles that failed to load; treated as tiles without content (never drawn nor requested).
    frame
        Frame number, copied into the result.
    refine_to_cull
        Also refine a REPLACE tile whose visible children (recursively) hold fewer triangles than it does
        (see the module docstring); False keeps the refinement by error alone.

    Returns
    -------
    Selection
        ``render`` (resident tiles to draw), ``request`` (keys to load, most needed first) and ``stats``.

    Examples
    --------
    >>> import citylod
    >>> from citylod.core.camera import View
    >>> ts = citylod.open_tileset("TILES")                                   # doctest: +SKIP
    >>> cam = citylod.load_cameras("camera.json")[0]                          # doctest: +SKIP
    >>> sel = select(ts.root, View(cam, 1280, 720), tau_px=1.0)               # doctest: +SKIP
    >>> sel.request[:3], sel.stats.selected                                   # doctest: +SKIP
    (['0/0/0'], 0)
    """
    budget = budget or UNLIMITED
    fr = _Frame(view, resident, unavailable)
    fr.refine_to_cull = refine_to_cull
    # Requests: key -> (priority tuple, node); a dict so a tile reached twice is requested once.
    wanted: dict[str, tuple[tuple[float, float, str], TileNode]] = {}

    def want(node: TileNode) -> None:
        if node.key in wanted or fr.is_resident(node) or not fr.has_content(node):
            return
        _, sse, distance = fr.evaluate(node)
        wanted[node.key] = ((-sse, distance, node.key), node)

    culled, root_sse, root_dist = fr.evaluate(tree)
    # Frontier of the drawn set: id -> (node, depth). Tiles on it are "desired"; only resident ones
    # end up in render, and the others are requested.
    desired: dict[int, tuple[TileNode, int]] = {}
    budget_limited = False
    admitted: list[tuple[int, int, tuple[str, ...]]] = []
    if not culled:
        desired[id(tree)] = (tree, 0)
        total = fr.cost(tree)  # the root is drawn whatever it costs
        admitted.append((total.points, total.triangles, (tree.key,) if fr.has_content(tree) else ()))
        # Potree updatePointClouds: a max-heap on projected size (here: sse), popped in order, so the
        # budget is spent on what is largest on screen first. The counter keeps ties stable and
        # avoids comparing nodes.
        order = 0
        heap: list[tuple[float, float, int, TileNode, int]] = [(-root_sse, root_dist, order, tree, 0)]
        # Empty tiles whose refinement a parent already paid for and checked (see _fill_set): they
        # refine unconditionally, or the budget could stop them after their parent was replaced.
        committed: set[int] = set()
        while heap:
            _, _, _, node, depth = heapq.heappop(heap)
            if not fr.refines(node, tau_px):
                continue
            visible = [c for c in node.children if not fr.evaluate(c)[0]]
            additive = node.refine.upper() == ADD
            if not visible:
                # REPLACE: the children stand for the tile, and none is in view, so at the error asked for
                # nothing of it is (CesiumJS keeps such a tile drawn; its box can reach past its children's,
                # with a point octree's quads or cluster centres, and then a tile many times over τ is drawn
                # next to the camera: Delft, a coarse node at 122 px, its splats blobs across the view).
                if not additive and id(node) in desired:
                    desired.pop(id(node))
                    total = total - fr.cost(node)
                continue
            if id(node) in committed:
                pushed = visible
            elif additive:
                delta = _ZERO
                for c in visible:
                    delta = delta + fr.cost(c)
                if budget_limited or not _fits(budget, total + delta):
                    budget_limited = True
                    continue
                total = total + delta
                admitted.append((total.points, total.triangles, tuple(c.key for c in visible if fr.has_content(c))))
                for c in visible:
                    want(c)
                # Empty children draw nothing but are looked through; below a missing child nothing is
                # visited until it arrives (one level at a time, as in CesiumJS).
                pushed = [c for c in visible if not fr.has_content(c) or fr.is_resident(c)]
            else:
                fill: list[TileNode] = []
                through: list[TileNode] = []
                for c in visible:
                    f, t = _fill_set(c, fr, tau_px)
                    fill.extend(f)
                    through.extend(t)
                delta = _ZERO
                for t_node in fill:
                    delta = delta + fr.cost(t_node)
                delta = delta - fr.cost(node)
                if budget_limited or not _fits(budget, total + delta):
                    # The budget also withholds requests: what could not be drawn is not loaded.
                    budget_limited = True
                    continue
                missing = [t_node for t_node in fill if not fr.is_resident(t_node)]
                if missing and fr.has_content(node):
                    # No holes: keep the parent drawn until its whole fill set is resident.
                    for t_node in missing:
                        want(t_node)
                    continue
                total = total + delta
                admitted.append((total.points, total.triangles, tuple(t_node.key for t_node in fill)))
                committed.update(id(t_node) for t_node in through)
                pushed = visible
            if not additive:
                desired.pop(id(node), None)
            for c in pushed:
                desired[id(c)] = (c, depth + 1)
                order += 1
                _, sse, distance = fr.evaluate(c)
                heapq.heappush(heap, (-sse, distance, order, c, depth + 1))

    render: list[tuple[float, float, str, TileNode, int]] = []
    for node, depth in desired.values():
        if not fr.has_content(node):
            continue
        if fr.is_resident(node):
            _, sse, distance = fr.evaluate(node)
            render.append((-sse, distance, node.key, node, depth))
        else:
            want(node)
    render.sort(key=lambda r: (r[0], r[1], r[2]))
    requests = sorted(wanted.values(), key=lambda w: w[0])

    drawn = _ZERO
    for r in render:
        drawn = drawn + fr.cost(r[3])
    stats = SelectionStats(
        visited=fr.visited,
        culled=fr.culled,
        selected=len(render),
        requested=len(requests),
        triangles=drawn.triangles,
        points=drawn.points,
        bytes=drawn.bytes,
        max_sse_px=max((-r[0] for r in render), default=0.0),
        depth=max((r[4] for r in render), default=-1),
        budget_limited=budget_limited,
    )
    return Selection(
        render=[r[3] for r in render],
        request=[w[0][2] for w in requests],
        stats=stats,
        request_nodes=[w[1] for w in requests],
        frame=frame,
        admitted=admitted,
    )
