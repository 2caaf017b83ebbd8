"""`acra.narrow`: the narrow phase's box culls compiled, against their array form."""

import numpy as np

from acra import narrow
from pipeline.grids import overlap, triangle_boxes


def _array_form(box_a, box_b, pad, rounds=2):
    boxes = [box_a, box_b]
    keep = [np.ones(len(box_a[0]), bool), np.ones(len(box_b[0]), bool)]
    for _ in range(rounds):
        for me, other in ((0, 1), (1, 0)):
            if keep[other].any():
                lo, hi = boxes[other][0][keep[other]].min(axis=0), boxes[other][1][keep[other]].max(axis=0)
                keep[me] &= overlap(boxes[me][0], boxes[me][1], lo, hi, pad)
            else:
                keep[me][:] = False
    return np.nonzero(keep[0])[0], np.nonzero(keep[1])[0]


def test_face_boxes_and_culls_are_the_array_form():
    """Face boxes are `triangle_boxes` of the gathered corners; the kept rows of both sides are
    those of the array form, for overlapping, touching (within ``pad``), nested and apart sets."""
    rng = np.random.default_rng(0)
    for trial in range(300):
        na, nb = rng.integers(1, 80, 2)
        pa = rng.normal(size=(int(na) + 2, 3))
        pb = rng.normal(size=(int(nb) + 2, 3)) * rng.choice([0.1, 1.0]) + rng.choice([0.0, 1.5, 4.0]) * rng.normal(size=3)
        fa = rng.integers(0, len(pa), (int(na), 3))
        fb = rng.integers(0, len(pb), (int(nb), 3))
        box_a, box_b = narrow.face_boxes(pa, fa), narrow.face_boxes(pb, fb)
        ref = triangle_boxes(pa[fa])
        assert np.array_equal(box_a[0], ref[0]) and np.array_equal(box_a[1], ref[1])
        pad = float(rng.choice([0.0, 1e-7, 0.1]))
        got, want = narrow.triangles_near(box_a, box_b, pad), _array_form(box_a, box_b, pad)
        assert all(np.array_equal(g, w) for g, w in zip(got, want)), trial


def test_compact_is_numpy_unique():
    """`compact` gives the used vertices and renumbered faces of ``np.unique(faces,
    return_inverse=True)``, with unused and repeated vertices."""
    rng = np.random.default_rng(1)
    for _ in range(100):
        v = rng.normal(size=(int(rng.integers(3, 200)), 3))
        f = rng.integers(0, len(v), (int(rng.integers(1, 120)), 3))
        used, inv = np.unique(f, return_inverse=True)
        got_v, got_f = narrow.compact(v, f)
        assert np.array_equal(got_v, v[used]) and np.array_equal(got_f, inv.reshape(-1, 3).astype(np.int32))
        assert got_f.dtype == np.int32 and got_v.flags.c_contiguous and got_f.flags.c_contiguous


def _solid_rows_array_form(points, triangles, collapse):
    tri = points[:, triangles]  # (r, f, 3, 3)
    tol = collapse * np.maximum(np.ptp(points, axis=1).max(axis=1), 1e-300)  # (r,)
    edges = np.linalg.norm(tri - np.roll(tri, 1, axis=2), axis=3)  # (r, f, 3)
    return edges.min(axis=2) > tol[:, None]


def test_rows_in_box_is_the_gather_and_mask():
    """The kept rows are ``points[rows]``, ``uv[rows]`` masked by ``np.all((p >= lo) & (p <= hi),
    axis=1)``, in order: points on the box's faces kept, NaN rows and empty sets dropped."""
    rng = np.random.default_rng(3)
    for trial in range(200):
        n = int(rng.integers(0, 60))
        points = np.round(rng.normal(size=(n, 3)), 1)  # rounded: many coordinates on the box's faces
        if n and trial % 3 == 0:
            points[rng.integers(0, n), rng.integers(0, 3)] = np.nan
        uv = rng.random((n, 2))
        rows = rng.integers(0, n, int(rng.integers(0, 2 * n + 1))) if n else np.zeros(0, np.int64)
        lo, hi = np.round(rng.normal(size=3) - 0.5, 1), np.round(rng.normal(size=3) + 0.5, 1)
        pts, puv = narrow.rows_in_box(points, uv, rows, lo, hi)
        keep = np.all((points[rows] >= lo) & (points[rows] <= hi), axis=1)
        np.testing.assert_array_equal(pts, points[rows][keep])
        np.testing.assert_array_equal(puv, uv[rows][keep])
        assert pts.shape == (int(keep.sum()), 3) and puv.shape == (int(keep.sum()), 2)


