"""Quaternions and unit dual quaternions for skeletons, skinning and paths.

Conventions: quaternions are ``(..., 4) float64`` in ``(w, x, y, z)`` order, unit length; all
functions broadcast over leading axes. Transforms are ``(..., 4, 4) float64`` for column vectors:
``x' = M[:3, :3] @ x + M[:3, 3]``. A unit dual quaternion ``(..., 8)`` is ``(q0, qe)`` with the
rotation ``q0`` and ``qe = ½ (0, t) ⊗ q0`` for the translation ``t`` (Kavan et al. 2007).
"""

from __future__ import annotations

import numpy as np

__all__ = ["quat_multiply", "quat_conjugate", "quat_normalize", "quat_from_axis_angle", "quat_to_matrix",
           "matrix_to_quat", "quat_to_rotvec", "quat_slerp", "dq_from_matrix", "dq_to_matrix"]


def quat_multiply(a, b):
    """Hamilton product ``a ⊗ b`` of ``(..., 4)`` quaternions (w, x, y, z); broadcasts."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


def quat_conjugate(q):
    """Conjugate ``(w, -x, -y, -z)`` of ``(..., 4)`` quaternions (the inverse of a unit one)."""
    q = np.asarray(q, dtype=np.float64)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_normalize(q):
    """``(..., 4)`` quaternions scaled to unit length."""
    q = np.asarray(q, dtype=np.float64)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_from_axis_angle(axis, angle):
    """Unit quaternion of a rotation by ``angle : (...)`` radians about ``axis : (..., 3)``."""
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    half = 0.5 * np.asarray(angle, dtype=np.float64)[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * axis], axis=-1)


def quat_to_matrix(q):
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions ``(..., 4)``."""
    w, x, y, z = np.moveaxis(quat_normalize(q), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], axis=-2)


def matrix_to_quat(R):
    """Unit quaternions ``(..., 4)`` with ``w >= 0`` of rotation matrices ``R : (..., 3, 3)``.

    Shepperd's method: take the largest of ``4w², 4x², 4y², 4z²`` as the pivot (stable)."""
    R = np.asarray(R, dtype=np.float64)
    m = R.reshape(-1, 3, 3)
    tr = np.trace(m, axis1=1, axis2=2)
    diag = np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    piv = np.argmax(diag, axis=1)
    q = np.empty((len(m), 4))
    for k in range(4):
        s = piv == k
        if not np.any(s):
            continue
        a = m[s]
        if k == 0:
            r = np.sqrt(1.0 + tr[s]) * 2.0
            q[s] = np.stack([0.25 * r, (a[:, 2, 1] - a[:, 1, 2]) / r,
                             (a[:, 0, 2] - a[:, 2, 0]) / r, (a[:, 1, 0] - a[:, 0, 1]) / r], 1)
        else:
            i = k - 1
            j, l = (i + 1) % 3, (i + 2) % 3
            r = np.sqrt(1.0 + a[:, i, i] - a[:, j, j] - a[:, l, l]) * 2.0
            v = np.empty((len(a), 4))
            v[:, 0] = (a[:, l, j] - a[:, j, l]) / r
            v[:, 1 + i] = 0.25 * r
            v[:, 1 + j] = (a[:, j, i] + a[:, i, j]) / r
            v[:, 1 + l] = (a[:, l, i] + a[:, i, l]) / r
            q[s] = v
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return quat_normalize(q).reshape(R.shape[:-2] + (4,))


def quat_to_rotvec(q):
    """Rotation vectors ``(..., 3)`` (axis × angle, angle in [0, π]) of quaternions ``(..., 4)``:
    the logarithm map, used as pose-space coordinates ("joint angles") by PSD."""
    q = quat_normalize(q)
    q = q * np.where(q[..., :1] < 0, -1.0, 1.0)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1)
    angle = 2.0 * np.arctan2(s, q[..., 0])
    scale = np.where(s > 1e-12, angle / np.maximum(s, 1e-300), 2.0)
    return v * scale[..., None]


def quat_slerp(a, b, t):
    """Spherical linear interpolation from ``a`` to ``b`` (``(..., 4)``) at ``t : (...)``, along the
    shorter arc (``b`` is negated when ``a·b < 0``)."""
    a = quat_normalize(a)
    b = quat_normalize(b)
    t = np.asarray(t, dtype=np.float64)[..., None]
    d = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(d < 0, -b, b)
    d = np.abs(d)
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    s = np.sin(theta)
    small = s < 1e-9
    wa = np.where(small, 1.0 - t, np.sin((1.0 - t) * theta) / np.where(small, 1.0, s))
    wb = np.where(small, t, np.sin(t * theta) / np.where(small, 1.0, s))
    return quat_normalize(wa * a + wb * b)


def dq_from_matrix(M):
    """Unit dual quaternions ``(..., 8)`` = (real, dual) of rigid transforms ``M : (..., 4, 4)``:
    ``q0 = quat(R)``, ``qε = ½ (0, t) ⊗ q0`` (Kavan et al. 2007, §3)."""
    M = np.asarray(M, dtype=np.float64)
    q0 = matrix_to_quat(M[..., :3, :3])
    t = np.concatenate([np.zeros(M.shape[:-2] + (1,)), M[..., :3, 3]], axis=-1)
    return np.concatenate([q0, 0.5 * quat_multiply(t, q0)], axis=-1)


def dq_to_matrix(dq):
    """Rigid transforms ``(..., 4, 4)`` of dual quaternions ``(..., 8)``, normalised first as in
    Kavan et al. 2007 (divide by ``|q0|``; the translation ``2 qε ⊗ q0*`` drops the part of
    ``qε`` that is not orthogonal to ``q0``)."""
    dq = np.asarray(dq, dtype=np.float64)
    n = np.linalg.norm(dq[..., :4], axis=-1, keepdims=True)
    q0, qe = dq[..., :4] / n, dq[..., 4:] / n
    M = np.zeros(dq.shape[:-1] + (4, 4))
    M[..., :3, :3] = quat_to_matrix(q0)
    M[..., :3, 3] = 2.0 * quat_multiply(qe, quat_conjugate(q0))[..., 1:]
    M[..., 3, 3] = 1.0
    return M
