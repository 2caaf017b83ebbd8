"""Multi-resolution interpolation (thesis §4.1): move CVs so a surface passes through data points.

All solvers work on the same sparse linear model. Data point ``k`` at parameters ``(u_k, v_k)``
is a weighted sum of the CVs ``p`` of one level, ``Q_k = sum_p w_kp V_p``, with ``w_kp`` the
tensor-product basis ``B_a(u) B_b(v)`` (eq. 4.10); moving the CVs by ``dV`` moves the point by
``W dV``. Given the wanted point moves ``dQ``:

* `bartels_beatty` — eq. 4.4 / 4.11 for one point: the minimum-norm change, exact;
* `blend_update` — eq. 4.6–4.9 / 4.11 for many points: every point proposes its minimum-norm
  change, a CV shared by several points takes their ``w**2``-weighted blend (Lee, Wolberg &
  Shin's multilevel B-spline update). Not exact; `iterate_blend` repeats it on the remainder;
* `min_norm_solve` — the exact minimum-norm solution ``dV = W^T (W W^T)^+ dQ`` of the small
  ``K × K`` system (a pseudo-inverse, so coincident points with different targets stay finite).
"""

from __future__ import annotations

import functools

from dataclasses import dataclass

import numpy as np

try:  # numpy's private LAPACK gufuncs; `_eigh` falls back to `np.linalg.eigh` without them
    from numpy.linalg._umath_linalg import eigh_lo as _EIGH_LO
except ImportError:  # pragma: no cover - a numpy without the module
    _EIGH_LO = None

from . import levelkernels, memo
from .basis import basis, locate
from .hierarchy import _pole_ring_keys, pole_ring_rows
from .hspline import HSpline, _cv_keys, _lookup, _patch_keys, closed_ends, pole_of, pole_ring

__all__ = [
    "PointWeights",
    "point_active",
    "active_rows",
    "SystemTooLarge",
    "dense_bytes",
    "point_weights",
    "bartels_beatty",
    "blend_update",
    "iterate_blend",
    "min_norm_solve",
    "solve",
]


@dataclass(frozen=True)
class PointWeights:
    """Sparse weights of data points on the movable CVs of one level.

    Attributes
    ----------
    level : int
    point : (e,) int64
        Data point of each non-zero entry.
    col : (e,) int64
        Unknown (column) of each entry, into ``cv_rows``.
    w : (e,) float64
        Basis weight ``B_a(u) B_b(v)``.
    cv_rows : (P,) int64
        Sorted, each once. For level 0 the flat grid index ``i * nv + j``; for level ``k >= 1`` the row into
        ``level(k).cv_keys``.
    npoints : int
    active : (K,) bool
        Points that have at least one movable CV with a non-zero weight.
    """

    level: int
    point: np.ndarray
    col: np.ndarray
    w: np.ndarray
    cv_rows: np.ndarray
    npoints: int
    active: np.ndarray

    def dense(self) -> np.ndarray:
        """``(K, P)`` dense weight matrix."""
        # np.bincount adds each cell's entries in order from 0.0, as np.add.at does, in one pass
        P = self.cv_rows.size
        return np.bincount(self.point * P + self.col, self.w, self.npoints * P).reshape(self.npoints, P)

    def apply(self, dv: np.ndarray) -> np.ndarray:
        """Point moves ``W dV``: ``dv (P, 3) -> (K, 3)``."""
        out = np.zeros((self.npoints, 3))
        np.add.at(out, self.point, self.w[:, None] * dv[self.col])
        return out


