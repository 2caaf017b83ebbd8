"""The pipeline's data model: static models read once per run, per-frame states evaluated per time.

Newton-style split: a *model* holds what never changes during a run (topology, controls, the
animator's hierarchy, a collider's mesh); a *state* holds what a time code evaluates to (the
animator's level-0 CVs, world transforms, ``acra:enabled``). The frame loop never mutates either:
responses are new objects.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

import acra  # noqa: F401  (before numba: numba's configuration then loads without PyYAML, acra/__init__.py)
from numba import njit

from acra.hspline import HierarchyArrays, HSpline
from acra.controls import Controls as AcraControls
from acra.tessellate import MeshTopology

__all__ = ["Controls", "DeformableModel", "ColliderModel", "SceneModel", "DeformableState", "ColliderState", "InputError"]


class InputError(ValueError):
    """Invalid input: the message is one line naming the prim, the attribute and the problem."""

    def __init__(self, prim: str, attribute: str | None, problem: str):
        self.prim, self.attribute, self.problem = prim, attribute, problem
        where = f"{prim}.{attribute}" if attribute else prim
        super().__init__(f"{where}: {problem}")

    def __reduce__(self):
        # rebuilt from its three parts, so the error a farm worker raises reaches the client whole
        return type(self), (self.prim, self.attribute, self.problem)


@dataclass(frozen=True)
class Controls(AcraControls):
    """ACRA controls of one deformable as read from USD (contract §1): the algorithm's
    `acra.controls.Controls` (absorption, deform/translate/rotate mix, rigidity, refine policy)
    plus the display tessellation density.

    Attributes
    ----------
    samples : int
        Display samples per level-0 patch edge (``acra:samples``).
    relax_times : (n,) float64
        Time codes of ``acra:relax``'s samples (one entry, ``nan``, for a default value; none
        when unauthored).
    relax_values : (n, L) float64
        ``acra:relax`` at those times: the fraction of the carried elastic offset each level
        releases per frame (`relax_at`); unauthored, every level releases all of it (1).
    plasticity : (L,) float64 or None
        ``acra:plasticity`` per level (a scalar is spread over every level); ``None`` when
        unauthored (0: nothing kept).
    preserve_volume : float
        ``acra:preserveVolume`` strength in [0, 1] (0: off).
    bulge_level : int
        ``acra:bulgeLevel``: the level whose CVs make the volume-preserving bulge.
    bulge_falloff : float
        ``acra:bulgeFalloff``: distance (fraction of the object's size) over which the bulge's
        weight falls off from the dent.
    """

    samples: int = 4
    relax_times: np.ndarray | None = None
    relax_values: np.ndarray | None = None
    plasticity: np.ndarray | None = None
    preserve_volume: float = 0.0
    bulge_level: int = 0
    bulge_falloff: float = 0.25

    def relax_at(self, t: float) -> np.ndarray:
        """``acra:relax`` at time code ``t``, ``(L,) float64``: linear between samples, held past
        the first and last (USD's interpolation of a ``float[]``)."""
        L = self.absorption.size
        if self.relax_values is None or not len(self.relax_values):
            return np.ones(L)
        if len(self.relax_values) == 1:
            return self.relax_values[0].copy()
        return np.array([np.interp(float(t), self.relax_times, self.relax_values[:, l]) for l in range(L)])

    @property
    def stateful(self) -> bool:
        """Whether anything is carried across frames (a release rate below 1 or plasticity)."""
        slow = self.relax_values is not None and bool(np.any(self.relax_values < 1.0))
        return slow or (self.plasticity is not None and bool(np.any(self.plasticity > 0.0)))


@dataclass(frozen=True)
class DeformableModel:
    """A deformable H-spline object: everything that is fixed for the run.

    Attributes
    ----------
    path : str
        Prim path.
    u_periodic, v_periodic : bool
    nu, nv : int
        Level-0 grid size.
    depth : int
        ``acra:levels``.
    controls : Controls
    hierarchy : HierarchyArrays
        The animator's refined patches and offsets (input, not time-varying).
    topology : MeshTopology
        Rest display tessellation: the adaptive tessellation of the animator's hierarchy
        (`acra.tessellate.run_topology`); a run's output has its own (`display.run_topologies`).
    """

    path: str
    u_periodic: bool
    v_periodic: bool
    nu: int
    nv: int
    depth: int
    controls: Controls
    hierarchy: HierarchyArrays
    topology: MeshTopology


@dataclass(frozen=True)
class ColliderModel:
    """A rigid collider mesh (``PhysicsCollisionAPI``), in its object space.

    Attributes
    ----------
    path : str
    vertices : (n, 3) float64
    triangles : (f, 3) int64
        Faces triangulated (fan) from the Mesh's polygons.
    """

    path: str
    vertices: np.ndarray
    triangles: np.ndarray


@dataclass(frozen=True)
class SceneModel:
    """All objects of a stage and its frame range.

    Attributes
    ----------
    deformables, colliders : tuple
    start, end : int
        Integer frames to process (inclusive).
    meters_per_unit, up_axis : stage metadata (for reports)
    """

    deformables: tuple[DeformableModel, ...]
    colliders: tuple[ColliderModel, ...]
    start: int
    end: int
    meters_per_unit: float = 1.0
    up_axis: str = "Y"
    extra: dict = field(default_factory=dict)


@dataclass(frozen=True)
class DeformableState:
    """A deformable at one time code: the animator's shape, before any response.

    Attributes
    ----------
    surface : HSpline
        Object-space H-spline (level-0 CVs at this time + the animator's hierarchy).
    xform : (4, 4) float64
        Object-to-world matrix, column-vector convention: ``world = xform @ [p, 1]``.
    enabled : bool
        ``acra:enabled`` at this time.
    """

    surface: HSpline
    xform: np.ndarray
    enabled: bool = True


@dataclass(frozen=True)
class ColliderState:
    """A collider at one time code.

    Attributes
    ----------
    xform : (4, 4) float64
        Object-to-world matrix, column-vector convention.
    """

    xform: np.ndarray


def apply_xform(xform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``(n, 3)`` points mapped by a ``(4, 4)`` column-convention matrix: ``points @ R.T + t``,
    in one compiled pass (`translated`) where ``R`` is the identity and the points are many."""
    if (type(points) is np.ndarray and points.ndim == 2 and len(points) >= TRANSLATED_ROWS and points.shape[1] == 3
            and points.dtype == np.float64 and points.flags.c_contiguous and type(xform) is np.ndarray
            and xform.dtype == np.float64 and xform.shape == (4, 4)):
        out = np.empty(points.shape)
        if translated(points, xform, False, out, out, np.empty((2, 3))):
            return out
    return points @ xform[:3, :3].T + xform[:3, 3]


TRANSLATED_ROWS = 64  # fewer points are mapped by numpy as fast as the compiled pass is called


def is_translation(xform: np.ndarray) -> bool:
    """Whether ``xform (4, 4)``'s linear part is exactly the identity (a zero of either sign) and
    no coordinate of its translation is -0.0: `translated`'s test of the matrix, without points
    (16 Python floats: cheaper to test than arrays)."""
    rows = np.asarray(xform, np.float64).tolist()
    return all(rows[i][j] == (1.0 if i == j else 0.0) for i in range(3) for j in range(3)) and not any(
        rows[i][3] == 0.0 and math.copysign(1.0, rows[i][3]) < 0.0 for i in range(3))


def translated(points: np.ndarray, xform: np.ndarray, round32: bool, local: np.ndarray, world: np.ndarray,
               box: np.ndarray) -> bool:
    """``world (n, 3) float64``: ``points (n, 3) float64`` (rounded to float32 first where
    ``round32``, those values in ``local``) plus the translation ``t`` of ``xform (4, 4)``, and
    ``box (2, 3)`` their `acra.bvh.bounds`, where ``xform``'s linear part is exactly the
    identity, no ``t`` is -0.0 and every world point is finite; returns whether it is so (else
    the outputs are unset; ``local`` may be ``world`` where ``round32`` is false).

    Then `apply_xform`'s ``points @ I.T + t`` has these bits in any summation order, with or
    without fused multiply-adds: each product is exact and all but one are zeros, which add
    nothing to a finite value; only a zero sum's sign depends on the order, and adding ``t``,
    not -0.0, makes it +0.0 either way. A non-finite point, whose row numpy fills with NaN
    through the zeros' products, answers false."""
    # read-only views: one specialisation of the kernel whether the caller's arrays are writable or not
    points, xform = points.view(), xform.view()
    points.flags.writeable = xform.flags.writeable = False
    return _translated(points, xform, round32, local, world, box)


@njit(cache=True, nogil=True)
def _translated(points, xform, round32, local, world, box):
    for i in range(3):
        for j in range(3):
            if xform[i, j] != (1.0 if i == j else 0.0):
                return False
        if xform[i, 3] == 0.0 and np.signbit(xform[i, 3]):
            return False
    n = points.shape[0]
    if n == 0:
        return True
    t0, t1, t2 = xform[0, 3], xform[1, 3], xform[2, 3]
    # `bvh.bounds`' comparisons, in its order, so equal values of either sign pick alike: the
    # first row starts the box and every row, the first again, takes ``w < lo`` and ``w > hi``,
    # which leave the first row's values as they are; held in locals, so the loop keeps no
    # per-element branch on the row and no store to ``box``
    if round32:
        lo0, lo1, lo2 = np.float64(np.float32(points[0, 0])), np.float64(np.float32(points[0, 1])), np.float64(np.float32(points[0, 2]))
    else:
        lo0, lo1, lo2 = points[0, 0], points[0, 1], points[0, 2]
    lo0, lo1, lo2 = lo0 + t0, lo1 + t1, lo2 + t2
    hi0, hi1, hi2 = lo0, lo1, lo2
    finite = True
    for i in range(n):
        if round32:
            x0, x1, x2 = np.float64(np.float32(points[i, 0])), np.float64(np.float32(points[i, 1])), np.float64(np.float32(points[i, 2]))
        else:
            x0, x1, x2 = points[i, 0], points[i, 1], points[i, 2]
        w0, w1, w2 = x0 + t0, x1 + t1, x2 + t2
        local[i, 0], local[i, 1], local[i, 2] = x0, x1, x2
        world[i, 0], world[i, 1], world[i, 2] = w0, w1, w2
        finite &= np.isfinite(w0) & np.isfinite(w1) & np.isfinite(w2)
        if w0 < lo0:
            lo0 = w0
        if w0 > hi0:
            hi0 = w0
        if w1 < lo1:
            lo1 = w1
        if w1 > hi1:
            hi1 = w1
        if w2 < lo2:
            lo2 = w2
        if w2 > hi2:
            hi2 = w2
    box[0, 0], box[0, 1], box[0, 2] = lo0, lo1, lo2
    box[1, 0], box[1, 1], box[1, 2] = hi0, hi1, hi2
    return finite


def apply_inverse(xform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``(n, 3)`` world points mapped back into the object space of ``xform``."""
    return (points - xform[:3, 3]) @ np.linalg.inv(xform[:3, :3]).T
