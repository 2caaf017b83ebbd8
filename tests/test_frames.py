"""End to end through `acra run`: a box jumps deep into a sheet and stays; bad input writes nothing."""

import shutil
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from conftest import write_tiny_stage
from pipeline import clearance, geometry
from pipeline import detect as D
from pipeline import frames as F
from pipeline.cli import main

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "box_into_sheet.py"


@pytest.fixture(scope="module")
def box_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("box")
    scene = d / "box_into_sheet.py"
    shutil.copy(SCENE, scene)
    assert main(["run", str(scene), "--quiet"]) == 0
    return d / "box_into_sheet.usda", d / "box_into_sheet.acra.usda"


def test_box_into_sheet_is_cleared_on_the_side_it_came_from(box_run):
    src, out = box_run
    stage = Usd.Stage.Open(str(out))
    sheet = stage.GetPrimAtPath("/World/Sheet")
    points = UsdGeom.Mesh(sheet).GetPointsAttr()
    residual = sheet.GetAttribute("acra:response:residual")
    for frame in range(11, 17):  # the box sits 0.7 deep from frame 11 on
        p = np.array(points.Get(frame))
        under = (np.abs(p[:, 0] - 0.2) < 0.45) & (np.abs(p[:, 1] + 0.1) < 0.45)
        # pushed down with the box (it came from above), never left above its bottom face
        assert p[under, 2].max() <= -0.7 + 1e-3 * 5.7
        assert np.all(np.isfinite(p)) and p[:, 2].max() <= 1e-9
        assert residual.Get(frame) <= 1e-3 * 5.7
    # before the contact the sheet is untouched
    np.testing.assert_allclose(np.array(points.Get(5))[:, 2], 0.0, atol=1e-9)


def test_transforms_unchanged(box_run):
    src, out = box_run
    a, b = Usd.Stage.Open(str(src)), Usd.Stage.Open(str(out))
    for path in ("/World/Mover", "/World/Mover/Box", "/World/Sheet"):
        for f in range(1, 17):
            ma = UsdGeom.Xformable(a.GetPrimAtPath(path)).ComputeLocalToWorldTransform(f)
            mb = UsdGeom.Xformable(b.GetPrimAtPath(path)).ComputeLocalToWorldTransform(f)
            assert ma == mb


