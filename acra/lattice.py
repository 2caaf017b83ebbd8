"""Compiled sorted sets of lattice points, for the adaptive display mesh (`acra.tessellate`).

The adaptive topology's vertices are points ``(i, j)`` of an integer lattice, ``0 <= i <= ni``,
``0 <= j < w``, kept as sorted keys ``i * w + j``. In array form they are ``np.unique`` of every
cell corner's key with its inverse: a sort of four keys a cell over the whole set. Here the keys
are bucketed by ``i`` (a counting sort: each column's few keys sorted alone), and each point's
position among the keys comes out of the same pass, so the mesh finds every corner's vertex (and,
as corners bound each cell side, the vertices between them) without a search. The keys, the
positions and the column starts are the same as numpy's (`tests/test_tessellate.py` holds them to
``np.unique`` and ``np.searchsorted``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["unique_keys"]


@njit(cache=True, nogil=True)
def unique_keys(i, j, ni, w):
    """The sorted distinct keys ``i * w + j`` of the points ``(i[p], j[p])`` (``0 <= i <= ni``,
    ``0 <= j < w``), ``(m,) int64``; where each column ``i`` starts in them, ``(ni + 2,) int64``
    (entry ``ni + 1`` is ``m``); and the position of each point's key in them, ``(n,) int64``
    (``np.unique``'s inverse)."""
    n = i.shape[0]
    # two stable counting sorts, by j then by i, order the points by key
    count = np.zeros(w + 1, np.int64)
    for p in range(n):
        count[j[p] + 1] += 1
    for x in range(w):
        count[x + 1] += count[x]
    by_j = np.empty(n, np.int64)
    for p in range(n):
        by_j[count[j[p]]] = p
        count[j[p]] += 1
    first = np.zeros(ni + 2, np.int64)
    for p in range(n):
        first[i[p] + 1] += 1
    for c in range(ni + 1):
        first[c + 1] += first[c]
    fill = first.copy()
    order = np.empty(n, np.int64)
    for q in range(n):
        p = by_j[q]
        order[fill[i[p]]] = p
        fill[i[p]] += 1
    out = np.empty(n, np.int64)
    where = np.empty(n, np.int64)
    m = 0
    last = -1
    c = 0
    for q in range(n):
        p = order[q]
        x = i[p] * w + j[p]
        if x != last:
            while c <= i[p]:  # the columns up to this key's start here
                first[c] = m
                c += 1
            out[m] = x
            m += 1
            last = x
        where[p] = m - 1
    while c <= ni + 1:
        first[c] = m
        c += 1
    return out[:m].copy(), first, where
