"""First hits of rays on a triangle mesh as embree reports them, compiled, where the answer is sure.

`pipeline.queries.RayMesh` casts rays the way trimesh's embree intersector does: the mesh and the
rays rounded to float32 (the mesh scaled to a diagonal of 100), embree's first triangle, then the
float64 ray on that triangle's plane. Building an embree scene per patch set costs far more than
casting a few dozen rays on it, so here every triangle near each ray is tested in float64 on the
same float32 numbers embree gets. Embree's float32 arithmetic (Möller–Trumbore or Plücker edge
tests, depth test, the nearest hit kept) differs from the exact values by at most a few units of
float32 rounding of the products involved; a triangle is a *sure* hit where every edge function
and the depth clear zero by a bound far above that rounding (`SLACK`), a *sure* miss where one is
below zero by it. A ray's answer is sure where its nearest sure hit's distance interval lies below
every other possible hit's (or it has no possible hit at all): embree then reports that triangle
(or none), whatever its own rounding and traversal order. Rays through an edge or a vertex, nearly
tied hits and nearly parallel triangles are left unsure for embree to decide
(`RayMesh.first_hits`), so the caller's answers are embree's in every case.

Triangles are visited through boxes of `GROUP` consecutive faces (a grid's faces come row by
row, so a group is a compact strip), widened by the rounding slack of the ray's distances.
Arrays are float64 unless stated.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from acra import meshops

__all__ = ["GROUP", "SLACK", "merged", "group_boxes", "sure_first_hits", "sure_hits"]

GROUP = 16  # consecutive faces per box
# Bound on embree's float32 error of an edge function, a determinant or a depth, as a multiple of
# float32's unit roundoff times the product of the operands' L1 norms: each is a triple product of
# differences (a cross product and a dot, about 5 roundings each, some fused); 64 is a wide margin
SLACK = 64.0 * 2.0**-24


@njit(cache=True, nogil=True)
def _merge(keys, referenced, new_id, rep):
    """Number the referenced rows of ``keys (n, 3) int64`` by first appearance, equal rows one
    number (``new_id (n,)``, ``rep``: each number's first row); returns how many. An open
    addressing table of the rows seen: which rows are equal, not how they hash, fixes the
    answer."""
    size = 1
    while size < 2 * keys.shape[0]:
        size *= 2
    table = np.full(size, -1, np.int64)
    count = 0
    for i in range(keys.shape[0]):
        if not referenced[i]:
            continue
        h = (np.uint64(keys[i, 0]) * np.uint64(0x9E3779B97F4A7C15) ^ np.uint64(keys[i, 1]) * np.uint64(0xC2B2AE3D27D4EB4F)
             ^ np.uint64(keys[i, 2]) * np.uint64(0x165667B19E3779F9))
        slot = np.int64((h ^ (h >> np.uint64(29))) & np.uint64(size - 1))
        while True:
            j = table[slot]
            if j < 0:
                table[slot] = i
                new_id[i] = count
                rep[count] = i
                count += 1
                break
            if keys[j, 0] == keys[i, 0] and keys[j, 1] == keys[i, 1] and keys[j, 2] == keys[i, 2]:
                new_id[i] = new_id[j]
                break
            slot = (slot + 1) & (size - 1)
    return count


def merged(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`acra.meshops.merge_vertices` (trimesh's merge to 1e-8), the same vertices ``(m, 3)`` and
    faces ``(f, 3) int64``, grouping the rounded rows in one compiled pass instead of sorting them."""
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    if not len(vertices):
        return vertices, faces
    referenced, keys = meshops.merge_keys(vertices, faces)
    new_id, rep = np.zeros(len(vertices), np.int64), np.empty(len(vertices), np.int64)
    count = _merge(keys, referenced, new_id, rep)
    return vertices[rep[:count]], new_id[faces]


@njit(cache=True, nogil=True)
def _group_boxes(v, faces, group, lo, hi):
    for g in range(lo.shape[0]):
        for a in range(3):
            lo[g, a], hi[g, a] = np.inf, -np.inf
        for f in range(g * group, min((g + 1) * group, faces.shape[0])):
            for k in range(3):
                for a in range(3):
                    x = np.float64(v[faces[f, k], a])
                    lo[g, a] = min(lo[g, a], x)
                    hi[g, a] = max(hi[g, a], x)


def group_boxes(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Boxes ``lo, hi (g, 3)`` of each `GROUP` consecutive faces ``faces (f, 3) int64`` of
    ``vertices (v, 3) float32``."""
    count = -(-len(faces) // GROUP)
    lo, hi = np.empty((count, 3)), np.empty((count, 3))
    _group_boxes(vertices, faces, GROUP, lo, hi)
    return lo, hi


@njit(cache=True, nogil=True)
def _sure_first_hits(v, faces, group, glo, ghi, orig, dirs, slack, tri, sure, v64, orig64, dirs64, zero, loc, has):
    reach = 3.0 * max(np.abs(glo).max(), np.abs(ghi).max()) if glo.shape[0] else 0.0
    for i in range(orig.shape[0]):
        ox, oy, oz = np.float64(orig[i, 0]), np.float64(orig[i, 1]), np.float64(orig[i, 2])
        dx, dy, dz = np.float64(dirs[i, 0]), np.float64(dirs[i, 1]), np.float64(dirs[i, 2])
        nd = abs(dx) + abs(dy) + abs(dz)
        # farthest a possible hit's point can lie outside its triangle's box along the ray's
        # rounding: slack times the origin's and the mesh's magnitudes, padded generously
        pad = 16.0 * slack * (abs(ox) + abs(oy) + abs(oz) + reach)
        best, best_lo, best_hi = -1, np.inf, np.inf
        other_lo = np.inf  # the least distance any other possible hit may have
        unsure = False
        for g in range(glo.shape[0]):
            near, far = -np.inf, np.inf
            skip = False
            for a, o, d in ((0, ox, dx), (1, oy, dy), (2, oz, dz)):
                lo, hi = glo[g, a] - pad, ghi[g, a] + pad
                if d == 0.0:
                    if o < lo or o > hi:
                        skip = True
                    continue
                t0, t1 = (lo - o) / d, (hi - o) / d
                near = max(near, min(t0, t1))
                far = min(far, max(t0, t1))
            if skip or near > far or far < -pad:
                continue
            for f in range(g * group, min((g + 1) * group, faces.shape[0])):
                a0, a1, a2 = faces[f, 0], faces[f, 1], faces[f, 2]
                v0x, v0y, v0z = np.float64(v[a0, 0]), np.float64(v[a0, 1]), np.float64(v[a0, 2])
                v1x, v1y, v1z = np.float64(v[a1, 0]), np.float64(v[a1, 1]), np.float64(v[a1, 2])
                v2x, v2y, v2z = np.float64(v[a2, 0]), np.float64(v[a2, 1]), np.float64(v[a2, 2])
                if (v0x == v1x and v0y == v1y and v0z == v1z) or (v0x == v2x and v0y == v2y and v0z == v2z):
                    continue  # an edge from the first corner is exactly 0, so is embree's determinant
                e1x, e1y, e1z = v0x - v1x, v0y - v1y, v0z - v1z
                e2x, e2y, e2z = v2x - v0x, v2y - v0y, v2z - v0z
                cx, cy, cz = v0x - ox, v0y - oy, v0z - oz
                # Ng = e2 x e1, R = C x D (embree's Möller-Trumbore quantities)
                ngx, ngy, ngz = e2y * e1z - e2z * e1y, e2z * e1x - e2x * e1z, e2x * e1y - e2y * e1x
                rx, ry, rz = cy * dz - cz * dy, cz * dx - cx * dz, cx * dy - cy * dx
                den = ngx * dx + ngy * dy + ngz * dz
                u = rx * e2x + ry * e2y + rz * e2z
                w = rx * e1x + ry * e1y + rz * e1z
                t = ngx * cx + ngy * cy + ngz * cz
                n1 = abs(e1x) + abs(e1y) + abs(e1z)
                n2 = abs(e2x) + abs(e2y) + abs(e2z)
                nc = max(abs(cx) + abs(cy) + abs(cz), abs(v1x - ox) + abs(v1y - oy) + abs(v1z - oz),
                         abs(v2x - ox) + abs(v2y - oy) + abs(v2z - oz))  # Plücker's corners too
                eu, ew = slack * nc * nd * n2, slack * nc * nd * n1
                ed, et = slack * n1 * n2 * nd, slack * n1 * n2 * nc
                if abs(den) <= ed:  # the side the triangle faces is unsure
                    # a hit needs both edge functions within the determinant's size
                    if abs(u) - eu > abs(den) + ed or abs(w) - ew > abs(den) + ed:
                        continue
                    unsure = True
                    continue
                s = 1.0 if den > 0.0 else -1.0
                ad, us, ws, ts = abs(den), u * s, w * s, t * s
                rest = ad - us - ws
                er = eu + ew + ed + slack * (abs(us) + abs(ws) + ad)
                if us < -eu or ws < -ew or rest < -er or ts < -et:
                    continue  # a sure miss
                # the distance embree computes lies in [t_lo, t_hi] (its reciprocal good to 1e-6)
                t_lo = (ts - et) / (ad + ed) if ts - et >= 0.0 else (ts - et) / (ad - ed)
                t_hi = (ts + et) / (ad - ed)
                t_lo -= 1e-6 * abs(t_lo)
                t_hi += 1e-6 * abs(t_hi)
                if us > eu and ws > ew and rest > er and ts > et:
                    if best < 0 or t_hi < best_lo or (t_lo + t_hi < best_lo + best_hi):
                        if best >= 0:
                            other_lo = min(other_lo, best_lo)
                        best, best_lo, best_hi = f, t_lo, t_hi
                    else:
                        other_lo = min(other_lo, t_lo)
                else:
                    other_lo = min(other_lo, t_lo)
        tri[i] = best
        sure[i] = not unsure and (other_lo > best_hi if best >= 0 else other_lo == np.inf)
        if has.shape[0] == 0 or not sure[i] or best < 0:
            continue
        # the hit: the float64 ray on the plane of the triangle (its first corner, unit normal),
        # each product and sum in the order numpy's expressions round them (`sure_hits`)
        fa, fb, fc = faces[best, 0], faces[best, 1], faces[best, 2]
        ax, ay, az = v64[fb, 0] - v64[fa, 0], v64[fb, 1] - v64[fa, 1], v64[fb, 2] - v64[fa, 2]
        bx, by, bz = v64[fc, 0] - v64[fb, 0], v64[fc, 1] - v64[fb, 1], v64[fc, 2] - v64[fb, 2]
        nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        norm = np.sqrt((nx * nx + ny * ny) + nz * nz)
        if not norm > zero:
            continue  # a face of no area: no plane, no hit
        inv = 1.0 / norm
        nx, ny, nz = nx * inv, ny * inv, nz * inv
        px, py, pz = orig64[i, 0], orig64[i, 1], orig64[i, 2]
        qx, qy, qz = dirs64[i, 0], dirs64[i, 1], dirs64[i, 2]
        towards = ((v64[fa, 0] - px) * nx + (v64[fa, 1] - py) * ny) + (v64[fa, 2] - pz) * nz
        along = (qx * nx + qy * ny) + qz * nz
        if not abs(along) > 1e-5:
            continue  # the ray runs along the plane
        t = towards / along
        loc[i, 0], loc[i, 1], loc[i, 2] = qx * t + px, qy * t + py, qz * t + pz
        has[i] = True


def sure_first_hits(vertices: np.ndarray, faces: np.ndarray, boxes: tuple[np.ndarray, np.ndarray],
                    origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The triangle embree reports for each ray ``origins, directions (n, 3) float32`` on
    ``vertices (v, 3) float32, faces (f, 3) int64`` (`group_boxes` ``boxes``): ``(n,) int64``,
    -1 for none, and whether that answer is sure ``(n,) bool`` (unsure rows hold no answer)."""
    none = np.zeros((0, 3))
    tri, sure = np.full(len(origins), -1, np.int64), np.zeros(len(origins), np.bool_)
    if len(origins):
        _sure_first_hits(vertices, faces, GROUP, boxes[0], boxes[1], np.ascontiguousarray(origins, np.float32),
                         np.ascontiguousarray(directions, np.float32), SLACK, tri, sure, none, none, none, 0.0, none,
                         np.zeros(0, np.bool_))
    return tri, sure


def sure_hits(vertices: np.ndarray, faces: np.ndarray, boxes: tuple[np.ndarray, np.ndarray], origins: np.ndarray,
              directions: np.ndarray, exact: tuple[np.ndarray, np.ndarray, np.ndarray]
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`sure_first_hits` and, in the same pass, the hit of each sure ray: where the float64 ray
    meets its triangle's plane. ``exact``: the float64 vertices ``(v, 3)`` the float32
    ``vertices`` were scaled from, and the rays ``origins, directions (n, 3) float64`` (unit
    directions) that ``origins, directions`` round. Returns ``tri (n,) int64``, ``sure (n,)
    bool``, ``loc (n, 3) float64`` and which rows hold a hit ``(n,) bool``: a sure ray on a
    triangle, unless the triangle has no area or the ray runs along its plane (`acra.meshops
    .planes_lines`' 1e-5). Each hit is the same bits as `acra.meshops.face_normals` of its face
    followed by `acra.meshops.planes_lines` (trimesh's arithmetic), without their dozen numpy
    steps on a cast's few dozen rays."""
    n = len(origins)
    tri, sure = np.full(n, -1, np.int64), np.zeros(n, np.bool_)
    loc, has = np.empty((n, 3)), np.zeros(n, np.bool_)
    if n:
        v64, o64, d64 = (np.ascontiguousarray(a, np.float64) for a in exact)
        _sure_first_hits(vertices, faces, GROUP, boxes[0], boxes[1], np.ascontiguousarray(origins, np.float32),
                         np.ascontiguousarray(directions, np.float32), SLACK, tri, sure, v64, o64, d64,
                         meshops.TOL_ZERO, loc, has)
    return tri, sure, loc, has

