"""Unit quaternions ``(w, x, y, z)`` for the rotational response (thesis §4.3.3): from an axis and
an angle, rotating vectors, and the mean of a set of rotations by successive slerp.
"""

from __future__ import annotations

import numpy as np

__all__ = ["quat_from_axis_angle", "quat_rotate", "slerp_mean"]


def quat_from_axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(m, 4)`` as ``(w, x, y, z)`` from unit axes ``(m, 3)`` and angles ``(m,)``."""
    axis = np.atleast_2d(axis)
    half = 0.5 * np.atleast_1d(angle)
    return np.concatenate([np.cos(half)[:, None], np.sin(half)[:, None] * axis], axis=1)


def quat_rotate(q: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Rotate vectors ``x (m, 3)`` by unit quaternions ``q (m, 4)``."""
    w, v = q[:, :1], q[:, 1:]
    t = 2.0 * np.cross(v, x)
    return x + w * t + np.cross(v, t)


def slerp_mean(qs: np.ndarray) -> np.ndarray:
    """Mean of unit quaternions ``(n, 4)`` by successive slerp with weights ``1/i``."""
    acc = qs[0]
    for i in range(1, qs.shape[0]):
        q = qs[i] if np.dot(acc, qs[i]) >= 0 else -qs[i]
        t = 1.0 / (i + 1)
        cos = np.clip(np.dot(acc, q), -1.0, 1.0)
        ang = np.arccos(cos)
        if ang < 1e-12:
            acc = (1 - t) * acc + t * q
        else:
            acc = (np.sin((1 - t) * ang) * acc + np.sin(t * ang) * q) / np.sin(ang)
        acc = acc / np.linalg.norm(acc)
    return acc
