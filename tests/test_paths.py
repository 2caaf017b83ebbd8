"""Arc length, its inverse and motion along a path (seed-systems.md §B)."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.integrate import quad
from scipy.spatial.transform import Rotation

from pipeline.animation import curves as C
from pipeline.animation import easing as E
from pipeline.animation import paths as P

METHODS = ["forward", "adaptive", "gauss"]
GL_X, GL_W = np.polynomial.legendre.leggauss(20)


def bezier_arc(theta=np.pi / 2, radius=2.0):
    """A circular arc as one cubic Bézier (handle length 4/3 tan(theta/4)); not exactly circular."""
    k = 4 / 3 * np.tan(theta / 4)
    c, s = np.cos(theta), np.sin(theta)
    ctrl = radius * np.array([[1, 0, 0], [1, k, 0], [c + k * s, s - k * c, 0], [c, s, 0]])
    return C.bezier_polygon(ctrl)


def helix(r=1.5, c=0.4, turns=2.0):
    th = 2 * np.pi * turns
    curve = P.ParametricCurve(
        lambda u: np.stack([r * np.cos(u), r * np.sin(u), c * u], -1),
        lambda u: np.stack([-r * np.sin(u), r * np.cos(u), c * np.ones_like(u)], -1),
        (0.0, th))
    return curve, th * np.hypot(r, c)          # closed-form length


def ref_length(curve, a, b, pieces=32):
    """Reference length from a to b (vectorised): composite 20-point Gauss-Legendre, ``pieces``
    sub-intervals per cubic segment (a single high-order rule per segment is not enough where a
    path nearly has a cusp; checked against scipy's adaptive quad below)."""
    a, b = np.atleast_1d(a).astype(float), np.atleast_1d(b).astype(float)
    knots = getattr(curve, "times", np.array(curve.domain))
    total = np.zeros(a.size)
    for k0, k1 in zip(knots[:-1], knots[1:]):
        lo, hi = np.clip(a, k0, k1), np.clip(b, k0, k1)
        edges = lo[:, None] + (hi - lo)[:, None] * np.linspace(0, 1, pieces + 1)[None, :]
        l, r = edges[:, :-1], edges[:, 1:]
        half = (r - l) / 2
        u = ((l + r) / 2)[..., None] + half[..., None] * GL_X
        sp = np.linalg.norm(curve.derivative(u.ravel()), axis=1).reshape(u.shape)
        total += np.sum(half * (sp @ GL_W), axis=1)
    return total


def quad_length(curve, a, b):
    """scipy's adaptive quadrature, segment by segment (scalar reference)."""
    knots = getattr(curve, "times", np.array(curve.domain))
    sp = lambda u: np.linalg.norm(curve.derivative(np.array([u]))[0])  # noqa: E731
    cuts = np.unique(np.clip(np.concatenate([[a, b], knots]), a, b))
    return sum(quad(sp, x0, x1, epsabs=0, epsrel=1e-13, limit=500)[0] for x0, x1 in zip(cuts[:-1], cuts[1:]))


@pytest.fixture(scope="module")
def arc_reference():
    curve = bezier_arc()
    L = quad(lambda u: np.linalg.norm(curve.derivative(np.array([u]))[0]), 0, 1,
             epsabs=0, epsrel=1e-13, limit=200)[0]
    return curve, L


def test_bezier_arc_is_not_a_circle_but_close(arc_reference):
    curve, L = arc_reference
    r = np.linalg.norm(curve(np.linspace(0, 1, 101)), axis=1)
    assert 0 < r.max() - 2.0 < 1e-3                       # the known ~2.7e-4 radial error
    assert 1e-5 < L / np.pi - 1 < 1e-3                     # so its length is not pi * r either
    np.testing.assert_allclose(ref_length(curve, 0.0, 1.0)[0], L, rtol=1e-13)


@pytest.mark.parametrize("method", METHODS)
def test_arc_length_of_a_bezier_arc(method, arc_reference):
    curve, L = arc_reference
    table = P.arc_length_table(curve, method)
    assert abs(table.length / L - 1) < 1e-6
    assert table.u[0] == 0.0 and table.u[-1] == 1.0 and np.all(np.diff(table.s) > 0)


@pytest.mark.parametrize("method", METHODS)
def test_arc_length_of_a_helix(method):
    curve, L = helix()
    table = P.arc_length_table(curve, method)
    assert abs(table.length / L - 1) < 1e-6
    # and at interior parameters, where the helix length is linear in u
    u = np.linspace(0, curve.domain[1], 37)
    np.testing.assert_allclose(P.arc_length(table, u), u * np.hypot(1.5, 0.4), rtol=1e-6, atol=1e-9)


def test_forward_differencing_converges_quadratically(arc_reference):
    curve, L = arc_reference
    e1 = abs(P.arc_length_forward(curve, n=50, supersample=1).length - L)
    e2 = abs(P.arc_length_forward(curve, n=100, supersample=1).length - L)
    assert 3.8 < e1 / e2 < 4.2                             # chords: error ~ 1 / N^2
    e3 = abs(P.arc_length_forward(curve, n=50, supersample=4).length - L)
    assert 15 < e1 / e3 < 17                               # supersampling x4 -> error / 16
    assert P.arc_length_forward(curve, n=50, supersample=1).length < L   # chords are short


def test_adaptive_threshold_controls_the_error():
    curve = P.path_through(np.array([[0, 0, 0], [1, 3, 0], [4, 3, 1], [5, 0, 0], [7, 1, 3.0]]))
    L = ref_length(curve, *curve.domain)[0]
    errs, sizes = [], []
    for tol in (1e-5, 1e-7, 1e-9):
        t = P.arc_length_adaptive(curve, tol=tol)
        errs.append(abs(t.length - L) / L)
        sizes.append(t.u.size)
    assert errs[0] > errs[1] > errs[2] and sizes[0] < sizes[1] < sizes[2]
    assert errs[2] < 1e-6
    # nodes crowd where the path bends: interval widths vary
    w = np.diff(P.arc_length_adaptive(curve, tol=1e-7).u)
    assert w.max() / w.min() >= 4


def test_gauss_splits_only_where_halves_disagree():
    # a path whose speed varies strongly on one segment: the table refines there
    pts = np.array([[0, 0, 0], [0.1, 0, 0], [0.2, 0.05, 0], [5, 4, 0], [6, 4, 0]])
    curve = P.path_through(pts, "catmull_rom", "uniform")
    t = P.arc_length_gauss(curve, tol=1e-13, order=3, min_intervals=1)
    L = quad_length(curve, *curve.domain)
    assert abs(t.length / L - 1) < 1e-10
    assert abs(ref_length(curve, *curve.domain)[0] / L - 1) < 1e-10     # the vector reference too
    counts = np.histogram(t.u[1:], bins=curve.times)[0]
    assert counts.max() >= 4 * counts.min()


@pytest.mark.parametrize("method", METHODS)
def test_inverse_arc_length(method, arc_reference):
    curve, L = arc_reference
    table = P.arc_length_table(curve, method)
    s = np.linspace(0, table.length, 53)
    u = P.inverse_arc_length(table, s, curve, newton=2 if method == "gauss" else 0)
    assert np.all(np.diff(u) > 0)
    np.testing.assert_allclose(ref_length(curve, np.zeros_like(u), u), s, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(P.arc_length(table, u, curve if method == "gauss" else None), s, atol=1e-7)
    np.testing.assert_array_equal(P.inverse_arc_length(table, np.array([-1.0, 1e9])), [0.0, 1.0])


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("kind", ["catmull_rom", "bezier", "helix"])
def test_constant_speed_moves_equal_distances_per_frame(method, kind):
    if kind == "helix":
        curve, _ = helix()
    elif kind == "bezier":
        curve = P.path_through(np.array([[0, 0, 0], [2, 3, 0], [4, -1, 1], [5, 0, 0],
                                         [6, 1, -1], [9, 0.5, 2], [8, 4, 0]]), "bezier")
    else:
        curve = P.path_through(np.array([[0, 0, 0], [1, 2, 0], [3, 2, 1], [4, 0, 0], [6, 1, 2.0]]))
    frames = 96
    pos, tan, u, s = P.sample_path(curve, np.linspace(0, 1, frames + 1), method=method)
    d = ref_length(curve, u[:-1], u[1:])
    L = ref_length(curve, *curve.domain)[0]
    np.testing.assert_allclose(d, L / frames, rtol=1e-4)
    np.testing.assert_allclose(pos[[0, -1]], curve(np.array(curve.domain)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(tan, axis=1), 1.0, atol=1e-12)


def test_ease_in_out_along_a_path_starts_and_stops_at_rest():
    curve = P.path_through(np.array([[0, 0, 0], [1, 2, 0], [3, 2, 1], [4, 0, 0.0]]))
    table = P.arc_length_gauss(curve)
    t = np.linspace(0, 1, 201)
    for h in (E.sine_ease(), E.sine_linear_sine(), E.parabolic_ease()):
        pos, _, u, s = P.sample_path(curve, t, h, table)
        step = np.linalg.norm(np.diff(pos, axis=0), axis=1)
        # zero end speed: distance grows quadratically, so the first two steps are 1 : 3
        # (a non-zero start speed gives 1 : 1), and symmetrically at the end
        assert abs(step[1] / step[0] - 3) < 0.05 and abs(step[-2] / step[-1] - 3) < 0.05
        assert step.max() > 20 * step[0]
        np.testing.assert_allclose(ref_length(curve, np.zeros_like(u), u, pieces=8), table.length * h(t),
                                   rtol=1e-6, atol=1e-9)


def test_path_through_interpolates_and_tangents_follow_the_path():
    pts = np.array([[0, 0, 0], [1, 2, 0], [3, 2, 1], [4, 0, 0.0]])
    for param in ("uniform", "centripetal", "chordal"):
        curve = P.path_through(pts, "catmull_rom", param)
        np.testing.assert_allclose(curve(curve.times), pts, atol=1e-12)
    curve = P.path_through(pts, "catmull_rom")
    pos, tan, u, _ = P.sample_path(curve, np.linspace(0, 1, 11))
    d = curve.derivative(u[:-1])
    np.testing.assert_allclose(tan[:-1], d / np.linalg.norm(d, axis=1, keepdims=True), atol=1e-12)
    # the last tangent is the arriving direction, not the held extrapolation's zero
    d_end = curve.derivative(np.array([curve.domain[1]]), side="left")[0]
    np.testing.assert_allclose(tan[-1], d_end / np.linalg.norm(d_end), atol=1e-12)


def test_orientations_turn_forward_onto_the_tangent_and_keep_up():
    rng = np.random.default_rng(3)
    T = rng.normal(size=(50, 3))
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    fwd, up = np.array([0, 0, -1.0]), np.array([0, 1.0, 0])
    q = P.orientations(T, forward=fwd, up=up)
    R = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()
    np.testing.assert_allclose(R @ fwd, T, atol=1e-12)
    local_up_world = R @ up
    np.testing.assert_allclose(np.sum(local_up_world * T, axis=1), 0, atol=1e-12)
    # no roll: the object's up is the world up projected off the tangent
    proj = up - (T @ up)[:, None] * T
    proj /= np.linalg.norm(proj, axis=1, keepdims=True)
    np.testing.assert_allclose(local_up_world, proj, atol=1e-12)


def test_orientations_are_continuous_and_survive_a_vertical_tangent():
    th = np.linspace(0, np.pi, 41)
    T = np.stack([np.sin(th), np.cos(th), 0 * th], 1)        # passes through +y and -y (= up)
    q = P.orientations(T, up=(0, 1, 0))
    assert np.all(np.isfinite(q))
    assert np.all(np.sum(q[1:] * q[:-1], axis=1) > 0)          # one hemisphere, frame to frame
    R = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()
    np.testing.assert_allclose(R @ np.array([1.0, 0, 0]), T, atol=1e-12)


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_quaternions_from_matrices_round_trip(seed):
    rots = Rotation.random(16, random_state=seed)
    # include the pivots: trace-dominant and each diagonal-dominant (180-degree turns)
    extra = Rotation.from_rotvec(np.pi * np.eye(3) * 0.999)
    R = np.concatenate([rots.as_matrix(), extra.as_matrix(), np.eye(3)[None]])
    q = P.quaternions_from_matrices(R)
    back = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()
    np.testing.assert_allclose(back, R, atol=1e-12)


def test_unknown_method_is_rejected():
    with pytest.raises(ValueError):
        P.arc_length_table(bezier_arc(), "guesswork")
