"""Hierarchical uniform bicubic B-spline surfaces (H-splines; Forsey & Bartels 1988, thesis §3.4):
evaluation, local frames and details.

The structure (levels, refinement, the C2 rule, offsets, the plain-array form) is
`acra.hierarchy`, and where two surfaces of one grid differ is `acra.changes`; every public name
of the first and the comparisons of the second are importable from here too, so ``from acra
import hspline`` gives the whole H-spline API.

Because subdivision reproduces the coarser surface exactly, the surface is

    Q(u, v) = Q0(u, v) + sum_{k>=1} sum_{movable j at level k} B_j^k(u, v) · F_j @ offset_j

and each level's sum vanishes outside its active region. `evaluate` uses this form (one sparse
B-spline sum per level); `cv_positions` builds the explicit hierarchy of derived + offset CVs,
and the tests check the two agree, which is the refinement-exactness property.

Evaluation and details live together because they need each other: a point's detail terms are
``F_j @ offset_j`` (`details`), and a level-``k`` frame ``F_j`` is the normal and tangent of the
surface of levels ``0..k-1`` (`surface_normals`, which evaluates it).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, fields
from functools import cached_property

import numpy as np

from . import changes, framekernels, hierarchy, kernels, levelkernels, memo
from .basis import Direction, basis_rows, locate, refine_rows
from .hierarchy import (  # noqa: F401  (re-exported; the key helpers are used by interpolate, respond, tessellate and tests)
    _I4,
    HierarchyArrays,
    HSpline,
    Level,
    _cv_keys,
    _end_rows,
    _lookup,
    _patch_keys,
    _split_cv,
    closed_ends,
    cv_uv,
    from_arrays,
    from_grid,
    make_movable,
    offsets_of,
    patch_cvs,
    pole_of,
    pole_patches,
    pole_ring,
    pole_ring_movable,
    pole_ring_rows,
    refine,
    refine_blocks,
    set_offsets,
    storage_size,
    to_arrays,
    with_cvs,
    with_fine,
    with_offsets,
)

from .changes import changed_cells, changed_patches, grown_patches, mark_moved  # noqa: F401  (re-exported)

# this module's own names, the comparisons of two surfaces (`acra.changes`) and the structure's
# (`acra.hierarchy`), re-exported
__all__ = ["Details", "SurfaceEval", "details", "moved_details", "keep_details", "evaluate", "eval_arrays", "cv_positions",
           "surface_normals", "changed_cells", "changed_patches", "grown_patches", "mark_moved",
           *hierarchy.__all__]


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


def _stacked(vectors: list, frames: list, table: np.ndarray) -> Details:
    """``Details(vectors, frames)`` with its `Details.table` given: ``table (sum c_k, 3) float64``
    already holds ``vectors`` stacked (`details` and `moved_details` write each level's rows as
    they finish it, so a level's frames, which evaluate the coarser levels, and the evaluations
    after a move read a prefix of one array instead of stacking the levels again)."""
    # the fields set directly: the frozen constructor sets one at a time through
    # ``object.__setattr__``, and a move's pass stacks a level's coarser details per level
    out = object.__new__(Details)
    out.__dict__.update(vectors=tuple(vectors), frames=tuple(frames), table=table)
    return out


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
    rows = basis_rows(t, order)
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
    finer level's active patch under it (`HSpline._terms_index`), summed point by point in
    compiled code (`acra.kernels.eval_points`; `_evaluate_numpy` is the same sum as array
    operations).

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

    A point with a NaN parameter (or an infinite one along a periodic direction) gets NaN.
    """
    if order not in (0, 1, 2):
        raise ValueError(f"derivative order must be 0, 1 or 2, got {order}")
    u, v = _flat(u), _flat(v)
    if u.size != v.size:
        raise ValueError(f"u and v must have the same size, got {u.size} and {v.size}")
    out = np.empty((_NSLOTS[order], u.size, 3))
    kernels.eval_points(u, v, int(order), int(side), *eval_arrays(hs, det, upto), out)
    return _surface_eval(out)


def eval_arrays(hs: HSpline, det: Details | None = None, upto: int | None = None) -> tuple:
    """`acra.kernels.eval_points`' arguments after the order and side, as `evaluate` passes them
    for ``det`` and ``upto``: ``(top, nu, u_periodic, nv, v_periodic, cvs, levels, keys, shifts,
    ends, patch_rows, table_rows, table)``, plain ints, bools and C-contiguous arrays, so one
    compiled signature serves every call (and compiled code that evaluates the surface itself,
    `acra.sides.behind`, sums what `evaluate` sums)."""
    top = hs.depth - 1 if upto is None else min(upto, hs.depth - 1)
    known = hs.__dict__.get(_EVAL_ARGS)
    if known is None:
        known = hs.__dict__[_EVAL_ARGS] = {}
    hit = known.get(top)
    if hit is None:
        if top < 0:
            raise ValueError(f"upto must be at least 0, got {upto}")
        levels, keys, shifts, ends, patch_rows = hs._terms_index
        hit = known[top] = (levels.size > 1 and levels[1] <= top,  # a fine level with detail is summed
                            (int(top), int(hs.u.n), bool(hs.u.periodic), int(hs.v.n), bool(hs.v.periodic),
                             _flat(hs.cvs.reshape(-1, 3), 2), levels, keys, shifts, ends, patch_rows, hs._table_rows))
    if hit[0]:
        return (*hit[1], _flat((det if det is not None else _details_for(hs, top)).table, 2))
    return (*hit[1], _NO_DETAILS)


