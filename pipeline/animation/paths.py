"""Motion along a 3-D path: arc length, its inverse, speed control (seed-systems.md §B).

A *path* is any object with ``evaluate(u) -> (n, 3)``, ``derivative(u) -> (n, 3)`` and
``domain -> (u0, u1)``: the curve objects of :mod:`pipeline.animation.curves` (a key curve over a
path parameter), or a :class:`ParametricCurve` wrapping two callables (a helix, say).

Arc length ``s = G(u)`` has no closed form for cubics; it is tabulated three ways (slides,
"Estimating arc length"):

* :func:`arc_length_forward` -- evenly spaced ``u``, chord sums, each table interval supersampled;
* :func:`arc_length_adaptive` -- split an interval while ``|A| + |B| - |C|`` exceeds a threshold
  (``C`` the chord, ``A``, ``B`` the chords of its halves);
* :func:`arc_length_gauss` -- Gauss-Legendre quadrature of ``|p'(u)|``, an interval split while
  its two halves disagree with the whole.

Every table is an :class:`ArcLengthTable` (``u``, ``s``, the speed ``|p'(u)|`` at the nodes).
:func:`arc_length` reads ``G(u)`` and :func:`inverse_arc_length` reads ``u = G^-1(s)`` by binary
search plus cubic Hermite interpolation (the slides' "higher order interpolation than linear":
the node speeds are the exact derivatives ``ds/du``).  A distance-time function ``s = h(t)`` from
:mod:`pipeline.animation.easing` then gives the position ``P(G^-1(L h(t)))``
(:func:`sample_path`); :func:`orientations` turns the tangents into quaternions.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from . import curves as _curves
from . import easing as _easing
from .quaternions import matrix_to_quat as _matrix_to_quat

__all__ = [
    "ParametricCurve", "ArcLengthTable", "path_through",
    "arc_length_forward", "arc_length_adaptive", "arc_length_gauss", "arc_length_table",
    "arc_length", "inverse_arc_length", "sample_path", "orientations", "quaternions_from_matrices",
]


class ParametricCurve:
    """A path from callables: ``evaluate(u (n,)) -> (n, d)``, ``derivative(u (n,)) -> (n, d)``."""

    def __init__(self, evaluate: Callable, derivative: Callable, domain=(0.0, 1.0)):
        self._f, self._df = evaluate, derivative
        self.domain = (float(domain[0]), float(domain[1]))

    def evaluate(self, u) -> np.ndarray:
        return np.asarray(self._f(np.asarray(u, dtype=np.float64)), dtype=np.float64)

    __call__ = evaluate

    def derivative(self, u, side: str = "right") -> np.ndarray:
        return np.asarray(self._df(np.asarray(u, dtype=np.float64)), dtype=np.float64)


def path_through(points, kind: str = "catmull_rom", parameterization="centripetal",
                 tension: float = 0.0):
    """A path curve through (or, for ``'bspline'``, near) 3-D points ``(k, 3)``.

    ``'catmull_rom'`` / ``'cardinal'``: cardinal spline over :func:`curves.parameter_knots`
    (default centripetal: no cusps or self-intersections inside a segment); ``'bezier'``: the
    points are a Bézier control polygon (3n+1 points); ``'bspline'``: uniform B-spline control
    points; ``'linear'``: the polyline.  The parameter runs over the knots (``0..k-1`` if uniform).
    """
    P = np.asarray(points, dtype=np.float64)
    if kind in ("catmull_rom", "cardinal"):
        s = _curves.parameter_knots(P, parameterization)
        return _curves.cardinal(s, P, tension if kind == "cardinal" else 0.0, "time")
    if kind == "bezier":
        return _curves.bezier_polygon(P)
    if kind == "bspline":
        return _curves.bspline(np.arange(P.shape[0], dtype=np.float64), P)
    if kind == "linear":
        return _curves.linear(np.arange(P.shape[0], dtype=np.float64), P)
    raise ValueError(f"unknown path kind {kind!r}")


@dataclass
class ArcLengthTable:
    """Tabulated arc length ``s = G(u)``.

    u : (m,) float64 increasing parameters, u[0], u[-1] the curve's domain
    s : (m,) float64 non-decreasing arc length from u[0], s[0] = 0
    speed : (m,) float64 ``|p'(u)|`` at the nodes (for Hermite interpolation)
    evaluations : int, curve point / derivative evaluations spent building the table
    method : str
    """

    u: np.ndarray
    s: np.ndarray
    speed: np.ndarray
    evaluations: int
    method: str

    @property
    def length(self) -> float:
        return float(self.s[-1])


def _derivative(curve, u: np.ndarray) -> np.ndarray:
    """``p'(u) (n, d)`` inside the domain: right-sided, but left-sided at the far end.

    Key curves hold their end value outside their keys, so their right derivative at the last
    key is zero; along a path the motion arrives there with the last segment's tangent.
    """
    u = np.asarray(u, dtype=np.float64)
    D = curve.derivative(u)
    end = u >= curve.domain[1]
    if np.any(end):
        D[end] = curve.derivative(u[end], side="left")
    return D


def _speed(curve, u: np.ndarray) -> np.ndarray:
    return np.linalg.norm(_derivative(curve, u), axis=-1)


def _breaks(curve, pieces: int) -> np.ndarray:
    """Initial interval ends: the curve's own knots if it has them, each cut into ``pieces``.

    Starting the adaptive methods at the knots keeps every interval inside one cubic segment,
    where ``|p'|`` is smooth (it is only C0 in its derivative across a segment join).
    """
    u0, u1 = curve.domain
    knots = getattr(curve, "times", None)
    knots = np.array([u0, u1]) if knots is None else np.asarray(knots, dtype=np.float64)
    fine = [np.linspace(a, b, pieces + 1)[:-1] for a, b in zip(knots[:-1], knots[1:])]
    return np.concatenate(fine + [[knots[-1]]])


def arc_length_forward(curve, n: int = 1000, supersample: int = 10) -> ArcLengthTable:
    """Forward-difference table: ``n`` even steps in u, each measured by ``supersample`` chords.

    The slides' 1000-entry table evaluated with 10 points per interval is the default.  The chord
    sum underestimates the length by about ``kappa^2 L^3 / (24 N^2)`` for ``N = n supersample``.
    """
    u0, u1 = curve.domain
    N = n * supersample
    uf = np.linspace(u0, u1, N + 1)
    P = curve.evaluate(uf)
    chords = np.linalg.norm(np.diff(P, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(chords)])[::supersample]
    u = uf[::supersample]
    return ArcLengthTable(u, s, _speed(curve, u), (N + 1) + (n + 1), "forward")


def arc_length_adaptive(curve, tol: float = 1e-9, min_depth: int = 2, max_depth: int = 40,
                        pieces: int = 4) -> ArcLengthTable:
    """Adaptive chord subdivision (slides): accept ``[a, b]`` when ``A + B - C <= tol * L0``.

    ``C = |P(b) - P(a)|``, ``A``, ``B`` the chords to the midpoint, ``L0`` a coarse length
    estimate; an accepted interval adds nodes ``(m, s_a + A)`` and ``(b, s_a + A + B)``.  The
    remaining error per interval is about ``(A + B - C) / 3``.  ``min_depth`` forced splits guard
    against a chord that happens to pass through the midpoint of a curved span.
    """
    uu = _breaks(curve, pieces)
    a, b = uu[:-1], uu[1:]
    Pa, Pb = curve.evaluate(a), curve.evaluate(b)
    evals = 2 * a.size
    L0 = float(np.sum(np.linalg.norm(Pb - Pa, axis=1)))
    thr = tol * max(L0, np.finfo(float).tiny)
    acc_a, acc_m, acc_b, acc_A, acc_B = [], [], [], [], []
    for depth in range(max_depth + 1):
        if a.size == 0:
            break
        m = 0.5 * (a + b)
        Pm = curve.evaluate(m)
        evals += m.size
        A = np.linalg.norm(Pm - Pa, axis=1)
        B = np.linalg.norm(Pb - Pm, axis=1)
        C = np.linalg.norm(Pb - Pa, axis=1)
        ok = (A + B - C <= thr) & (depth >= min_depth) | (depth == max_depth)
        for lst, x in zip((acc_a, acc_m, acc_b, acc_A, acc_B), (a, m, b, A, B)):
            lst.append(x[ok])
        keep = ~ok
        a, b, m, Pa, Pb, Pm = a[keep], b[keep], m[keep], Pa[keep], Pb[keep], Pm[keep]
        a, b = np.concatenate([a, m]), np.concatenate([m, b])
        Pa, Pb = np.concatenate([Pa, Pm]), np.concatenate([Pm, Pb])
    a, m, b, A, B = (np.concatenate(x) for x in (acc_a, acc_m, acc_b, acc_A, acc_B))
    order = np.argsort(a)
    a, m, b, A, B = a[order], m[order], b[order], A[order], B[order]
    start = np.concatenate([[0.0], np.cumsum(A + B)[:-1]])
    u = np.concatenate([[a[0]], np.stack([m, b], axis=1).ravel()])
    s = np.concatenate([[0.0], np.stack([start + A, start + A + B], axis=1).ravel()])
    return ArcLengthTable(u, s, _speed(curve, u), evals + u.size, "adaptive")


def _gauss_legendre(curve, a: np.ndarray, b: np.ndarray, x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``(m,)`` integrals of ``|p'(u)|`` over ``[a, b]`` with nodes ``x``, weights ``w`` on [-1, 1]."""
    half = 0.5 * (b - a)
    u = (0.5 * (a + b))[:, None] + half[:, None] * x[None, :]
    sp = _speed(curve, u.ravel()).reshape(u.shape)
    return half * (sp @ w)


