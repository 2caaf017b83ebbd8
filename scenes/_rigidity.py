"""Shared stage of `rigid_floor` and `rigid_top` (thesis Fig. 5.3 against Fig. 5.4).

A soft pillow is pressed 0.1 into a floor slab and lifted off again. Both are deformable, with
the same controls (3 levels, the response absorbed half on level 1 and half on level 2, the
finest two, as the top object of Fig. 5.3) except their rigidity, which the two scenes swap:
1 for the soft object, 10 for the stiff one. By eq. 4.15 both surfaces move to
``P' = R P1 + (1 − R) P2`` with ``R = R1 / (R1 + R2)``, so each object moves
``R_other / (R1 + R2)`` of the way: the soft one 10/11, the stiff one 1/11, a 10 : 1 ratio.

Why a slab and not an open sheet: a sheet has no inside, so the pillow would have no
interpenetration region of its own, only its contact point to move; with the sheet the stiffer,
each round clears only 1/11 of what is left and four rounds leave 1.7e-2 of the pillow's size
(measured with a 12×12 sheet). Why the poles point sideways: a response on levels ≥ 1 whose
CVs reach the three rows at a collapsed pole opens the pole (by ~1e-5 here), and detection then
no longer sees an inside. With 10 CVs from pole to pole the pillow's data points stay more than
2 level-0 patches from its poles (a level-1 CV reaches 1.5); the slab's poles are 1.5 away.
"""

from __future__ import annotations

import numpy as np
from pxr import Usd

from acra import shapes
from pipeline import authoring as A
from pipeline.animation import usdkeys as K

SOFT, STIFF = 1.0, 10.0
ABSORPTION = [0.0, 0.5, 0.5]
DEEPEST = (11, 12)  # frames where the pillow is lowest


def _poles_along_x(cvs: np.ndarray) -> np.ndarray:
    """Turn a `shapes.sphere` grid ``(nu, nv, 3)`` a quarter turn about y: poles on ±x."""
    return cvs[..., [2, 1, 0]] * np.array([1.0, 1.0, -1.0])


def build(rigid_floor: bool) -> Usd.Stage:
    """The stage; ``rigid_floor`` gives the floor rigidity 10 and the pillow 1, else the reverse."""
    stage = A.new_stage(1, 20, fps=24, up_axis="Z")
    r_floor, r_top = (STIFF, SOFT) if rigid_floor else (SOFT, STIFF)
    # floor: a slab 3 × 3 × 0.5 whose top is at z = 0
    slab, _, _ = shapes.sphere(12, 8, radii=(0.25, 1.5, 1.5))
    A.add_deformable(stage, "/World/Floor", _poles_along_x(slab) + [0.0, 0.0, -0.25], u_wrap="periodic",
                     levels=3, absorption=ABSORPTION, rigidity=r_floor)
    # pillow: 2 × 1.4 × 0.8, lowered onto the floor and lifted (native USD splines, linear knots)
    pillow, _, _ = shapes.sphere(8, 10, radii=(0.4, 0.7, 1.0))
    mover = A.add_xform(stage, "/World/Mover")
    A.add_deformable(stage, "/World/Mover/Pillow", _poles_along_x(pillow), u_wrap="periodic",
                     levels=3, absorption=ABSORPTION, rigidity=r_top)
    K.key_translate(mover, "x", [1, 20], [0.1, 0.1])
    K.key_translate(mover, "y", [1, 20], [0.05, 0.05])
    K.key_translate(mover, "z", [1, 7, *DEEPEST, 16, 20], [0.8, 0.42, 0.3, 0.3, 0.42, 0.8], interp="linear")
    return stage
