"""acra.depthbound: the residual's branch and bound, compiled, against the array form of pipeline.clearance."""

import numpy as np
import pytest
import trimesh

from conftest import soup

from acra import bvh, depthbound


def test_lattice_points_are_clearances_numpy_points_to_the_bit():
    """`depthbound.lattice_points` is `clearance._at` at the weights ``lattice / steps`` of each cell's
    triangle: the same products summed in the same order, so a point shared by two cells is
    bitwise one point (`clearance._distinct`)."""
    from pipeline import clearance
    rng = np.random.default_rng(3)
    tri = soup(5, 300) * 10.0 ** rng.integers(-3, 3, (300, 1, 1))
    steps = 1 << 6
    owner = rng.integers(0, 300, 500)
    i = rng.integers(0, steps + 1, (500, 3))
    j = rng.integers(0, steps + 1, (500, 3))
    j = np.minimum(j, steps - i)
    lattice = np.stack([i, j, steps - i - j], axis=2)  # (c, 3 corners, 3 weights)
    want = clearance._at(np.repeat(tri[owner], 3, axis=0), lattice.reshape(-1, 3) / steps)
    got = depthbound.lattice_points(tri, owner, lattice, steps)
    assert got.tobytes() == want.tobytes()


def test_children_are_the_numpy_concatenations():
    """`depthbound.children` gives the arrays `clearance._triangle_depth` built by concatenating each
    child's picks of the corners and midpoints, child by child, bit for bit."""
    rng = np.random.default_rng(3)
    c = 300
    lattice = rng.integers(0, 64, (c, 3, 3)) * 2
    mid = (lattice + lattice[:, [1, 2, 0]]) // 2
    sd, fc = rng.normal(size=(c, 3)), rng.integers(-1, 500, (c, 3))
    sd[::7, 1] = -np.inf
    sd[::5, 0] = -0.0
    u = 400
    sd_mid, face_mid, inverse = rng.normal(size=u), rng.integers(0, 500, u), rng.integers(0, u, 3 * c)
    rows, rho = rng.integers(0, 1000, c), rng.uniform(0, 1, c)
    sm, fm = sd_mid[inverse].reshape(-1, 3), face_mid[inverse].reshape(-1, 3)
    pick = [(0, 3, 5), (3, 1, 4), (5, 4, 2), (3, 4, 5)]
    all_lat, all_sd = np.concatenate([lattice, mid], axis=1), np.concatenate([sd, sm], axis=1)
    all_fc = np.concatenate([fc, fm], axis=1)
    want = (np.concatenate([all_lat[:, list(p)] for p in pick]), np.concatenate([all_sd[:, list(p)] for p in pick]),
            np.concatenate([all_fc[:, list(p)] for p in pick]), np.tile(rows, 4), np.tile(0.5 * rho, 4))
    got = depthbound.children(lattice, mid, sd, sd_mid, fc, face_mid, inverse, rows, rho)
    for x, y in zip(got, want):
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()
    empty = depthbound.children(lattice[:0], mid[:0], sd[:0], sd_mid, fc[:0], face_mid, inverse[:0], rows[:0], rho[:0])
    assert [x.shape for x in empty] == [(0, 3, 3), (0, 3), (0, 3), (0,), (0,)]


def test_sortable_keys_sort_as_the_floats_do():
    """`depthbound._sortable`'s int64 keys (the branch and bound's orders by bound, one merge-sort key
    type for every kernel) give numpy's stable merge sort of the float64 values: negative and
    positive, infinite, subnormal, both zeros (equal, kept in row order) and ties."""
    rng = np.random.default_rng(7)
    x = np.concatenate([rng.standard_normal(500), -rng.random(200) * 1e-300, [0.0, -0.0, 0.0, np.inf, -np.inf, 5e-324,
                                                                                -5e-324], rng.integers(-3, 3, 300) * 1.0])
    rng.shuffle(x)
    keys = depthbound._sortable(x.copy())
    assert keys.dtype == np.int64
    np.testing.assert_array_equal(np.argsort(keys, kind="mergesort"), np.argsort(x, kind="mergesort"))


@pytest.mark.parametrize("merged", [False, True])
def test_a_cells_bound_with_its_corners_own_distances_is_eq6_capped_to_the_bit(merged):
    # the corners' distances from their walks and the cell's eq. (4) as a cap spare measures,
    # never the answer: min(cap, eq. (6)) as `facet_bound` gives it, bit for bit
    mesh = trimesh.creation.icosphere(subdivisions=2)
    v, fc = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
    f = len(fc)
    facet = np.arange(f, dtype=np.int64)
    if merged:  # pairs of faces as one facet, as a flat region's faces are
        facet = facet // 2
    g = int(facet.max()) + 1
    facet_faces = np.argsort(facet, kind="stable").astype(np.int64)
    facet_start = np.searchsorted(facet[facet_faces], np.arange(g + 1)).astype(np.int64)
    rng = np.random.default_rng(3)
    centre = rng.normal(size=(400, 3))
    centre *= rng.uniform(0.9, 1.1, (400, 1)) / np.linalg.norm(centre, axis=1, keepdims=True)
    cells = centre[:, None] + rng.normal(scale=rng.choice([0.01, 0.05, 0.2], (400, 1, 1)), size=(400, 3, 3))
    dist, _, face, _ = bvh.closest(bvh.build_linear(v, fc), cells.reshape(-1, 3))
    dist, face = dist.reshape(-1, 3), face.reshape(-1, 3)
    sd = dist * rng.choice([-1.0, 1.0], size=dist.shape)
    eq6 = depthbound.facet_bound(cells, face, v, fc, facet, facet_start, facet_faces)
    normals = np.asarray(mesh.face_normals, np.float64)
    scratch, least = np.empty((3, 3)), np.empty(3)
    caps = np.where(rng.random(400) < 0.5, np.inf, eq6 * rng.uniform(0.5, 1.5, 400))
    got = np.array([depthbound._cell_bound(cells[c], face[c, 0], face[c, 1], face[c, 2], v, fc, normals, facet, facet_start, facet_faces,
                                    depthbound._NO_PLANES, scratch, least, sd[c], caps[c]) for c in range(400)])
    assert (got < caps).any() and (got == caps).any()
    assert got.tobytes() == np.minimum(caps, eq6).tobytes()
