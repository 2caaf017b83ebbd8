"""pipeline.display: the run's display topology from every frame's refinement, every frame's points
on it, and the frame loop's per-surface displays."""

import numpy as np
import pytest

from acra import hspline as H
from acra import shapes
from acra.tessellate import grid_samples, pole_normals, run_topology
from conftest import with_random_offsets
from pipeline import display, usdio
from pipeline import frames as F


@pytest.fixture
def pressed(tiny_stage):
    """A 3-level sheet pressed by a box over 4 frames (responses refine it on level 2), the
    frames responded but not yet displayed."""
    path = tiny_stage(frames=4, n=7, levels=3, depth=0.15, samples=2)
    stage = usdio.open_input(path)
    scene = usdio.read_scene(stage)
    result, stats = F.respond_frames(stage, scene, [1, 2, 3, 4])
    return stage, scene, result, stats


def test_the_frame_loop_leaves_the_display_to_the_run(pressed):
    _, scene, result, _ = pressed
    assert all(r.points is None for per in result.frames.values() for r in per.values())


def test_the_run_topology_holds_every_frame_s_own_and_shows_the_refinement(pressed):
    """The union's vertices hold each frame's own adaptive vertices; a responded frame refines
    the sheet where the box pressed, so the run's display is denser than the rest display."""
    _, scene, result, _ = pressed
    (model,) = scene.deformables
    topo = display.run_topologies(scene, result)[model.path]
    sites = set(zip(topo.u, topo.v))
    for per in result.frames.values():
        own = run_topology([per[model.path].surface], model.controls.samples)
        assert set(zip(own.u, own.v)) <= sites
    assert topo.u.size > model.topology.u.size
    assert topo.u.size == run_topology([r[model.path].surface for r in result.frames.values()], 2).u.size


def test_every_frame_is_evaluated_on_the_run_topology_as_a_full_evaluation(pressed):
    """Each distinct surface is evaluated where it differs from the one before it; the points
    equal a full evaluation bit for bit, and unchanged frames share one array."""
    _, scene, result, _ = pressed
    (model,) = scene.deformables
    topologies = display.run_topologies(scene, result)
    ms = display.evaluate_run(scene, result, topologies)
    topo = topologies[model.path]
    assert result.topology(model) is topo and set(ms) == set(result.frames)
    for f, per in result.frames.items():
        r = per[model.path]
        full = grid_samples(r.surface, topo, H.details(r.surface))[0]
        np.testing.assert_array_equal(r.points, full)
        assert r.normals.shape == r.points.shape and np.allclose(np.linalg.norm(r.normals, axis=1), 1.0)
    surfaces = [result.frames[f][model.path].surface for f in sorted(result.frames)]
    for f, g in zip(sorted(result.frames), sorted(result.frames)[1:]):
        if surfaces[f - 1] is surfaces[g - 1]:
            assert result.frames[f][model.path].points is result.frames[g][model.path].points


def test_finish_measures_every_frame_on_the_display(pressed):
    stage, scene, result, stats = pressed
    display.finish(stage, scene, result, stats, F.RunOptions())
    for st in stats:
        assert st.residual_rel <= 1e-3 and st.ms_output >= 0.0
        assert result.frames[st.frame]["/World/Sheet"].residual == st.residual


