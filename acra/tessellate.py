"""Tessellations of an H-spline: the fixed-topology display grid and per-patch collision grids.

Both are uniform ``(u, v)`` grids, so every vertex carries its parameters and every face its
level-0 patch. The display grid's topology depends only on the level-0 grid size, the wraps and
``samples`` (contract §1), never on the hierarchy or the frame; collision grids are built per
level-0 patch so detection can tessellate only the patches whose control hulls can touch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .basis import Direction
from .hspline import Details, HSpline, details, evaluate, surface_normals

__all__ = [
    "GridTopology",
    "display_topology",
    "evaluate_grid",
    "grid_samples",
    "pole_normals",
    "patch_grids",
    "patch_hulls",
]


@dataclass(frozen=True)
class GridTopology:
    """A uniform parameter grid and its faces.

    Attributes
    ----------
    u, v : (n,) float64
        Parameters of every vertex (level-0 units), vertex ``i * nv + j`` at ``(us[i], vs[j])``.
    shape : (int, int)
        Vertex counts ``(nu, nv)`` along u and v.
    quads : (f, 4) int64
        Vertex indices of each quad, counter-clockwise seen from the side ``du × dv`` points to.
    face_patch : (f, 2) int64
        Level-0 patch ``(pu, pv)`` of each quad.
    """

    u: np.ndarray
    v: np.ndarray
    shape: tuple[int, int]
    quads: np.ndarray
    face_patch: np.ndarray

    def triangles(self) -> np.ndarray:
        """The quads split into two triangles each: ``(2 f, 3) int64`` (faces ``2q``, ``2q+1``)."""
        q = self.quads
        return np.stack([q[:, [0, 1, 2]], q[:, [0, 2, 3]]], axis=1).reshape(-1, 3)


def _axis(d: Direction, samples: int) -> np.ndarray:
    """Vertex parameters along one direction: ``P0 * samples (+1 if open)`` values."""
    count = d.patches0 * samples
    x = np.arange(count + (0 if d.periodic else 1), dtype=np.float64) / samples
    return x


def display_topology(u: Direction, v: Direction, samples: int) -> GridTopology:
    """The contract's display tessellation: ``samples`` steps per level-0 patch edge.

    Open directions have ``P0 * samples + 1`` vertices (the domain ends are included), periodic
    ones ``P0 * samples`` (the seam is shared, so a closed surface is watertight).
    """
    if samples < 1:
        raise ValueError(f"samples must be at least 1, got {samples}")
    us, vs = _axis(u, samples), _axis(v, samples)
    nu, nv = us.size, vs.size
    fu = nu if u.periodic else nu - 1
    fv = nv if v.periodic else nv - 1
    i = np.arange(fu)[:, None]
    j = np.arange(fv)[None, :]
    i1, j1 = (i + 1) % nu, (j + 1) % nv
    quads = np.stack(
        np.broadcast_arrays(i * nv + j, i1 * nv + j, i1 * nv + j1, i * nv + j1), axis=-1
    ).reshape(-1, 4)
    face_patch = np.stack(np.broadcast_arrays(i // samples, j // samples), axis=-1).reshape(-1, 2)
    uu, vv = np.meshgrid(us, vs, indexing="ij")
    return GridTopology(uu.reshape(-1), vv.reshape(-1), (nu, nv), quads.astype(np.int64), face_patch.astype(np.int64))


def evaluate_grid(hs: HSpline, topo: GridTopology, det: Details | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Points and unit normals at a grid's vertices.

    Rows of the grid that collapse to one point (a pole) get one shared normal, the mean of the
    row's limit normals, so shading at a pole is smooth.

    Returns
    -------
    points : (n, 3) float64
    normals : (n, 3) float64
    """
    points, limit = grid_samples(hs, topo, det)
    return points, pole_normals(hs, topo, points, limit)


