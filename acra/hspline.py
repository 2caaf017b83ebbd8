"""Hierarchical uniform bicubic B-spline surfaces (H-splines; Forsey & Bartels 1988, thesis §3.4):
evaluation, normals and local frames.

The structure (levels, refinement, the C2 rule, offsets, the plain-array form) is
`acra.hierarchy`, the fine levels' detail vectors `acra.details`, and where two surfaces of one
grid differ `acra.changes`; every public name of the first two and the comparisons of the third
are importable from here too, so ``from acra import hspline`` gives the whole H-spline API.

Because subdivision reproduces the coarser surface exactly, the surface is

    Q(u, v) = Q0(u, v) + sum_{k>=1} sum_{movable j at level k} B_j^k(u, v) · F_j @ offset_j

and each level's sum vanishes outside its active region. `evaluate` uses this form (one sparse
B-spline sum per level); `acra.details.cv_positions` builds the explicit hierarchy of derived +
offset CVs, and the tests check the two agree, which is the refinement-exactness property.

Evaluation and details need each other: a point's detail terms are ``F_j @ offset_j``
(`acra.details.details`), and a level-``k`` frame ``F_j`` is the normal and tangent of the
surface of levels ``0..k-1`` (`surface_normals`, which evaluates it). `acra.details` imports
this module; this module reaches `acra.details` at run time alone (`_level_details`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

import numpy as np

from . import framekernels, hierarchy, kernels
from .basis import Direction, basis_rows, locate
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
    refine_keys,
    refinement_keys,
    set_offsets,
    storage_size,
    to_arrays,
    with_cvs,
    with_fine,
    with_offsets,
)

from .changes import changed_cells, changed_patches, grown_patches, mark_moved  # noqa: F401  (re-exported)

if TYPE_CHECKING:
    from .details import Details

# this module's own names, the comparisons of two surfaces (`acra.changes`), the structure's
# (`acra.hierarchy`) and the detail vectors' (`acra.details`, through `__getattr__`), re-exported
_FROM_DETAILS = ("Details", "details", "moved_details", "cv_positions", "all_cv_positions", "cv_refinement", "MOVED_VECTORS")
__all__ = ["SurfaceEval", "keep_details", "evaluate", "eval_arrays", "surface_normals", "changed_cells", "changed_patches",
           "grown_patches", "mark_moved", *_FROM_DETAILS, *hierarchy.__all__]


def _level_details():
    """The module `acra.details`. Imported here, at the call, because the two modules need each
    other: evaluating a surface whose details are not given computes them (`_details_for`), and
    computing a level's details evaluates the surface of the coarser levels for its frames
    ``F_j`` (`acra.details._frames_at`); `acra.details` imports this module at its load."""
    from . import details

    return details


def __getattr__(name: str):
    """``hspline.details`` and the other `_FROM_DETAILS` names: `acra.details`' objects, looked
    up there on each access, so a replaced ``acra.details.details`` is the one every caller gets."""
    if name in _FROM_DETAILS:
        return getattr(_level_details(), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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
    det = _level_details().details(hs, upto=top)
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
        det = _level_details().details(hs, upto=top)
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