@pytest.mark.parametrize("seed", [0, 1])
def test_a_responded_surface_s_display_is_its_parent_s_where_it_did_not_change(seed):
    """`Displays.of` evaluates a surface responded from a displayed one only where the response
    changed it (through the shapes' parent chain), and equals a full evaluation: its points and
    limit normals those of `hspline.surface_normals`, bit for bit."""
    from pipeline import shape as S

    rng = np.random.default_rng(seed)
    hs = with_random_offsets(H.make_movable(H.from_grid(*shapes.sphere(12, 10), depth=3), 2, [[10, 14]]), 0.02, seed)
    shown = display.Displays(density=8)
    first = shown.of(hs, 4)
    idx, off = H.offsets_of(hs, 2)
    moved = H.set_offsets(hs, 2, idx, off + rng.normal(scale=0.01, size=off.shape))
    S.seed_details(moved, None, 8, parent=hs)
    second = shown.of(moved, 4)
    full = grid_samples(moved, second.topology, H.details(moved))
    np.testing.assert_array_equal(second.points, full[0])
    np.testing.assert_array_equal(second.normals, full[1])
    for d, hs_ in ((first, hs), (second, moved)):
        ev, normals = H.surface_normals(hs_, d.topology.u, d.topology.v, det=H.details(hs_))
        np.testing.assert_array_equal(d.points, ev.points)
        np.testing.assert_array_equal(d.normals, normals)
        assert not hasattr(d, "tangents")
    assert shown.of(moved, 4) is second and shown.of(hs, 4) is first
    assert second.solid().faces.shape[1] == 3  # a closed sphere's display welds to a solid


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_display_is_evaluated_since_the_last_on_its_topology_with_the_same_level0_cvs(seed, monkeypatch):
    """Two responses of one surface that refine it alike (a held contact's frames, the animator
    moving no level-0 CV): the second is evaluated since the first, on its own topology, not since
    their parent, displayed on a coarser one; on the rows where the two differ alone, and equal to
    a full evaluation bit for bit. A surface whose level-0 CVs differ, or whose parent's display
    is on its own topology, is evaluated since its parent."""
    from acra import tessellate as T
    from pipeline import shape as S

    rng = np.random.default_rng(seed)
    hs = with_random_offsets(H.make_movable(H.from_grid(*shapes.sphere(12, 10), depth=3), 2, [[10, 14]]), 0.02, seed)
    shown = display.Displays(density=8)
    parent = shown.of(hs, 4)
    refined = H.make_movable(hs, 2, [[30, 4]])  # both responses refine one more place
    idx, off = H.offsets_of(refined, 2)

    def response(offsets, of=refined):
        r = H.set_offsets(of, 2, idx, offsets)
        S.seed_details(r, None, 8, parent=hs)
        return r

    first_off = off + rng.normal(scale=0.01, size=off.shape)
    first = shown.of(response(first_off), 4)
    assert first.topology is not parent.topology
    second_off = first_off.copy()
    second_off[:2] += rng.normal(scale=0.01, size=second_off[:2].shape)  # differs from the first on two offsets
    b = response(second_off)
    evaluated = []
    normals_into = T._normals_into

    def counted(hs_, u, v, det, rows, points, limit):
        evaluated.append(len(rows))
        return normals_into(hs_, u, v, det, rows, points, limit)

    monkeypatch.setattr(T, "_normals_into", counted)
    topo = shown.topology(b, 4)[0]
    assert topo is first.topology
    assert shown._nearest(S.shape_of(b, 8), topo) is first
    second = shown.of(b, 4)
    assert 0 < sum(evaluated) < topo.u.size
    full = grid_samples(b, topo, H.details(b))
    np.testing.assert_array_equal(second.points, full[0])
    np.testing.assert_array_equal(second.normals, full[1])
    c = H.with_cvs(b, b.cvs + 1e-3)  # the same fine levels, other level-0 CVs
    S.seed_details(c, None, 8, parent=hs)
    assert shown._nearest(S.shape_of(c, 8), topo) is parent
    # a response on its parent's own topology is evaluated since its parent, not since a later
    # display on that topology (a sibling response)
    i0, o0 = H.offsets_of(hs, 2)
    sibling = H.set_offsets(hs, 2, i0, o0 + rng.normal(scale=0.01, size=o0.shape))
    S.seed_details(sibling, None, 8, parent=hs)
    assert shown.of(sibling, 4).topology is parent.topology
    d = H.set_offsets(hs, 2, i0, o0 + rng.normal(scale=0.01, size=o0.shape))
    S.seed_details(d, None, 8, parent=hs)
    assert shown.topology(d, 4)[0] is parent.topology
    assert shown._nearest(S.shape_of(d, 8), parent.topology) is parent
    for surface in (c, d):
        shown_ = shown.of(surface, 4)
        full = grid_samples(surface, shown_.topology, H.details(surface))
        np.testing.assert_array_equal(shown_.points, full[0])
        np.testing.assert_array_equal(shown_.normals, full[1])


