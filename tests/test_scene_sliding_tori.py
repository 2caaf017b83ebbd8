"""sliding_tori (issue 17): two soft tori of equal rigidity slide into each other and apart.

Moves are each torus's animator surface against the output layer's responded surface at the
same parameters (`conftest.surface_moves`, double precision, world space).
"""

import numpy as np
import pytest

from conftest import surface_moves

NAME, LEFT, RIGHT = "sliding_tori", "/World/Left", "/World/Slider/Right"
MAJOR, MINOR = 1.0, 0.35


def _overlapping(report) -> dict:
    """``{frame: (stats, overlap)}`` of the responded frames where the tubes overlap by more than
    a tenth of the tube's radius along the line between the centres (read from the run's
    transforms): frames 4-9; there the deepest contact is on that line. At the first graze, frame
    3 (0.018 on the line), the B-spline tubes, which are not exact circles between their CVs,
    meet off it (deepest move at y = -0.083, z = 0.22)."""
    out = {}
    for st in report.stats:
        overlap = 2 * (MAJOR + MINOR) - (st.xforms[RIGHT][0, 3] - st.xforms[LEFT][0, 3])
        if st.iterations and overlap > 0.1 * MINOR:
            out[st.frame] = st, overlap
    return out


def test_each_torus_takes_half_of_the_overlap(run_scene):
    """Equal rigidities: eq. 4.15 puts the common point half way, so where the tubes overlap the
    two tori's largest moves are equal (measured within 1e-3) and each is half the overlap: at
    the deepest key, frame 6, 2 (MAJOR + MINOR) - 2.45 = 0.25, each moves 0.125 (measured to 1e-4)."""
    report = run_scene(NAME)
    frames = _overlapping(report)
    assert 6 in frames and len(frames) >= 5
    for frame, (_, overlap) in frames.items():
        left, right = (np.linalg.norm(surface_moves(report, p, frame)[2], axis=1).max() for p in (LEFT, RIGHT))
        assert left == pytest.approx(right, rel=2e-3), frame
        assert left + right == pytest.approx(overlap, rel=0.05), frame
    assert frames[6][1] == pytest.approx(0.25, abs=1e-12)


def test_each_torus_is_dented_where_the_other_one_is_and_nowhere_else(run_scene):
    """Each deepest move is on the tube's side facing the other torus, along the line between
    the centres; the side facing away (more than 160 degrees round the major circle from the
    other torus) does not move at all. The B-spline support bounds it: a torus's points inside
    the other lie within 35.4 degrees of that line (cos = 1.1 / 1.35 at the deepest overlap), and
    a level-0 CV moves the surface at most 4 patches (120 degrees) from a data point."""
    report = run_scene(NAME)
    for frame, (st, _) in _overlapping(report).items():
        for path, facing in ((LEFT, 1.0), (RIGHT, -1.0)):
            p, _, d = surface_moves(report, path, frame)
            rel = p[:, :2] - st.xforms[path][:2, 3]
            move = np.linalg.norm(d, axis=1)
            k = int(np.argmax(move))
            assert facing * rel[k, 0] > MAJOR and abs(rel[k, 1]) < 0.1 * MINOR, (path, frame, p[k])
            angle = np.degrees(np.arccos(np.clip(facing * rel[:, 0] / np.linalg.norm(rel, axis=1), -1.0, 1.0)))
            assert np.count_nonzero(angle > 160.0) > 100
            assert move[angle > 160.0].max() == 0.0, (path, frame)
