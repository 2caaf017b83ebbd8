"""The independent measure of what the user sees: an output layer read back with USD and measured
with trimesh and fcl alone.

Nothing here imports `pipeline` or `acra`: the measure must not share a bug with what it measures.
It lives outside ``tests/`` so that the tests (``tests/test_visible.py``, the scene and hard-case
tests) and ``benchmarks/visible.py`` import the same code.
Per frame, each deformable's composed display mesh (its ``points`` and face arrays as a USD client
reads them, in world space through ``UsdGeom.Xformable.ComputeLocalToWorldTransform``) is welded,
its zero-area faces dropped, and, for a closed object (every direction periodic or collapsed at
both ends), checked watertight; a closed object that is not is an error, never "nothing inside".
The depth of its display vertices and of points on a barycentric grid inside each triangle
(`STEPS` steps per edge) inside every other closed object (other deformables' display meshes,
colliders' meshes) is taken as the exact distance to that object's surface (fcl), as a fraction of
the diagonal of the bounding box of the object's own display mesh at that frame.

``python3 benchmarks/visible.py`` prints the measure as a table beside the residual each run reports.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import fcl
import numpy as np
import trimesh
from pxr import Usd, UsdGeom, UsdPhysics

STEPS = 4  # barycentric steps per triangle edge (the issue asks at least 4)
TOL = 1e-3  # contract §3: residual penetration as a fraction of the object's own size


# --- reading what a USD client reads ------------------------------------------------------------
def _world_matrix(prim: Usd.Prim, frame: float) -> np.ndarray:
    """Object-to-world ``(4, 4) float64`` in column-vector convention (USD stores row vectors)."""
    return np.asarray(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode(frame)), np.float64).T


def _triangulate(counts: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Faces ``counts (f,) int`` over ``indices (sum counts,) int`` as a fan from each face's
    first vertex, as USD's own triangulation does: ``(t, 3) int64``."""
    tris = []
    for n in np.unique(counts):
        starts = np.cumsum(np.r_[0, counts[:-1]])[counts == n]
        for k in range(1, n - 1):
            tris.append((starts, starts + k, starts + k + 1))
    if not tris:
        return np.zeros((0, 3), np.int64)
    rows = np.concatenate([np.stack(t, axis=1) for t in tris])
    return indices[rows].astype(np.int64)


def _weld(points: np.ndarray, triangles: np.ndarray, scale: float) -> trimesh.Trimesh:
    """A trimesh of ``points (n, 3)`` / ``triangles (t, 3)``, vertices closer than ``1e-7 scale``
    welded (float32 output points of one surface point evaluated at two parameters, a seam or a
    pole, differ in the last bits), zero-area faces dropped."""
    q = np.round(points / max(scale * 1e-7, 1e-300)).astype(np.int64)
    _, first, inverse = np.unique(q, axis=0, return_index=True, return_inverse=True)
    tri = inverse.reshape(-1)[triangles]
    mesh = trimesh.Trimesh(points[first], tri, process=False)
    mesh.update_faces(mesh.nondegenerate_faces(height=1e-9 * scale))
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    return mesh


def _closed_by_cvs(prim: Usd.Prim, frame: float, cvs_attr: str) -> bool:
    """Whether the H-spline is closed: each direction periodic or with both end curves collapsed
    to a point (a pole), at least one periodic. A uniform cubic B-spline's end curve at an open
    end is the spline of ``(P0 + 4 P1 + P2) / 6`` over the first three rows."""
    nu = int(prim.GetAttribute("acra:uCount").Get())
    nv = int(prim.GetAttribute("acra:vCount").Get())
    wrap = [str(prim.GetAttribute(n).Get() or "open") == "periodic" for n in ("acra:uWrap", "acra:vWrap")]
    if not any(wrap):
        return False
    attr = prim.GetAttribute(cvs_attr)
    if not attr or not attr.HasValue():
        attr = prim.GetAttribute("acra:cvs")
    cvs = np.asarray(attr.Get(Usd.TimeCode(frame)), np.float64).reshape(nv, nu, 3).transpose(1, 0, 2)
    size = np.linalg.norm(np.ptp(cvs.reshape(-1, 3), axis=0))
    for axis, periodic in enumerate(wrap):
        if periodic:
            continue
        rows = np.moveaxis(cvs, axis, 0)
        for end in (rows[:3], rows[::-1][:3]):
            curve = (end[0] + 4 * end[1] + end[2]) / 6
            if np.ptp(curve, axis=0).max() > 1e-9 * size:
                return False
    return True