def point_weights(hs: HSpline, level: int, u: np.ndarray, v: np.ndarray, pole: np.ndarray | None = None) -> PointWeights:
    """Weights of points ``(u, v)`` (level-0 units, ``(K,)`` each) on the movable CVs of ``level``.

    Level 0: all 16 CVs of the point's patch. Level ``k >= 1``: the CVs of the point's level-k
    patch that exist and are movable (C2 rule); a point whose patch is not refined to ``k`` gets
    no weights (``active`` False): under the ``obey`` policy it is not moved by this level.

    A point on a pole (`H.pole_of`) is the same surface point for every value of the periodic
    parameter, so its row is that row averaged over the parameter: each CV of the level's
    `H.pole_ring` weighs its row's weight over the ring size. A projection's arbitrary choice of
    the parameter then changes nothing, and moving the point moves the pole as one point. On a
    level whose ring is not wholly movable the point gets no weights.

    ``pole (K,) int64``: `H.pole_of` of the points, if the caller has it (a response asks every
    level about the same points on the same level-0 grid).
    The entries are one compiled pass (`acra.levelkernels.point_entries`; `_entries_numpy` is
    their array form), numbered by `acra.levelkernels.unique_inverse`.
    """
    point, rows, wts, active = _kernel_entries(hs, level, u, v, pole)
    cv_rows, col = levelkernels.unique_inverse(rows)
    # the fields set directly: the frozen constructor sets one at a time through
    # ``object.__setattr__``, and a response builds weights on every level
    out = object.__new__(PointWeights)
    out.__dict__.update(level=level, point=point, col=col, w=wts, cv_rows=cv_rows, npoints=active.size, active=active)
    return out


def point_active(hs: HSpline, level: int, u: np.ndarray, v: np.ndarray, pole: np.ndarray | None = None) -> np.ndarray:
    """`point_weights(hs, level, u, v, pole).active` alone: ``(K,) bool``, whether each point
    weighs some movable CV of ``level`` (a point on a pole: whether its ring is wholly
    movable)."""
    return _kernel_entries(hs, level, u, v, pole)[3]


def _entries(hs: HSpline, level: int, u: np.ndarray, v: np.ndarray,
             pole: np.ndarray | None = None) -> tuple[list, list, list]:
    """`point_weights`' nonzero weights as lists of arrays: points, CV rows, weights (compiled,
    `acra.levelkernels.point_entries`; `_entries_numpy` is the array form)."""
    pt, rows, w = _kernel_entries(hs, level, u, v, pole)[:3]
    return [pt], [rows], [w]


_NONE = np.zeros(0, np.int64)  # a level-0 call's absent level arrays (writeable: the kernel's one signature)


def _kernel_entries(hs: HSpline, level: int, u: np.ndarray, v: np.ndarray, pole: np.ndarray | None) -> tuple:
    """`acra.levelkernels.point_entries` of the points: entries' points ``(e,) int64``, CV rows
    ``(e,) int64`` and weights ``(e,) float64``, and ``active (K,) bool``."""
    lev = hs.level(level) if level else None
    u, v = _writeable(u), _writeable(v)
    pole = pole_of(hs, u, v) if pole is None else pole
    # the level's rings only for points on a pole: a level a response refined is a new `Level`,
    # whose ring table is built afresh
    rows, w, at, use = _ring_table(hs, level) if np.count_nonzero(pole >= 0) else _NO_RINGS
    return levelkernels.point_entries(
        u, v, pole, level, hs.u.cvs(level), hs.u.periodic, hs.v.cvs(level), hs.v.periodic,
        hs.u.patches(level), hs.v.patches(level), _NONE if lev is None else lev.cv_keys,
        _NO_BOOLS if lev is None else lev.movable, _NONE if lev is None else lev.patches, rows, w, at, use)


_NO_BOOLS = np.zeros(0, bool)


def _writeable(x: np.ndarray) -> np.ndarray:
    """``x (K,) float64`` C-contiguous and writeable (a copy only where it is not): one compiled
    signature of `levelkernels.point_entries` serves every call."""
    a = np.ascontiguousarray(x, dtype=np.float64).reshape(-1)
    return a if a.flags.writeable else a.copy()


