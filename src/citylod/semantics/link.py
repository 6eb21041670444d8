"""Link point clouds to city objects by volume: each point gets the feature id of the proxy containing it.

Wahl & Klein (2007) link rendered geometry to semantic objects only through proxy volumes; this applies
that link to LiDAR points once and writes it into the LAS/LAZ file as an ``object_id`` int32 extra
dimension (the GeoPackage fid, -1 for no object), so any tool can colour or filter points by object.
Reading is chunked (laspy ``chunk_iterator``), so memory is bounded by the chunk size; the output is
written under a temporary name and renamed when complete. No VTK, no Qt.
"""

from __future__ import annotations

import os
import time
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pyproj

from citylod.core.errors import EmptyInputError, GeoreferenceError, InputError
from citylod.io.crs import horizontal_crs
from citylod.io.las import iter_points, read_info
from citylod.semantics.store import CityStore

__all__ = ["CHUNK_POINTS", "link_command", "link_file", "link_points"]

CHUNK_POINTS = 1_000_000
DIMENSION = "object_id"


def link_points(store: CityStore, xyz: npt.ArrayLike) -> npt.NDArray[np.int32]:
    """Feature id of the object whose proxy contains each point.

    Parameters
    ----------
    store
        An open city store.
    xyz
        (N, 3) float64 positions in the store's CRS.

    Returns
    -------
    (N,) int32
        GeoPackage fid (``store.object_id(fid)`` gives the object id), -1 for points in no proxy.
    """
    proxies = store.proxies
    idx = proxies.contains(xyz)
    out = np.full(idx.shape, -1, dtype=np.int32)
    hit = idx >= 0
    out[hit] = proxies.fids[idx[hit]]
    return out


def _transformer(las_crs: pyproj.CRS | None, store_crs: pyproj.CRS | None) -> pyproj.Transformer | None:
    if las_crs is None or store_crs is None:
        return None
    a, b = horizontal_crs(las_crs), horizontal_crs(store_crs)
    if a.equals(b, ignore_axis_order=True):
        return None
    return pyproj.Transformer.from_crs(a, b, always_xy=True)


def link_file(store: CityStore, points: str | PathLike[str], output: str | PathLike[str], *,
              progress: bool = True, chunk_points: int = CHUNK_POINTS) -> dict[str, Any]:
    """Write a copy of a LAS/LAZ file with the ``object_id`` extra dimension; returns counts and timing."""
    import laspy

    src, dst = Path(points), Path(output)
    if not src.is_file():
        raise InputError("no such point cloud", src)
    # The header is checked first (as build points does): no points, or a header laspy cannot read, is refused
    # before anything is written; iter_points then refuses a stream that ends before the header's count.
    if read_info(src).point_count == 0:
        raise EmptyInputError("the file holds no points", src)
    t0 = time.perf_counter()
    tmp = dst.with_name(f".{dst.name}.{os.getpid()}.tmp{dst.suffix}")
    linked = total = 0
    try:
        with laspy.open(src) as reader:
            header = reader.header
            try:
                las_crs = header.parse_crs()
            except Exception:  # laspy raises various errors on odd GeoTIFF keys; treat as unknown
                las_crs = None
            tr = _transformer(las_crs, store.crs)
            out_header = laspy.LasHeader(point_format=header.point_format.id, version=header.version)
            out_header.offsets, out_header.scales = header.offsets, header.scales
            for dim in header.point_format.extra_dimension_names:
                if dim != DIMENSION:
                    out_header.add_extra_dim(laspy.ExtraBytesParams(
                        name=dim, type=header.point_format.dimension_by_name(dim).dtype))
            out_header.add_extra_dim(laspy.ExtraBytesParams(
                name=DIMENSION, type=np.int32, description="citylod fid, -1 none"))
            for vlr in header.vlrs:
                if vlr.user_id not in ("LASF_Spec", "laszip encoded"):
                    out_header.vlrs.append(vlr)
            names = [n for n in header.point_format.dimension_names]
            bar = None
            if progress:
                from tqdm import tqdm

                bar = tqdm(total=header.point_count, desc=f"link {src.name}", unit="pt", unit_scale=True)
            with laspy.open(tmp, mode="w", header=out_header, do_compress=dst.suffix.lower() == ".laz") as writer:
                for chunk in iter_points(src, chunk_points=chunk_points, raw=True):
                    xyz = np.column_stack([np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)])
                    if tr is not None:
                        xyz[:, 0], xyz[:, 1] = tr.transform(xyz[:, 0], xyz[:, 1])
                    ids = link_points(store, xyz)
                    rec = laspy.ScaleAwarePointRecord.zeros(len(chunk), header=out_header)
                    for n in names:
                        if n != DIMENSION:
                            rec[n] = chunk[n]
                    rec[DIMENSION] = ids
                    writer.write_points(rec)
                    total += len(ids)
                    linked += int((ids >= 0).sum())
                    if bar is not None:
                        bar.update(len(ids))
            if bar is not None:
                bar.close()
        os.replace(tmp, dst)
    except (laspy.errors.LaspyException, OSError, ValueError) as exc:
        tmp.unlink(missing_ok=True)
        if isinstance(exc, GeoreferenceError):
            raise
        raise InputError(f"cannot link points: {exc}", src) from exc
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return {"points": total, "linked": linked, "seconds": time.perf_counter() - t0, "output": str(dst)}


def link_command(store: str | PathLike[str], points: str | PathLike[str], output: str | PathLike[str],
                 progress: bool = True) -> int:
    """``citylod link STORE POINTS -o OUT``: link, print a one-line summary, return the exit code."""
    with CityStore.open(store) as s:
        r = link_file(s, points, output, progress=progress)
    share = r["linked"] / r["points"] if r["points"] else 0.0
    print(f"{r['output']}: {r['linked']:,} of {r['points']:,} points ({share:.1%}) inside a city object proxy, "
          f"{r['seconds']:.1f} s")
    return 0
