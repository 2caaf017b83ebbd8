"""Collision grids and exact closest points on them, in object space.

A deformable is collided as triangle grids over its level-0 patches (`PatchGrid`), one per patch
at the density its finest level needs, built lazily per patch and cached per shape (`GridCache`).
Closest points on a triangle set are exact (`Closest`); several patch grids near a contact are
queried as one set (`GridSet`). Set-up time spent building them is counted on `SetupClock`, the
analogue of RAPID's initial set-up in the thesis's Fig. 5.2. Arrays are float64 unless stated.
"""

from __future__ import annotations

import hashlib
import time
import weakref
from dataclasses import dataclass
from functools import cached_property
from itertools import accumulate
from typing import TYPE_CHECKING

import numpy as np

from acra import narrow, nearest
from acra.bvh import bounds
from acra.tessellate import patch_grids
from pipeline.spatial import cKDTree

if TYPE_CHECKING:
    import fcl

    from pipeline.shape import Shape

__all__ = ["PatchGrid", "solid_rows", "GridSet", "GridCache", "Nearest", "Closest", "SetupClock", "timed", "bvh", "BvhCache", "triangle_boxes", "overlap", "boxes_near", "COLLAPSE"]

COLLAPSE = 1e-6  # a grid line within this fraction of the object size is one point (a pole); float32 `acra:cvs` round at ~1e-7


