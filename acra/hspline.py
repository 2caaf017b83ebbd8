"""Hierarchical uniform bicubic B-spline surfaces (H-splines; Forsey & Bartels 1988, thesis §3.4).

Representation
--------------
Level 0 is a dense control grid ``cvs : (nu, nv, 3)`` (object space), open or periodic in u and v
independently. Each finer level ``k >= 1`` halves the knot spacing (thesis eq. 3.13–3.15) and is
*sparse*: it holds only the **active patches** that were refined, and the CVs of their 4×4 blocks.
A level-``k`` CV's position is its **derived vector** (the binary subdivision of level ``k-1``)
plus its **offset**, stored in the local frame of level ``k-1`` at the CV's parameter centre
(thesis Fig. 3.9): ``position = derived + F @ offset`` with ``F = [e_u, e_v, n]`` columns
(unit tangent along u, the tangent completing a right-handed frame, unit normal).

C2 rule (thesis Fig. 3.8): a CV may carry an offset only if its basis function vanishes on the
border to the coarser region, i.e. every existing patch in its support (a 4×4 block) is active.
Such CVs are *movable*.

Because subdivision reproduces the coarser surface exactly, the surface is

    Q(u, v) = Q0(u, v) + sum_{k>=1} sum_{movable j at level k} B_j^k(u, v) · F_j @ offset_j

and each level's sum vanishes outside its active region. `evaluate` uses this form (one sparse
B-spline sum per level); `cv_positions` builds the explicit hierarchy of derived + offset CVs,
and the tests check the two agree, which is the refinement-exactness property.

Keys: a patch ``(pu, pv)`` at level ``k`` has key ``pu * Pv_k + pv``; a CV ``(ju, jv)`` has key
``ju * Nv_k + jv`` (``Pv_k``, ``Nv_k``: patch and CV counts along v at level ``k``). Key arrays are
sorted, so membership is a `np.searchsorted`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from .basis import Direction, basis_all, locate, refine_rows

__all__ = [
    "Level",
    "HSpline",
    "Details",
    "SurfaceEval",
    "from_grid",
    "refine",
    "make_movable",
    "set_offsets",
    "offsets_of",
    "details",
    "evaluate",
    "cv_positions",
    "cv_uv",
    "surface_normals",
    "patch_cvs",
    "closed_ends",
    "pole_of",
    "pole_ring",
    "pole_patches",
    "storage_size",
    "HierarchyArrays",
    "to_arrays",
    "from_arrays",
]

_I4 = np.arange(4)


@dataclass(frozen=True)
class Level:
    """The sparse content of one hierarchy level ``k >= 1``.

    Attributes
    ----------
    k : int
        The level.
    patches : (m,) int64
        Sorted keys of the active (refined) patches.
    cv_keys : (c,) int64
        Sorted keys of the CVs present (union of the active patches' 4×4 blocks).
    offsets : (c, 3) float64
        Offset of each CV in the local frame of level ``k-1``; zero where not movable.
    movable : (c,) bool
        C2 rule: every existing patch of the CV's support is active.
    patch_rows : (m, 4, 4) int64
        For each active patch, the rows (into ``cv_keys``) of its CVs ``[a, b]`` =
        ``(pu + a, pv + b)``.
    """

    k: int
    patches: np.ndarray
    cv_keys: np.ndarray
    offsets: np.ndarray
    movable: np.ndarray
    patch_rows: np.ndarray


@dataclass(frozen=True)
class HSpline:
    """A hierarchical B-spline surface: level-0 grid plus sparse finer levels.

    Attributes
    ----------
    cvs : (nu, nv, 3) float64
        Level-0 control vertices, ``cvs[i, j]`` with ``i`` along u (USD ``acra:cvs`` index
        ``j * nu + i``).
    u, v : Direction
        Level-0 CV count and wrap of each direction.
    depth : int
        Number of levels the object may use (levels ``0 .. depth-1``; contract ``acra:levels``).
    fine : tuple[Level, ...]
        ``fine[k - 1]`` is level ``k``; always ``depth - 1`` entries (possibly empty).
    """

    cvs: np.ndarray
    u: Direction
    v: Direction
    depth: int
    fine: tuple[Level, ...]

    @cached_property
    def _terms_index(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What `evaluate` looks patches up in, built once per surface: the levels it visits
        ``(L,) int64`` (0, then each level with a movable CV); every visited fine level's active
        patch keys plus that level's shift past all coarser levels' keys ``(p,) int64`` (sorted,
        so one `np.searchsorted` finds a point's patch on every level); the shifts ``(L-1,)
        int64``; where each fine level's keys end ``(L-1,) int64``; and each patch's CV block as
        rows of the table ``[level-0 CVs; level-1 detail vectors; ...]`` ``(p, 4, 4) int64``."""
        levels, keys, shifts, ends, rows = [0], [], [], [], []
        shift, base = 0, self.u.n * self.v.n
        for lev in self.fine:
            if lev.patches.size and np.any(lev.movable):
                levels.append(lev.k)
                keys.append(lev.patches + shift)
                shifts.append(shift)
                ends.append((ends[-1] if ends else 0) + lev.patches.size)
                rows.append(lev.patch_rows + base)
            shift += self.u.patches(lev.k) * self.v.patches(lev.k)
            base += lev.cv_keys.size
        cat = lambda xs, shape: np.concatenate(xs) if xs else np.zeros(shape, np.int64)  # noqa: E731
        ints = lambda xs: np.array(xs, np.int64)  # noqa: E731
        return ints(levels), cat(keys, (0,)), ints(shifts), ints(ends), cat(rows, (0, 4, 4))

    def level(self, k: int) -> Level:
        if not 1 <= k < self.depth:
            raise IndexError(f"level {k} outside 1..{self.depth - 1}")
        return self.fine[k - 1]

    @property
    def domain(self) -> tuple[float, float]:
        """Parameter extent ``(P0u, P0v)`` in level-0 patch units."""
        return float(self.u.patches0), float(self.v.patches0)

    def size(self) -> float:
        """Object size: the diagonal of the level-0 control net's bounding box."""
        pts = self.cvs.reshape(-1, 3)
        return float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))