def grid_samples(hs: HSpline, topo: GridTopology, det: Details | None = None,
                 since: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Points ``(n, 3)`` and limit unit normals ``(n, 3)`` (`surface_normals`) at a grid's
    vertices. ``since = (points, limit, stale)``: those of a surface that differs from ``hs``
    only on the level-0 patches ``stale (P0u, P0v) bool`` (`changed_patches`); only vertices on
    a stale patch (or its border) are evaluated, the others are copied. Each vertex is evaluated
    on its own, so the result equals a full evaluation bit for bit."""
    det = details(hs) if det is None and hs.depth > 1 else det
    if since is None:
        ev, n = surface_normals(hs, topo.u, topo.v, det=det)
        return ev.points, n
    points, limit, stale = (x.copy() for x in since)
    on = np.zeros(topo.u.size, bool)
    for cu in _cells(hs.u, topo.u):
        for cv in _cells(hs.v, topo.v):
            on |= stale[cu, cv]
    idx = np.nonzero(on)[0]
    if idx.size:
        ev, n = surface_normals(hs, topo.u[idx], topo.v[idx], det=det)
        points[idx], limit[idx] = ev.points, n
    return points, limit


def _cells(d: Direction, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The level-0 patch of each parameter ``x (n,)`` and the one before it where ``x`` is on
    the border between them (else the same patch), both in range."""
    cell = np.floor(x).astype(np.int64)
    before = np.where(cell == x, cell - 1, cell)
    if d.periodic:
        return np.mod(cell, d.patches0), np.mod(before, d.patches0)
    return np.clip(cell, 0, d.patches0 - 1), np.clip(before, 0, d.patches0 - 1)


def pole_normals(hs: HSpline, topo: GridTopology, points: np.ndarray, limit: np.ndarray) -> np.ndarray:
    """Display normals ``(n, 3)``: the limit normals, except that every grid line collapsed to
    one point (a pole) shares the mean of its limit normals, so shading at a pole is smooth."""
    nu, nv = topo.shape
    scale = hs.size()
    grid_p = points.reshape(nu, nv, 3)
    grid_n = limit.reshape(nu, nv, 3).copy()
    for axis in (0, 1):
        spread = np.ptp(grid_p, axis=axis).max(axis=-1)  # per line across the other index
        for line in np.nonzero(spread <= 1e-12 * scale)[0]:
            sl = (slice(None), line) if axis == 0 else (line, slice(None))
            m = grid_n[sl].mean(axis=0)
            norm = np.linalg.norm(m)
            if norm > 1e-12:
                grid_n[sl] = m / norm
    return grid_n.reshape(-1, 3)


def patch_grids(hs: HSpline, patches: np.ndarray, samples: int, det: Details | None = None):
    """Independent triangle grids over chosen level-0 patches, for collision tests.

    Parameters
    ----------
    patches : (m, 2) int64
        Level-0 patches ``(pu, pv)``.
    samples : int
        Steps per patch edge.

    Returns
    -------
    points : (m * (s+1)**2, 3) float64
    uv : (m * (s+1)**2, 2) float64
        Parameters of each vertex.
    triangles : (m * 2 s**2, 3) int64
    tri_patch : (m * 2 s**2,) int64
        Row into ``patches`` of each triangle.
    """
    patches = np.asarray(patches, dtype=np.int64).reshape(-1, 2)
    s = int(samples)
    t = np.arange(s + 1) / s
    tu, tv = np.meshgrid(t, t, indexing="ij")
    u = (patches[:, 0, None] + tu.reshape(1, -1)).reshape(-1)
    v = (patches[:, 1, None] + tv.reshape(1, -1)).reshape(-1)
    det = details(hs) if det is None and hs.depth > 1 else det
    pts = evaluate(hs, u, v, det=det).points
    i = np.arange(s)[:, None]
    j = np.arange(s)[None, :]
    a = i * (s + 1) + j
    b = (i + 1) * (s + 1) + j
    local = np.stack(np.broadcast_arrays(a, b, b + 1, a, b + 1, a + 1), axis=-1).reshape(-1, 2, 3).reshape(-1, 3)
    base = np.arange(patches.shape[0])[:, None, None] * (s + 1) ** 2
    tris = (local[None] + base).reshape(-1, 3)
    tri_patch = np.repeat(np.arange(patches.shape[0]), 2 * s * s)
    return pts, np.stack([u, v], axis=1), tris, tri_patch


def patch_hulls(hs: HSpline, det: Details | None = None, only: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned boxes bounding every level-0 patch, from the convex-hull property.

    A patch lies in the hull of its 16 level-0 CVs plus whatever detail finer levels add; the
    detail of each fine CV is bounded by its level's CV positions, so the box of all control
    points (all levels) whose support touches the patch bounds it.

    Parameters
    ----------
    only : (P0u, P0v) bool, optional
        Bound just these patches (a responded surface reuses its parent's other boxes); the
        other entries of the result are level 0's boxes alone.

    Returns
    -------
    lo, hi : (P0u, P0v, 3) float64
    """
    from .hspline import all_cv_positions, _split_cv

    pu, pv = hs.u.patches0, hs.v.patches0
    i4 = np.arange(4)
    iu = hs.u.wrap_cv(np.arange(pu)[:, None] + i4, 0)
    iv = hs.v.wrap_cv(np.arange(pv)[:, None] + i4, 0)
    block = hs.cvs[iu[:, None, :, None], iv[None, :, None, :]]  # (pu, pv, 4, 4, 3)
    lo = block.min(axis=(2, 3))
    hi = block.max(axis=(2, 3))
    if hs.depth > 1:
        det = details(hs) if det is None else det
        every = all_cv_positions(hs, det)
        cells, points = [], []
        for k in range(1, hs.depth):
            lev = hs.level(k)
            if lev.cv_keys.size == 0:
                continue
            ju, jv = _split_cv(hs, k, lev.cv_keys)
            # level-k CV j supports level-k patches j-3..j, i.e. level-0 patches (j-3)>>k .. j>>k
            for du in range(4):
                for dv in range(4):
                    qu = hs.u.wrap_patch((ju - 3 + du) >> k, 0)
                    qv = hs.v.wrap_patch((jv - 3 + dv) >> k, 0)
                    ok = hs.u.patch_valid(qu, 0) & hs.v.patch_valid(qv, 0)
                    if only is not None:
                        ok &= only[np.clip(qu, 0, pu - 1), np.clip(qv, 0, pv - 1)]
                    cells.append(qu[ok] * pv + qv[ok])
                    points.append(every[k][ok])
        if cells:
            # one sort groups every (patch, control point) pair; reduceat takes each patch's box
            cell = np.concatenate(cells)
            order = np.argsort(cell, kind="stable")
            cell, pts = cell[order], np.concatenate(points)[order]
            start = np.flatnonzero(np.r_[True, cell[1:] != cell[:-1]])
            flo, fhi, at = lo.reshape(-1, 3), hi.reshape(-1, 3), cell[start]
            flo[at] = np.minimum(flo[at], np.minimum.reduceat(pts, start, axis=0))
            fhi[at] = np.maximum(fhi[at], np.maximum.reduceat(pts, start, axis=0))
    return lo, hi
