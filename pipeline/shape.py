"""A deformable's object-space shape data, and the one `Shape` per surface the frame loop shares.

Everything about a surface that does not depend on where it is lives in a `Shape`: level details,
level-0 patch hull boxes, the density map, a coarse sample grid, the convex hull of the CVs, and
the per-patch collision grids (`pipeline.grids.GridCache`). The queries on it — closest points,
inside tests, ray casts (`Shape.nearest`, `Shape.signed`, `Shape.cast`) — are in
`pipeline.queries`: they visit only the patches whose hull boxes can hold the answer, and a
response, which changes a surface locally, re-tessellates only the patches it changed
(`changed_patches`). Object space throughout; arrays are float64 unless stated.
"""

from __future__ import annotations

import hashlib
from functools import cached_property

import numpy as np

from acra import halfspaces, kdtree, lattice, memo
from acra import hspline as H
from acra.hspline import HSpline, changed_patches
from acra.orientation import volume_sign_about_mean
from acra.patch_boxes import patch_boxes
from pipeline import queries
from pipeline.grids import (COLLAPSE, BvhCache, Closest, GridCache, GridSet, Nearest, PatchGrid, SetupClock, bvh, overlap,
                            timed)
from pipeline.spatial import ConvexHull, QhullError, cKDTree

__all__ = ["PatchGrid", "GridSet", "GridCache", "HullIndex", "Shape", "SetupClock", "shape_of", "seed_details", "Nearest",
           "Closest", "bvh", "overlap", "content_digest", "surface_digest", "coarse_points", "coarse_triangles"]


@timed
def _kd_tree(points: np.ndarray) -> kdtree.PointTree:
    """A compiled kd-tree of ``points (n, 3)`` (`acra.kdtree`; its build timed as set-up)."""
    return kdtree.build(points)


# a 2-step patch grid's samples in `patch_grids`' order (u's step slowest), in half patches
_HALF_U = np.repeat(np.arange(3, dtype=np.int64), 3)
_HALF_V = np.tile(np.arange(3, dtype=np.int64), 3)


def coarse_points(hs: HSpline, patches: np.ndarray, det: H.Details | None) -> np.ndarray:
    """``points (9 m, 3)`` of `patch_grids` ``(hs, patches, 2, det)`` for level-0 ``patches
    (m, 2) int64``, each distinct sample evaluated once. Neighbouring patches share their edge
    samples, and a shared sample has the same parameters in both, ``pu + 1.0 == (pu + 1) +
    0.0`` (half patches are exact in float64): the same ``(u, v)`` evaluates to the same bits,
    so one evaluation serves every copy, about half the samples of a block of patches."""
    patches = np.asarray(patches, np.int64).reshape(-1, 2)
    width = 2 * hs.v.patches0 + 1  # half-patch samples along v, the end included
    first = 2 * (patches[:, 0] * width + patches[:, 1])  # each patch's sample (0, 0)
    key = (first[:, None] + (_HALF_U * width + _HALF_V)).reshape(-1)
    seen = np.zeros((2 * hs.u.patches0 + 1) * width, bool)
    seen[key] = True
    distinct = np.flatnonzero(seen)
    slot = np.cumsum(seen) - 1  # a sample's row among the distinct ones
    u, v = np.divmod(distinct, width)
    return H.evaluate(hs, u / 2.0, v / 2.0, det=det).points[slot[key]]


def coarse_triangles(m: int) -> np.ndarray:
    """``triangles (8 m, 3) int64`` of `patch_grids` ``(hs, patches, 2)`` for ``m`` patches:
    each patch's 9 rows split into 4 cells of 2 triangles, as `patch_grids` splits them."""
    a = (3 * np.arange(2)[:, None] + np.arange(2)[None, :]).reshape(-1)  # each cell's first corner
    cell = np.stack([a, a + 3, a + 4, a, a + 4, a + 1], axis=1).reshape(-1, 3)
    return (cell[None] + 9 * np.arange(m, dtype=np.int64)[:, None, None]).reshape(-1, 3)


