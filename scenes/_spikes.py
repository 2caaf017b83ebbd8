"""Local detail for the response-type scenes (thesis Fig. 5.7–5.11): a sheet with one raised
feature modelled as offsets on a fine level of its H-spline.

Not a scene (files starting with ``_`` are not run); `deform_vs_translate`, `rolling_bump` and
`rotate_and_deform` build their deformables with it and their tests use `feature_cvs`.
"""

import numpy as np

from acra import hspline as H
from acra import shapes


def feature_sheet(n=7, width=3.0, levels=3, level=2, tip=0.8, spread=0.3):
    """A flat ``n × n`` sheet (``width`` wide, centred at the origin, facing +z) whose centre
    carries a feature on ``level``: the 3×3 block of level-``level`` CVs around the centre is
    offset along the normal by ``tip · w_a · w_b`` with ``w = (spread, 1, spread)``, a separable
    (so nearly round) profile.

    A small ``spread`` gives a spike (Fig. 5.7–5.9), a large one a round bump (Fig. 5.10–5.11).
    The feature's CVs lie in every level-``level`` patch touching the centre, so a contact at
    the top of the feature moves or turns all of them together.

    Returns
    -------
    cvs : (n, n, 3) float64
        Level-0 CVs.
    hs : HSpline
        ``levels`` deep, the feature's patches refined and its 9 offsets set.
    """
    cvs, _, _ = shapes.sheet(n, n, width=width, depth=width)
    hs = H.from_grid(cvs, depth=levels)
    idx = feature_cvs(hs, level)
    # the four patches around the centre, made fully movable (C2 rule)
    hs = H.make_movable(hs, level, idx[[0, 1, 3, 4]] - 1)
    w = np.array([spread, 1.0, spread])
    off = np.zeros((9, 3))
    off[:, 2] = tip * np.outer(w, w).reshape(-1)
    return cvs, H.set_offsets(hs, level, idx, off)


def feature_cvs(hs, level=2) -> np.ndarray:
    """Indices ``(9, 2) int64`` of the feature's level-``level`` CVs, row-major, centre at [4].

    The centre of the parameter domain is level-``k`` CV ``1 + P0 · 2^k / 2`` in each direction
    (CV ``j`` is centred at ``(j - 1) / 2^k``).
    """
    cu = 1 + hs.u.patches0 * 2**level // 2
    cv = 1 + hs.v.patches0 * 2**level // 2
    return np.array([(cu + a, cv + b) for a in (-1, 0, 1) for b in (-1, 0, 1)], np.int64)


def feature_offsets(hs, level=2) -> np.ndarray:
    """Local-frame offsets ``(9, 3) float64`` of the feature's CVs (order of `feature_cvs`)."""
    return hs.level(level).offsets[_feature_rows(hs, level)]


def feature_positions(hs, level=2) -> np.ndarray:
    """Object-space positions ``(9, 3) float64`` of the feature's CVs (derived + offset)."""
    return H.cv_positions(hs, level)[_feature_rows(hs, level)]


def _feature_rows(hs, level):
    idx = feature_cvs(hs, level)
    rows, found = H._lookup(hs.level(level).cv_keys, H._cv_keys(hs, level, idx[:, 0], idx[:, 1]))
    assert found.all(), "the feature's CVs are not refined"
    return rows
