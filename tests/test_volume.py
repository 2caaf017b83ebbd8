"""acra.volume: the display mesh's volume, its gradient, and the bulge that restores it."""

from decimal import Decimal, localcontext

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from acra import hspline as H
from acra import shapes, volume
from acra.tessellate import display_topology


def ball(samples=4, depth=2, radii=(1.0, 1.0, 1.0)):
    cvs, up, vp = shapes.sphere(8, 8, radii=radii)
    hs = H.from_grid(cvs, up, vp, depth=depth)
    return hs, display_topology(hs.u, hs.v, samples)


def mesh_volume(hs, topo):
    return volume.enclosed_volume(H.evaluate(hs, topo.u, topo.v).points, volume.triangles(topo))


def test_volume_of_a_box_is_exact():
    """A unit cube as a 2x2x... quad mesh: the divergence theorem gives its volume exactly."""
    p = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 2.0) for z in (0.0, 3.0)])
    quads = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]])
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    assert volume.enclosed_volume(p, tris) == pytest.approx(6.0, abs=1e-15)
    assert volume.enclosed_volume(p + [5.0, -3.0, 2.0], tris) == pytest.approx(6.0, abs=1e-12)


def test_sphere_volume_is_positive_and_scales_with_the_cube_of_the_radius():
    hs, topo = ball()
    v = mesh_volume(hs, topo)
    assert v > 0
    big = H.HSpline(2.0 * hs.cvs, hs.u, hs.v, hs.depth, hs.fine)
    assert mesh_volume(big, topo) == pytest.approx(8.0 * v, rel=1e-12)


def _volume_exact(p, tris):
    """Eq. of `volume.enclosed_volume` in 50-digit decimals over points ``p`` (list of 3-tuples
    of `Decimal`)."""
    total = Decimal(0)
    for i, j, k in tris:
        (ax, ay, az), (bx, by, bz), (cx, cy, cz) = p[i], p[j], p[k]
        total += ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
    return total / 6


