"""Collision detection: broad phase, inside tests, ray casts, residuals, face samples.

Run ``python tests/test_detect.py`` for the timings quoted in docs/detection.md.
"""

import time
import weakref

import numpy as np
import pytest
import trimesh

from acra import hspline as H
from acra.controls import check_controls
from acra.targets import DataPoints
from acra import shapes
from pipeline import geometry
from pipeline import contact as C
from pipeline import detect as D
from pipeline import shape as S
from pipeline import tessellation as T
from pipeline.model import ColliderModel, apply_inverse
from conftest import (BOX_TRIANGLES, BOX_VERTICES, assert_finite, box, move, responded_sphere, rotated_scaled, sheet_geom,
                      sphere_geom, wavy_sheet, with_random_offsets)

def every_patch(hs):
    """All level-0 patches ``(P, 2) int64`` of ``hs``."""
    return np.argwhere(np.ones((hs.u.patches0, hs.v.patches0), bool))


def all_triangles(geom):
    """World triangles ``(f, 3, 3)`` of every patch's collision grid (poles' slivers dropped)."""
    grids = geom.shape.grids_for(every_patch(geom.surface))
    tri = np.concatenate([g.points[g.triangles[g.solid]] for g in grids])
    return (tri.reshape(-1, 3) @ geom.xform[:3, :3].T + geom.xform[:3, 3]).reshape(-1, 3, 3)


def brute_closest(geom, points):
    """Distances ``(k,)`` from world points to every collision-grid triangle (brute force)."""
    tri = all_triangles(geom)
    return np.array([np.linalg.norm(trimesh.triangles.closest_point(tri, np.tile(p, (len(tri), 1))) - p, axis=1).min()
                     for p in points])


def parity_inside(geom, points):
    """Ray-parity inside test on the merged collision grids (independent of `Shape.signed`)."""
    tri = all_triangles(geom)
    mesh = trimesh.Trimesh(tri.reshape(-1, 3), np.arange(len(tri) * 3).reshape(-1, 3))
    mesh.merge_vertices(digits_vertex=9)
    assert mesh.is_watertight
    return mesh.contains(points)


def inradius(geom, centre):
    """Smallest distance from ``centre`` to ``geom``'s collision grids (brute force)."""
    return float(brute_closest(geom, np.asarray(centre, float)[None])[0])


def test_box_mesh_is_closed_and_outward():
    mesh = trimesh.Trimesh(BOX_VERTICES, BOX_TRIANGLES)
    assert mesh.is_watertight and mesh.volume == pytest.approx(8.0)
    assert box(1.0).closed


@pytest.mark.parametrize("maker,closed", [(shapes.sphere, True), (shapes.torus, True), (shapes.tube, False), (shapes.sheet, False)])
def test_inside_agrees_with_ray_parity_and_distances_with_brute_force(maker, closed):
    """`Shape.signed` (closest point, normal side) against ray parity on the merged grids, and the
    pruned closest-point search against every triangle, at random points near and far."""
    cvs, pu, pv = maker(8, 8)
    rot = trimesh.transformations.rotation_matrix(0.7, [1, 2, 3])
    g = geometry.SurfaceGeometry(H.from_grid(cvs, pu, pv), move(1.0, 2.0, 3.0) @ rot)
    assert geometry.is_closed(g) == closed
    rng = np.random.default_rng(11)
    pts = g.xform[:3, 3] + 0.8 * rng.normal(size=(300, 3))  # the shapes are centred at the origin
    d, _ = D.surface_distance(g, pts)
    np.testing.assert_allclose(d, brute_closest(g, pts), rtol=0, atol=1e-12 * g.size)
    m = D.inside(g, pts)
    if not closed:
        assert not m.any()
        return
    assert g.shape.outward in (1.0, -1.0)
    clear = d > 1e-9 * g.size
    np.testing.assert_array_equal(m[clear], parity_inside(g, pts[clear]))
    assert 0.05 * len(pts) < m.sum() < 0.95 * len(pts)


@pytest.mark.parametrize("seed", range(3))
def test_closest_points_over_grids_of_mixed_density_match_brute_force(seed):
    """Grids refined to 16 and 32 steps beside 8-step ones (one index per density in
    `GridSet`): distances equal a search of every triangle, points lie at those distances, and
    parameters map back onto the triangle the point is on."""
    rng = np.random.default_rng(seed)
    hs = H.from_grid(*shapes.sphere(12, 10), depth=5)
    hs = H.make_movable(hs, 4, [[16 * int(rng.integers(0, 12)) + 8, 72]])
    hs = with_random_offsets(H.make_movable(hs, 3, [[8 * int(rng.integers(0, 12)) + 4, 20]]), 0.02, seed)
    g = geometry.SurfaceGeometry(hs, move(0.5, -0.2, 0.1))
    assert len(np.unique(g.shape.density_map)) >= 3
    pts = g.xform[:3, 3] + 0.6 * rng.normal(size=(200, 3))
    near = g.shape.nearest(g.to_object(pts))
    np.testing.assert_allclose(near.distance, brute_closest(g, pts), rtol=0, atol=1e-12 * g.size)
    np.testing.assert_allclose(np.linalg.norm(near.points - g.to_object(pts), axis=1), near.distance, rtol=1e-12, atol=1e-15)
    grids = g.shape.grids_for(every_patch(hs))
    lo, hi = np.array([gr.uv[0] for gr in grids]), np.array([gr.uv[-1] for gr in grids])
    home = np.all((near.uv[:, None] >= lo[None] - 1e-12) & (near.uv[:, None] <= hi[None] + 1e-12), axis=2)
    assert home.any(axis=1).all()  # each parameter lies in some patch's box
    ev = H.evaluate(hs, near.uv[:, 0], near.uv[:, 1], det=g.shape.details).points
    step = 1.0 / g.shape.density_map.min()  # chord error of the grids: a few times step² of size
    assert np.max(np.linalg.norm(ev - near.points, axis=1)) < 4 * step**2 * g.size


@pytest.mark.parametrize("seed", range(2))
def test_closest_picks_the_same_triangle_as_testing_every_triangle(seed):
    """`Closest.query` tests only the triangles whose boxes lie within the nearest vertex's
    distance: its answer is bit for bit the one of the exact test on every triangle with the
    query's rule (nearest first, the lowest face row among equal distances), for points off the
    surface, on grid vertices (shared by several triangles) and on edge midpoints."""
    rng = np.random.default_rng(seed)
    hs = with_random_offsets(H.make_movable(H.from_grid(*shapes.sphere(8, 6), depth=3), 2, [[4, 6]]), 0.02, seed)
    shape = S.Shape(hs)
    grids = shape.grids_for(every_patch(hs))
    sets = S.GridSet(grids)
    vertices, faces = sets.points, sets.triangles
    index = S.Closest(vertices, faces)
    pts = np.concatenate([0.8 * rng.normal(size=(60, 3)), vertices[rng.integers(0, len(vertices), 20)],
                          vertices[faces[:20, :2]].mean(axis=1)])
    dist, close, face = index.query(pts)
    unit = index.unit
    for i, p in enumerate(pts):
        cp = unit * trimesh.triangles.closest_point(vertices[faces] / unit, np.tile(p / unit, (len(faces), 1)))
        d = np.linalg.norm(cp - p, axis=1)
        best = int(np.lexsort((np.arange(len(d)), d))[0])
        assert (dist[i], face[i]) == (d[best], best)
        assert np.array_equal(close[i], cp[best])


def test_bvh_cache_answers_equal_triangle_sets_with_one_tree():
    """`grids.BvhCache` finds a BVH by the content it is built from: equal arrays (another copy,
    unused vertices aside) give the same tree, a vertex moved by one ulp a new one, and a found
    tree collides exactly as a rebuilt one; the oldest entries go past ``kept``."""
    import fcl

    from pipeline import grids

    cache = grids.BvhCache(kept=2)
    vertices, faces = BOX_VERTICES.astype(np.float64), np.asarray(BOX_TRIANGLES, np.int64)
    first = cache.get(vertices, faces)
    padded = np.concatenate([vertices, [[9.0, 9.0, 9.0]]])  # a vertex no face uses
    assert cache.get(padded.copy(), faces.copy()) is first
    moved = vertices.copy()
    moved[0, 0] = np.nextafter(moved[0, 0], np.inf)
    assert cache.get(moved, faces) is not first
    other = grids.bvh(vertices + 0.5, faces)
    request = fcl.CollisionRequest(num_max_contacts=1000, enable_contact=True)
    found, rebuilt = fcl.CollisionResult(), fcl.CollisionResult()
    fcl.collide(cache.get(vertices, faces), other, request, found)
    fcl.collide(grids.bvh(vertices, faces), other, request, rebuilt)
    assert [(c.b1, c.b2, tuple(c.pos)) for c in found.contacts] == [(c.b1, c.b2, tuple(c.pos)) for c in rebuilt.contacts]
    assert len(found.contacts) > 0
    cache.get(vertices * 2.0, faces)
    cache.get(vertices * 3.0, faces)
    assert cache.get(moved, faces) is not None and len(cache._built) == 2


