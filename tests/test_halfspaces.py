"""`acra.halfspaces`: a point's greatest height over planes (`heights`) and which points lie
within them (`within`, also tested through `acra.nearest` in tests/test_nearest.py)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from acra import halfspaces

_BOX = np.array([[1.0, 0.0, 0.0, -1.0], [-1.0, 0.0, 0.0, -1.0], [0.0, 1.0, 0.0, -2.0],
                 [0.0, -1.0, 0.0, -2.0], [0.0, 0.0, 1.0, -3.0], [0.0, 0.0, -1.0, -3.0]])  # |x| <= 1, |y| <= 2, |z| <= 3


def test_heights_over_a_box_are_the_exact_distances():
    """Inside the box ``-heights`` is the distance to its nearest side; outside beside one side
    the distance to it; no rows give ``-inf``; NaN stays NaN."""
    q = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.0, -2.5], [3.0, 0.0, 0.0], [0.0, -2.25, 1.0],
                  [np.nan, 0.0, 0.0]])
    h = halfspaces.heights(_BOX, q)
    np.testing.assert_array_equal(h[:5], [-1.0, -0.5, -0.5, 2.0, 0.25])
    assert np.isnan(h[5])
    np.testing.assert_array_equal(halfspaces.heights(np.zeros((0, 4)), q[:2]), [-np.inf, -np.inf])
    nan_row = np.concatenate([_BOX[:2], [[np.nan, 0.0, 0.0, 0.0]], _BOX[2:]])  # a NaN row before finite ones
    assert np.isnan(halfspaces.heights(nan_row, q[:2])).all()
    assert halfspaces.heights(_BOX, np.zeros((0, 3))).shape == (0,)


@settings(max_examples=60, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 20), st.just(4)), elements=st.floats(-10, 10) | st.just(np.nan)),
       arrays(np.float64, st.tuples(st.integers(0, 30), st.just(3)), elements=st.floats(-100, 100)))
def test_heights_are_the_row_maximum_and_agree_with_within(equations, q):
    """`heights` is the maximum over the rows of each value summed term by term, and a point is
    `within` at slack ``s`` exactly when its height is at most ``s``."""
    values = ((equations[None, :, 0] * q[:, None, 0] + equations[None, :, 1] * q[:, None, 1])
              + equations[None, :, 2] * q[:, None, 2]) + equations[None, :, 3]
    h = halfspaces.heights(equations, q)
    np.testing.assert_array_equal(h, values.max(axis=1) if len(q) else np.zeros(0))
    for slack in (0.0, 0.5, -1.0):
        np.testing.assert_array_equal(halfspaces.within(equations, q, slack), h <= slack)
