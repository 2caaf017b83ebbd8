"""Scene soft_ball: a ball dented by a finger at frames 2-4 recovers at its per-level rates.

Read from the output layer as a USD client sees it: the carried elastic field (``acra:state:*``)
and the display points against the animator's.
"""

import numpy as np
import pytest
from pxr import UsdGeom

from conftest import elastic_levels, scene_run
from pipeline import output_layer

BALL = "/World/Ball"
RELAX = np.array([0.5, 0.7])  # the scene's acra:relax
LAST_HIT = 4


@pytest.fixture(scope="module")
def run(run_scene):
    return scene_run(run_scene, "soft_ball")


def _carried(out, frame):
    """Largest elastic vector per level at ``frame``, read from the output layer: ``(2,) float64``."""
    cvs, offs = elastic_levels(out, BALL, frame)
    return np.array([np.linalg.norm(cvs, axis=1).max(), np.linalg.norm(offs, axis=1).max(initial=0.0)])


def _fields(out, frame):
    return elastic_levels(out, BALL, frame)


def test_the_finger_dents_the_ball_at_frames_2_to_4(run):
    report, _, out = run
    assert [s.frame for s in report.stats if s.in_collision] == [2, 3, 4]
    # both levels carry a dent at the last pressed frame (measured 0.128 and 0.148)
    assert np.all(_carried(out, LAST_HIT) > 0.1)


def test_each_level_recovers_at_its_own_rate(run):
    """After the finger leaves, every carried coefficient of level l is (1 - r_l)^n of what it was
    at the last pressed frame, n frames later (to 1e-6 of the dent)."""
    report, _, out = run
    cvs0, offs0 = _fields(out, LAST_HIT)
    scale = max(np.abs(cvs0).max(), np.abs(offs0).max())
    for n, f in enumerate(range(LAST_HIT + 1, report.stats[-1].frame + 1), start=1):
        cvs, offs = _fields(out, f)
        assert np.abs(cvs - (1 - RELAX[0]) ** n * cvs0).max() <= 1e-6 * scale, f
        assert offs.shape == offs0.shape
        assert np.abs(offs - (1 - RELAX[1]) ** n * offs0).max() <= 1e-6 * scale, f
        np.testing.assert_allclose(_carried(out, f), (1 - RELAX) ** n * _carried(out, LAST_HIT), rtol=1e-6)


def test_the_displayed_ball_returns_to_the_animators_shape(run):
    """The display points' largest distance from the animator's (the input's rest points) shrinks
    at every frame after the finger leaves by at most the slower level's factor 1 - 0.5, and the
    factor tends to it as level 1's faster part dies out (measured: 0.378, 0.407, ... 0.493;
    0.156 at frame 4, 2.6e-4 at frame 12)."""
    report, inp, out = run
    rest = output_layer.input_points(out, BALL)  # the animator's surface at the output's display vertices
    last = report.stats[-1].frame
    dev = {f: np.linalg.norm(np.asarray(UsdGeom.Mesh(out.GetPrimAtPath(BALL)).GetPointsAttr().Get(f)) - rest, axis=1).max()
           for f in range(1, last + 1)}
    assert dev[1] < 1e-6  # before the press: the animator's shape (float32 display points)
    ratios = [dev[f + 1] / dev[f] for f in range(LAST_HIT, last)]
    assert max(ratios) <= 1 - RELAX[0]
    assert ratios[-1] == pytest.approx(1 - RELAX[0], abs=0.01)
    assert dev[LAST_HIT] > 0.15 and dev[last] <= (1 - RELAX[0]) ** (last - LAST_HIT) * dev[LAST_HIT]


def test_the_preview_plots_the_carried_offsets_per_level(run):
    from rerun.chunk import RrdReader

    report, _, _ = run
    rrd = report.output.with_name("soft_ball.rrd")
    entities = {c.entity_path for c in RrdReader(str(rrd)).stream()}
    for part in ("elastic", "plastic"):
        for k in (0, 1):
            assert f"/metrics/state{BALL}/{part}/level_{k}" in entities, sorted(e for e in entities if "metrics" in e)


def test_the_preview_colours_the_carried_dent(run):
    """Vertex colours on the ball (RGBA packed in a uint32, `preview.moved_colours`: the ball's own
    colour where the output equals the key-framed shape, viridis by log distance otherwise). The
    key-framed shape is the animator's, so the carried dent shows: no vertex coloured before the
    press, the brightest at the deepest frame, and the brightest colour fading frame by frame as
    the dent relaxes (viridis' green channel rises with the distance)."""
    from rerun.chunk import RrdReader

    from pipeline.preview import DEFORMABLE_COLOUR

    report, _, _ = run
    own = np.array(DEFORMABLE_COLOUR, dtype=np.int64)
    brightest = {}  # frame -> (coloured vertices, the largest green channel among them)
    for c in RrdReader(str(report.output.with_name("soft_ball.rrd"))).stream():
        if c.entity_path != f"/world{BALL}":
            continue
        b = c.to_record_batch()
        if "Mesh3D:vertex_colors" not in b.schema.names:
            continue
        for f, v in zip(b.column("frame").to_pylist(), b.column("Mesh3D:vertex_colors").to_pylist()):
            rgba = np.array(v, dtype=np.uint32)
            rgb = np.stack([(rgba >> 24) & 0xFF, (rgba >> 16) & 0xFF, (rgba >> 8) & 0xFF], axis=1).astype(np.int64)
            coloured = np.any(rgb != own, axis=1)
            brightest[f] = (int(coloured.sum()), int(rgb[coloured, 1].max(initial=0)))
    assert sorted(brightest) == list(range(1, 13))
    assert brightest[1] == (0, 0)
    # the deepest frame: 0.156 of a 3.4-size ball, log10 -1.3, near viridis' bright end (G 220-231)
    assert brightest[4][0] > 0 and brightest[4][1] >= 200
    assert all(brightest[f + 1][1] <= brightest[f][1] for f in range(4, 12))
    # frame 12 carries 2.6e-4 (7.7e-5 of the size): below the map's 1e-4 end, the darkest colour
    assert brightest[12][0] > 0 and brightest[12][1] <= 45