def test_displays_on_one_topology_hold_one_parameter_array():
    """Every display on one topology holds its vertex parameters as one array (the topology's),
    so the residual digests them once (`pipeline.residual.Shown.fingerprint`)."""
    from pipeline import shape as S

    hs = with_random_offsets(H.make_movable(H.from_grid(*shapes.sphere(12, 10), depth=3), 2, [[10, 14]]), 0.02, 0)
    shown = display.Displays(density=8)
    first = shown.of(hs, 4)
    idx, off = H.offsets_of(hs, 2)
    moved = H.set_offsets(hs, 2, idx, off + 0.01)
    S.seed_details(moved, None, 8, parent=hs)
    second = shown.of(moved, 4)
    assert second.topology is first.topology and second.uv is first.uv
    np.testing.assert_array_equal(first.uv, np.stack([first.topology.u, first.topology.v], axis=1))


def test_the_rest_display_s_topology_is_the_one_the_frame_loop_gets(tiny_stage, monkeypatch):
    """Reading a scene keeps its rest display's topology (`display.topology_of`): a round that
    displays the animator's surface, and the run's display of frames that never left it, get
    that object without building it again."""
    stage = usdio.open_input(tiny_stage(frames=4, n=7, levels=3, depth=0.15, samples=2))
    scene = usdio.read_scene(stage)
    (model,) = scene.deformables
    rest = scene.extra["templates"][model.path]
    built = []
    monkeypatch.setattr(display, "run_topology", lambda *a: built.append(a) or run_topology(*a))
    topo, triangles = display.Displays(density=8).topology(rest, model.controls.samples)
    assert topo is model.topology and not built
    np.testing.assert_array_equal(triangles, model.topology.triangles())


def test_the_run_s_display_takes_the_rounds_displays_and_equals_a_full_evaluation(tiny_stage):
    """`evaluate_run` with the frame loop's displays evaluates no vertex they hold again: a
    surface displayed on the run's topology gives its points array itself, and its derivatives
    the normals; the points and normals equal a full evaluation with normals bit for bit."""
    scene, model, shown, result, topologies = _four_responded_frames(tiny_stage)
    topo = topologies[model.path]
    display.evaluate_run(scene, result, topologies, displays=shown)
    taken = sum(d is not None and d.topology is topo and r.points is d.points
                for r, d in _frames_as_evaluated_in_full(result, model, topo, shown))
    assert taken >= 1


def _frames_as_evaluated_in_full(result, model, topo, shown):
    """Each frame's run result of ``model`` and the frame loop's display of its surface (or
    ``None``), once its points and normals are asserted equal to a full evaluation on ``topo``
    with normals, bit for bit."""
    for per in result.frames.values():
        r = per[model.path]
        points, limit = grid_samples(r.surface, topo, H.details(r.surface))
        np.testing.assert_array_equal(r.points, points)
        np.testing.assert_array_equal(r.normals, pole_normals(r.surface, topo, points, limit))
        yield r, shown.shown(r.surface)


def test_the_run_s_residual_takes_the_rounds_shown_objects(tiny_stage, monkeypatch):
    """Where the run shows a round's display points, `residual.measure_run` measures on the
    `residual.Shown` the frame loop built of them (`SurfaceDisplay.view`, its fingerprint taken),
    and the figures are those of a run that builds its own."""
    from pipeline import residual

    stage = usdio.open_input(tiny_stage(frames=4, n=7, levels=3, depth=0.15, samples=2))
    scene = usdio.read_scene(stage)
    (model,) = scene.deformables

    def run(displays):
        seen = []
        real = residual.measure_frame
        monkeypatch.setattr(residual, "measure_frame", lambda objects, *a, **k: seen.append(list(objects))
                            or real(objects, *a, **k))
        result, stats = F.respond_frames(stage, scene, [1, 2, 3, 4], displays=displays)
        seen.clear()
        display.finish(stage, scene, result, stats, F.RunOptions(), displays)
        monkeypatch.setattr(residual, "measure_frame", real)
        return result, stats, seen

    shown = display.Displays(density=8)
    result, stats, seen = run(shown)
    # the frame loop's `Shown` of a display share its part solids; one `measure_run` builds keeps none
    assert seen and all(objects[0].path == model.path and objects[0].parts is not None for objects in seen)
    _, alone, _ = run(None)
    assert [(st.residual, st.pair_residual_rel) for st in stats] == [(st.residual, st.pair_residual_rel) for st in alone]


