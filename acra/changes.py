"""What differs between two H-splines of one grid (`acra.hierarchy`): the level-0 patches where
one may differ from the other (`changed_patches`, `grown_patches`, `mark_moved`), the cells of a
level where their evaluations may differ bit for bit (`changed_cells`), and the coarsest level
whose CVs moved (`first_moved`, `moved_cvs`).

A display re-evaluates only where a response changed its surface (`acra.tessellate`), the
details follow a move only where it reached (`acra.details.details`' ``since``), and a shape's
data is rebuilt only on the patches that changed (`pipeline.shape`): each asks these. A change is
found by the bits of the arrays, so ``-0.0`` and ``0.0`` differ as they may in what is computed
from them. `acra.hspline` re-exports the public names.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import numpy as np

from . import kernels, levelkernels
from .basis import Direction
from .hierarchy import _I4, HSpline, _lookup, _split_cv

if TYPE_CHECKING:
    from .details import Details

__all__ = ["changed_patches", "grown_patches", "mark_moved", "changed_cells", "first_moved", "moved_cvs", "bits", "MOVED"]

# key in a `Level`'s ``__dict__``: ``(old offsets (c, 3) float64, rows (m,) int64)``, set by a move
# that changed ``rows`` alone (sorted, each once) of the offsets of the level it was made from (the
# array, not that level, so a surface keeps no chain of the levels it was moved from)
MOVED = "_moved"


def changed_patches(old: HSpline, new: HSpline, margin: int = 2, levels: tuple[int, ...] | None = None) -> np.ndarray:
    """Level-0 patches ``(P0u, P0v) bool`` where ``new`` may differ from ``old`` (same grid).

    A changed level-``k`` CV ``j`` (level-0 row, or an offset that differs or is new and non-zero)
    moves level-``k`` patches ``j-3 .. j``, i.e. level-0 patches ``(j-3)>>k .. j>>k``; ``margin``
    more patches cover finer details whose frames follow the moved surface (their support reaches
    less than one level-0 patch beyond) and grid vertices on patch borders.

    ``levels``: the only levels whose CVs can differ, when the caller knows them (a response
    moves one level at a time, a refinement none); the other levels are not compared. ``None``
    compares every level."""
    mask = np.zeros((new.u.patches0, new.v.patches0), bool)
    hits = [(0, *np.nonzero(np.any(old.cvs != new.cvs, axis=-1)))] if levels is None or 0 in levels else []
    for k in range(1, new.depth):
        if levels is not None and k not in levels:
            continue
        b = new.level(k)
        hits.append((k, *_split_cv(new, k, b.cv_keys[moved_cvs(old, new, k)])))
    wrap = lambda q, d: np.mod(q, d.patches0) if d.periodic else np.clip(q, 0, d.patches0 - 1)  # noqa: E731
    for k, ju, jv in hits:
        if not len(ju):
            continue
        # (j - 3 + d) >> k for d = 0..3 covers every level-0 patch of j's support; the interval
        # always meets the domain, so clipping (open) or wrapping (periodic) loses nothing
        qu = wrap((ju[:, None] - 3 + _I4) >> k, new.u)
        qv = wrap((jv[:, None] - 3 + _I4) >> k, new.v)
        mask[qu[:, :, None], qv[:, None, :]] = True
    return grown_patches(new, mask, margin)


def grown_patches(hs: HSpline, mask: np.ndarray, margin: int = 2) -> np.ndarray:
    """Level-0 patches ``(P0u, P0v) bool``: ``mask`` grown by ``margin`` patches both ways along
    each direction (wrapping where periodic), as `changed_patches` grows its moved CVs' supports."""
    if not margin or not mask.any():
        return mask
    # one product with each direction's band of patches within ``margin``: counts of 0/1
    # entries, exact in float64
    return (_band(hs.u, margin) @ mask.astype(np.float64) @ _band(hs.v, margin)) > 0.0


