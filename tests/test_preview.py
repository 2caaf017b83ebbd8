"""pipeline/preview.py and pipeline/preview_usd.py: conventions, colours, absorption per level, the
framing of the deepest collision, and `acra preview` on the demo's output equal to `acra run --rrd`."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from hypothesis import given, settings
from hypothesis import strategies as st
from rerun.chunk import RrdReader

from acra import hspline
from acra.tessellate import display_topology
from pipeline import preview, preview_usd

ROOT = Path(__file__).parents[1]


def acra(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "pipeline.cli", *map(str, args)], env=env, cwd=cwd,
                          capture_output=True, text=True, timeout=600)


def table(rrd: Path) -> dict:
    """``{entity: {column: {frame (None if static): [cell, ...]}}}`` of a recording's data."""
    out: dict = {}
    for chunk in RrdReader(str(rrd)).stream().to_chunks():
        batch = chunk.to_record_batch()
        names = batch.schema.names
        frames = batch.column("frame").to_pylist() if "frame" in names else [None] * batch.num_rows
        for name in names:
            if name.startswith("rerun.") or name in ("frame", "log_time"):
                continue
            cells = out.setdefault(chunk.entity_path, {}).setdefault(name, {})
            for f, v in zip(frames, batch.column(name).to_pylist()):
                cells.setdefault(f, []).append(v)
    return out


# --- colours ------------------------------------------------------------------------------------

def test_unmoved_vertices_keep_the_objects_colour_and_the_ends_of_the_scale_are_exact():
    size = 2.0
    moved = np.array([0.0, 1e-4 * size, 1e-1 * size, 1e-7 * size, 5.0 * size, 10 ** -2.5 * size])
    c = preview.moved_colours(moved, size, own=(1, 2, 3))
    assert c.dtype == np.uint8 and c.shape == (6, 3)
    assert c[0].tolist() == [1, 2, 3]
    assert c[1].tolist() == preview.VIRIDIS[0].tolist() == c[3].tolist()  # 1e-4 of size and below: dark end
    assert c[2].tolist() == preview.VIRIDIS[-1].tolist() == c[4].tolist()  # 1e-1 and above: bright end
    assert c[5].tolist() == preview.VIRIDIS[4].tolist()  # the middle decade: the middle stop


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(1e-9, 10.0), min_size=2, max_size=20))
def test_colour_brightens_monotonically_with_the_move(moves):
    moves = np.sort(np.array(moves))
    c = preview.moved_colours(moves, 1.0).astype(np.float64)
    brightness = c @ np.array([0.2126, 0.7152, 0.0722])  # viridis is monotone in luminance
    assert np.all(np.diff(brightness) >= -1.0)  # rounding to uint8


def test_view_coordinates_follow_the_up_axis():
    assert preview.view_coordinates("Z") == rr.ViewCoordinates.RIGHT_HAND_Z_UP
    assert preview.view_coordinates("Y") == rr.ViewCoordinates.RIGHT_HAND_Y_UP
    assert preview.up_vector("Z").tolist() == [0, 0, 1] and preview.up_vector("y").tolist() == [0, 1, 0]


# --- geometry helpers ---------------------------------------------------------------------------

def test_fan_triangulation_of_the_written_quads_equals_the_topologys_triangles(sheet4):
    topo = display_topology(sheet4.u, sheet4.v, 3)
    tris = preview_usd.triangulate(np.full(len(topo.quads), 4), topo.quads.reshape(-1))
    assert np.array_equal(tris, topo.triangles())
    pent = preview_usd.triangulate([5, 3], [0, 1, 2, 3, 4, 5, 6, 7])
    assert pent.tolist() == [[0, 1, 2], [0, 2, 3], [0, 3, 4], [5, 6, 7]]


def test_absorbed_by_level_is_the_largest_offset_change_per_level(sheet4):
    sheet4 = hspline.make_movable(sheet4, 2, [[8, 8], [8, 9]])
    idx, off = hspline.offsets_of(sheet4, 2)
    moved = off.copy()
    moved[3] += [0.0, 0.3, 0.4]
    moved[5] += [0.1, 0.0, 0.0]
    responded = hspline.set_offsets(sheet4, 2, idx, moved)
    cvs = responded.cvs.copy()
    cvs[1, 1] += [0.0, 0.0, -0.25]
    from dataclasses import replace

    responded = replace(responded, cvs=cvs)
    a = preview.absorbed_by_level(sheet4, responded)
    assert a.shape == (sheet4.depth,)
    assert a[0] == pytest.approx(0.25, abs=1e-15) and a[2] == pytest.approx(0.5, abs=1e-15)
    assert a[1] == 0.0 and a[3] == 0.0