def test_a_reversed_surface_still_has_its_inside_inside():
    """Swapping u's direction turns ``du × dv`` inward; `Shape.outward` finds it."""
    cvs, pu, pv = shapes.sphere(8, 8)
    g = geometry.SurfaceGeometry(H.from_grid(cvs, pu, pv), move())
    r = geometry.SurfaceGeometry(H.from_grid(cvs[::-1].copy(), pu, pv), move())
    assert g.shape.outward == -r.shape.outward
    pts = np.array([[0.0, 0.0, 0.0], [0.3, -0.2, 0.1], [2.0, 0.0, 0.0], [0.0, 0.0, -1.5]])
    np.testing.assert_array_equal(D.inside(r, pts), [True, True, False, False])
    np.testing.assert_array_equal(D.inside(g, pts), [True, True, False, False])


def test_grids_of_a_refined_sphere_lie_on_it():
    hs = H.from_grid(*shapes.sphere(8, 8), depth=4)
    hs = H.make_movable(hs, 3, [[20, 20]])  # level-0 patch (2, 2) and its neighbours get 16 steps
    g = geometry.SurfaceGeometry(with_random_offsets(hs), move(5.0, -2.0, 1.0))
    assert geometry.patch_density(g).max() == 16
    tess = T.tessellate(g, every_patch(g.surface))
    np.testing.assert_allclose(geometry.surface_points(g, tess.uv).points, tess.points, atol=1e-12)
    assert len(tess.points) == sum((s + 1) ** 2 for s in geometry.patch_density(g).reshape(-1))
    pts = g.xform[:3, 3] + np.random.default_rng(2).normal(size=(200, 3))
    d, _ = D.surface_distance(g, pts)
    np.testing.assert_allclose(d, brute_closest(g, pts), rtol=0, atol=1e-12 * g.size)


def test_broad_phase_tessellates_only_patches_near_the_box():
    # 17 x 17 patches of unit size; a patch's control hull spans CVs p..p+3, i.e. x in
    # [x0 + (p - 1), x0 + (p + 2)]: a box of half-size 0.1 at the corner x0 meets patches 0, 1.
    g = sheet_geom(n=20, width=17.0)
    b = geometry.ColliderGeometry(box(0.1), move(-8.5, -8.5, 0.0))
    c = C.detect_pair(g, b)
    assert c is not None and c.region_a.points.shape == (1, 3)  # the sheet's corner vertex
    np.testing.assert_allclose(c.region_a.points[0], [-8.5, -8.5, 0.0], atol=1e-12)
    assert c.depth == pytest.approx(0.1, abs=1e-12)
    np.testing.assert_array_equal(T.tessellated(g), [[0, 0], [0, 1], [1, 0], [1, 1]])
    assert "full" not in g.shape.__dict__  # the open sheet's full grid was never built
    # two spheres far apart: nothing is tessellated at all
    s1, s2 = sphere_geom(), sphere_geom(move(2.5, 0.3, 0.0), "/s2")
    assert C.detect_pair(s1, s2) is None
    assert T.tessellated(s1).size == 0 and T.tessellated(s2).size == 0


def test_box_wholly_inside_sphere_is_detected_without_fcl_contact():
    s = sphere_geom()
    b = geometry.ColliderGeometry(box(0.2), move(0.1, -0.05, 0.08))
    assert D.intersect(s, b).count == 0  # fcl sees no crossing surfaces
    assert D.touching(s, b)
    c = C.detect_pair(s, b)
    assert c is not None and c.region_a.empty and c.region_b.points.shape == (8, 3)
    corners = BOX_VERTICES * 0.2 + [0.1, -0.05, 0.08]
    r = np.linalg.norm(c.region_b.points, axis=1)
    np.testing.assert_allclose(np.sort(r), np.sort(np.linalg.norm(corners, axis=1)), atol=1e-15)
    # depth to the tessellation lies between the inscribed and the unit sphere's
    r_in = inradius(s, [0, 0, 0])
    assert 1.0 - r_in < 1e-3
    assert np.all(c.region_b.depth <= 1.0 - r + 1e-12) and np.all(c.region_b.depth >= r_in - r - 1e-12)
    # fallback contact: the deepest box corner and its closest sphere point (radially outward)
    assert not c.rewound and c.uv_b is None
    i = np.argmax(c.region_b.depth)
    np.testing.assert_array_equal(c.point_b, c.region_b.points[i])
    np.testing.assert_allclose(c.local_b, c.point_b - [0.1, -0.05, 0.08], atol=1e-15)
    assert abs(np.linalg.norm(c.point_a) - 1.0) < 1e-4
    assert np.dot(c.point_a, c.point_b) / np.linalg.norm(c.point_b) > 0.999
    assert_finite(c)


def test_sphere_wholly_inside_a_rotated_scaled_collider_has_exact_depths():
    # the collider's matrix is a similarity (rotation, scale 1.5, translation): depths stay exact
    m = move(0.3, 0.2, -0.1) @ trimesh.transformations.rotation_matrix(0.7, [1.0, 1.0, 0.3]) @ np.diag([1.5, 1.5, 1.5, 1.0])
    s = geometry.SurfaceGeometry(H.from_grid(*shapes.sphere(16, 14, radii=(0.3, 0.3, 0.3), center=(0.1, 0.0, 0.0))), m)
    b = geometry.ColliderGeometry(box(1.0), m)
    assert D.intersect(s, b).count == 0
    c = C.detect_pair(s, b)
    assert c is not None and c.region_b.empty
    # every vertex is inside; a point inside a box is as deep as its nearest face plane
    all_uv = T.tessellate(s, np.argwhere(np.ones((16, 11), bool))).uv
    assert len(c.region_a.points) == len(np.unique(geometry.wrap_uv(s.surface, all_uv), axis=0))
    local = apply_inverse(m, c.region_a.points)
    np.testing.assert_allclose(c.region_a.depth, 1.5 * (1.0 - np.abs(local)).min(axis=1), atol=1e-12)
    # fallback: P_B is the deepest vertex's foot on the nearest face
    assert not c.rewound
    assert np.abs(c.local_b).max() == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(apply_inverse(m, c.point_b[None])[0], c.local_b, atol=1e-12)
    assert np.linalg.norm(c.point_b - c.point_a) == pytest.approx(c.depth, abs=1e-12)
    assert_finite(c)


@pytest.mark.parametrize("seed", range(6))
def test_random_box_placements_give_consistent_finite_results(seed):
    rng = np.random.default_rng(seed)
    s = sphere_geom()
    rot = trimesh.transformations.random_rotation_matrix(rng.uniform(size=3))
    m = move(*rng.uniform(-1.2, 1.2, size=3)) @ rot
    b = geometry.ColliderGeometry(box(rng.uniform(0.05, 0.6)), m)
    c = C.detect_pair(s, b)
    res = D.residual(s, b)
    if c is None:
        assert res == D.Residual(0.0, 0.0, 0) and not D.touching(s, b)
        return
    assert_finite(c) and D.touching(s, b)
    assert c.depth == res.max and res.count == len(c.region_a.points) + len(c.region_b.points)
    # region vertices really are inside: sphere vertices inside the box, box corners inside r <= 1
    local = apply_inverse(m, c.region_a.points)
    half = np.abs(b.static.mesh.vertices).max()
    assert np.all(np.abs(local) <= half + 1e-9)
    assert np.all(np.linalg.norm(c.region_b.points, axis=1) <= 1.0 + 1e-9)
    assert np.all(c.region_a.depth <= half + 1e-12) and np.all(c.region_b.depth >= 0.0)


def analytic_hits(origins, dirs, radius):
    b = np.einsum("ij,ij->i", origins, dirs)
    return -b + np.sqrt(b * b - np.einsum("ij,ij->i", origins, origins) + radius * radius)


@pytest.mark.parametrize("kind", ["hspline", "icosphere"])
def test_ray_casts_hit_the_unit_sphere(kind):
    if kind == "hspline":
        g = sphere_geom()
        r_in = inradius(g, [0, 0, 0])
    else:
        ico = trimesh.creation.icosphere(subdivisions=5)
        g = geometry.ColliderGeometry(geometry.prepare_collider(ColliderModel("/ico", ico.vertices, ico.faces)), move())
        r_in = np.abs(np.einsum("ij,ij->i", ico.face_normals, ico.triangles[:, 0])).min()
    assert 1.0 - r_in < 1e-3
    rng = np.random.default_rng(7)
    dirs = rng.normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    origins = rng.uniform(-0.3, 0.3, size=(200, 3))
    hits, valid = D.cast(g, origins, 3.0 * dirs)
    assert valid.all()
    s = np.einsum("ij,ij->i", hits - origins, dirs)
    np.testing.assert_allclose(hits, origins + s[:, None] * dirs, atol=1e-9)  # on the ray
    # the tessellation lies in the shell r_in <= |x| <= 1: the hit is where the ray crosses it
    assert np.all(s >= analytic_hits(origins, dirs, r_in) - 1e-9)
    assert np.all(s <= analytic_hits(origins, dirs, 1.0) + 1e-9)
    # just outside, pointing away: the surface just behind counts; farther out it does not
    out = dirs[:5] * np.array([1.001, 1.001, 1.2, 1.2, 1.2])[:, None]
    hits, valid = D.cast(g, out, dirs[:5])
    np.testing.assert_array_equal(valid, [True, True, False, False, False])
    assert np.all(np.linalg.norm(hits[:2], axis=1) <= 1.0 + 1e-12)
    np.testing.assert_array_equal(hits[2:], out[2:])
    # just inside, pointing inward: the exit is on the far side, not the entry behind
    hits, valid = D.cast(g, 0.9995 * dirs[:5], -dirs[:5])
    assert valid.all() and np.all(np.einsum("ij,ij->i", hits, dirs[:5]) < -0.99)