# key in an `HSpline`'s ``__dict__``: ``{top: (whether a fine level is summed, eval_arrays' arguments
# before the table)}``, which depend on level 0 and the levels' structure alone (carried by
# `hierarchy.with_fine` to a surface of other offsets)
_EVAL_ARGS = hierarchy.EVAL_ARGS


def _surface_eval(out: np.ndarray) -> SurfaceEval:
    """The `SurfaceEval` of ``out (s, m, 3) float64``, slot by slot in field order, the slots not
    evaluated None; built without the frozen dataclass's ``__init__``, which sets a field at a
    time through ``object.__setattr__`` (every stage evaluates a few points at a time, many
    times a frame)."""
    ev = object.__new__(SurfaceEval)
    ev.__dict__.update(_UNSET)
    ev.__dict__.update(zip(_FIELDS, out))
    return ev


def _flat(x, ndim: int = 1) -> np.ndarray:
    """``x`` as `_plain` gives it, flattened (``ndim`` 1) or as it is (2): ``x`` itself where it
    is already a C-contiguous, writeable float64 array of ``ndim`` dimensions, as the common
    call passes, found by a check that costs less than `np.ascontiguousarray`'s."""
    if type(x) is np.ndarray and x.dtype == np.float64 and x.ndim == ndim:
        flags = x.flags
        if flags.c_contiguous and flags.writeable:
            return x
    a = _plain(x)
    return a.reshape(-1) if ndim == 1 else a


_NO_DETAILS = np.zeros((0, 3))
_FIELDS = tuple(f.name for f in fields(SurfaceEval))
_UNSET = dict.fromkeys(_FIELDS)  # `_surface_eval`'s slots not evaluated, as the constructor's defaults


def _details_for(hs: HSpline, top: int) -> Details:
    """Details of levels ``1..top`` for an `evaluate` not given them: every level's, kept on the
    surface (`keep_details`), where they are known; else computed, and kept when they are every
    level's. Levels up to ``top`` are the same either way (each level's frames depend on the
    coarser levels alone), and `evaluate` sums only those."""
    known = hs.__dict__.get("_details")
    if known is not None:
        return known
    det = details(hs, upto=top)
    if top == hs.depth - 1:
        keep_details(hs, det)
    return det


def keep_details(hs: HSpline, det: Details | None) -> None:
    """Keep ``det`` (`details(hs)`, every level) on the surface object, for later `evaluate` calls
    on it without ``det``: a response hands back its surface's details (`acra.respond`), and a
    frame's later round evaluates its parent (the earlier round's surface) without them."""
    if det is not None and hs.depth > 1 and len(det.vectors) == hs.depth - 1:
        hs.__dict__.setdefault("_details", det)


def _plain(x) -> np.ndarray:
    """``x`` as a C-contiguous, writeable float64 array (a copy only where it is not one): the
    kernel reads its arrays alone, but numba compiles another signature for a read-only one."""
    a = np.ascontiguousarray(x, dtype=_F64)
    return a if a.flags.writeable else a.copy()


_F64 = np.dtype(np.float64)  # `_plain`'s dtype as an object: numpy converts a type on every call