def _ring_table(hs: HSpline, level: int) -> tuple:
    """The level's pole rings as `levelkernels.point_entries` takes them, one per closed end
    (`closed_ends`): each end's ring rows flattened (level 0: grid indices; finer:
    `pole_ring_rows`), concatenated ``(R,) int64``, their weights (`_ring_weights`) ``(R,)
    float64``, where each end's span starts ``(E + 1,) int64``, and whether each ring is wholly
    movable ``(E,) bool``. They depend on the grid, the closed ends and the level's CVs alone:
    kept on the level (with `pole_ring_rows`, which a move carries to its new `Level`), on the
    grid's directions for level 0."""
    ends = closed_ends(hs)
    if not ends:
        return _NO_RINGS
    if level == 0:
        return _level0_rings(hs.u, hs.v, ends)
    tables = hs.level(level).__dict__.setdefault("_ring_rows", {})
    key = ("table", hs.u.n, hs.u.periodic, hs.v.n, hs.v.periodic, ends)
    hit = tables.get(key)
    if hit is None:
        rings = [pole_ring_rows(hs, level, axis, end) for axis, end in ends]
        hit = tables[key] = _stack_rings([r for r, _ in rings], [bool(ok.all()) for _, ok in rings])
    return hit


@functools.lru_cache(maxsize=32)
def _level0_rings(u_dir, v_dir, ends: tuple) -> tuple:
    """`_ring_table` of level 0 (every grid CV movable), per grid and closed ends."""
    return _stack_rings([_pole_ring_keys(u_dir, v_dir, 0, axis, end) for axis, end in ends], [True] * len(ends))


def _stack_rings(rows: list, use: list) -> tuple:
    """`_ring_table`'s arrays from each end's ring rows ``(N, 3) int64`` (at least one end) and
    movability."""
    at = np.zeros(len(rows) + 1, np.int64)
    at[1:] = [r.size for r in rows]
    out = (np.concatenate(rows, axis=None), np.concatenate([_ring_weights(r.shape[0]) for r in rows]),
           np.cumsum(at), np.array(use))
    for a in out:
        a.flags.writeable = False
    return out


def _no_rings() -> tuple:
    """`_ring_table` of a grid without a closed end (read-only, the kernel's one signature)."""
    out = (np.zeros(0, np.int64), np.zeros(0), np.zeros(1, np.int64), np.zeros(0, bool))
    for a in out:
        a.flags.writeable = False
    return out


_NO_RINGS = _no_rings()


def _pole_entries(hs: HSpline, level: int, pole: np.ndarray, pts: list, rws: list, ws: list) -> tuple[list, list, list]:
    """`_entries_numpy`'s lists with the entries of the points on a pole (`pole_of`) appended:
    each weighs its level's whole `pole_ring` (if the ring is wholly movable)."""
    if not pole.size or pole.max() < 0:  # no point on a pole
        return pts, rws, ws
    for i, (axis, end) in enumerate(closed_ends(hs)):
        on = np.nonzero(pole == i)[0]
        if not on.size:
            continue
        # kept on the level (`pole_ring_rows`): every level's weights ask for its rings
        rrows, rok = _movable_rows(hs, level, pole_ring(hs, level, axis, end)[0]) if level == 0 \
            else pole_ring_rows(hs, level, axis, end)
        if not rok.all():
            continue
        # each point on the pole weighs every ring CV, rows and weights repeated point by point
        # (one point, the usual case, takes the ring's rows and weights as they are)
        flat, w_ring = rrows.reshape(-1), _ring_weights(rrows.shape[0])
        pts.append(np.repeat(on, flat.size))
        rws.append(flat if on.size == 1 else np.tile(flat, on.size))
        ws.append(w_ring if on.size == 1 else np.tile(w_ring, on.size))
    return pts, rws, ws