def test_residual_separated_and_analytic_overlaps():
    s = sphere_geom()
    far = geometry.ColliderGeometry(box(0.3), move(0.0, 0.0, 1.5))
    assert D.residual(s, far) == D.Residual(0.0, 0.0, 0)
    # a wide box pressed 0.1 onto the north pole: each cap vertex is as deep as its height
    cap = geometry.ColliderGeometry(box(2.0), move(0.0, 0.0, 2.9))
    res = D.residual(s, cap)
    ra, _ = D.regions(s, cap)
    assert res.max == pytest.approx(0.1, abs=1e-12)  # the pole is exactly at z = 1
    np.testing.assert_allclose(ra.depth, ra.points[:, 2] - 0.9, atol=1e-12)
    assert res.count == len(ra.points) > 0 and res.mean == pytest.approx(np.mean(ra.points[:, 2] - 0.9), abs=1e-12)
    # two unit spheres 1.5 apart overlap by 0.5: bounded by the inscribed and the true sphere
    other = sphere_geom(move(0.0, 0.0, 1.5), "/other")
    res = D.residual(s, other)
    gap = 1.0 - inradius(other, [0.0, 0.0, 1.5])
    assert 0.5 - gap - 1e-12 <= res.max <= 0.5 + 1e-12 and gap < 1e-3
    ra, rb = D.regions(s, other)
    assert len(ra.points) == len(rb.points) > 0  # symmetric configuration
    assert res.count == len(ra.points) + len(rb.points)
    assert D.default_tolerance(s, cap) == pytest.approx(1e-3 * s.size)


def test_projection_is_a_true_closest_point_on_a_refined_surface():
    hs = with_random_offsets(H.make_movable(wavy_sheet(depth=3), 2, [[6, 6]]), scale=0.1)
    rot = trimesh.transformations.rotation_matrix(0.4, [1.0, 2.0, 0.5])
    g = geometry.SurfaceGeometry(hs, rot @ move(0.5, 0.0, 0.2))
    rng = np.random.default_rng(3)
    uv = rng.uniform([1.0, 1.0], [4.0, 3.0], size=(40, 2))
    ev = geometry.surface_points(g, uv, order=1)
    n = np.cross(ev.du, ev.dv)
    n /= np.linalg.norm(n, axis=1)[:, None]
    offset = 0.05 * rng.uniform(-1, 1, size=40)
    targets = ev.points + offset[:, None] * n
    pr = D.project(g, targets)
    ev = geometry.surface_points(g, pr.uv, order=1)
    r = targets - ev.points
    for t in (ev.du, ev.dv):  # first-order optimality: the offset is normal to the surface
        assert np.all(np.abs(np.einsum("ij,ij->i", r, t)) <= 1e-10 * np.linalg.norm(t, axis=1))
    assert np.all(pr.distance <= np.abs(offset) + 1e-12)  # no farther than the point it came from
    np.testing.assert_allclose(pr.points, geometry.surface_points(g, pr.uv).points, atol=1e-15)


# --------------------------------------------------------------------------------------------
# timings (python tests/test_detect.py)


def _median_ms(fn, runs=7):
    out = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(out))


def benchmark():
    collider = box(0.3)
    hs = H.from_grid(*shapes.sphere(16, 14))
    pairs = {
        "sphere 16x14 vs box (12 tri), 0.1 deep": lambda z=1.2: (geometry.SurfaceGeometry(hs, move()), geometry.ColliderGeometry(collider, move(0.0, 0.0, z))),
        "sphere 16x14 vs sphere 16x14, 0.1 deep": lambda z=1.9: (geometry.SurfaceGeometry(hs, move()), geometry.SurfaceGeometry(hs, move(0.0, 0.0, z))),
    }
    rays = np.random.default_rng(0).normal(size=(100, 3))
    for name, pair in pairs.items():
        start_z = 1.2 + 0.4 if "box" in name else 1.9 + 0.4
        end_z = 1.2 if "box" in name else 1.9

        def geometry_at(t, pair=pair, a=start_z, b=end_z):
            return pair(a + (b - a) * float(np.clip(t - 10.0, 0.0, 1.0)))

        warm = C.RewindCache()
        C.detect_pair(*pair(), 11.0, geometry_at, start=0.0, cache=warm)
        rows = {
            "detect_pair (fallback, fresh geometry)": lambda: C.detect_pair(*pair(), 11.0),
            "detect_pair (rewound, fresh cache)": lambda: C.detect_pair(*pair(), 11.0, geometry_at, start=0.0),
            "detect_pair (rewound, warm cache)": lambda: C.detect_pair(*pair(), 11.0, geometry_at, start=0.0, cache=warm),
            "residual (fresh geometry)": lambda: D.residual(*pair()),
            "cast 100 rays onto B (fresh geometry)": lambda: (D._CASTS.clear(), D.cast(pair()[1], rays * 0.1 + [0, 0, 1.0], rays)),
            "touching (fresh geometry)": lambda: D.touching(*pair()),
        }
        print(name)
        for label, fn in rows.items():
            print(f"  {label:44s} {_median_ms(fn):8.1f} ms")


if __name__ == "__main__":
    benchmark()


