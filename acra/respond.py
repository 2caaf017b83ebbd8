"""The collision response (thesis §4.2–4.3): data points, per-level absorption, three responses.

Everything here is a pure function: it takes a surface, data points and controls and returns a
new surface (new level-0 CVs and offsets); the caller's objects are never modified.

Order (thesis §4.3.4): the wanted moves ``dQ_k = target_k - Q(u_k, v_k)`` are computed once;
then for each level ``l`` from coarse to fine the level takes its share ``a[l] dQ_k``, split into
a deformational (``d[l]``), translational (``t[l]``) and rotational (``r[l]``) part, each applied
to the surface left by the previous step.

**Interpretation (cumulative targets).** Moving a coarse level turns the frames of finer CVs, so
finer detail rides along and the data point drifts slightly from ``Q + a[0] dQ``. Each level's
deformational step therefore aims at ``Q_orig + (shares applied so far + its own) · dQ`` rather
than at ``Q_current + a[l] dQ``; without drift the two are the same, and with it the final level
lands on the full target. Under ``obey`` a level that is not refined at a point is skipped there
and its share is not made up by finer levels: the remainder is exactly the missing absorption.

The moves themselves (deformational, translational, rotational) and the details each leaves are
`acra.moves`'; this module chooses them level by level.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from . import details as D
from . import framekernels, levelkernels, memo
from . import hspline as H
from . import moves as M
from .basis import locate
from .controls import ControlError, Controls
from .hierarchy import pole_ring_movable, pole_ring_rows, refine_keys, refinement_keys
from .interpolate import PointWeights, active_rows, point_active, point_weights, solve
from .targets import DataPoints, merge_trig, per_level_points

__all__ = [
    "respond",
]


# --------------------------------------------------------------------------------------------
# the fine levels' pole rings; answers kept across responses


def _ring_sums(hs: H.HSpline, det: D.Details, k: int, axis: int,
               end: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Level ``k``'s share of one pole (`H.pole_ring`): per ring column ``j`` the sum
    ``D0 + 4 D1 + D2`` of its three rows' detail vectors, ``sums (N, 3) float64``; the rows of
    those CVs in the level, ``rows (N, 3) int64``; whether each is movable, ``ok (N, 3) bool``;
    and how far the sums spread, ``np.ptp(sums, axis=0).max()`` (compiled,
    `acra.framekernels.ring_sums`).

    A fine level adds ``sum_j B_j(s) sums_j / 6`` at the pole, so it keeps the pole one point iff
    ``sums`` is the same for every column (an absent CV's detail is zero)."""
    rows, ok = _ring_rows(hs, k, axis, end)
    sums = np.empty((rows.shape[0], 3))
    spread = framekernels.ring_sums(det.vectors[k - 1], rows, ok, sums)
    return sums, rows, ok, spread


# `_ring_sums`' rows and movability, looked up once per `Level` object (`H.pole_ring_rows`)
_ring_rows = pole_ring_rows


def _closed_rings(hs: H.HSpline, det: D.Details | None) -> list[tuple[int, int, int]]:
    """``(k, axis, end)`` of every fine level whose share of a pole of ``hs`` keeps it one point
    (the ring sums agree within 1e-9 of the size): the rings `_close_rings` must keep closed.
    Kept per surface and details (`_KEPT`): a static object responds from the same surface
    every frame."""
    if det is None:
        return []
    key = ("rings", id(hs), id(det))
    hit = _KEPT.get(key)
    if hit is not None and hit[0] is hs and hit[1] is det:
        return hit[2]
    tol = 1e-9 * hs.size()
    spread = {(k, axis, end): _ring_sums(hs, det, k, axis, end)[3] for k in range(1, hs.depth)
              for axis, end in H.closed_ends(hs)}
    rings = [ring for ring, x in spread.items() if x <= tol]
    _keep(key, (hs, det, rings))
    # each ring's spread with the vectors it was read from, for `_close_rings` (a level the
    # response leaves alone keeps its vectors' array)
    det.__dict__.setdefault(_SPREAD, {k: (det.vectors[k[0] - 1], hs.level(k[0]).cv_keys, x) for k, x in spread.items()})
    return rings


# key in a `Details`' ``__dict__``: ``{(k, axis, end): (vectors and CV keys of level k, spread)}``,
# each ring's `_ring_sums` spread as `_closed_rings` found it on those details and their surface
_SPREAD = "_ring_spread"


