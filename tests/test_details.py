"""The fine levels' detail vectors (`acra.details`, thesis §3.4, Fig. 3.10): detail riding along
a coarse move, passes since a move or a refinement and after a response's move equal to a full
pass, the stacked table, a pole ring's one normal and the move's compiled bookkeeping."""

import numpy as np
import pytest

from acra import details as D
from acra import hspline as H
from acra import shapes
from conftest import nudged, with_random_offsets


def _random_uv(hs, n, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(0, hs.u.patches0, n), rng.uniform(0, hs.v.patches0, n)


def test_coarse_move_carries_level3_bump_along(sheet4):
    hs = H.make_movable(sheet4, 3, [[10, 9]])
    bump = np.array([[10 + a, 9 + b] for a in range(4) for b in range(4)])
    offs = np.zeros((16, 3))
    offs[:, 2] = 0.02 * (1 + np.arange(16) % 3)
    offs[:, 0] = 0.005
    hs = H.set_offsets(hs, 3, bump, offs)
    det0 = D.details(hs)

    # (a) a rigid motion of the level-0 grid moves the whole surface, bump included, rigidly
    ang = 0.7
    rot = np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0], [0, 0, 1]]) @ np.array(
        [[1, 0, 0], [0, np.cos(0.3), -np.sin(0.3)], [0, np.sin(0.3), np.cos(0.3)]]
    )
    moved = H.HSpline(hs.cvs @ rot.T + [1.0, -2.0, 0.5], hs.u, hs.v, hs.depth, hs.fine)
    u, v = _random_uv(hs, 5000, 9)
    p0 = H.evaluate(hs, u, v, det=det0).points
    p1 = H.evaluate(moved, u, v).points
    assert np.abs(p1 - (p0 @ rot.T + [1.0, -2.0, 0.5])).max() <= 1e-9 * hs.size()

    # (b) moving one coarse CV near the bump: the bump's CVs keep their shape in their frames
    cvs = hs.cvs.copy()
    cvs[3, 3] += [0.1, -0.2, 0.6]
    bent = H.HSpline(cvs, hs.u, hs.v, hs.depth, hs.fine)
    det1 = D.details(bent)
    lev = hs.level(3)
    rows = H._lookup(lev.cv_keys, bump[:, 0] * hs.v.cvs(3) + bump[:, 1])[0]
    for surf, det in ((hs, det0), (bent, det1)):
        pos = D.cv_positions(surf, 3, det)[rows]
        derived = pos - det.vectors[2][rows]
        local = np.einsum("mji,mj->mi", det.frames[2][rows], pos - derived)
        np.testing.assert_allclose(local, offs, rtol=0, atol=1e-9)
    # and the bump really moved with the coarse surface (not a vacuous check)
    pb0 = D.cv_positions(hs, 3, det0)[rows]
    pb1 = D.cv_positions(bent, 3, det1)[rows]
    assert np.abs(pb1 - pb0).max() > 1e-2
    # the frames turned, so the world detail vectors turned with them
    assert np.abs(det1.vectors[2][rows] - det0.vectors[2][rows]).max() > 1e-4


@pytest.mark.parametrize("seed", range(4))
def test_details_since_a_local_move_equal_a_full_recomputation(seed):
    """`details(since=...)` recomputes only CVs centred on changed patches: equal to a full pass."""
    rng = np.random.default_rng(seed)
    hs = H.from_grid(*shapes.sphere(12, 10), depth=4)
    u0 = int(rng.integers(0, 12))
    hs = H.make_movable(hs, 3, [[8 * u0 + 4, 30]])
    hs = with_random_offsets(hs, 0.02, seed)
    det = D.details(hs)
    levels = [0] + [k for k in range(1, hs.depth) if len(H.offsets_of(hs, k)[1])]
    assert len(levels) >= 2
    for k in levels:
        moved = nudged(hs, k, rng, cv=(u0, 4))
        stale = H.changed_patches(hs, moved)
        assert 0 < stale.sum() < stale.size
        fast = D.details(moved, since=(hs, det, stale))
        full = D.details(moved)
        for a, b in zip(fast.vectors + fast.frames, full.vectors + full.frames):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_details_since_a_refinement_evaluate_only_the_new_cvs(seed, monkeypatch):
    """Refinement moves nothing: `details(since=...)` keeps every old frame, evaluates frames
    only for the CVs it added, and equals a full pass; a move on top of it still does."""
    rng = np.random.default_rng(seed)
    hs = H.from_grid(*shapes.sphere(12, 10), depth=4)
    hs = H.make_movable(hs, 2, [[4 * int(rng.integers(0, 12)) + 2, 14]])
    hs = with_random_offsets(hs, 0.02, seed)
    det = D.details(hs)
    finer = H.make_movable(hs, 3, [[8 * int(rng.integers(0, 12)) + 4, 30]])
    added = sum(int(b.movable.sum() - a.movable.sum()) for a, b in zip(hs.fine, finer.fine))
    assert added > 0
    evaluated = []
    real = D._frames_at  # every frame `details` evaluates, in one pass per level
    monkeypatch.setattr(D, "_frames_at", lambda hs_, k, ends, partial, ring, u, v: evaluated.append(np.size(u)) or real(hs_, k, ends, partial, ring, u, v))
    fast = D.details(finer, since=(hs, det, H.changed_patches(hs, finer)))
    assert sum(evaluated) == added
    monkeypatch.setattr(D, "_frames_at", real)
    full = D.details(finer)
    for a, b in zip(fast.vectors + fast.frames, full.vectors + full.frames):
        np.testing.assert_array_equal(a, b)
    moved = nudged(finer, 2, rng)
    fast = D.details(moved, since=(finer, full, H.changed_patches(finer, moved)))
    full = D.details(moved)
    for a, b in zip(fast.vectors + fast.frames, full.vectors + full.frames):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