@dataclass(frozen=True)
class Details:
    """World-space detail vectors of every fine level, for one configuration.

    Attributes
    ----------
    vectors : tuple of (c_k, 3) float64
        ``F_j @ offset_j`` per CV of level ``k`` (zero for non-movable CVs); entry ``k - 1``.
    frames : tuple of (c_k, 3, 3) float64
        Local frame of each CV, columns ``(e_u, e_v, n)`` of level ``k-1`` at the CV centre; the
        CVs of a pole ring (`pole_ring`) take their end's one normal (`_end_normal`).
    """

    vectors: tuple[np.ndarray, ...]
    frames: tuple[np.ndarray, ...]

    @cached_property
    def table(self) -> np.ndarray:
        """Every level's detail vectors stacked ``(sum c_k, 3)``, in level order."""
        return np.concatenate(self.vectors) if self.vectors else np.zeros((0, 3))


@dataclass(frozen=True)
class SurfaceEval:
    """Surface points and partial derivatives (with respect to level-0 ``u``, ``v``).

    Each field is ``(m, 3) float64`` or ``None`` when not requested.
    """

    points: np.ndarray
    du: np.ndarray | None = None
    dv: np.ndarray | None = None
    duu: np.ndarray | None = None
    duv: np.ndarray | None = None
    dvv: np.ndarray | None = None


# --------------------------------------------------------------------------------------------
# construction and refinement


def _empty_level(k: int) -> Level:
    return Level(
        k=k,
        patches=np.zeros(0, np.int64),
        cv_keys=np.zeros(0, np.int64),
        offsets=np.zeros((0, 3)),
        movable=np.zeros(0, bool),
        patch_rows=np.zeros((0, 4, 4), np.int64),
    )


def from_grid(cvs: np.ndarray, u_periodic: bool = False, v_periodic: bool = False, depth: int = 1) -> HSpline:
    """An H-spline with only its level-0 grid.

    Parameters
    ----------
    cvs : (nu, nv, 3) float64
        Level-0 control vertices.
    depth : int
        Levels the object may use (``>= 1``).
    """
    cvs = np.ascontiguousarray(cvs, dtype=np.float64)
    if cvs.ndim != 3 or cvs.shape[2] != 3:
        raise ValueError(f"cvs must have shape (nu, nv, 3), got {cvs.shape}")
    if depth < 1:
        raise ValueError(f"depth must be at least 1, got {depth}")
    u = Direction(cvs.shape[0], bool(u_periodic))
    v = Direction(cvs.shape[1], bool(v_periodic))
    return HSpline(cvs=cvs, u=u, v=v, depth=int(depth), fine=tuple(_empty_level(k) for k in range(1, depth)))


def _patch_keys(hs: HSpline, k: int, pu: np.ndarray, pv: np.ndarray) -> np.ndarray:
    return pu * hs.v.patches(k) + pv


def _cv_keys(hs: HSpline, k: int, ju: np.ndarray, jv: np.ndarray) -> np.ndarray:
    return ju * hs.v.cvs(k) + jv