def arc_length_gauss(curve, tol: float = 1e-12, order: int = 5, min_intervals: int = 4,
                     max_depth: int = 40) -> ArcLengthTable:
    """Adaptive Gauss-Legendre quadrature of ``|p'(u)|`` (slides, "Adaptive Gaussian integration").

    Each interval is integrated whole and as two halves with ``order``-point Gauss-Legendre; it is
    accepted (taking the halves' sum) when they agree to ``tol * L0 * width / (u1 - u0)``, else
    both halves are subdivided further.  The table nodes are the accepted intervals' ends and
    midpoints; the curve's own knots, each cut into ``min_intervals``, are the starting intervals.
    """
    x, w = np.polynomial.legendre.leggauss(order)
    u0, u1 = curve.domain
    uu = _breaks(curve, min_intervals)
    a, b = uu[:-1], uu[1:]
    whole = _gauss_legendre(curve, a, b, x, w)
    evals = order * a.size
    L0 = float(np.sum(whole))
    scale = tol * max(abs(L0), np.finfo(float).tiny) / (u1 - u0)
    acc = []
    for depth in range(max_depth + 1):
        if a.size == 0:
            break
        m = 0.5 * (a + b)
        left = _gauss_legendre(curve, a, m, x, w)
        right = _gauss_legendre(curve, m, b, x, w)
        evals += 2 * order * a.size
        ok = (np.abs(left + right - whole) <= scale * (b - a)) | (depth == max_depth)
        acc.append(np.stack([a, m, b, left, right], axis=1)[ok])
        keep = ~ok
        a, m, b, left, right = a[keep], m[keep], b[keep], left[keep], right[keep]
        a, b = np.concatenate([a, m]), np.concatenate([m, b])
        whole = np.concatenate([left, right])
    rows = np.concatenate(acc)
    rows = rows[np.argsort(rows[:, 0])]
    start = np.concatenate([[0.0], np.cumsum(rows[:, 3] + rows[:, 4])[:-1]])
    u = np.concatenate([[rows[0, 0]], rows[:, 1:3].ravel()])
    s = np.concatenate([[0.0], np.stack([start + rows[:, 3], start + rows[:, 3] + rows[:, 4]], 1).ravel()])
    return ArcLengthTable(u, s, _speed(curve, u), evals + u.size, "gauss")


