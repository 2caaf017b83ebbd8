"""acra.moves: a level's moves and the details they leave."""

import numpy as np
from conftest import with_random_offsets

from acra import hspline as H
from acra import moves as M
from acra import shapes


def test_a_move_of_rows_each_once_adds_as_np_add_at_does():
    """`move_level` with ``unique`` (rows each once, as a solve's ``cv_rows``) adds each row's
    move by one fancy-indexed addition: the same offsets, bit for bit, as `np.add.at`."""
    hs = H.make_movable(H.from_grid(*shapes.sphere(8, 7), depth=3), 2, np.array([[3, 4], [9, 2]]))
    hs = with_random_offsets(hs, scale=0.01, seed=5)
    det = H.details(hs)
    rows = np.flatnonzero(hs.level(2).movable)[::3]
    dv = np.random.default_rng(2).normal(size=(rows.size, 3)) * 1e-3
    a = M.move_level(hs, 2, rows, dv, det, True)
    b = M.move_level(hs, 2, rows, dv, det)
    np.testing.assert_array_equal(a.level(2).offsets.view(np.int64), b.level(2).offsets.view(np.int64))
    assert not np.array_equal(a.level(2).offsets, hs.level(2).offsets)
    assert a.fine[0] is hs.fine[0] and a.level(2).cv_keys is hs.level(2).cv_keys
