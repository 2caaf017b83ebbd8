"""`acra.patch_boxes`: the level-0 patch boxes of `patch_hulls`, compiled."""

import numpy as np
import pytest
from conftest import wavy_sheet, with_random_offsets

from acra import hspline as H
from acra import shapes
from acra.patch_boxes import patch_boxes, patch_hulls


@pytest.mark.parametrize("name", ["sheet", "sphere", "torus", "tube"])
def test_patch_boxes_equal_patch_hulls(name):
    """The same boxes bit for bit as the array form, whole and for a subset of patches, on open,
    periodic and pole-closed surfaces with details on several levels (CVs whose supports wrap
    and pass the open ends)."""
    if name == "sheet":
        hs = H.make_movable(wavy_sheet(), 3, [[10, 9]])
    else:
        cvs, pu, pv = getattr(shapes, name)()
        hs = H.from_grid(cvs, pu, pv, depth=4)
        hs = H.make_movable(hs, 2, [[1, 1], [hs.u.patches0 - 1, 0]])
        hs = H.make_movable(hs, 3, [[2, hs.v.patches0 - 1]])
    hs = with_random_offsets(hs, scale=0.3)
    det = H.details(hs)
    every = H.all_cv_positions(hs, det)
    lo, hi = patch_boxes(hs, every)
    ref = patch_hulls(hs, det)
    assert np.array_equal(lo, ref[0]) and np.array_equal(hi, ref[1])
    only = np.random.default_rng(3).random((hs.u.patches0, hs.v.patches0)) < 0.3
    lo, hi = patch_boxes(hs, every, only=only)
    ref = patch_hulls(hs, det, only=only)
    assert np.array_equal(lo, ref[0]) and np.array_equal(hi, ref[1])


def test_patch_hulls_bound_the_surface():
    hs = with_random_offsets(H.make_movable(wavy_sheet(), 3, [[10, 9]]), scale=0.3)
    lo, hi = patch_hulls(hs)
    rng = np.random.default_rng(2)
    u = rng.uniform(0, hs.u.patches0, 20_000)
    v = rng.uniform(0, hs.v.patches0, 20_000)
    p = H.evaluate(hs, u, v).points
    pu = np.minimum(u.astype(int), hs.u.patches0 - 1)
    pv = np.minimum(v.astype(int), hs.v.patches0 - 1)
    assert np.all(p >= lo[pu, pv] - 1e-12) and np.all(p <= hi[pu, pv] + 1e-12)


