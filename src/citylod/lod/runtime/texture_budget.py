"""Which texture atlases stay resident under a byte budget, and what is drawn while the rest loads.

Buchholz (PhD thesis, Potsdam 2006, §4.6) orders the atlases of a multiresolution tree by what the frame
needs: first the atlases of nodes the frame draws (*needed*), then those the traversal selected but culled
outside the view frustum (*culled*: the camera may turn back), then the parents of needed nodes (*parent*:
what is drawn while a child loads, and what coarsens gracefully), then everything else (*unused*); within a
class nearer atlases first, then coarser levels. Residency takes atlases in that order while they fit the
budget, so the budget is never exceeded: when the needed atlases alone do not fit, the farthest are not
loaded and their nearest resident ancestor is drawn instead (a coarser texture, never a missing one).

Pure: no I/O, no VTK, no globals; the renderer passes what it knows and applies the plan.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

__all__ = ["ROLES", "TextureNeed", "TexturePlan", "plan_textures"]

#: Priority classes, most important first.
ROLES = ("needed", "culled", "parent", "unused")


@dataclass(frozen=True)
class TextureNeed:
    """One atlas as the frame sees it: tile ``key``, its ``parent`` key (None at the root), its size in
    bytes, its ``role`` (one of :data:`ROLES`), the distance from the eye in metres, its tree ``level``
    (0 at the root) and whether it is ``resident`` (uploaded) now."""

    key: str
    parent: str | None
    nbytes: int
    role: str
    distance_m: float
    level: int
    resident: bool = False


@dataclass(frozen=True)
class TexturePlan:
    """What to do this frame: ``keep`` (atlases that stay or become resident, within the budget),
    ``load`` (those of ``keep`` not resident yet, in priority order), ``evict`` (resident ones not kept),
    ``draw`` (for every needed key, the key whose atlas is drawn for it now: itself when resident, else its
    nearest resident ancestor, None when there is none yet), and ``bytes`` kept."""

    keep: frozenset[str]
    load: tuple[str, ...]
    evict: tuple[str, ...]
    draw: Mapping[str, str | None]
    bytes: int


def plan_textures(needs: Sequence[TextureNeed], budget_bytes: int) -> TexturePlan:
    """Choose the resident atlases by Buchholz's priority under ``budget_bytes``.

    The plan never holds more than the budget, given that the resident atlases held no more (the invariant
    every plan keeps): atlases drawn this frame stay (they are resident), the kept resident ones stay, and
    loads are admitted in priority order only while the total fits.

    Examples
    --------
    Two needed children of a resident root, room for two atlases: one child loads, the other is drawn with
    the root's atlas meanwhile.

    >>> n = [TextureNeed("0", None, 4, "parent", 50.0, 0, True), TextureNeed("0/1", "0", 4, "needed", 20.0, 1),
    ...      TextureNeed("0/2", "0", 4, "needed", 30.0, 1)]
    >>> p = plan_textures(n, 8)
    >>> p.load, dict(p.draw), p.bytes
    (('0/1',), {'0/1': '0', '0/2': '0'}, 8)
    """
    rank = {r: i for i, r in enumerate(ROLES)}
    order = sorted(needs, key=lambda t: (rank.get(t.role, len(ROLES)), t.distance_m, t.level, t.key))
    wanted: set[str] = set()
    total = 0
    for t in order:  # the residency the priority order asks for
        if total + t.nbytes <= budget_bytes:
            wanted.add(t.key)
            total += t.nbytes
    by_key = {t.key: t for t in needs}
    draw: dict[str, str | None] = {}
    for t in needs:
        if t.role != "needed":
            continue
        k: str | None = t.key
        while k is not None and not (k in by_key and by_key[k].resident):
            k = by_key[k].parent if k in by_key else None
        draw[t.key] = k
    drawn = {k for k in draw.values() if k is not None}
    keep = {t.key for t in needs if t.resident and (t.key in drawn or t.key in wanted)}
    used = sum(by_key[k].nbytes for k in keep)
    load = []
    for t in order:
        if t.key in wanted and not t.resident and used + t.nbytes <= budget_bytes:
            load.append(t.key)
            keep.add(t.key)
            used += t.nbytes
    evict = tuple(t.key for t in order if t.resident and t.key not in keep)
    return TexturePlan(frozenset(keep), tuple(load), evict, draw, used)
