"""acra.meshrows: rows of a mesh picked out in compiled passes, against numpy's own operations."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acra import meshrows


@pytest.mark.parametrize("seed", range(3))
def test_boxes_meet_is_the_overlap_of_the_triangle_boxes(seed):
    from pipeline.grids import overlap, triangle_boxes

    rng = np.random.default_rng(seed)
    points = rng.uniform(-1, 1, (300, 3))
    faces = rng.integers(0, 300, (500, 3))
    tri = points[faces]
    lo, hi = np.sort(rng.uniform(-0.5, 0.5, (2, 3)), axis=0)
    for pad in (0.0, 0.05):
        want = overlap(*triangle_boxes(tri), lo, hi, pad)
        np.testing.assert_array_equal(meshrows.boxes_meet(tri, lo, hi, pad), want)
        rows = meshrows.faces_meet_rows(points, faces, lo, hi, pad)
        assert rows.dtype == np.int64 and np.array_equal(rows, np.nonzero(want)[0])
        assert meshrows.faces_at(points, faces, rows).tobytes() == tri[rows].tobytes()
        assert 0 < want.sum() < len(want)
    assert meshrows.faces_meet_rows(points, faces[:0], lo, hi).shape == (0,)
    assert meshrows.faces_at(points, faces, np.zeros(0, np.int64)).shape == (0, 3, 3)


@pytest.mark.parametrize("seed", range(6))
def test_faces_meet_rows_at_the_box_s_sides_is_the_overlap_of_the_triangle_boxes(seed):
    """Corners on the padded box's sides, one float step either side of them, on ``lo - pad``
    rounded (where ``x + pad`` rounds onto ``lo`` or not) and far beyond each side: the rows are `grids.overlap`'s mask of
    the gathered triangles' boxes, shared corners and faces with repeated corners included."""
    from pipeline.grids import overlap, triangle_boxes

    rng = np.random.default_rng(seed)
    lo, hi = np.sort(rng.uniform(-0.5, 0.5, (2, 3)), axis=0)
    for pad in (0.0, 0.1, float(rng.uniform(0, 0.3)), 1e-300):
        sides = np.stack([lo, hi, hi + pad, lo - pad, (lo - pad) + pad, lo + pad, 0.5 * (lo + hi)])
        values = np.concatenate([sides, np.nextafter(sides, np.inf), np.nextafter(sides, -np.inf),
                                 [lo - pad - 1.0, hi + pad + 1.0]])  # (23, 3), two far apart
        points = values[rng.integers(0, len(values), (400, 3)), np.arange(3)]
        faces = rng.integers(0, 400, (3000, 3))
        faces[:50, 1] = faces[:50, 0]  # a corner repeated
        tri = points[faces]
        want = overlap(*triangle_boxes(tri), lo, hi, pad)
        rows = meshrows.faces_meet_rows(points, faces, lo, hi, pad)
        assert rows.dtype == np.int64 and np.array_equal(rows, np.nonzero(want)[0])
        np.testing.assert_array_equal(meshrows.boxes_meet(tri, lo, hi, pad), want)
        assert 0 < want.sum() < len(want)
        chunked = meshrows.faces_meet_rows(points, faces, lo, hi, pad, meshrows.face_chunks(points, meshrows.chunk_vertices(faces, 400)))
        assert chunked.dtype == np.int64 and np.array_equal(chunked, rows)


def test_chunk_vertices_lists_each_chunk_s_points_once_in_order_of_first_use():
    faces = np.array([[0, 1, 2], [2, 1, 3], [3, 4, 0]] * 15, np.int64)  # 45 rows: a chunk of 32 and one of 13
    faces[32:] += 5
    start, verts = meshrows.chunk_vertices(faces, 10)
    assert meshrows.CHUNK == 32 and start.tolist() == [0, 5, 10]
    assert verts.tolist() == [0, 1, 2, 3, 4, 8, 9, 5, 6, 7]  # row 32 is (3, 4, 0) + 5
    start, verts = meshrows.chunk_vertices(faces[:0], 10)
    assert start.tolist() == [0] and verts.shape == (0,)
    assert meshrows.faces_meet_rows(np.zeros((10, 3)), faces[:0], np.zeros(3), np.ones(3), 0.0,
                               meshrows.face_chunks(np.zeros((10, 3)), (start, verts))).shape == (0,)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 2500), st.floats(0.0, 0.5))
