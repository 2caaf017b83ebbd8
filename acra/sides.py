"""Which side of a closed H-spline surface points lie on, from their closest points, compiled.

An inside test (`pipeline.queries.signed`) finds each point's closest point on the surface's
collision grid, then reads the surface's outward normal there: a point lies inside when it is
behind that normal. After the search, the steps are the closest point's parameters (trimesh's
barycentric coordinates on its face, `acra.nearest.face_uv`), a first-order evaluation there
(`acra.kernels.eval_points`), the unit normal ``du × dv / |du × dv|`` and the sign of the
point's offset along it. As array operations they are some twenty numpy calls on a few hundred
rows; `behind` runs them in one pass, each value in the arithmetic of the array form, so the
answers are the same bits (`tests/test_sides.py` holds them to it):

* the parameters and the evaluation are those kernels' own;
* the cross product, its length and the test for no direction are `acra.framekernels.cross_test`
  (`acra.hspline._degenerate`'s), the unit normal each component over the length
  (`acra.framekernels.unit_rows`);
* the offset's component along the normal is ``np.einsum("ij,ij->i", d, n)`` as numpy sums three
  terms, ``(d0 n0 + d2 n2) + d1 n1``.

A point whose ``du × dv`` has no direction (at a pole, on a collapsed edge) is left to
`acra.hspline.surface_normals`, whose limit and nudges decide its normal; `behind` marks it
``-1``. Arrays are float64 unless stated.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from acra.framekernels import cross_test
from acra.kernels import eval_points
from acra.nearest import _face_uv

__all__ = ["behind"]


@njit(cache=True, nogil=True, error_model="numpy")
def _behind(points, uv, triangles, face, close, face_lo, face_hi, q, outward, c1, c2, top, nu, u_periodic, nv,
            v_periodic, cvs, levels, keys, shifts, ends, patch_rows, table_rows, table, uv_out, flag):
    m = face.shape[0]
    _face_uv(points, uv, triangles, face, close, face_lo, face_hi, uv_out)
    u, v = np.empty(m), np.empty(m)  # (m,) float64 each: contiguous, as `evaluate` passes them
    for i in range(m):
        u[i], v[i] = uv_out[i, 0], uv_out[i, 1]
    ev = np.empty((3, m, 3))  # (slot, m, xyz) float64: points, du, dv
    eval_points(u, v, np.int64(1), np.int64(0), top, nu, u_periodic, nv, v_periodic, cvs, levels, keys, shifts, ends,
                patch_rows, table_rows, table, ev)
    for i in range(m):
        n0, n1, n2, length, bad = cross_test(ev[1, i, 0], ev[1, i, 1], ev[1, i, 2], ev[2, i, 0], ev[2, i, 1], ev[2, i, 2],
                                             c1, c2)
        if bad:
            flag[i] = -1
            continue
        x0, x1, x2 = n0 / length, n1 / length, n2 / length
        d0, d1, d2 = q[i, 0] - close[i, 0], q[i, 1] - close[i, 1], q[i, 2] - close[i, 2]
        flag[i] = 1 if outward * ((d0 * x0 + d2 * x2) + d1 * x1) < 0 else 0


def behind(points: np.ndarray, uv: np.ndarray, triangles: np.ndarray, face_lo: np.ndarray, face_hi: np.ndarray,
           face: np.ndarray, close: np.ndarray, q: np.ndarray, outward: float, size: float,
           args: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Closest points' parameters and which points lie behind the surface's outward normal there.

    Parameters
    ----------
    points : (n, 3) float64
        A collision grid set's points (`pipeline.grids.GridSet`); ``uv (n, 2) float64`` their
        parameters, ``triangles (f, 3) int64`` its faces, ``face_lo, face_hi (f, 2) float64`` the
        parameter box of each face's patch.
    face : (m,) int64
        The face holding each query's closest point ``close (m, 3) float64``.
    q : (m, 3) float64
        The queries.
    outward : float
        ``+1`` where ``du × dv`` points out of the surface, else ``-1`` (`Shape.outward`).
    size : float
        The surface's size (`HSpline.size`): the scale of the no-direction test.
    args : tuple
        `acra.hspline.eval_arrays` of the surface (every level).

    Returns
    -------
    uv : (m, 2) float64
        The closest points' parameters (`acra.nearest.face_uv`).
    flag : (m,) int8
        1 behind the outward normal, 0 not, -1 no direction at the closest point (``du × dv``
        too small: the caller's `hspline.surface_normals` decides).
    """
    m = len(face)
    uv_out, flag = np.empty((m, 2)), np.empty(m, np.int8)
    if m:
        s = max(size, 1e-300)
        _behind(points, uv, triangles, face, close, face_lo, face_hi, q, float(outward), 1e-6 * s, 1e-12 * s**2, *args,
                uv_out, flag)
    return uv_out, flag
