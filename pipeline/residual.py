"""Residual penetration as the user sees it (contract §3): the largest depth of any point of a
deformable's display mesh inside another object, as a fraction of the diagonal of the bounding
box of that deformable's own display at that frame.

"Display mesh" is what a USD client draws: the output's float32 ``points`` under the prim's world
matrix, its faces split into triangles as a fan from each face's first vertex. "Another object"
is every other closed object: a closed deformable's display mesh (welded at poles and seams) or
a closed collider's mesh; an open object has no inside. Depths come from
`pipeline.clearance.triangle_depth`, a certified upper bound over the whole of each triangle, not
only at samples, so the figure never under-states what the user sees; it is refined until it is
within 1.25 times the deepest point found, or within half the tolerance, and until it is on the
same side of the tolerance as the deepest point found.

The queries run in the other object's object space: a collider's `clearance.Solid` is built once
per run, a deformable's is the part of its display near the other object's triangles (after
those proven clear of it are left out, `_clear_depth`), built per pair and kept on the display by
its face rows (`Shown.parts`; a kept part holding the rows a pair asks for answers it too). An object-space depth times the largest singular value of the world matrix's linear part
(`clearance.sigma_max`) bounds the world depth from above (exact for rotations, translations and
uniform scales).

`measure_frame` is what both the frame loop (every round, on each surface's own adaptive display
near the other objects) and `measure_run` (every frame of a finished run, on the run's display)
call. World units unless stated; arrays are float64.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from acra import bvh, clearcells, depthbound, memo, meshrows
from pipeline import clearance, workers
from pipeline.model import SceneModel, apply_xform, is_translation, translated

__all__ = ["Shown", "Inside", "PairDepth", "FrameResidual", "shown", "collider_shown", "collider_solid", "pair_depth",
           "measure_frame", "complete", "measure_run", "known", "TARGET", "OVER"]

TARGET = 0.5  # a bound within this fraction of the tolerance needs no refining (clearance.triangle_depth)
# a point this many times deeper than the tolerance proves a pair over it (`measure_frame`'s
# ``settle``): the certified bound of the full search, at least that point's depth but for the
# rounding of eq. (6)'s few operations, then lies over the tolerance too
OVER = 1.0 + 1e-6


@dataclass(frozen=True, eq=False)
class Shown:
    """One object as the user sees it at one frame.

    Attributes
    ----------
    path : str
    world : (n, 3) float64
        World points of the display (float32 points as stored, mapped by the world matrix).
    vertex_uv : (n, 2) float64 or None
        Surface parameters of each point (a deformable), else ``None``.
    size : float
        Diagonal of the bounding box of the object's whole display (world).
    box : (2, 3) float64
        World box of the whole object (min and max corner).
    xform : (4, 4) float64
        Object-to-world matrix.
    closed : bool
        Whether the object has an inside.
    local : (n, 3) float64 or None
        A deformable's display points in object space (float32 values), for its `part`.
    triangles : (t, 3) int64
        Its triangles (rows of ``world`` and ``local``).
    outward : float
        ``+1`` if the triangles' winding gives outward normals, ``-1`` if inward.
    whole : callable or None
        Builds (or returns a kept) `clearance.Solid` of the whole object in object space.
    deformable : bool
    parts : dict or None
        Part solids of these ``local`` points and ``triangles`` already built (`pair_depth`), by
        face rows; shared by every `Shown` of one display (`display.SurfaceDisplay.parts`).
    like : Shown or None
        Another display of the same surface, whose ``parts`` may hold a part of the same content
        (`_like`): the round's display where the run's display of a frame differs from it.
    topology : acra.tessellate.MeshTopology or None
        The topology whose fan triangles and vertex parameters ``triangles`` and ``vertex_uv``
        are (`shown`), else ``None``; its `MeshTopology.key`, where it has one, stands for them
        in `fingerprint`.

    A pair gathers only the triangles near the other object (`near`); ``corners`` and ``uv``
    gather all of them.
    """

    path: str
    world: np.ndarray
    vertex_uv: np.ndarray | None
    size: float
    box: np.ndarray
    xform: np.ndarray
    closed: bool
    local: np.ndarray | None = None
    triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    outward: float = 1.0
    whole: object = None
    deformable: bool = True
    parts: dict | None = None
    like: Shown | None = None
    topology: object = None

    @cached_property
    def corners(self) -> np.ndarray:
        """World triangles ``(t, 3, 3)``."""
        return self.world[self.triangles]

    @cached_property
    def uv(self) -> np.ndarray | None:
        """Surface parameters ``(t, 3, 2)`` of each triangle's corners, or ``None``."""
        return None if self.vertex_uv is None else self.vertex_uv[self.triangles]

    def near(self, box: np.ndarray, pad: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """World triangles ``(m, 3, 3)`` whose boxes come within ``pad`` of the world ``box (2, 3)``
        and their rows in ``triangles``."""
        rows = self.near_rows(box, pad)
        return meshrows.faces_at(self.world, self.triangles, rows), rows

    def near_rows(self, box: np.ndarray, pad: float = 0.0) -> np.ndarray:
        """The rows of `near`'s triangles, without them."""
        return meshrows.faces_meet_rows(self.world, self.triangles, box[0], box[1], pad, self.chunks)

    @cached_property
    def chunks(self) -> tuple:
        """`acra.meshrows.face_chunks` of the world triangles: `near_rows` compares the faces of the
        chunks near its box alone (the same rows). Each display is asked near both objects of a
        pair, as the inner object and as the other, and a still display every frame."""
        return meshrows.face_chunks(self.world, _chunk_vertices(self.triangles, len(self.world)))

    @cached_property
    def fingerprint(self) -> bytes:
        """A digest of everything `pair_depth` reads of this object (its path names a
        collider's solid, which is fixed for a run): two `Shown` with the same digest give the
        same `pair_depth` answers, as either side of a pair."""
        h = hashlib.sha1(repr((self.path, self.closed, self.deformable, self.outward, self.size)).encode())
        # ``world`` is ``local`` mapped by ``xform`` (`shown`; a collider's is empty). ``local``
        # holds float32 values (`shown`), so its float32 copy has the same values in half the
        # bytes to hash
        local = None if self.local is None else self.local.astype(np.float32)
        for x in (self.box, self.xform, local):
            h.update(b"-" if x is None else repr((x.dtype.str, x.shape)).encode())
            if x is not None:
                h.update(np.ascontiguousarray(x).data)
        key = getattr(self.topology, "key", None)
        if key is not None:
            # the triangles and parameters are a function of the topology's key (`shown`), so it
            # stands for them: a new topology's arrays are not hashed (about 1.5 MB on the
            # demo's head); tagged apart from the arrays' digests, which lead with a dtype
            h.update(b"topology" + key + (b"-" if self.vertex_uv is None else b"uv"))
            return h.digest()
        for x in (self.triangles, self.vertex_uv):  # a display's, the same arrays every round and frame
            h.update(b"-" if x is None else _digest(x))
        return h.digest()

    @cached_property
    def box_local(self) -> np.ndarray:
        """The box ``(2, 3)`` of the object-space display points. Under the identity matrix
        (a translation of zeros) a finite world box is theirs, taken already (`shown`): each
        world value is its point's ``x * 1`` plus zeros, the same value but for a zero's sign,
        which neither the grid's cells (``floor((x - origin) / h)``, `acra.clearcells`) nor the
        diagonal (squares) reads, and a point that is not finite leaves a coordinate of the
        world box not finite."""
        x = self.xform
        if not np.count_nonzero(x[:3] - _IDENTITY34) and np.isfinite(self.box).all():  # a NaN counts
            return self.box
        return bvh.bounds(self.local)

    @cached_property
    def diagonal_local(self) -> float:
        """Diagonal of the box of the object-space display points (the scale solids weld at)."""
        return float(np.linalg.norm(self.box_local[1] - self.box_local[0]))


_IDENTITY34 = np.eye(4)[:3]  # an affine matrix's rows of the identity map

_DIGESTS = memo.Table("residual.digests", 16)  # id(array) -> (array, digest), the arrays made read-only, most recent last


def _digest(x: np.ndarray) -> bytes:
    """A digest of ``x``'s dtype, shape and values, kept per array: the array is made read-only,
    so the values it was taken of are the values it holds. An array holding the bytes of a kept
    one gets that one's digest without hashing: every display on one topology holds the
    topology's parameter array (`acra.tessellate.MeshTopology.uv`), and a topology built again (a
    refinement no longer kept) gives new parameters and triangles of the same bytes; comparing
    bytes costs a tenth of hashing them."""
    digests = _DIGESTS.entries()
    hit = digests.pop(id(x), None)
    if hit is None or hit[0] is not x or x.flags.writeable:
        x.flags.writeable = False
        same = next((d for y, d in reversed(digests.values()) if _same_bytes(x, y)), None)
        if same is None:
            h = hashlib.sha1(repr((x.dtype.str, x.shape)).encode())
            h.update(np.ascontiguousarray(x).data)
            same = h.digest()
        hit = (x, same)
    digests[id(x)] = hit
    _DIGESTS.trim()
    return hit[1]


_CHUNK_VERTICES = memo.Table("residual.chunk_vertices", 16)  # id(triangles) -> (triangles made read-only, their points' count, `meshrows.chunk_vertices`), most recent last


def _chunk_vertices(triangles: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """`acra.meshrows.chunk_vertices` of ``triangles`` into ``n`` points, kept per array: a display's
    topology holds one triangles array for every display on it, made read-only here (as `_digest`
    does), so the lists taken of it still hold."""
    lists = _CHUNK_VERTICES.entries()
    hit = lists.pop(id(triangles), None)
    if hit is None or hit[0] is not triangles or hit[1] != n or triangles.flags.writeable:
        triangles.flags.writeable = False
        hit = (triangles, n, meshrows.chunk_vertices(triangles, n))
    lists[id(triangles)] = hit
    _CHUNK_VERTICES.trim()
    return hit[2]


def _same_bytes(x: np.ndarray, y: np.ndarray) -> bool:
    """Whether ``x`` and the kept array ``y`` (still read-only) hold the same dtype, shape and
    bytes: compared as unsigned integers of the item's size, so -0.0 and 0.0, or two NaNs, are
    told apart or alike exactly as their bytes are."""
    if y.flags.writeable or x.dtype != y.dtype or x.shape != y.shape or x.dtype.hasobject:
        return False
    if x.dtype.itemsize not in (1, 2, 4, 8):
        return np.ascontiguousarray(x).tobytes() == np.ascontiguousarray(y).tobytes()
    code = f"u{x.dtype.itemsize}"
    return bool(np.array_equal(np.ascontiguousarray(x).view(code), np.ascontiguousarray(y).view(code)))


def shown(path: str, points: np.ndarray, triangles: np.ndarray, xform: np.ndarray, uv: np.ndarray | None = None,
          closed: bool = False, outward: float = 1.0, whole=None, parts: dict | None = None, topology=None) -> Shown:
    """A deformable's display as the user sees it: object-space ``points (n, 3)`` (rounded to
    float32, as the output stores them), ``triangles (t, 3) int64``, world matrix ``xform (4, 4)``,
    vertex parameters ``uv (n, 2)``; ``closed`` with the winding's ``outward`` sign; ``whole()``
    gives its whole `clearance.Solid` (default: built from the points); ``parts`` keeps the part
    solids built of these points and triangles (a dict shared by every call on one display).
    ``topology``: the `acra.tessellate.MeshTopology` whose fan triangles (``topology.triangles()``)
    and parameters (``topology.uv``, or ``None``) ``triangles`` and ``uv`` are, whose key then
    stands for them in `Shown.fingerprint`."""
    p32, world, box = _placed(points, xform)
    if whole is None and closed:
        whole = _Once(lambda: clearance.solid(p32, triangles))
    return Shown(path, world, None if uv is None else _held(uv, np.float64),
                 float(np.linalg.norm(box[1] - box[0])), box, np.asarray(xform, np.float64), closed, p32,
                 _held(triangles, np.int64), float(outward), whole, True, parts,
                 topology=topology)


def _held(x, dtype) -> np.ndarray:
    """``x`` itself where it is an array of ``dtype`` (a display's triangles or parameters, the
    same object every round that shows the display, so `_digest` knows it by identity), else
    ``np.asarray(x, dtype)``: numpy hands back a new view of an array whose dtype equals ``dtype``
    but is another instance of it (a numba kernel's output)."""
    return x if isinstance(x, np.ndarray) and x.dtype == dtype else np.asarray(x, dtype)


def _placed(points: np.ndarray, xform: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``points (n, 3)`` rounded to float32 (as float64), mapped to world by ``xform (4, 4)``
    (`apply_xform`'s bits), and the world box ``(2, 3)`` (`bvh.bounds`'): one compiled pass where
    the linear part is the identity (`pipeline.model.translated`), else numpy's."""
    p = np.ascontiguousarray(points, np.float64)
    x = np.ascontiguousarray(xform, np.float64)
    if p.ndim == 2 and p.shape[1] == 3 and len(p) and x.shape == (4, 4):
        local, world, box = np.empty(p.shape), np.empty(p.shape), np.empty((2, 3))
        if translated(p, x, True, local, world, box):
            return local, world, box
    local = np.asarray(points, np.float32).astype(np.float64)
    world = apply_xform(xform, local)
    return local, world, bvh.bounds(world)


def collider_shown(path: str, box: np.ndarray, size: float, solid: clearance.Solid | None, xform: np.ndarray) -> Shown:
    """A collider as the other object of a pair: its world ``box (2, 3)``, ``size``, inside and
    world matrix. It is never the inner object (the residual is measured on the deformables'
    output), so it holds no triangles."""
    return Shown(path, np.zeros((0, 3)), None, float(size), np.asarray(box, np.float64), np.asarray(xform, np.float64),
                 solid is not None, whole=(lambda: solid), deformable=False)


class _Once:
    """A value built on the first call and kept (``None`` too)."""

    _UNSET = object()

    def __init__(self, make) -> None:
        self.make, self.value = make, _Once._UNSET

    def __call__(self):
        if self.value is _Once._UNSET:
            self.value = self.make()
        return self.value


_COLLIDER_SOLIDS = memo.Table("residual.collider_solids")  # a collider mesh's content digest -> (its inside or None,); a run has a few


def collider_solid(vertices: np.ndarray, triangles: np.ndarray, built=None) -> clearance.Solid | None:
    """A collider's inside in its object space, or ``None`` if its mesh is not closed; kept by
    the mesh's content (`shape.content_digest`), so the frame loop's rounds and the run's display
    measure (`measure_run`) build one a run: its weld, pseudo-normals and BVH cost about 7 µs a
    triangle, and hashing the arrays a hundredth of that. ``built``: where given, a call that
    answers the `clearance.solid` of these same arrays built already (detection's,
    `geometry.ColliderStatic.solid`), taken in place of building it."""
    from pipeline.shape import content_digest

    v, f = np.asarray(vertices, np.float64), np.asarray(triangles, np.int64)

    def make():
        try:
            return (clearance.solid(v, f) if built is None else built(),)
        except ValueError:  # not closed: kept too, as the table keeps no None
            return (None,)

    return _COLLIDER_SOLIDS.kept(content_digest(v, f), make)[0]


@dataclass
class Inside:
    """What of ``a`` lies inside ``b``: the certified ``depth`` bound (world), the deepest point
    found ``lower``, and the points found inside: world ``points (m, 3)``, parameters on ``a``
    ``uv (m, 2)`` (``None`` if ``a`` is not a deformable), ``deep (m,)``.

    ``stopped``: the search ended at a point deeper than `pair_depth`'s ``stop``, or the pair
    was not measured (`measure_frame`'s ``settle``): ``depth`` is then ``lower``, a lower bound
    only (0 where not measured), and the points are the first the full search finds. Such an
    answer is never kept where a lookup takes answers (`measure_frame`'s ``measured``, `known`)."""

    depth: float
    lower: float
    points: np.ndarray
    uv: np.ndarray | None
    deep: np.ndarray
    complete: bool = True
    stopped: bool = False


def pair_depth(a: Shown, b: Shown, target: float, decide: float = np.inf, stop: float = np.inf) -> Inside:
    """How deep ``a``'s triangles go inside ``b`` (`clearance.triangle_depth` in ``b``'s object
    space), with ``target`` the world depth below which the bound need not be refined and
    ``decide`` the world depth it is held against (the tolerance: refined until on one side).
    ``stop``: a world depth whose first evaluated point ends the search (`Inside.stopped`, a
    lower bound; `clearance.triangle_depth`'s ``stop``); without one, the full answer.

    A deformable ``b`` is queried through the part of its display near ``a``'s triangles in its
    box: its faces whose world boxes come within ``P`` (the diagonal of those triangles' box) of
    it. A point within ``P`` of that part has its closest point, and every face around it, in
    the part, so the part answers exactly; a point farther (``a`` deep inside a large ``b``) is
    answered by ``b``'s whole solid. Where that part holds `CLEAR_ROWS` faces or more, the
    triangles proven clear of ``b`` are left out first and the part near the others, a fraction
    of it, answers (`_clear_depth`: the same answer, or ``None`` and the part above)."""
    if not b.closed:
        return _nothing(a)
    near = a.near_rows(b.box)
    if not len(near):
        return _nothing(a)
    # the triangles, their box and their corners less ``b``'s translation in one pass
    corners, region, moved, plain = meshrows.faces_placed(a.world, a.triangles, near, b.xform[:3, 3])
    k, inverse, identity = _placement(b.xform)  # eq. (5): world lengths at most k times object-space ones
    # `apply_inverse`: under an identity linear part the product changes no finite nonzero value
    # (`meshrows.faces_placed`), so those are the object-space corners as they are
    local = moved if plain and identity else (moved.reshape(-1, 3) @ inverse.T).reshape(-1, 3, 3)
    d = None
    if b.deformable:
        pad = float(np.linalg.norm(region[1] - region[0]))
        rows = b.near_rows(region, pad)
        if len(rows) >= CLEAR_ROWS:
            d = _clear_depth(b, local, target / k, decide / k, pad / k, _within(b.xform, region, pad, rows), stop / k)
        if d is None:
            if rows.size:
                part, answers = _part(b, rows)
                d = _answer(answers, part, local, target / k, pad / k, decide / k, stop / k)
    if d is None:
        d = clearance.triangle_depth(b.whole(), local, target / k, decide=decide / k, stop=stop / k)
    points, uv = meshrows.barycentric(d.bary, d.tri, corners, near, a.triangles, a.vertex_uv)
    return Inside(k * d.bound, k * d.lower, points, uv, k * d.depth, d.complete, d.stopped)


def _nothing(a: Shown) -> Inside:
    """No point of ``a`` inside."""
    return Inside(0.0, 0.0, np.zeros((0, 3)), None if a.vertex_uv is None else np.zeros((0, 2)), np.zeros(0))


CLEAR_ROWS = 2000  # a part of fewer faces is built as it is: proving triangles clear costs more than it saves
REACH = 2.0  # a near part answers within this many times the triangles' largest covering radius
SLACK = 1e-6  # x the display's diagonal: how far the weld may move a part's surface (`clearance.solid`)


def _within(xform: np.ndarray, region: np.ndarray, pad: float, rows: np.ndarray):
    """`acra.clearcells.clear_of`'s ``near``: ``rows`` (the faces whose world boxes come within ``pad``
    of the world box ``region (2, 3)``) for an object-space box whose image under ``xform`` lies
    in that padded box (with room for the roundings of the mapped points), else ``None``."""
    def near(lo, hi):
        (l0, l1, l2), (h0, h1, h2) = lo.tolist(), hi.tolist()
        w = apply_xform(xform, np.array([[l0, l1, l2], [h0, l1, l2], [l0, h1, l2], [l0, l1, h2], [h0, h1, l2], [h0, l1, h2],
                                         [l0, h1, h2], [h0, h1, h2]]))
        least, most = w.min(axis=0), w.max(axis=0)
        room = 1e-9 * (max(float(most.max()), -float(least.min())) + pad)  # the largest |w|
        fits = bool((least - room >= region[0] - pad).all() and (most + room <= region[1] + pad).all())
        return rows if fits else None
    return near


def _clear_depth(b: Shown, local: np.ndarray, target: float, decide: float, pad: float, near=None, stop: float = np.inf):
    """`clearance.triangle_depth` of the object-space triangles ``local (m, 3, 3)`` in ``b``,
    with the triangles `acra.clearcells.clear_of` proves outside ``b`` by more than their covering
    radii left out, in the part of ``b``'s display near the others; ``None`` where that part
    cannot answer (the caller then takes the part near all of them).

    A left-out triangle's corners lie outside by more than its covering radius ``rho``, so eq.
    (4) bounds it by 0 and it holds no point inside: it adds nothing to the bound, the depth
    found or the points found inside, and no other triangle's cells or points depend on it (a
    point shared with it is outside too, and its cells are never split). The part holds every
    face whose box comes within ``R`` (`REACH` times the largest ``rho``) of a kept triangle's,
    so within ``R`` of any point the kept triangles hold, it has every face the whole display
    has: a point's closest face and the faces around it, and the empty ball about a far corner
    (`clearance._signed_corners`), are the whole's, and a point farther than ``R`` from it is
    not answered (`clearance.triangle_depth` with ``reach``: ``None``). Most triangles of a
    display near a thin object lie far from it, and a part near the rest is a fraction of the
    part near their box."""
    rho = depthbound.covering_radii(local)
    reach = min(REACH * float(rho.max(initial=0.0)), pad)
    got = clearcells.clear_of(b.local, b.triangles, local, rho, SLACK * b.diagonal_local, reach, b.box_local, near=near)
    if got is None:
        return None
    keep, rows, reach = got
    if reach >= pad:
        return None
    if not keep.any():  # every triangle outside with eq. (4) at 0: the bound is 0 and nothing is inside
        return clearance.Depth(0.0, 0.0, True, np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), 0, 0)
    if not rows.size:
        return None
    kept = np.nonzero(keep)[0]
    part, answers = _part(b, rows)
    d = _answer(answers, part, local if len(kept) == len(local) else local[kept], target, reach, decide, stop)
    if d is None or len(kept) == len(local):
        return d
    return replace(d, tri=kept[d.tri])


_PLACEMENTS = memo.Table("residual.placements", 16)  # the bytes of a (4, 4) matrix -> (sigma_max, inverse of its linear part, whether it is the identity)


def _placement(xform: np.ndarray) -> tuple[float, np.ndarray, bool]:
    """`clearance.sigma_max` of ``xform``, the inverse of its linear part (`apply_inverse`'s) and
    whether that inverse is the identity (zeros of either sign off its diagonal), kept by the
    matrix's bytes: every pair of a frame, and every frame of a still object, asks the same
    matrix."""
    key = np.ascontiguousarray(xform, np.float64).tobytes()
    placements = _PLACEMENTS.entries()
    hit = placements.get(key)
    if hit is None:
        if len(placements) >= _PLACEMENTS.size:
            placements.pop(next(iter(placements)))
        inverse = np.linalg.inv(np.asarray(xform, np.float64)[:3, :3])
        hit = placements[key] = (clearance.sigma_max(xform), inverse, bool(np.array_equal(inverse, np.eye(3))))
    return hit


PARTS_KEPT = 8  # part solids kept per display
ANSWERS_KEPT = 4  # `triangle_depth` answers kept per part solid


def _part(b: Shown, rows: np.ndarray) -> tuple[clearance.Solid, list]:
    """The part solid of ``b``'s faces ``rows`` (`clearance.solid` with ``part``), or one built
    before from the same points and a superset of those rows: the rounds of a frame and the
    frames of a contact query an unchanged display near the same place. A superset answers as
    the part of ``rows`` does: ``rows`` holds every face within the reach of every queried point
    (`pair_depth`), so a point's closest face and the faces around it, and the empty ball about a
    far corner (`clearance._signed_corners`), are the same in both. The smallest kept superset is
    taken. With it, the list of answers `_answer` keeps for it (a fresh list where nothing is
    kept).

    rows : (m,) int64, increasing rows of ``b.triangles``"""
    make = lambda: _like(b, rows) or (clearance.solid(b.local, b.triangles[rows], part=True, outward=b.outward,  # noqa: E731
                                                      scale=b.diagonal_local), [])
    if b.parts is None:
        return make()
    key = (b.outward, rows.tobytes())
    hit = b.parts.pop(key, None)
    if hit is None:
        best = None
        for k, (_, _, kept) in b.parts.items():
            if k[0] == b.outward and len(kept) > len(rows) and (best is None or len(kept) < len(b.parts[best][2])):
                at = np.minimum(np.searchsorted(kept, rows), len(kept) - 1)
                if np.array_equal(kept[at], rows):  # every row of ``rows`` is kept (both increasing)
                    best = k
        hit = (*make(), rows) if best is None else b.parts.pop(best)
        key = key if best is None else best
    b.parts[key] = hit
    while len(b.parts) > PARTS_KEPT:
        del b.parts[next(iter(b.parts))]
    return hit[0], hit[1]


def _like(b: Shown, rows: np.ndarray) -> tuple[clearance.Solid, list] | None:
    """A part solid ``b.like`` keeps that is the part of ``b``'s faces ``rows``, with its kept
    answers, else ``None``: `clearance.solid` reads of the points only those the faces use, in
    the order of their rows, and of the faces only which of those each corner is (`_content`),
    so two parts alike in both, under the same winding and weld scale, are the same solid and
    answer alike (`_answer`). The run's display of a frame often shows the other object near the
    inner one as the round's display did, where the two topologies differ elsewhere.

    rows : (m,) int64, increasing rows of ``b.triangles``"""
    like = b.like
    if like is None or not like.parts or like.outward != b.outward or like.diagonal_local != b.diagonal_local:
        return None
    mine = None
    for (outward, _), (solid, answers, kept) in like.parts.items():
        if outward == b.outward and len(kept) == len(rows):
            mine = _content(b.local, b.triangles, rows) if mine is None else mine
            if all(np.array_equal(x.view(np.uint64), y.view(np.uint64))
                   for x, y in zip(mine, _content(like.local, like.triangles, kept))):
                return solid, answers
    return None


def _content(local: np.ndarray, triangles: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What `clearance.solid` reads of the part ``triangles[rows]`` of the points ``local (n, 3)``
    (`acra.pseudonormals.weld`'s input): the points the faces use, in the order of their rows,
    ``(k, 3) float64``, and each corner's place among them ``(m, 3) int64``."""
    faces = triangles[rows]
    used = np.zeros(len(local), np.bool_)
    used[faces] = True
    # a used point's place among them is the count of used points before it: what a search of
    # the sorted distinct corners gives, without sorting them
    return local[used], (np.cumsum(used) - 1)[faces]


def _answer(answers: list, part: clearance.Solid, local: np.ndarray, target: float, reach: float, decide: float,
            stop: float = np.inf):
    """`clearance.triangle_depth` of the object-space triangles ``local (m, 3, 3)`` in ``part``, or
    the answer kept in ``answers`` for the same bits of triangles and the same figures: it is a
    function of them alone. The run's display of a frame (`measure_run`) often shows the inner
    object's triangles near the other object as the round's display did, where the two displays
    differ elsewhere, so the pair's fingerprints differ and `known` misses it. Only full answers
    are kept: one answers a ``stop`` query too (it is what the stopped search would have gone
    on to), and a stopped one is kept nowhere."""
    figures = (target, reach, decide)
    bits = local.view(np.uint64)
    for kept_bits, kept_figures, d in answers:
        if kept_figures == figures and kept_bits.shape == bits.shape and np.array_equal(kept_bits, bits):
            return d
    d = clearance.triangle_depth(part, local, target, reach=reach, decide=decide, stop=stop)
    if d is not None and d.stopped:
        return d
    answers.append((bits, figures, d))
    if len(answers) > ANSWERS_KEPT:
        del answers[0]
    return d


@dataclass
class PairDepth:
    """One ordered pair at one frame: ``inside`` (`Inside` of ``a`` in ``b``) and its ``rel``,
    the depth over ``a``'s size."""

    a: str
    b: str
    inside: Inside
    rel: float


@dataclass
class FrameResidual:
    """A frame's residual: ``pairs`` (every ordered pair measured), ``worst`` (world) and
    ``worst_rel`` (over the inner object's size), and per deformable path its own worst depth
    ``by_object`` (world) and ``rel_by_object``; ``measured`` holds ``(a, b, Inside)`` per pair
    (the two `Shown`), for `known`. ``stopped``: some answer is a lower bound only
    (`Inside.stopped`, `measure_frame`'s ``settle``), and so are the figures; `complete` gives
    the full measure."""

    pairs: list = field(default_factory=list)
    measured: list = field(default_factory=list)
    worst: float = 0.0
    worst_rel: float = 0.0
    by_object: dict = field(default_factory=dict)
    rel_by_object: dict = field(default_factory=dict)
    stopped: bool = False

    def pair_rel(self, a: str, b: str) -> float:
        """The larger of ``a`` in ``b`` and ``b`` in ``a``, each over its own object's size (0
        where neither was measured)."""
        return self._by_pair().get((a, b) if a <= b else (b, a), 0.0)

    def _by_pair(self) -> dict:
        """Each measured unordered pair's larger ``rel`` by its two paths in sorted order, taken
        as ``max`` takes it over ``pairs`` in order; built once for the pairs held (a frame of
        many objects asks it of every pair)."""
        kept = self.__dict__.get("_pair_max")
        if kept is None or kept[0] != len(self.pairs):
            by: dict = {}
            for p in self.pairs:
                key = (p.a, p.b) if p.a <= p.b else (p.b, p.a)
                if key not in by or p.rel > by[key]:
                    by[key] = p.rel
            kept = self.__dict__["_pair_max"] = (len(self.pairs), by)
        return kept[1]


def known(fr: FrameResidual, tolerance: float) -> dict:
    """``fr``'s answers by the content of their pairs (`Shown.fingerprint`) and ``tolerance``, for
    `measure_frame`'s ``known``: the run's display of a frame often shows the surfaces of the
    round the frame loop kept, on the same topology, as the same points. Each answer keeps its
    depths and completeness but not the points found inside (`measure_run` reads the depths
    alone), so a run's kept answers stay a few numbers a pair. A lower bound (`Inside.stopped`)
    is left out: a lookup takes what it finds as the full answer."""
    return {(a.fingerprint, b.fingerprint, tolerance): _depths_only(ins) for a, b, ins in fr.measured if not ins.stopped}


def _depths_only(ins: Inside) -> Inside:
    """``ins`` without its points."""
    return Inside(ins.depth, ins.lower, ins.points[:0], None if ins.uv is None else ins.uv[:0], ins.deep[:0], ins.complete,
                  ins.stopped)


def measure_frame(objects: list[Shown], tolerance: float, pairs=None, measured: dict | None = None,
                  known: dict | None = None, settle=(), over: bool = False) -> FrameResidual:
    """`pair_depth` of every deformable of ``objects`` in every other closed one (or the ordered
    ``pairs`` of indices given), refined to ``TARGET * tolerance`` of the inner object's size.
    ``measured`` keeps each pair's `Inside` by the two `Shown` objects (which never change): a
    round whose response left both as they were gets the answer measured before. ``known``
    (`known`) holds answers by content: a pair whose two objects hold what a measured pair's
    held gets that answer's depths (`pair_depth` is a function of them), without its points.

    ``settle`` lists positions in ``pairs`` whose answers the caller reads only as far as
    whether the frame is over the tolerance (the frame loop's first round, for the pairs
    detection found: any answer over it sends the frame to a response). They are measured after
    the others, in the order given, each stopping at its first point `OVER` times deeper than
    the tolerance (`pair_depth`'s ``stop``), until one answer proves the frame over it; the
    rest are not measured (an answer kept in ``measured`` or ``known`` is still taken). With
    ``over`` the caller knows the frame is over already, and none is measured. A stopped or
    unmeasured answer is a lower bound (`Inside.stopped`, `FrameResidual.stopped`), kept in
    neither table; an answer the stop did not end is the full one, and is kept."""
    if pairs is None:  # every deformable's display in every other object
        pairs = [(i, j) for i, a in enumerate(objects) if a.deformable for j in range(len(objects)) if j != i]
    answers: list = [None] * len(pairs)
    later = set(settle)
    full = [n for n, (i, j) in enumerate(pairs) if n not in later and objects[j].closed]
    a, b = (objects[pairs[full[0]][0]], objects[pairs[full[0]][1]]) if full else (None, None)
    if (len(full) == 2 and pairs[full[0]] == pairs[full[1]][::-1] and workers.threads() > 1
            and _kept(a, b, tolerance, measured, known) is None and _kept(b, a, tolerance, measured, known) is None):
        # a pair both ways to measure (a closed pair's two sides, 2-4 ms each after a response):
        # the sides read each other's display and write only their own part caches, so they run
        # side by side (`pipeline.workers`) once the entries both would make in shared tables are taken
        _shared(a, b)
        keys = [k for k in ((id(a), id(b), tolerance), (id(b), id(a), tolerance)) if measured is not None and k not in measured]
        answers[full[0]], answers[full[1]] = workers.both(
            lambda: _pair_answer(a, b, tolerance, measured, known), lambda: _pair_answer(b, a, tolerance, measured, known))
        for key in keys:  # the answers kept, most recent last, in the order one thread keeps them
            if key in measured:
                measured[key] = measured.pop(key)
    else:
        for n in full:
            i, j = pairs[n]
            answers[n] = _pair_answer(objects[i], objects[j], tolerance, measured, known)
    proven = over or any(ins is not None and ins.depth / max(objects[i].size, 1e-300) > tolerance
                         for ins, (i, _) in zip(answers, pairs))
    for n in settle:
        i, j = pairs[n]
        if objects[j].closed:
            answers[n] = _pair_answer(objects[i], objects[j], tolerance, measured, known, settle=True, proven=proven)
            proven = proven or answers[n].stopped or answers[n].depth / max(objects[i].size, 1e-300) > tolerance
    return _residual([(objects[i], objects[j], ins) for (i, j), ins in zip(pairs, answers) if ins is not None])


def _shared(a: Shown, b: Shown) -> None:
    """The memo table entries `pair_depth` of ``a`` in ``b`` and of ``b`` in ``a`` both make
    (`_placement`, and `_chunk_vertices` through `Shown.chunks`), made before the two run in two
    threads: they then only read those tables (`pipeline.workers`)."""
    for s in (a, b):
        _placement(s.xform)
        s.chunks


def _kept(a: Shown, b: Shown, tolerance: float, measured: dict | None, known: dict | None) -> Inside | None:
    """`_pair_answer`'s answer for ``a`` in ``b`` kept in ``measured`` or ``known``, or ``None``."""
    hit = None if measured is None else measured.get((id(a), id(b), tolerance))
    if hit is not None and hit[0] is a and hit[1] is b:
        return hit[2]
    if known and (a.fingerprint, b.fingerprint, tolerance) in known:
        return known[a.fingerprint, b.fingerprint, tolerance]
    return None


def _pair_answer(a: Shown, b: Shown, tolerance: float, measured: dict | None, known: dict | None, settle: bool = False,
                 proven: bool = False) -> Inside:
    """`measure_frame`'s answer for ``a`` in ``b``: kept in ``measured`` or ``known``, else
    measured (and kept in ``measured``); with ``settle``, a search stopped at a point `OVER`
    times deeper than the tolerance, or, where the frame is ``proven`` over it, no measure (a
    lower bound, kept nowhere)."""
    size = max(a.size, 1e-300)
    key = (id(a), id(b), tolerance)
    hit = _kept(a, b, tolerance, measured, known)
    if hit is not None:
        return hit
    if settle and proven:  # depth and deepest point 0: lower bounds
        return replace(_nothing(a), complete=False, stopped=True)
    more = {"stop": OVER * tolerance * size} if settle else {}
    ins = pair_depth(a, b, TARGET * tolerance * size, tolerance * size, **more)
    if measured is not None and not ins.stopped:
        measured[key] = (a, b, ins)
    return ins


def _residual(answers: list) -> FrameResidual:
    """The `FrameResidual` of ``answers``, ``(a, b, Inside)`` per measured pair in order."""
    out = FrameResidual()
    for a, b, ins in answers:
        size = max(a.size, 1e-300)
        rel = ins.depth / size
        out.pairs.append(PairDepth(a.path, b.path, ins, rel))
        out.measured.append((a, b, ins))
        out.worst = max(out.worst, ins.depth)
        out.worst_rel = max(out.worst_rel, rel)
        out.by_object[a.path] = max(out.by_object.get(a.path, 0.0), ins.depth)
        out.rel_by_object[a.path] = max(out.rel_by_object.get(a.path, 0.0), rel)
        out.stopped = out.stopped or ins.stopped
    return out


def complete(fr: FrameResidual, tolerance: float, measured: dict | None = None) -> FrameResidual:
    """``fr`` (`measure_frame`'s at ``tolerance``) with every lower bound (`Inside.stopped`)
    measured in full (``measured`` as `measure_frame`'s): what `measure_frame` without
    ``settle`` gives on the same objects, its answers and figures in the same order."""
    if not fr.stopped:
        return fr
    return _residual([(a, b, _pair_answer(a, b, tolerance, measured, None) if ins.stopped else ins)
                      for a, b, ins in fr.measured])


def measure_run(stage, scene: SceneModel, result, stats: list, options, displays=None) -> None:
    """Measure every frame of a finished run on its display (``result``'s points and topologies,
    `pipeline.display.evaluate_run`): each `frames.FrameStats` gets ``residual``, ``residual_rel``
    and ``pair_residual_rel`` from what the output shows, and each deformable's result its own
    ``residual`` (world), and its milliseconds join the frame's ``ms_output`` and ``ms_total``.
    A pair the frame loop measured on the same content (``result.residuals[frame]``, `known`) is
    not measured again. World matrices come from the stats (``xforms``) or, where a frame's statistics do not carry
    them (a merge of part files), from the stage. A frame whose display points are those of one
    of the frame loop's ``displays`` (`pipeline.display.Displays`, `display.evaluate_run`) takes
    the `Shown` the loop built of them under the same matrix (`SurfaceDisplay.view`), whose
    fingerprint is taken."""
    from dataclasses import replace

    from pipeline import usdio
    from pipeline.display import kept_triangles
    from pipeline.shape import shape_of

    colliders = [_Once(lambda c=c: collider_solid(c.vertices, c.triangles)) for c in scene.colliders]
    meshes: dict = {}  # path -> the run display's triangles, vertex parameters and topology

    def mesh(m) -> tuple[np.ndarray, np.ndarray, object]:
        # built on first need: a frame whose objects are the loop's `Shown`s reads neither
        if m.path not in meshes:
            topo = result.topology(m)
            meshes[m.path] = (kept_triangles(topo), np.stack([topo.u, topo.v], axis=1), topo)
        return meshes[m.path]

    import time

    local_boxes: dict = {}  # id(points) -> (points, object-space box of their float32 values)
    collider_boxes = [bvh.bounds(np.asarray(c.vertices, np.float64)) for c in scene.colliders]
    for st in stats:
        t0 = time.perf_counter()
        xforms = st.xforms
        if not xforms:
            dstates, cstates = usdio.state_at(stage, scene, float(st.frame))
            xforms = {m.path: s.xform for m, s in zip(scene.deformables, dstates)}
            xforms.update({c.path: s.xform for c, s in zip(scene.colliders, cstates)})
        per = result.frames[st.frame]
        # the `Shown` the loop built of each deformable's round display under this frame's matrix
        # (`SurfaceDisplay.view`), with the round display, where the displays hold the surface
        kept = []
        for m in scene.deformables:
            sd = None if displays is None else displays.shown(per[m.path].surface)
            kept.append((sd, None if sd is None else sd.view(m.path, xforms[m.path])))
        boxes = [_display_box(xforms[m.path], per[m.path].points, view if sd is not None and sd.points is per[m.path].points
                              else None, local_boxes) for m, (sd, view) in zip(scene.deformables, kept)]
        boxes += [_outer_box(xforms[c.path], box) for c, box in zip(scene.colliders, collider_boxes)]
        if not _any_meet(np.array(boxes).reshape(-1, 2, 3), len(scene.deformables)):
            # no deformable's display comes near another object: every pair's depth is 0 (`pair_depth`
            # finds no triangle of one in the other's box), so nothing is shown or measured
            st.residual, st.residual_rel = 0.0, 0.0
            names = [m.path for m in scene.deformables]
            others = names + [c.path for c in scene.colliders]
            st.pair_residual_rel = {(a, b): 0.0 for i, a in enumerate(names) for b in others[i + 1:]}
            for m in scene.deformables:
                per[m.path] = replace(per[m.path], residual=0.0)
            ms = 1e3 * (time.perf_counter() - t0)
            st.ms_output += ms
            st.ms_total += ms
            continue
        objects = []
        for m, (sd, like) in zip(scene.deformables, kept):
            r = per[m.path]
            shape = shape_of(r.surface, options.density)
            view = like if sd is not None and sd.points is r.points else None
            # an open object's winding is read by nothing (it is never the outer object)
            same = view is not None and view.closed == shape.closed and (view.outward == shape.outward or not shape.closed)
            if same:
                objects.append(view)
            else:
                triangles, uv, topo = mesh(m)
                # the round's display of this surface, where the run's shows other points: the
                # parts it built may be the run's near the other objects (`_like`)
                objects.append(replace(shown(m.path, r.points, triangles, xforms[m.path], uv, shape.closed, shape.outward,
                                             topology=topo), like=like))
        for c, s in zip(scene.colliders, colliders):
            v = apply_xform(xforms[c.path], c.vertices)
            box = np.stack([v.min(axis=0), v.max(axis=0)])
            objects.append(collider_shown(c.path, box, float(np.linalg.norm(box[1] - box[0])), s(), xforms[c.path]))
        fr = measure_frame(objects, options.tolerance, known=getattr(result, "residuals", {}).get(st.frame))
        st.residual, st.residual_rel = fr.worst, fr.worst_rel
        st.pair_residual_rel = {}
        names = [m.path for m in scene.deformables]
        others = names + [c.path for c in scene.colliders]
        for i, a in enumerate(names):
            for b in others[i + 1:]:
                st.pair_residual_rel[a, b] = fr.pair_rel(a, b)
        for m in scene.deformables:
            per[m.path] = replace(per[m.path], residual=float(fr.by_object.get(m.path, 0.0)))
        ms = 1e3 * (time.perf_counter() - t0)
        st.ms_output += ms
        st.ms_total += ms


def _local_box(kept: dict, points: np.ndarray) -> np.ndarray:
    """The box ``(2, 3)`` of ``points`` rounded to float32 (what `shown` maps), kept by the array
    (a run's frames share the display points of an unchanged surface)."""
    hit = kept.get(id(points))
    if hit is None or hit[0] is not points:
        hit = kept[id(points)] = (points, bvh.bounds(np.asarray(points, np.float32).astype(np.float64)))
    return hit[1]


def _display_box(xform: np.ndarray, points: np.ndarray, view: Shown | None, kept: dict) -> np.ndarray:
    """`_outer_box` of a deformable's run display ``points (n, 3) float64`` (object space) under
    ``xform (4, 4)``; ``view`` is the `Shown` the frame loop built of these points under ``xform``
    (`SurfaceDisplay.view`), or ``None``. Where ``xform``'s linear part is the identity with no
    translation -0.0 (`model.is_translation`), the corners' mapping is the view's world box
    (``box``), not a pass over the points: there each world value is ``x + t``
    (`model.translated`: the products by the identity add only zeros), monotone in ``x`` as the rounding to float32 is, so the least world value is
    the least float32 point's plus ``t``, and neither holds a zero of the other sign (a zero sum
    with ``t``, not -0.0, is +0.0). A box that is not finite (a point that is not finite) takes
    the points' own box (`_local_box`, kept in ``kept``)."""
    if view is not None and is_translation(xform) and all(map(math.isfinite, view.box.ravel().tolist())):
        return _padded(view.box)
    return _outer_box(xform, _local_box(kept, points))


def _outer_box(xform: np.ndarray, box: np.ndarray) -> np.ndarray:
    """A world box ``(2, 3)`` holding every point of the object-space ``box`` mapped by ``xform``
    (`apply_xform`): `_padded` of its 8 corners' images."""
    return _padded(apply_xform(np.asarray(xform, np.float64), _corners(box)))


def _corners(box: np.ndarray) -> np.ndarray:
    """The 8 corners ``(8, 3) float64`` of ``box (2, 3)``."""
    return np.array([[box[i, 0], box[j, 1], box[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])


def _padded(world: np.ndarray) -> np.ndarray:
    """The box ``(2, 3)`` of ``world (m, 3)`` (a box's corners, or a box ``(2, 3)`` itself),
    widened by 1e-9 of its diagonal and of its largest coordinate for the rounding of each
    point's own mapping."""
    lo, hi = world.min(axis=0), world.max(axis=0)
    pad = 1e-9 * (float(np.linalg.norm(hi - lo)) + float(np.abs(world).max())) + 1e-300
    return np.stack([lo - pad, hi + pad])


def _any_meet(boxes: np.ndarray, n: int) -> bool:
    """Whether any of the first ``n`` of ``boxes (m, 2, 3)`` meets another of them: each corner
    of one at most the other's opposite corner (`meshrows.faces_meet_rows`' comparisons), every
    pair at once (a frame of many objects has thousands)."""
    lo, hi = boxes[:, 0], boxes[:, 1]
    meet = np.all(lo[:n, None] <= hi[None], axis=2) & np.all(lo[None] <= hi[:n, None], axis=2)
    meet[np.arange(n), np.arange(n)] = False
    return bool(meet.any())
