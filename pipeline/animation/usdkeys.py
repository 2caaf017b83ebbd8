"""Writing key curves to USD: native ``Ts`` splines where exact, baked time samples elsewhere.

A :class:`~pipeline.animation.curves.KeyCurve` *is* a Ts knot list (time, value, pre/post slope,
pre/post tangent width, interpolation to the next knot), so :func:`to_ts_spline` copies it and
``attr.Get(t)`` then equals ``curve.evaluate(t)`` to rounding at every time, not only at frames:

* constant, linear -> ``Ts.InterpHeld``, ``Ts.InterpLinear``;
* Hermite, Catmull-Rom, cardinal, Kochanek-Bartels, Bézier polygon, interpolating cubic ->
  ``Ts.CurveTypeHermite`` (tangent widths fixed at 1/3 of the interval; slopes are d value /
  d time, already converted from per-segment tangents by the constructors);
* Bézier keys with free handles -> ``Ts.CurveTypeBezier`` with the handles' time extents as
  widths and their value/time ratios as slopes.

USD splines exist only on scalar ``double`` / ``float`` attributes (usd-core 26.11), hence the
single-axis ops (``xformOp:translateX`` ...).  The uniform B-spline and the easing presets are not
cubic Hermite/Bézier in time, so they are baked: one time sample per integer frame (USD
interpolates linearly between samples, so they match the curve at the frames only).  Path
following (:func:`follow_path`) is baked too: it writes a ``double3`` translate and a ``quatd``
orient op per frame.

Ops are appended to ``xformOpOrder`` in the order they are first keyed (first = outermost), so a
scene that keys translate, then rotate, then scale gets the usual ``T R S``.  An op that already
exists under the same name is re-keyed in place.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from pxr import Gf, Sdf, Ts, Usd, UsdGeom, Vt

from . import curves as _curves
from . import easing as _easing

if TYPE_CHECKING:
    from . import paths as _paths

__all__ = [
    "is_spline_representable", "to_ts_spline", "default_frames", "bake", "write_curve",
    "xform_op", "key_op", "key_translate", "key_rotate", "key_scale", "follow_path",
]

_TS_INTERP = {_curves.HELD: Ts.InterpHeld, _curves.LINEAR: Ts.InterpLinear,
              _curves.CURVE: Ts.InterpCurve}
_SCALAR = {"double": Vt.Double, "float": Vt.Float}
_KINDS = ("translate", "rotate", "scale")


def is_spline_representable(curve) -> bool:
    """True for curves that map exactly onto Ts knots (every :class:`KeyCurve`)."""
    return isinstance(curve, _curves.KeyCurve)


def to_ts_spline(curve: "_curves.KeyCurve", component: int = 0, value_type: str = "double") -> Ts.Spline:
    """The Ts spline of one component of a key curve (``value_type`` 'double' or 'float').

    Curve type ``Hermite`` when every curved segment has standard 1/3 widths, else ``Bezier``
    with explicit widths.  Pre/post extrapolation stay ``Held``, like the curve objects.
    Raises if Ts's anti-regression would have altered a tangent (the constructors reject
    regressive handles, so this guards the mapping, not the user).
    """
    if not is_spline_representable(curve):
        raise TypeError(f"{type(curve).__name__} is not representable as a Ts spline; bake it")
    if value_type not in _SCALAR:
        raise ValueError("Ts splines take 'double' or 'float' values")
    hermite = curve.standard_widths
    spline = Ts.Spline(value_type)
    spline.SetCurveType(Ts.CurveTypeHermite if hermite else Ts.CurveTypeBezier)
    k = curve.times.size
    c = int(component)
    with Ts.AntiRegressionAuthoringSelector(Ts.AntiRegressionNone):
        for i in range(k):
            knot = Ts.Knot(value_type)
            knot.SetTime(float(curve.times[i]))
            knot.SetValue(float(curve.values[i, c]))
            knot.SetNextInterpolation(_TS_INTERP[int(curve.interp[i])] if i < k - 1 else Ts.InterpHeld)
            knot.SetPreTanSlope(float(curve.slopes_in[i, c]))
            knot.SetPostTanSlope(float(curve.slopes_out[i, c]))
            if not hermite:
                knot.SetPreTanWidth(float(curve.widths_in[i]))
                knot.SetPostTanWidth(float(curve.widths_out[i]))
            spline.SetKnot(knot)
    if not hermite:
        for i, knot in enumerate(spline.GetKnots().values()):
            if (knot.GetPreTanWidth() != float(curve.widths_in[i])
                    or knot.GetPostTanWidth() != float(curve.widths_out[i])):
                raise RuntimeError(f"Ts altered the tangent widths of knot {i}")
    return spline


def default_frames(curve) -> np.ndarray:
    """Integer frames ``(n,) float64`` covering the curve's key range."""
    t0, t1 = curve.domain
    return np.arange(math.ceil(t0 - 1e-9), math.floor(t1 + 1e-9) + 1, dtype=np.float64)


