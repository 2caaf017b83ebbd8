"""The thesis's benchmark (Fig. 5.1–5.2): a spike jabs the cheek of a large, detailed head.

    python scenes/dog_head_spike.py          # writes dog_head_spike.usda beside this file
    acra run scenes/dog_head_spike.py --rrd dog_head_spike.rrd

The head is an H-spline with 7 levels and about 2200 stored CVs: a 16×12 closed level-0 grid
(poles top and bottom, the snout toward +x) with its detail modelled locally on finer levels — snout
and ears on level 1, muzzle and brows on level 2, nose on levels 4–5, nostrils on level 6 — so
most of the model exists only where it has detail (a dense level 6 would hold 700 000 CVs). The
spike is a cone with 3 levels and 89 CVs. It is keyed (native USD splines) to jab the side of the
head and pull back: 30 frames, 4 of them in collision, as in the thesis's timing animation.

The head is soft (rigidity 10) and the spike stiff (rigidity 80), so by eq. 4.15 the head takes
8/9 of the response; the head's absorption lies on levels 2–4 (a dent the size of the spike's
tip, refined only where the spike touches), the spike's on its levels 1–2.
"""

from pathlib import Path

import numpy as np

from acra import hspline as H
from acra import shapes
from pipeline import authoring as A
from pipeline.animation import usdkeys as K


def bump(hs: H.HSpline, k: int, uc: float, vc: float, ru: float, rv: float, height: float) -> H.HSpline:
    """Add a smooth bump of ``height`` (along the level-(k−1) normal) on level ``k``.

    The bump is centred at ``(uc, vc)`` with radii ``(ru, rv)`` in level-0 parameter units, with
    the profile ``(1 − d²)²``; only the level-``k`` patches under it are refined (7×7 blocks,
    the C2 rule of `acra.hspline.make_movable`).
    """
    n = 2**k
    pu = np.arange(int(np.floor((uc - ru) * n)) - 1, int(np.ceil((uc + ru) * n)) + 1)
    pv = np.arange(int(np.floor((vc - rv) * n)) - 1, int(np.ceil((vc + rv) * n)) + 1)
    hs = H.make_movable(hs, k, np.stack(np.meshgrid(pu, pv, indexing="ij"), -1).reshape(-1, 2))
    idx, _ = H.offsets_of(hs, k)
    du = hs.u.greville(idx[:, 0], k) - uc
    if hs.u.periodic:
        du = (du + hs.u.patches0 / 2) % hs.u.patches0 - hs.u.patches0 / 2
    w = np.clip(1.0 - (du / ru) ** 2 - ((hs.v.greville(idx[:, 1], k) - vc) / rv) ** 2, 0.0, None) ** 2
    sel = w > 0
    off = np.zeros((int(sel.sum()), 3))
    off[:, 2] = height * w[sel]
    return H.set_offsets(hs, k, idx[sel], off, add=True)


def head() -> tuple[np.ndarray, H.HSpline]:
    """The head: level-0 CVs ``(16, 12, 3)`` and its 7-level hierarchy of local detail."""
    cvs, u_periodic, v_periodic = shapes.sphere(16, 12, radii=(1.0, 0.85, 0.9))
    hs = H.from_grid(cvs, u_periodic, v_periodic, depth=7)
    # (level, u, v, radius u, radius v, height): u = 0 faces +x, u = 4 faces +y; v = 4.5 is the equator
    features = [
        (1, 0.0, 4.5, 1.5, 1.4, 0.45),  # snout
        (1, 3.0, 7.0, 0.6, 0.8, 0.5),  # ears
        (1, 13.0, 7.0, 0.6, 0.8, 0.5),
        (2, 0.0, 4.6, 0.6, 0.5, 0.12),  # muzzle
        (2, 1.4, 5.8, 0.5, 0.2, 0.05),  # brows
        (2, 14.6, 5.8, 0.5, 0.2, 0.05),
        (4, 0.0, 4.9, 0.25, 0.2, 0.07),  # nose
        (5, 0.0, 5.0, 0.1, 0.08, 0.025),  # nose tip
        (6, -0.05, 4.97, 0.035, 0.03, -0.01),  # nostrils
        (6, 0.05, 4.97, 0.035, 0.03, -0.01),
    ]
    for feature in features:
        hs = bump(hs, *feature)
    return cvs, hs


def spike() -> tuple[np.ndarray, H.HSpline]:
    """The spike: a cone along −y (tip at y = −0.6), 8×8 level-0 CVs and a refined tip region."""
    cvs, u_periodic, v_periodic = shapes.sphere(8, 8, radii=(0.18, 0.18, 0.6))
    # taper toward the north pole (the tip), then lay the cone along -y
    cvs[..., :2] *= np.clip(0.6 - cvs[..., 2:3], 0.0, None) / 1.2
    cvs = cvs[..., [0, 2, 1]] * np.array([1.0, -1.0, 1.0])
    hs = H.from_grid(cvs, u_periodic, v_periodic, depth=3)
    hs = H.refine(hs, 1, np.array([[pu, pv] for pu in range(2) for pv in range(8, 10)]))  # at the tip
    return cvs, hs


def build():
    stage = A.new_stage(1, 30, fps=24, up_axis="Z")
    cvs, hs = head()
    A.add_deformable(
        stage, "/World/Head", cvs, u_wrap="periodic", v_wrap="open", hierarchy=hs,
        absorption=[0, 0, 0.2, 0.3, 0.5, 0, 0], rigidity=10, samples=6,
    )
    cvs, hs = spike()
    mover = A.add_xform(stage, "/World/Jab")
    A.add_deformable(
        stage, "/World/Jab/Spike", cvs, u_wrap="periodic", v_wrap="open", hierarchy=hs,
        absorption=[0, 0.5, 0.5], rigidity=80, samples=4,
    )
    # the tip approaches the cheek (+y side), goes 0.1 deep at frame 15 and pulls back
    K.key_translate(mover.GetPrim() if hasattr(mover, "GetPrim") else mover, "xyz",
                    [1, 12, 15, 18, 30], [[0.1, 2.2, 0.15], [0.1, 1.5, 0.1], [0.1, 1.36, 0.08],
                                           [0.1, 1.5, 0.1], [0.1, 2.2, 0.15]], interp="catmull_rom")
    return stage


if __name__ == "__main__":
    A.save(build(), Path(__file__).with_suffix(".usda"))
