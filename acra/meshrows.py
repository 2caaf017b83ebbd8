"""Rows of a triangle mesh picked out in compiled passes: the faces near a box, their chunks, the
corners of chosen faces, points by barycentric coordinates, and distinct points.

The residual a user sees (`pipeline.residual`) measures the display triangles near the other
object: which faces' boxes come within a padded box (`faces_meet_rows`, through the boxes of
`CHUNK`-face chunks and groups of chunks where a display's chunk lists are kept,
`chunk_vertices`, `face_chunks`), their corners (`faces_at`; with their box and a shift,
`faces_placed`), the points found inside and their parameters (`barycentric`, numpy einsum's
arithmetic to the bit), and the distinct points of a
set with each row's first equal row (`first_rows`, `distinct_rows`, by the bits of the
coordinates). Each is one compiled loop over the rows where numpy would build a boolean array
per comparison.

Arrays are float64 unless stated.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["boxes_meet", "faces_meet_rows", "CHUNK", "chunk_vertices", "face_chunks", "faces_at", "faces_placed",
           "barycentric", "first_rows", "distinct_rows"]


@njit(cache=True, nogil=True)
def _boxes_meet(tri, lo, hi, pad, out):
    for i in range(tri.shape[0]):
        meet = True
        for k in range(3):
            a, b, c = tri[i, 0, k], tri[i, 1, k], tri[i, 2, k]
            if not (min(min(a, b), c) <= hi[k] + pad and lo[k] <= max(max(a, b), c) + pad):
                meet = False
                break
        out[i] = meet


def boxes_meet(tri: np.ndarray, lo: np.ndarray, hi: np.ndarray, pad: float = 0.0) -> np.ndarray:
    """Whether the box of each of triangles ``tri (f, 3, 3)`` comes within ``pad`` of the box
    ``lo, hi (3,)``: ``(f,) bool``, the comparisons of ``grids.overlap`` on the corners' minima
    and maxima, in one pass without the boxes' arrays."""
    t = np.ascontiguousarray(tri, np.float64).reshape(-1, 3, 3)
    out = np.empty(len(t), np.bool_)
    if len(t):
        _boxes_meet(t, np.ascontiguousarray(lo, np.float64).reshape(3), np.ascontiguousarray(hi, np.float64).reshape(3),
                    float(pad), out)
    return out


def _read_only(faces: np.ndarray) -> np.ndarray:
    """``faces`` as C-contiguous int64, read-only (a view where it is writeable): a display's
    triangles turn read-only once digested (`pipeline.residual`), and numba compiles a kernel once
    per writeability, so the kernels that take them see one kind."""
    f = np.ascontiguousarray(faces, np.int64)
    if f.flags.writeable:
        f = f.view()
        f.flags.writeable = False
    return f


@njit(inline="always")
def _beyond(points, v, lo0, lo1, lo2, top0, top1, top2, pad):
    # point ``v``'s side bits against the box padded by ``pad`` (``top`` = ``hi + pad``): bits 1,
    # 4, 16 where it lies below the box on x, y, z, bits 2, 8, 32 where above
    x, y, z = points[v, 0], points[v, 1], points[v, 2]
    bits = 0
    if not lo0 <= x + pad:
        bits |= 1
    if not x <= top0:
        bits |= 2
    if not lo1 <= y + pad:
        bits |= 4
    if not y <= top1:
        bits |= 8
    if not lo2 <= z + pad:
        bits |= 16
    if not z <= top2:
        bits |= 32
    return bits


@njit(cache=True, nogil=True)
def _faces_meet_rows(points, faces, lo, hi, pad, beyond, out):
    # a face's box misses the padded box on an axis exactly when all three corners lie beyond the
    # same side: ``min <= hi + pad`` holds iff some corner is ``<= hi + pad``, and ``lo <= max + pad``
    # iff some corner has ``lo <= x + pad`` (rounding ``x + pad`` is monotone in ``x``, so it
    # commutes with the max). So each point is compared once, a bit per side per axis, and a face
    # meets the box unless its corners' bits share one.
    top0, top1, top2 = hi[0] + pad, hi[1] + pad, hi[2] + pad
    lo0, lo1, lo2 = lo[0], lo[1], lo[2]
    for v in range(points.shape[0]):
        beyond[v] = _beyond(points, v, lo0, lo1, lo2, top0, top1, top2, pad)
    n = 0
    for i in range(faces.shape[0]):
        if beyond[faces[i, 0]] & beyond[faces[i, 1]] & beyond[faces[i, 2]] == 0:
            out[n] = i
            n += 1
    return n


