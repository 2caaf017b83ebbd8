"""The geometry a collision is found between: a deformable's surface placed in the world and a
collider's mesh placed in the world, with what is derived from them once.

A deformable is a `SurfaceGeometry` (an object-space H-spline, its `pipeline.shape.Shape` and a 4×4
matrix): its world patch boxes (`SurfaceGeometry.boxes`, the object-space hull boxes mapped by the
matrix, kept by content), its size, its outer box, its points at parameters (`surface_points`,
`wrap_uv`) and the patch densities its collision tessellation takes (`patch_density`,
`candidate_patches`); a collision tessellation of chosen patches is a `Tessellation`. A rigid
collider is a run-constant `ColliderStatic` (its mesh, closest-point index, solid, face planes when
it is a small convex mesh, `prepare_collider`) under a matrix (`ColliderGeometry`), sampled on its
faces by `face_samples`. `pipeline.detect` answers the questions between two of them (apart,
intersections, inside, depth, projections, casts). World units; arrays are float64 unless stated.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Union

import numpy as np

from acra import hspline as H
from acra import memo, narrow, patch_boxes
from acra.bvh import bounds as bounds_of
from acra.hspline import HSpline
from pipeline.grids import boxes_near
from pipeline.model import ColliderModel, apply_xform
from pipeline.shape import Closest, Shape, bvh as _bvh, content_digest, overlap as _overlap, shape_of

if TYPE_CHECKING:
    import fcl
    import trimesh

__all__ = [
    "ColliderStatic", "prepare_collider", "SurfaceGeometry", "ColliderGeometry", "Geometry", "Tessellation",
    "patch_density", "candidate_patches", "is_closed", "surface_points", "world_normals", "wrap_uv", "face_samples",
    "PLANES_MAX",
]


PLANES_MAX = 64  # a convex collider with at most this many faces answers far points' sides by its face planes


class _once:
    """A property computed at its first read and kept in the instance's ``__dict__`` (a later
    read finds it there without calling this descriptor): `functools.cached_property` without
    its lock, which Python 3.11 takes at every first read (about 1.3 us against 0.3). Each
    rewinding step makes new geometries whose first reads (content, world data, boxes, bounds,
    size, outer box: about 15 a step) are most of that step's Python between the kernels."""

    def __init__(self, func) -> None:
        self.func, self.name, self.__doc__ = func, func.__name__, func.__doc__

    def __set_name__(self, owner, name: str) -> None:
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        value = obj.__dict__[self.name] = self.func(obj)
        return value


