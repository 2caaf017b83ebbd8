"""Level-0 patch boxes from every level's control points, compiled.

`patch_hulls` bounds each level-0 patch by the box of every control point (all levels) whose
support touches it (the convex-hull property). That array form sorts every (patch, control
point) pair, 16 per fine CV, to reduce them per patch, and is the reference the tests hold the
compiled form to; `patch_boxes` widens the boxes of the level-0 patches each fine CV's support
touches by its position, in one compiled pass.
Minima and maxima are exact, so the boxes are the same bits in any order. Arrays are float64
unless stated.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from acra.hierarchy import HSpline, _split_cv
from acra.details import Details, all_cv_positions, details

__all__ = ["boxes_within", "patch_boxes", "patch_hulls", "rays_meet", "translated_boxes"]


@njit(cache=True, nogil=True)
def _widen(lo, hi, ju, jv, pts, k, pu, pv, per_u, per_v, only, use_only):
    """Widen the boxes ``lo, hi (pu, pv, 3)`` by level-``k`` CVs ``(ju, jv)`` at ``pts (c, 3)``:
    level-``k`` CV ``j`` supports level-``k`` patches ``j-3 .. j``, inside level-0 patches
    ``(j-3) >> k .. j >> k`` (wrapped in a periodic direction, dropped past an open end)."""
    for c in range(ju.shape[0]):
        x, y, z = pts[c, 0], pts[c, 1], pts[c, 2]
        for du in range(4):
            qu = (ju[c] - 3 + du) >> k
            if per_u:
                qu = qu % pu
            elif qu < 0 or qu >= pu:
                continue
            for dv in range(4):
                qv = (jv[c] - 3 + dv) >> k
                if per_v:
                    qv = qv % pv
                elif qv < 0 or qv >= pv:
                    continue
                if use_only and not only[qu, qv]:
                    continue
                if x < lo[qu, qv, 0]:
                    lo[qu, qv, 0] = x
                if x > hi[qu, qv, 0]:
                    hi[qu, qv, 0] = x
                if y < lo[qu, qv, 1]:
                    lo[qu, qv, 1] = y
                if y > hi[qu, qv, 1]:
                    hi[qu, qv, 1] = y
                if z < lo[qu, qv, 2]:
                    lo[qu, qv, 2] = z
                if z > hi[qu, qv, 2]:
                    hi[qu, qv, 2] = z


@njit(cache=True, nogil=True)
def _level0(cvs, iu, iv, lo, hi):
    """The box of each level-0 patch's 4 x 4 CVs ``cvs[iu[p], :][:, iv[q]]``, without gathering
    the ``(pu, pv, 4, 4, 3)`` block (minima and maxima: the same numbers in any order)."""
    for p in range(iu.shape[0]):
        for q in range(iv.shape[0]):
            for k in range(3):
                a = cvs[iu[p, 0], iv[q, 0], k]
                b = a
                for i in range(4):
                    for j in range(4):
                        x = cvs[iu[p, i], iv[q, j], k]
                        a = min(a, x)
                        b = max(b, x)
                lo[p, q, k], hi[p, q, k] = a, b


def patch_boxes(hs: HSpline, every: list[np.ndarray], only: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """`patch_hulls` of ``hs`` given every level's CV positions ``every``
    (`acra.details.all_cv_positions`), the same boxes: ``lo, hi (P0u, P0v, 3)``. ``only
    (P0u, P0v) bool``: widen just these patches' boxes (the others hold level 0's alone)."""
    pu, pv = hs.u.patches0, hs.v.patches0
    i4 = np.arange(4)
    iu = hs.u.wrap_cv(np.arange(pu)[:, None] + i4, 0)
    iv = hs.v.wrap_cv(np.arange(pv)[:, None] + i4, 0)
    lo, hi = np.empty((pu, pv, 3)), np.empty((pu, pv, 3))
    _level0(np.ascontiguousarray(hs.cvs, np.float64), np.ascontiguousarray(iu, np.int64), np.ascontiguousarray(iv, np.int64),
            lo, hi)
    mask = np.zeros((1, 1), np.bool_) if only is None else np.ascontiguousarray(only, np.bool_)
    for k in range(1, hs.depth):
        keys = hs.level(k).cv_keys
        if keys.size == 0:
            continue
        ju, jv = _split_cv(hs, k, keys)
        _widen(lo, hi, np.ascontiguousarray(ju, np.int64), np.ascontiguousarray(jv, np.int64),
               np.ascontiguousarray(every[k], np.float64), k, pu, pv, hs.u.periodic, hs.v.periodic, mask, only is not None)
    return lo, hi


@njit(cache=True, nogil=True)
def _within(lo, hi, q, limit, out):
    for j in range(lo.shape[0]):
        for i in range(q.shape[0]):
            g0 = max(max(lo[j, 0] - q[i, 0], q[i, 0] - hi[j, 0]), 0.0)
            g1 = max(max(lo[j, 1] - q[i, 1], q[i, 1] - hi[j, 1]), 0.0)
            g2 = max(max(lo[j, 2] - q[i, 2], q[i, 2] - hi[j, 2]), 0.0)
            if np.sqrt(g0 * g0 + g1 * g1 + g2 * g2) <= limit[i]:
                out[j] = True
                break


def boxes_within(lo: np.ndarray, hi: np.ndarray, q: np.ndarray, limit: np.ndarray) -> np.ndarray:
    """Which boxes ``lo, hi (m, 3)`` lie within ``limit (k,)`` of some point of ``q (k, 3)``:
    ``(m,) bool``, each distance ``np.linalg.norm`` of the gap ``max(lo - q, q - hi, 0)`` as numpy
    rounds it (the squares summed in order), without the ``(k, m)`` arrays."""
    out = np.zeros(len(lo), np.bool_)
    if len(lo) and len(q):
        _within(np.ascontiguousarray(lo, np.float64), np.ascontiguousarray(hi, np.float64),
                np.ascontiguousarray(q, np.float64), np.ascontiguousarray(limit, np.float64), out)
    return out


@njit(cache=True, nogil=True)
def _translated_boxes(centre, half, xform, lo, hi, box, inner):
    for i in range(3):
        for j in range(3):
            if xform[i, j] != (1.0 if i == j else 0.0):
                return False
        if xform[i, 3] == 0.0 and np.signbit(xform[i, 3]):
            return False
    n = centre.shape[0]
    for p in range(n):
        for k in range(3):
            c, h = centre[p, k], half[p, k]
            w = c + xform[k, 3]
            if not (np.isfinite(c) and np.isfinite(h) and np.isfinite(w)):
                return False
            lo[p, k], hi[p, k] = w - h, w + h
    # no NaN is left (finite centres and half-extents), so plain comparisons are numpy's
    # minimum and maximum
    for k in range(3):
        box[0, k], box[1, k], inner[0, k], inner[1, k] = lo[0, k], hi[0, k], lo[0, k], hi[0, k]
        for p in range(1, n):
            a, b = lo[p, k], hi[p, k]
            if a < box[0, k]:
                box[0, k] = a
            if b > box[1, k]:
                box[1, k] = b
            if a > inner[0, k]:
                inner[0, k] = a
            if b < inner[1, k]:
                inner[1, k] = b
    return True


def translated_boxes(centre: np.ndarray, half: np.ndarray, xform: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                     box: np.ndarray, inner: np.ndarray) -> bool:
    """World boxes of object-space boxes ``centre, half (n, 3) float64`` (centres and
    half-extents, ``n >= 1``) under ``xform (4, 4) float64`` whose linear part is exactly the
    identity: ``lo, hi (n, 3) float64`` as ``M c + t -/+ |M| h``, ``box (2, 3)`` their union
    (the least ``lo`` and greatest ``hi`` of each axis) and ``inner (2, 3)`` the greatest
    ``lo`` and least ``hi``, in one pass. Returns whether it is so: the linear part is the
    identity, no ``t`` is -0.0 and every centre, half-extent and mapped centre is finite (else
    the outputs are unset).

    Then numpy's products ``c @ I.T + t`` and ``h @ |I|.T`` are ``c + t`` and ``h`` bit for bit
    in any summation order: each product is exact and all but one are zeros, which add nothing
    to a finite value; a zero's sign may differ in ``h @ |I|.T`` and in ``c @ I.T``, and
    ``c + t`` with ``t`` not -0.0 is never -0.0, so ``c + t -/+ h`` is the same either way."""
    centre, half, xform = centre.view(), half.view(), xform.view()
    # read-only views: one specialisation of the kernel whether the caller's arrays are writable or not
    centre.flags.writeable = half.flags.writeable = xform.flags.writeable = False
    return len(centre) > 0 and _translated_boxes(centre, half, xform, lo, hi, box, inner)


RAY_BLOCK = 8  # consecutive boxes `rays_meet` bounds by one box: a strip of patches along v


@njit(cache=True, nogil=True, error_model="numpy")
def _slab_meets(lo0, lo1, lo2, hi0, hi1, hi2, o, inv0, inv1, inv2):
    """The slab test of one ray (origin ``o (3,)``, ``1 / d`` per axis) against one box."""
    near, far = -np.inf, np.inf
    for lo_a, hi_a, o_a, inv in ((lo0, hi0, o[0], inv0), (lo1, hi1, o[1], inv1), (lo2, hi2, o[2], inv2)):
        t0, t1 = (lo_a - o_a) * inv, (hi_a - o_a) * inv
        if np.isnan(t0):
            t0 = -np.inf
        if np.isnan(t1):
            t1 = np.inf
        near = max(near, min(t0, t1))
        far = min(far, max(t0, t1))
    return far >= near and far >= 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def _rays_meet(lo, hi, o, d, box_hit, ray_hit):
    m = lo.shape[0]
    blocks = (m + RAY_BLOCK - 1) // RAY_BLOCK
    # each block's box holds its boxes' lo and hi corners (either may be the larger)
    blo, bhi = np.empty((blocks, 3)), np.empty((blocks, 3))
    finite = True
    for b in range(blocks):
        for a in range(3):
            x, y = np.inf, -np.inf
            for j in range(b * RAY_BLOCK, min(m, (b + 1) * RAY_BLOCK)):
                p, q = lo[j, a], hi[j, a]
                finite = finite and np.isfinite(p) and np.isfinite(q)
                x, y = min(x, p, q), max(y, p, q)
            blo[b, a], bhi[b, a] = x, y
    for i in range(o.shape[0]):
        inv0, inv1, inv2 = 1.0 / d[i, 0], 1.0 / d[i, 1], 1.0 / d[i, 2]
        # with finite corners and origin and a finite non-zero 1 / d per axis, no t is NaN and
        # each t is monotone in the corner, so a block's interval per axis holds each of its
        # boxes': a ray that misses the block's box misses every box in it
        prune = finite and np.isfinite(o[i, 0]) and np.isfinite(o[i, 1]) and np.isfinite(o[i, 2])
        for inv in (inv0, inv1, inv2):
            prune = prune and np.isfinite(inv) and inv != 0.0
        for b in range(blocks):
            if prune and not _slab_meets(blo[b, 0], blo[b, 1], blo[b, 2], bhi[b, 0], bhi[b, 1], bhi[b, 2],
                                         o[i], inv0, inv1, inv2):
                continue
            for j in range(b * RAY_BLOCK, min(m, (b + 1) * RAY_BLOCK)):
                if _slab_meets(lo[j, 0], lo[j, 1], lo[j, 2], hi[j, 0], hi[j, 1], hi[j, 2], o[i], inv0, inv1, inv2):
                    box_hit[j] = True
                    ray_hit[i] = True


def rays_meet(lo: np.ndarray, hi: np.ndarray, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Slab test of rays ``origins, directions (n, 3)`` (t >= 0) against boxes ``lo, hi (m, 3)``:
    which boxes some ray meets ``(m,) bool`` and which rays meet some box ``(n,) bool``.

    Per axis the ray is inside the slab for ``t`` between ``(lo - o) / d`` and ``(hi - o) / d``
    (``1 / d`` infinite for an axis-parallel ray; ``0 * inf``, a ray on the slab's plane, counts
    as inside); a ray meets the box where the slabs' intervals overlap at some ``t >= 0``. The
    numbers are numpy's for the same formula, without its ``(n, m, 3)`` arrays.

    A ray tests the boxes of a run of `RAY_BLOCK` rows only where it meets the box of their
    corners by the same formula, which it does wherever it meets one of them (``fl(fl(x - o) *
    inv)`` is monotone in ``x`` where nothing is infinite or NaN; an axis-parallel ray or a
    non-finite number tests every box): the same answer for a test per ray of the ``m /
    RAY_BLOCK`` blocks and of the boxes of the blocks it meets, which along one ray through a
    model of level-0 patches are about as many as the patches across it, not all of them."""
    box_hit, ray_hit = np.zeros(len(lo), np.bool_), np.zeros(len(origins), np.bool_)
    if len(lo) and len(origins):
        _rays_meet(np.ascontiguousarray(lo, np.float64), np.ascontiguousarray(hi, np.float64),
                   np.ascontiguousarray(origins, np.float64), np.ascontiguousarray(directions, np.float64),
                   box_hit, ray_hit)
    return box_hit, ray_hit


