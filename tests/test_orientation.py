"""`acra.orientation`: the sign of a grid's enclosed volume, compiled, against the array form."""

import numpy as np

from acra.orientation import volume_sign


def _array_form(pts, tris, centre):
    a, b, c = (pts[tris[:, i]] - centre for i in range(3))
    return 1 if np.einsum("ij,ij->i", a, np.cross(b, c)).sum() >= 0 else -1


def test_volume_sign_is_the_array_forms_where_sure():
    """Closed bumpy spheres either way round, far from the origin, and grids whose volume is
    (nearly) zero: a sure answer is the array form's sign; flat and empty grids are not sure."""
    rng = np.random.default_rng(5)
    sure = 0
    for trial in range(200):
        n = int(rng.integers(3, 20))
        u, v = np.meshgrid(np.linspace(0, 2 * np.pi, n + 1), np.linspace(0, np.pi, n + 1), indexing="ij")
        r = 1 + 0.3 * rng.normal(size=u.shape)
        pts = np.stack([r * np.cos(u) * np.sin(v), r * np.sin(u) * np.sin(v), r * np.cos(v)], -1).reshape(-1, 3)
        pts = pts * rng.choice([1e-3, 1.0, 1e3]) + rng.normal(size=3) * rng.choice([0.0, 1e3])
        q = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
        tris = np.concatenate([np.stack([q[:-1, :-1], q[1:, :-1], q[1:, 1:]], -1).reshape(-1, 3),
                               np.stack([q[:-1, :-1], q[1:, 1:], q[:-1, 1:]], -1).reshape(-1, 3)])
        if trial % 2:
            tris = tris[:, ::-1]
        if trial % 5 == 0:  # the grid and its mirror: volume about zero
            tris = np.concatenate([tris, tris[:, ::-1]])
        if trial % 7 == 0:
            pts[:, 2] = 0.0
        centre = pts.mean(axis=0)
        got = volume_sign(pts, tris, centre)
        if got:
            sure += 1
            assert got == _array_form(pts, tris, centre), trial
        if trial % 7 == 0:
            assert got == 0
    assert sure > 100
    assert volume_sign(np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(3)) == 0