@dataclass
class Body:
    """One object at one frame: world mesh (welded), whether it is closed, and its size."""

    path: str
    mesh: trimesh.Trimesh
    closed: bool
    deformable: bool
    size: float = field(init=False)

    def __post_init__(self) -> None:
        self.size = float(np.linalg.norm(np.ptp(self.mesh.vertices, axis=0)))


def _objects(stage: Usd.Stage):
    """``(prim, deformable)`` of every Mesh the contract names: a deformable carries ``acra:cvs``,
    a collider has ``PhysicsCollisionAPI``."""
    for prim in stage.Traverse():
        deformable = prim.HasAttribute("acra:cvs")
        if prim.IsA(UsdGeom.Mesh) and (deformable or prim.HasAPI(UsdPhysics.CollisionAPI)):
            yield prim, deformable


def bodies_at(stage: Usd.Stage, frame: float) -> list[Body]:
    """Every deformable (a Mesh with ``acra:cvs``) and collider (``PhysicsCollisionAPI``) at
    ``frame``, as composed by USD; raises if a closed one is not watertight."""
    out = []
    for prim, deformable in _objects(stage):
        mesh = UsdGeom.Mesh(prim)
        pts = np.asarray(mesh.GetPointsAttr().Get(Usd.TimeCode(frame)), np.float64)
        counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(Usd.TimeCode(frame)), np.int64)
        idx = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(Usd.TimeCode(frame)), np.int64)
        m = _world_matrix(prim, frame)
        world = pts @ m[:3, :3].T + m[:3, 3]
        scale = float(np.linalg.norm(np.ptp(world, axis=0)))
        tm = _weld(world, _triangulate(counts, idx), scale)
        closed = _closed_by_cvs(prim, frame, "acra:response:cvs") if deformable else True
        if closed and not tm.is_watertight:
            raise AssertionError(f"{prim.GetPath()} at frame {frame}: a closed object's display mesh is not watertight "
                                 f"({len(trimesh.grouping.group_rows(tm.edges_sorted, require_count=1))} boundary edges)")
        out.append(Body(str(prim.GetPath()), tm, closed, deformable))
    return out


def triangle_samples(mesh: trimesh.Trimesh, steps: int = STEPS) -> np.ndarray:
    """Points on a barycentric grid of ``steps`` steps per edge in every triangle (vertices
    included): ``(t * (steps+1)(steps+2)/2, 3) float64``."""
    w = np.array([(i, j, steps - i - j) for i in range(steps + 1) for j in range(steps + 1 - i)], np.float64) / steps
    tri = mesh.vertices[mesh.faces]  # (t, 3, 3)
    return np.einsum("wk,tkc->twc", w, tri).reshape(-1, 3)


def depth_inside(points: np.ndarray, other: Body) -> np.ndarray:
    """Depth ``(k,) float64`` of ``points (k, 3)`` inside the closed ``other`` (distance to its
    surface; 0 outside). Ray-parity ``contains`` (embree) for inside, `surface_distance` for depth."""
    depth = np.zeros(len(points))
    if not other.closed or not len(points):
        return depth
    lo, hi = other.mesh.bounds
    near = np.nonzero(np.all((points >= lo) & (points <= hi), axis=1))[0]
    if not near.size:
        return depth
    inside = near[other.mesh.contains(points[near])]
    if inside.size:
        depth[inside] = surface_distance(other.mesh, points[inside])
    return depth