# --- static collider data (once per run) and per-time geometry --------------------------------
@dataclass(frozen=True, eq=False)
class ColliderStatic:
    """A collider's run-constant data in its object space: merged non-degenerate ``mesh`` (its
    embree ``ray`` intersector built once), its fcl ``bvh`` (identity transform), ``closed``
    (watertight, so it has an inside)."""

    path: str
    mesh: trimesh.Trimesh
    bvh: fcl.CollisionObject
    closed: bool

    @_once
    def index(self) -> Closest:
        return Closest(self.mesh.vertices, self.mesh.faces, self.bvh)

    @_once
    def digest(self) -> bytes:
        """The mesh's content (path, vertices and faces, `shape.content_digest`): what every
        answer on it depends on besides the matrix."""
        return content_digest(self.path, self.mesh.vertices, self.mesh.faces)

    @_once
    def solid(self):
        """The closed mesh as a `pipeline.clearance.Solid` (pseudo-normals, exact closest
        points), for the side of a point off the mesh (`_collider_inside`)."""
        from pipeline import clearance

        return clearance.solid(np.asarray(self.mesh.vertices, np.float64), np.asarray(self.mesh.faces, np.int64))

    @_once
    def planes(self) -> np.ndarray | None:
        """The `solid`'s face planes ``(f, 4) float64``, rows ``(n, d)`` with ``n`` its unit
        outward normal (``n . p + d`` is a point's height over a face's plane), where the solid is
        convex and its pseudo-normals side with its faces; else None (`_convex_planes`)."""
        return _convex_planes(self.solid)

    @_once
    def scale(self) -> float:
        """The mesh's size (trimesh's ``scale``, its box's diagonal), read once: each read of a
        `trimesh.Trimesh` cached property hashes the mesh's arrays to check them."""
        return float(self.mesh.scale)

    @_once
    def face_boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """Object-space boxes ``lo, hi (f, 3)`` of the mesh's faces, built once per run (the mesh
        is rigid)."""
        tri = self.mesh.vertices[self.mesh.faces]
        return tri.min(axis=1), tri.max(axis=1)

    @_once
    def local_box(self) -> tuple[tuple, tuple]:
        """Object-space box of the mesh's vertices: centre and half-extents (`_centre_half`)."""
        v = np.asarray(self.mesh.vertices, np.float64)
        return _centre_half(v.min(axis=0), v.max(axis=0))

    @_once
    def thin(self) -> bool:
        """Whether a face is degenerate or thin (`acra.narrow.thin_faces`): fcl's BVH of every
        face may then pair it with triangles `acra.narrow.crossings` never meets, so only fcl
        counts the contacts."""
        return bool(narrow.thin_faces(self.mesh.vertices, self.mesh.faces).any())

    @_once
    def _face_centres(self) -> tuple[np.ndarray, np.ndarray]:
        """Centres and half-extents ``(f, 3)`` of `face_boxes`."""
        lo, hi = self.face_boxes
        return 0.5 * (lo + hi), 0.5 * (hi - lo)

    def faces_near(self, xform: np.ndarray, bounds: np.ndarray) -> np.ndarray:
        """Rows ``(m,) int64`` of ``mesh.faces``, ascending, that hold every face whose world box
        meets the world box ``bounds (2, 3)`` under ``xform (4, 4)`` (`grids.boxes_near`)."""
        return boxes_near(*self._face_centres, xform, bounds)


def _convex_planes(s) -> np.ndarray | None:
    """Face planes of a `pipeline.clearance.Solid` ``s`` for `_collider_inside`'s far points, or
    None unless all of these hold: at most `PLANES_MAX` faces, each with a finite normal; every vertex on or behind every
    face's plane (to 1e-12 of the size); the enclosed volume that of the vertices' convex hull
    (to 1e-9: the surface covers the hull's boundary once, so the inside is the planes'
    intersection ``K`` and its parity is 1 there); every edge and vertex pseudo-normal at least
    0.1 along each face it touches.

    Then a point's greatest height ``h = max_f (n_f . p + d_f)`` over the planes is ``-sd`` of
    eq. (1) (`pipeline.clearance`) within the planes' rounding: inside ``K`` the nearest surface
    point is the foot on the nearest plane, and outside, the distance to ``K`` is at least
    ``h``. Whatever feature eq. (1) reads the pseudo-normal ``n`` of (a face, or an edge or a
    corner within its feature tolerance), ``p - q`` lies in the normal cone of the closest point
    ``q``, spanned by normals of faces ``n`` is at least 0.1 along, so ``(p - q) . n`` has the
    side of ``h`` whenever ``|h|`` is far above the rounding."""
    from scipy.spatial import ConvexHull, QhullError

    v, f, normals = s.vertices, s.faces, s.normals
    if not s.convex or len(f) > PLANES_MAX or not np.isfinite(normals).all():
        return None
    size = float(np.linalg.norm(np.ptp(v, axis=0)))
    offsets = np.einsum("ij,ij->i", normals, v[f[:, 0]])
    if (v @ normals.T - offsets).max() > 1e-12 * size:
        return None
    base = v[f[:, 0]]
    volume = np.einsum("ij,ij->", base - v.mean(axis=0), np.cross(v[f[:, 1]] - base, v[f[:, 2]] - base)) / 6.0
    try:
        hull = ConvexHull(v).volume
    except QhullError:
        return None
    if abs(volume - hull) > 1e-9 * hull:
        return None
    if np.einsum("fkc,fc->fk", s.edge_normals, normals).min() < 0.1:
        return None
    if np.einsum("fkc,fc->fk", s.vertex_normals[f], normals).min() < 0.1:
        return None
    return np.concatenate([normals, -offsets[:, None]], axis=1)