@functools.lru_cache(maxsize=32)
def _ring_weights(N: int) -> np.ndarray:
    """A pole point's weight on each of the ``3 N`` CVs of a ring of ``N`` columns (`pole_ring`'s
    row weights over ``N``, column by column): ``(3 N,) float64``, read-only."""
    w = np.tile((np.array([1.0, 4.0, 1.0]) / 6.0) / N, N)
    w.flags.writeable = False
    return w


def _entries_numpy(hs: HSpline, level: int, u: np.ndarray, v: np.ndarray) -> tuple[list, list, list]:
    """`_entries` as array operations (the reference the kernel is tested against)."""
    su, tu = locate(hs.u, u, level)
    sv, tv = locate(hs.v, v, level)
    bu, bv = basis(tu), basis(tv)
    w = (bu[:, :, None] * bv[:, None, :]).reshape(-1, 16)
    i4 = np.arange(4)
    ju = hs.u.wrap_cv(su[:, None] + i4, level)
    jv = hs.v.wrap_cv(sv[:, None] + i4, level)
    keys = _cv_keys(hs, level, ju[:, :, None], jv[:, None, :]).reshape(-1, 16)
    rows, ok = _movable_rows(hs, level, keys)
    if level:
        ok &= _lookup(hs.level(level).patches, _patch_keys(hs, level, su, sv))[1][:, None]
    ok &= w > 0.0
    pole = pole_of(hs, u, v)
    ok[pole >= 0] = False
    pt = np.repeat(np.arange(u.size), 16).reshape(-1, 16)
    return _pole_entries(hs, level, pole, [pt[ok]], [rows[ok]], [w[ok]])