def _four_responded_frames(tiny_stage):
    """A tiny stage's frames 1-4 through the frame loop with its displays kept: the scene, its
    deformable, the `Displays`, the result and the run's topologies."""
    stage = usdio.open_input(tiny_stage(frames=4, n=7, levels=3, depth=0.15, samples=2))
    scene = usdio.read_scene(stage)
    (model,) = scene.deformables
    shown = display.Displays(density=8)
    result, _ = F.respond_frames(stage, scene, [1, 2, 3, 4], displays=shown)
    return scene, model, shown, result, display.run_topologies(scene, result)


def test_the_run_s_normals_of_a_displayed_surface_come_from_its_display_alone(tiny_stage, monkeypatch):
    """A surface the rounds displayed gets every limit normal from its display (taken where the
    display's vertices were evaluated, copied with the others): no cells are compared with the
    surface before it, and the normals equal a full evaluation's bit for bit."""
    scene, model, shown, result, topologies = _four_responded_frames(tiny_stage)
    compared = []
    real = H.changed_cells
    monkeypatch.setattr(display.hspline, "changed_cells", lambda old, od, new, *a: compared.append(new)
                        or real(old, od, new, *a))
    display.evaluate_run(scene, result, topologies, displays=shown)
    surfaces = [per[model.path].surface for per in result.frames.values()]
    assert any(shown.shown(s) is not None for s in surfaces[1:])
    assert not [s for s in compared if shown.shown(s) is not None]
    for r in (per[model.path] for per in result.frames.values()):
        points, limit = grid_samples(r.surface, topologies[model.path], H.details(r.surface))
        np.testing.assert_array_equal(r.normals, pole_normals(r.surface, topologies[model.path], points, limit))


def test_the_run_s_limit_normals_a_later_frame_reads_are_left_whole(tiny_stage, monkeypatch):
    """`evaluate_run` writes a frame's display normals over its limit normals only where no later
    frame reads them: without the loop's displays every frame but the last is evaluated since the
    one before it, so those keep their limit normals whole (the display normals a copy), and the
    result equals a full evaluation bit for bit; with them, a displayed surface's are written over
    except where they are its display's own (on the run's topology: a later round's display may
    be evaluated since them), which keeps them whole."""
    scene, model, shown, result, topologies = _four_responded_frames(tiny_stage)
    calls = []
    real = display.pole_normals
    monkeypatch.setattr(display, "pole_normals", lambda hs, topo, points, limit, in_place=False: calls.append(
        (hs, in_place)) or real(hs, topo, points, limit, in_place))
    surfaces = [per[model.path].surface for _, per in sorted(result.frames.items())]
    first = list({id(s): s for s in reversed(surfaces)}.values())[::-1]  # each surface once, in frame order

    def read_again(s, displays):
        return any(a is s and b is not a and (displays is None or displays.shown(b) is None)
                   for a, b in zip(surfaces, surfaces[1:]))

    def own(s, displays):
        d = None if displays is None else displays.shown(s)
        return d is not None and d.topology is topologies[model.path]

    assert any(own(s, shown) for s in first)
    for displays in (None, shown):
        calls.clear()
        kept = {id(s): shown.shown(s).normals.copy() for s in first if own(s, shown)}
        display.evaluate_run(scene, result, topologies, displays=displays)
        assert [c[0] for c in calls] == first
        assert [c[1] for c in calls] == [not read_again(s, displays) and not own(s, displays) for s in first]
        for s in first:
            if own(s, shown):
                np.testing.assert_array_equal(shown.shown(s).normals, kept[id(s)])
        for r in (per[model.path] for per in result.frames.values()):
            points, limit = grid_samples(r.surface, topologies[model.path], H.details(r.surface))
            np.testing.assert_array_equal(r.normals, pole_normals(r.surface, topologies[model.path], points, limit))
    assert read_again(first[0], None)  # without the displays the first surface's are read again


