"""Key-frame curves: cubic segments ``p(u) = [u^3 u^2 u 1] M G`` (seed-systems.md §A).

Two layers, kept apart:

* **Curve objects** evaluate.  :class:`KeyCurve` is the one piecewise-cubic form that every
  interpolating kind reduces to; it mirrors a USD ``Ts`` knot list (time, value, in/out slope,
  in/out tangent width, interpolation to the next key), so writing it to USD is a copy and not an
  approximation.  :class:`BSplineCurve` (approximating, uniform) and :class:`EasedCurve`
  (Blender-style easing presets between keys) are the two kinds that are *not* Ts-representable
  and are baked to time samples by :mod:`pipeline.animation.usdkeys`.
* **Constructors** (:func:`constant`, :func:`linear`, :func:`hermite`, :func:`bezier`,
  :func:`bezier_polygon`, :func:`interpolating_cubic`, :func:`cardinal`, :func:`catmull_rom`,
  :func:`kochanek_bartels`, :func:`bspline`, :func:`eased`, and the dispatcher :func:`make`) turn
  keys into curve objects.  The tangent rules live here and nowhere else.

Conventions (all arrays float64):

* ``times : (k,)`` strictly increasing key times (frames), or curve parameter values for a path.
* ``values : (k, d)`` key values; a ``(k,)`` input is read as ``d = 1``.
* ``evaluate(t)`` with ``t`` of any shape returns ``t.shape + (d,)``.
* ``derivative(t, side)`` is d value / d t; ``side='left'`` / ``'right'`` picks the one-sided
  derivative at a key, which is how the tests measure C1 and tangent breaks.
* Outside ``[times[0], times[-1]]`` every curve holds its end value (Ts's default ``Held``
  extrapolation), so the derivative there is zero.

Time is linear in the segment parameter ``u = (t - t_i) / h_i`` for every kind except
:func:`bezier` with handles not at 1/3 and 2/3 of the interval: that one is a 2-D Bézier in
(time, value), as in Blender and in Ts's ``Bezier`` curve type, and is evaluated by solving the
time cubic for ``u``.
"""

from __future__ import annotations

import numpy as np

from . import easing as _easing

__all__ = [
    "M_HERMITE", "M_BEZIER", "M_BSPLINE", "M_CATMULL_ROM", "M_INTERPOLATING",
    "HELD", "LINEAR", "CURVE",
    "cardinal_matrix", "segment_points", "segment_derivative", "parameter_knots",
    "KeyCurve", "BSplineCurve", "EasedCurve",
    "constant", "linear", "hermite", "bezier", "bezier_polygon", "interpolating_cubic",
    "cardinal", "catmull_rom", "kochanek_bartels", "bspline", "eased", "make", "KINDS",
]

# ---------------------------------------------------------------------------------------------
# Basis matrices, p(u) = [u^3 u^2 u 1] M G  (seed-systems.md §A; slides "Hermite", "Bezier",
# "Cubic B-splines", "Catmull-Rom").  Rows are the coefficients of u^3, u^2, u, 1.
# ---------------------------------------------------------------------------------------------

#: Hermite, geometry ``G = [p0, p3, p0', p3']`` (tangents per unit u).
M_HERMITE = np.array([[2, -2, 1, 1], [-3, 3, -2, -1], [0, 0, 1, 0], [1, 0, 0, 0]], dtype=np.float64)
#: Bézier, geometry ``G = [p0, p1, p2, p3]``; ``p'(0) = 3 (p1 - p0)``, ``p'(1) = 3 (p3 - p2)``.
M_BEZIER = np.array([[-1, 3, -3, 1], [3, -6, 3, 0], [-3, 3, 0, 0], [1, 0, 0, 0]], dtype=np.float64)
#: Uniform cubic B-spline, geometry ``G = [p_{i-1}, p_i, p_{i+1}, p_{i+2}]`` (segment p_i..p_{i+1}).
M_BSPLINE = np.array([[-1, 3, -3, 1], [3, -6, 3, 0], [-3, 0, 3, 0], [1, 4, 1, 0]], dtype=np.float64) / 6.0
#: Catmull-Rom, geometry ``G = [p_{i-1}, p_i, p_{i+1}, p_{i+2}]``.
M_CATMULL_ROM = np.array([[-1, 3, -3, 1], [2, -5, 4, -1], [-1, 0, 1, 0], [0, 2, 0, 0]], dtype=np.float64) / 2.0
#: Interpolating cubic through 4 points at u = 0, 1/3, 2/3, 1 (the inverse Vandermonde matrix).
M_INTERPOLATING = np.linalg.inv(
    np.array([[u**3, u**2, u, 1.0] for u in (0.0, 1 / 3, 2 / 3, 1.0)], dtype=np.float64)
)

