"""`acra.nearest`: trimesh's closest-point arithmetic compiled, and the BVH search over it."""

import numpy as np
import pytest
import trimesh

from acra import nearest as N


def _triangles(rng, n):
    """Random triangles with every degenerate kind trimesh's regions meet, and points near,
    on the corners of and on the edges of them."""
    tri = rng.standard_normal((n, 3, 3))
    q = n // 10
    tri[:q, 1] = tri[:q, 0]  # a = b: trimesh's segment rule
    tri[q:2 * q, 2] = tri[q:2 * q, 0]  # a = c
    tri[2 * q:3 * q, 2] = tri[2 * q:3 * q, 1]  # b = c
    tri[3 * q:4 * q] = tri[3 * q:4 * q, :1]  # a point
    tri[4 * q:5 * q] *= 1e-7  # tiny against the tolerance of the region tests
    pts = rng.standard_normal((n, 3)) * rng.choice([1e-3, 0.3, 1.0, 5.0], (n, 1))
    pts[5 * q:6 * q] = tri[5 * q:6 * q, 0]
    pts[6 * q:7 * q] = 0.5 * (tri[6 * q:7 * q, 0] + tri[6 * q:7 * q, 1])
    pts[7 * q:8 * q] = tri[7 * q:8 * q].mean(axis=1)
    return tri, pts


@pytest.mark.parametrize("unit", [1.0, 0.37, 123.0])
def test_closest_points_are_trimesh_bits(unit):
    """`closest_points` gives ``unit * trimesh.triangles.closest_point(tri / unit, p / unit)``
    and its norm bit for bit, degenerate triangles included."""
    rng = np.random.default_rng(int(unit * 100))
    tri, pts = _triangles(rng, 20000)
    ref = unit * trimesh.triangles.closest_point(tri / unit, pts / unit)
    dist, close = N.closest_points(tri, pts, unit)
    assert np.array_equal(close, ref)
    assert np.array_equal(dist, np.linalg.norm(ref - pts, axis=1))


def _every_triangle(tri, pts, unit):
    """The answer of testing every triangle: least distance, lowest row among equal ones."""
    out = []
    for p in pts:
        cp = unit * trimesh.triangles.closest_point(tri / unit, np.tile(p / unit, (len(tri), 1)))
        d = np.linalg.norm(cp - p, axis=1)
        best = int(np.lexsort((np.arange(len(d)), d))[0])
        out.append((d[best], cp[best], best))
    return out


@pytest.mark.parametrize("seed", range(3))
def test_query_is_every_triangle_s_answer(seed):
    """`query` on a grid of triangles sharing corners and edges (ties at every grid vertex and
    edge) answers as testing every triangle does, bit for bit, far, near and on the grid; with a
    bound, the same where the answer is within it and ``inf`` where it is not."""
    rng = np.random.default_rng(seed)
    n = 12
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, n + 1), np.linspace(0.2, np.pi - 0.2, n + 1), indexing="ij")
    grid = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], -1) * (1 + 0.05 * rng.normal(size=u.shape))[..., None]
    ids = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = ids[:-1, :-1].ravel(), ids[1:, :-1].ravel(), ids[1:, 1:].ravel(), ids[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    verts = grid.reshape(-1, 3)
    tri = verts[faces]
    unit = float(np.ptp(verts, axis=0).max())
    pts = np.concatenate([1.5 * rng.normal(size=(60, 3)), verts[rng.integers(0, len(verts), 30)],
                          tri[rng.integers(0, len(tri), 30), :2].mean(axis=1), 0.01 * rng.normal(size=(10, 3))])
    idx = N.index(tri, unit)
    dist, close, face = N.query(idx, pts)
    for i, (d, cp, f) in enumerate(_every_triangle(tri, pts, unit)):
        assert (dist[i], face[i]) == (d, f)
        assert np.array_equal(close[i], cp)
    bound = dist * rng.choice([0.5, 1.0, 2.0], len(dist))
    bd, bc, bf = N.query(idx, pts, bound)
    within = dist <= bound
    assert np.array_equal(bd[within], dist[within]) and np.array_equal(bf[within], face[within])
    assert np.array_equal(bc[within], close[within])
    assert np.isinf(bd[~within]).all()


@pytest.mark.parametrize("offset", [0.0, 1e3])
def test_query_keeps_every_tied_triangle_in_reach(offset):
    """A flat grid (every vertex shared by up to six triangles at the same distance, every edge by
    two), at the origin and 1e3 of its extent away from it: each triangle's box is within the
    reach of a point on a vertex or an edge above it, so `query` measures every tied triangle and
    answers as testing every triangle does, bit for bit (the lowest row among equal distances)."""
    rng = np.random.default_rng(7)
    n = 8
    x, y = np.meshgrid(np.arange(n + 1.0), np.arange(n + 1.0), indexing="ij")
    verts = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1) + offset
    ids = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = ids[:-1, :-1].ravel(), ids[1:, :-1].ravel(), ids[1:, 1:].ravel(), ids[:-1, 1:].ravel()
    tri = verts[np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])]
    on = verts[rng.integers(0, len(verts), 20)] + [0.0, 0.0, 0.5]
    edge = 0.5 * (tri[:20, 0] + tri[:20, 1]) + [0.0, 0.0, -0.25]
    pts = np.concatenate([on, edge, offset + rng.uniform(-1.0, n + 1.0, (20, 3))])
    dist, close, face = N.query(N.index(tri, float(n)), pts)
    for i, (dd, cp, f) in enumerate(_every_triangle(tri, pts, float(n))):
        assert (dist[i], face[i]) == (dd, f)
        assert np.array_equal(close[i], cp)