_METHODS = {"forward": arc_length_forward, "adaptive": arc_length_adaptive, "gauss": arc_length_gauss}


def arc_length_table(curve, method: str = "gauss", **params) -> ArcLengthTable:
    """Build a table by method name: ``'forward'``, ``'adaptive'`` or ``'gauss'``."""
    try:
        return _METHODS[method](curve, **params)
    except KeyError:
        raise ValueError(f"unknown arc-length method {method!r}; expected one of {list(_METHODS)}") from None


def _hermite01(y0, y1, m0, m1, tau):
    """Cubic Hermite on [0, 1] with end values y and end derivatives m (per unit tau)."""
    t2, t3 = tau * tau, tau * tau * tau
    return (2 * t3 - 3 * t2 + 1) * y0 + (t3 - 2 * t2 + tau) * m0 + (-2 * t3 + 3 * t2) * y1 + (t3 - t2) * m1


def arc_length(table: ArcLengthTable, u, curve=None) -> np.ndarray:
    """``s = G(u)`` from a table: binary search plus cubic Hermite (``ds/du`` = node speed).

    u : any shape, clamped to the table's range -> same shape.  With ``curve`` the part inside
    the table interval is integrated instead (8-point Gauss-Legendre of ``|p'|``), which is what a
    Gauss table, exact at few nodes, is for.
    """
    u = np.clip(np.asarray(u, dtype=np.float64), table.u[0], table.u[-1])
    i = np.clip(np.searchsorted(table.u, u, side="right") - 1, 0, table.u.size - 2)
    if curve is not None:
        x, w = np.polynomial.legendre.leggauss(8)
        shape = u.shape
        flat_i, flat_u = i.reshape(-1), u.reshape(-1)
        return (table.s[flat_i] + _gauss_legendre(curve, table.u[flat_i], flat_u, x, w)).reshape(shape)
    du = table.u[i + 1] - table.u[i]
    ds = table.s[i + 1] - table.s[i]
    m0 = np.minimum(table.speed[i] * du, 3 * ds)       # Fritsch-Carlson bound keeps it monotone
    m1 = np.minimum(table.speed[i + 1] * du, 3 * ds)
    return _hermite01(table.s[i], table.s[i + 1], m0, m1, (u - table.u[i]) / du)


