"""The heights of a built DSM tileset as a raster on its source grid, so a flood can run on the tileset.

``citylod build dsm`` puts every leaf on the raster's own grid: a leaf's vertices are raster samples and its
faces a TIN over them (docs/DESIGN.md, "DSM tile tree"). :func:`rasterise_tileset` maps each leaf's vertices
back to raster rows and columns (the grid is in the tileset's ``extras.citylod.grid``; rasters in degrees
through the inverse of the projection the build applied), and evaluates the TIN at every sample it covers:
linear interpolation in the (row, column) plane, with exact integer tests for which face holds a sample.
Rows are processed in strips, each leaf is decoded once, and only the leaves that reach the next strip are
kept, so memory depends on the strip and one row of leaves, not on the raster.

Why a flood on these heights stays within the tileset's error: a leaf's ``geometricError`` is its kernel's
bound on the *vertical* distance between its TIN and the raster surface (exact at every sample), plus the
rounding of its float32 heights and its horizontal quantisation (leaves never use the Hausdorff metric), so
at every sample the rasterised height h' and the source height h satisfy |h' − h| ≤ ε, ε the largest leaf
error. Connected flooding is monotone in the heights: a cell linked to a source through cells with h < L − ε
is linked through cells with h' < L, and a cell linked through h' < L is linked through h < L + ε. So
flood(h, L − ε) ⊆ flood(h', L) ⊆ flood(h, L + ε), and where both floods hold water their depths differ by at
most ε. The exception is a valid sample that no leaf face covers (a sample whose valid neighbours form no
triangle, such as a one-sample-wide line between no-data): it comes out as no-data. No VTK, no Qt.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pyproj
from numba import njit

from citylod.core.errors import InputError
from citylod.io.tiles3d.package import is_tileset_path

__all__ = ["TilesetHeights", "is_tileset", "rasterise_tileset"]

_STRIP_CELLS = 1 << 22
#: Largest distance (in cells) of a leaf vertex from a grid sample: more means the grid record is wrong.
_ON_GRID = 0.05


@dataclass(frozen=True)
class TilesetHeights:
    """What :func:`rasterise_tileset` wrote: the GeoTIFF, the tileset, its leaves and the bound ε (m)."""

    path: Path
    tileset: Path
    leaves: int
    max_error_m: float


def is_tileset(path: str | os.PathLike[str]) -> bool:
    """True for a ``tileset.json``, a folder holding one, or a ``.3tz`` / ``.3dtiles`` package."""
    p = Path(path)
    return (p.is_dir() and (p / "tileset.json").is_file()) or (p.is_file() and is_tileset_path(p))


@njit(cache=True, nogil=True)
def _rasterise(vr, vc, vz, faces, row0, out_h, out_v):  # pragma: no cover - compiled
    """Evaluate a TIN with integer (row, column) vertices at every sample of rows row0.. of ``out_h``.

    Barycentric weights are integer orientation tests (exact: the vertices are integers), so a sample on an
    edge or a vertex belongs to the face for certain; shared edges write the same interpolated height.
    Degenerate faces (skirts are vertical, so flat in this plane) cover nothing."""
    nr, nc = out_h.shape
    for f in range(faces.shape[0]):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        ar, ac, br, bc, cr, cc = vr[a], vc[a], vr[b], vc[b], vr[c], vc[c]
        area = (bc - ac) * (cr - ar) - (br - ar) * (cc - ac)
        if area == 0:
            continue
        sgn = 1 if area > 0 else -1
        area *= sgn
        r_lo = max(min(ar, br, cr), row0)
        r_hi = min(max(ar, br, cr), row0 + nr - 1)
        c_lo = max(min(ac, bc, cc), 0)
        c_hi = min(max(ac, bc, cc), nc - 1)
        for r in range(r_lo, r_hi + 1):
            for q in range(c_lo, c_hi + 1):
                w0 = sgn * ((cc - bc) * (r - br) - (cr - br) * (q - bc))
                if w0 < 0:
                    continue
                w1 = sgn * ((ac - cc) * (r - cr) - (ar - cr) * (q - cc))
                if w1 < 0:
                    continue
                w2 = area - w0 - w1
                if w2 < 0:
                    continue
                out_h[r - row0, q] = (w0 * vz[a] + w1 * vz[b] + w2 * vz[c]) / area
                out_v[r - row0, q] = True


@dataclass
class _Leaf:
    tile: object
    r_lo: int
    r_hi: int
    vr: npt.NDArray[np.int64] | None = None
    vc: npt.NDArray[np.int64] | None = None
    vz: npt.NDArray[np.float64] | None = None
    faces: npt.NDArray[np.int64] | None = None


def rasterise_tileset(tileset: str | os.PathLike[str], out_tif: str | os.PathLike[str], *,
                      strip_rows: int | None = None) -> TilesetHeights:
    """Write the heights of a citylod DSM tileset's leaves as a float64 GeoTIFF on the source grid.

    No-data (NaN) where no leaf face covers a sample. Raises :class:`InputError` for a tileset that is not a
    citylod DSM tileset, lacks its grid record (built before it was written: rebuild it), or whose leaves do
    not sit on that grid.
    """
    import rasterio
    from affine import Affine
    from rasterio.windows import Window

    from citylod.io.tiles3d import open_tileset

    ts = open_tileset(tileset)
    where = ts.path
    if ts.kind != "dsm":
        raise InputError(f"not a DSM tileset (kind {ts.kind!r}): only `citylod build dsm` tilesets can be "
                         "flooded", where)
    grid = ts.citylod.get("grid")
    if not isinstance(grid, dict) or "transform" not in grid:
        raise InputError("the tileset has no record of its source grid (built by an older citylod): rebuild it "
                         "with `citylod build dsm`", where)
    width, height = int(grid["width"]), int(grid["height"])
    a, b, c, d, e, f = (float(v) for v in grid["transform"])
    src_crs = pyproj.CRS.from_wkt(ts.citylod["source_crs"]) if ts.citylod.get("source_crs") else ts.crs
    to_src = None if src_crs.equals(ts.crs) else pyproj.Transformer.from_crs(ts.crs, src_crs, always_xy=True)
    det = a * e - b * d
    if det == 0:
        raise InputError("the tileset's recorded source grid is degenerate", where)
    n_levels = int(ts.citylod.get("levels", 0) or 0)

    def to_rc(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if to_src is not None:
            x, y = to_src.transform(x, y)
        dx, dy = np.asarray(x) - c, np.asarray(y) - f
        col = (e * dx - b * dy) / det
        row = (a * dy - d * dx) / det
        return row - 0.5, col - 0.5  # sample centres sit at +0.5

    leaves: list[_Leaf] = []
    for t in ts.walk():
        if not t.content_paths or t.children:
            continue
        if n_levels and t.level != n_levels - 1:
            raise InputError(f"tile {t.key} has content but no children above the finest level; not a complete "
                             "DSM tile tree", where)
        lo, hi = t.bounds
        xs = np.array([lo[0], hi[0], lo[0], hi[0]])
        ys = np.array([lo[1], lo[1], hi[1], hi[1]])
        rows, _ = to_rc(xs, ys)
        pad = 2 if to_src is not None else 1  # a projected box's corners are not the extreme rows in degrees
        leaves.append(_Leaf(t, max(int(math.floor(rows.min())) - pad, 0),
                            min(int(math.ceil(rows.max())) + pad, height - 1)))
    if not leaves:
        raise InputError("the tileset has no leaf with content", where)
    leaves.sort(key=lambda lf: lf.r_lo)
    rows_per = strip_rows or max(16, _STRIP_CELLS // max(width, 1))
    profile = {"driver": "GTiff", "width": width, "height": height, "count": 1, "dtype": "float64",
               "crs": src_crs.to_wkt(), "transform": Affine(a, b, c, d, e, f), "nodata": float("nan"),
               "tiled": True, "blockxsize": 256, "blockysize": 256, "compress": "zstd", "zstd_level": 1}
    out = Path(out_tif)
    worst = 0.0
    nxt = 0
    live: list[_Leaf] = []
    try:
        ds = rasterio.open(out, "w", **profile)
    except rasterio.errors.RasterioError:
        profile.pop("zstd_level")
        ds = rasterio.open(out, "w", **(profile | {"compress": "deflate"}))
    with ds:
        for row0 in range(0, height, rows_per):
            row1 = min(row0 + rows_per, height)
            while nxt < len(leaves) and leaves[nxt].r_lo < row1:
                live.append(leaves[nxt])
                nxt += 1
            h = np.full((row1 - row0, width), np.nan)
            v = np.zeros(h.shape, bool)
            for lf in live:
                if lf.r_hi < row0:
                    continue
                if lf.faces is None:
                    _load_leaf(lf, to_rc, where)
                    worst = max(worst, float(lf.tile.geometric_error))  # type: ignore[attr-defined]
                assert lf.vr is not None and lf.vc is not None and lf.vz is not None and lf.faces is not None
                _rasterise(lf.vr, lf.vc, lf.vz, lf.faces, row0, h, v)
                if lf.r_hi < row1:  # done: its arrays go now, not at the end of the strip
                    lf.vr = lf.vc = lf.vz = lf.faces = None
            live = [lf for lf in live if lf.r_hi >= row1]  # the others are done: let their arrays go
            h[~v] = np.nan
            ds.write(h, 1, window=Window(0, row0, width, row1 - row0))
    return TilesetHeights(out, Path(where), len(leaves), worst)


def _load_leaf(lf: _Leaf, to_rc, where: Path) -> None:  # type: ignore[no-untyped-def]
    """Decode a leaf, drop its skirts, and snap its vertices to (row, column) integers (checked)."""
    mesh = lf.tile.load()  # type: ignore[attr-defined]
    faces = mesh.faces[~mesh.skirt] if len(mesh.skirt) == len(mesh.faces) else mesh.faces
    mark = np.zeros(len(mesh.vertices), bool)
    mark[faces] = True  # the surface's vertices (skirt vertices hang below them, unused now)
    used = np.flatnonzero(mark)
    row, col = to_rc(mesh.vertices[used, 0], mesh.vertices[used, 1])
    ir, ic = np.rint(row), np.rint(col)
    off = float(np.max(np.maximum(np.abs(row - ir), np.abs(col - ic)), initial=0.0))
    if off > _ON_GRID:
        raise InputError(f"tile {lf.tile.key}: its vertices lie {off:.2f} cells off the recorded source grid "  # type: ignore[attr-defined]
                         "(not a leaf on the raster's grid)", where)
    remap = np.zeros(len(mesh.vertices), np.int64)
    remap[used] = np.arange(len(used))
    lf.vr, lf.vc = ir.astype(np.int64), ic.astype(np.int64)
    lf.vz = np.ascontiguousarray(mesh.vertices[used, 2], np.float64)
    lf.faces = np.ascontiguousarray(remap[faces], np.int64)
    lf.r_lo = min(lf.r_lo, int(lf.vr.min(initial=lf.r_lo)))
    lf.r_hi = max(lf.r_hi, int(lf.vr.max(initial=lf.r_hi)))
