"""Georeferenced height rasters and images through rasterio, read in windows.

A :class:`RasterSource` opens lazily (metadata only) and reads windows on demand, so memory depends on the
window, not on the raster. Windows that reach past the raster come back padded with invalid samples, which
lets the quadtree address a regular grid of tiles over a raster of any size. No-data becomes ``valid=False``,
never a height.
"""

from __future__ import annotations

import math
import os
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pyproj

from citylod.core.errors import EmptyInputError, GeoreferenceError, InputError
from citylod.core.perthread import PerThread
from citylod.io.crs import is_geographic, utm_crs_for


@dataclass(frozen=True)
class RasterInfo:
    """What a raster's header says: size, georeferencing and the metric sample spacing."""

    path: str
    width: int
    height: int
    crs_wkt: str
    transform: tuple[float, float, float, float, float, float]  # affine a, b, c, d, e, f (rasterio order)
    nodata: float | None
    dtype: str
    geographic: bool
    spacing_m: float  # mean sample spacing in metres (projected for geographic rasters)

    @property
    def crs(self) -> pyproj.CRS:
        return pyproj.CRS.from_wkt(self.crs_wkt)

    def sample_xy(self, rows: npt.ArrayLike, cols: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """CRS coordinates of sample centres at (fractional) ``rows``, ``cols``."""
        a, b, c, d, e, f = self.transform
        r = np.asarray(rows, dtype=np.float64) + 0.5
        q = np.asarray(cols, dtype=np.float64) + 0.5
        return a * q + b * r + c, d * q + e * r + f

    def metric_crs(self) -> pyproj.CRS:
        """The CRS citylod works in: the raster's own when projected, else the UTM zone of its centre."""
        if not self.geographic:
            return self.crs
        x, y = self.sample_xy(self.height / 2.0, self.width / 2.0)
        to_geo = pyproj.Transformer.from_crs(self.crs, "EPSG:4326", always_xy=True)
        lon, lat = to_geo.transform(float(x), float(y))
        return utm_crs_for(lon, lat)


# Open datasets, per thread and file, shared by the RasterSource objects of that file: a build sends each
# tile task its own (unpickled) source, and reopening the file per task would also drop GDAL's cache of
# decompressed blocks. GDAL handles are not thread-safe, hence one per thread (a build on threads must not
# let one thread's eviction close another's dataset); a thread's datasets are closed with it.
_DATASETS = PerThread()  # (path, inode, size, mtime) -> dataset, per thread; a forked child opens its own
_SHARED_MAX = 8


def _shared() -> OrderedDict[tuple[str, int, int, int], Any]:
    return _DATASETS.get()


def _open_shared(path: Path) -> Any:
    import rasterio

    st = os.stat(path)
    key = (str(path), st.st_ino, st.st_size, st.st_mtime_ns)  # a rewritten file reopens
    shared = _shared()
    ds = shared.pop(key, None)
    if ds is None or ds.closed:
        ds = rasterio.open(path)
    shared[key] = ds
    while len(shared) > _SHARED_MAX:
        shared.popitem(last=False)[1].close()
    return ds


def _close_shared(path: Path) -> None:
    shared = _shared()
    for key in [k for k in shared if k[0] == str(path)]:
        shared.pop(key).close()


class RasterSource:
    """A height raster opened for windowed reads. Picklable (reopens on the worker); usable from several
    threads at once (each reads through its own dataset handle)."""

    def __init__(self, path: str | os.PathLike[str], band: int = 1) -> None:
        self.path = Path(path)
        self.band = band
        self.info = read_info(self.path)
        self._fast: bool | None = None

    def __getstate__(self) -> dict[str, object]:
        return {"path": self.path, "band": self.band, "info": self.info}

    def __setstate__(self, state: dict[str, object]) -> None:
        self.__dict__.update(state)
        self._fast = None

    def _dataset(self):
        # Not cached on the object: build tasks on threads share one source, and a GDAL handle must not
        # be used by two threads (it failed reads when it was). The per-thread cache makes this a lookup.
        return _open_shared(self.path)

    def close(self) -> None:
        """Close the raster in this thread (also for the other sources of the same file that share it)."""
        _close_shared(self.path)

    def _fast_mask(self) -> bool:
        """True when validity is "finite and not the no-data value" (no mask band, no alpha)."""
        if self._fast is None:
            from rasterio.enums import MaskFlags

            flags = set(self._dataset().mask_flag_enums[self.band - 1])
            self._fast = flags <= {MaskFlags.all_valid, MaskFlags.nodata}
        return self._fast

    def _nodata_value(self, dtype: np.dtype) -> float | None:
        """The no-data value as stored in ``dtype`` (None when there is none or it cannot occur)."""
        nd = self.info.nodata
        if nd is None or math.isnan(nd):
            return None  # NaN never compares equal; non-finite samples are invalid anyway
        if np.issubdtype(dtype, np.integer):
            lim = np.iinfo(dtype)
            if not (lim.min <= nd <= lim.max) or nd != int(nd):
                return None
            return float(nd)
        return float(np.asarray(nd, dtype=dtype))

    def read_window(self, row0: int, col0: int, nrows: int, ncols: int) -> tuple[np.ndarray, np.ndarray]:
        """Samples ``row0 .. row0+nrows-1`` × ``col0 .. col0+ncols-1`` in one read.

        Returns C-contiguous heights (nrows, ncols) float64 and valid (nrows, ncols) bool; positions
        outside the raster or at no-data are invalid (height 0). Reads the band as stored and compares
        with the no-data value directly (no masked arrays) unless the raster has a mask band or alpha.
        """
        from rasterio.windows import Window

        info = self.info
        r_lo, r_hi = max(row0, 0), min(row0 + nrows, info.height)
        c_lo, c_hi = max(col0, 0), min(col0 + ncols, info.width)
        if r_lo >= r_hi or c_lo >= c_hi:
            return np.zeros((nrows, ncols), np.float64), np.zeros((nrows, ncols), bool)
        ds = self._dataset()
        win = Window(c_lo, r_lo, c_hi - c_lo, r_hi - r_lo)
        try:
            if self._fast_mask():
                raw = ds.read(self.band, window=win)
                data = raw.astype(np.float64)
                ok = np.isfinite(data)
                nd = self._nodata_value(raw.dtype)
                if nd is not None:
                    ok &= raw != raw.dtype.type(nd)
            else:
                block = ds.read(self.band, window=win, masked=True)
                data = np.ma.getdata(block).astype(np.float64)
                ok = ~np.ma.getmaskarray(block) & np.isfinite(data)
        except Exception as exc:  # rasterio raises several types for corrupt blocks
            raise InputError(f"cannot read raster window rows {r_lo}-{r_hi - 1} ({exc})", self.path) from exc
        data[~ok] = 0.0
        if (r_lo, r_hi, c_lo, c_hi) == (row0, row0 + nrows, col0, col0 + ncols):
            return data, ok
        heights = np.zeros((nrows, ncols), np.float64)
        valid = np.zeros((nrows, ncols), bool)
        heights[r_lo - row0:r_hi - row0, c_lo - col0:c_hi - col0] = data
        valid[r_lo - row0:r_hi - row0, c_lo - col0:c_hi - col0] = ok
        return heights, valid

    def read(self, row0: int, col0: int, nrows: int, ncols: int, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Samples ``row0 + i·stride``, ``col0 + j·stride`` for i < nrows, j < ncols.

        Returns heights (nrows, ncols) float64 and valid (nrows, ncols) bool; positions outside the raster
        or at no-data are invalid (their height is 0). Only the rows needed are read, in strips, so a
        decimated read of a large footprint stays small.
        """
        if stride == 1:
            return self.read_window(row0, col0, nrows, ncols)
        info = self.info
        heights = np.zeros((nrows, ncols), np.float64)
        valid = np.zeros((nrows, ncols), bool)
        rows = row0 + stride * np.arange(nrows)
        cols = col0 + stride * np.arange(ncols)
        rin = np.flatnonzero((rows >= 0) & (rows < info.height))
        cin = np.flatnonzero((cols >= 0) & (cols < info.width))
        if len(rin) == 0 or len(cin) == 0:
            return heights, valid
        c_lo, c_hi = int(cols[cin[0]]), int(cols[cin[-1]])
        # Read strips of at most ~4 M samples so memory stays bounded whatever the stride.
        strip = max(1, (4 << 20) // max(1, (c_hi - c_lo + 1)))
        strip = max(1, strip // stride)
        for s in range(0, len(rin), strip):
            idx = rin[s: s + strip]
            r_lo, r_hi = int(rows[idx[0]]), int(rows[idx[-1]])
            h, v = self.read_window(r_lo, c_lo, r_hi - r_lo + 1, c_hi - c_lo + 1)
            heights[np.ix_(idx, cin)] = h[::stride, ::stride]
            valid[np.ix_(idx, cin)] = v[::stride, ::stride]
        return heights, valid


def read_info(path: str | os.PathLike[str]) -> RasterInfo:
    """Open a raster's header and check it can be used as a DSM."""
    import rasterio
    from rasterio.errors import RasterioIOError

    p = Path(path)
    if not p.exists():
        raise InputError("raster not found", p)
    try:
        with rasterio.open(p) as ds:
            if ds.count < 1:
                raise InputError("raster has no bands", p)
            if ds.crs is None:
                raise GeoreferenceError("raster has no coordinate reference system (CRS)", p)
            t = ds.transform
            if t.is_identity or (t.a == 1 and t.e == 1 and t.c == 0 and t.f == 0):
                raise GeoreferenceError("raster has no georeferencing (identity geotransform)", p)
            if abs(t.b) > 1e-12 or abs(t.d) > 1e-12:
                raise InputError("rotated rasters are not supported", p)
            crs = pyproj.CRS.from_wkt(ds.crs.to_wkt())
            geo = is_geographic(crs)
            if geo:
                cy = t.f + t.e * ds.height / 2.0
                m_per_deg = 111_320.0
                spacing = 0.5 * (abs(t.a) * m_per_deg * math.cos(math.radians(cy)) + abs(t.e) * m_per_deg)
            else:
                unit = crs.axis_info[0].unit_conversion_factor if crs.axis_info else 1.0
                spacing = 0.5 * (abs(t.a) + abs(t.e)) * unit
            return RasterInfo(
                path=str(p), width=ds.width, height=ds.height, crs_wkt=crs.to_wkt(),
                transform=(t.a, t.b, t.c, t.d, t.e, t.f), nodata=ds.nodata, dtype=ds.dtypes[0],
                geographic=geo, spacing_m=float(spacing),
            )
    except RasterioIOError as exc:
        raise InputError(f"not a readable raster ({exc})", p) from exc


def check_has_data(src: RasterSource) -> None:
    """Raise :class:`EmptyInputError` when every sample is no-data (reads strips of the raster's own block
    height, 64 rows at least, until one holds a valid sample)."""
    info = src.info
    # One strip of the file's blocks decompresses as much as a taller read would convert; a raster with data
    # near its top is done after the first, on one core before the workers start.
    block = min(max(64, int(src._dataset().block_shapes[src.band - 1][0])), 1024)
    for r in range(0, info.height, block):
        _, v = src.read(r, 0, min(block, info.height - r), info.width)
        if v.any():
            return
    raise EmptyInputError("raster holds no valid samples (all no-data)", src.path)


def read_image_window(path: str | os.PathLike[str], bounds: tuple[float, float, float, float],
                      crs: pyproj.CRS, size: int) -> np.ndarray | None:
    """An RGB image window covering ``bounds`` (xmin, ymin, xmax, ymax in ``crs``) resampled by averaging
    to ``size``×``size`` pixels, (size, size, 3) uint8, or None when the image does not overlap.

    Averaging over power-of-two footprints equals repeated 2×2 averaging, the texture pyramid of Wahl 2004.
    """
    import rasterio
    from rasterio.enums import Resampling
    from rasterio.warp import transform_bounds
    from rasterio.windows import from_bounds

    with rasterio.open(path) as ds:
        if ds.crs is None:
            raise GeoreferenceError("orthophoto has no CRS", path)
        b = bounds
        img_crs = pyproj.CRS.from_wkt(ds.crs.to_wkt())
        if not img_crs.equals(crs):
            b = transform_bounds(crs.to_wkt(), ds.crs, *bounds)
        win = from_bounds(*b, transform=ds.transform)
        bands = [1, 2, 3] if ds.count >= 3 else [1, 1, 1]
        data = ds.read(bands, window=win, out_shape=(3, size, size), resampling=Resampling.average,
                       boundless=True, fill_value=0)
    if data.dtype != np.uint8:
        hi = float(np.nanmax(data)) if data.size else 1.0
        data = np.clip(data.astype(np.float64) * (255.0 / max(hi, 1.0)), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(np.moveaxis(data, 0, -1))
