"""off_centre_press (issue 17): a box presses a soft sheet near one corner.

Moves are the animator's surface against the output layer's responded surface at the same
parameters (`conftest.surface_moves`, double precision). The sheet is flat and uniform, so a
world ``(x, y)`` on it is the parameter ``((x, y) + 2) / PATCH``.
"""

import numpy as np

from conftest import deepest_move, surface_moves
from scenes import off_centre_press as S

NAME, SHEET = "off_centre_press", "/World/Sheet"
PATCH = 4.0 / 9.0  # level-0 patch width: 12 CVs give 9 patches over 4 units
HALF = S.BOX_SIZE / 2.0
LO, HI = np.array(S.BOX_XY) - HALF, np.array(S.BOX_XY) + HALF  # the box's footprint (world xy)
# a level-0 CV moves only if a data point lies in its support (4 x 4 patches) and moves the surface
# only there: nothing moves farther than 4 level-0 patches from a data point; data points lie in
# the footprint or one detection step (1/8 patch) outside it (`rim.rim_points`)
REACH = (4.0 + 1.0 / 8.0) * PATCH


def _underside(frame: int) -> float:
    """World z of the box's underside at ``frame`` (linear keys)."""
    return float(np.interp(frame, S.BOX_Z[0], S.BOX_Z[1])) - HALF


def test_the_sheet_is_dented_straight_down_under_the_box(run_scene):
    """At every responded frame the deepest move is under the box and straight down (the push is
    the box face's way: no move along the sheet, 1e-19 measured), and once the box stands 0.25
    below the sheet (frames 9-12) the dent reaches it (measured 1.034 times its depth)."""
    report = run_scene(NAME)
    responded = [s.frame for s in report.stats if s.iterations]
    assert responded and responded[-1] == 12
    for frame in responded:
        point, _, move, sideways = deepest_move(report, SHEET, frame)
        assert np.all(point[:2] >= LO) and np.all(point[:2] <= HI), (frame, point)
        assert sideways <= 1e-9 * move, frame
        if frame >= 9:
            depth = -_underside(frame)
            assert depth - 1e-3 * 4.0 * np.sqrt(2.0) <= move <= 1.05 * depth, (frame, move)


def test_the_far_side_of_the_sheet_stays_where_the_animator_put_it(run_scene):
    """Beyond `REACH` of the box's footprint (parameter distance along either axis) the sheet does
    not move at all: an L along the two far edges, a third of the sheet."""
    report = run_scene(NAME)
    for frame in [s.frame for s in report.stats if s.iterations]:
        p, _, d = surface_moves(report, SHEET, frame)
        away = np.maximum(LO - p[:, :2], p[:, :2] - HI).max(axis=1)  # Chebyshev distance to the footprint
        far = away > REACH
        assert far.mean() > 0.3
        assert np.abs(d[far]).max() == 0.0, frame