# Answers that depend on a response's input surface and its details alone (the objects, which
# are never changed, are held with each answer so an id is not mistaken for a later object's):
# ``("rings", id(hs), id(det))`` -> `_closed_rings`, ``("refined", id(hs), id(det), lazy, keys)``
# -> `_refined`, ``("refined at", id(hs), id(det), lazy, levels, uv bytes)`` -> `_refined_at`. A
# static object's responses start from the same surface frame after frame, and its contact
# stays in the same patches; a table of the run's memo (`acra.memo`).
_KEEP = 24  # answers kept, oldest dropped first (a refined entry holds two surfaces and their details)
_KEPT = memo.Table("respond.kept", _KEEP)


def _keep(key: tuple, answer: tuple) -> None:
    """Keep ``answer`` under ``key`` in `_KEPT`, dropping the oldest past `_KEEP`."""
    _KEPT[key] = answer
    _KEPT.trim()


# Answers about a response's data points on one surface structure, kept across responses (a
# table of the run's memo, `acra.memo`): a static object whose contact is held still is
# responded from the same surface at the same parameters frame after frame (the demo's head in
# 4 of its 5 calls of frames 13-17, the spike in 2), and every level of each response asks them
# again. ``("at", id(hs), id(det), u, v bytes)`` -> the surface's points there and their poles
# (`_points_at`); ``("weights", level, grid, closed ends, ids of the level's CV keys, movability
# and patches, u, v bytes)`` -> `_weights`. A moved level keeps its CV keys, movability and
# patches arrays (`moves.move_level`), so a level's weights serve every surface a response moves it
# to; each entry holds the objects its key names by ``id``.
_AT = memo.Table("respond.at", 64)