@pytest.mark.parametrize("seed", range(3))
def test_refit_answers_as_a_new_build(seed):
    """An `Index` whose tree is refitted from the triangles before they moved (``like``, part of
    them moved far, so the old Z-order no longer fits) has the boxes of its leaves' triangles and
    answers as one built anew, bit for bit, with and without a bound."""
    rng = np.random.default_rng(seed)
    tri, pts = _triangles(rng, 3000)
    old = N.index(tri, 2.0)
    moved = tri.copy()
    moved[rng.random(len(tri)) < 0.3] += rng.normal(size=3)
    moved += 1e-3 * rng.normal(size=moved.shape)
    fresh, refit = N.index(moved, 2.5), N.index(moved, 2.5, like=old)
    tree = refit.tree
    assert np.array_equal(tree.order, old.tree.order) and np.array_equal(tree.leaf_tri, moved[tree.order])
    for node in np.nonzero(tree.left < 0)[0]:
        leaf = moved[tree.order[tree.start[node]:tree.start[node] + tree.count[node]]].reshape(-1, 3)
        assert np.array_equal(tree.lo[node], leaf.min(axis=0)) and np.array_equal(tree.hi[node], leaf.max(axis=0))
    for bound in (None, rng.uniform(0.0, 1.0, len(pts))):
        for a, b in zip(N.query(fresh, pts, bound), N.query(refit, pts, bound)):
            assert np.array_equal(a, b)


def test_corners_are_numpys_fancy_index():
    rng = np.random.default_rng(3)
    v, f = rng.standard_normal((500, 3)), rng.integers(0, 500, (800, 3))
    for faces in (f, f.astype(np.int32), f[:0]):
        got = N.corners(v, faces)
        assert got.shape == v[faces].shape and got.dtype == v[faces].dtype
        np.testing.assert_array_equal(got, v[faces])


def test_face_uv_is_trimesh_barycentric_einsum_and_clip():
    """`face_uv` gives ``np.clip(np.einsum("kj,kjc->kc", points_to_barycentric(...), uv[tri]),
    lo[face], hi[face])`` bit for bit (NaN where trimesh's is): closest points on, near and off
    the faces, degenerate faces, negative and zero parameters (signed zeros), clipped and not."""
    rng = np.random.default_rng(7)
    for trial in range(60):
        tri_pts, pts = _triangles(rng, 400)
        points = tri_pts.reshape(-1, 3) * rng.choice([1e-3, 1.0, 1e3])
        faces = np.arange(len(points)).reshape(-1, 3)
        uv = rng.random((len(points), 2)) * rng.choice([1.0, 16.0])
        uv[rng.random(len(uv)) < 0.2] = 0.0
        uv[rng.random(len(uv)) < 0.05] *= -1.0
        face = rng.integers(0, len(faces), 900)
        w = rng.random((900, 3))
        w[rng.random(900) < 0.3, 0] = 0.0
        w /= w.sum(axis=1, keepdims=True)
        close = np.einsum("kj,kjc->kc", w, points[faces[face]]) + rng.normal(size=(900, 3)) * rng.choice([0.0, 1e-12, 1e-3])
        lo = uv[faces].min(axis=1) + rng.choice([0.0, 0.05])
        hi = np.maximum(uv[faces].max(axis=1) - rng.choice([0.0, 0.05]), lo)
        with np.errstate(all="ignore"):
            bary = trimesh.triangles.points_to_barycentric(points[faces[face]], close)
            want = np.clip(np.einsum("kj,kjc->kc", bary, uv[faces[face]]), lo[face], hi[face])
        got = N.face_uv(points, uv, faces, face, close, lo, hi)
        same = (got == want) & (np.signbit(got) == np.signbit(want)) | (np.isnan(got) & np.isnan(want))
        assert same.all(), trial


