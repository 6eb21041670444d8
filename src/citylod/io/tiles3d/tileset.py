"""OGC 3D Tiles 1.x ``tileset.json``: written atomically, read safely.

What citylod writes (decision 1 of docs/DESIGN.md): 3D Tiles 1.1, glb content, ``geometricError`` equal to the
tile's guaranteed object-space error in metres, float32 positions relative to the tile centre with the centre
in the tile ``transform`` (float64). The root transform places the data on the globe (ECEF) so any client
shows it; the source CRS and the local origin are recorded in ``extras.citylod`` so citylod works in the
source CRS.

What citylod reads: any 3D Tiles 1.x tileset — glb, glTF, b3dm, i3dm, cmpt and pnts content (gzip or not),
several contents per tile, implicit tiling (:mod:`.implicit`), box / region / sphere bounding volumes, tile
transforms, external tilesets, gzip-compressed tileset JSON, and all of it inside a ``.3tz`` or ``.3dtiles`` package
(:mod:`.package`), read in place, or on a web server (:mod:`.remote`). URIs that leave the tileset's folder or
package (``../``, absolute paths, URLs), or for a web server its server, are refused with
:class:`~citylod.core.errors.UnsafePathError`.

No VTK and no Qt here.
"""

from __future__ import annotations

import gzip
import json
import math
import os
import threading
import urllib.parse
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pyproj

from citylod._version import __version__
from citylod.core.errors import InputError, UnsafePathError
from citylod.core.fileio import atomic_write_bytes, atomic_write_text
from citylod.core.frames import geodetic_to_ecef
from citylod.core.geometry import F64, Box, translation
from citylod.io.crs import ecef_from_local, parse_crs
from citylod.io.tiles3d.content import TileContent, glb_buffer
from citylod.io.tiles3d.implicit import expand_implicit
from citylod.io.tiles3d.legacy import decode_content
from citylod.io.tiles3d.package import Package, package_kind
from citylod.io.tiles3d.remote import Remote, is_url, open_remote


# --------------------------------------------------------------------------------------- atomic writing
def content_path(out_dir: str | os.PathLike[str], key: str) -> Path:
    """Where :func:`write_content` puts the content of tile ``key``."""
    return Path(out_dir) / "tiles" / f"{key}.glb"


def write_content(out_dir: str | os.PathLike[str], key: str, content: TileContent, *, atomic: bool = True) -> str:
    """Write a tile's glb; returns its URI relative to ``out_dir``.

    ``atomic`` writes under a temporary name and renames (a resumed build trusts every file it finds);
    a builder that never resumes from its partial folder may pass False (the folder itself is published
    atomically when complete).
    """
    if ".." in key.split("/") or key.startswith("/"):
        raise ValueError(f"tile key {key!r} must not leave the tileset folder")
    uri = f"tiles/{key}.glb"
    data = glb_buffer(content).data  # a memoryview: written without another copy
    if atomic:
        atomic_write_bytes(content_path(out_dir, key), data)
        return uri
    # Plain os calls: pathlib's objects cost more than the write of a small tile, under the GIL.
    path = os.path.join(out_dir, uri)
    try:
        f = open(path, "wb")
    except FileNotFoundError:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        f = open(path, "wb")
    with f:
        f.write(data)
    return uri


@dataclass
class TileSpec:
    """A tile as a builder describes it (see docs/CONTRACTS.md). Coordinates in the source CRS."""

    key: str
    level: int
    center: F64
    lo: F64
    hi: F64
    geometric_error: float
    content: str | None = None
    children: list[TileSpec] = field(default_factory=list)
    refine: str = "REPLACE"
    extras: dict[str, Any] | None = None