def _points_at(hs: H.HSpline, det: D.Details | None, pu: np.ndarray, pv: np.ndarray,
               poles: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """`H.evaluate`'s points ``(K, 3) float64`` of ``hs`` (details ``det``) at ``pu, pv (K,)
    float64`` and, under ``poles``, `H.pole_of` of those parameters ``(K,) int64`` (else
    ``None``), kept (`_AT`); nothing writes into them (the points are read-only)."""
    key = ("at", id(hs), id(det), pu.tobytes(), pv.tobytes())
    kept = _AT.entries()
    hit = kept.pop(key, None)
    if hit is None or hit[0] is not hs or hit[1] is not det:
        q = H.evaluate(hs, pu, pv, det=det).points
        q.flags.writeable = False
        hit = [hs, det, q, None]
    if poles and hit[3] is None:  # writeable, as the weights' kernel takes it (never written)
        hit[3] = H.pole_of(hs, pu, pv)
    kept[key] = hit
    _AT.trim()
    return hit[2], hit[3]


def _weights(hs: H.HSpline, level: int, u: np.ndarray, v: np.ndarray, pole: np.ndarray | None = None) -> PointWeights:
    """`point_weights` of the points ``u, v (K,) float64`` on ``level`` (``pole``: their
    `H.pole_of`, if the caller has it), kept (`_AT`): they depend on the grid, its closed ends,
    the level's CV keys, movability and patches and the parameters alone. The weights are
    shared; nothing writes into them."""
    lev = hs.fine[level - 1] if level else None
    arrays = () if lev is None else (lev.cv_keys, lev.movable, lev.patches)
    key = ("weights", level, hs.u.n, hs.u.periodic, hs.v.n, hs.v.periodic, H.closed_ends(hs),
           *[id(a) for a in arrays], u.tobytes(), v.tobytes())
    kept = _AT.entries()
    hit = kept.pop(key, None)
    if hit is None or any(a is not b for a, b in zip(hit[0], arrays)):
        hit = (arrays, point_weights(hs, level, u, v, pole))
    kept[key] = hit
    _AT.trim()
    return hit[1]


def _refined(hs: H.HSpline, det: D.Details | None, keys: tuple, lazy: int) -> tuple[H.HSpline, D.Details | None]:
    """``hs`` with the patches ``keys`` (`hierarchy.refinement_keys`) active and its details
    (`moves.redetail`'s ``lazy``: the finer absorbing levels' new CVs are framed by the coarsest one's
    move, which turns them; the coarsest level's own frames its solve moves with). The
    refinement and its details pass depend on ``hs``, ``det`` and ``keys`` alone, so they are
    kept (`_KEPT`) for the next response from the same surface to the same patches (a level's
    patches are a set: keys listed twice, by two points in one patch, refine the same)."""
    key = ("refined", id(hs), id(det), lazy, tuple((level, _patch_set(hs, level, k)) for level, k in keys))
    hit = _KEPT.get(key)
    if hit is not None and hit[0] is hs and hit[1] is det:
        return hit[2], hit[3]
    new = refine_keys(hs, keys)
    new_det = M.redetail(hs, det, new, (), lazy=lazy)[1] if new is not hs else det
    _keep(key, (hs, det, new, new_det))
    return new, new_det


def _refined_at(hs: H.HSpline, det: D.Details | None, levels: tuple[int, ...], uv: np.ndarray, pole: np.ndarray,
                lazy: int) -> tuple[H.HSpline, D.Details | None]:
    """`_refined` of the patches `hierarchy.refinement_keys` lists for the points ``uv (K, 2)
    float64`` on ``levels`` (``pole (K,) int64``: `H.pole_of` of them), kept (`_KEPT`) by the
    points' parameters too: a contact held still gives a static object's response the same
    parameters frame after frame, and then the patches are not listed again."""
    key = ("refined at", id(hs), id(det), lazy, levels, uv.tobytes())
    hit = _KEPT.get(key)
    if hit is not None and hit[0] is hs and hit[1] is det:
        return hit[2], hit[3]
    new, new_det = _refined(hs, det, refinement_keys(hs, levels, uv[:, 0], uv[:, 1], _pole_blocks(hs, levels, pole)), lazy)
    _keep(key, (hs, det, new, new_det))
    return new, new_det


def _patch_set(hs: H.HSpline, level: int, keys: np.ndarray) -> bytes:
    """The level's patches ``keys (m,) int64`` (`hierarchy.refinement_keys`, in range, repeats
    and any order) as a set: one bit per patch of the level's grid, packed (a few kilobytes for
    the head's level 4; marking is linear where `np.unique` sorts)."""
    mark = np.zeros(hs.u.patches(level) * hs.v.patches(level), np.uint8)
    mark[keys] = 1
    return np.packbits(mark).tobytes()


_RING_W = np.array([1.0, 4.0, 1.0])  # a ring column's three rows in its pole sum (`_ring_sums`)


def _open_ring(hs: H.HSpline, det: D.Details | None, k: int, axis: int, end: int,
               refine: bool) -> tuple[H.HSpline, D.Details | None, bool]:
    """Make level ``k``'s whole pole ring movable under ``refine`` (its three patch rows all
    around, `H.pole_patches`); returns the surface, its details and whether the ring is movable."""
    ok = pole_ring_movable(hs, k, axis, end)
    if not ok and refine:
        hs, det = M.redetail(hs, det, H.refine(hs, k, H.pole_patches(hs, k, axis, end)), ())
        ok = pole_ring_movable(hs, k, axis, end)
    return hs, det, ok


def _close_rings(hs: H.HSpline, det: D.Details | None, rings: list[tuple[int, int, int]],
                 refine: bool, start: dict | None = None) -> tuple[H.HSpline, D.Details | None]:
    """Close again every fine level's pole ring in ``rings`` (`_closed_rings` before a response).

    The fine-level analogue of `_closed_ends`: a move of some ring columns, or a coarser move that
    turns the frames of their details, opens the pole into a ring of points: the column sums
    ``D0 + 4 D1 + D2`` that place the pole (``(R0 + 4 R1 + R2) / 6`` per column) stop agreeing,
    and the surface has a hole. Each column takes the minimum-norm change of its three CVs,
    ``-off_j (1, 4, 1) / 18``, that brings its sum to the common value: their mean when the whole
    ring is movable (refined so under ``refine``), else zero, the absent CVs' value; under
    ``obey`` a column not wholly movable stays open. The deformational step already keeps the
    rings closed (`_ring_constraints`), so this only mops up the translational and rotational
    steps and frame turns. Levels are closed coarse to fine, as closing one turns the next's
    frames. ``start``: the spreads `_closed_rings` found on the response's input details, with the
    vectors they were read from; a ring whose level still has those vectors is not summed again.
    """
    tol = 1e-12 * hs.size()
    start = start or {}
    for k, axis, end in rings:
        known = start.get((k, axis, end))
        if known is not None and known[0] is det.vectors[k - 1] and known[1] is hs.level(k).cv_keys and known[2] <= tol:
            continue  # the level's vectors as the response found them: closed then, closed now
        if _ring_sums(hs, det, k, axis, end)[3] <= tol:
            continue
        hs, det, full = _open_ring(hs, det, k, axis, end, refine)
        sums, rows, ok, _ = _ring_sums(hs, det, k, axis, end)
        off = sums - (sums.mean(axis=0) if full else 0.0)
        fix = ok.all(axis=1) & (np.abs(off).max(axis=1) > tol)
        if fix.any():
            dv = -off[fix, None, :] * (_RING_W / (_RING_W @ _RING_W))[None, :, None]
            hs, det = M.redetail(hs, det, M.move_level(hs, k, rows[fix].reshape(-1), dv.reshape(-1, 3), det), (k,))
    return hs, det


def _ring_reach(hs: H.HSpline, pw: PointWeights, k: int, axis: int, end: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`_ring_rows` of level ``k``'s ring at ``(axis, end)`` and which of its CVs ``pw``'s solve
    moves, ``reached (N, 3) bool``: kept on ``pw`` per level object, as `_reach_rings` and then
    `_ring_constraints` ask it of the same weights and level."""
    lev = hs.level(k)
    reach = pw.__dict__.setdefault("_reach", {})
    hit = reach.get((k, axis, end))
    if hit is None or hit[0] is not lev:
        rows, ok = _ring_rows(hs, k, axis, end)
        hit = reach[(k, axis, end)] = (lev, rows, ok, H._lookup(pw.cv_rows, rows)[1])  # cv_rows: sorted
    return hit[1], hit[2], hit[3]


def _reach_rings(hs: H.HSpline, det: D.Details | None, pw: PointWeights, uv: np.ndarray, rings: list[tuple[int, int, int]]):
    """Under ``refine``: make wholly movable each pole ring of ``pw``'s level that its points
    ``uv (K, 2)`` move a CV of, so `_ring_constraints` can keep it closed; ``pw`` is recomputed
    if that refined anything."""
    before = hs
    for k, axis, end in rings:
        if k == pw.level:
            if _ring_settled(hs, k, axis, end):
                continue  # wholly movable already, or no CV of it the solve could move
            _, ok, reached = _ring_reach(hs, pw, k, axis, end)
            if reached[ok].any():
                hs, det, _ = _open_ring(hs, det, k, axis, end, True)
    if hs is not before:
        pw = point_weights(hs, pw.level, uv[:, 0], uv[:, 1])
    return hs, det, pw


def _ring_settled(hs: H.HSpline, k: int, axis: int, end: int) -> bool:
    """Whether level ``k``'s ring at ``(axis, end)`` is wholly movable (`pole_ring_movable`) or
    has no movable CV (`_ring_rows`' ``ok`` all false): `_reach_rings` has nothing to open on it.
    Kept with the ring's rows on the `Level` object (which a move carries), as they depend on
    the level's CVs and movability alone."""
    memo = hs.level(k).__dict__.setdefault("_ring_rows", {})
    key = ("settled", hs.u.n, hs.u.periodic, hs.v.n, hs.v.periodic, axis, end)
    hit = memo.get(key)
    if hit is None:
        hit = memo[key] = pole_ring_movable(hs, k, axis, end) or not _ring_rows(hs, k, axis, end)[1].any()
    return hit


def _ring_constraints(hs: H.HSpline, det: D.Details | None, pw: PointWeights, want: np.ndarray,
                      rings: list[tuple[int, int, int]]):
    """Add to a level's interpolation problem one virtual point per column of each of its pole
    rings that the move reaches: ``(sum_j - mean sum) / 6``, the column's offset from the pole,
    must become zero. The minimum-norm solve then moves the CVs near the pole so that it stays
    one point while the data points reach their targets (closing afterwards, `_close_rings`,
    would pull them back). The rings must be wholly movable.

    ``pw`` : PointWeights of the data points; ``want (K, 3)``: their wanted moves. Returns both
    extended by the ``N`` virtual points of each ring (the weights by `_ring_extension`).
    """
    used, ext = _ring_extension(hs, pw, rings)
    if not used:
        return pw, want
    targets = [want]
    for k, axis, end in used:
        sums = _ring_sums(hs, det, k, axis, end)[0]
        targets.append(-(sums - np.add.reduce(sums, axis=0) / sums.shape[0]) / 6.0)  # `sums.mean(axis=0)`'s sum and division
    return ext, np.concatenate(targets)


def _ring_extension(hs: H.HSpline, pw: PointWeights, rings: list[tuple[int, int, int]]) -> tuple[tuple, PointWeights]:
    """The rings of ``rings`` whose virtual points `_ring_constraints` adds to ``pw``'s problem
    (on ``pw``'s level, wholly movable, reached by its solve), in order, and ``pw`` extended by
    their entries (``pw`` itself if none). They depend on ``pw`` and the level's CV keys and
    movability alone, so they are kept on ``pw`` (`_weights` hands a level the same weights
    for the same points, move after move and frame after frame)."""
    if not pw.level:  # rings are of fine levels
        return (), pw
    lev = hs.level(pw.level)
    kept = pw.__dict__.setdefault("_ring_extension", {})
    key = tuple(rings)
    hit = kept.get(key)
    if hit is not None and hit[0] is lev.cv_keys and hit[1] is lev.movable:
        return hit[2], hit[3]
    point, w, ring_rows, used = [pw.point], [pw.w], [], []
    n = pw.npoints
    for k, axis, end in rings:
        if k != pw.level or not pole_ring_movable(hs, k, axis, end):
            continue
        rows, ok, reached = _ring_reach(hs, pw, k, axis, end)  # a ring the move does not reach needs no sums
        if not reached.any():
            continue
        N = rows.shape[0]
        own, every, w_own, w_every = _ring_pattern(N)[:4]
        point += [n + own, n + every]
        ring_rows.append(rows.reshape(-1))
        w += [w_own, w_every]
        used.append((k, axis, end))
        n += N
    ext = pw
    if used:
        # the unknowns: the data points' CVs and the rings';
        # each entry's column is its CV's place among them (np.unique's inverse of every entry)
        cv_rows = levelkernels.unique_inverse(np.concatenate([pw.cv_rows, *ring_rows]))[0]  # pw.cv_rows: its entries' rows, each once
        col = [np.searchsorted(cv_rows, pw.cv_rows)[pw.col]]
        for r in ring_rows:
            c = np.searchsorted(cv_rows, r)
            col += [c, c[_ring_pattern(r.size // 3)[4]]]  # every column's CVs, once per row
        active = np.concatenate([pw.active, np.ones(n - pw.npoints, bool)])
        ext = PointWeights(pw.level, np.concatenate(point), np.concatenate(col).astype(np.int64, copy=False),
                           np.concatenate(w), cv_rows.astype(np.int64, copy=False), n, active)
    kept[key] = (lev.cv_keys, lev.movable, tuple(used), ext)
    return tuple(used), ext


@functools.lru_cache(maxsize=32)
def _ring_pattern(N: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`_ring_constraints`' entries of a ring of ``N`` columns, which depend on ``N`` alone: row
    ``j`` weighs +w_r / 6 on column ``j``'s three CVs and -w_r / (6 N) on every column's. Returns
    the rows of the own entries ``(3 N,) int64`` and of the every-column ones ``(3 N², ) int64``
    (from row 0), their weights ``(3 N,)``, ``(3 N²,) float64``, and which of the ring's ``3 N``
    CVs each every-column entry weighs, ``(3 N²,) int64``; read-only."""
    own = np.repeat(np.arange(N), 3)
    every = np.repeat(np.arange(N), 3 * N)
    w_own = np.tile(_RING_W / 6.0, N)
    w_every = -np.tile(_RING_W / (6.0 * N), N * N)
    cv_every = np.tile(np.arange(3 * N), N)
    for a in (own, every, w_own, w_every, cv_every):
        a.flags.writeable = False
    return own, every, w_own, w_every, cv_every




# --------------------------------------------------------------------------------------------
# the response

@dataclass(frozen=True)
class ResponseReport:
    """What `respond` did.

    Attributes
    ----------
    applied : (K,) float64
        Share of its move each data point received (1 unless ``obey`` skipped levels).
    remaining : (K, 3) float64
        ``target - Q`` after the response.
    refined : int
        Patches the ``refine`` policy activated.
    details : Details or None
        ``D.details`` of the responded surface (computed anyway; callers may reuse it).
    moved : (P0u, P0v) bool or None
        Level-0 patches holding every one where the responded surface may differ from the one
        responded from (a superset of `H.changed_patches`); ``None`` where it was not followed.
    """

    applied: np.ndarray
    remaining: np.ndarray
    refined: int
    details: D.Details | None = None
    moved: np.ndarray | None = None


def _make_movable(hs: H.HSpline, level: int, uv: np.ndarray) -> H.HSpline:
    """``hs`` refined so that every CV of the level-``level`` patch of each point ``uv (K, 2)``
    is movable, with the pole rings the points sit on (`_open_pole_rings`)."""
    su, _ = locate(hs.u, uv[:, 0], level)
    sv, _ = locate(hs.v, uv[:, 1], level)
    return _open_pole_rings(H.make_movable(hs, level, np.stack([su, sv], axis=1)), level, uv)


def _pole_blocks(hs: H.HSpline, levels: tuple[int, ...], pole: np.ndarray) -> dict[int, np.ndarray]:
    """The level patches ``(m, 2) int64`` that `_make_movable` activates on each of ``levels``
    besides each point's 7×7 block: the whole pole ring (`H.pole_patches`) of each pole a point
    sits on (``pole (K,)``, `H.pole_of`)."""
    on = set(pole.tolist())  # the poles any point sits on (a few dozen points)
    ends = [(axis, end) for i, (axis, end) in enumerate(H.closed_ends(hs)) if i in on]
    if not ends:
        return {}
    return {level: np.concatenate([H.pole_patches(hs, level, axis, end) for axis, end in ends]) for level in levels}


def _open_pole_rings(hs: H.HSpline, level: int, uv: np.ndarray) -> H.HSpline:
    """Refine the whole level-``level`` `H.pole_ring` of every pole a point ``uv (K, 2)`` sits on:
    such a point weighs the ring all around (`point_weights`), so the ring must be movable."""
    pole = H.pole_of(hs, uv[:, 0], uv[:, 1])
    for i, (axis, end) in enumerate(H.closed_ends(hs)):
        if np.any(pole == i):
            hs = H.refine(hs, level, H.pole_patches(hs, level, axis, end))
    return hs




def respond(
    hs: H.HSpline,
    points: DataPoints,
    controls: Controls,
    method: str = "direct",
    iterations: int = 5,
    det: D.Details | None = None,
    max_bytes: int | None = None,
    held: DataPoints | None = None,
    rcond: float = 1e-4,
    amplify: float | None = None,
) -> tuple[H.HSpline, ResponseReport]:
    """Move a surface so it passes through its data points (thesis §4.3.4 prolongation).

    Parameters
    ----------
    hs : HSpline
        The surface (object space).
    points : DataPoints
        Contact and additional points with their targets.
    controls : Controls
        Absorption and response mix per level, refinement policy.
    method : str
        ``"direct"`` minimum-norm solve or ``"blend"`` (iterated Bartels–Beatty) for the
        deformational step; ``iterations`` caps the latter.
    det : Details, optional
        ``D.details(hs)`` if the caller has it already (details are most of a response's cost).
    max_bytes : int, optional
        Bound on each direct solve's dense arrays (`interpolate.SystemTooLarge` past it).
    held : DataPoints, optional
        Points the response must leave at their targets (``is_contact`` unused): rows of the
        finest absorbing level's deformational solve, one each, not merged per patch; the coarser
        levels take their shares of ``points`` as without them. A coarse level cannot hold a point
        a patch away from a moved one (its patches span both), so the finest level, which
        interpolates, puts each back; solved one each they stay exact where the merged mean of
        eq. 4.16's per-patch points would move both.
    rcond : float
        Eigenvalue cut-off of the direct solves (`interpolate.min_norm_solve`): modes of the
        points' Gram matrix below ``rcond`` times its largest eigenvalue are dropped. A mode of
        relative eigenvalue ``λ`` multiplies the points' disagreement along it by ``1/√λ``.
    amplify : float or None
        The direct solves also drop a mode below 1e-3 of the largest eigenvalue whose CV move
        exceeds ``amplify`` times the largest point move asked (`interpolate.min_norm_solve`),
        except on the last deforming level when finer absorbing levels only turn or translate.

    Returns
    -------
    HSpline
        The responded surface (a new object).
    ResponseReport
    """
    uv = np.asarray(points.uv, dtype=np.float64).reshape(-1, 2)
    # the parameters along u and v as their own C-contiguous arrays, made once: the compiled
    # passes every level calls (evaluate, weights) take them so, and would copy a column each call
    pu, pv = uv[:, 0].copy(), uv[:, 1].copy()
    K = uv.shape[0]
    if K == 0:
        return hs, ResponseReport(np.zeros(0), np.zeros((0, 3)), 0)
    L = controls.absorption.size
    if L > hs.depth:
        raise ControlError("acra:absorption", f"has {L} levels but the surface has {hs.depth}")
    if det is None and hs.depth > 1:
        det = D.details(hs)
    rings, det0, start = _closed_rings(hs, det), det, hs
    if det is not None:  # a note from the response that made ``hs`` is not this one's
        det.__dict__.pop(M.SINCE, None)
    # A collapsed edge of an open grid (a fan's apex) is closed after the finest absorbing
    # level's solve (`_close_rings`), not within it (`_ring_constraints`); coarser levels keep it
    # in the solve. Why: every data point on the apex weighs the same ring (eq. 4.10 weights
    # averaged over u), so in the finest solve the ring constraints hold the samples beside the
    # apex at their targets while the patch's middle asks only part of what its corner needs;
    # closing the ring after the solve lets the finest level fit its points freely. The rule is
    # chosen by measurement, not derived: `python3 benchmarks/fan_sweep.py` (18 variations of
    # hard case 10) clears 18 of 18 within 4 rounds this way, 6 of 18 with the ring in the solve.
    # A periodic pole keeps its ring in the solve: there the ring is the spike tip's whole
    # closed end, and without it dog_head_spike's frame 15 needs a third round.
    fan = {(axis, end): not (hs.v if axis == 0 else hs.u).periodic for axis, end in H.closed_ends(hs)}
    # the controls as Python floats: the loop reads them per level, a numpy scalar at a time
    absorb, deform = controls.absorption.tolist(), controls.deform.tolist()
    translate, rotate = controls.translate.tolist(), controls.rotate.tolist()
    absorbing = [level for level in range(L) if absorb[level] > 0.0]
    finest = absorbing[-1] if absorbing else -1
    # the last level that deforms, where finer absorbing levels only turn or translate their
    # detail, keeps every mode above ``rcond`` (`amplify`): what it leaves unfitted no later level
    # can reshape
    shaping = [level for level in range(L) if absorb[level] > 0.0 and deform[level] > 0.0]
    exact = shaping[-1] if shaping and shaping[-1] < finest else -1
    # each level's own rings (`_reach_rings` and `_ring_constraints` look at a level's alone),
    # and those its solve keeps closed: every one, and on the finest level the periodic poles'
    # alone (tuples: `_ring_extension` keys its kept extensions by them)
    rings_at = {level: tuple(g for g in rings if g[0] == level) for level in absorbing}
    rings_kept = {level: tuple(g for g in rings_at[level] if not (level == finest and fan[g[1:]])) for level in absorbing}
    # which pole each point sits on depends on the level-0 grid alone (its closed ends): found
    # once for every level's weights while level 0 stays as it is
    cvs0 = hs.cvs
    q0, pole0 = _points_at(hs, det, pu, pv, True)
    dq = np.asarray(points.target, dtype=np.float64) - q0
    applied = np.zeros(K)
    refined = 0
    # Refinement depends on the points' parameters alone, not on where the CVs are, and moves
    # nothing; unless level 0 moves (its ends decide the poles `_open_pole_rings` opens), every
    # absorbing level is refined before the first solve, so one pass of `D.details` frames all
    # the new CVs and each later move's pass turns those on its stale patches with the rest.
    early = controls.refine and absorb[0] <= 0.0
    is_contact = np.asarray(points.is_contact, bool)
    merged = points.per_patch and np.count_nonzero(is_contact) < K  # additional points merged per patch (eq. 4.16)
    trig = merge_trig(hs, uv, is_contact) if merged else None  # their angles, the same on every level
    if early:
        coarse, before = hs, sum(lev.patches.size for lev in hs.fine)
        levels = tuple(level for level in absorbing if level >= 1)
        hs, det = _refined_at(hs, det, levels, uv, pole0, absorbing[0])
        refined = sum(lev.patches.size for lev in hs.fine) - before
    for level in range(L):
        a = absorb[level]
        if a <= 0.0:
            continue
        if level >= 1 and controls.refine and not early:
            before = sum(lev.patches.size for lev in hs.fine)
            coarse = hs
            hs = _make_movable(hs, level, uv)
            added = sum(lev.patches.size for lev in hs.fine) - before
            refined += added
            if added:  # new CVs need their frames; refinement alone moves nothing
                hs, det = M.redetail(coarse, det, hs, ())
        d, t, r = deform[level], translate[level], rotate[level]
        # the points' own weights serve the solve only when it takes them as they are (no points
        # merged per patch, none held); otherwise which points the level reaches is all it needs
        own = d > 0 and not merged and not (
            level == finest and held is not None and len(held.uv))
        pole = pole0 if hs.cvs is cvs0 else None
        pw = _weights(hs, level, pu, pv, pole)
        present = pw.active
        every = active_rows(pw)[1]  # every point reaches the level: the selections below are the arrays themselves
        if d > 0:
            # the first level's surface is the refined input, kept with its details (`_refined_at`)
            cur = _points_at(hs, det, pu, pv)[0] if level == absorbing[0] else H.evaluate(hs, pu, pv, det=det).points
            goal = q0 + (applied + a * d)[:, None] * dq
            want = goal - cur if every else np.where(present[:, None], goal - cur, 0.0)
            if merged:  # `per_level_points` of contacts alone is the points as they are
                luv, lwant = per_level_points(hs, level, uv, want, is_contact, trig)
            else:
                luv, lwant = uv, want
            if level == finest and held is not None and len(held.uv):
                huv = np.asarray(held.uv, dtype=np.float64).reshape(-1, 2)
                on = point_active(hs, level, huv[:, 0], huv[:, 1])  # a point with no CV of the level here
                huv, htarget = huv[on], np.asarray(held.target, dtype=np.float64).reshape(-1, 3)[on]
                hcur = H.evaluate(hs, huv[:, 0], huv[:, 1], det=det).points
                luv = np.concatenate([luv, huv])
                lwant = np.concatenate([lwant, htarget - hcur])
            lpw = pw if luv is uv and own else _weights(hs, level, np.ascontiguousarray(luv[:, 0]), np.ascontiguousarray(luv[:, 1]))
            if controls.refine:
                hs, det, lpw = _reach_rings(hs, det, lpw, luv, rings_at[level])
            lpw, lwant = _ring_constraints(hs, det, lpw, lwant, rings_kept[level])
            dv = solve(lpw, lwant, method=method, iterations=iterations, max_bytes=max_bytes, rcond=rcond,
                       amplify=None if level == exact else amplify)
            hs, det = M.redetail(hs, det, M.move_level(hs, level, lpw.cv_rows, dv, det, True), (level,))
        sel = np.nonzero(present)[0] if t > 0 or r > 0 else None
        if t > 0 and sel.size:
            hs, det = M.redetail(hs, det, M.translate(hs, level, uv[sel], a * t * dq[sel], det), (level,))
        if r > 0 and sel.size:
            # thesis §4.3.2: contacts and additional points alike turn their patch's detail
            cur = H.evaluate(hs, uv[sel, 0], uv[sel, 1], det=det).points
            pivots = M.rotation_pivots(hs, level, uv[sel], det)
            # a level with no detail at a point has nothing to turn there: deform instead
            flat = np.linalg.norm(cur - pivots, axis=1) <= 1e-9 * hs.size()
            rot, rest = sel[~flat], sel[flat]
            if rot.size:
                hs, det = M.redetail(hs, det, M.rotate(hs, level, uv[rot], cur[~flat], a * r * dq[rot], det), (level,))
            if rest.size:  # points without detail take the share as deformation
                sub = point_weights(hs, level, uv[rest, 0], uv[rest, 1])
                dv = solve(sub, a * r * dq[rest], method=method, iterations=iterations, max_bytes=max_bytes, rcond=rcond,
                           amplify=None if level == exact else amplify)
                hs, det = M.redetail(hs, det, M.move_level(hs, level, sub.cv_rows, dv, det, True), (level,))
        applied = applied + a if every else applied + np.where(present, a, 0.0)
        hs, det = M.settled(hs, det)
    hs, det = _close_rings(hs, det, rings, controls.refine, det0.__dict__.get(_SPREAD) if det0 is not None else None)
    H.keep_details(hs, det)
    final = H.evaluate(hs, pu, pv, det=det).points
    return hs, ResponseReport(applied, np.asarray(points.target) - final, refined, det, M.moved_patches(hs, start, det))
