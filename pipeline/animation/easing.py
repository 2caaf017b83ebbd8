"""Distance-time functions ``s = h(t)`` and Blender's easing presets (seed-systems.md §B).

A distance-time function maps normalised time ``t in [0, 1]`` to normalised distance
``s in [0, 1]``: monotonic (for the speed-control ones), continuous, ``h(0) = 0``, ``h(1) = 1``
(slides, "Specification of distance-time function").  Each is a :class:`DistanceTime` with the
value ``h(t)`` and the speed ``h'(t)``, both vectorised over ``t : (n,) float64`` and clamped to
``[0, 1]`` outside.

* Speed control for motion along a path: :func:`constant_speed`, :func:`sine_ease`
  (``(1 - cos pi t) / 2``), :func:`sine_linear_sine` (sine segments joined to a constant-speed
  middle), :func:`parabolic_ease` (constant acceleration), :func:`velocity_keys` (a velocity curve
  normalised so its area -- the distance -- is 1).  These follow Parent, *Computer Animation*, §3.2,
  which the slides restate.
* Blender's easing interpolation presets (:func:`preset`, families :data:`FAMILIES`, modes
  :data:`MODES`) are Robert Penner's easing equations, the ones Blender's ``easing.cc`` implements.
  ``out(t) = 1 - in(1 - t)`` and ``in_out`` joins ``in`` and ``out`` at ``t = 1/2``.  ``expo`` and
  ``elastic`` are affinely rescaled so that they hit 0 and 1 exactly at the ends (Penner's forms
  miss by about ``2^-10`` and special-case the end points, which leaves a jump; Blender rescales
  ``expo`` the same way and blends ``elastic``'s start instead, so ``elastic`` is close to, not
  identical with, Blender's).  ``back`` and ``elastic`` overshoot [0, 1] on purpose.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

__all__ = [
    "DistanceTime", "FAMILIES", "MODES", "preset",
    "constant_speed", "sine_ease", "sine_linear_sine", "parabolic_ease", "velocity_keys",
]

#: Blender's easing interpolation families (F-curve ``interpolation`` values, lower case).
FAMILIES = ("sine", "quad", "cubic", "quart", "quint", "expo", "circ", "back", "bounce", "elastic")
#: Easing modes; ``auto`` is Blender's rule: ease out for back/bounce/elastic, ease in otherwise.
MODES = ("in", "out", "in_out", "auto")


class DistanceTime:
    """A distance-time function: ``self(t)`` = h(t), ``self.speed(t)`` = h'(t).

    h, dh : callables mapping ``(n,) float64`` in [0, 1] to ``(n,) float64``.  Inputs are clamped
    to [0, 1] (the motion holds before its start and after its end), where the speed is 0.
    """

    def __init__(self, h: Callable, dh: Callable, name: str):
        self._h, self._dh, self.name = h, dh, name

    def __call__(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        return self._h(np.clip(t, 0.0, 1.0))

    def speed(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        v = self._dh(np.clip(t, 0.0, 1.0))
        return np.where((t < 0) | (t > 1), 0.0, v)

    def __repr__(self) -> str:
        return f"DistanceTime({self.name})"


# ---------------------------------------------------------------------------------------------
# Speed control (slides "Speed control", "Ease-in ease-out")
# ---------------------------------------------------------------------------------------------

def constant_speed() -> DistanceTime:
    """``h(t) = t``: equal arc length per frame."""
    return DistanceTime(lambda t: t.copy(), lambda t: np.ones_like(t), "constant_speed")


def sine_ease() -> DistanceTime:
    """Sinusoidal ease-in/ease-out ``h(t) = (1 - cos(pi t)) / 2``; zero speed at both ends."""
    return DistanceTime(lambda t: (1 - np.cos(np.pi * t)) / 2,
                        lambda t: np.pi / 2 * np.sin(np.pi * t), "sine_ease")


def sine_linear_sine(k1: float = 0.25, k2: float = 0.75) -> DistanceTime:
    """Sine ease-in on [0, k1], constant speed on [k1, k2], sine ease-out on [k2, 1].

    Parent's ``ease(t)``: quarter sine waves whose slopes match the linear middle, normalised by
    ``f = 2 k1 / pi + (k2 - k1) + 2 (1 - k2) / pi`` so that ``h(1) = 1``; C1, zero end speeds.
    """
    if not 0 < k1 <= k2 < 1:
        raise ValueError("need 0 < k1 <= k2 < 1")
    f = 2 * k1 / np.pi + (k2 - k1) + 2 * (1 - k2) / np.pi

    def h(t):
        a = k1 * 2 / np.pi * (np.sin(t / k1 * np.pi / 2 - np.pi / 2) + 1)
        b = 2 * k1 / np.pi + (t - k1)
        c = 2 * k1 / np.pi + (k2 - k1) + (1 - k2) * 2 / np.pi * np.sin((t - k2) / (1 - k2) * np.pi / 2)
        return np.where(t < k1, a, np.where(t <= k2, b, c)) / f

    def dh(t):
        a = np.cos(t / k1 * np.pi / 2 - np.pi / 2)
        c = np.cos((t - k2) / (1 - k2) * np.pi / 2)
        return np.where(t < k1, a, np.where(t <= k2, 1.0, c)) / f

    return DistanceTime(h, dh, f"sine_linear_sine({k1}, {k2})")


def parabolic_ease(t1: float = 0.25, t2: float = 0.75) -> DistanceTime:
    """Constant acceleration on [0, t1], constant speed v0 on [t1, t2], constant deceleration after.

    The area under the trapezoidal velocity curve is 1, so ``v0 = 2 / (1 + t2 - t1)``.
    """
    if not 0 < t1 <= t2 < 1:
        raise ValueError("need 0 < t1 <= t2 < 1")
    v0 = 2.0 / (1.0 + t2 - t1)

    def h(t):
        a = v0 * t**2 / (2 * t1)
        b = v0 * t1 / 2 + v0 * (t - t1)
        tau = t - t2
        c = v0 * t1 / 2 + v0 * (t2 - t1) + v0 * tau - v0 * tau**2 / (2 * (1 - t2))
        return np.where(t < t1, a, np.where(t <= t2, b, c))

    def dh(t):
        return np.where(t < t1, v0 * t / t1, np.where(t <= t2, v0, v0 * (1 - (t - t2) / (1 - t2))))

    return DistanceTime(h, dh, f"parabolic_ease({t1}, {t2})")


def velocity_keys(times, speeds, mode: str = "scale") -> DistanceTime:
    """Distance from a piecewise-linear velocity curve whose area is made 1 (slides).

    times : (k,) float64 from 0 to 1 (strictly increasing), speeds : (k,) float64 >= 0.  The
    area is the distance travelled, so it must be 1: ``mode='scale'`` multiplies the curve by
    ``1 / area`` (keeps its shape and zeros); ``mode='shift'`` floats it up or down by
    ``1 - area`` (the slides' description; can change the values the animator set, and is rejected
    if it makes a speed negative).  h is the exact piecewise-quadratic integral.
    """
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    v = np.asarray(speeds, dtype=np.float64).reshape(-1)
    if t.size < 2 or t.size != v.size:
        raise ValueError("need matching times and speeds, at least two keys")
    if abs(t[0]) > 1e-12 or abs(t[-1] - 1) > 1e-12 or np.any(np.diff(t) <= 0):
        raise ValueError("velocity key times must increase from 0 to 1")
    if np.any(v < 0) or not np.all(np.isfinite(v)):
        raise ValueError("speeds must be finite and non-negative (motion only moves forward)")
    dt = np.diff(t)
    area = float(np.sum((v[:-1] + v[1:]) / 2 * dt))
    if mode == "scale":
        if area <= 0:
            raise ValueError("velocity curve has zero area")
        v = v / area
    elif mode == "shift":
        v = v + (1.0 - area)
        if np.any(v < -1e-15):
            raise ValueError("shifting the velocity curve to area 1 makes a speed negative")
        v = np.maximum(v, 0.0)
    else:
        raise ValueError("mode must be 'scale' or 'shift'")
    H = np.concatenate([[0.0], np.cumsum((v[:-1] + v[1:]) / 2 * dt)])

    def _seg(x):
        i = np.clip(np.searchsorted(t, x, side="right") - 1, 0, t.size - 2)
        return i, x - t[i]

    def h(x):
        i, tau = _seg(x)
        return H[i] + v[i] * tau + (v[i + 1] - v[i]) * tau**2 / (2 * dt[i])

    def dh(x):
        i, tau = _seg(x)
        return v[i] + (v[i + 1] - v[i]) * tau / dt[i]

    return DistanceTime(h, dh, f"velocity_keys({mode})")


# ---------------------------------------------------------------------------------------------
# Easing presets (Penner's equations, as in Blender's easing interpolation)
# ---------------------------------------------------------------------------------------------

def _bounce_out(t):
    """Penner's bounce: four parabolic arcs, 7.5625 = 121/16 and breaks at 1, 2, 2.5 over 2.75."""
    a = 7.5625
    t1 = t - 1.5 / 2.75
    t2 = t - 2.25 / 2.75
    t3 = t - 2.625 / 2.75
    return np.where(t < 1 / 2.75, a * t * t,
           np.where(t < 2 / 2.75, a * t1 * t1 + 0.75,
           np.where(t < 2.5 / 2.75, a * t2 * t2 + 0.9375, a * t3 * t3 + 0.984375)))