def prepare_collider(model: ColliderModel) -> ColliderStatic:
    """Build a collider's BVH, ray intersector and closest-point index once per run."""
    import trimesh  # only rigid colliders need it: a run without one never imports trimesh

    mesh = trimesh.Trimesh(np.asarray(model.vertices, np.float64), np.asarray(model.triangles, np.int64), process=True)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    static = ColliderStatic(model.path, mesh, _bvh(mesh.vertices, mesh.faces), bool(mesh.is_watertight))
    static.mesh.ray.intersects_first(np.zeros((1, 3)), np.ones((1, 3)))  # build the embree scene now
    return static


@dataclass(frozen=True, eq=False)
class ColliderGeometry:
    """A collider at one time: its static data and object-to-world matrix ``xform (4, 4)``."""

    static: ColliderStatic
    xform: np.ndarray

    @property
    def name(self) -> str:
        return self.static.path

    @_once
    def vertices(self) -> np.ndarray:
        """World vertices ``(n, 3)``."""
        return apply_xform(self.xform, self.static.mesh.vertices)

    @_once
    def bounds(self) -> np.ndarray:
        """World box ``(2, 3)``: min and max corner."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    @_once
    def size(self) -> float:
        return float(np.linalg.norm(np.ptp(self.vertices, axis=0)))

    @property
    def outer(self) -> np.ndarray:
        """World box ``(2, 3)`` holding `bounds`: the mesh's object-space box mapped through the
        matrix (`_mapped_box`), without mapping its vertices."""
        return np.array(self._outer[:2])

    @_once
    def _outer(self) -> tuple[tuple, tuple, float]:
        return _mapped_box(self.xform, self.static.local_box)

    @_once
    def content(self) -> tuple:
        """What detection's answers on this collider depend on: its mesh's digest and the
        matrix's bytes."""
        return ("collider", self.static.digest, np.ascontiguousarray(self.xform, np.float64).tobytes())

    def to_object(self, points: np.ndarray) -> np.ndarray:
        """World points ``(k, 3)`` in object space: `pipeline.model.apply_inverse`'s arithmetic,
        the same bits, with the linear part's inverse found once per geometry (the rim's
        bisection asks for it in each of its inside tests on this geometry)."""
        return (points - self.xform[:3, 3]) @ self._inverse_t

    @_once
    def _inverse_t(self) -> np.ndarray:
        """``(3, 3) float64``: the transposed inverse of ``xform``'s linear part."""
        return np.linalg.inv(self.xform[:3, :3]).T


@dataclass(frozen=True, eq=False)
class Tessellation:
    """Independent triangle grids over level-0 patches: world ``points (n, 3)``, their parameters
    ``uv (n, 2)`` (level-0 units), ``triangles (f, 3) int64``, level-0 patch of each triangle
    ``tri_patch (f, 2) int64``."""

    points: np.ndarray
    uv: np.ndarray
    triangles: np.ndarray
    tri_patch: np.ndarray

    @_once
    def face_boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """Boxes ``lo, hi (f, 3)`` of the triangles (`_face_boxes`), built once per
        tessellation: the narrow phase of every pair it meets uses them."""
        return _face_boxes(self.points, self.triangles)

    @_once
    def bounds(self) -> np.ndarray:
        """Box ``(2, 3)`` of the points (`acra.bvh.bounds`), found once per tessellation: a still
        object's candidate set meets every step of the rewinding search's bisection. Read-only."""
        box = bounds_of(self.points)
        box.setflags(write=False)
        return box


