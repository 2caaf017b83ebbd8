"""Compiled local frames of surface points (`acra.hspline.surface_normals`, `_frames`).

The frames of a level's detail CVs are built from a first-order evaluation at each CV's centre:
``du × dv``, whether it is too small to give a direction, the unit normal, and the tangent frame
around it. In array form that is some forty numpy calls on a few dozen rows each time a response
moves a level (`acra.details.details`); here it is one pass per call. Each value is computed by
numpy's operations in numpy's order (a cross product as ``a1 b2 - a2 b1``, a norm over three
components as ``sqrt((x0² + x1²) + x2²)``, a sum over three as ``(a0 + a1) + a2``), so the frames
are the same bits as the array form's (`tests/test_kernels.py` holds them to it).

`ring_sums` is the pole-ring bookkeeping of a response (`acra.respond._ring_sums`): per ring
column the sum of its three rows' detail vectors and how far the columns' sums spread, which a
response reads for every fine level and closed end before and after it moves the surface.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["degenerate", "unit_rows", "frames", "frames_at", "limit_normals", "ring_sums"]


@njit(cache=True, nogil=True)
def cross_test(a0, a1, a2, b0, b1, b2, c1, c2):
    """``n = a × b`` of one row's tangents, its length and whether the row has no direction:
    ``|n| <= c1 max(|a|, |b|) + c2`` (`acra.hspline._degenerate`'s test). Returns
    ``(n0, n1, n2, |n|, bad)``."""
    n0 = a1 * b2 - a2 * b1
    n1 = a2 * b0 - a0 * b2
    n2 = a0 * b1 - a1 * b0
    la = math.sqrt((a0 * a0 + a1 * a1) + a2 * a2)
    lb = math.sqrt((b0 * b0 + b1 * b1) + b2 * b2)
    if la != la or lb != lb:  # np.maximum propagates NaN
        longest = math.nan
    else:
        longest = la if la >= lb else lb
    length = math.sqrt((n0 * n0 + n1 * n1) + n2 * n2)
    return n0, n1, n2, length, length <= c1 * longest + c2


@njit(cache=True, nogil=True)
def degenerate(du, dv, c1, c2, n, bad):
    """``n[i] = du[i] × dv[i]`` and ``bad[i]``: ``|n[i]| <= c1 max(|du[i]|, |dv[i]|) + c2``
    (`acra.hspline._degenerate`, whose ``c1``, ``c2`` the caller computes)."""
    for i in range(du.shape[0]):
        n0, n1, n2, _, bad[i] = cross_test(du[i, 0], du[i, 1], du[i, 2], dv[i, 0], dv[i, 1], dv[i, 2], c1, c2)
        n[i, 0], n[i, 1], n[i, 2] = n0, n1, n2


@njit(cache=True, nogil=True)
def unit_rows(n, out):
    """``out[i] = n[i] / |n[i]|``."""
    for i in range(n.shape[0]):
        x0, x1, x2 = n[i, 0], n[i, 1], n[i, 2]
        length = math.sqrt((x0 * x0 + x1 * x1) + x2 * x2)
        out[i, 0], out[i, 1], out[i, 2] = x0 / length, x1 / length, x2 / length


@njit(cache=True, nogil=True)
def frames(du, dv, n, out):
    """Orthonormal frames ``out (m, 3, 3)``, columns ``(e_u, e_v, n)``, of unit normals ``n``
    and tangents ``du``, ``dv`` (`acra.hspline._frames`)."""
    for i in range(du.shape[0]):
        a0, a1, a2 = du[i, 0], du[i, 1], du[i, 2]
        b0, b1, b2 = dv[i, 0], dv[i, 1], dv[i, 2]
        n0, n1, n2 = n[i, 0], n[i, 1], n[i, 2]
        d = (a0 * n0 + a1 * n1) + a2 * n2
        t0, t1, t2 = a0 - d * n0, a1 - d * n1, a2 - d * n2
        tl = math.sqrt((t0 * t0 + t1 * t1) + t2 * t2)
        la = math.sqrt((a0 * a0 + a1 * a1) + a2 * a2)
        lb = math.sqrt((b0 * b0 + b1 * b1) + b2 * b2)
        if tl <= 1e-12 * ((la + lb) + 1e-300):  # du vanishes (pole): perpendicular to dv instead
            t0 = b1 * n2 - b2 * n1
            t1 = b2 * n0 - b0 * n2
            t2 = b0 * n1 - b1 * n0
            tl = math.sqrt((t0 * t0 + t1 * t1) + t2 * t2)
        if tl <= 1e-300:  # fully degenerate: any perpendicular of n
            if abs(n0) < 0.9:
                p0, p1, p2 = 1.0, 0.0, 0.0
            else:
                p0, p1, p2 = 0.0, 1.0, 0.0
            s = (p0 * n0 + p1 * n1) + p2 * n2
            t0, t1, t2 = p0 - s * n0, p1 - s * n1, p2 - s * n2
            tl = math.sqrt((t0 * t0 + t1 * t1) + t2 * t2)
        e0, e1, e2 = t0 / tl, t1 / tl, t2 / tl
        out[i, 0, 0], out[i, 1, 0], out[i, 2, 0] = e0, e1, e2
        out[i, 0, 1] = n1 * e2 - n2 * e1
        out[i, 1, 1] = n2 * e0 - n0 * e2
        out[i, 2, 1] = n0 * e1 - n1 * e0
        out[i, 0, 2], out[i, 1, 2], out[i, 2, 2] = n0, n1, n2


@njit(cache=True, nogil=True)
def frames_at(du, dv, c1, c2, fixed, n_fixed, out):
    """Frames ``out (m, 3, 3)`` of detail CVs from their first-order evaluation ``du, dv (m, 3)``
    in one pass: ``du × dv`` and its test (`degenerate`), the unit normal (`unit_rows`'
    arithmetic) and the frame (`frames`); a row with ``fixed[i]`` takes the unit normal
    ``n_fixed[i]`` instead (a pole ring's one normal). Returns how many other rows are
    degenerate: if any, nothing is written to ``out`` and the caller takes their limit normals
    (`acra.hspline.surface_normals`). Each row is the same arithmetic as those kernels on it
    alone, so the same bits. The evaluation is the caller's `acra.kernels.eval_points` call: a
    kernel calling it with the argument types Python's calls use links its compiled code (0.4 s
    to compile such a caller), but a literal argument or another array layout compiles it again
    for the caller (4.5 s on a first run; `benchmarks/nested_compile.py`)."""
    m = du.shape[0]
    n = np.empty((m, 3))
    bad = np.empty(m, np.bool_)
    degenerate(du, dv, c1, c2, n, bad)
    count = 0
    for i in range(m):
        if bad[i] and not fixed[i]:
            count += 1
    if count:
        return count
    unit = np.empty((m, 3))
    for i in range(m):
        if fixed[i]:
            unit[i, 0], unit[i, 1], unit[i, 2] = n_fixed[i, 0], n_fixed[i, 1], n_fixed[i, 2]
        else:  # `unit_rows`' arithmetic; a ring row's own du × dv may vanish, so it is not divided
            x0, x1, x2 = n[i, 0], n[i, 1], n[i, 2]
            length = math.sqrt((x0 * x0 + x1 * x1) + x2 * x2)
            unit[i, 0], unit[i, 1], unit[i, 2] = x0 / length, x1 / length, x2 / length
    frames(du, dv, unit, out)
    return 0


@njit(cache=True, nogil=True)
def _cross_add(a, b, c, d, i):
    """Row ``i`` of ``a × b + c × d`` (``numpy.cross``'s products and differences, then the sum)."""
    x0 = (a[i, 1] * b[i, 2] - a[i, 2] * b[i, 1]) + (c[i, 1] * d[i, 2] - c[i, 2] * d[i, 1])
    x1 = (a[i, 2] * b[i, 0] - a[i, 0] * b[i, 2]) + (c[i, 2] * d[i, 0] - c[i, 0] * d[i, 2])
    x2 = (a[i, 0] * b[i, 1] - a[i, 1] * b[i, 0]) + (c[i, 0] * d[i, 1] - c[i, 1] * d[i, 0])
    return x0, x1, x2


@njit(cache=True, nogil=True)
def _centre_sign(x, count, periodic):
    """``np.sign(0.5 - t)`` of ``t``, the level-0 local parameter of ``x`` (`acra.basis.locate`):
    which way the patch's centre lies."""
    xs = x % count if periodic else min(max(x, 0.0), float(count))
    seg = math.floor(xs)
    if seg > count - 1:
        seg = count - 1
    d = 0.5 - (xs - seg)
    return 1.0 if d > 0 else (-1.0 if d < 0 else (0.0 if d == 0 else d))


@njit(cache=True, nogil=True)
def limit_normals(u, v, du, dv, duu, duv, dvv, c1, c2, c3, pu, pv, u_periodic, v_periodic, unit):
    """Unit normals ``unit (m, 3)`` at ``u, v (m,)`` from a second-order evaluation there (``du
    .. dvv (m, 3)``), as `acra.hspline.surface_normals` takes them without nudging: ``du × dv``
    where `degenerate` finds a direction, else the first-order term of ``du × dv`` toward the
    level-0 patch centre (``pu, pv``: level-0 patch counts) where its length exceeds ``c3``.
    Returns how many points have neither (nothing is written then; the caller nudges them,
    `surface_normals`). The same arithmetic in the same order as the array form, so the same
    bits (an evaluation's ``du, dv`` are the same bits at either order)."""
    m = u.shape[0]
    n = np.empty((m, 3))
    bad = np.empty(m, np.bool_)
    degenerate(du, dv, c1, c2, n, bad)
    left = 0
    for i in range(m):
        if bad[i]:
            left += 1
    for i in range(m):
        if not bad[i]:
            continue
        su = _centre_sign(u[i], pu, u_periodic)
        sv = _centre_sign(v[i], pv, v_periodic)
        a0, a1, a2 = _cross_add(duu, dv, du, duv, i)
        b0, b1, b2 = _cross_add(duv, dv, du, dvv, i)
        f0, f1, f2 = su * a0 + sv * b0, su * a1 + sv * b1, su * a2 + sv * b2
        if not math.sqrt((f0 * f0 + f1 * f1) + f2 * f2) > c3:
            return left
        n[i, 0], n[i, 1], n[i, 2] = f0, f1, f2
        left -= 1
    unit_rows(n, unit)
    return 0


@njit(cache=True, nogil=True)
def ring_sums(vectors, rows, ok, sums):
    """``sums[j] = D0 + 4 D1 + D2`` of ring column ``j``'s CVs ``rows[j] (3,)`` (``D``: the row of
    ``vectors``, zero where ``ok[j]`` is False), summed as ``(D0 + 4.0 D1) + D2``; returns the
    largest over the three coordinates of ``max_j - min_j`` (``np.ptp(sums, axis=0).max()``,
    NaN if a sum is)."""
    spread = 0.0
    for c in range(3):
        lo, hi, nan = math.inf, -math.inf, False
        for j in range(rows.shape[0]):
            d0 = vectors[rows[j, 0], c] if ok[j, 0] else 0.0
            d1 = vectors[rows[j, 1], c] if ok[j, 1] else 0.0
            d2 = vectors[rows[j, 2], c] if ok[j, 2] else 0.0
            x = (d0 + 4.0 * d1) + d2
            sums[j, c] = x
            if x != x:
                nan = True
            if x < lo:
                lo = x
            if x > hi:
                hi = x
        width = math.nan if nan else hi - lo
        if width != width or spread != spread:
            spread = math.nan
        elif width > spread:
            spread = width
    return spread