def _evaluate_numpy(
    hs: HSpline,
    u: np.ndarray,
    v: np.ndarray,
    order: int = 0,
    det: Details | None = None,
    upto: int | None = None,
    side: int = 0,
) -> SurfaceEval:
    """`evaluate` as array operations: every (point, level) term gathered first and contracted
    with its 4×4 CV block in one batch. The reference the compiled kernel (`acra.kernels`) is
    tested against; same parameters and result."""
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
    # basis rows of u and v in one call: ``(n, o, 4)`` each, derivatives w.r.t. level-0 units
    n, o = rows.shape[0], order + 1
    if n > 1:
        ruv = _rows(np.concatenate([tus, tvs]), np.concatenate([scale, scale]), order)
        ru, rv = ruv[:n], ruv[n:]
    else:  # one term: each direction's row alone, as `basis_rows` rounds a single row
        ru, rv = _rows(tus, scale, order), _rows(tvs, scale, order)
    if order:
        # tensor products as batched matrix products: sum_b rv[o, b] block[a, b, c] for every
        # (a, c) in one (o × 4)(4 × 12) product per term, the CV block gathered b-major, then
        # sum_a ru[p, a] (...) -> (n, p, o, c). Each output entry is the same dot of length 4 as
        # a product per row a would give, so this equals that form bit for bit at a third of
        # the products.
        block = np.take(table, rows.transpose(0, 2, 1), axis=0).reshape(n, 4, 12)  # (n, 4 b, 4 a · 3 c)
        half = (rv @ block).reshape(n, o, 4, 3).transpose(0, 2, 1, 3)  # (n, a, o, c)
    else:
        # points alone: a (1 × 4)(4 × 3) product per row a (a vector-matrix product, which
        # BLAS sums in another order than a matrix product)
        half = rv[:, None] @ np.take(table, rows, axis=0)  # (n, 4 a, 1, 3 c)
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


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise ``a × b`` of ``(m, 3)`` arrays: `numpy.cross`'s products and differences (so the
    same bits) without its general-shape set-up, which costs more than the arithmetic on the
    few dozen rows an evaluation near a contact has."""
    out = np.empty(a.shape)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def _degenerate(ev: SurfaceEval, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Cross products ``du × dv`` and where they are too small to give a direction: where a
    tangent (times the sine between them) is under 1e-6 of the object's size, the resolution at
    which float32 ``acra:cvs`` keep a pole one point; there ``du × dv`` is rounding noise.
    Compiled (`acra.framekernels.degenerate`); `_degenerate_numpy` is the array form."""
    du, dv = _plain(ev.du), _plain(ev.dv)
    n, bad = np.empty(du.shape), np.empty(du.shape[0], bool)
    s = max(scale, 1e-300)
    framekernels.degenerate(du, dv, 1e-6 * s, 1e-12 * s**2, n, bad)
    return n, bad