def _dbounce_out(t):
    a = 7.5625
    return 2 * a * np.where(t < 1 / 2.75, t,
                   np.where(t < 2 / 2.75, t - 1.5 / 2.75,
                   np.where(t < 2.5 / 2.75, t - 2.25 / 2.75, t - 2.625 / 2.75)))


def _ease_in_pair(family: str, overshoot: float, amplitude: float, period: float):
    """The ``in`` form f(t) and f'(t) of a family, as numpy callables on [0, 1]."""
    if family == "sine":
        return (lambda t: 1 - np.cos(t * np.pi / 2), lambda t: np.pi / 2 * np.sin(t * np.pi / 2))
    powers = {"quad": 2, "cubic": 3, "quart": 4, "quint": 5}
    if family in powers:
        p = powers[family]
        return (lambda t: t**p, lambda t: p * t ** (p - 1))
    if family == "expo":
        lo = 2.0**-10
        return (lambda t: (2.0 ** (10 * (t - 1)) - lo) / (1 - lo),
                lambda t: 10 * math.log(2) * 2.0 ** (10 * (t - 1)) / (1 - lo))
    if family == "circ":
        def dcirc(t):
            with np.errstate(divide="ignore"):
                return np.where(t < 1, t / np.sqrt(np.maximum(1 - t * t, 0.0)), np.inf)
        return (lambda t: 1 - np.sqrt(np.maximum(1 - t * t, 0.0)), dcirc)
    if family == "back":
        o = overshoot
        return (lambda t: t * t * ((o + 1) * t - o), lambda t: 3 * (o + 1) * t * t - 2 * o * t)
    if family == "bounce":
        return (lambda t: 1 - _bounce_out(1 - t), lambda t: _dbounce_out(1 - t))
    if family == "elastic":
        # Penner: out(t) = a 2^(-10 t) sin((t - s) 2 pi / p) + 1, s = p asin(1/a) / (2 pi),
        # which is 0 at t = 0; divide by its value at t = 1 so out(1) = 1 exactly.
        a = max(float(amplitude), 1.0)
        p = float(period)
        s = p / (2 * np.pi) * math.asin(1 / a)
        w = 2 * np.pi / p
        g1 = a * 2.0**-10 * math.sin((1 - s) * w) + 1

        def out(t):
            return (a * 2.0 ** (-10 * t) * np.sin((t - s) * w) + 1) / g1

        def dout(t):
            e = a * 2.0 ** (-10 * t)
            return e * (w * np.cos((t - s) * w) - 10 * math.log(2) * np.sin((t - s) * w)) / g1

        return (lambda t: 1 - out(1 - t), lambda t: dout(1 - t))
    raise ValueError(f"unknown easing family {family!r}; expected one of {FAMILIES}")


