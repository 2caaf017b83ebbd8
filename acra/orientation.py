"""The sign of the volume a closed triangle grid encloses, compiled, where it is sure.

`pipeline.shape.Shape.outward` orients a closed surface by the sign of the volume its coarse grid
encloses (divergence theorem): the sum over the triangles of ``a . (b x c)``, the corners taken
from the points' mean. Here the terms are summed in one pass with the sum of their magnitudes;
the array form sums the same terms in another order, so the two sums differ by about ``n *
2**-53`` of that magnitude for ``n`` terms (1e-10 for a million), and where the sum is farther
from zero than `SURE` of it both signs are the same. Nearer zero the answer is ``0``: the
caller sums as the array form does. Arrays are float64
unless stated.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["SURE", "volume_sign", "volume_sign_about_mean"]

SURE = 1e-9  # the sum is sure where it exceeds this fraction of the terms' magnitudes


@njit(cache=True, nogil=True)
def _volume(points, triangles, centre, mean):
    if mean:
        # numpy's ``points.mean(axis=0)`` of a C-contiguous (n, 3) array: each column summed row
        # by row from +0.0 (the reduced axis is not the contiguous one, so no pairwise blocks),
        # then divided by n; one pass instead of numpy's strided reduction
        n = points.shape[0]
        for k in range(3):
            centre[k] = 0.0
        for i in range(n):
            for k in range(3):
                centre[k] += points[i, k]
        for k in range(3):
            centre[k] = centre[k] / n if n else np.nan
    total, size = 0.0, 0.0
    for f in range(triangles.shape[0]):
        i, j, k = triangles[f, 0], triangles[f, 1], triangles[f, 2]
        a0, a1, a2 = points[i, 0] - centre[0], points[i, 1] - centre[1], points[i, 2] - centre[2]
        b0, b1, b2 = points[j, 0] - centre[0], points[j, 1] - centre[1], points[j, 2] - centre[2]
        c0, c1, c2 = points[k, 0] - centre[0], points[k, 1] - centre[1], points[k, 2] - centre[2]
        term = a0 * (b1 * c2 - b2 * c1) + a1 * (b2 * c0 - b0 * c2) + a2 * (b0 * c1 - b1 * c0)
        total += term
        size += abs(term)
    return total, size


def volume_sign(points: np.ndarray, triangles: np.ndarray, centre: np.ndarray) -> int:
    """``+1`` or ``-1``, the sign of ``sum(a . (b x c))`` over ``triangles (f, 3) int64`` of
    ``points (n, 3)`` less ``centre (3,)``, where it exceeds `SURE` of the terms' magnitudes
    (and is finite), else ``0``."""
    if not len(triangles):
        return 0
    total, size = _volume(np.ascontiguousarray(points, np.float64), np.ascontiguousarray(triangles, np.int64),
                          np.array(centre, np.float64), np.bool_(False))
    return _sign(total, size)


def volume_sign_about_mean(points: np.ndarray, triangles: np.ndarray) -> tuple[int, np.ndarray]:
    """`volume_sign` of ``triangles (f, 3) int64`` about the mean of ``points (n, 3) float64``,
    and that mean ``(3,) float64`` with the bits of ``points.mean(axis=0)``, found in the same
    compiled call (numpy's strided mean of a coarse grid's 22,000 points costs more than the
    volume's pass over its triangles)."""
    points = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    centre = np.empty(3)
    total, size = _volume(points, np.ascontiguousarray(triangles, np.int64).reshape(-1, 3), centre, np.bool_(True))
    return (_sign(total, size) if len(triangles) else 0), centre


def _sign(total: float, size: float) -> int:
    """`volume_sign`'s answer from the kernel's sum ``total`` and sum of magnitudes ``size``."""
    if not np.isfinite(total) or not np.isfinite(size) or abs(total) <= SURE * size:
        return 0
    return 1 if total > 0 else -1
