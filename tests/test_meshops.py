"""`acra.meshops` and `pipeline.queries.RayMesh` give trimesh's answers bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from trimesh.ray.ray_pyembree import RayMeshIntersector

from acra import meshops
from pipeline.queries import RayMesh


def _grids(rng: np.random.Generator, scale: float = 1.0, patches: int = 6, n: int = 7):
    """Triangle grids over adjacent patches of a bumpy sheet, each patch's border points
    evaluated again by the next patch (as `queries._ray_mesh` concatenates them), with a
    collapsed (pole) row and some unreferenced points."""
    points, faces, base = [], [], 0
    for p in range(patches):
        u, v = np.meshgrid(np.linspace(p, p + 1, n), np.linspace(0, 1, n), indexing="ij")
        z = 0.1 * np.sin(3 * u) * np.cos(2 * v) + 0.01 * rng.standard_normal(u.shape) * (u != p) * (u != p + 1)
        pts = np.stack([u, v, z], -1).reshape(-1, 3)
        pts[:n] = pts[0]  # a pole: its triangles have no area
        idx = np.arange(n * n).reshape(n, n)
        a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
        tri = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
        tri = tri[rng.random(len(tri)) > 0.05]  # slivers dropped: some points unreferenced
        points.append(pts * scale + np.array([0.3, -0.2, 0.5]))
        faces.append(tri + base)
        base += len(pts)
    return np.concatenate(points), np.concatenate(faces).astype(np.int64)


def _same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype
    assert a.tobytes() == b.tobytes()


@pytest.mark.parametrize("scale", [1.0, 1e-3, 250.0])
def test_merge_normals_scale_match_trimesh(scale):
    rng = np.random.default_rng(7)
    points, faces = _grids(rng, scale)
    mesh = trimesh.Trimesh(points, faces, process=False)
    mesh.merge_vertices()
    vertices, merged = meshops.merge_vertices(points, faces)
    assert len(vertices) < len(points)
    _same(vertices, np.asarray(mesh.vertices))
    _same(merged, np.asarray(mesh.faces))
    _same(meshops.face_normals(vertices, merged), np.asarray(mesh.face_normals))
    assert meshops.scale(vertices) == mesh.scale
    from acra.bvh import bounds

    assert meshops.scale(vertices, bounds(vertices)) == mesh.scale  # the box found in one compiled pass


def test_unitize_and_planes_lines_match_trimesh():
    rng = np.random.default_rng(5)
    v = rng.standard_normal((200, 3))
    v[:3] = 0.0
    unit, valid = meshops.unitize(v.copy())
    ref, ref_valid = trimesh.util.unitize(v.copy(), check_valid=True)
    _same(unit[valid], ref)
    _same(valid, ref_valid)
    _same(meshops.unitize(v.copy())[0], trimesh.util.unitize(v.copy()))
    po, pn, lo, ld = (rng.standard_normal((200, 3)) for _ in range(4))
    ld[:4] = np.cross(pn[:4], rng.standard_normal((4, 3)))  # parallel: dropped
    got = meshops.planes_lines(po, pn, lo, ld)
    want = trimesh.intersections.planes_lines(po, pn, lo, ld)
    _same(got[0], want[0])
    _same(got[1], want[1])


@pytest.mark.parametrize("scale", [1.0, 1e-3, 250.0])
def test_ray_mesh_first_hits_match_trimesh_embree(scale):
    rng = np.random.default_rng(11)
    points, faces = _grids(rng, scale)
    mesh = trimesh.Trimesh(points, faces, process=False)
    mesh.merge_vertices()
    ours = RayMesh(points, faces)
    lo, hi = points.min(axis=0), points.max(axis=0)
    n = 4000
    origins = lo + (hi - lo) * rng.random((n, 3)) + np.array([0, 0, 1.0]) * (hi - lo)[2] * 2
    directions = np.array([0.0, 0.0, -1.0]) + 0.3 * rng.standard_normal((n, 3))
    directions[:50] *= 1e-3 * scale  # unnormalised
    # rays along grid lines and through shared vertices: where float32 decides the triangle
    on = mesh.vertices[rng.integers(0, len(mesh.vertices), 500)]
    origins[-500:] = on + np.array([0.0, 0.0, 1.0]) * scale
    directions[-500:] = np.array([0.0, 0.0, -1.0])
    for _ in range(2):  # the scene is built on the first cast; the second casts on it again
        loc, ray = ours.first_hits(origins, directions)
        want_loc, want_ray, _ = RayMeshIntersector(mesh).intersects_location(origins, directions, multiple_hits=False)
        assert len(ray) > n // 4
        _same(loc, want_loc)
        _same(ray, want_ray)


def test_ray_mesh_as_trimesh():
    points, faces = _grids(np.random.default_rng(2))
    mesh = RayMesh(points, faces).trimesh()
    ref = trimesh.Trimesh(points, faces, process=False)
    ref.merge_vertices()
    _same(np.asarray(mesh.vertices), np.asarray(ref.vertices))
    _same(np.asarray(mesh.faces), np.asarray(ref.faces))