def preset(family: str, mode: str = "in_out", overshoot: float = 1.70158, amplitude: float = 1.0,
           period: float = 0.3) -> DistanceTime:
    """Blender easing preset as a distance-time function.

    family : one of :data:`FAMILIES`; mode : ``'in'``, ``'out'``, ``'in_out'`` or ``'auto'``.
    ``overshoot`` (back, Blender's default 1.70158), ``amplitude`` (elastic, >= 1) and ``period``
    (elastic, in units of the normalised segment, Penner's 0.3) shape the dynamic families.
    """
    family = family.lower()
    mode = mode.lower().replace("ease_", "")
    if mode == "auto":
        mode = "out" if family in ("back", "bounce", "elastic") else "in"
    if mode not in ("in", "out", "in_out"):
        raise ValueError(f"unknown easing mode {mode!r}; expected one of {MODES}")
    f, df = _ease_in_pair(family, overshoot, amplitude, period)
    if mode == "in":
        h, dh = f, df
    elif mode == "out":
        def h(t):
            return 1 - f(1 - t)

        def dh(t):
            return df(1 - t)
    else:
        def h(t):
            return np.where(t < 0.5, f(2 * t) / 2, 1 - f(2 - 2 * t) / 2)

        def dh(t):
            return np.where(t < 0.5, df(np.minimum(2 * t, 1.0)), df(np.minimum(2 - 2 * t, 1.0)))
    return DistanceTime(h, dh, f"{family}_{mode}")