def write_tileset(out_dir: str | os.PathLike[str], root: TileSpec, crs: Any,
                  extras: dict[str, Any] | None = None, origin: npt.ArrayLike | None = None) -> Path:
    """Write ``tileset.json`` (3D Tiles 1.1) for the tree under ``root``, atomically.

    The root transform is the ECEF placement of the local frame at ``origin`` (default: the root centre);
    every other tile's transform is the translation from its parent's centre to its own.
    """
    out = Path(out_dir)
    crs = parse_crs(crs)
    org = np.asarray(root.center if origin is None else origin, dtype=np.float64)
    ecef = ecef_from_local(crs, org)

    def tile_json(spec: TileSpec, parent_center: list[float] | None) -> dict[str, Any]:
        # Plain floats, not 4×4 numpy matrices and Box objects (Box.aabb_3dtiles): the same numbers (IEEE double arithmetic
        # either way) at a tenth of the cost.
        center = [float(v) for v in spec.center]
        lo = [float(a) - c for a, c in zip(spec.lo, center, strict=True)]
        hi = [float(b) - c for b, c in zip(spec.hi, center, strict=True)]
        # A zero-thickness box (flat tile) is legal but degenerate for some clients: pad by a millimetre.
        hi = [max(b, a + 1e-3) for a, b in zip(lo, hi, strict=True)]
        t: dict[str, Any] = {
            "boundingVolume": {"box": Box.aabb_3dtiles(lo, hi)},
            "geometricError": float(spec.geometric_error),
            "refine": spec.refine,
        }
        if parent_center is None:
            m = ecef @ translation(np.subtract(center, org))
            if not np.array_equal(m, np.eye(4)):
                t["transform"] = [float(v) for v in m.T.reshape(16)]
        else:
            d = [c - p for c, p in zip(center, parent_center, strict=True)]
            if any(d):
                t["transform"] = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, *d, 1.0]
        if spec.content:
            t["content"] = {"uri": spec.content}
        if spec.extras:
            t["extras"] = spec.extras
        if spec.children:
            t["children"] = [tile_json(c, center) for c in spec.children]
        return t

    cl_extras = {"crs": crs.to_wkt(), "origin": [float(v) for v in org], "generator": f"citylod {__version__}"}
    epsg = crs.to_epsg()
    if epsg:
        cl_extras["epsg"] = epsg
    cl_extras.update((extras or {}).get("citylod", {}))
    doc = {
        "asset": {"version": "1.1", "generator": f"citylod {__version__}"},
        "geometricError": float(max(root.geometric_error * 2.0, float(np.linalg.norm(np.subtract(root.hi, root.lo))))),
        "root": tile_json(root, None),
        "extras": {**{k: v for k, v in (extras or {}).items() if k != "citylod"}, "citylod": cl_extras},
    }
    path = out / "tileset.json"
    # Compact: json's C encoder runs only without ``indent`` (indenting is pure Python, several times
    # slower on trees of thousands of tiles). `python -m json.tool` pretty-prints it.
    atomic_write_text(path, json.dumps(doc, separators=(",", ":")) + "\n")
    return path


# ----------------------------------------------------------------------------------------------- reading
def safe_resolve(base_dir: Path, uri: str, root_dir: Path, source: str) -> Path:
    """Resolve a content URI against ``base_dir``, refusing anything that leaves ``root_dir``."""
    parsed = urllib.parse.urlsplit(uri)
    if parsed.scheme or parsed.netloc:
        raise UnsafePathError(f"content URI {uri!r} is a URL; only files inside the tileset folder are read", source)
    rel = urllib.parse.unquote(parsed.path)
    if "\x00" in rel:
        raise UnsafePathError(f"content URI {uri!r} holds a NUL byte", source)
    if not rel or rel.startswith(("/", "\\")) or (len(rel) > 1 and rel[1] == ":"):
        raise UnsafePathError(f"content URI {uri!r} is an absolute path", source)
    target = (base_dir / rel).resolve()
    root = root_dir.resolve()
    if not target.is_relative_to(root):
        raise UnsafePathError(f"content URI {uri!r} points outside the tileset folder {root}", source)
    return target


