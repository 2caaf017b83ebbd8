"""Warp and Barr's taper / twist / bend against closed forms."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pipeline.animation import deformers as df

RNG = np.random.default_rng(7)


def tube(nu=12, nv=9, radius=0.8, length=4.0):
    phi = 2 * np.pi * np.arange(nu) / nu
    z = np.linspace(0.0, length, nv)
    return np.stack(np.broadcast_arrays(radius * np.cos(phi)[:, None],
                                        radius * np.sin(phi)[:, None], z[None, :]), axis=-1)


# ------------------------------------------------------------------------------------- warp

@pytest.mark.parametrize("name", sorted(df.PROFILES))
def test_profiles_go_from_one_to_zero_monotonically(name):
    r = np.linspace(0.0, 1.0, 101)
    f = df.PROFILES[name](r)
    assert np.isclose(f[0], 1.0, atol=1e-15) and np.isclose(f[-1], 0.0, atol=1e-15)
    assert np.all(np.diff(f) <= 1e-15)
    w = df.attenuation([0.0, 0.5, 1.0, 1.5, np.inf], 1.0, name)
    assert w[0] == 1.0 and np.all(w[2:] == 0.0)


def test_grid_edge_distance_respects_wrap():
    d = df.grid_edge_distance((8, 5), (0, 0), wrap=(True, False))
    assert d[7, 0] == 1 and d[4, 0] == 4 and d[0, 4] == 4 and d[7, 4] == 5
    d_open = df.grid_edge_distance((8, 5), (0, 0), wrap=(False, False))
    assert d_open[7, 0] == 7


def test_mesh_edge_distance_matches_grid_graph():
    nu, nv = 6, 5
    idx = np.arange(nu * nv).reshape(nu, nv)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
    d = df.mesh_edge_distance(nu * nv, quads, idx[2, 3])
    assert np.array_equal(d.reshape(nu, nv), df.grid_edge_distance((nu, nv), (2, 3)))


@settings(max_examples=60, deadline=None)
@given(i=st.integers(0, 11), j=st.integers(0, 8), cutoff=st.floats(0.3, 3.0),
       metric=st.sampled_from(["euclidean", "edges"]), profile=st.sampled_from(sorted(df.PROFILES)),
       dx=st.floats(-2, 2), dy=st.floats(-2, 2), dz=st.floats(-2, 2))
def test_warp_moves_pick_exactly_and_nothing_beyond_cutoff(i, j, cutoff, metric, profile,
                                                          dx, dy, dz):
    P = tube()
    disp = np.array([dx, dy, dz])
    out = df.warp(P, (i, j), disp, cutoff, metric, profile, wrap=(True, False))
    assert np.array_equal(out[i, j], P[i, j] + disp)
    if metric == "euclidean":
        d = np.linalg.norm(P - P[i, j], axis=-1)
    else:
        d = df.grid_edge_distance((12, 9), (i, j), (True, False))
    far = d >= cutoff
    assert np.array_equal(out[far], P[far])
    # inside the cut-off every vertex moves along the displacement by at most its full length
    delta = out - P
    assert np.allclose(np.cross(delta.reshape(-1, 3), disp), 0.0, atol=1e-12)
    assert np.all(np.linalg.norm(delta, axis=-1) <= np.linalg.norm(disp) + 1e-12)


def test_warp_edges_on_mesh_and_wrap_neighbour():
    P = tube()
    out = df.warp(P, (0, 4), [0, 0, 1.0], cutoff=2, metric="edges", profile="linear",
                  wrap=(True, False))
    # across the seam (i = 11) is one edge away: weight 1 - 1/2
    assert np.isclose(out[11, 4, 2] - P[11, 4, 2], 0.5)
    assert np.isclose(out[1, 4, 2] - P[1, 4, 2], 0.5)
    assert np.array_equal(out[2, 4], P[2, 4])
    # the same through faces of a mesh
    V = P.reshape(-1, 3)
    faces = np.array([[0, 1, 2], [2, 3, 4]])
    out = df.warp(V[:5], 0, [1.0, 0, 0], 2, "edges", "linear", faces=faces)
    assert np.allclose(out[:, 0] - V[:5, 0], [1.0, 0.5, 0.5, 0.0, 0.0])
    with pytest.raises(ValueError):
        df.warp(V, 0, [1.0, 0, 0], 2, "edges")


# --------------------------------------------------------------------------------- taper

@settings(max_examples=40, deadline=None)
@given(k=st.floats(-0.2, 0.5), lo=st.floats(0.0, 1.5), span=st.floats(0.5, 2.0),
       axis=st.integers(0, 2))
def test_taper_scales_cross_sections_by_profile(k, lo, span, axis):
    P = np.roll(tube(), axis - 2, axis=-1)                   # tube along coordinate `axis`
    hi = lo + span
    out = df.taper(P, k, axis=axis, bounds=(lo, hi))
    z = P[..., axis]
    r = 1.0 + k * np.clip(z, lo, hi)
    across = [c for c in range(3) if c != axis]
    assert np.array_equal(out[..., axis], z)
    assert np.allclose(out[..., across], r[..., None] * P[..., across], atol=1e-12)
    # cross-section radius: 0.8 r(z)
    assert np.allclose(np.linalg.norm(out[..., across], axis=-1), 0.8 * r, atol=1e-12)


def test_taper_with_callable_profile():
    P = tube()
    out = df.taper(P, lambda z: np.exp(-z), axis=2)
    assert np.allclose(np.linalg.norm(out[..., :2], axis=-1), 0.8 * np.exp(-P[..., 2]))


# --------------------------------------------------------------------------------- twist

@settings(max_examples=40, deadline=None)
@given(rate=st.floats(-2.0, 2.0), lo=st.floats(0.0, 1.5), span=st.floats(0.5, 2.0))
def test_twist_turns_each_cross_section_by_theta(rate, lo, span):
    P = tube()
    hi = lo + span
    out = df.twist(P, rate, axis=2, bounds=(lo, hi))
    theta = rate * np.clip(P[..., 2], lo, hi)
    ang_in = np.arctan2(P[..., 1], P[..., 0])
    ang_out = np.arctan2(out[..., 1], out[..., 0])
    diff = np.angle(np.exp(1j * (ang_out - ang_in - theta)))
    assert np.allclose(diff, 0.0, atol=1e-12)
    assert np.allclose(np.linalg.norm(out[..., :2], axis=-1), 0.8, atol=1e-12)
    # beyond the upper bound the shape turns rigidly (pairwise distances kept)
    above = out[P[..., 2] >= hi]
    orig = P[P[..., 2] >= hi]
    if len(orig) > 1:
        d0 = np.linalg.norm(orig[:, None] - orig[None], axis=-1)
        d1 = np.linalg.norm(above[:, None] - above[None], axis=-1)
        assert np.allclose(d0, d1, atol=1e-12)


# ---------------------------------------------------------------------------------- bend

@settings(max_examples=50, deadline=None)
@given(k=st.floats(0.05, 2.0), y0=st.floats(-1.0, 1.0), lo=st.floats(-1.0, 0.0),
       span=st.floats(0.2, 3.0), offset=st.floats(-0.3, 0.3))
def test_bend_maps_line_to_arc_of_radius_one_over_k(k, y0, lo, span, offset):
    hi = lo + span
    y = np.linspace(lo - 1.0, hi + 1.0, 41)
    line = np.stack([np.full_like(y, 0.3), y, np.full_like(y, offset)], axis=1)
    out = df.bend(line, k, y0, (lo, hi), axis=1, toward=2)
    assert np.array_equal(out[:, 0], line[:, 0])              # third coordinate untouched
    inside = (y >= lo) & (y <= hi)
    # a line at height z = offset lies on the circle of radius 1/k - offset about (y0, 1/k)
    rad = np.hypot(out[inside, 1] - y0, out[inside, 2] - 1.0 / k)
    assert np.allclose(rad, 1.0 / k - offset, atol=1e-12)
    # the angle swept is k (y - y0): the axis (offset 0) keeps its length
    ang = np.arctan2(out[inside, 1] - y0, -(out[inside, 2] - 1.0 / k))
    assert np.allclose(np.angle(np.exp(1j * (ang - k * (y[inside] - y0)))), 0.0, atol=1e-12)
    # outside the bounds the line continues straight along the end tangent
    for part, end in ((y > hi, hi), (y < lo, lo)):
        if part.sum() > 1:
            seg = out[part]
            t = np.array([0.0, np.cos(k * (end - y0)), np.sin(k * (end - y0))])
            rel = seg - seg[0]
            assert np.allclose(np.cross(rel, t), 0.0, atol=1e-12)
            assert np.allclose(np.linalg.norm(rel, axis=1), np.abs(y[part] - y[part][0]),
                               atol=1e-12)


def test_bend_is_continuous_and_identity_for_zero_curvature():
    P = RNG.normal(size=(200, 3))
    assert np.allclose(df.bend(P, 0.0, 0.2, (-0.5, 0.5)), P, atol=1e-12)
    assert np.allclose(df.bend(P, 1e-9, 0.2, (-0.5, 0.5)), P, atol=1e-8)
    y = np.array([0.5 - 1e-9, 0.5 + 1e-9])
    pts = np.stack([np.zeros(2), y, np.full(2, 0.2)], 1)
    out = df.bend(pts, 1.3, 0.0, (-0.5, 0.5))
    assert np.linalg.norm(out[1] - out[0]) < 1e-8


def test_in_frame_bends_about_an_arbitrary_axis():
    Q, _ = np.linalg.qr(RNG.normal(size=(3, 3)))
    Q[:, 2] *= np.sign(np.linalg.det(Q))
    o = RNG.normal(size=3)
    local = tube()
    world = local @ Q.T + o
    out = df.in_frame(world, o, Q, df.bend, 0.7, 0.0, (0.0, 3.0), axis=2, toward=0)
    assert np.allclose(out, df.bend(local, 0.7, 0.0, (0.0, 3.0), axis=2, toward=0) @ Q.T + o,
                       atol=1e-12)
