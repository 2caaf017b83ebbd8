"""The compiled evaluator (`acra.kernels`, behind `hspline.evaluate`) against the array form
(`hspline._evaluate_numpy`): the same sum on random multi-level surfaces, open and closed, at
random parameters, on knots and at the domain's ends, for every derivative order and side; and
the compiled frames (`acra.framekernels`) against theirs, bit for bit."""

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from acra import details as D
from acra import hspline as H
from acra import framekernels, kernels, shapes
from conftest import wavy_sheet, with_random_offsets

FIELDS = ("points", "du", "dv", "duu", "duv", "dvv")


def _surface(kind: str, depth: int, seed: int) -> H.HSpline:
    """A ``kind`` surface of ``depth`` levels: on each fine level a random block of patches made
    movable (so coarser levels are refined under it), sometimes one refined without movable CVs
    (a level the evaluator skips), then random offsets on every movable CV."""
    rng = np.random.default_rng(seed)
    if kind == "sheet":
        hs = wavy_sheet(nu=7, nv=8, depth=depth, seed=seed)
    elif kind == "sphere":  # periodic in u, poles at both ends of v
        hs = H.from_grid(*shapes.sphere(8, 7), depth=depth)
    elif kind == "torus":  # periodic both ways
        hs = H.from_grid(*shapes.torus(7, 6), depth=depth)
    else:  # open in v: a tube
        hs = H.from_grid(*shapes.tube(6, 7), depth=depth)
    for k in range(1, depth):
        n = hs.u.patches(k), hs.v.patches(k)
        size = rng.integers(1, 4, 2)
        corner = rng.integers(-2, n, 2)  # across a periodic seam or an open border too
        block = np.stack(np.meshgrid(corner[0] + np.arange(size[0]), corner[1] + np.arange(size[1]), indexing="ij"), -1).reshape(-1, 2)
        if rng.random() < 0.2:
            hs = H.refine(hs, k, block)  # active patches, no movable CV
        else:
            block = block[(block >= 0).all(1) & (block < n).all(1)]
            hs = H.make_movable(hs, k, block) if block.size else hs
    return with_random_offsets(hs, scale=0.1, seed=seed + 1)


