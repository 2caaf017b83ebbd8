"""Which points lie within a set of half-spaces (a convex hull's facet planes), and how high a
point lies over them, compiled.

A point ``x`` is within rows ``(n, d)`` of ``equations (m, 4)`` when ``n · x + d <= slack`` for
every row: one pass per point over the rows, each value summed term by term (``n0 x0 + n1 x1 +
n2 x2``, then ``+ d``), the point settled outside at the first row beyond ``slack``. A point
outside a closed surface's hull usually fails one of the first rows it meets, so only points
inside pay for every row: far less than the ``(k, m)`` matrix of every value, and no kd-tree."""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["within", "heights"]


@njit(cache=True, nogil=True)
def _within(equations, q, slack, out):
    m = equations.shape[0]
    for i in range(q.shape[0]):
        x, y, z = q[i, 0], q[i, 1], q[i, 2]
        ok = True
        for f in range(m):
            v = equations[f, 0] * x + equations[f, 1] * y + equations[f, 2] * z + equations[f, 3]
            if not v <= slack:  # NaN counts as beyond, as numpy's max comparison does
                ok = False
                break
        out[i] = ok


def within(equations: np.ndarray, q: np.ndarray, slack: float) -> np.ndarray:
    """``(k,) bool``: points ``q (k, 3) float64`` with ``n · x + d <= slack`` for every row
    ``(n, d)`` of ``equations (m, 4) float64``."""
    q = np.ascontiguousarray(q, np.float64).reshape(-1, 3)
    out = np.empty(len(q), np.bool_)
    _within(np.ascontiguousarray(equations, np.float64), q, float(slack), out)
    return out


@njit(cache=True, nogil=True)
def _heights(equations, q, out):
    m = equations.shape[0]
    for i in range(q.shape[0]):
        x, y, z = q[i, 0], q[i, 1], q[i, 2]
        top = -np.inf
        for f in range(m):
            v = equations[f, 0] * x + equations[f, 1] * y + equations[f, 2] * z + equations[f, 3]
            if v != v:  # a NaN is the maximum, as numpy's max has it
                top = v
                break
            if v > top:
                top = v
        out[i] = top


def heights(equations: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``(k,) float64``: the greatest ``n · x + d`` over the rows ``(n, d)`` of ``equations (m, 4)
    float64`` for each of points ``q (k, 3) float64`` (each value summed term by term, as
    `within`'s); ``-inf`` without rows. One pass per point, no ``(k, m)`` matrix."""
    q = np.ascontiguousarray(q, np.float64).reshape(-1, 3)
    out = np.empty(len(q))
    if len(q):
        _heights(np.ascontiguousarray(equations, np.float64), q, out)
    return out