@dataclass(eq=False)
class _World:
    """World data of one `SurfaceGeometry.content`, shared by every geometry with that content
    (a frame's detection and its rewinding at the same time, a still object across frames):
    each level-0 patch's grid in world space ``patch: (points (n, 3), uv (n, 2), triangles
    (f, 3) int64)``, the last few patch sets' `Tessellation` by the set's bytes, and the world
    patch boxes ``lo, hi (P0u, P0v, 3)``, their union ``bounds (2, 3)`` and its diagonal ``size``, the object-level box
    (`SurfaceGeometry.outer`'s ``(lo, hi, diagonal)``) once found; ``mapped``: the first patch set
    asked for, ``(patches (m, 2), world points (n, 3), grids)``, until another set asks and
    ``grids`` takes its rows (`_split_mapped`); ``inner``: the patch boxes' highest low and
    lowest high corner (3 floats each, `_every_box_meets`). Each
    rewinding step's geometries are new objects, and the still one of a pair has the content of
    the step before."""

    grids: dict = field(default_factory=dict)
    tessellations: dict = field(default_factory=dict)
    boxes: tuple | None = None
    bounds: np.ndarray | None = None
    size: float | None = None
    outer: tuple | None = None
    mapped: tuple | None = None
    inner: tuple | None = None


WORLDS_KEPT = 4


_WORLDS = memo.Table("detect.worlds", WORLDS_KEPT)  # world data by `SurfaceGeometry.content`, most recent last


@dataclass(frozen=True, eq=False)
class SurfaceGeometry:
    """A deformable at one time: object-space ``surface``, ``xform (4, 4)``, collision density.
    Object-space data lives in its `Shape` (shared across times); world data is derived lazily
    and kept here, so pairs sharing an object share the work."""

    surface: HSpline
    xform: np.ndarray
    name: str = ""
    density: int = 8
    max_density: int = 64
    # the level-0 patch sets tessellated for this geometry, by their bytes (`tessellated`)
    _asked: dict = field(default_factory=dict, init=False, repr=False)

    @_once
    def shape(self) -> Shape:
        return shape_of(self.surface, self.density, self.max_density)

    @_once
    def content(self) -> tuple:
        """What this geometry's world data and detection's answers depend on: the surface's
        content (`Shape.digest`), the matrix's bytes and the densities."""
        return ("surface", self.shape.digest, np.ascontiguousarray(self.xform, np.float64).tobytes(),
                self.density, self.max_density)

    @property
    def details(self) -> H.Details | None:
        return self.shape.details

    @_once
    def _world(self) -> _World:
        """The world data of this content (`_World`); the `WORLDS_KEPT` most recent are kept."""
        return _WORLDS.kept(self.content, _World)

    @_once
    def boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """World boxes ``lo, hi`` ``(P0u, P0v, 3)`` of the level-0 patches: the box of each hull
        box's 8 mapped corners, from its centre ``c`` and half-extents ``h`` as ``M c + t ± |M| h``
        (``|M|`` entrywise): the same box as mapping the corners, to rounding (2e-15 of the
        coordinates), at 1/50 of the cost (4 ms against 0.08 ms for 2,496 patches), so the broad
        phase every frame pays stays small on a large model. Shared by the geometries of the same
        content (`_World`)."""
        world = self._world
        if world.boxes is None:
            obj_centre, obj_half = _object_patch_boxes(self.shape)
            shape = self.shape.hulls[0].shape
            if _translated_boxes(world, obj_centre, obj_half, self.xform, shape):
                return world.boxes
            centre = apply_xform(self.xform, obj_centre).reshape(shape)
            half = (obj_half @ np.abs(self.xform[:3, :3]).T).reshape(shape)
            world.boxes = centre - half, centre + half
        return world.boxes

    @_once
    def bounds(self) -> np.ndarray:
        """World box ``(2, 3)`` of the whole surface (union of the patch boxes)."""
        world = self._world
        if world.bounds is None:
            lo, hi = self.boxes
            # a matrix that only translates gets the union in the boxes' own compiled pass
            # (`_translated_boxes`, the same bits as the reductions below): each rewinding step's
            # moving object finds it set there
            if world.bounds is None:
                # `min(axis=0)` of the low corners and `max(axis=0)` of the high ones, each in one
                # compiled pass (`acra.bvh.bounds`, exact: numpy reduces a last axis of 3 row by row)
                world.bounds = np.stack([bounds_of(lo)[0], bounds_of(hi)[1]])
                world.bounds.setflags(write=False)  # shared by every geometry of this content
        return world.bounds

    @_once
    def size(self) -> float:
        """The diagonal of `bounds`, kept with them in the content's world data."""
        world = self._world
        if world.size is None:
            world.size = float(np.linalg.norm(self.bounds[1] - self.bounds[0]))
        return world.size

    @property
    def outer(self) -> np.ndarray:
        """World box ``(2, 3)`` holding `bounds`: the union of the object-space hull boxes, one
        box per shape (`_object_box`), mapped through the matrix (`_mapped_box`). A few products
        instead of the world box of every level-0 patch, which a pair whose objects are apart
        never needs (`apart`)."""
        return np.array(self._outer[:2])

    @_once
    def _outer(self) -> tuple[tuple, tuple, float]:
        # a content met before (the still object of each rewinding step, a new geometry object
        # each time) keeps its box in its world data; a surface whose digest is not known yet is
        # not hashed for it, nor is world data made here (`apart` costs a few products)
        world = _WORLDS.get(self.content) if "digest" in self.shape.__dict__ else None
        if world is not None and world.outer is not None:
            return world.outer
        out = _mapped_box(self.xform, _object_box(self.shape))
        if world is not None:
            world.outer = out
        return out

    @property
    def closed(self) -> bool:
        return self.shape.closed

    def to_object(self, points: np.ndarray) -> np.ndarray:
        """World points ``(k, 3)`` in object space: `pipeline.model.apply_inverse`'s arithmetic,
        the same bits, with the linear part's inverse found once per geometry (a round asks for
        it in every inside test, closest point and projection on this geometry)."""
        return (points - self.xform[:3, 3]) @ self._inverse_t

    @_once
    def _inverse_t(self) -> np.ndarray:
        """``(3, 3) float64``: the transposed inverse of ``xform``'s linear part."""
        return np.linalg.inv(self.xform[:3, :3]).T


