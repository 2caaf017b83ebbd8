"""Volume of a closed surface and the bulge that keeps it (thesis §5.4, "volume conservation").

The volume is the display mesh's, by the divergence theorem: each quad ``(a, b, c, d)`` of a
`acra.tessellate.GridTopology` is split into the triangles ``(a, b, c)`` and ``(a, c, d)``, and

    V = 1/6 · Σ_triangles  a · (b × c),      ∂V/∂a = (b × c)/6,  ∂V/∂b = (c × a)/6,  ∂V/∂c = (a × b)/6

(signed: positive when the quads' normals point outward). A watertight mesh (periodic seams
shared, poles collapsed) gives the enclosed volume exactly for the mesh.

`bulge` restores a target volume by moving the CVs of one level away from the dent: a weighted
minimum-norm step on the linearised constraint ``Σ_j g_j · δ_j = V* − V`` with
``g_j = Σ_i B_j(u_i, v_i) ∂V/∂p_i`` (display sample ``i``, level-``l`` basis ``B_j``), repeated as
Newton steps. Samples moved by the frame's collision response (the dent) weigh nothing, the
others ``exp(−(d/L)²)`` at distance ``d`` from the dent (`bulge_weights`), so the bulge rises
around the dent and the dent itself, held by its data points, is left alone.
"""

from __future__ import annotations

import numpy as np

from . import details as D
from . import hspline as H
from .interpolate import point_weights
from .moves import move_level
from .tessellate import GridTopology

__all__ = ["encloses", "triangles", "enclosed_volume", "volume_gradient", "surface_area", "area_gradient", "MEASURES",
           "bulge_weights", "bulge"]


def encloses(hs: H.HSpline) -> bool:
    """Whether ``hs`` encloses a volume: periodic both ways, or periodic one way with both ends of
    the open direction closed to a point (`acra.hspline.closed_ends`, poles)."""
    if hs.u.periodic and hs.v.periodic:
        return True
    if hs.u.periodic == hs.v.periodic:
        return False
    axis = 1 if hs.u.periodic else 0
    return {(axis, 0), (axis, 1)} <= set(H.closed_ends(hs))


def triangles(topo) -> np.ndarray:
    """The display faces as triangles ``(t, 3) int64`` of a `GridTopology` or a
    `MeshTopology`: quads split in two (all first halves, then all second halves), a mesh with
    triangles where its density changes fanned face by face (`MeshTopology.triangles`)."""
    counts = np.asarray(topo.counts)
    if counts.size and np.any(counts != 4):
        return topo.triangles()
    q = np.asarray(topo.indices, dtype=np.int64).reshape(-1, 4)
    return np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])


def enclosed_volume(points: np.ndarray, tris: np.ndarray) -> float:
    """Signed volume enclosed by triangles ``tris (t, 3)`` over ``points (n, 3)``."""
    a, b, c = (points[tris[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0)


def volume_gradient(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """``∂V/∂p`` for every point: ``(n, 3) float64``."""
    a, b, c = (points[tris[:, k]] for k in range(3))
    g = np.zeros_like(points, dtype=np.float64)
    np.add.at(g, tris[:, 0], np.cross(b, c))
    np.add.at(g, tris[:, 1], np.cross(c, a))
    np.add.at(g, tris[:, 2], np.cross(a, b))
    return g / 6.0


def surface_area(points: np.ndarray, tris: np.ndarray) -> float:
    """Area of triangles ``tris (t, 3)`` over ``points (n, 3)``."""
    a, b, c = (points[tris[:, k]] for k in range(3))
    return float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())


def area_gradient(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """``∂A/∂p`` for every point: ``(n, 3) float64``; per triangle with unit normal ``n``,
    ``∂A/∂a = n × (c − b) / 2`` and cyclically (zero for a degenerate triangle)."""
    a, b, c = (points[tris[:, k]] for k in range(3))
    n = np.cross(b - a, c - a)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    g = np.zeros_like(points, dtype=np.float64)
    np.add.at(g, tris[:, 0], np.cross(n, c - b))
    np.add.at(g, tris[:, 1], np.cross(n, a - c))
    np.add.at(g, tris[:, 2], np.cross(n, b - a))
    return g / 2.0


MEASURES = {"volume": (enclosed_volume, volume_gradient), "area": (surface_area, area_gradient)}


def bulge_weights(points: np.ndarray, dent: np.ndarray, falloff: float) -> np.ndarray:
    """How much each display sample may move to make the bulge: ``(n,) float64``.

    ``dent (n,) bool`` marks the samples the collision response moved; ``falloff`` is a length.
    A dent sample weighs 0; another weighs ``exp(-(d / falloff)^2)`` with ``d`` its distance to
    the nearest dent sample, so the bulge rises right around the dent and fades away from it
    (the bulge ramp of collision deformers). Without a dent every sample weighs 1."""
    if not np.any(dent):
        return np.ones(len(points))
    from scipy.spatial import cKDTree

    d, _ = cKDTree(points[dent]).query(points)
    w = np.exp(-((d / falloff) ** 2))
    w[dent] = 0.0
    return w


def bulge(hs: H.HSpline, topo: GridTopology, target: float, level: int, weights: np.ndarray,
          steps: int = 4, rtol: float = 1e-4, measure: str = "volume") -> tuple[H.HSpline, float]:
    """``hs`` with its level-``level`` CVs moved so the display mesh's ``measure`` (``"volume"``
    enclosed, or ``"area"`` for an open sheet) is ``target``.

    Parameters
    ----------
    topo : GridTopology
        The display tessellation the volume is measured on.
    target : float
        The wanted (signed) volume or area.
    weights : (n,) float64
        Per display sample, how much it may move (`bulge_weights`).
    steps : int
        Newton steps at most; stops once ``|V - target| <= rtol · |target|``.

    Returns
    -------
    The surface and its measure. Each step moves CV ``j`` by ``λ c_j h_j`` with
    ``h_j = Σ_i B_ij w_i ∂V/∂p_i`` (the gradient seen through the weights), ``c_j`` the CV's
    mean sample weight, and ``λ`` making the linearised change ``Σ_j g_j · δ_j`` equal to the
    volume missing: the minimum of ``Σ_j |δ_j|² / c_j`` under the masked constraint.
    """
    size, gradient = MEASURES[measure]
    tris = triangles(topo)
    pw = point_weights(hs, level, topo.u, topo.v)
    n_cv = pw.cv_rows.size
    mean_w = np.bincount(pw.col, pw.w * weights[pw.point], n_cv) / np.maximum(np.bincount(pw.col, pw.w, n_cv), 1e-300)
    det = D.details(hs) if hs.depth > 1 else None
    pts = H.evaluate(hs, topo.u, topo.v, det=det).points
    vol = size(pts, tris)
    for _ in range(steps):
        missing = target - vol
        if abs(missing) <= rtol * abs(target):
            break
        grad = gradient(pts, tris)
        g = np.stack([np.bincount(pw.col, pw.w * grad[pw.point, c], n_cv) for c in range(3)], axis=1)
        h = np.stack([np.bincount(pw.col, pw.w * weights[pw.point] * grad[pw.point, c], n_cv) for c in range(3)], axis=1)
        direction = mean_w[:, None] * h
        rate = float(np.einsum("ij,ij->", g, direction))
        if abs(rate) <= 1e-300:
            break
        hs = move_level(hs, level, pw.cv_rows, (missing / rate) * direction, det)
        det = D.details(hs) if hs.depth > 1 else None
        pts = H.evaluate(hs, topo.u, topo.v, det=det).points
        vol = size(pts, tris)
    return hs, vol
