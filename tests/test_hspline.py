"""H-spline surfaces (thesis §3.4): exactness, continuity, locality, normals, the plain-array form."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from acra import basis as B
from acra import hierarchy as Hi
from acra import hspline as H
from acra import shapes
from conftest import wavy_sheet, with_random_offsets


def _net_eval(hs, k, u, v, det):
    """Evaluate the explicit level-k control net (derived + offset CVs) on its active patches."""
    pos = H.cv_positions(hs, k, det)
    lev = hs.level(k)
    su, tu = B.locate(hs.u, u, k)
    sv, tv = B.locate(hs.v, v, k)
    rows, found = H._lookup(lev.patches, su * hs.v.patches(k) + sv)
    q = np.einsum("ma,mb,mabc->mc", B.basis(tu), B.basis(tv), pos[lev.patch_rows[rows]])
    return q, found


def _random_uv(hs, n, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(0, hs.u.patches0, n), rng.uniform(0, hs.v.patches0, n)


@pytest.mark.parametrize("periodic", [(False, False), (True, False), (True, True)])
def test_refinement_leaves_the_surface_unchanged(periodic):
    rng = np.random.default_rng(3)
    nu, nv = 7, 6
    cvs = rng.normal(size=(nu, nv, 3))
    hs0 = H.from_grid(cvs, *periodic, depth=4)
    u, v = _random_uv(hs0, 10_000, 4)
    before = H.evaluate(hs0, u, v).points
    # refine a random patch set at every level, including ones across a periodic seam
    hs = hs0
    for k in (1, 2, 3):
        n = hs.u.patches(k), hs.v.patches(k)
        hs = H.refine(hs, k, np.stack([rng.integers(0, n[0], 12), rng.integers(0, n[1], 12)], 1))
    det = H.details(hs)
    size = hs.size()
    assert np.abs(H.evaluate(hs, u, v, det=det).points - before).max() <= 1e-12 * size
    covered = 0
    for k in (1, 2, 3):
        q, found = _net_eval(hs, k, u, v, det)
        covered += found.sum()
        assert np.abs(q[found] - before[found]).max() <= 1e-12 * size
    assert covered > 1000


def test_explicit_net_equals_detail_sum_with_random_offsets(sheet4):
    hs = H.make_movable(sheet4, 3, [[10, 9], [11, 9]])
    hs = with_random_offsets(hs)
    det = H.details(hs)
    u, v = _random_uv(hs, 10_000, 5)
    p = H.evaluate(hs, u, v, det=det).points
    for k in (1, 2, 3):
        q, found = _net_eval(hs, k, u, v, det)
        assert found.sum() > 50
        # the level-k net reproduces the surface of levels 0..k on its active patches
        pk = H.evaluate(hs, u[found], v[found], det=det, upto=k).points
        assert np.abs(q[found] - pk).max() <= 1e-12 * hs.size()
    assert np.abs(H.evaluate(hs, u, v, det=det, upto=3).points - p).max() == 0.0


def _knot_points(hs, k, n=200, seed=0):
    """Points on level-k knot lines of both directions (inside the domain)."""
    rng = np.random.default_rng(seed)
    ku = rng.integers(1, hs.u.patches(k), n) / float(1 << k)
    kv = rng.integers(1, hs.v.patches(k), n) / float(1 << k)
    fu = rng.uniform(0, hs.u.patches0, n)
    fv = rng.uniform(0, hs.v.patches0, n)
    return (ku, fv), (fu, kv)


@pytest.mark.parametrize("k", [0, 1, 2, 3])
def test_c2_across_patch_and_refined_region_borders(sheet4, k):
    hs = H.make_movable(sheet4, 3, [[10, 9]])
    hs = H.make_movable(hs, 2, [[3, 3]])
    hs = with_random_offsets(hs, scale=0.2, seed=7)
    det = H.details(hs)
    for axis, (u, v) in enumerate(_knot_points(hs, k)):
        left = H.evaluate(hs, u, v, order=2, det=det, side=-1)
        right = H.evaluate(hs, u, v, order=2, det=det, side=0)
        for name in ("points", "du", "dv", "duu", "duv", "dvv"):
            a, b = getattr(left, name), getattr(right, name)
            scale = max(1.0, np.abs(a).max())
            assert np.abs(a - b).max() <= 1e-10 * scale, (axis, name)
    # the third derivative is allowed to jump: the test would see a broken C2 as a jump here
    u = np.array([1.0])
    v = np.array([1.3])
    l3 = B.basis(np.array([1.0]), 3)[0]
    r3 = B.basis(np.array([0.0]), 3)[0]
    assert not np.allclose(l3[1:], r3[:3])


def test_c2_rule_refuses_offsets_on_border_cvs(sheet4):
    hs = H.refine(sheet4, 1, [[4, 4]])  # one patch: none of its CVs has its whole support active
    idx, off = H.offsets_of(hs, 1)
    assert idx.shape[0] == 0
    with pytest.raises(ValueError, match="not free to move"):
        H.set_offsets(hs, 1, [[5, 5]], [[0, 0, 1.0]])
    hs = H.make_movable(hs, 1, [[4, 4]])
    idx, _ = H.offsets_of(hs, 1)
    block = {(4 + a, 4 + b) for a in range(4) for b in range(4)}
    assert block <= {tuple(x) for x in idx}


def test_open_border_cvs_are_movable(sheet4):
    # the domain edge is not a border to a coarser level: its CVs may move
    hs = H.make_movable(sheet4, 1, [[0, 0]])
    idx, _ = H.offsets_of(hs, 1)
    assert (0, 0) in {tuple(x) for x in idx}


@settings(max_examples=20, deadline=None)
@given(st.integers(1, 3), st.integers(0, 10_000))
def test_locality_of_an_offset(k, seed):
    rng = np.random.default_rng(seed)
    hs = wavy_sheet(seed=seed % 5)
    pu = int(rng.integers(0, hs.u.patches(k)))
    pv = int(rng.integers(0, hs.v.patches(k)))
    hs = H.make_movable(hs, k, [[pu, pv]])
    j = np.array([[pu + int(rng.integers(0, 4)), pv + int(rng.integers(0, 4))]])
    moved = H.set_offsets(hs, k, j, rng.normal(size=(1, 3)))
    u, v = _random_uv(hs, 4000, seed)
    d = np.linalg.norm(H.evaluate(moved, u, v).points - H.evaluate(hs, u, v).points, axis=1)
    scale = float(1 << k)
    inside = (u > (j[0, 0] - 3) / scale) & (u < (j[0, 0] + 1) / scale) & (v > (j[0, 1] - 3) / scale) & (v < (j[0, 1] + 1) / scale)
    assert d[~inside].max(initial=0.0) == 0.0
    assert d[inside].max(initial=1.0) > 0.0


def test_storage_grows_with_the_refined_area_only():
    cvs, pu, pv = shapes.sphere(16, 14)
    hs = H.from_grid(cvs, pu, pv, depth=7)
    # detail in one region: a 2x2 block of level-6 patches made movable, plus a level-3 area
    base = np.array([[300, 300], [301, 300], [300, 301], [301, 301]])
    hs = H.make_movable(hs, 6, base)
    hs = H.make_movable(hs, 3, np.array([[37, 37], [38, 38]]))
    dense = 16 * 64 * (11 * 64 + 3)
    assert H.storage_size(hs) <= 3000
    assert H.storage_size(hs) * 100 < dense


def test_sphere_poles_have_limit_normals():
    cvs, pu, pv = shapes.sphere(8, 9)
    hs = H.from_grid(cvs, pu, pv)
    u = np.linspace(0, hs.u.patches0, 33)
    for vv, sign in ((0.0, -1.0), (float(hs.v.patches0), 1.0)):
        ev, n = H.surface_normals(hs, u, np.full(u.size, vv))
        assert np.all(np.isfinite(n))
        assert np.ptp(ev.points, axis=0).max() < 1e-12  # the pole is one point
        np.testing.assert_allclose(n, np.tile([0, 0, sign], (u.size, 1)), atol=1e-6)


def test_normals_of_a_batch_without_poles_are_the_rows_of_one_with_poles():
    """A batch where every ``du × dv`` has a direction returns at once; its normals are the bits
    the general path (limits and nudges for the pole rows) gives the same rows in a mixed batch,
    and ``nudged`` is all False."""
    hs = with_random_offsets(H.make_movable(H.from_grid(*shapes.sphere(8, 8), depth=2), 1, [[4, 9]]), 0.02, seed=3)
    det = H.details(hs)
    rng = np.random.default_rng(5)
    uv = np.column_stack([rng.uniform(0, hs.u.patches0, 60), rng.uniform(0.1, hs.v.patches0 - 0.1, 60)])
    mixed = np.vstack([uv, [[1.3, 0.0], [2.5, float(hs.v.patches0)]]])
    assert H._degenerate(H.evaluate(hs, mixed[-2:, 0], mixed[-2:, 1], order=1, det=det), hs.size())[1].any()  # the general path
    flags = np.ones(len(uv), bool)
    _, plain = H.surface_normals(hs, uv[:, 0], uv[:, 1], det=det, nudged=flags)
    _, general = H.surface_normals(hs, mixed[:, 0], mixed[:, 1], det=det)
    assert plain.tobytes() == general[:len(uv)].tobytes() and not flags.any()
    assert H.surface_normals(hs, uv[:0, 0], uv[:0, 1], det=det)[1].shape == (0, 3)


def test_collapsed_edges_evaluate_finite():
    # a degenerate patch: a whole row of an open sheet collapsed to one point
    cvs, pu, pv = shapes.sheet(6, 6)
    cvs[:, 0] = cvs[2, 2]
    cvs[:, 1] = cvs[2, 2]
    cvs[:, 2] = cvs[2, 2]
    hs = H.from_grid(cvs, pu, pv)
    u, v = np.meshgrid(np.linspace(0, 3, 13), np.linspace(0, 3, 13))
    ev, n = H.surface_normals(hs, u.ravel(), v.ravel())
    assert np.all(np.isfinite(n)) and np.allclose(np.linalg.norm(n, axis=1), 1.0)


def test_arrays_round_trip_is_exact(sheet4):
    hs = H.make_movable(sheet4, 3, [[10, 9]])
    hs = H.make_movable(hs, 2, [[1, 1]])
    hs = with_random_offsets(hs, seed=11)
    arr = H.to_arrays(hs)
    back = H.from_arrays(H.from_grid(hs.cvs, False, False, hs.depth), arr)
    for a, b in zip(hs.fine, back.fine):
        np.testing.assert_array_equal(a.patches, b.patches)
        np.testing.assert_array_equal(a.cv_keys, b.cv_keys)
        np.testing.assert_array_equal(a.offsets, b.offsets)
    with pytest.raises(ValueError, match="outside"):
        H.from_arrays(H.from_grid(hs.cvs, False, False, 2), arr)


@pytest.mark.parametrize("closed", [False, True])
def test_to_arrays_splits_each_level_by_its_own_row_length(closed):
    """`to_arrays` gives, level by level in order, each refined patch ``(key // patches_v(k), key
    % patches_v(k))`` and each non-zero offset's CV ``(key // cvs_v(k), key % cvs_v(k))``
    (open and closed surfaces, some offsets zero, a surface with no fine content), int32 keys and
    levels, float64 offsets."""
    hs = H.from_grid(*(shapes.sphere(10, 8) if closed else shapes.sheet(10, 8, 7.0, 5.0)), depth=4)
    hs = with_random_offsets(H.refine(H.refine(hs, 1, [[2, 2], [5, 3]]), 3, [[20, 17], [21, 17]]), 0.05, 0)
    idx, off = H.offsets_of(hs, 2)
    off[::2] = 0.0
    hs = H.set_offsets(hs, 2, idx, off)
    for surface in (hs, H.from_grid(hs.cvs, hs.u.periodic, hs.v.periodic, depth=4)):
        got = H.to_arrays(surface)
        pl, pp, ol, oc, oo = [], [], [], [], []
        for lev in surface.fine:
            npv, ncv = surface.v.patches(lev.k), surface.v.cvs(lev.k)
            pl += [lev.k] * lev.patches.size
            pp += [(key // npv, key % npv) for key in lev.patches.tolist()]
            for key, o in zip(lev.cv_keys.tolist(), lev.offsets):
                if np.any(o != 0.0):
                    ol.append(lev.k)
                    oc.append((key // ncv, key % ncv))
                    oo.append(o)
        want = (np.array(pl, np.int32), np.array(pp, np.int32).reshape(-1, 2), np.array(ol, np.int32),
                np.array(oc, np.int32).reshape(-1, 2), np.array(oo, np.float64).reshape(-1, 3))
        for x, y in zip(want, (got.patch_level, got.patches, got.offset_level, got.offset_cvs, got.offsets)):
            assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()
    assert len(H.to_arrays(hs).offsets) < sum(lev.cv_keys.size for lev in hs.fine)  # zero offsets left out


def test_refine_rejects_levels_outside_depth(sheet4):
    with pytest.raises(ValueError, match="levels 0..3"):
        H.refine(sheet4, 4, [[0, 0]])


@pytest.mark.parametrize("closed", [False, True])
def test_refine_levels_builds_each_level_once_as_refining_them_in_turn(closed, monkeypatch):
    """`Hi.refine_levels` of several levels is `H.refine` of each in turn (patches, CVs, rows,
    movability, offsets), with one `_build_level` per level it touches."""
    hs = H.from_grid(*(shapes.sphere(10, 8) if closed else shapes.sheet(10, 8, 7.0, 5.0)), depth=4)
    hs = with_random_offsets(H.refine(hs, 1, [[2, 2]]), 0.05, 0)  # offsets the new levels keep
    want = {1: np.array([[0, 1], [5, 3]]), 3: np.array([[20, 17], [21, 17], [-1, 3]]), 2: np.array([[9, 2]])}
    seq = hs
    for k in (3, 1, 2):
        seq = H.refine(seq, k, want[k])
    built = []
    build = Hi._build_level
    monkeypatch.setattr(Hi, "_build_level", lambda *a: built.append(a[1]) or build(*a))
    one = Hi.refine_levels(hs, want)
    assert built == [3, 2, 1]
    for a, b in zip(seq.fine, one.fine):
        for name in ("patches", "cv_keys", "patch_rows", "movable", "offsets"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert Hi.refine_levels(one, want) is one
    with pytest.raises(ValueError, match="levels 0..3"):
        Hi.refine_levels(hs, {1: [[0, 0]], 4: [[0, 0]]})


@pytest.mark.parametrize("kind", ["sheet", "sphere", "torus"])
def test_refine_blocks_equal_make_movable_of_each_level_in_one_sweep(kind):
    """`Hi.refine_blocks` (a response's up-front refinement: the 7×7 block about each point's
    patch on each absorbing level, listed by `levelkernels.block_keys`, plus a pole's rows) is
    `refine_levels` of those blocks: the same levels, key for key, across periodic seams and
    open borders, points on knots and ends included; the same surface when nothing is new."""
    grid = {"sheet": shapes.sheet(9, 8, 6.0, 5.0), "sphere": shapes.sphere(10, 8), "torus": shapes.torus(7, 6)}[kind]
    hs = with_random_offsets(H.refine(H.from_grid(*grid, depth=5), 1, [[2, 2]]), 0.05, 0)
    rng = np.random.default_rng(3)
    u = np.concatenate([rng.uniform(0, hs.u.patches0, 6), [0.0, hs.u.patches0, 2.5, 1.0]])
    v = np.concatenate([rng.uniform(0, hs.v.patches0, 6), [hs.v.patches0, 0.0, 3.0, 0.75]])
    extra = {3: np.array([[0, 1], [4, 2]])}
    for levels in ((2, 3, 4), (1,), (2, 4)):
        want = {}
        for k in levels:
            su, _ = B.locate(hs.u, u, k)
            sv, _ = B.locate(hs.v, v, k)
            d = np.arange(-3, 4)
            block = np.stack(np.broadcast_arrays(su[:, None, None] + d[:, None], sv[:, None, None] + d[None, :]), -1)
            want[k] = np.concatenate([block.reshape(-1, 2), extra.get(k, np.zeros((0, 2), np.int64))])
        ref = Hi.refine_levels(hs, want)
        got = Hi.refine_blocks(hs, levels, u, v, {k: extra[k] for k in levels if k in extra})
        assert got is not hs
        for a, b in zip(ref.fine, got.fine):
            _same_level(a, b)
        assert Hi.refine_blocks(got, levels, u, v) is got
    with pytest.raises(ValueError, match="levels 0..4"):
        Hi.refine_blocks(hs, (1, 5), u, v)


def test_evaluate_takes_plain_arrays_as_they_are_and_fills_its_slots_in_order():
    """`evaluate` hands the kernel a C-contiguous writeable float64 array of the right dimensions
    as it is (`H._flat`) and a copy of any other (read-only, strided, another dtype, nested), and
    its `SurfaceEval` holds the evaluated slots in field order, the others None, as the
    constructor's defaults."""
    a = np.linspace(0.0, 1.0, 6)
    grid = a.reshape(2, 3)
    assert H._flat(a) is a and H._flat(grid, 2) is grid
    ro = a.copy()
    ro.flags.writeable = False
    for other in (ro, a[::2], a.astype(np.float32), a.reshape(2, 3), [0.5, 0.25]):
        got = H._flat(other)
        assert got is not other and got.ndim == 1 and got.flags.writeable and got.flags.c_contiguous
        np.testing.assert_array_equal(got, np.asarray(other, np.float64).reshape(-1))
    hs = with_random_offsets(H.make_movable(H.from_grid(*shapes.sphere(8, 8), depth=3), 2, [[6, 6]]), 0.02, 0)
    u, v = np.array([0.3, 1.6, 2.2]), np.array([1.4, 1.5, 0.2])
    for order, names in ((0, ("points",)), (1, ("points", "du", "dv")), (2, ("points", "du", "dv", "duu", "duv", "dvv"))):
        ev = H.evaluate(hs, u, v, order=order)
        ref = H._evaluate_numpy(hs, u, v, order=order)
        for name in ("points", "du", "dv", "duu", "duv", "dvv"):
            if name in names:
                np.testing.assert_allclose(getattr(ev, name), getattr(ref, name), rtol=0, atol=1e-12)
            else:
                assert getattr(ev, name) is None and vars(ev)[name] is None


def _per_level_sum(hs, u, v, order, det, side=0):
    """Reference for `evaluate`: the module docstring's sum, one level at a time, term by term."""
    from acra.basis import basis, locate
    combos = [(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)][: {0: 1, 1: 3, 2: 6}[order]]
    out = np.zeros((len(combos), u.size, 3))
    for k in range(hs.depth):
        for i in range(u.size):
            seg, t = [], []
            for d, x in ((hs.u, u[i]), (hs.v, v[i])):
                s, tt = locate(d, np.array([x]), k)
                if side < 0 and tt[0] == 0.0 and (s[0] > 0 or d.periodic):
                    s, tt = d.wrap_patch(s - 1, k), np.array([1.0])
                seg.append(int(s[0]))
                t.append(tt)
            if k == 0:
                ju = hs.u.wrap_cv(seg[0] + np.arange(4), 0)
                jv = hs.v.wrap_cv(seg[1] + np.arange(4), 0)
                block = hs.cvs[ju[:, None], jv[None, :]]
            else:
                lev = hs.level(k)
                row = np.searchsorted(lev.patches, seg[0] * hs.v.patches(k) + seg[1])
                if row >= lev.patches.size or lev.patches[row] != seg[0] * hs.v.patches(k) + seg[1]:
                    continue
                block = det.vectors[k - 1][lev.patch_rows[row]]
            for s, (a, b) in enumerate(combos):
                bu = basis(t[0], a)[0] * 2.0 ** (k * a)
                bv = basis(t[1], b)[0] * 2.0 ** (k * b)
                out[s, i] += np.einsum("a,b,abc->c", bu, bv, block)
    return out


@pytest.mark.parametrize("periodic", [(False, False), (True, False), (True, True)])
def test_batched_evaluation_equals_the_per_level_sum(periodic):
    """`evaluate` gathers every (point, level) term into one batch; it must equal the plain sum
    of each level's B-spline, derivatives and one-sided knots included."""
    rng = np.random.default_rng(7)
    hs = H.from_grid(rng.normal(size=(8, 9, 3)), *periodic, depth=4)
    for k in (1, 2, 3):
        hs = H.make_movable(hs, k, np.array([[2 << k, 2 << k], [3 << (k - 1), 5 << (k - 1)]]) // 2)
        ij, _ = H.offsets_of(hs, k)
        hs = H.set_offsets(hs, k, ij, 0.1 * rng.normal(size=(len(ij), 3)))
    det = H.details(hs)
    u = rng.uniform(0, hs.u.patches0, 60)
    v = rng.uniform(0, hs.v.patches0, 60)
    u[:15] = np.round(u[:15] * 4) / 4  # on knots of levels 0..2
    names = ["points", "du", "dv", "duu", "duv", "dvv"]
    for side in (0, -1):
        for order in (0, 1, 2):
            ev = H.evaluate(hs, u, v, order=order, det=det, side=side)
            ref = _per_level_sum(hs, u, v, order, det, side)
            for s in range(ref.shape[0]):
                np.testing.assert_allclose(getattr(ev, names[s]), ref[s], rtol=0, atol=1e-12)


def test_closed_ends_and_pole_points():
    sphere = H.from_grid(*shapes.sphere(8, 9))
    assert H.closed_ends(sphere) == ((1, 0), (1, 1))
    for shape in (shapes.torus(), shapes.sheet(6, 6), shapes.tube()):
        assert H.closed_ends(H.from_grid(*shape)) == ()
    # an open grid whose v = 0 edge is one point (a fan's apex) closes that end too
    fan, _, _ = shapes.sheet(8, 8, width=3.0, depth=3.0)
    fan[:, :, 0] *= ((np.arange(8) - 1.0) / 5)[None, :]
    fan[:, 0, 0] = -fan[:, 2, 0]
    fan = H.from_grid(fan)
    assert H.closed_ends(fan) == ((1, 0),)
    np.testing.assert_array_equal(H.pole_of(fan, np.array([0.3, 4.9, 2.0]), np.array([0.0, 0.0, 0.5])), [0, 0, -1])
    P = sphere.v.patches0
    pole = H.pole_of(sphere, np.array([0.3, 2.0, 5.5, 1.0]), np.array([0.0, P, P - 1e-3, P * (1 - 1e-11)]))
    np.testing.assert_array_equal(pole, [0, 1, -1, 1])
    # the ring's columns are what the pole point weighs: each column's rows blend to the pole
    keys, w = H.pole_ring(sphere, 0, 1, 1)
    cols = sphere.cvs.reshape(-1, 3)[keys]  # (N, 3, 3)
    tip = H.evaluate(sphere, np.array([0.7]), np.array([float(P)])).points[0]
    np.testing.assert_allclose(np.einsum("r,jrc->jc", w, cols), np.tile(tip, (keys.shape[0], 1)), atol=1e-12)


def _same_level(a, b):
    for f in ("k", "patches", "cv_keys", "patch_rows", "movable", "offsets"):
        x, y = np.asarray(getattr(a, f)), np.asarray(getattr(b, f))
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), f


@pytest.mark.parametrize("periodic", [(False, False), (True, False), (False, True), (True, True)])
@pytest.mark.parametrize("seed", range(4))
def test_compiled_level_building_equals_the_array_form(periodic, seed):
    """`hierarchy._build_level` (compiled, `acra.levelkernels.build_level`) gives the array
    form's level, array for array and bit for bit: refinements from nothing, of levels with
    offsets, with repeated keys, across a periodic seam, and none where every key is active."""
    rng = np.random.default_rng(seed)
    hs = H.from_grid(rng.normal(size=(7, 6, 3)), *periodic, depth=4)
    if seed % 2:  # else the levels start empty
        hs = with_random_offsets(H.make_movable(hs, 3, np.array([[2, 3], [9, 1]])), seed=seed)
    built = 0
    for _ in range(8):
        k = int(rng.integers(1, hs.depth))
        old = hs.level(k)
        n = int(rng.integers(1, 60))
        keys = rng.integers(0, hs.u.patches(k) * hs.v.patches(k), n)
        if old.patches.size and rng.random() < 0.3:  # keys already active, some repeated
            keys = rng.choice(old.patches, n)
        got = Hi._build_level(hs, k, keys, old)
        if np.all(H._lookup(old.patches, keys)[1]):
            assert got is None
            continue
        _same_level(got, Hi._build_level_numpy(hs, k, np.concatenate([old.patches, keys]), old))
        built += 1
        hs = H.refine(hs, k, np.stack(np.divmod(keys, hs.v.patches(k)), axis=1))
        assert hs.level(k).patches is got.patches or np.array_equal(hs.level(k).patches, got.patches)
    assert built >= 3


def test_level_building_refuses_to_strand_an_offset():
    """Activating patches never makes a CV with an offset non-movable; a level whose CV set a
    caller broke is refused by both forms."""
    hs = with_random_offsets(H.make_movable(H.from_grid(shapes.sphere(8, 7)[0], True, False, depth=3), 2,
                                            np.array([[4, 4]])))
    old = hs.level(2)
    broken = H.Level(old.k, old.patches[:1], old.cv_keys, old.offsets, old.movable, old.patch_rows[:1])
    keys = np.array([old.patches[-1] + 1])
    with pytest.raises(ValueError, match="not free to move"):
        Hi._build_level(hs, 2, keys, broken)
    with pytest.raises(ValueError, match="not free to move"):
        Hi._build_level_numpy(hs, 2, np.concatenate([broken.patches, keys]), broken)


def test_level_building_past_the_kernels_grid_is_the_array_form(monkeypatch):
    """A level grid larger than the kernel's dense marks (`levelkernels._MAX_CELLS`) is built
    by the array form: the same surface."""
    from acra import levelkernels

    hs = H.from_grid(shapes.sphere(8, 7)[0], True, False, depth=4)
    patches = np.array([[3, 5], [17, 2], [30, 40]])
    compiled = H.make_movable(hs, 3, patches)
    monkeypatch.setattr(levelkernels, "_MAX_CELLS", 0)
    plain = H.make_movable(hs, 3, patches)
    for a, b in zip(compiled.fine, plain.fine):
        _same_level(a, b)


def test_mark_changed_calls_mark_cells_with_the_pythons_specialisation():
    """`levelkernels.mark_changed` hands `kernels.mark_cells` its level and spread as int64
    values: integer literals in a compiled call would type as ``Literal[int]`` and compile a second
    specialisation of `mark_cells` on a fresh install (about 1 s). A copy of `mark_changed`
    compiled here types its call again, adding any new signature to `mark_cells`."""
    from numba import njit, types

    from acra import kernels, levelkernels

    fresh = njit(levelkernels.mark_changed.py_func)
    bits = np.zeros((4, 3), np.int64)
    other = bits.copy()
    other[1, 0] = 1
    stale = np.zeros((4, 4), bool)
    assert fresh(bits, other, np.arange(4, dtype=np.int64), np.arange(4, dtype=np.int64), 4, 0, 4, 4, False, False, stale) == 1
    assert stale.any()
    for sig in kernels.mark_cells.signatures:
        assert not any(isinstance(t, types.Literal) for t in sig), sig


def test_restating_a_levels_rows_is_the_array_form():
    """`levelkernels.restate_rows` (behind `H.moved_details`) gives the frames with the rows'
    replaced and the vectors ``np.einsum("mij,mj->mi")`` gives (its ``(p0 + p2) + p1`` from 0.0:
    a zero offset's vector is +0.0 whatever the frame's signs)."""
    from acra import levelkernels

    hs = H.make_movable(H.from_grid(*shapes.sphere(8, 7), depth=3), 2, np.array([[3, 4], [9, 2], [0, 0]]))
    rng = np.random.default_rng(8)
    k, lev = 2, hs.level(2)
    c = lev.cv_keys.size
    frames = rng.normal(size=(c, 3, 3)) * 10.0 ** rng.integers(-6, 6, (c, 3, 3))
    offsets = rng.normal(size=(c, 3)) * 10.0 ** rng.integers(-6, 6, (c, 3))
    vectors = np.einsum("mij,mj->mi", frames, offsets)
    rows = np.flatnonzero(lev.movable)[::3]
    offsets[rows[0]] = -0.0
    frames[rows[0]] = -np.abs(frames[rows[0]])
    new_frames = rng.normal(size=(rows.size, 3, 3))
    new_frames[1::2] = frames[rows[1::2]]  # half the rows keep their frames, and so their vectors
    args = (lev.cv_keys, int(hs.v.cvs(k)), k, int(hs.u.patches(k)), int(hs.v.patches(k)), bool(hs.u.periodic),
            bool(hs.v.periodic))
    for fresh in (new_frames, np.zeros((0, 3, 3))):
        want_fr = frames.copy()
        if fresh.size:
            want_fr[rows] = fresh
        want_vec = vectors.copy()
        want_vec[rows] = np.einsum("mij,mj->mi", want_fr[rows], offsets[rows])
        none = np.zeros((0, 3))
        fr, vec = levelkernels.restate_rows(frames, fresh, rows, offsets, vectors, none, none)
        assert fr.tobytes() == want_fr.tobytes() and vec.tobytes() == want_vec.tobytes()
        assert (fr is frames) == (not fresh.size) and vec is not vectors
        assert vec[rows[0]].tobytes() == np.zeros(3).tobytes()
        stale = np.zeros((hs.u.patches0, hs.v.patches0), bool)
        n = levelkernels.mark_changed(vec.view(np.int64), vectors.view(np.int64), rows, *args, stale)
        assert 0 < n < rows.size  # the test moved some rows' vectors and not others


@pytest.mark.parametrize("seed", range(4))
def test_restating_a_moves_rows_is_the_array_form(seed):
    """`levelkernels.restate_rows` with moves (behind `acra.moves.move_level`) gives the
    offsets ``offsets[rows] += np.einsum("mji,mj->mi", frames[rows], moves)`` gives, bit for bit
    (its products summed from 0.0 in order, then added), and the vectors restated from them on
    the rows whose offsets changed bits, every other row's kept: a zero move, or one too small to
    change an offset, keeps the row's vector even where it is not the frame's product."""
    from acra import levelkernels

    rng = np.random.default_rng(20 + seed)
    c = 200
    frames = rng.normal(size=(c, 3, 3)) * 10.0 ** rng.integers(-6, 6, (c, 3, 3))
    offsets = rng.normal(size=(c, 3)) * 10.0 ** rng.integers(-6, 6, (c, 3))
    vectors = rng.normal(size=(c, 3))  # not the frames' products: a kept row shows as its own bits
    rows = rng.permutation(c)[: 1 + seed * 40].astype(np.int64)
    moves = rng.normal(size=(rows.size, 3)) * 10.0 ** rng.integers(-9, 3, (rows.size, 3))
    moves[::5] = 0.0  # rows the move leaves
    moves[1::7] = -0.0
    moves[2::9] *= 1e-30  # below an ulp of the offset
    offsets[rows[3::6]] = -0.0
    want_off = offsets.copy()
    want_off[rows] += np.einsum("mji,mj->mi", frames[rows], moves)
    changed = rows[np.any(want_off[rows].view(np.int64) != offsets[rows].view(np.int64), axis=-1)]
    want_vec = vectors.copy()
    want_vec[changed] = np.einsum("mij,mj->mi", frames[changed], want_off[changed])
    moved = offsets.copy()
    fr, vec = levelkernels.restate_rows(frames, np.zeros((0, 3, 3)), rows, offsets, vectors, moves, moved)
    assert moved.tobytes() == want_off.tobytes() and vec.tobytes() == want_vec.tobytes()
    assert fr is frames and vec is not vectors
    if seed:
        assert 0 < changed.size < rows.size  # some rows moved and some did not


def test_a_rings_movability_is_its_rows_all_movable_kept_per_level():
    """`pole_ring_movable` is `pole_ring_rows`' ``ok`` all true, found once per `Level` object
    (and so per refinement: a refined level is another object)."""
    hs = H.from_grid(*shapes.sphere(8, 9), depth=3)
    for axis, end in H.closed_ends(hs):
        assert not H.pole_ring_movable(hs, 2, axis, end)
    ref = H.refine(hs, 2, H.pole_patches(hs, 2, 1, 1))
    for k in (1, 2):
        for axis, end in H.closed_ends(ref):
            want = bool(H.pole_ring_rows(ref, k, axis, end)[1].all())
            assert H.pole_ring_movable(ref, k, axis, end) is want
    assert H.pole_ring_movable(ref, 2, 1, 1) and not H.pole_ring_movable(ref, 2, 1, 0)
    assert not H.pole_ring_movable(hs, 2, 1, 1)  # the unrefined level keeps its own answer


def test_the_detail_names_are_acra_details_own_looked_up_on_each_access(monkeypatch):
    """`acra.hspline` re-exports `acra.details`' public names by looking them up there on each
    access, so a replaced ``acra.details.details`` (a benchmark's timer, a test's counter) is what
    every ``H.details`` caller gets; either module imports first."""
    import subprocess
    import sys

    from acra import details as D
    for name in H._FROM_DETAILS:
        assert getattr(H, name) is getattr(D, name)
        assert name in H.__all__
    seen = []
    monkeypatch.setattr(D, "details", lambda *a, **k: seen.append(a) or "replaced")
    assert H.details(None) == "replaced" and seen == [(None,)]
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        H.nothing  # noqa: B018
    for first in ("acra.details", "acra.hspline"):
        done = subprocess.run([sys.executable, "-c", f"import {first}; from acra import hspline, details; "
                               "assert hspline.Details is details.Details"], capture_output=True, text=True)
        assert done.returncode == 0, done.stderr


def test_every_name_hspline_exports_is_there():
    """`acra.hspline`'s ``__all__`` (its own names and those it re-exports from `acra.hierarchy`,
    `acra.changes` and `acra.details`) names only what the module gives: ``import *`` works."""
    import acra.hspline as H

    missing = [name for name in H.__all__ if not hasattr(H, name)]
    assert not missing
    namespace: dict = {}
    exec("from acra.hspline import *", namespace)
    assert set(H.__all__) <= set(namespace)
