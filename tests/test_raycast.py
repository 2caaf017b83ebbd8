"""`acra.raycast`: embree's triangle for every ray it calls sure, and trimesh's merged mesh."""

from __future__ import annotations

import numpy as np
import pytest
from embreex import rtcore, rtcore_scene
from embreex.mesh_construction import TriangleMesh

from acra import meshops, raycast
from pipeline.queries import RayMesh
from tests.test_meshops import _grids


def _embree_view(points, faces):
    """The merged mesh in embree's float32 frame (as `RayMesh` gives it to embree) and its scene."""
    v, f = meshops.merge_vertices(points, faces)
    origin, factor = v.min(axis=0), 100.0 / meshops.scale(v)
    scaled = ((v - origin) * factor).astype(np.float32)
    scene = rtcore_scene.EmbreeScene(rtcore.EmbreeDevice())
    TriangleMesh(scene=scene, vertices=scaled, indices=f.astype(np.int32))
    return v, f, origin, factor, scaled, scene


def _rays(rng, v, f, n=6000):
    """Rays of five kinds, in rows of n // 6: through a vertex, through a point of an edge, from
    inside the mesh's box every way, straight down, and from above at random slopes."""
    lo, hi = v.min(axis=0), v.max(axis=0)
    k, reach = n // 6, (hi - lo).max()
    o = lo + (hi - lo) * rng.random((n, 3)) + np.array([0, 0, 2.0]) * (hi - lo)[2]
    d = np.array([0.0, 0.0, -1.0]) + 0.3 * rng.standard_normal((n, 3))
    at = v[rng.integers(0, len(v), k)]
    o[:k] = at + reach * rng.standard_normal((k, 3))
    d[:k] = at - o[:k]
    face, a = rng.integers(0, len(f), k), rng.random((k, 1))
    at = v[f[face, 0]] * a + v[f[face, 1]] * (1 - a)
    o[k:2 * k] = at + reach * rng.standard_normal((k, 3))
    d[k:2 * k] = at - o[k:2 * k]
    o[2 * k:3 * k] = lo + (hi - lo) * rng.random((k, 3))
    d[2 * k:3 * k] = rng.standard_normal((k, 3))
    d[3 * k:4 * k] = [0.0, 0.0, -1.0]
    return o, meshops.unitize(d)[0], k


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("scale", [1.0, 1e-3, 250.0])
def test_sure_answers_are_embrees(seed, scale):
    rng = np.random.default_rng(seed)
    v, f, origin, factor, scaled, scene = _embree_view(*_grids(rng, scale))
    o, d, k = _rays(rng, v, f)
    so, sd = ((o - origin) * factor).astype(np.float32), d.astype(np.float32)
    want = scene.run(so, sd)
    tri, sure = raycast.sure_first_hits(scaled, f, raycast.group_boxes(scaled, f), so, sd)
    assert (want != -1).sum() > len(o) // 2
    np.testing.assert_array_equal(tri[sure], want[sure])
    # through a vertex or an edge float32 decides: left to embree; elsewhere nearly every ray is sure
    assert (~sure[:2 * k]).mean() > 0.8
    assert (~sure[2 * k:]).mean() < 0.01


@pytest.mark.parametrize("scale", [1.0, 1e-3, 250.0])
def test_merged_is_trimeshs_merge(scale):
    for seed in range(3):
        points, faces = _grids(np.random.default_rng(seed), scale)
        want = meshops.merge_vertices(points, faces)
        got = raycast.merged(points, faces)
        for a, b in zip(got, want):
            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    got = raycast.merged(points, np.zeros((0, 3), np.int64))  # no faces: every vertex counts
    want = meshops.merge_vertices(points, np.zeros((0, 3), np.int64))
    assert got[0].tobytes() == want[0].tobytes() and got[1].shape == want[1].shape


def test_hit_faces_normals_are_the_whole_meshs_rows():
    v, f = meshops.merge_vertices(*_grids(np.random.default_rng(3), 7.0))
    whole = meshops.face_normals(v, f)
    rng = np.random.default_rng(4)
    for n in (1, 2, 3, 5, 8, 17, 96, len(f)):
        rows = rng.integers(0, len(f), n)
        assert meshops.face_normals(v, f[rows]).tobytes() == whole[rows].tobytes()


@pytest.mark.parametrize("scale", [1.0, 1e-3, 250.0])
def test_sure_hits_are_face_normals_then_planes_lines(scale):
    """`raycast.sure_hits`: the triangles and sureness of `sure_first_hits`, and each sure ray's
    hit in the same pass, the same bits as `meshops.face_normals` of its face and
    `meshops.planes_lines` (trimesh's arithmetic); no other row holds a hit."""
    for seed in range(3):
        rng = np.random.default_rng(seed)
        v, f, origin, factor, scaled, _ = _embree_view(*_grids(rng, scale))
        o, d, _ = _rays(rng, v, f)
        d[:40] = np.cross(d[:40], rng.standard_normal((40, 3)))  # some rays near their plane
        d = meshops.unitize(d)[0]
        so, sd = ((o - origin) * factor).astype(np.float32), d.astype(np.float32)
        boxes = raycast.group_boxes(scaled, f)
        tri, sure, loc, has = raycast.sure_hits(scaled, f, boxes, so, sd, (v, o, d))
        want_tri, want_sure = raycast.sure_first_hits(scaled, f, boxes, so, sd)
        np.testing.assert_array_equal(tri, want_tri)
        np.testing.assert_array_equal(sure, want_sure)
        rows = np.nonzero(sure & (tri >= 0))[0]
        faces = f[tri[rows]]
        want, valid = meshops.planes_lines(v[faces[:, 0]], meshops.face_normals(v, faces), o[rows], d[rows])
        assert len(rows) > len(o) // 4
        assert has[rows].tolist() == valid.tolist() and not has[np.setdiff1d(np.arange(len(o)), rows)].any()
        assert loc[rows[valid]].tobytes() == want.tobytes()


def test_generic_rays_build_no_embree_scene():
    """Casting rays off the mesh's edges answers without an embree scene; a ray through a shared
    vertex builds it (whether embree's float32 lets that ray through is embree's answer, held to
    trimesh's by tests/test_meshops.py)."""
    rng = np.random.default_rng(9)
    points, faces = _grids(rng)
    mesh = RayMesh(points, faces)
    lo, hi = points.min(axis=0), points.max(axis=0)
    origins = lo + (hi - lo) * rng.random((70, 3)) + np.array([0.0, 0.0, 2.0])
    loc, ray = mesh.first_hits(origins, np.array([0.0, 0.0, -1.0]) + 0.1 * rng.standard_normal((70, 3)))
    assert len(ray) > 35 and mesh._scene is None
    vertex = mesh.vertices[mesh.faces[len(mesh.faces) // 2, 1]]
    mesh.first_hits(vertex[None] + [[0.0, 0.0, 1.0]], np.array([[0.0, 0.0, -1.0]]))
    assert mesh._scene is not None
