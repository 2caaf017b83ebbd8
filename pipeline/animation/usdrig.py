"""Writing deformer results and rigs to USD so that any client sees them.

* :func:`write_cvs_samples` — deformed level-0 control grids as ``acra:cvs`` time samples on a
  deformable object's ``UsdGeom.Mesh`` prim (the schema of ``docs/contract.md`` §1: point3f[],
  flat index ``j * uCount + i``), authored through the Sdf API inside one ``Sdf.ChangeBlock``.
* :func:`write_skeleton` — a :class:`~pipeline.animation.skinning.Skeleton` and its key-framed
  joint rotations as a ``UsdSkel.Skeleton`` (joints, rest and bind transforms) with a bound
  ``UsdSkel.Animation``, so usdview, Blender or Houdini can show the rig.

USD matrices are row-vector (``p' = p M``); our transforms are column-vector, so they are
transposed on the way out.  ``GfQuatf`` is stored as ``(x, y, z, w)``; ours are ``(w, x, y, z)``.
"""

from __future__ import annotations

import numpy as np
from pxr import Gf, Sdf, UsdGeom, UsdSkel, Vt

from ..usdio import cvs_to_flat, flat_to_cvs  # the contract's grid order, defined once
from .quaternions import matrix_to_quat, quat_multiply, quat_normalize
from .skinning import Skeleton, bind_transforms

__all__ = ["cvs_to_flat", "flat_to_cvs", "write_cvs_samples", "read_cvs_samples",
           "joint_paths", "write_skeleton"]

CVS_ATTR = "acra:cvs"


def _spec_path(stage, path):
    return stage.GetEditTarget().MapToSpecPath(path)


def write_cvs_samples(prim, frames, cvs_per_frame) -> None:
    """Author ``acra:cvs`` time samples on ``prim`` (a ``UsdGeom.Mesh``) in the stage's edit
    target layer.

    ``frames : (F,)`` time codes; ``cvs_per_frame : (F, nu, nv, 3)`` grids, stored as float32.
    ``acra:uCount``/``acra:vCount`` are authored when absent and must match when present.  The
    attribute is created with the Usd API; the samples are written with
    ``layer.SetTimeSample`` inside ``Sdf.ChangeBlock`` (no Usd calls inside), several times
    faster than ``attr.Set`` per frame."""
    if not prim or not prim.IsA(UsdGeom.Mesh):
        raise ValueError(f"{prim}: write_cvs_samples needs a UsdGeom.Mesh prim")
    C = np.asarray(cvs_per_frame, dtype=np.float64)
    t = np.asarray(frames, dtype=np.float64).ravel()
    if C.ndim != 4 or C.shape[-1] != 3 or len(C) != len(t):
        raise ValueError(f"cvs_per_frame must be (F, nu, nv, 3) with F = {len(t)}, got {C.shape}")
    if not np.all(np.isfinite(C)):
        raise ValueError(f"{prim.GetPath()}: acra:cvs contains NaN or inf")
    nu, nv = C.shape[1:3]
    for name, n in (("acra:uCount", nu), ("acra:vCount", nv)):
        attr = prim.GetAttribute(name)
        if attr and attr.HasAuthoredValue():
            if attr.Get() != n:
                raise ValueError(f"{prim.GetPath()}.{name} is {attr.Get()}, the grid has {n}")
        else:
            prim.CreateAttribute(name, Sdf.ValueTypeNames.Int, custom=True).Set(int(n))
    attr = prim.CreateAttribute(CVS_ATTR, Sdf.ValueTypeNames.Point3fArray, custom=True)
    stage = prim.GetStage()
    layer = stage.GetEditTarget().GetLayer()
    spec = _spec_path(stage, attr.GetPath())
    flat = np.ascontiguousarray(C.transpose(0, 2, 1, 3).reshape(len(C), -1, 3), dtype=np.float32)
    with Sdf.ChangeBlock():
        for ti, f in zip(t, flat):
            layer.SetTimeSample(spec, float(ti), Vt.Vec3fArray.FromNumpy(f))


