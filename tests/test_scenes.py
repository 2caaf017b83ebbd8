"""Every scene file runs through all its frames as `acra run NAME.py --rrd NAME.rrd` would.

Generic checks for each scene (issue #5): residual penetration within 1e-3 of object size at every
frame, every transform unchanged at every frame, finite output, and a readable Rerun recording.
Each scene's own property is tested in ``test_scene_<name>.py``.
"""

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from conftest import scene_names
from pipeline.frames import RunOptions


@pytest.mark.parametrize("name", scene_names())
def test_scene_is_cleared_at_every_frame(run_scene, name):
    report = run_scene(name)
    assert report.stats, "no frames ran"
    worst = max(report.stats, key=lambda s: s.residual_rel)
    assert worst.residual_rel <= 1e-3, f"frame {worst.frame}: residual {worst.residual_rel:.2e} of size"
    assert any(s.in_collision for s in report.stats), "the scene never collides"


@pytest.mark.parametrize("name", scene_names())
def test_scene_clears_within_the_round_cap_and_exits_0(run_scene, name):
    """No frame over tolerance after at most the default cap of detect → respond rounds, so
    `acra run` exits 0 (contract §3: a frame left over tolerance exits 3)."""
    report = run_scene(name)
    assert max(s.iterations for s in report.stats) <= RunOptions().iterations
    assert report.over == [] and report.status == 0


@pytest.mark.parametrize("name", scene_names())
def test_scene_keeps_transforms_and_writes_finite_points(run_scene, name):
    report = run_scene(name)
    src = report.output.with_name(report.output.name.replace(".acra.usda", ".usda"))
    a, b = Usd.Stage.Open(str(src)), Usd.Stage.Open(str(report.output))
    frames = [s.frame for s in report.stats]
    for prim in a.Traverse():
        if not prim.IsA(UsdGeom.Xformable):
            continue
        xa, xb = UsdGeom.Xformable(prim), UsdGeom.Xformable(b.GetPrimAtPath(prim.GetPath()))
        for f in frames:
            assert xa.ComputeLocalToWorldTransform(f) == xb.ComputeLocalToWorldTransform(f), (prim.GetPath(), f)
    for m in report.scene.deformables:
        pts = UsdGeom.Mesh(b.GetPrimAtPath(m.path)).GetPointsAttr()
        for f in frames:
            assert np.all(np.isfinite(np.asarray(pts.Get(f)))), (m.path, f)


@pytest.mark.parametrize("name", scene_names())
def test_scene_recording_reads_back(run_scene, name):
    from rerun.chunk import RrdReader

    report = run_scene(name)
    rrd = report.output.with_name(f"{name}.rrd")
    assert rrd.stat().st_size > 0
    entities = {c.entity_path for c in RrdReader(str(rrd)).stream()}
    assert any("residual" in e for e in entities), sorted(entities)[:10]
