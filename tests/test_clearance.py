"""Certified residual penetration (`pipeline.clearance`): signed depths by pseudo-normals, the
covering radius, the branch and bound of triangle depths, and the object/world conversion.

Truth comes from elsewhere: the exact depth of an interior point of a convex polytope (the
smallest distance to a face plane), a linear programme for a plane through a box, and
`acceptance.visible.surface_distance` (fcl) with trimesh's ray-parity ``contains`` on a dense
barycentric grid of 64 steps per edge.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog

from acceptance.visible import surface_distance
from acra import depthbound, pseudonormals
from pipeline import clearance as C
from pipeline.model import apply_inverse

STEPS = 64  # dense grid steps per triangle edge (2^max_split: the evaluated lattice is a subset)
PROPERTY = settings(max_examples=25, derandomize=True, deadline=None)


def unit_cube():
    m = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    return trimesh.Trimesh(m.vertices + 0.5, m.faces, process=False)  # [0, 1]^3


def box2():
    return trimesh.creation.box(extents=(2.0, 2.0, 2.0))  # [-1, 1]^3


def icosphere():
    return trimesh.creation.icosphere(subdivisions=2)


def torus():
    return trimesh.creation.torus(1.0, 0.35, major_sections=32, minor_sections=16)


def plane_depth(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Exact depth ``(k,)`` of points inside a convex ``mesh``: the smallest distance to a face
    plane (positive inside)."""
    n = mesh.face_normals
    a = mesh.vertices[mesh.faces[:, 0]]
    return (np.einsum("fc,fc->f", n, a)[None, :] - points @ n.T).min(axis=1)


def dense_depth(mesh: trimesh.Trimesh, tri: np.ndarray, steps: int = STEPS) -> float:
    """Largest depth inside ``mesh`` over a barycentric grid of ``steps`` per edge on each of
    ``tri (t, 3, 3)``: trimesh ``contains`` for inside, fcl for the distance."""
    w = np.array([(i, j, steps - i - j) for i in range(steps + 1) for j in range(steps + 1 - i)], np.float64) / steps
    pts = np.einsum("wk,tkc->twc", w, tri).reshape(-1, 3)
    inside = pts[mesh.contains(pts)]
    return float(surface_distance(mesh, inside).max()) if len(inside) else 0.0