def test_faces_meet_rows_through_chunks_gives_the_rows_of_the_full_scan(seed, n_faces, pad):
    """A strip of faces along a wandering path (a display's rows run along its surface) and
    random faces among them, a box anywhere near: the chunks' and groups' boxes only skip faces
    that miss it, so the rows are the full scan's, in the same order."""
    rng = np.random.default_rng(seed)
    n = n_faces + 2
    path = np.cumsum(rng.normal(0.0, 0.05, (n, 3)), axis=0)
    points = path + rng.normal(0.0, 0.01, (n, 3))
    faces = np.stack([np.arange(n_faces), np.arange(n_faces) + 1, np.arange(n_faces) + 2], axis=1)
    odd = rng.random(n_faces) < 0.05
    faces[odd] = rng.integers(0, n, (int(odd.sum()), 3))
    centre = points[rng.integers(0, n)]
    lo, hi = np.sort(centre + rng.uniform(-0.3, 0.3, (2, 3)), axis=0)
    chunks = meshrows.face_chunks(points, meshrows.chunk_vertices(faces, n))
    rows = meshrows.faces_meet_rows(points, faces, lo, hi, pad)
    assert np.array_equal(meshrows.faces_meet_rows(points, faces, lo, hi, pad, chunks), rows)
    clo, chi, glo, ghi = chunks
    tri = points[faces]
    for c in range(len(clo)):  # each chunk's box is its faces' corners' box
        np.testing.assert_array_equal(clo[c], tri[32 * c:32 * c + 32].reshape(-1, 3).min(axis=0))
        np.testing.assert_array_equal(chi[c], tri[32 * c:32 * c + 32].reshape(-1, 3).max(axis=0))
    assert len(glo) == -(-len(clo) // 32) and (glo <= clo[::32]).all() and (ghi >= chi[::32]).all()


def test_barycentric_points_and_values_are_numpys_einsum_to_the_bit():
    """`barycentric` gives ``np.einsum("mk,mkc->mc", ...)`` of the triangles' corners and of
    per-vertex values to the bit, signed zeros among them (weights 0 on negative coordinates)."""
    rng = np.random.default_rng(5)
    points = rng.choice([0.0, -0.0, -1.5, 2.0, 0.3], size=(40, 3)) * rng.uniform(0.5, 2.0, size=(40, 1))
    values = rng.choice([0.0, -0.0, 0.25, -3.0], size=(40, 2))
    faces = rng.integers(0, 40, size=(90, 3))
    rows = np.sort(rng.choice(90, size=30, replace=False))
    corners = meshrows.faces_at(points, faces, rows)
    for m in (0, 1, 7, 200):
        tri = rng.integers(0, 30, size=m)
        bary = rng.choice([0.0, 1.0, 0.5, 0.25, 1.0 / 3.0], size=(m, 3))
        got, at = meshrows.barycentric(bary, tri, corners, rows, faces, values)
        want = np.einsum("mk,mkc->mc", bary, corners[tri])
        assert np.array_equal(got.view(np.uint64), want.view(np.uint64))
        want = np.einsum("mk,mkc->mc", bary, values[faces[rows[tri]]])
        assert at.shape == want.shape and np.array_equal(at.view(np.uint64), want.view(np.uint64))
        assert meshrows.barycentric(bary, tri, corners, rows, faces)[1] is None
        frozen = values.copy()
        frozen.flags.writeable = False
        assert np.array_equal(meshrows.barycentric(bary, tri, corners, rows, faces, frozen)[1], at)
    assert len(meshrows._barycentric.signatures) == 1  # writeable or not, one compiled kernel


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), special=st.booleans())
def test_faces_placed_are_the_corners_their_box_and_their_shift_to_the_bit(seed, special):
    """`faces_placed` gives ``points[faces[rows]]``, its `acra.bvh.bounds` and ``tri - shift``
    bit for bit, and says the shifted values are all finite and nonzero exactly when they are;
    then the identity's product (numpy's, through BLAS) gives them unchanged, under an identity
    with zeros of either sign."""
    from acra import bvh

    rng = np.random.default_rng(seed)
    points = rng.uniform(-2, 2, (50, 3))
    shift = rng.choice([0.0, -0.0, 0.5, float(rng.uniform(-1, 1))], size=3)
    if special:  # values on the shift (zero after it), signed zeros and non-finite values
        points[rng.integers(0, 50, 6), rng.integers(0, 3, 6)] = rng.choice([shift[0], 0.0, -0.0, np.inf, np.nan], size=6)
    faces = rng.integers(0, 50, (80, 3))
    rows = np.sort(rng.choice(80, size=int(rng.integers(1, 80)), replace=False))
    tri, box, moved, plain = meshrows.faces_placed(points, faces, rows, shift)
    want = points[faces[rows]]
    assert tri.tobytes() == want.tobytes()
    assert box.tobytes() == bvh.bounds(want).tobytes()
    flat = want.reshape(-1, 3) - shift
    assert moved.tobytes() == flat.tobytes()
    assert plain == bool(np.all(np.isfinite(flat) & (flat != 0)))
    if plain:
        for eye in (np.eye(3), np.where(np.eye(3) > 0, 1.0, -0.0)):
            assert (flat @ eye.T).tobytes() == flat.tobytes()


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 3000), st.sampled_from([0.0, 1e-300, 1e-9, 0.01]))
def test_faces_meet_rows_of_chunks_and_groups_inside_the_box_are_the_full_scan_s(seed, n_faces, pad):
    """Boxes holding whole chunks and groups (whose rows are taken without their corners'
    comparisons): the box of all the points or of a run of them, its sides on points' values,
    one float step inside or outside them; the rows are the full scan's, in the same order."""
    rng = np.random.default_rng(seed)
    n = n_faces + 2
    points = np.cumsum(rng.normal(0.0, 0.05, (n, 3)), axis=0)
    faces = np.stack([np.arange(n_faces), np.arange(n_faces) + 1, np.arange(n_faces) + 2], axis=1)
    chunks = meshrows.face_chunks(points, meshrows.chunk_vertices(faces, n))
    a = int(rng.integers(0, n))
    b = int(rng.integers(a, n)) + 1
    lo, hi = points[a:b].min(axis=0), points[a:b].max(axis=0)
    for step in (0, 1, -1):
        l, h = (np.nextafter(lo, lo + step), np.nextafter(hi, hi - step)) if step else (lo, hi)
        for pad_lo, pad_hi in ((l, h), (points.min(axis=0), points.max(axis=0))):
            rows = meshrows.faces_meet_rows(points, faces, pad_lo, pad_hi, pad)
            assert np.array_equal(meshrows.faces_meet_rows(points, faces, pad_lo, pad_hi, pad, chunks), rows)