def surface_distance(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Exact distances ``(k,)`` from ``points (k, 3)`` to ``mesh``'s triangles: fcl's distance
    from a point (a sphere of radius 0) to the mesh's BVH. (trimesh's ``proximity.closest_point``
    picks its candidate triangles heuristically and was measured to miss the nearest one by 1e-4
    of the distance, which would make this measure over-state a depth.)"""
    bvh = fcl.BVHModel()
    bvh.beginModel(len(mesh.vertices), len(mesh.faces))
    bvh.addSubModel(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int32))
    bvh.endModel()
    body = fcl.CollisionObject(bvh, fcl.Transform())
    return np.array([fcl.distance(body, fcl.CollisionObject(fcl.Sphere(0.0), fcl.Transform(p)),
                                  fcl.DistanceRequest(), fcl.DistanceResult()) for p in points])


@dataclass
class Measure:
    """One deformable at one frame: largest depth of its display vertices and of all its
    triangle samples inside any other object, as fractions of its own display diagonal."""

    frame: int
    path: str
    vertices: float
    samples: float
    count: int  # vertices inside


def measure_frame(stage: Usd.Stage, frame: int, steps: int = STEPS) -> list[Measure]:
    """`Measure` of every deformable of ``stage`` at ``frame``."""
    bodies = bodies_at(stage, frame)
    out = []
    for a in bodies:
        if not a.deformable:
            continue
        v_depth, s_depth, count = 0.0, 0.0, 0
        samples = None
        for b in bodies:
            if b is a or not b.closed:
                continue
            if np.any(a.mesh.bounds[1] < b.mesh.bounds[0]) or np.any(b.mesh.bounds[1] < a.mesh.bounds[0]):
                continue
            dv = depth_inside(a.mesh.vertices, b)
            samples = triangle_samples(a.mesh, steps) if samples is None else samples
            ds = depth_inside(samples, b)
            v_depth, s_depth = max(v_depth, dv.max(initial=0.0)), max(s_depth, ds.max(initial=0.0))
            count += int(np.count_nonzero(dv > 0))
        out.append(Measure(frame, a.path, v_depth / a.size, max(s_depth, v_depth) / a.size, count))
    return out


def measure_layer(path: str | Path, frames=None, steps: int = STEPS) -> list[Measure]:
    """`measure_frame` at every frame of the output layer ``path`` (its start..end time codes)."""
    stage = Usd.Stage.Open(str(path))
    if frames is None:
        frames = range(int(stage.GetStartTimeCode()), int(stage.GetEndTimeCode()) + 1)
    return [m for f in frames for m in measure_frame(stage, f, steps)]


def worst_by_frame(measures: list[Measure]) -> dict[int, float]:
    """Per frame, the largest sampled depth of any deformable (fraction of its own size)."""
    out: dict[int, float] = {}
    for m in measures:
        out[m.frame] = max(out.get(m.frame, 0.0), m.samples)
    return out


# --- the measure against what a run reported ------------------------------------------------------
SLACK = 2e-7  # float32 output points: a coordinate of a few units is known to ~6e-8 of the size


def disagreements(reported: dict[int, float], measured: dict[int, float], tol: float = TOL) -> list[str]:
    """What is wrong with a run, frame by frame, as readable lines (empty: nothing):

    * a frame whose measured depth (``measured``: frame -> largest `Measure.samples`) is over
      ``tol`` of the object's own size;
    * a reported residual (``reported``: frame -> the run's figure, a fraction of size) under the
      measure by more than `SLACK`: the figure must never flatter what the user sees;
    * a reported residual over ``max(3 × measured, tol)``: the figure must say how deep, not
      only that something may be. Below the tolerance the bound is the tolerance itself: a
      residual is an upper bound between samples, which cannot be 0 where surfaces touch, and a
      figure within the tolerance changes no decision (the frame is clear either way); over it, a
      figure more than 3 times the measure would name frames over tolerance that are not.
    """
    out = []
    for frame in sorted(measured):
        m, r = measured[frame], reported.get(frame, float("nan"))
        if m > tol:
            out.append(f"frame {frame}: measured {m:.2e} of size, over {tol:.0e}")
        if not r >= m - SLACK:
            out.append(f"frame {frame}: reported {r:.2e} under the measured {m:.2e}")
        elif r > max(3.0 * m, tol):
            out.append(f"frame {frame}: reported {r:.2e} over 3 x the measured {m:.2e} (and over {tol:.0e})")
    return out
