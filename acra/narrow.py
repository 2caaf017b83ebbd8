"""The narrow phase's box culls, compiled: which triangles of two sets can meet the other set.

Before the triangle pairs are tested (fcl, `pipeline.detect.intersect`), each side keeps the
triangles whose box overlaps the box of the other side's kept triangles, twice over. Boxes are
minima and maxima and the overlap test ``lo_a <= hi_b + pad and lo_b <= hi_a + pad`` is the same
comparison of the same sums as `pipeline.grids.overlap`, so the kept rows are the array form's.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["compact", "face_boxes", "solid_mask", "triangles_near"]


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


@njit(cache=True, nogil=True)
def _solid_mask(points, triangles, collapse, out):
    for r in range(points.shape[0]):
        side, nan = 0.0, False
        for k in range(3):
            lo, hi = points[r, 0, k], points[r, 0, k]
            for i in range(points.shape[1]):
                x = points[r, i, k]
                if x != x:
                    nan = True
                lo, hi = min(lo, x), max(hi, x)
            if hi - lo != hi - lo:  # an infinite coordinate: numpy's extent is NaN
                nan = True
            side = max(side, hi - lo)
        tol = np.nan if nan else collapse * max(side, 1e-300)
        for f in range(triangles.shape[0]):
            keep = True
            for e in range(3):
                a, b = triangles[f, e], triangles[f, (e + 2) % 3]
                dx = points[r, a, 0] - points[r, b, 0]
                dy = points[r, a, 1] - points[r, b, 1]
                dz = points[r, a, 2] - points[r, b, 2]
                if not np.sqrt(dx * dx + dy * dy + dz * dz) > tol:
                    keep = False
                    break
            out[r, f] = keep


def solid_mask(points: np.ndarray, triangles: np.ndarray, collapse: float) -> np.ndarray:
    """For grids ``points (r, n, 3)`` sharing ``triangles (f, 3) int64``: ``(r, f) bool``, whether
    each triangle's three edges are longer than ``collapse`` times its grid's extent (the largest
    side of the grid's box, at least 1e-300; NaN coordinates keep no row). Each edge length is
    ``np.linalg.norm`` of the corner difference as numpy rounds it (squares summed in order), so
    the rows are those of the array form (`pipeline.grids.solid_rows`) without its ``(r, f, 3, 3)``
    gathers."""
    out = np.zeros((points.shape[0], len(triangles)), np.bool_)
    if out.size and points.shape[1]:
        _solid_mask(np.ascontiguousarray(points, np.float64), np.ascontiguousarray(triangles, np.int64), float(collapse), out)
    return out
