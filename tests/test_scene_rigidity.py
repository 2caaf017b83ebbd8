"""Scenes rigid_floor and rigid_top (thesis Fig. 5.3 against 5.4): the softer object takes the dent.

Eq. 4.15: ``R = R1 / (R1 + R2)`` and both surfaces move to ``P' = R P1 + (1 − R) P2``, so object
1 moves ``1 − R = R2 / (R1 + R2)`` of the contact gap ``|P1 − P2|`` and object 2 ``R1 / (R1 + R2)``:
their displacements are in the ratio ``R2 : R1``, and they add up to the gap.
"""

import numpy as np
import pytest
from pxr import Usd

from conftest import surface_moves

FLOOR, PILLOW = "/World/Floor", "/World/Mover/Pillow"
STEPS = 16  # grid steps per level-0 patch edge: 4 samples per patch of level 2, the finest that absorbs


def _deepest(report):
    """The frame whose contact points are farthest apart (the deepest overlap), and that gap."""
    gaps = {s.frame: np.linalg.norm(s.contacts[0][0] - s.contacts[0][1]) for s in report.stats if s.in_collision}
    frame = max(gaps, key=gaps.get)
    return frame, float(gaps[frame])


def _max_move(report, path, frame) -> float:
    """Largest move of the response at ``frame`` over a fixed grid of `STEPS` steps per level-0
    patch (`conftest.surface_moves`: the animator's surface against the output's response at the
    same parameters), the same points in both scenes whatever each run's display refines."""
    return float(np.linalg.norm(surface_moves(report, path, frame, STEPS)[2], axis=1).max())


def _measure(report):
    """Rigidities, the deepest frame's gap and each object's largest move: dicts by path."""
    inp = Usd.Stage.Open(str(report.stage_path))
    frame, gap = _deepest(report)
    rig = {p: float(inp.GetPrimAtPath(p).GetAttribute("acra:rigidity").Get()) for p in (FLOOR, PILLOW)}
    moves = {p: _max_move(report, p, frame) for p in (FLOOR, PILLOW)}
    return rig, gap, moves


@pytest.mark.parametrize("name,soft", [("rigid_floor", PILLOW), ("rigid_top", FLOOR)])
def test_displacements_are_in_the_inverse_ratio_of_the_rigidities(run_scene, name, soft):
    report = run_scene(name)
    assert sum(s.in_collision for s in report.stats) >= 5, "the pillow should press over several frames"
    rig, gap, moves = _measure(report)
    stiff = FLOOR if soft == PILLOW else PILLOW
    assert rig[soft] < rig[stiff]
    # eq. 4.15: each object moves the other's rigidity share of the gap
    expected = rig[stiff] / rig[soft]  # 10 with rigidities 10 and 1
    measured = moves[soft] / moves[stiff]
    # measured on the grid 10.42 (rigid_floor) and 9.59 (rigid_top): a round stops once the
    # overlap is below 1e-3 of the pillow's size, and a round that clears what the display still
    # shows inside moves only the side whose display is over
    assert measured == pytest.approx(expected, rel=0.1), (name, moves, expected)
    # both surfaces meet at P': the moves add up to the gap (measured 1.037 and 1.003 of it)
    assert moves[soft] + moves[stiff] == pytest.approx(gap, rel=0.05), (name, moves, gap)
    # the soft object moves its share R_stiff / (R_soft + R_stiff) = 10/11 of the gap (measured
    # 1.041 and 0.999 of that)
    assert moves[soft] == pytest.approx(gap * rig[stiff] / (rig[soft] + rig[stiff]), rel=0.05)


def test_swapping_the_rigidities_swaps_the_dent(run_scene):
    """The two scenes differ only in the swapped rigidities; the dent changes object, not size."""
    rig_f, gap_f, moves_f = _measure(run_scene("rigid_floor"))
    rig_t, gap_t, moves_t = _measure(run_scene("rigid_top"))
    assert (rig_f[FLOOR], rig_f[PILLOW]) == (rig_t[PILLOW], rig_t[FLOOR])
    assert gap_f == pytest.approx(gap_t, rel=1e-6)  # the same input motion
    # floor over pillow: 1/10.42 in rigid_floor, 9.59 in rigid_top; product 1 within 10% (0.920)
    ratio_f = moves_f[FLOOR] / moves_f[PILLOW]
    ratio_t = moves_t[FLOOR] / moves_t[PILLOW]
    assert ratio_f < 0.2 and ratio_t > 5.0
    assert ratio_f * ratio_t == pytest.approx(1.0, rel=0.1)
    # the soft object's dent is the same size whichever object is soft (measured 0.0939 and 0.0901)
    assert moves_f[PILLOW] == pytest.approx(moves_t[FLOOR], rel=0.05)