@dataclass
class TileMesh:
    """A tile's content in the tileset's CRS: ``vertices`` (N, 3) float64, ``faces`` (M, 3) int64,
    ``skirt`` (M,) bool, ``points`` (K, 3) float64 or None, and the raw ``content``."""

    vertices: F64
    faces: npt.NDArray[np.int64]
    skirt: npt.NDArray[np.bool_]
    points: F64 | None
    content: TileContent

    def to_pyvista(self, *, origin: npt.ArrayLike | None = None, skirts: bool = False, part: str = "auto") -> Any:
        """The tile as a ``pyvista.PolyData`` in float64: its triangles, or its points.

        ``part`` is ``"surface"`` (the triangles), ``"points"`` or ``"auto"`` (the triangles when there are
        any, else the points); a hybrid point tile has both (points and plane quads).

        ``origin`` (3,) is subtracted from every position: pass one near the data (e.g. the tileset's
        root centre) before rendering, since GPUs draw in float32 and UTM or ECEF coordinates lose
        centimetres there. Skirt triangles are left out unless ``skirts``. Point tiles carry their
        ``classification``, ``intensity`` and ``rgb`` as point data where present.

        pyvista is imported here, lazily, for scripted users; nothing else in io/ touches VTK.

        Examples
        --------
        >>> mesh = tileset.root.load().to_pyvista(origin=tileset.root.box.center)  # doctest: +SKIP
        >>> mesh.plot()                                                             # doctest: +SKIP
        """
        import pyvista as pv

        if part not in ("auto", "surface", "points"):
            raise ValueError(f"part must be 'auto', 'surface' or 'points', got {part!r}")
        shift = np.zeros(3) if origin is None else np.asarray(origin, np.float64)
        if part == "points" and self.points is None:
            raise ValueError("this tile has no points")
        if self.points is not None and (part == "points" or (part == "auto" and len(self.faces) == 0)):
            cloud = pv.PolyData(self.points - shift)
            pts = self.content.points
            assert pts is not None
            for name in ("classification", "intensity", "rgb"):
                value = getattr(pts, name, None)
                if value is not None:
                    cloud.point_data[name] = np.asarray(value)
            return cloud
        faces = self.faces if skirts else self.faces[~self.skirt]
        cells = np.column_stack([np.full(len(faces), 3, np.int64), faces]).ravel()
        return pv.PolyData(self.vertices - shift, cells)


class Tile:
    """One tile of an opened tileset. See docs/CONTRACTS.md."""

    __slots__ = ("_size", "base", "box", "chain", "children", "content_path", "content_paths", "content_uri",
                 "external", "geometric_error", "key", "level", "matrix", "parent", "pending", "point_count", "refine",
                 "shift", "source", "tileset", "triangle_count", "world")

    def __init__(self, tileset: Tileset, key: str, level: int, parent: Tile | None, matrix: F64, box: Box,
                 geometric_error: float, refine: str, content_uri: str | None, content_path: Path | None,
                 content_paths: list[Path] | None = None) -> None:
        self.tileset = tileset
        self.key = key
        self.level = level
        self.parent = parent
        self.children: list[Tile] = []
        self.matrix = matrix
        # Where the content's positions are measured from in the tile's own frame (``matrix`` includes it):
        # zero, or the bounding volume's centre when the tile frame is far from its content (ECEF tilesets).
        self.shift = np.zeros(3)
        self.box = box
        self.geometric_error = geometric_error
        self.refine = refine
        self.content_uri = content_uri
        self.content_path = content_path
        # Every content of the tile (3D Tiles 1.1 ``contents``): all are loaded and drawn together.
        self.content_paths: list[Path] = content_paths if content_paths is not None else (
            [] if content_path is None else [content_path])
        self._size: int | None = None
        # Cost hints for budgets before a tile is loaded (written by citylod builders in tile extras).
        self.triangle_count = 0
        self.point_count = 0
        #: Children not read yet, as (child index, external tileset file, or a function building an implicit
        #: subtree's root tile); None when every child is known (:meth:`Tileset.expand` reads them).
        self.pending: list[tuple[int, Path | Callable[[], dict[str, Any]]]] | None = None
        #: Some of the tile's content is an external tileset (its root is a child): clients traverse such a tile
        #: whatever its error, as CesiumJS does, since the tile itself draws none of it.
        self.external = False
        # The tile frame in the world (ECEF for other tools' tilesets) and the tileset files above it, which
        # an expansion continues from.
        self.world: F64 = np.eye(4)
        self.chain: tuple[str, ...] = ()
        self.base: Path = tileset.folder  # the folder the tile's URIs are relative to, and its tileset file
        self.source = ""

    def __repr__(self) -> str:
        return f"Tile({self.key!r}, level={self.level}, error={self.geometric_error:.3g})"

    @property
    def bounds(self) -> tuple[F64, F64]:
        return self.box.bounds()

    @property
    def content_bytes(self) -> int:
        if self._size is None:
            self._size = 0
            for p in self.content_paths:
                self._size += self.tileset.file_size(p)
        return self._size

    def load_content(self) -> TileContent:
        """The content with float32 positions relative to the tile's origin (map them with ``matrix``)."""
        if not self.content_paths:
            return TileContent()
        # Positions relative to the tile frame's point ``shift`` (what ``matrix`` includes), in float64 first.
        out = TileContent.merged([self._load_one(p) for p in self.content_paths]).rebased(self.shift)
        out.origin = np.zeros(3)
        return out

    def _load_one(self, path: Path) -> TileContent:
        ts = self.tileset
        data = ts.read_file(path, "tile content", str(path))

        def resolve(uri: str) -> bytes:
            return ts.read_file(ts.resolve(path.parent, uri, str(path)), repr(uri), str(path))

        content = decode_content(data, str(path), y_up=self.tileset.y_up, resolve=resolve)
        if self.tileset.up_axis == "X":  # CesiumJS's Axis.X_UP_TO_Z_UP, a −90° turn about y; RTC is z-up already
            turn = np.array([[0.0, 0, -1], [0, 1, 0], [1, 0, 0]])
            for m in content.meshes:
                m.positions = (m.positions.astype(np.float64) @ turn.T).astype(np.float32)
            if content.points is not None:
                content.points.positions = (content.points.positions.astype(np.float64) @ turn.T).astype(np.float32)
        return content

    def load(self) -> TileMesh:
        """The content in the tileset's CRS, float64."""
        content = self.load_content()
        verts, faces, skirt = [], [], []
        offset = 0
        for m in content.meshes:
            verts.append(m.positions)
            faces.append(m.faces.astype(np.int64) + offset)
            skirt.append(np.zeros(len(m.faces), bool) if m.skirt is None else m.skirt)
            offset += len(m.positions)
        v = np.concatenate(verts) if verts else np.zeros((0, 3), np.float32)
        mat = self.matrix
        vertices = v.astype(np.float64) @ mat[:3, :3].T + mat[:3, 3]
        pts = None
        if content.points is not None:
            pts = content.points.positions.astype(np.float64) @ mat[:3, :3].T + mat[:3, 3]
        return TileMesh(
            vertices=vertices,
            faces=np.concatenate(faces) if faces else np.zeros((0, 3), np.int64),
            skirt=np.concatenate(skirt) if skirt else np.zeros(0, bool),
            points=pts, content=content,
        )


