"""acra.targets: data points' grouping per finest absorbing patch (eq. 4.16)."""

import numpy as np
import pytest

from acra import hspline as H
from acra import shapes
from acra import targets as T
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


@pytest.mark.parametrize("grid", ["torus", "sheet"])
def test_per_level_points_kernel_is_the_array_form_bit_for_bit(grid):
    """`targets.per_level_points` (compiled, `levelkernels.merge_points`) merges the additional
    points per level patch with the array form's bits: contacts first in order, one row per
    patch in key order, means of the open parameters and moves, a periodic direction's mean
    angle; several points to a patch, a point on a patch border, none or every point a contact."""
    hs = H.from_grid(*shapes.torus(8, 6), depth=4) if grid == "torus" else H.from_grid(*shapes.sheet(12, 12, 9.0, 9.0), depth=4)
    rng = np.random.default_rng(7)
    P = np.array(hs.domain)
    for level in range(4):
        for K in (1, 2, 9, 40):
            uv = rng.uniform(0.0, 1.0, (K, 2)) * P
            uv[K // 2] = np.floor(uv[K // 2] * 2 ** level) / 2 ** level  # on a level-patch corner
            if K > 3:
                uv[-2:] = uv[1] + 1e-3  # with the second point in its patch
            want = rng.normal(size=(K, 3))
            for is_contact in (rng.uniform(size=K) < 0.3, np.zeros(K, bool), np.ones(K, bool)):
                got = T.per_level_points(hs, level, uv, want, is_contact)
                ref = T._per_level_points_numpy(hs, level, uv, want, is_contact)
                # the angles found once for a response's levels (`merge_trig`) give the same
                kept = T.per_level_points(hs, level, uv, want, is_contact, T.merge_trig(hs, uv, is_contact))
                for g, k, r in zip(got, kept, ref):
                    assert g.shape == r.shape == k.shape
                    assert np.array_equal(g.view(np.int64), r.view(np.int64))
                    assert np.array_equal(k.view(np.int64), r.view(np.int64))


@pytest.mark.filterwarnings("ignore:invalid value encountered in cast")  # the NaN parameter's key in numpy
@pytest.mark.parametrize("grid", ["torus", "sheet"])
def test_region_groups_kernel_is_the_array_form_bit_for_bit(grid):
    """`targets.region_groups` (compiled, `_region_groups`) groups a region's samples per level
    patch with the array form's bits (`_patch_groups_numpy`, `_deepest_rows_numpy`): the sorted
    keys, each sample's group, the mean parameters (a periodic direction's by its angles) and
    each patch's deepest row, with tied depths, signed zeros and NaN depths, samples on patch
    corners, outside the domain and a NaN parameter; `patch_groups`, `region_midpoints` and
    `region_deepest` give the same, and each sample's key is `patch_keys`' (an empty set's too)."""
    hs = H.from_grid(*shapes.torus(8, 6), depth=4) if grid == "torus" else H.from_grid(*shapes.sheet(12, 12, 9.0, 9.0), depth=4)
    rng = np.random.default_rng(11)
    P = np.array(hs.domain)
    for level in range(4):
        for n in (1, 2, 9, 40, 300):
            uv = rng.uniform(-0.05, 1.05, (n, 2)) * P
            uv[n // 2] = np.floor(uv[n // 2] * 2 ** level) / 2 ** level  # on a level-patch corner
            depth = rng.choice(np.array([0.0, -0.0, 0.5, 0.25, 1.0]), n) if n > 9 else rng.uniform(size=n)
            if n > 9:
                depth[rng.integers(0, n, 3)] = np.nan
                uv[-3:] = uv[1] + 1e-3  # with the second sample in its patch
            if n == 300:
                uv[7, 1] = np.nan  # the least int64 as its key: `unique_inverse` sorts
            mids, inv, rows, keys = T.region_groups(hs, uv, level, depth)
            ref_mids, ref_inv, ref_keys = T._patch_groups_numpy(hs, uv, level)
            ref_rows = T._deepest_rows_numpy(depth, ref_inv)
            for got, want in ((mids, ref_mids), (inv, ref_inv), (rows, ref_rows), (keys, ref_keys)):
                assert got.shape == want.shape
                assert np.array_equal(got.view(np.int64), np.asarray(want).view(np.int64))
            assert T.region_groups(hs, uv, level)[2].shape == (0,)  # no depths, no rows
            keys, ref = T.patch_keys(hs, uv, level), T._patch_keys_numpy(hs, uv, level)
            assert keys.dtype == ref.dtype == np.int64 and np.array_equal(keys, ref)
            assert np.array_equal(T.patch_keys(hs, uv[::-2], level), T._patch_keys_numpy(hs, uv[::-2], level))  # a strided view
            m, patches, i = patch_groups(hs, uv, level)
            assert np.array_equal(m.view(np.int64), ref_mids.view(np.int64)) and np.array_equal(i, ref_inv)
            np.testing.assert_array_equal(patches[:, 0] * hs.v.patches(level) + patches[:, 1], ref_keys)
            for got, want in zip(region_deepest(hs, uv, depth, level), (uv[ref_rows], depth[ref_rows])):
                assert np.array_equal(got.view(np.int64), want.view(np.int64))
    assert T.patch_keys(hs, np.zeros((0, 2)), 2).shape == (0,)
