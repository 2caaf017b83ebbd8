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
        elif head.moved.max() > 0.01:
            # rigidity 10 against 80: eq. 4.15 puts the data points 8/9 of the way toward the spike
            assert head.moved.max() > 5.0 * spike.moved.max()