# --- closest points on a triangle set ---------------------------------------------------------
def triangle_boxes(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Boxes ``lo, hi (f, 3)`` of triangles ``tri (f, 3, 3)``: the corners' minima and maxima
    pairwise (exact, as ``tri.min(axis=1)`` is, at a third of its time)."""
    return (np.minimum(np.minimum(tri[:, 0], tri[:, 1]), tri[:, 2]),
            np.maximum(np.maximum(tri[:, 0], tri[:, 1]), tri[:, 2]))


def overlap(lo_a, hi_a, lo_b, hi_b, pad: float) -> np.ndarray:
    """Whether boxes overlap (broadcast over leading axes; corners ``(..., 3) float64``): the
    three axes' tests joined column by column, ``np.all(axis=-1)``'s answer without its reduction
    over a last axis of 3, which numpy runs row by row (77 against 12 us for 1,600 rows)."""
    c = (lo_a <= hi_b + pad) & (lo_b <= hi_a + pad)
    return c[..., 0] & c[..., 1] & c[..., 2]


def boxes_near(centre: np.ndarray, half: np.ndarray, xform: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Rows ``(m,) int64``, ascending, of object-space boxes (centres and half-extents ``(f, 3)``)
    whose world box under ``xform (4, 4)`` meets the world box ``bounds (2, 3)``: a box's world box
    lies in the world box of its mapped centre and extents (``M c + t ± |M| h``), two small products
    per box instead of gathering and reducing its corners (widened by 1e-9 of the query's
    coordinates for the rounding of the two)."""
    world = centre @ xform[:3, :3].T + xform[:3, 3]
    reach = half @ np.abs(xform[:3, :3]).T
    slack = 1e-9 * (float(np.abs(bounds).max()) + float(np.ptp(bounds, axis=0).max()))
    return np.nonzero(overlap(world - reach, world + reach, bounds[0], bounds[1], slack))[0]


def _compact(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The vertices ``(u, 3) float64`` that ``faces (f, 3)`` use and the faces renumbered into
    them ``(f, 3) int32``, contiguous: what fcl builds a BVH from (`acra.narrow.compact`)."""
    return narrow.compact(vertices, faces)


def _build(vertices: np.ndarray, faces: np.ndarray) -> fcl.CollisionObject:
    import fcl  # here: a run whose pairs `acra.narrow` settles alone (the demo's) never imports fcl

    model = fcl.BVHModel()
    model.beginModel(len(vertices), len(faces))
    model.addSubModel(vertices, faces)
    model.endModel()
    return fcl.CollisionObject(model, fcl.Transform())


def bvh(vertices: np.ndarray, faces: np.ndarray) -> fcl.CollisionObject:
    """An fcl BVH of a triangle set at the identity transform; face rows are kept, so fcl's
    ``b1``/``b2`` are rows of ``faces``. Only the vertices the faces use go in: fcl's build costs
    per vertex too (3,009 vertices for 39 faces: 2.4 ms, compacted 0.2 ms)."""
    return _build(*_compact(vertices, faces))


class BvhCache:
    """The last few fcl BVHs (`bvh`) of one object's triangle sets, by content: the compacted
    vertices and faces a BVH is built from, hashed. The narrow phase asks for the same set again
    in the next round of a frame where a response left that part alone, and when the rewinding
    search tests a time it already tested; the same arrays build the same tree, so a hit answers
    exactly as a rebuild would. Hashing costs ~1/20 of a build (about 0.05 against 1 ms for
    2,000 triangles)."""

    def __init__(self, kept: int = 8) -> None:
        self.kept = kept
        self._built: dict[bytes, fcl.CollisionObject] = {}

    def get(self, vertices: np.ndarray, faces: np.ndarray) -> fcl.CollisionObject:
        """`bvh` of ``vertices (n, 3)`` and ``faces (f, 3) int64``, built or found."""
        compact = _compact(vertices, faces)
        key = hashlib.blake2b(compact[0].tobytes() + compact[1].tobytes(), digest_size=16).digest()
        hit = self._built.pop(key, None)
        self._built[key] = hit = _build(*compact) if hit is None else hit
        while len(self._built) > self.kept:
            del self._built[next(iter(self._built))]
        return hit


def extent(vertices: np.ndarray) -> float:
    """The largest side of the box of ``vertices (n, 3)``, or 1 if it is empty or a point. The box
    in one compiled pass (`acra.bvh.bounds`: ``np.ptp(axis=0)``'s min and max, exact)."""
    if not len(vertices):
        return 1.0
    box = bounds(vertices)
    side = float((box[1] - box[0]).max())
    return side if side > 0 else 1.0


class Closest:
    """Exact closest points on triangles: the least distance over the triangles and, among equal
    ones, the lowest face row, each (point, triangle) distance in trimesh's ``closest_point``
    arithmetic in units of the mesh's size (its region tests have absolute tolerances, 1e-13),
    searched through a compiled BVH (`acra.nearest`: the same bits as testing every triangle).
    A collider's index holds its fcl BVH ``bvh_``: a point farther than twice the largest
    centroid-corner distance from every vertex (deep inside a coarse mesh) takes fcl's closest
    point on it, as the collider's queries always have."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, bvh_: fcl.CollisionObject | None = None,
                 unit: float | None = None, like: "Closest | None" = None) -> None:
        self.vertices, self.faces, self.bvh = vertices, faces, bvh_
        self.tri = nearest.corners(vertices, faces)  # (f, 3, 3): vertices[faces]
        # ``unit``: `extent` of ``vertices``, passed in by a caller that has it
        self.unit = extent(vertices) if unit is None else unit
        # ``like``: the same faces before their vertices moved; its tree, if built, is refitted
        # (`acra.nearest.refit`) instead of sorted and split again. Only its `Index` is held, so
        # a chain of moved sets keeps no older one alive.
        self._like = None if like is None or len(like.faces) != len(faces) else like.__dict__.get("index")

    @cached_property
    def index(self) -> nearest.Index:
        like, self._like = self._like, None
        return nearest.index(self.tri, self.unit, like)

    @cached_property
    def _deep(self) -> tuple[cKDTree, float]:
        """A kd-tree of the vertices the faces use and the largest centroid-corner distance."""
        cen = (self.tri[:, 0] + self.tri[:, 1] + self.tri[:, 2]) / 3.0
        return cKDTree(self.vertices[np.unique(self.faces)]), float(np.linalg.norm(self.tri - cen[:, None], axis=2).max())

    def query(self, points: np.ndarray, bound: np.ndarray | None = None):
        """Distances ``(k,)``, closest points ``(k, 3)`` and face rows ``(k,) int64``. With
        ``bound (k,)``, only closest points within it are sought (else distance ``inf``)."""
        points = np.asarray(points, np.float64).reshape(-1, 3)
        k = len(points)
        if not k or not len(self.faces):
            return np.full(k, np.inf), np.zeros((k, 3)), np.zeros(k, np.int64)
        if self.bvh is None:
            return nearest.query(self.index, points, bound)
        vtree, reach = self._deep
        dv, _ = vtree.query(points)
        if bound is not None:
            dv = np.minimum(dv, bound)
        deep = dv > 2.0 * reach
        if not deep.any():
            return nearest.query(self.index, points, bound)
        dist, close, face = np.full(k, np.inf), np.zeros((k, 3)), np.zeros(k, np.int64)
        near = np.nonzero(~deep)[0]
        if len(near):
            dist[near], close[near], face[near] = nearest.query(self.index, points[near], None if bound is None else bound[near])
        import fcl  # here, as in `_build`

        probe, req = fcl.Sphere(0.0), fcl.DistanceRequest(enable_nearest_points=True)
        for i in np.nonzero(deep)[0]:
            res = fcl.DistanceResult()  # mesh first: b1 is its face, nearest_points[0] on it
            dist[i] = fcl.distance(self.bvh, fcl.CollisionObject(probe, fcl.Transform(points[i])), req, res)
            close[i], face[i] = res.nearest_points[0], res.b1
        return dist, close, face

    def within(self, points: np.ndarray, dist: float) -> np.ndarray:
        """Which ``points (k, 3)`` lie within ``dist`` of a triangle, ``(k,) bool``: the compiled
        search bounded by ``dist``, which opens only the boxes within it."""
        points = np.asarray(points, np.float64).reshape(-1, 3)
        if not len(points) or not len(self.faces):
            return np.zeros(len(points), bool)
        return nearest.query(self.index, points, np.full(len(points), float(dist)))[0] <= dist


# --- set-up time ---------------------------------------------------------------------------------
class SetupClock:
    """Milliseconds spent building `Shape` data (the thesis's "initial setup" of RAPID, Fig. 5.2):
    the frame loop reads it around detection to report set-up apart from the queries. ``open``:
    how many `timed` builders are running, one inside another (a shape's patch boxes build its
    details on their first read): only the outermost one's time is counted, once."""

    ms: float = 0.0
    open: int = 0


def timed(build):
    """Decorate a `Shape` builder so its time goes to `SetupClock`: the whole time of a builder
    that no other one called, nothing for a builder called inside another (its time is in that
    one's)."""

    def clocked(*args, **kwargs):
        if SetupClock.open:
            SetupClock.open += 1
            try:
                return build(*args, **kwargs)
            finally:
                SetupClock.open -= 1
        SetupClock.open = 1
        t = time.perf_counter()
        try:
            return build(*args, **kwargs)
        finally:
            SetupClock.ms += 1e3 * (time.perf_counter() - t)
            SetupClock.open = 0

    clocked.__name__, clocked.__doc__ = build.__name__, build.__doc__
    return clocked


# --- per-patch collision grids --------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class PatchGrid:
    """One level-0 patch's collision grid in object space: ``points (n, 3)``, their parameters
    ``uv (n, 2)`` (level-0 units, continuous within the patch), ``triangles (f, 3) int64`` wound
    so that their normals follow ``du × dv``, and ``solid (s,) int64``: the rows of
    ``triangles`` with three distinct corners (a pole row's slivers dropped, `solid_rows`)."""

    points: np.ndarray
    uv: np.ndarray
    triangles: np.ndarray
    solid: np.ndarray


def solid_rows(points: np.ndarray, triangles: np.ndarray) -> list[np.ndarray]:
    """For grids ``points (r, n, 3)`` sharing ``triangles (f, 3) int64``: per grid, the rows
    ``(s,) int64`` of the triangles whose three edges are longer than `COLLAPSE` times the grid's
    extent. All grids of one density in one compiled pass (`acra.narrow.solid_mask`: each edge's
    length rounded as ``np.linalg.norm`` rounds it, so each grid's rows are those the array form
    gives it alone)."""
    return [np.nonzero(row)[0] for row in narrow.solid_mask(points, triangles, COLLAPSE)]


class GridSet:
    """Several patch grids as one triangle set, so a batch of queries near a contact is answered
    by one kd-tree pass and one exact closest-point call per grid density instead of one of each
    per patch grid. Grids of one density share a `Closest` index (its search radius grows with
    the largest triangle, so a coarse grid must not widen a fine one's). ``face_lo, face_hi
    (f, 2)``: the parameter box of each solid face's patch (closest points' parameters are kept
    inside their patch)."""

    def __init__(self, grids: list[PatchGrid], like: "GridSet | None" = None) -> None:
        # finest first, ties in the order given (a stable sort); the sizes read once, as plain ints:
        # a set holds a few dozen grids, where Python lists cost less than numpy's small-array calls
        sizes = [len(g.points) for g in grids]
        order = sorted(range(len(grids)), key=sizes.__getitem__, reverse=True)
        grids = [grids[i] for i in order]
        self.grids = grids
        if like is not None and like._same_rows(grids):
            # the same patches at the same densities and solid rows, moved (a response's new
            # surface): the parameters and faces are ``like``'s, only the points are new
            self.points = np.concatenate([g.points for g in grids])
            self.uv, self.triangles, self.face_lo, self.face_hi = like.uv, like.triangles, like.face_lo, like.face_hi
            unit = extent(self.points)
            self.indices = [(start, Closest(self.points, c.faces, unit=unit, like=c)) for start, c in like.indices]
            return
        sizes = [sizes[i] for i in order]
        counts = [len(g.solid) for g in grids]
        firsts = [0, *accumulate(sizes)]  # each grid's first row in the set's points, and the end
        faces = [0, *accumulate(counts)]  # each grid's first solid face row, and the end
        base, count = np.array(firsts[:-1]), np.array(counts)
        self.points = np.concatenate([g.points for g in grids])
        self.uv = np.concatenate([g.uv for g in grids])
        # a grid without slivers keeps every row (``solid`` is then ``arange``): no gather
        self.triangles = np.concatenate([g.triangles if c == len(g.triangles) else g.triangles[g.solid]
                                         for g, c in zip(grids, counts)])
        self.triangles += np.repeat(base, count)[:, None]
        # a grid's first and last points are its patch's parameter corners
        self.face_lo = np.repeat(self.uv[base], count, axis=0)
        self.face_hi = np.repeat(self.uv[np.array(firsts[1:]) - 1], count, axis=0)
        self.indices = []  # (first face row, Closest) per density, all over the set's points
        unit = extent(self.points)
        a = 0  # the grids of one density are consecutive (finest first)
        for b in range(1, len(grids) + 1):
            if b == len(grids) or sizes[b] != sizes[a]:
                self.indices.append((np.int64(faces[a]), Closest(self.points, self.triangles[faces[a]:faces[b]], unit=unit)))
                a = b

    def _same_rows(self, grids: list[PatchGrid]) -> bool:
        """Whether ``grids`` (finest first) have this set's grids' point counts and solid rows, one
        by one: a grid's parameters and triangles are those of its patch and density
        (`acra.tessellate.patch_grids`), so the set's parameters and faces are then this set's."""
        return len(grids) == len(self.grids) and all(
            len(g.points) == len(h.points) and (g.solid is h.solid or np.array_equal(g.solid, h.solid))
            for g, h in zip(grids, self.grids))

    def closest(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Distances ``(k,)``, closest points ``(k, 3)`` and the set's face rows ``(k,) int64`` of
        ``q (k, 3)``: the least distance over the densities, a finer density's on ties."""
        # the finest density's answer whole: its faces come first (``start`` 0), and where it
        # finds no face its answer is the starting one (``inf``, zeros, row 0)
        (_, first), rest = self.indices[0], self.indices[1:]
        dist, close, face = first.query(q)
        for start, index in rest:
            d, cp, f = index.query(q, dist * (1 + 1e-9) + 1e-300)  # only what beats a finer density's
            better = d < dist
            dist[better], close[better], face[better] = d[better], cp[better], f[better] + start
        return dist, close, face

    def nearest(self, q: np.ndarray) -> Nearest:
        """Closest points to ``q (k, 3)`` (`closest`) and their parameters, interpolated from the
        face corners (trimesh's barycentric coordinates, `acra.nearest.face_uv`)."""
        dist, close, face = self.closest(q)
        # trimesh's barycentric coordinates of the closest points, the corners' parameters mixed by
        # them and clipped to the face's patch, in one compiled pass (`acra.nearest.face_uv`)
        return Nearest(dist, close, nearest.face_uv(self.points, self.uv, self.triangles, face, close, self.face_lo, self.face_hi))


@dataclass(frozen=True, eq=False)
class Nearest:
    """Closest points on a shape's collision grids: ``distance (k,)``, object-space ``points
    (k, 3)``, parameters ``uv (k, 2)``."""

    distance: np.ndarray
    points: np.ndarray
    uv: np.ndarray


class GridCache:
    """The collision grids of one `Shape`, built on demand per level-0 patch at the patch's
    `Shape.density_map` steps, and the last few `GridSet`s asked for. A responded shape takes its
    parent's grid objects for patches the response did not reach (`Shape._stale`), so a local
    response re-tessellates only where it changed the surface.

    The cache reaches its shape through a weak reference: the shape holds the cache
    (`Shape.cache`), so a strong one back would make a cycle, and a dropped shape, its grids and
    their sets would wait for the cyclic collector instead of being freed at once."""

    def __init__(self, shape: Shape) -> None:
        self._shape = weakref.ref(shape)
        self.grids: dict[tuple[int, int], PatchGrid] = {}
        self._gridsets: dict[tuple[int, ...], GridSet] = {}
        self._sets: dict[bytes, tuple[np.ndarray, list[PatchGrid]]] = {}

    @property
    def shape(self) -> Shape:
        """The shape whose grids these are (alive while the cache is used: it is reached through
        its shape, `Shape.cache`)."""
        return self._shape()

    @timed
    def build(self, missing: list[tuple[int, int]]) -> None:
        """Grids of the level-0 patches ``missing`` (row, column), the parent's where it serves."""
        shape = self.shape
        stale = shape._stale
        todo = []
        for key in missing:
            old = None if stale is None or stale[key] else shape.parent.grids.get(key)
            if old is not None:
                self.grids[key] = old
            else:
                todo.append(key)
        todo_arr = np.array(todo, np.int64).reshape(-1, 2)
        steps = shape.density_map[todo_arr[:, 0], todo_arr[:, 1]]
        for s in np.unique(steps):
            sel, n = todo_arr[steps == s], (int(s) + 1) ** 2
            pts, uv, tris, _ = patch_grids(shape.surface, sel, int(s), det=shape.details)
            tri = tris[: 2 * int(s) ** 2]
            solid = solid_rows(pts.reshape(len(sel), n, 3), tri)
            for r, p in enumerate(sel):
                self.grids[(int(p[0]), int(p[1]))] = PatchGrid(pts[r * n:(r + 1) * n], uv[r * n:(r + 1) * n], tri, solid[r])

    def grids_for(self, patches: np.ndarray) -> list[PatchGrid]:
        """Collision grids of level-0 ``patches (m, 2) int64`` at their density (cached)."""
        keys = list(map(tuple, np.asarray(patches, np.int64).reshape(-1, 2).tolist()))
        missing = list(dict.fromkeys(k for k in keys if k not in self.grids))
        if missing:
            self.build(missing)
        return [self.grids[k] for k in keys]

    def set_points(self, patches: np.ndarray) -> tuple[np.ndarray, list[PatchGrid]]:
        """The grids of level-0 ``patches (m, 2) int64`` (`grids_for`) and their points one after
        the other ``(n, 3)``, read-only: every matrix a patch set is mapped by (each step of a
        rewinding search) maps the same rows. The last 8 sets are kept."""
        key = np.ascontiguousarray(patches, np.int64).tobytes()
        hit = self._sets.pop(key, None)
        if hit is None:
            grids = self.grids_for(patches)
            points = np.concatenate([g.points for g in grids])
            points.setflags(write=False)
            hit = (points, grids)
        self._sets[key] = hit
        while len(self._sets) > 8:
            del self._sets[next(iter(self._sets))]
        return hit

    def gridset(self, found: tuple[int, ...]) -> GridSet:
        """The `GridSet` of flattened patch rows ``found`` (the last few are kept: consecutive
        rounds and frames query the same contact)."""
        hit = self._gridsets.pop(found, None)
        if hit is None:
            # a response's new surface is queried where its parent was: the parent's set of the
            # same patches lends its faces and its trees (`GridSet`'s ``like``)
            parent = self.shape.parent
            like = None if parent is None else parent.cache._gridsets.get(found)
            hit = GridSet(self.grids_for(self.shape._boxes[2][list(found)]), like)
        self._gridsets[found] = hit
        while len(self._gridsets) > 16:
            del self._gridsets[next(iter(self._gridsets))]
        return hit