def test_the_spent_run_s_display_writes_its_normals_over_the_displays_own(tiny_stage):
    """`evaluate_run` with ``spent`` (no display is read again: `finish`) gives a surface the
    rounds displayed on the run's topology the display's own limit-normal array, written over by
    the display normals (no copy), and every frame's points and normals equal a full evaluation
    bit for bit; `finish` runs it spent."""
    scene, model, shown, result, topologies = _four_responded_frames(tiny_stage)
    topo = topologies[model.path]
    display.evaluate_run(scene, result, topologies, displays=shown, spent=True)
    taken = 0
    for r, d in _frames_as_evaluated_in_full(result, model, topo, shown):
        if d is not None and d.topology is topo:
            assert r.normals is d.normals
            taken += 1
    assert taken >= 1
    stage = usdio.open_input(tiny_stage(frames=4, n=7, levels=3, depth=0.15, samples=2))
    scene = usdio.read_scene(stage)
    (model,) = scene.deformables
    displays = display.Displays(density=8)
    result, stats = F.respond_frames(stage, scene, [1, 2, 3, 4], displays=displays)
    display.finish(stage, scene, result, stats, F.RunOptions(), displays)
    topo = result.topologies[model.path]
    pairs = [(per[model.path], displays.shown(per[model.path].surface)) for per in result.frames.values()]
    on = [(r, d) for r, d in pairs if d is not None and d.topology is topo]
    assert on and all(r.normals is d.normals for r, d in on)


def test_a_display_on_a_topology_of_the_run_s_key_gives_its_points_and_equals_a_full_evaluation(tiny_stage):
    """A topology built apart from the run's (another object) with the same `MeshTopology.key`
    holds the same arrays (`_same_topology`): `evaluate_run` on it gives a surface the rounds
    displayed on the run's topology the display's points array itself, copying no row, and every
    frame's points and normals equal a full evaluation on it bit for bit."""
    scene, model, shown, result, topologies = _four_responded_frames(tiny_stage)
    topo = topologies[model.path]
    surfaces = display._distinct(result, model.path)
    twin = run_topology(surfaces, model.controls.samples)
    assert twin is not topo and twin.key is not None and twin.key == topo.key
    for name in ("u", "v", "counts", "indices"):
        np.testing.assert_array_equal(getattr(twin, name), getattr(topo, name))
    assert display._same_topology(twin, topo) and display._same_topology(topo, topo)
    other = run_topology(surfaces, model.controls.samples + 1)
    assert not display._same_topology(other, topo)
    display.evaluate_run(scene, result, {model.path: twin}, displays=shown, spent=True)
    taken = 0
    for r, d in _frames_as_evaluated_in_full(result, model, twin, shown):
        if d is not None and d.topology is topo:
            assert r.points is d.points and r.normals is d.normals
            taken += 1
    assert taken >= 1


def test_the_run_s_triangles_are_the_kept_topology_s(tiny_stage):
    """`kept_triangles` of a topology `_topology` keeps is the array kept with it (the run's
    residual takes it, built once a round built the topology), equal to ``triangles()``; of
    another topology it builds them."""
    stage = usdio.open_input(tiny_stage(frames=4, n=7, levels=3, depth=0.15, samples=2))
    scene = usdio.read_scene(stage)
    (model,) = scene.deformables
    topo, triangles = display.Displays(density=8).topology(scene.extra["templates"][model.path], 2)
    assert display.kept_triangles(topo) is triangles
    np.testing.assert_array_equal(triangles, topo.triangles())
    other = run_topology([scene.extra["templates"][model.path]], 3)
    np.testing.assert_array_equal(display.kept_triangles(other), other.triangles())


