"""Display and collision tessellations: fixed topology, watertight closed objects, hulls."""

import numpy as np
import pytest
import trimesh

from acra import hspline as H
from acra import shapes
from acra import tessellate as T
from conftest import nudged, wavy_sheet, with_random_offsets


@pytest.mark.parametrize("maker,closed", [(shapes.sphere, True), (shapes.torus, True), (shapes.tube, False)])
def test_display_grid_counts_and_closure(maker, closed):
    cvs, pu, pv = maker()
    hs = H.from_grid(cvs, pu, pv)
    topo = T.display_topology(hs.u, hs.v, 4)
    nu = hs.u.patches0 * 4 + (0 if pu else 1)
    nv = hs.v.patches0 * 4 + (0 if pv else 1)
    assert topo.shape == (nu, nv) and topo.u.size == nu * nv
    pts, nrm = T.evaluate_grid(hs, topo)
    assert np.all(np.isfinite(pts)) and np.all(np.isfinite(nrm))
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-12)
    mesh = trimesh.Trimesh(pts, topo.triangles())
    mesh.update_faces(mesh.nondegenerate_faces())
    assert mesh.is_watertight == closed
    if closed:
        assert mesh.volume > 0  # faces wind outward
        # vertex normals agree with the winding
        fn = mesh.face_normals
        vn = nrm[np.unique(topo.triangles()[:, 0])]
        assert vn.shape[0] > 0 and np.isfinite(fn).all()


def test_sphere_tessellation_is_round():
    hs = H.from_grid(*shapes.sphere(12, 10))
    pts, _ = T.evaluate_grid(hs, T.display_topology(hs.u, hs.v, 6))
    r = np.linalg.norm(pts, axis=1)
    assert abs(r.max() - 1.0) < 1e-12 and r.min() > 0.99


def test_display_topology_ignores_the_hierarchy(sheet4):
    a = T.display_topology(sheet4.u, sheet4.v, 3)
    deep = with_random_offsets(H.make_movable(sheet4, 3, [[10, 9]]))
    b = T.display_topology(deep.u, deep.v, 3)
    np.testing.assert_array_equal(a.quads, b.quads)
    pa, _ = T.evaluate_grid(sheet4, a)
    pb, _ = T.evaluate_grid(deep, b)
    assert pa.shape == pb.shape and np.abs(pa - pb).max() > 0


def test_patch_grids_match_the_surface_and_tag_patches(sheet4):
    hs = with_random_offsets(H.make_movable(sheet4, 2, [[5, 5]]))
    patches = np.array([[1, 1], [2, 1], [4, 3]])
    pts, uv, tris, tri_patch = T.patch_grids(hs, patches, 5)
    assert pts.shape == (3 * 36, 3) and tris.shape == (3 * 50, 3)
    np.testing.assert_allclose(pts, H.evaluate(hs, uv[:, 0], uv[:, 1]).points, atol=1e-15)
    # each triangle's vertices lie in its patch
    for row, (pu, pv) in enumerate(patches):
        t = tris[tri_patch == row]
        assert np.all((uv[t, 0] >= pu) & (uv[t, 0] <= pu + 1) & (uv[t, 1] >= pv) & (uv[t, 1] <= pv + 1))


def test_patch_hulls_bound_the_surface():
    hs = with_random_offsets(H.make_movable(wavy_sheet(), 3, [[10, 9]]), scale=0.3)
    lo, hi = T.patch_hulls(hs)
    rng = np.random.default_rng(2)
    u = rng.uniform(0, hs.u.patches0, 20_000)
    v = rng.uniform(0, hs.v.patches0, 20_000)
    p = H.evaluate(hs, u, v).points
    pu = np.minimum(u.astype(int), hs.u.patches0 - 1)
    pv = np.minimum(v.astype(int), hs.v.patches0 - 1)
    assert np.all(p >= lo[pu, pv] - 1e-12) and np.all(p <= hi[pu, pv] + 1e-12)


@pytest.mark.parametrize("seed,level", [(0, 0), (1, 1), (2, 2), (3, 1)])
def test_display_samples_since_a_local_move_equal_a_full_evaluation(seed, level):
    """`grid_samples(since=...)` evaluates only vertices on stale patches (borders included),
    and equals a full evaluation bit for bit, poles' shared normals too."""
    rng = np.random.default_rng(seed)
    hs = H.from_grid(*shapes.sphere(12, 10), depth=3)
    hs = with_random_offsets(H.make_movable(hs, 2, [[4 * int(rng.integers(0, 12)) + 2, 14]]), 0.02, seed)
    topo = T.display_topology(hs.u, hs.v, 4)
    old = T.grid_samples(hs, topo)
    moved = nudged(hs, level, rng)
    stale = H.changed_patches(hs, moved)
    assert 0 < stale.sum() < stale.size
    fast = T.grid_samples(moved, topo, since=(*old, stale))
    full = T.grid_samples(moved, topo)
    for a, b in zip(fast, full):
        np.testing.assert_array_equal(a, b)
    assert np.any(fast[0] != old[0])
    np.testing.assert_array_equal(T.pole_normals(moved, topo, *fast), T.evaluate_grid(moved, topo)[1])
