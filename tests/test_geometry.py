"""pipeline.geometry: a collider's static data (face planes, faces near a box, samples on its faces) and its
closest points."""

import time

import numpy as np
import pytest
import trimesh

from conftest import BOX_TRIANGLES, BOX_VERTICES, box, move, rotated_scaled
from pipeline import geometry
from pipeline import shape as S
from pipeline.model import ColliderModel


@pytest.mark.parametrize("seed", [0, 1])
def test_closest_within_agrees_with_the_closest_distance(seed):
    """`Closest.within` answers what `Closest.query`'s distance does, for points on the faces of a
    ball, a rounding error and 1e-9 of its size off them, and farther."""
    from pipeline.authoring import uv_sphere

    v, f = uv_sphere(0.45, 24, 12)
    st = geometry.prepare_collider(ColliderModel("/ball", np.asarray(v), np.asarray(f)))
    rng = np.random.default_rng(seed)
    tri = st.mesh.triangles[rng.integers(0, len(st.mesh.faces), 200)]
    on = np.einsum("ij,ijk->ik", rng.dirichlet([1.0, 1.0, 1.0], 200), tri)
    size = st.mesh.scale
    pts = np.concatenate([on + rng.normal(size=on.shape) * e * size for e in (0.0, 1e-15, 5e-10, 2e-9, 1e-6, 1e-2)])
    band = 1e-9 * size
    got = st.index.within(pts, band)
    np.testing.assert_array_equal(got, st.index.query(pts)[0] <= band)
    assert got[:400].all() and not got[-400:].any()


def test_face_samples_cover_a_collider_at_the_spacing():
    """`geometry.face_samples`: points on the box's faces within the given bounds, the corners
    included, every face point within the spacing of a sample."""
    b = geometry.ColliderGeometry(box(0.15), move(0.2, 0.0, 0.0))
    bounds = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    s = geometry.face_samples(b, bounds, 0.05)
    local = s - [0.2, 0.0, 0.0]
    np.testing.assert_allclose(np.abs(local).max(axis=1), 0.15, atol=1e-12)  # on the surface
    corners = BOX_VERTICES * 0.15 + [0.2, 0.0, 0.0]
    assert np.all(np.linalg.norm(s[:, None] - corners[None], axis=2).min(axis=0) < 1e-12)
    rng = np.random.default_rng(3)
    probe = rng.uniform(-0.15, 0.15, (500, 3))
    probe[np.arange(500), rng.integers(0, 3, 500)] = rng.choice([-0.15, 0.15], 500)  # on a face
    near = np.linalg.norm((probe + [0.2, 0.0, 0.0])[:, None] - s[None], axis=2).min(axis=1)
    assert near.max() <= 0.05
    half = geometry.face_samples(b, np.array([[0.0, -1.0, -1.0], [0.2, 1.0, 1.0]]), 0.05)  # the -x half
    assert len(half) and np.all(half[:, 0] <= 0.2 + 1e-12) and np.all(half[:, 0] >= 0.05 - 1e-12)


def test_face_samples_of_a_huge_face_cost_only_the_part_in_the_bounds():
    """A floor 2e3 across through a 0.2 box: the samples cover the floor inside the box at the
    spacing, and their number is that part's, not the floor's (5e9 points unsplit)."""
    floor = trimesh.Trimesh([[-1e3, -1e3, 0.0], [1e3, -1e3, 0.0], [1e3, 1e3, 0.0], [-1e3, 1e3, 0.0]],
                            [[0, 1, 2], [0, 2, 3]], process=False)
    g = geometry.ColliderGeometry(geometry.prepare_collider(ColliderModel("/Floor", floor.vertices, floor.faces)), np.eye(4))
    bounds = np.array([[0.3, -0.1, -0.1], [0.5, 0.1, 0.1]])
    t = time.perf_counter()
    s = geometry.face_samples(g, bounds, 0.01)
    assert time.perf_counter() - t < 5.0
    assert np.all((s >= bounds[0]) & (s <= bounds[1])) and np.all(s[:, 2] == 0.0)
    assert 21 * 21 <= len(s) < 20 * 21 * 21
    rng = np.random.default_rng(5)
    probe = np.column_stack([rng.uniform(0.3, 0.5, 400), rng.uniform(-0.1, 0.1, 400), np.zeros(400)])
    assert np.linalg.norm(probe[:, None] - s[None], axis=2).min(axis=1).max() <= 0.01