def test_an_off_centre_ball_stored_in_float32_is_still_closed():
    """float32 ``acra:cvs`` round a pole row by ~1e-8 of the size: still one point, still closed."""
    cvs, pu, pv = shapes.sphere(8, 8, radii=(0.7,) * 3, center=(0.3, 0.1, 0.2))
    g = geometry.SurfaceGeometry(H.from_grid(cvs.astype(np.float32).astype(np.float64), pu, pv), move())
    assert g.closed
    pole = geometry.surface_points(g, np.array([[0.5, 0.0], [0.5, g.surface.v.patches0]])).points
    np.testing.assert_allclose(pole, [[0.3, 0.1, -0.5], [0.3, 0.1, 0.9]], atol=1e-6)
    np.testing.assert_array_equal(D.inside(g, pole + [[0, 0, 1e-3], [0, 0, -1e-3]]), [True, True])
    np.testing.assert_array_equal(D.inside(g, pole - [[0, 0, 1e-3], [0, 0, -1e-3]]), [False, False])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_responded_shape_reuses_its_parents_grids_only_where_it_did_not_change(seed):
    """The responded shape's grids (the parent's where unchanged, re-evaluated elsewhere) equal a
    fresh shape's, and most are the parent's own objects."""
    from acra import respond as R

    rng = np.random.default_rng(seed)
    hs = H.from_grid(*shapes.sphere(24, 16), depth=3)
    u0 = int(rng.integers(0, 24))
    hs = H.make_movable(hs, 2, [[4 * u0, 24]])
    hs = with_random_offsets(hs, 0.02, seed)
    every = every_patch(hs)
    parent = S.shape_of(hs)
    parent.grids_for(every)
    uv = np.array([[u0 + rng.uniform(0, 1), 6 + rng.uniform(0, 1)]])
    p = H.evaluate(hs, uv[:, 0], uv[:, 1]).points
    out, rep = R.respond(hs, DataPoints(uv, 0.9 * p, np.array([True])), check_controls(3, absorption=[0, 0.5, 0.5]))
    S.seed_details(out, rep.details, parent=hs)
    child = S.shape_of(out)
    assert child.parent is parent
    derived = child.grids_for(every)
    reused = np.array([a is b for a, b in zip(derived, parent.grids_for(every))])
    assert 0.75 * len(every) < reused.sum() < len(every)  # local: most grids are the parent's
    fresh = S.Shape(out).grids_for(every)
    for a, b in zip(derived, fresh):
        np.testing.assert_allclose(a.points, b.points, rtol=0, atol=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_responded_shape_s_grid_set_from_its_parents_answers_as_a_new_one(seed):
    """A responded shape queried near the response, where its parent was, takes the parent's
    `GridSet` of those patches (faces, parameters, refitted trees): its closest points, distances
    and parameters are those of a set built anew from the same grids, bit for bit."""
    hs, out, _, rng, p = responded_sphere(seed)
    parent = S.shape_of(hs)
    q = p * rng.uniform(0.8, 1.1, (40, 1)) + 0.05 * rng.normal(size=(40, 3))
    found = tuple(range(len(parent._boxes[2])))
    like = parent.cache.gridset(found)
    like.nearest(q)  # its trees built
    child = S.shape_of(out)
    assert child.parent is parent
    kept = child.cache.gridset(found)
    assert kept.triangles is like.triangles and any(a is not b for a, b in zip(kept.grids, like.grids))
    got = kept.nearest(q)
    assert all(c.index.tree.order is d.index.tree.order for (_, c), (_, d) in zip(kept.indices, like.indices))
    ref = S.GridSet(kept.grids).nearest(q)
    for a, b in zip((got.distance, got.points, got.uv), (ref.distance, ref.points, ref.uv)):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("seed,absorption", [(0, [0, 0.5, 0.5]), (2, [0.4, 0.3, 0.3]), (3, [1.0, 0, 0])])
def test_a_responded_shapes_orientation_needs_no_changed_patches(seed, absorption):
    """`Shape.outward` of a responded shape (the residual's only ask of it, `frames._Run.visible`)
    evaluates its coarse grid without finding the changed patches (`_stale`, which compares every
    level): the same points as a fresh shape's, bit for bit, so the same sign; the changed patches
    are found once a builder that reuses the parent's asks (`coarse_index`), with the same answers."""
    hs, out, rep, rng, p = responded_sphere(seed, absorption)
    parent = S.shape_of(hs)
    parent.coarse_index  # the parent's grid and tree built, as detection leaves them
    child = S.shape_of(out)
    assert child.parent is parent
    outward = child.outward
    assert "_stale" not in child.__dict__
    fresh = S.Shape(out)
    fresh.__dict__["details"] = rep.details
    for a, b in zip(child._coarse, fresh._coarse):
        np.testing.assert_array_equal(a, b)
    assert outward == fresh.outward
    q = p * rng.uniform(0.8, 1.1, (40, 1)) + 0.05 * rng.normal(size=(40, 3))
    np.testing.assert_array_equal(child.coarse_index.query(q), fresh.coarse_index.query(q))
    assert 0 < child._stale.sum() < child._stale.size


@pytest.mark.parametrize("seed,absorption", [(0, [0, 0.5, 0.5]), (1, [0, 0.5, 0.5]), (2, [0.4, 0.3, 0.3]), (3, [1.0, 0, 0])])
def test_a_responded_shape_reuses_its_parents_boxes_and_coarse_grid_exactly(seed, absorption):
    """Hull boxes and the coarse sample grid of a responded shape (the parent's where the
    response did not reach, recomputed elsewhere) equal a fresh shape's bit for bit, whichever
    levels moved."""
    hs, out, rep, _, _ = responded_sphere(seed, absorption)
    parent = S.shape_of(hs)
    child = S.shape_of(out)
    assert child.parent is parent and 0 < child._stale.sum() < child._stale.size
    fresh = S.Shape(out)
    fresh.__dict__["details"] = rep.details
    for a, b in zip(child.hulls + child._coarse[:2], fresh.hulls + fresh._coarse[:2]):
        np.testing.assert_array_equal(a, b)
    assert np.any(child._coarse[0] != parent._coarse[0])  # the move reached the coarse grid
    # distances to the coarse points: the parent's tree without the moved points and a tree of
    # those (`CoarseIndex`), the same bits as a tree of the child's points, also where a query's
    # nearest parent points all moved
    from scipy.spatial import cKDTree

    pts = child._coarse[0]
    moved = np.any(pts != parent._coarse[0], axis=1)
    rng = np.random.default_rng(seed)
    q = np.concatenate([rng.uniform(pts.min(axis=0), pts.max(axis=0), (2000, 3)), parent._coarse[0][moved], pts[moved]])
    shared = 4 * 9 * child._stale.sum() <= len(pts)  # a response that moved a quarter of the points builds anew
    assert (child.coarse_index.tree is parent.coarse_index.tree) == shared and (child.coarse_index.extra is not None) == shared
    np.testing.assert_array_equal(child.coarse_index.query(q), cKDTree(pts).query(q)[0])
    # every level's CV positions, on the parent's subdivision rows and weights where the response
    # kept the levels' cv_keys, the same bits as built afresh
    parent.cv_positions
    for a, b in zip(child.cv_positions, fresh.cv_positions):
        np.testing.assert_array_equal(a, b)
    for k in range(1, out.depth):
        kept = all(out.level(j).cv_keys is hs.level(j).cv_keys for j in range(max(k - 1, 1), k + 1))
        assert (child._cv_refinements[k] is parent._cv_refinements[k]) == kept


def test_changed_patches_marks_the_support_of_a_moved_cv():
    hs = H.from_grid(*shapes.sheet(12, 12, width=9.0, depth=9.0), depth=2)
    hs = H.make_movable(hs, 1, [[8, 8]])
    idx, off = H.offsets_of(hs, 1)
    row = int(np.nonzero((idx[:, 0] == 9) & (idx[:, 1] == 9))[0][0])
    off = off.copy()
    off[row] = [0.0, 0.0, 0.1]
    moved = H.set_offsets(hs, 1, idx, off)
    mask = H.changed_patches(hs, moved, margin=0)
    # level-1 CV 9 supports level-1 patches 6..9, i.e. level-0 patches 3..4 in each direction
    assert set(map(tuple, np.argwhere(mask))) == {(3, 3), (3, 4), (4, 3), (4, 4)}
    assert not H.changed_patches(hs, hs).any()


def test_inside_is_reproducible_for_points_on_the_surface():
    """Points exactly on the surface make trimesh re-cast in a random direction; the answer must
    still be the same on every call (a farm run is reproducible)."""
    g = sphere_geom()
    on = T.tessellate(g, every_patch(g.surface)).points[::7]
    rng = np.random.default_rng(3)
    mid = on + 1e-12 * rng.normal(size=on.shape)
    first = D.inside(g, mid)
    for _ in range(5):
        np.random.default_rng().random(10)  # unrelated draws in between do not matter
        np.testing.assert_array_equal(D.inside(g, mid), first)


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3])
def test_points_on_a_collider_face_are_not_inside_at_any_scale(scale):
    """A point on a collider's face, or a rounding error off it on either side, is on the mesh
    (`detect.ON_MESH` of its size) and not inside, whatever ray parity makes of it; a point
    1e-7 of the size in is inside. The answers are the same at every scale of the scene."""
    half = 0.48828125 * scale
    g = geometry.ColliderGeometry(box(half), move(0.25 * scale, -0.125 * scale, 0.5 * scale))
    rng = np.random.default_rng(5)
    local = rng.uniform(-0.9, 0.9, size=(64, 3)) * half
    local[:, 1] = -half  # on the face y = -half, the box's lowest plane
    size = g.static.mesh.scale
    for off, expect in ((0.0, False), (1e-15, False), (-1e-15, False), (1e-7, True)):
        pts = local + np.array([0.0, off * size, 0.0])
        world = pts + g.xform[:3, 3]
        assert D.inside(g, world).tolist() == [expect] * len(pts), (off, scale)
        m, _, _, depth = D._inside_rows(g, world)
        assert m.tolist() == [expect] * len(pts) and len(depth) == int(m.sum())


def test_points_outside_the_cv_hull_are_outside_without_a_search():
    """`Shape.signed` skips the closest-point search for points outside the convex hull of every
    level's CVs (the surface and what it encloses lie inside it). On a thin spindle with detail,
    seeded points filling its box: the same inside set and the same nearest points as a search of
    every point, while most points are decided by the hull alone; and every CV-hull half-space
    holds the surface's own samples (convex hull property, including the fine levels)."""
    rng = np.random.default_rng(11)
    c, s_ = np.cos(np.pi / 4), np.sin(np.pi / 4)
    tilt = np.array([[1, 0, 0], [0, c, -s_], [0, s_, c]]) @ np.array([[c, 0, s_], [0, 1, 0], [-s_, 0, c]])
    cvs = shapes.sphere(8, 12, radii=(0.15, 0.15, 1.0))[0] @ tilt.T  # diagonal in its box, like a spike
    hs = H.from_grid(cvs, True, False, depth=3)
    hs = H.make_movable(H.make_movable(hs, 1, [[4, 9]]), 2, [[9, 18], [5, 17]])  # away from the poles
    hs = with_random_offsets(hs, 0.02, seed=11)
    hulled, plain = S.Shape(hs), S.Shape(hs)
    plain.__dict__["cv_hull"] = None  # the cached property, bypassed: search every point
    lo, hi = hs.cvs.reshape(-1, 3).min(axis=0), hs.cvs.reshape(-1, 3).max(axis=0)
    q = rng.uniform(lo, hi, (3000, 3))
    m1, n1 = hulled.signed(q)
    m2, n2 = plain.signed(q)
    np.testing.assert_array_equal(m1, m2)
    np.testing.assert_allclose(n1.points, n2.points, rtol=0, atol=1e-12)  # other search batches: rounding
    assert 0 < m1.sum() < 0.1 * len(q)
    outside = (q @ hulled.cv_hull[:, :3].T + hulled.cv_hull[:, 3]).max(axis=1) > 0
    assert outside.mean() > 0.8  # most of a thin object's box is decided without a search
    uu, vv = np.meshgrid(np.linspace(0, hs.u.patches0, 40), np.linspace(0, hs.v.patches0, 40))
    p = H.evaluate(hs, uu.ravel(), vv.ravel()).points
    assert (p @ hulled.cv_hull[:, :3].T + hulled.cv_hull[:, 3]).max() <= 1e-12


