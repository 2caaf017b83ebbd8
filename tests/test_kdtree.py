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
