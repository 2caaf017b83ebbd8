"""A level's moves and the details they leave (thesis §4.2): the deformational move of CVs
(`move_level`), the translational and rotational responses of a level's patches, and the
details of the surface a move makes, followed from the surface before it (`redetail`).

A fine level stores its CVs as offsets in the frames of the coarser surface (thesis §3.4), so a
move of world ``dv`` adds ``F^T dv`` to an offset and a CV's position moves by exactly ``dv``;
the finer levels' frames turn with it, and `redetail` evaluates them only on the level-0
patches the move reaches (`acra.details.moved_details`). Each function takes a surface and
returns a new one; the caller's objects are never modified. `acra.respond` applies these moves
level by level.
"""

from __future__ import annotations

import numpy as np

from . import changes, levelkernels
from . import details as D
from . import hspline as H
from .basis import locate
from .hierarchy import with_offsets
from .quat import quat_from_axis_angle, quat_rotate, slerp_mean

__all__ = [
    "SINCE",
    "move_level",
    "moved_patches",
    "redetail",
    "rotate",
    "rotation_of",
    "rotation_pivots",
    "settled",
    "translate",
]


# --------------------------------------------------------------------------------------------
# applying moves to a level

def move_level(hs: H.HSpline, level: int, cv_rows: np.ndarray, dv: np.ndarray, det: D.Details | None,
               unique: bool = False) -> H.HSpline:
    """Add object-space moves ``dv (P, 3) float64`` to the level-``level`` CVs ``cv_rows (P,)
    int64`` (rows as in `acra.interpolate.PointWeights.cv_rows`), keeping closed ends closed;
    ``det`` is ``D.details(hs)`` (needed for ``level >= 1``); ``unique``: the caller knows each
    row occurs once (a `PointWeights`' ``cv_rows``).

    Level 0 moves the grid directly; finer levels store ``F^T dv`` in the offsets, so the CV's
    position moves by exactly ``dv`` (its frame depends only on coarser levels).
    """
    if cv_rows.size == 0:
        return hs
    if level == 0:
        cvs = hs.cvs.reshape(-1, 3).copy()
        np.add.at(cvs, cv_rows, dv)
        return H.with_cvs(hs, _closed_ends(hs, cvs.reshape(hs.cvs.shape)))
    lev = hs.level(level)
    if unique:
        # each row once: one addition per row, as `np.add.at` makes it; the move and the level's
        # vectors restated from its new offsets are one compiled pass (`levelkernels.restate_rows`
        # with moves: ``offsets[cv_rows] += np.einsum("mji,mj->mi", frames[cv_rows], dv)``'s bits)
        rows = np.ascontiguousarray(cv_rows, np.int64)
        old = H._plain(lev.offsets)
        offsets = old.copy()
        vec = levelkernels.restate_rows(H._plain(det.frames[level - 1]), D._NO_FRAMES, rows, old,
                                        H._plain(det.vectors[level - 1]), H._plain(dv), offsets)[1]
    else:
        offsets = lev.offsets.copy()
        np.add.at(offsets, cv_rows, np.einsum("mji,mj->mi", det.frames[level - 1][cv_rows], dv))
    fine = list(hs.fine)
    fine[level - 1] = with_offsets(lev, offsets)
    if unique:  # the rows that can differ from ``lev``'s offsets, and its vectors, for `D.moved_details`
        fine[level - 1].__dict__[changes.MOVED] = (lev.offsets, cv_rows)
        fine[level - 1].__dict__[D.MOVED_VECTORS] = (det.frames[level - 1], det.vectors[level - 1], vec)
    for name in _SAME_CVS:  # same CVs, other offsets: the same ring rows and movable CVs' places
        if name in lev.__dict__:
            fine[level - 1].__dict__[name] = lev.__dict__[name]
    return H.with_fine(hs, tuple(fine), same_cvs=True)


# what a `Level` keeps on itself that depends on its CV keys and movability alone (`_ring_rows`,
# `D._movable_places`), carried to the level a move makes
_SAME_CVS = ("_ring_rows", D.PLACES)