def test_details_give_their_table_stacked_as_they_go(monkeypatch):
    """`D.details` and `D.moved_details` hand back (and hand `_frames_at` the coarser levels as)
    `Details` whose ``table`` is already there, without stacking the vectors on first read, and
    is their vectors stacked bit for bit; so is a pass up to a level (``upto``) and one since a
    refinement or a move."""
    from acra.moves import move_level
    seen = []
    real = D._frames_at
    monkeypatch.setattr(D, "_frames_at", lambda hs_, k, ends, partial, ring, u, v: seen.append(partial) or real(hs_, k, ends, partial, ring, u, v))

    def given_and_stacked(det):
        assert "table" in det.__dict__
        want = np.concatenate(det.vectors) if det.vectors else np.zeros((0, 3))
        np.testing.assert_array_equal(det.table.view(np.int64), want.view(np.int64))

    rng = np.random.default_rng(3)
    hs = H.from_grid(*shapes.sphere(12, 10), depth=4)
    hs = H.make_movable(hs, 2, [[6, 16], [10, 1]])  # the second reaches a pole
    hs = with_random_offsets(H.make_movable(hs, 3, [[12, 30]]), 0.02, 3)
    outs = [D.details(hs), D.details(hs, upto=2)]
    finer = H.make_movable(hs, 3, [[40, 30]])
    outs.append(D.details(finer, since=(hs, outs[0], H.changed_patches(hs, finer))))
    for k in range(1, hs.depth):
        rows = np.unique(rng.choice(np.nonzero(hs.level(k).movable)[0], size=2, replace=False))
        moved = move_level(hs, k, rows, rng.normal(scale=0.03, size=(rows.size, 3)), outs[0])
        outs.append(D.moved_details(hs, outs[0], moved, k))
    assert len(seen) >= 4 and all(d is not None for d in outs)
    for det in outs + seen:
        given_and_stacked(det)


def test_moved_details_follow_a_move_down_the_levels_as_a_full_pass(monkeypatch):
    """`D.moved_details` after a response's move (`moves.move_level`) is `D.details` of the
    moved surface bit for bit, frames of pole rings included; it keeps the coarser levels'
    arrays and evaluates no more frames than `details(since=...)` on `changed_patches`, fewer
    where the move's reach stops short of the patches' margin."""
    from acra.moves import move_level
    counted, mine, theirs = [], 0, 0
    real = D._frames_at
    monkeypatch.setattr(D, "_frames_at", lambda hs_, k, ends, partial, ring, u, v: counted.append(np.size(u)) or real(hs_, k, ends, partial, ring, u, v))
    for seed in range(4):
        rng = np.random.default_rng(seed)
        hs = H.from_grid(*shapes.sphere(12, 10), depth=4)
        u0 = int(rng.integers(0, 12))
        hs = H.make_movable(hs, 1, [[2 * u0 + 1, 8]])
        hs = H.make_movable(hs, 2, [[4 * u0 + 2, 16], [4 * u0 + 6, 1]])  # the second reaches a pole
        hs = with_random_offsets(H.make_movable(hs, 3, [[8 * u0 + 4, 30], [8 * u0 + 12, 2]]), 0.02, seed)
        det = D.details(hs)
        for k in range(1, hs.depth):
            movable = np.nonzero(hs.level(k).movable)[0]
            rows = np.unique(rng.choice(movable, size=2, replace=False))
            moved = move_level(hs, k, rows, rng.normal(scale=0.03, size=(rows.size, 3)), det)
            counted.clear()
            fast = D.moved_details(hs, det, moved, k)
            step = sum(counted)
            counted.clear()
            D.details(moved, since=(hs, det, H.changed_patches(hs, moved, levels=(k,))), moved=(k,))
            assert step <= sum(counted)
            mine, theirs = mine + step, theirs + sum(counted)
            full = D.details(moved)
            for a, b in zip(fast.vectors + fast.frames, full.vectors + full.frames):
                np.testing.assert_array_equal(a.view(np.int64), b.view(np.int64))
            assert all(fast.vectors[m] is det.vectors[m] and fast.frames[m] is det.frames[m] for m in range(k - 1))
        finer = H.refine(hs, 3, [[(8 * u0 + 48) % 96, 40]])
        assert finer.level(3).cv_keys.size > hs.level(3).cv_keys.size
        assert D.moved_details(hs, det, finer, 3) is None  # not a move
    assert mine < theirs


