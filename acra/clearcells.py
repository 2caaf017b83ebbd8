"""Triangles proven clear of a closed mesh by a grid of cells flooded from outside it, compiled.

The residual's branch and bound (`pipeline.clearance`) bounds a triangle by eq. (4) from its
corners' signed distances and its covering radius: a triangle outside the other object farther
than its covering radius is bounded by 0. Where most of a display's triangles near the other
object lie well outside it (a head's display around a thin spike), `clear_of` proves them so
without a closest-point search each: the cells a face's box touches hold the surface, every
untouched cell joined through untouched cells to one beyond the mesh's box is outside, and a
triangle whose cells within its covering radius are all outside is clear. The part of the mesh
a caller builds as a solid then only needs the faces near the triangles left.

Arrays are float64 unless stated.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from acra.bvh import bounds

from acra.meshrows import _read_only, faces_meet_rows
from acra.pseudonormals import _row

__all__ = ["CELLS", "MORE", "clear_of"]

CELLS = 24  # `clear_of`'s cells along the longest side of its grid
MORE = 2  # `clear_of`'s cells added to the reach


@njit(cache=True, nogil=True)
def _cell(x, origin, h):
    # one rounded subtraction and division, then floor: monotone in x, so a box's cells are
    # those of its corners and a segment's cells lie between its ends' on every axis
    return np.int64(np.floor((x - origin) / h))


@njit(cache=True, nogil=True)
def _box_add(diff, lo, hi, w):
    # ``w`` on the cells ``lo .. hi`` (3 ints each, a tuple: `acra.pseudonormals._row`) of a
    # difference array (its prefix sums over the three axes)
    a0, a1, a2, b0, b1, b2 = lo[0], lo[1], lo[2], hi[0] + 1, hi[1] + 1, hi[2] + 1
    diff[a0, a1, a2] += w
    diff[b0, a1, a2] -= w
    diff[a0, b1, a2] -= w
    diff[a0, a1, b2] -= w
    diff[b0, b1, a2] += w
    diff[b0, a1, b2] += w
    diff[a0, b1, b2] += w
    diff[b0, b1, b2] -= w


@njit(cache=True, nogil=True)
def _sums(a):
    # prefix sums along the three axes, in place
    for i in range(a.shape[0]):
        for j in range(a.shape[1]):
            for q in range(1, a.shape[2]):
                a[i, j, q] += a[i, j, q - 1]
    for i in range(a.shape[0]):
        for j in range(1, a.shape[1]):
            for q in range(a.shape[2]):
                a[i, j, q] += a[i, j - 1, q]
    for i in range(1, a.shape[0]):
        for j in range(a.shape[1]):
            for q in range(a.shape[2]):
                a[i, j, q] += a[i - 1, j, q]


@njit(cache=True, nogil=True)
def _box_sum(sat, lo, hi):
    # the sum over cells ``lo .. hi`` (3 ints each, a tuple) of a table whose ``sat[i + 1, j + 1, q + 1]``
    # sums cells up to (i, j, q)
    a0, a1, a2, b0, b1, b2 = lo[0], lo[1], lo[2], hi[0] + 1, hi[1] + 1, hi[2] + 1
    return (sat[b0, b1, b2] - sat[a0, b1, b2] - sat[b0, a1, b2] - sat[b0, b1, a2] + sat[a0, a1, b2] + sat[a0, b1, a2]
            + sat[b0, a1, a2] - sat[a0, a1, a2])


@njit(cache=True, nogil=True)
def _clear_cells(points, faces, rows, tri, rho, slack, reach, origin, h, dims, box_lo, box_hi, keep, chosen):
    nx, ny, nz = dims[0], dims[1], dims[2]
    o0, o1, o2 = origin[0], origin[1], origin[2]
    # the cells each face's box touches (clipped to the grid; empty if it misses it), its
    # corners read once as values
    flo, fhi = np.empty((rows.shape[0], 3), np.int64), np.empty((rows.shape[0], 3), np.int64)
    touch = np.zeros((nx + 1, ny + 1, nz + 1), np.int32)
    for r in range(rows.shape[0]):
        f0, f1, f2 = _row(faces, rows[r])
        x0, y0, z0 = _row(points, f0)
        x1, y1, z1 = _row(points, f1)
        x2, y2, z2 = _row(points, f2)
        l0 = max(_cell(min(min(x0, x1), x2) - slack, o0, h), 0)  # the slack: the solid's surface near this face's
        h0 = min(_cell(max(max(x0, x1), x2) + slack, o0, h), nx - 1)
        l1 = max(_cell(min(min(y0, y1), y2) - slack, o1, h), 0)
        h1 = min(_cell(max(max(y0, y1), y2) + slack, o1, h), ny - 1)
        l2 = max(_cell(min(min(z0, z1), z2) - slack, o2, h), 0)
        h2 = min(_cell(max(max(z0, z1), z2) + slack, o2, h), nz - 1)
        flo[r, 0], flo[r, 1], flo[r, 2], fhi[r, 0], fhi[r, 1], fhi[r, 2] = l0, l1, l2, h0, h1, h2
        if l0 <= h0 and l1 <= h1 and l2 <= h2:
            _box_add(touch, (l0, l1, l2), (h0, h1, h2), 1)
    _sums(touch)
    # the solid lies in its box: an untouched cell beyond the box's cells on an axis is outside,
    # and so is every untouched cell joined to one through untouched cells sharing a side
    bl0, bh0 = _cell(box_lo[0], o0, h), _cell(box_hi[0], o0, h)
    bl1, bh1 = _cell(box_lo[1], o1, h), _cell(box_hi[1], o1, h)
    bl2, bh2 = _cell(box_lo[2], o2, h), _cell(box_hi[2], o2, h)
    out = np.zeros((nx, ny, nz), np.bool_)
    queue = np.empty(nx * ny * nz, np.int32)  # a cell's coordinates packed 10 bits each (no divisions)
    n = 0
    for i in range(nx):
        for j in range(ny):
            for q in range(nz):
                if touch[i, j, q] == 0 and (i < bl0 or i > bh0 or j < bl1 or j > bh1 or q < bl2 or q > bh2):
                    out[i, j, q] = True
                    # the flood reaches the same cells in any order, and a seed spreads only to
                    # a neighbour that is no seed: untouched and within the box on all three
                    # axes, which only a seed one cell beyond the box on one axis and within it
                    # on the others has; only those are queued
                    wi, wj, wq = bl0 <= i <= bh0, bl1 <= j <= bh1, bl2 <= q <= bh2
                    if ((wj and wq and (i + 1 == bl0 or i - 1 == bh0)) or (wi and wq and (j + 1 == bl1 or j - 1 == bh1))
                            or (wi and wj and (q + 1 == bl2 or q - 1 == bh2))):
                        queue[n] = (i << 20) | (j << 10) | q
                        n += 1
    at = 0
    while at < n:  # breadth first, the six sides written out (a loop over them branches per side)
        c = queue[at]
        i, j, q = c >> 20, (c >> 10) & 1023, c & 1023
        at += 1
        if i > 0 and not out[i - 1, j, q] and touch[i - 1, j, q] == 0:
            out[i - 1, j, q] = True
            queue[n] = c - (1 << 20)
            n += 1
        if i + 1 < nx and not out[i + 1, j, q] and touch[i + 1, j, q] == 0:
            out[i + 1, j, q] = True
            queue[n] = c + (1 << 20)
            n += 1
        if j > 0 and not out[i, j - 1, q] and touch[i, j - 1, q] == 0:
            out[i, j - 1, q] = True
            queue[n] = c - (1 << 10)
            n += 1
        if j + 1 < ny and not out[i, j + 1, q] and touch[i, j + 1, q] == 0:
            out[i, j + 1, q] = True
            queue[n] = c + (1 << 10)
            n += 1
        if q > 0 and not out[i, j, q - 1] and touch[i, j, q - 1] == 0:
            out[i, j, q - 1] = True
            queue[n] = c - 1
            n += 1
        if q + 1 < nz and not out[i, j, q + 1] and touch[i, j, q + 1] == 0:
            out[i, j, q + 1] = True
            queue[n] = c + 1
            n += 1
    known = np.zeros((nx + 1, ny + 1, nz + 1), np.int32)  # cells not outside, summed
    for i in range(nx):
        for j in range(ny):
            for q in range(nz):
                known[i + 1, j + 1, q + 1] = 0 if out[i, j, q] else 1
    _sums(known)
    # a triangle is clear if every cell within its covering radius (and the slack) of its box is
    # outside; the cells within ``reach`` of the others' boxes are wanted
    want = np.zeros((nx + 1, ny + 1, nz + 1), np.int32)
    wide = reach * (1.0 + 1e-9) + slack  # past the roundings of ``a - reach``, and the slack
    for t in range(tri.shape[0]):
        pad = rho[t] * (1.0 + 1e-9) + slack
        x0, y0, z0 = tri[t, 0, 0], tri[t, 0, 1], tri[t, 0, 2]
        x1, y1, z1 = tri[t, 1, 0], tri[t, 1, 1], tri[t, 1, 2]
        x2, y2, z2 = tri[t, 2, 0], tri[t, 2, 1], tri[t, 2, 2]
        a0, b0 = min(min(x0, x1), x2), max(max(x0, x1), x2)
        a1, b1 = min(min(y0, y1), y2), max(max(y0, y1), y2)
        a2, b2 = min(min(z0, z1), z2), max(max(z0, z1), z2)
        l0, h0 = _cell(a0 - pad, o0, h), _cell(b0 + pad, o0, h)
        l1, h1 = _cell(a1 - pad, o1, h), _cell(b1 + pad, o1, h)
        l2, h2 = _cell(a2 - pad, o2, h), _cell(b2 + pad, o2, h)
        clear = 0 <= l0 and h0 < nx and 0 <= l1 and h1 < ny and 0 <= l2 and h2 < nz
        clear = clear and _box_sum(known, (l0, l1, l2), (h0, h1, h2)) == 0
        keep[t] = not clear
        if clear:
            continue
        l0, h0 = max(_cell(a0, o0, h), 0), min(_cell(b0, o0, h), nx - 1)
        l1, h1 = max(_cell(a1, o1, h), 0), min(_cell(b1, o1, h), ny - 1)
        l2, h2 = max(_cell(a2, o2, h), 0), min(_cell(b2, o2, h), nz - 1)
        for i in range(l0, h0 + 1):  # its cells inside, away from the surface: deeper than the reach
            for j in range(l1, h1 + 1):
                for q in range(l2, h2 + 1):
                    if out[i, j, q] or touch[i, j, q] > 0:
                        continue
                    apart = True  # no touched cell adjoins it
                    for e0 in range(max(i - 1, 0), min(i + 2, nx)):
                        for e1 in range(max(j - 1, 0), min(j + 2, ny)):
                            for e2 in range(max(q - 1, 0), min(q + 2, nz)):
                                apart = apart and touch[e0, e1, e2] == 0
                    if apart:
                        return -1
        l0, h0 = _cell(a0 - wide, o0, h), _cell(b0 + wide, o0, h)
        l1, h1 = _cell(a1 - wide, o1, h), _cell(b1 + wide, o1, h)
        l2, h2 = _cell(a2 - wide, o2, h), _cell(b2 + wide, o2, h)
        if l0 < 0 or h0 >= nx or l1 < 0 or h1 >= ny or l2 < 0 or h2 >= nz:
            return -1  # the kept triangle's reach leaves the grid, whose faces alone are known
        _box_add(want, (l0, l1, l2), (h0, h1, h2), 1)
    _sums(want)
    for i in range(nx, 0, -1):  # the wanted cells' indicator, summed: ``want[i + 1, j + 1, q + 1]``
        for j in range(ny, 0, -1):
            for q in range(nz, 0, -1):
                want[i, j, q] = 1 if want[i - 1, j - 1, q - 1] > 0 else 0
    want[0, :, :] = 0
    want[:, 0, :] = 0
    want[:, :, 0] = 0
    _sums(want)
    m = 0
    for r in range(rows.shape[0]):
        if (flo[r, 0] <= fhi[r, 0] and flo[r, 1] <= fhi[r, 1] and flo[r, 2] <= fhi[r, 2]
                and _box_sum(want, _row(flo, r), _row(fhi, r)) > 0):
            chosen[m] = rows[r]
            m += 1
    return m


def clear_of(points: np.ndarray, faces: np.ndarray, tri: np.ndarray, rho: np.ndarray, slack: float, reach: float,
             box: np.ndarray, cells: int | None = None, near=None, more: int | None = None):
    """Which triangles ``tri (t, 3, 3)`` certainly lie outside a closed mesh (``faces (f, 3) int64``
    into ``points (n, 3)``, inside its ``box (2, 3)``) farther than their covering radii ``rho
    (t,)`` plus ``slack`` from it, and the faces near the others, on a grid of cubic cells over
    the triangles' box padded by ``reach`` and the largest radius (about ``cells`` along its
    longest side). ``near(lo, hi)``, if given, may return rows of ``faces`` (increasing) holding
    every face whose box meets the box ``lo, hi``, or ``None`` (every face is then tested).

    ``slack`` bounds how far the solid's surface lies from the faces (a weld moves their
    corners): a face's box is widened by it. A cell no face's widened box touches holds no
    point of the surface (the cells of a point are monotone in it, so a point of a face lies in
    a cell its box touches); a cell beyond the
    box's cells on an axis holds no point of the solid, and a path through untouched cells
    sharing sides crosses no surface, so every cell so joined to one is outside. A triangle all
    of whose cells within ``rho + slack`` of its box are outside has every point outside and
    every corner farther than ``rho`` from the surface, so eq. (4) bounds it by 0
    (`pipeline.clearance`).

    Returns ``(keep (t,) bool, chosen (m,) int64, reach)``: the triangles not proven clear, the
    rows of ``faces`` whose boxes come within ``reach`` of a kept triangle's box, increasing (a
    superset: the faces touching the cells those boxes touch), and ``reach``, widened by `MORE`
    cells (a kept triangle may lie a few cells from the surface). ``None`` if a kept triangle's
    box padded by ``reach`` leaves the grid, or its box meets a cell inside the mesh that no
    touched cell adjoins (a point there may lie deeper than ``reach``: the caller's part would
    not answer it).
    """
    cells = CELLS if cells is None else cells
    tri = np.ascontiguousarray(tri, np.float64).reshape(-1, 3, 3)
    lo, hi = bounds(tri) if len(tri) else (np.zeros(3), np.zeros(3))  # compiled: numpy reduces an axis of 3 row by row
    more = MORE if more is None else more
    margin = reach + float(rho.max(initial=0.0)) * (1.0 + 1e-9) + slack
    h = float((hi - lo).max() + 2.0 * margin) / (cells - 2 - 2 * more)
    if not h > 0 or not np.isfinite(h):
        return None
    reach += more * h  # a kept triangle may lie a few cells from the surface
    margin += more * h
    origin = lo - margin - h  # a cell of room on every side for the roundings of the cells
    dims = np.maximum(np.ceil((hi + margin + h - origin) / h).astype(np.int64) + 1, 1)
    if dims.max() >= 1024:  # a cell's coordinates are packed in 10 bits each
        return None
    top = origin + dims * h
    rows = None if near is None else near(origin - h, top + h)
    if rows is None:
        rows = faces_meet_rows(points, faces, origin, top, h)  # every face whose box meets the grid
    keep, chosen = np.empty(len(tri), np.bool_), np.empty(len(rows), np.int64)
    m = _clear_cells(np.ascontiguousarray(points, np.float64), _read_only(faces), rows, tri,
                     np.ascontiguousarray(rho, np.float64), float(slack), float(reach), origin, h, dims,
                     np.ascontiguousarray(box[0], np.float64), np.ascontiguousarray(box[1], np.float64), keep, chosen)
    if m < 0:
        return None
    return keep, chosen[:m].copy(), reach