def faces_meet_rows(points: np.ndarray, faces: np.ndarray, lo: np.ndarray, hi: np.ndarray, pad: float = 0.0,
                    chunks: tuple | None = None) -> np.ndarray:
    """The rows ``(m,) int64`` of ``faces`` (``(f, 3) int64`` into ``points (n, 3) float64``, finite)
    whose triangles' boxes come within ``pad`` of the box ``lo, hi`` (`boxes_meet`'s comparisons,
    the same answers), in increasing order, without gathering the triangles: each point is
    compared with the box once, however many faces share it. With ``chunks`` (`face_chunks` of
    these points and faces) only the faces of the chunks whose boxes come within ``pad`` are
    compared, the same rows."""
    out = np.empty(len(faces), np.int64)
    n = 0
    if len(faces):
        p = np.ascontiguousarray(points, np.float64)
        lo3, hi3 = np.ascontiguousarray(lo, np.float64).reshape(3), np.ascontiguousarray(hi, np.float64).reshape(3)
        if chunks is None:
            n = _faces_meet_rows(p, _read_only(faces), lo3, hi3, float(pad), np.empty(len(p), np.uint8), out)
        else:
            n = _faces_meet_chunks(p, _read_only(faces), CHUNK, *chunks, lo3, hi3, float(pad), out)
    return out[:n].copy()


CHUNK = 32  # `face_chunks`: consecutive faces a chunk, consecutive chunks a group


@njit(cache=True, nogil=True)
def _chunk_vertices(faces, size, n, start, verts):
    seen = np.full(n, -1, np.int64)  # the last chunk each point was listed for
    k = 0
    for c in range(start.shape[0] - 1):
        start[c] = k
        for i in range(c * size, min((c + 1) * size, faces.shape[0])):
            for j in range(3):
                v = faces[i, j]
                if seen[v] != c:
                    seen[v] = c
                    verts[k] = v
                    k += 1
    start[start.shape[0] - 1] = k
    return k


