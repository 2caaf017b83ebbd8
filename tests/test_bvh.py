"""acra.bvh: exact closest points on triangle sets, against a brute force over every triangle."""

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import soup

from acra import bvh


def brute(tri: np.ndarray, points: np.ndarray):
    """Distances ``(k,)`` and the lowest row among the nearest triangles ``(k,)``, over all of ``tri``."""
    t = np.repeat(tri[None], len(points), axis=0).reshape(-1, 3, 3)
    p = np.repeat(points, len(tri), axis=0)
    d = np.linalg.norm(trimesh.triangles.closest_point(t, p) - p, axis=1).reshape(len(points), len(tri))
    return d.min(axis=1), d.argmin(axis=1)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.integers(0, 10_000), st.integers(1, 60))
def test_closest_equals_the_brute_force(seed, n):
    tri = soup(seed, n)
    points = np.random.default_rng(seed + 1).uniform(-2, 2, (50, 3))
    dist, close, face, bary = bvh.closest(bvh.build(tri), points)
    d_ref, _ = brute(tri, points)
    np.testing.assert_allclose(dist, d_ref, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(close - points, axis=1), dist, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(np.einsum("kj,kjc->kc", bary, tri[face]), close, atol=1e-12)
    np.testing.assert_allclose(bary.sum(axis=1), 1.0, atol=1e-12)
    assert np.all(bary >= -1e-12)


def test_ties_go_to_the_lowest_row_and_corners_have_exact_weights():
    """Two copies of one triangle: the lower row wins. A point beyond a corner gets weights
    exactly (1, 0, 0); one beside an edge exactly 0 on the opposite corner."""
    t = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    tri = np.stack([t + [5, 5, 5], t, t])  # rows 1 and 2 equal
    dist, close, face, bary = bvh.closest(bvh.build(tri), np.array([[-1.0, -1, 0.3], [0.5, -1, 0.0], [0.2, 0.2, 1.0]]))
    assert list(face) == [1, 1, 1]
    np.testing.assert_array_equal(bary[0], [1.0, 0.0, 0.0])
    assert bary[1][2] == 0.0 and bary[1][0] == pytest.approx(0.5)
    assert np.all(bary[2] > 0) and dist[2] == pytest.approx(1.0)


def test_a_bound_leaves_farther_points_unanswered():
    tri = soup(3, 20)
    points = np.array([[0.0, 0.0, 0.0], [50.0, 0.0, 0.0]])
    d_ref, _ = brute(tri, points)
    dist, _, face, _ = bvh.closest(bvh.build(tri), points, np.array([np.inf, 10.0]))
    assert dist[0] == pytest.approx(d_ref[0], rel=1e-12) and face[0] >= 0
    assert dist[1] == np.inf and face[1] == -1


def test_distances_to_given_triangles():
    tri = soup(7, 30)
    points = np.random.default_rng(8).uniform(-2, 2, (30, 3))
    expected = np.linalg.norm(trimesh.triangles.closest_point(tri, points) - points, axis=1)
    np.testing.assert_allclose(bvh.distances(points, tri), expected, rtol=1e-12, atol=1e-14)


def test_an_empty_set_is_refused():
    with pytest.raises(ValueError, match="at least one triangle"):
        bvh.build(np.zeros((0, 3, 3)))


def test_build_takes_numpys_boxes_and_centroids():
    tri = soup(7, 5000) * 10.0 ** np.random.default_rng(7).integers(-4, 4, (5000, 1, 1))
    lo, hi, cen = bvh._boxes_centroids(np.ascontiguousarray(tri))
    np.testing.assert_array_equal(lo, tri.min(axis=1))
    np.testing.assert_array_equal(hi, tri.max(axis=1))
    np.testing.assert_array_equal(cen, tri.mean(axis=1))


def test_bounds_are_numpys_minima_and_maxima():
    p = soup(3, 2000).reshape(-1, 3)
    np.testing.assert_array_equal(bvh.bounds(p), np.stack([p.min(axis=0), p.max(axis=0)]))
    np.testing.assert_array_equal(bvh.bounds(p[:1]), np.stack([p[0], p[0]]))
    with pytest.raises(ValueError):
        bvh.bounds(np.zeros((0, 3)))


@pytest.mark.parametrize("row", [0, 1, 999])
def test_bounds_propagate_a_nan_as_numpy_does(row):
    p = soup(4, 1000).reshape(-1, 3)[:1000].copy()
    p[row, 1], p[500, 2] = np.nan, np.inf
    expected = np.stack([p.min(axis=0), p.max(axis=0)])
    assert np.isnan(expected[:, 1]).all() and expected[1, 2] == np.inf
    np.testing.assert_array_equal(bvh.bounds(p), expected)


def _tree_sorting_every_node(tri: np.ndarray):
    """The tree `bvh.build` stands for, in numpy: each node's triangles sorted stably by their
    centroids along the longest side of its centroid box, split at the median; its box from its
    triangles. Returns ``(order, lo, hi, left, right, start, count)``."""
    lo_t, hi_t, cen = tri.min(axis=1), tri.max(axis=1), tri.mean(axis=1)
    order = np.arange(len(tri))
    nodes = [None] * (2 * len(tri) + 1)
    stack, used = [(0, 0, len(tri))], 1
    while stack:
        node, a, b = stack.pop()
        rows = order[a:b]
        box = (lo_t[rows].min(axis=0), hi_t[rows].max(axis=0))
        if b - a <= bvh.LEAF:
            nodes[node] = (*box, -1, -1, a, b - a)
            continue
        extent = cen[rows].max(axis=0) - cen[rows].min(axis=0)
        axis = max(range(3), key=lambda k: (extent[k], -k))
        order[a:b] = rows[np.argsort(cen[rows, axis], kind="stable")]
        mid = (a + b) // 2
        nodes[node] = (*box, used, used + 1, a, 0)
        stack += [(used, a, mid), (used + 1, mid, b)]
        used += 2
    lo, hi, left, right, start, count = (np.array(x) for x in zip(*nodes[:used]))
    return order, lo, hi, left, right, start, count


@pytest.mark.parametrize("case", ["soup", "grid", "ties"])
def test_build_is_the_tree_that_sorts_every_node(case):
    """The build selects each node's first half (`bvh._select`) instead of sorting the node; runs
    of equal centroids (a grid's columns, repeated triangles) are ordered as a stable sort of the
    node orders them, by the ancestors' axes, then the row (`bvh._before`)."""
    rng = np.random.default_rng(5)
    if case == "soup":
        tri = soup(11, 3000)
    elif case == "grid":
        g = np.stack(np.meshgrid(np.arange(40.0), np.arange(30.0), [0.0], indexing="ij"), -1).reshape(-1, 3)
        tri = np.stack([g, g + [1.0, 0, 0], g + [0, 1.0, 0.5]], axis=1)
    else:
        tri = np.round(rng.normal(size=(400, 3, 3)), 1)[rng.integers(0, 400, 2500)]
    tree = bvh.build(tri)
    order, lo, hi, left, right, start, count = _tree_sorting_every_node(tri)
    np.testing.assert_array_equal(tree.order, order)
    np.testing.assert_array_equal(tree.lo, lo)  # as numbers: a zero's sign may differ
    np.testing.assert_array_equal(tree.hi, hi)
    for x, y in ((tree.left, left), (tree.right, right), (tree.start, start), (tree.count, count)):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("k", [0, 1, 63, 64, 1000, 20000])
def test_stable_order_is_numpys_merge_sort(k):
    from acra.bvh import _stable_order
    rng = np.random.default_rng(k)
    for top in (3, 1 << 30):  # many equal keys, then few
        key = rng.integers(0, top, k).astype(np.int64)
        np.testing.assert_array_equal(_stable_order(key), np.argsort(key, kind="mergesort"))


def _as_mesh(tri: np.ndarray):
    """``tri (f, 3, 3)`` as vertices ``(3f, 3)`` and faces ``(f, 3)``."""
    return tri.reshape(-1, 3), np.arange(3 * len(tri)).reshape(-1, 3)


def _check_tree(tree: bvh.Tree, tri: np.ndarray) -> None:
    """Every triangle in one leaf of at most `LEAF`, each box the least holding its triangles or
    its children's boxes, ``leaf_tri`` the triangles in leaf order."""
    np.testing.assert_array_equal(np.sort(tree.order), np.arange(len(tri)))
    np.testing.assert_array_equal(tree.leaf_tri, tri[tree.order])
    np.testing.assert_array_equal(tree.tri, tri)
    seen = np.zeros(len(tri), int)
    for node in range(len(tree.lo)):
        if tree.left[node] < 0:
            rows = tree.order[tree.start[node]:tree.start[node] + tree.count[node]]
            assert 1 <= len(rows) <= bvh.LEAF
            seen[rows] += 1
            lo, hi = tri[rows].min(axis=(0, 1)), tri[rows].max(axis=(0, 1))
        else:
            kids = [tree.left[node], tree.right[node]]
            assert min(kids) > node
            lo, hi = tree.lo[kids].min(axis=0), tree.hi[kids].max(axis=0)
        np.testing.assert_array_equal(tree.lo[node], lo)
        np.testing.assert_array_equal(tree.hi[node], hi)
    np.testing.assert_array_equal(seen, 1)


@pytest.mark.parametrize("case", ["soup", "grid", "ties", "one"])
def test_the_linear_tree_gives_the_median_trees_answers_to_the_bit(case):
    """`bvh.build_linear`'s tree (Z-order cells) is another tree over the same triangles:
    `closest` answers the same distances, points, rows and weights, bit for bit, as on `build`'s,
    with a bound and without, on random points and on points at the triangles (ties between
    neighbours)."""
    rng = np.random.default_rng(13)
    if case == "soup":
        tri = soup(11, 3000)
    elif case == "grid":
        g = np.stack(np.meshgrid(np.arange(40.0), np.arange(30.0), [0.0], indexing="ij"), -1).reshape(-1, 3)
        tri = np.stack([g, g + [1.0, 0, 0], g + [0, 1.0, 0.5]], axis=1)
    elif case == "ties":
        tri = np.round(rng.normal(size=(400, 3, 3)), 1)[rng.integers(0, 400, 2500)]
    else:
        tri = soup(2, 1)
    tree = bvh.build_linear(*_as_mesh(tri))
    _check_tree(tree, tri)
    lo, hi = tri.min(axis=(0, 1)), tri.max(axis=(0, 1))
    points = np.concatenate([rng.uniform(lo - 0.2 * (hi - lo), hi + 0.2 * (hi - lo), (2000, 3)),
                             tri.reshape(-1, 3)[rng.integers(0, 3 * len(tri), 500)],
                             tri.mean(axis=1)[rng.integers(0, len(tri), 500)]])
    for bound in (None, np.full(len(points), 0.05 * float(np.linalg.norm(hi - lo)))):
        want = bvh.closest(bvh.build(tri), points, bound)
        got = bvh.closest(tree, points, bound)
        for x, y in zip(got, want):
            np.testing.assert_array_equal(x, y)
    d_ref, _ = brute(tri, points[:300])
    dist = bvh.closest(tree, points[:300])[0]
    np.testing.assert_allclose(dist, d_ref, rtol=1e-12, atol=1e-14)


def test_a_part_tree_is_the_linear_tree_with_the_vertex_normals_and_box():
    """`bvh.part_tree` gives, in one call, `pseudonormals.vertex_normals`, `bounds` and
    `build_linear`'s tree of the same mesh, bit for bit."""
    from acra import pseudonormals

    rng = np.random.default_rng(5)
    v = rng.normal(size=(300, 3))
    f = rng.integers(0, 300, (500, 3))
    normals, angle = rng.normal(size=(500, 3)), rng.uniform(0.0, 3.0, (500, 3))
    vn, box, tree = bvh.part_tree(v, f, normals, angle)
    np.testing.assert_array_equal(vn, pseudonormals.vertex_normals(len(v), f, normals, angle))
    np.testing.assert_array_equal(box, bvh.bounds(v))
    want = bvh.build_linear(v, f)
    for name in ("tri", "order", "lo", "hi", "left", "right", "start", "count", "leaf_tri"):
        np.testing.assert_array_equal(getattr(tree, name), getattr(want, name))
        assert getattr(tree, name).flags.c_contiguous or getattr(tree, name).ndim == 1


def test_a_point_triangle_test_on_tuples_is_the_test_on_rows_to_the_bit():
    """The walks read points and corners as tuples (`pseudonormals._row`, `_corner`): the closest
    point and weights are the bits the same test gives on row arrays, in each Voronoi region of a
    triangle and on a degenerate one."""
    from acra import pseudonormals

    rng = np.random.default_rng(9)
    tri = rng.normal(size=(300, 3, 3))
    tri[:20, 2] = tri[:20, 1]  # two corners alike
    tri[20:30] = tri[20:30, :1]  # a point
    points = rng.normal(size=(300, 3)) * 2.0
    for i in range(len(tri)):
        rows = bvh._point_triangle(points[i], tri[i, 0], tri[i, 1], tri[i, 2])
        tuples = bvh._point_triangle(pseudonormals._row(points, i), *(pseudonormals._corner(tri, i, k) for k in range(3)))
        assert np.array_equal(np.float64(rows).view(np.uint64), np.float64(tuples).view(np.uint64))


def test_the_linear_tree_refuses_an_empty_set():
    with pytest.raises(ValueError, match="at least one triangle"):
        bvh.build_linear(np.zeros((3, 3)), np.zeros((0, 3), np.int64))


def test_morton_keys_interleave_each_axis_bit_by_bit():
    """`_morton_keys`' masked shifts put bit ``b`` of axis ``a``'s 10-bit step at bit ``3 b + a``,
    as a loop over the bits does."""
    q = np.arange(1024)
    loop = np.zeros(1024, np.int64)
    for bit in range(10):
        loop |= ((q >> bit) & 1) << (3 * bit)
    assert [bvh._spread(int(x)) for x in q] == loop.tolist()
    pts = np.random.default_rng(0).normal(size=(500, 3))
    lo, span = pts.min(axis=0), np.ptp(pts, axis=0)
    steps = np.clip((((pts - lo) / span) * 1023.0).astype(np.int64), 0, 1023)
    want = sum(loop[steps[:, a]] << a for a in range(3))
    assert np.array_equal(bvh._morton_keys(pts), want)


