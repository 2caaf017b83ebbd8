"""The structure of an H-spline (Forsey & Bartels 1988, thesis §3.4): levels, refinement, offsets.

Representation
--------------
Level 0 is a dense control grid ``cvs : (nu, nv, 3)`` (object space), open or periodic in u and v
independently. Each finer level ``k >= 1`` halves the knot spacing (thesis eq. 3.13–3.15) and is
*sparse*: it holds only the **active patches** that were refined, and the CVs of their 4×4 blocks.
A level-``k`` CV's position is its **derived vector** (the binary subdivision of level ``k-1``)
plus its **offset**, stored in the local frame of level ``k-1`` at the CV's parameter centre
(thesis Fig. 3.9): ``position = derived + F @ offset`` with ``F = [e_u, e_v, n]`` columns
(unit tangent along u, the tangent completing a right-handed frame, unit normal). The frames,
evaluation and explicit CV positions are in `acra.hspline`, which also re-exports every public
name of this module.

C2 rule (thesis Fig. 3.8): a CV may carry an offset only if its basis function vanishes on the
border to the coarser region, i.e. every existing patch in its support (a 4×4 block) is active.
Such CVs are *movable*.

Keys: a patch ``(pu, pv)`` at level ``k`` has key ``pu * Pv_k + pv``; a CV ``(ju, jv)`` has key
``ju * Nv_k + jv`` (``Pv_k``, ``Nv_k``: patch and CV counts along v at level ``k``). Key arrays are
sorted, so membership is a `np.searchsorted`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from . import levelkernels
from .basis import Direction

__all__ = [
    "Level",
    "HSpline",
    "from_grid",
    "refine",
    "make_movable",
    "refine_blocks",
    "refinement_keys",
    "refine_keys",
    "with_fine",
    "with_cvs",
    "with_offsets",
    "set_offsets",
    "offsets_of",
    "cv_uv",
    "patch_cvs",
    "closed_ends",
    "pole_of",
    "pole_ring",
    "pole_ring_rows",
    "pole_ring_movable",
    "pole_patches",
    "storage_size",
    "HierarchyArrays",
    "to_arrays",
    "from_arrays",
]

_I4 = np.arange(4)


@dataclass(frozen=True)
class Level:
    """The sparse content of one hierarchy level ``k >= 1``.

    Attributes
    ----------
    k : int
        The level.
    patches : (m,) int64
        Sorted keys of the active (refined) patches.
    cv_keys : (c,) int64
        Sorted keys of the CVs present (union of the active patches' 4×4 blocks).
    offsets : (c, 3) float64
        Offset of each CV in the local frame of level ``k-1``; zero where not movable.
    movable : (c,) bool
        C2 rule: every existing patch of the CV's support is active.
    patch_rows : (m, 4, 4) int64
        For each active patch, the rows (into ``cv_keys``) of its CVs ``[a, b]`` =
        ``(pu + a, pv + b)``.
    """

    k: int
    patches: np.ndarray
    cv_keys: np.ndarray
    offsets: np.ndarray
    movable: np.ndarray
    patch_rows: np.ndarray


@dataclass(frozen=True)
class HSpline:
    """A hierarchical B-spline surface: level-0 grid plus sparse finer levels.

    Attributes
    ----------
    cvs : (nu, nv, 3) float64
        Level-0 control vertices, ``cvs[i, j]`` with ``i`` along u (USD ``acra:cvs`` index
        ``j * nu + i``).
    u, v : Direction
        Level-0 CV count and wrap of each direction.
    depth : int
        Number of levels the object may use (levels ``0 .. depth-1``; contract ``acra:levels``).
    fine : tuple[Level, ...]
        ``fine[k - 1]`` is level ``k``; always ``depth - 1`` entries (possibly empty).
    """

    cvs: np.ndarray
    u: Direction
    v: Direction
    depth: int
    fine: tuple[Level, ...]

    @cached_property
    def _terms_index(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What `evaluate` looks patches up in, built once per surface: the levels it visits
        ``(L,) int64`` (0, then each level with a movable CV); every visited fine level's active
        patch keys plus that level's shift past all coarser levels' keys ``(p,) int64`` (sorted,
        so one `np.searchsorted` finds a point's patch on every level); the shifts ``(L-1,)
        int64``; where each fine level's keys end ``(L-1,) int64``; and each patch's CV block as
        rows of the table ``[level-0 CVs; level-1 detail vectors; ...]`` ``(p, 4, 4) int64``."""
        levels, keys, shifts, ends, rows = [0], [], [], [], []
        shift, base = 0, self.u.n * self.v.n
        for lev in self.fine:
            if lev.patches.size and np.any(lev.movable):
                levels.append(lev.k)
                keys.append(lev.patches + shift)
                shifts.append(shift)
                ends.append((ends[-1] if ends else 0) + lev.patches.size)
                rows.append(lev.patch_rows + base)
            shift += self.u.patches(lev.k) * self.v.patches(lev.k)
            base += lev.cv_keys.size
        cat = lambda xs, shape: np.concatenate(xs) if xs else np.zeros(shape, np.int64)  # noqa: E731
        ints = lambda xs: np.array(xs, np.int64)  # noqa: E731
        return ints(levels), cat(keys, (0,)), ints(shifts), ints(ends), cat(rows, (0, 4, 4))

    @cached_property
    def _table_rows(self) -> np.ndarray:
        """Rows of the table ``[level-0 CVs; level-1 detail vectors; ...; level-k ones]`` that
        `_terms_index`'s ``patch_rows`` index, for each ``k`` in ``0 .. depth-1``:
        ``(depth,) int64``."""
        return np.cumsum([self.u.n * self.v.n] + [lev.cv_keys.size for lev in self.fine], dtype=np.int64)

    def level(self, k: int) -> Level:
        if not 1 <= k < self.depth:
            raise IndexError(f"level {k} outside 1..{self.depth - 1}")
        return self.fine[k - 1]

    @property
    def domain(self) -> tuple[float, float]:
        """Parameter extent ``(P0u, P0v)`` in level-0 patch units."""
        return float(self.u.patches0), float(self.v.patches0)

    def size(self) -> float:
        """Object size: the diagonal of the level-0 control net's bounding box."""
        return self._size

    @cached_property
    def _size(self) -> float:
        # once per surface: every tolerance of a query on it is relative to this
        pts = self.cvs.reshape(-1, 3)
        return float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))

    @cached_property
    def _closed_ends(self) -> tuple[tuple[int, int], ...]:
        """`closed_ends`, found once per surface (they depend on level 0 alone)."""
        out, tol = [], 1e-6 * self.size()
        for axis, d in ((0, self.u), (1, self.v)):
            if d.periodic:
                continue
            grid = self.cvs if axis == 1 else self.cvs.transpose(1, 0, 2)  # (other, this, 3)
            m = grid.shape[1]
            for end, (e0, e1, e2) in enumerate(((0, 1, 2), (m - 1, m - 2, m - 3))):
                if m >= 5 and np.ptp(grid[:, e0] + 4.0 * grid[:, e1] + grid[:, e2], axis=0).max() <= tol:
                    out.append((axis, end))
        return tuple(out)