def _layer_and_path(attr: Usd.Attribute):
    target = attr.GetStage().GetEditTarget()
    return target.GetLayer(), target.MapToSpecPath(attr.GetPath())


def _write_samples(attr: Usd.Attribute, frames: np.ndarray, values: list) -> None:
    """Replace the attribute's opinion in the edit target by time samples (Sdf, in one block)."""
    attr.Clear()
    layer, path = _layer_and_path(attr)
    if layer.GetAttributeAtPath(path) is None:
        attr.Set(values[0], Usd.TimeCode(float(frames[0])))
    with Sdf.ChangeBlock():
        for f, v in zip(frames, values):
            layer.SetTimeSample(path, float(f), v)


def bake(attr: Usd.Attribute, curve, component: int = 0, frames=None) -> np.ndarray:
    """Write ``curve``'s component as one time sample per frame on a scalar attribute.

    frames : (n,) float64, default :func:`default_frames`.  Returns the values written ``(n,)``.
    """
    frames = default_frames(curve) if frames is None else np.asarray(frames, dtype=np.float64).reshape(-1)
    type_name = str(attr.GetTypeName())
    if type_name not in _SCALAR:
        raise TypeError(f"{attr.GetPath()}: expected a scalar double/float attribute, got {type_name}")
    vals = curve.evaluate(frames)[:, int(component)]
    wrap = _SCALAR[type_name]
    _write_samples(attr, frames, [wrap(float(v)) for v in vals])
    return vals


def write_curve(attr: Usd.Attribute, curve, component: int = 0, frames=None) -> str:
    """Key a scalar attribute with one component of a curve; returns ``'spline'`` or ``'samples'``.

    A Ts spline when the curve is representable (``frames`` is then unused), else baked samples.
    Any opinion the edit target already held on the attribute is replaced.
    """
    type_name = str(attr.GetTypeName())
    if is_spline_representable(curve) and type_name in _SCALAR:
        spline = to_ts_spline(curve, component, type_name)
        attr.Clear()
        if not attr.SetSpline(spline):
            raise RuntimeError(f"{attr.GetPath()}: SetSpline failed")
        return "spline"
    bake(attr, curve, component, frames)
    return "samples"


def xform_op(prim, kind: str, axis: str, suffix: str | None = None) -> UsdGeom.XformOp:
    """Get or append the single-axis op ``xformOp:{kind}{AXIS}[:suffix]`` (double precision).

    kind : 'translate', 'rotate' or 'scale'; axis : 'x', 'y' or 'z'.
    """
    xf = UsdGeom.Xformable(prim)
    if not xf:
        raise TypeError(f"{getattr(prim, 'GetPath', lambda: prim)()} is not Xformable")
    if kind not in _KINDS or axis.lower() not in "xyz" or len(axis) != 1:
        raise ValueError(f"bad op {kind!r} / axis {axis!r}")
    name = f"xformOp:{kind}{axis.upper()}" + (f":{suffix}" if suffix else "")
    for op in xf.GetOrderedXformOps():
        if op.GetOpName() == name:
            return op
    if xf.GetPrim().HasAttribute(name):
        raise ValueError(f"{xf.GetPath()}.{name} exists but is not in xformOpOrder")
    add = getattr(xf, f"Add{kind.capitalize()}{axis.upper()}Op")
    return add(precision=UsdGeom.XformOp.PrecisionDouble, opSuffix=suffix or "")


def key_op(prim, kind: str, axes: str, curve, frames=None, suffix: str | None = None) -> list:
    """Key single-axis ops of ``kind`` on ``axes`` (e.g. ``'x'``, ``'xyz'``) from a curve of dim ``len(axes)``.

    For ``rotate`` with several axes the rotation order is USD's: ``'xyz'`` applies X first, as
    ``rotateXYZ`` does, so the ops are appended as ``rotateZ, rotateY, rotateX``.  Returns the ops
    in ``axes`` order.
    """
    axes = axes.lower()
    if not axes or any(a not in "xyz" for a in axes) or len(set(axes)) != len(axes):
        raise ValueError(f"axes must be distinct letters of 'xyz', got {axes!r}")
    if curve.dim != len(axes):
        raise ValueError(f"curve has {curve.dim} components for {len(axes)} axes")
    order = axes[::-1] if kind == "rotate" else axes
    ops = {a: xform_op(prim, kind, a, suffix) for a in order}
    for c, a in enumerate(axes):
        write_curve(ops[a].GetAttr(), curve, c, frames)
    return [ops[a] for a in axes]


