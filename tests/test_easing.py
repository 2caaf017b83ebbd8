"""Distance-time functions and Blender easing presets (seed-systems.md §B)."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pipeline.animation import easing as E

ALL = [(f, m) for f in E.FAMILIES for m in ("in", "out", "in_out")]
MONOTONE = ("sine", "quad", "cubic", "quart", "quint", "expo", "circ")
# derivative kinks: the in_out join, bounce's impacts (velocity reverses), circ's vertical end
BOUNCE_KINKS = np.array([1, 2, 2.5]) / 2.75


def kinks(family, mode):
    k = [0.5] if mode == "in_out" else []
    if family == "bounce":
        b = BOUNCE_KINKS if mode == "out" else 1 - BOUNCE_KINKS
        k += list(b) if mode != "in_out" else list(b / 2) + list(0.5 + b / 2) + list((1 - b) / 2) + list(1 - (1 - b) / 2)
    return np.array(k)


@pytest.mark.parametrize("family,mode", ALL)
def test_presets_hit_zero_and_one(family, mode):
    f = E.preset(family, mode)
    assert abs(f(np.array([0.0]))[0]) < 1e-12
    assert abs(f(np.array([1.0]))[0] - 1) < 1e-12
    # and continuously: no jump next to the ends.  Penner's expo/elastic special-case the ends
    # and jump by ~1e-3 there; circ's vertical end approaches as sqrt(2 eps) ~ 1.4e-6
    eps = 1e-12
    assert abs(f(np.array([eps]))[0]) < 1e-5
    assert abs(f(np.array([1 - eps]))[0] - 1) < 1e-5


@pytest.mark.parametrize("family,mode", ALL)
def test_preset_speed_is_the_derivative(family, mode):
    f = E.preset(family, mode)
    t = np.linspace(0.01, 0.99, 197)
    k = kinks(family, mode)
    if k.size:
        t = t[np.min(np.abs(t[:, None] - k[None, :]), axis=1) > 1e-3]
    eps = 1e-7
    fd = (f(t + eps) - f(t - eps)) / (2 * eps)
    np.testing.assert_allclose(f.speed(t), fd, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("family", E.FAMILIES)
def test_out_and_in_out_are_built_from_in(family):
    t = np.linspace(0, 1, 41)
    fin, fout, fio = (E.preset(family, m) for m in ("in", "out", "in_out"))
    np.testing.assert_allclose(fout(t), 1 - fin(1 - t), atol=1e-14)
    np.testing.assert_allclose(fio(t) + fio(1 - t), 1.0, atol=1e-14)      # point symmetry
    np.testing.assert_allclose(fio(t[:20]), fin(2 * t[:20]) / 2, atol=1e-14)


@pytest.mark.parametrize("family", MONOTONE)
def test_transitional_presets_are_monotone(family):
    t = np.linspace(0, 1, 2001)
    for mode in ("in", "out", "in_out"):
        assert np.all(np.diff(E.preset(family, mode)(t)) >= -1e-15)


def test_closed_forms_of_a_few_presets():
    t = np.linspace(0, 1, 11)
    np.testing.assert_allclose(E.preset("quad", "in")(t), t**2)
    np.testing.assert_allclose(E.preset("cubic", "out")(t), 1 - (1 - t) ** 3)
    np.testing.assert_allclose(E.preset("sine", "in_out")(t), (1 - np.cos(np.pi * t)) / 2, atol=1e-15)
    np.testing.assert_allclose(E.preset("circ", "in")(t), 1 - np.sqrt(1 - t**2))
    o = 1.70158
    np.testing.assert_allclose(E.preset("back", "in")(t), t * t * ((o + 1) * t - o))
    # Penner's bounce: first arc 7.5625 t^2 up to 1/2.75, and a touch-down at 1/2.75
    b = E.preset("bounce", "out")
    np.testing.assert_allclose(b(np.array([0.2, 1 / 2.75])), [7.5625 * 0.04, 1.0])


def test_dynamic_presets_overshoot():
    t = np.linspace(0, 1, 4001)
    assert E.preset("back", "in")(t).min() < -0.09            # Penner's 10% overshoot
    assert E.preset("back", "out")(t).max() > 1.09
    assert E.preset("elastic", "out")(t).max() > 1.2
    assert E.preset("bounce", "out")(t).max() <= 1 + 1e-12     # bounces stay below the target


def test_auto_mode_follows_blender():
    t = np.linspace(0, 1, 9)
    np.testing.assert_array_equal(E.preset("quad", "auto")(t), E.preset("quad", "in")(t))
    np.testing.assert_array_equal(E.preset("bounce", "auto")(t), E.preset("bounce", "out")(t))
    np.testing.assert_array_equal(E.preset("elastic", "ease_in")(t), E.preset("elastic", "in")(t))
    with pytest.raises(ValueError):
        E.preset("wobble")
    with pytest.raises(ValueError):
        E.preset("quad", "sideways")


EASES = [E.sine_ease(), E.sine_linear_sine(0.2, 0.7), E.parabolic_ease(0.3, 0.6),
         E.velocity_keys([0, 0.5, 1], [0, 3, 0])]


@pytest.mark.parametrize("h", EASES + [E.constant_speed()], ids=lambda h: h.name)
def test_distance_time_functions_start_at_zero_end_at_one_and_are_monotone(h):
    t = np.linspace(0, 1, 2001)
    s = h(t)
    assert abs(s[0]) < 1e-15 and abs(s[-1] - 1) < 1e-12
    assert np.all(np.diff(s) >= -1e-15)
    eps = 1e-7
    tt = t[1:-1]
    np.testing.assert_allclose(h.speed(tt), (h(tt + eps) - h(tt - eps)) / (2 * eps), atol=1e-5)


@pytest.mark.parametrize("h", EASES, ids=lambda h: h.name)
def test_ease_in_ease_out_has_zero_speed_at_both_ends(h):
    assert abs(h.speed(np.array([0.0]))[0]) < 1e-12
    assert abs(h.speed(np.array([1.0]))[0]) < 1e-12
    # and the distance covered in the first instants is quadratic, not linear
    d1, d2 = h(np.array([1e-4, 2e-4]))
    assert abs(d2 / d1 - 4) < 1e-2


def test_sine_linear_sine_is_c1_with_a_constant_middle():
    k1, k2 = 0.2, 0.7
    h = E.sine_linear_sine(k1, k2)
    f = 2 * k1 / np.pi + (k2 - k1) + 2 * (1 - k2) / np.pi
    mid = np.linspace(k1, k2, 11)
    np.testing.assert_allclose(h.speed(mid), 1 / f)
    for k in (k1, k2):
        np.testing.assert_allclose(h.speed(np.array([k - 1e-9])), h.speed(np.array([k + 1e-9])), atol=1e-7)


def test_parabolic_ease_has_constant_acceleration():
    t1, t2 = 0.3, 0.6
    h = E.parabolic_ease(t1, t2)
    v0 = 2 / (1 + t2 - t1)
    a = np.linspace(0, t1, 7)
    np.testing.assert_allclose(h.speed(a), v0 * a / t1, atol=1e-14)                 # linear speed
    np.testing.assert_allclose(h(a), v0 * a**2 / (2 * t1), atol=1e-14)             # quadratic distance
    np.testing.assert_allclose(h.speed(np.linspace(t1, t2, 5)), v0)
    c = np.linspace(t2, 1, 7)
    np.testing.assert_allclose(np.diff(h.speed(c)) / np.diff(c), -v0 / (1 - t2))   # constant decel


def test_velocity_keys_scale_to_unit_area_and_keep_shape():
    times, speeds = np.array([0, 0.25, 0.8, 1.0]), np.array([0.0, 2.0, 2.0, 0.5])
    area = np.sum((speeds[:-1] + speeds[1:]) / 2 * np.diff(times))
    h = E.velocity_keys(times, speeds)
    np.testing.assert_allclose(h.speed(times), speeds / area, atol=1e-14)
    assert abs(h(np.array([1.0]))[0] - 1) < 1e-14
    # shift: the curve floats up by 1 - area
    hs = E.velocity_keys(times, speeds * 0.5, mode="shift")
    shift = 1 - area * 0.5
    np.testing.assert_allclose(hs.speed(times), speeds * 0.5 + shift, atol=1e-14)
    assert abs(hs(np.array([1.0]))[0] - 1) < 1e-14
    with pytest.raises(ValueError):
        E.velocity_keys(times, speeds * 3, mode="shift")          # would need negative speed
    with pytest.raises(ValueError):
        E.velocity_keys(times, -speeds)


@settings(max_examples=60, deadline=None)
@given(st.floats(0.01, 0.98), st.floats(0.0, 1.0), st.sampled_from(["sls", "parabolic"]))
def test_ease_functions_property(k1, frac, kind):
    k2 = k1 + frac * (0.99 - k1)
    h = E.sine_linear_sine(k1, k2) if kind == "sls" else E.parabolic_ease(k1, k2)
    t = np.linspace(0, 1, 501)
    s = h(t)
    assert abs(s[0]) < 1e-12 and abs(s[-1] - 1) < 1e-9
    assert np.all(np.diff(s) >= -1e-12)
    assert abs(h.speed(np.array([0.0]))[0]) < 1e-12 and abs(h.speed(np.array([1.0]))[0]) < 1e-9
    # mean speed is 1: the speed integrates to the unit distance
    tt = np.linspace(0, 1, 20001)
    v = h.speed(tt)
    assert abs(np.sum((v[1:] + v[:-1]) / 2) / 20000 - 1) < 1e-4


def test_clamped_outside_the_unit_interval():
    h = E.preset("cubic", "in_out")
    np.testing.assert_array_equal(h(np.array([-1.0, 2.0])), [0.0, 1.0])
    np.testing.assert_array_equal(h.speed(np.array([-1.0, 2.0])), [0.0, 0.0])