def test_bad_input_exits_nonzero_with_one_line_and_writes_nothing(tmp_path, capsys):
    bad = tmp_path / "bad.usda"
    bad.write_text('#usda 1.0\n(\n startTimeCode = 1\n endTimeCode = 2\n)\ndef Mesh "M" {\n int acra:uCount = 4\n int acra:vCount = 4\n point3f[] acra:cvs = [(0,0,0)]\n}\n')
    code = main(["run", str(bad), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and "/M" in err[0] and "acra:cvs" in err[0]
    assert not (tmp_path / "bad.acra.usda").exists()


def test_rrd_reads_back_with_meshes_on_the_frame_timeline(tmp_path):
    from rerun.chunk import RrdReader

    scene = tmp_path / "box_into_sheet.py"
    shutil.copy(SCENE, scene)
    rrd = tmp_path / "box.rrd"
    assert main(["run", str(scene), "--quiet", "--frames", "9:12", "--rrd", str(rrd)]) == 0
    chunks = list(RrdReader(str(rrd)).stream().to_chunks())
    paths = {c.entity_path for c in chunks}
    assert {"/world/World/Sheet", "/world/World/Mover/Box", "/metrics/residual_rel", "/metrics/ms/total",
            "/metrics/ms/detect", "/world/acra/contacts", "/world/acra/data_points/World/Sheet"} <= paths
    temporal = [c for c in chunks if c.entity_path == "/world/World/Sheet" and not c.is_static]
    assert temporal and "frame" in temporal[0].to_record_batch().schema.names
    assert any(c.is_static for c in chunks if c.entity_path == "/world/World/Sheet")
    # the box is drawn where USD puts it: its transform is logged per frame (z = 0.55 at frame 10)
    box = [c for c in chunks if c.entity_path == "/world/World/Mover/Box" and not c.is_static]
    names = " ".join(str(n) for c in box for n in c.to_record_batch().schema.names)
    assert "Transform3D" in names or "translation" in names.lower()
    # the default blueprint travels with the recording: the collision and whole-scene 3D views, the
    # legend, four plots and the event log
    reader = RrdReader(str(rrd))
    stores = reader.blueprints()
    assert stores
    views = {c.entity_path.split("/")[2] for c in reader.stream(store=stores[0]).to_chunks() if c.entity_path.startswith("/view/")}
    assert len(views) == 8


def test_preview_clears_markers_of_a_free_frame(tmp_path):
    """Scrubbing from a collision frame to a free one must not show the old contacts."""
    from rerun.chunk import RrdReader

    from pipeline import frames as F
    from pipeline import preview as P
    from pipeline import usdio

    scene_file = tmp_path / "box_into_sheet.py"
    shutil.copy(SCENE, scene_file)
    stage_path = usdio.load_scene_file(scene_file)
    stage = usdio.open_input(stage_path)
    scene = usdio.read_scene(stage)
    result, stats = F.run_frames(stage, scene, [10, 11])
    assert not stats[0].in_collision and stats[1].in_collision
    rrd = tmp_path / "p.rrd"
    preview = P.Preview(scene, "p", rrd=rrd, stage=stage)
    preview.log_frame(stats[1], result)  # collision first, then the free frame
    preview.log_frame(stats[0], result)
    preview.close()
    cleared = set()
    for c in RrdReader(str(rrd)).stream().to_chunks():
        if any("Clear" in str(n) for n in c.to_record_batch().schema.names):
            cleared.add(c.entity_path)
    assert {"/world/acra/contacts", "/world/acra/data_points/World/Sheet", "/world/acra/region/World/Sheet"} <= cleared


def test_residual_is_relative_to_the_size_of_the_display_the_user_sees(tiny_stage):
    """``residual_rel`` is the residual over the diagonal of the world box of the deformable's own
    output display at that frame (contract §3), not the size of its control net: a box left
    1e-4 of the sheet inside it, within the tolerance, is reported with exactly that depth (the
    box is convex and the sheet lies along its bottom face, where the bound is exact) over the
    display's diagonal."""

    from pipeline import usdio
    from pipeline.model import apply_xform

    path = tiny_stage(frames=2, n=6, levels=1, depth=1e-4)
    stage = usdio.open_input(path)
    scene = usdio.read_scene(stage)
    result, stats = F.run_frames(stage, scene, [2])
    (st,) = stats
    r = result.frames[2]["/World/Sheet"]
    shown = apply_xform(st.xforms["/World/Sheet"], np.asarray(r.points, np.float32).astype(np.float64))
    diagonal = float(np.linalg.norm(np.ptp(shown, axis=0)))
    net = geometry.SurfaceGeometry(r.surface, st.xforms["/World/Sheet"]).size
    assert st.iterations == 0 and net > 1.1 * diagonal  # the net reaches past the surface
    assert st.residual == pytest.approx(1e-4, rel=1e-3)  # float32 box and sheet points
    assert st.residual_rel == pytest.approx(st.residual / diagonal, rel=1e-12)


def test_two_runs_give_byte_identical_layers(tmp_path):
    scene = tmp_path / "box_into_sheet.py"
    shutil.copy(SCENE, scene)
    outs = []
    for name in ("a.usda", "b.usda"):
        assert main(["run", str(scene), "--quiet", "--frames", "10:12", "-o", str(tmp_path / name)]) == 0
        outs.append((tmp_path / name).read_bytes())
    assert outs[0] == outs[1]


def test_demo_motion_is_keyed_with_native_usd_splines(tmp_path):
    import runpy

    stage = runpy.run_path(str(SCENE))["build"]()
    op = stage.GetPrimAtPath("/World/Mover").GetAttribute("xformOp:translateZ")
    assert op.HasSpline() and not op.GetTimeSamples()
    assert op.Get(10.5) == pytest.approx(0.175)


def test_set_up_the_display_measure_triggers_is_counted_as_set_up(tiny_stage, monkeypatch):
    """Shape data built while a round measures its displays (`_Run.visible`, e.g. a responded
    surface's patch boxes) counts on ``ms_setup``, not on ``ms_visible``. The frame loop's clock
    advances here only inside a set-up of 30 ms made at the start of every measure, so that
    set-up moves whole to ``ms_setup`` and the measures keep exactly nothing."""
    import time

    from pipeline import grids
    from pipeline import usdio

    clock = [0.0]
    monkeypatch.setattr(time, "perf_counter", lambda: clock[0])

    @grids.timed
    def build():
        clock[0] += 0.03

    measured = F._Run.visible
    calls = []

    def visible(self, *args):
        build()
        calls.append(1)
        return measured(self, *args)

    monkeypatch.setattr(F._Run, "visible", visible)
    stage = usdio.open_input(tiny_stage(frames=3, depth=0.1))
    scene = usdio.read_scene(stage)
    _, (st,) = F.respond_frames(stage, scene, [3])
    assert st.in_collision and len(calls) == st.iterations + 1 >= 2
    assert st.ms_setup == pytest.approx(30.0 * len(calls), rel=1e-12)
    assert st.ms_visible == 0.0


def test_each_round_measures_its_displays_once(tiny_stage, monkeypatch):
    """A round's display measure (`residual.measure_frame`) is taken once, at the round's start:
    the round's judge, the skip of detection (`_Run._displays_judge`) and the kept round's
    residual all read that one measure (the first round's lower bounds are completed from it,
    `residual.complete`, not measured again)."""
    from pipeline import residual
    from pipeline import usdio

    measure = residual.measure_frame
    calls = []
    monkeypatch.setattr(residual, "measure_frame", lambda *a, **k: calls.append(1) or measure(*a, **k))
    stage = usdio.open_input(tiny_stage(frames=3, depth=0.1))
    scene = usdio.read_scene(stage)
    _, (st,) = F.respond_frames(stage, scene, [3])
    assert st.in_collision and len(calls) == st.iterations + 1


def test_the_residual_measures_a_pair_as_the_exact_box_test_without_a_met_surfaces_patch_boxes():
    """`frames._measured` answers as the exact test (``not detect.apart`` and
    `detect._boxes_overlap` at `detect.pair_pad`) for spheres and a box at random places, near
    and apart; a surface whose patch boxes are not built gets an inner box of its level-0 CVs
    (`frames._inner_box`) inside its exact `bounds`, and where that box meets the other's, the
    patch boxes stay unbuilt (a responded surface the rounds never detect)."""
    from acra import hspline as H
    from acra import shapes
    from conftest import box, move

    rng = np.random.default_rng(5)
    met = 0
    for trial in range(60):
        a = geometry.SurfaceGeometry(H.from_grid(*shapes.sphere(8, 6)), move(*rng.uniform(-1.5, 1.5, 3)) @ np.diag([*rng.uniform(0.5, 2.0, 3), 1.0]))
        if trial % 2:
            b = geometry.SurfaceGeometry(H.from_grid(*shapes.sphere(8, 6)), move(*rng.uniform(-1.5, 1.5, 3)))
        else:
            b = geometry.ColliderGeometry(box(rng.uniform(0.2, 1.0)), move(*rng.uniform(-2.0, 2.0, 3)))
        inner = F._inner_box(a)
        assert F._unbuilt(a)
        got = F._measured(a, b)
        unbuilt = "hulls" not in a.shape.__dict__
        exact = not (D.apart(a, b) or not D._boxes_overlap(a, b, D.pair_pad(a, b)))
        assert got == exact
        box_, diag = inner
        assert np.all(a.bounds[0] <= box_[0]) and np.all(box_[1] <= a.bounds[1]) and diag <= a.size
        if unbuilt:
            met += 1
            assert got
    assert met >= 5


# --- holds: a frame whose input is the previous frame's, bit for bit ----------------------------


def _pressed_and_held(path, keyed_cvs=False, **state):
    """`conftest.write_tiny_stage`'s box pressed 0.1 into the sheet at frame 3, the stage running
    to frame 5, so frames 4 and 5 hold frame 3's input. ``keyed_cvs``: the sheet's CVs are keyed
    too, rising 0.05 from frame 1 to 3. ``state``: the sheet's `authoring.set_state_controls`
    (state carried across frames)."""
    from pipeline import authoring

    def sheet(prim, cvs):
        if keyed_cvs:
            authoring.key_cvs(prim, 1, cvs)
            authoring.key_cvs(prim, 3, cvs + np.array([0.0, 0.0, 0.05]))
        if state:
            authoring.set_state_controls(prim, **state)

    return write_tiny_stage(path, frames=3, end=5, sheet=sheet)


@pytest.mark.parametrize("state, holds", [({}, [False, False, False, True, True]),
                                          ({"keyed_cvs": True}, [False, False, False, True, True]),
                                          ({"plasticity": 0.5}, [False] * 5)])
def test_frames_after_the_last_key_hold_unless_the_object_carries_state(tmp_path, state, holds):
    """Keyed CVs hold too after their last key, although the rewinding of frame 3 read the
    sheet's earlier CVs in between (the state memo hands back another surface object)."""
    from pipeline import usdio

    stage = usdio.open_input(_pressed_and_held(tmp_path / "held.usda", **state))
    scene = usdio.read_scene(stage)
    result, stats = F.respond_frames(stage, scene, [1, 2, 3, 4, 5])
    assert [s.hold for s in stats] == holds
    assert [s.in_collision for s in stats] == [False, False, True, True, True]
    if "plasticity" not in state:  # a hold's answer is the frame it holds: the same surface, residual and rounds
        three = result.frames[3]["/World/Sheet"]
        for f, st in ((4, stats[3]), (5, stats[4])):
            assert result.frames[f]["/World/Sheet"].surface is three.surface
            assert (st.residual, st.iterations, st.ms_respond) == (stats[2].residual, stats[2].iterations, 0.0)


def test_a_hold_gives_the_bits_computing_the_frame_gives():
    """`box_into_sheet`'s box lands at frame 11 and stays: frames 12 and 13 hold frame 11. Frame 12
    computed on its own (the first frame of a run holds nothing) gives the same surface bits,
    residual and rounds as the hold."""
    from acra import hspline as H
    from pipeline import usdio
    from pipeline.run import forget

    stage = usdio.open_input(usdio.load_scene_file(SCENE))
    scene = usdio.read_scene(stage)
    held, stats = F.respond_frames(stage, scene, [10, 11, 12, 13])
    assert [s.hold for s in stats] == [False, False, True, True]
    assert [s.in_collision for s in stats] == [False, True, True, True]
    forget()
    alone, (st,) = F.respond_frames(stage, scene, [12])
    assert not st.hold and st.in_collision
    a, b = held.frames[12]["/World/Sheet"].surface, alone.frames[12]["/World/Sheet"].surface
    np.testing.assert_array_equal(a.cvs, b.cvs)
    ha, hb = H.to_arrays(a), H.to_arrays(b)
    for name in ("patch_level", "patches", "offset_level", "offset_cvs", "offsets"):
        np.testing.assert_array_equal(getattr(ha, name), getattr(hb, name))
    assert (st.residual, st.residual_rel, st.iterations) == (stats[2].residual, stats[2].residual_rel, stats[2].iterations)
    assert stats[1].residual == stats[2].residual and stats[1].iterations == stats[2].iterations


def test_a_colliders_inside_is_the_detections_solid_where_trimesh_kept_its_arrays(monkeypatch):
    """`_Run.collider_solid`: a collider whose vertices and triangles trimesh's processing leaves
    byte for byte takes `ColliderStatic.solid` (the same call on the same arrays), one built a
    run; one it changes (an unused vertex dropped) or an open one gets `residual.collider_solid`'s
    answer. Either way the arrays are those `residual.collider_solid` builds."""
    from types import SimpleNamespace

    from acra import memo
    from conftest import BOX_TRIANGLES, BOX_VERTICES
    from pipeline import residual
    from pipeline.model import ColliderModel

    models = [ColliderModel("/kept", BOX_VERTICES * 0.5, BOX_TRIANGLES),
              ColliderModel("/unused", np.vstack([BOX_VERTICES * 0.5, [[3.0, 3.0, 3.0]]]), BOX_TRIANGLES),
              ColliderModel("/open", BOX_VERTICES * 0.5, BOX_TRIANGLES[:-1])]
    run = SimpleNamespace(scene=SimpleNamespace(colliders=models), statics=[geometry.prepare_collider(m) for m in models],
                          _collider_solids={})
    with memo.scope():  # a run's memo: nothing kept from an earlier run of the same box
        got = [F._Run.collider_solid(run, j) for j in range(3)]
        kept = [residual.collider_solid(m.vertices, m.triangles) for m in models]
    assert got[0] is run.statics[0].solid and F._Run.collider_solid(run, 0) is got[0]
    assert got[1] is not None and got[1] is not run.statics[1].solid
    assert got[2] is None and residual.collider_solid(models[2].vertices, models[2].triangles) is None
    built = []
    solid = clearance.solid
    monkeypatch.setattr(clearance, "solid", lambda v, f, **k: built.append(len(f)) or solid(v, f, **k))
    with memo.scope():  # an open mesh's answer (no inside) is kept as a closed one's is
        assert [residual.collider_solid(models[2].vertices, models[2].triangles) for _ in range(3)] == [None] * 3
    assert built == [11]
    for j in (0, 1):
        assert kept[j] is got[j]  # kept by the mesh's content: the run's display measure takes the loop's
        want = clearance.solid(np.asarray(models[j].vertices, np.float64), np.asarray(models[j].triangles, np.int64))
        for name in ("vertices", "faces", "normals", "edge_normals", "vertex_normals", "bounds", "facet", "convex"):
            np.testing.assert_array_equal(getattr(got[j], name), getattr(want, name))


def test_a_run_builds_a_colliders_inside_once(monkeypatch, tmp_path):
    """`box_into_sheet`'s box is measured by the frame loop's rounds and by the run's display
    measure (`residual.measure_run`): its inside (`clearance.solid` of the box's 12 triangles)
    is built once a run, and the output is a run's."""
    from pipeline import run

    built = []
    solid = clearance.solid
    monkeypatch.setattr(clearance, "solid", lambda v, f, **k: built.append(len(f)) or solid(v, f, **k))
    run.run_file(SCENE, tmp_path / "out.usda")
    assert built.count(12) == 1


def test_respond_frames_limits_blas_through_the_process_s_one_controller(tiny_stage, monkeypatch):
    """`respond_frames` holds every BLAS library the process has (as a fresh scan finds them) to
    one thread while its frames run, through the controller `display.finish` uses
    (`display._blas`: no scan of the loaded libraries a call), and gives their threads back
    after."""
    import threadpoolctl

    from pipeline import display, usdio

    stage = usdio.open_input(tiny_stage(frames=2, n=6, levels=1, depth=0.1))
    scene = usdio.read_scene(stage)
    blas = lambda c: {lib["filepath"]: lib["num_threads"] for lib in c.info() if lib["user_api"] == "blas"}  # noqa: E731
    controller = display._blas()
    with threadpoolctl.ThreadpoolController().limit(limits=2, user_api="blas"):  # threads to give back
        before = blas(threadpoolctl.ThreadpoolController())
        assert set(blas(controller)) == set(before) and set(before.values()) == {2}
        seen, scans = [], []
        run, scan = F._run_frames, threadpoolctl.ThreadpoolController._load_libraries
        monkeypatch.setattr(F, "_run_frames", lambda *a: seen.append(blas(controller)) or run(*a))
        monkeypatch.setattr(threadpoolctl.ThreadpoolController, "_load_libraries",
                            lambda self: scans.append(1) or scan(self))
        F.respond_frames(stage, scene, [1, 2])
        F.respond_frames(stage, scene, [2])
        assert display._blas() is controller and not scans
        assert seen == [dict.fromkeys(before, 1)] * 2
        assert blas(controller) == before


DEMO = Path(__file__).resolve().parents[1] / "scenes" / "dog_head_spike.py"


def _demo_frames(frames, monkeypatch=None, settle=True, respond=True, options=F.RunOptions()):
    """The demo's ``frames`` after a run's state is dropped: the results and statistics, and each
    `residual.pair_depth` call's stop (finite or not), stopped or not, and how many calls each
    `_Run.visible` made. ``settle`` false: every side of the first round measured in full (as
    without `_settle`); ``respond`` false: no response changes a surface; ``options`` the run's."""
    from pipeline import residual, usdio
    from pipeline.run import forget

    calls, per_round = [], []
    pair_depth, visible = residual.pair_depth, F._Run.visible

    def counted(a, b, target, decide=np.inf, stop=np.inf):
        ins = pair_depth(a, b, target, decide, stop)
        calls.append((bool(np.isfinite(stop)), ins.stopped))
        return ins

    def measured(self, *args):
        n = len(calls)
        out = visible(self, *args)
        per_round.append((bool(args[3:4] and args[3]), len(calls) - n))
        return out

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(residual, "pair_depth", counted)
        mp.setattr(F._Run, "visible", measured)
        if not settle:
            mp.setattr(F, "_settle", lambda rnd, sizes, tolerance: ({}, False))
        if not respond:
            mp.setattr(F._Run, "respond", lambda self, *a, **k: None)
        forget()
        stage = usdio.open_input(usdio.load_scene_file(DEMO))
        result, stats = F.respond_frames(stage, usdio.read_scene(stage), frames, options)
    return result, stats, calls, per_round


def _same_outcome(a, b):
    """Two runs' frame statistics (all but times) and kept residual answers, bit for bit."""
    (ra, sa), (rb, sb) = a, b
    for x, y in zip(sa, sb):
        assert (x.in_collision, x.iterations, x.residual, x.residual_rel, x.pair_residual_rel) == \
            (y.in_collision, y.iterations, y.residual, y.residual_rel, y.pair_residual_rel)
    assert ra.residuals.keys() == rb.residuals.keys()
    for f in ra.residuals:
        ka, kb = ra.residuals[f], rb.residuals[f]
        assert ka.keys() == kb.keys()
        for key in ka:
            assert (ka[key].depth, ka[key].lower, ka[key].complete, ka[key].stopped) == \
                (kb[key].depth, kb[key].lower, kb[key].complete, False)


def test_the_first_round_settles_the_pairs_detection_found_with_one_deep_point():
    """On the demo every first round finds the spike's tip inside the head: its display in the
    head is searched only until a point deeper than the tolerance (one call, stopped), the
    head's in the spike not at all; the second round is within the tolerance and kept, so the
    first is never measured in full, and every figure is the full measure's."""
    frames = [14, 15, 16]
    result, stats, calls, per_round = _demo_frames(frames)
    assert [r for r in per_round if r[0]] == [(True, 1)] * len(frames)  # the first rounds: one call each
    assert calls.count((True, True)) == len(frames) and (True, False) not in calls
    assert all(st.iterations == 1 and st.residual_rel <= 1e-3 for st in stats)
    full = _demo_frames(frames, settle=False)
    assert full[3] == [(False, 2), (False, 2)] * len(frames)
    _same_outcome(result_stats := (result, stats), full[:2])
    assert result_stats[1][0].in_collision


def test_a_kept_first_round_reports_its_full_measure():
    """Where no response changes a surface, every later round scores what the first did (over
    the tolerance) and the first round is kept: its figures and the answers the run's display
    takes (`residual.known`) are the full measure's, never the lower bounds that settled it."""
    from pipeline import residual

    completed = []
    complete = residual.complete
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(residual, "complete", lambda fr, *a, **k: completed.append(fr.stopped) or complete(fr, *a, **k))
        got = _demo_frames([15], respond=False)
    want = _demo_frames([15], settle=False, respond=False)
    assert completed == [True] and got[2].count((True, True)) == 1
    assert got[1][0].residual_rel > 1e-3 and got[1][0].iterations == F.RunOptions().iterations
    _same_outcome(got[:2], want[:2])
    assert len(got[0].residuals[15]) == 2  # both sides of the pair, the unmeasured one among them


def test_a_first_round_a_later_round_beats_by_its_lower_bounds_is_not_completed():
    """At half the default tolerance the demo's frame 15 takes two responses: its second round
    is over the tolerance, yet below the first round's lower bound (the spike's tip, one deep
    point) over `residual.OVER`, so the first round can never be kept or reported and is not
    measured in full (`residual.complete` is not called); every figure and kept answer is the
    full measure's."""
    from pipeline import residual

    options = F.RunOptions(tolerance=5e-4)
    completed = []
    complete = residual.complete
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(residual, "complete", lambda fr, *a, **k: completed.append(fr.stopped) or complete(fr, *a, **k))
        got = _demo_frames([15], options=options)
    want = _demo_frames([15], settle=False, options=options)
    assert got[3][0] == (True, 1) and len(got[3]) == 3  # the second round measured, so over the tolerance
    assert got[1][0].iterations == 2 and got[1][0].residual_rel <= 5e-4
    assert completed == [] and got[2].count((True, True)) == 1
    _same_outcome(got[:2], want[:2])


def test_an_inner_box_is_the_array_forms_box():
    """`frames._inner_box` of a surface whose patch boxes are not built: the box of its level-0
    CVs mapped by its matrix, shrunk by 1e-9 of the mapping's terms, equal to the array form's
    (numpy's reductions over the mapped CVs' first axis) value for value, and its diagonal bit
    for bit: random grids with signed zeros and coordinates over 12 decades, under rotations,
    scales and translations; a flat grid whose shrinking leaves no box gives ``None`` in both."""
    from acra import hspline as H
    from acra import shapes

    def array_form(g):
        m, t = g.xform[:3, :3], g.xform[:3, 3]
        cvs = g.surface.cvs.reshape(-1, 3)
        world = cvs @ m.T + t
        reach = float(np.abs(t).max() + (np.abs(m) @ np.abs(cvs).max(axis=0)).max())
        lo, hi = world.min(axis=0) + 1e-9 * reach, world.max(axis=0) - 1e-9 * reach
        return (np.stack([lo, hi]), float(np.linalg.norm(hi - lo))) if np.all(lo <= hi) else None

    rng = np.random.default_rng(23)
    for trial in range(80):
        cvs, up, vp = shapes.sphere(2 * int(rng.integers(2, 20)), int(rng.integers(5, 30)))
        cvs = cvs * 10.0 ** rng.integers(-6, 6, size=(*cvs.shape[:2], 1))
        cvs[rng.random(cvs.shape) < 0.1] = 0.0
        cvs[rng.random(cvs.shape) < 0.1] = -0.0
        if trial % 9 == 0:
            cvs[..., 2] = 0.0  # flat: no box left after the shrinking
        c, s = np.cos(rng.uniform(0, 6.3)), np.sin(rng.uniform(0, 6.3))
        xf = np.eye(4)
        if trial % 2:
            xf[:2, :2] = [[c, -s], [s, c]]
        xf[:3, :3] *= rng.uniform(0.5, 2.0, 3)
        xf[:3, 3] = rng.normal(size=3) * rng.choice([0.0, 1.0, 1e3])
        g = geometry.SurfaceGeometry(H.from_grid(cvs, up, vp), xf)
        got, want = F._inner_box(g), array_form(g)
        assert (got is None) == (want is None), trial
        if got is not None:
            assert np.array_equal(got[0], want[0]) and got[1] == want[1], trial


def test_the_frame_loop_hands_its_second_calls_to_one_parked_thread_and_ends_it(monkeypatch):
    """With two threads, the demo's frames 13-14 give one thread's answers bit for bit; every
    second call of the loop (`workers.both`: a closed pair's two sides, a round's two displays)
    runs in the one thread the loop parks (`workers.kept`), which has ended when it returns."""
    import threading

    from numba.core import config

    from pipeline import workers

    one = _demo_frames([13, 14])[:2]
    made, ran = [], []

    class Recorded(workers._Second):
        __slots__ = ()

        def __init__(self):
            super().__init__()
            made.append(self.thread)

    both = workers.both

    def recorded(first, second):
        return both(first, lambda: (ran.append(threading.get_ident()), second())[1])

    before = threading.active_count()
    monkeypatch.setattr(config, "NUMBA_NUM_THREADS", 2)
    monkeypatch.setattr(workers, "_Second", Recorded)
    monkeypatch.setattr(workers, "both", recorded)
    two = _demo_frames([13, 14])[:2]
    _same_outcome(one, two)
    assert len(made) == 1 and len(ran) >= 2 and set(ran) == {made[0].ident}
    assert not made[0].is_alive() and threading.active_count() == before