#: A tile's JSON waiting to be built: (JSON, world matrix, parent, key, level, folder its URIs are relative to,
#: the tileset file it is in, the chain of tileset files above it).
_Pending = tuple[dict[str, Any], F64, "Tile | None", str, int, Path, str, tuple[str, ...]]

# Limits on what a tileset may make citylod build, so that a small hostile file cannot exhaust memory or time:
# deep nesting, a chain of external tilesets each referenced many times (8 children pointing at the next file,
# nine files deep, are 8^9 tiles), self references. Real tilesets stay far below them: a quadtree of 64
# levels already resolves 1 mm on the Earth, and a file referenced from more than a few places is unusual.
MAX_TILES = 2_000_000
MAX_LEVELS = 64
MAX_EXTERNAL_LOADS = 1_000_000
MAX_LOADS_PER_EXTERNAL = 64
#: External tilesets read while a tileset opens; the others wait until :meth:`Tileset.expand` (a walk, or a view
#: that refines into them). Photogrammetry exports hold tens of thousands of them, one per tile.
EAGER_EXTERNAL_FILES = 1000
EAGER_EXTERNAL_REMOTE = 16


class Tileset:
    """An opened 3D Tiles tileset (see :func:`open_tileset`).

    Opening builds the tree, splicing in up to :data:`EAGER_EXTERNAL_FILES` external tilesets
    (:data:`EAGER_EXTERNAL_REMOTE` from a web server); a tile whose external tilesets are not read yet has
    ``pending`` set, and :meth:`expand` reads them (:meth:`walk` expands as it goes; the renderer's selection
    expands what a view refines into), so a tree of many files opens at once and loads what is looked at, as
    3D Tiles clients do. The limits :data:`MAX_TILES`, :data:`MAX_LEVELS`, :data:`MAX_EXTERNAL_LOADS` and
    :data:`MAX_LOADS_PER_EXTERNAL` hold over every expansion; a tileset that refers to itself, directly or
    through others, is refused.
    """

    def __init__(self, path: Path, doc: dict[str, Any], store: Package | Remote | None = None) -> None:
        self.path = path
        self.folder = path.parent
        # A .3tz / .3dtiles file read in place, or a folder on a web server: ``folder`` stands for it (the package's
        # path, or a stand-in path for the server's folder) and the files' paths lie below it. None: files.
        self.store = store
        #: Where the tileset came from, as the user named it (a path, or the URL of a remote tileset).
        self.source = store.source if isinstance(store, Remote) else str(path)
        #: Credits the data's server asks clients to show (a Cesium ion asset's attributions).
        self.attributions: list[str] = list(store.attributions) if isinstance(store, Remote) else []
        self.doc = doc
        self.extras: dict[str, Any] = doc.get("extras", {}) or {}
        cl = self.extras.get("citylod", {}) if isinstance(self.extras, dict) else {}
        # 3D Tiles 1.0 ``asset.gltfUpAxis`` (Y by default; Z and X were allowed, and CesiumJS still honours them).
        self.up_axis = str(doc.get("asset", {}).get("gltfUpAxis", "Y")).upper()
        self.y_up = self.up_axis not in ("Z", "X")
        self.citylod: dict[str, Any] = cl if isinstance(cl, dict) else {}
        root_json = doc["root"]
        root_m = _tile_transform(root_json, str(path))
        if self.citylod.get("crs"):
            self.crs = parse_crs(self.citylod["crs"], str(path))
            self.origin = np.asarray(self.citylod.get("origin", [0, 0, 0]), np.float64)
            # crs_from_ecef: undo the root's placement on the globe, then add the local origin.
            self._crs_from_world = translation(self.origin) @ np.linalg.inv(root_m)
        else:
            self.crs = pyproj.CRS.from_epsg(4978)
            self.origin = np.zeros(3)
            self._crs_from_world = np.eye(4)
        self.kind = str(self.citylod.get("kind", "unknown"))
        self._tiles = self._external_loads = 0
        self._loads: dict[str, int] = {}
        self._eager_left = EAGER_EXTERNAL_REMOTE if isinstance(store, Remote) else EAGER_EXTERNAL_FILES
        self._expand_lock = threading.RLock()
        root = self._grow([(root_json, root_m, None, "0", 0, self.folder, str(path), (str(self.path),))])
        assert root is not None
        self.root = root

    def _grow(self, stack: list[_Pending]) -> Tile | None:
        """Build the tiles of ``stack``'s JSON subtrees (an explicit stack: tilesets can be deep). External
        tilesets are read and spliced in while the eager budget lasts, else left ``pending`` on their tile.
        Each entry carries the chain of tileset files above it, to name a cycle. Returns the first entry's
        tile."""
        first: Tile | None = None
        grown: list[Tile] = []
        while stack:
            tj, world, parent, key, level, base, source, chain = stack.pop()
            self._tiles += 1
            if self._tiles > MAX_TILES:
                raise InputError(f"more than {MAX_TILES:,} tiles; refused as a likely hostile tileset", source)
            if level > MAX_LEVELS:
                raise InputError(f"tiles nest deeper than {MAX_LEVELS} levels; refused", source)
            if not isinstance(tj, dict) or "boundingVolume" not in tj or "geometricError" not in tj:
                raise InputError(f"tile {key[:80]} lacks boundingVolume or geometricError", source)
            if "implicitTiling" in tj or "3DTILES_implicit_tiling" in tj.get("extensions", {}):
                tj = expand_implicit(tj, self._reader(base, source), source, self._take_eager)
            matrix = self._crs_from_world @ world
            # A region is in ECEF whatever the tile's transform; boxes and spheres live in the tile's frame.
            in_ecef = "region" in tj["boundingVolume"]
            local_box = _bounding_box(tj["boundingVolume"], source, key)
            box = local_box.transformed(self._crs_from_world if in_ecef else matrix)
            centre = (np.linalg.inv(world) @ [*local_box.center, 1.0])[:3] if in_ecef else local_box.center
            # Content far from its tile frame's origin (ECEF coordinates with identity transforms) is loaded
            # relative to the volume's centre, so float32 positions keep millimetres (Tile.load_content).
            shift = np.round(centre) if float(np.abs(centre).max()) > 1e4 else np.zeros(3)
            refine = str(tj.get("refine", parent.refine if parent else "REPLACE")).upper()
            uri = None
            cpaths: list[Path] = []
            children_json = list(tj.get("children", []))
            # (child index, tileset file) of the tile's external tilesets; an implicit subtree not read yet is a
            # function giving its root tile's JSON (citylod.io.tiles3d.implicit)
            externals: list[tuple[int, Path | Callable[[], dict[str, Any]]]] = []
            if "_subtree" in tj:
                externals.append((len(children_json), tj["_subtree"]))
            for content in _contents(tj):
                curi = content.get("uri", content.get("url")) if isinstance(content, dict) else None
                if curi is not None and not isinstance(curi, str):
                    raise InputError(f"tile {key[:80]} has a content URI that is not a string", source)
                if not curi:
                    continue
                if curi.lower().split("?")[0].endswith(".json"):
                    ext_path = self.resolve(base, curi, source)
                    external = str(ext_path)
                    if external in chain:
                        raise InputError(f"tileset refers to itself through {curi!r} (a cycle of external "
                                         f"tilesets: {' -> '.join(Path(c).name for c in chain)} -> {ext_path.name})",
                                         source)
                    self._loads[external] = self._loads.get(external, 0) + 1
                    self._external_loads += 1
                    if (self._loads[external] > MAX_LOADS_PER_EXTERNAL
                            or self._external_loads > MAX_EXTERNAL_LOADS):
                        raise InputError(f"external tileset {curi!r} is referenced {self._loads[external]} times "
                                         f"({self._external_loads} external loads in all); refused as a likely "
                                         "hostile tileset", source)
                    externals.append((len(children_json) + len(externals), ext_path))
                else:
                    uri = uri or curi
                    cpaths.append(self.resolve(base, curi, source))
            tile = Tile(self, key, level, parent, matrix @ translation(shift), box, float(tj["geometricError"]),
                        refine, uri, cpaths[0] if cpaths else None, cpaths)
            tile.shift = shift
            tile.world = world
            tile.chain = chain
            tile.external = bool(externals)
            hints = tj.get("extras", {})
            if isinstance(hints, dict):
                tile.triangle_count = int(hints.get("triangles", 0) or 0)
                tile.point_count = int(hints.get("points", 0) or 0)
            if parent is not None:
                parent.children.append(tile)
            if first is None:
                first = tile
            grown.append(tile)
            for i, cj in enumerate(reversed(children_json)):
                ci = len(children_json) - 1 - i
                stack.append((cj, world @ _tile_transform(cj, source), tile, f"{key}/{ci}", level + 1, base, source,
                              chain))
            if externals:
                if "_subtree" not in tj and self._eager_left >= len(externals):
                    self._eager_left -= len(externals)
                    stack.extend(self._external_roots(tile, externals, base, source))
                else:
                    tile.pending = externals
                    tile.base, tile.source = base, source
        # children were pushed reversed and popped in order; splices come last: restore document order
        for t in grown:
            if len(t.children) > 1:
                t.children.sort(key=lambda c: int(c.key.rsplit("/", 1)[1]))
        return first

    def _external_roots(self, tile: Tile, externals: list[tuple[int, Path | Callable[[], dict[str, Any]]]],
                        base: Path, source: str) -> list[_Pending]:
        """Stack entries for the roots of ``tile``'s external tilesets (read now) and implicit subtrees (built
        now), last first; ``base`` and ``source`` are where ``tile`` itself was defined."""
        out: list[_Pending] = []
        for ci, where in reversed(externals):
            if callable(where):  # an implicit subtree: its root tile, in the implicit tileset's own frame
                root = where()
                out.append((root, tile.world, tile, f"{tile.key}/{ci}", tile.level + 1, base, source, tile.chain))
                continue
            external = str(where)
            ext = _read_json(where, self.read_file)
            root = ext["root"]
            out.append((root, tile.world @ _tile_transform(root, external), tile, f"{tile.key}/{ci}", tile.level + 1,
                        where.parent, external, (*tile.chain, external)))
        return out

    def _take_eager(self) -> bool:
        """Whether one more external file may be read while the tileset opens (and take it from the budget)."""
        if self._eager_left > 0:
            self._eager_left -= 1
            return True
        return False

    def expand(self, tile: Tile) -> bool:
        """Read the external tilesets ``tile`` refers to (``tile.pending``) and splice their trees in as its
        children; False when there were none. Threads may expand different tiles at once: the files are read
        outside the tree's lock, the tiles built under it."""
        with self._expand_lock:
            externals, tile.pending = tile.pending, None
        if not externals:
            return False
        try:
            roots = self._external_roots(tile, externals, tile.base, tile.source)
            with self._expand_lock:
                self._grow(roots)
        except Exception:
            with self._expand_lock:
                tile.pending = externals  # nothing spliced: the next call reports the same problem
                spliced = {ci for ci, _ in externals}
                tile.children[:] = [c for c in tile.children if int(c.key.rsplit("/", 1)[1]) not in spliced]
            raise
        with self._expand_lock:
            tile.children.sort(key=lambda c: int(c.key.rsplit("/", 1)[1]))
        return True

    def resolve(self, base: Path, uri: str, source: str) -> Path:
        """The path of ``uri`` referred to from folder ``base``: inside the tileset's folder or package
        (:func:`safe_resolve`), or on the same web server (:meth:`Remote.resolve`)."""
        if isinstance(self.store, Remote):
            return self.store.resolve(base, uri, source)
        return safe_resolve(base, uri, self.folder, source)

    def read_file(self, path: Path, what: str = "file", source: str | None = None) -> bytes:
        """The bytes of a file of this tileset (``path`` from :meth:`resolve`), in its folder, package or server."""
        if self.store is not None:
            return self.store.read(path.relative_to(self.store.root).as_posix())
        try:
            return path.read_bytes()
        except OSError as exc:
            raise InputError(f"cannot read {what} ({exc.strerror or exc})", source or path) from exc

    def file_size(self, path: Path) -> int:
        """A file's size in bytes, 0 when it cannot be found."""
        if self.store is not None:
            return self.store.size(path.relative_to(self.store.root).as_posix())
        try:
            return path.stat().st_size
        except OSError:
            return 0

    def _reader(self, base: Path, source: str) -> Callable[[str], bytes]:
        """Reads URIs relative to ``base`` that stay inside the tileset (implicit tiling's subtrees)."""

        def read(uri: str) -> bytes:
            return self.read_file(self.resolve(base, uri, source), repr(uri), source)

        return read

    @staticmethod
    def walk_from(root: Tile) -> Iterator[Tile]:
        """Every tile under ``root``, breadth first, external tilesets read as they are reached."""
        queue = [root]
        i = 0
        while i < len(queue):
            t = queue[i]
            i += 1
            if t.pending:
                t.tileset.expand(t)
            yield t
            queue.extend(t.children)

    def walk(self) -> Iterator[Tile]:
        """Every tile, root first (breadth first); external tilesets not read yet are read on the way."""
        return self.walk_from(self.root)

    @property
    def bounds(self) -> tuple[F64, F64]:
        return self.root.bounds

    def __repr__(self) -> str:
        return f"Tileset({str(self.path)!r}, kind={self.kind!r}, crs={self.crs.name!r})"


