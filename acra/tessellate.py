"""Tessellations of an H-spline: the adaptive display mesh and per-patch collision grids.

The display mesh (contract §1) shows every level the object uses: each place is sampled with
``samples`` steps per edge of the finest patch present there (`finest_levels`), on a quadtree of
patches (`adaptive_topology`), crack-free where the density changes, every vertex an exact surface
point, and one topology for a whole run (`run_topology`, a pure function of the run's surfaces).
Collision grids are uniform and built per level-0 patch so detection can tessellate only the
patches whose control hulls can touch. `display_topology`, the uniform grid of ``samples`` steps
per level-0 patch edge, is the adaptive mesh of a surface without finer levels.
"""

from __future__ import annotations

import contextlib
import hashlib
import contextvars
import functools
import weakref
from dataclasses import dataclass, field
from typing import Iterator

import numpy as np
from numba import njit

from . import framekernels, kernels, memo
from .basis import Direction
from .details import Details, details
from .hspline import HSpline, SurfaceEval, evaluate, surface_normals
from .lattice import adaptive_mesh, fan_triangles, quadtree_leaves, unique_keys

__all__ = [
    "GridTopology",
    "MeshTopology",
    "adaptive_topology",
    "display_topology",
    "finest_levels",
    "run_topology",
    "evaluate_grid",
    "grid_samples",
    "pole_normals",
    "patch_grids",
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

    @property
    def counts(self) -> np.ndarray:
        """Vertices per face ``(f,) int64`` (all 4), as USD's ``faceVertexCounts``."""
        return np.full(len(self.quads), 4, np.int64)

    @property
    def indices(self) -> np.ndarray:
        """Face vertex indices ``(4 f,) int64``, as USD's ``faceVertexIndices``."""
        return self.quads.reshape(-1)


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


@dataclass(frozen=True)
class MeshTopology:
    """A display mesh over the parameter domain: quads where the density is even, triangle fans
    where a coarse patch meets finer ones.

    Attributes
    ----------
    u, v : (n,) float64
        Parameters of every vertex (level-0 units), sorted by ``(u, v)``; a periodic seam and
        every shared patch border hold one vertex.
    counts : (f,) int64
        Vertices per face (4 or 3), USD's ``faceVertexCounts``.
    indices : (sum counts,) int64
        USD's ``faceVertexIndices``; every face counter-clockwise seen from the side ``du × dv``
        points to.
    by_v : (n,) int64 or None
        The vertices' rows by ``(v, u)`` (numpy's stable ``argsort`` of ``v``), where the mesh's
        build gives it (`acra.lattice.adaptive_mesh`): the order `grid_samples` evaluates in.
    source : tuple or None
        What the mesh is a function of, where its build gives it (`_adaptive_keys`): the two
        directions' ``(patches0, periodic)``, the samples, the finest level and the quadtree's
        leaves ``pu, pv, level (l,) int64``, `acra.lattice.adaptive_mesh`'s inputs; `key`
        digests it.
    """

    u: np.ndarray
    v: np.ndarray
    counts: np.ndarray
    indices: np.ndarray
    by_v: np.ndarray | None = field(default=None, compare=False, repr=False)
    source: tuple | None = field(default=None, compare=False, repr=False)

    @functools.cached_property
    def key(self) -> bytes | None:
        """A digest of `source` (``None`` without one): two topologies with the same key hold the
        same arrays, as `acra.lattice.adaptive_mesh` is a function of its inputs alone. Refinements
        whose patch keys differ where finer patches cover them have the same leaves, and so the
        same key. It stands for the digests of the vertex parameters and fan triangles, which
        hash about 1.5 MB on the demo's head, where the leaves are a few kilobytes
        (`pipeline.residual.Shown.fingerprint`)."""
        if self.source is None:
            return None
        *figures, pu, pv, level = self.source
        h = hashlib.sha1(repr(("adaptive_mesh", *figures, len(pu))).encode())
        for x in (pu, pv, level):
            h.update(np.ascontiguousarray(x, np.int64).data)
        return h.digest()

    @property
    def quads(self) -> np.ndarray:
        """The faces ``(f, 4) int64`` of a mesh of quads only (a surface without finer levels)."""
        if np.any(self.counts != 4):
            raise ValueError("the display has triangles where its density changes: use counts and indices")
        return self.indices.reshape(-1, 4)

    @functools.cached_property
    def uv(self) -> np.ndarray:
        """Parameters ``(n, 2) float64`` of the vertices, one array per topology: every display on
        it holds the same, so a digest of them (`pipeline.residual`) is taken once."""
        return np.stack([self.u, self.v], axis=1)

    def triangles(self) -> np.ndarray:
        """Every face as triangles, a fan from its first vertex, face by face (a quad ``a b c d``
        gives ``a b c``, ``a c d``, as `GridTopology.triangles` and a USD client's fan):
        ``(t, 3) int64``."""
        return fan_triangles(_i64(self.counts), _i64(self.indices))


def finest_levels(hs: HSpline) -> np.ndarray:
    """The finest level present at each place: ``(P0u << (depth-1), P0v << (depth-1)) int64``,
    one entry per patch of the finest level the object may use, holding the finest ``k`` whose
    active (refined) patches cover it (0 where only level 0 is). A level's detail lives on its
    active patches (a movable CV's support is all active, the C2 rule), so sampling each place
    for its finest active level shows every level."""
    top = hs.depth - 1
    out = np.zeros((hs.u.patches(top), hs.v.patches(top)), np.int64)
    for k in range(1, hs.depth):
        keys = hs.level(k).patches
        if not keys.size:
            continue
        pu, pv = np.divmod(keys, hs.v.patches(k))
        r = 1 << (top - k)
        du, dv = np.meshgrid(np.arange(r), np.arange(r), indexing="ij")
        iu = (pu[:, None] * r + du.reshape(1, -1)).reshape(-1)
        iv = (pv[:, None] * r + dv.reshape(1, -1)).reshape(-1)
        out[iu, iv] = np.maximum(out[iu, iv], k)
    return out


def run_topology(surfaces, samples: int) -> MeshTopology:
    """The display topology of a run: `adaptive_topology` of the union (the finest level at each
    place) of every surface's `finest_levels`, built from the active patches alone (no dense map
    of the finest level: a 12-level object with local detail costs its refined area). A pure
    function of the surfaces (all of one object, same grid and depth), so a run that responds to
    all frames first, or a merge of chunks of frames, chooses it after the responses."""
    surfaces = list(surfaces)
    present: dict[int, list] = {}
    for hs in surfaces:
        for k in range(1, hs.depth):
            keys = hs.level(k).patches
            if keys.size:
                present.setdefault(k, []).append(np.asarray(keys, np.int64))
    # a key pu * Pv_k + pv is the patch (pu, pv) of level k, as `acra.lattice.quadtree_leaves` takes it
    return _adaptive_keys(surfaces[0].u, surfaces[0].v, samples,
                          {k: keys[0] if len(keys) == 1 else np.concatenate(keys) for k, keys in present.items()})


def _leaves(p0u: int, p0v: int, present: dict[int, np.ndarray], top: int) -> list[tuple[int, np.ndarray]]:
    """Quadtree leaves over the ``(p0u, p0v)`` level-0 patches: per level ``k``, the level-``k``
    patches ``(m, 2) int64`` that hold no patch of a finer level present (``present[j]``, the
    level-``j`` patches ``(m_j, 2) int64`` where level ``j`` is present) while their parent holds
    one. Only the patches on the way to a present one are visited, so the cost follows the
    refined area, not the finest level's whole grid."""
    # per level k, the sorted keys u * (P0v << k) + v of the level-k patches that hold a present
    # patch of a finer level: the parents of level k + 1's present patches and of its own such
    # patches, so each level sorts only its own distinct ones
    holding: dict[int, np.ndarray] = {}
    below = np.zeros((0, 2), np.int64)
    for k in range(top - 1, -1, -1):
        rows = np.concatenate([below, np.asarray(present.get(k + 1, below), np.int64).reshape(-1, 2)]) >> 1
        holding[k] = np.unique(rows[:, 0] * (p0v << k) + rows[:, 1])
        below = np.stack(np.divmod(holding[k], p0v << k), axis=1)
    out = []
    open_ = np.argwhere(np.ones((p0u, p0v), bool)).astype(np.int64)  # level-0 roots
    children = np.array([[0, 0], [0, 1], [1, 0], [1, 1]], np.int64)
    for k in range(top + 1):
        busy = np.zeros(len(open_), bool)
        keys = holding.get(k)
        if keys is not None and keys.size:
            want = open_[:, 0] * (p0v << k) + open_[:, 1]
            at = np.minimum(np.searchsorted(keys, want), keys.size - 1)
            busy = keys[at] == want
        out.append((k, open_[~busy]))
        open_ = (open_[busy][:, None, :] * 2 + children[None]).reshape(-1, 2)
    return out


def adaptive_topology(u: Direction, v: Direction, samples: int, levels: np.ndarray) -> MeshTopology:
    """The display mesh: ``samples`` steps per edge of the finest patch present at each place.

    Parameters
    ----------
    levels : (P0u << L, P0v << L) int64
        Finest level needed at each patch of some level ``L`` (`finest_levels`, or their union over
        a run); all zero gives the uniform grid of `display_topology`, vertex for vertex.

    The domain is split as a quadtree of patches: a level-``k`` patch is a leaf where nothing
    finer than ``k`` is needed in it, and each leaf gets a grid of ``samples`` steps per edge.
    Dyadic nesting puts every vertex on a lattice of ``samples << L`` steps per level-0 patch, and
    a coarse leaf's edge vertices are a subset of a finer neighbour's, so a coarse cell whose edge
    a finer leaf shares takes all of that neighbour's vertices on it and is split into a fan of
    triangles about a vertex at its centre: no T-junction, no crack. Periodic seams share their
    lattice vertices (a closed object welds by index), collapsed ends (poles) by position.
    """
    levels = np.asarray(levels, np.int64)
    top = int(round(np.log2(levels.shape[0] // u.patches0))) if levels.size else 0
    if levels.shape != (u.patches(top), v.patches(top)):
        raise ValueError(f"levels has shape {levels.shape}, expected a power-of-two refinement of {(u.patches0, v.patches0)}")
    present = {j: np.unique(np.argwhere(levels >= j) >> (top - j), axis=0) for j in range(1, top + 1)}
    return _adaptive(u, v, samples, present)


def _adaptive(u: Direction, v: Direction, samples: int, present: dict[int, np.ndarray]) -> MeshTopology:
    """`adaptive_topology` of the levels ``present`` (level ``j`` -> its patches ``(m_j, 2) int64``
    where it is present; `_leaves`): `_adaptive_keys` of their keys."""
    keys = {}
    for j, p in present.items():
        p = np.asarray(p, np.int64).reshape(-1, 2)
        keys[j] = p[:, 0] * v.patches(j) + p[:, 1]
    return _adaptive_keys(u, v, samples, keys)


def _adaptive_keys(u: Direction, v: Direction, samples: int, present: dict[int, np.ndarray]) -> MeshTopology:
    """`adaptive_topology` of the levels ``present`` (level ``j`` -> the keys ``pu * (P0v << j) + pv``
    ``(m_j,) int64`` of its patches where it is present, in any order, repeats allowed): the
    quadtree's leaves (`acra.lattice.quadtree_leaves`, `_leaves`' in their order), then their
    cells and the mesh in one compiled pass (`acra.lattice.adaptive_mesh`, vertex for vertex and
    face for face `_adaptive_array`'s)."""
    if samples < 1:
        raise ValueError(f"samples must be at least 1, got {samples}")
    present = {j: k for j, k in present.items() if len(k)}
    top = max(present, default=0)  # the lattice of the finest level present
    s = int(samples)
    lengths = [len(present.get(j, ())) for j in range(1, top + 1)]
    starts = np.concatenate([np.zeros(1, np.int64), np.cumsum(lengths, dtype=np.int64)])
    keys = np.concatenate([np.zeros(0, np.int64)] + [np.asarray(present[j], np.int64).reshape(-1) for j in sorted(present)])
    pu, pv, level = quadtree_leaves(int(u.patches0), int(v.patches0), keys, starts)
    steps = np.left_shift(1, top - level)
    lu, lv, counts, indices, by_v = adaptive_mesh(pu, pv, steps, s, u.patches0 * (s << top), v.patches0 * (s << top),
                                                  bool(u.periodic), bool(v.periodic))
    step = float(s << top)
    source = ((int(u.patches0), bool(u.periodic)), (int(v.patches0), bool(v.periodic)), s, int(top), pu, pv, level)
    return MeshTopology(lu / step, lv / step, counts, indices, by_v, source)


def _adaptive_array(u: Direction, v: Direction, samples: int, present: dict[int, np.ndarray]) -> MeshTopology:
    """`_adaptive` in array form, the reference `tests/test_tessellate.py` holds the compiled
    pass to."""
    if samples < 1:
        raise ValueError(f"samples must be at least 1, got {samples}")
    present = {j: np.asarray(p, np.int64).reshape(-1, 2) for j, p in present.items() if len(p)}
    top = max(present, default=0)  # the lattice of the finest level present
    s = int(samples)
    nu_l, nv_l = u.patches0 * (s << top), v.patches0 * (s << top)  # lattice steps along u, v
    wrap_u = (lambda x: np.mod(x, nu_l)) if u.periodic else (lambda x: x)
    wrap_v = (lambda x: np.mod(x, nv_l)) if v.periodic else (lambda x: x)
    key = lambda a, b: wrap_u(a) * (nv_l + 1) + wrap_v(b)  # noqa: E731

    # every cell of every leaf: lower corner and step on the lattice
    cu, cv, ch = [], [], []
    t = np.arange(s)
    for k, patches in _leaves(u.patches0, v.patches0, present, top):
        if not len(patches):
            continue
        h = 1 << (top - k)
        gu = (patches[:, 0, None, None] * s + t[None, :, None]) * h
        gv = (patches[:, 1, None, None] * s + t[None, None, :]) * h
        gu, gv = np.broadcast_arrays(gu, gv)
        cu.append(gu.reshape(-1))
        cv.append(gv.reshape(-1))
        ch.append(np.full(gu.size, h, np.int64))
    cu, cv, ch = np.concatenate(cu), np.concatenate(cv), np.concatenate(ch)
    order = np.lexsort((cv, cu))
    cu, cv, ch = cu[order], cv[order], ch[order]
    nc = len(cu)
    # corners counter-clockwise on the lattice (a lower corner is inside the domain, the upper
    # one wraps onto a periodic seam)
    u1, v1 = cu + ch, cv + ch
    wu1, wv1 = wrap_u(u1), wrap_v(v1)
    corners = [(cu, cv), (wu1, cv), (wu1, wv1), (cu, wv1)]
    w = nv_l + 1  # a key is u * w + v (`acra.lattice`: sorted keys, bucketed by column)
    cu4, cv4 = np.concatenate([a for a, _ in corners]), np.concatenate([b for _, b in corners])
    lattice, first, at = unique_keys(cu4, cv4, nu_l, w)
    by_v, first_v, at_v = unique_keys(cv4, cu4, nv_l, nu_l + 1)  # the same vertices, v-major
    pos, pos_v = at.reshape(4, nc), at_v.reshape(4, nc)  # corner c of every cell: its vertex, u- and v-major
    v_to_u = np.empty(len(by_v), np.int64)
    v_to_u[at_v] = at

    # vertices strictly inside each cell edge (a finer neighbour's): on the edge's line, in the
    # order along it (v-major for an edge along u, u-major along v), they lie between its two
    # corners; an edge that ends on a periodic seam runs to its line's end (its far corner wraps
    # to the line's start)
    seam_u = u1 == nu_l if u.periodic else np.zeros(nc, bool)
    seam_v = v1 == nv_l if v.periodic else np.zeros(nc, bool)
    spans = [(pos_v[0] + 1, np.where(seam_u, first_v[cv + 1], pos_v[1])),
             (pos[1] + 1, np.where(seam_v, first[wu1 + 1], pos[2])),
             (pos_v[3] + 1, np.where(seam_u, first_v[wv1 + 1], pos_v[2])),
             (pos[0] + 1, np.where(seam_v, first[cu + 1], pos[3]))]
    extra = np.zeros(nc, bool)
    for lo, hi in spans:
        extra |= hi > lo
    plain = np.nonzero(~extra)[0]
    # each split cell's ring of vertices (rows of ``lattice``), counter-clockwise: per side its
    # corner, then the vertices strictly inside the side, sides 2 and 3 walked backwards; all
    # cells at once, as (cell, side, position) rows sorted into rings
    cells = np.nonzero(extra)[0]
    owner, order, ring = [], [], []
    for side, (lo, hi) in enumerate(spans):
        owner.append(cells)
        order.append(np.full(len(cells), 2 * side))  # the corner before the side's inner vertices
        ring.append(pos[side][cells])
        n = (hi - lo)[cells]
        own = np.repeat(cells, n)
        step = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)  # 0..n-1 within each cell
        inner = np.repeat(lo[cells], n) + step if side in (0, 1) else np.repeat(hi[cells], n) - 1 - step
        owner.append(own)
        order.append(2 * side + 1 + step / max(1, int(n.max(initial=0)) + 1))
        ring.append(v_to_u[inner] if side in (0, 2) else inner)
    owner, order, ring = np.concatenate(owner), np.concatenate(order), np.concatenate(ring)
    rank = np.lexsort((order, owner))
    owner, ring = owner[rank], ring[rank]
    start = np.searchsorted(owner, owner, side="left")
    length = np.searchsorted(owner, owner, side="right") - start
    following = start + (np.arange(len(ring)) - start + 1) % np.maximum(length, 1)
    # a split cell's centre is inside it, so no corner and no other centre: the mesh's vertices
    # are the corners' and the centres', and one more sort places both
    if len(cells):
        centre = key(cu[cells] + ch[cells] // 2, cv[cells] + ch[cells] // 2)
        every = np.concatenate([lattice, centre])
        lattice, _, at = unique_keys(every // w, every % w, nu_l, w)
        row, centre = at[:len(every) - len(cells)], at[len(every) - len(cells):]
    else:
        row = np.arange(len(lattice), dtype=np.int64)
    quads = row[pos[:, plain].T]
    tris = np.stack([centre[np.searchsorted(cells, owner)], row[ring], row[ring[following]]], axis=1) \
        if len(ring) else np.zeros((0, 3), np.int64)
    counts = np.r_[np.full(len(quads), 4, np.int64), np.full(len(tris), 3, np.int64)]
    indices = np.r_[quads.reshape(-1), tris.reshape(-1)].astype(np.int64)
    lu, lv = np.divmod(lattice, nv_l + 1)
    step = float(s << top)
    return MeshTopology(lu / step, lv / step, counts, indices)


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
                 since: tuple | None = None, matches: dict | None = None,
                 normals: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """Points ``(n, 3)`` and limit unit normals ``(n, 3)`` (`surface_normals`) at a grid's
    vertices (``topo``: a `GridTopology` or `MeshTopology`).

    ``since = (points, limit, stale)``: those of a surface that differs from ``hs`` only on the
    level-0 patches ``stale (P0u, P0v) bool`` (`changed_patches`), or the level-``L`` patches
    ``stale (P0u << L, P0v << L) bool`` (`changed_cells`), on the same topology; only vertices
    on a stale patch (or its border) are evaluated, the others are copied. With ``normals``, a
    vertex whose old normal was taken at nudged points (`surface_normals`: they read its whole
    level-0 patch) is evaluated again too; where the old limit normals' nudged rows are not known
    (`_nudged_rows`: not from `grid_samples`), every vertex of a level-0 patch holding a stale
    cell is. ``since =
    (old_topo, points, limit, stale)``: the same on another topology of the object (``old_topo``
    itself: as without it); a vertex at a
    parameter ``old_topo`` has, on no stale patch, is copied (adaptive topologies of one object
    put their vertices on nested dyadic lattices, so away from where a response refined, the
    old vertices are the new). Each vertex is evaluated on its own, so the result equals a full
    evaluation bit for bit. ``matches`` (a dict the caller keeps) holds what depends on the
    topologies alone: which old vertex each new one is, and each vertex's level-0 patches.
    Without ``normals`` only the points are evaluated (the same bits: a point's sum does not
    depend on the derivative orders summed beside it) and ``None`` stands for the normals,
    in ``since`` too. With ``normals``, the vertices evaluated take their points and first
    derivatives by v, then u, and the limit normals from those (`_normals_into`)."""
    det = details(hs) if det is None and hs.depth > 1 else det

    def place_points(rows: np.ndarray, points: np.ndarray) -> None:
        # the points alone, placed in their rows by `_place`
        ev = evaluate(hs, topo.u[rows], topo.v[rows], order=0, det=det)
        _place(ev.points, rows, points)

    # an evaluation takes its points by v, then u (a topology's vertices come by u, then v): a
    # point on the v and block of the one before reuses its v contraction
    # (`acra.kernels.eval_points`), and each point is summed on its own, so the order changes no bit
    if since is None:
        o = _v_order(topo)
        points = np.empty((topo.u.size, 3))
        if not normals:
            place_points(o, points)
            return points, None
        limit = np.empty((topo.u.size, 3))
        _note_nudged(limit, np.sort(_normals_into(hs, topo.u[o], topo.v[o], det, o, points, limit)))
        return points, limit
    old, (old_points, old_limit, stale) = (since[0] if len(since) == 4 else topo), since[-3:]
    # on the same topology vertex i is the old vertex i
    src, found = (_NO_INDEX, _NO_FOUND) if old is topo else _matched(old, topo, matches)
    level = _level_of(hs, stale)
    old_nudged = _nudged_rows(old_limit) if normals else None
    if normals and level and old_nudged is None:
        # a limit normal where du × dv vanishes is taken at points nudged toward the centre of the
        # vertex's level-0 patch (`surface_normals`), which a finer cell need not hold: where the
        # old vertices that took one are not known, a vertex is evaluated again on every level-0
        # patch with a changed cell
        r = 1 << level
        stale, level = stale.reshape(hs.u.patches0, r, hs.v.patches0, r).any(axis=(1, 3)), 0
    (cu, bu), (cv, bv) = _patch_cells(hs, topo, matches, level)
    points = np.empty((topo.u.size, 3))
    limit = np.empty((topo.u.size, 3)) if normals else _NO_POINTS
    # by v, `_carry` hands the rows to evaluate in the order they are evaluated in
    idx = _carry(old_points, old_limit if normals else _NO_POINTS, src, found,
                 np.ascontiguousarray(stale, np.bool_), cu, bu, cv, bv, points, limit,
                 _v_order(topo))
    carried = _NO_INDEX  # copied vertices whose old normal was taken at nudged points
    if old_nudged is not None and old_nudged.size:
        took = np.zeros(len(old_points), bool)
        took[old_nudged] = True
        took = took if old is topo else took[src] & found
        if level:
            # a nudged normal reads points anywhere in its level-0 patch, beyond the vertex's own
            # cells: such a vertex is evaluated again (they are few: where du × dv and its first
            # Taylor term both vanish)
            idx = np.union1d(idx, np.flatnonzero(took))
        else:
            copied = np.ones(topo.u.size, bool)
            copied[idx] = False
            carried = np.flatnonzero(took & copied)
    nudged = None
    if idx.size and normals:
        nudged = _normals_into(hs, topo.u[idx], topo.v[idx], det, idx, points, limit)
    elif idx.size:
        place_points(idx, points)
    if normals and old_nudged is not None:
        _note_nudged(limit, np.union1d(carried, nudged) if nudged is not None and nudged.size else carried)
    return points, limit if normals else None


def _normals_into(hs: HSpline, u: np.ndarray, v: np.ndarray, det: Details | None, rows: np.ndarray,
                  points: np.ndarray, limit: np.ndarray) -> np.ndarray:
    """Evaluate ``hs`` at ``(u, v) (m,) float64`` (by v, then u: `grid_samples`' order) into the
    rows ``rows (m,) int64`` of ``points`` and of the limit unit normals ``limit`` (both ``(n,
    3) float64``): `surface_normals`' points and normals bit for bit. A row where ``du × dv``
    gives a direction takes its cross product over its length, written with its point in one
    compiled pass (`acra.kernels.place_normals`, `acra.framekernels.degenerate`'s bits); the others
    (a pole's, a collapsed edge's) take the first-order term of ``du × dv`` from a second-order
    evaluation (`acra.framekernels.limit_normals`), and only where a row needs nudging do they
    go through `surface_normals`, which treats each row on its own: the result is its result on
    every row. Returns the rows ``(k,) int64`` whose normal was taken at nudged points."""
    ev = evaluate(hs, u, v, order=1, det=det)
    s = max(hs.size(), 1e-300)  # `surface_normals`' scale and `_degenerate`'s bounds
    bad = np.empty(rows.size, np.bool_)
    if not kernels.place_normals(ev.points, ev.du, ev.dv, rows, 1e-6 * s, 1e-12 * s**2, points, limit, bad):
        return _NO_INDEX
    idx = np.flatnonzero(bad)
    # the first-order term toward the patch centre, compiled (`framekernels.limit_normals`, its
    # bits), unless a row needs nudging
    ui, vi = u[idx], v[idx]
    e2 = evaluate(hs, ui, vi, order=2, det=det)
    unit = np.empty((idx.size, 3))
    if framekernels.limit_normals(ui, vi, e2.du, e2.dv, e2.duu, e2.duv, e2.dvv, 1e-6 * s, 1e-12 * s**2,
                                  1e-9 * hs.size()**2, int(hs.u.patches0), int(hs.v.patches0),
                                  bool(hs.u.periodic), bool(hs.v.periodic), unit):
        nudged = np.empty(idx.size, bool)
        _, unit = surface_normals(hs, ui, vi, det=det, nudged=nudged,
                                  ev=SurfaceEval(ev.points[idx], ev.du[idx], ev.dv[idx]))
        limit[rows[idx]] = unit
        return rows[idx[nudged]]
    limit[rows[idx]] = unit
    return _NO_INDEX


# Kept per live array: a weak reference without a callback, dead entries dropped when one is
# added. A callback would run Python code whenever an array dies, and a KeyboardInterrupt or
# SIGTERM raised inside it is reported and dropped by the interpreter, not delivered to the run.
_NUDGED = memo.Table("tessellate.nudged")  # id(limit normals) -> (a weak reference to them, rows taken at nudged points)


def _drop_dead(kept: dict) -> None:
    """Remove the entries of ``kept`` (values whose first item is a weak reference) whose object
    has died."""
    for key in [key for key, value in kept.items() if value[0]() is None]:
        del kept[key]


# A context's held notes (`held_notes`): a list of ``(limit normals, rows)``, or None (noted at once)
_HELD: contextvars.ContextVar = contextvars.ContextVar("acra_tessellate_held_notes", default=None)


@contextlib.contextmanager
def held_notes() -> Iterator[list]:
    """Inside the block, `grid_samples`' nudged rows (`_note_nudged`) go into the list it
    yields, ``[(limit normals (n, 3) float64, rows (k,) int64), ...]`` in the order noted, not
    into the run's table, which the block only reads: two evaluations in two threads
    (`pipeline.display.Displays.build`) leave the table to their caller, who adds both lists
    (`note_held`) in the order one thread would have noted them."""
    notes: list = []
    token = _HELD.set(notes)
    try:
        yield notes
    finally:
        _HELD.reset(token)


def note_held(notes: list) -> None:
    """Add `held_notes`' ``notes`` to the run's table, in their order."""
    for limit, rows in notes:
        _note_nudged(limit, rows)


def _note_nudged(limit: np.ndarray, rows: np.ndarray) -> None:
    """Keep, for as long as ``limit`` (a `grid_samples` result) lives, its rows ``(k,) int64``
    whose normal `surface_normals` took at nudged points, so a later evaluation since it knows
    which copied vertices read more than their own cells (inside `held_notes`, in its list)."""
    held = _HELD.get()
    if held is not None:
        held.append((limit, np.asarray(rows, np.int64)))
        return
    _drop_dead(_NUDGED)
    _NUDGED[id(limit)] = (weakref.ref(limit), np.asarray(rows, np.int64))


def _nudged_rows(limit: np.ndarray) -> np.ndarray | None:
    """`_note_nudged`'s rows of ``limit`` (``None``: not known)."""
    for kept, rows in _HELD.get() or ():
        if kept is limit:
            return rows
    hit = _NUDGED.get(id(limit))
    return hit[1] if hit is not None and hit[0]() is limit else None


_NO_INDEX, _NO_FOUND, _NO_POINTS = np.zeros(0, np.int64), np.zeros(0, np.bool_), np.zeros((0, 3))


@njit(cache=True, nogil=True)
def _place(p, rows, points):
    """Write an evaluation's ``p (m, 3) float64`` into ``points`` at ``rows (m,) int64``: numpy's
    ``points[rows] = p`` in one pass (the points come by v, the display's rows by u). A display
    with normals takes its points with them (`acra.kernels.place_normals`)."""
    for i in range(rows.shape[0]):
        r = rows[i]
        for e in range(3):
            points[r, e] = p[i, e]


def _v_order(topo) -> np.ndarray:
    """The rows of ``topo``'s vertices by ``(v, u)`` ``(n,) int64``: numpy's stable ``argsort`` of
    ``v`` (the vertices come by ``(u, v)``), which an adaptive mesh's build gives
    (`MeshTopology.by_v`)."""
    by_v = getattr(topo, "by_v", None)
    return by_v if by_v is not None else np.argsort(topo.v, kind="stable")


@njit(cache=True, nogil=True)
def _carry(old_points, old_limit, src, found, stale, cu, bu, cv, bv, points, limit, order):
    """Copy into ``points`` (and every column of ``limit``, unless empty) the old vertex
    ``src[i]`` of every vertex ``i`` that has one (``found[i]``; empty ``src``: vertex ``i``
    itself) and lies on no ``stale`` cell (its cells ``cu[i]``/``bu[i]`` along u, the one before
    where it is on a border, and ``cv[i]``/``bv[i]`` along v); returns the others' rows ``(m,)
    int64``, which the caller evaluates: ascending, or in the order they appear in ``order (n,)
    int64`` (a permutation of the rows; empty: ascending). One pass for numpy's copy of every
    found vertex, mask of the four cells and ``np.nonzero`` (then ``idx[argsort(rank[idx])]``
    with ``order``), whose results it equals (`tests/test_tessellate.py`)."""
    n = points.shape[0]
    same = src.shape[0] == 0
    width = limit.shape[1] if limit.shape[0] > 0 else 0
    # the rows left are marked (n bytes) and counted, and their list is sized to them: an (n,)
    # int64 scratch is new memory whose page faults cost more than a second pass over the marks
    left = np.zeros(n, np.bool_)
    m = 0
    for i in range(n):
        a, b, c, d = cu[i], bu[i], cv[i], bv[i]
        if (not same and not found[i]) or stale[a, c] or stale[a, d] or stale[b, c] or stale[b, d]:
            left[i] = True
            m += 1
            continue
        j = i if same else src[i]
        points[i, 0], points[i, 1], points[i, 2] = old_points[j, 0], old_points[j, 1], old_points[j, 2]
        # a constant width (a display's 6 derivatives, the run's 3 normals) lets the copy unroll
        if width == 6:
            for e in range(6):
                limit[i, e] = old_limit[j, e]
        elif width == 3:
            for e in range(3):
                limit[i, e] = old_limit[j, e]
        else:
            for e in range(width):
                limit[i, e] = old_limit[j, e]
    idx = np.empty(m, np.int64)
    k = 0
    if order.shape[0] == 0:
        for i in range(n):
            if left[i]:
                idx[k] = i
                k += 1
        return idx
    # the rows left, in ``order``'s sequence (the copy's rows are walked in their own order,
    # which keeps its reads and writes near each other)
    for q in range(n):
        if k == m:
            break
        i = order[q]
        if left[i]:
            idx[k] = i
            k += 1
    return idx


def _matched(old, topo, matches: dict | None) -> tuple[np.ndarray, np.ndarray]:
    """The vertex of ``old`` at each vertex's parameters of ``topo`` ``(n,) int64`` and whether
    there is one ``(n,) bool``."""
    key = ("matched", id(old), id(topo))
    hit = None if matches is None else matches.get(key)
    if hit is not None and hit[0] is old and hit[1] is topo:
        return hit[2], hit[3]
    src, found = np.empty(topo.u.size, np.int64), np.empty(topo.u.size, np.bool_)
    # a topology's vertices are sorted by (u, v) (`MeshTopology`, `GridTopology`): one merge of
    # the two lists, unless one of them is not
    if not _merge(_f64(old.u), _f64(old.v), _f64(topo.u), _f64(topo.v), src, found):
        new_key, old_key = topo.u + 1j * topo.v, old.u + 1j * old.v  # complex values sort by (u, v)
        order = np.argsort(old_key, kind="stable")
        src = order[np.minimum(np.searchsorted(old_key[order], new_key), max(len(order) - 1, 0))]
        found = old_key[src] == new_key if len(order) else np.zeros(new_key.size, bool)
    if matches is not None:
        matches[key] = (old, topo, src, found)
    return src, found


def _i64(x: np.ndarray) -> np.ndarray:
    """``x`` as a C-contiguous, writeable int64 array (a copy only where it is not one)."""
    a = np.ascontiguousarray(x, np.int64)
    return a if a.flags.writeable else a.copy()


def _f64(x: np.ndarray) -> np.ndarray:
    """``x`` as a C-contiguous float64 array (a copy only where it is not one)."""
    return np.ascontiguousarray(x, np.float64)


@njit(cache=True, nogil=True)
def _merge(old_u, old_v, u, v, src, found):
    """`_matched` of two vertex lists each sorted by ``(u, v)`` ``(m,)``, ``(n,) float64``: writes
    into ``src (n,) int64`` the old vertex at each new vertex's parameters and into ``found (n,)
    bool`` whether there is one (else ``src`` is the old vertex after it, clipped into range), in
    one merge; returns False, having written nothing usable, where either list is not sorted."""
    m, n = old_u.shape[0], u.shape[0]
    for i in range(1, m):
        if old_u[i] < old_u[i - 1] or (old_u[i] == old_u[i - 1] and old_v[i] <= old_v[i - 1]):
            return False
    for i in range(1, n):
        if u[i] < u[i - 1] or (u[i] == u[i - 1] and v[i] <= v[i - 1]):
            return False
    j = 0
    for i in range(n):
        while j < m and (old_u[j] < u[i] or (old_u[j] == u[i] and old_v[j] < v[i])):
            j += 1
        src[i] = min(j, max(m - 1, 0))
        found[i] = j < m and old_u[j] == u[i] and old_v[j] == v[i]
    return True


def _level_of(hs: HSpline, stale: np.ndarray) -> int:
    """The level ``L`` of a stale mask ``(P0u << L, P0v << L) bool``."""
    level = int(stale.shape[0] // hs.u.patches0).bit_length() - 1
    if stale.shape != (hs.u.patches(level), hs.v.patches(level)):
        raise ValueError(f"stale has shape {stale.shape}, not the patches of one level of {(hs.u.patches0, hs.v.patches0)}")
    return level


def _patch_cells(hs: HSpline, topo, matches: dict | None, level: int = 0) -> tuple:
    """`_cells` of ``topo``'s u and v parameters on ``hs``'s level-``level`` grid."""
    key = ("cells", id(topo), hs.u, hs.v, level)
    hit = None if matches is None else matches.get(key)
    if hit is not None and hit[0] is topo:
        return hit[1], hit[2]
    cells = _cells(hs.u, topo.u, level), _cells(hs.v, topo.v, level)
    if matches is not None:
        matches[key] = (topo,) + cells
    return cells


def _cells(d: Direction, x: np.ndarray, level: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The level-``level`` patch of each parameter ``x (n,)`` (level-0 units) and the one before
    it where ``x`` is on the border between them (else the same patch), both in range."""
    x = _f64(x)
    cell, before = np.empty(x.size, np.int64), np.empty(x.size, np.int64)
    _cells_into(x, float(1 << level), int(d.patches(level)), bool(d.periodic), cell, before)
    return cell, before


@njit(cache=True, nogil=True)
def _cells_into(x, scale, n, periodic, cell, before):
    """`_cells` in one pass: of each ``x (m,) float64`` times ``scale`` (a power of two, so
    exact), the floor into ``cell (m,) int64`` and, where it is on that border, the patch before
    into ``before (m,) int64``, wrapped into ``0 .. n-1`` (``periodic``) or clipped, as numpy's
    ``floor``, ``where``, ``mod`` and ``clip``."""
    for i in range(x.shape[0]):
        y = x[i] * scale
        c = np.int64(np.floor(y))
        b = c - 1 if c == y else c
        if periodic:
            c, b = c % n, b % n
        else:
            c, b = min(max(c, 0), n - 1), min(max(b, 0), n - 1)
        cell[i], before[i] = c, b


def pole_normals(hs: HSpline, topo, points: np.ndarray, limit: np.ndarray, in_place: bool = False) -> np.ndarray:
    """Display normals ``(n, 3)``: the limit normals, except that the vertices of every domain
    edge collapsed to one point (a pole) share the mean of their limit normals, so shading at a
    pole is smooth. ``topo`` is a `GridTopology` or a `MeshTopology` (its ``u``, ``v``). With
    ``in_place`` they are written over ``limit`` (returned), which spares a copy of the whole
    display where the caller needs the limit normals no more; every mean is of the limit normals
    either way (a corner on two poles' lines)."""
    lines, rows, starts = _end_rows(hs, topo)
    shared = []
    if lines:
        means = np.empty((len(lines), 3))
        collapsed = _pole_means(_f64(points), _f64(limit), rows, starts, 1e-12 * hs.size(), means)
        for line, m, pole in zip(lines, means, collapsed):
            if not pole:
                continue
            norm = np.linalg.norm(m)
            if norm > 1e-12:
                shared.append((line, m / norm))
    out = limit if in_place else limit.copy()
    for line, n in shared:
        out[line] = n
    return out


@njit(cache=True, nogil=True)
def _pole_means(points, limit, rows, starts, tol, means):
    """Of each end line ``rows[starts[j]:starts[j + 1]]`` (`_end_rows`), whether its ``points
    (n, 3) float64`` lie within ``tol`` of one point, returned ``(k,) bool``: numpy's
    ``not np.ptp(points[line], axis=0).max() > tol`` (an extent NaN where a column holds a NaN,
    or spans two equal infinities); and where they do, the mean of its ``limit (n, 3) float64``
    rows into ``means[j]`` (``(k, 3) float64``): numpy's ``limit[line].mean(axis=0)``, each
    column summed in row order from ``+0.0`` (numpy's identity of the sum: a column of ``-0.0``
    sums to ``+0.0``), then divided by the count. Both in one pass a line, without the
    gathered copies."""
    k = starts.shape[0] - 1
    collapsed = np.zeros(k, np.bool_)
    for j in range(k):
        a, b = starts[j], starts[j + 1]
        nan = False
        above = False
        for e in range(3):
            lo = hi = points[rows[a], e]
            gap = lo != lo
            for i in range(a + 1, b):
                x = points[rows[i], e]
                if x != x:
                    gap = True
                elif x < lo:
                    lo = x
                elif x > hi:
                    hi = x
            extent = hi - lo
            if gap or extent != extent:
                nan = True
            elif extent > tol:
                above = True
        if above and not nan:
            continue
        collapsed[j] = True
        for e in range(3):
            total = 0.0
            for i in range(a, b):
                total += limit[rows[i], e]
            means[j, e] = total / (b - a)
    return collapsed


_END_LINES = memo.Table("tessellate.end_lines")  # id(topology) -> (a weak reference to it, the surface's directions, its `_end_rows`)


def _end_lines(hs: HSpline, topo) -> list[np.ndarray]:
    """The vertices ``(k,) int64`` of each end of each open direction of ``topo`` that has two or
    more (the rows `pole_normals` may share a normal over), a function of the topology alone,
    kept while it lives: the frames of a run share their display's."""
    return _end_rows(hs, topo)[0]


def _end_rows(hs: HSpline, topo) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """`_end_lines` and the same rows end to end ``(r,) int64`` with each line's start in them
    and their end ``(k + 1,) int64`` (`_pole_means`' arguments), kept with them."""
    hit = _END_LINES.get(id(topo))
    if hit is not None and hit[0]() is topo and hit[1] == (hs.u, hs.v):
        return hit[2]
    lines = []
    for x, d in ((topo.u, hs.u), (topo.v, hs.v)):
        if d.periodic:
            continue
        for end in (0.0, float(d.patches0)):
            line = np.nonzero(x == end)[0]
            if line.size >= 2:
                lines.append(line)
    rows = np.concatenate(lines).astype(np.int64) if lines else _NO_INDEX
    starts = np.zeros(len(lines) + 1, np.int64)
    starts[1:] = np.cumsum([line.size for line in lines])
    ends = (lines, rows, starts)
    try:
        ref = weakref.ref(topo)
    except TypeError:  # a topology without weak references is not kept
        return ends
    _drop_dead(_END_LINES)
    _END_LINES[id(topo)] = (ref, (hs.u, hs.v), ends)
    return ends


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
    tu, tv, local = _patch_pattern(s)
    u = (patches[:, 0, None] + tu).reshape(-1)
    v = (patches[:, 1, None] + tv).reshape(-1)
    det = details(hs) if det is None and hs.depth > 1 else det
    pts = evaluate(hs, u, v, det=det).points
    base = np.arange(patches.shape[0])[:, None, None] * (s + 1) ** 2
    tris = (local[None] + base).reshape(-1, 3)
    tri_patch = np.repeat(np.arange(patches.shape[0]), 2 * s * s)
    return pts, np.stack([u, v], axis=1), tris, tri_patch


@functools.lru_cache(maxsize=32)
def _patch_pattern(s: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What `patch_grids` repeats in every patch at ``s`` steps, a function of ``s`` alone:
    the offsets ``(1, (s+1)**2)`` of the vertices' u and v within the patch, and the triangles
    ``(2 s**2, 3) int64`` on the vertex rows; read-only."""
    t = np.arange(s + 1) / s
    tu, tv = np.meshgrid(t, t, indexing="ij")
    i = np.arange(s)[:, None]
    j = np.arange(s)[None, :]
    a = i * (s + 1) + j
    b = (i + 1) * (s + 1) + j
    local = np.stack(np.broadcast_arrays(a, b, b + 1, a, b + 1, a + 1), axis=-1).reshape(-1, 2, 3).reshape(-1, 3)
    out = tu.reshape(1, -1), tv.reshape(1, -1), local
    for x in out:
        x.flags.writeable = False
    return out