def read_cvs_samples(prim):
    """``(frames : (F,) float64, cvs : (F, nu, nv, 3) float64)`` — the ``acra:cvs`` time samples
    of ``prim`` as composed on its stage, shaped by ``acra:uCount``/``acra:vCount``."""
    attr = prim.GetAttribute(CVS_ATTR)
    nu, nv = prim.GetAttribute("acra:uCount").Get(), prim.GetAttribute("acra:vCount").Get()
    times = np.array(attr.GetTimeSamples(), dtype=np.float64)
    cvs = np.array([flat_to_cvs(np.asarray(attr.Get(float(t)), dtype=np.float64), nu, nv)
                    for t in times]).reshape(len(times), nu, nv, 3)
    return times, cvs


def joint_paths(skeleton: Skeleton) -> list:
    """UsdSkel joint tokens: each joint's path of names from its root, e.g.
    ``["shoulder", "shoulder/elbow"]`` (the order of ``skeleton.names``)."""
    paths = []
    for j, p in enumerate(skeleton.parents):
        paths.append(skeleton.names[j] if p < 0 else f"{paths[p]}/{skeleton.names[j]}")
    return paths


def _matrix_array(M):
    return Vt.Matrix4dArray([Gf.Matrix4d(m.T.tolist()) for m in np.asarray(M, dtype=np.float64)])


def _xyzw(q):
    q = np.asarray(q, dtype=np.float64)
    return np.ascontiguousarray(q[..., [1, 2, 3, 0]], dtype=np.float32)


def write_skeleton(stage, path, skeleton: Skeleton, rotations_per_frame, frames=None):
    """Define a ``UsdSkel.Skeleton`` at ``path`` with a ``UsdSkel.Animation`` child ``Anim``
    bound as its animation source; returns the ``UsdSkel.Skeleton``.

    ``rotations_per_frame : (F, J, 4)`` our per-frame poses (local rotations relative to rest,
    ``(w, x, y, z)``); ``frames : (F,)`` time codes, default ``0..F-1``.  Authored: ``joints``
    (:func:`joint_paths`), ``jointNames``, ``restTransforms`` (our rest local transforms),
    ``bindTransforms`` (world-space rest pose), and on the animation the constant rest
    ``translations``, unit ``scales`` and time-sampled ``rotations`` = rest rotation ⊗ pose
    rotation, so UsdSkel's joint transforms equal :func:`~.skinning.forward_kinematics`.  If
    ``path``'s parent does not exist yet it is defined as a ``UsdSkel.Root``."""
    path = Sdf.Path(path)
    R = np.asarray(rotations_per_frame, dtype=np.float64)
    J = skeleton.n_joints
    if R.ndim != 3 or R.shape[1:] != (J, 4):
        raise ValueError(f"rotations_per_frame must be (F, {J}, 4), got {R.shape}")
    t = np.arange(len(R), dtype=np.float64) if frames is None else np.asarray(frames, float)
    if len(t) != len(R):
        raise ValueError("frames and rotations_per_frame differ in length")
    parent = path.GetParentPath()
    if parent != Sdf.Path.absoluteRootPath and not stage.GetPrimAtPath(parent):
        UsdSkel.Root.Define(stage, parent)
    skel = UsdSkel.Skeleton.Define(stage, path)
    anim = UsdSkel.Animation.Define(stage, path.AppendChild("Anim"))
    tokens = Vt.TokenArray(joint_paths(skeleton))
    skel.CreateJointsAttr(tokens)
    skel.CreateJointNamesAttr(Vt.TokenArray(list(skeleton.names)))
    skel.CreateRestTransformsAttr(_matrix_array(skeleton.rest_local))
    skel.CreateBindTransformsAttr(_matrix_array(bind_transforms(skeleton)))
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets(
        [anim.GetPath()])
    anim.CreateJointsAttr(tokens)
    anim.CreateTranslationsAttr(Vt.Vec3fArray.FromNumpy(
        np.ascontiguousarray(skeleton.rest_local[:, :3, 3], dtype=np.float32)))
    anim.CreateScalesAttr(Vt.Vec3hArray([Gf.Vec3h(1.0, 1.0, 1.0)] * J))
    rot_attr = anim.CreateRotationsAttr()
    rest_q = matrix_to_quat(skeleton.rest_local[:, :3, :3])
    local = _xyzw(quat_normalize(quat_multiply(rest_q[None], R)))
    layer = stage.GetEditTarget().GetLayer()
    spec = _spec_path(stage, rot_attr.GetPath())
    with Sdf.ChangeBlock():
        for ti, q in zip(t, local):
            layer.SetTimeSample(spec, float(ti), Vt.QuatfArray.FromNumpy(q))
    return skel
