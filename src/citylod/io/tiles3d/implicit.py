"""3D Tiles implicit tiling (1.1 core, and the 1.0 ``3DTILES_implicit_tiling`` extension) made explicit.

An implicit root (quadtree or octree) names its subtree files and its content by URI templates
(``{level}``, ``{x}``, ``{y}``, ``{z}``); each subtree file says, with bitstreams in Morton order, which
tiles, contents and child subtrees exist (3D Tiles 1.1 specification, "Implicit Tiling"). This module reads
the subtrees and returns the same tree as explicit tile JSON, which :class:`~citylod.io.tiles3d.tileset.Tileset`
then opens like any other. Bounding volumes are the root's box or region halved per level, geometric errors
the root's halved per level, as the specification defines.

The whole tree is expanded when the tileset is opened, so a tileset with millions of available tiles costs
memory in proportion; the samples and exports citylod meets are far below that. No VTK and no Qt here.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Callable
from typing import Any

import numpy as np

from citylod.core.errors import InputError

#: Reads a URI relative to the tileset JSON that holds the implicit root; raises InputError when it cannot.
ReadUri = Callable[[str], bytes]
_MAX_TILES = 1_000_000


def _morton(coords: tuple[int, ...], level: int) -> int:
    """Morton index of (x, y[, z]) at ``level`` bits: bit i of x, y, z interleaved, x lowest."""
    m = 0
    for bit in range(level):
        for axis, c in enumerate(coords):
            m |= ((c >> bit) & 1) << (bit * len(coords) + axis)
    return m


class _Subtree:
    """One subtree's availability: ``tile``, ``content[i]`` and ``child`` bit tests."""

    def __init__(self, data: bytes, source: str, read: ReadUri, n_children: int, levels: int):
        self.source = source
        if data[:4] == b"subt":
            if len(data) < 24:
                raise InputError("subtree header is truncated", source)
            _, _, jlen, blen = struct.unpack_from("<4sIQQ", data, 0)
            doc = json.loads(data[24: 24 + jlen].decode("utf-8").rstrip(" \x00"))
            binary = data[24 + jlen: 24 + jlen + blen]
        else:
            doc, binary = json.loads(data.decode("utf-8")), b""
        buffers = [binary if "uri" not in b else read(b["uri"]) for b in doc.get("buffers", [])]
        views = doc.get("bufferViews", [])

        def bits(av: dict[str, Any] | None, count: int) -> np.ndarray:
            if av is None:
                return np.zeros(count, bool)
            if "constant" in av:
                return np.full(count, bool(av["constant"]))
            bv = views[av.get("bitstream", av.get("bufferView"))]
            raw = buffers[bv.get("buffer", 0)][bv.get("byteOffset", 0): bv.get("byteOffset", 0) + bv["byteLength"]]
            b = np.unpackbits(np.frombuffer(raw, np.uint8), bitorder="little").astype(bool)
            if len(b) < count:
                raise InputError("subtree availability bitstream is too short", source)
            return b[:count]

        n_tiles = (n_children ** levels - 1) // (n_children - 1)
        self.tile = bits(doc.get("tileAvailability"), n_tiles)
        contents = doc.get("contentAvailability", [])
        if isinstance(contents, dict):  # 1.0 extension: a single object
            contents = [contents]
        self.content = [bits(c, n_tiles) for c in contents]
        self.child = bits(doc.get("childSubtreeAvailability"), n_children ** levels)


