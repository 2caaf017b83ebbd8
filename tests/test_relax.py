"""acra.relax: offset fields, release per level, plasticity (the equations of its docstring)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from acra import hspline as H
from acra import relax
from conftest import wavy_sheet, with_random_offsets


def refined(seed: int, depth: int = 3) -> H.HSpline:
    """A wavy sheet with random refined regions on every fine level and random offsets there."""
    rng = np.random.default_rng(seed)
    hs = wavy_sheet(depth=depth, seed=seed)
    for k in range(1, depth):
        n = hs.u.patches(k), hs.v.patches(k)
        hs = H.make_movable(hs, k, np.stack([rng.integers(0, n[0], 2), rng.integers(0, n[1], 2)], axis=1))
    return with_random_offsets(hs, seed=seed + 1)


def coefficients(hs: H.HSpline, like: H.HSpline) -> list[np.ndarray]:
    """Every level's coefficients of ``hs`` on the union structure with ``like``."""
    a, _ = relax.aligned(hs, like)
    return [a.cvs] + [lev.offsets for lev in a.fine]


def assert_same_surface(a: H.HSpline, b: H.HSpline, tol: float = 1e-12) -> None:
    for x, y in zip(coefficients(a, b), coefficients(b, a)):
        np.testing.assert_allclose(x, y, rtol=0, atol=tol)
    u, v = np.meshgrid(np.linspace(0, a.domain[0], 9), np.linspace(0, a.domain[1], 9))
    pa = H.evaluate(a, u.ravel(), v.ravel()).points
    pb = H.evaluate(b, u.ravel(), v.ravel()).points
    np.testing.assert_allclose(pa, pb, rtol=0, atol=10 * tol)


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 10_000), st.integers(0, 10_000))
def test_difference_then_added_gives_back_the_surface(s1, s2):
    """``before ⊕ (after ⊖ before) = after`` on different refined structures (a response only
    refines, but the fields must not depend on that)."""
    before, after = refined(s1), refined(s2)
    after = H.HSpline(after.cvs, before.u, before.v, before.depth, after.fine)
    assert_same_surface(relax.added(before, relax.difference(after, before)), after)


def test_aligned_keeps_both_surfaces_and_shares_rows():
    a, b = refined(3), refined(4)
    a2, b2 = relax.aligned(a, b)
    for k in range(1, a.depth):
        np.testing.assert_array_equal(a2.level(k).cv_keys, b2.level(k).cv_keys)
        assert set(a.level(k).patches) | set(b.level(k).patches) == set(a2.level(k).patches)
    assert_same_surface(a2, a, 0.0)
    assert_same_surface(b2, b, 0.0)


def test_scaled_multiplies_each_level_by_its_factor():
    f = relax.difference(refined(5), relax.zero_field(refined(5)))
    g = relax.scaled(f, [2.0, 0.5, 0.0])
    np.testing.assert_array_equal(g.cvs, 2.0 * f.cvs)
    np.testing.assert_array_equal(g.level(1).offsets, 0.5 * f.level(1).offsets)
    assert not np.any(g.level(2).offsets)
    np.testing.assert_array_equal(relax.level_magnitudes(g)[:2], [2.0, 0.5] * relax.level_magnitudes(f)[:2])


def test_nothing_carried_starts_from_the_animators_surface_itself():
    a = refined(6)
    z = relax.zero_field(a)
    s, released = relax.begin(a, relax.Carried(z, z), np.full(a.depth, 0.3))
    assert s is a and relax.is_zero(released.elastic) and relax.is_zero(released.plastic)


@pytest.mark.parametrize("p", [0.0, 0.5, 1.0])
def test_a_response_is_split_into_plastic_and_elastic_parts(p):
    """After a response ``R``: ``P = p ΔV``, ``E = (1 - p) ΔV`` and ``R = A ⊕ P ⊕ E``."""
    a = refined(7)
    z = relax.zero_field(a)
    s, released = relax.begin(a, relax.Carried(z, z), np.ones(a.depth))
    r = H.HSpline(refined(8).cvs, a.u, a.v, a.depth, refined(8).fine)
    c = relax.absorb(released, s, r, np.full(a.depth, p))
    dv = relax.difference(r, s)
    assert_same_surface(c.plastic, relax.scaled(dv, np.full(a.depth, p)))
    assert_same_surface(c.elastic, relax.scaled(dv, np.full(a.depth, 1 - p)))
    assert_same_surface(relax.added(a, c.plastic, c.elastic), r)


def test_free_frames_release_each_level_geometrically():
    """Without a response, level ``l`` keeps ``(1 - r_l)^n`` of its elastic field after ``n``
    frames, and the plastic field stays as it is."""
    a = refined(9)
    e = relax.difference(refined(10), relax.zero_field(a))
    p = relax.difference(refined(11), relax.zero_field(a))
    rates = np.array([0.1, 0.5, 0.9])
    carried = relax.Carried(e, p)
    for n in range(1, 6):
        s, released = relax.begin(a, carried, rates)
        carried = relax.absorb(released, s, s, np.full(3, 0.5))
        want = relax.scaled(e, (1 - rates) ** n)
        assert_same_surface(carried.elastic, want, 1e-15)
        assert carried.plastic is p
        assert_same_surface(s, relax.added(a, p, want), 1e-12)


def test_collisions_stack():
    """Two responses in a row carry the sum of both offsets (p = 0, nothing released)."""
    a = refined(12)
    z = relax.zero_field(a)
    keep = np.zeros(a.depth)
    s1, rel = relax.begin(a, relax.Carried(z, z), keep)
    r1 = relax.added(s1, relax.scaled(relax.difference(refined(13), a), [0.1, 0.1, 0.1]))
    c1 = relax.absorb(rel, s1, r1, keep)
    s2, rel = relax.begin(a, c1, keep)
    assert_same_surface(s2, r1)
    r2 = relax.added(s2, relax.scaled(relax.difference(refined(14), a), [0.1, 0.1, 0.1]))
    c2 = relax.absorb(rel, s2, r2, keep)
    assert_same_surface(relax.added(a, c2.elastic), r2)


@settings(max_examples=5, deadline=None)
@given(st.integers(0, 10_000))
def test_the_output_is_always_the_animators_surface_plus_both_fields(seed):
    """Over random frames (animator surfaces, rates, plasticity, responses or none): ``R_f = A_f ⊕
    P_f ⊕ E_f``, and the plastic field only ever grows by ``p ΔV``."""
    rng = np.random.default_rng(seed)
    base = refined(seed)
    z = relax.zero_field(base)
    carried = relax.Carried(z, z)
    p = rng.uniform(0, 1, base.depth)
    for f in range(4):
        animator = H.HSpline(base.cvs + 0.1 * rng.normal(size=base.cvs.shape), base.u, base.v, base.depth, base.fine)
        s, released = relax.begin(animator, carried, rng.uniform(0, 1, base.depth))
        if rng.uniform() < 0.6:
            move = relax.difference(refined(seed + 100 + f), relax.zero_field(base))
            r = relax.added(s, relax.scaled(move, rng.uniform(0, 0.2, base.depth)))
        else:
            r = s
        new = relax.absorb(released, s, r, p)
        assert_same_surface(relax.added(animator, new.plastic, new.elastic), r, 1e-11)
        assert_same_surface(new.plastic, relax.added(carried.plastic, relax.scaled(relax.difference(r, s), p)), 1e-12)
        carried = new