def uv_sphere(rows: int = 12, cols: int = 20, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A unit sphere as an unwelded ``(rows + 1) x (cols + 1)`` grid: pole rows of ``cols + 1``
    copies of one point (each off by ~1e-12, as float output of one point at several parameters
    is) and a periodic seam column repeated. Quads split in two, wound outward."""
    rng = np.random.default_rng(seed)
    th = np.linspace(0.0, np.pi, rows + 1)[:, None]
    ph = np.linspace(0.0, 2 * np.pi, cols + 1)[None, :]
    v = np.stack(np.broadcast_arrays(np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)), axis=-1).reshape(-1, 3)
    v += 1e-12 * rng.normal(size=v.shape)
    idx = np.arange((rows + 1) * (cols + 1)).reshape(rows + 1, cols + 1)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]
    faces = np.concatenate([np.stack([a, d, c], -1).reshape(-1, 3), np.stack([a, c, b], -1).reshape(-1, 3)])
    return v, faces


# --- signed depth ---------------------------------------------------------------------------------
def test_cube_exact_signed_depths():
    s = C.solid(*(lambda m: (m.vertices, m.faces))(unit_cube()))
    pts = np.array([
        [0.5, 0.5, 0.5],  # centre
        [0.5, 0.5, 0.9],  # inside under a face
        [0.5, 0.5, 1.0],  # on a face
        [2.0, 0.5, 0.5],  # outside a face
        [1.1, 1.1, 0.5],  # outside an edge: the closest point is on the edge
        [1.1, 1.2, 1.3],  # outside a vertex
        [0.9, 0.95, 0.99],  # inside, near a vertex
        [0.99, 0.99, 0.5],  # inside, near an edge (two faces tie)
        [1.0, 1.0, 1.0],  # a vertex
        [-1e-3, 0.5, 1 + 1e-3],  # outside, just past an edge
    ])
    want = [0.5, 0.1, 0.0, -1.0, -np.sqrt(0.02), -np.sqrt(0.14), 0.01, 0.01, 0.0, -np.sqrt(2e-6)]
    sd, close = C.signed_depth(s, pts)
    np.testing.assert_allclose(sd, want, rtol=0, atol=1e-15)
    np.testing.assert_allclose(close[4], [1.0, 1.0, 0.5], atol=1e-15)
    np.testing.assert_allclose(close[5], [1.0, 1.0, 1.0], atol=1e-15)


def test_cube_agrees_with_exact_box_distance_on_random_points():
    s = C.solid(unit_cube().vertices, unit_cube().faces)
    p = np.random.default_rng(1).uniform(-0.5, 1.5, size=(4000, 3))
    outside = np.linalg.norm(np.maximum(np.abs(p - 0.5) - 0.5, 0.0), axis=1)
    inside = np.min(np.concatenate([p, 1 - p], axis=1), axis=1)
    want = np.where(outside > 0, -outside, inside)
    np.testing.assert_allclose(C.signed_depth(s, p)[0], want, rtol=0, atol=1e-14)


def test_icosphere_exact_inside_and_at_its_five_fold_vertices():
    m = icosphere()
    s = C.solid(m.vertices, m.faces)
    rng = np.random.default_rng(2)
    p = rng.normal(size=(2000, 3))
    p *= (rng.uniform(0, 0.9, size=2000) / np.linalg.norm(p, axis=1))[:, None]
    np.testing.assert_allclose(C.signed_depth(s, p)[0], plane_depth(m, p), rtol=0, atol=1e-14)
    assert C.signed_depth(s, [[0, 0, 0]])[0][0] == pytest.approx(plane_depth(m, np.zeros((1, 3)))[0], abs=1e-15)
    five = np.nonzero(np.bincount(m.faces.ravel()) == 5)[0]  # the icosahedron's corners: radial symmetry axes
    assert len(five) == 12
    sd, close = C.signed_depth(s, 1.5 * m.vertices[five])
    np.testing.assert_allclose(sd, -0.5, atol=1e-14)  # the closest point is the vertex
    np.testing.assert_allclose(close, m.vertices[five], atol=1e-14)


@pytest.mark.parametrize("make", [icosphere, torus], ids=["icosphere", "torus"])
def test_random_points_agree_with_trimesh_and_fcl(make):
    m = make()
    s = C.solid(m.vertices, m.faces)
    lo, hi = m.bounds
    p = np.random.default_rng(3).uniform(lo - 0.2, hi + 0.2, size=(3000, 3))
    sd, _ = C.signed_depth(s, p)
    dist = surface_distance(m, p)
    np.testing.assert_allclose(np.abs(sd), dist, rtol=0, atol=1e-12)
    clear = dist > 1e-6  # ray parity is unreliable at the surface
    np.testing.assert_array_equal(sd[clear] > 0, m.contains(p[clear]))


@pytest.mark.parametrize("make", [icosphere, torus], ids=["icosphere", "torus"])
def test_points_off_vertices_and_edges_get_the_right_sign(make):
    """Points just off every vertex and edge midpoint along the feature's normal either way: the
    closest feature is the vertex or edge itself, where eq. (1) needs the pseudo-normal."""
    m = make()
    s = C.solid(m.vertices, m.faces)
    eps = 1e-3
    edges = m.edges_unique
    mid = m.vertices[edges].mean(axis=1)
    edge_n = trimesh.unitize(m.face_normals[m.face_adjacency].sum(axis=1))
    # face_adjacency_edges and edges_unique list the same edges: match them by sorted pair
    key_adj = {tuple(e): i for i, e in enumerate(np.sort(m.face_adjacency_edges, axis=1))}
    mid_n = edge_n[[key_adj[tuple(e)] for e in np.sort(edges, axis=1)]]
    base = np.concatenate([m.vertices, mid])
    normal = np.concatenate([m.vertex_normals, mid_n])
    for side, inside in ((1.0, False), (-1.0, True)):
        p = base + side * eps * normal
        sd, _ = C.signed_depth(s, p)
        np.testing.assert_array_equal(sd > 0, inside)
        np.testing.assert_array_equal(m.contains(p), inside)


def test_uv_sphere_pole_rows_and_seam_are_welded_watertight():
    rows, cols = 12, 20
    v, f = uv_sphere(rows, cols)
    assert not trimesh.Trimesh(v, f, process=False).is_watertight
    s = C.solid(v, f)
    assert len(s.vertices) == (rows - 1) * cols + 2
    assert len(s.faces) == 2 * cols * (rows - 1)  # each pole row's quads lose their sliver
    welded = trimesh.Trimesh(s.vertices, s.faces, process=False)
    assert welded.is_watertight and welded.is_winding_consistent and welded.volume > 0
    p = np.random.default_rng(4).uniform(-0.6, 0.6, size=(500, 3))  # inside (the poles' noise makes it not quite convex)
    np.testing.assert_allclose(C.signed_depth(s, p)[0], surface_distance(welded, p), rtol=0, atol=1e-12)


def test_inward_faces_are_flipped():
    m = icosphere()
    s = C.solid(m.vertices, m.faces[:, ::-1])
    assert C.signed_depth(s, [[0.0, 0.0, 0.0]])[0][0] > 0.9
    assert trimesh.Trimesh(s.vertices, s.faces, process=False).volume > 0


def test_defects_raise():
    m = icosphere()
    with pytest.raises(ValueError, match="3 boundary edges"):
        C.solid(m.vertices, m.faces[1:])
    flipped = m.faces.copy()
    flipped[0] = flipped[0, ::-1]
    with pytest.raises(ValueError, match="inconsistently oriented"):
        C.solid(m.vertices, flipped)
    with pytest.raises(ValueError, match="non-manifold"):
        C.solid(np.concatenate([m.vertices, [[2.0, 0, 0], [0, 2.0, 0]]]), _fin(m))


@pytest.mark.parametrize("seed", range(4))
def test_compiled_part_is_the_array_form_bit_for_bit(seed):
    """A part (welded pole rows and seam, slivers and a repeated face dropped, a rim) built by
    `acra.pseudonormals` equals the array form in every array, either winding."""
    rng = np.random.default_rng(seed)
    v, f = uv_sphere(14, 24)
    v = v * rng.uniform(0.5, 2.0, 3) + rng.uniform(-1, 1, 3)
    centre = v[rng.integers(len(v))]
    near = np.linalg.norm(v[f].mean(axis=1) - centre, axis=1) < rng.uniform(0.3, 1.5)
    faces = np.concatenate([f[near], f[near][:1]])  # one face twice
    scale = float(np.linalg.norm(np.ptp(v, axis=0)))
    # copies of some vertices within the weld's radius (1e-7 of the scale) and beyond it
    copies = rng.choice(np.unique(faces), 6, replace=False)
    offset = np.array([0.3, 0.3, 0.3, 3.0, 3.0, 3.0])[:, None] * 1e-7 * scale * _unit_rows(rng.normal(size=(6, 3)))
    v = np.concatenate([v, v[copies] + offset])
    faces = faces.copy()
    for target, copy in zip(copies, range(len(v) - 6, len(v))):
        pick = (faces == target) & (rng.uniform(size=faces.shape) < 0.5)
        faces[pick] = copy
    for outward, size in ((1.0, None), (-1.0, None), (1.0, scale), (-1.0, scale)):
        a = C.solid(v, faces, part=True, outward=outward, scale=size)
        b = C.solid(v, faces, part=True, outward=outward, scale=size, compiled=False)
        for name in ("vertices", "faces", "normals", "edge_normals", "vertex_normals", "bounds", "facet", "facet_start",
                     "facet_faces"):
            x, y = getattr(a, name), getattr(b, name)
            assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y), name
        np.testing.assert_array_equal(a.tree.order, b.tree.order)


def test_compiled_part_with_a_poles_fan_is_the_array_form():
    """A part holding a pole of 80 faces (buckets of faces and edges above
    `pseudonormals._SMALL`, matched by sorting) with a face repeated in the fan equals the array
    form in every array; a fan face flipped, or a third face on a fan edge, raises its error."""
    v, f = uv_sphere(10, 80)
    near = v[f].mean(axis=1)[:, 2] > 0.3  # the top pole's fan and the rings below it
    fan = np.nonzero(near & np.any(f <= 80, axis=1))[0]
    faces = np.concatenate([f[near], f[fan[5]][None]])
    for outward in (1.0, -1.0):
        a = C.solid(v, faces, part=True, outward=outward, scale=2.0)
        b = C.solid(v, faces, part=True, outward=outward, scale=2.0, compiled=False)
        for name in ("vertices", "faces", "normals", "edge_normals", "vertex_normals", "bounds"):
            x, y = getattr(a, name), getattr(b, name)
            assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y), name
    assert np.bincount(a.faces.reshape(-1)).max() > 2 * 32  # the fan's faces at one vertex
    code, vw, fw = pseudonormals.weld(v, faces, 2e-7)
    assert code == 0 and pseudonormals.part_mesh(vw, fw, 2e-7, False)[0] == 0  # built compiled, not by the fallback
    flipped = f[near].copy()
    row = int(np.nonzero(np.isin(np.nonzero(near)[0], fan))[0][3])
    flipped[row] = flipped[row, ::-1]
    with pytest.raises(ValueError, match="inconsistently oriented"):
        C.solid(v, flipped, part=True, outward=1.0, scale=2.0)
    pole, ring = f[fan[3]][f[fan[3]] <= 80][0], f[fan[3]][f[fan[3]] > 80]
    extra = np.concatenate([v, [[0.0, 0.0, 2.0]]])
    third = np.concatenate([f[near], [[pole, ring[0], len(v)]]])
    with pytest.raises(ValueError, match="non-manifold"):
        C.solid(extra, third, part=True, outward=1.0, scale=2.0)


def test_compiled_part_raises_the_array_forms_errors():
    m = icosphere()
    flipped = m.faces.copy()
    flipped[0] = flipped[0, ::-1]
    with pytest.raises(ValueError, match="inconsistently oriented"):
        C.solid(m.vertices, flipped, part=True, outward=1.0)
    with pytest.raises(ValueError, match="non-manifold"):
        C.solid(np.concatenate([m.vertices, [[2.0, 0, 0], [0, 2.0, 0]]]), _fin(m), part=True, outward=1.0)


def _unit_rows(x):
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def _face_bound_arrays(s, cells, faces):
    """Eq. (6) in numpy (`clearance._face_bound` before it was compiled): every (cell, corner j,
    member face of j's facet) against the 3 corners, the least per (cell, j, corner i)."""
    from acra import bvh

    c = len(cells)
    facet = s.facet[faces.reshape(-1)]
    count = s.facet_start[facet + 1] - s.facet_start[facet]
    pair = np.repeat(np.arange(3 * c), count)
    member = s.facet_faces[np.repeat(s.facet_start[facet], count) + np.arange(len(pair)) - np.repeat(np.cumsum(count) - count, count)]
    tri = np.repeat(s.vertices[s.faces[member]], 3, axis=0)
    d = bvh.distances(cells[pair // 3].reshape(-1, 3), tri).reshape(-1, 3)
    least = np.full((3 * c, 3), np.inf)
    np.minimum.at(least, pair, d)
    return least.reshape(c, 3, 3).max(axis=2).min(axis=1)


@pytest.mark.parametrize("make", [unit_cube, icosphere])
def test_compiled_face_bound_is_the_array_form(make):
    m = make()
    s = C.solid(m.vertices, m.faces)
    rng = np.random.default_rng(5)
    cells = rng.uniform(-0.2, 1.2, (400, 3, 3))
    faces = C._signed(s, cells.reshape(-1, 3))[2].reshape(-1, 3)
    np.testing.assert_array_equal(C._face_bound(s, cells, faces), _face_bound_arrays(s, cells, faces))


def _signed_arrays(s, p):
    """Eq. (1) in numpy (`clearance._signed` before its signs were compiled)."""
    from acra import bvh

    dist, close, face, bary = bvh.closest(s.tree, p)
    corners = s.faces[face]
    tri = s.vertices[corners]
    twice_area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    opposite = np.linalg.norm(tri[:, [2, 0, 1]] - tri[:, [1, 2, 0]], axis=2)
    on = bary * (twice_area[:, None] / opposite) <= C.FEATURE * C._extent(s)
    zeros = on.sum(axis=1)
    normal = s.normals[face]
    edge = zeros == 1
    normal[edge] = s.edge_normals[face[edge], (np.argmax(on[edge], axis=1) + 1) % 3]
    vertex = zeros >= 2
    normal[vertex] = s.vertex_normals[corners[vertex, np.argmax(bary[vertex], axis=1)]]
    inside = np.einsum("kc,kc->k", p - close, normal) < 0
    return np.where(inside, dist, -dist)


@pytest.mark.parametrize("make", [unit_cube, icosphere])
def test_compiled_signs_are_the_array_form(make):
    m = make()
    s = C.solid(m.vertices, m.faces)
    rng = np.random.default_rng(6)
    edge = m.vertices[m.edges_unique[:, 0]] * 0.3 + m.vertices[m.edges_unique[:, 1]] * 0.7
    p = np.concatenate([rng.uniform(-0.3, 1.3, (2000, 3)), m.vertices * 1.01, m.vertices * 0.99, edge * 1.001,
                        edge * 0.999, m.vertices + rng.normal(size=m.vertices.shape) * 1e-12])
    np.testing.assert_array_equal(C.signed_depth(s, p)[0], _signed_arrays(s, p))


def _fin(m: trimesh.Trimesh) -> np.ndarray:
    """``m``'s faces with a closed tetrahedron glued to one of its edges: that edge in 4 faces."""
    a, b = m.edges_unique[0]
    n = len(m.vertices)
    return np.concatenate([m.faces, [[a, b, n], [b, a, n + 1], [a, n + 1, n], [b, n, n + 1]]])


# --- covering radius -----------------------------------------------------------------------------
def test_covering_radius_exact():
    tri = np.array([
        [[0, 0, 0], [1, 0, 0], [0.5, np.sqrt(3) / 2, 0]],  # equilateral: circumradius 1/sqrt(3)
        [[0, 0, 0], [3, 0, 0], [0, 4, 0]],  # right: half the hypotenuse
        [[0, 0, 0], [2, 0, 0], [1, 0.1, 0]],  # obtuse: |AC| / (2 cos A) = 1.01 x 2 / (2 x 2)
        [[0, 0, 0], [2, 0, 0], [0.5, 0.3, 0]],  # obtuse, lopsided: |BC|^2 |AB| / (2 BC . BA)
        [[0, 0, 0], [2, 0, 0], [1, 0, 0]],  # collinear: half of the longer piece
        [[0, 0, 0], [2, 0, 0], [0, 0, 0]],  # two corners at one point: half the edge
        [[1, 1, 1], [1, 1, 1], [1, 1, 1]],  # a point
    ], np.float64)
    want = [1 / np.sqrt(3), 2.5, 0.505, 2.34 * 2 / (2 * 3.0), 0.5, 1.0, 0.0]
    np.testing.assert_allclose(C.covering_radius(tri), want, rtol=1e-15, atol=0)
    assert C.covering_radius(tri)[2] < 1.0  # below half the longest edge


@pytest.mark.parametrize("seed", range(4))
def test_compiled_covering_radii_are_the_array_form(seed):
    """`acra.depthbound.covering_radii` (what `triangle_depth` uses) gives `covering_radius`'s bits: acute,
    obtuse, degenerate (a repeated corner) and collinear triangles at several scales."""
    rng = np.random.default_rng(seed)
    tri = rng.normal(size=(3000, 3, 3)) * 10.0 ** rng.integers(-6, 3, (3000, 1, 1))
    tri[::7, 2] = tri[::7, 0]
    tri[1::7, 2] = 0.5 * (tri[1::7, 0] + tri[1::7, 1])
    tri[2::7] = np.round(tri[2::7], 1)
    assert depthbound.covering_radii(tri).tobytes() == C.covering_radius(tri).tobytes()


@PROPERTY
@given(st.integers(0, 2**31))
def test_covering_radius_covers_and_is_attained(seed):
    """Against the largest distance to the nearest corner over a barycentric grid of 200 steps:
    covered, and attained to within the grid's spacing (random triangles: acute and obtuse)."""
    tri = np.random.default_rng(seed).normal(size=(1, 3, 3))
    w = np.array([(i, j, 200 - i - j) for i in range(201) for j in range(201 - i)], np.float64) / 200
    pts = w @ tri[0]
    worst = np.linalg.norm(pts[:, None] - tri[0][None], axis=2).min(axis=1).max()
    rho = C.covering_radius(tri)[0]
    edge = np.linalg.norm(tri[0] - tri[0][[1, 2, 0]], axis=1).max()
    assert worst <= rho * (1 + 1e-12)
    assert rho <= worst + edge / 200  # the grid's spacing


# --- triangle depth ------------------------------------------------------------------------------
def box_solid():
    m = box2()
    return m, C.solid(m.vertices, m.faces)


def test_plane_through_box_peaks_between_outside_corners():
    """z = 0 through [-1, 1]^3: the depth min(1 - |x|, 1 - |y|, 1) peaks at 1 at the origin, inside
    the triangle, while its corners are outside. Every cell lies 1 above the bottom's plane, so
    eq. (7) bounds it by exactly 1; the cells split until the deepest point found is within
    1.25 of that (1 needs no split at a target of 1.2)."""
    m, s = box_solid()
    tri = np.array([[[-3.1, -2.9, 0.0], [6.3, -3.2, 0.0], [-2.7, 6.1, 0.0]]])
    assert np.all(C.signed_depth(s, tri[0])[0] < 0)
    for target in (0.0, 0.01, 0.2, 1.2):
        d = C.triangle_depth(s, tri, target)
        assert d.complete and d.bound == 1.0
        assert d.lower <= 1.0 <= max(target, 1.25 * d.lower)
        assert (0 < d.split < 6) == (target < 1.0) and d.evaluated < (STEPS + 1) * (STEPS + 2) // 2


def test_tilted_plane_through_box_matches_linear_programme():
    """The depth in [-1, 1]^3 is min(1 - |x_i|): its maximum over a triangle is a linear programme."""
    _, s = box_solid()
    tri = np.array([[[-2.5, -1.7, -1.2], [3.1, -0.8, 0.9], [0.2, 3.3, 0.4]]])
    # maximise t: t <= 1 -+ x_i, x = sum_k w_k c_k, w >= 0, sum w = 1
    a, rows = tri[0].T, []  # a: (3 coords, 3 corners)
    for sign in (1, -1):
        for i in range(3):
            rows.append(np.r_[sign * a[i], 1.0])
    res = linprog(np.r_[0, 0, 0, -1.0], A_ub=np.array(rows), b_ub=np.ones(6), A_eq=[[1, 1, 1, 0]], b_eq=[1],
                  bounds=[(0, None)] * 3 + [(None, None)], method="highs")
    exact = -res.fun
    assert 0.3 < exact < 1
    for target in (0.0, 0.02):
        d = C.triangle_depth(s, tri, target)
        assert d.lower <= exact + 1e-12 and d.bound >= exact - 1e-12
        if d.complete:
            assert d.bound <= max(target, 1.25 * exact) + 1e-12


def test_outside_triangles_bound_zero():
    _, s = box_solid()
    far = np.array([[[3.0, 0, 0], [4, 1, 0], [3, 2, 1]]])
    d = C.triangle_depth(s, far, 0.0)
    assert (d.bound, d.lower, d.complete, d.evaluated, len(d.depth)) == (0.0, 0.0, True, 0, 0)
    m = icosphere()  # inside the sphere's box, outside the sphere: queried, certified 0
    corner = np.array([[[0.9, 0.9, 0.7], [0.7, 0.9, 0.9], [0.9, 0.7, 0.9]]])
    d = C.triangle_depth(C.solid(m.vertices, m.faces), corner, 0.0)
    assert (d.bound, d.complete, d.split) == (0.0, True, 0) and d.evaluated == 3


def test_tiny_deep_triangle_is_bounded_by_a_face_plane():
    """Deep in [-1, 1]^3 the corners' closest faces are +x, +y and +z; eq. (4) gives the deepest
    corner plus rho (0.93 + 0.085), eq. (7) the plane of any one of them, 1 - min coordinate over
    the corners = 1.0 for each: the bound is 1.0, above the exact maximum 1 - 1/31.98 (where
    0.1 l1 = 0.13 l2 = 0.07 l3)."""
    _, s = box_solid()
    tri = np.array([[[0.1, 0.0, 0.0], [0.0, 0.13, 0.0], [0.0, 0.0, 0.07]]])
    d = C.triangle_depth(s, tri, 0.0)
    assert s.convex
    assert (d.complete, d.split, d.evaluated) == (True, 0, 3)  # U <= 1.25 L at once
    assert 0.93 + C.covering_radius(tri)[0] > 1.0
    assert d.bound == pytest.approx(1.0, abs=1e-15)
    assert d.bound >= 1.0 - 1.0 / (1 / 0.1 + 1 / 0.13 + 1 / 0.07)
    assert d.lower == pytest.approx(0.93, abs=1e-15)
    np.testing.assert_allclose(np.sort(d.depth), [0.87, 0.9, 0.93], atol=1e-15)
    np.testing.assert_array_equal(d.tri, 0)
    np.testing.assert_allclose(np.einsum("mk,mkc->mc", d.bary, tri[d.tri]), d.points, atol=1e-15)


def test_found_points_are_consistent_and_shared_corners_evaluated_once():
    _, s = box_solid()
    fan = np.array([[0, 0, 0.5], [2, 0, 0.5], [0, 2, 0.5], [-2, 0, 0.5], [0, -2, 0.5]], np.float64)
    tri = fan[[[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1]]]
    d = C.triangle_depth(s, tri, 10.0)  # target above any bound: corners only
    assert (d.evaluated, d.split, d.complete) == (5, 0, True)
    d = C.triangle_depth(s, tri, 0.01)
    assert d.complete and d.lower == pytest.approx(0.5, abs=1e-15) and 0.5 <= d.bound <= 0.625
    assert np.all(d.depth > 0) and np.all((d.tri >= 0) & (d.tri < 4))
    np.testing.assert_allclose(d.bary.sum(axis=1), 1.0, atol=1e-15)
    np.testing.assert_allclose(np.einsum("mk,mkc->mc", d.bary, tri[d.tri]), d.points, atol=1e-15)
    np.testing.assert_allclose(C.signed_depth(s, d.points)[0], d.depth, atol=1e-15)
    assert len(np.unique(d.points, axis=0)) == len(d.points)  # a point of two triangles' shared edge once


def test_cap_and_budget_stop_early_but_still_bound():
    """A triangle through a torus's tube (not convex, so eq. (7) does not apply): the tube's depth
    peaks at its radius 0.35 on the core circle, between corners that are outside."""
    m, s = shape("torus")
    assert not s.convex
    tri = np.array([[[0.6, -0.3, 0.0], [1.6, -0.3, 0.0], [1.1, 0.6, 0.0]]])
    d0 = C.triangle_depth(s, tri, 0.01, max_split=0)
    assert not d0.complete and d0.bound >= dense_depth(m, tri)
    for budget in (7, 13, 21):  # the refinement completes with 23 points
        d = C.triangle_depth(s, tri, 0.01, budget=budget)
        assert not d.complete and d.evaluated <= budget and d.bound >= dense_depth(m, tri) - 1e-12


# --- the bound against a dense grid ------------------------------------------------------------------
SHAPES = {"box": box2, "icosphere": icosphere, "torus": torus}
CACHE: dict = {}


def shape(name):
    if name not in CACHE:
        m = SHAPES[name]()
        CACHE[name] = (m, C.solid(m.vertices, m.faces))
    return CACHE[name]


def check_against_dense(m, s, tri, target):
    d = C.triangle_depth(s, tri, target)
    truth = dense_depth(m, tri)
    assert d.bound >= truth - 1e-12
    assert d.lower <= truth + 1e-12  # the evaluated points are on the dense grid
    if d.complete:
        assert d.bound <= max(target, 1.25 * truth) + 1e-12


@settings(max_examples=150, derandomize=True, deadline=None)
@given(name=st.sampled_from(sorted(SHAPES)), seed=st.integers(0, 2**31), size=st.floats(0.05, 1.5),
       target=st.sampled_from([0.0, 1e-3, 0.02, 0.1]), pair=st.booleans())
def test_bound_covers_dense_grid(name, seed, size, target, pair):
    """Random triangles through the shape, alone or two sharing an edge."""
    m, s = shape(name)
    rng = np.random.default_rng(seed)
    at = m.vertices[rng.integers(len(m.vertices))] + 0.2 * rng.normal(size=3)
    a, b, c, e = at + size * rng.normal(size=(4, 3))
    check_against_dense(m, s, np.array([[a, b, c], [b, a, e]] if pair else [[a, b, c]]), target)


@settings(max_examples=100, derandomize=True, deadline=None)
@given(name=st.sampled_from(sorted(SHAPES)), seed=st.integers(0, 2**31), target=st.sampled_from([0.0, 1e-3, 5e-3]))
def test_bound_covers_dense_grid_in_light_contact(name, seed, target):
    """Small triangles hugging the surface, corners within 0.01 of it on either side: depths near
    the tolerance, where the sign of points close to the surface decides."""
    m, s = shape(name)
    rng = np.random.default_rng(seed)
    f = rng.integers(len(m.faces))
    centre, normal = m.triangles_center[f], m.face_normals[f]
    tangent = trimesh.unitize(np.cross(normal, rng.normal(size=3)))
    base = centre + 0.1 * rng.normal(size=(3, 1)) * tangent + 0.1 * rng.normal(size=(3, 1)) * np.cross(normal, tangent)
    tri = (base + rng.uniform(-0.01, 0.01, size=(3, 1)) * normal)[None]
    check_against_dense(m, s, tri, target)


@pytest.mark.parametrize("seed", range(6))
def test_distinct_rows_are_numpys_unique_over_the_bytes(seed):
    """`_distinct` (a hash table, then the distinct rows sorted by their bytes) gives what
    ``np.unique`` over 24-byte rows gives: the rows, first occurrences and inverse, with -0.0
    and 0.0 distinct."""
    rng = np.random.default_rng(seed)
    base = rng.normal(size=(300, 3))
    if seed % 2:
        base = np.round(base, 1)
    base[::3, 1] = 0.0
    base[::6, 1] = -0.0
    pts = base[rng.integers(0, len(base), 2000)]
    rows = pts.view(np.dtype((np.void, 24))).reshape(-1)
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    got = C._distinct(pts)
    for x, y in zip(got, (pts[first], first, inverse.reshape(-1))):
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()


def _sheet(rng, centre, size, n):
    """A tilted ``n x n`` grid of triangles ``(2 n^2, 3, 3)`` of side ``size`` about ``centre``,
    its corners shared (bit for bit) by neighbouring triangles."""
    axes = np.linalg.qr(rng.normal(size=(3, 3)))[0][:, :2]
    g = np.linspace(-0.5, 0.5, n + 1) * size
    pts = centre + g[:, None, None] * axes[:, 0] + g[None, :, None] * axes[:, 1]
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return pts.reshape(-1, 3)[faces]


def _same_depth(d, e):
    if d is None or e is None:
        assert d is None and e is None
        return
    assert (d.bound, d.lower, d.complete, d.evaluated, d.split) == (e.bound, e.lower, e.complete, e.evaluated, e.split)
    for x, y in ((d.tri, e.tri), (d.bary, e.bary), (d.points, e.points), (d.depth, e.depth)):
        assert x.shape == y.shape and x.tobytes() == y.tobytes()


@pytest.mark.parametrize("name", sorted(SHAPES))
@pytest.mark.parametrize("seed", range(4))
def test_far_corners_signed_by_their_neighbours_give_the_same_depth(name, seed, monkeypatch):
    """`_signed_corners`: corners with no face within FAR x the largest covering radius take their
    neighbours' sign (outside, or inside and then measured); a sheet wider than the shape with
    triangles far outside, deep inside and crossing the surface, plus loose triangles no near
    corner reaches, gives the same `Depth`, bit for bit, as every corner measured."""
    m, s = shape(name)
    rng = np.random.default_rng(seed)
    tri = _sheet(rng, m.vertices[rng.integers(len(m.vertices))] * 0.3, 3.0, 40)
    loose = rng.uniform(-1.4, 1.4, size=(30, 1, 3)) + 0.05 * rng.normal(size=(30, 3, 3))
    tri = np.concatenate([tri, loose])
    for target in (0.0, 1e-3, 0.05):
        got = C.triangle_depth(s, tri, target, budget=60_000)
        with monkeypatch.context() as mp:
            mp.setattr(C, "FAR", 0.0)  # every corner measured
            want = C.triangle_depth(s, tri, target, budget=60_000)
        _same_depth(got, want)
    pts, _, inverse = C._distinct(tri.reshape(-1, 3))
    sd, face, pending = C._signed_corners(s, pts, inverse.reshape(-1, 3), C.covering_radius(tri), np.inf)
    assert pending is not None and pending.sum() > len(pending) // 4  # most corners were never measured
    exact = C.signed_depth(s, pts)[0]
    assert np.all(exact[pending] < 0) and np.array_equal(sd[~pending], exact[~pending])


@pytest.mark.parametrize("seed", range(4))
def test_far_corners_of_a_part_give_the_same_depth_or_none(seed, monkeypatch):
    """On a part of a solid (`solid` with ``part``), a corner beyond ``reach`` gives ``None`` with
    the far corners signed by their neighbours exactly when it does with every corner measured."""
    v, f = uv_sphere(24, 40, seed)
    rng = np.random.default_rng(seed)
    tri = _sheet(rng, rng.normal(size=3) * 0.4, 1.2, 30)
    lo, hi = tri.reshape(-1, 3).min(axis=0), tri.reshape(-1, 3).max(axis=0)
    for pad in (0.05, 0.3, 1.0):
        rows = np.nonzero(np.all((v[f].min(axis=1) <= hi + pad) & (v[f].max(axis=1) >= lo - pad), axis=1))[0]
        if not len(rows):
            continue
        part = C.solid(v, f[rows], part=True, outward=1.0, scale=2.0)
        for target in (0.0, 1e-3):
            got = C.triangle_depth(part, tri, target, reach=pad, budget=40_000)
            with monkeypatch.context() as mp:
                mp.setattr(C, "FAR", 0.0)
                want = C.triangle_depth(part, tri, target, reach=pad, budget=40_000)
            _same_depth(got, want)


def _every_retired_cell(s, tri, src, steps, retired, bound, cells, rows, lattice, fc):
    """`clearance._retired_max` as it stood: eq. (6) for every cell, then the largest bound."""
    if not len(cells):
        return retired
    six = C._cell_bound(s, C._at_cells(tri, src[rows[cells]], lattice[cells], steps), fc[cells])
    return max(retired, float(np.minimum(bound[cells], six).max(initial=0.0)))


@pytest.mark.parametrize("seed", range(3))
def test_retired_cells_bounded_lazily_give_the_same_depth(seed, monkeypatch):
    """Eq. (6) taken only on the retired cells that could raise the largest bound
    (`_retired_max`) gives the same `Depth`, bit for bit, as on every cell eq. (4) leaves above 0:
    on whole shapes (a convex one with eq. (7)) and on parts of a sphere, sheets crossing the
    surface, with targets from 0 to coarse, decided against a tolerance and not."""
    rng = np.random.default_rng(seed)
    cases = []
    for name in sorted(SHAPES):
        m, s = shape(name)
        cases.append((s, _sheet(rng, m.vertices[rng.integers(len(m.vertices))] * 0.3, 3.0, 30), np.inf))
    v, f = uv_sphere(24, 40, seed)
    tri = _sheet(rng, rng.normal(size=3) * 0.4, 1.2, 30)
    lo, hi = tri.reshape(-1, 3).min(axis=0), tri.reshape(-1, 3).max(axis=0)
    rows = np.nonzero(np.all((v[f].min(axis=1) <= hi + 1.0) & (v[f].max(axis=1) >= lo - 1.0), axis=1))[0]
    cases.append((C.solid(v, f[rows], part=True, outward=1.0, scale=2.0), tri, 1.0))
    for s, tri, reach in cases:
        for target, decide in ((0.0, np.inf), (1e-3, np.inf), (1e-3, 2e-3), (0.05, 0.1)):
            got = C.triangle_depth(s, tri, target, reach=reach, decide=decide, budget=60_000, compiled=False)
            with monkeypatch.context() as mp:
                mp.setattr(C, "_retired_max", _every_retired_cell)
                want = C.triangle_depth(s, tri, target, reach=reach, decide=decide, budget=60_000, compiled=False)
            _same_depth(got, want)


def _tangent_sheet(rng, normal, depth, size, n):
    """An ``n x n`` grid of triangles ``(2 n^2, 3, 3)`` of side ``size`` square to the unit
    ``normal``, at ``depth`` inside the unit sphere's surface (below 0: outside), turned at random
    about the normal: its cells along the surface need every level of splitting."""
    q = np.linalg.qr(np.column_stack([normal, rng.normal(size=(3, 2))]))[0]
    g = np.linspace(-0.5, 0.5, n + 1) * size
    pts = (1.0 - depth) * normal + g[:, None, None] * q[:, 1] + g[None, :, None] * q[:, 2]
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return pts.reshape(-1, 3)[faces]


def _depth_cases(seed: int, whole: tuple, sheets: tuple) -> list:
    """Solids and triangle sheets to bound, seeded: on each whole solid of ``whole`` (a shape's
    name and the sheet's size) a sheet through one of its vertices; on parts of a uv sphere, each
    of ``sheets`` (size, triangles a side, the part's reach, and a depth below the surface for a
    sheet tangent to it or ``None`` for one through it). ``(solid, triangles, reach)`` each."""
    rng = np.random.default_rng(seed)
    cases = []
    for name, size in whole:
        m, solid = shape(name)
        cases.append((solid, _sheet(rng, m.vertices[rng.integers(len(m.vertices))], size, 12), np.inf))
    v, f = uv_sphere(24, 40, seed)
    for size, n, pad, depth in sheets:
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        tri = _sheet(rng, normal, size, n) if depth is None else _tangent_sheet(rng, normal, depth, size, n)
        lo, hi = tri.reshape(-1, 3).min(axis=0), tri.reshape(-1, 3).max(axis=0)
        rows = np.nonzero(np.all((v[f].min(axis=1) <= hi + pad) & (v[f].max(axis=1) >= lo - pad), axis=1))[0]
        cases.append((C.solid(v, f[rows], part=True, outward=1.0, scale=2.0), tri, pad))
    return cases



@pytest.mark.parametrize("seed", range(3))
def test_compiled_depth_is_the_array_form_bit_for_bit(seed):
    """`acra.depthbound.depth` (the branch and bound in one compiled call) gives the `Depth` of the
    array form (`_signed_corners`, `_levels`), bit for bit, and leaves unresolved what it leaves
    unresolved: on a whole torus (a sheet partly beyond its box), a box and an icosphere (convex:
    eq. (7) on every facet's plane, and on the corners' faces') and on parts of a sphere, sheets
    crossing the surface and sheets along it (just inside and just outside, one with a ``reach``
    too short), with targets from 0 to coarse, decided against a tolerance and not, with budgets
    that end refinement part way through a level and split caps."""
    cases = _depth_cases(seed, (("torus", 1.0), ("torus", 4.0), ("box", 1.0), ("icosphere", 1.0)),
                         ((1.2, 20, 1.0, None), (0.8, 8, 0.8, 1e-3), (0.3, 4, 0.3, 0.004), (0.3, 4, 0.3, -0.002),
                          (0.3, 4, 0.01, 0.004)))
    planes = [len(s.facet_start) - 1 <= C.ALL_PLANES for s, _, _ in cases if s.convex]
    assert planes == [True, False]  # eq. (7) on every facet's plane (the box), and on the corners' faces'
    deep = cut = unresolved = 0
    for s, tri, reach in cases:
        for target, decide in ((0.0, np.inf), (1e-4, 2e-3), (1e-3, 2e-3), (0.05, 0.1)):
            for budget, max_split in ((60_000, 6), (1_500, 6), (60_000, 2), (400, 0)):
                got = C.triangle_depth(s, tri, target, max_split, budget, reach=reach, decide=decide)
                want = C.triangle_depth(s, tri, target, max_split, budget, reach=reach, decide=decide, compiled=False)
                _same_depth(got, want)
                unresolved += got is None
                deep += got is not None and got.split == max_split > 0
                cut += got is not None and not got.complete and got.split < max_split
    assert deep and cut and unresolved


@pytest.mark.parametrize("seed", range(2))
def test_a_search_stopped_deeper_than_a_figure_is_the_full_search_s_first_steps(seed):
    """``stop``: the search ends after the first level (the corners, then a split's midpoints)
    whose points reach deeper than it. Compiled and array forms stop alike, bit for bit; a
    stopped answer is a lower bound over ``stop`` whose points are the first the full search
    finds, in its order and bits, and an answer no point ended is the full one. On a whole
    torus, a box and parts of a sphere, stops under the corners' depth, between it and the
    deepest point, and over every point."""
    cases = _depth_cases(seed, (("torus", 1.0), ("box", 1.0)), ((1.2, 20, 1.0, None), (0.3, 4, 0.3, 0.004)))
    at_corners = later = full = 0
    for s, tri, reach in cases:
        for target, decide in ((0.0, np.inf), (1e-3, 2e-3)):
            want = C.triangle_depth(s, tri, target, reach=reach, decide=decide)
            corners = C.triangle_depth(s, tri, target, max_split=6, budget=1, reach=reach, decide=decide)  # level 0 alone
            if want is None or want.lower <= 0.0:
                continue
            for stop in (0.5 * corners.lower, 0.5 * (corners.lower + want.lower), want.lower, 2.0 * want.lower):
                got = C.triangle_depth(s, tri, target, reach=reach, decide=decide, stop=stop)
                ref = C.triangle_depth(s, tri, target, reach=reach, decide=decide, stop=stop, compiled=False)
                _same_depth(got, ref)
                assert got.stopped == ref.stopped
                if not got.stopped:
                    _same_depth(got, want)
                    full += 1
                    continue
                assert got.lower > stop and got.bound == got.lower and not got.complete
                assert got.evaluated <= want.evaluated and got.split <= want.split
                m = len(got.tri)
                for x, y in ((got.tri, want.tri), (got.bary, want.bary), (got.points, want.points), (got.depth, want.depth)):
                    assert x.tobytes() == y[:m].tobytes()
                at_corners += got.evaluated == corners.evaluated
                later += got.evaluated > corners.evaluated
    assert at_corners and later and full


# --- object space and world space --------------------------------------------------------------------
def rotation(seed: int) -> np.ndarray:
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.diag(r))


def affine(linear: np.ndarray, shift) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = linear, shift
    return m


def test_similarity_gives_world_depth_exactly():
    box, s = box_solid()
    mat = affine(2.5 * rotation(5), [0.3, -1.0, 2.0])
    assert C.sigma_max(mat) == pytest.approx(2.5, rel=1e-14)
    world = box.vertices @ mat[:3, :3].T + mat[:3, 3]
    sw = C.solid(world, box.faces)
    p = np.random.default_rng(6).uniform(-4, 4, size=(2000, 3)) + mat[:3, 3]
    np.testing.assert_allclose(2.5 * C.signed_depth(s, apply_inverse(mat, p))[0], C.signed_depth(sw, p)[0], atol=1e-12)
    tri = np.array([[[-3.1, -2.9, 0.0], [6.3, -3.2, 0.0], [-2.7, 6.1, 0.0]]])
    tw = tri @ mat[:3, :3].T + mat[:3, 3]
    k = C.sigma_max(mat)  # eq. (5), as pipeline.residual maps targets and bounds
    d = C.triangle_depth(s, apply_inverse(mat, tw.reshape(-1, 3)).reshape(-1, 3, 3), 0.05 / k)
    assert d.complete
    assert 2.5 <= k * d.bound <= max(0.05, 1.25 * 2.5)  # world truth: 2.5 x 1
    assert k * d.bound == pytest.approx(C.triangle_depth(sw, tw, 0.05).bound, rel=1e-12)


def test_non_uniform_scale_bound_covers_world_truth():
    box, s = box_solid()
    mat = affine(rotation(7) @ np.diag([1.0, 2.0, 0.5]) @ rotation(8), [1.0, 0.0, -0.5])
    world = trimesh.Trimesh(box.vertices @ mat[:3, :3].T + mat[:3, 3], box.faces, process=False)
    rng = np.random.default_rng(9)
    for _ in range(6):
        tw = mat[:3, 3] + rng.normal(size=(1, 3, 3))
        k = C.sigma_max(mat)
        d = C.triangle_depth(s, apply_inverse(mat, tw.reshape(-1, 3)).reshape(-1, 3, 3), 0.01 / k)
        assert k * d.bound >= dense_depth(world, tw) - 1e-12


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 3000), faces=st.integers(1, 200))
def test_a_few_faces_of_many_points_number_their_vertices_by_bits_as_a_pass_over_them(seed, n, faces):
    """`pseudonormals._used_bits` (a bit per point, counted) gives `_used`'s places of the
    faces' corners and its vertices, bit for bit, however the used points fall across the
    64-point words; `weld` of a few faces of many points (its bits) is the array form's."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v[rng.random(v.shape) < 0.1] = -0.0
    f = rng.integers(0, n, size=(faces, 3))
    if rng.random() < 0.5:  # neighbouring rows, as a display's part uses them
        f = np.minimum(f % 70 + int(rng.integers(0, n)), n - 1)
    place, vu = pseudonormals._used_bits(v, f)
    rank, want = pseudonormals._used(v, f, np.arange(faces))
    assert np.array_equal(place, rank[f]) and vu.tobytes() == want.tobytes()
    radius = 0.05
    code, vw, fw = pseudonormals.weld(v, f, radius)
    if n > pseudonormals.SPARSE * faces and code == 0:
        used = np.unique(f)
        label = C._weld(v[used], radius)
        first = np.unique(label, return_index=True)[1]
        assert vw.tobytes() == v[used][first].tobytes()
        np.testing.assert_array_equal(fw, label[np.searchsorted(used, f)])


@pytest.mark.parametrize("offset", [0.0, 3e12])
def test_compiled_weld_is_the_kd_trees(offset):
    """`pseudonormals.weld` joins the groups `clearance._weld` (a kd-tree's pairs) joins, each
    its lowest row's point, by cells along x (`_pairs_by_cells`) with a ring of points sharing
    their x (a display's ring about the x axis) on the way; coordinates too large for a cell's
    integer give code 1, and `clearance.solid` welds them with the kd-tree."""
    rng = np.random.default_rng(7)
    radius = 1e-3
    base = rng.uniform(-1, 1, (300, 3))
    base[:40, 0] = base[0, 0]  # one x for 40 points apart in y and z
    copies = base[rng.integers(0, 300, 200)] + rng.normal(size=(200, 3)) * 0.2 * radius  # within the radius
    chain = base[5] + np.outer(np.arange(1, 4), [0.9 * radius, 0, 0])  # a chain longer than the radius
    v = np.concatenate([base, copies, chain])[rng.permutation(503)] + offset
    faces = np.arange(503 - 503 % 3).reshape(-1, 3)
    rank, vu = pseudonormals._used(v, faces, np.arange(len(faces)))
    r2 = radius * radius
    path = pseudonormals._pairs_by_cells(vu, np.arange(len(vu)), r2 * (1 - 1e-9), r2 * (1 + 1e-9), radius * (1 + 1e-6))
    assert path == (1 if offset == 0 else -1)
    code, vw, fw = pseudonormals.weld(v, faces, radius)
    assert code == (0 if offset == 0 else 1)
    if code:
        return
    used = np.unique(faces)
    label = C._weld(v[used], radius)
    first = np.unique(label, return_index=True)[1]
    np.testing.assert_array_equal(vw, v[used][first])
    np.testing.assert_array_equal(fw, label[np.searchsorted(used, faces)])
    assert len(vw) < len(used) - 150  # the copies and the chain joined


def test_a_poles_copies_join_their_first_point_as_the_kd_trees_pairs_join_them():
    """`pseudonormals._pairs_by_cells` joins a point whose differences from the last point of
    its cell are 0 to it without testing its pairs (a pole row's copies in consecutive rows):
    the groups are the kd-tree's, with copies in consecutive and in scattered rows, zeros of
    either sign, and points near a copy within the radius or beyond it; a pair whose distance
    lies at the radius from a copy's point leaves the weld undecided (code 1) as from the point;
    a coordinate's infinity is no copy (its difference is not 0)."""
    rng = np.random.default_rng(23)
    radius = 1e-3
    base = rng.uniform(-1, 1, (200, 3))
    base[:30, 1] = 0.0
    pole = np.repeat(base[:1], 64, axis=0)  # consecutive copies
    pole[1::2, 1] = -0.0
    near = base[:1] + np.outer(np.arange(1, 4), [0.0, 0.6 * radius, 0.0])  # a chain from the pole
    v = np.concatenate([base[:100], pole, near, base[100:], base[3:40]])  # base[3:40] again, scattered
    faces = np.arange(len(v) - len(v) % 3).reshape(-1, 3)
    code, vw, fw = pseudonormals.weld(v, faces, radius)
    assert code == 0
    used = np.unique(faces)
    label = C._weld(v[used], radius)
    first = np.unique(label, return_index=True)[1]
    assert vw.tobytes() == v[used][first].tobytes()
    np.testing.assert_array_equal(fw, label[np.searchsorted(used, faces)])
    assert len(vw) == 200  # the pole, its chain and the repeated rows joined
    # a point at the radius from the pole: undecided, whichever of its copies asks
    far = v.copy()
    far[-2] = base[0] + [0.0, 0.0, radius]
    assert pseudonormals.weld(far, faces, radius)[0] == 1
    # copies of a point with an infinite coordinate stay apart, as their pair's distance is NaN
    inf = np.array([[0.5, np.inf, 0.0], [0.5, np.inf, 0.0], [0.5, np.inf, 0.0]])
    code, vw, fw = pseudonormals.weld(inf, np.array([[0, 1, 2]]), radius)
    assert code == 0 and len(vw) == 3


def test_compiled_part_far_from_its_origin_is_the_array_form():
    """A part whose coordinates are too large for the compiled weld's cells (code 1) is welded
    by the kd-tree and equals the array form."""
    v, f = uv_sphere(8, 12)
    v = v * 1e-3 + np.array([1e6, 0.0, 0.0])  # weld radius 1e-7 x 2e-3: x is 5e15 radii away
    a = C.solid(v, f[:60], part=True, outward=1.0, scale=2e-3)
    b = C.solid(v, f[:60], part=True, outward=1.0, scale=2e-3, compiled=False)
    assert pseudonormals.weld(v, f[:60], 2e-10)[0] == 1
    for name in ("vertices", "faces", "normals", "edge_normals", "vertex_normals", "bounds"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def _prism(poly: np.ndarray, fan: int) -> trimesh.Trimesh:
    """A unit-high prism over the polygon ``poly (k, 2)``, its caps fanned from corner ``fan``."""
    k = len(poly)
    v = np.vstack([np.c_[poly, np.zeros(k)], np.c_[poly, np.ones(k)]])
    tris = []
    for i in range(1, k - 1):
        a, b, c = fan, (fan + i) % k, (fan + i + 1) % k
        tris += [[a, c, b], [k + a, k + b, k + c]]
    for i in range(k):
        j = (i + 1) % k
        tris += [[i, j, k + j], [i, k + j, k + i]]
    m = trimesh.Trimesh(v, np.array(tris), process=True)
    if m.volume < 0:
        m.invert()
    return m


def _hull_facets(s: C.Solid) -> np.ndarray:
    """`_facets`' labels by the hull test alone, for every group of faces (no two-face shortcut,
    scipy's components): the reference `_pair_facets` and `_components` are held to."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from pipeline.spatial import ConvexHull, QhullError

    v, f, normals = s.vertices, s.faces, s.normals
    n = len(f)
    head, tail = f.reshape(-1), f[:, [1, 2, 0]].reshape(-1)
    key = np.minimum(head, tail) * len(v) + np.maximum(head, tail)
    order = np.argsort(key, kind="stable")
    other = np.arange(3 * n)
    pair = np.nonzero(key[order][1:] == key[order][:-1])[0]
    other[order[pair]], other[order[pair + 1]] = order[pair + 1], order[pair]
    scale = float(np.linalg.norm(np.ptp(v, axis=0)))
    across, me = other // 3, np.repeat(np.arange(n), 3)
    far = v[f[across, (other % 3 + 2) % 3]]
    same = (np.einsum("ij,ij->i", normals[me], normals[across]) > 1.0 - 1e-12) & (across != me)
    same &= np.abs(np.einsum("ij,ij->i", far - v[f[me, 0]], normals[me])) <= 1e-12 * scale
    label = connected_components(coo_matrix((np.ones(int(same.sum())), (me[same], across[same])), shape=(n, n)),
                                 directed=False)[1].astype(np.int64)
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    for k in np.nonzero(np.bincount(label) > 1)[0]:
        rows = np.nonzero(label == k)[0]
        corners, nrm = v[np.unique(f[rows])], normals[rows[0]]
        e1 = C._unit(np.cross(nrm, [1.0, 0.0, 0.0] if abs(nrm[0]) < 0.9 else [0.0, 1.0, 0.0]))
        try:
            hull = ConvexHull(np.stack([corners @ e1, corners @ np.cross(nrm, e1)], axis=1)).volume
        except QhullError:
            hull = np.inf
        if abs(hull - area[rows].sum()) > 1e-9 * max(hull, 1e-300):
            label[rows] = n + rows
    return np.unique(label, return_inverse=True)[1].astype(np.int64)


@pytest.mark.parametrize("poly,fan", [
    ([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], 3),  # an L: its caps' quads convex
    ([[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]], 0),  # fanned from a convex corner: a concave quad
    ([[0, 0], [2, 0], [0.5, 0.5], [0, 2]], 0),  # an arrowhead: its caps concave quads
    ([[0, 0], [2, 0], [0.5, 0.5], [0, 2]], 2),
    ([[0, 0], [2, 0], [1, 1 - 1e-9], [0, 2]], 0),  # concave by about 1e-9 of its area: the hull decides
    ([[0, 0], [2, 0], [1, 1 - 1e-4], [0, 2]], 0),
    ([[0, 0], [2, 0], [1, 1 + 1e-9], [0, 2]], 0),  # convex, a corner 1e-9 off the diagonal
    ([[0, 0], [2, 0], [2, 2], [1, 2 - 1e-9], [0, 2]], 3),
])
def test_two_face_facets_take_the_hull_tests_answer(poly, fan):
    """`_facets` decides a group of two faces without a hull where its excess over the faces is
    surely below or above the hull test's 1e-9, and labels components by a union-find on small
    meshes: the facets are the hull test's over every group, concave quads split."""
    m = _prism(np.array(poly, float), fan)
    s = C.solid(np.asarray(m.vertices, float), np.asarray(m.faces, np.int64))
    assert np.array_equal(s.facet, _hull_facets(s))
    assert np.array_equal(s.facet_start, np.r_[0, np.cumsum(np.bincount(s.facet))])


def test_facets_of_boxes_and_hulls_are_the_hull_tests():
    """Seeded boxes (turned, scaled, thin) and convex hulls of rounded points (coplanar quads and
    larger groups): the facets are the hull test's."""
    rng = np.random.default_rng(19)
    meshes = [trimesh.creation.box(rng.uniform(1e-3, 10, 3)).apply_transform(
        trimesh.transformations.random_rotation_matrix(rng.random(3))) for _ in range(8)]
    meshes += [trimesh.creation.box((1, 2, 3)).subdivide()]
    meshes += [trimesh.convex.convex_hull(np.round(rng.normal(size=(20, 3)) * 2) / 2) for _ in range(8)]
    split = 0
    for m in meshes:
        s = C.solid(np.asarray(m.vertices, float), np.asarray(m.faces, np.int64))
        assert np.array_equal(s.facet, _hull_facets(s))
        split += len(s.facet_start) - 1
    assert split < sum(len(m.faces) for m in meshes)  # facets of several faces were met


def test_components_number_as_scipy():
    """`_components` ranks components as scipy's ``connected_components`` numbers them."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rng = np.random.default_rng(7)
    for _ in range(50):
        n = int(rng.integers(1, 40))
        e = rng.integers(0, n, size=(int(rng.integers(0, 2 * n)), 2))
        ours = np.unique(C._components(n, e[:, 0], e[:, 1]), return_inverse=True)[1]
        theirs = connected_components(coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)), directed=False)[1]
        assert np.array_equal(ours, theirs)