def _degenerate_numpy(ev: SurfaceEval, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """`_degenerate` as array operations (the reference the kernel is tested against)."""
    n = _cross(ev.du, ev.dv)
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
    nudged: np.ndarray | None = None,
) -> tuple[SurfaceEval, np.ndarray]:
    """First-order evaluation plus unit normals that are finite everywhere.

    Where ``du × dv`` vanishes (a pole, a collapsed edge) the normal is the limit taken from
    inside the patch: the derivative of ``du × dv`` toward the patch centre (exact when one
    tangent vanishes linearly); where that vanishes too, the point is nudged toward its patch
    centre by growing amounts until the cross product has a direction (acra-notes §1).

    ``nudged`` ``(m,) bool``, if given, is set True at the points whose normal was taken at nudged
    points (which read the whole level-0 patch, not only the point's own cells) and False elsewhere.

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
    if not bad.any():  # every row has a direction (closest points seldom sit on a pole)
        if nudged is not None:
            nudged[:] = False
        unit = np.empty(n.shape)
        framekernels.unit_rows(n, unit)  # n / |n| row by row
        return ev, unit
    # first-order Taylor term of du × dv along the direction toward the patch centre:
    # exact limit where du or dv vanishes linearly (a pole, a collapsed edge)
    idx = np.nonzero(bad)[0]
    e2 = evaluate(hs, u[idx], v[idx], order=2, det=det, upto=upto)
    su = np.sign(0.5 - locate(hs.u, u[idx], 0)[1])[:, None]
    sv = np.sign(0.5 - locate(hs.v, v[idx], 0)[1])[:, None]
    c_u = _cross(e2.duu, e2.dv) + _cross(e2.du, e2.duv)
    c_v = _cross(e2.duv, e2.dv) + _cross(e2.du, e2.dvv)
    nf = su * c_u + sv * c_v
    ok = np.linalg.norm(nf, axis=1) > 1e-9 * scale**2
    n[idx[ok]] = nf[ok]
    bad[idx[ok]] = False
    if nudged is not None:
        nudged[:] = bad
    for amount in (1e-3, 1e-2, 1e-1, 0.5):
        if not np.any(bad):
            break
        idx = np.nonzero(bad)[0]
        nu_, nv_ = _nudged(hs, u[idx], v[idx], amount)
        nf, still = _degenerate(evaluate(hs, nu_, nv_, order=1, det=det, upto=upto), scale)
        n[idx[~still]] = nf[~still]
        bad[idx[~still]] = False
    n[bad] = (0.0, 0.0, 1.0)
    unit = np.empty(n.shape)
    framekernels.unit_rows(n, unit)  # n / |n| row by row
    return ev, unit


def _frames(ev: SurfaceEval, normals: np.ndarray) -> np.ndarray:
    """Orthonormal frames ``(m, 3, 3)``, columns ``(e_u, e_v, n)``. Compiled
    (`acra.framekernels.frames`); `_frames_numpy` is the array form."""
    du, dv, n = _plain(ev.du), _plain(ev.dv), _plain(normals)
    out = np.empty((du.shape[0], 3, 3))
    framekernels.frames(du, dv, n, out)
    return out


def _frames_numpy(ev: SurfaceEval, normals: np.ndarray) -> np.ndarray:
    """`_frames` as array operations (the reference the kernel is tested against)."""
    n = normals
    t = ev.du - np.sum(ev.du * n, axis=1)[:, None] * n
    tl = np.linalg.norm(t, axis=1)
    weak = tl <= 1e-12 * (np.linalg.norm(ev.du, axis=1) + np.linalg.norm(ev.dv, axis=1) + 1e-300)
    if np.any(weak):  # du vanishes (pole): take the direction perpendicular to dv instead
        alt = _cross(ev.dv[weak], n[weak])
        t[weak] = alt
        tl[weak] = np.linalg.norm(alt, axis=1)
    still = tl <= 1e-300
    if np.any(still):  # fully degenerate: any perpendicular of n
        pick = np.where(np.abs(n[still, 0:1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
        alt = pick - np.sum(pick * n[still], axis=1)[:, None] * n[still]
        t[still] = alt
        tl[still] = np.linalg.norm(alt, axis=1)
    e_u = t / tl[:, None]
    e_v = _cross(n, e_u)
    return np.stack([e_u, e_v, n], axis=2)


def details(hs: HSpline, upto: int | None = None,
            since: "tuple[HSpline, Details, np.ndarray] | None" = None,
            moved: tuple[int, ...] | None = None, lazy: int | None = None) -> Details:
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
    ``moved``: with ``since``, the levels whose CVs alone can differ from ``old`` (as
    `changed_patches` was given them); with at most one, the coarsest level that moved is that
    level if ``stale`` holds a patch, else none, without comparing the levels again. A level no
    finer than the coarsest moved one and the same `Level` object as ``old``'s (neither
    refined nor moved) keeps ``old``'s vectors and frames as they are: its frames' surface and its
    offsets are ``old``'s, and each vector is its own row's product.
    ``lazy``: on levels finer than ``lazy``, the frames of CVs with zero offsets that would be
    evaluated are left pending (`_PENDING`): their vectors are zero whatever the frame (numpy's
    product sums from +0.0), so evaluation does not need them, and a response's next move
    evaluates them with the frames it turns anyway (`moved_details`). Pending frames are NaN;
    the next pass of this function or of `moved_details` evaluates them.
    """
    top = hs.depth - 1 if upto is None else min(upto, hs.depth - 1)
    old_pending = since[1].__dict__.get(_PENDING, {}) if since is not None else {}
    pending = {}
    if since is None:
        first = 0
    elif moved is not None and len(moved) <= 1:
        first = moved[0] if moved and since[2].any() else hs.depth
    else:
        first = changes.first_moved(since[0], hs)
    ends = closed_ends(hs) if top >= 1 else ()
    vectors: list[np.ndarray] = []
    frames: list[np.ndarray] = []
    # the vectors stacked as each level is finished (`_stacked`): level k's rows are
    # ``start[k - 1]:start[k]``
    start = _starts(hs)
    table = np.empty((int(start[top]), 3))
    ends_stale = None  # `_ends_stale` of ``since``, found once
    for k in range(1, top + 1):
        lev = hs.fine[k - 1]
        if since is not None and k <= first and k - 1 < len(since[1].frames) and lev is since[0].fine[k - 1] \
                and k not in old_pending:
            vectors.append(since[1].vectors[k - 1])
            frames.append(since[1].frames[k - 1])
            table[start[k - 1]:start[k]] = vectors[-1]
            continue
        c = lev.cv_keys.size
        vec = np.zeros((c, 3))
        fr = np.zeros((c, 3, 3))
        places = _movable_places(hs, k, lev, ends)
        rows = every = places[0]
        pos = None  # positions in ``places`` of the rows left to evaluate (``None``: all)
        if rows.size and since is not None and k - 1 < len(since[1].frames):
            old, old_det, stale = since
            was = old.fine[k - 1]
            if lev.cv_keys is was.cv_keys and lev.movable is was.movable:  # a move: only offsets differ
                if k <= first and k not in old_pending:  # and the frames' surface is old's: old's frames, vectors of the new offsets
                    fr = old_det.frames[k - 1]
                    vec = levelkernels.restate_rows(_plain(fr), _NO_FRAMES, rows, _plain(lev.offsets), vec, _NO_MOVES, _NO_MOVES)[1]
                    vectors.append(vec)
                    frames.append(fr)
                    table[start[k - 1]:start[k]] = vec
                    continue
                orow, found = rows, np.ones(rows.size, bool)
            else:
                orow, found = _lookup(was.cv_keys, lev.cv_keys[rows])
                found &= was.movable[orow] if was.cv_keys.size else False
            if k in old_pending:  # frames an earlier pass left pending are evaluated here
                unknown = np.zeros(was.cv_keys.size, bool)
                unknown[old_pending[k]] = True
                found &= ~unknown[orow]
            fr[rows[found]] = old_det.frames[k - 1][orow[found]]
            if k > first:  # the surface under this level's frames moved on the stale patches
                ring, centre = places[1], places[4]
                found &= ~stale.reshape(-1)[centre]
                # a ring's frames depend on the surface all along its end (`_end_normal`)
                if ends_stale is None:
                    ends_stale = _ends_stale(hs, ends, stale)
                found &= (ring < 0) | ~ends_stale[np.maximum(ring, 0)]
            pos = np.nonzero(~found)[0]
            rows = rows[pos]
        later = None
        if rows.size and lazy is not None and k > lazy:
            zero = ~np.any(lev.offsets[rows], axis=-1)
            later = rows[zero]
            if later.size:
                pending[k] = later
                keep = ~zero
                rows = rows[keep]
                pos = np.nonzero(keep)[0] if pos is None else pos[keep]
        if rows.size:
            ring, gu, gv = (places[i] if pos is None else places[i][pos] for i in (1, 2, 3))
            fr[rows] = _frames_at(hs, k, ends, _stacked(vectors, frames, table[:start[k - 1]]), ring, gu, gv)
        # every movable CV's vector from its frame, kept or new (offsets may have moved); each
        # row's product is its own, so one product serves both
        vec = levelkernels.restate_rows(_plain(fr), _NO_FRAMES, every, _plain(lev.offsets), vec, _NO_MOVES, _NO_MOVES)[1]
        if later is not None and later.size:
            vec[later] = 0.0  # the product of zero offsets, whatever the frame
            fr[later] = np.nan
        vectors.append(vec)
        frames.append(fr)
        table[start[k - 1]:start[k]] = vec
    out = _stacked(vectors, frames, table)
    if pending:
        out.__dict__[_PENDING] = pending
    return out


