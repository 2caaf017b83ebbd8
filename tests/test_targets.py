"""acra.targets: data points' grouping per finest absorbing patch (eq. 4.16)."""

import numpy as np

from acra import hspline as H
from acra import shapes
from acra.targets import patch_groups, region_deepest, region_midpoints


def test_region_midpoints_average_across_a_periodic_seam():
    hs = H.from_grid(*shapes.torus(8, 6))
    uv = np.array([[7.9, 1.2], [0.1, 1.4], [0.05, 1.3]])
    mids, patches = region_midpoints(hs, uv, 0)
    # 7.9 is in patch 7, the others in patch 0
    assert patches.tolist() == [[0, 1], [7, 1]]
    np.testing.assert_allclose(mids[0], [0.075, 1.35], atol=1e-9)


def test_region_deepest_picks_each_patchs_deepest_sample_in_midpoint_order():
    hs = H.from_grid(*shapes.torus(8, 6))
    uv = np.array([[7.9, 1.2], [0.1, 1.4], [0.05, 1.3], [3.5, 2.5], [3.2, 2.1]])
    depth = np.array([0.3, 0.1, 0.2, 0.05, 0.07])
    _, patches = region_midpoints(hs, uv, 0)
    assert patches.tolist() == [[0, 1], [3, 2], [7, 1]]
    uv_deep, depth_deep = region_deepest(hs, uv, depth, 0)
    np.testing.assert_array_equal(uv_deep, uv[[2, 4, 0]])
    np.testing.assert_array_equal(depth_deep, [0.2, 0.07, 0.3])
    assert region_deepest(hs, np.zeros((0, 2)), np.zeros(0), 0)[0].shape == (0, 2)
    groups = patch_groups(hs, uv, 0, patches=False)[2]  # the caller's groups: the same samples
    for got, want in zip(region_deepest(hs, uv, depth, 0, groups), (uv_deep, depth_deep)):
        np.testing.assert_array_equal(got, want)
