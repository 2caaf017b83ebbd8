"""Skeletons and skinning: LBS, dual-quaternion skinning and pose-space deformation, and the
two-bone "arm" of the CCM paper on which they and the Control Cluster Method are compared.
Quaternions are in :mod:`pipeline.animation.quaternions`, the Control Cluster Method in
:mod:`pipeline.animation.ccm`; both are re-exported here, so every skinning name imports from
this module.

Conventions
-----------
* Quaternions are ``(..., 4) float64`` in ``(w, x, y, z)`` order, unit length.
* Transforms are ``(..., 4, 4) float64`` for column vectors: ``x' = M[:3, :3] @ x + M[:3, 3]``.
  (USD uses row vectors; :mod:`pipeline.animation.usdrig` transposes.)
* A :class:`Skeleton` is the static model (names, parents, rest local transforms); a pose is the
  per-frame state, ``rotations : (J, 4)``, one local quaternion per joint *relative to the rest
  local transform*: ``L_j = Rest_j @ R(q_j)``.  The identity pose is the rest pose, and the bind
  pose ``B_j`` is the world transform of the rest pose.

Sources: Lewis, Cordner & Fong 2000 (PSD); Kavan, Collins, Zara & O'Sullivan 2007 (DQS);
Bukatov, Gridchina & Zastavnoy 2014 (CCM), restated in ``docs/seed-systems.md`` §D.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .ccm import CCMPlan, cardinal_segment, ccm_free_vertices, ccm_plan, procedural_bulge
from .ccm import _kabsch  # noqa: F401  (re-exported with the rest of the CCM)
from .quaternions import (dq_from_matrix, dq_to_matrix, matrix_to_quat, quat_conjugate, quat_from_axis_angle,
                          quat_multiply, quat_normalize, quat_slerp, quat_to_matrix, quat_to_rotvec)

__all__ = [
    # quaternions, dual quaternions
    "quat_multiply", "quat_conjugate", "quat_normalize", "quat_from_axis_angle", "quat_to_matrix",
    "matrix_to_quat", "quat_to_rotvec", "quat_slerp", "dq_from_matrix", "dq_to_matrix",
    # skeleton and poses
    "Skeleton", "make_skeleton", "identity_pose", "forward_kinematics", "bind_transforms",
    "skinning_matrices", "interpolate_keys",
    # skinning
    "lbs", "dqs", "pose_coordinates", "PSDModel", "psd_fit", "psd_displacements", "psd_deform",
    # control cluster method
    "cardinal_segment", "CCMPlan", "ccm_plan", "ccm_free_vertices", "procedural_bulge",
    # the arm experiment
    "tube_mesh", "grid_volume", "ArmRig", "arm_grid", "arm_rig", "arm_pose", "arm_sample",
    "bent_arm", "LABEL_FREE", "LABEL_LBS", "LABEL_SAMPLE", "LABEL_BULGE",
]


# ---------------------------------------------------------------------------------------------
# Skeleton (static model) and poses (per-frame state)
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Skeleton:
    """A joint hierarchy.  ``names : tuple[str]`` (J); ``parents : (J,) int64`` with ``-1`` for a
    root and ``parents[j] < j``; ``rest_local : (J, 4, 4) float64`` rigid rest transforms of each
    joint relative to its parent.  Build with :func:`make_skeleton`."""

    names: tuple
    parents: np.ndarray
    rest_local: np.ndarray

    @property
    def n_joints(self) -> int:
        return len(self.names)


def make_skeleton(names, parents, rest_local) -> Skeleton:
    """Validated :class:`Skeleton`.  ``rest_local : (J, 4, 4)`` must be rigid (orthonormal,
    det +1, last row ``0 0 0 1``) and parents must precede children, so one forward pass of
    :func:`forward_kinematics` suffices."""
    names = tuple(str(n) for n in names)
    parents = np.asarray(parents, dtype=np.int64)
    rest = np.array(rest_local, dtype=np.float64)
    J = len(names)
    if parents.shape != (J,) or rest.shape != (J, 4, 4):
        raise ValueError(f"need {J} parents and (J, 4, 4) rest transforms, got "
                         f"{parents.shape} and {rest.shape}")
    if len(set(names)) != J or any(not n or "/" in n for n in names):
        raise ValueError("joint names must be unique, non-empty and contain no '/'")
    for j, p in enumerate(parents):
        if not -1 <= p < j:
            raise ValueError(f"joint {j} ({names[j]}): parent {p} must be -1 or < {j}")
    R = rest[:, :3, :3]
    if (not np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-9)
            or not np.allclose(np.linalg.det(R), 1.0, atol=1e-9)
            or not np.allclose(rest[:, 3], [0, 0, 0, 1])):
        raise ValueError("rest_local transforms must be rigid (rotation + translation)")
    rest.setflags(write=False)
    parents.setflags(write=False)
    return Skeleton(names, parents, rest)


def forward_kinematics(skeleton: Skeleton, rotations) -> np.ndarray:
    """World transforms ``(..., J, 4, 4)`` of the pose ``rotations : (..., J, 4)``:
    ``W_j = W_parent(j) @ Rest_j @ R(q_j)`` (a child inherits its parent's transform)."""
    q = np.asarray(rotations, dtype=np.float64)
    local = np.broadcast_to(np.eye(4), q.shape[:-1] + (4, 4)).copy()
    local[..., :3, :3] = quat_to_matrix(q)
    local = skeleton.rest_local @ local
    world = np.empty_like(local)
    for j, p in enumerate(skeleton.parents):
        lj = local[..., j, :, :]
        world[..., j, :, :] = lj if p < 0 else world[..., p, :, :] @ lj
    return world


def identity_pose(skeleton: Skeleton) -> np.ndarray:
    """The rest pose: ``(J, 4)`` identity quaternions."""
    q = np.zeros((skeleton.n_joints, 4))
    q[:, 0] = 1.0
    return q


def bind_transforms(skeleton: Skeleton) -> np.ndarray:
    """Bind (rest) world transforms ``B : (J, 4, 4)``, the FK of the identity pose."""
    return forward_kinematics(skeleton, identity_pose(skeleton))


def skinning_matrices(skeleton: Skeleton, rotations) -> np.ndarray:
    """``W_j B_j⁻¹ : (..., J, 4, 4)`` — bind space to posed world space, per joint."""
    return forward_kinematics(skeleton, rotations) @ np.linalg.inv(bind_transforms(skeleton))


def interpolate_keys(key_times, key_rotations, times) -> np.ndarray:
    """Per-frame poses ``(F, J, 4)`` from key poses ``key_rotations : (K, J, 4)`` at increasing
    ``key_times : (K,)``, by slerp between neighbouring keys (held before the first and after
    the last key) — the same interpolation USD applies to quaternion time samples."""
    kt = np.asarray(key_times, dtype=np.float64)
    kq = np.asarray(key_rotations, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64)
    if kt.ndim != 1 or len(kt) != len(kq) or np.any(np.diff(kt) <= 0):
        raise ValueError("key_times must be strictly increasing and match key_rotations")
    seg = np.clip(np.searchsorted(kt, t, side="right") - 1, 0, max(len(kt) - 2, 0))
    if len(kt) == 1:
        return np.broadcast_to(kq[0], (len(t),) + kq.shape[1:]).copy()
    a = np.clip((t - kt[seg]) / (kt[seg + 1] - kt[seg]), 0.0, 1.0)
    return quat_slerp(kq[seg], kq[seg + 1], np.broadcast_to(a[:, None], kq[seg].shape[:-1]))


# ---------------------------------------------------------------------------------------------
# LBS and DQS
# ---------------------------------------------------------------------------------------------

def _check_weights(points, weights, mats):
    P = np.asarray(points, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    M = np.asarray(mats, dtype=np.float64)
    if P.shape[-1] != 3 or w.shape != P.shape[:-1] + (M.shape[-3],):
        raise ValueError(f"points (..., 3), weights (..., J) and mats (J, 4, 4) disagree: "
                         f"{P.shape}, {w.shape}, {M.shape}")
    if not np.allclose(w.sum(-1), 1.0, atol=1e-9) or np.any(w < -1e-12):
        raise ValueError("skin weights must be non-negative and sum to 1 per vertex")
    return P, w, M


def lbs(points, weights, skin_mats) -> np.ndarray:
    """Linear blend skinning ``v' = Σ_j w_j (W_j B_j⁻¹) v``.

    ``points : (..., 3)`` bind-space positions, ``weights : (..., J)`` (rows sum to 1),
    ``skin_mats : (J, 4, 4)`` from :func:`skinning_matrices`.  Returns ``(..., 3) float64``."""
    P, w, M = _check_weights(points, weights, skin_mats)
    A = np.einsum("...j,jab->...ab", w, M)
    return np.einsum("...ab,...b->...a", A[..., :3, :3], P) + A[..., :3, 3]


def dqs(points, weights, skin_mats) -> np.ndarray:
    """Dual-quaternion skinning (Kavan et al. 2007, "DLB"): blend the joints' unit dual
    quaternions ``b = Σ_j w_j ŝ_j q̂_j`` — each sign ``ŝ_j`` chosen so the real part lies in the
    hemisphere of the vertex's most weighted joint (antipodality) — normalise by ``|b0|`` and
    apply the resulting rigid transform.  Same arguments and result as :func:`lbs`."""
    P, w, M = _check_weights(points, weights, skin_mats)
    dq = dq_from_matrix(M)                                    # (J, 8)
    flat_w = w.reshape(-1, w.shape[-1])
    pivot = dq[np.argmax(flat_w, axis=1), :4]                 # (n, 4)
    sign = np.where(pivot @ dq[:, :4].T < 0, -1.0, 1.0)       # (n, J)
    b = (flat_w * sign) @ dq                                  # (n, 8)
    T = dq_to_matrix(b)
    out = np.einsum("nab,nb->na", T[:, :3, :3], P.reshape(-1, 3)) + T[:, :3, 3]
    return out.reshape(P.shape)


# ---------------------------------------------------------------------------------------------
# Pose-space deformation (Lewis et al. 2000)
# ---------------------------------------------------------------------------------------------

def pose_coordinates(rotations, joints) -> np.ndarray:
    """Pose-space coordinates ``(..., 3k)``: the rotation vectors (joint angles, radians) of the
    local rotations of ``joints`` (k indices) in pose ``rotations : (..., J, 4)``."""
    q = np.asarray(rotations, dtype=np.float64)[..., list(joints), :]
    rv = quat_to_rotvec(q)
    return rv.reshape(rv.shape[:-2] + (-1,))


@dataclass(frozen=True)
class PSDModel:
    """A fitted pose-space deformation (static model).

    ``vertices : (m,) int64`` flat indices of the sampled vertices; ``joints : (k,) int64``
    joints spanning pose space; ``centers : (S, 3k)`` pose-space sample positions (the rest pose
    included as a zero-displacement sample); ``coeffs : (S, m, 3)`` Gaussian-RBF weights of the
    bind-space displacements; ``sigma`` the RBF width (radians)."""

    vertices: np.ndarray
    joints: np.ndarray
    centers: np.ndarray
    coeffs: np.ndarray
    sigma: float


def _lbs_affine(weights, skin_mats):
    A = np.einsum("nj,jab->nab", weights, skin_mats)
    return A[:, :3, :3], A[:, :3, 3]


def psd_fit(skeleton: Skeleton, rest_points, weights, vertices, sample_rotations,
            sample_shapes, joints, sigma=None, include_rest=True) -> PSDModel:
    """Fit PSD correctives from sample pairs ``<X, S>`` (Lewis et al. 2000; CCM paper eq. 3).

    ``rest_points : (n, 3)`` bind positions, ``weights : (n, J)``, ``vertices : (m,)`` the sampled
    vertices (flat indices), ``sample_rotations : (S, J, 4)`` the sample poses,
    ``sample_shapes : (S, m, 3)`` the sculpted positions of those vertices at those poses.

    Each displacement inverts the skinning at its sample pose,
    ``d = LBS⁻¹(x) − v0 = A⁻¹ (x − b) − v0`` with ``A, b`` the blended matrix ``Σ w_j W_j B_j⁻¹``,
    so ``LBS(v0 + d)`` reproduces the sample exactly.  ``d`` lives in bind space, i.e. it is
    carried by the bones' frames: ``B_j⁻¹ (v0 + d) = B_j⁻¹ v0 + R_Bjᵀ d``, the displacement stored
    in bone ``j``'s frame.  Between samples ``d`` is interpolated by Gaussian radial basis
    functions ``φ(r) = exp(−r² / 2σ²)`` over :func:`pose_coordinates` of ``joints``; the rest
    pose is an extra sample with ``d = 0`` (``include_rest``).  ``sigma`` defaults to the
    smallest distance between two samples."""
    P = np.asarray(rest_points, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    vid = np.asarray(vertices, dtype=np.int64).ravel()
    rots = np.asarray(sample_rotations, dtype=np.float64)
    X = np.asarray(sample_shapes, dtype=np.float64)
    if X.shape != (len(rots), len(vid), 3):
        raise ValueError(f"sample_shapes must be (S, m, 3) = {(len(rots), len(vid), 3)}, "
                         f"got {X.shape}")
    joints = np.asarray(joints, dtype=np.int64).ravel()
    disp = []
    for rq, x in zip(rots, X):
        A, b = _lbs_affine(w[vid], skinning_matrices(skeleton, rq))
        v = np.linalg.solve(A, (x - b)[..., None])[..., 0]
        disp.append(v - P[vid])
    centers = pose_coordinates(rots, joints)
    disp = np.array(disp)
    if include_rest:
        centers = np.vstack([pose_coordinates(identity_pose(skeleton), joints)[None], centers])
        disp = np.concatenate([np.zeros((1,) + disp.shape[1:]), disp])
    D = np.linalg.norm(centers[:, None] - centers[None], axis=-1)
    if sigma is None:
        off = D[~np.eye(len(D), dtype=bool)]
        if off.size == 0 or off.min() <= 0:
            raise ValueError("need at least two distinct sample poses to choose sigma")
        sigma = float(off.min())
    Phi = np.exp(-0.5 * (D / sigma) ** 2)
    coeffs = np.linalg.solve(Phi, disp.reshape(len(disp), -1)).reshape(disp.shape)
    return PSDModel(vid, joints, centers, coeffs, float(sigma))


def psd_displacements(model: PSDModel, rotations) -> np.ndarray:
    """Bind-space corrective displacements ``(m, 3)`` of ``model.vertices`` at pose
    ``rotations : (J, 4)``: ``d(x) = Σ_s c_s φ(|x − x_s|)``; equals the sampled ``d`` at every
    sample pose."""
    x = pose_coordinates(rotations, model.joints)
    phi = np.exp(-0.5 * (np.linalg.norm(model.centers - x, axis=-1) / model.sigma) ** 2)
    return np.einsum("s,smc->mc", phi, model.coeffs)


def psd_deform(model: PSDModel, skeleton: Skeleton, rest_points, weights, rotations) -> np.ndarray:
    """PSD-corrected skinning of all points: ``LBS(v0 + d(pose))`` (CCM paper eq. 4), with
    ``d = 0`` on vertices the model does not sample.  ``rest_points : (n, 3)``,
    ``weights : (n, J)``, ``rotations : (J, 4)``; returns ``(n, 3)``."""
    P = np.array(rest_points, dtype=np.float64)
    P[model.vertices] += psd_displacements(model, rotations)
    return lbs(P, weights, skinning_matrices(skeleton, rotations))


# ---------------------------------------------------------------------------------------------
# Volume of a closed grid (for the arm experiment)
# ---------------------------------------------------------------------------------------------

def _bspline_matrix(n, samples, periodic):
    """``(N, n)`` matrix evaluating a uniform cubic B-spline curve with ``n`` CVs at ``samples``
    points per span (periodic: ``n`` spans; open: ``n − 3`` spans, end point included), with
    the basis ``B0..B3`` of ``docs`` (acra-notes §1)."""
    spans = n if periodic else n - 3
    r = np.arange(spans * samples + (0 if periodic else 1))
    seg, t = np.divmod(r, samples)
    t = t / samples
    end = seg == spans
    seg[end], t[end] = spans - 1, 1.0
    b = np.stack([(1 - t) ** 3, 3 * t ** 3 - 6 * t ** 2 + 4,
                  -3 * t ** 3 + 3 * t ** 2 + 3 * t + 1, t ** 3], axis=1) / 6.0
    C = np.zeros((len(r), n))
    np.add.at(C, (np.repeat(r, 4), ((seg[:, None] + np.arange(4)) % n).ravel()), b.ravel())
    return C


def tube_mesh(cvs, wrap=(True, False), samples=0):
    """Closed triangle mesh ``(vertices : (k, 3) float64, faces : (f, 3) int64)`` of a tube-like
    grid ``cvs : (nu, nv, 3)`` periodic in u, consistently oriented.

    ``samples = 0`` gives the control polyhedron: the grid's quads split into two triangles,
    each open end capped by a fan to its end ring's centroid.  ``samples > 0`` tessellates the
    bicubic B-spline surface instead (``samples`` steps per patch edge), capped the same way."""
    P = np.asarray(cvs, dtype=np.float64)
    if not wrap[0]:
        raise ValueError("tube_mesh needs a grid that is periodic in u (a tube)")
    if samples:
        Cu = _bspline_matrix(P.shape[0], samples, True)
        Cv = _bspline_matrix(P.shape[1], samples, bool(wrap[1]))
        P = np.einsum("ai,ijc,bj->abc", Cu, P, Cv)
    nu, nv = P.shape[:2]
    idx = np.arange(nu * nv).reshape(nu, nv)
    i = np.arange(nu)[:, None]
    j = np.arange(nv if wrap[1] else nv - 1)[None, :]
    a, b = idx[i, j], idx[(i + 1) % nu, j]
    c, d = idx[(i + 1) % nu, (j + 1) % nv], idx[i, (j + 1) % nv]
    faces = [np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)]
    V = [P.reshape(-1, 3)]
    if not wrap[1]:
        k, k1 = np.arange(nu), (np.arange(nu) + 1) % nu
        for n_cap, (jj, flip) in enumerate(((0, True), (nv - 1, False))):
            V.append(P[:, jj].mean(axis=0)[None])
            cen = np.full(nu, nu * nv + n_cap)
            tri = (cen, idx[k1, jj], idx[k, jj]) if flip else (cen, idx[k, jj], idx[k1, jj])
            faces.append(np.stack(tri, -1))
    return np.vstack(V), np.vstack(faces).astype(np.int64)


def grid_volume(cvs, wrap=(True, False), samples=0) -> float:
    """Enclosed volume of :func:`tube_mesh` (control polyhedron for ``samples = 0``, bicubic
    surface otherwise) by the divergence theorem, ``|Σ a · (b × c)| / 6`` over its triangles
    (signed, so a fold that overlaps itself counts once per winding)."""
    V, F = tube_mesh(cvs, wrap, samples)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(abs(np.einsum("ij,ij->", a, np.cross(b, c))) / 6.0)


# ---------------------------------------------------------------------------------------------
# The CCM paper's experiment: a cylinder "arm" on a two-bone skeleton
# ---------------------------------------------------------------------------------------------

LABEL_FREE, LABEL_LBS, LABEL_SAMPLE, LABEL_BULGE = 0, 1, 2, 3


def arm_grid(n_around=8, n_along=12, radius=1.0, length=11.0) -> np.ndarray:
    """Rest control grid ``(n_around, n_along, 3) float64`` of a cylinder along +x from
    ``x = 0`` to ``x = length``: ``cvs[i, j] = (x_j, r cos φ_i, r sin φ_i)``, ``φ_i = 2π i /
    n_around``.  Periodic in u (around), open in v (along).  Vertex column ``i = 0`` faces +y,
    the inside of the elbow bend of :func:`arm_pose`; ``i = n_around/2`` faces −y, the outside."""
    phi = 2.0 * np.pi * np.arange(n_around) / n_around
    x = np.linspace(0.0, length, n_along)
    cvs = np.empty((n_around, n_along, 3))
    cvs[..., 0] = x[None, :]
    cvs[..., 1] = radius * np.cos(phi)[:, None]
    cvs[..., 2] = radius * np.sin(phi)[:, None]
    return cvs


@dataclass(frozen=True)
class ArmRig:
    """The static arm model (see :func:`arm_rig`).  ``rest : (nu, nv, 3)`` grid, wrap
    ``(True, False)``; ``skeleton`` with joints ``shoulder`` (x = 0) and ``elbow``
    (x = ``elbow``); ``weights : (nu, nv, 2)``; ``labels : (nu, nv) int8`` CCM vertex groups
    (``LABEL_FREE`` 0, ``LABEL_LBS`` 1, ``LABEL_SAMPLE`` 2, ``LABEL_BULGE`` 3);
    ``psd_vertices : (12,) int64`` and ``ccm_sample_vertices : (4,) int64`` (counts for the
    default 8 × 12 grid) flat C-order indices of the vertices PSD resp. the CCM sample cluster
    take from the sculpted sample; ``sample_angle`` (radians) the pose of that one sample;
    ``blend`` the half-width of the weight ramp; ``plan`` the :class:`CCMPlan`; ``bulge`` the
    keyword arguments of :func:`procedural_bulge` (without ``angle``)."""

    rest: np.ndarray
    skeleton: Skeleton
    weights: np.ndarray
    labels: np.ndarray
    psd_vertices: np.ndarray
    ccm_sample_vertices: np.ndarray
    sample_angle: float
    elbow: float
    blend: float
    plan: CCMPlan
    bulge: dict


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def arm_rig(n_around=8, n_along=12, radius=1.0, length=11.0, elbow=None, blend=2.0,
            sample_angle=np.radians(120.0), bulge_gain=0.0, tension=-0.5) -> ArmRig:
    """Build the arm experiment's rig (CCM paper §5, Fig. 1).

    Joints ``shoulder`` at x = 0 and ``elbow`` at x = ``elbow`` (default mid-length).  The elbow
    joint's skin weight is ``smoothstep((x − elbow + blend) / 2 blend)``, so the rings within
    ``blend`` of the elbow blend both bones (4 rings with the defaults).  Vertex groups, on the
    blended rings only (all other vertices are LBS clusters, "red"):

    * the *outer region*: the columns within 45° of the outside of the bend (−y; 3 columns of 8);
      PSD takes all of them from the sculpted sample — 3 × 4 = **12 vertices**;
    * the CCM sample cluster ("yellow"): the outer column alone — **4 vertices**;
    * CCM free vertices ("blue"): the rest of the outer region, placed by cardinal splines;
    * with ``bulge_gain > 0``, the inner side (+y) of the upper arm is a procedural bulge
      cluster ("green", :func:`procedural_bulge`); its shape does not change the volume test,
      which like the paper's Fig. 2 runs without bulge."""
    rest = arm_grid(n_around, n_along, radius, length)
    nu, nv = rest.shape[:2]
    elbow = 0.5 * length if elbow is None else float(elbow)
    E = np.eye(4)
    E[0, 3] = elbow
    skel = make_skeleton(["shoulder", "elbow"], [-1, 0], [np.eye(4), E])
    w1 = _smoothstep((rest[..., 0] - elbow + blend) / (2.0 * blend))
    weights = np.stack([1.0 - w1, w1], axis=-1)
    blended = (w1 > 0.0) & (w1 < 1.0)
    phi = 2.0 * np.pi * np.arange(nu) / nu
    from_outside = np.abs(np.angle(np.exp(1j * (phi - np.pi))))        # (nu,) radians
    region = blended & (from_outside <= np.pi / 4 + 1e-9)[:, None]
    sample = blended & (from_outside == from_outside.min())[:, None]
    labels = np.full((nu, nv), LABEL_LBS, dtype=np.int8)
    labels[region] = LABEL_FREE
    labels[sample] = LABEL_SAMPLE
    bulge = dict(axis_origin=np.zeros(3), axis_dir=np.array([1.0, 0.0, 0.0]), gain=bulge_gain,
                 center=0.5 * (elbow - blend), half_width=0.5 * (elbow - blend),
                 side=np.array([0.0, 1.0, 0.0]))
    if bulge_gain:
        d = procedural_bulge(rest, **bulge, angle=np.pi)           # full amplitude
        moves = np.linalg.norm(d, axis=-1) > 1e-9 * abs(bulge_gain)  # not cos 90° ≈ 6e-17
        labels[moves & (labels == LABEL_LBS)] = LABEL_BULGE
    plan = ccm_plan(rest, labels != LABEL_FREE, (True, False), tension)
    return ArmRig(rest, skel, weights, labels, np.flatnonzero(region.ravel()),
                  np.flatnonzero(sample.ravel()), float(sample_angle), elbow, float(blend),
                  plan, bulge)


def arm_pose(rig: ArmRig, angle) -> np.ndarray:
    """Pose ``(2, 4)`` — or ``(F, 2, 4)`` for ``angle : (F,)`` — with the elbow bent by
    ``angle`` radians about +z (the forearm swings toward +y); feed it to
    :func:`~pipeline.animation.usdrig.write_skeleton`."""
    a = np.asarray(angle, dtype=np.float64)
    q = np.broadcast_to(identity_pose(rig.skeleton), a.shape + (2, 4)).copy()
    q[..., 1, :] = quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), a)
    return q


