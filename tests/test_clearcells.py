"""`acra.clearcells`: triangles proven clear of a closed mesh by a flooded grid of cells."""

import numpy as np

from acra import depthbound
from acra import hspline as H
from acra import shapes
from acra.clearcells import clear_of
from acra.tessellate import grid_samples, run_topology
from pipeline import residual


def _ball_display():
    """A closed unit ball's display (`residual.Shown`), in its object space."""
    ball = H.from_grid(*shapes.sphere(10, 8))
    topo = run_topology([ball], 4)
    return residual.shown("/ball", grid_samples(ball, topo)[0], topo.triangles(), np.eye(4), None, closed=True, outward=1.0)


def test_triangles_clear_of_a_solid_are_those_outside_by_more_than_their_covering_radius():
    """`clear_of` on a closed ball's display: a triangle far outside is clear; one outside
    but nearer the surface than its covering radius, one crossing the surface and one deep
    inside (no face near it: its cells are not joined to the outside) are kept, and the faces
    chosen hold every face whose box comes within the reach of a kept triangle's."""
    b = _ball_display()
    r = float(b.box[1, 2])  # the ball's top
    tri = np.array([[0.0, 0.0, 0.0], [0.02, 0.0, 0.0], [0.0, 0.02, 0.0]])  # rho 0.01 (right-angled)
    cases = {"far": tri + [0.0, 0.0, r + 0.3], "near": tri + [0.0, 0.0, r + 0.005], "across": tri * 5 + [0.0, 0.0, r - 0.02]}
    corners = np.stack(list(cases.values()))
    rho = depthbound.covering_radii(corners)
    keep, chosen, reach = clear_of(b.local, b.triangles, corners, rho, 0.0, 0.05, b.box_local)
    assert dict(zip(cases, keep.tolist())) == {"far": False, "near": True, "across": True}
    deep = np.concatenate([corners, tri[None]])  # the ball's centre: kept, and deeper than a part near it reaches
    assert clear_of(b.local, b.triangles, deep, depthbound.covering_radii(deep), 0.0, 0.05, b.box_local) is None
    assert reach >= 0.05
    box_lo, box_hi = corners[keep].min(axis=1), corners[keep].max(axis=1)
    tri_b = b.local[b.triangles]
    near = np.zeros(len(tri_b), bool)
    for lo, hi in zip(box_lo, box_hi):
        near |= np.all((tri_b.min(axis=1) <= hi + reach) & (tri_b.max(axis=1) >= lo - reach), axis=1)
    assert np.isin(np.nonzero(near)[0], chosen).all() and len(chosen) < len(tri_b)