def inverse_arc_length(table: ArcLengthTable, s, curve=None, newton: int = 0) -> np.ndarray:
    """``u = G^-1(s)``: binary search for the interval, cubic Hermite interpolation within it.

    s : any shape, clamped to ``[0, length]`` -> u of the same shape.  ``du/ds = 1 / speed`` at the
    nodes (bounded by 3x the secant so the interpolant stays monotone where the speed vanishes).
    With ``curve`` and ``newton > 0`` each u is then polished by Newton steps on
    ``s_i + integral_{u_i}^{u} |p'| - s`` (8-point Gauss-Legendre within the interval).
    """
    s = np.clip(np.asarray(s, dtype=np.float64), 0.0, table.s[-1])
    shape, s = s.shape, s.reshape(-1)
    i = np.clip(np.searchsorted(table.s, s, side="right") - 1, 0, table.s.size - 2)
    du = table.u[i + 1] - table.u[i]
    ds = table.s[i + 1] - table.s[i]
    with np.errstate(divide="ignore", invalid="ignore"):
        tau = np.where(ds > 0, (s - table.s[i]) / ds, 0.0)
        m0 = np.where(table.speed[i] > 0, ds / table.speed[i], np.inf)
        m1 = np.where(table.speed[i + 1] > 0, ds / table.speed[i + 1], np.inf)
    m0, m1 = np.minimum(m0, 3 * du), np.minimum(m1, 3 * du)
    u = _hermite01(table.u[i], table.u[i + 1], m0, m1, tau)
    if curve is not None and newton > 0:
        x, w = np.polynomial.legendre.leggauss(8)
        lo, hi = table.u[i], table.u[i + 1]
        for _ in range(newton):
            G = table.s[i] + _gauss_legendre(curve, lo, u, x, w)
            sp = _speed(curve, u)
            with np.errstate(divide="ignore", invalid="ignore"):
                step = np.where(sp > 0, (G - s) / sp, 0.0)
            u = np.clip(u - step, lo, hi)
    return u.reshape(shape)