def mark_moved(old: HSpline, new: HSpline, k: int, stale: np.ndarray) -> None:
    """Mark in ``stale (P0u, P0v) bool`` the level-0 patches holding a level-``k`` patch that a
    CV whose offset has other bits in ``new`` than in ``old`` supports: `changed_patches` of a
    move of level ``k >= 1`` alone (the same ``cv_keys``, `details.moved_details`' surfaces) before its
    margin. Only the rows the move names (`acra.moves.move_level`'s hint) can differ, else
    every row is compared."""
    was, lev = old.level(k), new.level(k)
    hint = lev.__dict__.get(MOVED)
    if hint is not None and hint[0] is was.offsets:
        rows = np.ascontiguousarray(hint[1], np.int64)
    else:
        rows = np.arange(lev.cv_keys.size, dtype=np.int64)
    levelkernels.mark_changed(bits(lev.offsets), bits(was.offsets), rows, lev.cv_keys, int(new.v.cvs(k)), k,
                              int(new.u.patches(k)), int(new.v.patches(k)), bool(new.u.periodic),
                              bool(new.v.periodic), stale)


def changed_cells(old: HSpline, old_det: Details | None, new: HSpline, new_det: Details | None,
                  level: int) -> np.ndarray:
    """Level-``level`` cells ``(P0u << level, P0v << level) bool`` (each a level-``level`` patch,
    closed) holding every point where `hspline.evaluate` of ``new`` with ``new_det`` may give other bits
    than of ``old`` with ``old_det`` (same grid; the details `hspline.evaluate` is given, every level's).

    A point's sum reads level 0's 4×4 CV block and, on each level `hspline.evaluate` visits
    (`HSpline._terms_index`), the detail vectors of its active patch's 4×4 block, if the patch
    is active. So a point can change only on a level-0 patch a changed CV supports, or on a
    level-``k`` patch whose activity (or its level's visiting) changed or which a level-``k``
    CV supports whose detail vector is not the same bits (or which only one surface has). The
    detail vectors are compared, not the offsets, so the frames a coarser move turned are found
    where they turned, with no margin: on the demo a response's changed cells are a fraction of
    the 2-patch margin `changed_patches` grows its moved CVs by."""
    cu, cv = new.u.patches(level), new.v.patches(level)
    out = np.zeros((cu, cv), bool)

    def mark(k: int, pu: np.ndarray, pv: np.ndarray, spread: int = 0) -> None:
        # level-k patches (spread 3: the patches j-3 .. j a CV j supports) into level-`level`
        # cells: a coarser patch covers a block of cells, a finer one lies in one cell (its closed
        # box in the cell's); compiled, so the work follows the changed patches, not the grid
        if pu.size:
            kernels.mark_cells(out, np.ascontiguousarray(pu, np.int64), np.ascontiguousarray(pv, np.int64), k, level,
                               spread, new.u.patches(k), new.v.patches(k), bool(new.u.periodic), bool(new.v.periodic))

    def support(k: int, ju: np.ndarray, jv: np.ndarray) -> None:
        # CV j supports level-k patches j-3 .. j (wrapped where periodic, clipped where open)
        mark(k, ju, jv, 3)

    if old.cvs.shape != new.cvs.shape:
        out[...] = True
        return out
    if old.cvs is not new.cvs:
        support(0, *np.nonzero(np.any(bits(old.cvs) != bits(new.cvs), axis=-1)))
    old_levels, new_levels = (set(hs._terms_index[0].tolist()) for hs in (old, new))
    for k in range(1, new.depth):
        a, b = old.level(k), new.level(k)
        pa = a.patches if k in old_levels else a.patches[:0]
        pb = b.patches if k in new_levels else b.patches[:0]
        if not (pa.size or pb.size):
            continue
        va = old_det.vectors[k - 1] if old_det is not None and pa.size else np.zeros((a.cv_keys.size, 3))
        vb = new_det.vectors[k - 1] if new_det is not None and pb.size else np.zeros((b.cv_keys.size, 3))
        if a.cv_keys is b.cv_keys and pa is pb and va is vb:  # the same level
            continue
        # compiled: the patches active on one surface alone and the CVs whose detail differs,
        # by merging the sorted key lists (the set operations below where one is not sorted)
        if kernels.changed_level(out, k, level, _ints(pa), _ints(pb), _ints(a.cv_keys), _ints(b.cv_keys),
                                 _writable(bits(va)), _writable(bits(vb)), new.v.patches(k), new.v.cvs(k),
                                 new.u.patches(k), new.v.patches(k), bool(new.u.periodic), bool(new.v.periodic)):
            continue
        if a.cv_keys is b.cv_keys and pa is pb:  # one refinement (a move): the rows align
            keys = b.cv_keys[np.any(bits(va) != bits(vb), axis=-1)]
        else:
            flip = np.setxor1d(pa, pb, assume_unique=True)  # active on one surface alone
            mark(k, *np.divmod(flip, new.v.patches(k)))
            rows, found = _lookup(a.cv_keys, b.cv_keys)
            same = np.zeros(b.cv_keys.size, bool)
            same[found] = np.all(bits(va[rows[found]]) == bits(vb[found]), axis=-1)
            gone = ~_lookup(b.cv_keys, a.cv_keys)[1]
            keys = np.concatenate([b.cv_keys[~same], a.cv_keys[gone]])
        support(k, *_split_cv(new, k, keys))
    return out