def test_solid_mask_is_the_array_form():
    """`solid_mask` keeps the rows the array form keeps (edge lengths by ``np.linalg.norm``, the
    extent by ``np.ptp``), bit for bit at the threshold: grids with collapsed rows (poles), edges
    exactly at the tolerance, flat and single-point grids, NaN and infinite coordinates."""
    from pipeline.grids import COLLAPSE
    rng = np.random.default_rng(2)
    for trial in range(300):
        s = int(rng.integers(1, 6))
        n, r = (s + 1) ** 2, int(rng.integers(1, 5))
        i, j = np.divmod(np.arange(n), s + 1)
        q = (i * (s + 1) + j).reshape(s + 1, s + 1)
        tri = np.concatenate([np.stack([q[:-1, :-1], q[1:, :-1], q[1:, 1:]], -1).reshape(-1, 3),
                              np.stack([q[:-1, :-1], q[1:, 1:], q[:-1, 1:]], -1).reshape(-1, 3)])
        pts = rng.normal(size=(r, n, 3)) * rng.choice([1e-3, 1.0, 1e3])
        kind = trial % 6
        if kind == 1:  # a pole: the first grid line one point
            pts[:, : s + 1] = pts[:, :1]
        elif kind == 2:  # a pole within rounding of one point
            pts[:, : s + 1] = pts[:, :1] + rng.normal(size=(r, s + 1, 3)) * 1e-7
        elif kind == 3:  # one edge exactly at the tolerance
            side = np.ptp(pts, axis=1).max(axis=1)
            tol = COLLAPSE * side
            pts[:, 1] = pts[:, 0] + np.array([1.0, 0, 0]) * tol[:, None]
        elif kind == 4:
            pts[:, :, 2] = 0.0 if trial % 12 == 4 else pts[:, :1, 2]  # flat, or all one point
            if trial % 12 == 10:
                pts[:] = pts[:, :1]
        elif kind == 5:
            pts[0, int(rng.integers(n))] = rng.choice([np.nan, np.inf, -np.inf])
        want = _solid_rows_array_form(pts, tri, COLLAPSE)
        got = narrow.solid_mask(pts, tri, COLLAPSE)
        assert np.array_equal(got, want), trial


def _fcl_contacts(pa, fa, pb, fb):
    import fcl

    from pipeline.grids import bvh
    res = fcl.CollisionResult()
    fcl.collide(bvh(pa, fa), bvh(pb, fb), fcl.CollisionRequest(num_max_contacts=1_000_000, enable_contact=True), res)
    return len(res.contacts)


def _grid(rng, n, centre, radius):
    """A bumpy sphere's triangle grid (poles of coincident and nearly coincident points)."""
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, n + 1), np.linspace(0, np.pi, n + 1), indexing="ij")
    r = radius * (1 + 0.05 * rng.normal(size=u.shape))
    pts = np.stack([r * np.cos(u) * np.sin(v), r * np.sin(u) * np.sin(v), r * np.cos(v)], -1).reshape(-1, 3) + centre
    q = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    tri = np.concatenate([np.stack([q[:-1, :-1], q[1:, :-1], q[1:, 1:]], -1).reshape(-1, 3),
                          np.stack([q[:-1, :-1], q[1:, 1:], q[:-1, 1:]], -1).reshape(-1, 3)])
    return pts, tri