def _contents(tj: dict[str, Any]) -> list[Any]:
    """A tile's contents: ``content``, 1.1 ``contents`` and the 1.0 ``3DTILES_multiple_contents`` extension."""
    out = [tj["content"]] if tj.get("content") else []
    out += list(tj.get("contents") or [])
    out += list(tj.get("extensions", {}).get("3DTILES_multiple_contents", {}).get("contents", []))
    return out


def _read_json(path: Path, read: Callable[[Path], bytes] | None = None) -> dict[str, Any]:
    try:
        raw = path.read_bytes() if read is None else read(path)
        if raw[:2] == b"\x1f\x8b":  # gzip-compressed tileset JSON, as some servers store it
            raw = gzip.decompress(raw)
        doc = json.loads(raw.decode("utf-8"))
    except FileNotFoundError as exc:
        raise InputError("tileset not found", path) from exc
    except OSError as exc:
        raise InputError(f"cannot read tileset ({exc.strerror or exc})", path) from exc
    except RecursionError as exc:
        raise InputError("tileset JSON nests too deeply to read", path) from exc
    except (UnicodeDecodeError, ValueError, EOFError, zlib.error) as exc:  # JSONDecodeError, 5000-digit numbers
        raise InputError(f"tileset is not valid JSON ({str(exc)[:200]})", path) from exc
    if not isinstance(doc, dict) or "root" not in doc:
        raise InputError("not a 3D Tiles tileset (no 'root')", path)
    asset = doc.get("asset")
    version = str(asset.get("version", "") if isinstance(asset, dict) else "")[:20]
    if not version.startswith("1."):
        raise InputError(f"3D Tiles version {version!r} is not supported (1.x only)", path)
    return doc


