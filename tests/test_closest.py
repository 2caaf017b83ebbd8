"""acra.closest: the compiled closest point on candidate triangles agrees with trimesh's numpy
version (the same algorithm and tolerance) pair by pair, keeps the first of equally near
candidates, and leaves points without candidates at infinity."""

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from acra import closest


def _reference(tri, points, starts, faces, scale):
    """The numpy route `pipeline.shape.Closest` took before: every pair through
    `trimesh.triangles.closest_point`, then each point's nearest (first among equals)."""
    k = len(points)
    lens = np.diff(starts)
    owner = np.repeat(np.arange(k), lens)
    dist, close, face = np.full(k, np.inf), np.zeros((k, 3)), np.zeros(k, np.int64)
    if not len(faces):
        return dist, close, face
    cp = scale * trimesh.triangles.closest_point(tri[faces] / scale, points[owner] / scale)
    d = np.linalg.norm(cp - points[owner], axis=1)
    order = np.lexsort((d, owner))
    first = order[np.r_[True, owner[order][1:] != owner[order][:-1]]]
    hit = owner[first]
    dist[hit], close[hit], face[hit] = d[first], cp[first], faces[first]
    return dist, close, face


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), scale=st.sampled_from([1e-3, 1.0, 1e4]))
def test_nearest_in_lists_matches_the_numpy_closest_point(seed, scale):
    """Random triangles (some with coincident corners: segments and points) and random candidate
    lists: the same distance, point and face as the numpy route, to rounding."""
    rng = np.random.default_rng(seed)
    tri = rng.normal(size=(60, 3, 3)) * scale
    tri[:5, 1] = tri[:5, 0]  # A = B: the segment AC
    tri[5:8, 2] = tri[5:8, 1] = tri[5:8, 0]  # a point
    points = rng.normal(size=(40, 3)) * 2 * scale
    lens = rng.integers(0, 12, len(points))
    starts = np.r_[0, np.cumsum(lens)].astype(np.int64)
    faces = rng.integers(0, len(tri), int(starts[-1])).astype(np.int64)
    d, c, f = closest.nearest_in_lists(tri, points, starts, faces, 3.0 * scale)
    rd, rc, rf = _reference(tri, points, starts, faces, 3.0 * scale)
    assert np.array_equal(np.isinf(d), lens == 0)
    some = lens > 0
    assert np.allclose(d[some], rd[some], rtol=0, atol=1e-12 * scale)
    assert np.allclose(c[some], rc[some], rtol=0, atol=1e-12 * scale)
    assert np.array_equal(f[some], rf[some])


def test_closest_point_regions_of_one_triangle():
    """The corner, edge and face regions of the unit right triangle, exactly."""
    tri = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]])
    points = np.array([[-1.0, -1.0, 0.0], [2.0, -0.5, 0.0], [-0.5, 2.0, 0.0], [0.5, -1.0, 0.0],
                       [-1.0, 0.5, 0.0], [1.0, 1.0, 0.0], [0.25, 0.25, 3.0]])
    want = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.5, 0.0, 0.0],
                     [0.0, 0.5, 0.0], [0.5, 0.5, 0.0], [0.25, 0.25, 0.0]])
    starts = np.arange(len(points) + 1, dtype=np.int64)
    d, c, f = closest.nearest_in_lists(tri, points, starts, np.zeros(len(points), np.int64), 1.0)
    assert np.array_equal(c, want)
    assert np.allclose(d, np.linalg.norm(points - want, axis=1), rtol=0, atol=1e-15)
    assert np.array_equal(f, np.zeros(len(points), np.int64))


def test_equally_near_candidates_keep_the_first_and_empty_lists_stay_infinite():
    """Two copies of one triangle: the first listed wins; a point without candidates is at inf."""
    tri = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]] * 2)
    points = np.array([[0.2, 0.2, 1.0], [5.0, 5.0, 5.0]])
    d, c, f = closest.nearest_in_lists(tri, points, np.array([0, 2, 2]), np.array([1, 0]), 1.0)
    assert f[0] == 1 and d[0] == pytest.approx(1.0, abs=1e-15) and np.allclose(c[0], [0.2, 0.2, 0.0], rtol=0, atol=1e-15)
    assert np.isinf(d[1]) and np.array_equal(c[1], np.zeros(3))
