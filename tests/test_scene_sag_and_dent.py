"""Scene sag_and_dent: the fine dent (level 1, relax 0.6) fades fast, the coarse sag (level 0,
relax 0.1) slowly; each follows its rate to 1e-6, read from the output layer."""

import numpy as np
import pytest
from pxr import UsdGeom

from conftest import elastic_levels, scene_run
from pipeline import output_layer

SHEET = "/World/Sheet"
RELAX = np.array([0.1, 0.6])
LAST_HIT = 3


@pytest.fixture(scope="module")
def run(run_scene):
    return scene_run(run_scene, "sag_and_dent")


def _fields(out, frame):
    return elastic_levels(out, SHEET, frame)


def test_both_levels_carry_the_press(run):
    report, _, out = run
    assert [s.frame for s in report.stats if s.in_collision] == [2, LAST_HIT]
    sag, dent = _fields(out, LAST_HIT)
    # measured: 0.1997 on level 0, 0.1228 on level 1
    assert np.linalg.norm(sag, axis=1).max() > 0.15 and np.linalg.norm(dent, axis=1).max() > 0.12


def test_each_level_follows_its_rate(run):
    report, _, out = run
    sag0, dent0 = _fields(out, LAST_HIT)
    scale = max(np.abs(sag0).max(), np.abs(dent0).max())
    last = report.stats[-1].frame
    for n, f in enumerate(range(LAST_HIT + 1, last + 1), start=1):
        sag, dent = _fields(out, f)
        assert np.abs(sag - (1 - RELAX[0]) ** n * sag0).max() <= 1e-6 * scale, f
        assert np.abs(dent - (1 - RELAX[1]) ** n * dent0).max() <= 1e-6 * scale, f
    sag, dent = _fields(out, last)
    # 7 frames on: the sag keeps 0.9^7 = 0.478 of itself, the dent 0.4^7 = 0.0016
    assert np.abs(sag).max() / np.abs(sag0).max() == pytest.approx(0.9**7, rel=1e-6)
    assert np.abs(dent).max() / np.abs(dent0).max() == pytest.approx(0.4**7, rel=1e-6)


def test_the_displayed_sheet_eases_back(run):
    """The display points' distance from the animator's shrinks at every free frame, by a factor
    that tends to the sag's 0.9 once the dent has gone (measured 0.842, 0.885, ... 0.8998)."""
    report, inp, out = run
    rest = output_layer.input_points(out, SHEET)  # the animator's surface at the output's display vertices
    last = report.stats[-1].frame
    dev = [np.linalg.norm(np.asarray(UsdGeom.Mesh(out.GetPrimAtPath(SHEET)).GetPointsAttr().Get(f)) - rest, axis=1).max()
           for f in range(LAST_HIT, last + 1)]
    ratios = np.array(dev[1:]) / np.array(dev[:-1])
    assert np.all(ratios < 1.0)
    assert ratios[0] < 0.86 and ratios[-1] == pytest.approx(0.9, abs=0.001)
