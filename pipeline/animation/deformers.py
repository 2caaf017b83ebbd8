"""Point deformers: warping (move a vertex, neighbours follow) and Barr's global taper, twist and
bend (Barr 1984, "Global and local deformations of solid primitives").

All functions take plain point arrays — an ACRA control grid ``(nu, nv, 3)`` or a collider's
vertices ``(n, 3)``, in general ``(..., 3) float64`` — and return new arrays of the same shape;
nothing is modified in place.  Parameters that an animator keys over time (displacement, taper
profile, twist angle, bend curvature) are plain arguments: evaluate the key-frame curve for the
frame, then call the deformer.  Restated in ``docs/seed-systems.md`` §C and ``docs/deformers.md``.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import shortest_path

__all__ = [
    "PROFILES", "attenuation", "grid_edge_distance", "mesh_edge_distance", "warp",
    "taper", "twist", "bend", "in_frame",
]

_GAUSS_K = 4.5  # exp(-4.5 r^2): sigma = cut-off / 3


def _cosine(r):
    return 0.5 * (1.0 + np.cos(np.pi * r))


def _linear(r):
    return 1.0 - r


def _gaussian(r):
    e = np.exp(-_GAUSS_K)
    return (np.exp(-_GAUSS_K * r * r) - e) / (1.0 - e)


def _smoothstep(r):
    return 1.0 - r * r * (3.0 - 2.0 * r)


PROFILES = {"cosine": _cosine, "linear": _linear, "gaussian": _gaussian, "smoothstep": _smoothstep}
"""Attenuation profiles ``f(r)`` of the normalised distance ``r = d / cutoff ∈ [0, 1]``, each
with ``f(0) = 1`` and ``f(1) = 0``: smooth cosine ``½(1 + cos πr)``; linear ``1 − r``; gaussian
``(e^{−4.5 r²} − e^{−4.5}) / (1 − e^{−4.5})`` (σ = cut-off / 3, shifted and rescaled so it reaches
0 at the cut-off instead of jumping); smoothstep ``1 − (3r² − 2r³)``."""


def attenuation(distance, cutoff, profile="cosine") -> np.ndarray:
    """Warp weights ``(...) float64`` for distances ``(...)``: ``f(d / cutoff)`` for
    ``d < cutoff`` and exactly 0 for ``d ≥ cutoff`` (and for ``inf``, unreachable vertices).
    ``profile`` is a key of :data:`PROFILES` or a callable ``f(r)`` on ``[0, 1]``."""
    if cutoff <= 0:
        raise ValueError("cutoff must be positive")
    f = PROFILES[profile] if isinstance(profile, str) else profile
    d = np.asarray(distance, dtype=np.float64)
    inside = d < cutoff
    r = np.where(inside, d / cutoff, 1.0)
    return np.where(inside, f(r), 0.0)


def grid_edge_distance(shape, index, wrap=(False, False)) -> np.ndarray:
    """Edge counts ``(nu, nv) int64`` from grid vertex ``index = (i, j)`` to every vertex of a
    ``shape = (nu, nv)`` grid whose edges join 4-neighbours.  A periodic direction wraps, so
    ``|Δi|`` becomes ``min(|Δi|, nu − |Δi|)``; the grid graph's shortest path is then
    ``|Δi| + |Δj|``."""
    nu, nv = shape
    i0, j0 = index
    di = np.abs(np.arange(nu) - i0)
    dj = np.abs(np.arange(nv) - j0)
    if wrap[0]:
        di = np.minimum(di, nu - di)
    if wrap[1]:
        dj = np.minimum(dj, nv - dj)
    return di[:, None] + dj[None, :]


def mesh_edge_distance(n_vertices, faces, index) -> np.ndarray:
    """Edge counts ``(n,) float64`` from vertex ``index`` to every vertex of a polygon mesh with
    ``faces : (f, k) int`` (triangles or quads), by breadth-first search; ``inf`` where
    unreachable."""
    F = np.asarray(faces, dtype=np.int64)
    a = F.ravel()
    b = np.roll(F, -1, axis=1).ravel()
    G = coo_matrix((np.ones(len(a)), (a, b)), shape=(n_vertices, n_vertices)).tocsr()
    return shortest_path(G, directed=False, unweighted=True, indices=int(index))


def warp(points, index, displacement, cutoff, metric="euclidean", profile="cosine",
         wrap=(False, False), faces=None) -> np.ndarray:
    """Move one vertex by ``displacement : (3,)``; every vertex within ``cutoff`` follows with
    the attenuated displacement ``f(d / cutoff) · displacement`` (slides §"Object warping").

    ``points`` is a grid ``(nu, nv, 3)`` with ``index = (i, j)``, or ``(n, 3)`` with an int
    ``index``.  ``metric``: ``"euclidean"`` — distance to the picked vertex in the input
    positions; ``"edges"`` — edge count, along the grid lines (respecting ``wrap``) for a grid,
    or through ``faces`` for a mesh.  The picked vertex moves exactly by ``displacement``
    (``f(0) = 1``); vertices at ``d ≥ cutoff`` do not move at all."""
    P = np.asarray(points, dtype=np.float64)
    dv = np.asarray(displacement, dtype=np.float64)
    grid = P.ndim == 3
    if grid:
        center = P[tuple(index)]
    elif P.ndim == 2:
        center = P[int(index)]
    else:
        raise ValueError(f"points must be (nu, nv, 3) or (n, 3), got {P.shape}")
    if metric == "euclidean":
        d = np.linalg.norm(P - center, axis=-1)
    elif metric == "edges":
        if grid:
            d = grid_edge_distance(P.shape[:2], tuple(index), wrap).astype(np.float64)
        elif faces is None:
            raise ValueError("metric='edges' on a (n, 3) point set needs faces")
        else:
            d = mesh_edge_distance(len(P), faces, index)
    else:
        raise ValueError(f"unknown metric {metric!r}")
    w = attenuation(d, cutoff, profile)
    out = P + w[..., None] * dv
    out[tuple(index) if grid else int(index)] = center + dv        # exact for the picked vertex
    return out


# ---------------------------------------------------------------------------------------------
# Barr 1984: taper, twist, bend.  The long axis is `axis`; bounds clamp the axial coordinate.
# ---------------------------------------------------------------------------------------------

def _axes(axis, toward=None):
    a = int(axis)
    if toward is None:
        b, c = (a + 1) % 3, (a + 2) % 3
        return a, b, c
    b = int(toward)
    if a == b or not (0 <= a < 3 and 0 <= b < 3):
        raise ValueError("axis and toward must be different coordinate indices 0, 1, 2")
    return a, b, 3 - a - b


def _clamp(z, bounds):
    if bounds is None:
        return z
    lo, hi = bounds
    if lo > hi:
        raise ValueError("bounds must be (lower, upper) with lower <= upper")
    return np.clip(z, lo, hi)


def _profile(f, default):
    if callable(f):
        return f
    k = float(f)
    return lambda z: default(k, z)


def taper(points, scale, axis=2, bounds=None) -> np.ndarray:
    """Barr's taper along ``axis``: ``X = r(ẑ) x``, ``Y = r(ẑ) y``, ``Z = z``, where ``x, y``
    are the two coordinates across the axis and ``ẑ`` the axial coordinate clamped to
    ``bounds = (lower, upper)`` (no clamp if None).  ``scale`` is a callable ``r(z)`` (array in,
    array out) or a number ``k`` for the linear taper ``r(z) = 1 + k z``.  Outside the bounds
    every cross-section keeps the scale of the nearer bound (the taper stops there)."""
    P = np.array(points, dtype=np.float64)
    a, b, c = _axes(axis)
    r = np.asarray(_profile(scale, lambda k, z: 1.0 + k * z)(_clamp(P[..., a], bounds)))
    P[..., b] *= r
    P[..., c] *= r
    return P


def twist(points, angle, axis=2, bounds=None) -> np.ndarray:
    """Barr's twist about ``axis``: each cross-section turns by ``θ(ẑ)`` (right-handed about the
    axis): ``X = x cos θ − y sin θ``, ``Y = x sin θ + y cos θ``, ``Z = z``; ``ẑ`` clamped to
    ``bounds`` so outside them the shape turns rigidly with its bound.  ``angle`` is a callable
    ``θ(z)`` (radians) or a number ``k`` (radians per unit length) for ``θ = k z``."""
    P = np.array(points, dtype=np.float64)
    a, b, c = _axes(axis)
    th = np.asarray(_profile(angle, lambda k, z: k * z)(_clamp(P[..., a], bounds)))
    C, S = np.cos(th), np.sin(th)
    x, y = P[..., b].copy(), P[..., c].copy()
    P[..., b] = C * x - S * y
    P[..., c] = S * x + C * y
    return P


def bend(points, curvature, center, bounds, axis=1, toward=2) -> np.ndarray:
    """Barr's global linear bend along ``axis`` (Barr's y) toward ``toward`` (Barr's z); the
    third coordinate is unchanged.  With ``ŷ = clamp(y, y_min, y_max)``, ``θ = k (ŷ − y0)``,
    ``C = cos θ``, ``S = sin θ`` (k = ``curvature``, y0 = ``center``, ``bounds = (y_min, y_max)``):

        Y = −S (z − 1/k) + y0 + C (y − ŷ)
        Z =  C (z − 1/k) + 1/k + S (y − ŷ)

    Inside the bounds the axis ``z = 0`` becomes a circular arc of radius ``1/k`` about
    ``(y0, 1/k)`` (arc length preserved); outside, the shape continues rigidly along the end
    tangents.  Evaluated as ``S/k = d·sinc``, ``(1 − C)/k = d sin(θ/2) sinc`` (``d = ŷ − y0``)
    so ``k → 0`` is the identity without dividing by zero."""
    P = np.array(points, dtype=np.float64)
    a, b, _ = _axes(axis, toward)
    k = float(curvature)
    y, z = P[..., a].copy(), P[..., b].copy()
    yh = _clamp(y, bounds)
    d = yh - center
    th = k * d
    C, S = np.cos(th), np.sin(th)
    s_over_k = d * np.sinc(th / np.pi)                          # sin(kd)/k
    c_over_k = d * np.sin(0.5 * th) * np.sinc(th / (2 * np.pi))  # (1 - cos(kd))/k
    P[..., a] = -S * z + s_over_k + center + C * (y - yh)
    P[..., b] = C * z + c_over_k + S * (y - yh)
    return P


def in_frame(points, origin, rotation, deformer, *args, **kwargs) -> np.ndarray:
    """Apply ``deformer(local, *args, **kwargs)`` in a local frame: ``origin : (3,)`` and
    ``rotation : (3, 3)`` whose columns are the frame's axes in world space.
    ``local = (p − origin) R``; result ``deformer(local) Rᵀ + origin``.  Use it to taper, twist
    or bend about an arbitrary axis (e.g. a bone)."""
    P = np.asarray(points, dtype=np.float64)
    o = np.asarray(origin, dtype=np.float64)
    R = np.asarray(rotation, dtype=np.float64)
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-9):
        raise ValueError("rotation must be orthonormal")
    return deformer((P - o) @ R, *args, **kwargs) @ R.T + o