class CoarseIndex:
    """Distances from points to the nearest of a set of points held as a kd-tree ``tree`` of
    other points (`acra.kdtree.PointTree`), of which the rows ``current (n,) bool`` belong to the
    set (``None``: all), and a kd-tree ``extra`` of the set's other points. The same distances as
    scipy's ``cKDTree`` of the set: each is the distance of the same nearest point, computed the
    same way (`acra.kdtree`)."""

    def __init__(self, tree: kdtree.PointTree, current: np.ndarray | None = None,
                 extra: kdtree.PointTree | None = None) -> None:
        self.tree, self.current, self.extra = tree, current, extra

    def query(self, q: np.ndarray) -> np.ndarray:
        """Distances ``(k,)`` from points ``q (k, 3)`` to the nearest point of the set: the
        ``extra`` tree's least square bounds the masked tree's search, which passes over the
        masked points in its leaves, so a query beside the moved points visits only the tree
        points about as near as its nearest moved one."""
        q = np.asarray(q, np.float64).reshape(-1, 3)
        best = None if self.extra is None else kdtree.nearest_squares(self.extra, q)
        return np.sqrt(kdtree.nearest_squares(self.tree, q, self.current, best))


class HullIndex:
    """A convex hull (scipy ``ConvexHull``, triangulated facets) and a test of which points lie
    within ``slack`` of it that costs what the points cost, not what the hull's facet count costs.

    The hull is the union of the tetrahedra joining an interior point ``c`` (the mean of its
    vertices) to its facets, so a point in the cone from ``c`` through facet ``f`` is inside iff it
    is behind ``f``'s plane; a point beyond any facet plane by more than ``slack`` is outside. The
    facet whose cone holds a point is looked up among those whose centroid direction from ``c`` is
    nearest the point's (a kd-tree of unit directions); points whose answer this does not settle
    (no such cone within 1e-12 of the size, or behind their facet by less than ``slack``) take the
    test against every facet, so the answer is that test's (`within`). Points in a small box
    (a contact's) take the compiled test against the few facets whose planes pass near the box
    (`_facets_near`), which is the test against every facet, without the cone lookup's
    per-point kd-tree query (docs/performance.md, *Scale with model size*). A hull of at most
    `DIRECT` facets takes that test for every point (`acra.halfspaces.within`, compiled): a
    point outside stops at the first facet it is beyond, and one inside costs about a
    nanosecond a facet, less than the kd-tree's lookup of its cone (a 198-facet CV hull: 0.16
    against 1.4 µs a point)."""

    CANDIDATES = 6  # facets tried per point, by centroid direction
    DIRECT = 1024  # facets up to which every point takes the compiled test against every facet

    def __init__(self, hull: ConvexHull) -> None:
        self.hull = hull
        self.equations = hull.equations

    @cached_property
    def _cones(self) -> tuple[np.ndarray, np.ndarray, cKDTree, float]:
        """Centre ``c (3,)``, unit inward normals ``(m, 3, 3)`` of each facet's three cone sides
        through ``c``, the kd-tree of the facets' unit centroid directions, and 1e-12 of the size."""
        pts, tri = self.hull.points, self.hull.simplices
        verts = pts[self.hull.vertices]
        c = verts.mean(axis=0)
        a, b, d = (pts[tri[:, i]] - c for i in range(3))
        sides = np.stack([np.cross(a, b), np.cross(b, d), np.cross(d, a)], axis=1)  # (m, 3, 3)
        sides *= np.sign(np.einsum("ij,ij->i", sides[:, 0], d))[:, None, None]  # towards the third corner
        with np.errstate(invalid="ignore", divide="ignore"):
            sides /= np.linalg.norm(sides, axis=2, keepdims=True)  # a degenerate cone gets NaN: never holds a point
        mid = a + b + d
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        return c, sides, cKDTree(mid), 1e-12 * float(np.ptp(verts, axis=0).max())

    def within(self, q: np.ndarray, slack: float) -> np.ndarray:
        """``(k,) bool``: points ``q (k, 3)`` with ``n · x + d <= slack`` for every facet."""
        q = np.asarray(q, np.float64).reshape(-1, 3)
        eq = self.equations
        if len(eq) <= self.DIRECT or not len(q):  # no points: no cone to look up
            return halfspaces.within(eq, q, slack)
        near = self._facets_near(q, slack) if slack > 0.0 else None
        if near is not None:
            return halfspaces.within(eq[near], q, slack)
        c, sides, tree, tol = self._cones
        r = q - c
        size = np.linalg.norm(r, axis=1)
        _, cand = tree.query(r / np.maximum(size, 1e-300)[:, None], k=min(self.CANDIDATES, len(eq)))
        cand = cand.reshape(len(q), -1)
        cone = (np.einsum("nkij,nj->nki", sides[cand], r) >= tol).all(axis=2)  # (k, K)
        val = np.einsum("nkj,nj->nk", eq[cand, :3], q) + eq[cand, 3]
        hit = cone.any(axis=1)
        own = val[np.arange(len(q)), cone.argmax(axis=1)]
        inside = hit & (own <= 0.0)
        res = inside.copy()
        rest = np.nonzero(~inside & ~(val > slack).any(axis=1))[0]
        if len(rest):
            res[rest] = halfspaces.within(eq, q[rest], slack)
        return res

    def _facets_near(self, q: np.ndarray, slack: float) -> np.ndarray | None:
        """Rows ``(m',) int64`` of the facets that some point of ``q (k, 3)``'s box may lie
        beyond by more than ``slack``, where there are at most `DIRECT` of them (else ``None``).

        Over the box with centre ``o`` and half extents ``h``, ``n · x + d`` is at most ``n · o
        + |n| · h + d``; a facet whose bound is below ``slack`` by more than the rounding of
        both sums (1e-12 of the magnitudes they add, ``|n| · (|o| + h) + |d|``) holds every
        point of the box, as `acra.halfspaces.within` sums its value, so the test against the
        others is the test against every facet. A contact's points fill a small box near one
        side of the hull, which a handful of facets' planes pass near: the test costs what the
        points cost, not what the hull's facet count costs. A non-finite point has no box
        (``None``). `within` asks only at a positive ``slack`` (`Shape.signed`'s): at none, a
        point on a facet plane (a hull vertex, as `cv_index` tests the CVs with details) is
        the rounding's either way, and the cone lookup keeps its answer."""
        lo, hi = q.min(axis=0), q.max(axis=0)
        if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
            return None
        mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        half = np.maximum(half, np.maximum(mid - lo, hi - mid))  # the box's centre rounded: still covers it
        rows, d, size = self._box_rows
        top, mag = np.split(rows @ np.concatenate([mid, half, np.abs(mid) + half]), 2)
        top += d
        mag += size
        near = np.flatnonzero(~(top <= slack - 1e-12 * mag))  # a NaN bound is kept
        return near if len(near) <= self.DIRECT else None

    @cached_property
    def _box_rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`_facets_near`'s rows: ``(2 m, 9) float64`` whose product with ``(o, h, |o| + h)``
        gives each facet's ``n · o + |n| · h`` (first ``m``) and ``|n| · (|o| + h)`` (last
        ``m``), the offsets ``d (m,)`` and ``|d| (m,)``."""
        n, d = self.equations[:, :3], self.equations[:, 3]
        an, zero = np.abs(n), np.zeros_like(n)
        return np.ascontiguousarray(np.block([[n, an, zero], [zero, zero, an]])), d.copy(), np.abs(d)


_REFINEMENTS_KEPT = 64
_REFINEMENTS = memo.Table("shape.refinements", _REFINEMENTS_KEPT)  # (u, v, k, level k-1 and k cv_keys bytes) -> `acra.details.cv_refinement`, most recent last


class Shape:
    """Everything about a surface that does not depend on where it is, in object space. A
    deformable's input shape is the same at every time code unless its ``acra:cvs`` are keyed, so
    one `Shape` serves every frame and every rewinding step (`shape_of`); only the matrix changes.
    Built lazily, so what is never needed is never computed. ``parent``: the shape this one was
    responded from, whose grids it reuses where the response did not reach."""

    def __init__(self, surface: HSpline, density: int = 8, max_density: int = 64, parent: "Shape | None" = None) -> None:
        self.surface, self.density, self.max_density = surface, density, max_density
        self.cache = GridCache(self)
        self.parent = parent
        # with ``parent``: level-0 patches ``(P0u, P0v) bool`` holding every one where the surface
        # may differ from the parent's, as the response that made it followed its moves
        # (`acra.respond.ResponseReport.moved`); ``None``: `_stale` compares the levels
        self.moved: np.ndarray | None = None
        self.bvhs = BvhCache()  # fcl BVHs of the narrow phase's world triangle sets, by content
        self.ray_meshes: dict[bytes, object] = {}  # merged grids that rays were cast on (`queries.cast`)
        self._display = None  # a display of the surface while `outward_shown` builds `_coarse`

    @cached_property
    def digest(self) -> bytes:
        """The surface's content (`surface_digest`), found once per surface object: what
        answers kept by content (`detect.intersect`, a geometry's world data) are kept under."""
        return surface_digest(self.surface)

    @property
    def grids(self) -> dict[tuple[int, int], PatchGrid]:
        """The collision grids built so far, by level-0 patch (row, column)."""
        return self.cache.grids

    @cached_property
    @timed
    def details(self) -> H.Details | None:
        return H.details(self.surface) if self.surface.depth > 1 else None

    @cached_property
    def eval_args(self) -> tuple:
        """What `acra.kernels.eval_points` reads of the surface and its `details`, read once
        (`acra.hspline.eval_arrays`): the inside tests' normals are evaluated in compiled code."""
        return H.eval_arrays(self.surface, self.details)

    @cached_property
    def cv_positions(self) -> list[np.ndarray]:
        """Every level's CV positions ``(c_k, 3)`` (`acra.details.all_cv_positions`): the patch
        boxes and the CV hull both bound the surface by them (timed as theirs)."""
        return H.all_cv_positions(self.surface, self.details, self._cv_refinement)

    def _cv_refinement(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """`acra.details.cv_refinement` of level ``k``: the parent's where both surfaces hold the
        same ``cv_keys`` arrays on levels ``k`` and ``k-1`` (it depends on them alone; a response
        that does not refine a level keeps its arrays), else built."""
        p, hs = self.parent, self.surface
        hit = None
        if p is not None and k < p.surface.depth and all(hs.level(j).cv_keys is p.surface.level(j).cv_keys for j in range(max(k - 1, 1), k + 1)):
            hit = p._cv_refinements.get(k)
        if hit is None:
            # else the last few built, by content: each frame starts again from the input and
            # its responses refine the same region, so the same levels' keys come back
            key = (hs.u, hs.v, k, hs.level(k - 1).cv_keys.tobytes() if k > 1 else b"", hs.level(k).cv_keys.tobytes())
            hit = _REFINEMENTS.kept(key, lambda: H.cv_refinement(hs, k))
        self._cv_refinements[k] = hit
        return hit

    @cached_property
    def _cv_refinements(self) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        return {}

    @cached_property
    @timed
    def hulls(self) -> tuple[np.ndarray, np.ndarray]:
        """Object-space boxes ``lo, hi (P0u, P0v, 3)`` of the level-0 patches' control hulls
        (`acra.patch_boxes.patch_hulls`, compiled: `patch_boxes`); the parent's where the
        response did not reach."""
        stale = self._stale
        if stale is None or stale.all():
            return patch_boxes(self.surface, self.cv_positions)
        lo, hi = (x.copy() for x in self.parent.hulls)
        if stale.any():
            new = patch_boxes(self.surface, self.cv_positions, only=stale)
            lo[stale], hi[stale] = new[0][stale], new[1][stale]
        return lo, hi

    @cached_property
    def density_map(self) -> np.ndarray:
        """Steps per edge of each level-0 patch ``(P0u, P0v) int64``: ``max(density, 2 * 2**k)``,
        ``k`` the finest level with an active patch inside it, capped at ``max_density``."""
        hs = self.surface
        finest = np.zeros((hs.u.patches0, hs.v.patches0), np.int64)
        for lev in hs.fine:
            if lev.patches.size:
                npv = hs.v.patches(lev.k)
                finest[(lev.patches // npv) >> lev.k, (lev.patches % npv) >> lev.k] = lev.k
        return np.minimum(np.maximum(self.density, 2 * (1 << finest)), self.max_density)

    @cached_property
    def closed(self) -> bool:
        """Periodic both ways, or one way with both ends of the other collapsed (poles); a cubic is
        fixed by 4 points per segment, so 4 coincident samples per patch make an end one point."""
        hs = self.surface
        if hs.u.periodic == hs.v.periodic:
            return hs.u.periodic
        per, end = (hs.u, hs.v) if hs.u.periodic else (hs.v, hs.u)
        p = self.parent
        if self._changed_known and p.surface.size() == hs.size():
            # the end samples lie on the first and last rows of patches across ``end``: where
            # none of those changed they are the parent's bits, and so is the answer
            stale = self._changed if hs.u.periodic else self._changed.T
            if not (stale[:, 0].any() or stale[:, -1].any()):
                return p.closed
        run = np.arange(4 * per.patches0) / 4.0
        for e in (0.0, float(end.patches0)):
            uv = (run, np.full_like(run, e)) if hs.u.periodic else (np.full_like(run, e), run)
            if np.ptp(H.evaluate(hs, *uv, det=self.details).points, axis=0).max() > COLLAPSE * hs.size():
                return False
        return True

    @cached_property
    @timed
    def _coarse(self) -> tuple[np.ndarray, np.ndarray]:
        """A 2-step grid of every level-0 patch: surface ``points (9 P, 3)`` and ``triangles
        (8 P, 3) int64``; the parent's points off `_changed`, once that is known or free (the
        response handed its `moved` patches), and on it those of the display `outward_shown`
        hands it where its vertices hold every sample (`_shown_points`). Before that every
        patch is evaluated (a patch's 9 points depend on its own CVs and details alone, so they
        are the parent's bits where it did not change): finding the changed patches compares
        every level's offsets, which costs about what evaluating 9 points a patch does, and the
        residual's orientation (`outward`) of a responded surface needs nothing else of it."""
        stale = self._changed if self._changed_known else None
        if stale is None or stale.all():
            p = np.argwhere(np.ones((self.surface.u.patches0, self.surface.v.patches0), bool))
            # the triangles depend on the patch count alone, which a response keeps
            known = self.parent.__dict__.get("_coarse") if stale is not None else None
            tris = known[1] if known is not None and len(known[1]) == 8 * len(p) else coarse_triangles(len(p))
            pts = np.empty((9 * len(p), 3))
            if stale is None or not self._shown_points(stale, pts):
                pts = coarse_points(self.surface, p, self.details)
            return pts, tris
        pts, tris = self.parent._coarse
        pts = pts.copy()
        if stale.any() and not self._shown_points(stale, pts):  # 9 points per patch, patches in row-major order
            new = coarse_points(self.surface, np.argwhere(stale), self.details)
            pts.reshape(stale.size, 9, 3)[stale.reshape(-1)] = new.reshape(-1, 9, 3)
        return pts, tris

    def _shown_points(self, patches: np.ndarray, out: np.ndarray) -> bool:
        """Write `coarse_points` of the level-0 patches ``patches (P0u, P0v) bool`` into their
        rows of ``out (9 P, 3)`` (9 a patch, row-major), read from the display `outward_shown`
        hands `_coarse`: its vertices at their samples (`acra.lattice.half_patch_points`).
        False (``out`` partly written) without one, or where it was evaluated with other details
        or lacks a sample. A display vertex is the surface evaluated at its own ``(u, v)`` alone
        (`acra.tessellate.grid_samples`), the sample's parameters bit for bit (a periodic end
        ``P0`` the seam's vertex at 0: `acra.kernels.eval_points` wraps ``P0`` to exactly 0.0
        before it reads anything of the parameter), so its point is the bits `coarse_points`
        gives."""
        sd, hs = self._display, self.surface
        if sd is None or sd.surface is not hs or sd.details is not self.details:
            return False
        return lattice.half_patch_points(sd.topology.u, sd.topology.v, sd.points, patches.reshape(-1),
                                         int(hs.v.patches0), bool(hs.u.periodic), bool(hs.v.periodic), out)

    def outward_shown(self, display) -> float:
        """`outward`, a responded surface's moved coarse samples read from ``display`` (a
        `pipeline.display.SurfaceDisplay` of the surface: its ``surface``, ``topology``,
        ``points`` and ``details``), the bits evaluating them gives (`_shown_points`). The
        display is read while `_coarse` is built and not kept: a kept shape does not hold its
        display's points."""
        if "_coarse" in self.__dict__ or not self._changed_known:
            return self.outward
        self._display = display
        try:
            return self.outward
        finally:
            self._display = None

    @cached_property
    def coarse_index(self) -> "CoarseIndex":
        """Distances to the nearest `_coarse` point (they bound a closest-point query's). A
        responded shape takes its parent's kd-tree with the points the response moved masked out,
        and a tree of the moved points alone, so a response costs what it changed, until the
        points off the shared tree pass a quarter of them."""
        pts = self._coarse[0]
        stale = self._changed if self.parent is not None else None
        if stale is None or stale.all():
            return CoarseIndex(_kd_tree(pts))
        par = self.parent.coarse_index
        moved = np.repeat(stale.reshape(-1), 9)  # 9 points per patch, patches in row-major order
        if not moved.any():
            return par
        current = ~moved if par.current is None else par.current & ~moved
        off = ~current
        if off.sum() * 4 > len(pts):
            return CoarseIndex(_kd_tree(pts))
        return CoarseIndex(par.tree, current, _kd_tree(pts[off]))

    @cached_property
    def outward(self) -> float:
        """``+1`` if ``du × dv`` points out of a closed surface, else ``-1``: the sign of the
        volume enclosed by the coarse grid (divergence theorem)."""
        pts, tris = self._coarse
        # compiled, where no summation order can flip it; ``centre`` is ``pts.mean(axis=0)``
        sure, centre = volume_sign_about_mean(pts, tris)
        if sure:
            return float(sure)
        a, b, c = (pts[tris[:, i]] - centre for i in range(3))
        return 1.0 if np.einsum("ij,ij->i", a, np.cross(b, c)).sum() >= 0 else -1.0

    @cached_property
    def _boxes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Flattened hull boxes ``lo, hi (P, 3)`` and their patches ``(P, 2) int64``."""
        lo, hi = (x.reshape(-1, 3) for x in self.hulls)
        return lo, hi, np.argwhere(np.ones(self.hulls[0].shape[:2], bool)).astype(np.int64)

    @cached_property
    def _stale(self) -> np.ndarray | None:
        """Patches ``(P0u, P0v) bool`` where the parent's grids, hull boxes, coarse points and
        display samples cannot serve (``None``: no parent)."""
        p = self.parent
        if p is None:
            return None
        return self._changed | (p.density_map != self.density_map)

    @cached_property
    def _changed(self) -> np.ndarray:
        """Patches ``(P0u, P0v) bool`` where the surface may differ from the parent's
        (`changed_patches`: the response's `moved` where it handed them), so where its points,
        coarse grid and ends are the parent's bits; with a parent only. Refinement alone moves
        no point (a new CV's detail vector is zero), so unlike `_stale` the density map does not
        enter."""
        p = self.parent
        return changed_patches(p.surface, self.surface) if self.moved is None else self.moved

    @property
    def _changed_known(self) -> bool:
        """Whether `_changed` is found or free (the response handed its `moved` patches)."""
        return self.parent is not None and (self.moved is not None or "_changed" in self.__dict__)

    def grids_for(self, patches: np.ndarray) -> list[PatchGrid]:
        """Collision grids of level-0 ``patches (m, 2) int64`` at their density (cached)."""
        return self.cache.grids_for(patches)

    @cached_property
    def cv_hull(self) -> np.ndarray | None:
        """Half-spaces ``(m, 4) float64`` of the convex hull of every level's CV positions, a point
        ``x`` within it iff ``n · x + d <= 0`` for every row ``(n, d)``; ``None`` if the CVs are
        flat. The surface lies in it (B-spline convex hull property: a fine level's net is the
        refined coarser net plus details, and refinement takes convex combinations), so do its
        collision grids and, for a closed surface, everything they enclose (`cv_index`)."""
        index = self.cv_index
        return None if index is None else index.equations

    @cached_property
    def _level0_index(self) -> "HullIndex | None":
        """`HullIndex` of the level-0 CVs (``None`` if flat); the parent's where the level-0 CVs
        are the same (a response that leaves level 0 keeps its hull)."""
        if self._same_level0:
            return self.parent._level0_index
        try:
            return HullIndex(ConvexHull(self.surface.cvs.reshape(-1, 3)))
        except QhullError:
            return None

    @cached_property
    def _same_level0(self) -> bool:
        """Whether the parent's level-0 CVs are this surface's."""
        p, cvs = self.parent, self.surface.cvs
        return p is not None and (p.surface.cvs is cvs or np.array_equal(p.surface.cvs, cvs))

    def _known_level0(self) -> "tuple[bool, HullIndex | None]":
        """Whether an ancestor with these level-0 CVs (or this shape) has built `_level0_index`,
        and that index."""
        s = self
        while "_level0_index" not in s.__dict__:
            if not s._same_level0:
                return False, None
            s = s.parent
        return True, s.__dict__["_level0_index"]

    @cached_property
    @timed
    def cv_index(self) -> "HullIndex | None":
        """`HullIndex` of every level's CV positions (`cv_hull`). A fine CV with a zero detail
        vector is a convex combination of the coarser level's CVs (refinement weights are
        non-negative and sum to 1), so by induction the hull of every level is the hull of level 0
        plus the CVs with details. Where level 0's hull is at hand (the shape's or an ancestor's
        with the same level-0 CVs), only those outside it can add to it: a response that moves
        the surface inwards keeps level 0's hull, shared, with no new qhull; otherwise the hull of
        level 0's hull vertices and those CVs. Else one qhull of level 0 and the CVs with details."""
        det = self.details
        moved = [pos[np.any(vec != 0.0, axis=1)] for pos, vec in zip(self.cv_positions[1:], det.vectors)] if det else []
        moved = np.concatenate(moved) if moved else np.zeros((0, 3))
        known, base = self._known_level0()
        if not len(moved):
            known, base = True, self._level0_index
        if not known:
            level0 = self.surface.cvs.reshape(-1, 3)
        elif base is None:  # flat level 0: the details alone can give the hull a volume
            level0 = np.concatenate(self.cv_positions)
        else:
            moved = moved[~base.within(moved, 0.0)]
            if not len(moved):
                return base
            level0 = base.hull.points[base.hull.vertices]
        try:
            return HullIndex(ConvexHull(np.concatenate([level0, moved])))
        except QhullError:
            return None

    def nearest(self, q: np.ndarray) -> Nearest:
        """Closest points on the collision grids to object-space points ``q (k, 3)``
        (`queries.nearest`)."""
        return queries.nearest(self, q)

    def signed(self, q: np.ndarray, nearest: bool = True) -> tuple[np.ndarray, Nearest | None]:
        """Which object-space points ``q (k, 3)`` are inside, and their nearest points unless
        ``nearest`` is false (`queries.signed`)."""
        return queries.signed(self, q, nearest)

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """First hits of object-space rays on the collision grids (`queries.cast`)."""
        return queries.cast(self, origins, directions)


def content_digest(*parts) -> bytes:
    """A 20-byte digest of ``parts`` (arrays by dtype, shape and bytes, anything else by its
    ``repr``): equal content gives an equal digest whichever objects hold it, and other content
    another, so an answer kept under it is never served for other data (an ``id()`` can be
    reused by a new array once the old one is freed). SHA-1, which processors with SHA
    instructions hash about twice as fast as BLAKE2b (0.37 against 0.75 ms for a 564 KB
    display's points on the benchmark machine)."""
    h = hashlib.sha1()
    for x in parts:
        if isinstance(x, np.ndarray):
            x = np.ascontiguousarray(x)
            h.update(f"{x.dtype.str}{x.shape}".encode())
            h.update(x.data)
        else:
            h.update(repr(x).encode())
        h.update(b"|")
    return h.digest()


def surface_digest(hs: HSpline) -> bytes:
    """`content_digest` of an H-spline: its directions, depth, level-0 CVs and every fine level's
    active patches, CVs, offsets and movability (all a point of it depends on)."""
    fine = [x for lev in hs.fine for x in (lev.k, lev.patches, lev.cv_keys, lev.offsets, lev.movable)]
    return content_digest(hs.u, hs.v, hs.depth, hs.cvs, *fine)


_SHAPES_KEPT = 64
_SHAPES = memo.Table("shape.shapes", _SHAPES_KEPT)  # id(surface) -> (surface, density, max_density, Shape), most recent last


def shape_of(surface: HSpline, density: int = 8, max_density: int = 64) -> Shape:
    """The `Shape` of ``surface`` (the same object for the same surface object and densities).

    Keyed by identity: surfaces are immutable, and the frame loop hands the same object back for
    unchanged input CVs. The most recent ``_SHAPES_KEPT`` shapes are kept."""
    key = id(surface)
    shapes = _SHAPES.entries()
    hit = shapes.pop(key, None)
    if hit is None or hit[0] is not surface or hit[1:3] != (density, max_density):
        hit = (surface, density, max_density, Shape(surface, density, max_density))
    shapes[key] = hit
    _SHAPES.trim()
    return hit[3]


def seed_details(surface: HSpline, details: H.Details | None, density: int = 8, max_density: int = 64,
                 parent: HSpline | None = None, moved: np.ndarray | None = None) -> None:
    """Give ``surface``'s `Shape` details computed elsewhere (by `acra.respond.respond`) and the
    shape it was responded from, whose grids it then reuses where it did not change; ``moved
    (P0u, P0v) bool``: the level-0 patches holding every one where it may differ from ``parent``
    (`acra.respond.ResponseReport.moved`), so the changed patches need no comparison."""
    shape = shape_of(surface, density, max_density)
    if details is not None and "details" not in shape.__dict__:
        shape.__dict__["details"] = details
    if parent is not None and shape.parent is None and not shape.grids:
        shape.parent = shape_of(parent, density, max_density)
        shape.moved = moved
