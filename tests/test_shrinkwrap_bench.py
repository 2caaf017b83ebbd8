"""The Shrinkwrap benchmark's own parts that need no Blender: the shared residual measure, welding,
the keyed export and the npz the Blender side reads, the report (benchmarks/shrinkwrap.py)."""

import importlib.util
import re
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("shrinkwrap_bench", ROOT / "benchmarks" / "shrinkwrap.py")
S = sys.modules["shrinkwrap_bench"] = importlib.util.module_from_spec(_spec)  # dataclasses look it up
_spec.loader.exec_module(S)


def unit_box(centre=(0.0, 0.0, 0.0)):
    """A closed unit cube (12 outward triangles): ``(8, 3)``, ``(12, 3)``."""
    import trimesh

    m = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    return np.asarray(m.vertices) + centre, np.asarray(m.faces)


def test_depth_inside_unit_box_is_distance_to_nearest_face():
    v, f = unit_box()
    mesh = S.closed_mesh(v, f)
    pts = np.array([[0.0, 0.0, 0.0], [0.4, 0.0, 0.0], [0.1, -0.45, 0.2], [0.6, 0.0, 0.0], [0.0, 0.0, 2.0]])
    np.testing.assert_allclose(S.depth_inside(pts, mesh), [0.5, 0.1, 0.05, 0.0, 0.0], atol=1e-12)
    assert not np.any(S.depth_inside(pts, None))  # no container: nothing is inside


def test_weld_closes_a_display_sphere_with_poles():
    """A sphere's display grid has a whole row of vertices at each pole and degenerate quads
    there; welded, it is watertight and its volume is close to the ellipsoid's."""
    from acra import hspline as H
    from acra import shapes
    from acra.basis import Direction
    from acra.tessellate import display_topology, evaluate_grid

    cvs, up, vp = shapes.sphere(8, 8, radii=(1.0, 1.0, 1.0))
    hs = H.from_grid(cvs, up, vp)
    topo = display_topology(Direction(8, up), Direction(8, vp), 4)
    pts, _ = evaluate_grid(hs, topo)
    assert S.closed_mesh(pts, topo.triangles()) is None  # raw: two pole rows of duplicates
    w = S.weld(pts, topo.triangles())
    welded = w.apply(pts)
    mesh = S.closed_mesh(welded, w.triangles)
    assert mesh is not None and len(welded) == len(pts) - 2 * (topo.shape[0] - 1)
    # a B-spline sphere lies inside its control net: volume below 4/3 pi, but of that order
    assert 0.5 * 4.18879 < mesh.volume < 4.18879
    # the same weld applies to a moved copy, even one whose pole opened a little
    moved = pts + 1e-8 * np.random.default_rng(0).normal(size=pts.shape)
    assert S.closed_mesh(w.apply(moved), w.triangles) is not None


def test_weld_winds_an_inside_out_mesh_outward():
    v, f = unit_box()
    w = S.weld(v, f[:, ::-1])
    assert S.closed_mesh(w.apply(v), w.triangles).volume == pytest.approx(1.0)


def test_face_samples_are_interior_barycentric_points():
    tri = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    s = S.face_samples(tri, np.array([[0, 1, 2]]), steps=4)
    assert s.shape == (3, 3)  # (4 - 1)(4 - 2) / 2
    assert np.all(s[:, :2] > 0) and np.all(s[:, 0] + s[:, 1] < 1)
    np.testing.assert_allclose(np.sort(s[:, 0]), [0.25, 0.25, 0.5])


def test_crease_over_a_box_edge_is_caught_between_vertices():
    """Shrinkwrap's crease: one vertex on the box's top face, one on its side face, both depth 0,
    yet the triangle between them cuts the edge. The sample at barycentric (1/2, 1/4, 1/4) of
    the triangle below lies 0.075 inside the box (nearest face: the top, at z = 0.5)."""
    v, f = unit_box()
    a = np.array([[0.3, 0.0, 0.5], [0.5, 0.0, 0.0], [0.3, 0.3, 0.5]])
    p = S.pair_residual(a, np.array([[0, 1, 2]]), v, f, size=1.0, b_is_deformable=False)
    assert p.max == 0.0 and p.count == 0
    # samples: (1/4,1/4,1/2) (1/4,1/2,1/4) (1/2,1/4,1/4) of (a0, a1, a2); the deepest is min over faces
    w = np.array([[0.25, 0.25, 0.5], [0.25, 0.5, 0.25], [0.5, 0.25, 0.25]])
    q = w @ a
    expected = np.max(np.min(np.column_stack([0.5 - np.abs(q[:, 0]), 0.5 - np.abs(q[:, 1]), 0.5 - np.abs(q[:, 2])]), axis=1))
    assert p.faces_max == pytest.approx(expected) and expected == pytest.approx(0.125)