def sample_path(curve, t, timing: "_easing.DistanceTime | None" = None,
                table: ArcLengthTable | None = None, method: str = "gauss",
                newton: int | None = None, **params):
    """Positions and unit tangents along a path at normalised times ``t : (n,)`` in [0, 1].

    ``s = L h(t)`` with the distance-time function ``timing`` (default constant speed), then
    ``u = G^-1(s)`` (``params`` go to the table builder).  ``newton`` polishing steps default to
    2 for Gauss tables, whose nodes are few but whose ``s`` values are quadrature-exact, and 0 for
    the chord tables, whose dense nodes carry the (chord-sum) length the polishing would not match.  Returns ``positions (n, d)``, ``tangents (n, d)`` (unit; where the speed
    vanishes the direction of the next/previous position is used), ``u (n,)`` and ``s (n,)``.
    """
    timing = _easing.constant_speed() if timing is None else timing
    table = arc_length_table(curve, method, **params) if table is None else table
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    s = table.length * timing(t)
    newton = (2 if table.method == "gauss" else 0) if newton is None else newton
    u = inverse_arc_length(table, s, curve, newton)
    P = curve.evaluate(u)
    D = _derivative(curve, u)
    n = np.linalg.norm(D, axis=1)
    small = n <= 1e-12 * max(table.length, 1e-300)
    if np.any(small):
        # a cusp or a held end: take the direction of travel from a nearby parameter
        eps = 1e-6 * (curve.domain[1] - curve.domain[0])
        ua = np.clip(u[small] + eps, *curve.domain)
        ub = np.clip(u[small] - eps, *curve.domain)
        D[small] = curve.evaluate(ua) - curve.evaluate(ub)
        n[small] = np.linalg.norm(D[small], axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        T = D / n[:, None]
    T[~np.isfinite(T)] = 0.0
    return P, T, u, s


def quaternions_from_matrices(R: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(n, 4)`` as (w, x, y, z), ``w >= 0``, from proper rotations ``R : (n, 3, 3)``
    (Shepperd's method, shared with skinning: `quaternions.matrix_to_quat`)."""
    return _matrix_to_quat(R).reshape(-1, 4)


def orientations(tangents, forward=(1.0, 0.0, 0.0), up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """Quaternions ``(n, 4)`` (w, x, y, z) turning the local ``forward`` axis onto each tangent.

    tangents : (n, 3).  The local ``up`` axis (its part orthogonal to ``forward``) is turned
    towards the world ``up`` projected off the tangent, so the object banks only as little as the
    path forces.  Where the tangent is parallel to ``up`` the side axis of the nearest valid frame
    is reused.  Consecutive quaternions are kept in one hemisphere (no sign flips between frames).
    """
    T = np.asarray(tangents, dtype=np.float64).reshape(-1, 3)
    T = T / np.linalg.norm(T, axis=1, keepdims=True)
    f = np.asarray(forward, dtype=np.float64)
    f = f / np.linalg.norm(f)
    upw = np.asarray(up, dtype=np.float64)
    upw = upw / np.linalg.norm(upw)
    ul = upw - (upw @ f) * f
    if np.linalg.norm(ul) < 1e-9:
        raise ValueError("forward and up axes must not be parallel")
    ul /= np.linalg.norm(ul)
    L = np.stack([f, ul, np.cross(f, ul)], axis=1)              # local frame as columns
    S = np.cross(T, upw)
    ns = np.linalg.norm(S, axis=1)
    valid = ns > 1e-9
    if not np.any(valid):
        S = np.tile(np.cross(f, ul), (T.shape[0], 1)) if abs(T[0] @ np.cross(f, ul)) < 0.9 \
            else np.tile(f, (T.shape[0], 1))
    else:
        S[valid] /= ns[valid, None]
        idx = np.flatnonzero(valid)
        nearest = idx[np.clip(np.searchsorted(idx, np.arange(T.shape[0])), 0, idx.size - 1)]
        S[~valid] = S[nearest[~valid]]
    S = S - np.sum(S * T, axis=1, keepdims=True) * T             # make it orthogonal to T
    S /= np.linalg.norm(S, axis=1, keepdims=True)
    U = np.cross(S, T)
    W = np.stack([T, U, S], axis=2)                             # world frame as columns
    q = quaternions_from_matrices(W @ L.T)
    for j in range(1, q.shape[0]):
        if q[j] @ q[j - 1] < 0:
            q[j] = -q[j]
    return q