def _starts(hs: HSpline) -> list[int]:
    """Where each fine level's rows start in a `Details.table` of ``hs``, ``depth`` ints: level
    ``k``'s rows are ``[k - 1]:[k]`` (`HSpline._table_rows` less level 0's), as Python ints
    for slicing."""
    out = hs.__dict__.get(_STARTS)
    if out is None:
        out = hs.__dict__[_STARTS] = (hs._table_rows - hs._table_rows[0]).tolist()
    return out


_STARTS = hierarchy.TABLE_STARTS


# key in a `Details`' ``__dict__``: ``{level: rows (m,) int64}`` of frames left pending (NaN) by
# `details`' ``lazy``; a `Details` without it has every frame
_PENDING = "_pending"
_NO_ROWS = np.zeros(0, np.int64)  # `levelkernels.stale_rows`' pending rows of a level with none
_NO_FRAMES = np.zeros((0, 3, 3))  # `levelkernels.restate_rows`' new frames of a level whose frames stay
_NO_MOVES = np.zeros((0, 3))  # `levelkernels.restate_rows`' moves (and moved offsets) of a pass that moves nothing
# key in a moved `Level`'s ``__dict__`` (`acra.respond.move_level`, beside `changes.MOVED`):
# ``(frames, vectors, new vectors)``, the level's vectors restated from its new offsets with the
# frames and vectors of the details it was moved with, in the same pass as the move
MOVED_VECTORS = "_moved_vectors"


