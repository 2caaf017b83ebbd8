"""The narrow phase's box culls, compiled: which triangles of two sets can meet the other set.

Before the triangle pairs are tested (fcl, `pipeline.detect.intersect`), each side keeps the
triangles whose box overlaps the box of the other side's kept triangles, twice over. Boxes are
minima and maxima and the overlap test ``lo_a <= hi_b + pad and lo_b <= hi_a + pad`` is the same
comparison of the same sums as `pipeline.grids.overlap`, so the kept rows are the array form's.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["THIN", "compact", "crossings", "face_boxes", "patches_near", "patch_rows_near", "rows_in_box", "solid_mask", "thin_faces",
           "triangles_near"]


@njit(cache=True, nogil=True)
def _face_boxes(points, faces, lo, hi):
    for i in range(faces.shape[0]):
        a, b, c = faces[i, 0], faces[i, 1], faces[i, 2]
        for k in range(3):
            x, y, z = points[a, k], points[b, k], points[c, k]
            lo[i, k] = min(min(x, y), z)
            hi[i, k] = max(max(x, y), z)


def face_boxes(points: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Boxes ``lo, hi (f, 3)`` of the triangles ``faces (f, 3) int64`` of ``points (n, 3)``
    (`pipeline.grids.triangle_boxes` of ``points[faces]``, without gathering the corners)."""
    lo, hi = np.empty((len(faces), 3)), np.empty((len(faces), 3))
    if len(faces):
        _face_boxes(np.ascontiguousarray(points, np.float64), np.ascontiguousarray(faces, np.int64), lo, hi)
    return lo, hi


@njit(cache=True, nogil=True)
def _bounds_of(lo, hi, keep, out):
    """Box ``out (2, 3)`` of the kept boxes; False if none is kept."""
    any_ = False
    for k in range(3):
        out[0, k], out[1, k] = np.inf, -np.inf
    for i in range(lo.shape[0]):
        if keep[i]:
            any_ = True
            for k in range(3):
                out[0, k] = min(out[0, k], lo[i, k])
                out[1, k] = max(out[1, k], hi[i, k])
    return any_


@njit(cache=True, nogil=True)
def _cull(lo, hi, keep, box, pad):
    for i in range(lo.shape[0]):
        if keep[i]:
            for k in range(3):
                if not (lo[i, k] <= box[1, k] + pad and box[0, k] <= hi[i, k] + pad):
                    keep[i] = False
                    break


@njit(cache=True, nogil=True)
def _cull_rows(lo, hi, rows, n, lo_o, hi_o, rows_o, n_o, box, pad):
    """Of the rows ``rows[:n]`` of boxes ``lo, hi``, those overlapping (within ``pad``) the box of
    the other side's rows ``rows_o[:n_o]``, moved to the front in their order; returns how many.
    The box is `_bounds_of`'s and the test `_cull`'s, over the same rows in the same order."""
    if n_o == 0:
        return 0
    for k in range(3):
        box[0, k], box[1, k] = np.inf, -np.inf
    for j in range(n_o):
        i = rows_o[j]
        for k in range(3):
            box[0, k] = min(box[0, k], lo_o[i, k])
            box[1, k] = max(box[1, k], hi_o[i, k])
    m = 0
    for j in range(n):
        i = rows[j]
        ok = True
        for k in range(3):
            if not (lo[i, k] <= box[1, k] + pad and box[0, k] <= hi[i, k] + pad):
                ok = False
                break
        if ok:
            rows[m] = i
            m += 1
    return m


@njit(cache=True, nogil=True)
def _near(lo_a, hi_a, lo_b, hi_b, pad, rounds, rows_a, rows_b):
    # after the first cull each side walks its kept rows alone (a contact keeps a few of
    # thousands), not a flag per row: the same rows, boxes and tests as flagging every row
    na, nb = rows_a.shape[0], rows_b.shape[0]
    box = np.empty((2, 3))
    for _ in range(rounds):
        na = _cull_rows(lo_a, hi_a, rows_a, na, lo_b, hi_b, rows_b, nb, box, pad)
        nb = _cull_rows(lo_b, hi_b, rows_b, nb, lo_a, hi_a, rows_a, na, box, pad)
    return na, nb


