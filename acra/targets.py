"""Data points (thesis §4.2): where points of a surface must go, and the targets of eq. 4.15–4.16.

A contact's two points meet at the split of their relative rigidity (`rigidity_share`,
`contact_targets`); additional points of a region inside the other object move by the same share
of their push (`additional_targets`), one per finest absorbing patch (`patch_keys`,
`patch_groups`: the middle of the region's samples in it, `region_midpoints`, or its deepest,
`region_deepest`). A surface's points and their targets are a `DataPoints`, what
`acra.respond.respond` takes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from . import levelkernels
from . import hspline as H
from .basis import locate
from .levelkernels import _segment, unique_inverse

__all__ = ["DataPoints", "rigidity_share", "contact_targets", "additional_targets", "region_midpoints", "region_deepest", "patch_keys", "patch_groups",
           "region_groups", "per_level_points", "merge_trig"]


@dataclass(frozen=True)
class DataPoints:
    """Where points of one surface must go.

    Attributes
    ----------
    uv : (K, 2) float64
        Parameters of each point on the surface (level-0 units).
    target : (K, 3) float64
        Where the point must go (object space of the surface).
    is_contact : (K,) bool
        Contact point ``P`` (True) or additional point ``A`` (False).
    per_patch : bool
        ``True`` (eq. 4.16): each level's solve merges the additional points to one per patch of
        that level (`per_level_points`). ``False``: every point is solved as it is, in least
        squares where they outnumber the CVs (a corrective round's samples, `corrective`).
    """

    uv: np.ndarray
    target: np.ndarray
    is_contact: np.ndarray
    per_patch: bool = True


def rigidity_share(r1: float, r2: float | None) -> float:
    """Eq. 4.15: ``R = R1 / (R1 + R2)``; a rigid collider (``r2 is None``) gives ``R = 0``.

    Surface 1 interpolates ``R P1 + (1 - R) P2``, so it moves ``1 - R`` of the way: the more
    rigid surface moves less, and against a collider the deformable moves all the way.
    """
    if r2 is None or np.isinf(r2):
        return 0.0
    return float(r1) / (float(r1) + float(r2))


def contact_targets(p1: np.ndarray, p2: np.ndarray, share: float) -> np.ndarray:
    """Eq. 4.15: the common target ``P' = R P1 + (1 - R) P2`` of two contact points ``(3,)``."""
    return share * np.asarray(p1, float) + (1.0 - share) * np.asarray(p2, float)


def additional_targets(a: np.ndarray, b: np.ndarray, share: float) -> np.ndarray:
    """Eq. 4.16: ``A' = R A + (1 - R) B`` for additional points ``a`` and their hits ``b``, ``(k, 3)``."""
    return share * np.asarray(a, float) + (1.0 - share) * np.asarray(b, float)


def region_midpoints(hs: H.HSpline, uv_inside: np.ndarray, level: int) -> tuple[np.ndarray, np.ndarray]:
    """Parametric middle of the part of each level-``level`` patch inside a region (eq. 4.16).

    Parameters
    ----------
    uv_inside : (n, 2) float64
        Parameters of surface samples that lie inside the other object.

    Returns
    -------
    uv_mid : (g, 2) float64
        One point per patch that is wholly or partly inside: the mean of its inside samples
        (periodic directions are averaged on the circle so a seam does not split the mean).
    patches : (g, 2) int64
        The patch of each point.
    """
    mids, patches, _ = patch_groups(hs, uv_inside, level)
    return mids, patches


def region_deepest(hs: H.HSpline, uv_inside: np.ndarray, depth: np.ndarray, level: int,
                   groups: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The deepest inside sample of each level-``level`` patch, in `region_midpoints`' order.

    Where a later round finds a patch still partly inside but the middle of its inside part
    already on its target (a sliver along the other object's edge, where the C2 surface curls
    back up between the samples), the middle moves nothing; the deepest sample is where the
    residual is.

    Parameters
    ----------
    uv_inside : (n, 2) float64
        Parameters of surface samples inside the other object.
    depth : (n,) float64
        Their depths (distance to the other surface).
    groups : (n,) int64, optional
        The group of each sample (`patch_groups`' ``inv``) where the caller has it already: the
        array form's sort then picks the rows (`_deepest_rows_numpy`); without it one compiled
        pass groups the samples and picks them (`region_groups`), the same rows.

    Returns
    -------
    uv_deep : (g, 2) float64
    depth_deep : (g,) float64
        The patch's largest depth.
    """
    uv_inside = np.asarray(uv_inside, dtype=np.float64).reshape(-1, 2)
    depth = np.asarray(depth, np.float64).reshape(-1)
    if groups is None:
        rows = region_groups(hs, uv_inside, level, depth)[2]
    else:
        rows = _deepest_rows_numpy(depth, groups)
    return uv_inside[rows], depth[rows]


def _deepest_rows_numpy(depth: np.ndarray, inv: np.ndarray) -> np.ndarray:
    """Row ``(g,) int64`` of each group's deepest sample, ``depth (n,) float64`` grouped by
    ``inv (n,) int64``, as array operations (the reference `_region_groups` is tested against):
    a sort by group then depth (a NaN after every number, ties in the samples' order), the last
    row of each group."""
    order = np.lexsort((depth, inv))  # by patch, deepest last
    last = np.r_[inv[order][1:] != inv[order][:-1], True] if order.size else np.zeros(0, bool)
    return order[last]


def patch_keys(hs: H.HSpline, uv: np.ndarray, level: int) -> np.ndarray:
    """Level-``level`` patch of each of ``uv (n, 2) float64`` as one key ``(n,) int64``
    (``su * patches_v + sv``): each row's key from `_region_groups`' pass (the sorted keys at
    each row's group), `_patch_keys_numpy`'s integers."""
    uv = np.ascontiguousarray(uv, dtype=np.float64).reshape(-1, 2)
    if not len(uv):
        return np.zeros(0, np.int64)
    uniq, inv = _region_groups(uv, _NO_DEPTH, level, hs.u.patches(level), hs.u.periodic, hs.v.patches(level),
                               hs.v.periodic, np.zeros((2, 2, len(uv))))[:2]
    return uniq[inv]


_NO_DEPTH = np.zeros(0)  # `_region_groups` without depths: no deepest rows


def _patch_keys_numpy(hs: H.HSpline, uv: np.ndarray, level: int) -> np.ndarray:
    """`patch_keys` as array operations (`acra.basis.locate` along each direction), the
    reference it is tested against."""
    su, _ = locate(hs.u, uv[:, 0], level)
    sv, _ = locate(hs.v, uv[:, 1], level)
    return su * hs.v.patches(level) + sv


def patch_groups(hs: H.HSpline, uv_inside: np.ndarray, level: int, patches: bool = True):
    """`region_midpoints` plus the group of each input point: ``inv (n,) int64``; with
    ``patches`` False the patches are ``None`` (a caller that needs the groups alone)."""
    mids, inv, _, uniq = region_groups(hs, uv_inside, level)
    if not patches:
        return mids, None, inv
    return mids, np.stack([uniq // hs.v.patches(level), uniq % hs.v.patches(level)], axis=1), inv


def region_groups(hs: H.HSpline, uv_inside: np.ndarray, level: int, depth: np.ndarray | None = None):
    """A region's samples ``uv_inside (n, 2) float64`` grouped per level-``level`` patch in one
    compiled pass (`_region_groups`): ``mids (g, 2) float64`` (`region_midpoints`), the group of
    each sample ``inv (n,) int64``, the row ``(g,) int64`` of each patch's deepest sample by
    ``depth (n,) float64`` (`region_deepest`; empty without ``depth``) and the patch keys
    ``(g,) int64`` in order (`patch_keys`). The array form's bits (`_patch_groups_numpy`,
    `_deepest_rows_numpy`): integer keys, sums from 0.0 in the samples' order as ``np.bincount``
    adds, numpy's cosines, sines and ``arctan2`` of a periodic direction's angles."""
    uv_inside = np.ascontiguousarray(uv_inside, dtype=np.float64).reshape(-1, 2)
    n = uv_inside.shape[0]
    if n == 0:
        return np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64)
    trig = np.zeros((2, 2, n))
    for col, d in ((0, hs.u), (1, hs.v)):
        if d.periodic:
            ang = 2 * np.pi * uv_inside[:, col] / d.patches0
            trig[col, 0], trig[col, 1] = np.cos(ang), np.sin(ang)
    depth = np.zeros(0) if depth is None else np.ascontiguousarray(depth, np.float64).reshape(-1)
    uniq, inv, mids, sums, rows = _region_groups(uv_inside, depth, level, hs.u.patches(level), hs.u.periodic,
                                                 hs.v.patches(level), hs.v.periodic, trig)
    for col, d in ((0, hs.u), (1, hs.v)):
        if d.periodic:
            mids[:, col] = np.mod(np.arctan2(sums[:, col, 1], sums[:, col, 0]), 2 * np.pi) * d.patches0 / (2 * np.pi)
    return mids, inv, rows, uniq


@njit(cache=True, nogil=True)
def _region_groups(uv, depth, level, u_patches, u_periodic, v_patches, v_periodic, trig):
    """`region_groups`' pass over ``uv (n, 2) float64``: the patch keys (`levelkernels._segment`,
    `patch_keys`' arithmetic), numbered as ``np.unique`` numbers them (`unique_inverse`); per
    patch the mean of each open parameter (a sum from 0.0 in the samples' order over the count),
    the sums ``(g, 2, 2)`` of ``trig (2, 2, n)``'s cosines and sines for a periodic direction's
    ``arctan2``, and, where ``depth (n,) float64`` has a row per sample, the deepest sample's row:
    the last in the samples' order of those with the largest depth, a NaN above every number
    (``np.lexsort``'s order, `_deepest_rows_numpy`). Returns ``uniq (g,)``, ``inv (n,)``,
    ``mids (g, 2)`` (a periodic column left for the caller), ``sums`` and ``rows (g,)`` (empty
    without depths)."""
    n = uv.shape[0]
    keys = np.empty(n, np.int64)
    for i in range(n):
        su = _segment(uv[i, 0], level, u_patches, u_periodic)[0]
        sv = _segment(uv[i, 1], level, v_patches, v_periodic)[0]
        keys[i] = su * v_patches + sv
    uniq, inv = unique_inverse(keys)
    g = uniq.shape[0]
    count = np.zeros(g, np.int64)
    mids = np.zeros((g, 2))
    sums = np.zeros((g, 2, 2))
    deep = depth.shape[0] == n
    rows = np.full(g if deep else 0, -1, np.int64)
    for i in range(n):
        r = inv[i]
        count[r] += 1
        for col in range(2):
            mids[r, col] += uv[i, col]
            sums[r, col, 0] += trig[col, 0, i]
            sums[r, col, 1] += trig[col, 1, i]
        if deep:
            b = rows[r]
            d = depth[i]
            if b < 0 or d != d or (depth[b] == depth[b] and d >= depth[b]):
                rows[r] = i
    for r in range(g):
        c = float(count[r])
        mids[r, 0] /= c
        mids[r, 1] /= c
    return uniq, inv, mids, sums, rows


def _patch_groups_numpy(hs: H.HSpline, uv_inside: np.ndarray, level: int):
    """`patch_groups` as array operations (the reference `_region_groups` is tested against):
    ``mids (g, 2)``, ``inv (n,)``, the sorted keys ``(g,)``."""
    uv_inside = np.asarray(uv_inside, dtype=np.float64).reshape(-1, 2)
    keys = _patch_keys_numpy(hs, uv_inside, level)
    uniq, inv = np.unique(keys, return_inverse=True)
    mids = np.zeros((uniq.size, 2))
    for col, d in ((0, hs.u), (1, hs.v)):
        x = uv_inside[:, col]
        if d.periodic:
            ang = 2 * np.pi * x / d.patches0
            c = np.bincount(inv, np.cos(ang), uniq.size)
            s = np.bincount(inv, np.sin(ang), uniq.size)
            mids[:, col] = np.mod(np.arctan2(s, c), 2 * np.pi) * d.patches0 / (2 * np.pi)
        else:
            mids[:, col] = np.bincount(inv, x, uniq.size) / np.bincount(inv, minlength=uniq.size)
    return mids, inv, uniq


def per_level_points(hs: H.HSpline, level: int, uv: np.ndarray, want: np.ndarray, is_contact: np.ndarray,
                     trig: np.ndarray | None = None):
    """Data points for one level's solve: contacts as they are, additional points merged per
    level-``level`` patch (mean parameters and mean wanted move), thesis eq. 4.16.

    The additional points come one per patch of the finest absorbing level; a coarser level has
    fewer CVs than that, and solving every point there would over-determine it. One point per
    patch of the level being solved keeps its system within its CVs.

    ``uv (K, 2) float64``, ``want (K, 3) float64``: the points and their wanted moves;
    ``is_contact (K,) bool``; ``trig``: `merge_trig` of the points, if the caller has it (a
    response merges the same points on every level). Returns ``uv (g, 2)``, ``want (g, 3)``.
    """
    if np.count_nonzero(is_contact) == is_contact.size:
        return uv, want
    # compiled (`levelkernels.merge_points`) but for a periodic direction's angles, whose
    # cosines, sines and arctan2 stay numpy's (`patch_groups`' arithmetic, as
    # `_per_level_points_numpy` holds it)
    if trig is None:
        trig = merge_trig(hs, uv, is_contact)
    luv, lwant, sums = levelkernels.merge_points(
        np.ascontiguousarray(uv), np.ascontiguousarray(want), np.ascontiguousarray(is_contact), level,
        hs.u.patches(level), hs.u.periodic, hs.v.patches(level), hs.v.periodic, trig)
    nc = luv.shape[0] - sums.shape[0]
    for col, d in ((0, hs.u), (1, hs.v)):
        if d.periodic:
            luv[nc:, col] = np.mod(np.arctan2(sums[:, col, 1], sums[:, col, 0]), 2 * np.pi) * d.patches0 / (2 * np.pi)
    return luv, lwant


def merge_trig(hs: H.HSpline, uv: np.ndarray, is_contact: np.ndarray) -> np.ndarray:
    """`levelkernels.merge_points`' ``trig (2, 2, E) float64``: numpy's cosines and sines of the
    angles of the ``E`` additional points (``is_contact (K,) bool`` false of ``uv (K, 2)``) along
    each periodic direction (zeros along an open one). They depend on the points alone, so a
    response finds them once for all its levels."""
    ex = uv[~is_contact]
    trig = np.zeros((2, 2, ex.shape[0]))
    for col, d in ((0, hs.u), (1, hs.v)):
        if d.periodic:
            ang = 2 * np.pi * ex[:, col] / d.patches0
            trig[col, 0], trig[col, 1] = np.cos(ang), np.sin(ang)
    return trig


def _per_level_points_numpy(hs: H.HSpline, level: int, uv: np.ndarray, want: np.ndarray, is_contact: np.ndarray):
    """`per_level_points` as array operations (the reference its kernel is tested against)."""
    extra = ~is_contact
    if not np.any(extra):
        return uv, want
    mids, inv, _ = _patch_groups_numpy(hs, uv[extra], level)
    g = mids.shape[0]
    moves = np.stack([np.bincount(inv, want[extra, c], g) for c in range(3)], axis=1)
    moves /= np.bincount(inv, minlength=g)[:, None]
    return np.concatenate([uv[is_contact], mids]), np.concatenate([want[is_contact], moves])
