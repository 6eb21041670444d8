"""Sorting kernels shared by the octree builder and the certifier (numba; numpy and numba only)."""

from __future__ import annotations

import numba
import numpy as np
import numpy.typing as npt

I64 = npt.NDArray[np.int64]


@numba.njit(cache=True, nogil=True)
def counting_sort(keys: I64, nbins: int) -> tuple[I64, I64]:  # pragma: no cover - compiled
    """Stable counting sort of small integer keys (PotreeConverter 2's chunk partitioning).

    Parameters
    ----------
    keys
        (N,) int64 in [0, nbins).
    nbins
        Number of distinct keys.

    Returns
    -------
    order
        (N,) int64 permutation: ``keys[order]`` is sorted, ties keep input order.
    offsets
        (nbins + 1,) int64: key k occupies ``order[offsets[k]:offsets[k + 1]]``.
    """
    n = keys.shape[0]
    offsets = np.zeros(nbins + 1, np.int64)
    for i in range(n):
        offsets[keys[i] + 1] += 1
    for k in range(nbins):
        offsets[k + 1] += offsets[k]
    fill = offsets[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n):
        k = keys[i]
        order[fill[k]] = i
        fill[k] += 1
    return order, offsets