def expand_implicit(tile: dict[str, Any], read: ReadUri, source: str,
                    may_read: Callable[[], bool] | None = None) -> dict[str, Any]:
    """The implicit ``tile`` as explicit tile JSON (children nested, content URIs filled in).

    Child subtrees are read while ``may_read()`` says so (always without it). Where it says no, the child
    subtree's root becomes a stub tile (its volume and error, no content) whose ``"_subtree"`` is a function
    building that subtree's root tile the same way: the reader (``Tileset.expand``) calls it when a walk or a
    view reaches the stub, and traverses the stub whatever its error, as for an external tileset.
    """
    ext = tile.get("extensions", {}).get("3DTILES_implicit_tiling", {})
    spec = tile.get("implicitTiling") or ext
    try:
        scheme = str(spec["subdivisionScheme"]).upper()
        dims = {"QUADTREE": 2, "OCTREE": 3}[scheme]
        levels = int(spec["subtreeLevels"])
        available = int(spec.get("availableLevels", spec.get("maximumLevel", 0) + 1))
        subtree_uri = spec["subtrees"]["uri"]
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"implicit tiling is invalid ({type(exc).__name__}: {exc})", source) from exc
    n_children = 1 << dims
    contents = [c for c in ([tile["content"]] if tile.get("content") else []) + list(tile.get("contents", []))]
    bv = tile["boundingVolume"]
    error0 = float(tile["geometricError"])
    refine = tile.get("refine", "REPLACE")
    count = 0

    def fill(template: str, level: int, coords: tuple[int, ...]) -> str:
        out = template.replace("{level}", str(level))
        for name, c in zip("xyz", coords, strict=False):
            out = out.replace("{" + name + "}", str(c))
        return out

    def volume(level: int, coords: tuple[int, ...]) -> dict[str, Any]:
        n = 1 << level
        if "box" in bv:
            b = np.asarray(bv["box"], float)
            c, axes = b[:3].copy(), b[3:].reshape(3, 3)
            new_axes = axes.copy()
            for a in range(3):
                if a < dims:
                    c = c + axes[a] * (-1.0 + (2 * coords[a] + 1) / n)
                    new_axes[a] = axes[a] / n
            return {"box": [*map(float, c), *map(float, new_axes.reshape(-1))]}
        if "region" in bv:
            w, s, e, nn, h0, h1 = (float(v) for v in bv["region"])
            dx, dy = (e - w) / n, (nn - s) / n
            r = [w + coords[0] * dx, s + coords[1] * dy, w + (coords[0] + 1) * dx, s + (coords[1] + 1) * dy, h0, h1]
            if dims == 3:
                dz = (h1 - h0) / n
                r[4], r[5] = h0 + coords[2] * dz, h0 + (coords[2] + 1) * dz
            return {"region": r}
        raise InputError("implicit tiling needs a box or region bounding volume", source)

    def load_subtree(level: int, coords: tuple[int, ...]) -> _Subtree:
        uri = fill(subtree_uri, level, coords)
        try:
            return _Subtree(read(uri), f"{source} (subtree {uri})", read, n_children, levels)
        except (KeyError, IndexError, TypeError, ValueError, UnicodeDecodeError) as exc:
            raise InputError(f"subtree {uri} is invalid ({type(exc).__name__}: {exc})", source) from exc

    def build(sub: _Subtree, root_level: int, root_coords: tuple[int, ...], rel_level: int,
              rel_coords: tuple[int, ...]) -> dict[str, Any] | None:
        nonlocal count
        index = (n_children ** rel_level - 1) // (n_children - 1) + _morton(rel_coords, rel_level)
        if not sub.tile[index]:
            return None
        count += 1
        if count > _MAX_TILES:
            raise InputError(f"implicit tileset has more than {_MAX_TILES} tiles", source)
        level = root_level + rel_level
        coords = tuple((r << rel_level) + c for r, c in zip(root_coords, rel_coords, strict=True))
        out: dict[str, Any] = {"boundingVolume": volume(level, coords), "geometricError": error0 / (1 << level),
                               "refine": refine}
        avail = [c for i, c in enumerate(contents) if i < len(sub.content) and sub.content[i][index]]
        if avail:
            out["contents"] = [{"uri": fill(c["uri"], level, coords)} for c in avail]
        children = []
        if level + 1 < available:
            for k in range(n_children):
                child_rel = tuple((c << 1) | ((k >> a) & 1) for a, c in enumerate(rel_coords))
                if rel_level + 1 < levels:
                    ch = build(sub, root_level, root_coords, rel_level + 1, child_rel)
                elif sub.child[_morton(child_rel, levels)]:
                    child_coords = tuple((r << levels) + c for r, c in zip(root_coords, child_rel, strict=True))
                    if may_read is None or may_read():
                        ch = build(load_subtree(level + 1, child_coords), level + 1, child_coords, 0, (0,) * dims)
                    else:
                        ch = {"boundingVolume": volume(level + 1, child_coords),
                              "geometricError": error0 / (1 << (level + 1)), "refine": refine,
                              "_subtree": _later(level + 1, child_coords)}
                else:
                    ch = None
                if ch is not None:
                    children.append(ch)
        if children:
            out["children"] = children
        return out

    def _later(level: int, coords: tuple[int, ...]) -> Callable[[], dict[str, Any]]:
        def subtree_root() -> dict[str, Any]:
            built = build(load_subtree(level, coords), level, coords, 0, (0,) * dims)
            # A subtree whose root is not available (the parent said it was): an empty tile, nothing below.
            return built or {"boundingVolume": volume(level, coords), "geometricError": error0 / (1 << level),
                             "refine": refine}

        return subtree_root

    root = build(load_subtree(0, (0,) * dims), 0, (0,) * dims, 0, (0,) * dims)
    if root is None:
        root = {"boundingVolume": bv, "geometricError": error0, "refine": refine}
    if "transform" in tile:
        root["transform"] = tile["transform"]
    return root


__all__ = ["expand_implicit"]