def moved_details(old: HSpline, old_det: Details, new: HSpline, level: int) -> Details | None:
    """`details` of ``new``, which is ``old`` with other offsets on level ``level >= 1`` alone
    (a response's move, `acra.respond.move_level`: the same `Level` objects elsewhere, the same
    CVs and movability on ``level``), found from ``old_det`` by following the move down the
    levels; ``None`` where ``new`` is not such a surface (then `details` with ``since`` serves).

    A point's evaluation reads, on each level ``m``, the 4×4 block of detail vectors of the
    level-``m`` patch it lies in, and its nudged points (`surface_normals`) stay in its level-0
    patch. So a level-``k`` frame can differ from ``old``'s only if its CV's level-0 patch holds
    a level-``m`` patch (``level <= m < k``) that a CV whose vector is not the same bits
    supports; a ring's frames only if such a patch lies along its end (`_end_normal`). Level by
    level the frames of those CVs are evaluated, their vectors taken, and the supports of the
    vectors that changed marked for the finer levels; every other row keeps ``old_det``'s bits,
    as `details` would give them (each row's frame and vector is its own point's, its own
    product). Levels the move does not reach keep ``old_det``'s arrays. Frames ``old_det`` left
    pending (`details`' ``lazy``) are evaluated with the others; the result has none."""
    pending = old_det.__dict__.get(_PENDING, {})
    if new.depth != old.depth or len(old_det.vectors) != old.depth - 1 or new.cvs is not old.cvs \
            or any(k <= level for k in pending):
        return None
    was, lev = old.fine[level - 1], new.fine[level - 1]
    if lev.cv_keys is not was.cv_keys or lev.movable is not was.movable or any(
            a is not b for k, (a, b) in enumerate(zip(old.fine, new.fine)) if k != level - 1):
        return None
    vectors, frames = list(old_det.vectors), list(old_det.frames)
    # the vectors stacked (`_stacked`), the rows of each level that moves rewritten: level k's
    # rows are ``start[k - 1]:start[k]``
    start = _starts(new)
    table = old_det.table.copy()
    hint = lev.__dict__.get(changes.MOVED)
    k = level
    if hint is not None and hint[0] is was.offsets:  # a move that names its rows: only those can differ
        rows = np.ascontiguousarray(hint[1], np.int64)
        restated = lev.__dict__.get(MOVED_VECTORS)
        if restated is not None and restated[0] is frames[k - 1] and restated[1] is vectors[k - 1]:
            vec = restated[2]  # the move's own pass restated them, from these frames and vectors
        else:
            rows = levelkernels.differing_rows(changes.bits(was.offsets), changes.bits(lev.offsets), rows)
            vec = None
    else:
        rows = np.nonzero(np.any(changes.bits(was.offsets) != changes.bits(lev.offsets), axis=-1))[0]
        vec = None
    # the level-0 patches holding a patch a changed CV supports; then level by level the frames
    # on them (compiled bookkeeping, `levelkernels.restate_rows`, `mark_changed` and `stale_rows`)
    stale = np.zeros((new.u.patches0, new.v.patches0), bool)
    ends = closed_ends(new)
    ends_arr = _ends_array(ends)
    up, vp = bool(new.u.periodic), bool(new.v.periodic)
    if vec is None:
        vec = levelkernels.restate_rows(_plain(frames[k - 1]), _NO_FRAMES, rows, _plain(lev.offsets), _plain(vectors[k - 1]),
                                        _NO_MOVES, _NO_MOVES)[1]
    marked = levelkernels.mark_changed(changes.bits(vec), changes.bits(vectors[k - 1]), rows, lev.cv_keys, int(new.v.cvs(k)), k,
                                       int(new.u.patches(k)), int(new.v.patches(k)), up, vp, stale) > 0
    vectors[k - 1] = vec
    table[start[k - 1]:start[k]] = vec
    while True:
        k += 1
        if k >= new.depth or not (marked or any(m >= k for m in pending)):
            break
        lev = new.fine[k - 1]
        every, ring, gu, gv, centre = _movable_places(new, k, lev, ends)
        if not every.size:
            continue
        pos = levelkernels.stale_rows(stale, centre, ring, ends_arr, every, pending.get(k, _NO_ROWS))
        if not pos.size:
            continue
        rows = every[pos]
        fresh = _plain(_frames_at(new, k, ends, _stacked(vectors[:k - 1], frames[:k - 1], table[:start[k - 1]]),
                                  ring[pos], gu[pos], gv[pos]))
        fr, vec = levelkernels.restate_rows(_plain(frames[k - 1]), fresh, rows, _plain(lev.offsets), _plain(vectors[k - 1]),
                                            _NO_MOVES, _NO_MOVES)
        marked |= levelkernels.mark_changed(changes.bits(vec), changes.bits(vectors[k - 1]), rows, lev.cv_keys, int(new.v.cvs(k)), k,
                                            int(new.u.patches(k)), int(new.v.patches(k)), up, vp, stale) > 0
        vectors[k - 1], frames[k - 1] = vec, fr
        table[start[k - 1]:start[k]] = vec
    return _stacked(vectors, frames, table)


def _frames_at(hs: HSpline, k: int, ends: tuple, partial: Details, ring: np.ndarray, gu: np.ndarray,
               gv: np.ndarray) -> np.ndarray:
    """Frames ``(m, 3, 3) float64`` of level-``k`` CVs centred at ``gu, gv (m,) float64`` on the
    surface of levels ``0..k-1`` (``partial``: their details), the CVs of a pole ring (``ring (m,)
    int64``, `_ring_members`) with their end's one normal (`_end_normal`)."""
    # a ring's CVs take their end's one normal: their own (at the end, where du x dv
    # vanishes and the limit normal needs second derivatives) are not computed
    fixed, n_fixed = np.zeros(gu.size, bool), np.zeros((gu.size, 3))
    for i, (axis, end) in enumerate(ends if np.count_nonzero(ring >= 0) else ()):
        on = ring == i
        if np.count_nonzero(on):
            n_end = _end_normal(hs, k, axis, end, partial)
            if n_end is not None:
                fixed |= on
                n_fixed[on] = n_end
    ev = evaluate(hs, gu, gv, order=1, det=partial, upto=k - 1)
    # normals and frames in one compiled pass (`framekernels.frames_at`) unless a row off the
    # rings is degenerate
    out = np.empty((gu.size, 3, 3))
    s = max(hs.size(), 1e-300)
    if not framekernels.frames_at(ev.du, ev.dv, 1e-6 * s, 1e-12 * s**2, fixed, n_fixed, out):
        return out
    own = ~fixed
    n = n_fixed.copy()
    if own.any():  # each row's normal is its own point's: the same on any subset
        sub = ev if not fixed.any() else SurfaceEval(ev.points[own], ev.du[own], ev.dv[own])
        n[own] = surface_normals(hs, gu[own], gv[own], det=partial, upto=k - 1, ev=sub)[1]
    return _frames(ev, n)


