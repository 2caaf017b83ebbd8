"""Readers of the spike that `deform_vs_translate`, `rolling_bump` and `rotate_and_deform` build
with `pipeline.authoring.add_spike` (level 2, middle of the sheet), under the names their tests
import. Not a scene (files starting with ``_`` are not run).
"""

import numpy as np

from pipeline import authoring


def feature_offsets(hs, level=2) -> np.ndarray:
    """Local-frame offsets ``(9, 3) float64`` of the spike's CVs (`authoring.spike_cvs` order)."""
    return authoring.spike_offsets(hs, level)


def feature_positions(hs, level=2) -> np.ndarray:
    """Object-space positions ``(9, 3) float64`` of the spike's CVs (derived + offset)."""
    return authoring.spike_positions(hs, level)
