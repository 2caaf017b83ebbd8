"""Certified residual penetration: an upper bound of how deep any point of a set of triangles lies
inside a closed triangle mesh.

The residual a user sees is the depth of the continuous display triangles of one object inside
another closed object, not the depth at sample points. This module bounds it from above, to run
every detect/respond round. Its cost grows as ``(triangle size / target)^2`` where triangles lie
along the other surface within the target (``python3 benchmarks/clearance_cost.py``): eq. (4) only
knows distances at corners.

**Signed depth** (`signed_depth`). For a closed, watertight, outward-oriented triangle mesh ``B``,
``|sd(p)|`` is the exact distance from ``p`` to ``B``'s triangles, positive inside, negative outside.
The sign comes from angle-weighted pseudo-normals (Bærentzen & Aanæs 2005): with ``q`` the closest
point and ``n`` the pseudo-normal of the feature ``q`` lies on (the face normal in a face's interior,
the sum of the two faces' normals on an edge, the angle-weighted sum of the incident faces' normals
at a vertex),

    p is inside  <=>  (p - q) · n < 0.                                                    (1)

This is exact on watertight meshes and casts no rays. The feature is read from ``q``'s barycentric
coordinates in its face: a coordinate counts as 0 when ``q`` lies within `FEATURE` x the mesh
extent of that coordinate's edge line. The tolerance leans towards the lower-dimensional feature,
which keeps (1) right: if ``q`` is in a face's interior, ``p - q`` is parallel to the face normal
``n_f``, and an edge's ``n_f + n_g`` or a vertex's angle-weighted sum has a positive dot product
with ``n_f`` unless a face folds back onto its neighbour.

**Cells** (`triangle_depth`). ``sd`` is 1-Lipschitz, so on a triangle cell ``t`` with corners
``c_0, c_1, c_2``, for every point ``p`` of ``t``

    sd(p) <= max_i sd(c_i) + rho(t),                                                     (2)
    rho(t) = max_{p in t} min_i |p - c_i|                                                 (3)

the covering radius of ``t`` by its corners (`covering_radius`): the circumradius if ``t`` is acute
or right; for an obtuse ``t`` the farthest point lies on its longest edge, below half that edge's
length. Depth is ``max(0, sd)``, so a cell's bound is

    U(t) = max(0, max_i sd(c_i) + rho(t))                                                 (4)

and ``U(t) = 0`` certifies ``t`` wholly outside. Depth is the distance to the nearest point of
``B``'s surface, so for any one face ``F`` of ``B`` and every ``p``, ``depth(p) <= dist(p, F)``; the
distance to a triangle is convex, so over ``t`` it peaks at a corner, and with ``F_j`` the face
closest to corner ``c_j``

    depth(p) <= min_j max_i dist(c_i, F_j)    for every p in t,                             (6)

exact where the corners' closest points share a face (a cell on one face of a box), so a cell
lying along a large face needs no splitting however close it is; ``F_j`` may be the whole convex
planar facet of its face (a box's side), which is part of the surface as well. Inside a convex
solid the depth is the least distance to a face's plane, so for any face ``F`` with corner ``a``
and outward normal ``n``, ``depth(p) <= max(0, (a - p) . n)``, convex in ``p``:

    depth(p) <= min_j max_i max(0, (a_j - c_i) . n_j)    on a convex solid,                 (7)

0 for a cell lying on or outside one face's plane (a sheet resting on a box) and exact for a
cell under one face, however it crosses the face's outline. A cell's bound is the smallest of
(4), (6) and (7). A triangle whose box is apart from ``B``'s box is outside (``B`` lies in its box)
and is not queried; this holds for a whole solid only, not for a part of one (a patch of its
surface, whose box a triangle inside the solid may miss).

**Branch and bound.** Cells start as the given triangles. ``L``, the largest ``sd`` at any evaluated
point, bounds the true maximum from below. A cell with ``U(t) > max(target, 1.25 L)`` is split into
four at its edge midpoints (its children are congruent, so each has ``rho`` half its parent's; a
point shared by neighbouring cells, of one source triangle or two sharing an edge, is evaluated once);
passes repeat until no cell needs it, or the split depth reaches ``max_split``, or the point budget
is spent. ``L`` only grows, so a cell that needs no split never needs one later and leaves the
active set with its ``U``. The result ``bound = max_t U(t)`` over the final cells is an upper bound
in every case; ``complete`` says whether it is also within ``max(target, 1.25 L)``.

**Far corners** (`_signed_corners`). Most corners of a display near another object lie far
outside it. A closest-point search bounded by ``Q`` (2.5 times the largest covering radius) opens
only the boxes within ``Q``; a corner with no face that near is outside by more than ``Q`` or
inside by more than ``Q``, and the ball of radius ``Q`` about it holds no surface, so it has the
sign of any corner within ``Q`` along the triangles' edges. An outside one stands at ``-inf`` in
(4): every other corner's depth is above ``-Q``, so a cell's bound is the same, and 0 for a cell
of such corners alone (``rho <= Q``); its nearest face, which (6) reads, is found when a cell of
it has a bound above 0. An inside one is measured.

**Placement.** A mesh may sit under a 4x4 affine matrix with linear part ``M``; queries run in its
object space. An object-space distance ``d`` is at most ``sigma_max(M) d`` in world space (equal
for a similarity), so

    world bound = sigma_max(M) x object bound,   object target = world target / sigma_max(M).  (5)

Arrays are float64 unless stated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from acra import bvh, depthbound, meshrows, pseudonormals
from pipeline.spatial import ConvexHull, QhullError, cKDTree

__all__ = ["Solid", "solid", "signed_depth", "covering_radius", "Depth", "triangle_depth", "Unresolved",
           "sigma_max", "FEATURE"]

FEATURE = 1e-9  # a closest point this close (x the mesh extent) to an edge line lies on it, eq. (1)


@dataclass(frozen=True, eq=False)
class Solid:
    """A closed triangle mesh in its object space, with what signed depths need.

    vertices : (n, 3) float64, welded
    faces : (f, 3) int64, oriented outward (enclosed signed volume > 0)
    normals : (f, 3) float64, unit face normals
    edge_normals : (f, 3, 3) float64, per face the pseudo-normal of its edge from corner k to
        corner k+1 (mod 3): the sum of the two adjacent faces' normals, unit length
    vertex_normals : (n, 3) float64, angle-weighted sums of incident face normals, unit length
    bounds : (2, 3) float64, the vertices' box (min, max)
    tree : `acra.bvh.Tree` over the faces (exact closest points)
    facet : (f,) int64, the convex planar facet of each face (`_facets`): its faces are
        ``facet_faces[facet_start[k] : facet_start[k + 1]]`` for facet ``k``
    facet_start : (g + 1,) int64
    facet_faces : (f,) int64
    convex : bool, whether the solid is convex (eq. (7) then bounds cells)
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    edge_normals: np.ndarray
    vertex_normals: np.ndarray
    bounds: np.ndarray
    tree: bvh.Tree
    facet: np.ndarray
    facet_start: np.ndarray
    facet_faces: np.ndarray
    convex: bool = False