def _split_patch(hs: HSpline, k: int, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    npv = hs.v.patches(k)
    return keys // npv, keys % npv


def _split_cv(hs: HSpline, k: int, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ncv = hs.v.cvs(k)
    return keys // ncv, keys % ncv


def _lookup(sorted_keys: np.ndarray, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows of ``keys`` in ``sorted_keys`` and whether each was found."""
    if sorted_keys.size == 0:
        return np.zeros(keys.shape, np.int64), np.zeros(keys.shape, bool)
    rows = np.searchsorted(sorted_keys, keys)
    rows = np.minimum(rows, sorted_keys.size - 1)
    return rows, sorted_keys[rows] == keys


def _valid_patches(hs: HSpline, k: int, pu: np.ndarray, pv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ok = hs.u.patch_valid(pu, k) & hs.v.patch_valid(pv, k)
    return hs.u.wrap_patch(pu, k), hs.v.wrap_patch(pv, k), ok


def _build_level(hs: HSpline, k: int, patches: np.ndarray, old: Level) -> Level:
    """Level ``k`` with the given active patch keys; keeps the offsets ``old`` had."""
    patches = np.unique(patches)
    pu, pv = _split_patch(hs, k, patches)
    ju = hs.u.wrap_cv(pu[:, None] + _I4[None, :], k)  # (m, 4)
    jv = hs.v.wrap_cv(pv[:, None] + _I4[None, :], k)
    block = _cv_keys(hs, k, ju[:, :, None], jv[:, None, :])  # (m, 4, 4)
    cv_keys, inverse = np.unique(block.reshape(-1), return_inverse=True)
    patch_rows = inverse.reshape(-1, 4, 4).astype(np.int64)

    # movable: all existing support patches (ju-3..ju) x (jv-3..jv) active
    cu, cv = _split_cv(hs, k, cv_keys)
    su = cu[:, None] - 3 + _I4[None, :]  # (c, 4)
    sv = cv[:, None] - 3 + _I4[None, :]
    su_w, sv_w = hs.u.wrap_patch(su, k), hs.v.wrap_patch(sv, k)
    ok_u, ok_v = hs.u.patch_valid(su, k), hs.v.patch_valid(sv, k)
    skeys = _patch_keys(hs, k, su_w[:, :, None], sv_w[:, None, :])
    _, found = _lookup(patches, skeys)
    exists = ok_u[:, :, None] & ok_v[:, None, :]
    movable = np.all(found | ~exists, axis=(1, 2))

    offsets = np.zeros((cv_keys.size, 3))
    if old.cv_keys.size:
        rows, hit = _lookup(old.cv_keys, cv_keys)
        offsets[hit] = old.offsets[rows[hit]]
    if np.any(offsets[~movable] != 0.0):
        raise ValueError(f"level {k}: refinement would leave offsets on CVs that are not free to move")
    return Level(k=k, patches=patches, cv_keys=cv_keys, offsets=offsets, movable=movable, patch_rows=patch_rows)


def refine(hs: HSpline, k: int, patches: np.ndarray) -> HSpline:
    """Activate level-``k`` patches (and their ancestors) by binary subdivision.

    Creates only the CVs of the new patches, with zero offsets: the surface is unchanged.

    Parameters
    ----------
    patches : (m, 2) int64
        ``(pu, pv)`` at level ``k``; periodic directions wrap, patches outside an open domain
        are ignored.
    """
    patches = np.asarray(patches, dtype=np.int64).reshape(-1, 2)
    if not 1 <= k < hs.depth:
        raise ValueError(f"cannot refine to level {k}: the object has levels 0..{hs.depth - 1}")
    fine = list(hs.fine)
    pu, pv = patches[:, 0], patches[:, 1]
    for level in range(k, 0, -1):
        wu, wv, ok = _valid_patches(hs, level, pu, pv)
        keys = _patch_keys(hs, level, wu[ok], wv[ok])
        old = fine[level - 1]
        if keys.size and not np.all(_lookup(old.patches, keys)[1]):
            fine[level - 1] = _build_level(hs, level, np.concatenate([old.patches, keys]), old)
        pu, pv = wu[ok] >> 1, wv[ok] >> 1
    return replace(hs, fine=tuple(fine))


def make_movable(hs: HSpline, k: int, patches: np.ndarray) -> HSpline:
    """Refine so that every CV of the given level-``k`` patches is movable (thesis §3.4).

    A CV ``j`` is supported on patches ``j-3 .. j``, so patch ``p``'s CVs need the 7×7 block of
    patches ``p-3 .. p+3`` active (clipped at an open border).

    Parameters
    ----------
    patches : (m, 2) int64
        ``(pu, pv)`` at level ``k``.
    """
    if k == 0:
        return hs
    patches = np.asarray(patches, dtype=np.int64).reshape(-1, 2)
    d = np.arange(-3, 4)
    pu = (patches[:, 0, None, None] + d[None, :, None]) + 0 * d[None, None, :]
    pv = (patches[:, 1, None, None] + 0 * d[None, :, None]) + d[None, None, :]
    return refine(hs, k, np.stack([pu.reshape(-1), pv.reshape(-1)], axis=1))


def set_offsets(hs: HSpline, k: int, cvs_uv: np.ndarray, offsets: np.ndarray, add: bool = False) -> HSpline:
    """Set (or add to) the local-frame offsets of level-``k`` CVs.

    Parameters
    ----------
    cvs_uv : (c, 2) int64
        CV indices ``(ju, jv)`` at level ``k`` (periodic directions wrap).
    offsets : (c, 3) float64
        Offsets in each CV's local frame ``(e_u, e_v, n)``.

    Raises ``ValueError`` if a CV is absent or not movable (C2 rule).
    """
    lev = hs.level(k)
    cvs_uv = np.asarray(cvs_uv, dtype=np.int64).reshape(-1, 2)
    offsets = np.asarray(offsets, dtype=np.float64).reshape(-1, 3)
    ju, jv = hs.u.wrap_cv(cvs_uv[:, 0], k), hs.v.wrap_cv(cvs_uv[:, 1], k)
    rows, found = _lookup(lev.cv_keys, _cv_keys(hs, k, ju, jv))
    if not np.all(found):
        bad = cvs_uv[~found][0]
        raise ValueError(f"level {k}: CV {tuple(int(x) for x in bad)} does not exist (refine its patches first)")
    if not np.all(lev.movable[rows]):
        bad = cvs_uv[~lev.movable[rows]][0]
        raise ValueError(f"level {k}: CV {tuple(int(x) for x in bad)} is not free to move (C2 rule at a refined-region border)")
    new = lev.offsets.copy()
    if add:
        np.add.at(new, rows, offsets)
    else:
        new[rows] = offsets
    fine = list(hs.fine)
    fine[k - 1] = replace(lev, offsets=new)
    return replace(hs, fine=tuple(fine))


def offsets_of(hs: HSpline, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Movable CVs of level ``k`` with their offsets: ``(c, 2) int64`` indices, ``(c, 3)``."""
    lev = hs.level(k)
    ju, jv = _split_cv(hs, k, lev.cv_keys[lev.movable])
    return np.stack([ju, jv], axis=1), lev.offsets[lev.movable]


def cv_uv(hs: HSpline, k: int, keys: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Parameter centres ``(u, v)`` (level-0 units) of level-``k`` CVs (all present by default)."""
    keys = hs.level(k).cv_keys if keys is None else keys
    ju, jv = _split_cv(hs, k, keys)
    return hs.u.greville(ju, k), hs.v.greville(jv, k)


def patch_cvs(hs: HSpline, k: int, patches: np.ndarray) -> np.ndarray:
    """CV indices ``(ju, jv)`` of level-``k`` patches: ``(m, 4, 4, 2) int64`` (wrapped)."""
    patches = np.asarray(patches, dtype=np.int64).reshape(-1, 2)
    ju = hs.u.wrap_cv(patches[:, 0, None] + _I4[None, :], k)
    jv = hs.v.wrap_cv(patches[:, 1, None] + _I4[None, :], k)
    return np.stack(np.broadcast_arrays(ju[:, :, None], jv[:, None, :]), axis=-1)


# --------------------------------------------------------------------------------------------
# poles: an end of the open direction that closes to one point


def closed_ends(hs: HSpline) -> tuple[tuple[int, int], ...]:
    """Ends of an open direction that close to a point: a pole (`acra.shapes.sphere`) or a
    collapsed edge of an open grid (a fan's apex, degenerate triangular patches).

    The surface at an end is ``(R0 + 4 R1 + R2) / 6`` blended along the other direction, with
    ``R0..R2`` its three outermost CV rows; it is one point when that sum is the same all along
    (within 1e-6 of the size, which covers float32 ``acra:cvs``), whether the other direction is
    periodic (a pole) or open (a collapsed edge): in both, every parameter along the end names the
    same point, and a response must keep it one point. Returns ``(axis, end)`` pairs: axis 0 = u,
    1 = v; end 0 at parameter 0, 1 at ``P0``.
    """
    out, tol = [], 1e-6 * hs.size()
    for axis, d in ((0, hs.u), (1, hs.v)):
        if d.periodic:
            continue
        grid = hs.cvs if axis == 1 else hs.cvs.transpose(1, 0, 2)  # (other, this, 3)
        m = grid.shape[1]
        for end, (e0, e1, e2) in enumerate(((0, 1, 2), (m - 1, m - 2, m - 3))):
            if m >= 5 and np.ptp(grid[:, e0] + 4.0 * grid[:, e1] + grid[:, e2], axis=0).max() <= tol:
                out.append((axis, end))
    return tuple(out)


def pole_of(hs: HSpline, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Index into `closed_ends` of the pole each point ``(u, v) (K,)`` sits on, or -1.

    A point is on a pole when its open parameter is within 1e-9 of a closed end: there every
    value of the periodic parameter names the same surface point, so the parameter a projection
    returns is arbitrary and anything weighted by it must not depend on it."""
    out = np.full(np.size(u), -1, np.int64)
    for i, (axis, end) in enumerate(closed_ends(hs)):
        d = hs.u if axis == 0 else hs.v
        x = np.atleast_1d(np.asarray(u if axis == 0 else v, np.float64))
        out[np.abs(x - end * d.patches0) <= 1e-9 * d.patches0] = i
    return out


def _end_rows(count: int, end: int) -> np.ndarray:
    """The three outermost of ``count`` rows at ``end`` (0: first, 1: last), outermost first."""
    return np.array([0, 1, 2]) if end == 0 else count - 1 - np.array([0, 1, 2])


def pole_ring(hs: HSpline, k: int, axis: int, end: int) -> tuple[np.ndarray, np.ndarray]:
    """The level-``k`` CVs that make a pole: ``keys (N, 3) int64`` (one column of three rows per
    periodic index ``0..N-1``, outermost row first) and ``weights (3,)``, the basis of the three
    rows at the end (1/6, 4/6, 1/6). The pole point is ``sum_j B_j(s) (weights @ rows_j)``, the
    same for every ``s`` iff ``weights @ rows_j`` is the same for every column ``j``."""
    per, opn = (hs.v, hs.u) if axis == 0 else (hs.u, hs.v)
    rows = _end_rows(opn.cvs(k), end)
    j = np.arange(per.cvs(k))[:, None]
    ju, jv = np.broadcast_arrays(rows[None, :], j) if axis == 0 else np.broadcast_arrays(j, rows[None, :])
    return _cv_keys(hs, k, ju, jv), np.array([1.0, 4.0, 1.0]) / 6.0


def pole_patches(hs: HSpline, k: int, axis: int, end: int) -> np.ndarray:
    """Level-``k`` patches ``(3 N, 2) int64`` whose activation makes the whole `pole_ring` movable:
    the three patch rows at the end, all around (a ring CV's support reaches three patches in)."""
    per, opn = (hs.v, hs.u) if axis == 0 else (hs.u, hs.v)
    rows = _end_rows(opn.patches(k), end)
    p = np.arange(per.patches(k))
    a, b = np.meshgrid(rows, p, indexing="ij") if axis == 0 else np.meshgrid(p, rows, indexing="ij")
    return np.stack([a.reshape(-1), b.reshape(-1)], axis=1).astype(np.int64)


def storage_size(hs: HSpline) -> int:
    """Total CVs stored: the level-0 grid plus every present fine CV."""
    return int(hs.cvs.shape[0] * hs.cvs.shape[1] + sum(lev.cv_keys.size for lev in hs.fine))


# --------------------------------------------------------------------------------------------
# evaluation

# (a, b): derivative orders along u and v of each output slot, in SurfaceEval's field order
_SLOTS = ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))
_NSLOTS = {0: 1, 1: 3, 2: 6}
def _segments(d: Direction, x: np.ndarray, k: int, side: int) -> tuple[np.ndarray, np.ndarray]:
    """Level-``k`` segment and local parameter of ``x``; ``side < 0`` takes a point on an
    interior knot from the segment on its left."""
    seg, t = locate(d, x, k)
    if side < 0:
        on_knot = (t == 0.0) & ((seg > 0) | d.periodic)
        seg = d.wrap_patch(np.where(on_knot, seg - 1, seg), k)
        t = np.where(on_knot, 1.0, t)
    return seg, t


def _rows(t: np.ndarray, scale: np.ndarray, order: int) -> np.ndarray:
    """Basis rows of derivative orders ``0..order`` w.r.t. level-0 units: ``(m, order+1, 4)``;
    ``scale (m,)`` is ``2**k`` of each point's level (d/dx = 2**k d/dt)."""
    rows = basis_all(t, order).transpose(1, 0, 2)
    for o in range(1, order + 1):
        rows[:, o] *= (scale**o)[:, None]
    return rows


def evaluate(
    hs: HSpline,
    u: np.ndarray,
    v: np.ndarray,
    order: int = 0,
    det: Details | None = None,
    upto: int | None = None,
    side: int = 0,
) -> SurfaceEval:
    """Points (and partial derivatives) of the surface at parameters ``(u, v)``.

    The sum over levels of the module docstring: each point takes level 0's patch and every
    finer level's active patch under it; all those (point, level) terms are gathered first and
    contracted with their 4×4 CV blocks in one batch, so the cost is a few array operations per
    level plus one tensor product per term.

    Parameters
    ----------
    u, v : (m,) float64
        Parameters in level-0 patch units (``[0, P0]``; periodic directions wrap).
    order : int
        0: points; 1: plus ``du, dv``; 2: plus ``duu, duv, dvv``.
    det : Details, optional
        Precomputed `details(hs)`; computed if omitted.
    upto : int, optional
        Evaluate only levels ``0..upto`` (the coarser surface a level's frames refer to).
    side : int
        ``-1`` evaluates points on an interior knot from the segment on their left (one-sided
        derivatives); ``0`` from the right.
    """
    u = np.atleast_1d(np.asarray(u, dtype=np.float64))
    v = np.atleast_1d(np.asarray(v, dtype=np.float64))
    top = hs.depth - 1 if upto is None else min(upto, hs.depth - 1)
    if top >= 1 and det is None:
        det = details(hs, upto=top)
    m = u.size
    levels, keys, shifts, ends, patch_rows = hs._terms_index
    used = int(np.searchsorted(levels, top, side="right"))  # levels 0 and the fine ones up to top
    levels = levels[:used]

    # every visited level's segment and local parameter of every point at once (`locate`)
    su, tu = _segments_all(hs.u, u, levels, side)
    sv, tv = _segments_all(hs.v, v, levels, side)
    iu = hs.u.wrap_cv(su[0][:, None] + _I4, 0)
    iv = hs.v.wrap_cv(sv[0][:, None] + _I4, 0)
    rows0 = iu[:, :, None] * hs.v.n + iv[:, None, :]
    if used > 1:
        # the (point, fine level) terms: the point's level-k patch is active; found in level order
        npv = (hs.v.patches0 << levels[1:])[:, None]
        want = su[1:] * npv + sv[1:] + shifts[: used - 1, None]  # (L-1, m) shifted keys
        live = keys[: ends[used - 2]]
        pos = np.minimum(np.searchsorted(live, want), max(live.size - 1, 0))
        lvl, pts = np.nonzero(live[pos] == want) if live.size else (np.zeros(0, np.int64),) * 2
        lvl = lvl + 1
        tus, tvs = np.concatenate([tu[0], tu[lvl, pts]]), np.concatenate([tv[0], tv[lvl, pts]])
        scale = np.concatenate([np.ones(m), np.ldexp(1.0, levels[lvl])])
        rows = np.concatenate([rows0, patch_rows[pos[lvl - 1, pts]]])
        table = np.concatenate([hs.cvs.reshape(-1, 3), det.table])
    else:
        pts = np.zeros(0, np.int64)
        tus, tvs, scale, rows, table = tu[0], tv[0], np.ones(m), rows0, hs.cvs.reshape(-1, 3)
    ru = _rows(tus, scale, order)  # (n, o, 4)
    rv = _rows(tvs, scale, order)
    block = np.take(table, rows, axis=0)  # (n, 4 a, 4 b, 3 c)

    # tensor products as batched matrix products: sum_b rv[o, b] block[a, b, c] -> (n, a, o, c),
    # then sum_a ru[p, a] (...) -> (n, p, o, c)
    n, o = block.shape[0], order + 1
    half = rv[:, None] @ block
    terms = (ru @ half.reshape(n, 4, 3 * o)).reshape(n, o, o, 3)

    # level 0 plus each fine term, added in level order (the terms are sorted by level)
    acc = terms[:m].copy()
    if len(pts):
        np.add.at(acc, pts, terms[m:])
    names = ["points", "du", "dv", "duu", "duv", "dvv"][: _NSLOTS[order]]
    return SurfaceEval(**{name: acc[:, a, b] for name, (a, b) in zip(names, _SLOTS)})


def _segments_all(d: Direction, x: np.ndarray, levels: np.ndarray, side: int) -> tuple[np.ndarray, np.ndarray]:
    """`_segments` of ``x (m,)`` on each of ``levels (L,)``: ``(L, m) int64`` and ``(L, m)``."""
    scale = np.ldexp(1.0, levels)[:, None]
    count = (d.patches0 << levels)[:, None]
    xs = x[None] * scale
    xs = np.mod(xs, count) if d.periodic else np.clip(xs, 0.0, count.astype(np.float64))
    seg = np.minimum(np.floor(xs).astype(np.int64), count - 1)  # mod can round up to count
    t = xs - seg
    if side < 0:
        on_knot = (t == 0.0) & ((seg > 0) | d.periodic)
        seg = np.where(on_knot, seg - 1, seg)
        seg = np.mod(seg, count) if d.periodic else seg
        t = np.where(on_knot, 1.0, t)
    return seg, t


def _degenerate(ev: SurfaceEval, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Cross products ``du × dv`` and where they are too small to give a direction: where a
    tangent (times the sine between them) is under 1e-6 of the object's size, the resolution at
    which float32 ``acra:cvs`` keep a pole one point; there ``du × dv`` is rounding noise."""
    n = np.cross(ev.du, ev.dv)
    longest = np.maximum(np.linalg.norm(ev.du, axis=1), np.linalg.norm(ev.dv, axis=1))
    return n, np.linalg.norm(n, axis=1) <= 1e-6 * max(scale, 1e-300) * longest + 1e-12 * max(scale, 1e-300) ** 2


def _nudged(hs: HSpline, u: np.ndarray, v: np.ndarray, amount: float) -> tuple[np.ndarray, np.ndarray]:
    """Parameters moved toward the centre of their level-0 patch by ``amount`` of the way."""
    out = []
    for d, x in ((hs.u, u), (hs.v, v)):
        seg, t = locate(d, x, 0)
        out.append(seg + t + amount * (0.5 - t))
    return out[0], out[1]


def surface_normals(
    hs: HSpline,
    u: np.ndarray,
    v: np.ndarray,
    det: Details | None = None,
    upto: int | None = None,
    ev: SurfaceEval | None = None,
) -> tuple[SurfaceEval, np.ndarray]:
    """First-order evaluation plus unit normals that are finite everywhere.

    Where ``du × dv`` vanishes (a pole, a collapsed edge) the normal is the limit taken from
    inside the patch: the derivative of ``du × dv`` toward the patch centre (exact when one
    tangent vanishes linearly); where that vanishes too, the point is nudged toward its patch
    centre by growing amounts until the cross product has a direction (acra-notes §1).

    Returns
    -------
    ev : SurfaceEval (order 1)
    normals : (m, 3) float64, unit length
    """
    u = np.atleast_1d(np.asarray(u, dtype=np.float64))
    v = np.atleast_1d(np.asarray(v, dtype=np.float64))
    ev = evaluate(hs, u, v, order=1, det=det, upto=upto) if ev is None else ev
    scale = hs.size()
    n, bad = _degenerate(ev, scale)
    if np.any(bad):
        # first-order Taylor term of du × dv along the direction toward the patch centre:
        # exact limit where du or dv vanishes linearly (a pole, a collapsed edge)
        idx = np.nonzero(bad)[0]
        e2 = evaluate(hs, u[idx], v[idx], order=2, det=det, upto=upto)
        su = np.sign(0.5 - locate(hs.u, u[idx], 0)[1])[:, None]
        sv = np.sign(0.5 - locate(hs.v, v[idx], 0)[1])[:, None]
        c_u = np.cross(e2.duu, e2.dv) + np.cross(e2.du, e2.duv)
        c_v = np.cross(e2.duv, e2.dv) + np.cross(e2.du, e2.dvv)
        nf = su * c_u + sv * c_v
        ok = np.linalg.norm(nf, axis=1) > 1e-9 * scale**2
        n[idx[ok]] = nf[ok]
        bad[idx[ok]] = False
    for amount in (1e-3, 1e-2, 1e-1, 0.5):
        if not np.any(bad):
            break
        idx = np.nonzero(bad)[0]
        nu_, nv_ = _nudged(hs, u[idx], v[idx], amount)
        nf, still = _degenerate(evaluate(hs, nu_, nv_, order=1, det=det, upto=upto), scale)
        n[idx[~still]] = nf[~still]
        bad[idx[~still]] = False
    n[bad] = (0.0, 0.0, 1.0)
    return ev, n / np.linalg.norm(n, axis=1)[:, None]


def _frames(ev: SurfaceEval, normals: np.ndarray) -> np.ndarray:
    """Orthonormal frames ``(m, 3, 3)``, columns ``(e_u, e_v, n)``."""
    n = normals
    t = ev.du - np.sum(ev.du * n, axis=1)[:, None] * n
    tl = np.linalg.norm(t, axis=1)
    weak = tl <= 1e-12 * (np.linalg.norm(ev.du, axis=1) + np.linalg.norm(ev.dv, axis=1) + 1e-300)
    if np.any(weak):  # du vanishes (pole): take the direction perpendicular to dv instead
        alt = np.cross(ev.dv[weak], n[weak])
        t[weak] = alt
        tl[weak] = np.linalg.norm(alt, axis=1)
    still = tl <= 1e-300
    if np.any(still):  # fully degenerate: any perpendicular of n
        pick = np.where(np.abs(n[still, 0:1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
        alt = pick - np.sum(pick * n[still], axis=1)[:, None] * n[still]
        t[still] = alt
        tl[still] = np.linalg.norm(alt, axis=1)
    e_u = t / tl[:, None]
    e_v = np.cross(n, e_u)
    return np.stack([e_u, e_v, n], axis=2)


def changed_patches(old: HSpline, new: HSpline, margin: int = 2) -> np.ndarray:
    """Level-0 patches ``(P0u, P0v) bool`` where ``new`` may differ from ``old`` (same grid).

    A changed level-``k`` CV ``j`` (level-0 row, or an offset that differs or is new and non-zero)
    moves level-``k`` patches ``j-3 .. j``, i.e. level-0 patches ``(j-3)>>k .. j>>k``; ``margin``
    more patches cover finer details whose frames follow the moved surface (their support reaches
    less than one level-0 patch beyond) and grid vertices on patch borders."""
    mask = np.zeros((new.u.patches0, new.v.patches0), bool)
    hits = [(0, *np.nonzero(np.any(old.cvs != new.cvs, axis=-1)))]
    for k in range(1, new.depth):
        b = new.level(k)
        hits.append((k, *_split_cv(new, k, b.cv_keys[_moved_cvs(old, new, k)])))
    for k, ju, jv in hits:
        if not len(ju):
            continue
        # (j - 3 + d) >> k for d = 0..3 covers every level-0 patch of j's support; the interval
        # always meets the domain, so clipping (open) or wrapping (periodic) loses nothing
        for du in range(4):
            qu = (ju - 3 + du) >> k
            qu = np.mod(qu, new.u.patches0) if new.u.periodic else np.clip(qu, 0, new.u.patches0 - 1)
            for dv in range(4):
                qv = (jv - 3 + dv) >> k
                qv = np.mod(qv, new.v.patches0) if new.v.periodic else np.clip(qv, 0, new.v.patches0 - 1)
                mask[qu, qv] = True
    for axis, d in ((0, new.u), (1, new.v)):
        mask = _dilate(mask, margin, axis, d.periodic)
    return mask


def _dilate(mask: np.ndarray, m: int, axis: int, periodic: bool) -> np.ndarray:
    """``mask`` grown by ``m`` cells both ways along ``axis`` (wrapping if ``periodic``)."""
    out = mask.copy()
    for s in range(1, m + 1):
        if periodic:
            out |= np.roll(mask, s, axis) | np.roll(mask, -s, axis)
            continue
        a = np.moveaxis(out, axis, 0)
        b = np.moveaxis(mask, axis, 0)
        a[s:] |= b[:-s]
        a[:-s] |= b[s:]
    return out


def details(hs: HSpline, upto: int | None = None,
            since: "tuple[HSpline, Details, np.ndarray] | None" = None) -> Details:
    """World detail vectors of levels ``1..upto``, computed coarse to fine.

    The frame of a level-``k`` CV is taken on the surface of levels ``0..k-1`` at the CV's
    parameter centre, so moving a coarse CV carries finer detail along (thesis Fig. 3.10); the
    CVs of a pole ring at a closed end all take the end's one normal (`_end_normal`), since the
    one tangent vanishes at a closed end, so per-CV normals there turn by tens of degrees under
    coarse bumps far below the tolerance and would turn the ring's detail with them
    (docs/algorithm.md, Closed ends).
    ``since = (old, old_details, stale)``: ``hs`` differs from ``old`` only on the level-0
    patches ``stale (P0u, P0v) bool`` (`changed_patches`, whose margin covers the frames that
    follow a moved surface) and by refinement. A CV ``old`` had movable keeps its frame if its
    level is no finer than the coarsest level that moved (its frame's surface is unchanged) or if
    it is centred off ``stale`` (a ring CV: if its end is off ``stale`` all along); only the
    others, and CVs refinement added, are evaluated. A
    response is local and a refinement moves nothing, so this skips most of the work.
    """
    top = hs.depth - 1 if upto is None else min(upto, hs.depth - 1)
    first = _first_moved(since[0], hs) if since is not None else 0
    ends = closed_ends(hs) if top >= 1 else ()
    vectors: list[np.ndarray] = []
    frames: list[np.ndarray] = []
    for k in range(1, top + 1):
        lev = hs.fine[k - 1]
        c = lev.cv_keys.size
        vec = np.zeros((c, 3))
        fr = np.zeros((c, 3, 3))
        rows = np.nonzero(lev.movable)[0] if c else np.zeros(0, np.int64)
        ring = _ring_members(hs, k, ends, rows)  # (len(rows),) int64: closed end of each row, or -1
        if rows.size and since is not None and k - 1 < len(since[1].frames):
            old, old_det, stale = since
            was = old.fine[k - 1]
            orow, found = _lookup(was.cv_keys, lev.cv_keys[rows])
            found &= was.movable[orow] if was.cv_keys.size else False
            fr[rows[found]] = old_det.frames[k - 1][orow[found]]
            if k > first:  # the surface under this level's frames moved on the stale patches
                gu, gv = cv_uv(hs, k, lev.cv_keys[rows])
                pu = np.mod(np.floor(gu), hs.u.patches0) if hs.u.periodic else np.clip(np.floor(gu), 0, hs.u.patches0 - 1)
                pv = np.mod(np.floor(gv), hs.v.patches0) if hs.v.periodic else np.clip(np.floor(gv), 0, hs.v.patches0 - 1)
                found &= ~stale[pu.astype(np.int64), pv.astype(np.int64)]
                # a ring's frames depend on the surface all along its end (`_end_normal`)
                found &= (ring < 0) | ~_ends_stale(hs, ends, stale)[np.maximum(ring, 0)]
            vec[rows] = np.einsum("mij,mj->mi", fr[rows], lev.offsets[rows])  # offsets may have moved
            rows, ring = rows[~found], ring[~found]
        if rows.size:
            gu, gv = cv_uv(hs, k, lev.cv_keys[rows])
            partial = Details(tuple(vectors), tuple(frames))
            ev, n = surface_normals(hs, gu, gv, det=partial, upto=k - 1)
            for i, (axis, end) in enumerate(ends):
                if np.any(ring == i):
                    n_end = _end_normal(hs, k, axis, end, partial)
                    if n_end is not None:
                        n[ring == i] = n_end
            f = _frames(ev, n)
            fr[rows] = f
            vec[rows] = np.einsum("mij,mj->mi", f, lev.offsets[rows])
        vectors.append(vec)
        frames.append(fr)
    return Details(tuple(vectors), tuple(frames))


def _ring_members(hs: HSpline, k: int, ends: tuple[tuple[int, int], ...], rows: np.ndarray) -> np.ndarray:
    """For level-``k`` CV ``rows (m,) int64``: the index into ``ends`` (`closed_ends`) of the pole
    ring (`pole_ring`: the three CV rows at the end, all along it) each belongs to, or -1, as
    ``(m,) int64``."""
    out = np.full(rows.size, -1, np.int64)
    if not ends or not rows.size:
        return out
    ju, jv = _split_cv(hs, k, hs.level(k).cv_keys[rows])
    for i, (axis, end) in enumerate(ends):
        j, d = (ju, hs.u) if axis == 0 else (jv, hs.v)
        out[np.isin(j, _end_rows(d.cvs(k), end))] = i
    return out


def _ends_stale(hs: HSpline, ends: tuple[tuple[int, int], ...], stale: np.ndarray) -> np.ndarray:
    """Whether the surface moved anywhere along each closed end: ``(len(ends),) bool``, from the
    level-0 patches ``stale (P0u, P0v) bool`` (`changed_patches`)."""
    out = np.zeros(max(len(ends), 1), bool)
    for i, (axis, end) in enumerate(ends):
        row = stale[-end if end else 0] if axis == 0 else stale[:, -end if end else 0]
        out[i] = bool(row.any())
    return out


def _end_normal(hs: HSpline, k: int, axis: int, end: int, det: Details) -> np.ndarray | None:
    """The one normal ``(3,) float64`` that every CV of level ``k``'s ring at a closed end frames
    its detail with: the mean of the limit normals of the surface of levels ``0..k-1`` along the
    end (2 per level-``k`` patch), normalised.

    A ring's CVs shape the end point and the surface within a level-``k`` patch of it. The per-CV
    normals there are the worst conditioned on the surface: along a collapsed end one tangent
    vanishes, so a bump far below the tolerance across the short direction turns them by tens of
    degrees, and a fan apex that a response bent into a cone has a different limit normal for
    every parameter along it (measured on hard case 10b, levels 0-2: the level-1 surface's normals
    within a level-2 patch of the apex spread 63 degrees after two rounds, and level 2's detail,
    0.06 long, turned sideways by up to 0.05 and folded the fan, display normal z -0.89). One
    normal per ring turns the ring's detail together. For a pole with a tangent plane (a sphere)
    it is that plane's normal. ``None`` where the limit normals cancel (no side is favoured):
    the CVs then keep their own."""
    other = hs.v if axis == 0 else hs.u
    m = 2 * other.patches(k)
    s = np.arange(m) * other.patches0 / m if other.periodic else np.linspace(0.0, other.patches0, m + 1)
    at = np.full_like(s, end * (hs.u if axis == 0 else hs.v).patches0)
    u, v = (at, s) if axis == 0 else (s, at)
    n = surface_normals(hs, u, v, det=det, upto=k - 1)[1].mean(axis=0)
    length = np.linalg.norm(n)
    return n / length if length > 1e-6 else None


def _first_moved(old: HSpline, new: HSpline) -> int:
    """The coarsest level whose CVs differ between ``old`` and ``new`` (``depth`` if none):
    a changed level-0 CV, or a level-``k`` offset that differs or is new and non-zero. Refinement
    alone (new CVs with zero offsets) moves nothing. Frames of levels ``<=`` it are unchanged."""
    if old.cvs.shape != new.cvs.shape or np.any(old.cvs != new.cvs):
        return 0
    for k in range(1, new.depth):
        if np.any(_moved_cvs(old, new, k)):
            return k
    return new.depth


def _moved_cvs(old: HSpline, new: HSpline, k: int) -> np.ndarray:
    """Which of ``new``'s level-``k`` CVs ``(c_k,) bool`` moved from ``old``: an offset that
    differs, or a new CV with a non-zero offset (a new CV with offset zero is a refinement)."""
    a, b = old.level(k), new.level(k)
    rows, found = _lookup(a.cv_keys, b.cv_keys)
    same = np.zeros(b.cv_keys.size, bool)
    same[found] = np.all(a.offsets[rows[found]] == b.offsets[found], axis=-1)
    return ~same & (found | np.any(b.offsets != 0, axis=-1))


def cv_positions(hs: HSpline, k: int, det: Details | None = None) -> np.ndarray:
    """Explicit positions (derived + offset) of the CVs present at level ``k``.

    Level 0 returns ``cvs`` reshaped ``(nu * nv, 3)`` in key order; level ``k >= 1`` returns
    ``(c_k, 3)`` aligned with ``level(k).cv_keys``, built by binary subdivision of level
    ``k-1`` (thesis Fig. 3.7) plus each CV's detail vector.
    """
    if k == 0:
        return hs.cvs.reshape(-1, 3).copy()
    det = details(hs, upto=k) if det is None else det
    return _cv_positions_from(hs, k, det, cv_positions(hs, k - 1, det))


def all_cv_positions(hs: HSpline, det: Details | None = None) -> list[np.ndarray]:
    """`cv_positions` of every level ``0 .. depth-1``, each level built once from the previous."""
    det = details(hs) if det is None and hs.depth > 1 else det
    out = [hs.cvs.reshape(-1, 3).copy()]
    for k in range(1, hs.depth):
        out.append(_cv_positions_from(hs, k, det, out[-1]))
    return out


def _cv_positions_from(hs: HSpline, k: int, det: Details, parent: np.ndarray) -> np.ndarray:
    """Level-``k`` CV positions from level ``k-1``'s ``parent`` positions (`cv_positions`)."""
    parent_keys = (np.arange(hs.u.n)[:, None] * hs.v.n + np.arange(hs.v.n)[None, :]).reshape(-1) if k == 1 else hs.level(k - 1).cv_keys
    lev = hs.level(k)
    ju, jv = _split_cv(hs, k, lev.cv_keys)
    iu, wu = refine_rows(hs.u, k - 1, ju)
    iv, wv = refine_rows(hs.v, k - 1, jv)
    pkeys = _cv_keys(hs, k - 1, iu[:, :, None], iv[:, None, :])  # (c, 3, 3)
    w = wu[:, :, None] * wv[:, None, :]
    rows, found = _lookup(parent_keys, pkeys)
    if not np.all(found | (w == 0.0)):
        raise AssertionError(f"level {k}: a derived CV needs a coarser CV that is not stored")
    derived = np.einsum("mab,mabc->mc", w, parent[rows])
    return derived + det.vectors[k - 1]


# --------------------------------------------------------------------------------------------
# plain-array form (what the pipeline stores in USD)


@dataclass(frozen=True)
class HierarchyArrays:
    """The fine levels of an H-spline as flat arrays (lossless, storage-sized).

    Attributes
    ----------
    patch_level : (m,) int32
        Level (``>= 1``) of each refined patch.
    patches : (m, 2) int32
        ``(pu, pv)`` of each refined patch at its level.
    offset_level : (c,) int32
        Level of each non-zero offset.
    offset_cvs : (c, 2) int32
        ``(ju, jv)`` of each offset CV at its level.
    offsets : (c, 3) float64
        Offsets in the CVs' local frames.
    """

    patch_level: np.ndarray
    patches: np.ndarray
    offset_level: np.ndarray
    offset_cvs: np.ndarray
    offsets: np.ndarray


def to_arrays(hs: HSpline) -> HierarchyArrays:
    """The fine levels as flat arrays; only refined patches and non-zero offsets are kept."""
    pl, pp, ol, oc, oo = [], [], [], [], []
    for lev in hs.fine:
        pu, pv = _split_patch(hs, lev.k, lev.patches)
        pl.append(np.full(pu.size, lev.k))
        pp.append(np.stack([pu, pv], axis=1))
        nz = np.any(lev.offsets != 0.0, axis=1)
        ju, jv = _split_cv(hs, lev.k, lev.cv_keys[nz])
        ol.append(np.full(ju.size, lev.k))
        oc.append(np.stack([ju, jv], axis=1))
        oo.append(lev.offsets[nz])
    cat = lambda xs, shape: np.concatenate(xs) if xs else np.zeros(shape)  # noqa: E731
    return HierarchyArrays(
        patch_level=cat(pl, (0,)).astype(np.int32),
        patches=cat(pp, (0, 2)).astype(np.int32).reshape(-1, 2),
        offset_level=cat(ol, (0,)).astype(np.int32),
        offset_cvs=cat(oc, (0, 2)).astype(np.int32).reshape(-1, 2),
        offsets=cat(oo, (0, 3)).astype(np.float64).reshape(-1, 3),
    )


def from_arrays(base: HSpline, arrays: HierarchyArrays) -> HSpline:
    """Rebuild the fine levels stored by `to_arrays` on top of a level-0-only ``base``.

    Raises ``ValueError`` naming the level and index when a patch or offset is out of range or
    an offset sits on a CV that the C2 rule keeps fixed.
    """
    hs = base
    levels = np.asarray(arrays.patch_level, dtype=np.int64)
    patches = np.asarray(arrays.patches, dtype=np.int64).reshape(-1, 2)
    for k in np.unique(levels):
        if not 1 <= k < hs.depth:
            raise ValueError(f"refined patch at level {k}, outside 1..{hs.depth - 1}")
        sel = patches[levels == k]
        for d, col, name in ((hs.u, 0, "u"), (hs.v, 1, "v")):
            bad = (sel[:, col] < 0) | (sel[:, col] >= d.patches(int(k)))
            if np.any(bad):
                raise ValueError(f"level {k}: patch index {int(sel[bad][0, col])} along {name} outside 0..{d.patches(int(k)) - 1}")
        hs = refine(hs, int(k), sel)
    olev = np.asarray(arrays.offset_level, dtype=np.int64)
    ocvs = np.asarray(arrays.offset_cvs, dtype=np.int64).reshape(-1, 2)
    offs = np.asarray(arrays.offsets, dtype=np.float64).reshape(-1, 3)
    for k in np.unique(olev):
        if not 1 <= k < hs.depth:
            raise ValueError(f"offset at level {k}, outside 1..{hs.depth - 1}")
        sel = olev == k
        hs = set_offsets(hs, int(k), ocvs[sel], offs[sel])
    return hs
