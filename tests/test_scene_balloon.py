"""Scene balloon: the pressed balloon keeps its volume within 1 % at every frame by bulging; the
same press without acra:preserveVolume loses a measured amount.

Volumes are the display meshes' (`acra.volume.enclosed_volume`) read from the output layer as a
USD client sees it, against the input's rest display mesh.
"""

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from acra import volume
from pipeline import output_layer

BALLOON, BALL = "/World/Balloon", "/World/Ball"


@pytest.fixture(scope="module")
def ratios(run_scene):
    """Per object, ``{frame: output volume / input volume}``; and the report."""
    report = run_scene("balloon")
    out = Usd.Stage.Open(str(report.output))  # the input shows through it
    got = {}
    for m in report.scene.deformables:
        tris = volume.triangles(output_layer.read_display_topology(out, m.path))  # what the user sees
        rest = volume.enclosed_volume(output_layer.input_points(out, m.path), tris)  # the animator's, same vertices
        pts = lambda f: np.asarray(UsdGeom.Mesh(out.GetPrimAtPath(m.path)).GetPointsAttr().Get(f), dtype=np.float64)  # noqa: E731
        got[m.path] = {s.frame: volume.enclosed_volume(pts(s.frame), tris) / rest for s in report.stats}
    return got, report


def test_both_balls_are_pressed(ratios):
    _, report = ratios
    c = {m.path: m.controls for m in report.scene.deformables}
    assert (c[BALLOON].preserve_volume, c[BALLOON].bulge_level, c[BALLOON].bulge_falloff) == (1.0, 0, 0.5)
    assert c[BALL].preserve_volume == 0.0 and not c[BALLOON].stateful
    assert [s.frame for s in report.stats if s.in_collision] == [2, 3, 4, 5]


def test_the_balloon_keeps_its_volume_within_1_percent_at_every_frame(ratios):
    got, _ = ratios
    # measured: within 1e-4 at every frame
    assert max(abs(r - 1.0) for r in got[BALLOON].values()) <= 1e-3


def test_the_same_press_without_it_loses_volume(ratios):
    got, _ = ratios
    # measured 0.9940, 0.9811, 0.9609, 0.9158 at frames 2-5
    assert got[BALL][5] == pytest.approx(0.9158, abs=2e-3)
    assert all(got[BALL][f + 1] < got[BALL][f] for f in (2, 3, 4))
    assert got[BALL][6] == pytest.approx(1.0, abs=1e-6)  # the finger has gone: the animator's ball


def test_the_bulge_does_not_penetrate_the_finger(ratios):
    """The residual the run reports is measured after the bulge (the frame loop detects again)."""
    _, report = ratios
    assert max(s.residual_rel for s in report.stats) <= 1e-3


def test_the_preview_plots_the_volume_ratio(ratios):
    from rerun.chunk import RrdReader

    _, report = ratios
    entities = {c.entity_path for c in RrdReader(str(report.output.with_name("balloon.rrd"))).stream()}
    assert f"/metrics/volume{BALLOON}" in entities and f"/metrics/volume{BALL}" not in entities