Geometry = Union[SurfaceGeometry, ColliderGeometry]


# id(shape) -> (a weak reference to it without a callback, `_object_box`'s answer), and
# ("patch boxes", id(shape)) -> (the same, `_object_patch_boxes`'s answer): a callback would run
# Python code when a shape dies, where an interrupt raised inside it is dropped
_OBJECT_BOXES = memo.Table("detect.object_boxes")


def _object_box(shape: Shape) -> tuple[tuple, tuple]:
    """Object-space box of every level-0 hull box of ``shape`` as its centre and half-extents
    (3 floats each), found once per shape (a shape serves every frame of a run, `shape_of`)."""
    hit = _OBJECT_BOXES.get(id(shape))
    if hit is not None and hit[0]() is shape:
        return hit[1]
    lo, hi = shape.hulls
    box = _centre_half(lo.reshape(-1, 3).min(axis=0), hi.reshape(-1, 3).max(axis=0))
    for key in [key for key, (ref, _) in _OBJECT_BOXES.items() if ref() is None]:
        del _OBJECT_BOXES[key]
    _OBJECT_BOXES[id(shape)] = (weakref.ref(shape), box)
    return box


def _object_patch_boxes(shape: Shape) -> tuple[np.ndarray, np.ndarray]:
    """Centres and half-extents ``(P, 3)`` of ``shape``'s level-0 hull boxes in object space,
    found once per shape (kept in `_OBJECT_BOXES` beside `_object_box`): every matrix's world
    boxes (`SurfaceGeometry.boxes`, a rewinding search's every step) map the same ones."""
    key = ("patch boxes", id(shape))
    hit = _OBJECT_BOXES.get(key)
    if hit is not None and hit[0]() is shape:
        return hit[1]
    lo, hi = shape.hulls
    boxes = (0.5 * (lo + hi)).reshape(-1, 3), (0.5 * (hi - lo)).reshape(-1, 3)
    for a in boxes:
        a.setflags(write=False)
    for dead in [k for k, (ref, _) in _OBJECT_BOXES.items() if ref() is None]:
        del _OBJECT_BOXES[dead]
    _OBJECT_BOXES[key] = (weakref.ref(shape), boxes)
    return boxes