def test_cv_refinements_are_kept_by_the_levels_keys():
    """`Shape._cv_refinement`: a surface without a parent whose levels hold the same ``cv_keys``
    (other arrays, as a later frame's response refining the same region builds them) takes the
    subdivision rows and weights built for an earlier one, the same as built afresh."""
    hs = with_random_offsets(H.make_movable(H.from_grid(*shapes.sphere(12, 10), depth=3), 2, [[9, 10]]), 0.02, 3)
    again = H.with_fine(hs, tuple(H.Level(lev.k, lev.patches.copy(), lev.cv_keys.copy(), lev.offsets, lev.movable, lev.patch_rows)
                                  for lev in hs.fine))
    first, second = S.Shape(hs), S.Shape(again)
    for a, b in zip(first.cv_positions, second.cv_positions):
        np.testing.assert_array_equal(a, b)
    for k in (1, 2):
        assert second._cv_refinements[k] is first._cv_refinements[k]
        for a, b in zip(second._cv_refinements[k], H.cv_refinement(again, k)):
            np.testing.assert_array_equal(a, b)


def test_hull_index_answers_as_every_facet():
    """`HullIndex.within` (the facet whose cone from the centre holds a point, every facet only
    where that does not settle it) answers as the test against every facet: random points in and
    around a 64x48 ellipsoid net's hull (5,000 facets), the CVs themselves and points within
    1e-10 of them, at the slack `Shape.signed` uses and at none."""
    from scipy.spatial import ConvexHull

    rng = np.random.default_rng(5)
    cvs = shapes.sphere(64, 48, radii=(1.0, 0.85, 0.9))[0].reshape(-1, 3)
    index = S.HullIndex(ConvexHull(cvs))
    eq = index.equations
    q = np.concatenate([rng.uniform(-1.2, 1.2, (20000, 3)), cvs * (1 + rng.normal(size=(len(cvs), 1)) * 1e-10), cvs])
    every = q @ eq[:, :3].T + eq[:, 3]
    np.testing.assert_array_equal(index.within(q, 1e-9), every.max(axis=1) <= 1e-9)
    got = index.within(q, 0.0)
    exact = every.max(axis=1)
    decided = np.abs(exact) > 1e-15  # a point on a facet plane: either answer is the rounding's
    np.testing.assert_array_equal(got[decided], exact[decided] <= 0.0)


def test_a_small_hull_tests_every_facet_compiled():
    """A hull of at most `HullIndex.DIRECT` facets (a 14x12 ellipsoid net's, about 300) answers
    many points by the compiled test against every facet, with no kd-tree of cone directions
    built, as the test against every facet does: random points in and around it, the CVs within
    1e-10, at the slack `Shape.signed` uses and at none; a point with a NaN coordinate is outside."""
    from scipy.spatial import ConvexHull

    rng = np.random.default_rng(7)
    cvs = shapes.sphere(14, 12, radii=(1.0, 0.85, 0.9))[0].reshape(-1, 3)
    index = S.HullIndex(ConvexHull(cvs))
    eq = index.equations
    assert len(eq) <= S.HullIndex.DIRECT
    q = np.concatenate([rng.uniform(-1.2, 1.2, (4000, 3)), cvs * (1 + rng.normal(size=(len(cvs), 1)) * 1e-10),
                        [[np.nan, 0.0, 0.0], [0.0, 0.0, 0.0]]])
    assert len(q) * len(eq) > 1 << 16  # too many for one matrix of every value
    every = (q @ eq[:, :3].T + eq[:, 3]).max(axis=1)
    np.testing.assert_array_equal(index.within(q, 1e-9), every <= 1e-9)
    got = index.within(q, 0.0)
    decided = np.isnan(every) | (np.abs(every) > 1e-15)  # on a facet plane: either answer is the rounding's
    np.testing.assert_array_equal(got[decided], every[decided] <= 0.0)
    assert not got[-2] and got[-1]
    assert "_cones" not in index.__dict__


