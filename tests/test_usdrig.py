"""acra:cvs time samples and the UsdSkel rig, read back through USD."""

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom, UsdSkel, UsdValidation

from pipeline.animation import skinning as sk
from pipeline.animation import usdrig as ur


def new_stage():
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    return stage


def test_flat_order_is_j_times_nu_plus_i():
    cvs = np.random.default_rng(0).normal(size=(5, 7, 3))
    flat = ur.cvs_to_flat(cvs)
    assert np.array_equal(flat[3 * 5 + 2], cvs[2, 3])
    assert np.array_equal(ur.flat_to_cvs(flat, 5, 7), cvs)


def test_cvs_samples_round_trip_to_float32():
    stage = new_stage()
    mesh = UsdGeom.Mesh.Define(stage, "/World/Arm")
    frames = np.arange(1.0, 8.0)
    cvs = sk.bent_arm(np.radians(np.linspace(0, 120, len(frames))), "ccm")
    ur.write_cvs_samples(mesh.GetPrim(), frames, cvs)
    # re-open from text, so nothing is served from an in-memory cache
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.ImportFromString(stage.GetRootLayer().ExportToString())
    reopened = Usd.Stage.Open(layer)
    prim = reopened.GetPrimAtPath("/World/Arm")
    times, back = ur.read_cvs_samples(prim)
    assert np.array_equal(times, frames)
    assert np.array_equal(back, cvs.astype(np.float32).astype(np.float64))
    assert np.abs(back - cvs).max() <= 1e-6 * np.abs(cvs).max()
    attr = prim.GetAttribute("acra:cvs")
    assert attr.GetTypeName() == Sdf.ValueTypeNames.Point3fArray and attr.IsCustom()
    assert prim.GetAttribute("acra:uCount").Get() == 8
    assert prim.GetAttribute("acra:vCount").Get() == 12
    # USD interpolates between samples linearly
    mid = np.asarray(prim.GetAttribute("acra:cvs").Get(1.5), dtype=np.float64)
    assert np.allclose(mid, 0.5 * (ur.cvs_to_flat(back[0]) + ur.cvs_to_flat(back[1])), atol=1e-6)


def test_cvs_samples_go_to_the_edit_target_and_check_counts():
    stage = new_stage()
    UsdGeom.Mesh.Define(stage, "/World/Arm")
    sub = Sdf.Layer.CreateAnonymous("anim.usda")
    stage.GetRootLayer().subLayerPaths.insert(0, sub.identifier)
    stage.SetEditTarget(Usd.EditTarget(sub))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Arm"))     # recomposed after the sublayer
    cvs = np.zeros((2, 4, 5, 3))
    ur.write_cvs_samples(mesh.GetPrim(), [0, 1], cvs)
    assert sub.GetAttributeAtPath("/World/Arm.acra:cvs").GetInfo("timeSamples")
    assert not stage.GetRootLayer().GetAttributeAtPath("/World/Arm.acra:cvs")
    with pytest.raises(ValueError, match="uCount"):
        ur.write_cvs_samples(mesh.GetPrim(), [0], np.zeros((1, 6, 5, 3)))
    with pytest.raises(ValueError):
        ur.write_cvs_samples(mesh.GetPrim(), [0], np.full((1, 4, 5, 3), np.nan))
    with pytest.raises(ValueError):
        ur.write_cvs_samples(stage.GetPrimAtPath("/World"), [0], cvs[:1])


def three_joint_skeleton():
    rest = []
    for k, (axis, ang, off) in enumerate((([0, 0, 1], 0.3, [0.5, 0, 0]),
                                          ([1, 0, 0], -0.6, [2.0, 0.2, 0]),
                                          ([0, 1, 0], 0.9, [1.5, 0, 0.1]))):
        M = np.eye(4)
        M[:3, :3] = sk.quat_to_matrix(sk.quat_from_axis_angle(axis, ang))
        M[:3, 3] = off
        rest.append(M)
    return sk.make_skeleton(["hip", "knee", "ankle"], [-1, 0, 1], rest)


def validation_errors(stage):
    ctx = UsdValidation.ValidationContext(
        UsdValidation.ValidationRegistry().GetOrLoadAllValidators())
    return ctx.Validate(stage)


def test_skeleton_validates_and_matches_forward_kinematics():
    stage = new_stage()
    skel_model = three_joint_skeleton()
    rng = np.random.default_rng(3)
    key_q = sk.quat_normalize(rng.normal(size=(3, 3, 4)))
    rots = sk.interpolate_keys([0, 5, 10], key_q, np.arange(11))
    skel = ur.write_skeleton(stage, "/World/Rig/Skel", skel_model, rots)
    assert stage.GetPrimAtPath("/World/Rig").IsA(UsdSkel.Root)
    assert list(skel.GetJointsAttr().Get()) == ["hip", "hip/knee", "hip/knee/ankle"]
    assert validation_errors(stage) == []
    query = UsdSkel.Cache().GetSkelQuery(skel)
    assert query and query.HasBindPose() and query.HasRestPose()
    bind = np.array([np.array(m).T for m in query.GetJointWorldBindTransforms()])
    assert np.allclose(bind, sk.bind_transforms(skel_model), atol=1e-12)
    for f in range(11):
        ours = sk.forward_kinematics(skel_model, rots[f])
        theirs = np.array([np.array(m).T for m in query.ComputeJointSkelTransforms(f)])
        world = np.array([np.array(m).T for m in
                          query.ComputeJointWorldTransforms(UsdGeom.XformCache(f))])
        assert np.allclose(theirs, ours, atol=2e-6)       # rotations stored as quatf
        assert np.allclose(world, ours, atol=2e-6)        # identity transforms above the skel
        skin = np.array([np.array(m).T for m in query.ComputeSkinningTransforms(f)])
        assert np.allclose(skin, sk.skinning_matrices(skel_model, rots[f]), atol=2e-6)


def test_arm_rig_on_stage_validates():
    stage = new_stage()
    rig = sk.arm_rig()
    angles = np.radians(np.linspace(0, 120, 5))
    ur.write_skeleton(stage, "/World/Arm/Skel", rig.skeleton, sk.arm_pose(rig, angles))
    mesh = UsdGeom.Mesh.Define(stage, "/World/Arm/Skin")
    ur.write_cvs_samples(mesh.GetPrim(), np.arange(5), sk.bent_arm(angles, "dqs", rig))
    assert validation_errors(stage) == []
    # the validators do look at these prims: an unapplied binding property is reported
    bad = stage.DefinePrim("/World/Arm/Bad", "Skeleton")
    bad.CreateRelationship("skel:animationSource").SetTargets(["/World/Arm/Skel/Anim"])
    names = [e.GetName() for e in validation_errors(stage)]
    assert names == ["MissingSkelBindingAPI"]


def test_write_skeleton_checks_shapes():
    stage = new_stage()
    with pytest.raises(ValueError):
        ur.write_skeleton(stage, "/World/S", three_joint_skeleton(), np.zeros((4, 2, 4)))