def _parameters(hs: H.HSpline, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``4 n + 4`` parameter pairs: a knot of a random level along u and a random parameter
    (over a little more than the domain) along v, the other way round, knots both ways, points
    in random active patches of random levels (on a knot of the next level in a third of the
    cases), and the domain's four corners."""
    free, knots = [], []
    for d in (hs.u, hs.v):
        p0 = d.patches0
        free.append(rng.uniform(-0.25 * p0, 1.25 * p0, n))
        k = rng.integers(0, hs.depth, n)
        knots.append(rng.integers(0, (p0 << k) + 1) / np.ldexp(1.0, k))  # the domain's ends among them
    fine = [lev for lev in hs.fine if lev.patches.size]
    if fine:
        lev = [fine[i] for i in rng.integers(0, len(fine), n)]
        key = np.array([lv.patches[rng.integers(0, lv.patches.size)] for lv in lev])
        k = np.array([lv.k for lv in lev])
        pu, pv = np.divmod(key, hs.v.patches0 << k)
        t = rng.uniform(0, 1, (2, n))
        t = np.where(rng.random((2, n)) < 1 / 3, rng.integers(0, 3, (2, n)) / 2.0, t)
        inside = [(pu + t[0]) / np.ldexp(1.0, k), (pv + t[1]) / np.ldexp(1.0, k)]
    else:
        inside = free
    pu, pv = float(hs.u.patches0), float(hs.v.patches0)
    u = np.concatenate([knots[0], free[0], knots[0], inside[0], [0.0, 0.0, pu, pu]])
    v = np.concatenate([free[1], knots[1], knots[1], inside[1], [0.0, pv, 0.0, pv]])
    return u, v


def _assert_same(hs, u, v, order, det, upto, side):
    fast = H.evaluate(hs, u, v, order=order, det=det, upto=upto, side=side)
    ref = H._evaluate_numpy(hs, u, v, order=order, det=det, upto=upto, side=side)
    size = hs.size()
    for name in FIELDS[: kernels.NSLOTS[order]]:
        a, b = getattr(fast, name), getattr(ref, name)
        assert a.shape == b.shape == (u.size, 3), name
        err = np.abs(a - b).max(initial=0.0)
        assert err <= 1e-12 * size, f"{name}: {err:.3e} of size {size:.3e}"
    for name in FIELDS[kernels.NSLOTS[order]:]:
        assert getattr(fast, name) is None


@settings(max_examples=200, deadline=None, derandomize=True)
@given(
    kind=st.sampled_from(["sheet", "sphere", "torus", "tube"]),
    depth=st.integers(1, 5),
    seed=st.integers(0, 2**16),
    order=st.integers(0, 2),
    side=st.sampled_from([0, -1]),
    upto=st.one_of(st.none(), st.integers(0, 4)),
    det_kind=st.sampled_from(["computed", "given", "rough"]),
)
def test_kernel_equals_the_array_form(kind, depth, seed, order, side, upto, det_kind):
    """``rough``: random detail vectors on every CV, movable or not, so the sum jumps across
    the borders of active patches and a point on a knot there takes the side ``side`` picks."""
    hs = _surface(kind, depth, seed)
    rng = np.random.default_rng(seed + 2)
    u, v = _parameters(hs, 40, rng)
    if det_kind == "computed" or hs.depth == 1:
        det = None
    elif det_kind == "given":
        det = D.details(hs)
    else:
        det = D.Details(tuple(rng.normal(size=(lev.cv_keys.size, 3)) for lev in hs.fine), ())
    _assert_same(hs, u, v, order, det, upto, side)


@pytest.mark.parametrize("n", [1, 2, 50])
@pytest.mark.parametrize("kind", ["sheet", "sphere", "torus", "tube"])
def test_small_calls_and_strided_parameters(kind, n):
    """Calls of a point or a few (numpy's single-row route in the array form) and parameters
    taken as a column of an ``(m, 2)`` array."""
    hs = _surface(kind, 4, 11)
    det = D.details(hs)
    uv = np.stack(_parameters(hs, 30, np.random.default_rng(3)), axis=1)[:n]
    for order in (0, 1, 2):
        for side in (0, -1):
            _assert_same(hs, uv[:, 0], uv[:, 1], order, det, None, side)


def test_the_demo_head_display():
    """The shape of the display case (7 levels, periodic u): a sphere with detail on a spot."""
    hs = H.from_grid(*shapes.sphere(16, 14), depth=7)
    rng = np.random.default_rng(0)
    for k, c in ((2, 18), (4, 74), (6, 300)):
        hs = H.make_movable(hs, k, np.array([[c, c], [c + 1, c + 1]]))
    hs = with_random_offsets(hs, scale=0.01, seed=4)
    det = D.details(hs)
    u = np.repeat(np.linspace(0, 16, 161), 3)
    v = np.tile(np.linspace(0, 11, 3 * 161) % 11, 1)[: u.size]
    for order in (0, 1, 2):
        _assert_same(hs, u, v, order, det, None, 0)
        _assert_same(hs, rng.uniform(0, 16, 500), rng.uniform(0, 11, 500), order, det, None, -1)


def _bits(ev, order):
    return [getattr(ev, name).view(np.int64) for name in FIELDS[: kernels.NSLOTS[order]]]


@pytest.mark.parametrize("kind", ["sheet", "sphere", "torus", "tube"])
def test_points_sharing_v_equal_each_point_evaluated_alone(kind):
    """A point on the v and block of the point before reuses its v contraction
    (`kernels.eval_points`): a display's lattice taken by v, then u (runs of one v across patches
    and levels, knots of every level, the domain's ends, -0.0 beside 0.0, v one ulp apart), gives
    the bits of each point evaluated in a call of its own, where nothing is reused."""
    hs = _surface(kind, 5, 7)
    det = D.details(hs)
    rng = np.random.default_rng(1)
    us = np.concatenate([np.arange(0, 16 * hs.u.patches0 + 1) / 16.0, rng.uniform(0, hs.u.patches0, 20)])
    vs = np.concatenate([np.arange(0, 16 * hs.v.patches0 + 1, 3) / 16.0, rng.uniform(0, hs.v.patches0, 6),
                         [-0.0, 0.0, -0.0, np.nextafter(1.0, 0.0), 1.0, np.nextafter(1.0, 2.0)]])
    v, u = (x.reshape(-1) for x in np.meshgrid(vs, us, indexing="ij"))  # by v, then u
    u = np.concatenate([u, np.repeat(us[:40], 2)])  # then u runs whose v alternates in sign of zero
    v = np.concatenate([v, np.tile([0.0, -0.0], 40)])
    for order in (0, 1, 2):
        for side in (0, -1):
            whole = _bits(H.evaluate(hs, u, v, order=order, det=det, side=side), order)
            for i in range(0, u.size, 7):
                alone = _bits(H.evaluate(hs, u[i:i + 1], v[i:i + 1], order=order, det=det, side=side), order)
                for w, a in zip(whole, alone):
                    assert np.array_equal(w[i], a[0]), (order, side, u[i], v[i])


def test_non_finite_parameters_give_nan_and_bad_arguments_raise():
    hs = _surface("sphere", 3, 5)  # periodic u, open v
    ev = H.evaluate(hs, [np.nan, 1.0, np.inf, 1.0, 1.0], [1.0, np.nan, 1.0, np.inf, -np.inf], order=1)
    assert np.isnan(ev.points[:3]).all() and np.isnan(ev.du[:3]).all()
    # an infinite open parameter is clamped to the domain's end, as np.clip does
    np.testing.assert_array_equal(ev.points[3:], H.evaluate(hs, [1.0, 1.0], [hs.v.patches0, 0.0], order=1).points)
    with pytest.raises(ValueError):
        H.evaluate(hs, [1.0], [1.0], order=3)
    with pytest.raises(ValueError):
        H.evaluate(hs, [1.0, 2.0], [1.0])
    with pytest.raises(ValueError):
        H.evaluate(hs, [1.0], [1.0], upto=-1)


def test_a_detail_table_too_short_raises():
    """Details of fewer levels than are evaluated: the kernel refuses rather than read past the
    table; with ``upto`` at the levels the details cover it agrees with the array form."""
    hs = with_random_offsets(H.make_movable(wavy_sheet(depth=4), 3, [[10, 9], [11, 9]]))
    short = D.details(hs, upto=2)
    with pytest.raises(ValueError, match="detail table"):
        H.evaluate(hs, [1.5], [1.5], det=short)
    u, v = _parameters(hs, 40, np.random.default_rng(1))
    _assert_same(hs, u, v, 1, short, 2, 0)


def test_one_compiled_signature_serves_every_call():
    """Lists, float32, strided, scalar and read-only parameters, read-only CVs, numpy integer
    arguments: all reach the kernel as the one signature, so no call compiles again."""
    hs = _surface("torus", 3, 2)
    det = D.details(hs)
    H.evaluate(hs, np.zeros(3), np.zeros(3), det=det)
    before = len(kernels.eval_points.signatures)
    uv = np.random.default_rng(0).uniform(0, 5, (20, 2))
    H.evaluate(hs, list(uv[:, 0]), list(uv[:, 1]), det=det)
    H.evaluate(hs, uv[:, 0].astype(np.float32), uv[:, 1], order=np.int64(1), det=det)
    H.evaluate(hs, uv[::2, 0], uv[::2, 1], order=2, side=np.int64(-1), upto=np.int64(2), det=det)
    H.evaluate(hs, 0.5, 0.25)
    ro = uv.copy()
    ro.setflags(write=False)
    cvs = hs.cvs.copy()
    cvs.setflags(write=False)
    H.evaluate(replace(hs, cvs=cvs), ro[:, 0], ro[:, 1], order=1, det=det)
    assert len(kernels.eval_points.signatures) == before


# --------------------------------------------------------------------------------------------
# the compiled frames (`acra.framekernels`, behind `hspline._degenerate`, `surface_normals`, `_frames`)


def _tangents(rng, m):
    """Tangent pairs of every kind a surface gives: general, tiny or huge, a vanishing ``du``
    (a pole), parallel ``du`` and ``dv`` (a collapsed edge), both zero, ``dv`` along z (the
    fallback normal), and NaN rows."""
    du = rng.normal(size=(m, 3)) * 10.0 ** rng.uniform(-8, 2, (m, 1))
    dv = rng.normal(size=(m, 3)) * 10.0 ** rng.uniform(-8, 2, (m, 1))
    k = rng.integers(0, m, m // 5)
    du[k] = 0.0
    k = rng.integers(0, m, m // 7)
    dv[k] = du[k] * rng.uniform(-2, 2)
    k = rng.integers(0, m, m // 9)
    du[k] = dv[k] = 0.0
    k = rng.integers(0, m, m // 9)
    du[k], dv[k] = 0.0, [0.0, 0.0, 1.5]
    k = rng.integers(0, m, m // 20)
    du[k, 1] = np.nan
    return du, dv


@pytest.mark.parametrize("seed", range(20))
def test_compiled_frames_equal_the_array_form(seed):
    rng = np.random.default_rng(seed)
    m = int(rng.integers(1, 400))
    du, dv = _tangents(rng, m)
    ev = H.SurfaceEval(points=du, du=du, dv=dv)
    scale = float(10.0 ** rng.uniform(-3, 3))
    n, bad = H._degenerate(ev, scale)
    n_ref, bad_ref = H._degenerate_numpy(ev, scale)
    np.testing.assert_array_equal(n, n_ref)
    np.testing.assert_array_equal(bad, bad_ref)
    n[bad] = (0.0, 0.0, 1.0)
    with np.errstate(invalid="ignore"):
        unit_ref = n / np.linalg.norm(n, axis=1)[:, None]
        unit = np.empty(n.shape)
        framekernels.unit_rows(n, unit)  # surface_normals' last step
        np.testing.assert_array_equal(unit, unit_ref)
        np.testing.assert_array_equal(H._frames(ev, unit_ref), H._frames_numpy(ev, unit_ref))


def test_frames_of_a_sphere_with_poles_equal_the_array_form():
    """Every level's frames of a refined sphere (poles at both ends of v), through `details`."""
    hs = H.from_grid(*shapes.sphere(8, 7), depth=4)
    for k in (1, 2, 3):
        hs = H.refine(hs, k, H.pole_patches(hs, k, 1, 0))
        hs = H.make_movable(hs, k, np.array([[1, 1], [2, 2]]))
    hs = with_random_offsets(hs, scale=0.01, seed=3)
    det = D.details(hs)
    for k in range(1, hs.depth):
        rows = np.nonzero(hs.level(k).movable)[0]
        gu, gv = H.cv_uv(hs, k, hs.level(k).cv_keys[rows])
        ev, n = H.surface_normals(hs, gu, gv, det=det, upto=k - 1)
        np.testing.assert_array_equal(H._frames(ev, n), H._frames_numpy(ev, n))


def test_frames_in_one_pass_equal_normals_and_frames():
    """`framekernels.frames_at` (behind `acra.details._frames_at`: normal and frame of each CV in one
    pass after its evaluation) gives the bits of `surface_normals` and `_frames` one after
    another, a pole ring's CVs with their end's one normal; a degenerate row off the rings is
    left to `surface_normals` (the kernel reports it and writes no frame)."""
    hs = H.from_grid(*shapes.sphere(8, 7), depth=4)
    for k in (1, 2, 3):
        hs = H.refine(hs, k, H.pole_patches(hs, k, 1, 0))
        hs = H.make_movable(hs, k, np.array([[1, 1], [2, 2]]))
    hs = with_random_offsets(hs, scale=0.01, seed=3)
    det = D.details(hs)
    ends = H.closed_ends(hs)
    for k in range(1, hs.depth):
        rows, ring, gu, gv, _ = D._movable_places(hs, k, hs.level(k), ends)
        assert (ring >= 0).any() and (ring < 0).any()
        partial = D.Details(det.vectors[:k - 1], det.frames[:k - 1])
        ev, n = H.surface_normals(hs, gu, gv, det=partial, upto=k - 1)
        for i, (axis, end) in enumerate(ends):
            n[ring == i] = D._end_normal(hs, k, axis, end, partial)
        want = H._frames(ev, n)
        got = D._frames_at(hs, k, ends, partial, ring, gu, gv)
        np.testing.assert_array_equal(got.view(np.int64), want.view(np.int64))
        np.testing.assert_array_equal(got.view(np.int64), det.frames[k - 1][rows].view(np.int64))
    # a point on a pole, not on a ring: its du x dv vanishes, so the kernel leaves it
    ev = H.evaluate(hs, np.array([0.5, 1.3]), np.array([0.0, 2.2]), order=1, upto=0)
    s = hs.size()
    out = np.full((2, 3, 3), 7.0)
    assert framekernels.frames_at(ev.du, ev.dv, 1e-6 * s, 1e-12 * s**2, np.zeros(2, bool), np.zeros((2, 3)), out) == 1
    assert (out == 7.0).all()
    fixed = np.array([[0.0, 0.0, -1.0], [0, 0, 0]])
    assert framekernels.frames_at(ev.du, ev.dv, 1e-6 * s, 1e-12 * s**2, np.array([True, False]), fixed, out) == 0
    n = H.surface_normals(hs, np.array([1.3]), np.array([2.2]), upto=0)[1]
    np.testing.assert_array_equal(out, H._frames(ev, np.concatenate([fixed[:1], n])))


def _limit_normals(hs, u, v, top, det, unit):
    e2 = H.evaluate(hs, u, v, order=2, det=det, upto=top)
    c, scale = max(hs.size(), 1e-300), hs.size()
    return framekernels.limit_normals(u, v, e2.du, e2.dv, e2.duu, e2.duv, e2.dvv, 1e-6 * c, 1e-12 * c**2,
                                      1e-9 * scale**2, hs.u.patches0, hs.v.patches0, hs.u.periodic, hs.v.periodic, unit)


def test_compiled_limit_normals_equal_surface_normals():
    """`framekernels.limit_normals` (behind `acra.details._end_normal`, on a second-order evaluation)
    gives `surface_normals`' bits
    at the poles of a refined sphere, where every ``du × dv`` vanishes and the normal is the
    first-order term toward the patch centre, and off them; a point that needs nudging (a grid
    collapsed to one point) is reported and nothing is written."""
    hs = H.from_grid(*shapes.sphere(8, 7), depth=3)
    for k in (1, 2):
        hs = H.refine(hs, k, H.pole_patches(hs, k, 1, 0))
    hs = with_random_offsets(hs, scale=0.01, seed=5)
    det = D.details(hs)
    rng = np.random.default_rng(0)
    for top in (0, 1, 2):
        u = np.concatenate([np.arange(16) / 2.0, rng.uniform(0, 8, 9)])
        v = np.concatenate([np.zeros(8), np.full(8, float(hs.v.patches0)), rng.uniform(0, hs.v.patches0, 9)])
        unit = np.empty((u.size, 3))
        assert _limit_normals(hs, u, v, top, det, unit) == 0
        want = H.surface_normals(hs, u, v, det=det, upto=top)[1]
        np.testing.assert_array_equal(unit.view(np.int64), want.view(np.int64))
    flat = H.from_grid(np.zeros((6, 6, 3)), depth=1)
    unit = np.full((2, 3), 7.0)
    assert _limit_normals(flat, np.array([0.5, 1.5]), np.array([0.5, 2.0]), 0, None, unit) == 2
    assert (unit == 7.0).all()


@pytest.mark.parametrize("seed", range(12))
def test_compiled_ring_sums_equal_the_array_form(seed):
    """`framekernels.ring_sums` (behind `respond._ring_sums`): the column sums and their spread
    are numpy's ``np.where(ok, D, 0)``, ``D0 + 4 D1 + D2`` and ``np.ptp(sums, axis=0).max()``,
    bit for bit, with absent CVs, values of every size and NaN."""
    rng = np.random.default_rng(seed)
    c, n = int(rng.integers(1, 300)), int(rng.integers(1, 200))
    vectors = rng.normal(size=(c, 3)) * 10.0 ** rng.uniform(-12, 2, (c, 1))
    if seed % 3 == 0:
        vectors[rng.integers(0, c, 2), rng.integers(0, 3)] = np.nan
    if seed % 4 == 1:  # a closed ring: every column the same sum
        vectors[:] = 0.0
    rows = rng.integers(0, c, (n, 3))
    ok = rng.random((n, 3)) < (1.0 if seed % 2 else 0.7)
    rows.flags.writeable = ok.flags.writeable = False  # as `respond._ring_rows` keeps them
    sums = np.empty((n, 3))
    spread = framekernels.ring_sums(vectors, rows, ok, sums)
    ref = np.where(ok[..., None], vectors[rows], 0.0)
    ref = ref[:, 0] + 4.0 * ref[:, 1] + ref[:, 2]
    np.testing.assert_array_equal(sums, ref)
    want = np.ptp(ref, axis=0).max()
    assert (np.isnan(spread) and np.isnan(want)) or np.float64(spread).tobytes() == want.tobytes()


# the compiled marking of `hspline.changed_cells` (`acra.kernels.mark_cells`)


@pytest.mark.parametrize("seed", range(4))
def test_marked_cells_equal_numpy_index_assignment(seed):
    """`mark_cells` sets the cells numpy's wrapped or clipped index assignment sets, for levels
    coarser and finer than the cells', CV supports (spread 3) and patches alone (spread 0)."""
    rng = np.random.default_rng(seed)
    p0u, p0v, level = 6, 5, 2
    for k in range(4):
        for spread in (0, 3):
            for u_periodic in (False, True):
                for v_periodic in (False, True):
                    nu_k, nv_k = p0u << k, p0v << k
                    pu = rng.integers(0, nu_k + spread, 7).astype(np.int64)
                    pv = rng.integers(0, nv_k + spread, 7).astype(np.int64)
                    want = np.zeros((p0u << level, p0v << level), bool)
                    d = np.arange(spread + 1)
                    qu = pu[:, None] - spread + d
                    qv = pv[:, None] - spread + d
                    qu = np.mod(qu, nu_k) if u_periodic else np.clip(qu, 0, nu_k - 1)
                    qv = np.mod(qv, nv_k) if v_periodic else np.clip(qv, 0, nv_k - 1)
                    qu, qv = (x.reshape(-1) for x in np.broadcast_arrays(qu[:, :, None], qv[:, None, :]))
                    if k >= level:
                        want[qu >> (k - level), qv >> (k - level)] = True
                    else:
                        r = 1 << (level - k)
                        s = np.arange(r)
                        want[(qu[:, None] * r + s)[:, :, None], (qv[:, None] * r + s)[:, None, :]] = True
                    got = np.zeros_like(want)
                    kernels.mark_cells(got, pu, pv, k, level, spread, nu_k, nv_k, u_periodic, v_periodic)
                    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("seed", range(4))
def test_normals_of_tangent_rows_equal_degenerate_and_unit_rows(seed):
    """`kernels.place_normals` marks the rows `framekernels.degenerate` marks and gives every
    other row `unit_rows`' bits, on tangents of every kind (vanishing, parallel, NaN)."""
    rng = np.random.default_rng(seed)
    du, dv = _tangents(rng, 400)
    c1, c2 = 1e-6 * 3.0, 1e-12 * 9.0
    n, bad = np.empty((400, 3)), np.empty(400, bool)
    framekernels.degenerate(du, dv, c1, c2, n, bad)
    want = np.empty((int((~bad).sum()), 3))
    framekernels.unit_rows(n[~bad], want)
    got, flagged = _placed(du, dv, c1, c2)
    assert flagged.sum() == bad.sum() > 0
    np.testing.assert_array_equal(flagged, bad)
    np.testing.assert_array_equal(got[~bad].view(np.int64), want.view(np.int64))


@pytest.mark.parametrize("c1, c2", [(3e-6, 9e-12), (1e-6, 1e-120), (1e-6, 0.0), (1e-300, 1e-300), (1e-165, 1e-162), (1e150, 1e200)])
def test_normals_of_tangent_rows_about_the_test_equal_degenerate(c1, c2):
    """Rows whose ``|du × dv|`` lies about ``c1 max(|du|, |dv|) + c2`` (from half to twice it,
    and within a few ulps of it): `kernels.place_normals`' one-root path for rows far above
    it gives the flags and bits of `framekernels.degenerate` and `unit_rows` on each, with a
    ``c2`` whose square underflows and bounds whose squares overflow."""
    rng = np.random.default_rng(5)
    m = 2000
    du = rng.normal(size=(m, 3)) * 10.0 ** rng.uniform(-3, 3, (m, 1))
    e = rng.normal(size=(m, 3))
    w = np.cross(du, e)
    w /= np.linalg.norm(w, axis=1, keepdims=True)  # a unit vector normal to du
    dv = du * rng.uniform(-2, 2, (m, 1))  # parallel to du, then tilted off it by w
    longest = np.maximum(np.linalg.norm(du, axis=1), np.linalg.norm(dv, axis=1))
    bound = c1 * longest + c2
    ratio = np.where(rng.random(m) < 0.5, rng.uniform(0.5, 2.0, m), 1.0 + rng.integers(-8, 9, m) * 2.0**-52)
    # |du × (dv + h w)| = h |du| for w normal to du; |dv| changes by at most h, well under bound
    h = ratio * bound / np.linalg.norm(du, axis=1)
    dv = dv + h[:, None] * w
    with np.errstate(over="ignore", invalid="ignore"):
        n, bad = np.empty((m, 3)), np.empty(m, bool)
        framekernels.degenerate(du, dv, c1, c2, n, bad)
        want = np.empty((int((~bad).sum()), 3))
        framekernels.unit_rows(n[~bad], want)
    with np.errstate(over="ignore", invalid="ignore"):
        got, flagged = _placed(du, dv, c1, c2)
    np.testing.assert_array_equal(flagged, bad)
    np.testing.assert_array_equal(got[~bad].view(np.int64), want.view(np.int64))
    assert 0 < bad.sum() < m or c2 >= 1e200


@pytest.mark.parametrize("seed", range(3))
def test_placed_normals_equal_degenerate_and_numpy_s_row_assignment(seed):
    """`kernels.place_normals` (an evaluation's points and unit normals written into a display's
    rows in one pass) gives ``points[rows] = p`` and, on the rows with a direction,
    ``limit[rows] = n`` of `framekernels.degenerate` and `unit_rows`, bit for bit, the same rows
    flagged and the same count; a flagged row's ``limit`` is left as it was."""
    rng = np.random.default_rng(seed)
    m, n = 400, 700
    du, dv = _tangents(rng, m)
    p = rng.normal(size=(m, 3))
    rows = rng.permutation(n)[:m]
    c1, c2 = 1e-6 * 3.0, 1e-12 * 9.0
    cross, want_bad = np.empty((m, 3)), np.empty(m, bool)
    framekernels.degenerate(du, dv, c1, c2, cross, want_bad)
    want_n = np.empty((int((~want_bad).sum()), 3))
    framekernels.unit_rows(cross[~want_bad], want_n)
    want_points, want_limit = np.full((n, 3), np.nan), np.full((n, 3), np.nan)
    want_points[rows] = p
    want_limit[rows[~want_bad]] = want_n
    points, limit, bad = np.full((n, 3), np.nan), np.full((n, 3), np.nan), np.empty(m, bool)
    assert kernels.place_normals(p, du, dv, rows, c1, c2, points, limit, bad) == want_bad.sum() > 0
    np.testing.assert_array_equal(bad, want_bad)
    np.testing.assert_array_equal(points.view(np.int64), want_points.view(np.int64))
    np.testing.assert_array_equal(limit.view(np.int64), want_limit.view(np.int64))


def _placed(du: np.ndarray, dv: np.ndarray, c1: float, c2: float) -> tuple[np.ndarray, np.ndarray]:
    """`kernels.place_normals` of ``du, dv (m, 3)`` into rows ``0..m-1``: the normals ``(m, 3)``
    (rows without a direction NaN) and the flags ``(m,) bool``."""
    m = len(du)
    limit, bad = np.full((m, 3), np.nan), np.empty(m, bool)
    kernels.place_normals(np.zeros((m, 3)), du, dv, np.arange(m), c1, c2, np.empty((m, 3)), limit, bad)
    return limit, bad


@pytest.mark.parametrize("kind", ["sheet", "sphere", "torus", "tube"])
def test_compiled_movable_places_equal_the_array_form(kind):
    """`levelkernels.movable_places` (behind `acra.details._movable_places`: each movable CV's row,
    Greville centre and level-0 patch) gives the array form's integers and bits on every level,
    across periodic seams and open borders (where a centre's patch is clamped)."""
    from acra import levelkernels

    for seed in range(3):
        hs = _surface(kind, 4, seed)
        ends = H.closed_ends(hs)
        for k in range(1, hs.depth):
            lev = hs.level(k)
            D._PLACES.clear()
            got = D._movable_places(hs, k, lev, ends)
            want = D._movable_places_numpy(hs, k, lev, ends)
            for a, b in zip(got, want):
                assert a.dtype == b.dtype
                np.testing.assert_array_equal(np.asarray(a).view(np.int64), np.asarray(b).view(np.int64))
            rows, _, ju, jv = levelkernels.movable_places(lev.cv_keys, lev.movable, k, hs.u.cvs(k), hs.v.cvs(k),
                                                          hs.u.patches0, hs.u.periodic, hs.v.patches0, hs.v.periodic,
                                                          D._ends_array(ends))[:4]
            np.testing.assert_array_equal(ju * hs.v.cvs(k) + jv, lev.cv_keys[rows])
    D._PLACES.clear()


@pytest.mark.parametrize("seed", range(6))
def test_compiled_unique_inverse_equals_numpy_unique(seed):
    """`levelkernels.unique_inverse` (behind `interpolate.point_weights`' columns and
    `patch_groups`) gives `np.unique`'s sorted values and inverse, duplicates and an
    empty array included."""
    from acra import levelkernels

    rng = np.random.default_rng(seed)
    for n in (0, 1, 7, 300):
        x = rng.integers(0, max(n // 3, 1) + 5 * seed, n).astype(np.int64)
        uniq, inv = levelkernels.unique_inverse(x)
        want_uniq, want_inv = np.unique(x, return_inverse=True)
        np.testing.assert_array_equal(uniq, want_uniq)
        np.testing.assert_array_equal(inv, want_inv)
        assert uniq.dtype == inv.dtype == np.int64


@pytest.mark.parametrize("span", [1, 200, 5000, 10**9])
def test_unique_inverse_marks_a_narrow_span_and_sorts_a_wide_one(span):
    """`levelkernels.unique_inverse` numbers values within a few times their count of each other
    by marking their span (a pole's thousands of entries on two hundred rows) and sorts the rest
    (far-flung keys, the least int64 of a NaN parameter's patch); both are `np.unique`'s."""
    from acra import levelkernels

    rng = np.random.default_rng(span)
    for n in (1, 40, 4096):
        x = (rng.integers(0, span, n) - span // 2).astype(np.int64)
        if n > 1:
            x[n // 2] = np.iinfo(np.int64).min if span > 5000 else x[0]
        uniq, inv = levelkernels.unique_inverse(x)
        want_uniq, want_inv = np.unique(x, return_inverse=True)
        np.testing.assert_array_equal(uniq, want_uniq)
        np.testing.assert_array_equal(inv, want_inv)
