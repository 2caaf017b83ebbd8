"""Display and collision tessellations: fixed topology, watertight closed objects, hulls."""

import weakref

import numpy as np
import pytest
import trimesh

from acra import hspline as H
from acra import kernels
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


def _pinched_sheet() -> H.HSpline:
    """A wavy 8×8 sheet whose CVs of one corner are one point: there ``du × dv`` and its first
    Taylor term vanish, so `surface_normals` nudges."""
    rng = np.random.default_rng(0)
    cvs, pu, pv = shapes.sheet(8, 8, width=5.0, depth=5.0, height=0.3 * rng.normal(size=(8, 8)))
    cvs[:4, :4] = cvs[0, 0]
    return H.from_grid(cvs, pu, pv, depth=2)


@pytest.mark.parametrize("kind", ["sphere", "pinched"])
def test_normals_from_the_evaluated_derivatives_equal_surface_normals(kind):
    """`grid_samples` takes each vertex's normal from its first derivatives (`_normals_into`:
    `kernels.place_normals`) and only the rows without a direction from `surface_normals`: the
    points, the normals and the rows noted as nudged equal `surface_normals`', bit for bit, at a
    refined sphere's poles and at a corner collapsed to one point."""
    if kind == "sphere":
        hs = H.from_grid(*shapes.sphere(8, 7), depth=3)
        for k in (1, 2):
            hs = H.refine(hs, k, H.pole_patches(hs, k, 1, 0))
        hs = with_random_offsets(hs, scale=0.01, seed=5)
    else:
        hs = _pinched_sheet()
    det = H.details(hs) if hs.depth > 1 else None
    topo = T.run_topology([hs], 3)
    points, limit = T.grid_samples(hs, topo, det)
    nudged = np.empty(topo.u.size, bool)
    ev, want = H.surface_normals(hs, topo.u, topo.v, det=det, nudged=nudged)
    np.testing.assert_array_equal(points, ev.points)
    np.testing.assert_array_equal(limit.view(np.int64), want.view(np.int64))
    np.testing.assert_array_equal(T._nudged_rows(limit), np.flatnonzero(nudged))
    assert nudged.any() if kind == "pinched" else True
    alone, none = T.grid_samples(hs, topo, det, normals=False)
    assert none is None
    np.testing.assert_array_equal(alone, ev.points)


# --- the adaptive display (contract §1) ----------------------------------------------------------
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