def arm_sample(rig: ArmRig, angle) -> np.ndarray:
    """The sculpted sample shape ``(nu, nv, 3)`` at elbow angle ``angle`` — the stand-in for an
    artist's sculpt that PSD and the CCM sample cluster learn from.  Every rest ring is turned
    rigidly about the elbow axis by ``φ(x) = angle · smoothstep((x − elbow + blend) / 2 blend)``
    (the skin weights' ramp).  In the continuum this keeps the volume exactly: the map's Jacobian
    is ``1 − φ'(x) y`` (``x, y`` relative to the elbow, ``y`` toward the bend), which averages to
    1 over a cross-section symmetric in ``y`` (no fold while ``|φ'| r < 1``)."""
    P = rig.rest
    phi = angle * _smoothstep((P[..., 0] - rig.elbow + rig.blend) / (2.0 * rig.blend))
    c, s = np.cos(phi), np.sin(phi)
    x, y = P[..., 0] - rig.elbow, P[..., 1]
    out = P.copy()
    out[..., 0] = rig.elbow + c * x - s * y
    out[..., 1] = s * x + c * y
    return out


def _arm_psd(rig: ArmRig, vertices) -> PSDModel:
    shape = arm_sample(rig, rig.sample_angle).reshape(-1, 3)[vertices]
    return psd_fit(rig.skeleton, rig.rest.reshape(-1, 3), rig.weights.reshape(-1, 2), vertices,
                   arm_pose(rig, rig.sample_angle)[None], shape[None], joints=[1])