@pytest.mark.parametrize("seed", range(4))
def test_candidates_are_the_array_steps(seed):
    """`candidates` gives the rows `acra.halfspaces.within` keeps, and the patch rows of the
    coarse bound's box overlap then `acra.patch_boxes.boxes_within`, for a plain tree, a masked
    tree with an extra one, no hull, an empty hull pass and an empty tree, bit for bit."""
    from scipy.spatial import ConvexHull

    from acra import halfspaces, kdtree
    from acra.bvh import bounds
    from acra.patch_boxes import boxes_within
    from pipeline.grids import overlap

    rng = np.random.default_rng(seed)
    for trial in range(40):
        coarse = rng.standard_normal((int(rng.integers(1, 300)), 3))
        hull = None if trial % 4 == 0 else ConvexHull(rng.standard_normal((30, 3))).equations
        q = rng.standard_normal((int(rng.integers(1, 120)), 3)) * rng.choice([0.3, 1.0, 3.0])
        centre = rng.standard_normal((int(rng.integers(1, 60)), 3)) * 1.5
        half = np.abs(rng.standard_normal(centre.shape)) * 0.2
        lo, hi = centre - half, centre + half
        tree, keep, extra = kdtree.build(coarse), None, None
        if trial % 3 == 1:
            keep = rng.random(len(coarse)) < 0.7
            extra = kdtree.build(coarse[~keep] + 0.01)
        if trial % 11 == 5:
            tree = kdtree.build(np.zeros((0, 3)))
        slack = float(rng.choice([0.0, 1e-9, 0.1]))
        # the array form, step by step
        rows = np.arange(len(q)) if hull is None else np.nonzero(halfspaces.within(hull, q, slack))[0]
        qc = q[rows]
        want = np.zeros(0, np.int64)
        if len(qc):
            best = None if extra is None else kdtree.nearest_squares(extra, qc)
            upper = np.sqrt(kdtree.nearest_squares(tree, qc, keep, best))
            size = np.abs(qc).max(axis=1)
            reach = upper.max() * (1 + 1e-9) + N.ROUNDING * size.max() + 1e-300
            qlo, qhi = bounds(qc)
            pre = np.nonzero(overlap(lo, hi, qlo - reach, qhi + reach, 0.0))[0]
            want = pre[boxes_within(lo[pre], hi[pre], qc, upper * (1 + 1e-9) + N.ROUNDING * size + 1e-300)]
        got_rows, got_q, got = N.candidates(q, hull, slack, extra, tree, keep, lo, hi)
        np.testing.assert_array_equal(got_rows, rows)
        np.testing.assert_array_equal(got_q, qc)
        np.testing.assert_array_equal(got, want)


def test_a_point_on_a_flat_patch_finds_its_box_through_the_last_bits():
    """A flat patch's box has no thickness: a point evaluated on it, at its coarse point
    (distance 0), lies off the box by its last bits, and still gets the patch."""
    from acra import kdtree

    z = 0.03846435624
    lo, hi = np.array([[-3.0, -3.0, z]]), np.array([[3.0, 3.0, z]])
    q = np.array([[0.0, 0.0, np.nextafter(z, 1.0)]])
    tree = kdtree.build(q.copy())
    rows, qc, patches = N.candidates(q, None, 0.0, None, tree, None, lo, hi)
    np.testing.assert_array_equal(patches, [0])
    far = np.array([[0.0, 0.0, z + 1e-9]])  # a real gap: a coarse point there, the box out of reach
    _, _, none = N.candidates(far, None, 0.0, None, kdtree.build(far.copy()), None, lo, hi)
    assert none.size == 0


def test_tree_boxes_are_their_triangles_boxes():
    """A built or refitted tree's node boxes are the minima and maxima of the corners of the
    triangles under the node, and its leaf triangles are ``tri[order]``, bit for bit."""
    rng = np.random.default_rng(7)
    tri, _ = _triangles(rng, 700)
    moved = tri + rng.standard_normal(tri.shape) * 0.1
    built = N.build(tri)
    for tree, t in ((built, tri), (N.refit(built, moved), moved)):
        np.testing.assert_array_equal(tree.leaf_tri, t[tree.order])

        def under(node):
            if tree.left[node] < 0:
                return list(tree.order[tree.start[node]:tree.start[node] + tree.count[node]])
            return under(tree.left[node]) + under(tree.right[node])

        for node in range(len(tree.lo)):
            corners = t[under(node)].reshape(-1, 3)
            np.testing.assert_array_equal(tree.lo[node], corners.min(axis=0))
            np.testing.assert_array_equal(tree.hi[node], corners.max(axis=0))
