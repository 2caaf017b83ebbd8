"""State carried across frames (thesis §5.4): a response's offsets released back to rest, per level,
with a plastic part kept for good.

A response changes a surface's coefficients level by level: the level-0 CVs (object space) and
the offsets of the finer levels (each in its CV's local frame, `acra.hspline`). The difference of
two surfaces of one object, coefficient by coefficient and level by level, is an *offset field*:
an `HSpline` whose ``cvs`` are level-0 differences and whose fine levels' ``offsets`` are offset
differences (its surface means nothing by itself). Adding a field to a surface adds the
coefficients; because finer offsets live in local frames, a carried fine dent rides along with
whatever the animator does to the coarser levels.

Equations (per level ``l``; ``A_f`` the animator's surface at frame ``f``, ``r_l(f)`` the release
rate ``acra:relax`` at ``f``, ``p_l`` the plasticity, ``E`` the elastic and ``P`` the plastic
field carried out of frame ``f - 1``; ``⊕`` adds coefficients)::

    S_f   = A_f ⊕ P_{f-1} ⊕ (1 - r_l(f)) E_{f-1}      the surface frame f starts from
    R_f   = the response of S_f (detect → respond rounds)
    ΔV_f  = R_f ⊖ S_f                                   the collision offset made at frame f
    P_f   = P_{f-1} + p_l ΔV_f                            kept for good
    E_f   = (1 - r_l(f)) E_{f-1} + (1 - p_l) ΔV_f        released at the following frames

so ``R_f = A_f ⊕ P_f ⊕ E_f`` at every frame, and on frames without a collision the elastic field
decays geometrically: ``E_{f+n} = prod_{i=1..n} (1 - r_l(f+i)) E_f``. With ``r = 1`` and ``p = 0``
nothing is carried: every frame starts from the animator's shape (the stateless loop).

All functions are pure; fields and surfaces are never modified in place.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from . import hspline as H

__all__ = [
    "Carried",
    "aligned",
    "zero_field",
    "difference",
    "added",
    "scaled",
    "is_zero",
    "level_magnitudes",
    "begin",
    "absorb",
]


@dataclass(frozen=True)
class Carried:
    """The offsets one object carries out of a frame.

    Attributes
    ----------
    elastic : HSpline
        Offset field released at the following frames by ``acra:relax``.
    plastic : HSpline
        Offset field kept for good (the ``acra:plasticity`` share of every response).
    """

    elastic: H.HSpline
    plastic: H.HSpline


def _patches(hs: H.HSpline, k: int) -> np.ndarray:
    """Active level-``k`` patches of ``hs`` as ``(m, 2) int64`` ``(pu, pv)``."""
    keys = hs.level(k).patches
    npv = hs.v.patches(k)
    return np.stack([keys // npv, keys % npv], axis=1)


def _refined_like(hs: H.HSpline, other: H.HSpline) -> H.HSpline:
    for k in range(1, hs.depth):
        mine, theirs = hs.level(k).patches, other.level(k).patches
        if theirs.size and not np.all(np.isin(theirs, mine)):
            hs = H.refine(hs, k, _patches(other, k))
    return hs


def aligned(a: H.HSpline, b: H.HSpline) -> tuple[H.HSpline, H.HSpline]:
    """``a`` and ``b`` refined to the union of their active patches (neither surface changes), so
    every level holds the same CV keys in the same rows."""
    a = _refined_like(a, b)
    b = _refined_like(b, a)
    return a, b


def zero_field(hs: H.HSpline) -> H.HSpline:
    """A field of zeros with no refined patch, shaped like ``hs`` (grid, wraps, depth)."""
    return H.from_grid(np.zeros_like(hs.cvs), hs.u.periodic, hs.v.periodic, depth=hs.depth)


def _map(fields: list[H.HSpline], fn) -> H.HSpline:
    """Coefficient-wise ``fn(level, *arrays)`` over aligned fields (structure of ``fields[0]``)."""
    first = fields[0]
    fine = tuple(replace(lev, offsets=fn(lev.k, *[f.fine[i].offsets for f in fields])) for i, lev in enumerate(first.fine))
    return replace(first, cvs=fn(0, *[f.cvs for f in fields]), fine=fine)


def difference(after: H.HSpline, before: H.HSpline) -> H.HSpline:
    """The field ``after ⊖ before``: per level, coefficients of ``after`` less those of ``before``."""
    a, b = aligned(after, before)
    return _map([a, b], lambda k, x, y: x - y)


def scaled(field: H.HSpline, factors: np.ndarray) -> H.HSpline:
    """Level ``l`` of ``field`` times ``factors[l]`` (``factors : (depth,) float64``)."""
    factors = np.asarray(factors, dtype=np.float64)
    return _map([field], lambda k, x: factors[k] * x)


def added(base: H.HSpline, *fields: H.HSpline) -> H.HSpline:
    """``base ⊕ fields...``: a surface (or field) plus fields, level by level."""
    out = base
    for f in fields:
        if is_zero(f):
            continue
        out, f = aligned(out, f)
        out = _map([out, f], lambda k, x, y: x + y)
    return out


def is_zero(field: H.HSpline) -> bool:
    """Whether every coefficient of ``field`` is zero."""
    return not np.any(field.cvs) and not any(np.any(lev.offsets) for lev in field.fine)


def level_magnitudes(field: H.HSpline) -> np.ndarray:
    """Largest coefficient length per level, ``(depth,) float64`` (level 0 in object units, finer
    levels in their local frames' units, which are object units too)."""
    out = np.zeros(field.depth)
    out[0] = float(np.linalg.norm(field.cvs, axis=-1).max(initial=0.0))
    for lev in field.fine:
        out[lev.k] = float(np.linalg.norm(lev.offsets, axis=-1).max(initial=0.0))
    return out


def begin(animator: H.HSpline, carried: Carried, relax: np.ndarray) -> tuple[H.HSpline, Carried]:
    """The surface a frame starts from and the carried state after this frame's release.

    Parameters
    ----------
    animator : HSpline
        ``A_f``, the animator's surface at the frame.
    carried : Carried
        ``E_{f-1}``, ``P_{f-1}``.
    relax : (depth,) float64
        ``r_l(f)`` in [0, 1].

    Returns
    -------
    ``S_f = A_f ⊕ P_{f-1} ⊕ (1 - r) E_{f-1}`` (``animator`` itself when nothing is carried) and
    ``Carried((1 - r) E_{f-1}, P_{f-1})``.
    """
    keep = 1.0 - np.asarray(relax, dtype=np.float64)
    elastic = carried.elastic if np.all(keep == 1.0) or is_zero(carried.elastic) else scaled(carried.elastic, keep)
    released = Carried(elastic, carried.plastic)
    return added(animator, carried.plastic, elastic), released


def absorb(released: Carried, started: H.HSpline, responded: H.HSpline, plasticity: np.ndarray) -> Carried:
    """The state carried out of a frame: ``ΔV = responded ⊖ started`` split into its plastic part
    ``p ΔV`` (added to ``P``) and its elastic part ``(1 - p) ΔV`` (added to the released ``E``).

    ``plasticity : (depth,) float64`` in [0, 1].
    """
    p = np.asarray(plasticity, dtype=np.float64)
    if responded is started:
        return released
    dv = difference(responded, started)
    plastic = added(released.plastic, scaled(dv, p)) if np.any(p) else released.plastic
    elastic = added(released.elastic, scaled(dv, 1.0 - p)) if np.any(p < 1.0) else released.elastic
    return Carried(elastic, plastic)