def bent_arm(angles, method="ccm", rig: ArmRig | None = None) -> np.ndarray:
    """Per-frame deformed control grids ``(F, nu, nv, 3) float64`` of the arm bent to
    ``angles : (F,)`` radians by ``method`` in {"lbs", "dqs", "psd", "ccm"}.  ``rig`` defaults
    to :func:`arm_rig`.  A scene authors the skinned arm with
    `pipeline.authoring.add_skinned_arm`, which writes these grids as ``acra:cvs`` time samples
    beside the UsdSkel skeleton posed by :func:`arm_pose`."""
    rig = arm_rig() if rig is None else rig
    if method not in ("lbs", "dqs", "psd", "ccm"):
        raise ValueError(f"unknown method {method!r}")
    nu, nv = rig.rest.shape[:2]
    P = rig.rest.reshape(-1, 3)
    W = rig.weights.reshape(-1, 2)
    if method == "psd":
        model = _arm_psd(rig, rig.psd_vertices)
    elif method == "ccm":
        model = _arm_psd(rig, rig.ccm_sample_vertices)
        bulge_ids = np.flatnonzero(rig.labels.ravel() == LABEL_BULGE)
    frames = []
    for a in np.atleast_1d(np.asarray(angles, dtype=np.float64)):
        pose = arm_pose(rig, a)
        M = skinning_matrices(rig.skeleton, pose)
        if method == "lbs":
            X = lbs(P, W, M)
        elif method == "dqs":
            X = dqs(P, W, M)
        elif method == "psd":
            X = psd_deform(model, rig.skeleton, P, W, pose)
        else:
            V = P.copy()
            V[model.vertices] += psd_displacements(model, pose)
            if len(bulge_ids):
                V[bulge_ids] += procedural_bulge(P[bulge_ids], **rig.bulge, angle=a)
            X = ccm_free_vertices(rig.plan, lbs(V, W, M).reshape(nu, nv, 3))
        frames.append(X.reshape(nu, nv, 3))
    return np.array(frames)