def test_pair_residual_sees_a_collider_vertex_inside_a_closed_deformable():
    """A spike whose tip pierces a closed object between its vertices: no vertex of the object is
    inside the spike, but the spike's tip is inside the object (B in A), 0.2 deep."""
    a, fa = unit_box()
    tip = np.array([[0.0, 0.0, 0.3], [-0.05, -0.05, 2.0], [0.05, -0.05, 2.0], [0.0, 0.05, 2.0]])
    tf = np.array([[0, 2, 1], [0, 3, 2], [0, 1, 3], [1, 2, 3]])
    w = S.weld(tip, tf)
    p = S.pair_residual(a, fa, w.apply(tip), w.triangles, size=2.0, b_is_deformable=False)
    assert p.count == 1 and p.max == pytest.approx(0.2 / 2.0) and p.mean == pytest.approx(0.1)


def test_displacement_counts_moves_outside_the_contact():
    keyed = np.zeros((5, 3))
    out = keyed.copy()
    out[0, 2] = -0.3  # in contact, pushed
    out[1, 2] = -0.1  # not in contact, dragged along (a dent)
    out[2, 2] = 1e-9  # below the threshold
    d = S.displacement(keyed, out, np.array([True, False, False, False, False]), size=2.0)
    assert (d.moved, d.free_moved) == (2, 1)
    assert d.free_max == pytest.approx(0.05) and d.max == pytest.approx(0.15)


def test_opposite_moves_counts_vertices_pushed_different_ways():
    keyed = np.zeros((3, 3))
    down = np.array([[0, 0, -0.1]] * 3)
    other = np.array([[0, 0, 0.1], [0.1, 0, -0.01], [0, 0, 0]])
    assert S.opposite_moves(keyed, down, other, size=1.0) == 1  # the third did not move in b


def test_targets_soft_is_wrapped_around_stiff():
    k = S.Keyed(np.arange(1), ["/A", "/B"], [], [], ["/C", "/A", "/B"], [], [], [], [-1, 0, 1], [10.0, 80.0], [], [])
    assert k.targets_of(0) == [0, 2] and k.targets_of(1) == [0]
    k.def_rigidity = [50.0, 50.0]
    assert k.targets_of(0) == [0] and k.targets_of(1) == [0, 1]


@pytest.fixture(scope="module")
def keyed_box(tmp_path_factory):
    from pipeline import usdio

    d = tmp_path_factory.mktemp("sw")
    shutil.copy(ROOT / "scenes" / "box_into_sheet.py", d / "box_into_sheet.py")
    return S.export_keyed(usdio.load_scene_file(d / "box_into_sheet.py"), "10:11"), d


def test_export_is_world_space_and_matches_the_display_topology(keyed_box):
    keyed, _ = keyed_box
    assert list(keyed.frames) == [10, 11] and keyed.def_paths == ["/World/Sheet"]
    sheet = keyed.def_points[0]
    topo = keyed.def_topology[0]  # the input display: no finer level keyed, so a 37 x 37 grid of quads
    assert sheet.shape == (2, 37 * 37, 3) and topo.counts.shape == (36 * 36,) and np.all(topo.counts == 4)
    np.testing.assert_allclose(sheet[:, :, 2], 0.0, atol=1e-12)  # the flat sheet, as keyed
    box10, box11 = keyed.target_world(0, 0), keyed.target_world(0, 1)
    # the scene's keys: z 0.55 at frame 10, -0.2 at 11, box height 1, x 0.2, y -0.1
    np.testing.assert_allclose([box10[:, 2].min(), box10[:, 2].max()], [0.05, 1.05], atol=1e-9)
    np.testing.assert_allclose([box11[:, 2].min(), box11[:, 2].max()], [-0.7, 0.3], atol=1e-9)
    np.testing.assert_allclose(box11[:, :2].mean(axis=0), [0.2, -0.1], atol=1e-9)
    assert keyed.targets_of(0) == [0]  # the box; the sheet's own keyed copy is never its target
    p = S.pair_residual(keyed.def_weld[0].apply(sheet[1]), keyed.def_weld[0].triangles,
                        box11, keyed.tgt_tris[0], S.size_of(sheet[1]), False)
    assert p.count == 81 and p.max * S.size_of(sheet[1]) == pytest.approx(0.3)  # 9 x 9 vertices, 0.3 under the top


