"""`acra.sides.behind`, the compiled side test after a closest-point search, held bit for bit to
its array form (`GridSet.nearest`, `hspline.surface_normals`, numpy's einsum) through
`pipeline.queries.signed`."""

import numpy as np
import pytest

from acra import hspline as H
from acra import shapes, sides
from pipeline import queries
from pipeline import shape as S
from pipeline.grids import Nearest


def _reference(shape: S.Shape, q: np.ndarray) -> tuple[np.ndarray, Nearest]:
    """`queries.signed` as array operations: the search's `Nearest`, every closest point's normal
    from `hspline.surface_normals`, the side by ``np.einsum``."""
    inside = np.zeros(len(q), bool)
    cand, qc, patches = queries._candidates(shape, q, shape.cv_hull)
    if not len(qc):
        return inside, queries._no_points()
    near = shape.cache.gridset(tuple(patches.tolist())).nearest(qc)
    _, n = H.surface_normals(shape.surface, near.uv[:, 0], near.uv[:, 1], det=shape.details)
    side = np.flatnonzero(shape.outward * np.einsum("ij,ij->i", qc - near.points, n) < 0)
    inside[cand[side]] = True
    return inside, Nearest(near.distance[side], near.points[side], near.uv[side])


def _ball() -> S.Shape:
    """A sphere with two poles and a level of detail (so the normals read the details)."""
    hs = H.from_grid(*shapes.sphere(10, 15), depth=3)
    return S.Shape(hs)


def _torus() -> S.Shape:
    return S.Shape(H.from_grid(*shapes.torus(12, 8), depth=2))


def _queries(shape: S.Shape, rng: np.random.Generator) -> np.ndarray:
    """Points near the surface (on both sides), far inside and beyond it, at patch borders
    (integer parameters) and over the poles of a sphere: ``(k, 3) float64``."""
    hs = shape.surface
    pu, pv = hs.u.patches0, hs.v.patches0
    u = np.concatenate([rng.uniform(0, pu, 200), rng.integers(0, pu + 1, 60).astype(float), rng.uniform(0, pu, 40)])
    v = np.concatenate([rng.uniform(0, pv, 200), rng.uniform(0, pv, 60), rng.integers(0, pv + 1, 40).astype(float)])
    ev, n = H.surface_normals(hs, u, v, det=shape.details)
    size = hs.size()
    off = size * rng.choice([-0.2, -0.01, -1e-4, 1e-4, 0.01, 0.2], len(u))[:, None]
    near = ev.points + off * n
    centre = hs.cvs.reshape(-1, 3).mean(axis=0)
    far = centre + size * rng.uniform(-0.6, 0.6, (80, 3))
    axis = centre + np.outer(np.linspace(-0.7, 0.7, 15), [0.0, 0.0, size])  # along a sphere's poles' axis
    return np.concatenate([near, far, axis, ev.points[:20]])


@pytest.mark.parametrize("make", [_ball, _torus])
def test_signed_is_its_array_form_bit_for_bit(make):
    rng = np.random.default_rng(7)
    shape = make()
    q = _queries(shape, rng)
    inside, near = queries.signed(shape, q)
    want, want_near = _reference(shape, q)
    assert 0 < inside.sum() < len(q)
    np.testing.assert_array_equal(inside, want)
    for a, b in ((near.distance, want_near.distance), (near.points, want_near.points), (near.uv, want_near.uv)):
        assert a.shape == b.shape and a.tobytes() == b.tobytes()


def test_a_closest_point_on_a_pole_takes_surface_normals_limit(monkeypatch):
    shape = _ball()
    hs = shape.surface
    centre = hs.cvs.reshape(-1, 3).mean(axis=0)
    top = H.evaluate(hs, np.array([0.5, 3.25]), np.full(2, float(hs.v.patches0))).points
    # on the pole (its closest point is the pole, distance about 1e-17), and under it, whose closest
    # point lies on the pole's fan of triangles, where the normal has a direction
    q = np.array([top[0], top[1], centre + 0.9 * (top[0] - centre)])
    rows = []
    normals = H.surface_normals
    monkeypatch.setattr(H, "surface_normals", lambda *a, **k: rows.append(len(a[1])) or normals(*a, **k))
    inside, near = queries.signed(shape, q)
    assert rows == [2]  # the two on the pole: du x dv has no direction there
    np.testing.assert_array_equal(inside, [False, False, True])
    monkeypatch.setattr(H, "surface_normals", normals)
    want, want_near = _reference(shape, q)
    np.testing.assert_array_equal(inside, want)
    assert near.points.tobytes() == want_near.points.tobytes() and near.uv.tobytes() == want_near.uv.tobytes()


def test_behind_flags_and_parameters_are_the_array_forms():
    rng = np.random.default_rng(3)
    shape = _torus()
    q = _queries(shape, rng)
    _, qc, patches = queries._candidates(shape, q, shape.cv_hull)
    grid = shape.cache.gridset(tuple(patches.tolist()))
    dist, close, face = grid.closest(qc)
    uv, flag = sides.behind(grid.points, grid.uv, grid.triangles, grid.face_lo, grid.face_hi, face, close, qc,
                            shape.outward, shape.surface.size(), shape.eval_args)
    assert uv.tobytes() == grid.nearest(qc).uv.tobytes()
    _, n = H.surface_normals(shape.surface, uv[:, 0], uv[:, 1], det=shape.details)
    dot = np.einsum("ij,ij->i", qc - close, n)
    assert not (flag < 0).any()  # a torus has no pole
    np.testing.assert_array_equal(flag == 1, shape.outward * dot < 0)
    assert flag.dtype == np.int8 and set(np.unique(flag)) == {0, 1}


def test_behind_of_no_points():
    shape = _torus()
    grid = shape.cache.gridset((0,))
    uv, flag = sides.behind(grid.points, grid.uv, grid.triangles, grid.face_lo, grid.face_hi, np.zeros(0, np.int64),
                            np.zeros((0, 3)), np.zeros((0, 3)), 1.0, 1.0, shape.eval_args)
    assert uv.shape == (0, 2) and flag.shape == (0,)