def _translated_boxes(world: _World, centre: np.ndarray, half: np.ndarray, xform: np.ndarray, shape: tuple) -> bool:
    """Fill ``world``'s patch boxes ``(*shape, 3)``, their union and inner corners
    (`_World`) from object-space ``centre, half (P, 3)`` under a matrix that only translates, in
    one compiled pass (`acra.patch_boxes.translated_boxes`: the same bits as the products of
    `SurfaceGeometry.boxes` and the reductions of `SurfaceGeometry.bounds` and
    `pipeline.detect._every_box_meets`). A rewinding step's moving object has a new matrix, so
    all three are new each step; returns False (nothing set) for any other matrix."""
    if type(xform) is not np.ndarray or xform.dtype != np.float64 or xform.shape != (4, 4):
        return False
    lo, hi, box, inner = np.empty(centre.shape), np.empty(centre.shape), np.empty((2, 3)), np.empty((2, 3))
    if not patch_boxes.translated_boxes(centre, half, xform, lo, hi, box, inner):
        return False
    box.setflags(write=False)  # shared by every geometry of this content
    world.boxes, world.bounds = (lo.reshape(shape), hi.reshape(shape)), box
    world.inner = (inner[0].tolist(), inner[1].tolist())
    return True


def _centre_half(lo: np.ndarray, hi: np.ndarray) -> tuple[tuple, tuple]:
    """Centre and half-extents (3 floats each) of the box ``lo, hi (3,)``."""
    return tuple((0.5 * (lo + hi)).tolist()), tuple((0.5 * (hi - lo)).tolist())


def _mapped_box(xform: np.ndarray, box: tuple[tuple, tuple]) -> tuple[tuple, tuple, float]:
    """World box holding the object-space box ``box`` (`_centre_half`) under ``xform (4, 4)``
    and every box inside it however mapped: ``M c + t ± |M| h``, widened by 1e-9 of its terms'
    size, far beyond the rounding (1e-15 of them) by which a sub-box's own mapped box
    (`SurfaceGeometry.boxes`, `ColliderGeometry.bounds`) could poke out of it. Returns its low
    and high corners (3 floats each) and its diagonal. In Python floats: on three coordinates
    numpy's per-call cost is most of the work."""
    (cx, cy, cz), (hx, hy, hz) = box
    lo, hi, reach = [], [], 0.0
    for a, b, c, t in xform.tolist()[:3]:
        centre = a * cx + b * cy + c * cz + t
        half = abs(a) * hx + abs(b) * hy + abs(c) * hz
        # the rounding of ``M c`` and ``+ t`` scales with the terms, which may cancel in ``centre``
        reach = max(reach, abs(t) + abs(a * cx) + abs(b * cy) + abs(c * cz) + 2.0 * half)
        lo.append(centre - half)
        hi.append(centre + half)
    slack = 1e-9 * reach
    lo, hi = tuple(x - slack for x in lo), tuple(x + slack for x in hi)
    return lo, hi, math.sqrt(sum((b - a) ** 2 for a, b in zip(lo, hi)))


def patch_density(geom: SurfaceGeometry) -> np.ndarray:
    """Steps per edge of each level-0 patch ``(P0u, P0v) int64``: ``max(density, 2 * 2**k)``, ``k``
    the finest level with an active patch inside it, capped at ``max_density``."""
    return geom.shape.density_map


def candidate_patches(geom: SurfaceGeometry, bounds: np.ndarray, pad: float = 0.0) -> np.ndarray:
    """Level-0 patches ``(m, 2) int64`` whose world box overlaps ``bounds (2, 3)``, distinct and
    ascending (row-major), as `tessellate` keys them."""
    lo, hi = geom.boxes
    return np.argwhere(_overlap(lo, hi, bounds[0], bounds[1], pad)).astype(np.int64)


