"""World tessellations of level-0 patch sets (`pipeline.tessellation`): grid layouts, the kept
sets' answers against a fresh computation, the distinct rows against numpy's."""

import numpy as np
import pytest

from acra import hspline as H
from acra import shapes
from pipeline import geometry
from pipeline import tessellation as T
from conftest import move, responded_sphere


def test_patch_density_follows_refinement():
    hs = H.from_grid(*shapes.sheet(8, 8, width=5.0, depth=5.0), depth=5)
    hs = H.refine(hs, 3, [[10, 10]])  # inside level-0 patch (1, 1)
    g = geometry.SurfaceGeometry(hs, move())
    dens = geometry.patch_density(g)
    assert dens[1, 1] == 16 and dens.sum() == 8 * (dens.size - 1) + 16
    tess = T.tessellate(g, [[1, 1], [0, 0]])
    assert tess.points.shape == (17 * 17 + 9 * 9, 3) and tess.triangles.shape == (2 * 256 + 2 * 64, 3)
    np.testing.assert_allclose(tess.points, H.evaluate(hs, tess.uv[:, 0], tess.uv[:, 1]).points, atol=1e-14)


@pytest.mark.parametrize("seed", [0, 1])
def test_vertices_in_box_kept_per_patch_set_equal_a_new_search(seed):
    """`vertices_in_box` and `tessellate` keep each patch set's distinct vertex
    rows (`distinct`) and layout (parameters, triangles, patches) and give a responded surface,
    moved, what they give with nothing kept, bit for bit, seams and poles of a closed surface
    included."""
    hs, out, _, _, _ = responded_sphere(seed)
    xform = move(0.3, -0.1, 0.2)
    bounds = np.array([[-2.0, -2.0, -0.5], [2.0, 2.0, 2.0]]) + xform[:3, 3]
    T._DISTINCT.clear()
    T._LAYOUTS.clear()
    T.vertices_in_box(geometry.SurfaceGeometry(hs, xform), bounds, 1e-7)
    g = geometry.SurfaceGeometry(out, xform)
    got = T.vertices_in_box(g, bounds, 1e-7)
    assert len(T._DISTINCT) == len(T._LAYOUTS) == 1  # the responded surface's set was the parent's
    kept = T.tessellate(g, geometry.candidate_patches(g, bounds, 1e-7))
    T._DISTINCT.clear()
    T._LAYOUTS.clear()
    g = geometry.SurfaceGeometry(out, xform)
    ref = T.vertices_in_box(g, bounds, 1e-7)
    assert len(got[0]) > 100
    for a, b in zip(got, ref):
        np.testing.assert_array_equal(a, b)
    for name in ("points", "uv", "triangles", "tri_patch"):
        np.testing.assert_array_equal(getattr(kept, name), getattr(T.tessellate(g, geometry.candidate_patches(g, bounds, 1e-7)), name))


def test_unique_patches_and_rows_are_numpy_unique():
    """`unique_patches` and `unique_rows` give `np.unique(axis=0)`'s rows and first
    indices, in its order, signed zeros and repeated rows included."""
    rng = np.random.default_rng(0)
    for _ in range(100):
        n = int(rng.integers(1, 300))
        x = rng.integers(-3, 6, (n, 2)).astype(float) / rng.choice([1, 3, 7])
        x = np.where(rng.random((n, 2)) < 0.05, -0.0, x)
        assert np.array_equal(T.unique_rows(x), np.unique(x, axis=0, return_index=True)[1])
        p = rng.integers(0, 30, (n, 2))
        assert np.array_equal(T.unique_patches(p), np.unique(p, axis=0))
