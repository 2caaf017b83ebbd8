"""Free-form deformation (Sederberg & Parry 1986) with trivariate Bernstein (Bézier) lattices of
any size, sequential composition and the three ways the slides animate an FFD.

The static model is a :class:`Lattice` — origin ``P0`` and edge vectors ``S, T, U`` of a
parallelepiped split into ``l × m × n`` cells; its rest control points are
``P_ijk = P0 + (i/l) S + (j/m) T + (k/n) U`` (:func:`lattice_points`).  The per-frame state is
the moved control points ``(l+1, m+1, n+1, 3) float64``.  Points are ``(..., 3) float64``:
an ACRA control grid ``(nu, nv, 3)`` or a collider's vertices ``(n, 3)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import comb

__all__ = [
    "Lattice", "make_lattice", "lattice_around", "lattice_points", "local_coordinates",
    "bernstein", "ffd", "ffd_sequence", "morph_lattice", "ffd_frames",
]


@dataclass(frozen=True)
class Lattice:
    """FFD lattice: ``origin : (3,)`` (P0), ``axes : (3, 3)`` rows ``S, T, U`` (edge vectors,
    linearly independent, not necessarily orthogonal), ``divisions = (l, m, n)`` cells per axis
    (the Bernstein degrees).  Build with :func:`make_lattice` or :func:`lattice_around`."""

    origin: np.ndarray
    axes: np.ndarray
    divisions: tuple

    @property
    def shape(self) -> tuple:
        """Control point grid shape ``(l+1, m+1, n+1)``."""
        return tuple(d + 1 for d in self.divisions)


def make_lattice(origin, s, t, u, divisions) -> Lattice:
    """Validated :class:`Lattice` from ``P0`` and edge vectors ``S, T, U : (3,)``; each of
    ``divisions = (l, m, n)`` ≥ 1."""
    axes = np.array([s, t, u], dtype=np.float64)
    o = np.array(origin, dtype=np.float64)
    div = tuple(int(d) for d in divisions)
    if axes.shape != (3, 3) or o.shape != (3,) or len(div) != 3 or min(div) < 1:
        raise ValueError("need origin (3,), three edge vectors (3,) and divisions (l, m, n) >= 1")
    if abs(np.linalg.det(axes)) < 1e-12 * np.prod(np.linalg.norm(axes, axis=1)):
        raise ValueError("lattice edge vectors S, T, U are (nearly) coplanar")
    axes.setflags(write=False)
    o.setflags(write=False)
    return Lattice(o, axes, div)


def lattice_around(points, divisions, padding=0.0) -> Lattice:
    """Axis-aligned lattice around ``points : (..., 3)``'s bounding box grown by ``padding`` on
    every side (a flat direction gets a unit extent so the lattice is never degenerate)."""
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lo, hi = P.min(axis=0) - padding, P.max(axis=0) + padding
    ext = np.where(hi - lo > 0, hi - lo, 1.0)
    return make_lattice(lo, *np.diag(ext), divisions)


def lattice_points(lattice: Lattice) -> np.ndarray:
    """Rest control points ``(l+1, m+1, n+1, 3)``: ``P_ijk = P0 + (i/l) S + (j/m) T + (k/n) U``
    (Sederberg & Parry eq. 2)."""
    l, m, n = lattice.divisions
    g = np.stack(np.meshgrid(np.arange(l + 1) / l, np.arange(m + 1) / m, np.arange(n + 1) / n,
                             indexing="ij"), axis=-1)
    return lattice.origin + g @ lattice.axes


def local_coordinates(lattice: Lattice, points) -> np.ndarray:
    """Lattice coordinates ``(..., 3)`` = ``(s, t, u)`` of ``points : (..., 3)``, so that
    ``X = P0 + s S + t T + u U`` (Sederberg & Parry eq. 1):

        s = (T × U)·(X − P0) / ((T × U)·S)
        t = (S × U)·(X − P0) / ((S × U)·T)
        u = (S × T)·(X − P0) / ((S × T)·U)

    A point is inside the lattice iff ``0 ≤ s, t, u ≤ 1``."""
    S, T, U = lattice.axes
    rel = np.asarray(points, dtype=np.float64) - lattice.origin
    tu, su, st = np.cross(T, U), np.cross(S, U), np.cross(S, T)
    return np.stack([rel @ tu / (tu @ S), rel @ su / (su @ T), rel @ st / (st @ U)], axis=-1)


def bernstein(degree, t) -> np.ndarray:
    """Bernstein basis ``(..., degree+1)``: ``B_i(t) = C(degree, i) t^i (1 − t)^(degree−i)``."""
    t = np.asarray(t, dtype=np.float64)[..., None]
    i = np.arange(degree + 1)
    return comb(degree, i) * t ** i * (1.0 - t) ** (degree - i)


def ffd(lattice: Lattice, control_points, points, outside="keep") -> np.ndarray:
    """Deform ``points : (..., 3)`` by the lattice with moved ``control_points :
    (l+1, m+1, n+1, 3)``: the trivariate Bézier volume (Sederberg & Parry eq. 3)

        X_ffd = Σ_i Σ_j Σ_k P_ijk B_i^l(s) B_j^m(t) B_k^n(u)

    at the point's :func:`local_coordinates`.  With the rest control points this is the
    identity (Bernstein polynomials reproduce linear functions), and with affinely moved ones
    it is that affine map.  Points outside the unit cube: ``outside="keep"`` leaves them
    unchanged (the usual FFD; continuous when the lattice's boundary points are unmoved),
    ``"extrapolate"`` evaluates the polynomial there too."""
    Q = np.asarray(control_points, dtype=np.float64)
    if Q.shape != lattice.shape + (3,):
        raise ValueError(f"control_points must be {lattice.shape + (3,)}, got {Q.shape}")
    P = np.asarray(points, dtype=np.float64)
    stu = local_coordinates(lattice, P).reshape(-1, 3)
    l, m, n = lattice.divisions
    Bs, Bt, Bu = bernstein(l, stu[:, 0]), bernstein(m, stu[:, 1]), bernstein(n, stu[:, 2])
    out = np.einsum("pi,pj,pk,ijkc->pc", Bs, Bt, Bu, Q, optimize=True)
    if outside == "keep":
        tol = 1e-12
        inside = np.all((stu >= -tol) & (stu <= 1.0 + tol), axis=1)
        out = np.where(inside[:, None], out, P.reshape(-1, 3))
    elif outside != "extrapolate":
        raise ValueError(f"outside must be 'keep' or 'extrapolate', got {outside!r}")
    return out.reshape(P.shape)


def ffd_sequence(points, stages, outside="keep") -> np.ndarray:
    """Sequential composition: apply ``stages = [(lattice, control_points), ...]`` in order,
    each to the previous result (slides, "Compositing of FFDs").  For hierarchical composition
    deform a child lattice's control points by its parent first: ``ffd(parent, Q_parent,
    Q_child)``, then use those as the child's moved control points."""
    X = np.asarray(points, dtype=np.float64)
    for lattice, Q in stages:
        X = ffd(lattice, Q, X, outside)
    return X