def test_crossings_count_fcl_contacts():
    """`crossings` counts the contacts ``fcl.collide`` reports on the same triangles wherever it
    says it knows them all, and never more than fcl where it does not (then fcl reports some if
    it counted some): random soups (shared coordinates, coplanar sets, slivers, degenerate
    triangles) and crossing bumpy spheres with poles, at three scales."""
    rng = np.random.default_rng(3)
    known = 0
    for trial in range(900):
        scale = float(rng.choice([1e-3, 1.0, 100.0]))
        kind = trial % 6
        if kind == 5:
            pa, fa = _grid(rng, int(rng.integers(4, 12)), np.zeros(3), scale)
            pb, fb = _grid(rng, int(rng.integers(4, 12)), rng.normal(size=3) * scale, scale * rng.choice([0.3, 1.0]))
        else:
            n, m = int(rng.integers(3, 50)), int(rng.integers(3, 50))
            pa = rng.normal(size=(n, 3)) * scale
            pb = rng.normal(size=(m, 3)) * scale * rng.choice([0.3, 1.0]) + rng.normal(size=3) * scale * rng.choice([0, 0.5, 2])
            fa = np.array([rng.choice(n, 3, replace=False) for _ in range(int(rng.integers(1, 30)))])
            fb = np.array([rng.choice(m, 3, replace=False) for _ in range(int(rng.integers(1, 30)))])
            if kind == 1:  # shared coordinates: touching pairs
                pa, pb = np.round(pa / scale * 2) * scale / 2, np.round(pb / scale * 2) * scale / 2
            elif kind == 2:  # coplanar
                pa[:, 2], pb[:, 2] = 0.0, 0.0
            elif kind == 3:  # degenerate and thin
                fa[::3, 1] = fa[::3, 0]
                pb[1::4] = pb[0::4][: len(pb[1::4])] * (1 + 1e-15)
        ka, kb = np.arange(len(fa)), np.arange(len(fb))
        count, unsure = narrow.crossings(pa, fa, ka, pb, fb, kb, 1e-7 * scale)
        want = _fcl_contacts(pa, fa, pb, fb)
        if unsure:
            assert count <= want and (want > 0 or count == 0), trial
        else:
            known += 1
            assert count == want, (trial, count, want)
    assert known > 500



def test_crossings_first_stops_at_a_contact_and_says_whether_the_sets_cross():
    """`crossings(..., first=True)`, the rewinding search's question: a count of 0 exactly where
    the whole pass counts 0 (with its ``unsure``), else at least 1 and at most the whole count
    (the pass stopped at the first pair with a contact); random soups and crossing bumpy spheres."""
    rng = np.random.default_rng(8)
    stopped = crossed = 0
    for trial in range(300):
        scale = float(rng.choice([1e-3, 1.0, 100.0]))
        if trial % 2:
            pa, fa = _grid(rng, int(rng.integers(4, 12)), np.zeros(3), scale)
            pb, fb = _grid(rng, int(rng.integers(4, 12)), rng.normal(size=3) * scale, scale * rng.choice([0.3, 1.0]))
        else:
            n, m = int(rng.integers(3, 50)), int(rng.integers(3, 50))
            pa = rng.normal(size=(n, 3)) * scale
            pb = rng.normal(size=(m, 3)) * scale + rng.normal(size=3) * scale * rng.choice([0, 0.5, 2])
            fa = np.array([rng.choice(n, 3, replace=False) for _ in range(int(rng.integers(1, 30)))])
            fb = np.array([rng.choice(m, 3, replace=False) for _ in range(int(rng.integers(1, 30)))])
        ka, kb = np.arange(len(fa)), np.arange(len(fb))
        whole, unsure = narrow.crossings(pa, fa, ka, pb, fb, kb, 1e-7 * scale)
        part, part_unsure = narrow.crossings(pa, fa, ka, pb, fb, kb, 1e-7 * scale, first=True)
        if whole == 0:
            assert (part, part_unsure) == (0, unsure), trial
        else:
            crossed += 1
            assert 1 <= part <= whole, (trial, part, whole)
            stopped += part < whole
    assert crossed > 50 and stopped > 20