def _area_exact(p, tris):
    """Eq. of `volume.surface_area` in 50-digit decimals over points ``p``."""
    total = Decimal(0)
    for i, j, k in tris:
        a, b, c = p[i], p[j], p[k]
        u = [b[m] - a[m] for m in range(3)]
        w = [c[m] - a[m] for m in range(3)]
        n = (u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0])
        total += (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt()
    return total / 2


def _assert_gradient(exact, gradient, pts, tris, rng):
    """``gradient`` along a random direction ``d`` equals the central difference of the measure
    to 1e-9 (at most 1e-12 measured over 56 seeds of each test). The difference is taken in
    50-digit decimals over the float inputs converted exactly (``Decimal(float)``): in float64 its rounding, eps * measure / h, exceeds the bound wherever the
    directional derivative is small against the measure itself; here the truncation, h^2 times
    the third derivative, and the rounding, 1e-50 / h, are both far below the bound."""
    d = rng.normal(size=pts.shape)
    with localcontext() as ctx:
        ctx.prec = 50
        h = Decimal("1e-12")
        p = [tuple(Decimal(float(x)) for x in row) for row in pts]
        dd = [tuple(Decimal(float(x)) for x in row) for row in d]
        plus = [tuple(a + h * b for a, b in zip(r, s)) for r, s in zip(p, dd)]
        minus = [tuple(a - h * b for a, b in zip(r, s)) for r, s in zip(p, dd)]
        fd = float((exact(plus, tris) - exact(minus, tris)) / (2 * h))
    assert np.einsum("ij,ij->", gradient(pts, tris), d) == pytest.approx(fd, rel=1e-9)


@settings(max_examples=10, deadline=None, derandomize=True)
@given(st.integers(0, 10_000))
@example(6402)  # a small directional derivative (-5.2e-4 against a volume of about 4)
def test_gradient_matches_finite_differences(seed):
    rng = np.random.default_rng(seed)
    hs, topo = ball()
    pts = H.evaluate(hs, topo.u, topo.v).points + 0.05 * rng.normal(size=(topo.u.size, 3))
    _assert_gradient(_volume_exact, volume.volume_gradient, pts, volume.triangles(topo), rng)


@pytest.mark.parametrize("level", [0, 1])
def test_bulge_restores_the_volume_and_leaves_the_dent(level):
    """A squashed ball gets its volume back to 1e-4 in a few Newton steps; samples weighted 0 (the
    dent) move by less than 1e-3 of what the bulge moves elsewhere."""
    hs, topo = ball()
    if level:
        hs = H.make_movable(hs, 1, np.argwhere(np.ones((hs.u.patches(1), hs.v.patches(1)), bool)))
    target = mesh_volume(hs, topo)
    dented = H.HSpline(hs.cvs * [1.0, 1.0, 0.8], hs.u, hs.v, hs.depth, hs.fine)
    pts = H.evaluate(dented, topo.u, topo.v).points
    dent = pts[:, 2] > 0.5
    w = volume.bulge_weights(pts, dent, 0.5)
    out, v = volume.bulge(dented, topo, target, level, w)
    assert v == pytest.approx(target, rel=1e-4)
    assert mesh_volume(out, topo) == v
    moved = np.linalg.norm(H.evaluate(out, topo.u, topo.v).points - pts, axis=1)
    assert moved[~dent].max() > 0.01
    if level == 0:  # a level-0 CV's support is wide: the dent moves, but less than the bulge
        assert moved[dent].max() < moved[~dent].max()


def test_weights_are_zero_on_the_dent_and_fall_off_with_distance():
    pts = np.array([[0.0, 0, 0], [0.5, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    w = volume.bulge_weights(pts, np.array([True, False, False, False]), 1.0)
    np.testing.assert_allclose(w, [0.0, np.exp(-0.25), np.exp(-1.0), np.exp(-4.0)], rtol=1e-15)
    np.testing.assert_array_equal(volume.bulge_weights(pts, np.zeros(4, bool), 1.0), np.ones(4))


@settings(max_examples=10, deadline=None, derandomize=True)
@given(st.integers(0, 10_000))
@example(444)  # a small directional derivative (4.66e-4 against an area of about 9)
def test_area_gradient_matches_finite_differences(seed):
    rng = np.random.default_rng(seed)
    cvs, up, vp = shapes.sheet(6, 6, width=3.0, depth=3.0, height=0.2 * rng.normal(size=(6, 6)))
    hs = H.from_grid(cvs, up, vp)
    topo = display_topology(hs.u, hs.v, 3)
    pts = H.evaluate(hs, topo.u, topo.v).points
    _assert_gradient(_area_exact, volume.area_gradient, pts, volume.triangles(topo), rng)


def test_area_of_a_flat_sheet_is_exact_and_a_bulge_restores_a_stretched_one():
    cvs, up, vp = shapes.sheet(7, 7, width=4.0, depth=4.0)
    hs = H.from_grid(cvs, up, vp)
    topo = display_topology(hs.u, hs.v, 4)
    pts = H.evaluate(hs, topo.u, topo.v).points
    area = volume.surface_area(pts, volume.triangles(topo))
    span = np.ptp(pts[:, :2], axis=0)
    assert area == pytest.approx(span[0] * span[1], rel=1e-12)
    cvs = hs.cvs.copy()
    cvs[3, 3, 2] -= 1.0  # the middle CV pushed down: a dent that stretches the sheet
    dented = H.HSpline(cvs, hs.u, hs.v, hs.depth, hs.fine)
    dpts = H.evaluate(dented, topo.u, topo.v).points
    dent = np.linalg.norm(dpts - pts, axis=1) > 1e-3
    assert volume.surface_area(dpts, volume.triangles(topo)) > 1.015 * area  # measured 1.019
    out, got = volume.bulge(dented, topo, area, 0, volume.bulge_weights(dpts, dent, 2.0), measure="area")
    assert got == pytest.approx(area, rel=1e-4)


def test_encloses():
    assert volume.encloses(ball()[0])
    assert not volume.encloses(H.from_grid(*shapes.sheet(5, 5)))
    assert volume.encloses(H.from_grid(*shapes.torus(8, 6)))