# --------------------------------------------------------------------------------------------
# construction and refinement


_LEVEL0 = ("_size", "_closed_ends")  # cached properties of level 0 alone
TABLE_STARTS = "_table_starts"  # `details._starts`, kept on a surface
_STRUCTURE = ("_terms_index", "_table_rows", TABLE_STARTS)  # of the grid's size and the fine levels' patches and CVs alone
# `hspline.eval_arrays`' arguments of a surface, kept on it: of level 0 and the structure alone
EVAL_ARGS = "_eval_args"


def with_fine(hs: HSpline, fine: tuple[Level, ...], same_cvs: bool = False) -> HSpline:
    """``hs`` with other fine levels and the same level 0: what depends on level 0 alone (the
    size, the closed ends) is carried over, not found again for the new surface object; with
    ``same_cvs`` (only offsets changed: every level's patches, CVs and movability as in ``hs``)
    so is `HSpline._terms_index`."""
    # the fields set directly, not `dataclasses.replace` nor the frozen constructor, which sets
    # one field at a time through ``object.__setattr__``: a response builds a surface per move
    new = object.__new__(HSpline)
    new.__dict__.update(cvs=hs.cvs, u=hs.u, v=hs.v, depth=hs.depth, fine=fine)
    return _carry(hs, new, _LEVEL0 + (_STRUCTURE + (EVAL_ARGS,) if same_cvs else ()))


def with_offsets(lev: Level, offsets: np.ndarray) -> Level:
    """``lev`` with other ``offsets (c, 3) float64`` (the same patches, CVs and movability),
    its fields set directly as `with_fine` sets a surface's (a response moves a level per
    step)."""
    new = object.__new__(Level)
    new.__dict__.update(k=lev.k, patches=lev.patches, cv_keys=lev.cv_keys, offsets=offsets, movable=lev.movable,
                        patch_rows=lev.patch_rows)
    return new


