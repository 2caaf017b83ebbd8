"""First triangles met by rays, exactly in float64, through `acra.bvh`'s tree, compiled.

Detection casts a few dozen rays at a time on the collision grids of the patches they meet
(`pipeline.queries.cast`, thesis eq. 4.16): building an embree scene for each patch set cost
1-5 ms, more than the rays. Here the tree is `acra.bvh.build`'s (median splits, compiled) and
each ray walks it depth first, nearer child first, pruning a box it enters beyond the nearest hit
found. The triangle test is Möller and Trumbore's (*Fast, minimum storage ray-triangle
intersection*, 1997): ``t`` along the ray and barycentric ``u, v`` from one determinant, a hit
where ``u, v >= -TOL``, ``u + v <= 1 + TOL`` and ``t >= 0``; the small tolerance lets no ray slip
between two triangles sharing an edge, where float32 embree can. Triangles without area (their
normal is zero, `acra.meshops.face_normals`) are never met, since the hit point is the ray's
meeting with the triangle's plane. The answer is the least ``t`` and, among equal ones, the
lowest triangle row, whatever the tree. Boxes are padded by ``pad`` (a multiple of the mesh's
size far above float64 rounding) so a box is never pruned while a triangle in it could hold or
tie the answer. Arrays are float64 unless stated.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from acra.bvh import Tree

__all__ = ["TOL", "first_faces", "first_faces_brute"]

TOL = 1e-12  # barycentric slack: a ray along an edge shared by two triangles meets one of them


@njit(cache=True, nogil=True, error_model="numpy")
def _hit(o, d, a, b, c):
    """Möller-Trumbore: ``t`` of ray ``o + t d`` on triangle ``a, b, c``, or ``inf``."""
    e1x, e1y, e1z = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    e2x, e2y, e2z = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    px, py, pz = d[1] * e2z - d[2] * e2y, d[2] * e2x - d[0] * e2z, d[0] * e2y - d[1] * e2x
    det = (e1x * px + e1y * py) + e1z * pz
    if det == 0.0:
        return np.inf
    inv = 1.0 / det
    sx, sy, sz = o[0] - a[0], o[1] - a[1], o[2] - a[2]
    u = ((sx * px + sy * py) + sz * pz) * inv
    if not (u >= -TOL and u <= 1.0 + TOL):
        return np.inf
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    v = ((d[0] * qx + d[1] * qy) + d[2] * qz) * inv
    if not (v >= -TOL and u + v <= 1.0 + TOL):
        return np.inf
    t = ((e2x * qx + e2y * qy) + e2z * qz) * inv
    if not t >= 0.0:
        return np.inf
    return t


@njit(cache=True, nogil=True, error_model="numpy")
def _enter(o, inv, lo, hi, node, pad):
    """Where ray ``o`` (reciprocal direction ``inv``) enters the box of ``node`` padded by
    ``pad``, ``inf`` if it misses it or the box lies behind ``o``. An axis-parallel ray on a
    slab's plane (``0 * inf``) counts as inside that slab."""
    near, far = 0.0, np.inf
    for k in range(3):
        t0 = (lo[node, k] - pad - o[k]) * inv[k]
        t1 = (hi[node, k] + pad - o[k]) * inv[k]
        if np.isnan(t0):
            t0 = -np.inf
        if np.isnan(t1):
            t1 = np.inf
        near = max(near, min(t0, t1))
        far = min(far, max(t0, t1))
    return near if near <= far else np.inf


@njit(cache=True, nogil=True, error_model="numpy")
def _first(tri, order, lo, hi, left, right, start, count, usable, origins, directions, pad, face, dist):
    # tri is the tree's leaf_tri; a child is pushed with its entry, the nearer one last so it is
    # visited first, and a popped node whose entry lies beyond the best hit (plus pad) is skipped
    stack = np.empty(256, np.int64)
    entry = np.empty(256)
    inv = np.empty(3)
    for i in range(origins.shape[0]):
        o, d = origins[i], directions[i]
        for k in range(3):
            inv[k] = 1.0 / d[k]
        best, best_face = np.inf, -1
        e = _enter(o, inv, lo, hi, 0, pad)
        if e == np.inf:
            continue
        stack[0], entry[0] = 0, e
        top = 1
        while top > 0:
            top -= 1
            node = stack[top]
            if entry[top] > best + pad:
                continue
            if left[node] < 0:
                for s in range(start[node], start[node] + count[node]):
                    f = order[s]
                    if not usable[f]:
                        continue
                    t = _hit(o, d, tri[s, 0], tri[s, 1], tri[s, 2])
                    if t < best or (t == best and t < np.inf and f < best_face):
                        best, best_face = t, f
                continue
            a, b = left[node], right[node]
            ea, eb = _enter(o, inv, lo, hi, a, pad), _enter(o, inv, lo, hi, b, pad)
            if ea <= eb:
                if eb < np.inf:
                    stack[top], entry[top] = b, eb
                    top += 1
                if ea < np.inf:
                    stack[top], entry[top] = a, ea
                    top += 1
            else:
                if ea < np.inf:
                    stack[top], entry[top] = a, ea
                    top += 1
                if eb < np.inf:
                    stack[top], entry[top] = b, eb
                    top += 1
        face[i], dist[i] = best_face, best


@njit(cache=True, nogil=True, error_model="numpy")
def _first_brute(tri, usable, origins, directions, face, dist):
    for i in range(origins.shape[0]):
        best, best_face = np.inf, -1
        for f in range(tri.shape[0]):
            if usable[f]:
                t = _hit(origins[i], directions[i], tri[f, 0], tri[f, 1], tri[f, 2])
                if t < best:
                    best, best_face = t, f
        face[i], dist[i] = best_face, best


def first_faces(tree: Tree, usable: np.ndarray, origins: np.ndarray, directions: np.ndarray,
                pad: float) -> tuple[np.ndarray, np.ndarray]:
    """Row of the first triangle of ``tree`` each ray ``origins, directions (n, 3)`` meets at
    ``t >= 0`` ``(n,) int64`` (``-1`` where none; the lowest row among equally near ones) and its
    ``t`` ``(n,)`` (``inf`` where none), skipping rows where ``usable (f,) bool`` is False.
    ``pad``: box padding, e.g. ``1e-9`` of the mesh's size."""
    o = np.ascontiguousarray(origins, np.float64).reshape(-1, 3)
    d = np.ascontiguousarray(directions, np.float64).reshape(-1, 3)
    face, dist = np.full(len(o), -1, np.int64), np.full(len(o), np.inf)
    if len(o):
        _first(tree.leaf_tri, tree.order, tree.lo, tree.hi, tree.left, tree.right, tree.start, tree.count,
               np.ascontiguousarray(usable, np.bool_), o, d, float(pad), face, dist)
    return face, dist


def first_faces_brute(tri: np.ndarray, usable: np.ndarray, origins: np.ndarray,
                      directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`first_faces` by testing every triangle ``tri (f, 3, 3)``: the reference the tree's
    search is held to (tests/test_raycast.py)."""
    o = np.ascontiguousarray(origins, np.float64).reshape(-1, 3)
    d = np.ascontiguousarray(directions, np.float64).reshape(-1, 3)
    face, dist = np.full(len(o), -1, np.int64), np.full(len(o), np.inf)
    if len(o):
        _first_brute(np.ascontiguousarray(tri, np.float64), np.ascontiguousarray(usable, np.bool_), o, d, face, dist)
    return face, dist