_PLACES = memo.Table("hspline.places", 64)  # (id of a level's cv_keys, closed ends) -> `_movable_places`, most recent last


def _movable_places(hs: HSpline, k: int, lev: Level, ends: tuple) -> tuple:
    """What `details` needs of level ``k``'s movable CVs that depends on the level's CVs and
    movability alone: their ``rows (m,) int64``, pole ring ``(m,) int64`` (`_ring_members`),
    centres ``gu, gv (m,) float64`` (`cv_uv`) and the level-0 patch ``(m,) int64`` (flat,
    ``pu * P0v + pv``) each centre is in. Kept per `Level` CV arrays: a move replaces a level's
    offsets, not its ``cv_keys`` and ``movable``, so the response's steps share them."""
    # first on the `Level` object itself (`PLACES`; a move's new `Level` carries it), which a
    # response asks on every level its moves follow
    on_level = lev.__dict__.get(PLACES)
    if on_level is None:
        on_level = lev.__dict__[PLACES] = {}
    hit = on_level.get(ends)
    if hit is not None and hit[0] is lev.cv_keys and hit[1] is lev.movable:
        return hit[2]
    key = (id(lev.cv_keys), ends)  # a level's CV keys are of one grid and level
    places = _PLACES.entries()
    hit = places.pop(key, None)
    if hit is None or hit[0] is not lev.cv_keys or hit[1] is not lev.movable:
        # compiled (`levelkernels.movable_places`); `_movable_places_numpy` is the array form
        rows, ring, _, _, gu, gv, centre = levelkernels.movable_places(
            lev.cv_keys, lev.movable, int(k), int(hs.u.cvs(k)), int(hs.v.cvs(k)), int(hs.u.patches0),
            bool(hs.u.periodic), int(hs.v.patches0), bool(hs.v.periodic), _ends_array(ends))
        hit = (lev.cv_keys, lev.movable, (rows, ring, gu, gv, centre))
    places[key] = hit
    _PLACES.trim()
    on_level[ends] = hit
    return hit[2]


# key in a `Level`'s ``__dict__``: ``{closed ends: (cv_keys, movable, `_movable_places`)}``
PLACES = "_places"


@functools.lru_cache(maxsize=16)
def _ends_array(ends: tuple[tuple[int, int], ...]) -> np.ndarray:
    """`closed_ends` as ``(E, 2) int64`` rows ``(axis, end)`` for the kernels; read-only."""
    out = np.array(ends, np.int64).reshape(-1, 2)
    out.flags.writeable = False
    return out


def _movable_places_numpy(hs: HSpline, k: int, lev: Level, ends: tuple) -> tuple:
    """`_movable_places` as array operations (the reference the kernel is tested against)."""
    c = lev.cv_keys.size
    rows = np.flatnonzero(lev.movable) if c else np.zeros(0, np.int64)
    ju, jv = np.divmod(lev.cv_keys[rows], hs.v.cvs(k))  # `_split_cv`
    ring = _ring_members(hs, k, ends, rows, ju, jv)
    scale = float(1 << k)
    gu, gv = (ju - 1.0) / scale, (jv - 1.0) / scale  # `cv_uv`: the Greville centres, exact
    # the level-0 patch of a centre, floor((j - 1) / 2^k), in integers
    pu, pv = (ju - 1) >> k, (jv - 1) >> k
    pu = np.mod(pu, hs.u.patches0) if hs.u.periodic else np.clip(pu, 0, hs.u.patches0 - 1)
    pv = np.mod(pv, hs.v.patches0) if hs.v.periodic else np.clip(pv, 0, hs.v.patches0 - 1)
    return rows, ring, gu, gv, pu * hs.v.patches0 + pv