def _facets(v: np.ndarray, f: np.ndarray, normals: np.ndarray, other: np.ndarray, scale: float):
    """Faces grouped into convex planar facets: ``(facet (f,) int64, start (g + 1,) int64, faces
    (f,) int64)`` (CSR: facet ``k`` holds ``faces[start[k] : start[k + 1]]``).

    Two faces sharing an edge join when their normals agree and the other's far corner lies in
    the plane (to 1e-12 of the mesh's size); a group is kept whole only if its faces tile a
    convex polygon (its area equals that of the convex hull of its corners in its plane), else
    its faces stand alone. A box's side is one facet of its two triangles: eq. (6) against the
    facet is exact for a cell over the whole side, where against one triangle it sees the
    diagonal."""
    from scipy.sparse import coo_matrix  # here: the deformables-only run path never needs scipy.sparse.csgraph
    from scipy.sparse.csgraph import connected_components

    n = len(f)
    across = other // 3
    me = np.repeat(np.arange(n), 3)
    far = v[f[across, (other % 3 + 2) % 3]]  # the corner of the face across, off the shared edge
    same = (np.einsum("ij,ij->i", normals[me], normals[across]) > 1.0 - 1e-12) & (across != me)
    same &= np.abs(np.einsum("ij,ij->i", far - v[f[me, 0]], normals[me])) <= 1e-12 * scale
    if n <= SMALL_FACETS:
        label = _components(n, me[same], across[same])
    else:
        graph = coo_matrix((np.ones(int(same.sum())), (me[same], across[same])), shape=(n, n))
        label = connected_components(graph, directed=False)[1].astype(np.int64)
    sizes = np.bincount(label)
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    pairs = np.nonzero(sizes == 2)[0]
    if len(pairs):
        sure, apart = _pair_facets(v, f, normals, other, area, label, pairs)
        for k in pairs[apart]:
            rows = np.nonzero(label == k)[0]
            label[rows] = n + rows
        pairs = pairs[~sure]
    for k in np.r_[pairs, np.nonzero(sizes > 2)[0]].astype(np.int64):
        rows = np.nonzero(label == k)[0]
        corners = v[np.unique(f[rows])]
        nrm = normals[rows[0]]
        e1 = _unit(np.cross(nrm, [1.0, 0.0, 0.0] if abs(nrm[0]) < 0.9 else [0.0, 1.0, 0.0]))
        flat = np.stack([corners @ e1, corners @ np.cross(nrm, e1)], axis=1)
        try:
            hull = ConvexHull(flat).volume  # the area of a 2-d hull
        except QhullError:
            hull = np.inf
        if abs(hull - area[rows].sum()) > 1e-9 * max(hull, 1e-300):
            label[rows] = n + rows  # not convex: each face its own facet
    _, label = np.unique(label, return_inverse=True)
    order = np.argsort(label, kind="stable")
    start = np.r_[0, np.cumsum(np.bincount(label))]
    return label.astype(np.int64), start.astype(np.int64), order.astype(np.int64)


SMALL_FACETS = 256  # faces up to which `_facets` joins its facets by a union-find instead of scipy's graph