@njit(cache=True, nogil=True)
def _patches_near(lo_a, hi_a, bounds_a, lo_b, hi_b, bounds_b, pad, keep_a, keep_b, box_b, pv_a, pv_b, rows_a, rows_b):
    keep_a[:] = True
    _cull(lo_a, hi_a, keep_a, bounds_b, pad)
    keep_b[:] = True
    _cull(lo_b, hi_b, keep_b, bounds_a, pad)
    meet_a, meet_b = np.zeros(keep_a.shape[0], np.bool_), np.zeros(keep_b.shape[0], np.bool_)
    for i in range(lo_a.shape[0]):
        if not keep_a[i]:
            continue
        for j in range(lo_b.shape[0]):
            if not keep_b[j]:
                continue
            ok = True
            for k in range(3):
                if not (lo_a[i, k] <= hi_b[j, k] + pad and lo_b[j, k] <= hi_a[i, k] + pad):
                    ok = False
                    break
            if ok:
                meet_a[i] = True
                meet_b[j] = True
    keep_a[:] = meet_a
    keep_b[:] = meet_b
    return _bounds_of(lo_b, hi_b, keep_b, box_b), _grid_rows(keep_a, pv_a, rows_a), _grid_rows(keep_b, pv_b, rows_b)


@njit(cache=True, nogil=True)
def _grid_rows(keep, pv, rows):
    """The kept rows of a row-major grid of ``pv`` columns as ``(row, column)`` pairs in
    ``rows``, in order (``np.argwhere`` of the grid's mask); returns how many."""
    m = 0
    for i in range(keep.shape[0]):
        if keep[i]:
            rows[m, 0], rows[m, 1] = i // pv, i % pv
            m += 1
    return m


def _broad_phase(box_a: tuple[np.ndarray, np.ndarray], bounds_a: np.ndarray, box_b: tuple[np.ndarray, np.ndarray],
                 bounds_b: np.ndarray, pad: float, pv_a: int, pv_b: int):
    """`_patches_near`'s outputs: kept rows ``(n,) bool`` of each side, ``b``'s kept box ``(2, 3)``
    or None, and each side's kept ``(row, column)`` pairs ``(m, 2) int64`` of a grid of
    ``pv_a`` (``pv_b``) columns."""
    f = lambda x: np.ascontiguousarray(x, np.float64).reshape(-1, 3)  # noqa: E731
    # The bounds are copied: `detect` shares them read-only, and numba types a read-only array
    # apart from a writable one (each type a specialisation of `_cull`, compiled and cached again).
    g = lambda x: np.array(x, np.float64).reshape(2, 3)  # noqa: E731
    lo_a, hi_a, lo_b, hi_b = f(box_a[0]), f(box_a[1]), f(box_b[0]), f(box_b[1])
    keep_a, keep_b, box = np.empty(len(lo_a), np.bool_), np.empty(len(lo_b), np.bool_), np.empty((2, 3))
    rows_a, rows_b = np.empty((len(lo_a), 2), np.int64), np.empty((len(lo_b), 2), np.int64)
    any_b, na, nb = _patches_near(lo_a, hi_a, g(bounds_a), lo_b, hi_b, g(bounds_b), float(pad), keep_a, keep_b, box,
                                  np.int64(pv_a), np.int64(pv_b), rows_a, rows_b)
    return keep_a, keep_b, box if any_b else None, rows_a[:na], rows_b[:nb]