def _tile_transform(tj: dict[str, Any], source: str) -> F64:
    if "transform" not in tj:
        return np.eye(4)
    try:
        m = np.asarray(tj["transform"], dtype=np.float64).reshape(4, 4).T
    except (TypeError, ValueError) as exc:
        raise InputError(f"tile transform is not 16 numbers ({exc})", source) from exc
    if not np.all(np.isfinite(m)):
        raise InputError("tile transform has non-finite numbers", source)
    return m


def _bounding_box(bv: dict[str, Any], source: str, key: str) -> Box:
    try:
        if "box" in bv:
            return Box.from_3dtiles(bv["box"])
        if "sphere" in bv:
            x, y, z, r = (float(v) for v in bv["sphere"])
            return Box(np.array([x, y, z]), np.eye(3) * r)
        if "region" in bv:
            w, s, e, n, h0, h1 = (float(v) for v in bv["region"])
            # Region in radians on WGS84: enclose a grid of surface points at both heights (ECEF).
            lons = np.linspace(w, e, 5)
            lats = np.linspace(s, n, 5)
            pts = np.array([geodetic_to_ecef(math.degrees(lo), math.degrees(la), h)
                            for lo in lons for la in lats for h in (h0, h1)])
            return Box.from_bounds(pts.min(axis=0), pts.max(axis=0))
    except (TypeError, ValueError) as exc:
        raise InputError(f"tile {key} has an invalid bounding volume ({exc})", source) from exc
    raise InputError(f"tile {key} has no box, region or sphere bounding volume", source)