def _closed_ends(hs: H.HSpline, cvs: np.ndarray) -> np.ndarray:
    """Level-0 ``cvs (nu, nv, 3)`` (``hs``'s after a move) with every end that ``hs`` closes
    (`H.closed_ends`) closed again.

    Moving rows 1–2 of a pole alone, as any level-0 contact within two patches does, splits it:
    the surface gets a hole, detection no longer sees an inside and the pole normal flips. The end
    row ``R0`` takes the least change that closes the end again (after a collapsed pole row ``R1``
    is collapsed to its mean), so the surface changes only in that end's patch rows.
    """
    ends = H.closed_ends(hs)
    if not ends:
        return cvs
    tol, new = 1e-6 * hs.size(), cvs.copy()
    for axis, end in ends:  # each end in its own orientation: (along the end, across it, 3) views
        old_v, new_v = (hs.cvs.transpose(1, 0, 2), new.transpose(1, 0, 2)) if axis == 0 else (hs.cvs, new)
        m = old_v.shape[1]
        e0, e1, e2 = (0, 1, 2) if end == 0 else (m - 1, m - 2, m - 3)
        if np.ptp(old_v[:, e1], axis=0).max() <= tol:
            new_v[:, e1] = new_v[:, e1].mean(axis=0)
        ring = new_v[:, e0] + 4.0 * new_v[:, e1] + new_v[:, e2]
        new_v[:, e0] -= ring - ring.mean(axis=0)
    return new


def _patch_cv_rows(hs: H.HSpline, level: int, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows of the 16 CVs of each point's level patch, and whether each is movable: ``(K, 16)``."""
    su, _ = locate(hs.u, uv[:, 0], level)
    sv, _ = locate(hs.v, uv[:, 1], level)
    i4 = np.arange(4)
    ju = hs.u.wrap_cv(su[:, None] + i4, level)
    jv = hs.v.wrap_cv(sv[:, None] + i4, level)
    if level == 0:
        rows = (ju[:, :, None] * hs.v.n + jv[:, None, :]).reshape(-1, 16)
        return rows, np.ones(rows.shape, bool)
    lev = hs.level(level)
    rows, found = H._lookup(lev.cv_keys, H._cv_keys(hs, level, ju[:, :, None], jv[:, None, :]).reshape(-1, 16))
    _, pfound = H._lookup(lev.patches, H._patch_keys(hs, level, su, sv))
    ok = found & pfound[:, None]
    if lev.cv_keys.size:
        ok &= lev.movable[rows]
    return rows, ok


def translate(hs, level, uv, moves, det):
    """Translational response: every CV of each point's level patch moves by that point's move.

    A CV shared by several patches takes the mean of their moves; a patch holding several
    points moves by their mean.
    """
    rows, ok = _patch_cv_rows(hs, level, uv)
    flat_rows = rows[ok]
    flat_moves = np.repeat(moves[:, None, :], 16, axis=1)[ok]
    uniq, inv = np.unique(flat_rows, return_inverse=True)
    acc = np.zeros((uniq.size, 3))
    np.add.at(acc, inv, flat_moves)
    acc /= np.bincount(inv, minlength=uniq.size)[:, None]
    return move_level(hs, level, uniq, acc, det, True)


def rotation_pivots(hs, level, uv, det):
    """Pivot of a level's rotation: the point on the surface of the coarser levels (base of the
    detail being turned); for level 0, the centroid of the level-0 control net."""
    if level == 0:
        return np.broadcast_to(hs.cvs.reshape(-1, 3).mean(axis=0), (uv.shape[0], 3)).copy()
    return H.evaluate(hs, uv[:, 0], uv[:, 1], det=det, upto=level - 1).points


def rotation_of(pivot: np.ndarray, p: np.ndarray, p_rot: np.ndarray):
    """Axis ``(m, 3)`` and angle ``(m,)`` turning ``p - pivot`` toward ``p_rot - pivot`` (§4.2.2)."""
    a = p - pivot
    b = p_rot - pivot
    axis = np.cross(a, b)
    n = np.linalg.norm(axis, axis=1)
    ang = np.arctan2(n, np.sum(a * b, axis=1))
    ok = n > 1e-15 * (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1) + 1e-300)
    axis = np.where(ok[:, None], axis / np.where(ok, n, 1.0)[:, None], [1.0, 0.0, 0.0])
    return axis, np.where(ok, ang, 0.0)