@pytest.mark.parametrize("seed", range(3))
def test_faces_near_holds_every_face_whose_world_box_meets_the_query(seed):
    """`ColliderStatic.faces_near` (object-space face boxes built once) holds every face whose
    world box meets a world box, in ascending order, and on an axis-aligned box collider under
    a translation exactly those."""
    rng = np.random.default_rng(seed)
    mesh = trimesh.creation.icosphere(3)
    static = geometry.prepare_collider(ColliderModel("/ball", mesh.vertices, mesh.faces))
    xform = rotated_scaled(seed)
    tri = (static.mesh.vertices[static.mesh.faces].reshape(-1, 3) @ xform[:3, :3].T + xform[:3, 3]).reshape(-1, 3, 3)
    for _ in range(10):
        c, h = xform[:3, 3] + rng.normal(size=3) * 2, rng.uniform(0.05, 1.5, 3)
        bounds = np.stack([c - h, c + h])
        want = np.nonzero(S.overlap(tri.min(axis=1), tri.max(axis=1), bounds[0], bounds[1], 0.0))[0]
        got = static.faces_near(xform, bounds)
        assert np.all(np.diff(got) > 0) and np.isin(want, got).all()
    b, bounds = box(1.0), np.array([[4.5, -2.0, -2.0], [5.0, 0.5, 2.0]])  # object-space x = 1 only at world x = 4
    tri = b.mesh.vertices[b.mesh.faces] + [3.0, 0.0, 0.0]
    want = np.nonzero(S.overlap(tri.min(axis=1), tri.max(axis=1), bounds[0], bounds[1], 0.0))[0]
    assert np.array_equal(b.faces_near(move(3.0, 0, 0), bounds), want) and len(want) == 0
    bounds[0, 0] = 3.9  # now the +x face and the faces along it with y below 0.5
    want = np.nonzero(S.overlap(tri.min(axis=1), tri.max(axis=1), bounds[0], bounds[1], 0.0))[0]
    assert np.array_equal(b.faces_near(move(3.0, 0, 0), bounds), want) and 0 < len(want) < len(tri)


def test_collider_planes_only_for_convex_solids_with_few_faces():
    """`ColliderStatic.planes`: a box's 12 unit outward normals and offsets; none for a ball of
    more than `PLANES_MAX` faces, nor for a box with a dent."""
    from pipeline.authoring import uv_sphere

    planes = box(0.5).planes
    assert planes.shape == (12, 4) and np.allclose(np.abs(planes[:, :3]).sum(axis=1), 1.0) and np.allclose(planes[:, 3], -0.5)
    v, f = uv_sphere(0.45, 24, 12)
    assert geometry.prepare_collider(ColliderModel("/ball", np.asarray(v), np.asarray(f))).planes is None
    dent = np.vstack([BOX_VERTICES, [[1.0, 0.0, 0.0]], [[0.5, 0.0, 0.0]]])  # a point on the +x face, then pushed in
    for centre, planes in ((8, True), (9, False)):
        hull = trimesh.Trimesh(dent[[0, 1, 2, 3, 4, 5, 6, 7, centre]], process=False)
        tris = [t for t in BOX_TRIANGLES.tolist() if not all(BOX_VERTICES[i][0] == 1.0 for i in t)]
        tris += [[4, 6, 8], [6, 7, 8], [7, 5, 8], [5, 4, 8]]  # the +x face as a fan about its centre
        st = geometry.prepare_collider(ColliderModel("/dent", np.asarray(hull.vertices), np.asarray(tris)))
        assert st.closed and (st.planes is not None) == planes


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_collider_to_object_has_apply_inverses_bits(seed):
    """`ColliderGeometry.to_object` (the linear part's inverse found once) maps world points to
    the bits `pipeline.model.apply_inverse` gives, under rotations, scales and translations."""
    from pipeline.model import apply_inverse

    rng = np.random.default_rng(seed)
    m = np.eye(4)
    m[:3, :3] = rng.normal(size=(3, 3))
    m[:3, 3] = rng.normal(size=3) * 10.0
    g = geometry.ColliderGeometry(box(0.7), m)
    for n in (0, 1, 5, 300):
        pts = rng.normal(size=(n, 3)) * 3.0
        assert g.to_object(pts).tobytes() == apply_inverse(m, pts).tobytes()


@pytest.mark.parametrize("seed", range(4))
def test_surface_bounds_are_the_reductions_of_its_boxes(seed):
    """`SurfaceGeometry.bounds` is ``min(axis=0)`` of the world patch boxes' low corners and
    ``max(axis=0)`` of their high ones, bit for bit, whether the boxes' compiled pass of a
    translation (`_translated_boxes`) set it or the reductions did (a rotation and scale),
    read before or after the boxes; the size is the diagonal's norm."""
    from conftest import sphere_geom

    rng = np.random.default_rng(seed)
    t = rng.normal(size=3) * 10.0 ** rng.integers(-3, 4, 3)
    for turn in (np.eye(4), rotated_scaled(seed)):
        for boxes_first in (False, True):  # each a new matrix: world data is kept by content
            g = sphere_geom(turn @ move(*(t + boxes_first)))
            if boxes_first:
                g.boxes
            lo, hi = g.boxes
            want = np.stack([lo.reshape(-1, 3).min(axis=0), hi.reshape(-1, 3).max(axis=0)])
            assert g.bounds.tobytes() == want.tobytes() and not g.bounds.flags.writeable
            assert g.size == float(np.linalg.norm(want[1] - want[0]))