def test_boxes_within_is_the_array_form():
    """`boxes_within` keeps the boxes whose gap to some point is within its limit, each gap's
    norm rounded as numpy's: the same boxes as the (points, boxes) array of norms."""
    from acra.patch_boxes import boxes_within

    rng = np.random.default_rng(1)
    for _ in range(200):
        m, k = rng.integers(0, 60), rng.integers(1, 40)
        c, h = rng.normal(size=(m, 3)), np.abs(rng.normal(size=(m, 3))) * 0.3
        lo, hi, q = c - h, c + h, rng.normal(size=(k, 3))
        q[: k // 3] = np.clip(q[: k // 3], -0.1, 0.1)  # inside some boxes
        limit = np.abs(rng.normal(size=k)) * 0.5 * (1 + 1e-9) + 1e-300
        gap = np.linalg.norm(np.maximum(np.maximum(lo[None] - q[:, None], q[:, None] - hi[None]), 0.0), axis=2)
        assert np.array_equal(np.nonzero(boxes_within(lo, hi, q, limit))[0], np.unique(np.nonzero(gap <= limit[:, None])[1]))


def _rays_meet_numpy(lo, hi, origins, directions):
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / directions[:, None, :]
        t0, t1 = (lo[None] - origins[:, None]) * inv, (hi[None] - origins[:, None]) * inv
    t0, t1 = np.nan_to_num(t0, nan=-np.inf), np.nan_to_num(t1, nan=np.inf)
    near, far = np.minimum(t0, t1).max(axis=2), np.maximum(t0, t1).min(axis=2)
    meets = (far >= near) & (far >= 0)
    return meets.any(axis=0), meets.any(axis=1)


def test_rays_meet_is_the_array_form():
    """`rays_meet`'s slab test gives numpy's answer for the same formula, also for rays parallel
    to an axis, starting on a slab's plane or on a box's corner, and behind or inside a box."""
    from acra.patch_boxes import rays_meet

    rng = np.random.default_rng(2)
    hits = 0
    for _ in range(300):
        m, n = rng.integers(0, 50), rng.integers(0, 30)
        c = np.round(rng.normal(size=(m, 3)), 1)
        h = np.round(np.abs(rng.normal(size=(m, 3))) * 0.3, 1)  # some boxes flat along an axis
        lo, hi = c - h, c + h
        o = np.round(rng.normal(size=(n, 3)) * 2, 1)  # on many boxes' planes
        d = rng.normal(size=(n, 3))
        d[rng.random((n, 3)) < 0.3] = 0.0  # parallel to axes
        d[rng.random(n) < 0.05] = -0.0
        if m and n:
            o[0] = lo[0]  # on a corner
        box_hit, ray_hit = rays_meet(lo, hi, o, d)
        want_box, want_ray = _rays_meet_numpy(lo, hi, o, d)
        assert np.array_equal(box_hit, want_box) and np.array_equal(ray_hit, want_ray)
        hits += box_hit.sum()
    assert hits > 100  # the cases meet boxes, not only miss them



def test_rays_meet_by_blocks_is_the_array_form():
    """Many boxes in runs of `RAY_BLOCK` (a run's box tested first): the answer is the slab test
    of every pair, for boxes in a grid along rays through it, boxes whose corners are swapped,
    rays with a zero or -0.0 component, and a non-finite box, which every ray tests in full."""
    from acra.patch_boxes import RAY_BLOCK, rays_meet

    rng = np.random.default_rng(7)
    hits = misses = 0
    for trial in range(120):
        m, n = int(rng.integers(RAY_BLOCK, 40 * RAY_BLOCK)), int(rng.integers(1, 60))
        c = np.round(rng.normal(size=(m, 3)) * 3, 2)
        c[: m // 2] = np.round(np.cumsum(rng.normal(size=(m // 2, 3)) * 0.2, axis=0), 2)  # strips, as patch rows
        h = np.round(np.abs(rng.normal(size=(m, 3))) * 0.2, 2)
        lo, hi = c - h, c + h
        swap = rng.random(m) < 0.05
        lo[swap], hi[swap] = hi[swap].copy(), lo[swap].copy()
        o = np.round(rng.normal(size=(n, 3)) * 4, 2)
        o[: n // 3] = lo[rng.integers(0, m, n // 3)]  # on boxes' corners and planes
        d = rng.normal(size=(n, 3))
        d[rng.random((n, 3)) < 0.05] = 0.0
        d[rng.random(n) < 0.03] = -0.0
        if trial % 10 == 9:
            lo[rng.integers(0, m)] = (np.inf, -np.inf, np.nan)[trial // 10 % 3]
        box_hit, ray_hit = rays_meet(lo, hi, o, d)
        with np.errstate(invalid="ignore"):
            want_box, want_ray = _rays_meet_numpy(lo, hi, o, d)
        assert np.array_equal(box_hit, want_box) and np.array_equal(ray_hit, want_ray)
        hits += box_hit.sum()
        misses += (~box_hit).sum()
    assert hits > 1000 and misses > 1000  # rays meet some boxes of a run and miss others

def _mapped_boxes_numpy(centre, half, xform):
    """`pipeline.geometry.SurfaceGeometry.boxes`' array form, with its union and inner corners."""
    world = centre @ xform[:3, :3].T + xform[:3, 3]
    span = half @ np.abs(xform[:3, :3]).T
    lo, hi = world - span, world + span
    return lo, hi, np.stack([lo.min(axis=0), hi.max(axis=0)]), np.stack([lo.max(axis=0), hi.min(axis=0)])


def test_translated_boxes_are_the_array_form():
    """`translated_boxes` under a translation gives the products' boxes, their union and inner
    corners bit for bit (zeros of either sign, a zero translation, half-extents of zero); any
    other matrix, a -0.0 translation or a non-finite entry answers False."""
    from acra.patch_boxes import translated_boxes

    rng = np.random.default_rng(3)
    done = 0
    for trial in range(300):
        n = int(rng.integers(1, 90))
        centre = rng.normal(size=(n, 3)) * 10.0 ** rng.integers(-3, 4)
        half = np.abs(rng.normal(size=(n, 3))) * 0.1
        centre[rng.random((n, 3)) < 0.1] = 0.0
        centre[rng.random((n, 3)) < 0.05] = -0.0
        half[rng.random((n, 3)) < 0.1] = 0.0
        xform = np.eye(4)
        xform[:3, 3] = rng.normal(size=3) * 10.0 ** rng.integers(-3, 4)
        xform[:3, 3][rng.random(3) < 0.2] = 0.0
        kind = trial % 6
        if kind == 1:
            xform[rng.integers(0, 3), rng.integers(0, 3)] += 1e-12  # not a translation
        elif kind == 2:
            xform[rng.integers(0, 3), 3] = -0.0
        elif kind == 3:
            centre[rng.integers(0, n), rng.integers(0, 3)] = rng.choice([np.nan, np.inf])
        outs = [np.empty((n, 3)), np.empty((n, 3)), np.empty((2, 3)), np.empty((2, 3))]
        ok = translated_boxes(centre, half, xform, *outs)
        assert ok == (kind not in (1, 2, 3))
        if ok:
            for got, want in zip(outs, _mapped_boxes_numpy(centre, half, xform)):
                assert got.tobytes() == want.tobytes()
            done += 1
    assert done > 100
    assert not translated_boxes(np.zeros((0, 3)), np.zeros((0, 3)), np.eye(4), *[np.empty((0, 3))] * 2,
                                np.empty((2, 3)), np.empty((2, 3)))