def _movable_rows(hs: HSpline, level: int, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows of CV ``keys`` (any shape) at ``level`` (level 0: flat grid index) and whether each
    exists and is movable."""
    if level == 0:
        return keys, np.ones(keys.shape, bool)
    lev = hs.level(level)
    rows, found = _lookup(lev.cv_keys, keys)
    return rows, found & (lev.movable[rows] if lev.cv_keys.size else False)


def bartels_beatty(w: np.ndarray, dq: np.ndarray) -> np.ndarray:
    """One point, eq. 4.4 / 4.11: ``dV_i = dQ · w_i / sum_j w_j**2``.

    Parameters
    ----------
    w : (n,) float64
        Basis weights of the point on its CVs (4 on a curve, 16 on a patch).
    dq : (3,) float64
        Wanted move of the point.

    Returns
    -------
    (n, 3) float64
        CV moves; ``w @ dV == dq`` exactly and ``|dV|`` is minimal.
    """
    w = np.asarray(w, dtype=np.float64)
    return np.outer(w / np.dot(w, w), dq)


def blend_update(pw: PointWeights, dq: np.ndarray) -> np.ndarray:
    """Eq. 4.6–4.9 / 4.11: per-point minimum-norm proposals blended with weights ``w**2``.

    Parameters
    ----------
    dq : (K, 3) float64
        Wanted point moves (inactive points are ignored).

    Returns
    -------
    (P, 3) float64
        CV moves.
    """
    norm = np.zeros(pw.npoints)
    np.add.at(norm, pw.point, pw.w**2)
    safe = np.where(norm > 0, norm, 1.0)
    proposal = (pw.w / safe[pw.point])[:, None] * dq[pw.point]  # dV_p(k)
    num = np.zeros((pw.cv_rows.size, 3))
    den = np.zeros(pw.cv_rows.size)
    np.add.at(num, pw.col, (pw.w**2)[:, None] * proposal)
    np.add.at(den, pw.col, pw.w**2)
    return num / np.where(den > 0, den, 1.0)[:, None]


def iterate_blend(pw: PointWeights, dq: np.ndarray, iterations: int = 5, tol: float = 0.0):
    """Repeat `blend_update` on what is left (thesis: "5 iterations give an excellent fit").

    Returns
    -------
    dv : (P, 3) float64
    history : (n + 1,) float64
        Max remaining point error before each iteration and after the last.
    """
    dv = np.zeros((pw.cv_rows.size, 3))
    act = pw.active
    rem = np.where(act[:, None], dq, 0.0)
    history = [float(np.abs(rem).max(initial=0.0))]
    for _ in range(iterations):
        if history[-1] <= tol:
            break
        dv += blend_update(pw, rem)
        rem = np.where(act[:, None], dq - pw.apply(dv), 0.0)
        history.append(float(np.abs(rem).max(initial=0.0)))
    return dv, np.array(history)


class SystemTooLarge(MemoryError):
    """A direct solve whose dense arrays would exceed the caller's memory bound.

    Attributes
    ----------
    points, cvs : int
        ``K`` active data points and ``P`` movable CVs of the solve.
    nbytes, limit : int
        `dense_bytes` of the solve and the bound it exceeds.
    """

    def __init__(self, points: int, cvs: int, nbytes: int, limit: int):
        self.points, self.cvs, self.nbytes, self.limit = points, cvs, nbytes, limit
        super().__init__(f"a direct solve of {points} points on {cvs} CVs needs ~{nbytes} bytes (bound {limit})")


def dense_bytes(k: int, p: int) -> int:
    """Bytes `min_norm_solve` holds at once for ``k`` active points on ``p`` CVs: the dense weights
    ``W (k, p)`` and ``Wᵀ`` products of the same size, and the Gram matrix ``W Wᵀ (k, k)`` with
    its eigenvectors and LAPACK's workspace, all float64."""
    return 8 * (2 * k * p + 3 * k * k)


_TINY = np.finfo(float).tiny  # np.finfo costs microseconds a call


def min_norm_solve(pw: PointWeights, dq: np.ndarray, rcond: float = 1e-4, max_bytes: int | None = None,
                   amplify: float | None = None, weak: float = 1e-3) -> np.ndarray:
    """Exact minimum-norm CV moves ``W^T (W W^T)^+ dQ`` for the active points.

    The ``K × K`` Gram matrix is inverted through its eigen-decomposition with eigenvalues
    below ``rcond`` times the largest dropped, so coincident or nearly dependent points with
    different targets give the least-squares compromise instead of an amplified error (a mode
    of eigenvalue ``λ`` multiplies its share of the targets' inconsistency by ``1/√λ``). Nearly
    dependent: a contact inside a dent sampled once per patch, whose neighbours already fix the
    surface there. Measured (`tests/test_respond.py`): eigenvalue ratios of 1e-9 (a 1%
    inconsistent target moved a 7-wide sheet by 14) and 1e-6 (targets with 1.3% noise moved a
    dent 1.9 times its depth); the next eigenvalue in those solves was 1.2e-3 to 1.7e-2.

    ``max_bytes`` bounds the dense arrays (`dense_bytes`): a solve over it raises `SystemTooLarge`
    before anything is allocated, since a contact's extent, and so ``K`` and ``P``, is known only
    once it is found.

    ``amplify`` (None: off) also drops a mode below ``weak`` times the largest eigenvalue whose CV
    move, ``|v^T dQ| / √λ``, exceeds ``amplify`` times the largest wanted point move: such a mode
    fits the points' disagreement, not a move any of them asks (one point's exact fit moves a
    cubic's CVs at most 16/9 of its ask), while a weak mode the asks do need keeps its share.

    Returns
    -------
    (P, 3) float64
    """
    act, every = active_rows(pw)
    if act.size == 0:
        return np.zeros((pw.cv_rows.size, 3))
    if max_bytes is not None and dense_bytes(act.size, pw.cv_rows.size) > max_bytes:
        raise SystemTooLarge(int(act.size), int(pw.cv_rows.size), dense_bytes(act.size, pw.cv_rows.size), int(max_bytes))
    W, lam, vec, _, modes = _decomposition(pw, act, every)
    dqa = dq if every and dq.flags.c_contiguous else dq[act]
    if amplify is None:
        # the modes above ``rcond`` depend on the decomposition alone: taken once per kept one
        hit = modes.get(rcond)
        if hit is None:
            hit = modes[rcond] = _kept_modes(lam, vec, lam > rcond * lam[-1])
            for a in hit:  # shared with every later solve of these weights
                a.flags.writeable = False
        kept, lam_kept = hit
        return W.T @ (kept @ (kept.T @ dqa / lam_kept))
    keep = lam > rcond * lam[-1]
    along = vec.T @ dqa
    # `np.linalg.norm(x, axis=1)`'s own sum, without its wrapper
    moves = np.sqrt(np.add.reduce(along * along, axis=1)) / np.sqrt(np.maximum(lam, _TINY))
    keep &= ~((lam < weak * lam[-1]) & (moves > amplify * np.sqrt(np.add.reduce(dqa * dqa, axis=1)).max()))
    kept, lam_kept = _kept_modes(lam, vec, keep)
    return W.T @ (kept @ (kept.T @ dqa / lam_kept))


def active_rows(pw: PointWeights) -> tuple[np.ndarray, bool]:
    """The rows of ``pw``'s active points ``(k,) int64`` and whether that is all of them, kept on
    the weights (a response solves kept weights level after level, `acra.respond._weights`).
    Every point active: the solve takes the rows as they are, without copies (the same C-ordered
    arrays a selection would give, so BLAS sums the same products in the same order)."""
    hit = pw.__dict__.get(_ACTIVE)
    if hit is None:
        act = np.nonzero(pw.active)[0]
        hit = pw.__dict__[_ACTIVE] = (act, act.size == pw.npoints)
    return hit


_ACTIVE = "_active_rows"  # key in a `PointWeights`' ``__dict__``: `active_rows`' answer


def _kept_modes(lam: np.ndarray, vec: np.ndarray, keep: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The eigenvectors ``(k, m) float64`` of the ``m`` modes ``keep (k,) bool`` keeps, and their
    eigenvalues as a column ``(m, 1) float64``: ``vec`` itself where every mode is kept and it is
    C-ordered, else one copy of the kept columns for both products of the solve."""
    if np.count_nonzero(keep) == keep.size and vec.flags.c_contiguous:
        return vec, lam[:, None]
    return vec[:, keep], lam[keep][:, None]


# The dense weights of recent solves' active points and their Gram matrix's eigen-decomposition
# (`min_norm_solve`), by the weights' entries: a contact held still asks a static object the same
# solve frame after frame (the demo's frames 13-17: 15 of their 25 solves, the spike's 49- and
# 69-point ones among them), and the decomposition is most of a solve. The key holds every
# entry's bytes and the active points', so a hit's arrays are the ones the solve would compute.
# The most recent `_DECOMPOSED_KEEP` kept, in `_DECOMPOSED_BYTES` at most (a solve past a
# quarter of it is not kept); a table of the run's memo (`acra.memo`).
_DECOMPOSED = memo.Table("interpolate.decomposed")
_DECOMPOSED_KEEP = 32
_DECOMPOSED_BYTES = 1 << 25  # 32 MB: the demo's largest solve keeps 0.3 MB
_KEY = "_decomposed_key"  # key in a `PointWeights`' ``__dict__``: its `_DECOMPOSED` key


class _Content:
    """A `_DECOMPOSED` key: a solve's sizes and its weights' bytes, ``parts = (K, P, point, col,
    w, active bytes)``, equal to another only with every byte the same, hashed by the sizes and
    the first `_HASHED` bytes of each array alone. Python hashes a bytes object whole, and a
    large solve's entries are 90 kB; two solves' weights differ in their first entries almost
    always, and where they do not, equality still reads them all."""

    __slots__ = ("parts", "_hash")

    def __init__(self, parts: tuple) -> None:
        self.parts = parts
        self._hash = hash(parts[:2] + tuple(b[:_HASHED] for b in parts[2:]) + tuple(len(b) for b in parts[2:]))

    def __hash__(self) -> int:
        return self._hash

    def __eq__(self, other: object) -> bool:
        return type(other) is _Content and self._hash == other._hash and self.parts == other.parts


_HASHED = 1024  # bytes of each array a `_Content` hashes


def _decomposition(pw: PointWeights, act: np.ndarray, every: bool) -> tuple:
    """The active points' dense weights ``W (k, P) float64`` and the eigenvalues ``(k,)`` and
    eigenvectors ``(k, k)`` of ``W Wᵀ`` (`_eigh`), read-only, then the bytes the entry holds and
    its kept modes by eigenvalue cut-off (``{rcond: `_kept_modes`}``, filled by `min_norm_solve`):
    the entry kept (`_DECOMPOSED`) or computed. ``act (k,) int64``: the active points; ``every``:
    all of them."""
    # the key is made once per weights object, whose arrays nothing writes into (a response
    # solves the same kept weights again, `acra.respond._weights`): its bytes keep their hashes
    key = pw.__dict__.get(_KEY)
    if key is None:
        key = pw.__dict__[_KEY] = _Content((pw.npoints, pw.cv_rows.size, pw.point.tobytes(), pw.col.tobytes(), pw.w.tobytes(),
                                            pw.active.tobytes()))
    kept = _DECOMPOSED.entries()
    hit = kept.pop(key, None)
    if hit is not None:
        kept[key] = hit  # the most recent last
        return hit
    W = pw.dense() if every else pw.dense()[act]
    lam, vec = _eigh(W @ W.T)
    for a in (W, lam, vec):
        a.flags.writeable = False
    size = sum(len(b) for b in key.parts[2:]) + W.nbytes + lam.nbytes + vec.nbytes  # what the entry holds
    entry = (W, lam, vec, size, {})
    if size <= _DECOMPOSED_BYTES // 4:
        kept[key] = entry
        while len(kept) > _DECOMPOSED_KEEP or sum(v[3] for v in kept.values()) > _DECOMPOSED_BYTES:
            del kept[next(iter(kept))]
    return entry


def _eigh(g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`np.linalg.eigh(g)` of a symmetric ``g (K, K) float64``: eigenvalues ``(K,)`` ascending and
    eigenvectors ``(K, K)``, from the same LAPACK driver (``syevd`` on the lower triangle) called
    without `np.linalg.eigh`'s checks and conversions, which cost about as much as a response's
    small solves; an answer with a NaN (a NaN in ``g``, or no convergence) is `np.linalg.eigh`'s,
    which raises `np.linalg.LinAlgError` where LAPACK reports no convergence."""
    if _EIGH_LO is None:
        return np.linalg.eigh(g)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore", under="ignore"):
        lam, vec = _EIGH_LO(g, signature="d->dd")
    if np.count_nonzero(np.isnan(lam)):
        return np.linalg.eigh(g)
    return lam, vec


def solve(pw: PointWeights, dq: np.ndarray, method: str = "direct", iterations: int = 5, tol: float = 0.0,
          max_bytes: int | None = None, rcond: float = 1e-4, amplify: float | None = None) -> np.ndarray:
    """CV moves for wanted point moves, by ``"direct"`` (`min_norm_solve` with its eigenvalue cut-off
    ``rcond`` and its rule for weak modes ``amplify``, its dense arrays bounded by ``max_bytes``) or
    ``"blend"`` (memory linear in the weights)."""
    if method == "direct":
        return min_norm_solve(pw, dq, rcond=rcond, max_bytes=max_bytes, amplify=amplify)
    if method == "blend":
        return iterate_blend(pw, dq, iterations, tol)[0]
    raise ValueError(f"unknown interpolation method {method!r} (use 'direct' or 'blend')")