def _components(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Connected components ``(n,) int64`` of the graph on ``n`` nodes with edges ``a[i] - b[i]``,
    each labelled by its least node. Renumbered by `np.unique` they are scipy's
    ``connected_components`` labels, which number the components in the order of their least
    node: `_facets` only ranks them."""
    parent = list(range(n))

    def root(x: int) -> int:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for x, y in zip(a.tolist(), b.tolist()):
        rx, ry = root(x), root(y)
        if rx != ry:
            parent[max(rx, ry)] = min(rx, ry)
    return np.array([root(x) for x in range(n)], np.int64)


def _pair_facets(v: np.ndarray, f: np.ndarray, normals: np.ndarray, other: np.ndarray, area: np.ndarray,
                 label: np.ndarray, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`_facets`' convexity test of the groups ``pairs (g,)`` of exactly two faces, where it is
    sure without a hull: ``sure (g,) bool`` and, of those, ``apart (g,) bool``, the groups that
    are not convex (their faces stand alone).

    The faces ``(a, b, c)`` and ``(b, a, d)`` share the edge ``ab``, lie in one plane and wind
    alike, so ``c`` and ``d`` lie on either side of the line ``ab``: their union is convex where
    the segment ``cd`` meets the segment ``ab``. Otherwise ``a`` or ``b`` lies inside the triangle
    the other forms with ``c`` and ``d``, and the hull exceeds the two faces' areas by the
    triangle ``(c, d, x)`` of the one inside: ``x``'s signed height over ``cd`` (in the plane, by
    the face normal ``n``: ``((d - c) x (x - c)) . n``) with the other's sign and the smaller
    magnitude. `_facets`' hull test keeps a group whose excess is at most 1e-9 of the hull's
    area; a group is decided here where the excess is surely below 1e-11 of it or above 1e-7,
    and only where the two faces' area is at least 1e-2 of the square of the diagonal of the
    four corners' box (the rounding of these products and of the hull's is then below 1e-13 of
    its area); the rest go to the hull."""
    g = len(pairs)
    order = np.argsort(label, kind="stable")
    first = np.searchsorted(label[order], pairs)
    r1, r2 = order[first], order[first + 1]
    slots = 3 * r1[:, None] + np.arange(3)
    k = np.argmax(other[slots] // 3 == r2[:, None], axis=1)  # r1's edge r2 shares
    s = slots[np.arange(g), k]
    a, b = v[f[r1, k]], v[f[r1, (k + 1) % 3]]
    c, d = v[f[r1, (k + 2) % 3]], v[f[r2, (other[s] % 3 + 2) % 3]]
    nrm = normals[r1]
    cd = d - c
    ha = np.einsum("ij,ij->i", np.cross(cd, a - c), nrm)
    hb = np.einsum("ij,ij->i", np.cross(cd, b - c), nrm)
    faces = area[r1] + area[r2]
    excess = np.where(ha * hb > 0, 0.5 * np.minimum(np.abs(ha), np.abs(hb)), 0.0)
    hull = faces + excess
    quad = np.stack([a, b, c, d], axis=1)
    span = (quad.max(axis=1) - quad.min(axis=1)) ** 2
    shaped = np.isfinite(hull) & (faces >= 1e-2 * span.sum(axis=1)) & (other[s] // 3 == r2)
    apart = shaped & (excess > 1e-7 * hull)
    return apart | (shaped & (excess < 1e-11 * hull)), apart


def _unit(v: np.ndarray) -> np.ndarray:
    """``v (..., 3)`` scaled to unit length along the last axis (zero rows stay zero)."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def _weld(vertices: np.ndarray, radius: float) -> np.ndarray:
    """Label ``(n,) int64`` in ``0 .. g-1`` of each of ``vertices (n, 3)``: vertices chained by
    distances ``<= radius`` share one."""
    from scipy.sparse import coo_matrix  # here: the deformables-only run path never needs scipy.sparse.csgraph
    from scipy.sparse.csgraph import connected_components

    n = len(vertices)
    pairs = cKDTree(vertices).query_pairs(radius, output_type="ndarray") if radius > 0 else np.zeros((0, 2), np.int64)
    if not len(pairs):
        return np.arange(n, dtype=np.int64)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1].astype(np.int64)


def solid(vertices, faces, weld: float = 1e-7, part: bool = False, outward: float | None = None,
          scale: float | None = None, compiled: bool = True) -> Solid:
    """A `Solid` from ``vertices (n, 3) float`` and ``faces (f, 3) int``.

    Vertices closer than ``weld`` x ``scale`` (default: the bounding-box diagonal) are welded (a
    closed H-spline's display mesh repeats its pole rows' point and its periodic seam); faces
    narrower than that distance (height over their longest edge, which includes faces with two
    welded corners) and repeated faces are dropped. Raises ValueError naming the defect if the
    rest is not a closed 2-manifold: an edge used by one face (a hole) or by more than two, an
    edge two faces traverse the same way (inconsistent winding), or no enclosed volume. Faces are
    flipped if the enclosed signed volume is negative.

    ``part``: the faces are the part of a closed mesh near where the queries are (`part_of`), so
    edges on the part's rim have one face (their pseudo-normal is that face's) and the
    orientation is not read from a volume: ``outward`` is ``+1`` if the faces' winding gives
    outward normals, ``-1`` if inward. A part is built past the weld by compiled loops
    (`acra.pseudonormals`, the same bits) unless ``compiled`` is false (the array form below).
    A part's BVH is `acra.bvh.build_linear`'s (built in linear time: a part is queried in one
    round), a whole solid's `acra.bvh.build`'s (median splits, queried for a run); the closest
    points do not depend on the tree.
    """
    v = np.asarray(vertices, np.float64).reshape(-1, 3)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    if not len(f):
        raise ValueError("solid: no faces")
    flip = outward is not None and outward < 0
    if part and compiled and scale is not None and len(v) < 2_000_000:
        mesh = pseudonormals.welded_part(np.ascontiguousarray(v), np.ascontiguousarray(f), weld * scale, flip)
        if mesh[0] >= 0:
            return _compiled_part(mesh, outward, vertices, faces, weld, scale)
    used = np.unique(f)
    if scale is None:
        scale = float(np.linalg.norm(np.ptp(v[used], axis=0)))
    radius = weld * scale
    label = _weld(v[used], radius)
    first = np.unique(label, return_index=True)[1]  # first member of each group
    v = v[used][first]
    f = label[np.searchsorted(used, f)]
    if part and compiled and len(v) < 2_000_000:
        return _compiled_part(pseudonormals.part_mesh(v, f, radius, flip), outward, vertices, faces, weld, scale)
    tri = v[f]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    longest = np.sqrt((np.diff(tri[:, [0, 1, 2, 0]], axis=1) ** 2).sum(axis=2).max(axis=1))
    f = f[np.linalg.norm(cross, axis=1) > radius * longest]  # twice the area = height x longest edge
    key = np.sort(f, axis=1)
    if len(v) < 2_000_000:  # n^3 fits in int64
        key = key[:, 0] * len(v) ** 2 + key[:, 1] * len(v) + key[:, 2]
    f = f[np.sort(np.unique(key, axis=0 if key.ndim == 2 else None, return_index=True)[1])]
    if not len(f):
        raise ValueError("solid: every face is degenerate")
    live = np.unique(f)  # vertices only dropped faces used
    v, f = v[live], np.searchsorted(live, f)
    n = len(v)

    # every undirected edge in exactly two faces, traversed oppositely by them
    head, tail = f.reshape(-1), f[:, [1, 2, 0]].reshape(-1)  # slot 3r+k: face r's edge from corner k to k+1
    undirected = np.minimum(head, tail) * n + np.maximum(head, tail)
    order = np.argsort(undirected, kind="stable")
    keys = undirected[order]
    _, start, count = np.unique(keys, return_index=True, return_counts=True)
    if np.any(count > 2) or (not part and np.any(count != 2)):
        raise ValueError(f"solid: not watertight: {int((count == 1).sum())} boundary edges (one face), "
                         f"{int((count > 2).sum())} non-manifold edges (more than two faces)")
    if len(np.unique(head * n + tail)) != len(head):
        raise ValueError("solid: faces inconsistently oriented (an edge traversed the same way by both its faces)")
    if not part:
        base = v[f[:, 0]]  # volume: sum of det(v0 - c, v1 - c, v2 - c) / 6 about the centroid c
        volume = np.einsum("ij,ij->", base - v.mean(axis=0), np.cross(v[f[:, 1]] - base, v[f[:, 2]] - base)) / 6.0
        size = float(np.linalg.norm(np.ptp(v, axis=0)))
        if abs(volume) <= 1e-12 * size ** 3:
            raise ValueError("solid: the mesh encloses no volume")
        flip = volume < 0
    if flip:
        f = f[:, ::-1].copy()
        head, tail = f.reshape(-1), f[:, [1, 2, 0]].reshape(-1)
        undirected = np.minimum(head, tail) * n + np.maximum(head, tail)
        order = np.argsort(undirected, kind="stable")
        keys = undirected[order]
    tri = v[f]
    normals = _unit(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]))
    other = np.arange(len(head))  # the slot across each edge (itself on a part's rim)
    pair = np.nonzero(keys[1:] == keys[:-1])[0]
    other[order[pair]], other[order[pair + 1]] = order[pair + 1], order[pair]
    edge_normals = _unit(np.repeat(normals, 3, axis=0) + normals[other // 3]).reshape(-1, 3, 3)
    # corner angles, atan2(|e1 x e2|, e1 . e2), weight the vertex pseudo-normals
    e1, e2 = tri[:, [1, 2, 0]] - tri, tri[:, [2, 0, 1]] - tri
    angle = np.arctan2(np.linalg.norm(np.cross(e1, e2), axis=2), np.einsum("fkc,fkc->fk", e1, e2))
    weighted = (angle[:, :, None] * normals[:, None, :]).reshape(-1, 3)
    vertex_normals = _unit(np.stack([np.bincount(head, weighted[:, c], minlength=n) for c in range(3)], axis=1))
    bounds = np.stack([v.min(axis=0), v.max(axis=0)])
    convex = False
    if part:  # a deformable's display: curved, no two faces share a plane
        facet, start, members = np.arange(len(f)), np.arange(len(f) + 1), np.arange(len(f))
    else:
        size = float(np.linalg.norm(np.ptp(v, axis=0)))
        facet, start, members = _facets(v, f, normals, other, size)
        try:  # convex: the hull of the corners encloses no more than the mesh
            convex = ConvexHull(v).volume <= abs(volume) * (1 + 1e-9) + 1e-12 * size ** 3
        except QhullError:
            convex = False
    tree = bvh.build_linear(v, f) if part else bvh.build(v[f])
    return Solid(v, f, normals, edge_normals, vertex_normals, bounds, tree, facet, start, members, convex)


def _compiled_part(mesh: tuple, outward, vertices, faces, weld, scale) -> Solid:
    """`solid` of a part from its mesh (`acra.pseudonormals.part_mesh`'s answer) and the rest in one
    compiled call (`acra.bvh.part_tree`); a defect is raised by the array form, from the given
    ``vertices`` and ``faces``."""
    code, v, f, normals, edge_normals, sin, cos = mesh
    if code:
        return solid(vertices, faces, weld, True, outward, scale, compiled=False)  # raises the defect's error
    vertex_normals, box, tree = bvh.part_tree(v, f, normals, np.arctan2(sin, cos))
    facet = np.arange(len(f))
    return Solid(v, f, normals, edge_normals, vertex_normals, box, tree, facet, np.arange(len(f) + 1), facet.copy())


def signed_depth(s: Solid, points) -> tuple[np.ndarray, np.ndarray]:
    """Signed depths ``sd (k,) float64`` (positive inside) of ``points (k, 3) float`` in ``s``'s
    object space, and their closest points ``(k, 3) float64`` on ``s``: eq. (1)."""
    sd, close, _ = _signed(s, points)
    return sd, close


class Unresolved(Exception):
    """A point's closest point on a part of a solid lies farther than the part answers for."""


def _signed(s: Solid, points, reach: float = np.inf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`signed_depth` plus the face row ``(k,) int64`` of each closest point. Raises `Unresolved`
    if a point is farther than ``reach`` from every face."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    if not len(p):
        return np.zeros(0), np.zeros((0, 3)), np.zeros(0, np.int64)
    dist, close, face, bary = bvh.closest(s.tree, p, None if not np.isfinite(reach) else np.full(len(p), reach))
    if np.any(face < 0):
        raise Unresolved
    return pseudonormals.signs(p, dist, close, face, bary, s.vertices, s.faces, s.normals, s.edge_normals,
                               s.vertex_normals, FEATURE * _extent(s)), close, face


def covering_radius(tri) -> np.ndarray:
    """``rho (t,) float64`` of eq. (3) for triangles ``tri (t, 3, 3) float``. An acute or right
    triangle's is its circumradius ``abc / (4 area)`` (the circumcentre is in it). An obtuse one's
    circumcentre lies beyond its longest edge ``AB``; the farthest point from the corners is where
    the perpendicular bisector of ``AC`` or ``BC`` crosses ``AB``, at ``|AC| / (2 cos A)`` from ``A``
    (or ``|BC| / (2 cos B)`` from ``B``), which is below half of ``AB``."""
    tri = np.asarray(tri, np.float64)
    edge = tri[:, [1, 2, 0]] - tri  # edge k from corner k to k+1
    sq = (edge**2).sum(axis=2)  # (t, 3)
    k = np.argmax(sq, axis=1)[:, None]  # the longest edge, A = corner k, B = corner k+1, C = corner k+2
    ab, bc, ca = (np.take_along_axis(sq, (k + i) % 3, axis=1)[:, 0] for i in range(3))
    obtuse = ab > bc + ca
    twice_area = np.linalg.norm(np.cross(edge[:, 0], -edge[:, 2]), axis=1)
    circum = np.sqrt(ab * bc * ca) / np.where(twice_area > 0, 2 * twice_area, 1.0)
    # |AC| / (2 cos A) = |AC|^2 |AB| / (2 AC . AB), and the same from B; a corner on A or B gives |AB| / 2
    dot_a, dot_b = 0.5 * (ab + ca - bc), 0.5 * (ab + bc - ca)  # AC . AB, BC . BA by the law of cosines
    root = np.sqrt(ab)
    from_a = np.where(dot_a > 0, ca * root / np.where(dot_a > 0, 2 * dot_a, 1.0), 0.0)
    from_b = np.where(dot_b > 0, bc * root / np.where(dot_b > 0, 2 * dot_b, 1.0), 0.0)
    return np.where(obtuse | (twice_area == 0), np.maximum(from_a, from_b), circum)


@dataclass
class Depth:
    """How deep triangles reach into a `Solid`, in the triangles' (the solid's object) units.

    bound : certified upper bound of the depth of any point of the triangles, eq. (4)
    lower : the largest depth at an evaluated point (0 if none is inside)
    complete : False if the split cap or the point budget stopped refinement while some cell's
        bound was above ``max(target, 1.25 lower)``
    tri : (m,) int64, the source triangle of each evaluated point with depth > 0
    bary : (m, 3) float64, its barycentric coordinates in that triangle
    points : (m, 3) float64, the point
    depth : (m,) float64, its depth (> 0)
    evaluated : number of points whose signed depth was evaluated
    split : the deepest split level any cell reached
    stopped : True if a point deeper than `triangle_depth`'s ``stop`` ended the search: ``bound``
        is then ``lower``, a lower bound only, and ``complete`` is False
    """

    bound: float
    lower: float
    complete: bool
    tri: np.ndarray
    bary: np.ndarray
    points: np.ndarray
    depth: np.ndarray
    evaluated: int
    split: int
    stopped: bool = False


def _at(tri: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Points ``(k, 3)`` at barycentric ``w (k, 3)`` in ``tri (k, 3, 3)``, summed corner by corner:
    a point on an edge two triangles share comes out bit for bit the same from either (the third
    term is 0 and addition commutes), so `_distinct` evaluates it once."""
    return w[:, :1] * tri[:, 0] + w[:, 1:2] * tri[:, 1] + w[:, 2:] * tri[:, 2]


def _distinct(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The distinct rows of ``points (k, 3) float64`` (bitwise), the index ``(u,) int64`` of each one's
    first occurrence and the inverse ``(k,) int64``."""
    # in the order of np.unique over the rows as 24 raw bytes (memcmp), compiled
    p = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    first, inverse = meshrows.distinct_rows(p)
    return p[first], first, inverse


def _at_cells(tri: np.ndarray, owner: np.ndarray, lattice: np.ndarray, steps: int) -> np.ndarray:
    """Corners ``(c, 3, 3)`` of cells given by their source triangles ``tri[owner]`` and integer
    barycentric ``lattice (c, 3, 3)`` (per corner, its weights times ``steps``)."""
    return depthbound.lattice_points(tri, owner, lattice, steps).reshape(-1, 3, 3)  # `_at`, compiled


ALL_PLANES = 64  # a convex solid with at most this many facets is bounded by every facet's plane


def _plane_bound(s: Solid, cells: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Eq. (7) for cells ``(c, 3, 3)`` of a convex solid whose corners' closest faces are ``faces
    (c, 3) int64``: ``min_j max_i max(0, (a_j - c_i) . n_j)``, ``(c,) float64``, with ``a_j``,
    ``n_j`` a corner and the outward normal of ``F_j``. A solid of at most `ALL_PLANES` facets
    (a box) takes every facet's plane as an ``F_j``: a cell in a box's corner, its corners on two
    sides, is bounded by the bottom it lies along."""
    if len(s.facet_start) - 1 <= ALL_PLANES:
        rows = s.facet_faces[s.facet_start[:-1]]
        a, n = s.vertices[s.faces[rows, 0]], s.normals[rows]  # (g, 3) one face of each facet
        inner = (np.einsum("gk,gk->g", a, n)[None, :, None] - np.einsum("cik,gk->cgi", cells, n))  # (c, g, i)
    else:
        a, n = s.vertices[s.faces[faces, 0]], s.normals[faces]  # (c, 3 j, 3)
        inner = np.einsum("cjk,cjk->cj", a, n)[:, :, None] - np.einsum("cik,cjk->cji", cells, n)  # (c, j, i)
    return np.maximum(inner, 0.0).max(axis=2).min(axis=1)


def _face_bound(s: Solid, cells: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Eq. (6) for cells ``(c, 3, 3)`` whose corners' closest faces are ``faces (c, 3) int64``:
    ``min_j max_i dist(c_i, P_j)``, ``(c,) float64``, with ``P_j`` the convex facet of ``F_j``
    (`_facets`; the distance to a convex set is convex too, and the facet is part of the
    surface): ``dist(c_i, P_j)`` is the least distance to the facet's faces."""
    return depthbound.facet_bound(cells, faces, s.vertices, s.faces, s.facet, s.facet_start, s.facet_faces)


def _cell_bound(s: Solid, cells: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The tighter of eq. (6) and, on a convex solid, eq. (7): ``(c,) float64``."""
    out = _face_bound(s, cells, faces)
    return np.minimum(out, _plane_bound(s, cells, faces)) if s.convex else out


def _extent(s: Solid) -> float:
    """The largest side of the solid's box (the scale of eq. (1)'s feature tolerance)."""
    return float(np.ptp(s.bounds, axis=0).max()) or 1.0


def _retired_max(s: Solid, tri, src, steps, retired: float, bound, cells, rows, lattice, fc) -> float:
    """``max(retired, max of the tighter of eq. (4) ``bound`` and eq. (6) over ``cells``)``, eq. (6)
    taken only where eq. (4) is above the largest so far: the cells by eq. (4) in decreasing
    order, in doubling batches, until the next is no higher (a maximum is exact, so the bits are
    those of bounding every cell)."""
    cells = cells[bound[cells] > retired]
    if not len(cells):
        return retired
    cells = cells[np.argsort(-bound[cells], kind="stable")]
    at, size = 0, 16
    while at < len(cells) and bound[cells[at]] > retired:
        batch = cells[at:at + size]
        six = _cell_bound(s, _at_cells(tri, src[rows[batch]], lattice[batch], steps), fc[batch])
        retired = max(retired, float(np.minimum(bound[batch], six).max()))
        at, size = at + size, 2 * size
    return retired


def triangle_depth(s: Solid, corners, target: float, max_split: int = 6, budget: int = 200_000,
                   reach: float = np.inf, decide: float = np.inf, compiled: bool = True,
                   stop: float = np.inf) -> Depth | None:
    """`Depth` of triangles ``corners (t, 3, 3) float`` (in ``s``'s object space) inside ``s``,
    refined until every cell's ``U <= max(target, 1.25 L)``, ``max_split`` levels, or ``budget``
    evaluated points (the given triangles' corners are always evaluated). On a whole solid, a
    triangle whose box does not meet ``s.bounds`` has no point inside and is not queried.

    ``reach``: ``s`` is a part of a solid that answers exactly for points within this distance of
    it (`solid` with ``part``); ``None`` is returned if an evaluated point lies farther, or a
    triangle's box lies farther than ``reach`` from ``s.bounds``. Every triangle is queried on a
    part: one missing the part's box may lie inside the solid (a triangle under a curved cap).
    ``decide``: a depth the caller compares the bound with (a tolerance): while no evaluated point
    is deeper than it, a cell bounded above it is split too, so a bound within 1.25 of the depth
    found does not put a clear surface over the tolerance.
    ``compiled``: the whole branch and bound runs in one compiled call (`acra.depthbound.depth`, the
    same bits) unless false (this module's array form: `_signed_corners`, `_levels`).
    ``stop``: the search ends after the first level (the corners, then each split's midpoints)
    whose points reach deeper than it (`Depth.stopped`): a caller asking only whether the
    depth exceeds a figure learns it from one such point. Every step before is the full
    search's, so the points found are the first of the full search's; without such a point
    the answer is the full search's.
    """
    try:
        return _triangle_depth(s, corners, target, max_split, budget, reach, decide, compiled, stop)
    except Unresolved:
        return None


def _triangle_depth(s: Solid, corners, target: float, max_split: int, budget: int, reach: float,
                    decide: float = np.inf, compiled: bool = True, stop: float = np.inf) -> Depth:
    if not 0 <= max_split <= 30:
        raise ValueError(f"max_split must be in 0..30, not {max_split}")
    tri = np.ascontiguousarray(corners, np.float64).reshape(-1, 3, 3)
    steps = 1 << max_split  # integer barycentric lattice: weights (i, j, steps - i - j) / steps
    if compiled:
        planes = None  # eq. (7): every facet's plane, or each corner's closest face's (`_plane_bound`)
        if s.convex:
            planes = s.facet_faces[s.facet_start[:-1]] if len(s.facet_start) - 1 <= ALL_PLANES else np.zeros(0, np.int64)
        out = depthbound.depth(tri, s.bounds, np.isfinite(reach), reach, target, decide, max_split, budget, FAR, LINK, s.tree,
                        s.vertices, s.faces, s.normals, s.edge_normals, s.vertex_normals, FEATURE * _extent(s), s.facet,
                        s.facet_start, s.facet_faces, planes, stop)
        if out is None:
            raise Unresolved
        retired, low, complete, evaluated, level, t, lat, p, d, stopped = out
        return Depth(retired, max(low, 0.0), complete, t, lat / steps, p, d, evaluated, level, stopped)
    if np.isfinite(reach):
        # a part is a patch of the surface: a triangle missing its box may still lie inside the
        # solid (under a curved cap), so none is skipped; one whose box is beyond ``reach`` of the
        # part's box has every point farther than the part answers for
        if not meshrows.boxes_meet(tri, s.bounds[0], s.bounds[1], reach).all():
            raise Unresolved
        src, live = np.arange(len(tri)), tri  # every triangle, without a copy
    else:  # a whole solid lies in its box: a triangle missing it has no point inside
        src = np.nonzero(meshrows.boxes_meet(tri, s.bounds[0], s.bounds[1], 0.0))[0]
        live = tri[src]
    rho0 = depthbound.covering_radii(live)  # (c,) per live source triangle (covering_radius compiled), halved per split level
    found: list[tuple] = []  # (tri, bary, points, sd) of evaluated points with sd > 0

    def keep(rows, lattice, pts, sd):
        inside = sd > 0
        found.append((rows[inside], lattice[inside] / steps, pts[inside], sd[inside]))

    # level 0: each distinct corner once; corners far outside get -inf and no face (`_signed_corners`)
    pts, first, inverse = _distinct(live.reshape(-1, 3))
    corner_pts = inverse.reshape(-1, 3)
    sd_pts, face_pts, pending = _signed_corners(s, pts, corner_pts, rho0, reach)
    evaluated = len(pts)
    lattice = np.broadcast_to(steps * np.eye(3, dtype=np.int64), (len(src), 3, 3))  # (c, 3 corners, 3 weights)
    keep(src[first // 3], lattice[first // 3, first % 3], pts, sd_pts)
    sd = sd_pts[inverse.reshape(-1)].reshape(-1, 3)
    fc = face_pts[inverse.reshape(-1)].reshape(-1, 3)
    rows, rho = np.arange(len(src)), rho0  # cells: row into src, lattice, corner sd, corner faces, rho
    low = float(sd_pts.max()) if len(pts) else -np.inf
    retired, level, complete, stopped = 0.0, 0, True, False
    if len(rows) and low > stop:  # a corner deeper than ``stop`` answers the caller
        retired, complete, stopped = low, False, True
    elif len(rows):
        bound = _eq4(sd, rho)
        if pending is not None:  # eq. (6) needs the nearest faces of the far corners of cells above 0
            wanted = np.zeros(len(pts), np.bool_)  # the corners of these cells, once each, in order
            wanted[corner_pts[bound > 0.0]] = True
            ids = np.nonzero(wanted & pending)[0]
            if len(ids):
                sd_pts[ids], _, face_pts[ids] = _signed(s, pts[ids], reach)
                sd, fc = sd_pts[corner_pts], face_pts[corner_pts]
        retired, low, complete, evaluated, level, stopped = _levels(s, tri, src, steps, target, max_split, budget, reach,
                                                                    decide, keep, rows, lattice, sd, fc, rho, bound, low,
                                                                    evaluated, stop)
    t, b, p, d = (np.concatenate(x) for x in zip(*found))
    return Depth(retired, max(low, 0.0), complete, t.astype(np.int64), b, p, d, evaluated, level, stopped)


def _eq4(sd: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """Eq. (4) ``(c,) float64`` of cells with corner depths ``sd (c, 3)`` and covering radii ``rho
    (c,)``; the largest corner as two elementwise maxima: numpy's reduction along an axis of 3
    costs about 40 ns a row, the maxima 2."""
    return np.maximum(np.maximum(np.maximum(sd[:, 0], sd[:, 1]), sd[:, 2]) + rho, 0.0)


def _levels(s: Solid, tri, src, steps, target, max_split, budget, reach, decide, keep, rows, lattice, sd, fc, rho, bound,
            low, evaluated, stop=np.inf):
    """The branch and bound from level 0's cells (``bound`` their eq. (4)) in numpy: ``(bound, low,
    complete, evaluated, level, stopped)``, the points found inside handed to ``keep``; a level
    whose points reach deeper than ``stop`` ends it (``stopped``, ``bound`` is ``low``).
    `acra.depthbound.depth` compiles it in the same arithmetic and order; this form is the
    reference the compiled one is held to."""
    retired, level, complete = 0.0, 0, True
    while len(rows):
        now = max(target, 1.25 * max(low, 0.0))
        if level:
            bound = _eq4(sd, rho)
        over = np.nonzero(bound > 0.0)[0]
        # eq. (6): the faces nearest the corners bound the cell too. It only lowers a bound, so a
        # cell that eq. (4) already retires is retired with it, and its bound only counts where it
        # could raise the largest retired bound (`_retired_max`)
        split = (bound > now) | ((bound > decide) & (low <= decide))
        if len(over):
            first = over[split[over]]
            if len(first):
                bound[first] = np.minimum(bound[first], _cell_bound(s, _at_cells(tri, src[rows[first]], lattice[first], steps), fc[first]))
        need = (bound > now) | ((bound > decide) & (low <= decide))
        retired = max(retired, float(bound[~need & split].max(initial=0.0)))
        if len(over):
            retired = _retired_max(s, tri, src, steps, retired, bound, over[~split[over]], rows, lattice, fc)
        rows, lattice, sd, fc, rho, bound = rows[need], lattice[need], sd[need], fc[need], rho[need], bound[need]
        room = (budget - evaluated) // 3
        if not len(rows) or level == max_split or room <= 0:
            complete = not len(rows)
            retired = max(retired, float(bound.max(initial=0.0)))
            break
        if room < len(rows):  # the budget's last pass: the cells of largest bound
            top = np.argsort(-bound, kind="stable")[:room]
            retired = max(retired, float(np.delete(bound, top).max(initial=0.0)))
            complete = False
            rows, lattice, sd, fc, rho = rows[top], lattice[top], sd[top], fc[top], rho[top]
        # midpoints of edges (0,1), (1,2), (2,0); lattice steps at this level are even
        mid = (lattice + lattice[:, [1, 2, 0]]) // 2  # (c, 3, 3)
        pts, first, inverse = _distinct(depthbound.lattice_points(tri, src[rows], mid, steps))  # `_at`, compiled
        wts = mid.reshape(-1, 3)[first]
        sd_mid, _, face_mid = _signed(s, pts, reach)
        evaluated += len(pts)
        keep(src[rows[first // 3]], wts, pts, sd_mid)
        low = max(low, float(sd_mid.max(initial=-np.inf)))
        if low > stop:
            return low, low, False, evaluated, level, True
        # children (c0, m01, m20), (m01, c1, m12), (m20, m12, c2), (m01, m12, m20), child by child
        lattice, sd, fc, rows, rho = depthbound.children(lattice, mid, sd, sd_mid, fc, face_mid, inverse, rows, rho)
        level += 1
        if not complete:  # the budget's last pass: bound the children and stop
            last = np.minimum(_eq4(sd, rho), _cell_bound(s, _at_cells(tri, src[rows], lattice, steps), fc))
            retired = max(retired, float(last.max()))
            complete = retired <= max(target, 1.25 * max(low, 0.0)) and not (decide < retired and low <= decide)
            break
    return retired, low, complete, evaluated, level, False


FAR = 2.5  # corners with no face within FAR x the largest covering radius are signed by their neighbours
LINK = 0.8  # ... along edges shorter than LINK x that distance


def _signed_corners(s: Solid, pts: np.ndarray, cells: np.ndarray, rho: np.ndarray, reach: float):
    """Eq. (1) at the distinct level-0 corners ``pts (n, 3)`` of cells ``cells (c, 3) int64`` (rows of
    ``pts``) with covering radii ``rho (c,)``: ``(sd (n,), face (n,) int64, pending (n,) bool or
    None)``, exact (as `_signed`) except at corners ``pending``: outside by more than ``Q``, with
    ``sd = -inf`` and ``face = -1``.

    ``Q = min(FAR max(rho), reach)``. A closest-point search bounded by ``Q`` opens only the boxes
    within ``Q``: a corner with no face that near (a display corner far from the other object's
    part, most of them) costs a few boxes instead of every box nearer than its answer. Its
    sign is its neighbour's: the ball of radius ``Q`` about it holds no point of the surface (no
    face of the part, hence none of the whole within ``reach``), so an edge shorter than ``Q``
    from it does not cross the surface. Signs spread along the cells' edges shorter than ``LINK
    Q`` from the corners found near, with the sum of the edges' lengths and the near corner's
    distance bounding each corner's distance; a group of far corners no near one reaches gets
    one corner queried exactly. A far corner found inside, or not certainly within ``reach``
    (where `_signed` raises `Unresolved`), is queried exactly.

    A pending corner's depth is below ``-Q``, a non-pending one's is at least ``-Q`` (or exact),
    so eq. (4)'s ``max_i sd(c_i) + rho`` is the same for a cell with any other corner, and 0 for
    a cell of pending corners alone (``rho <= Q``); the largest depth found and the points found
    inside are the same. A cell whose bound is above 0 has its pending corners queried before
    eq. (6) reads their faces (`_triangle_depth`), so the bound is the same bits."""
    q = min(FAR * float(rho.max(initial=0.0)), reach)
    if not len(pts) or not q >= float(rho.max(initial=0.0)) or not q > 0:
        sd, _, face = _signed(s, pts, reach)
        return sd, face, None
    p = np.ascontiguousarray(pts, np.float64)
    dist, close, face, bary = bvh.closest(s.tree, p, np.full(len(p), q))
    known = face >= 0
    sd = np.full(len(p), -np.inf)
    if known.any():
        sd[known] = pseudonormals.signs(p[known], dist[known], close[known], face[known], bary[known], s.vertices,
                                        s.faces, s.normals, s.edge_normals, s.vertex_normals, FEATURE * _extent(s))
    if known.all():
        return sd, face, None
    sign = np.where(known, np.where(sd > 0, 1, -1), 0).astype(np.int8)
    ub = np.where(known, dist, np.inf)
    start, neighbour, length = pseudonormals.links(p, np.ascontiguousarray(cells, np.int64), LINK * q)
    pseudonormals.flood(start, neighbour, length, np.nonzero(known)[0], sign, ub)
    reps = pseudonormals.representatives(start, neighbour, sign)
    if len(reps):  # a group of far corners no near corner reaches: one of each exactly
        sd[reps], _, face[reps] = _signed(s, p[reps], reach)
        sign[reps] = np.where(sd[reps] > 0, 1, -1)
        ub[reps] = np.abs(sd[reps])
        pseudonormals.flood(start, neighbour, length, reps, sign, ub)
    exact = np.nonzero((face < 0) & ((sign > 0) | (ub > reach)))[0]
    if len(exact):
        sd[exact], _, face[exact] = _signed(s, p[exact], reach)
    pending = face < 0
    return sd, face, (pending if pending.any() else None)


def sigma_max(matrix) -> float:
    """The largest singular value of the linear part of an affine ``matrix (4, 4) float``
    (column-vector convention): eq. (5)'s factor from object to world distances."""
    return float(np.linalg.svd(np.asarray(matrix, np.float64)[:3, :3], compute_uv=False)[0])