def patches_near(box_a: tuple[np.ndarray, np.ndarray], bounds_a: np.ndarray, box_b: tuple[np.ndarray, np.ndarray],
                 bounds_b: np.ndarray, pad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The broad phase of two surfaces in one pass: of side ``a``'s patch boxes ``lo, hi (n, 3)``
    those overlapping (within ``pad``) the other side's whole box ``bounds_b (2, 3)``, the same
    of ``b``'s against ``bounds_a``, then of those the ones overlapping some box kept on the
    other side. Returns the kept rows ``(m,) bool`` of each side and the box ``(2, 3)`` of
    ``b``'s kept boxes (``None`` if none is kept)."""
    return _broad_phase(box_a, bounds_a, box_b, bounds_b, pad, 1, 1)[:3]


def patch_rows_near(box_a: tuple[np.ndarray, np.ndarray], bounds_a: np.ndarray, box_b: tuple[np.ndarray, np.ndarray],
                    bounds_b: np.ndarray, pad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """`patches_near` of two grids of level-0 patch boxes ``lo, hi (P0u, P0v, 3)``, its kept
    boxes given as patches ``(m, 2) int64``, row-major (``np.argwhere`` of each side's kept
    mask), from the same pass: each side's patches and the box ``(2, 3)`` of ``b``'s kept
    boxes (``None`` if none is kept)."""
    _, _, box, ca, cb = _broad_phase(box_a, bounds_a, box_b, bounds_b, pad, box_a[0].shape[1], box_b[0].shape[1])
    return ca, cb, box


def triangles_near(box_a: tuple[np.ndarray, np.ndarray], box_b: tuple[np.ndarray, np.ndarray], pad: float,
                   rounds: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``(m,) int64`` of side ``a``'s and side ``b``'s triangles, given by their boxes
    ``lo, hi (f, 3)``, whose boxes overlap (within ``pad``) the box of the other side's kept
    ones: ``a`` against ``b``'s, then ``b`` against ``a``'s kept, ``rounds`` times."""
    rows_a, rows_b = np.arange(len(box_a[0]), dtype=np.int64), np.arange(len(box_b[0]), dtype=np.int64)
    na, nb = _near(np.ascontiguousarray(box_a[0], np.float64), np.ascontiguousarray(box_a[1], np.float64),
                   np.ascontiguousarray(box_b[0], np.float64), np.ascontiguousarray(box_b[1], np.float64), float(pad),
                   int(rounds), rows_a, rows_b)
    return rows_a[:na], rows_b[:nb]


@njit(cache=True, nogil=True)
def _rows_in_box(points, uv, rows, lo, hi, pts_out, uv_out):
    n = 0
    for j in range(rows.shape[0]):
        r = rows[j]
        x, y, z = points[r, 0], points[r, 1], points[r, 2]
        if lo[0] <= x <= hi[0] and lo[1] <= y <= hi[1] and lo[2] <= z <= hi[2]:
            pts_out[n, 0], pts_out[n, 1], pts_out[n, 2] = x, y, z
            uv_out[n, 0], uv_out[n, 1] = uv[r, 0], uv[r, 1]
            n += 1
    return n


def rows_in_box(points: np.ndarray, uv: np.ndarray, rows: np.ndarray, lo: np.ndarray, hi: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Of the rows ``rows (m,) int64`` of ``points (n, 3) float64`` and their parameters ``uv (n,
    2) float64``, those with ``lo <= point <= hi`` on every axis (``lo, hi (3,) float64``), in
    order: ``points[rows][keep]`` and ``uv[rows][keep]`` for the array form's ``keep = np.all((p
    >= lo) & (p <= hi), axis=1)`` (a NaN coordinate fails it), the same values, in one pass
    instead of two gathers and a mask of every candidate row."""
    rows = np.ascontiguousarray(rows, np.int64)
    pts, puv = np.empty((len(rows), 3)), np.empty((len(rows), 2))
    n = _rows_in_box(np.ascontiguousarray(points, np.float64), np.ascontiguousarray(uv, np.float64), rows,
                     np.ascontiguousarray(lo, np.float64), np.ascontiguousarray(hi, np.float64), pts, puv)
    return pts[:n], puv[:n]


@njit(cache=True, nogil=True)
def _compact(n, faces):
    rank = np.full(n, -1, np.int64)
    for i in range(faces.shape[0]):
        for k in range(3):
            rank[faces[i, k]] = 0
    used = 0
    for v in range(n):
        if rank[v] == 0:
            rank[v] = used
            used += 1
    rows = np.empty(used, np.int64)
    for v in range(n):
        if rank[v] >= 0:
            rows[rank[v]] = v
    tri = np.empty((faces.shape[0], 3), np.int32)
    for i in range(faces.shape[0]):
        for k in range(3):
            tri[i, k] = rank[faces[i, k]]
    return rows, tri


def compact(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The vertices ``(u, 3) float64`` that ``faces (f, 3)`` use, in ascending row order, and the
    faces renumbered into them ``(f, 3) int32``, both contiguous: ``np.unique(faces,
    return_inverse=True)``'s rows and inverse, by marking the used rows instead of sorting."""
    rows, tri = _compact(len(vertices), np.ascontiguousarray(faces, np.int64).reshape(-1, 3))
    return np.ascontiguousarray(vertices[rows], np.float64), tri


@njit(cache=True, nogil=True)
def _solid_mask(points, triangles, collapse, out):
    for r in range(points.shape[0]):
        side, nan = 0.0, False
        for k in range(3):
            lo, hi = points[r, 0, k], points[r, 0, k]
            for i in range(points.shape[1]):
                x = points[r, i, k]
                if x != x:
                    nan = True
                lo, hi = min(lo, x), max(hi, x)
            if hi - lo != hi - lo:  # an infinite coordinate: numpy's extent is NaN
                nan = True
            side = max(side, hi - lo)
        tol = np.nan if nan else collapse * max(side, 1e-300)
        for f in range(triangles.shape[0]):
            keep = True
            for e in range(3):
                a, b = triangles[f, e], triangles[f, (e + 2) % 3]
                dx = points[r, a, 0] - points[r, b, 0]
                dy = points[r, a, 1] - points[r, b, 1]
                dz = points[r, a, 2] - points[r, b, 2]
                if not np.sqrt(dx * dx + dy * dy + dz * dz) > tol:
                    keep = False
                    break
            out[r, f] = keep


def solid_mask(points: np.ndarray, triangles: np.ndarray, collapse: float) -> np.ndarray:
    """For grids ``points (r, n, 3)`` sharing ``triangles (f, 3) int64``: ``(r, f) bool``, whether
    each triangle's three edges are longer than ``collapse`` times its grid's extent (the largest
    side of the grid's box, at least 1e-300; NaN coordinates keep no row). Each edge length is
    ``np.linalg.norm`` of the corner difference as numpy rounds it (squares summed in order), so
    the rows are those of the array form (`pipeline.grids.solid_rows`) without its ``(r, f, 3, 3)``
    gathers."""
    out = np.zeros((points.shape[0], len(triangles)), np.bool_)
    if out.size and points.shape[1]:
        _solid_mask(np.ascontiguousarray(points, np.float64), np.ascontiguousarray(triangles, np.int64), float(collapse), out)
    return out


# --- fcl's triangle-pair test, for the count of contacts ---------------------------------------
THIN = 1e-12  # squared sine of a triangle's sharpest corner below which `crossings` leaves the pair to fcl


@njit(cache=True, nogil=True)
def _lt_min(a, b):  # std::min(a, b)
    return b if b < a else a


@njit(cache=True, nogil=True)
def _lt_max(a, b):  # std::max(a, b)
    return b if a < b else a


@njit(cache=True, nogil=True)
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(cache=True, nogil=True)
def _project6(a0, a1, a2, w):
    """fcl's ``Intersect::project6``: whether the projections of triangle ``w[0:3]`` and triangle
    ``w[3:6]`` on the axis overlap (each dot product summed as Eigen sums a 3-vector's)."""
    p1 = a0 * w[0, 0] + a1 * w[0, 1] + a2 * w[0, 2]
    p2 = a0 * w[1, 0] + a1 * w[1, 1] + a2 * w[1, 2]
    p3 = a0 * w[2, 0] + a1 * w[2, 1] + a2 * w[2, 2]
    q1 = a0 * w[3, 0] + a1 * w[3, 1] + a2 * w[3, 2]
    q2 = a0 * w[4, 0] + a1 * w[4, 1] + a2 * w[4, 2]
    q3 = a0 * w[5, 0] + a1 * w[5, 1] + a2 * w[5, 2]
    if _lt_min(p1, _lt_min(p2, p3)) > _lt_max(q1, _lt_max(q2, q3)):
        return False
    if _lt_min(q1, _lt_min(q2, q3)) > _lt_max(p1, _lt_max(p2, p3)):
        return False
    return True


@njit(cache=True, nogil=True, inline="always")
def _sat(P, Q, w, e, f):
    """fcl's ``Intersect::intersect_Triangle`` test (17 axes) of triangles ``P, Q (3, 3)``, in its
    arithmetic: both moved by ``-P[0]`` into ``w (6, 3)``, edges ``p2 - p1, p3 - p2, p1 - p3``
    into ``e, f (3, 3)``. It runs per pair of overlapping boxes, so it is inlined and works in
    the caller's buffers: a compiled call takes and drops the reference count of each array
    handed to it, and two arrays allocated per call cost a good part of its arithmetic."""
    for r in range(3):
        for k in range(3):
            w[r, k] = P[r, k] - P[0, k]
            w[3 + r, k] = Q[r, k] - P[0, k]
    for k in range(3):
        e[0, k], e[1, k], e[2, k] = w[1, k] - w[0, k], w[2, k] - w[1, k], w[0, k] - w[2, k]
        f[0, k], f[1, k], f[2, k] = w[4, k] - w[3, k], w[5, k] - w[4, k], w[3, k] - w[5, k]
    n0, n1, n2 = _cross(e[0, 0], e[0, 1], e[0, 2], e[1, 0], e[1, 1], e[1, 2])
    if not _project6(n0, n1, n2, w):
        return False
    m0, m1, m2 = _cross(f[0, 0], f[0, 1], f[0, 2], f[1, 0], f[1, 1], f[1, 2])
    if not _project6(m0, m1, m2, w):
        return False
    for i in range(3):
        for j in range(3):
            a0, a1, a2 = _cross(e[i, 0], e[i, 1], e[i, 2], f[j, 0], f[j, 1], f[j, 2])
            if not _project6(a0, a1, a2, w):
                return False
    for i in range(3):
        a0, a1, a2 = _cross(e[i, 0], e[i, 1], e[i, 2], n0, n1, n2)
        if not _project6(a0, a1, a2, w):
            return False
    for i in range(3):
        a0, a1, a2 = _cross(f[i, 0], f[i, 1], f[i, 2], m0, m1, m2)
        if not _project6(a0, a1, a2, w):
            return False
    return True


@njit(cache=True, nogil=True)
def _plane(T):
    """fcl's ``buildTrianglePlane``: unit normal of ``(v2 - v1) x (v3 - v1)`` (divided by the root
    of its squared norm) and its offset ``n . v1``; the squared norm of the cross product, and
    the squared sine of the triangle's sharpest corner."""
    u0, u1, u2 = T[1, 0] - T[0, 0], T[1, 1] - T[0, 1], T[1, 2] - T[0, 2]
    v0, v1, v2 = T[2, 0] - T[0, 0], T[2, 1] - T[0, 1], T[2, 2] - T[0, 2]
    c0, c1, c2 = _cross(u0, u1, u2, v0, v1, v2)
    sq = c0 * c0 + c1 * c1 + c2 * c2
    d0, d1, d2 = T[2, 0] - T[1, 0], T[2, 1] - T[1, 1], T[2, 2] - T[1, 2]
    lu, lv, ld = u0 * u0 + u1 * u1 + u2 * u2, v0 * v0 + v1 * v1 + v2 * v2, d0 * d0 + d1 * d1 + d2 * d2
    lens = max(max(lu * lv, lu * ld), lv * ld)  # |n|^2 over it: the squared sine of the sharpest corner
    if sq > 0:
        r = np.sqrt(sq)
        c0, c1, c2 = c0 / r, c1 / r, c2 / r
    t = c0 * T[0, 0] + c1 * T[0, 1] + c2 * T[0, 2]
    return c0, c1, c2, t, sq, sq / lens if lens > 0 else 0.0


@njit(cache=True, nogil=True)
def _deepest(T, n0, n1, n2, t):
    """fcl's ``computeDeepestPoints`` of a triangle's corners against a plane: the largest depth
    and how many points it reports (within 1e-6 of it; none if every corner is clear of the plane
    by 1e-5 on one side, or the deepest is 1e-5 above it)."""
    eps = 1e-5
    best = -1.7976931348623157e308
    count, pos, neg, zero = 0, 0, 0, 0
    for i in range(3):
        dist = -((n0 * T[i, 0] + n1 * T[i, 1] + n2 * T[i, 2]) - t)
        if dist > eps:
            pos += 1
        elif dist < -eps:
            neg += 1
        else:
            zero += 1
        if dist > best:
            best = dist
            count = 1
        elif dist + 1e-6 >= best:
            count += 1
    if best < -eps:
        count = 0
    if zero == 0 and (neg == 0 or pos == 0):
        count = 0
    return best, count


@njit(cache=True, nogil=True)
def _orient(T, a, b, c, U, d):
    """Sign of ``((b - a) x (c - a)) . (d - a)`` (rows ``a, b, c`` of ``T``, ``d`` of ``U``): +1 or
    -1, or 0 unless it exceeds 1e-12 of the product of the three lengths (rounding's bound)."""
    u0, u1, u2 = T[b, 0] - T[a, 0], T[b, 1] - T[a, 1], T[b, 2] - T[a, 2]
    v0, v1, v2 = T[c, 0] - T[a, 0], T[c, 1] - T[a, 1], T[c, 2] - T[a, 2]
    w0, w1, w2 = U[d, 0] - T[a, 0], U[d, 1] - T[a, 1], U[d, 2] - T[a, 2]
    c0, c1, c2 = _cross(u0, u1, u2, v0, v1, v2)
    det = c0 * w0 + c1 * w1 + c2 * w2
    scale = np.sqrt((u0 * u0 + u1 * u1 + u2 * u2) * (v0 * v0 + v1 * v1 + v2 * v2) * (w0 * w0 + w1 * w1 + w2 * w2))
    if det > 1e-12 * scale:
        return 1
    if det < -1e-12 * scale:
        return -1
    return 0


@njit(cache=True, nogil=True)
def _edge_through(T, U, E):
    """Whether an edge of ``U`` passes through the inside of triangle ``T``, every sign sure:
    its ends on both sides of ``T``'s plane, and ``T``'s corners all on one side of it."""
    # rows as int64, not literals: a literal argument compiles a specialisation of `_orient` of
    # its own (four of them, ~0.3 s each in the first run); these make it one
    r0, r1, r2, r3, r4 = np.int64(0), np.int64(1), np.int64(2), np.int64(3), np.int64(4)
    for e in range(3):
        d, f = e, (e + 1) % 3
        sd, sf = _orient(T, r0, r1, r2, U, d), _orient(T, r0, r1, r2, U, f)
        if sd == 0 or sf == 0 or sd == sf:
            continue
        # the edge's side of T's edges: orient(d, f, corner, next corner) by rows of one array
        for r in range(3):
            for k in range(3):
                E[r, k] = T[r, k]
            E[3, 0], E[3, 1], E[3, 2] = U[d, 0], U[d, 1], U[d, 2]
            E[4, 0], E[4, 1], E[4, 2] = U[f, 0], U[f, 1], U[f, 2]
        s0, s1, s2 = _orient(E, r3, r4, r0, E, r1), _orient(E, r3, r4, r1, E, r2), _orient(E, r3, r4, r2, E, r0)
        if s0 != 0 and s0 == s1 and s1 == s2:
            return True
    return False


@njit(cache=True, nogil=True)
def _side(points, faces, rows, thin, lo, hi, reach, flag):
    """Per triangle ``faces[rows]``: box ``lo, hi``, diagonal of the box ``reach`` and whether it
    is degenerate or thin ``flag``."""
    T = np.empty((3, 3))
    for i in range(len(rows)):
        for r in range(3):
            for k in range(3):
                T[r, k] = points[faces[rows[i], r], k]
        d = 0.0
        for k in range(3):
            lo[i, k] = min(min(T[0, k], T[1, k]), T[2, k])
            hi[i, k] = max(max(T[0, k], T[1, k]), T[2, k])
            d += (hi[i, k] - lo[i, k]) * (hi[i, k] - lo[i, k])
        reach[i] = np.sqrt(d)
        flag[i] = not (_plane(T)[5] > thin)


@njit(cache=True, nogil=True)
def _crossings(pa, fa, ka, pb, fb, kb, pad, thin, first):
    w, E = np.empty((6, 3)), np.empty((5, 3))
    P, Q, e, f = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    lo_a, hi_a, lo_b, hi_b = np.empty((len(ka), 3)), np.empty((len(ka), 3)), np.empty((len(kb), 3)), np.empty((len(kb), 3))
    reach_a, reach_b = np.empty(len(ka)), np.empty(len(kb))
    thin_a, thin_b = np.empty(len(ka), np.bool_), np.empty(len(kb), np.bool_)
    _side(pa, fa, ka, thin, lo_a, hi_a, reach_a, thin_a)
    _side(pb, fb, kb, thin, lo_b, hi_b, reach_b, thin_b)
    total, unsure = 0, False
    for i in range(len(ka)):
        for r in range(3):
            for k in range(3):
                P[r, k] = pa[fa[ka[i], r], k]
        for j in range(len(kb)):
            odd = thin_a[i] or thin_b[j]
            # a pair with a degenerate or thin triangle is looked at as far as fcl's leaf boxes
            # (oriented, around each triangle, within twice its box's diagonal) can meet
            gap = pad + (2.0 * (reach_a[i] + reach_b[j]) if odd else 0.0)
            if not (lo_a[i, 0] <= hi_b[j, 0] + gap and lo_b[j, 0] <= hi_a[i, 0] + gap and lo_a[i, 1] <= hi_b[j, 1] + gap
                    and lo_b[j, 1] <= hi_a[i, 1] + gap and lo_a[i, 2] <= hi_b[j, 2] + gap and lo_b[j, 2] <= hi_a[i, 2] + gap):
                continue
            for r in range(3):
                for k in range(3):
                    Q[r, k] = pb[fb[kb[j], r], k]
            if not _sat(P, Q, w, e, f):
                continue  # fcl, testing the pair, finds the same axis apart
            a0, a1, a2, ta, sqa, _ = _plane(P)
            b0, b1, b2, tb, sqb, _ = _plane(Q)
            # its axes may separate nothing: unless it surely crosses (so fcl's BVHs meet it too)
            # and both planes are set, whether fcl counts it is its BVHs' to say
            if odd and not (sqa > 0 and sqb > 0 and (_edge_through(P, Q, E) or _edge_through(Q, P, E))):
                unsure = True
                continue
            depth2, count2 = _deepest(Q, a0, a1, a2, ta)
            depth1, count1 = _deepest(P, b0, b1, b2, tb)
            total += min(count2, 2) if depth1 > depth2 else min(count1, 2)
            if first and total:
                return total, unsure
    return total, unsure


def crossings(pa: np.ndarray, fa: np.ndarray, ka: np.ndarray, pb: np.ndarray, fb: np.ndarray, kb: np.ndarray,
              pad: float, first: bool = False) -> tuple[int, bool]:
    """The contacts ``fcl.collide`` reports between side ``a``'s triangles ``fa[ka]`` on points
    ``pa (n, 3)`` and side ``b``'s ``fb[kb]`` on ``pb (m, 3)``: how many the pairs this count can
    answer for give, and whether some pair's are left unknown (then fcl reports at least as
    many).

    fcl tests the triangle pairs its BVHs (oriented boxes) do not separate by the 17 axes of
    ``Intersect::intersect_Triangle`` and gives a crossing pair the deepest points
    (``computeDeepestPoints``, at most 2) of the side its planes choose; here the same
    arithmetic runs on every pair whose boxes overlap within ``pad``. A pair the axes part
    gives fcl nothing whether it tests it or not. A pair they pass meets (touches, to
    rounding), so its boxes overlap and fcl's BVHs do not part it: both count the same pairs.
    That holds for triangles whose axes are true directions. A degenerate triangle (no plane)
    or a thin one (the squared sine of its sharpest corner at most `THIN`) may pass the axes
    apart from the other: such a pair passing them, looked for as far as fcl's leaf boxes
    reach, counts only if an edge of one surely passes through the other (every orientation's
    sign beyond rounding) and both have planes; else its contacts are unknown (fcl's planes of
    a degenerate triangle are unset, and whether it tests a pair apart is its BVHs' to say).

    With ``first``, the pass stops at the first pair that gives a contact: a count above 0 is
    then a lower bound (whether the sets cross is all it answers), a count of 0 the whole
    pass's."""
    if not len(ka) or not len(kb):
        return 0, False
    total, unsure = _crossings(np.ascontiguousarray(pa, np.float64), np.ascontiguousarray(fa, np.int64),
                               np.ascontiguousarray(ka, np.int64), np.ascontiguousarray(pb, np.float64),
                               np.ascontiguousarray(fb, np.int64), np.ascontiguousarray(kb, np.int64), float(pad), THIN,
                               bool(first))
    return int(total), bool(unsure)


@njit(cache=True, nogil=True)
def _thin_faces(points, faces, thin, out):
    T = np.empty((3, 3))
    for i in range(faces.shape[0]):
        for r in range(3):
            for k in range(3):
                T[r, k] = points[faces[i, r], k]
        out[i] = not (_plane(T)[5] > thin)


def thin_faces(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Which ``faces (f, 3) int64`` of ``points (n, 3)`` are degenerate or thin (`crossings`'
    test, `THIN`): ``(f,) bool``."""
    out = np.zeros(len(faces), np.bool_)
    if len(faces):
        _thin_faces(np.ascontiguousarray(points, np.float64), np.ascontiguousarray(faces, np.int64), THIN, out)
    return out
