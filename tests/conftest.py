"""Shared, seeded test objects."""

import numpy as np
import pytest

from acra import hspline as H
from acra import shapes


def wavy_sheet(nu=8, nv=7, depth=4, seed=0):
    rng = np.random.default_rng(seed)
    cvs, pu, pv = shapes.sheet(nu, nv, width=nu - 3.0, depth=nv - 3.0, height=0.3 * rng.normal(size=(nu, nv)))
    return H.from_grid(cvs, pu, pv, depth=depth)


def with_random_offsets(hs, scale=0.05, seed=1):
    rng = np.random.default_rng(seed)
    for k in range(1, hs.depth):
        idx, off = H.offsets_of(hs, k)
        hs = H.set_offsets(hs, k, idx, scale * rng.normal(size=off.shape))
    return hs


@pytest.fixture
def sheet4():
    return wavy_sheet()