def patch_hulls(hs: HSpline, det: Details | None = None, only: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned boxes bounding every level-0 patch, from the convex-hull property.

    A patch lies in the hull of its 16 level-0 CVs plus whatever detail finer levels add; the
    detail of each fine CV is bounded by its level's CV positions, so the box of all control
    points (all levels) whose support touches the patch bounds it.

    Parameters
    ----------
    only : (P0u, P0v) bool, optional
        Bound just these patches (a responded surface reuses its parent's other boxes); the
        other entries of the result are level 0's boxes alone.

    Returns
    -------
    lo, hi : (P0u, P0v, 3) float64
    """
    pu, pv = hs.u.patches0, hs.v.patches0
    i4 = np.arange(4)
    iu = hs.u.wrap_cv(np.arange(pu)[:, None] + i4, 0)
    iv = hs.v.wrap_cv(np.arange(pv)[:, None] + i4, 0)
    block = hs.cvs[iu[:, None, :, None], iv[None, :, None, :]]  # (pu, pv, 4, 4, 3)
    lo = block.min(axis=(2, 3))
    hi = block.max(axis=(2, 3))
    if hs.depth > 1:
        det = details(hs) if det is None else det
        every = all_cv_positions(hs, det)
        cells, points = [], []
        for k in range(1, hs.depth):
            lev = hs.level(k)
            if lev.cv_keys.size == 0:
                continue
            ju, jv = _split_cv(hs, k, lev.cv_keys)
            # level-k CV j supports level-k patches j-3..j, i.e. level-0 patches (j-3)>>k .. j>>k
            for du in range(4):
                for dv in range(4):
                    qu = hs.u.wrap_patch((ju - 3 + du) >> k, 0)
                    qv = hs.v.wrap_patch((jv - 3 + dv) >> k, 0)
                    ok = hs.u.patch_valid(qu, 0) & hs.v.patch_valid(qv, 0)
                    if only is not None:
                        ok &= only[np.clip(qu, 0, pu - 1), np.clip(qv, 0, pv - 1)]
                    cells.append(qu[ok] * pv + qv[ok])
                    points.append(every[k][ok])
        if cells:
            # one sort groups every (patch, control point) pair; reduceat takes each patch's box
            cell = np.concatenate(cells)
            order = np.argsort(cell, kind="stable")
            cell, pts = cell[order], np.concatenate(points)[order]
            start = np.flatnonzero(np.r_[True, cell[1:] != cell[:-1]])
            flo, fhi, at = lo.reshape(-1, 3), hi.reshape(-1, 3), cell[start]
            flo[at] = np.minimum(flo[at], np.minimum.reduceat(pts, start, axis=0))
            fhi[at] = np.maximum(fhi[at], np.maximum.reduceat(pts, start, axis=0))
    return lo, hi
