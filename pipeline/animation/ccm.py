"""The Control Cluster Method (Bukatov, Gridchina & Zastavnoy 2014), restated in
``docs/seed-systems.md`` §D: free vertices of a skinned control grid placed by cardinal splines
through the clusters around them (`ccm_plan`, `ccm_free_vertices`), and the procedural bulge the
paper adds on the outside of a bend (`procedural_bulge`). Grids are ``(nu, nv, 3) float64``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["cardinal_segment", "CCMPlan", "ccm_plan", "ccm_free_vertices", "procedural_bulge"]

_EPS = 1e-12


def cardinal_segment(p, t, s, tension=-0.5) -> np.ndarray:
    """Point of the cardinal spline segment between ``p[..., 1, :]`` and ``p[..., 2, :]``.

    ``p : (..., 4, 3)`` control points ``p_{k-1}, p_k, p_{k+1}, p_{k+2}``, ``t : (..., 4)`` their
    (increasing) parameters, ``s : (...)`` in ``[t_k, t_{k+1}]``.  Tangents (CCM paper eq. 1)
    ``m_k = (1 − q)(p_{k+1} − p_{k−1}) / (t_{k+1} − t_{k−1})``, then the cubic Hermite segment
    over ``h = t_{k+1} − t_k``: ``h00 p_k + h10 h m_k + h01 p_{k+1} + h11 h m_{k+1}``.
    ``q = 0`` with uniform ``t`` is Catmull–Rom; ``q = −0.5`` (the paper's default) gives 1.5×
    longer tangents, so the curve swings wider round a bend and keeps volume."""
    p = np.asarray(p, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    s = np.asarray(s, dtype=np.float64)
    f = 1.0 - tension
    m1 = f * (p[..., 2, :] - p[..., 0, :]) / np.maximum(t[..., 2] - t[..., 0], _EPS)[..., None]
    m2 = f * (p[..., 3, :] - p[..., 1, :]) / np.maximum(t[..., 3] - t[..., 1], _EPS)[..., None]
    h = t[..., 2] - t[..., 1]
    u = ((s - t[..., 1]) / np.maximum(h, _EPS))[..., None]
    h = h[..., None]
    u2, u3 = u * u, u * u * u
    return ((2 * u3 - 3 * u2 + 1) * p[..., 1, :] + (u3 - 2 * u2 + u) * h * m1
            + (-2 * u3 + 3 * u2) * p[..., 2, :] + (u3 - u2) * h * m2)


@dataclass(frozen=True)
class CCMPlan:
    """Static part of the CCM on a grid (from :func:`ccm_plan`).

    One row per (free vertex, usable grid direction): ``target : (r,) int64`` the free vertex;
    ``ctrl : (r, 4) int64`` its four cluster control vertices ``p_{k-1}, p_k, p_{k+1}, p_{k+2}``
    along the grid line (flat C-order indices into the ``(nu, nv)`` grid; ``-1`` = no cluster
    vertex beyond an open end, replaced by the reflection ``2 p_k − p_{k+1}``);
    ``alpha : (r,)`` the free vertex's rest arc-length fraction between ``p_k`` and ``p_{k+1}``;
    ``weight : (r,)`` the direction's share (1, or 1/2 where two directions tie);
    ``offset : (r, 3)`` the rest vertex minus the rest spline point (zero on a straight line),
    carried along so that the rest pose is reproduced exactly; ``rest_controls : (r, 4, 3)`` the
    rest control points; ``mask : (nu, nv) bool`` marks cluster vertices; ``tension`` is ``q``."""

    shape: tuple
    mask: np.ndarray
    target: np.ndarray
    ctrl: np.ndarray
    alpha: np.ndarray
    weight: np.ndarray
    offset: np.ndarray
    rest_controls: np.ndarray
    tension: float


def ccm_plan(rest_cvs, cluster_mask, wrap=(False, False), tension=-0.5) -> CCMPlan:
    """Find, for every free vertex and each grid direction, its nearest cluster vertices along
    that grid line (respecting wrap): the bracketing pair ``p_k, p_{k+1}`` and the next cluster
    vertex beyond each (for the tangents).  ``rest_cvs : (nu, nv, 3)``,
    ``cluster_mask : (nu, nv) bool``.  A direction with no cluster vertex on one side of the
    free vertex is skipped; of the usable ones only the direction whose bracketing cluster
    vertices are *nearest* (fewest edges ``d_a + d_b`` between them) is used, ties averaged.  A
    spline across a wide gap cuts the corner of a bent joint (its tangent at ``p_k`` points at
    ``p_{k+1}`` across the gap), so it is not blended in.  Raises if a free vertex has no usable
    direction."""
    P = np.asarray(rest_cvs, dtype=np.float64)
    mask = np.asarray(cluster_mask, dtype=bool)
    nu, nv = mask.shape
    if P.shape != (nu, nv, 3):
        raise ValueError(f"rest_cvs {P.shape} and cluster_mask {mask.shape} disagree")
    rows = {"target": [], "ctrl": [], "alpha": [], "gap": []}
    for axis in (0, 1):
        n, periodic = (nu, nv)[axis], bool(wrap[axis])
        for other in range((nv, nu)[axis]):
            flat = np.arange(n) * nv + other if axis == 0 else other * nv + np.arange(n)
            line_mask = mask.ravel()[flat]
            pts = P.reshape(-1, 3)[flat]
            seg = np.linalg.norm(np.roll(pts, -1, 0) - pts, axis=1)   # seg[i] = |p[i+1] - p[i]|
            clusters = np.flatnonzero(line_mask)
            if len(clusters) < 2:
                continue
            for k in np.flatnonzero(~line_mask):
                before, after = clusters[clusters < k], clusters[clusters > k]
                if periodic:
                    back = np.concatenate([before[::-1], after[::-1]])  # nearest first, wrapping
                    fwd = np.concatenate([after, before])
                    a, a2, b, b2 = back[0], back[1], fwd[0], fwd[1]
                    da, db = (k - a) % n, (b - k) % n
                else:
                    if len(before) == 0 or len(after) == 0:
                        continue
                    a, b = before[-1], after[0]
                    a2 = before[-2] if len(before) > 1 else -1
                    b2 = after[1] if len(after) > 1 else -1
                    da, db = k - a, b - k
                run_ak = seg[np.arange(a, a + da) % n].sum()
                run_ab = seg[np.arange(a, a + da + db) % n].sum()
                rows["target"].append(flat[k])
                rows["ctrl"].append([flat[a2] if a2 >= 0 else -1, flat[a], flat[b],
                                     flat[b2] if b2 >= 0 else -1])
                rows["alpha"].append(run_ak / max(run_ab, _EPS))
                rows["gap"].append(da + db)
    target = np.array(rows["target"], dtype=np.int64)
    gap = np.array(rows["gap"], dtype=np.int64)
    best = np.full(nu * nv, np.iinfo(np.int64).max)
    np.minimum.at(best, target, gap)
    keep = gap == best[target]
    missing = np.setdiff1d(np.flatnonzero(~mask.ravel()), target)
    if len(missing):
        bad = [divmod(int(m), nv) for m in missing[:5]]
        raise ValueError(f"free vertices without cluster vertices on both sides of any grid "
                         f"line: {bad}{' ...' if len(missing) > 5 else ''}")
    target = target[keep]
    ctrl = np.array(rows["ctrl"], dtype=np.int64).reshape(-1, 4)[keep]
    alpha = np.array(rows["alpha"])[keep]
    flat_rest = P.reshape(-1, 3)
    offset = flat_rest[target] - _ccm_spline_points(flat_rest, ctrl, alpha, tension)
    weight = 1.0 / np.bincount(target, minlength=nu * nv)[target]
    return CCMPlan((nu, nv), mask, target, ctrl, alpha, weight, offset,
                   _ccm_controls(flat_rest, ctrl), float(tension))


def _ccm_controls(flat, ctrl):
    p1, p2 = flat[ctrl[:, 1]], flat[ctrl[:, 2]]
    p0 = np.where((ctrl[:, 0] < 0)[:, None], 2 * p1 - p2, flat[np.maximum(ctrl[:, 0], 0)])
    p3 = np.where((ctrl[:, 3] < 0)[:, None], 2 * p2 - p1, flat[np.maximum(ctrl[:, 3], 0)])
    return np.stack([p0, p1, p2, p3], axis=1)


def _ccm_spline_points(flat, ctrl, alpha, tension):
    """Chord-length parameterised cardinal spline through each row's 4 controls, at ``alpha``."""
    p = _ccm_controls(flat, ctrl)
    t = np.concatenate([np.zeros((len(p), 1)),
                        np.cumsum(np.linalg.norm(np.diff(p, axis=1), axis=2), axis=1)], axis=1)
    return cardinal_segment(p, t, t[:, 1] + alpha * (t[:, 2] - t[:, 1]), tension)


def _kabsch(A, B):
    """Rotations ``(r, 3, 3)`` best mapping centred point sets ``A`` onto ``B`` (both (r, k, 3))."""
    A = A - A.mean(axis=1, keepdims=True)
    B = B - B.mean(axis=1, keepdims=True)
    U, _, Vt = np.linalg.svd(np.einsum("rki,rkj->rij", A, B))
    d = np.sign(np.linalg.det(np.einsum("rij,rjk->rik", U, Vt)))
    D = np.broadcast_to(np.eye(3), U.shape).copy()
    D[:, 2, 2] = d
    return np.einsum("rji,rjk,rkl->ril", Vt, D, np.swapaxes(U, 1, 2))


def ccm_free_vertices(plan: CCMPlan, cluster_positions) -> np.ndarray:
    """Place the free vertices of a grid from its deformed cluster vertices (CCM §3.3).

    ``cluster_positions : (nu, nv, 3)`` — only entries under ``plan.mask`` are read.  Along each
    usable grid line the four cluster control points get chord-length parameters
    ``t_{i+1} − t_i = |p_{i+1} − p_i|`` and the free vertex the parameter
    ``t_k + α (t_{k+1} − t_k)``; its position is the :func:`cardinal_segment` there (tension
    ``plan.tension``) plus its rest offset from the rest spline, turned by the best-fit rotation
    of the four controls (Kabsch), averaged over directions with ``plan.weight``.  Returns the
    full grid ``(nu, nv, 3)``: cluster vertices as given, free vertices placed."""
    X = np.asarray(cluster_positions, dtype=np.float64)
    nu, nv = plan.shape
    if X.shape != (nu, nv, 3):
        raise ValueError(f"cluster_positions must be {(nu, nv, 3)}, got {X.shape}")
    flat = X.reshape(-1, 3)
    out = flat.copy()
    if len(plan.target) == 0:
        return out.reshape(nu, nv, 3)
    pos = _ccm_spline_points(flat, plan.ctrl, plan.alpha, plan.tension)
    if np.any(plan.offset):
        R = _kabsch(plan.rest_controls, _ccm_controls(flat, plan.ctrl))
        pos = pos + np.einsum("rij,rj->ri", R, plan.offset)
    acc = np.zeros_like(flat)
    wsum = np.zeros(len(flat))
    np.add.at(acc, plan.target, plan.weight[:, None] * pos)
    np.add.at(wsum, plan.target, plan.weight)
    free = wsum > 0
    out[free] = acc[free] / wsum[free, None]
    return out.reshape(nu, nv, 3)


def procedural_bulge(rest_points, axis_origin, axis_dir, angle, gain, center, half_width,
                     side=None) -> np.ndarray:
    """Bind-space displacements ``(..., 3)`` of a muscle bulge driven by a joint angle (CCM §4.1,
    "biceps bulging ... depending on the angle between upper arm and lower arm bones").

    Each point moves radially away from the bone axis (``axis_origin``, ``axis_dir : (3,)``) by
    ``gain · (1 − cos angle)/2 · window(s) · facing``: ``window`` is the cosine bump
    ``½(1 + cos(π (s − center)/half_width))`` of the point's axial coordinate ``s`` (zero beyond
    ``half_width``), ``facing = max(0, r̂ · side)`` restricts it to one side (or 1 if no side)."""
    P = np.asarray(rest_points, dtype=np.float64)
    o = np.asarray(axis_origin, dtype=np.float64)
    a = np.asarray(axis_dir, dtype=np.float64)
    a = a / np.linalg.norm(a)
    rel = P - o
    s = rel @ a
    radial = rel - s[..., None] * a
    rn = np.linalg.norm(radial, axis=-1, keepdims=True)
    rhat = np.where(rn > _EPS, radial / np.maximum(rn, _EPS), 0.0)
    x = (s - center) / half_width
    window = np.where(np.abs(x) < 1.0, 0.5 * (1.0 + np.cos(np.pi * x)), 0.0)
    facing = np.ones_like(s) if side is None else np.maximum(0.0, rhat @ np.asarray(side, float))
    amp = gain * 0.5 * (1.0 - np.cos(angle)) * window * facing
    return amp[..., None] * rhat