def key_translate(prim, axes: str, times, values, interp: str = "linear", frames=None,
                  suffix: str | None = None, **params) -> list:
    """Key translation: ``times (k,)``, ``values (k,)`` or ``(k, len(axes))`` in scene units.

    ``interp`` is any name of :func:`curves.make` (``'catmull_rom'``, ``'tcb'``, ``'bspline'``,
    ``'cubic'`` ...) with its ``params``.  With several axes the curve is built on the vector
    values, so chord-length/centripetal knots measure spatial distance.
    """
    return key_op(prim, "translate", axes, _curves.make(times, values, interp, **params), frames, suffix)


def key_rotate(prim, axes: str, times, values, interp: str = "linear", frames=None,
               suffix: str | None = None, **params) -> list:
    """Key Euler rotation in degrees; ``axes='xyz'`` applies X, then Y, then Z (USD order)."""
    return key_op(prim, "rotate", axes, _curves.make(times, values, interp, **params), frames, suffix)


def key_scale(prim, axes: str, times, values, interp: str = "linear", frames=None,
              suffix: str | None = None, **params) -> list:
    """Key per-axis scale factors."""
    return key_op(prim, "scale", axes, _curves.make(times, values, interp, **params), frames, suffix)


def _vector_op(xf: UsdGeom.Xformable, name: str, add) -> UsdGeom.XformOp:
    for op in xf.GetOrderedXformOps():
        if op.GetOpName() == name:
            return op
    return add()


def follow_path(prim, path, frames, timing: "_easing.DistanceTime | None" = None, orient: bool = True,
                forward=(1.0, 0.0, 0.0), up=None, method: str = "gauss",
                suffix: str = "path", table: "_paths.ArcLengthTable | None" = None, **params):
    """Move a prim along a path curve, one time sample per frame.

    path : path curve (``evaluate`` / ``derivative`` / ``domain``, see :mod:`paths`);
    frames : (n,) frame numbers, n >= 2: the motion starts at ``frames[0]`` and ends at
    ``frames[-1]``; normalised time ``(f - f0) / (f1 - f0)`` goes through the distance-time
    function ``timing`` (default constant speed) and the arc-length inverse (``method``).
    Writes ``xformOp:translate:{suffix}`` (double3) and, if ``orient``, ``xformOp:orient:{suffix}``
    (quatd) turning the local ``forward`` axis onto the tangent with ``up`` kept upright
    (default: the stage's ``upAxis``, Y or Z).  Returns ``(translate_op, orient_op or None)``.
    """
    frames = np.asarray(frames, dtype=np.float64).reshape(-1)
    if frames.size < 2 or np.any(np.diff(frames) <= 0):
        raise ValueError("frames must be at least two increasing frame numbers")
    xf = UsdGeom.Xformable(prim)
    if not xf:
        raise TypeError("prim is not Xformable")
    from . import paths as _paths  # here: a scene that only keys transforms never imports the path curves

    t = (frames - frames[0]) / (frames[-1] - frames[0])
    P, T, _, _ = _paths.sample_path(path, t, timing, table, method, **params)
    if P.shape[1] != 3:
        raise ValueError("a path for follow_path must be 3-D")
    dbl = UsdGeom.XformOp.PrecisionDouble
    top = _vector_op(xf, f"xformOp:translate:{suffix}",
                     lambda: xf.AddTranslateOp(precision=dbl, opSuffix=suffix))
    vec = Gf.Vec3f if str(top.GetAttr().GetTypeName()) == "float3" else Gf.Vec3d
    _write_samples(top.GetAttr(), frames, [vec(*map(float, p)) for p in P])
    oop = None
    if orient:
        if up is None:
            up = (0.0, 0.0, 1.0) if UsdGeom.GetStageUpAxis(prim.GetStage()) == UsdGeom.Tokens.z else (0.0, 1.0, 0.0)
        q = _paths.orientations(T, forward, up)
        oop = _vector_op(xf, f"xformOp:orient:{suffix}",
                         lambda: xf.AddOrientOp(precision=dbl, opSuffix=suffix))
        quat, im = ((Gf.Quatf, Gf.Vec3f) if str(oop.GetAttr().GetTypeName()) == "quatf"
                    else (Gf.Quatd, Gf.Vec3d))
        _write_samples(oop.GetAttr(), frames,
                       [quat(float(w), im(float(x), float(y), float(z))) for w, x, y, z in q])
    return top, oop