def morph_lattice(reference, deformed, alpha) -> np.ndarray:
    """Control points between a ``reference`` and a ``deformed`` lattice (both
    ``(l+1, m+1, n+1, 3)``): ``(1 − α) reference + α deformed`` for ``alpha : (F,)`` or a scalar;
    returns ``(F, l+1, m+1, n+1, 3)`` (or one lattice for a scalar)."""
    R = np.asarray(reference, dtype=np.float64)
    D = np.asarray(deformed, dtype=np.float64)
    a = np.asarray(alpha, dtype=np.float64)
    return R + a.reshape(a.shape + (1,) * R.ndim) * (D - R)


def ffd_frames(lattice: Lattice, points, control_points, object_offsets=None,
               lattice_offsets=None, outside="keep") -> np.ndarray:
    """Per-frame FFD ``(F, ..., 3)`` in the three ways the slides animate one:

    * moving lattice points — ``control_points : (F, l+1, m+1, n+1, 3)`` (e.g. from
      :func:`morph_lattice`, the reference → deformed morph);
    * moving the object through a fixed (deformed) lattice — ``object_offsets : (F, 3)``: the
      object is translated by the offset, then deformed;
    * moving the lattice through the object ("mouse under the rug") — ``lattice_offsets :
      (F, 3)``: the lattice and its control points are translated by the offset.

    ``control_points`` may also be a single ``(l+1, m+1, n+1, 3)`` lattice used at every frame;
    ``F`` comes from whichever argument is per-frame."""
    Q = np.asarray(control_points, dtype=np.float64)
    P = np.asarray(points, dtype=np.float64)
    per_frame = [len(x) for x in (object_offsets, lattice_offsets) if x is not None]
    if Q.ndim == 5:
        per_frame.append(len(Q))
    if not per_frame or len(set(per_frame)) != 1:
        raise ValueError("give per-frame control points and/or offsets of one common length F")
    F = per_frame[0]
    frames = []
    for f in range(F):
        Qf = Q[f] if Q.ndim == 5 else Q
        Xf = P if object_offsets is None else P + np.asarray(object_offsets[f], dtype=np.float64)
        lat = lattice
        if lattice_offsets is not None:
            off = np.asarray(lattice_offsets[f], dtype=np.float64)
            lat = make_lattice(lattice.origin + off, *lattice.axes, lattice.divisions)
            Qf = Qf + off
        frames.append(ffd(lat, Qf, Xf, outside))
    return np.array(frames)
