"""The detail vectors of an H-spline's fine levels (thesis §3.4, Fig. 3.10): each movable CV's
offset turned into world space by its local frame, ``F_j @ offset_j``, and the explicit control
nets (derived + offset CVs) they give.

The frame ``F_j`` of a level-``k`` CV is the tangent plane and normal of the surface of levels
``0..k-1`` at the CV's parameter centre (`acra.hspline.surface_normals`), so `details` evaluates
the surface level by level, coarse to fine, and `moved_details` follows a response's move down
the levels; the CVs of a pole ring at a closed end share their end's one normal (`_end_normal`).
`acra.hspline.evaluate` sums these vectors (`Details.table`) into points. The frames here
evaluate through the module attributes ``H.evaluate`` and ``H.surface_normals``, so a replaced
`acra.hspline.evaluate` sees them too. Every public name here is importable from `acra.hspline`
as well.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from . import changes, framekernels, hierarchy, levelkernels, memo
from . import hspline as H
from .basis import Direction, refine_rows
from .hierarchy import HSpline, Level, _cv_keys, _end_rows, _lookup, _split_cv, closed_ends
from .hspline import SurfaceEval, _frames, _plain

__all__ = ["Details", "details", "moved_details", "cv_positions", "all_cv_positions", "cv_refinement", "MOVED_VECTORS"]


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
# key in a moved `Level`'s ``__dict__`` (`acra.moves.move_level`, beside `changes.MOVED`):
# ``(frames, vectors, new vectors)``, the level's vectors restated from its new offsets with the
# frames and vectors of the details it was moved with, in the same pass as the move
MOVED_VECTORS = "_moved_vectors"


def moved_details(old: HSpline, old_det: Details, new: HSpline, level: int) -> Details | None:
    """`details` of ``new``, which is ``old`` with other offsets on level ``level >= 1`` alone
    (a response's move, `acra.moves.move_level`: the same `Level` objects elsewhere, the same
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
    ev = H.evaluate(hs, gu, gv, order=1, det=partial, upto=k - 1)
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
        n[own] = H.surface_normals(hs, gu[own], gv[own], det=partial, upto=k - 1, ev=sub)[1]
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
    e2 = H.evaluate(hs, u, v, order=2, det=det, upto=k - 1)
    unit = np.empty((u.size, 3))
    scale = hs.size()
    c = max(scale, 1e-300)
    if framekernels.limit_normals(u, v, e2.du, e2.dv, e2.duu, e2.duv, e2.dvv, 1e-6 * c, 1e-12 * c**2,
                                  1e-9 * scale**2, int(hs.u.patches0), int(hs.v.patches0), bool(hs.u.periodic),
                                  bool(hs.v.periodic), unit):
        unit = H.surface_normals(hs, u, v, det=det, upto=k - 1)[1]
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