def _random_levels(hs, seed, blobs=3):
    """A finest-level map of ``hs`` (depth 4) with a few rectangles refined to levels 1..3."""
    rng = np.random.default_rng(seed)
    top = hs.depth - 1
    levels = np.zeros((hs.u.patches(top), hs.v.patches(top)), np.int64)
    for _ in range(blobs):
        k = int(rng.integers(1, top + 1))
        a, b = (int(rng.integers(0, n)) for n in levels.shape)
        w, h = (int(rng.integers(1, n // 2 + 1)) for n in levels.shape)
        iu, iv = np.arange(a, a + w) % levels.shape[0], np.arange(b, b + h) % levels.shape[1]
        levels[np.ix_(iu, iv)] = np.maximum(levels[np.ix_(iu, iv)], k)
    return levels


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_samples_since_an_evaluation_on_another_topology_equal_a_full_evaluation(seed):
    """A response that refines a new place changes the adaptive topology; `grid_samples` with
    ``since = (old topology, points, limit, stale)`` copies every vertex the old topology has
    off the stale patches and evaluates the rest, bit for bit a full evaluation."""
    rng = np.random.default_rng(seed)
    hs = H.from_grid(*shapes.sphere(12, 10), depth=3)
    hs = with_random_offsets(H.make_movable(hs, 2, [[4 * int(rng.integers(0, 12)) + 2, 14]]), 0.02, seed)
    old_topo = T.run_topology([hs], 4)
    old = T.grid_samples(hs, old_topo)
    moved = with_random_offsets(H.make_movable(hs, 2, [[4 * int(rng.integers(0, 12)) + 2, 22]]), 0.02, seed + 7)
    topo = T.run_topology([moved], 4)
    assert topo.u.size > old_topo.u.size  # the new detail refines the display where it is
    stale = H.changed_patches(hs, moved)
    fast = T.grid_samples(moved, topo, since=(old_topo, *old, stale))
    full = T.grid_samples(moved, topo)
    for a, b in zip(fast, full):
        np.testing.assert_array_equal(a, b)


def _changed_vertices(old, new, topo):
    """Which vertices of ``topo`` a full evaluation of ``new`` gives other bits than of ``old``
    (points or limit normals)."""
    a, b = T.grid_samples(old, topo), T.grid_samples(new, topo)
    return np.any(a[0].view(np.int64) != b[0].view(np.int64), axis=1) | np.any(a[1].view(np.int64) != b[1].view(np.int64), axis=1)


def _covered(mask, hs, topo, level):
    """Whether each vertex of ``topo`` is on a marked level-``level`` cell (or its border)."""
    u, v = T._patch_cells(hs, topo, None, level)
    return mask[u[0], v[0]] | mask[u[1], v[0]] | mask[u[0], v[1]] | mask[u[1], v[1]]


@pytest.mark.parametrize("seed,level,cells,open_", [(0, 0, 2, False), (1, 1, 2, False), (2, 2, 1, False), (3, 2, 3, False),
                                                     (4, 1, 2, True), (5, 3, 3, True), (6, 2, 0, True)])
def test_changed_cells_hold_every_changed_vertex(seed, level, cells, open_):
    """`changed_cells` (detail vectors compared, no margin) marks every cell where a vertex
    changed bits, fewer cells than `changed_patches`' margin, and `grid_samples` with it equals a
    full evaluation bit for bit, on the same and on another (refined) topology."""
    rng = np.random.default_rng(seed)
    if open_:
        hs = wavy_sheet()
        for k, cv in ((1, [3, 3]), (2, [5, 5]), (3, [10, 9])):
            hs = H.make_movable(hs, k, [cv])
        hs = with_random_offsets(hs, 0.05, seed)
    else:
        hs, at = H.from_grid(*shapes.sphere(12, 10), depth=4), int(rng.integers(0, 12))
        for k in (1, 2, 3):
            hs = H.make_movable(hs, k, [[(2 * at + 1) << (k - 1), 4 << k]])
        hs = with_random_offsets(hs, 0.02, seed)
    moved = nudged(hs, level, rng)
    topo = T.run_topology([hs, moved], 4)
    mask = H.changed_cells(hs, H.details(hs), moved, H.details(moved), cells)
    assert mask.shape == (hs.u.patches(cells), hs.v.patches(cells))
    changed = _changed_vertices(hs, moved, topo)
    assert changed.any() and not np.any(changed & ~_covered(mask, moved, topo, cells))
    margin = H.changed_patches(hs, moved)
    assert mask.sum() << (2 * (3 - cells)) <= margin.sum() << 6  # never more area than the margin's
    old = T.grid_samples(hs, topo)
    for since in ((*old, mask), (topo, *old, mask), (T.run_topology([hs], 4), *T.grid_samples(hs, T.run_topology([hs], 4)), mask)):
        fast = T.grid_samples(moved, topo, since=since)
        full = T.grid_samples(moved, topo)
        for a, b in zip(fast, full):
            np.testing.assert_array_equal(a, b)


def test_changed_cells_of_a_refinement_alone_and_of_the_same_surface():
    """A refinement (new CVs, zero offsets) marks the patches whose activity changed; the same
    surface marks nothing."""
    hs = with_random_offsets(H.make_movable(wavy_sheet(), 2, [[5, 5]]), 0.05, 1)
    assert not H.changed_cells(hs, H.details(hs), hs, H.details(hs), 2).any()
    finer = H.make_movable(hs, 2, [[12, 9]])
    mask = H.changed_cells(hs, H.details(hs), finer, H.details(finer), 2)
    assert mask.any()
    topo = T.run_topology([hs, finer], 4)
    assert not np.any(_changed_vertices(hs, finer, topo) & ~_covered(mask, finer, topo, 2))


@pytest.mark.parametrize("seed,open_", [(0, False), (1, True), (2, False)])
def test_changed_cells_compiled_equals_the_set_operations(seed, open_, monkeypatch):
    """`changed_cells`' compiled level pass (`acra.kernels.changed_level`, sorted key lists
    merged) marks the cells numpy's set operations mark, for a move, a refinement, both, and a
    surface against a coarser one; unsorted key lists take the set operations."""
    rng = np.random.default_rng(seed)
    if open_:
        hs = with_random_offsets(H.make_movable(H.make_movable(wavy_sheet(), 1, [[3, 3]]), 2, [[5, 5]]), 0.05, seed)
        finer = H.make_movable(hs, 2, [[12, 9]])
    else:
        hs, at = H.from_grid(*shapes.sphere(12, 10), depth=4), int(rng.integers(0, 12))
        for k in (1, 2, 3):
            hs = H.make_movable(hs, k, [[(2 * at + 1) << (k - 1), 4 << k]])
        hs = with_random_offsets(hs, 0.02, seed)
        finer = H.make_movable(hs, 2, [[(2 * at + 5) << 1, 12]])
    moved = nudged(hs, 2, rng)
    pairs = [(hs, moved), (hs, finer), (finer, moved), (moved, finer), (hs, hs)]
    compiled = [H.changed_cells(a, H.details(a), b, H.details(b), lv) for a, b in pairs for lv in (0, 2, 3)]
    assert any(m.any() for m in compiled)
    monkeypatch.setattr(H.kernels, "changed_level", lambda *a: False)
    arrays = [H.changed_cells(a, H.details(a), b, H.details(b), lv) for a, b in pairs for lv in (0, 2, 3)]
    for got, want in zip(compiled, arrays):
        np.testing.assert_array_equal(got, want)
    out = np.zeros((4, 4), bool)
    assert not kernels.changed_level(out, 1, 1, np.array([3, 1]), np.zeros(0, np.int64), np.zeros(0, np.int64),
                                     np.zeros(0, np.int64), np.zeros((0, 3), np.int64), np.zeros((0, 3), np.int64),
                                     4, 7, 4, 4, False, False)
    assert not out.any()


def test_adaptive_topology_without_fine_levels_is_the_uniform_grid():
    hs = H.from_grid(*shapes.sphere(8, 7), depth=3)
    grid = T.display_topology(hs.u, hs.v, 4)
    mesh = T.adaptive_topology(hs.u, hs.v, 4, T.finest_levels(hs))
    np.testing.assert_array_equal(mesh.u, grid.u)
    np.testing.assert_array_equal(mesh.v, grid.v)
    np.testing.assert_array_equal(mesh.indices, grid.quads.reshape(-1))
    assert set(mesh.counts) == {4}


def test_finest_levels_marks_each_refined_patch_with_its_level():
    hs = H.from_grid(*shapes.sheet(8, 7), depth=3)  # 5 x 4 patches
    hs = H.refine(hs, 1, np.array([[2, 3]]))
    hs = H.refine(hs, 2, np.array([[0, 0], [9, 7]]))
    levels = T.finest_levels(hs)
    assert levels.shape == (20, 16)  # one entry per level-2 patch
    expected = np.zeros((20, 16), np.int64)
    for k in (1, 2):
        r = 1 << (2 - k)
        for key in hs.level(k).patches:  # refining may activate neighbours too (C2 rule)
            pu, pv = divmod(int(key), hs.v.patches(k))
            expected[pu * r:(pu + 1) * r, pv * r:(pv + 1) * r] = k
    assert expected[4:6, 6:8].min() >= 1 and expected[0, 0] == expected[9, 7] == 2
    np.testing.assert_array_equal(levels, expected)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 10_000), samples=st.integers(1, 4), shape=st.sampled_from(["sphere", "torus", "sheet"]))
def test_adaptive_display_is_crack_free_and_shows_every_level(seed, samples, shape):
    """Closed objects weld to a watertight, outward mesh; an open one has boundary edges only on
    the domain's border (no T-junction gap inside); every place gets ``samples`` steps per edge of
    the finest patch there; every vertex is the surface point of its parameters."""
    maker = {"sphere": shapes.sphere, "torus": shapes.torus, "sheet": shapes.sheet}[shape]
    cvs, pu, pv = maker(8, 7)
    hs = H.from_grid(cvs, pu, pv, depth=4)
    levels = _random_levels(hs, seed)
    topo = T.adaptive_topology(hs.u, hs.v, samples, levels)
    pts = H.evaluate(hs, topo.u, topo.v).points
    mesh = trimesh.Trimesh(pts, topo.triangles(), process=False)
    mesh.merge_vertices(digits_vertex=9)
    mesh.update_faces(mesh.nondegenerate_faces())
    if shape != "sheet":
        assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    else:
        flat = trimesh.Trimesh(np.stack([topo.u, topo.v, 0 * topo.u], axis=1), topo.triangles(), process=False)
        edges = flat.edges_sorted[trimesh.grouping.group_rows(flat.edges_sorted, require_count=1)]
        ends = flat.vertices[edges.reshape(-1)]
        on_border = np.isin(ends[:, 0], [0.0, hs.u.patches0]) | np.isin(ends[:, 1], [0.0, hs.v.patches0])
        assert on_border.reshape(-1, 2).all(axis=1).all()
        assert np.all(flat.area_faces > 0)  # counter-clockwise in (u, v)... every face has area
    # every place holds the grid of `samples` steps per edge of the finest patch there: in units
    # of 1 / (samples << 8) of a level-0 patch, level k's vertices are the multiples of 2^(8 - k)
    top, q = hs.depth - 1, samples << 8
    nu, nv = hs.u.patches0 * q, hs.v.patches0 * q
    have = set(zip(np.round(topo.u * q).astype(int) % nu, np.round(topo.v * q).astype(int) % nv))
    for (i, j), k in np.ndenumerate(levels):
        step = 1 << (8 - k)
        a = [x for x in range(i * q >> top, ((i + 1) * q >> top) + 1) if x % step == 0]
        b = [y for y in range(j * q >> top, ((j + 1) * q >> top) + 1) if y % step == 0]
        missing = [(x, y) for x in a for y in b if (x % nu, y % nv) not in have]
        assert not missing, ((i, j), k, missing[:3])


def test_run_topology_holds_every_surface_s_vertices():
    hs = with_random_offsets(H.make_movable(wavy_sheet(depth=3), 2, [[6, 6]]))
    other = H.make_movable(wavy_sheet(depth=3), 1, [[1, 1]])
    run = T.run_topology([hs, other], 3)
    have = set(zip(run.u, run.v))
    for s in (hs, other):
        one = T.adaptive_topology(s.u, s.v, 3, T.finest_levels(s))
        assert set(zip(one.u, one.v)) <= have


def test_a_topology_s_key_is_its_refinement_s_and_stands_for_its_arrays():
    """`MeshTopology.key` digests what `acra.lattice.adaptive_mesh` builds the mesh from (the
    quadtree's leaves, samples, finest level, directions): the surfaces in another order or
    repeated, or refinements with the same leaves, give the same key and the same arrays; other
    leaves or other samples give another key; a topology built otherwise has none."""
    hs = with_random_offsets(H.make_movable(wavy_sheet(depth=3), 2, [[6, 6]]))
    other = H.make_movable(wavy_sheet(depth=3), 1, [[1, 1]])
    run = T.run_topology([hs, other], 3)
    # ``hs`` alone: ``other``'s refined patches lie within ``hs``'s finer ones, the same leaves
    for again in (T.run_topology([other, hs], 3), T.run_topology([hs, other, hs], 3), T.run_topology([hs], 3)):
        assert again is not run and again.key == run.key and len(run.key) == 20
        for name in ("u", "v", "counts", "indices"):
            np.testing.assert_array_equal(getattr(again, name), getattr(run, name))
    coarser, fewer = T.run_topology([other], 3), T.run_topology([hs, other], 2)
    assert len({coarser.key, fewer.key, run.key}) == 3 and len(coarser.u) != len(run.u) != len(fewer.u)
    assert T.MeshTopology(run.u, run.v, run.counts, run.indices).key is None


def test_run_topology_equals_the_dense_map_and_scales_with_the_refined_area():
    """`run_topology` builds from the active patches alone: the same mesh, vertex for vertex and
    face for face, as `adaptive_topology` of the union of the surfaces' `finest_levels`; and a
    12-level sheet refined about one CV (a dense level-11 map would hold 5.2e7 entries) gets a
    mesh of a few hundred vertices."""
    hs = with_random_offsets(H.make_movable(wavy_sheet(depth=3), 2, [[6, 6]]))
    other = H.make_movable(wavy_sheet(depth=3), 1, [[1, 1]])
    run = T.run_topology([hs, other], 3)
    dense = T.adaptive_topology(hs.u, hs.v, 3, np.maximum(T.finest_levels(hs), T.finest_levels(other)))
    for name in ("u", "v", "counts", "indices"):
        np.testing.assert_array_equal(getattr(run, name), getattr(dense, name))
    deep = H.make_movable(wavy_sheet(depth=12), 11, [[3, 3]])
    topo = T.run_topology([deep], 2)
    assert topo.u.max() == deep.u.patches0 and topo.u.size < 1000, topo.u.size  # measured 543


def test_mesh_triangles_fan_face_by_face_as_a_usd_client():
    """Each face's triangles are consecutive, fanned from its first vertex (``a b c``, ``a c d``
    for a quad), as a USD client triangulates ``faceVertexCounts``/``faceVertexIndices``."""
    topo = T.MeshTopology(np.zeros(7), np.zeros(7), np.array([4, 3, 5]), np.array([0, 1, 2, 3, 4, 5, 6, 0, 2, 4, 6, 1]))
    np.testing.assert_array_equal(topo.triangles(), [[0, 1, 2], [0, 2, 3], [4, 5, 6], [0, 2, 4], [0, 4, 6], [0, 6, 1]])


def test_adaptive_mesh_triangles_fan_face_by_face():
    """An adaptive mesh (its quads, then its fans' triangles) splits into the same triangles,
    face by face, as a fan from each face's first vertex."""
    hs = H.from_grid(*shapes.torus(8, 7), depth=4)
    topo = T.adaptive_topology(hs.u, hs.v, 3, _random_levels(hs, 5))
    assert set(topo.counts) == {3, 4}
    at = np.r_[0, np.cumsum(topo.counts)]
    expected = [[topo.indices[a], topo.indices[a + k], topo.indices[a + k + 1]]
                for a, n in zip(at[:-1], topo.counts) for k in range(1, n - 1)]
    tris = topo.triangles()
    assert tris.dtype == np.int64
    np.testing.assert_array_equal(tris, expected)


@pytest.mark.parametrize("shape", ["sphere", "torus", "sheet"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_compiled_adaptive_mesh_is_the_array_form_s_vertex_for_vertex(shape, seed):
    """`acra.lattice.adaptive_mesh` (the adaptive topology in one compiled pass) gives the array
    form's vertices, counts and indices, in the same order and dtypes, across periodic seams and
    poles, with fans of every size and without finer levels."""
    maker = {"sphere": shapes.sphere, "torus": shapes.torus, "sheet": shapes.sheet}[shape]
    hs = H.from_grid(*maker(8, 7), depth=4)
    for samples, blobs in ((1, 0), (2, 3), (3, 6), (4, 2)):
        levels = _random_levels(hs, seed, blobs)
        top = hs.depth - 1
        present = {j: np.unique(np.argwhere(levels >= j) >> (top - j), axis=0) for j in range(1, top + 1)}
        got, want = T._adaptive(hs.u, hs.v, samples, present), T._adaptive_array(hs.u, hs.v, samples, present)
        assert np.count_nonzero(got.counts == 3) > 0 or not blobs
        for name in ("u", "v", "counts", "indices"):
            a, b = getattr(got, name), getattr(want, name)
            assert a.dtype == b.dtype, name
            np.testing.assert_array_equal(a, b, err_msg=name)
        assert got.by_v.dtype == np.int64
        np.testing.assert_array_equal(got.by_v, np.argsort(want.v, kind="stable"), err_msg="by_v")


@settings(max_examples=30, deadline=None)
@given(shape=st.sampled_from(["sphere", "torus", "sheet"]), seed=st.integers(0, 2**32 - 1),
       samples=st.integers(1, 5), blobs=st.integers(0, 8))
def test_compiled_mesh_s_corner_keys_merge_every_line_as_the_array_form_s_unique(shape, seed, samples, blobs):
    """`acra.lattice.adaptive_mesh`'s corners' keys (`_corner_keys`: one merge a lattice line of
    the cells starting and ending there) give the array form's ``np.unique`` of every corner, so
    its vertices and faces, across a periodic seam in u (sphere), in both (torus, whose v seam
    maps a line's top corners onto its first vertex) and in neither (sheet), for any refinement."""
    maker = {"sphere": shapes.sphere, "torus": shapes.torus, "sheet": shapes.sheet}[shape]
    hs = H.from_grid(*maker(6, 5), depth=4)
    levels = _random_levels(hs, seed, blobs)
    top = hs.depth - 1
    present = {j: np.unique(np.argwhere(levels >= j) >> (top - j), axis=0) for j in range(1, top + 1)}
    got, want = T._adaptive(hs.u, hs.v, samples, present), T._adaptive_array(hs.u, hs.v, samples, present)
    for name in ("u", "v", "counts", "indices"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    np.testing.assert_array_equal(got.by_v, np.argsort(want.v, kind="stable"), err_msg="by_v")


@pytest.mark.parametrize("shape", ["sphere", "torus", "sheet"])
@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_compiled_quadtree_leaves_are_the_array_form_s_in_its_order(shape, seed):
    """`acra.lattice.quadtree_leaves` (the adaptive topology's leaves in one compiled pass, from
    each level's patch keys in any order, repeated) gives `tessellate._leaves`' leaves, level by
    level in the same order, with levels present, skipped and absent."""
    from acra.lattice import quadtree_leaves

    maker = {"sphere": shapes.sphere, "torus": shapes.torus, "sheet": shapes.sheet}[shape]
    hs = H.from_grid(*maker(8, 7), depth=4)
    rng = np.random.default_rng(seed)
    for blobs in (0, 1, 3, 6):
        levels = _random_levels(hs, seed + 10 * blobs, blobs)
        top = hs.depth - 1
        present = {j: np.unique(np.argwhere(levels >= j) >> (top - j), axis=0) for j in range(1, top + 1)}
        present = {j: p for j, p in present.items() if len(p) and (blobs != 6 or j != 1)}  # level 1 skipped
        t = max(present, default=0)
        want = [(k, p) for k, p in T._leaves(hs.u.patches0, hs.v.patches0, present, t) if len(p)]
        keys = [rng.permutation(np.repeat(present[j][:, 0] * hs.v.patches(j) + present[j][:, 1], 2)) if j in present
                else np.zeros(0, np.int64) for j in range(1, t + 1)]
        starts = np.concatenate([[0], np.cumsum([len(k) for k in keys])]).astype(np.int64)
        pu, pv, level = quadtree_leaves(hs.u.patches0, hs.v.patches0, np.concatenate([np.zeros(0, np.int64)] + keys),
                                        starts)
        np.testing.assert_array_equal(np.stack([pu, pv], axis=1), np.concatenate([p for _, p in want]))
        np.testing.assert_array_equal(level, np.concatenate([np.full(len(p), k) for k, p in want]))


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_lattice_keys_positions_and_columns_equal_numpy_s(seed):
    """`acra.lattice.unique_keys` (the adaptive topology's vertex keys, bucketed by column) gives
    ``np.unique``'s keys and inverse, and each column's start as ``np.searchsorted`` finds it,
    for empty columns and past the last."""
    from acra import lattice

    rng = np.random.default_rng(seed)
    ni, w = int(rng.integers(1, 60)), int(rng.integers(1, 40))
    n = int(rng.integers(1, 3000))
    i, j = rng.integers(0, ni + 1, n), rng.integers(0, w, n)
    i[i == ni // 2] = 0  # an empty column inside
    keys, first, where = lattice.unique_keys(i, j, ni, w)
    expected, inverse = np.unique(i * w + j, return_inverse=True)
    np.testing.assert_array_equal(keys, expected)
    np.testing.assert_array_equal(where, inverse)
    assert keys.dtype == where.dtype == np.int64 and first[-1] == keys.size
    np.testing.assert_array_equal(first, np.searchsorted(keys, np.arange(ni + 2) * w))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_carry_equals_numpy_s_copy_and_mask(seed):
    """`tessellate._carry` (an incremental display's copies of unchanged vertices and the rows
    left to evaluate, one compiled pass) gives the bits and rows of numpy's copy of every found
    vertex, or of every vertex on the same topology, the mask of each vertex's four cells and
    ``np.nonzero``; with normals, with first derivatives (6 columns) and without; and with an
    order of the rows (a display's by v), the rows left in its sequence."""
    rng = np.random.default_rng(seed)
    n, m, cu_n, cv_n = 2000, 2500, 12, 9
    old_points, wide = rng.normal(size=(m, 3)), rng.normal(size=(m, 6))
    stale = rng.random((cu_n, cv_n)) < 0.2
    cu, cv = rng.integers(0, cu_n, n), rng.integers(0, cv_n, n)
    bu, bv = np.where(rng.random(n) < 0.3, (cu - 1) % cu_n, cu), np.where(rng.random(n) < 0.3, (cv - 1) % cv_n, cv)
    cells = stale[cu, cv] | stale[cu, bv] | stale[bu, cv] | stale[bu, bv]
    order = rng.permutation(n)
    rank = np.argsort(order)
    for src, found in ((rng.integers(0, m, n), rng.random(n) < 0.8), (T._NO_INDEX, T._NO_FOUND)):
        same = not src.size
        want_idx = np.nonzero(cells if same else ~found | cells)[0]
        keep = np.ones(n, bool) if same else found
        for width in (3, 6, 0):
            normals, old_limit = width > 0, np.ascontiguousarray(wide[:, :width])
            points, limit = np.full((n, 3), np.nan), np.full((n, width), np.nan) if normals else T._NO_POINTS
            idx = T._carry(old_points[:n] if same else old_points, old_limit[:n] if same else old_limit, src, found, stale,
                           cu, bu, cv, bv, points, limit, order if width == 6 else T._NO_INDEX)
            # with an order (a display's rows by v), the rows come in its sequence
            np.testing.assert_array_equal(idx, want_idx[np.argsort(rank[want_idx])] if width == 6 else want_idx)
            idx = np.sort(idx)
            copied = np.setdiff1d(np.nonzero(keep)[0], want_idx)
            rows = copied if same else src[copied]
            np.testing.assert_array_equal(points[copied], old_points[rows])
            assert np.isnan(points[want_idx]).all()
            if normals:
                np.testing.assert_array_equal(limit[copied], old_limit[rows])


def test_place_equals_numpy_s_row_assignment():
    """`tessellate._place` (an evaluation's points written into a display's rows in one pass)
    gives numpy's ``points[rows] = p``, bit for bit, and leaves the other rows alone."""
    rng = np.random.default_rng(3)
    n, rows = 500, rng.permutation(500)[:300]
    p = rng.normal(size=(rows.size, 3))
    points = np.full((n, 3), np.nan)
    T._place(p, rows, points)
    want = np.full((n, 3), np.nan)
    want[rows] = p
    np.testing.assert_array_equal(points.view(np.int64), want.view(np.int64))


@pytest.mark.parametrize("seed", [0, 1])
def test_normals_since_changed_cells_evaluate_those_cells_and_the_nudged_vertices(seed, monkeypatch):
    """With normals, `grid_samples(since=...)` on `changed_cells` evaluates the vertices on the
    changed cells (not every vertex of their level-0 patches) and, anywhere, the old vertices
    whose normal was taken at nudged points (`_note_nudged`), and equals a full evaluation."""
    rng = np.random.default_rng(seed)
    hs = H.from_grid(*shapes.sphere(12, 10), depth=3)
    hs = with_random_offsets(H.make_movable(hs, 2, [[4 * int(rng.integers(0, 12)) + 2, 14]]), 0.02, seed)
    topo = T.run_topology([hs], 4)
    old = T.grid_samples(hs, topo)
    moved = nudged(hs, 2, rng)
    stale = H.changed_cells(hs, H.details(hs), moved, H.details(moved), 2)
    assert 0 < stale.sum() < stale.size
    (cu, bu), (cv, bv) = T._cells(hs.u, topo.u, 2), T._cells(hs.v, topo.v, 2)
    on_cells = stale[cu, cv] | stale[cu, bv] | stale[bu, cv] | stale[bu, bv]
    patch = stale.reshape(hs.u.patches0, 4, hs.v.patches0, 4).any(axis=(1, 3))
    (pu, qu), (pv, qv) = T._cells(hs.u, topo.u), T._cells(hs.v, topo.v)
    on_patches = patch[pu, pv] | patch[pu, qv] | patch[qu, pv] | patch[qu, qv]
    clean = np.flatnonzero(~on_patches)[:3]
    T._note_nudged(old[1], clean)  # as if these three had taken nudged points
    counted = []
    real = T._normals_into
    monkeypatch.setattr(T, "_normals_into", lambda hs_, u, *a: (counted.append(u.size), real(hs_, u, *a))[1])
    fast = T.grid_samples(moved, topo, H.details(moved), since=(*old, stale))
    assert counted == [on_cells.sum() + clean.size] and on_cells.sum() < on_patches.sum()
    full = T.grid_samples(moved, topo, H.details(moved))
    for a, b in zip(fast, full):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("seed", [0, 1])
def test_normals_since_another_topology_equal_a_full_evaluation(seed, monkeypatch):
    """`grid_samples` since a display on another topology where nothing changed copies the
    vertices the two share, with their limit normals, and evaluates the others; since the
    surface before a response, it evaluates only where the surface changed. Both equal a full
    evaluation bit for bit."""
    rng = np.random.default_rng(seed)
    hs = with_random_offsets(H.make_movable(H.from_grid(*shapes.sphere(12, 10), depth=3), 2, [[10, 14]]), 0.02, seed)
    moved = nudged(hs, 2, rng)
    coarse, topo = T.run_topology([H.from_grid(*shapes.sphere(12, 10), depth=1)], 4), T.run_topology([hs], 4)
    assert coarse.u.size < topo.u.size
    stale = H.changed_cells(hs, H.details(hs), moved, H.details(moved), 2)
    full = T.grid_samples(moved, topo, H.details(moved))
    old = T.grid_samples(moved, coarse, H.details(moved))
    counted = []
    real = H.evaluate
    monkeypatch.setattr(T, "evaluate", lambda *a, **k: (counted.append(a[1].size), real(*a, **k))[1])
    shared = T.grid_samples(moved, topo, H.details(moved), since=(coarse, *old, np.zeros((hs.u.patches0, hs.v.patches0), bool)))
    assert 0 < sum(counted) < topo.u.size  # the vertices the coarse display lacks
    for a, b in zip(shared, full):
        np.testing.assert_array_equal(a, b)
    before = T.grid_samples(hs, topo, H.details(hs))
    counted.clear()
    fast = T.grid_samples(moved, topo, H.details(moved), since=(*before, stale))
    assert 0 < sum(counted) < topo.u.size // 2
    for a, b in zip(fast, full):
        np.testing.assert_array_equal(a, b)


def test_a_pole_s_vertices_share_the_mean_of_their_limit_normals():
    """`pole_normals` gives every vertex of a collapsed domain edge the normalised mean of their
    limit normals, the same on later calls with the topology (its end rows are kept), and leaves
    the other vertices' limit normals."""
    hs = H.from_grid(*shapes.sphere(12, 10), depth=1)
    for topo in (T.display_topology(hs.u, hs.v, 4), T.run_topology([hs], 4)):
        points, limit = T.grid_samples(hs, topo)
        for _ in range(2):
            normals = T.pole_normals(hs, topo, points, limit)
            poles = 0
            for end in (0.0, float(hs.v.patches0)):
                line = np.nonzero(topo.v == end)[0]
                m = limit[line].mean(axis=0)
                np.testing.assert_array_equal(normals[line], np.broadcast_to(m / np.linalg.norm(m), (line.size, 3)))
                assert np.ptp(limit[line], axis=0).max() > 0.0  # the mean is not one of them
                poles += line.size
            inner = (topo.v != 0.0) & (topo.v != float(hs.v.patches0))
            np.testing.assert_array_equal(normals[inner], limit[inner])
            assert poles > 2


def test_pole_normals_in_place_equal_a_copy_where_two_poles_meet():
    """`pole_normals(in_place=True)` writes over the limit normals what the copy holds, where the
    lines of two collapsed edges share a corner (each mean is of the limit normals, not of the
    other line's shared normal), and returns the limit normals' array."""
    hs = wavy_sheet(nu=7, nv=8, depth=1, seed=3)  # open both ways: four end lines
    topo = T.display_topology(hs.u, hs.v, 4)
    rng = np.random.default_rng(0)
    points = rng.normal(size=(topo.u.size, 3))
    points[(topo.u == 0.0) | (topo.v == 0.0)] = [0.5, 0.25, 1.0]  # two edges collapsed to one point
    limit = rng.normal(size=(topo.u.size, 3))
    limit /= np.linalg.norm(limit, axis=1, keepdims=True)
    before = limit.copy()
    copied = T.pole_normals(hs, topo, points, limit)
    np.testing.assert_array_equal(limit, before)
    assert not np.array_equal(copied, before)
    written = T.pole_normals(hs, topo, points, limit, in_place=True)
    assert written is limit
    np.testing.assert_array_equal(written.view(np.int64), copied.view(np.int64))


def test_pole_means_are_numpy_s_extent_test_and_mean_bit_for_bit():
    """`_pole_means` tells each end line collapsed as numpy's ``not np.ptp(points[line],
    axis=0).max() > tol`` does (a NaN, two equal infinities, an extent just above the
    tolerance) and gives its limit normals' mean as ``limit[line].mean(axis=0)`` bit for bit (a
    column of ``-0.0`` included)."""
    rng = np.random.default_rng(5)
    kinds = set()
    for _ in range(400):
        n = int(rng.integers(4, 300))
        points, limit = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
        lines = []
        for _ in range(int(rng.integers(1, 5))):
            line = np.sort(rng.choice(n, int(rng.integers(2, min(n, 130))), replace=False)).astype(np.int64)
            kind = int(rng.integers(0, 6))
            if kind:
                points[line] = rng.normal(size=3)  # collapsed, then perturbed by kind
            if kind == 2:
                points[line[0], 1] += 1e-11
            elif kind == 3:
                points[line[rng.integers(line.size)], rng.integers(3)] = np.nan
            elif kind == 4:
                points[line, 0] = np.inf
            elif kind == 5:
                points[line[0], 2] = -np.inf
            if rng.random() < 0.3:
                limit[line, rng.integers(3)] = -0.0
            lines.append(line)
        rows = np.concatenate(lines)
        starts = np.concatenate([[0], np.cumsum([line.size for line in lines])]).astype(np.int64)
        means = np.empty((len(lines), 3))
        tol = 1e-12 * rng.uniform(0.1, 10)
        collapsed = T._pole_means(points, limit, rows, starts, tol, means)
        for line, pole, m in zip(lines, collapsed, means):
            with np.errstate(invalid="ignore"):
                want = not np.ptp(points[line], axis=0).max() > tol
            assert pole == want
            kinds.add(bool(pole))
            if pole:
                assert m.tobytes() == limit[line].mean(axis=0).tobytes()
    assert kinds == {True, False}


def test_kept_rows_hold_their_arrays_by_weak_references_without_callbacks():
    """`_note_nudged` and `_end_lines` keep their answers per live array or topology through weak
    references without callbacks (a callback runs Python code when the array dies, and an
    interrupt raised there is dropped by the interpreter, not delivered to the run), serve them
    while it lives, and drop the entries of dead ones when the next is kept."""
    import gc

    hs = H.from_grid(*shapes.sphere(12, 10), depth=1)
    topo = T.display_topology(hs.u, hs.v, 4)
    points, limit = T.grid_samples(hs, topo)
    T._note_nudged(limit, np.array([1, 2]))
    T._end_lines(hs, topo)
    for kept, obj in ((T._NUDGED, limit), (T._END_LINES, topo)):
        assert all(ref.__callback__ is None for ref in weakref.getweakrefs(obj))
        assert kept[id(obj)][0]() is obj
    np.testing.assert_array_equal(T._nudged_rows(limit), [1, 2])
    key = id(limit)
    del points, limit
    gc.collect()
    other = np.zeros((3, 3))
    T._note_nudged(other, np.array([0]))
    assert key not in T._NUDGED or T._NUDGED[key][0]() is not None  # dead entry dropped (or the id reused)
    assert all(value[0]() is not None for value in T._NUDGED.values())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_merge_matches_the_sorted_search_and_cells_numpy_s(seed):
    """`tessellate._merge` (the old vertex at each new vertex's parameters, by one merge of two
    lists sorted by ``(u, v)``) finds the vertices numpy's sorted search of complex keys finds,
    and refuses a list that is not sorted; `_cells_into` gives numpy's floor, border and
    wrap or clip (`tessellate._cells`)."""
    rng = np.random.default_rng(seed)
    lattice = np.stack(np.meshgrid(np.arange(40) / 8, np.arange(30) / 8, indexing="ij"), -1).reshape(-1, 2)
    old = lattice[np.sort(rng.choice(len(lattice), 700, replace=False))]
    new = lattice[np.sort(rng.choice(len(lattice), 900, replace=False))]
    src, found = np.empty(len(new), np.int64), np.empty(len(new), np.bool_)
    assert T._merge(old[:, 0].copy(), old[:, 1].copy(), new[:, 0].copy(), new[:, 1].copy(), src, found)
    old_key, new_key = old[:, 0] + 1j * old[:, 1], new[:, 0] + 1j * new[:, 1]
    want = np.minimum(np.searchsorted(old_key, new_key), len(old) - 1)
    np.testing.assert_array_equal(found, old_key[want] == new_key)
    np.testing.assert_array_equal(src[found], want[found])
    assert 0 < found.sum() < len(new) and src.min() >= 0 and src.max() < len(old)
    shuffled = old[rng.permutation(len(old))]
    assert not T._merge(shuffled[:, 0].copy(), shuffled[:, 1].copy(), new[:, 0].copy(), new[:, 1].copy(), src, found)
    x = np.concatenate([rng.uniform(-1, 9, 500), np.arange(-2, 10) / 2.0])
    for level in (0, 1, 3):
        for periodic in (False, True):
            n = 8 << level
            y = x * float(1 << level)
            cell = np.floor(y).astype(np.int64)
            before = np.where(cell == y, cell - 1, cell)
            wrap = (lambda c: np.mod(c, n)) if periodic else (lambda c: np.clip(c, 0, n - 1))  # noqa: E731
            got_cell, got_before = np.empty(x.size, np.int64), np.empty(x.size, np.int64)
            T._cells_into(x, float(1 << level), n, periodic, got_cell, got_before)
            np.testing.assert_array_equal(got_cell, wrap(cell))
            np.testing.assert_array_equal(got_before, wrap(before))


@pytest.mark.parametrize("shape", ["sphere", "torus", "sheet"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_compiled_adaptive_mesh_orders_its_cells_whatever_the_leaves_order(shape, seed):
    """`acra.lattice.adaptive_mesh` writes the cells in ``(u, v)`` order leaf by leaf (the leaves
    counting-sorted by their lower v, each leaf's rows appended to their lattice lines): the
    quadtree's leaves in any order give the same vertices, faces and rows by v."""
    from acra.lattice import adaptive_mesh

    maker = {"sphere": shapes.sphere, "torus": shapes.torus, "sheet": shapes.sheet}[shape]
    hs = H.from_grid(*maker(8, 7), depth=4)
    rng = np.random.default_rng(seed)
    for samples, blobs in ((1, 2), (3, 5), (4, 8)):
        levels = _random_levels(hs, seed, blobs)
        top = hs.depth - 1
        leaves = T._leaves(hs.u.patches0, hs.v.patches0,
                           {j: np.unique(np.argwhere(levels >= j) >> (top - j), axis=0) for j in range(1, top + 1)}, top)
        pu = np.concatenate([p[:, 0] for _, p in leaves]).astype(np.int64)
        pv = np.concatenate([p[:, 1] for _, p in leaves]).astype(np.int64)
        ph = np.concatenate([np.full(len(p), 1 << (top - k), np.int64) for k, p in leaves])
        args = (samples, hs.u.patches0 * (samples << top), hs.v.patches0 * (samples << top),
                bool(hs.u.periodic), bool(hs.v.periodic))
        want = adaptive_mesh(pu, pv, ph, *args)
        order = rng.permutation(pu.size)
        got = adaptive_mesh(pu[order].copy(), pv[order].copy(), ph[order].copy(), *args)
        for a, b in zip(got, want):
            np.testing.assert_array_equal(a, b)


def test_half_patch_points_are_the_vertices_at_each_patchs_half_patch_samples():
    """`acra.lattice.half_patch_points` copies, patch by patch, the point of the vertex at each of
    the 9 samples ``(pu + i / 2, pv + j / 2)`` (``i`` slowest) of the marked patches into their 9
    rows, a wrapped end at 0, as a lookup of the vertices' parameters gives, and leaves the other
    rows; a topology with one step a patch has no half samples."""
    from acra import lattice

    rng = np.random.default_rng(5)
    for hs in (H.from_grid(*shapes.sphere(6, 8)), H.from_grid(*shapes.torus(5, 7)), wavy_sheet()):
        p0u, p0v = hs.u.patches0, hs.v.patches0
        topo = T.run_topology([hs], 4)
        points = rng.normal(size=(len(topo.u), 3))
        at = {(a, b): r for r, (a, b) in enumerate(zip(topo.u.tolist(), topo.v.tolist()))}
        patches = rng.random(p0u * p0v) < 0.4
        want = rng.normal(size=(9 * p0u * p0v, 3))
        out = want.copy()
        for p in np.flatnonzero(patches).tolist():
            for i in range(3):
                for j in range(3):
                    a, b = (2 * (p // p0v) + i) / 2.0, (2 * (p % p0v) + j) / 2.0
                    a = 0.0 if hs.u.periodic and a == p0u else a
                    b = 0.0 if hs.v.periodic and b == p0v else b
                    want[9 * p + 3 * i + j] = points[at[a, b]]
        assert lattice.half_patch_points(topo.u, topo.v, points, patches, p0v, hs.u.periodic, hs.v.periodic, out)
        assert out.tobytes() == want.tobytes()
        coarse = T.run_topology([hs], 1)
        assert not lattice.half_patch_points(coarse.u, coarse.v, rng.normal(size=(len(coarse.u), 3)), patches,
                                             p0v, hs.u.periodic, hs.v.periodic, out)