def test_finish_limits_blas_to_one_thread_with_one_controller(pressed, monkeypatch):
    """`finish` holds every BLAS library the process has (numpy's and scipy's, as a fresh scan
    finds them) to one thread while it runs, through one controller built once (`display._blas`),
    and gives their threads back afterwards."""
    from threadpoolctl import ThreadpoolController

    from pipeline import residual

    stage, scene, result, stats = pressed
    seen = []
    measure = residual.measure_run

    def spy(*args, **kwargs):
        seen.append([lib["num_threads"] for lib in ThreadpoolController().info() if lib["user_api"] == "blas"])
        return measure(*args, **kwargs)

    monkeypatch.setattr(residual, "measure_run", spy)
    before = {lib["filepath"]: lib["num_threads"] for lib in ThreadpoolController().info() if lib["user_api"] == "blas"}
    display.finish(stage, scene, result, stats, F.RunOptions())
    controller = display._blas()
    display.finish(stage, scene, result, stats, F.RunOptions())
    assert display._blas() is controller
    assert {lib["filepath"] for lib in controller.info() if lib["user_api"] == "blas"} == set(before)
    assert seen == [[1] * len(before)] * 2
    after = {lib["filepath"]: lib["num_threads"] for lib in ThreadpoolController().info() if lib["user_api"] == "blas"}
    assert after == before


def test_a_dropped_display_and_its_shown_view_are_freed_without_the_cyclic_collector():
    """A display whose `pipeline.residual.Shown` view holds its inside (``solid``, as the frame
    loop builds the view) makes no reference cycle: dropped, its arrays are freed at once, not
    at the cyclic collector's next pass, so a later display reuses their memory. The inside and
    the triangles are the display's own, built once."""
    import gc
    import weakref

    from pipeline import residual

    hs = H.from_grid(*shapes.sphere(12, 10), depth=2)
    shown = display.Displays(density=8, kept=1)
    d = shown.of(hs, 4)
    view = d.view("/s", np.eye(4), lambda d=d: residual.shown("/s", d.points, d.triangles, np.eye(4), d.uv, True, 1.0,
                                                               d.solid, d.parts))
    assert view.whole() is d.solid() and d.triangles is d.triangles
    assert d.solid().faces.shape[1] == 3
    gone, points = weakref.ref(d), weakref.ref(d.points)
    del d, view
    enabled = gc.isenabled()
    gc.disable()
    try:
        shown.of(H.from_grid(*shapes.sphere(12, 10, radii=(2.0, 2.0, 2.0)), depth=2), 4)  # evicts the first (kept=1)
        assert gone() is None and points() is None
    finally:
        if enabled:
            gc.enable()


def _two_objects_responded(seed):
    """A ball and a torus (other grids), each with a response of it that refines one more
    place: ``(ball, torus, ball's response, torus's response)``, the responses' shapes seeded
    with their parents (`pipeline.shape.seed_details`)."""
    from pipeline import shape as S

    rng = np.random.default_rng(seed)
    out = []
    for grid, place in ((shapes.sphere(12, 10), [[10, 14]]), (shapes.torus(12, 8), [[6, 4]])):
        hs = with_random_offsets(H.make_movable(H.from_grid(*grid, depth=3), 2, [place]), 0.02, seed)
        refined = H.make_movable(hs, 2, [[2 * place[0][0] + 4, 2 * place[0][1] + 2]])
        idx, off = H.offsets_of(refined, 2)
        r = H.set_offsets(refined, 2, idx, off + rng.normal(scale=0.01, size=off.shape))
        S.seed_details(r, None, 8, parent=hs)
        out.append((hs, r))
    return out[0][0], out[1][0], out[0][1], out[1][1]


