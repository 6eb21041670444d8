"""Texture memory of a :class:`~citylod.render.tileset_actor.Scene` under a byte budget (Buchholz §4.6).

:func:`~citylod.lod.runtime.texture_budget.plan_textures` decides which atlases stay resident; this module
tells it what the frame needs and applies its plan to the scene:

* every textured tile the frame draws or requests is *needed*, and so are the visible siblings of a
  requested tile (REPLACE refines a sibling set at once, so a parent is replaced only when all of them
  are resident), and so are their ancestors: selection reaches a tile only through resident ancestors
  (REPLACE without holes), so for this renderer Buchholz's *parent* class (what is drawn while a child
  loads) is part of what the frame needs. Resident textured tiles outside the view are *culled*, the
  other resident ones *unused*; distance and level break ties;
* resident tiles the plan does not keep leave the tile cache at once (geometry and texture are one cache
  entry) and their GL textures are released;
* requested tiles whose atlas the plan does not admit are not loaded this frame (*refused*), nor are
  their missing siblings (half a sibling set cannot be drawn and would only hold memory): selection
  keeps their parent drawn, as it does for any child still loading (REPLACE without holes), so a view
  shows a coarser texture, never a missing one;
* the cache evicts by the same priority when it needs room for geometry (its eviction-order hook).

Texture bytes are counted as GL holds them: width × height × components, plus a third for the mipmap
chain. :func:`gl_texture_bytes` counts what the renderer really holds, from the GL texture objects of
every tile actor (shown, hidden or pooled), independent of the plan: the quantity the budget caps.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from citylod.core.camera import View
from citylod.lod.runtime.selection import Selection
from citylod.lod.runtime.texture_budget import ROLES, TextureNeed, TexturePlan, plan_textures

__all__ = ["TextureResidency", "gl_texture_bytes", "texture_nbytes"]


def texture_nbytes(width: int, height: int, components: int, mipmap: bool = True) -> int:
    """Bytes of one texture in GL: ``width · height · components``, plus a third for the mipmap chain."""
    base = int(width) * int(height) * int(components)
    return base + base // 3 if mipmap else base


def _prepared_texture_bytes(prepared: Any) -> int:
    n = 0
    for m in getattr(prepared, "meshes", ()):
        if m.texture is not None:
            h, w = m.texture.shape[:2]
            n += texture_nbytes(w, h, m.texture.shape[2] if m.texture.ndim == 3 else 1)
    return n


def gl_texture_bytes(scene: Any) -> int:
    """Bytes of the GL textures the scene's tile actors hold now (shown, hidden and pooled), read from the
    GL texture objects themselves (width, height, components, mipmaps), not from any plan. ``scene`` is a
    :class:`~citylod.render.tileset_actor.Scene`, typed loosely because the scene imports this module."""
    total = 0
    for tex in scene.tile_textures():
        obj = tex.GetTextureObject()
        if obj is None or not obj.GetHandle():
            continue
        total += texture_nbytes(obj.GetWidth(), obj.GetHeight(), obj.GetComponents(), bool(tex.GetMipmap()))
    return total


class TextureResidency:
    """Keeps a scene's resident textures under ``budget_bytes`` with Buchholz's priority.

    ``refused`` holds the keys whose load the last plan did not admit; ``last_plan`` is that plan.
    """

    def __init__(self, scene: Any, budget_bytes: int) -> None:
        if budget_bytes < 0:
            raise ValueError(f"budget_bytes must be >= 0, got {budget_bytes}")
        self.scene = scene
        self.budget_bytes = int(budget_bytes)
        self.refused: frozenset[str] = frozenset()
        self.last_plan: TexturePlan | None = None
        self._estimate: dict[int, int] = {}  # layer index -> bytes of one tile's textures before it loads

    def _layer_estimate(self, layer: Any, index: int) -> int:
        """Texture bytes of a tile of ``layer`` not loaded yet: the atlas size a citylod city tileset
        declares, else the largest seen in the layer so far (0 while no tile of it had a texture)."""
        if index not in self._estimate:
            extras = layer.tileset.extras if isinstance(layer.tileset.extras, dict) else {}
            cl = extras.get("citylod", {}) if isinstance(extras.get("citylod", {}), dict) else {}
            px = int(cl.get("atlas_px", 0) or 0) if cl.get("textured") else 0
            self._estimate[index] = texture_nbytes(px, px, 3) if px > 0 else 0
        return self._estimate[index]

    def _bytes(self, key: str, layer: Any, index: int) -> int:
        prepared = self.scene.cache.peek(key)  # peek: planning must not reorder the cache's LRU
        if prepared is not None:
            n = _prepared_texture_bytes(prepared)
            if n > self._estimate.get(index, 0):
                self._estimate[index] = n
            return n
        return self._layer_estimate(layer, index)

    def needs(self, sels: Sequence[Selection], view: View) -> list[TextureNeed]:
        """The frame's textured tiles with their roles (see the module docstring)."""
        out: list[TextureNeed] = []
        # Loads already under way arrive whatever this plan says: they count as resident, so that what the
        # plan admits next fits beside them (the budget holds between frames too, not only when resolved).
        resident = set(self.scene.cache) | set(self.scene.loader.busy_keys())
        for index, (layer, sel) in enumerate(zip(self.scene.layers, sels, strict=True)):
            needed = {n.key for n in sel.render} | set(sel.request) | {layer.root.key}
            for key in sel.request:
                parent = layer.node(key).tile.parent
                if parent is not None:
                    for c in layer.node(f"{layer.prefix}{parent.key}").children:
                        if not view.cull_box(c.box):
                            needed.add(c.key)
            for key in list(needed):
                tile = layer.node(key).tile.parent
                while tile is not None and f"{layer.prefix}{tile.key}" not in needed:
                    needed.add(f"{layer.prefix}{tile.key}")
                    tile = tile.parent
            mine = {k for k in resident if k.startswith(layer.prefix)}
            for key in needed | mine:
                node = layer.node(key)
                if node.content_uri is None:
                    continue
                nbytes = self._bytes(key, layer, index)
                if nbytes <= 0:
                    continue
                if key in needed:
                    role = "needed"
                elif view.cull_box(node.box):
                    role = "culled"
                else:
                    role = "unused"
                parent = node.tile.parent
                out.append(TextureNeed(key, None if parent is None else f"{layer.prefix}{parent.key}", nbytes,
                                       role, float(node.box.distance(view.eye)), int(node.level), key in resident))
        return out

    def apply(self, sels: Sequence[Selection], view: View) -> TexturePlan:
        """Plan this frame's textures and apply the plan: evict what it drops, refuse what it does not
        admit, and hand the cache the priority order for its own evictions."""
        needs = self.needs(sels, view)
        plan = plan_textures(needs, self.budget_bytes)
        for key in plan.evict:  # a load still under way is evicted by the next plan, once it has arrived
            if self.scene.cache.remove(key):
                self.scene._layer_of(key)._release(key)
        refused = {t.key for t in needs if not t.resident and t.key not in plan.keep}
        by_key = {t.key: t for t in needs}
        for t in [by_key[k] for k in refused]:
            if t.parent is not None:
                parent = self.scene._layer_of(t.key).node(t.parent)
                refused.update(c.key for c in parent.children
                               if c.key in by_key and not by_key[c.key].resident)
        self.refused = frozenset(refused)
        rank = {r: i for i, r in enumerate(ROLES)}
        order = sorted((t for t in needs if t.resident and t.key in plan.keep),
                       key=lambda t: (-rank[t.role], -t.distance_m, -t.level, t.key))
        self.scene.cache.set_eviction_order([t.key for t in order])
        self.last_plan = plan
        return plan