def test_patches_near_is_the_broad_phase_in_arrays():
    """`narrow.patches_near` keeps the patch boxes `geometry.candidate_patches` keeps on each side,
    then those meeting a kept box of the other side, as the array form did, and gives the box of
    ``b``'s kept boxes; boxes that touch exactly (a pad of 0) count, and no kept box gives None.
    `narrow.patch_rows_near` gives the same patches as ``np.argwhere`` of each grid's mask."""
    rng = np.random.default_rng(3)
    for trial in range(40):
        la = np.round(rng.uniform(-1, 1, (5, 4, 3)), 1)
        ha = la + np.round(rng.uniform(0, 0.6, (5, 4, 3)), 1)
        lb = np.round(rng.uniform(-1, 1, (3, 6, 3)), 1) + (0.0 if trial % 4 else 1.5)
        hb = lb + np.round(rng.uniform(0, 0.6, (3, 6, 3)), 1)
        bounds_a = np.stack([la.reshape(-1, 3).min(axis=0), ha.reshape(-1, 3).max(axis=0)])
        bounds_b = np.stack([lb.reshape(-1, 3).min(axis=0), hb.reshape(-1, 3).max(axis=0)])
        pad = 0.0 if trial % 2 else 0.05
        ca = np.argwhere(overlap(la, ha, bounds_b[0], bounds_b[1], pad))
        cb = np.argwhere(overlap(lb, hb, bounds_a[0], bounds_a[1], pad))
        ov = overlap(la[ca[:, 0], ca[:, 1]][:, None], ha[ca[:, 0], ca[:, 1]][:, None],
                     lb[cb[:, 0], cb[:, 1]][None], hb[cb[:, 0], cb[:, 1]][None], pad)
        ca, cb = ca[ov.any(axis=1)], cb[ov.any(axis=0)]
        keep_a, keep_b, box = narrow.patches_near((la, ha), bounds_a, (lb, hb), bounds_b, pad)
        np.testing.assert_array_equal(np.argwhere(keep_a.reshape(5, 4)), ca)
        np.testing.assert_array_equal(np.argwhere(keep_b.reshape(3, 6)), cb)
        rows_a, rows_b, box_rows = narrow.patch_rows_near((la, ha), bounds_a, (lb, hb), bounds_b, pad)
        assert rows_a.dtype == rows_b.dtype == np.int64
        np.testing.assert_array_equal(rows_a, ca.reshape(-1, 2))
        np.testing.assert_array_equal(rows_b, cb.reshape(-1, 2))
        assert (box_rows is None) == (box is None) and (box is None or np.array_equal(box_rows, box))
        if len(cb):
            np.testing.assert_array_equal(box, [lb[cb[:, 0], cb[:, 1]].min(axis=0), hb[cb[:, 0], cb[:, 1]].max(axis=0)])
        else:
            assert box is None


def test_culls_compile_once_for_read_only_bounds(monkeypatch):
    """`detect` passes its read-only shared bounds to `narrow.patches_near`; the boxes reaching
    `_cull` through `_patches_near` and those `triangles_near` gives `_near` are of one type
    (writable C-contiguous float64), so each has one specialisation (each more is compiled and
    cached again on the first run after a fresh install). Checked on the argument types, since a
    kernel loaded from the cache never compiles the kernels it calls."""
    import numba

    seen = set()

    def spy(kernel):
        def call(*args):
            seen.update(numba.typeof(a) for a in args if isinstance(a, np.ndarray) and a.dtype == np.float64)
            return kernel(*args)
        return call

    monkeypatch.setattr(narrow, "_patches_near", spy(narrow._patches_near))
    monkeypatch.setattr(narrow, "_near", spy(narrow._near))
    lo = np.zeros((4, 3))
    hi = lo + 1.0
    bounds = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    bounds.setflags(write=False)
    narrow.patches_near((lo, hi), bounds, (lo + 0.5, hi + 0.5), bounds, 0.0)
    narrow.triangles_near((lo, hi), (lo + 0.5, hi + 0.5), 0.0)
    assert seen == {numba.typeof(np.empty((2, 3)))}, seen
