"""Uniform cubic B-spline basis functions, their derivatives, and parameter bookkeeping.

Conventions (used throughout `acra`):

* A direction (u or v) at level ``k`` has knot spacing ``2**-k`` in *level-0 patch units*: the
  parameter ``u`` of a point runs over ``[0, P0]`` where ``P0`` is the number of level-0 patches
  in that direction, whatever level is evaluated.
* Segment (patch) ``s`` of a level spans ``[s, s + 1]`` in that level's own units and is shaped by
  the CVs ``s, s+1, s+2, s+3`` (modulo the CV count if the direction is periodic), thesis eq. 3.1.
* An open direction with ``n`` CVs has ``n - 3`` segments; a periodic one has ``n``. Refining a
  level doubles the segments, so level ``k`` has ``P0 * 2**k`` segments and
  ``P0 * 2**k + 3`` (open) or ``P0 * 2**k`` (periodic) CVs.
* Level-``k`` CV ``j`` is centred (its Greville abscissa) at ``(j - 1) / 2**k`` level-0 units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "Direction",
    "basis",
    "basis_all",
    "basis_rows",
    "locate",
    "refine_rows",
]

# Power-basis coefficients of B0..B3 (thesis eq. 3.2): B_i(t) = sum_p C[i, p] t**p.
_COEF = np.array(
    [
        [1.0, -3.0, 3.0, -1.0],
        [4.0, 0.0, -6.0, 3.0],
        [1.0, 3.0, 3.0, -3.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
) / 6.0


def basis(t: np.ndarray, order: int = 0) -> np.ndarray:
    """Uniform cubic B-spline blending functions (or a derivative) at local parameters.

    Parameters
    ----------
    t : (m,) float64
        Local segment parameters in ``[0, 1]``.
    order : int
        Derivative order 0..3 with respect to ``t``.

    Returns
    -------
    (m, 4) float64
        ``B_i^(order)(t)`` for ``i = 0..3``, the weights of CVs ``s..s+3``. For ``order == 0``
        the rows are non-negative and sum to 1 (partition of unity, thesis Fig. 3.3).
    """
    t = np.asarray(t, dtype=np.float64)
    if not 0 <= order <= 3:
        raise ValueError(f"derivative order must be 0..3, got {order}")
    if order == 0:
        out = np.empty(t.shape + (4,))
        _blending(out, t)
        return out
    powers = np.empty(t.shape + (4,))
    _derivative_powers(powers, t, order)
    return powers @ _COEF.T


def _blending(out: np.ndarray, t: np.ndarray) -> None:
    """Write ``B_0..B_3`` at ``t (...)`` into ``out (..., 4)``: the factored forms, with no
    cancellation, so values stay non-negative to the last bit."""
    s = 1.0 - t
    out[..., 0], out[..., 1] = s * s * s, (3.0 * t - 6.0) * t * t + 4.0
    out[..., 2], out[..., 3] = (3.0 * s - 6.0) * s * s + 4.0, t * t * t
    out /= 6.0


def _derivative_powers(out: np.ndarray, t: np.ndarray, order: int) -> None:
    """Write into ``out (..., 4)`` the ``order``-th derivative (1..3) of the powers ``1, t, t², t³``
    at ``t (...)``: the row that `_COEF` maps to that derivative of the blending functions."""
    if order == 1:
        out[..., 0], out[..., 1], out[..., 2], out[..., 3] = 0.0, 1.0, 2.0 * t, 3.0 * t * t
    elif order == 2:
        out[..., 0], out[..., 1], out[..., 2], out[..., 3] = 0.0, 0.0, 2.0, 6.0 * t
    else:
        out[..., :3], out[..., 3] = 0.0, 6.0


def basis_all(t: np.ndarray, max_order: int) -> np.ndarray:
    """Blending functions and derivatives up to ``max_order``: ``(max_order + 1, m, 4)``."""
    return np.stack([basis(t, d) for d in range(max_order + 1)])


def basis_rows(t: np.ndarray, max_order: int) -> np.ndarray:
    """`basis_all` point by point, ``(m, max_order + 1, 4)`` float64 for ``t (m,)``, equal to it bit
    for bit: the derivative rows of every order go through one product with `_COEF` (each row's
    product is its own dot of length 4, so batching them changes no bit), which is what an
    evaluation of a few dozen points pays for, rather than the arithmetic. A single ``t`` takes
    `basis_all`'s own route: numpy multiplies one row as a vector (BLAS ``gemv``), which rounds
    differently from a product of several rows (``gemm``, fused multiply-adds)."""
    t = np.asarray(t, dtype=np.float64)
    if t.size == 1:
        return basis_all(t.reshape(1), max_order).transpose(1, 0, 2).copy()
    out = np.empty((t.size, max_order + 1, 4))
    _blending(out[:, 0], t)
    if max_order:
        powers = np.empty((t.size, max_order, 4))
        for d in range(1, max_order + 1):
            _derivative_powers(powers[:, d - 1], t, d)
        out[:, 1:] = (powers.reshape(-1, 4) @ _COEF.T).reshape(t.size, max_order, 4)
    return out


@dataclass(frozen=True)
class Direction:
    """One parametric direction of a level-0 control grid.

    Attributes
    ----------
    n : int
        Level-0 CV count (open: at least 4, periodic: at least 3).
    periodic : bool
        Whether the direction wraps.
    patches0 : int
        Level-0 segment count ``P0`` (``n``, or ``n - 3`` open); the parameter domain is
        ``[0, P0]``. Not a field (equality and hashing are of ``n`` and ``periodic``): set once,
        as every query on the grid reads it, tens of times a response step.
    """

    n: int
    periodic: bool

    def __post_init__(self) -> None:
        need = 3 if self.periodic else 4
        if self.n < need:
            kind = "periodic" if self.periodic else "open"
            raise ValueError(f"an {kind} direction needs at least {need} CVs, got {self.n}")
        object.__setattr__(self, "patches0", self.n if self.periodic else self.n - 3)
        object.__setattr__(self, "_ends", 0 if self.periodic else 3)  # CVs beyond the segments

    def patches(self, level: int) -> int:
        """Segment count at ``level``."""
        return self.patches0 << level

    def cvs(self, level: int) -> int:
        """CV count at ``level``."""
        return (self.patches0 << level) + self._ends

    def wrap_cv(self, j: np.ndarray, level: int) -> np.ndarray:
        """Map CV indices into range (periodic) or leave them (open); ``j`` int64 any shape."""
        j = np.asarray(j, dtype=np.int64)
        return np.mod(j, self.cvs(level)) if self.periodic else j

    def wrap_patch(self, p: np.ndarray, level: int) -> np.ndarray:
        p = np.asarray(p, dtype=np.int64)
        return np.mod(p, self.patches(level)) if self.periodic else p

    def patch_valid(self, p: np.ndarray, level: int) -> np.ndarray:
        """Whether (unwrapped) segment indices exist at ``level``: bool, same shape as ``p``."""
        p = np.asarray(p, dtype=np.int64)
        if self.periodic:
            return np.ones(p.shape, dtype=bool)
        return (p >= 0) & (p < self.patches(level))

    def greville(self, j: np.ndarray, level: int) -> np.ndarray:
        """Centre of level-``level`` CV ``j`` in level-0 units (see module docstring)."""
        return (np.asarray(j, dtype=np.float64) - 1.0) / float(1 << level)


def locate(direction: Direction, x: np.ndarray, level: int) -> tuple[np.ndarray, np.ndarray]:
    """Segment index and local parameter of level-0 parameters ``x`` at ``level``.

    Parameters
    ----------
    x : (m,) float64
        Parameters in level-0 units. Periodic directions wrap; open ones are clamped to
        ``[0, P0]`` (the end of the domain belongs to the last segment).

    Returns
    -------
    seg : (m,) int64
        Segment index at ``level`` (in range).
    t : (m,) float64
        Local parameter in ``[0, 1]``.
    """
    x = np.asarray(x, dtype=np.float64)
    scale = float(1 << level)
    count = direction.patches(level)
    if direction.periodic:
        xs = np.mod(x * scale, count)
        seg = np.floor(xs).astype(np.int64)
        seg = np.minimum(seg, count - 1)  # mod can round up to count
        return seg, xs - seg
    xs = np.clip(x * scale, 0.0, float(count))
    seg = np.minimum(np.floor(xs).astype(np.int64), count - 1)
    return seg, xs - seg


def refine_rows(direction: Direction, level: int, j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Binary-subdivision (Lane–Riesenfeld) masks giving level ``level+1`` CVs from level ``level``.

    Level-(k+1) CV ``j`` is, with the centring of the module docstring:

    * odd ``j``: vertex point ``(V[i-1] + 6 V[i] + V[i+1]) / 8`` with ``i = (j + 1) / 2``;
    * even ``j``: edge point ``(V[i] + V[i+1]) / 2`` with ``i = j / 2``.

    Parameters
    ----------
    j : (m,) int64
        Level-(k+1) CV indices (in range).

    Returns
    -------
    idx : (m, 3) int64
        Level-k CV indices (wrapped for periodic directions; ``-1`` never occurs for CVs that
        belong to a segment of the domain).
    w : (m, 3) float64
        Mask weights, each row summing to 1 (unused slots have weight 0 and a valid index).
    """
    j = np.asarray(j, dtype=np.int64)
    odd = (j & 1) == 1
    base = np.where(odd, (j - 1) // 2, j // 2)
    idx = base[:, None] + np.arange(3)[None, :]
    w = np.where(odd[:, None], np.array([1.0, 6.0, 1.0]) / 8.0, np.array([0.5, 0.5, 0.0]))
    if direction.periodic:
        idx = np.mod(idx, direction.cvs(level))
    else:
        # The unused third slot of an edge point may run past the end: point it at a valid CV.
        idx = np.minimum(idx, direction.cvs(level) - 1)
    return idx, w