def chunk_vertices(faces: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The points each chunk of `CHUNK` consecutive rows of ``faces (f, 3) int64`` (into ``n``
    points) uses, once each: ``(start (c + 1,) int64, verts (k,) int64)``, chunk ``c``'s points
    ``verts[start[c]:start[c + 1]]``. A function of the faces alone: a display's topology gives
    it to every display on it (`face_chunks`)."""
    nc = -(-len(faces) // CHUNK)
    start, verts = np.zeros(nc + 1, np.int64), np.empty(3 * len(faces), np.int64)
    k = _chunk_vertices(_read_only(faces), CHUNK, int(n), start, verts) if len(faces) else 0
    return start, verts[:k].copy()


@njit(cache=True, nogil=True)
def _face_chunks(points, start, verts, size, clo, chi, glo, ghi):
    nc = clo.shape[0]
    for c in range(nc):
        a0, a1, a2, b0, b1, b2 = np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf
        for r in range(start[c], start[c + 1]):
            v = verts[r]
            x, y, z = points[v, 0], points[v, 1], points[v, 2]
            a0, b0 = min(a0, x), max(b0, x)
            a1, b1 = min(a1, y), max(b1, y)
            a2, b2 = min(a2, z), max(b2, z)
        clo[c, 0], clo[c, 1], clo[c, 2], chi[c, 0], chi[c, 1], chi[c, 2] = a0, a1, a2, b0, b1, b2
    for g in range(glo.shape[0]):
        a0, a1, a2, b0, b1, b2 = np.inf, np.inf, np.inf, -np.inf, -np.inf, -np.inf
        for c in range(g * size, min((g + 1) * size, nc)):
            a0, a1, a2 = min(a0, clo[c, 0]), min(a1, clo[c, 1]), min(a2, clo[c, 2])
            b0, b1, b2 = max(b0, chi[c, 0]), max(b1, chi[c, 1]), max(b2, chi[c, 2])
        glo[g, 0], glo[g, 1], glo[g, 2], ghi[g, 0], ghi[g, 1], ghi[g, 2] = a0, a1, a2, b0, b1, b2


def face_chunks(points: np.ndarray, used: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Boxes of a mesh's faces in chunks of `CHUNK` consecutive rows, and of those chunks in
    groups of `CHUNK`, for `faces_meet_rows`: ``(lo (c, 3), hi (c, 3), group_lo (g, 3), group_hi
    (g, 3))`` float64, the minima and maxima of the points ``points (n, 3) float64`` (finite) each
    chunk's faces use (``used``, `chunk_vertices` of the faces). A display's rows run along its
    surface, so a chunk's faces lie together and a query near a contact opens a few chunks
    instead of comparing every point."""
    start, verts = used
    nc = len(start) - 1
    ng = -(-nc // CHUNK)
    clo, chi, glo, ghi = np.empty((nc, 3)), np.empty((nc, 3)), np.empty((ng, 3)), np.empty((ng, 3))
    if nc:
        _face_chunks(np.ascontiguousarray(points, np.float64), start, verts, CHUNK, clo, chi, glo, ghi)
    return clo, chi, glo, ghi


@njit(cache=True, nogil=True)
def _faces_meet_chunks(points, faces, size, clo, chi, glo, ghi, lo, hi, pad, out):
    # `_faces_meet_rows`' comparisons, face by face, in the chunks and groups that may hold a face
    # meeting the box: a face lacks a side's bit when one of its corners does (``x <= hi + pad``,
    # ``lo <= x + pad``), and then its chunk's least ``x`` (at most that corner's) is ``<= hi +
    # pad`` and ``lo <=`` its largest ``x`` plus ``pad`` (the rounding of ``x + pad`` is monotone
    # in ``x``): a box missing that is skipped with every face in it
    # A box whose least ``x`` has ``lo <= x + pad`` and whose largest is ``<= hi + pad`` on every
    # axis holds only points without a side's bit (each of its points lies between those two,
    # and ``x + pad`` rounds monotonically), so every face of it meets the box: its rows are
    # taken without comparing their corners
    top0, top1, top2 = hi[0] + pad, hi[1] + pad, hi[2] + pad
    lo0, lo1, lo2 = lo[0], lo[1], lo[2]
    nf, nc = faces.shape[0], clo.shape[0]
    n = 0
    for g in range(glo.shape[0]):
        if not (glo[g, 0] <= top0 and glo[g, 1] <= top1 and glo[g, 2] <= top2 and lo0 <= ghi[g, 0] + pad
                and lo1 <= ghi[g, 1] + pad and lo2 <= ghi[g, 2] + pad):
            continue
        if (ghi[g, 0] <= top0 and ghi[g, 1] <= top1 and ghi[g, 2] <= top2 and lo0 <= glo[g, 0] + pad
                and lo1 <= glo[g, 1] + pad and lo2 <= glo[g, 2] + pad):
            for i in range(g * size * size, min((g + 1) * size * size, nf)):
                out[n] = i
                n += 1
            continue
        for c in range(g * size, min((g + 1) * size, nc)):
            if not (clo[c, 0] <= top0 and clo[c, 1] <= top1 and clo[c, 2] <= top2 and lo0 <= chi[c, 0] + pad
                    and lo1 <= chi[c, 1] + pad and lo2 <= chi[c, 2] + pad):
                continue
            if (chi[c, 0] <= top0 and chi[c, 1] <= top1 and chi[c, 2] <= top2 and lo0 <= clo[c, 0] + pad
                    and lo1 <= clo[c, 1] + pad and lo2 <= clo[c, 2] + pad):
                for i in range(c * size, min((c + 1) * size, nf)):
                    out[n] = i
                    n += 1
                continue
            for i in range(c * size, min((c + 1) * size, nf)):
                shared = 63
                for j in range(3):
                    shared &= _beyond(points, faces[i, j], lo0, lo1, lo2, top0, top1, top2, pad)
                if shared == 0:
                    out[n] = i
                    n += 1
    return n


@njit(cache=True, nogil=True)
def _faces_at(points, faces, rows, shift, out, moved, box):
    # the corners in order, each read once as its three values, their box in `acra.bvh.bounds`'
    # comparisons and order (the first corner's values, then each corner against the least and
    # largest so far, held as values: the first against itself changes nothing, a NaN winning as
    # in numpy), and, where ``moved`` has rows, each corner less ``shift`` (numpy's subtraction);
    # true where every such value is finite and not zero
    placed = moved.shape[0] > 0
    plain = True
    if rows.shape[0] == 0:
        return plain
    v = faces[rows[0], 0]
    b0, b1, b2 = points[v, 0], points[v, 1], points[v, 2]
    t0, t1, t2 = b0, b1, b2
    s0, s1, s2 = shift[0], shift[1], shift[2]
    for i in range(rows.shape[0]):
        r = rows[i]
        for c in range(3):
            v = faces[r, c]
            x, y, z = points[v, 0], points[v, 1], points[v, 2]
            out[i, c, 0], out[i, c, 1], out[i, c, 2] = x, y, z
            if x < b0 or x != x:
                b0 = x
            if x > t0 or x != x:
                t0 = x
            if y < b1 or y != y:
                b1 = y
            if y > t1 or y != y:
                t1 = y
            if z < b2 or z != z:
                b2 = z
            if z > t2 or z != z:
                t2 = z
            if placed:
                d0, d1, d2 = x - s0, y - s1, z - s2
                moved[i, c, 0], moved[i, c, 1], moved[i, c, 2] = d0, d1, d2
                plain &= d0 != 0.0 and abs(d0) < np.inf and d1 != 0.0 and abs(d1) < np.inf and d2 != 0.0 and abs(d2) < np.inf
    box[0, 0], box[0, 1], box[0, 2], box[1, 0], box[1, 1], box[1, 2] = b0, b1, b2, t0, t1, t2
    return plain


def faces_at(points: np.ndarray, faces: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``points[faces[rows]]`` ``(m, 3, 3) float64`` (``points (n, 3) float64``, ``faces (f, 3)
    int64``, ``rows (m,) int64`` in range), copied in one compiled pass."""
    out = np.empty((len(rows), 3, 3))
    if len(rows):
        _faces_at(np.ascontiguousarray(points, np.float64), _read_only(faces),
                  np.ascontiguousarray(rows, np.int64), np.zeros(3), out, out[:0], np.empty((2, 3)))
    return out


def faces_placed(points: np.ndarray, faces: np.ndarray, rows: np.ndarray,
                 shift: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """`faces_at`'s corners ``tri (m, 3, 3)`` (``m`` > 0), with in the same compiled pass their
    box ``(2, 3)`` (`acra.bvh.bounds`' bits) and ``tri - shift`` ``(m, 3, 3)`` (``shift (3,)``,
    numpy's bits), and whether every value of the latter is finite and not zero.

    The last says when mapping those values by an identity matrix changes no bit: each output
    is its own value times 1 plus two products with 0, which are zeros and leave a finite
    nonzero value as it is, in any order of summation and with or without fused
    multiply-adds (`pipeline.residual.pair_depth` takes a display into an object space whose
    linear part is the identity)."""
    m = len(rows)
    out, moved, box = np.empty((m, 3, 3)), np.empty((m, 3, 3)), np.empty((2, 3))
    plain = _faces_at(np.ascontiguousarray(points, np.float64), _read_only(faces), np.ascontiguousarray(rows, np.int64),
                      np.ascontiguousarray(shift, np.float64).reshape(3), out, moved, box)
    return out, box, moved, bool(plain)


@njit(cache=True, nogil=True)
def _barycentric(bary, tri, corners, rows, faces, values, points, at):
    # numpy's einsum("mk,mkc->mc") arithmetic: each output summed from 0.0 (so a -0.0 sum comes
    # out as 0.0), corner by corner
    for i in range(bary.shape[0]):
        t = tri[i]
        w0, w1, w2 = bary[i, 0], bary[i, 1], bary[i, 2]
        for c in range(3):
            points[i, c] = ((0.0 + w0 * corners[t, 0, c]) + w1 * corners[t, 1, c]) + w2 * corners[t, 2, c]
        if at.shape[0]:
            f0, f1, f2 = faces[rows[t], 0], faces[rows[t], 1], faces[rows[t], 2]
            for c in range(values.shape[1]):
                at[i, c] = ((0.0 + w0 * values[f0, c]) + w1 * values[f1, c]) + w2 * values[f2, c]


def barycentric(bary: np.ndarray, tri: np.ndarray, corners: np.ndarray, rows: np.ndarray, faces: np.ndarray,
                values: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """The points at barycentric weights ``bary (m, 3)`` in triangles ``corners[tri] ((t, 3, 3),
    tri (m,) int64)``, and, given per-vertex ``values (n, c)``, the values there in the faces
    ``faces[rows[tri]]`` (``faces (f, 3) int64`` into them, ``rows (t,) int64``), in one compiled
    pass: ``np.einsum("mk,mkc->mc", bary, corners[tri])`` and ``np.einsum("mk,mkc->mc", bary,
    values[faces[rows[tri]]])`` to the bit. Returns ``(points (m, 3), at (m, c) or None)``."""
    m = len(bary)
    points = np.empty((m, 3))
    v = np.zeros((0, 2)) if values is None else np.ascontiguousarray(values, np.float64)
    if v.flags.writeable:  # one writeability, so the kernel is compiled once (`_read_only`)
        v = v.view()
        v.flags.writeable = False
    at = np.empty((m if values is not None else 0, v.shape[1]))
    if m:
        _barycentric(np.ascontiguousarray(bary, np.float64), np.ascontiguousarray(tri, np.int64),
                     np.ascontiguousarray(corners, np.float64), np.ascontiguousarray(rows, np.int64), _read_only(faces), v,
                     points, at)
    return points, None if values is None else at


@njit(cache=True, nogil=True)
def _first_rows(bits, first, label):
    size = 1
    while size < 2 * bits.shape[0]:
        size *= 2
    table = np.full(size, -1, np.int64)
    # the slot is the product's top bits (multiplicative hashing): a coordinate of few mantissa
    # bits (a lattice's dyadic parameters) has its low bits zero, and so have its products' low
    # bits, which would send such rows to a few slots
    b = 0
    while (1 << b) < size:
        b += 1
    shift = np.uint64(64 - b)  # size >= 2 rows' worth, so b >= 1
    u = 0
    for i in range(bits.shape[0]):
        h = (bits[i, 0] * np.uint64(0x9E3779B97F4A7C15)) ^ (bits[i, 1] * np.uint64(0xC2B2AE3D27D4EB4F)) \
            ^ (bits[i, 2] * np.uint64(0x165667B19E3779F9))
        slot = np.int64(h >> shift)
        while True:
            j = table[slot]
            if j < 0:
                table[slot] = u
                first[u] = i
                label[i] = u
                u += 1
                break
            r = first[j]
            if bits[r, 0] == bits[i, 0] and bits[r, 1] == bits[i, 1] and bits[r, 2] == bits[i, 2]:
                label[i] = j
                break
            slot = (slot + 1) & (size - 1)
    return u


def first_rows(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The bitwise distinct rows of ``points (k, 3) float64`` by a hash table: the row ``(u,)
    int64`` of each one's first occurrence, in the order of first occurrence, and each row's
    index ``(k,) int64`` into them."""
    bits = np.ascontiguousarray(points, np.float64).reshape(-1, 3).view(np.uint64)
    first, label = np.empty(len(bits), np.int64), np.empty(len(bits), np.int64)
    u = _first_rows(bits, first, label) if len(bits) else 0
    return first[:u], label


@njit(cache=True, nogil=True)
def _swapped(x):
    """The bytes of ``x (uint64)`` in reverse order: a little-endian value's first byte most
    significant, so unsigned order is the order of the 8 bytes as stored (memcmp's)."""
    y = np.uint64(0)
    for _ in range(8):
        y = (y << np.uint64(8)) | (x & np.uint64(255))
        x = x >> np.uint64(8)
    return y


@njit(cache=True, nogil=True)
def _distinct_rows(bits, first, inverse):
    # the distinct rows in order of first occurrence (`_first_rows`), then sorted by their
    # 24 bytes as stored: x's bytes, then y's, then z's (no two distinct rows tie)
    k = bits.shape[0]
    once, label = np.empty(k, np.int64), np.empty(k, np.int64)
    u = _first_rows(bits, once, label)
    key = np.empty((u, 3), np.uint64)
    for j in range(u):
        for c in range(3):
            key[j, c] = _swapped(bits[once[j], c])
    # the stable sort of the x keys over int64 (the sign bit flipped: the same order as uint64),
    # the one key type every kernel's merge sort takes, so a first run compiles numba's
    # argsort once (about 1.5 s CPU for a second key type)
    signed = np.empty(u, np.int64)
    for j in range(u):
        signed[j] = np.int64(key[j, 0] ^ np.uint64(0x8000000000000000))
    order = np.argsort(signed, kind="mergesort")
    a = 0
    while a < u:  # a run of equal x: by y, then z (insertion; runs are short)
        b = a + 1
        while b < u and key[order[b], 0] == key[order[a], 0]:
            b += 1
        for i in range(a + 1, b):
            r = order[i]
            t = i - 1
            while t >= a and (key[order[t], 1] > key[r, 1] or (key[order[t], 1] == key[r, 1] and key[order[t], 2] > key[r, 2])):
                order[t + 1] = order[t]
                t -= 1
            order[t + 1] = r
        a = b
    rank = np.empty(u, np.int64)
    for r in range(u):
        rank[order[r]] = r
        first[r] = once[order[r]]
    for i in range(k):
        inverse[i] = rank[label[i]]
    return u


def distinct_rows(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The bitwise distinct rows of ``points (k, 3) float64`` in the order ``np.unique`` gives
    rows viewed as 24 raw bytes (memcmp; -0.0 and 0.0 distinct): the row ``(u,) int64`` of each
    one's first occurrence and each row's index ``(k,) int64`` into them (``np.unique``'s
    ``return_index`` and ``return_inverse``)."""
    bits = np.ascontiguousarray(points, np.float64).reshape(-1, 3).view(np.uint64)
    first, inverse = np.empty(len(bits), np.int64), np.empty(len(bits), np.int64)
    u = _distinct_rows(bits, first, inverse) if len(bits) else 0
    return first[:u], inverse