def test_eye_looks_at_the_dent_from_outside_along_its_normal():
    d = preview.Deepest(7, "/A", 0.1, np.array([1.0, 2.0, 3.0]), np.array([0.0, 1.0, 0.0]), radius=0.5, size=2.0)
    position, target = d.eye()
    assert target.tolist() == [1.0, 2.0, 3.0]
    assert position == pytest.approx([1.0, 2.0 + 2.2 * 0.75, 3.0])  # 1.5 x radius beats 0.2 x size
    d.radius = 0.1
    assert d.eye()[0] == pytest.approx([1.0, 2.0 + 2.2 * 0.4, 3.0])


# --- the demo: a run's recording and the output layer's ------------------------------------------

def stats_residual(out: Path, frame: int) -> float:
    """The frame's residual as the output layer records it: per deformable its
    ``acra:response:residual`` (scene units) over the diagonal of its display's world box."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(out))
    worst = 0.0
    for prim in stage.Traverse():
        if prim.HasAttribute("acra:response:residual"):
            m = np.asarray(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(frame), np.float64).T
            p = np.asarray(UsdGeom.Mesh(prim).GetPointsAttr().Get(frame), np.float64) @ m[:3, :3].T + m[:3, 3]
            worst = max(worst, prim.GetAttribute("acra:response:residual").Get(frame) / np.linalg.norm(np.ptp(p, axis=0)))
    return worst


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """``acra run`` of the demo's frames 1-15 with ``--rrd``, and ``acra preview`` of its output."""
    d = tmp_path_factory.mktemp("demo")
    out, run_rrd, view_rrd = d / "dog.acra.usda", d / "run.rrd", d / "preview.rrd"
    r = acra("run", ROOT / "scenes" / "dog_head_spike.py", "-o", out, "--frames", "1:15", "--rrd", run_rrd, "--quiet")
    assert r.returncode == 0, r.stderr
    p = acra("preview", out, "--rrd", view_rrd)
    assert p.returncode == 0, p.stderr
    return out, table(run_rrd), table(view_rrd), p.stdout


def test_preview_of_the_output_equals_the_runs_recording(demo):
    _, run, view = demo[:3]
    run_only = {e for e in run if any(e.startswith("/" + p) for p in preview.RUN_ONLY)}
    assert run_only >= {"/world/acra/contacts", "/metrics/residual_rel", "/metrics/over_tolerance"}
    assert set(view) == set(run) - run_only  # same entities, minus what only a run knows
    for e in set(view) - {"/__properties"}:
        assert set(view[e]) == set(run[e]), e
        for column in view[e]:
            assert set(view[e][column]) == set(run[e][column]), (e, column)  # same frames
            if e == "/log" and column.endswith("text"):
                continue  # a run's lines say more (rounds, ms)
            assert view[e][column] == run[e][column], (e, column)  # same points, colours, transforms, plots
    frames = set(view["/world/World/Head"]["Mesh3D:vertex_positions"])
    assert frames == set(range(1, 16))