def with_cvs(hs: HSpline, cvs: np.ndarray) -> HSpline:
    """``hs`` with other level-0 CVs (the same grid) and the same fine levels: `HSpline._terms_index`
    is carried over."""
    return _carry(hs, HSpline(cvs, hs.u, hs.v, hs.depth, hs.fine), _STRUCTURE)


def _carry(old: HSpline, new: HSpline, names: tuple[str, ...]) -> HSpline:
    for name in names:
        if name in old.__dict__:
            new.__dict__[name] = old.__dict__[name]
    return new




def _empty_level(k: int) -> Level:
    return Level(
        k=k,
        patches=np.zeros(0, np.int64),
        cv_keys=np.zeros(0, np.int64),
        offsets=np.zeros((0, 3)),
        movable=np.zeros(0, bool),
        patch_rows=np.zeros((0, 4, 4), np.int64),
    )


def from_grid(cvs: np.ndarray, u_periodic: bool = False, v_periodic: bool = False, depth: int = 1) -> HSpline:
    """An H-spline with only its level-0 grid.

    Parameters
    ----------
    cvs : (nu, nv, 3) float64
        Level-0 control vertices.
    depth : int
        Levels the object may use (``>= 1``).
    """
    cvs = np.ascontiguousarray(cvs, dtype=np.float64)
    if cvs.ndim != 3 or cvs.shape[2] != 3:
        raise ValueError(f"cvs must have shape (nu, nv, 3), got {cvs.shape}")
    if depth < 1:
        raise ValueError(f"depth must be at least 1, got {depth}")
    u = Direction(cvs.shape[0], bool(u_periodic))
    v = Direction(cvs.shape[1], bool(v_periodic))
    return HSpline(cvs=cvs, u=u, v=v, depth=int(depth), fine=tuple(_empty_level(k) for k in range(1, depth)))


def _patch_keys(hs: HSpline, k: int, pu: np.ndarray, pv: np.ndarray) -> np.ndarray:
    return pu * hs.v.patches(k) + pv


def _cv_keys(hs: HSpline, k: int, ju: np.ndarray, jv: np.ndarray) -> np.ndarray:
    return ju * hs.v.cvs(k) + jv