def _ints(x: np.ndarray) -> np.ndarray:
    """``x`` as a C-contiguous, writeable int64 array (a copy only where it is not one), so one
    compiled signature serves every call."""
    return _writable(np.ascontiguousarray(x, np.int64))


def _writable(x: np.ndarray) -> np.ndarray:
    """``x``, or a copy of it where it is read-only (numba compiles another signature for a
    read-only array)."""
    return x if x.flags.writeable else x.copy()


def bits(x: np.ndarray) -> np.ndarray:
    """``x`` float64 as its bits (int64), so a comparison tells ``-0.0`` from ``0.0``."""
    return np.ascontiguousarray(x).view(_INT64)


_INT64 = np.dtype(np.int64)  # `bits`' view: a dtype object, which a view takes without converting a type


@functools.lru_cache(maxsize=64)
def _band(d: Direction, m: int) -> np.ndarray:
    """``(P0, P0) float64``: 1 where two level-0 patches along ``d`` are at most ``m`` apart
    (across the seam of a periodic direction), else 0; read-only."""
    i = np.arange(d.patches0)
    gap = np.abs(i[:, None] - i[None, :])
    if d.periodic:
        gap = np.minimum(gap, d.patches0 - gap)
    band = (gap <= m).astype(np.float64)
    band.flags.writeable = False
    return band


def first_moved(old: HSpline, new: HSpline) -> int:
    """The coarsest level whose CVs differ between ``old`` and ``new`` (``depth`` if none):
    a changed level-0 CV, or a level-``k`` offset that differs or is new and non-zero. Refinement
    alone (new CVs with zero offsets) moves nothing. Frames of levels ``<=`` it are unchanged."""
    if old.cvs.shape != new.cvs.shape or np.any(old.cvs != new.cvs):
        return 0
    for k in range(1, new.depth):
        if np.any(moved_cvs(old, new, k)):
            return k
    return new.depth


def moved_cvs(old: HSpline, new: HSpline, k: int) -> np.ndarray:
    """Which of ``new``'s level-``k`` CVs ``(c_k,) bool`` moved from ``old``: an offset that
    differs, or a new CV with a non-zero offset (a new CV with offset zero is a refinement)."""
    a, b = old.level(k), new.level(k)
    if a.cv_keys is b.cv_keys:  # a move (`with_fine` of new offsets): the rows align, every CV found
        return ~np.all(a.offsets == b.offsets, axis=-1)
    rows, found = _lookup(a.cv_keys, b.cv_keys)
    same = np.zeros(b.cv_keys.size, bool)
    same[found] = np.all(a.offsets[rows[found]] == b.offsets[found], axis=-1)
    return ~same & (found | np.any(b.offsets != 0, axis=-1))