#: Interpolation codes per segment, matching ``Ts.InterpHeld``, ``Ts.InterpLinear``, ``Ts.InterpCurve``.
HELD, LINEAR, CURVE = 0, 1, 2


def cardinal_matrix(tension: float) -> np.ndarray:
    """Cardinal basis matrix ``(4, 4)`` for tension ``q``, geometry ``[p_{i-1}, p_i, p_{i+1}, p_{i+2}]``.

    Tangent ``(1 - q)(p_{i+1} - p_{i-1}) / 2`` per unit u with uniform parameters, so ``q = 0``
    gives :data:`M_CATMULL_ROM` (CCM paper's cardinal spline; seed-systems.md §A).
    """
    s = (1.0 - float(tension)) / 2.0
    return np.array(
        [[-s, 2 - s, s - 2, s], [2 * s, s - 3, 3 - 2 * s, -s], [-s, 0, s, 0], [0, 1, 0, 0]],
        dtype=np.float64,
    )


def segment_points(M: np.ndarray, G: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Evaluate one cubic segment ``[u^3 u^2 u 1] M G``.

    M : (4, 4) basis, G : (4, d) geometry, u : (n,) -> (n, d).
    """
    u = np.asarray(u, dtype=np.float64)
    U = np.stack([u**3, u**2, u, np.ones_like(u)], axis=-1)
    return U @ (np.asarray(M, dtype=np.float64) @ np.asarray(G, dtype=np.float64))


def segment_derivative(M: np.ndarray, G: np.ndarray, u: np.ndarray) -> np.ndarray:
    """d/du of :func:`segment_points`: ``[3u^2 2u 1 0] M G``; shapes as there."""
    u = np.asarray(u, dtype=np.float64)
    U = np.stack([3 * u**2, 2 * u, np.ones_like(u), np.zeros_like(u)], axis=-1)
    return U @ (np.asarray(M, dtype=np.float64) @ np.asarray(G, dtype=np.float64))


# ---------------------------------------------------------------------------------------------
# Input checking
# ---------------------------------------------------------------------------------------------

def _as_times(times) -> np.ndarray:
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if t.size == 0:
        raise ValueError("need at least one key")
    if not np.all(np.isfinite(t)):
        raise ValueError("key times must be finite")
    if np.any(np.diff(t) <= 0):
        raise ValueError("key times must be strictly increasing")
    return t


def _as_values(values, k: int) -> np.ndarray:
    v = np.asarray(values, dtype=np.float64)
    if v.ndim == 1:
        v = v[:, None]
    if v.ndim != 2 or v.shape[0] != k:
        raise ValueError(f"values must have shape ({k},) or ({k}, d), got {np.shape(values)}")
    if not np.all(np.isfinite(v)):
        raise ValueError("key values must be finite")
    return v


def _per_key(x, k: int, name: str) -> np.ndarray:
    a = np.broadcast_to(np.asarray(x, dtype=np.float64), (k,)).copy()
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite")
    return a


def _bezier_time_monotone(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """True where a (time) Bézier 0, a, 1-b, 1 is non-decreasing in u (widths a, b in interval units).

    x'(u)/3 has Bernstein coefficients (a, 1-a-b, b): non-negative on [0, 1] iff a, b >= 0 and
    either 1-a-b >= 0 or (1-a-b)^2 <= a b.  A regressive segment would make the value a
    multi-valued function of time; Ts would silently alter it, so constructors reject it.
    """
    c = 1.0 - a - b
    return (a >= 0) & (b >= 0) & ((c >= 0) | (c * c <= a * b * (1 + 1e-12)))


def _locate(times: np.ndarray, t: np.ndarray, side: str) -> np.ndarray:
    """Segment index ``(n,) int`` in ``[0, k-2]``; right-continuous for ``side='right'``."""
    if side not in ("left", "right"):
        raise ValueError("side must be 'left' or 'right'")
    i = np.searchsorted(times, t, side=side) - 1
    return np.clip(i, 0, max(times.size - 2, 0))


def _outside(times: np.ndarray, t: np.ndarray, side: str):
    """Masks of ``t`` on the held extrapolation before / after the keys for one-sided queries."""
    if side == "right":
        return t < times[0], t >= times[-1]
    return t <= times[0], t > times[-1]


# ---------------------------------------------------------------------------------------------
# Curve objects
# ---------------------------------------------------------------------------------------------

class _Keyed:
    """What every key curve shares: ``times (k,)`` and ``values (k, d)`` attributes."""

    @property
    def dim(self) -> int:
        return self.values.shape[1]

    @property
    def domain(self) -> tuple[float, float]:
        return float(self.times[0]), float(self.times[-1])


class KeyCurve(_Keyed):
    """Piecewise cubic key curve in USD Ts knot form.

    Segment ``i`` (keys ``i -> i+1``, ``h_i = t_{i+1} - t_i``) is, for ``interp[i] == CURVE``,
    the 2-D Bézier in (time, value) with control points::

        (t_i, v_i), (t_i + wo_i, v_i + wo_i so_i), (t_{i+1} - wi_{i+1}, v_{i+1} - wi_{i+1} si_{i+1}), (t_{i+1}, v_{i+1})

    where ``so``/``si`` are the out/in slopes (d value / d time) and ``wo``/``wi`` the out/in
    tangent widths (time extents of the handles).  With the standard widths ``h_i / 3`` time is
    linear in u and the segment is the Hermite cubic ``[u^3 u^2 u 1] M_H [v_i, v_{i+1}, h so_i,
    h si_{i+1}]`` -- Ts's ``Hermite`` curve type.  ``HELD`` holds ``v_i``; ``LINEAR`` is the chord.

    Attributes
    ----------
    times : (k,) float64, values : (k, d) float64
    slopes_in, slopes_out : (k, d) float64, d value / d time arriving at / leaving each key
    widths_in, widths_out : (k,) float64 > 0, handle time extents
    interp : (k-1,) int8, one of HELD, LINEAR, CURVE per segment
    """

    def __init__(self, times, values, slopes_in=None, slopes_out=None, widths_in=None,
                 widths_out=None, interp=CURVE):
        self.times = _as_times(times)
        k = self.times.size
        self.values = _as_values(values, k)
        d = self.values.shape[1]
        zero = np.zeros((k, d))
        self.slopes_out = zero.copy() if slopes_out is None else _as_values(slopes_out, k)
        self.slopes_in = self.slopes_out.copy() if slopes_in is None else _as_values(slopes_in, k)
        if self.slopes_in.shape[1] != d or self.slopes_out.shape[1] != d:
            raise ValueError("slopes must have the same dimension as values")
        h = np.diff(self.times)
        # standard widths: a third of the adjacent interval (the end keys copy their only neighbour)
        std_in = np.concatenate([h[:1], h]) / 3.0 if k > 1 else np.ones(1) / 3.0
        std_out = np.concatenate([h, h[-1:]]) / 3.0 if k > 1 else np.ones(1) / 3.0
        self.widths_in = std_in if widths_in is None else _per_key(widths_in, k, "widths_in")
        self.widths_out = std_out if widths_out is None else _per_key(widths_out, k, "widths_out")
        self.interp = np.broadcast_to(np.asarray(interp, dtype=np.int8), (max(k - 1, 0),)).copy()
        if np.any((self.interp < HELD) | (self.interp > CURVE)):
            raise ValueError("interp codes must be HELD, LINEAR or CURVE")
        if k > 1:
            a = self.widths_out[:-1] / h
            b = self.widths_in[1:] / h
            curve = self.interp == CURVE
            if np.any(curve & ((a <= 0) | (b <= 0))):
                raise ValueError("tangent widths of curved segments must be positive")
            bad = curve & ~_bezier_time_monotone(a, b)
            if np.any(bad):
                raise ValueError(
                    f"Bezier handles make time regress in segment(s) {np.flatnonzero(bad).tolist()}")
            # segments whose time is linear in u (standard widths): evaluated in closed form
            self._linear_time = (np.abs(a - 1 / 3) <= 1e-12) & (np.abs(b - 1 / 3) <= 1e-12)

    # -- properties ------------------------------------------------------------------------------
    @property
    def standard_widths(self) -> bool:
        """True when every curved segment has handles at 1/3, 2/3 (Ts ``Hermite`` curve type)."""
        if self.times.size < 2:
            return True
        return bool(np.all(self._linear_time | (self.interp != CURVE)))

    # -- evaluation --------------------------------------------------------------------------------
    def _segment_controls(self, i: np.ndarray):
        """Control times ``X (4, n)`` and values ``Y (4, n, d)`` of segments ``i (n,)``."""
        t0, t1 = self.times[i], self.times[i + 1]
        wo, wi = self.widths_out[i], self.widths_in[i + 1]
        v0, v1 = self.values[i], self.values[i + 1]
        X = np.stack([t0, t0 + wo, t1 - wi, t1])
        Y = np.stack([v0, v0 + wo[:, None] * self.slopes_out[i],
                      v1 - wi[:, None] * self.slopes_in[i + 1], v1])
        return X, Y

    def _solve_u(self, i: np.ndarray, t: np.ndarray, X: np.ndarray) -> np.ndarray:
        """Bézier parameter ``u (n,)`` with ``x(u) = t``; closed form where time is linear in u.

        Otherwise safeguarded Newton on the monotone time cubic (bisection when Newton leaves the
        bracket), iterated to machine precision.
        """
        h = self.times[i + 1] - self.times[i]
        u = np.clip((t - self.times[i]) / h, 0.0, 1.0)
        todo = ~self._linear_time[i]
        if not np.any(todo):
            return u
        Xs, ts, us = X[:, todo], t[todo], u[todo]
        lo, hi = np.zeros_like(us), np.ones_like(us)
        B = np.array([[-1, 3, -3, 1], [3, -6, 3, 0], [-3, 3, 0, 0]], dtype=np.float64) @ Xs
        for _ in range(100):
            f = ((B[0] * us + B[1]) * us + B[2]) * us + Xs[0] - ts
            lo = np.where(f < 0, us, lo)
            hi = np.where(f > 0, us, hi)
            df = (3 * B[0] * us + 2 * B[1]) * us + B[2]
            with np.errstate(divide="ignore", invalid="ignore"):
                un = us - f / df
            bad = ~np.isfinite(un) | (un <= lo) | (un >= hi)
            un = np.where(bad, 0.5 * (lo + hi), un)
            if np.all(np.abs(un - us) <= 4e-16) or np.all(hi - lo <= 4e-16):
                us = un
                break
            us = un
        u[todo] = us
        return u

    def evaluate(self, t) -> np.ndarray:
        """Values at ``t`` (any shape) -> ``t.shape + (d,)``; right-continuous at held keys."""
        t = np.asarray(t, dtype=np.float64)
        shape, t = t.shape, t.reshape(-1)
        out = np.empty((t.size, self.dim))
        if self.times.size == 1:
            out[:] = self.values[0]
            return out.reshape(shape + (self.dim,))
        i = _locate(self.times, t, "right")
        before, after = _outside(self.times, t, "right")
        mode = self.interp[i]
        h = self.times[i + 1] - self.times[i]
        v0, v1 = self.values[i], self.values[i + 1]
        out[:] = v0
        lin = mode == LINEAR
        if np.any(lin):
            w = ((t[lin] - self.times[i[lin]]) / h[lin])[:, None]
            out[lin] = v0[lin] + w * (v1[lin] - v0[lin])
        cur = mode == CURVE
        if np.any(cur):
            ic, tc = i[cur], t[cur]
            X, Y = self._segment_controls(ic)
            u = self._solve_u(ic, tc, X)
            bern = np.stack([(1 - u) ** 3, 3 * u * (1 - u) ** 2, 3 * u**2 * (1 - u), u**3])
            out[cur] = np.einsum("jn,jnd->nd", bern, Y)
        out[before] = self.values[0]
        out[after] = self.values[-1]
        return out.reshape(shape + (self.dim,))

    __call__ = evaluate

    def derivative(self, t, side: str = "right") -> np.ndarray:
        """d value / d t at ``t`` -> ``t.shape + (d,)``; one-sided at keys (``side``)."""
        t = np.asarray(t, dtype=np.float64)
        shape, t = t.shape, t.reshape(-1)
        out = np.zeros((t.size, self.dim))
        if self.times.size == 1:
            return out.reshape(shape + (self.dim,))
        i = _locate(self.times, t, side)
        before, after = _outside(self.times, t, side)
        mode = self.interp[i]
        h = self.times[i + 1] - self.times[i]
        lin = mode == LINEAR
        out[lin] = (self.values[i[lin] + 1] - self.values[i[lin]]) / h[lin, None]
        cur = mode == CURVE
        if np.any(cur):
            ic, tc = i[cur], t[cur]
            X, Y = self._segment_controls(ic)
            u = self._solve_u(ic, tc, X)
            dB = np.stack([-3 * (1 - u) ** 2, 3 * (1 - u) ** 2 - 6 * u * (1 - u),
                           6 * u * (1 - u) - 3 * u**2, 3 * u**2])
            dx = np.einsum("jn,jn->n", dB, X)
            dy = np.einsum("jn,jnd->nd", dB, Y)
            out[cur] = dy / dx[:, None]
        out[before | after] = 0.0
        return out.reshape(shape + (self.dim,))

    def __repr__(self) -> str:
        return f"KeyCurve(k={self.times.size}, d={self.dim}, domain={self.domain})"


class BSplineCurve(_Keyed):
    """Uniform cubic B-spline key curve (approximating, C2): ``[u^3 u^2 u 1] M_S G``.

    ``control : (k, d)`` sits at uniformly spaced ``times : (k,)``.  Segment ``j`` spans
    ``[t_j, t_{j+1}]`` with ``G = [P_{j-1}, P_j, P_{j+1}, P_{j+2}]`` (slides: the curve between
    ``p_{i-1}, p_i`` uses ``p_{i-2} .. p_{i+1}``).  The missing ``P_{-1}, P_k`` are mirrored
    phantoms ``2 P_0 - P_1`` and ``2 P_{k-1} - P_{k-2}``, so the ends are interpolated:
    ``(P_{-1} + 4 P_0 + P_1) / 6 = P_0``.  Not Ts-representable: baked to samples.
    """

    def __init__(self, times, control):
        self.times = _as_times(times)
        k = self.times.size
        if k < 2:
            raise ValueError("a B-spline needs at least two control points")
        h = np.diff(self.times)
        if not np.allclose(h, h[0], rtol=1e-9, atol=0):
            raise ValueError("a uniform B-spline needs uniformly spaced key times")
        self.step = float(h[0])
        self.values = _as_values(control, k)
        self._ext = np.concatenate(
            [2 * self.values[:1] - self.values[1:2], self.values, 2 * self.values[-1:] - self.values[-2:-1]])

    def _geometry(self, t, side):
        t = np.asarray(t, dtype=np.float64)
        shape, t = t.shape, t.reshape(-1)
        j = _locate(self.times, t, side)
        u = np.clip((t - self.times[j]) / self.step, 0.0, 1.0)
        G = np.stack([self._ext[j + m] for m in range(4)])      # (4, n, d)
        C = np.einsum("ab,bnd->and", M_BSPLINE, G)               # coefficients of u^3..1
        return shape, t, u, C

    def evaluate(self, t) -> np.ndarray:
        """Values at ``t`` -> ``t.shape + (d,)``; held outside the key range."""
        shape, _, u, C = self._geometry(t, "right")
        out = ((C[0] * u[:, None] + C[1]) * u[:, None] + C[2]) * u[:, None] + C[3]
        return out.reshape(shape + (self.dim,))

    __call__ = evaluate

    def derivative(self, t, side: str = "right") -> np.ndarray:
        """d value / d t -> ``t.shape + (d,)``; zero on the held extrapolation."""
        shape, tt, u, C = self._geometry(t, side)
        out = ((3 * C[0] * u[:, None] + 2 * C[1]) * u[:, None] + C[2]) / self.step
        before, after = _outside(self.times, tt, side)
        out[before | after] = 0.0
        return out.reshape(shape + (self.dim,))


class EasedCurve(_Keyed):
    """Keys joined by a distance-time easing ``f`` (Blender's easing interpolation modes).

    ``v(t) = v_i + (v_{i+1} - v_i) f((t - t_i) / h_i)`` with ``f`` from
    :mod:`pipeline.animation.easing` (``f(0) = 0``, ``f(1) = 1``).  Not a cubic: baked to samples.
    """

    def __init__(self, times, values, ease: "_easing.DistanceTime"):
        self.times = _as_times(times)
        self.values = _as_values(values, self.times.size)
        self.ease = ease

    def evaluate(self, t) -> np.ndarray:
        """Values at ``t`` -> ``t.shape + (d,)``."""
        t = np.asarray(t, dtype=np.float64)
        shape, t = t.shape, t.reshape(-1)
        if self.times.size == 1:
            return np.broadcast_to(self.values[0], shape + (self.dim,)).copy()
        i = _locate(self.times, t, "right")
        u = np.clip((t - self.times[i]) / (self.times[i + 1] - self.times[i]), 0.0, 1.0)
        out = self.values[i] + self.ease(u)[:, None] * (self.values[i + 1] - self.values[i])
        before, after = _outside(self.times, t, "right")
        out[before], out[after] = self.values[0], self.values[-1]
        return out.reshape(shape + (self.dim,))

    __call__ = evaluate

    def derivative(self, t, side: str = "right") -> np.ndarray:
        """d value / d t -> ``t.shape + (d,)``."""
        t = np.asarray(t, dtype=np.float64)
        shape, t = t.shape, t.reshape(-1)
        if self.times.size == 1:
            return np.zeros(shape + (self.dim,))
        i = _locate(self.times, t, side)
        h = self.times[i + 1] - self.times[i]
        u = np.clip((t - self.times[i]) / h, 0.0, 1.0)
        out = (self.ease.speed(u) / h)[:, None] * (self.values[i + 1] - self.values[i])
        before, after = _outside(self.times, t, side)
        out[before | after] = 0.0
        return out.reshape(shape + (self.dim,))


# ---------------------------------------------------------------------------------------------
# Constructors
# ---------------------------------------------------------------------------------------------

def constant(times, values) -> KeyCurve:
    """Step curve: each key's value held until the next key (Ts ``InterpHeld``)."""
    t = _as_times(times)
    return KeyCurve(t, values, interp=HELD)


def linear(times, values) -> KeyCurve:
    """Piecewise linear through the keys (Ts ``InterpLinear``)."""
    t = _as_times(times)
    return KeyCurve(t, values, interp=LINEAR)


def hermite(times, values, slopes, slopes_in=None) -> KeyCurve:
    """Cubic Hermite through the keys with given tangents (``M_H``).

    slopes : (k,) or (k, d), d value / d time leaving each key; ``slopes_in`` (same shape,
    default ``slopes``) arriving.  Unequal in/out slopes give a tangent break (C0 only).
    """
    return KeyCurve(times, values, slopes_in=slopes_in if slopes_in is not None else slopes,
                    slopes_out=slopes, interp=CURVE)


def bezier(times, values, left, right) -> KeyCurve:
    """Blender-style Bézier keys: each key has absolute handles in (time, value) space.

    times : (k,), values : (k, d), left / right : (k, 1 + d) handle points ``(time, value...)``
    before / after each key (Blender's ``handle_left`` / ``handle_right``).  A segment is the
    2-D Bézier ``key_i, right_i, left_{i+1}, key_{i+1}``: tangent ``3 (p1 - p0)`` at the start and
    ``3 (p3 - p2)`` at the end (slides, "Bezier").  C1 at a key only when its two handles are
    collinear with it and equally long in time.  Handles at 1/3 and 2/3 of the interval make time
    linear in u (the matrix form ``M_B``); otherwise the curve is Ts's ``Bezier`` curve type.
    """
    t = _as_times(times)
    v = _as_values(values, t.size)
    L = np.asarray(left, dtype=np.float64).reshape(t.size, -1)
    R = np.asarray(right, dtype=np.float64).reshape(t.size, -1)
    if L.shape[1] != 1 + v.shape[1] or R.shape[1] != 1 + v.shape[1]:
        raise ValueError(f"handles must have shape ({t.size}, {1 + v.shape[1]})")
    w_in, w_out = t - L[:, 0], R[:, 0] - t
    if t.size > 1 and (np.any(w_in[1:] <= 0) or np.any(w_out[:-1] <= 0)):
        raise ValueError("left handles must precede and right handles follow their key in time")
    w_in = np.where(w_in > 0, w_in, 1.0)        # unused outer handles: any positive width
    w_out = np.where(w_out > 0, w_out, 1.0)
    s_in = (v - L[:, 1:]) / w_in[:, None]
    s_out = (R[:, 1:] - v) / w_out[:, None]
    return KeyCurve(t, v, slopes_in=s_in, slopes_out=s_out, widths_in=w_in, widths_out=w_out,
                    interp=CURVE)


def _chained_polygon(points, times, problem: str):
    """Validate a chained-cubic polygon ``(3n+1, d)`` and its key times ``(n+1,)``.

    Returns ``P (3n+1, d) float64``, ``n``, ``t (n+1,) float64`` (default ``0..n``).
    """
    P = np.asarray(points, dtype=np.float64)
    P = P[:, None] if P.ndim == 1 else P
    if P.ndim != 2 or (P.shape[0] - 1) % 3 or P.shape[0] < 4:
        raise ValueError(problem)
    n = (P.shape[0] - 1) // 3
    t = np.arange(n + 1, dtype=np.float64) if times is None else _as_times(times)
    if t.size != n + 1:
        raise ValueError(f"need {n + 1} key times for {P.shape[0]} points")
    return P, n, t


def bezier_polygon(control, times=None) -> KeyCurve:
    """Chained cubic Bézier from a control polygon ``control : (3n+1, d)`` (``M_B`` per segment).

    Keys are ``control[0::3]`` at ``times : (n+1,)`` (default ``0..n``); the inner control points
    sit at 1/3 and 2/3 of each interval, so time (or the path parameter) is linear in u and
    slope = ``3 (p1 - p0) / h``.  Used for paths and for keys given as a Bézier polygon.
    """
    P, n, t = _chained_polygon(control, times, "a Bezier polygon has 3n+1 control points, n >= 1")
    h = np.diff(t)[:, None]
    s_out = np.empty((n + 1, P.shape[1]))
    s_in = np.empty_like(s_out)
    s_out[:-1] = 3 * (P[1:-1:3] - P[0:-1:3]) / h
    s_in[1:] = 3 * (P[3::3] - P[2::3]) / h
    s_out[-1], s_in[0] = s_in[-1], s_out[0]
    return KeyCurve(t, P[0::3], slopes_in=s_in, slopes_out=s_out, interp=CURVE)


def interpolating_cubic(points, times=None) -> KeyCurve:
    """Cubics through 4 points at u = 0, 1/3, 2/3, 1 (``M_INTERPOLATING``), chained.

    points : (3n+1, d); segment j passes through ``points[3j : 3j+4]``; keys are
    ``points[0::3]`` at ``times : (n+1,)`` (default ``0..n``).  C0 only at the joins (slides).
    Exact as a Hermite: ``p'(0) = c_1`` and ``p'(1) = 3 c_3 + 2 c_2 + c_1`` from ``M_I G``.
    """
    P, n, t = _chained_polygon(points, times, "need 3n+1 points, n >= 1")
    G = np.stack([P[3 * j:3 * j + 4] for j in range(n)])            # (n, 4, d)
    C = np.einsum("ab,nbd->nad", M_INTERPOLATING, G)                 # u^3, u^2, u, 1
    h = np.diff(t)[:, None]
    s_out = np.empty((n + 1, P.shape[1]))
    s_in = np.empty_like(s_out)
    s_out[:-1] = C[:, 2] / h
    s_in[1:] = (3 * C[:, 0] + 2 * C[:, 1] + C[:, 2]) / h
    s_out[-1], s_in[0] = s_in[-1], s_out[0]
    return KeyCurve(t, P[0::3], slopes_in=s_in, slopes_out=s_out, interp=CURVE)


_ALPHA = {"uniform": 0.0, "centripetal": 0.5, "chordal": 1.0, "chord": 1.0}


def parameter_knots(points, parameterization="centripetal") -> np.ndarray:
    """Knot sequence ``(k,)`` for points ``(k, d)``: ``t_{i+1} - t_i = |p_{i+1} - p_i|^alpha``.

    ``alpha`` = 0 uniform, 1/2 centripetal (no cusps or self-intersections within a segment,
    Yuksel et al. 2009), 1 chord-length; a float is taken as ``alpha`` (seed-systems.md §A).
    """
    P = np.asarray(points, dtype=np.float64)
    P = P[:, None] if P.ndim == 1 else P
    alpha = _ALPHA[parameterization] if isinstance(parameterization, str) else float(parameterization)
    if alpha == 0.0:
        return np.arange(P.shape[0], dtype=np.float64)
    chord = np.linalg.norm(np.diff(P, axis=0), axis=1)
    if np.any(chord <= 0):
        raise ValueError("consecutive points coincide: chordal/centripetal knots are undefined")
    return np.concatenate([[0.0], np.cumsum(chord**alpha)])


def _phantoms(s: np.ndarray, P: np.ndarray):
    """Mirror a phantom key through each end: ``p_{-1} = 2 p_0 - p_1``, likewise in parameter."""
    s_ext = np.concatenate([[2 * s[0] - s[1]], s, [2 * s[-1] - s[-2]]])
    P_ext = np.concatenate([2 * P[:1] - P[1:2], P, 2 * P[-1:] - P[-2:-1]])
    return s_ext, P_ext


def cardinal(times, values, tension=0.0, parameterization="time", ends="mirror") -> KeyCurve:
    """Cardinal spline: ``m_k = (1 - q)(p_{k+1} - p_{k-1}) / (s_{k+1} - s_{k-1})``.

    times : (k,), values : (k, d); ``tension`` q in [-1, 1] (scalar or (k,)).  The parameter
    knots ``s`` are the key times for ``parameterization='time'`` (C1 in time, the CCM paper's
    formula with t = key time), or ``'uniform'``, ``'centripetal'``, ``'chordal'`` / alpha from
    the values (:func:`parameter_knots`).  In the latter case segment ``[s_k, s_{k+1}]`` is mapped
    linearly onto ``[t_k, t_{k+1}]``, so the time slopes are ``m_k Δs / Δt`` on each side: a
    tangent break in time where the two ratios differ (uniform knots with uneven key spacing).
    The end keys see mirrored phantom keys (``ends='mirror'``: one-sided difference slopes) or
    get zero slope (``ends='flat'``).  ``q = 0`` with uniform knots is Catmull-Rom.
    """
    t = _as_times(times)
    P = _as_values(values, t.size)
    k = t.size
    if k == 1:
        return KeyCurve(t, P, interp=CURVE)
    q = _per_key(tension, k, "tension")
    s = t.copy() if parameterization == "time" else parameter_knots(P, parameterization)
    s_ext, P_ext = _phantoms(s, P)
    m = (1 - q)[:, None] * (P_ext[2:] - P_ext[:-2]) / (s_ext[2:] - s_ext[:-2])[:, None]
    if ends == "flat":
        m[0] = m[-1] = 0.0
    elif ends != "mirror":
        raise ValueError("ends must be 'mirror' or 'flat'")
    ratio = np.diff(s) / np.diff(t)                                # ds/dt per segment
    r_out = np.concatenate([ratio, ratio[-1:]])
    r_in = np.concatenate([ratio[:1], ratio])
    return KeyCurve(t, P, slopes_in=m * r_in[:, None], slopes_out=m * r_out[:, None], interp=CURVE)


def catmull_rom(times, values, parameterization="time", ends="mirror") -> KeyCurve:
    """Catmull-Rom: cardinal with q = 0, tangent ``(p_{i+1} - p_{i-1}) / 2`` per unit u (``M_CR``)."""
    return cardinal(times, values, 0.0, parameterization, ends)


def kochanek_bartels(times, values, tension=0.0, continuity=0.0, bias=0.0, uneven=True,
                     ends="mirror") -> KeyCurve:
    """Kochanek-Bartels (TCB) spline (seed-systems.md §A; Kochanek & Bartels 1984).

    With ``d0 = p_i - p_{i-1}``, ``d1 = p_{i+1} - p_i`` (tangents per unit u of a segment)::

        in_i  = ((1-T)(1-C)(1+B) d0 + (1-T)(1+C)(1-B) d1) / 2
        out_i = ((1-T)(1+C)(1+B) d0 + (1-T)(1-C)(1-B) d1) / 2

    T, C, B scalars or (k,).  Uneven key spacing (``uneven=True``, the paper's adjustment): the
    incoming tangent is scaled by ``2 N_{i-1} / (N_{i-1} + N_i)`` and the outgoing by
    ``2 N_i / (N_{i-1} + N_i)`` (``N`` = interval lengths), so the time slopes are
    ``2 in_i / (N_{i-1} + N_i)`` and ``2 out_i / (N_{i-1} + N_i)``: C1 in time when C = 0, and
    T = C = B = 0 is Catmull-Rom with time knots for any spacing.  ``uneven=False`` keeps the
    per-segment tangents (slopes ``in_i / N_{i-1}``, ``out_i / N_i``).  C != 0 breaks the tangent.
    """
    t = _as_times(times)
    P = _as_values(values, t.size)
    k = t.size
    if k == 1:
        return KeyCurve(t, P, interp=CURVE)
    T, C, B = (_per_key(x, k, n)[:, None] for x, n in
               ((tension, "tension"), (continuity, "continuity"), (bias, "bias")))
    s_ext, P_ext = _phantoms(t, P)
    d0 = P_ext[1:-1] - P_ext[:-2]
    d1 = P_ext[2:] - P_ext[1:-1]
    t_in = ((1 - T) * (1 - C) * (1 + B) * d0 + (1 - T) * (1 + C) * (1 - B) * d1) / 2
    t_out = ((1 - T) * (1 + C) * (1 + B) * d0 + (1 - T) * (1 - C) * (1 - B) * d1) / 2
    N = np.diff(s_ext)                                  # N_{-1} .. N_{k-1}, phantoms mirrored
    N_prev, N_next = N[:-1, None], N[1:, None]
    if uneven:
        s_in = 2 * t_in / (N_prev + N_next)
        s_out = 2 * t_out / (N_prev + N_next)
    else:
        s_in, s_out = t_in / N_prev, t_out / N_next
    if ends == "flat":
        s_in[0] = s_out[0] = s_in[-1] = s_out[-1] = 0.0
    elif ends != "mirror":
        raise ValueError("ends must be 'mirror' or 'flat'")
    return KeyCurve(t, P, slopes_in=s_in, slopes_out=s_out, interp=CURVE)


def bspline(times, control) -> BSplineCurve:
    """Uniform cubic B-spline with control points at ``times`` (see :class:`BSplineCurve`)."""
    return BSplineCurve(times, control)


def eased(times, values, family="sine", mode="in_out", **params) -> EasedCurve:
    """Keys joined by a Blender easing preset (:func:`pipeline.animation.easing.preset`)."""
    return EasedCurve(times, values, _easing.preset(family, mode, **params))


#: Interpolation names accepted by :func:`make` (besides the easing families).
KINDS = ("constant", "linear", "hermite", "bezier", "bezier_polygon", "interpolating",
         "catmull_rom", "cardinal", "kochanek_bartels", "tcb", "bspline")


def make(times, values, interp="linear", **params):
    """Build a key curve by interpolation name: one of :data:`KINDS` or an easing family.

    ``params`` go to the named constructor (``slopes`` for hermite, ``left``/``right`` for bezier,
    ``tension``/``parameterization`` for cardinal, ``tension``/``continuity``/``bias`` for tcb,
    ``mode`` and preset parameters for easing families such as ``'cubic'``).
    """
    kind = interp.lower()
    if kind == "constant":
        return constant(times, values)
    if kind == "linear":
        return linear(times, values)
    if kind == "hermite":
        return hermite(times, values, **params)
    if kind == "bezier":
        return bezier(times, values, **params)
    if kind == "bezier_polygon":
        return bezier_polygon(values, times, **params)
    if kind == "interpolating":
        return interpolating_cubic(values, times, **params)
    if kind == "catmull_rom":
        return catmull_rom(times, values, **params)
    if kind == "cardinal":
        return cardinal(times, values, **params)
    if kind in ("kochanek_bartels", "tcb"):
        return kochanek_bartels(times, values, **params)
    if kind == "bspline":
        return bspline(times, values, **params)
    if kind in _easing.FAMILIES:
        return eased(times, values, kind, **params)
    raise ValueError(f"unknown interpolation {interp!r}; expected one of {KINDS + _easing.FAMILIES}")
