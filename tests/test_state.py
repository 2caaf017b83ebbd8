"""pipeline.state: the carried state across frames in the frame loop and in the output layer.

The scene is `scenes/soft_ball.py` (a finger presses a ball at frames 2-4; the dent relaxes at
[0.5, 0.7] per frame afterwards), run whole once per session by the ``run_scene`` fixture.
"""

import numpy as np
import pytest
from pxr import Usd

from acra import relax
from pipeline import frames as F
from pipeline import state
from pipeline import output_layer
from pipeline import usdio as U
from pipeline.run import run_file

BALL = "/World/Ball"


@pytest.fixture(scope="module")
def whole(run_scene):
    return run_scene("soft_ball")


def _stage(report):
    stage = U.open_input(report.stage_path)
    return stage, U.read_scene(stage)


def assert_same_frame(a, b):
    """Two results of one object at one frame: the same surface, display and carried state."""
    np.testing.assert_array_equal(a.surface.cvs, b.surface.cvs)
    for x, y in zip(a.surface.fine, b.surface.fine):
        np.testing.assert_array_equal(x.patches, y.patches)
        np.testing.assert_array_equal(x.offsets, y.offsets)
    np.testing.assert_array_equal(a.points, b.points)
    for fa, fb in ((a.carried.elastic, b.carried.elastic), (a.carried.plastic, b.carried.plastic)):
        fa, fb = relax.aligned(fa, fb)
        np.testing.assert_array_equal(fa.cvs, fb.cvs)
        for x, y in zip(fa.fine, fb.fine):
            np.testing.assert_array_equal(x.offsets, y.offsets)


def test_state_is_carried_and_written_every_frame(whole):
    stage = Usd.Stage.Open(str(whole.output))
    prim = stage.GetPrimAtPath(BALL)
    frames = [s.frame for s in whole.stats]
    for name in U.STATE_TYPES:
        assert prim.GetAttribute(name).GetTimeSamples() == [float(f) for f in frames], name
    hit = [s.frame for s in whole.stats if s.in_collision]
    assert hit == [2, 3, 4]
    c = whole.result.frames[4][BALL].carried
    assert np.all(relax.level_magnitudes(c.elastic) > 0.1) and relax.is_zero(c.plastic)


def test_frames_range_recomputes_the_state_before_it(whole, tmp_path):
    """``--frames 4:7`` gives at every frame exactly what the whole run gives: the state carried
    into frame 4 is recomputed from the stage's start (frames 1-3)."""
    part = run_file(whole.stage_path, tmp_path / "part.usda", frames="4:7")
    assert [s.frame for s in part.stats] == [4, 5, 6, 7]
    for f in range(4, 8):
        assert_same_frame(part.result.frames[f][BALL], whole.result.frames[f][BALL])


def test_a_run_resumes_from_a_previous_output_layer(whole):
    """The state read back from the whole run's output at frame 4 (`state.read_carried`) equals
    what the run carried, and a run of frames 5-8 from it gives what the whole run gives."""
    stage, scene = _stage(whole)
    carried = state.read_carried(Usd.Stage.Open(str(whole.output)), scene, 4, stage)
    ref = whole.result.frames[4][BALL].carried
    got = carried[0]
    for fa, fb in ((got.elastic, ref.elastic), (got.plastic, ref.plastic)):
        fa, fb = relax.aligned(fa, fb)
        np.testing.assert_array_equal(fa.cvs, fb.cvs)
        for x, y in zip(fa.fine, fb.fine):
            np.testing.assert_array_equal(x.offsets, y.offsets)
    result, _ = F.run_frames(stage, scene, [5, 6, 7, 8], initial=carried)
    for f in range(5, 9):
        assert_same_frame(result.frames[f][BALL], whole.result.frames[f][BALL])


def test_a_layer_written_from_another_input_is_refused(whole, tmp_path):
    """The input's animator surface changed since the output was written: the recorded state
    does not add up to the recorded response any more."""
    from pxr import Vt

    stage, scene = _stage(whole)
    edited = Usd.Stage.Open(str(whole.stage_path))
    edited.GetRootLayer().Export(str(tmp_path / "edited.usda"))
    edited = Usd.Stage.Open(str(tmp_path / "edited.usda"))
    attr = edited.GetPrimAtPath(BALL).GetAttribute("acra:cvs")
    attr.Set(Vt.Vec3fArray.FromNumpy(np.asarray(attr.Get(), dtype=np.float32) * np.float32(1.01)))
    with pytest.raises(ValueError, match=f"{BALL}: the acra:state recorded at frame 4 does not match the input"):
        state.read_carried(Usd.Stage.Open(str(whole.output)), scene, 4, edited)


def test_carried_at_gives_the_state_a_chunk_starts_from(whole):
    stage, scene = _stage(whole)
    got = state.carried_at(stage, scene, 3)[0]
    assert_same_frame(
        output_layer.DeformableResult(whole.result.frames[3][BALL].points, None, whole.result.frames[3][BALL].surface, carried=got),
        whole.result.frames[3][BALL],
    )
    z = state.carried_at(stage, scene, 0)[0]  # before the stage's start nothing is carried
    assert relax.is_zero(z.elastic) and relax.is_zero(z.plastic)


def test_reading_state_a_layer_does_not_hold_names_the_prim(whole):
    stage, scene = _stage(whole)
    with pytest.raises(ValueError, match=f"{BALL}: no acra:state recorded at frame 40"):
        state.read_carried(Usd.Stage.Open(str(whole.output)), scene, 40)


def test_stateful_frames_must_be_consecutive(whole):
    stage, scene = _stage(whole)
    with pytest.raises(ValueError, match="consecutive"):
        F.run_frames(stage, scene, [1, 3])


def test_stateless_objects_write_no_state(run_scene):
    from pxr import Usd

    report = run_scene("rigid_top")
    stage = Usd.Stage.Open(str(report.output))
    for m in report.scene.deformables:
        assert not any(stage.GetPrimAtPath(m.path).GetAttribute(n) for n in U.STATE_TYPES), m.path
        assert all(r[m.path].carried is None for r in report.result.frames.values())


def test_a_kept_dent_with_nothing_to_release_reuses_its_surface(run_scene):
    """clay: once the balls have gone, the fully plastic sheet starts every frame from the same
    surface object (same animator surface, same kept field), so nothing is evaluated again."""
    report = run_scene("clay")
    surfaces = [report.result.frames[f]["/World/Full/Sheet"].surface for f in (6, 7, 8)]
    assert surfaces[0] is surfaces[1] is surfaces[2]


def test_an_elastic_field_below_the_negligible_size_is_released_in_full(whole):
    stage, scene = _stage(whole)
    carried = whole.result.frames[4][BALL].carried
    animator = U.state_at(stage, scene, 5.0)[0][0].surface
    tiny = relax.scaled(carried.elastic, np.full(2, 0.5 * state.NEGLIGIBLE * animator.size() / relax.level_magnitudes(carried.elastic).max()))
    carry = state.Carry(scene, [relax.Carried(tiny, carried.plastic)])
    started = carry.begin(5, [animator])[0]
    assert started is animator and relax.is_zero(carry.released[0].elastic)
