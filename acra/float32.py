"""float64 results as the float32 values a layer stores, checked and rounded in one compiled pass.

A display's points and normals are computed in float64 and stored as ``float3[]``: each value
rounds to the nearest float32 (ties to even, beyond the largest float32 to infinity), as numpy's
``astype(np.float32)`` rounds, and a value that is NaN or infinite is refused before anything is
written. `round_into` does both in one pass over the values, into any float32 buffer (a new
`Vt` array's own, `pipeline.usdio.vt_buffer`), where checking with ``np.isfinite(...).all()``
and then converting reads them twice and makes a boolean array between; `rounded` into a new
numpy array.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["round_into", "rounded"]


@njit(cache=True, nogil=True)
def _rounded(values, out):
    """Round ``values (k,) float64`` (read-only) into ``out (k,) float32``; whether every value
    is finite. The test accumulates without a branch: the loop stays one straight pass."""
    finite = True
    for i in range(values.shape[0]):
        x = values[i]
        finite &= np.isfinite(x)
        out[i] = np.float32(x)
    return finite


def round_into(values: np.ndarray, out: np.ndarray) -> bool:
    """Round ``values`` (any shape) into ``out`` (float32, C-ordered, of that shape), each value
    its nearest float32 (numpy's ``astype``); whether every value is finite (where one is not,
    ``out`` holds whatever was written before the end).

    A float64 array is rounded by the compiled pass (one specialisation: the kernel always
    sees a read-only C-ordered view); any other dtype by numpy."""
    values = np.asarray(values)
    if values.dtype != np.float64:
        if not np.all(np.isfinite(values)):
            return False
        out[...] = values
        return True
    flat = np.ascontiguousarray(values).reshape(-1)
    if flat.flags.writeable:  # read-only or not, one specialisation
        flat = flat.view()
        flat.flags.writeable = False
    return bool(_rounded(flat, out.reshape(-1)))


def rounded(values: np.ndarray) -> np.ndarray | None:
    """``values`` (any shape) as a new C-ordered float32 array of that shape (`round_into`);
    ``None`` where a value is NaN or infinite."""
    values = np.asarray(values)
    out = np.empty(values.shape, np.float32)
    return out if round_into(values, out) else None
