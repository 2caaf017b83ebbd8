"""`acra.raycast`: the tree's search gives the brute force's answer bit for bit, and
`pipeline.queries.RayMesh` casts as trimesh's embree caster with its float64 retry did."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from trimesh.ray.ray_pyembree import RayMeshIntersector as Embree
from trimesh.ray.ray_triangle import RayMeshIntersector as Float64

from acra import bvh, meshops
from acra.raycast import first_faces, first_faces_brute
from pipeline.queries import RayMesh
from test_meshops import _grids


def _rays(rng, points, vertices, n=4000, scale=1.0):
    """Random rays from above the sheet, a few unnormalised, and rays straight down through
    vertices (where several triangles meet and float32 can let a ray through)."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    origins = lo + (hi - lo) * rng.random((n, 3)) + np.array([0, 0, 1.0]) * (hi - lo)[2] * 2
    directions = np.array([0.0, 0.0, -1.0]) + 0.3 * rng.standard_normal((n, 3))
    directions[:50] *= 1e-3 * scale
    on = vertices[rng.integers(0, len(vertices), 500)]
    origins[-500:] = on + np.array([0.0, 0.0, 1.0]) * scale
    directions[-500:] = np.array([0.0, 0.0, -1.0])
    return origins, directions


@pytest.mark.parametrize("scale", [1.0, 1e-3, 250.0])
def test_tree_search_is_the_brute_force(scale):
    rng = np.random.default_rng(4)
    points, faces = _grids(rng, scale)
    v, f = meshops.merge_vertices(points, faces)
    tri = v[f]
    usable = (meshops.face_normals(v, f) != 0).any(axis=1)
    assert not usable.all()  # the pole's triangles have no area
    origins, directions = _rays(rng, points, v, scale=scale)
    # rays from on and under the surface, sideways (axis-parallel: infinite slopes), and
    # along the sheet's grid lines
    extra_o = np.concatenate([v[:300], v[300:600] - [0, 0, 0.05 * scale], v[600:700] + [0, 0, 0.01 * scale]])
    extra_d = np.concatenate([rng.standard_normal((300, 3)), np.tile([0.0, 0.0, 1.0], (300, 1)),
                              np.tile([1.0, 0.0, 0.0], (100, 1))])
    origins, directions = np.concatenate([origins, extra_o]), np.concatenate([directions, extra_d])
    directions = meshops.unitize(directions)[0]
    tree = bvh.build(tri)
    face, t = first_faces(tree, usable, origins, directions, 1e-9 * meshops.scale(v))
    want_face, want_t = first_faces_brute(tri, usable, origins, directions)
    assert (face >= 0).sum() > len(face) // 2
    np.testing.assert_array_equal(face, want_face)
    assert t.tobytes() == want_t.tobytes()


@pytest.mark.parametrize("scale", [1.0, 1e-3, 250.0])
def test_ray_mesh_casts_as_embree_with_its_float64_retry(scale):
    """The rays hit are the same; the hit points are the same bits except where a ray meets an
    edge or a corner, where embree's float32 test and the exact one may pick different
    triangles of the same point: there they differ by a few 1e-9 of the size (stated bound
    1e-8), on at most 6 % of these rays (most of them aimed at vertices)."""
    rng = np.random.default_rng(11)
    points, faces = _grids(rng, scale)
    mesh = trimesh.Trimesh(points, faces, process=False)
    mesh.merge_vertices()
    ours = RayMesh(points, faces)
    origins, directions = _rays(rng, points, np.asarray(mesh.vertices), scale=scale)
    for _ in range(2):  # the tree is built at the first cast; the second casts on it again
        loc, ray = ours.first_hits(origins, directions)
        assert np.all(np.diff(ray) > 0)
        el, er, _ = Embree(mesh).intersects_location(origins, directions, multiple_hits=False)
        miss = np.setdiff1d(np.arange(len(origins)), er)
        ml, mr, _ = Float64(mesh).intersects_location(origins[miss], directions[miss], multiple_hits=False)
        want_loc = np.concatenate([el, np.reshape(ml, (-1, 3))])
        want_ray = np.concatenate([er, miss[np.asarray(mr, np.int64)]])
        order = np.argsort(want_ray)
        want_loc, want_ray = want_loc[order], want_ray[order]
        np.testing.assert_array_equal(ray, want_ray)
        same = (loc == want_loc).all(axis=1)
        size = meshops.scale(np.asarray(mesh.vertices))
        assert same[:-500].mean() >= 0.999
        assert same.mean() >= 0.94
        assert np.abs(loc - want_loc).max() <= 1e-8 * size
