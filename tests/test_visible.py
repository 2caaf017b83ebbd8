"""The independent measure of what the user sees (`acceptance.visible`): checked on stages whose
answer is known exactly, then applied to every frame of every scene in ``scenes/``.

Nothing here imports `pipeline` or `acra` (the scene runs come from the session fixture
``run_scene`` of ``conftest.py``, which runs each scene once as ``acra run`` does): the measure
must not share a bug with what it measures. Each scene's output layer is measured at every frame
and compared with the residual the run reported (`acceptance.visible.disagreements`: the measure
within 1e-3 of the object's own size, the report never under it and at most 3 times it, or within
the tolerance). The hard cases are measured the same way in ``tests/test_hard_cases.py``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from pxr import Sdf, Usd, UsdGeom, UsdPhysics

from acceptance.visible import Body, bodies_at, depth_inside, disagreements, measure_layer, triangle_samples, worst_by_frame
from conftest import scene_names


# --- the measure itself, on stages whose answer is known exactly ---------------------------------
def _cube_stage(tmp_path: Path, z: float) -> Path:
    """A unit-spaced 5x5 flat open 'deformable' sheet (display quads) at height ``z`` in a box
    collider ``[-1, 1]^3`` offset by a translate op: the sheet's depth inside is ``1 - |z|``."""
    stage = Usd.Stage.CreateNew(str(tmp_path / f"cube_{z}.usda"))
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(1)
    sheet = UsdGeom.Mesh.Define(stage, "/Sheet")
    n = 5
    x = np.linspace(-2.0, 2.0, n)
    xx, yy = np.meshgrid(x, x, indexing="ij")
    sheet.CreatePointsAttr([(float(a), float(b), z) for a, b in zip(xx.ravel(), yy.ravel())])
    quads = [(i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1) for i in range(n - 1) for j in range(n - 1)]
    sheet.CreateFaceVertexCountsAttr([4] * len(quads))
    sheet.CreateFaceVertexIndicesAttr([k for q in quads for k in q])
    prim = sheet.GetPrim()
    prim.CreateAttribute("acra:cvs", Sdf.ValueTypeNames.Point3fArray).Set([(0, 0, 0)] * 16)
    prim.CreateAttribute("acra:uCount", Sdf.ValueTypeNames.Int).Set(4)
    prim.CreateAttribute("acra:vCount", Sdf.ValueTypeNames.Int).Set(4)
    box = UsdGeom.Mesh.Define(stage, "/Box")
    box.AddTranslateOp().Set((0.5, 0.0, 0.0))
    c = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    box.CreatePointsAttr(c)
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    box.CreateFaceVertexCountsAttr([4] * 6)
    box.CreateFaceVertexIndicesAttr([k for f in faces for k in f])
    UsdPhysics.CollisionAPI.Apply(box.GetPrim())
    stage.Save()
    return Path(stage.GetRootLayer().realPath)


@pytest.mark.parametrize("z", [0.0, 0.25, -0.6, 1.5])
def test_measure_of_a_sheet_in_a_box_is_exact(tmp_path, z):
    """The box spans x in [-0.5, 1.5]: the deepest display vertex, (0, 0, z), is 0.5 from the
    face x = -0.5; the deepest triangle sample, (0.5, 0, z), is 1 from every side face."""
    (m,) = measure_layer(_cube_stage(tmp_path, z))
    size = np.hypot(4.0, 4.0)
    inside = max(0.0, 1.0 - abs(z))
    assert m.samples == pytest.approx(inside / size, rel=1e-6, abs=1e-12)  # float32 points
    assert m.vertices == pytest.approx(min(inside, 0.5) / size, rel=1e-6, abs=1e-12)


def test_triangle_samples_reach_between_vertices():
    """A triangle whose vertices are outside and whose middle is inside a box is caught."""
    mesh = trimesh.Trimesh([[-3, -3, 0.0], [3, -3, 0.0], [0, 3, 0.0]], [[0, 1, 2]], process=False)
    pts = triangle_samples(mesh, 4)
    assert len(pts) == 15
    box = Body("/b", trimesh.creation.box(extents=(1, 1, 1)), True, False)
    assert depth_inside(mesh.vertices, box).max() == 0.0
    assert depth_inside(pts, box).max() == pytest.approx(0.5)


def test_a_closed_display_with_a_crack_is_an_error(tmp_path):
    stage = Usd.Stage.CreateNew(str(tmp_path / "crack.usda"))
    ball = trimesh.creation.icosphere(2)
    mesh = UsdGeom.Mesh.Define(stage, "/Ball")
    mesh.CreatePointsAttr([tuple(map(float, p)) for p in ball.vertices])
    faces = ball.faces[1:]  # one face missing: a hole
    mesh.CreateFaceVertexCountsAttr([3] * len(faces))
    mesh.CreateFaceVertexIndicesAttr([int(k) for k in faces.ravel()])
    UsdPhysics.CollisionAPI.Apply(mesh.GetPrim())
    with pytest.raises(AssertionError, match="not watertight"):
        bodies_at(stage, 0)


# --- every scene, as the user opens it ------------------------------------------------------------
def test_disagreements_name_each_kind_of_fault():
    """Over tolerance, under the measure, far over it; and what passes: a touching frame reported
    at the tolerance, a frame reported between the measure and 3 times it."""
    assert disagreements({1: 2e-3}, {1: 2e-3}) == ["frame 1: measured 2.00e-03 of size, over 1e-03"]
    assert disagreements({1: 4e-4}, {1: 5e-4}) == ["frame 1: reported 4.00e-04 under the measured 5.00e-04"]
    assert disagreements({1: 3e-3}, {1: 9e-4}) == ["frame 1: reported 3.00e-03 over 3 x the measured 9.00e-04 (and over 1e-03)"]
    assert disagreements({1: float("nan")}, {1: 0.0}) == ["frame 1: reported nan under the measured 0.00e+00"]
    assert disagreements({1: 1e-3, 2: 8e-4, 3: 5e-4 - 1e-7}, {1: 0.0, 2: 3e-4, 3: 5e-4}) == []


@pytest.mark.parametrize("name", scene_names())
def test_scene_is_clear_where_the_user_looks(run_scene, name):
    """Every frame of the scene's output layer: display vertices and triangle samples at most 1e-3
    of the object's own size inside any other object, and the run's reported residual at least
    that and at most 3 times it (or within the tolerance)."""
    report = run_scene(name)
    measured = worst_by_frame(measure_layer(report.output, [s.frame for s in report.stats]))
    reported = {s.frame: float(s.residual_rel) for s in report.stats}
    assert disagreements(reported, measured) == []