def test_a_pole_rings_detail_turns_as_one_under_a_small_coarse_wiggle():
    """Every CV of a fine level's pole ring frames its detail with one normal, the end's
    (`acra.details._end_normal`). Near a pole one tangent vanishes, so the per-CV normals there swing
    with any bump across the short direction: here a level-1 wiggle of 1e-4 of the size (alternate
    columns up and down, four rows from the pole) turned level-2 ring detail by up to 180 degrees
    with per-CV normals (spread 2.0 between the ring's normals); with one normal per ring, which
    the symmetric wiggle leaves where it was, the detail does not turn (turned detail folds a
    fan's apex, hard case 10)."""
    hs = H.from_grid(*shapes.sphere(8, 9), depth=3)
    axis, end = H.closed_ends(hs)[1]
    for k in (1, 2):
        hs = H.refine(hs, k, H.pole_patches(hs, k, axis, end))
    keys, _ = H.pole_ring(hs, 2, axis, end)
    rows, _ = H._lookup(hs.level(2).cv_keys, keys.reshape(-1))
    ju, jv = H._split_cv(hs, 2, hs.level(2).cv_keys[rows])
    hs = H.set_offsets(hs, 2, np.stack([ju, jv], 1), np.tile([0.0, 0.0, -0.05], (rows.size, 1)))
    det = D.details(hs)
    assert np.ptp(det.frames[1][rows][:, :, 2], axis=0).max() <= 1e-12
    lev = hs.level(1)
    ju1, jv1 = H._split_cv(hs, 1, lev.cv_keys)
    near = (jv1 >= hs.v.cvs(1) - 4) & lev.movable
    wiggle = np.zeros((near.sum(), 3))
    wiggle[:, 2] = 1e-4 * hs.size() * np.where(ju1[near] % 2 == 0, 1.0, -1.0)
    det2 = D.details(H.set_offsets(hs, 1, np.stack([ju1[near], jv1[near]], 1), wiggle))
    v0, v1 = det.vectors[1][rows], det2.vectors[1][rows]
    cos = np.sum(v0 * v1, axis=1) / (np.linalg.norm(v0, axis=1) * np.linalg.norm(v1, axis=1))
    assert np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max() <= 1.0
    assert np.ptp(det2.frames[1][rows][:, :, 2], axis=0).max() <= 1e-12


def test_a_moves_bookkeeping_kernels_are_the_array_form():
    """`D.moved_details`' compiled bookkeeping (`levelkernels.differing_rows`, `mark_changed`,
    `stale_rows`) gives what its numpy form gives: the rows whose bits differ (``-0.0`` against
    ``0.0`` too), the level-0 patches their CVs support, and the CVs whose centre or pole ring
    lies on a stale patch or whose frame is pending."""
    from acra import kernels, levelkernels

    hs = H.make_movable(H.from_grid(*shapes.sphere(8, 7), depth=3), 2, np.array([[3, 4], [9, 2], [0, 0]]))
    rng = np.random.default_rng(4)
    k, lev, ends = 2, hs.level(2), H.closed_ends(hs)
    a = rng.normal(size=(lev.cv_keys.size, 3))
    b = a.copy()
    rows = np.flatnonzero(lev.movable)
    b[rows[::5], rng.integers(0, 3, rows[::5].size)] += 1e-17
    a[rows[1]], b[rows[1]] = 0.0, -0.0
    bits_a, bits_b = a.view(np.int64), b.view(np.int64)
    want = rows[np.any(bits_a[rows] != bits_b[rows], axis=-1)]
    np.testing.assert_array_equal(levelkernels.differing_rows(bits_a, bits_b, rows), want)
    stale = np.zeros((hs.u.patches0, hs.v.patches0), bool)
    n = levelkernels.mark_changed(bits_a, bits_b, rows, lev.cv_keys, int(hs.v.cvs(k)), k, int(hs.u.patches(k)),
                                  int(hs.v.patches(k)), bool(hs.u.periodic), bool(hs.v.periodic), stale)
    ref = np.zeros_like(stale)
    ju, jv = np.divmod(lev.cv_keys[want], hs.v.cvs(k))
    kernels.mark_cells(ref, ju, jv, k, 0, 3, hs.u.patches(k), hs.v.patches(k), bool(hs.u.periodic), bool(hs.v.periodic))
    assert n == want.size and stale.any() and not stale.all()
    np.testing.assert_array_equal(stale, ref)
    every, ring, _, _, centre = D._movable_places(hs, k, lev, ends)
    pending = every[[2, 7]]
    hit = stale.reshape(-1)[centre] | np.append(D._ends_stale(hs, ends, stale)[:len(ends)], False)[ring]
    hit[np.searchsorted(every, pending)] = True
    got = levelkernels.stale_rows(stale, centre, ring, D._ends_array(ends), every, pending)
    np.testing.assert_array_equal(got, np.nonzero(hit)[0])
    assert (ring[got] >= 0).any() and (ring[got] < 0).any()
