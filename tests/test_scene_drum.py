"""Scene drum: an open sheet with acra:preserveVolume keeps its display area within 1 % at every
frame of the press; the same press without it gains a measured amount. Read from the output
layer as a USD client sees it."""

import numpy as np
import pytest

from acceptance.visible import measure_layer
from acra import volume
from conftest import display_points, scene_stages
from pipeline import output_layer

DRUM, CLOTH = "/World/Drum", "/World/Cloth"


@pytest.fixture(scope="module")
def run(run_scene):
    report = run_scene("drum")
    _, out = scene_stages(report)  # the input shows through the output layer
    ratios, moves = {}, {}
    for m in report.scene.deformables:
        tris = volume.triangles(output_layer.read_display_topology(out, m.path))  # what the user sees
        rest = output_layer.input_points(out, m.path)  # the animator's surface at the same vertices
        pts = {s.frame: display_points(out, m.path, s.frame) for s in report.stats}
        ratios[m.path] = {f: volume.surface_area(p, tris) / volume.surface_area(rest, tris) for f, p in pts.items()}
        moves[m.path] = {f: p - rest for f, p in pts.items()}
    return report, ratios, moves


def test_both_sheets_are_pressed(run):
    report, _, moves = run
    assert [s.frame for s in report.stats if s.in_collision] == [2, 3, 4, 5]
    for path in (DRUM, CLOTH):  # 0.25 deep, within 1e-3 of the size (0.0035); measured 0.2507, 0.2515
        assert -moves[path][5][:, 2].min() == pytest.approx(0.25, abs=0.0035)


def test_the_drum_keeps_its_area_within_1_percent(run):
    _, ratios, _ = run
    # measured: within 5e-7 at every frame (docs/performance.md, *State across frames*)
    assert max(abs(r - 1.0) for r in ratios[DRUM].values()) <= 1e-3


def test_the_same_press_without_it_gains_area(run):
    """The cloth's area gain is a figure of a run clear where the user looks: its display is
    measured outside the ball (`acceptance.visible`, trimesh and fcl on the output layer) at the
    frames whose area is asserted, so the figures cannot come from a surface left inside."""
    report, ratios, _ = run
    clear = {m.frame: m.samples for m in measure_layer(report.output, frames=(2, 3, 4, 5)) if m.path == CLOTH}
    assert max(clear.values()) <= 1e-3, clear
    # measured 1.0013, 1.0262, 1.0437, 1.0355 at frames 2-5 (the cloth at most 7.8e-4 of its size inside)
    np.testing.assert_allclose([ratios[CLOTH][f] for f in (2, 3, 4, 5)], [1.0013, 1.0262, 1.0437, 1.0355], atol=2e-3)
    assert ratios[CLOTH][6] == pytest.approx(1.0, abs=1e-6)


def test_the_drum_draws_its_edges_in(run):
    """The area comes back from the level-0 net drawing in around the dent (measured 0.038 of
    in-plane move at frame 5, 8e-4 on the cloth: a corrective round moves level 1 only)."""
    _, _, moves = run
    assert np.abs(moves[DRUM][5][:, :2]).max() > 0.02
    assert np.abs(moves[CLOTH][5][:, :2]).max() < 1e-3