def test_the_recording_shows_the_dent_and_what_it_means(demo):
    out, run, _, stdout = demo
    assert "deepest collision at frame 15 (/World/Head" in stdout
    assert run["/world"]["ViewCoordinates:xyz"][None] == [rr.ViewCoordinates.RIGHT_HAND_Z_UP.as_arrow_array().to_pylist()]
    assert "What the colours mean" in run["/legend"]["TextDocument:text"][None][0][0]
    own = list(preview.DEFORMABLE_COLOUR)
    colours = run["/world/World/Head"]["Mesh3D:vertex_colors"]
    before = np.array(colours[1][0], dtype=np.uint32)
    dent = np.array(colours[15][0], dtype=np.uint32)
    packed_own = (own[0] << 24) | (own[1] << 16) | (own[2] << 8) | 255
    assert np.all(before == packed_own)  # frame 1: no collision, untouched
    assert 20 <= np.count_nonzero(dent != packed_own) < dent.size // 2  # frame 15: the dent, not the head
    log = run["/log"]["TextLog:text"]
    assert any(t[0].startswith("DEEPEST collision: frame 15") for t in log[15])
    absorbed = {k: run[f"/metrics/absorbed/World/Head/level{k}"]["Scalars:scalars"] for k in range(7)}
    assert all(absorbed[k][1] == [[0.0]] for k in range(7))
    assert max(absorbed[k][15][0][0] for k in (2, 3, 4)) > 0.01  # the head absorbs on levels 2-4
    assert absorbed[0][15] == [[0.0]] and absorbed[1][15] == [[0.0]]
    assert run["/metrics/over_tolerance"]["Scalars:scalars"][15] == [[0.0]]
    pair = run["/metrics/pairs/World/Head/vs/World/Jab/Spike"]["Scalars:scalars"]  # the scene's one pair
    worst = run["/metrics/residual_rel"]["Scalars:scalars"]
    assert set(pair) == set(range(1, 16)) and all(pair[f] == worst[f] for f in pair)
    # the residual the run reports at the deepest frame, where the user looks: within the
    # tolerance, and the same figure the plot shows
    assert 0.0 < worst[15][0][0] <= 1e-3 and worst[15][0][0] == pytest.approx(stats_residual(out, 15), rel=1e-12)


# --- bad input ------------------------------------------------------------------------------------

def _one_line_exit_2(r: subprocess.CompletedProcess, *words: str) -> None:
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("acra: error:") and "Traceback" not in r.stderr, r.stderr
    for w in words:
        assert w in lines[0]


def test_bad_input_gets_one_line_and_nothing_written(tmp_path, demo):
    out = demo[0]
    rrd = tmp_path / "x.rrd"
    _one_line_exit_2(acra("preview", tmp_path / "missing.acra.usda", "--rrd", rrd), "missing.acra.usda", "no such file")
    _one_line_exit_2(acra("preview", ROOT / "scenes" / "dog_head_spike.usda", "--rrd", rrd), "holds no ACRA output")
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    _one_line_exit_2(acra("preview", out, "--rrd", blocker / "x.rrd"), "--rrd", "does not exist")
    _one_line_exit_2(acra("preview", out, "--rrd", tmp_path), "--rrd", "is a directory")
    _one_line_exit_2(acra("preview", out), "--rrd FILE, --web or --spawn")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


def test_eye_leaves_the_normal_when_an_object_rests_on_the_dent():
    """A slab right over the dent hides it from the normal: the eye tilts until every region vertex
    is seen; with nothing in the way it stays on the normal."""
    from tests.conftest import BOX_TRIANGLES, BOX_VERTICES

    g = np.linspace(-0.2, 0.2, 5)
    region = np.array([[x, y, 0.0] for x in g for y in g])
    d = preview.Deepest(3, "/Sheet", 0.1, np.zeros(3), np.array([0.0, 0.0, 1.0]), radius=0.2, size=4.0, region=region)
    slab = (BOX_VERTICES * [0.4, 0.4, 0.025] + [0.0, 0.0, 0.275], BOX_TRIANGLES)  # z 0.25..0.3, x, y -0.4..0.4
    floor = (np.array([[-2, -2, -0.01], [2, -2, -0.01], [2, 2, -0.01], [-2, 2, -0.01]], float), np.array([[0, 1, 2], [0, 2, 3]]))
    up = np.array([0.0, 0.0, 1.0])
    position, target = d.eye([floor], up)
    assert position == pytest.approx([0.0, 0.0, d.distance()])  # nothing in the way: on the normal
    position, target = d.eye([floor, slab], up)
    direction = (position - target) / d.distance()
    assert np.degrees(np.arccos(direction[2])) == pytest.approx(75.0)  # 30 and 55 degrees: under the slab
    ray = position - region
    for s in np.linspace(0.02, 0.98, 50):  # every region vertex sees the eye past the slab
        p = region + s * ray
        assert not np.any((np.abs(p[:, 0]) < 0.4) & (np.abs(p[:, 1]) < 0.4) & (p[:, 2] > 0.25) & (p[:, 2] < 0.3))