@pytest.mark.parametrize("n", [14, 40])
def test_a_hull_answers_no_points_with_no_answers(n):
    """`HullIndex.within` of no points is an empty answer for a hull tested facet by facet (14x12
    net) and for one looked up by its cones (a 40x30 net's, above `HullIndex.DIRECT` facets), as
    a response that moves no CV out of level 0's hull asks (`Shape.cv_index`)."""
    from scipy.spatial import ConvexHull

    index = S.HullIndex(ConvexHull(shapes.sphere(n, 3 * n // 4, radii=(1.0, 0.85, 0.9))[0].reshape(-1, 3)))
    assert (len(index.equations) > S.HullIndex.DIRECT) == (n == 40)
    got = index.within(np.zeros((0, 3)), 0.0)
    assert got.shape == (0,) and got.dtype == np.bool_


@pytest.mark.parametrize("seed,absorption", [(0, [0, 0.5, 0.5]), (1, [0, 0.5, 0.5]), (2, [0.4, 0.3, 0.3]), (3, [1.0, 0, 0])])
def test_a_responded_shape_s_cv_hull_is_level_0_s_and_its_moved_cvs(seed, absorption):
    """`Shape.cv_hull` of a responded shape, built from level 0's hull and the CVs with details
    alone, is the hull of every level's CVs: each CV within 1e-12 of the size of it, and each of
    its half-spaces holds a hull of every CV within 1e-12 (no larger). A response that leaves level
    0 shares its parent's level-0 hull, and where no CV with a detail leaves it, takes it whole."""
    from scipy.spatial import ConvexHull

    hs, out, rep, _, _ = responded_sphere(seed, absorption)
    parent, child = S.shape_of(hs), S.shape_of(out)
    parent._level0_index  # built, as detection on an input without details builds it before a response
    every = np.concatenate(child.cv_positions)
    tol = 1e-12 * out.size()
    assert (every @ child.cv_hull[:, :3].T + child.cv_hull[:, 3]).max() <= tol
    full = ConvexHull(every)
    corners = full.points[full.vertices]
    assert np.abs(corners @ child.cv_hull[:, :3].T + child.cv_hull[:, 3]).min(axis=0).max() <= tol  # every facet touches a CV
    hull_pts = child.cv_index.hull.points[child.cv_index.hull.vertices]
    assert (hull_pts @ full.equations[:, :3].T + full.equations[:, 3]).max() <= tol
    same0 = np.array_equal(out.cvs, hs.cvs)
    assert (child._level0_index is parent._level0_index) == same0
    moved = [p[np.any(v != 0, axis=1)] for p, v in zip(child.cv_positions[1:], rep.details.vectors)]
    moved = np.concatenate(moved)
    eq0 = child._level0_index.equations
    if (moved @ eq0[:, :3].T + eq0[:, 3]).max() < -1e-12:
        assert child.cv_index is child._level0_index
    # with no level-0 hull at hand, one qhull of level 0 and the CVs with details: none built for level 0
    lone = S.Shape(out, parent=S.Shape(hs))
    lone.__dict__["details"] = rep.details
    assert (every @ lone.cv_hull[:, :3].T + lone.cv_hull[:, 3]).max() <= tol
    assert "_level0_index" not in lone.__dict__ and "_level0_index" not in lone.parent.__dict__


@pytest.mark.parametrize("seed", range(3))
def test_world_patch_boxes_are_the_boxes_of_the_mapped_hull_corners(seed):
    """`SurfaceGeometry.boxes` (centre and half-extents mapped) equals the box of each hull box's
    8 corners mapped by the matrix, to rounding."""
    geom = sphere_geom(rotated_scaled(seed))
    lo, hi = geom.shape.hulls
    corners = np.stack([np.where(np.array([a, b, c], bool), hi, lo) for a in (0, 1) for b in (0, 1) for c in (0, 1)], axis=-2)
    world = (corners.reshape(-1, 3) @ geom.xform[:3, :3].T + geom.xform[:3, 3]).reshape(corners.shape)
    wlo, whi = geom.boxes
    scale = np.abs(world).max()
    assert np.allclose(wlo, world.min(axis=-2), rtol=0, atol=1e-14 * scale)
    assert np.allclose(whi, world.max(axis=-2), rtol=0, atol=1e-14 * scale)


@pytest.mark.parametrize("seed", range(4))
def test_object_boxes_hold_the_exact_boxes_and_apart_implies_no_overlap(seed):
    """`outer` (the object-space box mapped once) holds `bounds` (the union of the world patch
    boxes, or of a collider's mapped vertices) under rotation, non-uniform scale and a far
    translation, and `apart` is True only where `_boxes_overlap` with the pair's padding is
    False; pairs placed near touching are tested both ways."""
    rng = np.random.default_rng(seed)
    m = rotated_scaled(seed)
    if seed % 2:
        m[:3, 3] *= 1e4  # far from the origin: the translation's rounding dominates
    ball = trimesh.creation.icosphere(2)
    static = geometry.prepare_collider(ColliderModel("/ball", ball.vertices, ball.faces))
    base = sphere_geom(m)
    for g in (base, geometry.ColliderGeometry(static, m)):
        assert np.all(g.outer[0] <= g.bounds[0]) and np.all(g.outer[1] >= g.bounds[1])
    seen = set()
    for _ in range(40):
        other = m.copy()
        other[:3, 3] += rng.normal(size=3) * rng.choice([0.5, 2.0, 6.0, 20.0])
        for gb in (sphere_geom(other, "/other"), geometry.ColliderGeometry(static, other)):
            meets = D._boxes_overlap(base, gb, D.pair_pad(base, gb))
            assert not (D.apart(base, gb) and meets)
            seen.add((D.apart(base, gb), meets))
    assert (True, False) in seen and (False, True) in seen


@pytest.mark.parametrize("seed", range(3))
def test_apart_all_is_apart_of_every_pair(seed):
    """`apart_all` gives `apart`'s answer for every two of a list of surfaces and colliders placed
    at random, many near touching (boxes a pad apart, equal sides, one inside another), with
    the diagonal entries apart from nothing."""
    rng = np.random.default_rng(seed)
    ball = trimesh.creation.icosphere(1)
    static = geometry.prepare_collider(ColliderModel("/ball", ball.vertices, ball.faces))
    geoms = []
    for k in range(12):
        m = move(*(rng.integers(-3, 4, size=3) * rng.choice([0.5, 1.0, 2.0, 2.0 + 1e-7])))
        geoms.append(sphere_geom(m, f"/s{k}") if k % 3 else geometry.ColliderGeometry(static, m))
    far = D.apart_all(geoms)
    want = np.array([[D.apart(a, b) for b in geoms] for a in geoms])
    np.testing.assert_array_equal(far, want)
    assert want.any() and not want.all()


def test_a_pair_apart_builds_no_world_patch_boxes():
    """Detection of two deformables whose objects are apart, and the free frame's sizes, never
    build the world box of each level-0 patch (`SurfaceGeometry.boxes`): the work of a free frame
    does not grow with the model."""
    ga, gb = sphere_geom(move()), sphere_geom(move(10.0, 0, 0), "/far")
    assert C.detect_pair(ga, gb) is None and not D.touching(ga, gb)
    assert D.residual(ga, gb).count == 0
    assert "boxes" not in vars(ga) and "boxes" not in vars(gb)
    near = sphere_geom(move(1.5, 0, 0), "/near")
    assert C.detect_pair(ga, near) is not None and "boxes" in vars(ga)


@pytest.mark.parametrize("seed", [0, 1])
def test_collider_inside_agrees_with_ray_parity_near_and_far(seed):
    """A collider's inside: the pseudo-normal side off the mesh (beyond `detect.SIDE_SURE` of its
    size) and ray parity nearer, against parity everywhere with the `ON_MESH` band, on points of
    a ball's faces moved along random directions by rounding up to 1e-2 of its size."""
    from pipeline.authoring import uv_sphere

    v, f = uv_sphere(0.45, 24, 12)
    rot = trimesh.transformations.rotation_matrix(0.7, [1, 2, 3])
    g = geometry.ColliderGeometry(geometry.prepare_collider(ColliderModel("/ball", np.asarray(v), np.asarray(f))), move(0.3, -0.2, 1.1) @ rot)
    st = g.static
    rng = np.random.default_rng(seed)
    tri = st.mesh.triangles[rng.integers(0, len(st.mesh.faces), 150)]
    on = np.einsum("ij,ijk->ik", rng.dirichlet([1.0, 1.0, 1.0], 150), tri)
    size = st.mesh.scale
    local = np.concatenate([on + rng.normal(size=on.shape) * e * size
                            for e in (0.0, 1e-15, 5e-10, 2e-9, 1e-7, 5e-7, 2e-6, 1e-4, 1e-2)])
    world = (g.xform[:3, :3] @ local.T).T + g.xform[:3, 3]
    local = apply_inverse(g.xform, world)
    trimesh.util._RANDOM_DEFAULT = np.random.default_rng(20260311)
    want = st.mesh.contains(local)
    want[st.index.query(local)[0] <= D.ON_MESH * size] = False
    got = D.inside(g, world)
    np.testing.assert_array_equal(got, want)
    m, _, _, depth = D._inside_rows(g, world)
    np.testing.assert_array_equal(m, want)
    assert len(depth) == int(want.sum())
    far = st.index.query(local)[0] > D.SIDE_SURE * size
    assert 0.2 < far.mean() < 0.8 and 0 < want[far].sum() < far.sum()  # both rules answer some points


def _convex_collider(kind: str, rng) -> geometry.ColliderStatic:
    """A box, a flat slab, or the convex hull of random points (at most `PLANES_MAX` faces)."""
    if kind == "box":
        return box(0.7)
    if kind == "slab":
        return geometry.prepare_collider(ColliderModel("/slab", BOX_VERTICES * [2.0, 0.01, 1.5], BOX_TRIANGLES))
    hull = trimesh.convex.convex_hull(rng.normal(size=(14, 3)) * [1.0, 0.6, 0.3])
    return geometry.prepare_collider(ColliderModel("/hull", np.asarray(hull.vertices), np.asarray(hull.faces)))


@pytest.mark.parametrize("kind,seed", [("box", 0), ("box", 1), ("slab", 2), ("hull", 3), ("hull", 4), ("hull", 5)])
def test_collider_inside_by_planes_is_the_closest_points_answer(kind, seed):
    """A convex collider's face planes (`ColliderStatic.planes`) answer `inside` and
    `_inside_rows` exactly as the closest points and parity do, on points of its faces, edges and
    corners moved by rounding up to far outside and deep inside, under a rotation and scale."""
    rng = np.random.default_rng(seed)
    st = _convex_collider(kind, rng)
    assert st.planes is not None and st.planes.shape == (len(st.solid.faces), 4)
    rot = trimesh.transformations.rotation_matrix(0.3 + seed, rng.normal(size=3))
    g = geometry.ColliderGeometry(st, move(*rng.normal(size=3)) @ rot @ np.diag([3.0, 3.0, 3.0, 1.0]))
    tri = st.mesh.triangles[rng.integers(0, len(st.mesh.faces), 200)]
    w = rng.dirichlet([1.0, 1.0, 1.0], 200)
    w[:50, 0] = 0.0  # on an edge
    w[50:80] = np.eye(3)[rng.integers(0, 3, 30)]  # on a corner
    on = np.einsum("ij,ijk->ik", w / w.sum(axis=1, keepdims=True), tri)
    size = st.mesh.scale
    local = np.concatenate([on + rng.normal(size=on.shape) * e * size
                            for e in (0.0, 1e-15, 5e-10, 1e-7, 1.5e-6, 2.5e-6, 5e-6, 1e-4, 1e-2, 0.3)])
    world = apply_inverse(np.linalg.inv(g.xform), local)
    slow = geometry.ColliderStatic(st.path, st.mesh, st.bvh, st.closed)
    slow.__dict__["planes"] = None
    gs = geometry.ColliderGeometry(slow, g.xform)
    got, want = D.inside(g, world), D.inside(gs, world)
    np.testing.assert_array_equal(got, want)
    (m, _, _, depth), (ms, _, _, depths) = D._inside_rows(g, world), D._inside_rows(gs, world)
    np.testing.assert_array_equal(m, ms)
    np.testing.assert_array_equal(depth, depths)
    assert 0 < want.sum() < len(want)


def test_intersect_answers_are_kept_by_content_and_never_served_for_other_content():
    """`intersect` keeps its answers by the pair's content: the same surface content and matrices
    in new objects get the kept answer, a moved matrix or changed CVs (one ulp) a new one that
    says what the new pair does, and at most `ANSWERS_KEPT` answers are kept."""
    hs = H.from_grid(*shapes.sphere(16, 14))
    a = geometry.SurfaceGeometry(hs, move(), "/a")
    b = geometry.SurfaceGeometry(hs, move(1.5, 0.0, 0.0), "/b")
    first = D.intersect(a, b)
    assert first.crosses
    again = D.intersect(geometry.SurfaceGeometry(H.with_cvs(hs, hs.cvs.copy()), move(), "/a"), geometry.SurfaceGeometry(hs, move(1.5, 0.0, 0.0), "/b"))
    assert again is first
    apart = D.intersect(a, geometry.SurfaceGeometry(hs, move(3.5, 0.0, 0.0), "/b"))  # the matrix moved b clear
    assert not apart.crosses
    shrunk = D.intersect(geometry.SurfaceGeometry(H.with_cvs(hs, 0.5 * hs.cvs), move(), "/a"), b)  # the CVs changed
    assert not shrunk.crosses
    cvs = hs.cvs.copy()
    cvs[0, 0, 0] = np.nextafter(cvs[0, 0, 0], np.inf)
    assert D.intersect(geometry.SurfaceGeometry(H.with_cvs(hs, cvs), move(), "/a"), b) is not first
    for k in range(2 * D.ANSWERS_KEPT):
        D.intersect(a, geometry.SurfaceGeometry(hs, move(1.0 + 0.01 * k, 0.0, 0.0), "/b"))
    assert len(D._ANSWERS) == D.ANSWERS_KEPT
    assert D.intersect(a, b) is not first and D.intersect(a, b).count == first.count


@pytest.mark.parametrize("kind", ["hspline", "collider"])
def test_cast_answers_are_kept_by_content_and_never_served_for_other_content(kind, monkeypatch):
    """`cast` keeps its answers by the geometry's content and the rays: a new geometry of the
    same content gets the kept answer without casting (arrays of its own), a moved matrix or a
    changed CV (one ulp) or other rays a new answer equal to a fresh one, and at most
    `CASTS_KEPT` answers are kept."""
    hs = H.from_grid(*shapes.sphere(16, 14))
    static = box(0.8)

    def geom(xform, surface=hs):
        return geometry.SurfaceGeometry(surface, xform) if kind == "hspline" else geometry.ColliderGeometry(static, xform)

    computed = []
    fresh = D._cast
    monkeypatch.setattr(D, "_cast", lambda *a: computed.append(1) or fresh(*a))
    D._CASTS.clear()
    rng = np.random.default_rng(3)
    origins, dirs = rng.uniform(-0.2, 0.2, (40, 3)), rng.normal(size=(40, 3))
    hits, valid = D.cast(geom(move()), origins, dirs)
    assert valid.all()
    hits[:] = np.nan
    again = D.cast(geom(move(0.0, 0.0, 0.0)), origins, dirs)
    assert len(computed) == 1 and np.isfinite(again[0]).all()
    cvs = hs.cvs.copy()
    cvs[3, 3, 0] = np.nextafter(cvs[3, 3, 0], np.inf)
    others = [(geom(move(0.05, 0.0, 0.0)), origins, dirs), (geom(move()), origins, -dirs)]
    if kind == "hspline":
        others.append((geom(move(), H.with_cvs(hs, cvs)), origins, dirs))
    for k, (g, o, d) in enumerate(others):
        got = D.cast(g, o, d)
        want = fresh(g, o, d, None, None)
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(got[1], want[1])
        assert k == 2 or not np.array_equal(got[0], again[0])  # an ulp of one CV may move no hit
    assert len(computed) == 1 + len(others)
    for k in range(2 * D.CASTS_KEPT):
        D.cast(geom(move(0.001 * (k + 1), 0.0, 0.0)), origins, dirs)
    assert len(D._CASTS) == D.CASTS_KEPT


def test_geometries_of_the_same_content_share_world_data_and_others_do_not():
    """Geometries with the same surface content, matrix and densities share their world grids,
    tessellations, patch boxes and bounds (`geometry._World`); a moved matrix or changed CVs get their own,
    equal to a fresh computation, and at most `WORLDS_KEPT` contents are kept."""
    from pipeline.model import apply_xform

    hs = H.from_grid(*shapes.sphere(16, 14))
    patches = np.array([[0, 0], [1, 2], [3, 1]])
    a = geometry.SurfaceGeometry(hs, move(0.25, 0.0, 0.0))
    ta = T.tessellate(a, patches)
    b = geometry.SurfaceGeometry(H.with_cvs(hs, hs.cvs.copy()), move(0.25, 0.0, 0.0))
    assert b._world is a._world and b.boxes is a.boxes and T.tessellate(b, patches) is ta
    assert b.bounds is a.bounds and not a.bounds.flags.writeable  # shared, so no caller may write it
    assert T.tessellated(b).tolist() == patches.tolist()
    for other in (geometry.SurfaceGeometry(hs, move(0.5, 0.0, 0.0)), geometry.SurfaceGeometry(H.with_cvs(hs, 1.5 * hs.cvs), move(0.25, 0.0, 0.0))):
        assert other._world is not a._world
        t = T.tessellate(other, patches)
        np.testing.assert_allclose(t.points, apply_xform(other.xform, H.evaluate(other.surface, t.uv[:, 0], t.uv[:, 1]).points), atol=1e-13)
        assert not np.allclose(t.points, ta.points)
        lo, hi = other.shape.hulls  # the world boxes of this surface at this matrix, found afresh
        centre = apply_xform(other.xform, (0.5 * (lo + hi)).reshape(-1, 3)).reshape(lo.shape)
        half = ((0.5 * (hi - lo)).reshape(-1, 3) @ np.abs(other.xform[:3, :3]).T).reshape(lo.shape)
        np.testing.assert_array_equal(other.boxes[0], centre - half)
        np.testing.assert_array_equal(other.boxes[1], centre + half)
        assert other.bounds is not a.bounds
        np.testing.assert_array_equal(other.bounds, [(centre - half).reshape(-1, 3).min(axis=0), (centre + half).reshape(-1, 3).max(axis=0)])
    for k in range(2 * geometry.WORLDS_KEPT):
        geometry.SurfaceGeometry(hs, move(0.01 * k, 0.0, 0.0)).boxes
    assert len(geometry._WORLDS) == geometry.WORLDS_KEPT


def test_a_new_contents_first_patch_set_maps_the_shapes_kept_grid_points():
    """Each matrix's first patch set maps the shape's kept concatenation of the set's grid points
    (`GridCache.set_points`, one array for every matrix, as a rewinding search's steps ask), with
    the product a fresh one gives; a later set of the same content takes the first set's rows of
    the patches they share; the still geometry's object-level box is kept in its world data, and
    the shape's object-space patch boxes once for every matrix."""
    from pipeline.model import apply_xform

    hs = H.from_grid(*shapes.sphere(16, 14))
    first, later = np.array([[0, 0], [1, 2], [3, 1]]), np.array([[1, 2], [2, 2], [3, 1]])
    seen = []
    for k in range(3):
        g = geometry.SurfaceGeometry(hs, move(0.1 + 0.37 * k, 0.2 * k, 0.0))
        t = T.tessellate(g, first)
        obj, grids = g.shape.cache.set_points(first)
        seen.append(obj)
        assert not obj.flags.writeable
        np.testing.assert_array_equal(t.points, apply_xform(g.xform, np.concatenate([x.points for x in g.shape.grids_for(first)])))
        u = T.tessellate(g, later)
        rows = np.cumsum([0] + [len(x.points) for x in grids])
        later_rows = np.cumsum([0] + [len(x.points) for x in g.shape.grids_for(later)])
        for i, j in ((1, 0), (2, 2)):  # patch (1, 2) and (3, 1): rows of the first set's product
            np.testing.assert_array_equal(u.points[later_rows[j]:later_rows[j + 1]], t.points[rows[i]:rows[i + 1]])
    assert seen[0] is seen[1] is seen[2]
    still = geometry.SurfaceGeometry(hs, move(0.1, 0.0, 0.0))
    D.pair_pad(still, still)
    again = geometry.SurfaceGeometry(hs, move(0.1, 0.0, 0.0))
    assert again._outer is still._outer and again._outer == geometry._mapped_box(again.xform, geometry._object_box(again.shape))
    boxes = geometry._object_patch_boxes(still.shape)  # every matrix maps one array of object boxes
    assert geometry._object_patch_boxes(again.shape) is boxes and not boxes[0].flags.writeable


def test_object_boxes_are_kept_by_weak_references_without_callbacks():
    """`_object_box` keeps each shape's box through a weak reference without a callback (an
    interrupt raised in a callback is dropped, not delivered to the run) and serves it while the
    shape lives."""
    g = sphere_geom(move())
    D.apart(g, sphere_geom(move(10.0, 0, 0), "/far"))
    shape = g.shape
    ref, box = geometry._OBJECT_BOXES[id(shape)]
    assert ref() is shape and geometry._object_box(shape) == box
    assert all(r.__callback__ is None for r in weakref.getweakrefs(shape))


def test_overlap_joins_the_three_axes_as_np_all_does():
    """`grids.overlap` joins the axes column by column: ``np.all(axis=-1)``'s answer for boxes of
    any leading shapes broadcast together, with sides that meet exactly (a pad of 0), NaN
    corners and 0-d answers for single boxes."""
    from pipeline.grids import overlap

    rng = np.random.default_rng(7)
    lo = np.round(rng.uniform(-1, 1, (6, 5, 3)), 1)
    hi = lo + np.round(rng.uniform(0, 1, (6, 5, 3)), 1)
    lo[0, 0, 1] = np.nan
    for pad in (0.0, 0.05):
        for args in ((lo, hi, lo[2, 3], hi[2, 3]), (lo[:, None], hi[:, None], lo[None, :2], hi[None, :2]),
                     (lo[1, 1], hi[1, 1], lo[4, 0], hi[4, 0])):
            got = overlap(*args, pad)
            want = np.all((args[0] <= args[3] + pad) & (args[2] <= args[1] + pad), axis=-1)
            assert got.shape == want.shape and got.dtype == want.dtype
            np.testing.assert_array_equal(got, want)


def test_touching_stops_at_a_crossing_pair_and_keeps_no_partial_answer():
    """`touching` of two crossing spheres stops the narrow phase at its first crossing pair
    (`acra.narrow.crossings`' ``first``): that partial count is not kept as the pair's
    `intersect` answer, which then counts every contact as a fresh pair's does; a pair that does
    not cross keeps the whole pass's answer."""
    hs = H.from_grid(*shapes.sphere(16, 14))
    pair = lambda x, z: (geometry.SurfaceGeometry(hs, move()), geometry.SurfaceGeometry(hs, move(x, 0.0, z)))  # noqa: E731
    D._ANSWERS.clear()
    ga, gb = pair(0.0, 1.9)
    assert D.touching(ga, gb)
    assert (ga.content, gb.content) not in D._ANSWERS
    whole = D.intersect(ga, gb).count
    assert whole > 1 and whole == D._intersect(*pair(0.0, 1.9)).count
    near = pair(1.5, 1.5)  # the boxes overlap, the spheres do not meet
    assert not D.touching(*near) and (near[0].content, near[1].content) in D._ANSWERS


def test_the_touch_test_s_box_checks_are_the_array_form():
    """`touching`'s test that every patch box meets the other object's box (`_every_box_meets`,
    from the boxes' highest low and lowest high corners) and `_box_meets` answer as
    `pipeline.grids.overlap` does, at and beyond ``pad``, with a NaN corner, in every direction."""
    from pipeline.grids import overlap

    rng = np.random.default_rng(7)
    g = geometry.SurfaceGeometry(sphere_geom().surface, move(0.3, -0.1, 0.2))
    lo, hi = (x.reshape(-1, 3) for x in g.boxes)
    for trial in range(400):
        # a box around some of the patch boxes' corners: some tests pass, some fail by a hair
        corner = lo[rng.integers(len(lo))] if rng.random() < 0.5 else hi[rng.integers(len(hi))]
        b = np.sort(np.stack([corner + rng.normal(0, 1.0, 3), corner + rng.choice([-1.0, 1.0], 3) * rng.random(3) * 3]), axis=0)
        pad = float(rng.choice([0.0, 1e-7, 0.5]))
        if trial % 2:  # the lowest high and highest low corners, one coordinate a step off: the edge
            b = np.stack([hi.min(axis=0) + pad, lo.max(axis=0) - pad])
            r, c = rng.integers(2), rng.integers(3)
            b[r, c] = np.nextafter(b[r, c], rng.choice([-np.inf, np.inf]))
        if trial % 7 == 0:
            b[rng.integers(2), rng.integers(3)] = [np.nan, np.inf, -np.inf][trial % 3]
        fresh = geometry.SurfaceGeometry(g.surface, g.xform)
        assert D._every_box_meets(fresh, b, pad) == bool(overlap(lo, hi, b[0], b[1], pad).all()), trial
        other = np.stack([lo[trial % len(lo)], hi[trial % len(hi)]])
        assert D._box_meets(other, b, pad) == bool(overlap(other[0], other[1], b[0], b[1], pad)), trial
    # a still geometry's corners are its content's: the whole box of every patch passes
    assert D._every_box_meets(g, np.stack([lo.min(axis=0), hi.max(axis=0)]), 0.0)


def test_collider_inside_by_planes_raises_as_the_closest_points_do_on_points_not_finite():
    """A point with a NaN or infinite coordinate takes the closest points' path on a convex
    collider too (`pipeline.clearance.Unresolved`: no face is nearer than infinity), as on one
    answered by them alone."""
    from pipeline import clearance

    st = box(0.5)
    slow = geometry.ColliderStatic(st.path, st.mesh, st.bvh, st.closed)
    slow.__dict__["planes"] = None
    for bad in (np.nan, np.inf):
        p = np.array([[0.0, 0.0, 0.0], [bad, 0.0, 0.0]])
        for s in (st, slow):
            with pytest.raises(clearance.Unresolved), np.errstate(invalid="ignore"):
                D.inside(geometry.ColliderGeometry(s, move()), p)


def test_reseeded_generator_draws_what_a_new_one_of_the_seed_draws():
    """`_reseeded` sets its kept generator back to the seed's start: after any draws it gives what
    ``np.random.default_rng(_RECAST_SEED)`` gives, so trimesh's re-casts of points on a mesh take
    the same directions in every inside test."""
    for n in (0, 1, 7, 1000):
        g = D._reseeded()
        g.random(n)
        g.normal(size=n)
        assert D._reseeded() is g
        assert g.random(9).tobytes() == np.random.default_rng(D._RECAST_SEED).random(9).tobytes()


@pytest.mark.parametrize("seed", [0, 1])
def test_near_points_of_several_inside_tests_asked_at_once_answer_as_in_each(seed):
    """`collider_sides` settles the points off a collider's mesh and leaves the near ones to
    `near_inside`: together they are `inside`, and the near points of several calls asked in one
    `near_inside` get the answers each call's own gives (the re-cast generator set back to its
    seed for every call), on a ball turned and moved, points on its faces moved by up to 1e-2 of
    its size."""
    from pipeline.authoring import uv_sphere

    v, f = uv_sphere(0.45, 24, 12)
    rot = trimesh.transformations.rotation_matrix(0.7, [1, 2, 3])
    g = geometry.ColliderGeometry(geometry.prepare_collider(ColliderModel("/ball", np.asarray(v), np.asarray(f))), move(0.3, -0.2, 1.1) @ rot)
    st = g.static
    rng = np.random.default_rng(seed)
    calls, locals_ = [], []
    for _ in range(4):
        tri = st.mesh.triangles[rng.integers(0, len(st.mesh.faces), 60)]
        on = np.einsum("ij,ijk->ik", rng.dirichlet([1.0, 1.0, 1.0], 60), tri)
        local = np.concatenate([on + rng.normal(size=on.shape) * e * st.mesh.scale for e in (0.0, 1e-15, 2e-9, 1e-7, 1e-2)])
        world = (g.xform[:3, :3] @ local.T).T + g.xform[:3, 3]
        at, side, near = D.collider_sides(g, world)
        want = D.inside(g, world)
        each = side.copy()
        each[near] = D.near_inside(st, at[near])
        np.testing.assert_array_equal(each, want)
        calls.append((side, near, want))
        locals_.append(at[near])
    together = D.near_inside(st, np.concatenate(locals_))
    np.testing.assert_array_equal(together, np.concatenate([w[n] for _, n, w in calls]))
    assert 0 < together.sum() < len(together)


@pytest.mark.parametrize("seed", range(3))
def test_collider_first_hits_are_trimesh_intersects_location(seed):
    """`detect._collider_first_hits` (trimesh's embree scene and face planes taken once per mesh)
    gives trimesh's ``intersects_location(..., multiple_hits=False)`` bit for bit: the hits and
    the rays that hit, rays through the box's edges, corners and along its faces' planes, from
    inside and outside, misses and unnormalised directions included; an icosphere too."""
    rng = np.random.default_rng(seed)
    ico = trimesh.creation.icosphere(2, 0.4)
    for static in (box(0.5), geometry.prepare_collider(ColliderModel("/ico", ico.vertices, ico.faces))):
        mesh = static.mesh
        n = 400
        origins = rng.uniform(-1.0, 1.0, (n, 3))
        directions = rng.standard_normal((n, 3)) * rng.uniform(0.1, 3.0, (n, 1))
        origins[:60] = np.round(origins[:60] * 2) / 2  # on the box's edges, corners and face planes
        directions[:60] = np.eye(3)[rng.integers(0, 3, 60)] * rng.choice([-1.0, 1.0], (60, 1))
        origins[60:80] = rng.uniform(-0.2, 0.2, (20, 3))  # from inside
        for o, d in ((origins, directions), (origins[:1], directions[:1]), (origins[:0], directions[:0])):
            loc, ray = D._collider_first_hits(static, o, d)
            want_loc, want_ray, _ = mesh.ray.intersects_location(o, d, multiple_hits=False)
            order = np.argsort(want_ray, kind="stable")
            want_loc, want_ray = np.asarray(want_loc, np.float64).reshape(-1, 3)[order], np.asarray(want_ray, np.int64)[order]
            assert ray.dtype == np.int64 and np.array_equal(ray, want_ray)
            assert loc.shape == want_loc.shape and loc.tobytes() == want_loc.tobytes()


def _same_region(x, y):
    """Whether two `Region`s hold the same bits (parameters, points, depths)."""
    return ((x.uv is None and y.uv is None) or (x.uv.tobytes() == y.uv.tobytes() and x.uv.shape == y.uv.shape)) and all(
        a.shape == b.shape and a.tobytes() == b.tobytes() for a, b in ((x.points, y.points), (x.depth, y.depth)))


@pytest.mark.parametrize("seed", range(3))
def test_regions_are_the_array_form(seed):
    """Two overlapping deformables (a ball under a seeded rotation, non-uniform scale and shift,
    and a responded ball with details) and a deformable against a box collider: each region
    (its inside rows gathered once for the points and the depths, `detect._inside_rows`) holds the
    array form's bits: the candidate vertices inside by a boolean mask, their parameters and
    their `surface_distance`."""
    hs, out, _, _, _ = responded_sphere(seed)
    m = rotated_scaled(seed)
    m[:3, :3] /= np.cbrt(abs(np.linalg.det(m[:3, :3])))  # about the ball's size: the two overlap
    centre = apply_inverse(m, np.zeros((1, 3)))[0]
    ga = geometry.SurfaceGeometry(H.from_grid(*shapes.sphere(12, 10)), m @ move(*(centre + 0.6)), "/a")
    gb = geometry.SurfaceGeometry(out, move(), "/b")
    cap = geometry.ColliderGeometry(box(1.0), move(0.3, 0.2, 1.2))
    for a, b in ((ga, gb), (gb, cap)):
        ra, rb = D.regions(a, b)
        assert not ra.empty
        pad = D.pair_pad(a, b)
        for x, y, reg in ((a, b, ra), (b, a, rb)):
            if not geometry.is_closed(y):
                continue
            pts, uv = T.vertices_in_box(x, y.bounds, pad)
            inside = D.inside(y, pts)
            want = D.Region(None if uv is None else uv[inside], pts[inside], D.surface_distance(y, pts[inside])[0])
            assert _same_region(reg, want)
