"""dog_head_spike (thesis Fig. 5.1–5.2): the benchmark scene's model sizes and the look of its response."""

import numpy as np
import pytest

from acra import hspline as H
from pipeline import geometry
from pipeline import snapshot as S

CONTACT = np.array([0.1, 0.8, 0.08])  # where the spike's tip meets the cheek (world)


def test_models_match_the_thesis_sizes():
    import runpy

    from conftest import SCENES

    ns = runpy.run_path(str(SCENES / "dog_head_spike.py"))
    _, head = ns["head"]()
    _, spike = ns["spike"]()
    assert head.depth == 7 and 1800 <= H.storage_size(head) <= 2600  # thesis: 7 levels, 2085 CVs
    assert all(lev.cv_keys.size for lev in head.fine)  # detail on every level, modelled locally
    assert H.storage_size(head) < 0.01 * (16 * 2**6) * (9 * 2**6 + 3)  # vs a dense level 6
    assert spike.depth == 3 and H.storage_size(spike) == 89  # thesis: 3 levels, 90 CVs


@pytest.fixture(scope="module")
def dog(run_scene):
    return run_scene("dog_head_spike")


def test_thirty_frames_about_four_in_collision(dog):
    hit = [s.frame for s in dog.stats if s.in_collision]
    assert len(dog.stats) == 30 and 4 <= len(hit) <= 5 and hit == list(range(hit[0], hit[0] + len(hit)))


def test_the_soft_head_takes_the_dent_and_it_stays_local(dog):
    from pxr import Usd

    output = Usd.Stage.Open(str(dog.output))
    for s in dog.stats:
        meshes = {m.path: m for m in S.world_meshes(output, s.frame)}
        head, spike = meshes["/World/Head"], meshes["/World/Jab/Spike"]
        far = np.linalg.norm(head.points - CONTACT, axis=1) > 0.5
        assert head.moved[far].max() < 1e-6  # float32 storage only: the dent is local
        if not s.in_collision:
            assert head.moved.max() < 1e-6 and spike.moved.max() < 1e-6
        else:
            # rigidity 10 against 80: eq. 4.15 moves the first-touch points 8/9 and 1/9 of the gap
            (h0, h1), (s0, s1) = (s.data_points[p] for p in ("/World/Head", "/World/Jab/Spike"))
            assert np.linalg.norm(h1[0] - h0[0]) == pytest.approx(8.0 * np.linalg.norm(s1[0] - s0[0]), rel=1e-9)
            if head.moved.max() > 0.01:
                # later rounds add the spike's own eq. 4.16 points (cast back out of the head) each
                # round, so over a 3-round frame its largest move grows: measured 4.9-6.3x
                assert head.moved.max() > 4.5 * spike.moved.max()


def test_a_frame_stops_at_the_first_round_whose_display_is_within_the_tolerance(dog):
    """Between two closed deformables a round is judged by what the user sees, both displays
    inside the other object (contract: residual penetration is on the output surface). Frames
    14-16's first response leaves the displays certified within 1e-3 while detection's samples
    of the limit surface still read 1.15e-3-1.35e-3, so the frame keeps that round; judged by
    both, each takes a second round. A pair with a collider
    is still judged by detection too (tests/test_hard_cases.py, case 3)."""
    hit = [s for s in dog.stats if s.in_collision]
    assert [s.iterations for s in hit] == [1] * len(hit)
    assert max(s.residual_rel for s in dog.stats) <= 1e-3


def test_a_round_the_displays_clear_is_not_detected_again(monkeypatch):
    """After a response, the displays are measured first; where they are within the tolerance and
    every pair is two closed deformables, the round ends the frame and detection does not run:
    frames 14-16 detect once each (round 0), and their residuals are those of
    `test_a_frame_stops_at_the_first_round_whose_display_is_within_the_tolerance`."""
    import pathlib

    from conftest import SCENES
    from pipeline import frames as F, usdio

    stage = usdio.open_input(usdio.load_scene_file(pathlib.Path(SCENES / "dog_head_spike.py")))
    scene = usdio.read_scene(stage)
    rounds = []
    detect = F._Run.detect
    monkeypatch.setattr(F._Run, "detect", lambda self, frame, it, *a: rounds.append((frame, it)) or detect(self, frame, it, *a))
    _, stats = F.run_frames(stage, scene, [14, 15, 16], F.RunOptions())
    assert rounds == [(14, 0), (15, 0), (16, 0)]
    assert [s.iterations for s in stats] == [1, 1, 1]
    assert all(9e-4 < s.residual_rel <= 1e-3 for s in stats), [s.residual_rel for s in stats]


def test_rounds_past_the_tolerance_keep_lowering_the_residual():
    """At tolerance 1e-9 every round runs, and the later rounds keep lowering both residuals a
    frame stops on: the display's (the run's figure, where the user looks) and detection's (the
    deepest vertex of detection's tessellation of one kept surface inside the other,
    `detect.residual`, over the animator's pair size).

    Detection's needs the later-round rule (`datapoints.deepest_instead`, once the rewound contact
    points meet within `datapoints.MEET`): without it the spike's tip, with no vertex of its own inside
    the head, gets no point, and detection's residual stays over the contract at any cap
    (measured without the rule: 1.11e-3, 1.31e-3, 1.09e-3 at cap 4, while the display's own points
    still lower the display to 5.2e-4). Measured with it: detection's worst 1.35e-3 after the
    single round of cap 1 and 9.5e-4 at cap 4, within the contract's 1e-3 only thanks to the later
    rounds; the display's 9.7e-4, 9.0e-4, 9.7e-4 at cap 1 and 2.8e-4, 3.6e-4, 3.3e-4 at cap 4."""
    import pathlib

    from conftest import SCENES
    from pipeline import detect as D, frames as F, usdio

    stage = usdio.open_input(usdio.load_scene_file(pathlib.Path(SCENES / "dog_head_spike.py")))
    scene = usdio.read_scene(stage)
    paths = [m.path for m in scene.deformables]
    shown, found = {}, {}
    for cap in (1, 4):
        result, stats = F.run_frames(stage, scene, [14, 15, 16], F.RunOptions(iterations=cap, tolerance=1e-9))
        assert [s.iterations for s in stats] == [cap] * 3
        shown[cap] = np.array([s.residual_rel for s in stats])
        depths = []
        for s in stats:
            states = usdio.state_at(stage, scene, s.frame)[0]
            size = min(geometry.SurfaceGeometry(st.surface, st.xform).size for st in states)
            kept = [geometry.SurfaceGeometry(result.frames[s.frame][p].surface, st.xform, name=p) for p, st in zip(paths, states)]
            depths.append(D.residual(*kept).max / size)
        found[cap] = max(depths)
    assert np.all(shown[4] < shown[1]), shown  # a stalled frame keeps its first round: equal
    assert found[4] < 1e-3 < found[1], found