@pytest.mark.parametrize("kind", ["random", "lattice", "signed zeros"])
def test_first_rows_are_each_distinct_rows_first_occurrence(kind):
    """`first_rows`: the rows of first occurrence in their order and each row's index into them,
    by the rows' bits, as a dictionary over their bytes gives them, on random values, on a
    lattice's dyadic values (few mantissa bits, whose products' low bits are all zero) and with
    ``-0.0`` apart from ``0.0``."""
    rng = np.random.default_rng(11)
    if kind == "random":
        rows = rng.standard_normal((400, 3))
    elif kind == "lattice":
        rows = np.zeros((1200, 3))
        rows[:, :2] = np.stack(np.meshgrid(np.arange(40) / 8.0 + 3, np.arange(30) / 8.0 + 2, indexing="ij"), -1).reshape(-1, 2)
    else:
        rows = rng.choice([0.0, -0.0, 1.0], size=(300, 3))
    points = np.concatenate([rows, rows[rng.integers(0, len(rows), len(rows) // 2)]])
    points = points[rng.permutation(len(points))]
    seen: dict = {}
    want_label = [seen.setdefault(p.tobytes(), len(seen)) for p in points]
    want_first = [next(i for i, p in enumerate(points) if p.tobytes() == key) for key in seen]
    first, label = meshrows.first_rows(points)
    assert first.tolist() == want_first and label.tolist() == want_label
