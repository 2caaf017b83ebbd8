"""`acra.kdtree`: distances to the nearest of a point set, the same bits as scipy's cKDTree."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from acra import kdtree as K


@pytest.mark.parametrize("n", [0, 1, 5, 9, 100, 1296, 5000])
def test_distances_are_cKDTree_s_with_and_without_a_mask(n):
    """Points on a sphere (a closed surface's coarse sample: queries inside are far from all of
    them), a third rounded to 0.1 (ties and equal coordinates), some repeated; queries inside,
    outside and on the points. Masked: the kept points and a small second tree of other points,
    as one cKDTree of both."""
    rng = np.random.default_rng(n)
    p = rng.normal(size=(n, 3))
    p /= np.maximum(np.linalg.norm(p, axis=1), 1e-300)[:, None]
    p *= [1.0, 2.0, 0.5]
    p[: n // 3] = np.round(p[: n // 3], 1)
    p[n // 2: n // 2 + n // 10] = p[: n // 10]
    q = np.concatenate([rng.normal(size=(2000, 3)) * 0.4, rng.normal(size=(500, 3)) * 3, p[:50]])
    tree = K.build(p)
    if n:
        np.testing.assert_array_equal(np.sqrt(K.nearest_squares(tree, q)), cKDTree(p).query(q)[0])
    else:
        assert np.isinf(K.nearest_squares(tree, q)).all()
    keep = rng.random(n) < 0.6
    extra = rng.normal(size=(7, 3))
    best = K.nearest_squares(K.build(extra), q)
    got = np.sqrt(K.nearest_squares(tree, q, keep, best))
    np.testing.assert_array_equal(got, cKDTree(np.concatenate([p[keep], extra])).query(q)[0])
    # a leaf holds at most LEAF points, and the leaves hold every point once
    leaves = tree.left < 0
    assert (tree.stop[leaves] - tree.start[leaves] <= K.LEAF).all() or n == 0 or len(np.unique(p, axis=0)) == 1
    assert np.array_equal(np.sort(tree.order), np.arange(n))


def test_thin_greedy_is_the_array_form_s_pass():
    """`kdtree.thin_greedy`: each kept row drops the later rows within the radius, the pairs'
    squared offsets summed in coordinate order as the array form sums them (``(g, g)`` arrays of
    ``p_i - p_j`` per coordinate, then a greedy pass over the rows): the same rows kept, on
    seeded points, crowds of nearly equal points (a pole) and rows already dropped."""
    def array_form(points, radius, keep):
        d = [points[:, None, c] - points[None, :, c] for c in range(3)]
        close = np.triu(d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= radius * radius, 1)
        for i in np.nonzero(close.any(axis=1))[0].tolist():
            if keep[i]:
                keep &= ~close[i]
        return keep

    rng = np.random.default_rng(5)
    for trial in range(300):
        n = int(rng.integers(0, 120))
        pts = rng.random((n, 3)) * rng.choice([1e-3, 1.0, 1e3])
        if trial % 3 == 0:
            pts[: n // 2] = pts[0] + rng.random((n // 2, 3)) * 1e-9 if n else pts[: n // 2]
        radius = float(rng.random() * (pts.std() if n else 1.0) * 0.5)
        keep = rng.random(n) < 0.9
        want = array_form(pts, radius, keep.copy())
        got = K.thin_greedy(pts, radius, keep.copy())
        np.testing.assert_array_equal(got, want)
    assert not K.thin_greedy(np.zeros((4, 3)), 0.0, np.ones(4, bool))[1:].any()  # equal points: the first kept