def is_closed(geom: Geometry) -> bool:
    """Whether ``geom`` has an inside (`SurfaceGeometry.closed`, `ColliderStatic.closed`)."""
    return geom.static.closed if isinstance(geom, ColliderGeometry) else geom.closed


def _face_boxes(points: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Boxes ``lo, hi (f, 3)`` of the triangles ``faces (f, 3) int64`` of ``points (n, 3)``
    (compiled: `acra.narrow.face_boxes`)."""
    return narrow.face_boxes(points, faces)


def wrap_uv(hs: HSpline, uv: np.ndarray) -> np.ndarray:
    """Parameters ``uv (k, 2) float64`` into the domain: wrapped in a periodic direction,
    clamped in an open one."""
    out = uv.copy()
    for c, d in enumerate((hs.u, hs.v)):
        out[:, c] = np.mod(out[:, c], d.patches0) if d.periodic else np.clip(out[:, c], 0.0, d.patches0)
    return out


def surface_points(geom: SurfaceGeometry, uv: np.ndarray, order: int = 0) -> H.SurfaceEval:
    """World points and world-space partial derivatives up to ``order`` at ``uv (k, 2)``."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    ev = H.evaluate(geom.surface, uv[:, 0], uv[:, 1], order=order, det=geom.details)
    lin = {k: None if x is None else x @ geom.xform[:3, :3].T for k, x in vars(ev).items() if k != "points"}
    return H.SurfaceEval(apply_xform(geom.xform, ev.points), **lin)


def face_samples(geom: ColliderGeometry, bounds: np.ndarray, spacing: float) -> np.ndarray:
    """World points ``(n, 3)`` on the collider's triangles within the world box ``bounds (2, 3)``,
    on a barycentric grid of each triangle whose box meets it, at most ``spacing`` apart along
    each edge (vertices included). A collider's region holds only its mesh's vertices, 8 for a
    box: too few to say which part of the other surface its faces need cleared
    (`datapoints.collider_points_for`).

    A triangle longer than the box's diagonal is first split in four, repeatedly, keeping the
    pieces whose box meets ``bounds``: the samples then cost the area inside the box, not the
    triangle's (a floor 1e3 across at a spacing of 1e-2 would be 5e9 points)."""
    mesh = geom.static.mesh
    rows = geom.static.faces_near(geom.xform, bounds)  # a superset of the faces met below, in order
    tri = apply_xform(geom.xform, mesh.vertices[mesh.faces[rows]].reshape(-1, 3)).reshape(-1, 3, 3)
    limit = max(float(np.linalg.norm(bounds[1] - bounds[0])), spacing)
    while True:
        tri = tri[_overlap(tri.min(axis=1), tri.max(axis=1), bounds[0], bounds[1], 0.0)]
        big = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1) > limit
        if not big.any():
            break
        a, b, c = (tri[big][:, k] for k in range(3))
        ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
        tri = np.concatenate([tri[~big], np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1),
                              np.stack([ca, bc, c], 1), np.stack([ab, bc, ca], 1)])
    if not len(tri):
        return np.zeros((0, 3))
    steps = np.maximum(np.ceil(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1) / spacing), 1).astype(np.int64)
    out = []
    for n in np.unique(steps):
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        bary = np.stack([i[keep], j[keep], n - i[keep] - j[keep]], axis=1) / n  # (m, 3)
        out.append(np.einsum("mk,tkc->tmc", bary, tri[steps == n]).reshape(-1, 3))
    pts = np.unique(np.concatenate(out), axis=0)
    return pts[np.all((pts >= bounds[0]) & (pts <= bounds[1]), axis=1)]


def world_normals(geom: Geometry, n: np.ndarray) -> np.ndarray:
    """Object-space normals ``n (k, 3)`` of ``geom`` as world unit normals ``(k, 3)`` (normals map
    by the inverse transpose of the matrix, so a non-uniform scale keeps them perpendicular)."""
    n = np.asarray(n, np.float64).reshape(-1, 3) @ np.linalg.inv(geom.xform[:3, :3])
    return n / np.linalg.norm(n, axis=1, keepdims=True)