def open_tileset(path: str | os.PathLike[str]) -> Tileset:
    """Open a 3D Tiles 1.x tileset: a ``tileset.json``, the folder holding one, a ``.3tz`` / ``.3dtiles``
    package (read in place, tile by tile) or an http(s) URL of a tileset JSON (:mod:`.remote`).

    Only the tileset document (and external tilesets it names) is read; tile content loads on demand
    (:meth:`Tile.load`). Coordinates come out in :attr:`Tileset.crs`: the source CRS for tilesets citylod
    built, ECEF (EPSG:4978) for others.

    Examples
    --------
    >>> import citylod
    >>> ts = citylod.open_tileset("TILES")                                   # doctest: +SKIP
    >>> ts.crs.name, ts.root.geometric_error                                  # doctest: +SKIP
    ('WGS 84 / UTM zone 32N', 21.97)
    >>> mesh = ts.root.load()                                                 # doctest: +SKIP
    >>> mesh.vertices.shape[1], mesh.faces.shape[1]                           # doctest: +SKIP
    (3, 3)
    """
    store: Package | Remote | None = None
    if is_url(path):
        store = open_remote(str(path))
        p = store.entry
    else:
        p = Path(path)
        kind = package_kind(p)
        if kind is not None:
            store = Package(p.resolve(), kind)
            p = store.path / "tileset.json"
        elif p.is_dir():
            p = p / "tileset.json"
    doc = _read_json(p, None if store is None else (lambda q: store.read(q.relative_to(store.root).as_posix())))
    try:
        return Tileset(p if store is not None else p.resolve(), doc, store)
    except (KeyError, TypeError, AttributeError, ValueError, OverflowError, IndexError) as exc:
        # Any shape the schema does not allow (a string where a number belongs, a list for an object).
        raise InputError(f"tileset structure is invalid ({type(exc).__name__}: {str(exc)[:200]})", p) from exc
