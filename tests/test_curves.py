"""Key curves against their closed forms (seed-systems.md §A)."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.optimize import brentq

from pipeline.animation import curves as C
from pipeline.animation import easing as E

RNG = np.random.default_rng(7)


def uneven_times(k, rng=RNG):
    return np.concatenate([[1.0], 1.0 + np.cumsum(rng.uniform(0.3, 4.0, k - 1))])


def one_sided(curve, t):
    """Left and right derivatives (n, d) measured by the curve, at times t (n,)."""
    return curve.derivative(t, side="left"), curve.derivative(t, side="right")


def second_derivative_sides(curve, t, eps=1e-5):
    """One-sided second derivatives by differencing the analytic first derivative."""
    dl, dr = one_sided(curve, t)
    left = (dl - curve.derivative(t - eps, side="left")) / eps
    right = (curve.derivative(t + eps, side="right") - dr) / eps
    return left, right


# --- basis matrices --------------------------------------------------------------------------

def test_catmull_rom_matrix_is_the_slides_matrix():
    expected = 0.5 * np.array([[-1, 3, -3, 1], [2, -5, 4, -1], [-1, 0, 1, 0], [0, 2, 0, 0]])
    np.testing.assert_array_equal(C.M_CATMULL_ROM, expected)
    np.testing.assert_allclose(C.cardinal_matrix(0.0), expected, atol=0)


def test_hermite_matrix_meets_its_end_conditions():
    G = RNG.normal(size=(4, 3))                       # p0, p3, p0', p3'
    p = C.segment_points(C.M_HERMITE, G, np.array([0.0, 1.0]))
    dp = C.segment_derivative(C.M_HERMITE, G, np.array([0.0, 1.0]))
    np.testing.assert_allclose(p, G[:2], atol=1e-14)
    np.testing.assert_allclose(dp, G[2:], atol=1e-14)


def test_bezier_matrix_is_hermite_with_tangents_three_times_the_handles():
    P = RNG.normal(size=(4, 2))
    G_h = np.stack([P[0], P[3], 3 * (P[1] - P[0]), 3 * (P[3] - P[2])])
    u = np.linspace(0, 1, 11)
    np.testing.assert_allclose(C.segment_points(C.M_BEZIER, P, u),
                               C.segment_points(C.M_HERMITE, G_h, u), atol=1e-14)
    # Bernstein form, and the convex-hull property: weights are non-negative and sum to 1
    B = np.stack([(1 - u) ** 3, 3 * u * (1 - u) ** 2, 3 * u**2 * (1 - u), u**3], 1)
    np.testing.assert_allclose(C.segment_points(C.M_BEZIER, P, u), B @ P, atol=1e-14)


def test_bspline_matrix_end_conditions_from_the_slides():
    G = RNG.normal(size=(4, 3))                       # p_{i-2} .. p_{i+1}
    np.testing.assert_allclose(C.segment_points(C.M_BSPLINE, G, np.array([0.0]))[0],
                               (G[0] + 4 * G[1] + G[2]) / 6, atol=1e-14)
    np.testing.assert_allclose(C.segment_points(C.M_BSPLINE, G, np.array([1.0]))[0],
                               (G[1] + 4 * G[2] + G[3]) / 6, atol=1e-14)
    np.testing.assert_allclose(C.segment_derivative(C.M_BSPLINE, G, np.array([0.0]))[0],
                               (G[2] - G[0]) / 2, atol=1e-14)
    np.testing.assert_allclose(C.segment_derivative(C.M_BSPLINE, G, np.array([1.0]))[0],
                               (G[3] - G[1]) / 2, atol=1e-14)
    w = np.array([[u**3, u**2, u, 1] for u in np.linspace(0, 1, 7)]) @ C.M_BSPLINE
    assert np.all(w >= -1e-15)
    np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-14)


def test_interpolating_matrix_passes_through_its_four_points():
    G = RNG.normal(size=(4, 2))
    np.testing.assert_allclose(C.segment_points(C.M_INTERPOLATING, G, np.array([0, 1 / 3, 2 / 3, 1])),
                               G, atol=1e-13)


# --- curves against the matrices ----------------------------------------------------------------

def segments_by_matrix(M, G_of, times, n=9):
    """(times, values) sampled from p(u) = U M G on every segment i with G = G_of(i)."""
    ts, vs = [], []
    for i in range(times.size - 1):
        u = np.linspace(0, 1, n, endpoint=False)
        ts.append(times[i] + u * (times[i + 1] - times[i]))
        vs.append(C.segment_points(M, G_of(i), u))
    return np.concatenate(ts), np.concatenate(vs)


def phantom(P):
    return np.concatenate([2 * P[:1] - P[1:2], P, 2 * P[-1:] - P[-2:-1]])


@pytest.mark.parametrize("times", [np.arange(6.0), uneven_times(6)])
def test_catmull_rom_uniform_parameterisation_is_the_matrix(times):
    # uniform knots map every segment to u in [0, 1]: exactly U M_CR [p_{i-1} .. p_{i+2}],
    # with the mirrored phantom keys at the ends -- for any key spacing
    P = RNG.normal(size=(6, 3))
    E_ = phantom(P)
    t, ref = segments_by_matrix(C.M_CATMULL_ROM, lambda i: E_[i:i + 4], times)
    curve = C.catmull_rom(times, P, parameterization="uniform")
    np.testing.assert_allclose(curve(t), ref, atol=1e-12)


@pytest.mark.parametrize("q", [-0.5, 0.0, 0.4])
def test_cardinal_uniform_is_the_cardinal_matrix(q):
    times = uneven_times(5)
    P = RNG.normal(size=(5, 2))
    E_ = phantom(P)
    t, ref = segments_by_matrix(C.cardinal_matrix(q), lambda i: E_[i:i + 4], times)
    np.testing.assert_allclose(C.cardinal(times, P, q, "uniform")(t), ref, atol=1e-12)


def test_cardinal_q0_with_uniform_keys_equals_catmull_rom():
    times = np.arange(7.0) * 2.5
    P = RNG.normal(size=(7, 3))
    t = np.linspace(times[0], times[-1], 301)
    cr = C.catmull_rom(times, P, parameterization="uniform")
    for param in ("time", "uniform"):
        np.testing.assert_allclose(C.cardinal(times, P, 0.0, param)(t), cr(t), atol=1e-12)


def test_cardinal_time_tangent_is_the_ccm_formula():
    # m_k = (1 - q)(p_{k+1} - p_{k-1}) / (t_{k+1} - t_{k-1}), C1 in time
    times = uneven_times(6)
    P = RNG.normal(size=(6, 2))
    q = -0.5
    curve = C.cardinal(times, P, q)
    k = np.arange(1, 5)
    m = (1 - q) * (P[k + 1] - P[k - 1]) / (times[k + 1] - times[k - 1])[:, None]
    dl, dr = one_sided(curve, times[k])
    np.testing.assert_allclose(dl, m, atol=1e-12)
    np.testing.assert_allclose(dr, m, atol=1e-12)


def test_centripetal_and_chordal_knots():
    P = np.array([[0.0, 0], [3, 4], [3, 4 + 9], [3, 4 + 9 + 1]])
    np.testing.assert_allclose(C.parameter_knots(P, "chordal"), [0, 5, 14, 15])
    np.testing.assert_allclose(C.parameter_knots(P, "centripetal"), [0, 5**0.5, 5**0.5 + 3, 5**0.5 + 4])
    np.testing.assert_allclose(C.parameter_knots(P, "uniform"), [0, 1, 2, 3])
    with pytest.raises(ValueError):
        C.parameter_knots(np.array([[0.0, 0], [0, 0], [1, 1]]), "centripetal")


def test_centripetal_segment_is_the_nonuniform_cardinal():
    # in the knot parameter s the tangents are the non-uniform central differences
    P = RNG.normal(size=(5, 3))
    s = C.parameter_knots(P, "centripetal")
    times = uneven_times(5)
    curve = C.cardinal(times, P, 0.0, "centripetal")
    path = C.cardinal(s, P, 0.0, "time")
    i = 2
    u = np.linspace(0, 1, 17)
    np.testing.assert_allclose(curve(times[i] + u * (times[i + 1] - times[i])),
                               path(s[i] + u * (s[i + 1] - s[i])), atol=1e-12)


def tcb_slopes(times, P, T, Cc, B, uneven=True):
    """Independent restatement of seed-systems.md §A, with mirrored end keys."""
    t_ext = np.concatenate([[2 * times[0] - times[1]], times, [2 * times[-1] - times[-2]]])
    E_ = phantom(P)
    s_in, s_out = [], []
    for i in range(times.size):
        d0, d1 = E_[i + 1] - E_[i], E_[i + 2] - E_[i + 1]
        tin = ((1 - T) * (1 - Cc) * (1 + B) * d0 + (1 - T) * (1 + Cc) * (1 - B) * d1) / 2
        tout = ((1 - T) * (1 + Cc) * (1 + B) * d0 + (1 - T) * (1 - Cc) * (1 - B) * d1) / 2
        n0, n1 = t_ext[i + 1] - t_ext[i], t_ext[i + 2] - t_ext[i + 1]
        if uneven:   # incoming scaled by 2 N0/(N0+N1) in a segment of length N0, etc.
            s_in.append(tin * 2 * n0 / (n0 + n1) / n0)
            s_out.append(tout * 2 * n1 / (n0 + n1) / n1)
        else:
            s_in.append(tin / n0)
            s_out.append(tout / n1)
    return np.array(s_in), np.array(s_out)


@pytest.mark.parametrize("uneven", [True, False])
def test_kochanek_bartels_tangent_break_matches_the_formula(uneven):
    times = uneven_times(6)
    P = RNG.normal(size=(6, 2))
    T, Cc, B = 0.2, 0.6, -0.3
    curve = C.kochanek_bartels(times, P, T, Cc, B, uneven=uneven)
    s_in, s_out = tcb_slopes(times, P, T, Cc, B, uneven)
    k = np.arange(1, 5)
    dl, dr = one_sided(curve, times[k])
    np.testing.assert_allclose(dl, s_in[k], atol=1e-12)
    np.testing.assert_allclose(dr, s_out[k], atol=1e-12)
    assert np.min(np.linalg.norm(dr - dl, axis=1)) > 1e-3      # C != 0: a real break


def test_kochanek_bartels_zero_is_catmull_rom_for_any_spacing():
    times = uneven_times(7)
    P = RNG.normal(size=(7, 3))
    t = np.linspace(times[0] - 1, times[-1] + 1, 500)
    np.testing.assert_allclose(C.kochanek_bartels(times, P)(t), C.catmull_rom(times, P)(t), atol=1e-12)
    # and the plain (unscaled) TCB with even keys is the M_CR curve
    even = np.arange(7.0) * 3
    np.testing.assert_allclose(C.kochanek_bartels(even, P, uneven=False)(t),
                               C.catmull_rom(even, P, parameterization="uniform")(t), atol=1e-12)


def test_kochanek_bartels_tension_is_cardinal_tension():
    times = uneven_times(5)
    P = RNG.normal(size=(5, 2))
    t = np.linspace(times[0], times[-1], 200)
    np.testing.assert_allclose(C.kochanek_bartels(times, P, tension=0.7)(t),
                               C.cardinal(times, P, 0.7)(t), atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(st.integers(3, 7), st.floats(-1, 1), st.floats(-1, 1), st.integers(0, 2**31 - 1))
def test_tcb_c1_in_time_when_continuity_is_zero(k, T, B, seed):
    rng = np.random.default_rng(seed)
    times = uneven_times(k, rng)
    P = rng.normal(size=(k, 2))
    curve = C.kochanek_bartels(times, P, T, 0.0, B)
    dl, dr = one_sided(curve, times[1:-1])
    np.testing.assert_allclose(dl, dr, atol=1e-10)
    # and without the spacing adjustment the break is there whenever the spacing is uneven
    raw = C.kochanek_bartels(times, P, T, 0.0, B, uneven=False)
    dl, dr = one_sided(raw, times[1:-1])
    h = np.diff(times)      # per-segment tangents agree, so the time slopes differ by h_i / h_{i-1}
    np.testing.assert_allclose(dr * h[1:, None], dl * h[:-1, None], atol=1e-10)


def test_hermite_is_the_hermite_matrix_in_time():
    times = uneven_times(4)
    P = RNG.normal(size=(4, 2))
    m_out = RNG.normal(size=(4, 2))
    m_in = RNG.normal(size=(4, 2))
    curve = C.hermite(times, P, m_out, slopes_in=m_in)
    h = np.diff(times)
    t, ref = segments_by_matrix(
        C.M_HERMITE, lambda i: np.stack([P[i], P[i + 1], h[i] * m_out[i], h[i] * m_in[i + 1]]), times)
    np.testing.assert_allclose(curve(t), ref, atol=1e-12)
    dl, dr = one_sided(curve, times[1:-1])
    np.testing.assert_allclose(dl, m_in[1:-1], atol=1e-12)
    np.testing.assert_allclose(dr, m_out[1:-1], atol=1e-12)


def test_bezier_polygon_is_the_bezier_matrix_and_c0_at_joins():
    ctrl = RNG.normal(size=(10, 3))
    times = np.array([0.0, 2.0, 3.0, 7.0])
    curve = C.bezier_polygon(ctrl, times)
    t, ref = segments_by_matrix(C.M_BEZIER, lambda i: ctrl[3 * i:3 * i + 4], times)
    np.testing.assert_allclose(curve(t), ref, atol=1e-12)
    dl, dr = one_sided(curve, times[1:-1])
    h = np.diff(times)
    np.testing.assert_allclose(dl, 3 * (ctrl[3:-1:3] - ctrl[2:-2:3]) / h[:-1, None], atol=1e-12)
    np.testing.assert_allclose(dr, 3 * (ctrl[4::3] - ctrl[3:-1:3]) / h[1:, None], atol=1e-12)
    assert np.all(np.linalg.norm(dl - dr, axis=1) > 1e-3)     # random handles: C0 only


def test_bezier_with_collinear_equal_handles_is_c1():
    ctrl = RNG.normal(size=(7, 2))
    ctrl[4] = 2 * ctrl[3] - ctrl[2]                           # mirror the handle through the key
    curve = C.bezier_polygon(ctrl)
    dl, dr = one_sided(curve, np.array([1.0]))
    np.testing.assert_allclose(dl, dr, atol=1e-12)


def test_interpolating_cubic_hits_its_points_and_is_c0():
    pts = RNG.normal(size=(7, 2))
    times = np.array([0.0, 3.0, 4.5])
    curve = C.interpolating_cubic(pts, times)
    tt = np.concatenate([times[0] + np.array([0, 1, 2]) / 3 * 3.0,
                         times[1] + np.array([0, 1, 2, 3]) / 3 * 1.5])
    np.testing.assert_allclose(curve(tt), pts, atol=1e-12)
    dl, dr = one_sided(curve, times[1:2])
    assert np.linalg.norm(dl - dr) > 1e-3


def bezier_xy(knot_t, knot_v, right, left, u):
    """The (time, value) Bézier of one segment, Bernstein form."""
    X = np.array([knot_t[0], right[0], left[0], knot_t[1]])
    Y = np.array([knot_v[0], right[1], left[1], knot_v[1]])
    B = np.stack([(1 - u) ** 3, 3 * u * (1 - u) ** 2, 3 * u**2 * (1 - u), u**3], 1)
    return B @ X, B @ Y


def test_bezier_keys_with_free_handles_follow_the_2d_bezier():
    times = np.array([0.0, 4.0, 5.0, 11.0])
    v = np.array([0.0, 3.0, -1.0, 2.0])
    left = np.stack([times - np.array([1, 2.5, 0.2, 4.0]), v + np.array([0, 1, -0.5, 0.3])], 1)
    right = np.stack([times + np.array([3.5, 0.6, 5.0, 1.0]), v + np.array([1, -0.2, 2, 0])], 1)
    curve = C.bezier(times, v, left, right)
    assert not curve.standard_widths
    u = np.linspace(0, 1, 101)
    for i in range(3):
        x, y = bezier_xy(times[i:i + 2], v[i:i + 2], right[i], left[i + 1], u)
        np.testing.assert_allclose(curve(x)[:, 0], y, atol=1e-12)
        # derivative dy/dx from the Bézier by brentq-free differencing in u
        dx, dy = np.gradient(x, u), np.gradient(y, u)
        inner = slice(5, -5)
        np.testing.assert_allclose(curve.derivative(x)[inner, 0], (dy / dx)[inner], rtol=2e-3, atol=2e-3)
    # end slopes are the handle directions
    dl, dr = one_sided(curve, times[1:3])
    np.testing.assert_allclose(dl[:, 0], (v[1:3] - left[1:3, 1]) / (times[1:3] - left[1:3, 0]))
    np.testing.assert_allclose(dr[:, 0], (right[1:3, 1] - v[1:3]) / (right[1:3, 0] - times[1:3]))
    # a value by root finding agrees too
    t = 7.3
    uu = brentq(lambda s: bezier_xy(times[2:4], v[2:4], right[2], left[3], np.array([s]))[0][0] - t, 0, 1,
                xtol=1e-15)
    assert abs(curve(t)[0] - bezier_xy(times[2:4], v[2:4], right[2], left[3], np.array([uu]))[1][0]) < 1e-12


def test_bezier_keys_with_third_handles_equal_the_polygon():
    times = np.array([0.0, 2.0, 5.0])
    v = RNG.normal(size=3)
    s = RNG.normal(size=3)
    h = np.array([2.0, 2.0, 3.0, 3.0])
    left = np.stack([times - h[[0, 0, 2]] / 3, v - s * h[[0, 0, 2]] / 3], 1)
    right = np.stack([times + h[[0, 2, 2]] / 3, v + s * h[[0, 2, 2]] / 3], 1)
    curve = C.bezier(times, v, left, right)
    assert curve.standard_widths
    t = np.linspace(0, 5, 51)
    np.testing.assert_allclose(curve(t), C.hermite(times, v, s)(t), atol=1e-12)


def test_regressive_bezier_handles_are_rejected():
    times, v = np.array([0.0, 1.0]), np.zeros(2)
    with pytest.raises(ValueError, match="regress"):
        C.bezier(times, v, np.array([[-1, 0], [-0.2, 0]]), np.array([[1.2, 0], [2, 0]]))
    # long but monotone handles are fine (a + b - 1 = 0.6, (0.6)^2 <= 0.5 * 1.1)
    C.bezier(times, v, np.array([[-1, 0], [1 - 1.1, 0]]), np.array([[0.5, 0], [2, 0]]))


def test_bspline_interior_is_the_bspline_matrix_and_c2():
    times = np.arange(8.0) * 2
    P = RNG.normal(size=(8, 3))
    curve = C.bspline(times, P)
    E_ = phantom(P)
    t, ref = segments_by_matrix(C.M_BSPLINE, lambda i: E_[i:i + 4], times)
    np.testing.assert_allclose(curve(t), ref, atol=1e-12)
    np.testing.assert_allclose(curve(times[[0, -1]]), P[[0, -1]], atol=1e-12)   # mirrored ends
    dl, dr = one_sided(curve, times[1:-1])
    np.testing.assert_allclose(dl, dr, atol=1e-12)
    al, ar = second_derivative_sides(curve, times[1:-1])
    np.testing.assert_allclose(al, ar, atol=1e-3)
    # approximating: it misses the interior control points
    assert np.min(np.linalg.norm(curve(times[1:-1]) - P[1:-1], axis=1)) > 1e-3
    with pytest.raises(ValueError):
        C.bspline(np.array([0.0, 1, 3]), P[:3])


def test_catmull_rom_is_c1_but_not_c2():
    times = uneven_times(6)
    P = RNG.normal(size=(6, 2))
    curve = C.catmull_rom(times, P)
    dl, dr = one_sided(curve, times[1:-1])
    np.testing.assert_allclose(dl, dr, atol=1e-12)
    al, ar = second_derivative_sides(curve, times[1:-1])
    assert np.min(np.abs(al - ar)) > 1e-2


def test_constant_and_linear():
    times = np.array([0.0, 1.0, 3.0])
    v = np.array([2.0, -1.0, 4.0])
    c = C.constant(times, v)
    np.testing.assert_array_equal(c(np.array([-1, 0, 0.999, 1, 2.5, 3, 9]))[:, 0], [2, 2, 2, -1, -1, 4, 4])
    lin = C.linear(times, v)
    np.testing.assert_allclose(lin(np.array([0.5, 2.0]))[:, 0], [0.5, 1.5])
    np.testing.assert_allclose(lin.derivative(np.array([1.0]), "left")[0, 0], -3.0)
    np.testing.assert_allclose(lin.derivative(np.array([1.0]), "right")[0, 0], 2.5)


def test_eased_curve_uses_the_preset_between_keys():
    times = np.array([0.0, 10.0, 14.0])
    v = np.array([[0.0, 1.0], [5.0, 1.0], [1.0, -3.0]])
    curve = C.eased(times, v, "cubic", "in_out")
    f = E.preset("cubic", "in_out")
    u = np.linspace(0, 1, 9)
    np.testing.assert_allclose(curve(10 + 4 * u), v[1] + f(u)[:, None] * (v[2] - v[1]), atol=1e-14)
    np.testing.assert_allclose(curve(times), v, atol=1e-14)


@pytest.mark.parametrize("make", [
    lambda t, v: C.catmull_rom(t, v),
    lambda t, v: C.cardinal(t, v, -0.5, "chordal"),
    lambda t, v: C.kochanek_bartels(t, v, 0.3, -0.4, 0.5),
    lambda t, v: C.bspline(np.arange(t.size) * 1.5, v),
    lambda t, v: C.eased(t, v, "elastic", "out"),
    lambda t, v: C.bezier(t, v[:, 0], np.stack([t - 0.2, v[:, 0] + 1], 1), np.stack([t + 0.7, v[:, 0]], 1)),
])
def test_derivative_matches_finite_differences(make):
    times = uneven_times(5)
    v = RNG.normal(size=(5, 2))
    curve = make(times, v)
    lo, hi = curve.domain
    t = np.linspace(lo, hi, 157)[1:-1]
    t = t[np.min(np.abs(t[:, None] - curve.times[None, :]), axis=1) > 1e-3]
    eps = 1e-6
    fd = (curve(t + eps) - curve(t - eps)) / (2 * eps)
    np.testing.assert_allclose(curve.derivative(t), fd, rtol=1e-5, atol=1e-5)


def test_held_extrapolation_and_shapes():
    curve = C.catmull_rom(np.array([0.0, 1.0, 2.0]), np.array([1.0, 2.0, 0.0]))
    np.testing.assert_array_equal(curve(np.array([-5.0, 7.0]))[:, 0], [1.0, 0.0])
    np.testing.assert_array_equal(curve.derivative(np.array([-5.0, 7.0]))[:, 0], [0.0, 0.0])
    assert curve(np.zeros((2, 3))).shape == (2, 3, 1)
    assert C.make(np.arange(3.0), np.zeros((3, 2)), "tcb")(0.5).shape == (2,)
    single = C.catmull_rom(np.array([4.0]), np.array([2.5]))
    np.testing.assert_array_equal(single(np.array([0.0, 9.0]))[:, 0], [2.5, 2.5])


def test_bad_input_is_rejected():
    with pytest.raises(ValueError):
        C.linear(np.array([0.0, 0.0]), np.array([1.0, 2.0]))
    with pytest.raises(ValueError):
        C.linear(np.array([0.0, 1.0]), np.array([1.0, np.nan]))
    with pytest.raises(ValueError):
        C.make(np.arange(3.0), np.zeros(3), "spline-o-matic")
