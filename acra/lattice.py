"""Compiled sorted sets of lattice points, for the adaptive display mesh (`acra.tessellate`).

The adaptive topology's vertices are points ``(i, j)`` of an integer lattice, ``0 <= i <= ni``,
``0 <= j < w``, kept as sorted keys ``i * w + j``. In array form they are ``np.unique`` of every
cell corner's key and each look-up a ``np.searchsorted`` over them: a sort of four keys a cell
and a binary search over the whole set per query, at random places in it. Here the keys are
bucketed by ``i`` (a counting sort: each column's few keys sorted alone) and a query searches its
own column only. The keys, and every position a query gets, are the same as numpy's
(`tests/test_tessellate.py` holds them to ``np.unique`` and ``np.searchsorted``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["unique_keys", "search"]


@njit(cache=True, nogil=True)
def unique_keys(i, j, ni, w):
    """The sorted distinct keys ``i * w + j`` of the points ``(i[p], j[p])`` (``0 <= i <= ni``,
    ``0 <= j < w``), ``(m,) int64``, and where each column ``i`` starts in them,
    ``(ni + 2,) int64`` (entry ``ni + 1`` is ``m``)."""
    n = i.shape[0]
    start = np.zeros(ni + 2, np.int64)
    for p in range(n):
        start[i[p] + 1] += 1
    for c in range(ni + 1):
        start[c + 1] += start[c]
    fill = start.copy()
    col = np.empty(n, np.int64)
    for p in range(n):
        c = i[p]
        col[fill[c]] = j[p]
        fill[c] += 1
    out = np.empty(n, np.int64)
    first = np.empty(ni + 2, np.int64)
    m = 0
    for c in range(ni + 1):
        first[c] = m
        seg = col[start[c]:start[c + 1]]
        seg.sort()
        last = -1
        for x in seg:
            if x != last:
                out[m] = c * w + x
                m += 1
                last = x
    first[ni + 1] = m
    return out[:m].copy(), first


@njit(cache=True, nogil=True)
def search(keys, first, w, queries, right):
    """``np.searchsorted(keys, queries, side="right" if right else "left")`` for ``keys`` and
    ``first`` from `unique_keys` and queries ``c * w + x`` with ``0 <= x < w``: each is
    searched within its column ``c`` (columns past the last give ``len(keys)``, before the first
    0), ``(q,) int64``."""
    nc = first.shape[0] - 1
    out = np.empty(queries.shape[0], np.int64)
    for p in range(queries.shape[0]):
        q = queries[p]
        c = q // w
        if c < 0:
            out[p] = 0
            continue
        if c >= nc:
            out[p] = first[nc]
            continue
        lo, hi = first[c], first[c + 1]
        while lo < hi:
            mid = (lo + hi) >> 1
            if keys[mid] < q or (right and keys[mid] == q):
                lo = mid + 1
            else:
                hi = mid
        out[p] = lo
    return out