def test_npz_holds_what_the_blender_side_reads(keyed_box):
    keyed, d = keyed_box
    keyed.save_npz(d / "k.npz")
    z = np.load(d / "k.npz")
    text = (ROOT / "benchmarks" / "_blender_shrinkwrap.py").read_text()
    for name in z.files:  # every array is documented and read by the Blender side
        key = re.sub(r"^def\d+", "def{i}", re.sub(r"^target\d+", "target{k}", name))
        assert key in text, name
    assert int(z["n_deformables"]) == 1 and int(z["n_targets"]) == 2
    assert z["target0_points"].shape == (1, 8, 3) and z["target0_matrix"].shape == (2, 4, 4)
    assert z["target1_points"].shape[0] == 1  # the sheet is not animated: one object-space sample
    np.testing.assert_array_equal(z["def0_targets"], [0])
    np.testing.assert_array_equal(z["def0_counts"], keyed.def_topology[0].counts)
    assert z["def0_indices"].shape == (int(z["def0_counts"].sum()),) and z["def0_indices"].max() == 37 * 37 - 1


def test_update_doc_replaces_only_its_section(tmp_path):
    doc = tmp_path / "d.md"
    doc.write_text("# T\n\nprose before\n\n<!-- bench:a -->\nold\n<!-- /bench:a -->\n\nprose after\n")
    S.update_doc(doc, "a", "<!-- bench:a -->\nnew\n<!-- /bench:a -->\n")
    S.update_doc(doc, "b", "<!-- bench:b -->\nB\n<!-- /bench:b -->\n")
    text = doc.read_text()
    assert "old" not in text and "new" in text and "prose before" in text and "prose after" in text
    assert text.index("prose after") < text.index("<!-- bench:b -->")


def test_tables_have_a_row_per_frame_and_a_median():
    pen = S.Penetration(0.1, 0.05, 3, 0.2)
    mv = S.Displacement(10, 4, 0.01, 0.1)
    rows = [S.FrameRow(f, pen, (100.0 + f, 1.0), (pen, pen), (mv, mv), 2) for f in (1, 2, 3)]
    text = S.tables(rows)
    assert text.count("| **median** |") == 2 and "| 102.0 | 1.00 |" in text


def test_the_median_times_leave_holds_out_and_say_so():
    """Frames 2 and 3 hold frame 1 (ACRA took its answer): the times' median is frame 1's alone,
    the holds' own median is given beside it, and the quality columns still cover every frame."""
    pen = S.Penetration(0.1, 0.05, 3, 0.2)
    mv = S.Displacement(10, 4, 0.01, 0.1)
    rows = [S.FrameRow(1, pen, (40.0, 2.0), (pen, pen), (mv, mv), 2),
            S.FrameRow(2, pen, (0.5, 2.0), (pen, pen), (mv, mv), 2, hold=True),
            S.FrameRow(3, pen, (0.25, 2.0), (pen, pen), (mv, mv), 2, hold=True)]
    text = S.tables(rows)
    median = next(line for line in text.splitlines() if line.startswith("| **median** | 3 /"))
    assert "| 40.0 | 2.00 | 20.0× |" in median
    assert "| 2 (hold) |" in text and "| 3 (hold) |" in text
    assert "Holds: at frames 2, 3" in text and "0.38 ms against Shrinkwrap's 2.00 ms" in text


def test_an_explicit_venv_without_python_is_an_error(tmp_path):
    with pytest.raises(RuntimeError, match="no python"):
        S.ensure_venv(tmp_path / "nothing")


def test_common_vertices_match_by_surface_parameter():
    a = np.array([[0.0, 0.0], [0.5, 0.0], [1.0, 0.25], [1.0, 1.0]])
    b = np.array([[1.0, 1.0], [0.0, 0.0], [0.75, 0.0]])
    ia, ib = S.common_vertices(a, b)
    np.testing.assert_array_equal(ia, [3, 0])
    np.testing.assert_array_equal(ib, [0, 1])


def test_with_samples_overrides_every_deformable(keyed_box):
    from pipeline import usdio

    _, d = keyed_box
    layer = S.with_samples(d / "box_into_sheet.usda", 2, d)  # the scene's own is 4
    scene = usdio.read_scene(usdio.open_input(layer))
    assert [m.controls.samples for m in scene.deformables] == [2]
    keyed = S.export_keyed(layer, "10:10")
    assert keyed.def_points[0].shape == (1, 19 * 19, 3)  # 2 steps per edge of its 9 x 9 level-0 patches