def _ring_members(hs: HSpline, k: int, ends: tuple[tuple[int, int], ...], rows: np.ndarray,
                  ju: np.ndarray | None = None, jv: np.ndarray | None = None) -> np.ndarray:
    """For level-``k`` CV ``rows (m,) int64``: the index into ``ends`` (`closed_ends`) of the pole
    ring (`pole_ring`: the three CV rows at the end, all along it) each belongs to, or -1, as
    ``(m,) int64``; ``ju, jv (m,) int64``: the rows' CV indices, if the caller has them."""
    out = np.full(rows.size, -1, np.int64)
    if not ends or not rows.size:
        return out
    if ju is None:
        ju, jv = _split_cv(hs, k, hs.level(k).cv_keys[rows])
    for i, (axis, end) in enumerate(ends):
        j, d = (ju, hs.u) if axis == 0 else (jv, hs.v)
        first, last = _end_rows(d.cvs(k), end)[[0, 2]]  # the three rows at the end, a run
        out[(j >= min(first, last)) & (j <= max(first, last))] = i
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
    u, v = _end_params(hs.u, hs.v, k, axis, end)
    # compiled (`framekernels.limit_normals`) unless a point needs nudging
    e2 = evaluate(hs, u, v, order=2, det=det, upto=k - 1)
    unit = np.empty((u.size, 3))
    scale = hs.size()
    c = max(scale, 1e-300)
    if framekernels.limit_normals(u, v, e2.du, e2.dv, e2.duu, e2.duv, e2.dvv, 1e-6 * c, 1e-12 * c**2,
                                  1e-9 * scale**2, int(hs.u.patches0), int(hs.v.patches0), bool(hs.u.periodic),
                                  bool(hs.v.periodic), unit):
        unit = surface_normals(hs, u, v, det=det, upto=k - 1)[1]
    n = np.add.reduce(unit, axis=0) / unit.shape[0]  # `unit.mean(axis=0)`: its sum and division
    length = np.sqrt(n.dot(n))  # `np.linalg.norm(n)`: its dot product and root, without its wrapper
    return n / length if length > 1e-6 else None


@functools.lru_cache(maxsize=64)
def _end_params(u_dir: Direction, v_dir: Direction, k: int, axis: int, end: int) -> tuple[np.ndarray, np.ndarray]:
    """`_end_normal`'s points along a closed end, ``u, v (m,) float64``: two per level-``k`` patch
    along it (and the far end of an open direction). They depend on the grid alone, so they are
    built once per grid and level; writeable, as the kernels take them (never written)."""
    other = v_dir if axis == 0 else u_dir
    m = 2 * other.patches(k)
    s = np.arange(m) * other.patches0 / m if other.periodic else np.linspace(0.0, other.patches0, m + 1)
    at = np.full_like(s, end * (u_dir if axis == 0 else v_dir).patches0)
    return (at, s) if axis == 0 else (s, at)


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


def all_cv_positions(hs: HSpline, det: Details | None = None, refinement=None) -> list[np.ndarray]:
    """`cv_positions` of every level ``0 .. depth-1``, each level built once from the previous.
    ``refinement``: a function ``k -> cv_refinement(hs, k)`` (a caller that keeps them)."""
    det = details(hs) if det is None and hs.depth > 1 else det
    refinement = refinement or (lambda k: cv_refinement(hs, k))
    out = [hs.cvs.reshape(-1, 3).copy()]
    for k in range(1, hs.depth):
        out.append(_cv_positions_from(hs, k, det, out[-1], refinement(k)))
    return out


def cv_refinement(hs: HSpline, k: int) -> tuple[np.ndarray, np.ndarray]:
    """How level ``k``'s derived CVs subdivide level ``k-1``'s (thesis Fig. 3.7): rows ``(c_k, 3,
    3) int64`` of level ``k-1``'s CVs (`cv_positions` order) and their weights ``(c_k, 3, 3)``. A
    function of the grid and the two levels' ``cv_keys`` alone."""
    parent_keys = (np.arange(hs.u.n)[:, None] * hs.v.n + np.arange(hs.v.n)[None, :]).reshape(-1) if k == 1 else hs.level(k - 1).cv_keys
    ju, jv = _split_cv(hs, k, hs.level(k).cv_keys)
    iu, wu = refine_rows(hs.u, k - 1, ju)
    iv, wv = refine_rows(hs.v, k - 1, jv)
    pkeys = _cv_keys(hs, k - 1, iu[:, :, None], iv[:, None, :])  # (c, 3, 3)
    w = wu[:, :, None] * wv[:, None, :]
    rows, found = _lookup(parent_keys, pkeys)
    if not np.all(found | (w == 0.0)):
        raise AssertionError(f"level {k}: a derived CV needs a coarser CV that is not stored")
    return rows, w


def _cv_positions_from(hs: HSpline, k: int, det: Details, parent: np.ndarray,
                       refinement: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Level-``k`` CV positions from level ``k-1``'s ``parent`` positions (`cv_positions`)."""
    rows, w = cv_refinement(hs, k) if refinement is None else refinement
    derived = np.einsum("mab,mabc->mc", w, parent[rows])
    return derived + det.vectors[k - 1]