def rotate(hs, level, uv, points, moves, det):
    """Rotational response: turn the detail of each point's patch about the coarser surface.

    The quaternion turns ``P - C`` toward ``P + r dP - C`` (``C``: pivot); it rotates the detail
    vectors (offsets) of the 16 CVs of the patch; a CV reached by several quaternions takes
    their slerp mean. Level 0, which has no detail, rotates its CVs about the net centroid.
    Contacts and additional points are treated alike (thesis: "an identical process"); points
    where the level has no detail to turn take the rotational share as a deformation (see
    `respond`).
    """
    pivots = rotation_pivots(hs, level, uv, det)
    axis, ang = rotation_of(pivots, points, points + moves)
    quats = quat_from_axis_angle(axis, ang)
    rows, ok = _patch_cv_rows(hs, level, uv)
    flat_rows = rows[ok]
    flat_q = np.repeat(quats[:, None, :], 16, axis=1)[ok]
    flat_piv = np.repeat(pivots[:, None, :], 16, axis=1)[ok]
    uniq, inv = np.unique(flat_rows, return_inverse=True)
    dv = np.zeros((uniq.size, 3))
    for i in range(uniq.size):
        sel = inv == i
        q = slerp_mean(flat_q[sel]) if sel.sum() > 1 else flat_q[sel][0]
        if level == 0:
            x = hs.cvs.reshape(-1, 3)[uniq[i]] - flat_piv[sel][0]
        else:
            x = det.vectors[level - 1][uniq[i]]
        dv[i] = quat_rotate(q[None], x[None])[0] - x
    return move_level(hs, level, uniq, dv, det, True)


# --------------------------------------------------------------------------------------------
# the details a move leaves


def redetail(old: H.HSpline, old_det: D.Details | None, new: H.HSpline,
              moved: tuple[int, ...] | None = None, lazy: int | None = None) -> tuple[H.HSpline, D.Details | None]:
    """``new`` and its details, recomputed only where it differs from ``old`` (a move is local).
    ``moved``: the levels whose CVs alone can differ (``(level,)`` after `move_level`, ``()``
    after a refinement), so the others are not compared; ``None`` compares them all. ``lazy``:
    after a refinement, the frames of new CVs finer than level ``lazy`` are left to the next
    move's pass (`D.details`), which turns them anyway."""
    if new.depth <= 1:
        return new, None
    if old_det is None:
        return new, D.details(new)
    if moved is not None and len(moved) == 1 and moved[0] >= 1:
        det = D.moved_details(old, old_det, new, moved[0])
        if det is not None:
            raw = np.zeros((new.u.patches0, new.v.patches0), bool)
            H.mark_moved(old, new, moved[0], raw)
            return new, _noted(old, old_det, det, raw, None)
    stale = H.changed_patches(old, new, levels=moved)
    return new, _noted(old, old_det, D.details(new, since=(old, old_det, stale), moved=moved, lazy=lazy), None, stale)


SINCE = "_since"  # a response's details: (the surface it started from, raw and grown stale patches)


def _noted(old: H.HSpline, old_det: D.Details, det: D.Details, raw: np.ndarray | None,
           grown: np.ndarray | None) -> D.Details:
    """``det``, the details of a surface that differs from ``old`` only on the level-0 patches
    ``raw`` grown by `H.changed_patches`' margin and ``grown`` (either ``None``: none), noted
    with where it differs from the surface the response started from: ``old``'s note joined
    with these, or these if ``old_det`` has none. Steps between `redetail` calls only refine,
    which moves no offset, so the union covers `H.changed_patches` of the whole response."""
    root, r0, g0 = old_det.__dict__.get(SINCE, (old, None, None))
    raw = r0 if raw is None else (raw if r0 is None else r0 | raw)
    grown = g0 if grown is None else (grown if g0 is None else g0 | grown)
    det.__dict__[SINCE] = (root, raw, grown)  # on ``old_det`` too, if handed back: a superset holds for both
    return det


def moved_patches(hs: H.HSpline, start: H.HSpline, det: D.Details | None) -> np.ndarray | None:
    """Level-0 patches ``(P0u, P0v) bool`` holding every one where ``hs``, responded from
    ``start`` with details ``det``, may differ from it (`H.changed_patches`, a superset), from the
    note `redetail` kept along the response; ``None`` where the note does not reach ``start``.
    The note is taken off ``det``, so a response from ``hs`` starts its own."""
    rec = det.__dict__.pop(SINCE, None) if det is not None else None
    if rec is None or rec[0] is not start:
        return None
    _, raw, grown = rec
    out = np.zeros((hs.u.patches0, hs.v.patches0), bool) if raw is None else H.grown_patches(hs, raw)
    return out if grown is None else out | grown


def settled(hs: H.HSpline, det: D.Details | None) -> tuple[H.HSpline, D.Details | None]:
    """``hs`` and ``det`` with the frames `redetail`'s ``lazy`` left pending evaluated (a level
    about to move reads its frames, and a response hands back every frame)."""
    if det is not None and D._PENDING in det.__dict__:
        return redetail(hs, det, hs, ())
    return hs, det
