"""turning_press (issue 17): a sheet on a turntable turns about z while a box presses it.

Moves are the animator's surface against the output layer's responded surface at the same
parameters (`conftest.surface_moves`, double precision, world space). The contact slides: the
sheet's material under the box at the first touch has turned away from it by frame 12, which
stalled the response when eq. 4.15 paired the first-touch points as they are now
(`contact.slide_since`).
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from conftest import SCENES, deepest_move, surface_moves
from scenes import turning_press as S

NAME, SHEET = "turning_press", "/World/Turntable/Sheet"
ROOT = Path(__file__).resolve().parents[1]
PATCH = 4.0 / 13.0  # level-0 patch width: 16 CVs give 13 patches over 4 units
LO, HI = np.array(S.BOX_XY) - 0.5, np.array(S.BOX_XY) + 0.5  # the 1-unit box's footprint (world xy)
REACH = (4.0 + 1.0 / 8.0) * PATCH  # B-spline support: see test_scene_off_centre_press


def test_acra_run_clears_every_frame_and_exits_0(tmp_path):
    """The command line a CI job runs: exit status 0, no frame over tolerance in the JSON report,
    every frame within the 4-round cap, the most rounds shown in the summary (measured: 1 round
    a frame; before the slide was taken out, frames 8-12 stayed over tolerance, 6.8e-3 at worst,
    after 4 rounds each)."""
    (tmp_path / f"{NAME}.py").write_bytes((SCENES / f"{NAME}.py").read_bytes())
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, "-m", "pipeline.cli", "run", f"{NAME}.py", "--report", "report.json"],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["status"] == 0 and report["over_tolerance"] == []
    rounds = [f["rounds"] for f in report["per_frame"]]
    assert max(rounds) <= 4 and all(f["residual"] <= 1e-3 for f in report["per_frame"])
    assert f"at most {max(rounds)} round" in done.stdout


def test_the_dent_goes_straight_down_under_the_box_while_the_sheet_turns(run_scene):
    """At every responded frame the deepest move is under the box (world) and every data point
    asks a move straight down: the box presses along z, the turn slides the sheet along itself
    and asks no move (pairing the first-touch points sheared the sheet sideways under the box).
    A frame of one round moves nothing sideways at all. A later round moves the coarser levels
    too, and the finer levels' detail rides on their frames (normal and tangents), so the dent
    the first round made tilts with them: at most 2 % of the deepest move sideways (measured 1.0 %
    at frame 12, its second round asked for by the display; the same second round on detection's
    residual alone tilts it by the same 2.14e-3). The dent travels across the sheet's material:
    its deepest point's parameters at the last frame are more than a patch from those at frame 8."""
    report = run_scene(NAME)
    responded = [s for s in report.stats if s.iterations]
    assert responded and responded[-1].frame == 12 and 8 in [s.frame for s in responded]
    deepest = {}
    for st in responded:
        point, deepest[st.frame], move, sideways = deepest_move(report, SHEET, st.frame)
        assert np.all(point[:2] >= LO) and np.all(point[:2] <= HI), (st.frame, point)
        assert sideways <= (1e-9 if st.iterations == 1 else 0.02) * move, (st.frame, st.iterations, sideways / move)
        start, target = st.data_points[SHEET]  # the world moves the frame's first round asked: along z to rounding
        assert np.abs((target - start)[:, :2]).max() <= 1e-12 * np.abs(target - start).max(), st.frame
    assert np.abs(deepest[12] - deepest[8]).max() > 1.0


def test_the_sheet_away_from_the_box_stays_where_the_animator_put_it(run_scene):
    """Beyond `REACH` (parameter distance) of the footprint's box in the sheet's own space the
    sheet does not move at all, at every responded frame."""
    report = run_scene(NAME)
    for frame in [s.frame for s in report.stats if s.iterations]:
        p, uv, d = surface_moves(report, SHEET, frame)
        angle = np.radians(np.interp(frame, *S.TURN))
        turn = np.array([[np.cos(angle), np.sin(angle)], [-np.sin(angle), np.cos(angle)]])  # world xy -> sheet's
        corners = np.array([[x, y] for x in (LO[0], HI[0]) for y in (LO[1], HI[1])]) @ turn.T
        lo, hi = (corners.min(axis=0) + 2.0) / PATCH, (corners.max(axis=0) + 2.0) / PATCH
        away = np.maximum(lo - uv, uv - hi).max(axis=1) * PATCH
        far = away > REACH
        assert far.mean() > 0.05
        assert np.abs(d[far]).max() == 0.0, frame
