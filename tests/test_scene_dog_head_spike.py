"""dog_head_spike (thesis Fig. 5.1–5.2): the benchmark scene's model sizes and the look of its response."""

import numpy as np
import pytest

from acra import hspline as H
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
    for s in dog.stats:
        meshes = {m.path: m for m in S.world_meshes(dog.output, s.frame)}
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


def test_rounds_past_the_tolerance_keep_lowering_the_residual():
    """At tolerance 1e-9 every round runs; the later-round rule (`frames.MEET`) must still
    fire, or frames 14-16 stall at 1.2e-3 whatever the cap (measured with MEET = 0: 1.199e-3 at
    caps 2 and 4). Measured with it: worst 1.35e-3 after the single round of cap 1 and 9.4e-4
    at cap 4, within the contract's 1e-3 only thanks to the later rounds."""
    import pathlib

    from conftest import SCENES
    from pipeline import frames as F, usdio

    stage = usdio.open_input(usdio.load_scene_file(pathlib.Path(SCENES / "dog_head_spike.py")))
    scene = usdio.read_scene(stage)
    worst = {}
    for cap in (1, 4):
        _, stats = F.run_frames(stage, scene, [14, 15, 16], F.RunOptions(iterations=cap, tolerance=1e-9))
        assert [s.iterations for s in stats] == [cap] * 3
        worst[cap] = max(s.residual_rel for s in stats)
    assert worst[4] < 1e-3 < worst[1]
