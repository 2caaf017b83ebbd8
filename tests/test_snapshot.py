"""The headless snapshot picks the deepest collision frame and draws every object where USD puts it."""

import shutil
from pathlib import Path

import numpy as np
import pytest

from pipeline import snapshot as S
from pipeline.cli import main

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "box_into_sheet.py"


@pytest.fixture(scope="module")
def box_output(tmp_path_factory):
    d = tmp_path_factory.mktemp("snap")
    shutil.copy(SCENE, d / SCENE.name)
    assert main(["run", str(d / SCENE.name), "--quiet", "--frames", "9:12"]) == 0
    return d / "box_into_sheet.acra.usda"


def test_world_meshes_hold_the_sheet_and_the_box_in_world_space(box_output):
    meshes = {m.path: m for m in S.world_meshes(box_output, 12)}
    assert set(meshes) == {"/World/Sheet", "/World/Mover/Box"}
    box = meshes["/World/Mover/Box"]
    # the unit box keyed at (0.2, -0.1, -0.2) from frame 11 on
    np.testing.assert_allclose(box.points.mean(axis=0), [0.2, -0.1, -0.2], atol=1e-9)
    assert not box.deformable and box.moved.max() == 0.0
    sheet = meshes["/World/Sheet"]
    # pushed at least to the box's bottom face (0.7 deep, tolerance 1e-3 of the 5.7 sheet), at most twice that
    assert sheet.deformable and 0.7 - 5.7e-3 <= sheet.moved.max() <= 1.4
    assert sheet.triangles.max() < len(sheet.points)


def test_faces_become_fans_in_face_order():
    """A face of c corners gives c - 2 triangles fanned from its first corner, in face order."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.CreateInMemory()
    mesh = UsdGeom.Mesh.Define(stage, "/m")
    mesh.CreateFaceVertexCountsAttr([3, 5, 4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 10, 11, 12, 13, 14, 20, 21, 22, 23])
    tris = S._triangles(mesh)
    assert tris.dtype == np.int64
    assert tris.tolist() == [[0, 1, 2], [10, 11, 12], [10, 12, 13], [10, 13, 14], [20, 21, 22], [20, 22, 23]]


def test_world_meshes_take_an_open_stage_as_its_path(box_output):
    from pxr import Usd

    by_path, by_stage = S.world_meshes(box_output, 12), S.world_meshes(Usd.Stage.Open(str(box_output)), 12)
    assert [m.path for m in by_path] == [m.path for m in by_stage]
    for a, b in zip(by_path, by_stage):
        assert np.array_equal(a.points, b.points) and np.array_equal(a.triangles, b.triangles) and np.array_equal(a.moved, b.moved)


def test_deepest_frame_and_png(box_output, tmp_path):
    assert S.deepest_frame(box_output) in (11, 12)
    png = tmp_path / "f.png"
    assert S.main([str(box_output), "-o", str(png)]) == 0
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and 10_000 < len(data) < 400_000