def _tables(shown: display.Displays, names: dict) -> tuple:
    """What ``shown`` and the current memo's display tables hold, in their order, with each
    object identity (a surface, a topology, a display's limit normals) written as its name in
    ``names`` (``id -> name``; "?" for an object not named)."""
    from acra import memo
    from acra import tessellate as T

    def name(i):
        return names.get(i, "?")

    def key(k):
        if k[0] == "matched":
            return ("matched", name(k[1]), name(k[2]))
        return ("cells", name(k[1])) + tuple(k[2:])

    topologies = memo.current().tables.get(display._TOPOLOGIES.name, {})
    nudged = memo.current().tables.get(T._NUDGED.name, {})
    return ([name(k) for k in shown._shown], [key(k) for k in shown._matches],
            [name(id(v[0])) for v in topologies.values()],
            [(name(k), v[1].tolist()) for k, v in nudged.items() if v[0]() is not None])


@pytest.mark.parametrize("seed", [0, 1])
def test_a_round_s_two_displays_built_side_by_side_are_one_thread_s(seed, monkeypatch):
    """`Displays.build` of two objects' responses, each evaluated since its parent's display on
    a topology of its own: with two threads (numba's ``NUMBA_NUM_THREADS``) the two are built
    side by side (`pipeline.workers.both`), and the displays and tables (the displays kept,
    the matches, the topologies, the nudged rows) are those of two `Displays.of` calls one after
    the other, bit for bit and in order, even where the second thread's build ends first (the
    caller's build waits for it here: a build writing the shared tables would put the second
    object's entries first)."""
    import threading

    from numba.core import config

    from acra import memo
    from pipeline import workers

    real_samples = display.grid_samples
    sides: list = []  # one entry a `both` call, True while it runs
    real_both = workers.both

    def counted(f, g):
        sides.append(True)
        try:
            return real_both(f, g)
        finally:
            sides[-1] = False

    monkeypatch.setattr(workers, "both", counted)

    def run(how: str):
        monkeypatch.setattr(config, "NUMBA_NUM_THREADS", 2 if how == "two" else 1)
        second_done = threading.Event()

        def samples(hs, *args, **kwargs):
            main = threading.current_thread() is threading.main_thread()
            if how == "two" and main and sides and sides[-1]:
                assert second_done.wait(60)
            try:
                return real_samples(hs, *args, **kwargs)
            finally:
                if not main:
                    second_done.set()

        monkeypatch.setattr(display, "grid_samples", samples)
        with memo.scope():
            a, b, ra, rb = _two_objects_responded(seed)
            shown = display.Displays(density=8)
            parents = [shown.of(a, 4), shown.of(b, 4)]
            if how == "calls":
                built = [shown.of(ra, 4), shown.of(rb, 4)]
            else:
                built = shown.build([(ra, 4), (rb, 4)])
            assert [d.surface for d in built] == [ra, rb]
            names = {}
            for label, d in zip(("a", "b", "ra", "rb"), parents + built):
                names[id(d.surface)], names[id(d.topology)], names[id(d.normals)] = label, "topo " + label, "normals " + label
            assert built[0].topology is not parents[0].topology and built[1].topology is not parents[1].topology
            return [(d.points, d.normals, d.topology.u, d.topology.v) for d in built], _tables(shown, names)

    calls = run("calls")
    assert not sides
    one = run("one")
    assert len(sides) == 1  # `both` ran the two one after the other
    two = run("two")
    assert len(sides) == 2
    assert calls[1] == one[1] == two[1]
    assert calls[1][0] == ["a", "b", "ra", "rb"] and calls[1][2] == ["topo a", "topo b", "topo ra", "topo rb"]
    assert ("matched", "topo a", "topo ra") in calls[1][1] and ("matched", "topo b", "topo rb") in calls[1][1]
    for got in (one[0], two[0]):
        for x, y in zip(calls[0], got):
            for p, q in zip(x, y):
                np.testing.assert_array_equal(p, q)


