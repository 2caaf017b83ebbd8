"""An object's ACRA controls (thesis §4.3): how much of the response each hierarchy level absorbs
and, per level, its mix of deformation, translation and rotation; its rigidity and whether a
response refines the surface where it needs finer levels.

`check_controls` holds controls to the contract (docs/usd-schema.md) and fills its defaults;
`corrective` gives the controls of a corrective round. The USD reader (`pipeline.usdio`) reads the
same attributes from a prim and names the prim in its errors.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

__all__ = ["ControlError", "Controls", "check_controls", "corrective"]


class ControlError(ValueError):
    """An invalid control: ``attribute`` names the contract attribute (``acra:absorption``, …)."""

    def __init__(self, attribute: str, problem: str):
        self.attribute, self.problem = attribute, problem
        super().__init__(f"{attribute}: {problem}")


@dataclass(frozen=True)
class Controls:
    """Validated ACRA controls for one object (see `check_controls`).

    Attributes
    ----------
    absorption : (L,) float64
    deform, translate, rotate : (L,) float64
    rigidity : float
    refine : bool
        ``True``: refine patches down to an absorbing level; ``False``: obey the refinement.
    """

    absorption: np.ndarray
    deform: np.ndarray
    translate: np.ndarray
    rotate: np.ndarray
    rigidity: float = 50.0
    refine: bool = True


def check_controls(levels, absorption=None, deform=None, translate=None, rotate=None, rigidity=50.0, refine="refine") -> Controls:
    """Validate controls against the contract and fill its defaults.

    Defaults: absorption ``[0, …, 0, 1]``, all deformational, rigidity 50, ``refine``.
    Raises `ControlError` naming the attribute: counts not matching ``levels``, negative or
    non-finite values, sums off 1 by more than 1e-6, rigidity outside ``[1, 100]``, unknown
    policy token.
    """
    if not isinstance(levels, (int, np.integer)) or levels < 1:
        raise ControlError("acra:levels", f"must be an integer of at least 1, got {levels!r}")
    L = int(levels)
    if absorption is None:
        absorption = np.zeros(L)
        absorption[-1] = 1.0
    mixes = {}
    for name, val, fill in (("deform", deform, 1.0), ("translate", translate, 0.0), ("rotate", rotate, 0.0)):
        mixes[name] = np.full(L, fill) if val is None else val
    if deform is None and (translate is not None or rotate is not None):
        mixes["deform"] = 1.0 - np.asarray(mixes["translate"], float) - np.asarray(mixes["rotate"], float)
    arrays = {}
    for name, val in (("absorption", absorption), *mixes.items()):
        a = np.asarray(val, dtype=np.float64).reshape(-1)
        attr = f"acra:{name}"
        if a.size != L:
            raise ControlError(attr, f"has {a.size} values but acra:levels is {L}")
        if not np.all(np.isfinite(a)):
            raise ControlError(attr, "contains NaN or infinity")
        if np.any(a < 0):
            raise ControlError(attr, f"value {float(a[a < 0][0])} is negative; shares must be >= 0")
        arrays[name] = a
    if abs(arrays["absorption"].sum() - 1.0) > 1e-6:
        raise ControlError("acra:absorption", f"sums to {arrays['absorption'].sum():.9g}, must sum to 1")
    total = arrays["deform"] + arrays["translate"] + arrays["rotate"]
    bad = np.nonzero(np.abs(total - 1.0) > 1e-6)[0]
    if bad.size:
        raise ControlError("acra:deform", f"deform + translate + rotate at level {int(bad[0])} sums to {total[bad[0]]:.9g}, must be 1")
    r = float(rigidity)
    if not np.isfinite(r) or not 1.0 <= r <= 100.0:
        raise ControlError("acra:rigidity", f"{rigidity!r} is outside [1, 100]")
    if refine not in ("refine", "obey"):
        raise ControlError("acra:refine", f"unknown token {refine!r} (use 'refine' or 'obey')")
    return Controls(arrays["absorption"], arrays["deform"], arrays["translate"], arrays["rotate"], r, refine == "refine")


def corrective(controls: Controls, depth: int) -> Controls:
    """Controls of a corrective response: the whole absorption on the finest absorbing level
    (of a surface ``depth`` levels deep), with that level's own deform/translate/rotate mix.

    A round that only corrects what an earlier round left (a display a fraction of the
    tolerance inside the other object) asks moves of a few thousandths of the size. Spread over
    the levels as the animator's absorption asks, a coarse level's share moves its CVs under the
    whole contact, so the part already in place (a dent's bottom) moves with the correction;
    the finest absorbing level's CVs reach least far."""
    L = controls.absorption.size
    levels = np.nonzero(controls.absorption > 0)[0]
    k = int(min(levels.max() if levels.size else L - 1, depth - 1))
    a = np.zeros(L)
    a[k] = 1.0
    return replace(controls, absorption=a)
