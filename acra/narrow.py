"""The narrow phase's box culls, compiled: which triangles of two sets can meet the other set.

Before the triangle pairs are tested (fcl, `pipeline.detect.intersect`), each side keeps the
triangles whose box overlaps the box of the other side's kept triangles, twice over. Boxes are
minima and maxima and the overlap test ``lo_a <= hi_b + pad and lo_b <= hi_a + pad`` is the same
comparison of the same sums as `pipeline.grids.overlap`, so the kept rows are the array form's.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["compact", "face_boxes", "triangles_near"]


@njit(cache=True, nogil=True)
def _face_boxes(points, faces, lo, hi):
    for i in range(faces.shape[0]):
        a, b, c = faces[i, 0], faces[i, 1], faces[i, 2]
        for k in range(3):
            x, y, z = points[a, k], points[b, k], points[c, k]
            lo[i, k] = min(min(x, y), z)
            hi[i, k] = max(max(x, y), z)


def face_boxes(points: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Boxes ``lo, hi (f, 3)`` of the triangles ``faces (f, 3) int64`` of ``points (n, 3)``
    (`pipeline.grids.triangle_boxes` of ``points[faces]``, without gathering the corners)."""
    lo, hi = np.empty((len(faces), 3)), np.empty((len(faces), 3))
    if len(faces):
        _face_boxes(np.ascontiguousarray(points, np.float64), np.ascontiguousarray(faces, np.int64), lo, hi)
    return lo, hi


@njit(cache=True, nogil=True)
def _bounds_of(lo, hi, keep, out):
    """Box ``out (2, 3)`` of the kept boxes; False if none is kept."""
    any_ = False
    for k in range(3):
        out[0, k], out[1, k] = np.inf, -np.inf
    for i in range(lo.shape[0]):
        if keep[i]:
            any_ = True
            for k in range(3):
                out[0, k] = min(out[0, k], lo[i, k])
                out[1, k] = max(out[1, k], hi[i, k])
    return any_


@njit(cache=True, nogil=True)
def _cull(lo, hi, keep, box, pad):
    for i in range(lo.shape[0]):
        if keep[i]:
            for k in range(3):
                if not (lo[i, k] <= box[1, k] + pad and box[0, k] <= hi[i, k] + pad):
                    keep[i] = False
                    break


@njit(cache=True, nogil=True)
def _near(lo_a, hi_a, lo_b, hi_b, pad, rounds, keep_a, keep_b):
    box = np.empty((2, 3))
    for _ in range(rounds):
        if _bounds_of(lo_b, hi_b, keep_b, box):
            _cull(lo_a, hi_a, keep_a, box, pad)
        else:
            keep_a[:] = False
        if _bounds_of(lo_a, hi_a, keep_a, box):
            _cull(lo_b, hi_b, keep_b, box, pad)
        else:
            keep_b[:] = False


def triangles_near(box_a: tuple[np.ndarray, np.ndarray], box_b: tuple[np.ndarray, np.ndarray], pad: float,
                   rounds: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``(m,) int64`` of side ``a``'s and side ``b``'s triangles, given by their boxes
    ``lo, hi (f, 3)``, whose boxes overlap (within ``pad``) the box of the other side's kept
    ones: ``a`` against ``b``'s, then ``b`` against ``a``'s kept, ``rounds`` times."""
    keep_a, keep_b = np.ones(len(box_a[0]), np.bool_), np.ones(len(box_b[0]), np.bool_)
    _near(np.ascontiguousarray(box_a[0], np.float64), np.ascontiguousarray(box_a[1], np.float64),
          np.ascontiguousarray(box_b[0], np.float64), np.ascontiguousarray(box_b[1], np.float64), float(pad), int(rounds),
          keep_a, keep_b)
    return np.nonzero(keep_a)[0], np.nonzero(keep_b)[0]


@njit(cache=True, nogil=True)
def _compact(n, faces):
    rank = np.full(n, -1, np.int64)
    for i in range(faces.shape[0]):
        for k in range(3):
            rank[faces[i, k]] = 0
    used = 0
    for v in range(n):
        if rank[v] == 0:
            rank[v] = used
            used += 1
    rows = np.empty(used, np.int64)
    for v in range(n):
        if rank[v] >= 0:
            rows[rank[v]] = v
    tri = np.empty((faces.shape[0], 3), np.int32)
    for i in range(faces.shape[0]):
        for k in range(3):
            tri[i, k] = rank[faces[i, k]]
    return rows, tri


def compact(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The vertices ``(u, 3) float64`` that ``faces (f, 3)`` use, in ascending row order, and the
    faces renumbered into them ``(f, 3) int32``, both contiguous: ``np.unique(faces,
    return_inverse=True)``'s rows and inverse, by marking the used rows instead of sorting."""
    rows, tri = _compact(len(vertices), np.ascontiguousarray(faces, np.int64).reshape(-1, 3))
    return np.ascontiguousarray(vertices[rows], np.float64), tri