def test_a_display_built_since_another_of_the_same_build_waits_for_it(monkeypatch):
    """`Displays.build` of a response and of a second response from it (the later round's): the
    second is evaluated since the first's display, so the two are built one after the other in
    the caller's thread (no `pipeline.workers.both`), as two `Displays.of` calls are."""
    from acra import memo
    from pipeline import shape as S
    from pipeline import workers

    sides: list = []
    monkeypatch.setattr(workers, "both", lambda f, g: sides.append(1))

    def run(together: bool):
        rng = np.random.default_rng(3)
        with memo.scope():
            hs = _two_objects_responded(3)[2]
            idx, off = H.offsets_of(hs, 2)
            again = H.set_offsets(hs, 2, idx, off + rng.normal(scale=0.01, size=off.shape))
            S.seed_details(again, None, 8, parent=hs)
            shown = display.Displays(density=8)
            built = shown.build([(hs, 4), (again, 4)]) if together else [shown.of(hs, 4), shown.of(again, 4)]
            assert built[1].topology is built[0].topology
            names = {id(built[0].surface): "r", id(built[1].surface): "again", id(built[0].topology): "topo",
                     id(built[0].normals): "normals r", id(built[1].normals): "normals again"}
            return [(d.points, d.normals) for d in built], _tables(shown, names)

    alone, together = run(False), run(True)
    assert not sides
    assert alone[1] == together[1]
    for x, y in zip(alone[0], together[0]):
        for p, q in zip(x, y):
            np.testing.assert_array_equal(p, q)


@pytest.mark.parametrize("threads, where", [(1, "build"), (2, "build"), (2, "plan")])
def test_a_build_that_raises_leaves_no_stand_in_in_the_tables(threads, where, monkeypatch):
    """Where a display's evaluation (either thread) or its plan raises inside `Displays.build`,
    the error reaches the caller and neither the kept displays nor the kept topologies hold a
    plan's stand-in (`display._Pending`): the next call builds the display anew."""
    from numba.core import config

    from acra import memo
    from pipeline import shape as S

    monkeypatch.setattr(config, "NUMBA_NUM_THREADS", threads)
    real = display.grid_samples if where == "build" else S.shape_of
    with memo.scope():
        a, b, ra, rb = _two_objects_responded(0)
        shown = display.Displays(density=8)
        shown.of(a, 4), shown.of(b, 4)

        def failing(hs, *args, **kwargs):
            if hs is rb:
                raise KeyboardInterrupt
            return real(hs, *args, **kwargs)

        target = (display, "grid_samples") if where == "build" else (S, "shape_of")
        monkeypatch.setattr(*target, failing)
        with pytest.raises(KeyboardInterrupt):
            shown.build([(ra, 4), (rb, 4)])
        topologies = memo.current().tables[display._TOPOLOGIES.name]
        assert not any(isinstance(x, display._Pending) for x in shown._shown.values())
        assert not any(isinstance(v[0], display._Pending) for v in topologies.values())
        monkeypatch.setattr(*target, real)
        d = shown.of(rb, 4)
        np.testing.assert_array_equal(d.points, grid_samples(rb, d.topology, H.details(rb))[0])


def test_a_refinement_key_is_the_union_of_the_distinct_key_lists():
    """`_refinement` of several surfaces: each level's key bytes are `np.unique` of every
    surface's list, taken over the distinct lists alone; one strictly increasing list is its own
    union, and a list that is not (out of order, or repeating a key) is sorted as `np.unique` does."""
    class Level:
        def __init__(self, patches):
            self.patches = patches

    class Surface:
        u, v, depth = "u", "v", 2

        def __init__(self, patches):
            self._level = Level(patches)

        def level(self, k):
            return self._level

    cases = [[[1, 4, 9]] * 3, [[1, 4, 9], [1, 4, 9], [2, 4]], [[9, 4, 1]] * 2, [[4, 4, 7]] * 2, [[], []], [[5]] * 2,
             [[3, 1], [1, 3]]]
    for lists in cases:
        surfaces = [Surface(np.array(k, np.int64)) for k in lists]
        key = display._refinement(surfaces, 4)
        assert key[:4] == ("u", "v", 2, 4)
        assert key[4] == (np.unique(np.concatenate([np.array(k, np.int64) for k in lists])).tobytes(),)
    one = Surface(np.array([9, 4], np.int64))
    assert display._refinement([one], 4)[4] == (np.array([9, 4], np.int64).tobytes(),)