def _split_patch(hs: HSpline, k: int, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    npv = hs.v.patches(k)
    return keys // npv, keys % npv


def _split_cv(hs: HSpline, k: int, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ncv = hs.v.cvs(k)
    return keys // ncv, keys % ncv


def _lookup(sorted_keys: np.ndarray, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows of ``keys`` in ``sorted_keys`` and whether each was found."""
    if sorted_keys.size == 0:
        return np.zeros(keys.shape, np.int64), np.zeros(keys.shape, bool)
    rows = np.searchsorted(sorted_keys, keys)
    rows = np.minimum(rows, sorted_keys.size - 1)
    return rows, sorted_keys[rows] == keys


def _valid_patches(hs: HSpline, k: int, pu: np.ndarray, pv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ok = hs.u.patch_valid(pu, k) & hs.v.patch_valid(pv, k)
    return hs.u.wrap_patch(pu, k), hs.v.wrap_patch(pv, k), ok


def _build_level(hs: HSpline, k: int, keys: np.ndarray, old: Level) -> Level | None:
    """Level ``k`` as ``old`` with the patch keys ``keys`` (in range, any order) also active,
    keeping the offsets ``old`` had; ``None`` if every key is active already. Compiled
    (`acra.levelkernels.build_level`); `_build_level_numpy` is the array form, used where the
    level's grid is too large for the kernel's dense marks or ``old``'s keys are not sorted."""
    u, v = hs.u, hs.v
    if max(u.patches(k) * v.patches(k), u.cvs(k) * v.cvs(k)) <= levelkernels._MAX_CELLS:
        status, patches, cv_keys, patch_rows, movable, offsets, stranded = levelkernels.build_level(
            np.ascontiguousarray(keys, np.int64), old.patches, old.cv_keys, old.offsets,
            u.cvs(k), u.patches(k), u.periodic, v.cvs(k), v.patches(k), v.periodic)
        if status == 1:
            return None
        if status == 0:
            if stranded:
                raise ValueError(f"level {k}: refinement would leave offsets on CVs that are not free to move")
            return Level(k=k, patches=patches, cv_keys=cv_keys, offsets=offsets, movable=movable, patch_rows=patch_rows)
    if np.all(_lookup(old.patches, keys)[1]):
        return None
    return _build_level_numpy(hs, k, np.concatenate([old.patches, keys]), old)


def _build_level_numpy(hs: HSpline, k: int, patches: np.ndarray, old: Level) -> Level:
    """`_build_level` as array operations (the reference the kernel is tested against)."""
    patches = np.unique(patches)
    pu, pv = _split_patch(hs, k, patches)
    ju = hs.u.wrap_cv(pu[:, None] + _I4[None, :], k)  # (m, 4)
    jv = hs.v.wrap_cv(pv[:, None] + _I4[None, :], k)
    block = _cv_keys(hs, k, ju[:, :, None], jv[:, None, :])  # (m, 4, 4)
    kept = _lookup(old.patches, patches)[1]
    if old.patches.size and int(kept.sum()) == old.patches.size:
        # every old patch stays (a refinement): the old level's CVs (its patches' blocks) plus
        # the new patches' blocks', each block's rows found by a binary search; `np.unique`'s
        # sorted keys and inverse without sorting every block key again
        cv_keys = np.union1d(old.cv_keys, block[~kept].reshape(-1))
        patch_rows = np.searchsorted(cv_keys, block).astype(np.int64)
    else:
        cv_keys, inverse = np.unique(block.reshape(-1), return_inverse=True)
        patch_rows = inverse.reshape(-1, 4, 4).astype(np.int64)

    # movable: all existing support patches (ju-3..ju) x (jv-3..jv) active
    cu, cv = _split_cv(hs, k, cv_keys)
    su = cu[:, None] - 3 + _I4[None, :]  # (c, 4)
    sv = cv[:, None] - 3 + _I4[None, :]
    su_w, sv_w = hs.u.wrap_patch(su, k), hs.v.wrap_patch(sv, k)
    ok_u, ok_v = hs.u.patch_valid(su, k), hs.v.patch_valid(sv, k)
    skeys = _patch_keys(hs, k, su_w[:, :, None], sv_w[:, None, :])
    _, found = _lookup(patches, skeys)
    exists = ok_u[:, :, None] & ok_v[:, None, :]
    movable = np.all(found | ~exists, axis=(1, 2))

    offsets = np.zeros((cv_keys.size, 3))
    if old.cv_keys.size:
        rows, hit = _lookup(old.cv_keys, cv_keys)
        offsets[hit] = old.offsets[rows[hit]]
    if np.any(offsets[~movable] != 0.0):
        raise ValueError(f"level {k}: refinement would leave offsets on CVs that are not free to move")
    return Level(k=k, patches=patches, cv_keys=cv_keys, offsets=offsets, movable=movable, patch_rows=patch_rows)


def refine(hs: HSpline, k: int, patches: np.ndarray) -> HSpline:
    """Activate level-``k`` patches (and their ancestors) by binary subdivision.

    Creates only the CVs of the new patches, with zero offsets: the surface is unchanged.

    Parameters
    ----------
    patches : (m, 2) int64
        ``(pu, pv)`` at level ``k``; periodic directions wrap, patches outside an open domain
        are ignored.
    """
    return refine_levels(hs, {k: patches})


def _top_level(hs: HSpline, levels) -> int:
    """The finest of ``levels`` (ints), after checking every one is a refinable level 1..depth-1."""
    top = max(levels)
    if not 1 <= min(levels) or not top < hs.depth:
        bad = top if top >= hs.depth else min(levels)
        raise ValueError(f"cannot refine to level {bad}: the object has levels 0..{hs.depth - 1}")
    return top


def _build_into(hs: HSpline, level: int, keys: np.ndarray, fine: list) -> None:
    """Level ``level`` with the patches ``keys (m,) int64`` (``pu * nv + pv``) active, into
    ``fine[level - 1]``; unchanged when they are all active already."""
    built = _build_level(hs, level, keys, fine[level - 1]) if keys.size else None
    if built is not None:
        fine[level - 1] = built


def _with_levels(hs: HSpline, fine: list) -> HSpline:
    """``hs`` with its finer levels ``fine``; ``hs`` itself when no level was rebuilt."""
    if all(a is b for a, b in zip(fine, hs.fine)):  # every patch was active: the same surface
        return hs
    return with_fine(hs, tuple(fine))


def refine_levels(hs: HSpline, patches: dict[int, np.ndarray]) -> HSpline:
    """`refine` of several levels at once: ``patches[k] (m_k, 2) int64`` at each level ``k``.

    One sweep from the finest level to level 1 builds each level once, with its own patches
    and the parents of the finer ones; the surface is the one that refining each level in turn
    gives (a level's patches and CVs are a set, the same whatever order they are added in).
    """
    if not patches:
        return hs
    top = _top_level(hs, patches)
    fine = list(hs.fine)
    pu = pv = np.zeros(0, np.int64)
    for level in range(top, 0, -1):
        if level in patches:
            own = np.asarray(patches[level], dtype=np.int64).reshape(-1, 2)
            pu, pv = (own[:, 0], own[:, 1]) if level == top else (np.concatenate([own[:, 0], pu]), np.concatenate([own[:, 1], pv]))
        wu, wv, ok = _valid_patches(hs, level, pu, pv)
        keys = _patch_keys(hs, level, wu[ok], wv[ok])
        _build_into(hs, level, keys, fine)
        pu, pv = wu[ok] >> 1, wv[ok] >> 1
    return _with_levels(hs, fine)


def refine_blocks(hs: HSpline, levels: tuple[int, ...], u: np.ndarray, v: np.ndarray,
                  extra: dict[int, np.ndarray] | None = None) -> HSpline:
    """`make_movable` of the patch of each point ``u, v (K,) float64`` (level-0 units) on each
    of ``levels``, plus ``extra[k] (m, 2) int64`` patches of level ``k`` (in range), as one
    `refine_levels`: the same surface, each level built once, its keys listed in one compiled
    pass (`levelkernels.block_keys`: the 7×7 blocks and the finer level's parents)."""
    return refine_keys(hs, refinement_keys(hs, levels, u, v, extra))


def refinement_keys(hs: HSpline, levels: tuple[int, ...], u: np.ndarray, v: np.ndarray,
                    extra: dict[int, np.ndarray] | None = None) -> tuple[tuple[int, np.ndarray], ...]:
    """The patches `refine_blocks` activates, ``(level, keys (m,) int64)`` finest level first
    (``pu * nv + pv``, the finer levels' parents among them): the refinement is a function of
    these and ``hs`` alone, so a caller can key what it derives from the refined surface by them."""
    if not levels:
        return ()
    top = _top_level(hs, levels)
    extra = extra or {}
    u = np.ascontiguousarray(u, np.float64)
    v = np.ascontiguousarray(v, np.float64)
    none = u[:0]
    out = []
    keys, finer_v = np.zeros(0, np.int64), 1
    for level in range(top, 0, -1):
        on = level in levels
        npv = hs.v.patches(level)
        keys = levelkernels.block_keys(u if on else none, v if on else none, level, hs.u.patches(level), hs.u.periodic,
                                       npv, hs.v.periodic, keys, finer_v)
        if level in extra:
            more = np.asarray(extra[level], np.int64).reshape(-1, 2)
            keys = np.concatenate([keys, more[:, 0] * npv + more[:, 1]])
        out.append((level, keys))
        finer_v = npv
    return tuple(out)


def refine_keys(hs: HSpline, keys: tuple[tuple[int, np.ndarray], ...]) -> HSpline:
    """``hs`` with the patches ``keys`` (`block_keys`) active, each level built once."""
    if not keys:
        return hs
    fine = list(hs.fine)
    for level, k in keys:
        _build_into(hs, level, k, fine)
    return _with_levels(hs, fine)


def make_movable(hs: HSpline, k: int, patches: np.ndarray) -> HSpline:
    """Refine so that every CV of the given level-``k`` patches is movable (thesis §3.4).

    A CV ``j`` is supported on patches ``j-3 .. j``, so patch ``p``'s CVs need the 7×7 block of
    patches ``p-3 .. p+3`` active (clipped at an open border).

    Parameters
    ----------
    patches : (m, 2) int64
        ``(pu, pv)`` at level ``k``.
    """
    if k == 0:
        return hs
    patches = np.asarray(patches, dtype=np.int64).reshape(-1, 2)
    d = np.arange(-3, 4)
    pu = (patches[:, 0, None, None] + d[None, :, None]) + 0 * d[None, None, :]
    pv = (patches[:, 1, None, None] + 0 * d[None, :, None]) + d[None, None, :]
    return refine(hs, k, np.stack([pu.reshape(-1), pv.reshape(-1)], axis=1))


def set_offsets(hs: HSpline, k: int, cvs_uv: np.ndarray, offsets: np.ndarray, add: bool = False) -> HSpline:
    """Set (or add to) the local-frame offsets of level-``k`` CVs.

    Parameters
    ----------
    cvs_uv : (c, 2) int64
        CV indices ``(ju, jv)`` at level ``k`` (periodic directions wrap).
    offsets : (c, 3) float64
        Offsets in each CV's local frame ``(e_u, e_v, n)``.

    Raises ``ValueError`` if a CV is absent or not movable (C2 rule).
    """
    lev = hs.level(k)
    cvs_uv = np.asarray(cvs_uv, dtype=np.int64).reshape(-1, 2)
    offsets = np.asarray(offsets, dtype=np.float64).reshape(-1, 3)
    ju, jv = hs.u.wrap_cv(cvs_uv[:, 0], k), hs.v.wrap_cv(cvs_uv[:, 1], k)
    rows, found = _lookup(lev.cv_keys, _cv_keys(hs, k, ju, jv))
    if not np.all(found):
        bad = cvs_uv[~found][0]
        raise ValueError(f"level {k}: CV {tuple(int(x) for x in bad)} does not exist (refine its patches first)")
    if not np.all(lev.movable[rows]):
        bad = cvs_uv[~lev.movable[rows]][0]
        raise ValueError(f"level {k}: CV {tuple(int(x) for x in bad)} is not free to move (C2 rule at a refined-region border)")
    new = lev.offsets.copy()
    if add:
        np.add.at(new, rows, offsets)
    else:
        new[rows] = offsets
    fine = list(hs.fine)
    fine[k - 1] = replace(lev, offsets=new)
    return with_fine(hs, tuple(fine))


def offsets_of(hs: HSpline, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Movable CVs of level ``k`` with their offsets: ``(c, 2) int64`` indices, ``(c, 3)``."""
    lev = hs.level(k)
    ju, jv = _split_cv(hs, k, lev.cv_keys[lev.movable])
    return np.stack([ju, jv], axis=1), lev.offsets[lev.movable]


def cv_uv(hs: HSpline, k: int, keys: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Parameter centres ``(u, v)`` (level-0 units) of level-``k`` CVs (all present by default)."""
    keys = hs.level(k).cv_keys if keys is None else keys
    ju, jv = _split_cv(hs, k, keys)
    return hs.u.greville(ju, k), hs.v.greville(jv, k)


def patch_cvs(hs: HSpline, k: int, patches: np.ndarray) -> np.ndarray:
    """CV indices ``(ju, jv)`` of level-``k`` patches: ``(m, 4, 4, 2) int64`` (wrapped)."""
    patches = np.asarray(patches, dtype=np.int64).reshape(-1, 2)
    ju = hs.u.wrap_cv(patches[:, 0, None] + _I4[None, :], k)
    jv = hs.v.wrap_cv(patches[:, 1, None] + _I4[None, :], k)
    return np.stack(np.broadcast_arrays(ju[:, :, None], jv[:, None, :]), axis=-1)


# --------------------------------------------------------------------------------------------
# poles: an end of the open direction that closes to one point


def closed_ends(hs: HSpline) -> tuple[tuple[int, int], ...]:
    """Ends of an open direction that close to a point: a pole (`acra.shapes.sphere`) or a
    collapsed edge of an open grid (a fan's apex, degenerate triangular patches).

    The surface at an end is ``(R0 + 4 R1 + R2) / 6`` blended along the other direction, with
    ``R0..R2`` its three outermost CV rows; it is one point when that sum is the same all along
    (within 1e-6 of the size, which covers float32 ``acra:cvs``), whether the other direction is
    periodic (a pole) or open (a collapsed edge): in both, every parameter along the end names the
    same point, and a response must keep it one point. Returns ``(axis, end)`` pairs: axis 0 = u,
    1 = v; end 0 at parameter 0, 1 at ``P0``.
    """
    return hs._closed_ends


def pole_of(hs: HSpline, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Index into `closed_ends` of the pole each point ``(u, v) (K,)`` sits on, or -1.

    A point is on a pole when its open parameter is within 1e-9 of a closed end: there every
    value of the periodic parameter names the same surface point, so the parameter a projection
    returns is arbitrary and anything weighted by it must not depend on it."""
    out = np.full(np.size(u), -1, np.int64)
    for i, (axis, end) in enumerate(closed_ends(hs)):
        d = hs.u if axis == 0 else hs.v
        x = np.atleast_1d(np.asarray(u if axis == 0 else v, np.float64))
        out[np.abs(x - end * d.patches0) <= 1e-9 * d.patches0] = i
    return out


def _end_rows(count: int, end: int) -> np.ndarray:
    """The three outermost of ``count`` rows at ``end`` (0: first, 1: last), outermost first."""
    return np.array([0, 1, 2]) if end == 0 else count - 1 - np.array([0, 1, 2])


def pole_ring(hs: HSpline, k: int, axis: int, end: int) -> tuple[np.ndarray, np.ndarray]:
    """The level-``k`` CVs that make a pole: ``keys (N, 3) int64`` (one column of three rows per
    periodic index ``0..N-1``, outermost row first) and ``weights (3,)``, the basis of the three
    rows at the end (1/6, 4/6, 1/6). The pole point is ``sum_j B_j(s) (weights @ rows_j)``, the
    same for every ``s`` iff ``weights @ rows_j`` is the same for every column ``j``."""
    return _pole_ring_keys(hs.u, hs.v, k, axis, end), np.array([1.0, 4.0, 1.0]) / 6.0


def pole_ring_rows(hs: HSpline, k: int, axis: int, end: int) -> tuple[np.ndarray, np.ndarray]:
    """The `pole_ring` of level ``k >= 1`` at ``(axis, end)`` as rows of the level's CVs, ``rows
    (N, 3) int64`` (`_lookup`'s, clipped where absent), and whether each CV exists and is
    movable, ``ok (N, 3) bool``; read-only. They depend on the level's CVs alone, so they are
    looked up once per `Level` object and kept on it (a response asks for each ring several times
    per step, and a weight for each point on a pole)."""
    lev = hs.level(k)
    memo = lev.__dict__.setdefault("_ring_rows", {})
    key = (hs.u.n, hs.u.periodic, hs.v.n, hs.v.periodic, axis, end)  # the grid's fields: cheaper to hash than its directions
    if key not in memo:
        ring = _pole_ring_keys(hs.u, hs.v, k, axis, end)
        rows, ok = _lookup(lev.cv_keys, ring)
        if lev.cv_keys.size:
            ok &= lev.movable[rows]
        rows.flags.writeable = ok.flags.writeable = False
        memo[key] = (rows, ok)
    return memo[key]


def pole_ring_movable(hs: HSpline, k: int, axis: int, end: int) -> bool:
    """Whether every CV of level ``k``'s `pole_ring` at ``(axis, end)`` exists and is movable
    (`pole_ring_rows`' ``ok`` all true), kept with those rows on the `Level` object: a response
    asks it of every ring at every step."""
    memo = hs.level(k).__dict__.setdefault("_ring_rows", {})
    key = ("movable", hs.u.n, hs.u.periodic, hs.v.n, hs.v.periodic, axis, end)
    hit = memo.get(key)
    if hit is None:
        hit = memo[key] = bool(pole_ring_rows(hs, k, axis, end)[1].all())
    return hit


@functools.lru_cache(maxsize=256)
def _pole_ring_keys(u: Direction, v: Direction, k: int, axis: int, end: int) -> np.ndarray:
    """`pole_ring`'s keys, which depend on the grid's directions alone: built once per grid and
    level (a response asks for each ring several times per level), read-only."""
    per, opn = (v, u) if axis == 0 else (u, v)
    rows = _end_rows(opn.cvs(k), end)
    j = np.arange(per.cvs(k))[:, None]
    ju, jv = np.broadcast_arrays(rows[None, :], j) if axis == 0 else np.broadcast_arrays(j, rows[None, :])
    keys = ju * v.cvs(k) + jv
    keys.flags.writeable = False
    return keys


def pole_patches(hs: HSpline, k: int, axis: int, end: int) -> np.ndarray:
    """Level-``k`` patches ``(3 N, 2) int64`` whose activation makes the whole `pole_ring` movable:
    the three patch rows at the end, all around (a ring CV's support reaches three patches in);
    read-only."""
    return _pole_patches(hs.u, hs.v, k, axis, end)


@functools.lru_cache(maxsize=256)
def _pole_patches(u: Direction, v: Direction, k: int, axis: int, end: int) -> np.ndarray:
    """`pole_patches`, which depend on the grid's directions alone: built once per grid and level
    (a response refines about a pole on each absorbing level), read-only."""
    per, opn = (v, u) if axis == 0 else (u, v)
    rows = _end_rows(opn.patches(k), end)
    p = np.arange(per.patches(k))
    a, b = np.meshgrid(rows, p, indexing="ij") if axis == 0 else np.meshgrid(p, rows, indexing="ij")
    out = np.stack([a.reshape(-1), b.reshape(-1)], axis=1).astype(np.int64)
    out.flags.writeable = False
    return out


def storage_size(hs: HSpline) -> int:
    """Total CVs stored: the level-0 grid plus every present fine CV."""
    return int(hs.cvs.shape[0] * hs.cvs.shape[1] + sum(lev.cv_keys.size for lev in hs.fine))




# --------------------------------------------------------------------------------------------
# plain-array form (what the pipeline stores in USD)


@dataclass(frozen=True)
class HierarchyArrays:
    """The fine levels of an H-spline as flat arrays (lossless, storage-sized).

    Attributes
    ----------
    patch_level : (m,) int32
        Level (``>= 1``) of each refined patch.
    patches : (m, 2) int32
        ``(pu, pv)`` of each refined patch at its level.
    offset_level : (c,) int32
        Level of each non-zero offset.
    offset_cvs : (c, 2) int32
        ``(ju, jv)`` of each offset CV at its level.
    offsets : (c, 3) float64
        Offsets in the CVs' local frames.
    """

    patch_level: np.ndarray
    patches: np.ndarray
    offset_level: np.ndarray
    offset_cvs: np.ndarray
    offsets: np.ndarray


def to_arrays(hs: HSpline) -> HierarchyArrays:
    """The fine levels as flat arrays; only refined patches and non-zero offsets are kept. A
    level's keys split by its own row length (`_split_patch`, `_split_cv`), so the levels' keys
    are concatenated with each key's divisor beside it and split in one pass."""
    if not hs.fine:
        return HierarchyArrays(np.zeros(0, np.int32), np.zeros((0, 2), np.int32), np.zeros(0, np.int32),
                               np.zeros((0, 2), np.int32), np.zeros((0, 3), np.float64))
    ks = np.array([lev.k for lev in hs.fine], np.int64)
    n_patches = [lev.patches.size for lev in hs.fine]
    keys = np.concatenate([lev.patches for lev in hs.fine])
    per_row = np.repeat(np.array([hs.v.patches(int(k)) for k in ks], np.int64), n_patches)
    patches = np.empty((keys.size, 2), np.int32)
    patches[:, 0], patches[:, 1] = keys // per_row, keys % per_row
    offsets = np.concatenate([lev.offsets for lev in hs.fine])
    nz = np.any(offsets != 0.0, axis=1)
    n_cvs = [lev.cv_keys.size for lev in hs.fine]
    cv_keys = np.concatenate([lev.cv_keys for lev in hs.fine])[nz]
    cv_row = np.repeat(np.array([hs.v.cvs(int(k)) for k in ks], np.int64), n_cvs)[nz]
    offset_cvs = np.empty((cv_keys.size, 2), np.int32)
    offset_cvs[:, 0], offset_cvs[:, 1] = cv_keys // cv_row, cv_keys % cv_row
    return HierarchyArrays(
        patch_level=np.repeat(ks.astype(np.int32), n_patches),
        patches=patches,
        offset_level=np.repeat(ks.astype(np.int32), n_cvs)[nz],
        offset_cvs=offset_cvs,
        offsets=np.ascontiguousarray(offsets[nz], dtype=np.float64),
    )


def from_arrays(base: HSpline, arrays: HierarchyArrays) -> HSpline:
    """Rebuild the fine levels stored by `to_arrays` on top of a level-0-only ``base``.

    Raises ``ValueError`` naming the level and index when a patch or offset is out of range or
    an offset sits on a CV that the C2 rule keeps fixed.
    """
    hs = base
    levels = np.asarray(arrays.patch_level, dtype=np.int64)
    patches = np.asarray(arrays.patches, dtype=np.int64).reshape(-1, 2)
    for k in np.unique(levels):
        if not 1 <= k < hs.depth:
            raise ValueError(f"refined patch at level {k}, outside 1..{hs.depth - 1}")
        sel = patches[levels == k]
        for d, col, name in ((hs.u, 0, "u"), (hs.v, 1, "v")):
            bad = (sel[:, col] < 0) | (sel[:, col] >= d.patches(int(k)))
            if np.any(bad):
                raise ValueError(f"level {k}: patch index {int(sel[bad][0, col])} along {name} outside 0..{d.patches(int(k)) - 1}")
        hs = refine(hs, int(k), sel)
    olev = np.asarray(arrays.offset_level, dtype=np.int64)
    ocvs = np.asarray(arrays.offset_cvs, dtype=np.int64).reshape(-1, 2)
    offs = np.asarray(arrays.offsets, dtype=np.float64).reshape(-1, 3)
    for k in np.unique(olev):
        if not 1 <= k < hs.depth:
            raise ValueError(f"offset at level {k}, outside 1..{hs.depth - 1}")
        sel = olev == k
        hs = set_offsets(hs, int(k), ocvs[sel], offs[sel])
    return hs
