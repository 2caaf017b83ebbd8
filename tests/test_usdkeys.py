"""Key curves written into USD: Ts splines equal the project's evaluation; the rest is baked."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from pxr import Gf, Sdf, Ts, Usd, UsdGeom

from pipeline.animation import curves as C
from pipeline.animation import easing as E
from pipeline.animation import paths as P
from pipeline.animation import usdkeys as K

RNG = np.random.default_rng(11)
TIMES = np.array([1.0, 4.0, 5.5, 12.0, 13.0, 24.0])          # uneven key spacing
VALUES = RNG.normal(size=(6, 3)) * np.array([1.0, 5.0, 0.2])


def new_prim(path="/Obj"):
    stage = Usd.Stage.CreateInMemory()
    return stage, UsdGeom.Xform.Define(stage, path).GetPrim()


def query_times(curve, n=1000):
    lo, hi = curve.domain
    t = np.linspace(lo - 2, hi + 2, n - curve.times.size)
    return np.sort(np.concatenate([t, curve.times]))         # include the knots themselves


def bez_handles(times, v):
    wl = np.array([0.5, 2.5, 0.4, 5.0, 0.3, 2.0])
    wr = np.array([2.0, 1.2, 3.0, 0.8, 6.5, 1.0])
    left = np.stack([times - wl, v - 0.7 * wl], 1)
    right = np.stack([times + wr, v + 0.3 * wr * np.sign(np.sin(times))], 1)
    return left, right


SPLINE_CURVES = {
    "constant": lambda: C.constant(TIMES, VALUES[:, 0]),
    "linear": lambda: C.linear(TIMES, VALUES[:, 0]),
    "hermite_broken": lambda: C.hermite(TIMES, VALUES[:, 0], RNG.normal(size=6), slopes_in=RNG.normal(size=6)),
    "bezier_free_handles": lambda: C.bezier(TIMES, VALUES[:, 0], *bez_handles(TIMES, VALUES[:, 0])),
    "bezier_polygon": lambda: C.bezier_polygon(RNG.normal(size=16), np.array([0.0, 3, 4, 10, 12, 30])),
    "interpolating": lambda: C.interpolating_cubic(RNG.normal(size=10), np.array([2.0, 9, 10, 17])),
    "catmull_rom": lambda: C.catmull_rom(TIMES, VALUES[:, 0]),
    "catmull_rom_uniform": lambda: C.catmull_rom(TIMES, VALUES[:, 0], parameterization="uniform"),
    "cardinal_centripetal": lambda: C.cardinal(TIMES, VALUES, -0.5, "centripetal"),
    "cardinal_chordal": lambda: C.cardinal(TIMES, VALUES, 0.3, "chordal"),
    "tcb": lambda: C.kochanek_bartels(TIMES, VALUES, 0.2, -0.6, 0.4),
    "tcb_unscaled": lambda: C.kochanek_bartels(TIMES, VALUES, [0, 0.5, -0.3, 0, 0.1, 0], 0.3, -0.2,
                                               uneven=False),
    "tcb_flat_ends": lambda: C.kochanek_bartels(TIMES, VALUES, 0.1, 0.0, 0.0, ends="flat"),
}


@pytest.mark.parametrize("name", list(SPLINE_CURVES))
def test_spline_evaluates_like_the_curve(name):
    curve = SPLINE_CURVES[name]()
    stage, prim = new_prim()
    xf = UsdGeom.Xformable(prim)
    t = query_times(curve)
    for c in range(curve.dim):
        attr = xf.AddTranslateXOp(precision=UsdGeom.XformOp.PrecisionDouble, opSuffix=f"c{c}").GetAttr()
        assert K.write_curve(attr, curve, c) == "spline"
        assert attr.HasSpline() and attr.GetTimeSamples() == [] and attr.ValueMightBeTimeVarying()
        got = np.array([attr.Get(float(x)) for x in t])
        np.testing.assert_allclose(got, curve(t)[:, c], rtol=0, atol=1e-9)


def test_curve_types_chosen_per_handle_widths():
    std = K.to_ts_spline(SPLINE_CURVES["catmull_rom"]())
    free = K.to_ts_spline(SPLINE_CURVES["bezier_free_handles"]())
    assert std.GetCurveType() == Ts.CurveTypeHermite
    assert free.GetCurveType() == Ts.CurveTypeBezier
    k = list(free.GetKnots().values())[1]
    assert k.GetPreTanWidth() == pytest.approx(2.5, abs=1e-14)
    assert k.GetPostTanWidth() == pytest.approx(1.2, abs=1e-14)
    held = K.to_ts_spline(SPLINE_CURVES["constant"]())
    assert list(held.GetKnots().values())[0].GetNextInterpolation() == Ts.InterpHeld


@settings(max_examples=25, deadline=None)
@given(st.integers(2, 7), st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1), st.integers(0, 2**31 - 1))
def test_tcb_spline_property(k, T, Cc, B, seed):
    rng = np.random.default_rng(seed)
    times = np.cumsum(rng.uniform(0.1, 20.0, k))
    curve = C.kochanek_bartels(times, rng.normal(size=k) * 10, T, Cc, B)
    _, prim = new_prim()
    attr = K.key_op(prim, "translate", "y", curve)[0].GetAttr()
    t = np.concatenate([rng.uniform(times[0] - 1, times[-1] + 1, 200), times])
    got = np.array([attr.Get(float(x)) for x in t])
    np.testing.assert_allclose(got, curve(t)[:, 0], rtol=0, atol=1e-9 * max(1.0, np.abs(curve.values).max()))


def test_spline_survives_a_round_trip_through_usda():
    stage, prim = new_prim()
    curve = SPLINE_CURVES["bezier_free_handles"]()
    K.key_op(prim, "translate", "x", curve)
    text = stage.GetRootLayer().ExportToString()
    assert "xformOp:translateX.spline" in text and "bezier" in text
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.ImportFromString(text)
    reopened = Usd.Stage.Open(layer)
    attr = reopened.GetAttributeAtPath("/Obj.xformOp:translateX")
    t = query_times(curve, 200)
    np.testing.assert_allclose([attr.Get(float(x)) for x in t], curve(t)[:, 0], atol=1e-9)


@pytest.mark.parametrize("make", [
    lambda: C.bspline(np.arange(6.0) * 4 + 1, VALUES[:, 0]),
    lambda: C.eased(TIMES, VALUES[:, 0], "bounce", "out"),
])
def test_bspline_and_easing_are_baked_per_frame(make):
    curve = make()
    _, prim = new_prim()
    attr = K.key_op(prim, "rotate", "z", curve)[0].GetAttr()
    assert not attr.HasSpline()
    frames = np.array(attr.GetTimeSamples())
    np.testing.assert_array_equal(frames, np.arange(np.ceil(curve.domain[0]), np.floor(curve.domain[1]) + 1))
    np.testing.assert_allclose([attr.Get(f) for f in frames], curve(frames)[:, 0], atol=1e-12)
    # explicit frames: e.g. the stage's whole range, held beyond the keys
    K.write_curve(attr, curve, 0, frames=np.arange(-3.0, 30.0))
    assert attr.GetTimeSamples()[0] == -3.0
    np.testing.assert_allclose(attr.Get(-3.0), curve(np.array([-3.0]))[0, 0])


def test_key_translate_all_axes_moves_the_prim():
    stage, prim = new_prim()
    ops = K.key_translate(prim, "xyz", TIMES, VALUES, "cardinal", tension=-0.5, parameterization="centripetal")
    assert [op.GetOpName() for op in ops] == ["xformOp:translateX", "xformOp:translateY", "xformOp:translateZ"]
    curve = C.cardinal(TIMES, VALUES, -0.5, "centripetal")
    xf = UsdGeom.Xformable(prim)
    for t in np.linspace(0, 25, 37):
        m = xf.ComputeLocalToWorldTransform(float(t))
        np.testing.assert_allclose(np.array(m.ExtractTranslation()), curve(np.array([t]))[0], atol=1e-9)


def test_key_rotate_xyz_matches_a_rotate_xyz_op():
    stage, prim = new_prim()
    K.key_rotate(prim, "xyz", TIMES, VALUES * 40, "tcb", continuity=0.3)
    assert list(UsdGeom.Xformable(prim).GetXformOpOrderAttr().Get()) == [
        "xformOp:rotateZ", "xformOp:rotateY", "xformOp:rotateX"]
    ref = UsdGeom.Xform.Define(stage, "/Ref")
    op = ref.AddRotateXYZOp(precision=UsdGeom.XformOp.PrecisionDouble)
    curve = C.kochanek_bartels(TIMES, VALUES * 40, continuity=0.3)
    for t in np.linspace(0, 25, 23):
        op.Set(Gf.Vec3d(*curve(np.array([t]))[0]))
        a = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(float(t)))
        b = np.array(ref.ComputeLocalToWorldTransform(float(t)))
        np.testing.assert_allclose(a, b, atol=1e-9)


def test_op_order_and_rekeying_in_place():
    stage, prim = new_prim()
    K.key_translate(prim, "x", TIMES, VALUES[:, 0], "linear")
    K.key_rotate(prim, "y", TIMES, VALUES[:, 1], "catmull_rom")
    K.key_scale(prim, "xyz", TIMES, 1 + 0 * VALUES, "constant")
    order = list(UsdGeom.Xformable(prim).GetXformOpOrderAttr().Get())
    assert order == ["xformOp:translateX", "xformOp:rotateY", "xformOp:scaleX", "xformOp:scaleY",
                     "xformOp:scaleZ"]
    # re-key translateX with a baked curve: the spline goes, samples come, order unchanged
    attr = prim.GetAttribute("xformOp:translateX")
    K.key_translate(prim, "x", np.arange(6.0) * 2, VALUES[:, 0], "bspline")
    assert not attr.HasSpline() and len(attr.GetTimeSamples()) == 11
    assert list(UsdGeom.Xformable(prim).GetXformOpOrderAttr().Get()) == order
    # and back to a spline: the samples go
    K.key_translate(prim, "x", TIMES, VALUES[:, 0], "hermite", slopes=np.zeros(6))
    assert attr.HasSpline() and attr.GetTimeSamples() == []


def test_existing_float_op_gets_a_float_spline():
    stage, prim = new_prim()
    op = UsdGeom.Xformable(prim).AddRotateXOp()                  # float precision by default
    assert str(op.GetAttr().GetTypeName()) == "float"
    curve = C.catmull_rom(TIMES, VALUES[:, 1] * 30)
    K.key_op(prim, "rotate", "x", curve)
    t = query_times(curve, 200)
    got = np.array([op.GetAttr().Get(float(x)) for x in t])
    np.testing.assert_allclose(got, curve(t)[:, 0], rtol=1e-6, atol=1e-5)   # float32 knots


def test_bad_requests_are_rejected():
    stage, prim = new_prim()
    with pytest.raises(ValueError):
        K.key_translate(prim, "xx", TIMES, VALUES[:, :2])
    with pytest.raises(ValueError):
        K.key_translate(prim, "xy", TIMES, VALUES)                # 3 components for 2 axes
    with pytest.raises(TypeError):
        K.to_ts_spline(C.bspline(np.arange(3.0), np.zeros(3)))
    scope = stage.DefinePrim("/Scope", "Scope")
    with pytest.raises(TypeError):
        K.key_translate(scope, "x", TIMES, VALUES[:, 0])


def test_follow_path_constant_speed_and_orientation():
    stage, prim = new_prim()
    path = P.path_through(np.array([[0, 0, 0], [2, 1, 0], [4, 3, 1], [5, 0, -1], [8, 1, 0.0]]))
    frames = np.arange(1.0, 49.0)
    fwd = np.array([0.0, 0, -1])
    top, oop = K.follow_path(prim, path, frames, forward=fwd, up=(0, 1, 0))
    assert top.GetOpName() == "xformOp:translate:path" and oop.GetOpName() == "xformOp:orient:path"
    assert top.GetAttr().GetTimeSamples() == list(frames)
    xf = UsdGeom.Xformable(prim)
    pos = np.array([np.array(xf.ComputeLocalToWorldTransform(f).ExtractTranslation()) for f in frames])
    P_ref, T_ref, u, _ = P.sample_path(path, (frames - 1) / 47)
    np.testing.assert_allclose(pos, P_ref, atol=1e-12)
    table = P.arc_length_gauss(path)
    d = np.diff(P.arc_length(table, u, path))
    np.testing.assert_allclose(d, table.length / 47, rtol=1e-4)
    for f, t in zip(frames[::6], T_ref[::6]):
        m = xf.ComputeLocalToWorldTransform(f)
        np.testing.assert_allclose(np.array(m.TransformDir(Gf.Vec3d(*fwd))), t, atol=1e-9)


@pytest.mark.parametrize("axis", ["Y", "Z"])
def test_follow_path_keeps_the_stage_up_axis_up(axis):
    stage, prim = new_prim()
    UsdGeom.SetStageUpAxis(stage, getattr(UsdGeom.Tokens, axis.lower()))
    up = np.array([0.0, 1, 0]) if axis == "Y" else np.array([0.0, 0, 1])
    path = P.path_through(np.array([[0, 0, 0], [2, 1, 1], [4, 3, 0], [5, 0, 2.0]]))
    K.follow_path(prim, path, np.arange(10.0))                 # forward = local +x, up from the stage
    xf = UsdGeom.Xformable(prim)
    _, T, _, _ = P.sample_path(path, np.arange(10.0) / 9)
    for f, t in zip(range(10), T):
        m = xf.ComputeLocalToWorldTransform(float(f))
        np.testing.assert_allclose(np.array(m.TransformDir(Gf.Vec3d(1, 0, 0))), t, atol=1e-9)
        local_up = np.array(m.TransformDir(Gf.Vec3d(*up)))
        proj = up - (up @ t) * t
        np.testing.assert_allclose(local_up, proj / np.linalg.norm(proj), atol=1e-9)


def test_follow_path_with_ease_starts_and_stops_at_rest():
    _, prim = new_prim()
    path = P.path_through(np.array([[0, 0, 0], [2, 1, 0], [4, 3, 1.0]]))
    K.follow_path(prim, path, np.arange(0.0, 25.0), timing=E.sine_ease(), orient=False)
    attr = prim.GetAttribute("xformOp:translate:path")
    pos = np.array([np.array(attr.Get(f)) for f in range(25)])
    step = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    # zero speed at the ends: distance grows quadratically, so the first two steps are 1 : 3
    # (constant speed would give 1 : 1), and symmetrically at the end
    assert abs(step[1] / step[0] - 3) < 0.1 and abs(step[-2] / step[-1] - 3) < 0.1
    assert not prim.HasAttribute("xformOp:orient:path")
