"""Free-form deformation against closed forms: identity, affine maps, locality, composition
and the three animation modes."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pipeline.animation import ffd as F


def random_lattice(rng, divisions):
    axes = np.diag(rng.uniform(0.5, 2.0, 3)) + rng.uniform(-0.3, 0.3, (3, 3))   # skewed
    return F.make_lattice(rng.normal(size=3), *axes, divisions)


def inside_points(rng, lat, n=60):
    return lat.origin + rng.uniform(0, 1, (n, 3)) @ lat.axes


divisions = st.tuples(st.integers(1, 5), st.integers(1, 5), st.integers(1, 5))


@settings(max_examples=40, deadline=None)
@given(divisions, st.integers(0, 2**31 - 1))
def test_undeformed_lattice_is_identity(div, seed):
    rng = np.random.default_rng(seed)
    lat = random_lattice(rng, div)
    X = inside_points(rng, lat)
    assert np.abs(F.ffd(lat, F.lattice_points(lat), X) - X).max() < 1e-12


@settings(max_examples=40, deadline=None)
@given(divisions, st.integers(0, 2**31 - 1))
def test_affinely_moved_lattice_gives_that_affine_map(div, seed):
    rng = np.random.default_rng(seed)
    lat = random_lattice(rng, div)
    X = inside_points(rng, lat)
    A = rng.normal(size=(3, 3))
    b = rng.normal(size=3)
    Q = F.lattice_points(lat) @ A.T + b
    assert np.abs(F.ffd(lat, Q, X) - (X @ A.T + b)).max() < 1e-12


def test_local_coordinates_invert_the_lattice_frame():
    rng = np.random.default_rng(1)
    lat = random_lattice(rng, (2, 3, 4))
    stu = rng.uniform(-0.5, 1.5, (50, 3))
    X = lat.origin + stu @ lat.axes
    assert np.allclose(F.local_coordinates(lat, X), stu, atol=1e-12)
    with pytest.raises(ValueError):
        F.make_lattice([0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], (1, 1, 1))


def test_bernstein_partition_of_unity_and_linear_precision():
    t = np.linspace(0, 1, 11)
    for n in range(1, 7):
        B = F.bernstein(n, t)
        assert np.allclose(B.sum(-1), 1.0, atol=1e-14)
        assert np.allclose(B @ (np.arange(n + 1) / n), t, atol=1e-14)


def test_moving_one_control_point_moves_points_by_its_basis_weight():
    rng = np.random.default_rng(2)
    lat = random_lattice(rng, (3, 2, 4))
    X = inside_points(rng, lat)
    Q = F.lattice_points(lat)
    dP = np.array([0.3, -0.2, 0.5])
    Q2 = Q.copy()
    Q2[1, 2, 3] += dP
    stu = F.local_coordinates(lat, X)
    w = F.bernstein(3, stu[:, 0])[:, 1] * F.bernstein(2, stu[:, 1])[:, 2] * \
        F.bernstein(4, stu[:, 2])[:, 3]
    assert np.allclose(F.ffd(lat, Q2, X) - X, w[:, None] * dP, atol=1e-12)


def test_points_outside_keep_or_extrapolate():
    lat = F.make_lattice([0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], (2, 2, 2))
    Q = F.lattice_points(lat) * 2.0                              # uniform scale by 2 about 0
    X = np.array([[0.5, 0.5, 0.5], [1.5, 0.5, 0.5], [-0.1, 0.2, 0.2]])
    kept = F.ffd(lat, Q, X)
    assert np.allclose(kept, [[1, 1, 1], [1.5, 0.5, 0.5], [-0.1, 0.2, 0.2]])
    assert np.allclose(F.ffd(lat, Q, X, outside="extrapolate"), 2 * X)
    # works on a (nu, nv, 3) grid as well
    grid = np.random.default_rng(3).uniform(0, 1, (4, 5, 3))
    assert np.allclose(F.ffd(lat, Q, grid), 2 * grid)


def test_sequential_composition_composes_maps():
    rng = np.random.default_rng(4)
    lat1 = F.make_lattice([-1, -1, -1], [4, 0, 0], [0, 4, 0], [0, 0, 4], (2, 3, 2))
    lat2 = F.make_lattice([-5, -5, -5], [10, 0, 0], [0, 10, 0], [0, 0, 10], (3, 3, 3))
    A1, A2 = np.eye(3) + 0.2 * rng.normal(size=(3, 3)), np.eye(3) + 0.2 * rng.normal(size=(3, 3))
    stages = [(lat1, F.lattice_points(lat1) @ A1.T), (lat2, F.lattice_points(lat2) @ A2.T)]
    X = rng.uniform(-0.5, 2.5, (30, 3))
    assert np.allclose(F.ffd_sequence(X, stages), X @ A1.T @ A2.T, atol=1e-12)
    # and a non-linear first stage is followed exactly by the second
    Q1 = F.lattice_points(lat1) + 0.3 * rng.normal(size=(3, 4, 3, 3))
    stages[0] = (lat1, Q1)
    assert np.allclose(F.ffd_sequence(X, stages), F.ffd(lat1, Q1, X) @ A2.T, atol=1e-12)


def test_animation_morph_object_through_lattice_and_lattice_through_object():
    lat = F.make_lattice([0, 0, 0], [4, 0, 0], [0, 1, 0], [0, 0, 1], (4, 2, 2))
    ref = F.lattice_points(lat)
    bump = ref.copy()
    bump[2, 1, 2, 2] += 0.8                                        # the "mouse under the rug"
    X = np.stack(np.meshgrid(np.linspace(-3, 7, 21), np.linspace(0, 1, 5), [1.0],
                             indexing="ij"), -1).reshape(-1, 3)
    # morph between reference and deformed: FFD is linear in the control points
    alphas = np.array([0.0, 0.25, 1.0])
    frames = F.ffd_frames(lat, X, F.morph_lattice(ref, bump, alphas))
    full = F.ffd(lat, bump, X)
    for a, fr in zip(alphas, frames):
        assert np.allclose(fr, (1 - a) * X + a * full, atol=1e-12)
    # moving the object through the fixed deformed lattice
    offs = np.array([[0.0, 0, 0], [1.5, 0, 0]])
    fr = F.ffd_frames(lat, X, bump, object_offsets=offs)
    assert np.allclose(fr[1], F.ffd(lat, bump, X + offs[1]), atol=1e-12)
    # moving the lattice through the object: the bump travels, the rest stays put
    fr = F.ffd_frames(lat, X, bump, lattice_offsets=offs)
    assert np.allclose(fr[1], F.ffd(lat, bump, X - offs[1]) + offs[1], atol=1e-12)
    moved0 = np.linalg.norm(fr[0] - X, axis=1) > 1e-9
    moved1 = np.linalg.norm(fr[1] - X, axis=1) > 1e-9
    assert np.isclose(X[moved1, 0].mean() - X[moved0, 0].mean(), 1.5, atol=0.3)
    assert np.all((X[moved1, 0] > 1.5) & (X[moved1, 0] < 5.5))
    with pytest.raises(ValueError):
        F.ffd_frames(lat, X, bump)                                 # nothing per frame


def test_lattice_around_contains_points():
    P = np.random.default_rng(6).normal(size=(40, 3))
    lat = F.lattice_around(P, (2, 2, 2), padding=0.1)
    stu = F.local_coordinates(lat, P)
    assert np.all((stu > 0) & (stu < 1))
    assert F.lattice_points(lat).shape == (3, 3, 3, 3)
