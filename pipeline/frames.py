"""The frame loop: detect → respond → detect again, per frame, from the animator's shape.

Each frame starts from the animator's input at that time code (`usdio.state_at`), so frames are
independent and the run is stateless (thesis §2.5 "animator override"), except for a deformable
that carries state across frames (``acra:relax``, ``acra:plasticity``): it starts from the
animator's shape plus what it carried out of the previous frame (`pipeline.state`). Within a
frame the loop iterates: detect every pair, turn each contact into data points (thesis eq. 4.15–4.16), respond
every deformable (`acra.respond.respond`), and detect again, until the residual penetration of
every pair is within tolerance or the iteration cap is reached. A frame whose input is the
previous frame's bit for bit (a hold) takes that frame's answer (`_Run._hold_of`). Transforms are
only read.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
from pxr import Usd

from acra import hspline as H
from acra import respond as R
from acra.controls import Controls, corrective as corrective_controls
from acra.targets import DataPoints, patch_keys, rigidity_share
from acra.interpolate import SystemTooLarge
from pipeline import geometry
from pipeline import contact as C
from pipeline import datapoints as P
from pipeline import detect as D
from pipeline import display
from pipeline import residual
from pipeline import shape as S
from pipeline import state
from pipeline import usdio
from pipeline import workers
from pipeline import output_layer
from pipeline.guard import format_size
from pipeline.model import InputError, SceneModel, apply_inverse

__all__ = ["FrameStats", "RunOptions", "run_frames", "respond_frames"]


@dataclass(frozen=True)
class RunOptions:
    """Frame-loop settings.

    Attributes
    ----------
    iterations : int
        Cap on detect → respond rounds per frame.
    tolerance : float
        Residual penetration accepted, as a fraction of the deformable's size (the smaller of two deformables; contract: 1e-3).
    method : str
        Interpolation solver, ``"direct"`` or ``"blend"`` (iterated Bartels–Beatty).
    density : int
        Collision tessellation: least steps per level-0 patch edge (`geometry.patch_density`).
    memory_budget : int, optional
        Bytes a response's direct solve may hold (`interpolate.dense_bytes`); ``None``: unbounded.
    """

    iterations: int = 4
    tolerance: float = 1e-3
    method: str = "direct"
    density: int = 8
    memory_budget: int | None = None


@dataclass
class FrameStats:
    """What one frame did (for the summary, the plots and the benchmark).

    Times are milliseconds (thesis Fig. 5.2's split): ``ms_setup`` building object-space shape data
    (`shape.Shape`, the analogue of RAPID's initial set-up) wherever a round asks for it,
    ``ms_detect`` detection queries less set-up, ``ms_convert`` contacts to data points less
    set-up, ``ms_respond`` the responses (``ms_respond_by`` per deformable path), ``ms_visible``
    measuring each round's residual where the user looks (`_Run.visible`) less set-up,
    ``ms_output`` the run's display and its residual (`display.finish`);
    ``residual`` is the largest depth of a deformable's display inside another object in world
    units and ``residual_rel`` the largest over that deformable's display diagonal (docs/cli.md,
    *Residual penetration*): the kept round's on its own display during the loop, then the run's
    display's (`display.finish`).
    """

    frame: int
    in_collision: bool = False
    iterations: int = 0
    residual: float = 0.0
    residual_rel: float = 0.0
    ms_setup: float = 0.0
    ms_detect: float = 0.0
    ms_convert: float = 0.0
    ms_respond: float = 0.0
    ms_respond_by: dict = field(default_factory=dict)
    ms_output: float = 0.0
    ms_visible: float = 0.0
    ms_total: float = 0.0
    contacts: list = field(default_factory=list)
    data_points: dict = field(default_factory=dict)  # path -> (from (K, 3), target (K, 3)), world
    xforms: dict = field(default_factory=dict)  # path -> (4, 4) object-to-world, every object
    regions: dict = field(default_factory=dict)
    events: list = field(default_factory=list)
    volume_targets: dict = field(default_factory=dict)  # path -> ("volume" | "area", the animator's display measure)
    pair_residual_rel: dict = field(default_factory=dict)  # (path, other path) -> residual_rel of that pair
    hold: bool = False  # a hold: the frame's input is the previous frame's, bit for bit, and so is its answer (`_Run._hold_of`)


def _respond_bounded(path: str, frame: int, parent: H.HSpline, dp: DataPoints, controls: Controls,
                     options: RunOptions, held: DataPoints | None = None, rcond: float = 1e-4,
                     amplify: float | None = None):
    """`respond.respond` with each direct solve's dense arrays bounded by the run's memory budget.

    How many CVs a contact moves on an absorbing level is known only once the contact is found
    (a fine absorbing level under a wide contact gives thousands), so this bound is checked at the
    solve, before it allocates; going over it refuses the deformable's absorption in one line.
    """
    try:
        return R.respond(parent, dp, controls, method=options.method,
                         det=S.shape_of(parent, options.density).details, max_bytes=options.memory_budget,
                         held=held, rcond=rcond, amplify=amplify)
    except SystemTooLarge as err:
        raise InputError(path, "acra:absorption", (
            f"at frame {frame} the response's solve of {err.points} data points on {err.cvs} CVs would need "
            f"{format_size(err.nbytes)}, over the memory budget of {format_size(err.limit)}; absorb on a coarser "
            f"level or raise --memory-budget")) from None


class _Sizes:
    """Each deformable's size (`geometry.SurfaceGeometry.size`) at the frame's first round, found
    when a pair in contact first reads it: a size is the box of every level-0 patch, which a
    frame whose objects are apart never builds (`detect.apart`)."""

    def __init__(self, geoms: list) -> None:
        self._geoms = list(geoms)

    def __getitem__(self, i: int) -> float:
        return self._geoms[i].size


def _unbuilt(g) -> bool:
    """Whether ``g`` is a surface whose patch boxes are not built (a responded surface the
    rounds have not detected)."""
    return isinstance(g, geometry.SurfaceGeometry) and "hulls" not in g.shape.__dict__


def _inner_box(g) -> tuple[np.ndarray, float] | None:
    """A world box ``(2, 3) float64`` inside the geometry's `bounds` (the union of its world patch
    boxes), and its diagonal, at most `size`. A surface whose patch boxes are not built
    (`_unbuilt`) gives the box of its level-0 CVs mapped by its matrix, shrunk by 1e-9 of the
    mapping's terms: every level-0 CV is one of the 4 x 4 of some level-0 patch's control net
    (`acra.patch_boxes`), so its image lies in that patch's world box ``M c + t ± |M| h`` but for
    rounding of a few units in the last place of those terms (``None`` where the shrinking
    leaves no box). Anything else gives its exact `bounds` and `size`."""
    if not _unbuilt(g):
        return g.bounds, g.size
    m, t = g.xform[:3, :3], g.xform[:3, 3]
    cvs = g.surface.cvs.reshape(-1, 3)
    world = cvs @ m.T + t
    # each coordinate's extremes over its contiguous row of the transposed copies: numpy's
    # reduction over the outer axis of an (n, 3) array walks it three values at a time, 5-10x
    # slower at the ×16 head's 2,496 CVs; a minimum or maximum rounds nothing, so the values
    # are the same whatever the order (a zero's sign aside, which no comparison below sees)
    reach = float(np.abs(t).max() + (np.abs(m) @ np.abs(np.ascontiguousarray(cvs.T)).max(axis=1)).max())
    rows = np.ascontiguousarray(world.T)
    lo, hi = rows.min(axis=1) + 1e-9 * reach, rows.max(axis=1) - 1e-9 * reach
    return (np.stack([lo, hi]), float(np.linalg.norm(hi - lo))) if np.all(lo <= hi) else None


def _measured(ga, gb) -> bool:
    """Whether the residual measures the pair ``ga, gb``: its world boxes meet within the pair's
    padding (``not detect.apart`` and `detect._boxes_overlap` at `detect.pair_pad`). A pair with
    a side whose patch boxes are not built (`_unbuilt`) is first tested on boxes inside each
    side's `bounds` with the padding of their diagonals (`_inner_box`): boxes and padding no
    larger than `_boxes_overlap`'s, so meeting there means meeting there too, and so not
    `apart` either (whose boxes and padding hold those); the patch boxes are then not built
    for it. Only a pair that does not meet there takes the exact test, which also answers every
    other pair (`apart` first: a few products). Rounding at the inner box's faces can only add a
    pair to the measure, never drop one, so the residual is never under-reported."""
    if _unbuilt(ga) or _unbuilt(gb):
        inner = _inner_box(ga), _inner_box(gb)
        if None not in inner:
            (a, da), (b, db) = inner
            if bool(S.overlap(a[0], a[1], b[0], b[1], D._PAD * max(da, db))):
                return True
    return not (D.apart(ga, gb) or not D._boxes_overlap(ga, gb, D.pair_pad(ga, gb)))


def _pairs(n_def: int, n_col: int):
    """Every deformable–deformable pair once and every deformable–collider pair."""
    for i in range(n_def):
        for j in range(i + 1, n_def):
            yield i, ("d", j)
        for j in range(n_col):
            yield i, ("c", j)


def run_frames(
    stage: Usd.Stage,
    scene: SceneModel,
    frames: list[int],
    options: RunOptions = RunOptions(),
    on_frame: Callable[[FrameStats, output_layer.FramesResult], None] | None = None,
    initial: list | None = None,
) -> tuple[output_layer.FramesResult, list[FrameStats]]:
    """Process ``frames`` and return the per-frame results to write and their statistics:
    `respond_frames`, then the run's display and every frame's residual on it
    (`display.finish`). ``on_frame(stats, result)`` is called as each frame's responses are done
    (its display and final residual come after the last frame)."""
    displays = display.Displays(options.density, _kept_displays(scene))
    result, stats = respond_frames(stage, scene, frames, options, on_frame, initial, displays)
    display.finish(stage, scene, result, stats, options, displays)
    return result, stats


def _kept_displays(scene: SceneModel) -> int:
    """How many surfaces' displays the frame loop keeps (`display.Displays`): each deformable's
    animator surface and responded ones of the last frames, which the run's display takes."""
    return 4 * len(scene.deformables) + 4


def respond_frames(
    stage: Usd.Stage,
    scene: SceneModel,
    frames: list[int],
    options: RunOptions = RunOptions(),
    on_frame: Callable[[FrameStats, output_layer.FramesResult], None] | None = None,
    initial: list | None = None,
    displays: display.Displays | None = None,
) -> tuple[output_layer.FramesResult, list[FrameStats]]:
    """Respond every frame of ``frames``: the results' surfaces (points left ``None``, the display
    is chosen from all of them, `display.finish`) and their statistics, whose residual is measured
    on each surface's own display (in ``displays``, which `display.finish` then takes the
    surfaces it holds from; a new `display.Displays` if ``None``).

    A deformable that carries state across frames (`pipeline.state`) starts each frame from the
    animator's shape plus what it carried out of the previous one: ``initial`` (per deformable,
    `acra.relax.Carried` or ``None``) is what it carries into ``frames[0]``; without it, that is
    recomputed from the stage's start (`state.carried_at`).

    BLAS runs single-threaded here: ACRA's systems are small (a Gram matrix per object, K ≲ a few
    hundred), and a threaded OpenBLAS on a busy 2-core machine made a 100×100 ``eigh`` take
    272 ms instead of 1.8 ms (measured; `docs/performance.md`). The limit is set through the
    process's one thread-pool controller (`display._blas`), which scans the loaded libraries once
    rather than at every call.
    """
    with display._blas().limit(limits=1, user_api="blas"):
        return _run_frames(stage, scene, frames, options, on_frame, initial, displays)


@dataclass
class _Round:
    """One detection pass over every pair (`_Run.detect`).

    ``found`` holds ``(i, other, PairContact)`` of the pairs to respond to, ``settled`` per pair the
    world move that counts as done (the tolerance or `MEET` times the pair's size), ``pair_rel``
    each pair's residual over its size, ``worst`` and ``worst_rel`` the largest residual in world
    units and over size, ``unseen_rel`` the largest over size of the pairs whose two insides the
    display measure (`_Run.visible`) does not both take: a pair with a collider (a collider's
    surface is not measured inside the deformable, so one wholly inside a closed deformable
    shows nothing of itself, yet is inside) or with an open surface."""

    found: list
    settled: dict
    pair_rel: dict
    worst: float
    worst_rel: float
    unseen_rel: float = 0.0


REWIND_FRAMES = 10_000  # `contact.rewind`'s ``max_back``: whole frames a rewind steps back at most


@dataclass(frozen=True)
class _Answered:
    """A processed frame: its input (`usdio.state_at`'s deformable and collider states), its
    statistics, its final surfaces (scene order) and its residuals (`residual.known`, ``None``
    if nothing was measured)."""

    frame: int
    dstates: list
    cstates: list
    stats: FrameStats
    surfaces: list
    residuals: object


class _Run:
    """What a run keeps across frames and the steps of one frame.

    Kept across frames: each collider's prepared mesh, the input states by time code (an
    unchanged input surface handed back as the same object, so its object-space `shape.Shape` is
    reused), the display of each distinct surface, each pair's rewinding cache, and the carried
    state (`pipeline.state`), and the last frame's input and answer, which a hold takes
    (`_hold_of`). A frame (`frame`) is rounds of `detect` → `data_points` (eq.
    4.15–4.16) → `respond` until the residual is within tolerance or the cap is reached; the
    round with the least residual where the user looks (`visible`) is kept.
    """

    def __init__(self, stage: Usd.Stage, scene: SceneModel, options: RunOptions, carry,
                 displays: display.Displays | None = None) -> None:
        self.stage, self.scene, self.options, self.carry = stage, scene, options, carry
        self.statics = [geometry.prepare_collider(c) for c in scene.colliders]
        self.defs = scene.deformables
        self.controls = [m.controls for m in self.defs]
        self.caches: dict = {}  # (i, other) -> contact.RewindCache
        self.state_memo: dict = {}
        self.held: dict = {}  # inputs that cannot vary in time, read once (`usdio.state_at`)
        self.canonical: list = [None] * len(self.defs)  # last input surface of each deformable
        self.displays = display.Displays(options.density, _kept_displays(scene)) if displays is None else displays
        self._shown: dict = {}  # (id(surface), world matrix) -> (surface, residual.Shown), most recent last
        self._collider_solids: dict = {}  # collider row -> its inside (`residual.collider_solid`)
        self._depths: dict = {}  # `residual.measure_frame`'s answers by pair of shown objects, most recent last
        self._last: _Answered | None = None  # the frame processed last and what it gave

    def states(self, t: float):
        """``(deformable states, collider states)`` at time code ``t`` (`usdio.state_at`)."""
        if t not in self.state_memo:
            if len(self.state_memo) > 64:
                self.state_memo.clear()
            dstates, cstates = usdio.state_at(self.stage, self.scene, t, self.held)
            for i, s in enumerate(dstates):  # unchanged input CVs: hand back the same surface, so
                c = self.canonical[i]        # its object-space Shape (shape.shape_of) is reused
                if c is s.surface:
                    continue
                if c is not None and np.array_equal(c.cvs, s.surface.cvs):
                    dstates[i] = replace(s, surface=c)
                else:
                    self.canonical[i] = s.surface
            self.state_memo[t] = (dstates, cstates)
        return self.state_memo[t]

    def geometry(self, kind_j, t):
        """The input geometry of a deformable (``("d", j)``) or a collider (``("c", j)``) at ``t``,
        for rewinding the motion."""
        dstates, cstates = self.states(t)
        kind, j = kind_j
        if kind == "d":
            return geometry.SurfaceGeometry(dstates[j].surface, dstates[j].xform, name=self.defs[j].path, density=self.options.density)
        return geometry.ColliderGeometry(self.statics[j], cstates[j].xform)

    def detect(self, frame: int, it: int, geoms: list, cgeoms: list, sizes: list, enabled: list) -> _Round:
        """Detect every pair with an enabled deformable (round ``it`` of ``frame``)."""
        defs, options = self.defs, self.options
        rnd = _Round([], {}, {}, 0.0, 0.0)
        # a pair whose objects' boxes lie apart is found by no test (`C.detect_pair` answers None):
        # every pair's boxes at once
        far = D.apart_all(list(geoms) + list(cgeoms)) if len(geoms) + len(cgeoms) > 2 else None
        for i, other in _pairs(len(defs), len(self.statics)):
            if not enabled[i] and (other[0] == "c" or not enabled[other[1]]):
                continue
            if far is not None and far[i, other[1] if other[0] == "d" else len(geoms) + other[1]]:
                continue
            gb = geoms[other[1]] if other[0] == "d" else cgeoms[other[1]]
            key = (i, other)
            cache = self.caches.setdefault(key, C.RewindCache())
            at = lambda t, i=i, other=other: (self.geometry(("d", i), t), self.geometry(other, t))  # noqa: E731
            # without motion to rewind, the first round picks the way out the whole region
            # needs least; later rounds clear what the response left, each vertex its nearest way
            c = C.detect_pair(geoms[i], gb, float(frame), at, start=float(self.scene.start), cache=cache, whole=it == 0)
            if c is None:
                continue
            # the contract's "object size": the deformable's own (the smaller one of two deformables)
            size = sizes[i] if other[0] == "c" else min(sizes[i], sizes[other[1]])
            rnd.worst = max(rnd.worst, c.penetration)
            rnd.worst_rel = max(rnd.worst_rel, c.penetration / size)
            other_path = defs[other[1]].path if other[0] == "d" else self.scene.colliders[other[1]].path
            rnd.pair_rel[defs[i].path, other_path] = c.penetration / size
            if other[0] == "c" or not (geoms[i].closed and gb.closed):
                rnd.unseen_rel = max(rnd.unseen_rel, c.penetration / size)
            meet = rnd.settled[key] = max(options.tolerance, P.MEET) * size
            if it > 0 and other[0] == "d" and c.region_a.empty != c.region_b.empty and np.linalg.norm(c.push) <= meet:
                c = P.deepest_instead(geoms[i], gb, c)
            if c.penetration > options.tolerance * size or it == 0:
                rnd.found.append((i, other, c))
        return rnd

    def _displays_judge(self, geoms: list, enabled: list) -> bool:
        """Whether every pair `detect` tests is two closed deformables, whose round the displays'
        residual alone judges (`frame`)."""
        for i, other in _pairs(len(self.defs), len(self.statics)):
            if not enabled[i] and (other[0] == "c" or not enabled[other[1]]):
                continue
            if other[0] == "c" or not (geoms[i].closed and geoms[other[1]].closed):
                return False
        return True

    def collider_solid(self, j: int):
        """Collider ``j``'s inside in its object space, built on first use (`residual.collider_solid`,
        kept by the mesh's content for the run's display measure). Where trimesh's processing
        (`geometry.prepare_collider`) left the model's vertices and triangles as they were, byte
        for byte, the detection's solid of the same arrays (`ColliderStatic.solid`, built by the
        same call) is that inside: it is built once a run."""
        if j not in self._collider_solids:
            c, st = self.scene.colliders[j], self.statics[j]
            v, f = np.asarray(c.vertices, np.float64), np.asarray(c.triangles, np.int64)
            mv, mf = np.asarray(st.mesh.vertices, np.float64), np.asarray(st.mesh.faces, np.int64)
            same = v.shape == mv.shape and f.shape == mf.shape and v.tobytes() == mv.tobytes() and f.tobytes() == mf.tobytes()
            self._collider_solids[j] = residual.collider_solid(v, f, built=(lambda: st.solid) if same else None)
        return self._collider_solids[j]



    def visible(self, geoms: list, cgeoms: list, enabled: list, settle: dict | None = None,
                over: bool = False) -> tuple[residual.FrameResidual, dict]:
        """The round's residual where the user looks (`pipeline.residual`): each deformable's own
        adaptive display (`display.Displays`) in every other closed object whose box meets its
        own, for the pairs `detect` tests. Returns it and, per pair ``(i, other)``, the
        `residual.Inside` of ``i`` in ``other`` and (a deformable ``other``) of ``other`` in ``i``.
        ``settle`` (`_settle`) maps ``((i, other), side)`` (``"a"``: ``i`` in ``other``, ``"b"``
        the reverse) to a guess of its depth: those sides are measured only until one shows the
        frame over the tolerance, the deepest guess first, or not at all with ``over``
        (`residual.measure_frame`'s ``settle``)."""
        shown: dict = {}

        def obj(kind: str, j: int) -> residual.Shown:
            if (kind, j) not in shown:
                if kind == "d":
                    g, m = geoms[j], self.defs[j]
                    key = (id(g.surface), g.xform.tobytes())
                    hit = self._shown.pop(key, None)
                    if hit is None or hit[0] is not g.surface:  # a surface shown at this place is reused
                        sd = self.displays.of(g.surface, m.controls.samples)
                        hit = (g.surface, sd.view(m.path, g.xform, lambda: residual.shown(
                            m.path, sd.points, sd.triangles, g.xform, sd.uv, g.closed,
                            g.shape.outward_shown(sd) if g.closed else 1.0, sd.solid, sd.parts, sd.topology)))
                    self._shown[key] = hit
                    while len(self._shown) > 4 * len(self.defs) + 4:
                        del self._shown[next(iter(self._shown))]
                    shown[kind, j] = hit[1]
                else:
                    g = cgeoms[j]
                    shown[kind, j] = residual.collider_shown(g.name, g.bounds, g.size, self.collider_solid(j), g.xform)
            return shown[kind, j]

        index, pairs, keys = {}, [], []
        # `_measured` is False for a pair whose objects' boxes lie apart (its inner boxes lie
        # within those): every pair's boxes at once (`detect.apart_all`)
        far = D.apart_all(list(geoms) + list(cgeoms)) if len(geoms) + len(cgeoms) > 2 else None
        for i, other in _pairs(len(self.defs), len(self.statics)):
            if not enabled[i] and (other[0] == "c" or not enabled[other[1]]):
                continue
            if far is not None and far[i, other[1] if other[0] == "d" else len(geoms) + other[1]]:
                continue
            ga, gb = geoms[i], (geoms[other[1]] if other[0] == "d" else cgeoms[other[1]])
            if not _measured(ga, gb):
                continue
            for kind_j in (("d", i), other):
                if kind_j not in index:
                    index[kind_j] = len(index)
            pairs.append((index["d", i], index[other]))
            keys.append(((i, other), "a"))
            if other[0] == "d":
                pairs.append((index[other], index["d", i]))
                keys.append(((i, other), "b"))
        # the deformables' displays not kept from before, built together (`display.Displays.build`:
        # two side by side), in the order their objects come
        wanted = []
        for kind, j in index:
            if kind == "d":
                hit = self._shown.get((id(geoms[j].surface), geoms[j].xform.tobytes()))
                if hit is None or hit[0] is not geoms[j].surface:
                    wanted.append((geoms[j].surface, self.defs[j].controls.samples))
        if len(wanted) > 1:
            self.displays.build(wanted)
        objects = [obj(*kind_j) for kind_j in index]
        settle = settle or {}
        order = sorted((n for n, ks in enumerate(keys) if ks in settle), key=lambda n: -settle[keys[n]])
        fr = residual.measure_frame(objects, self.options.tolerance, pairs, self._depths, settle=order, over=over)
        while len(self._depths) > 4 * len(pairs) + 4:
            del self._depths[next(iter(self._depths))]
        by_pair: dict = {}
        measured = {(p.a, p.b): p for p in fr.pairs}
        for (ia, ib), (key, side) in zip(pairs, keys):
            p = measured.get((objects[ia].path, objects[ib].path))
            if p is not None:
                by_pair.setdefault(key, {})[side] = p
        return fr, by_pair

    def data_points(self, rnd: _Round, geoms: list, cgeoms: list, sizes: list, enabled: list, surfaces: list,
                    directions: dict, wrapping: set, over: dict | None = None, seen: dict | None = None) -> dict:
        """Eq. 4.15–4.16: each responding deformable's data points for this round's contacts, as
        ``{i: [(DataPoints, world targets (k, 3), world starts (k, 3)), ...]}``. ``directions`` keeps
        each pair's first push of the frame, ``wrapping`` the collider pairs pushed by
        `collider_points_for` (both updated). ``over`` holds, per pair whose display is still over
        the tolerance where the user looks, its `residual.PairDepth` per side (``"a"``: the
        deformable in the other, ``"b"``: the other deformable in it): those sides get
        `visible_points` too."""
        controls = self.controls
        points: dict[int, list] = {}
        seen = {} if seen is None else seen
        for i, other, c in rnd.found:
            gb = geoms[other[1]] if other[0] == "d" else cgeoms[other[1]]
            r_other = None if other[0] == "c" or not enabled[other[1]] else controls[other[1]].rigidity
            if enabled[i]:
                share = rigidity_share(controls[i].rigidity, r_other)
                push = directions.setdefault((i, other), c.push)
                # a collider with vertices inside a closed surface: the wall in front of it is pushed
                # past it along the push, its own region included (`collider_points_for`); every
                # later round of the frame does the same, so the pocket keeps its direction
                wrap = other[0] == "c" and (not c.region_b.empty or (i, other) in wrapping)
                clear = rnd.settled[(i, other)] if wrap else 0.0
                p_other = (c.point_b + c.slide) + clear * push / max(np.linalg.norm(push), 1e-300)
                r_uv, r_depth = P.with_shown(c.region_a, seen.get((i, other), {}).get("a"))
                dp, world, start = P.data_points_for(geoms[i], gb, c.uv_a, c.point_a, p_other, None if wrap else r_uv,
                                                   share, P.group_level(controls[i], surfaces[i].depth), push,
                                                   r_depth, rnd.settled[(i, other)])
                points.setdefault(i, []).append((dp, world, start))
                if wrap:
                    uv, world, start = P.collider_points_for(geoms[i], gb, c.region_a, c.region_b, push, share,
                                                           P.group_level(controls[i], surfaces[i].depth), clear,
                                                           (i, other) not in wrapping)
                    wrapping.add((i, other))
                    keep = P.spread(start, c.point_a, P.MEET * sizes[i])
                    if keep.any():
                        dp = DataPoints(uv[keep], apply_inverse(geoms[i].xform, world[keep]), np.zeros(int(keep.sum()), bool))
                        points[i].append((dp, world[keep], start[keep]))
            if other[0] == "d" and enabled[other[1]]:
                j = other[1]
                share = rigidity_share(controls[j].rigidity, controls[i].rigidity if enabled[i] else None)
                push = -directions.setdefault((i, other), c.push)
                r_uv, r_depth = P.with_shown(c.region_b, seen.get((i, other), {}).get("b"))
                dp, world, start = P.data_points_for(geoms[j], geoms[i], c.uv_b, c.point_b, c.point_a - c.slide, r_uv, share,
                                                   P.group_level(controls[j], surfaces[j].depth), push,
                                                   r_depth, rnd.settled[(i, other)])
                points.setdefault(j, []).append((dp, world, start))
        for (i, other), sides in (over or {}).items():
            for side, pd in sides.items():
                me, them = (("d", i), other) if side == "a" else (other, ("d", i))
                j = me[1]
                if not enabled[j]:
                    continue
                gm, gt = geoms[j], (geoms[them[1]] if them[0] == "d" else cgeoms[them[1]])
                r_them = controls[them[1]].rigidity if them[0] == "d" and enabled[them[1]] else None
                push = directions.get((i, other))
                push = None if push is None else (push if side == "a" else -push)
                clear = P.CLEAR * self.options.tolerance * gm.size
                level = P.group_level(controls[j], surfaces[j].depth)
                local = them[0] == "c" and P.corrects(controls[j], surfaces[j].depth)  # a pair of two deformables keeps eq. 4.15's split by its held contacts
                shown = P.visible_points if local else P.deepest_shown
                uv, world, start = shown(gm, gt, pd.inside, push, rigidity_share(controls[j].rigidity, r_them), level, clear)
                if not len(uv):
                    continue
                # a patch already holding one of detection's points keeps it (two targets in one
                # patch fight in the interpolation, and the surface swings between them from
                # round to round)
                taken = np.concatenate([d.uv for d, _, _ in points.get(j, [])] or [np.zeros((0, 2))])
                keep = ~P.member(patch_keys(gm.surface, uv, level), patch_keys(gm.surface, taken, level))
                keep &= P.spread(start, np.full(3, np.inf), P.MEET * gm.size)
                if keep.any():
                    dp = DataPoints(uv[keep], apply_inverse(gm.xform, world[keep]), np.zeros(int(keep.sum()), bool))
                    points.setdefault(j, []).append((dp, world[keep], start[keep]))
        return points

    def respond(self, frame: int, it: int, st: FrameStats, points: dict, surfaces: list, pins: dict | None = None,
                shared: frozenset = frozenset(), corrective: set = frozenset()) -> None:
        """Respond every deformable with data points (thesis §4.3), replacing its surface in
        ``surfaces``; the first round's data points go to ``st`` for the preview.

        ``pins`` holds, per deformable, the data points of the frame's rounds so far (updated
        here): a later round holds their contact points at the targets they asked (`datapoints.pinned`).
        ``shared`` names the deformables in a pair with another deformable this frame. A deformable
        in ``corrective`` (its points all from `datapoints.visible_points`) gets a corrective
        response: its samples solved as they are, on the finest absorbing level (`corrective`)."""
        pins = {} if pins is None else pins
        for i, lst in points.items():
            t_i = time.perf_counter()
            dp = DataPoints(
                np.concatenate([d.uv for d, _, _ in lst]),
                np.concatenate([d.target for d, _, _ in lst]),
                np.concatenate([d.is_contact for d, _, _ in lst]),
                per_patch=i not in corrective,
            )
            parent = surfaces[i]
            controls = self.controls[i]
            held = None
            if it > 0:
                # a flank point this little shallower than an earlier contact reaches it (`datapoints.pinned`)
                slack = self.options.tolerance * parent.size()
                dp, held = P.pinned(parent, dp, pins.get(i), P.group_level(controls, parent.depth), i in shared, slack)
            pins[i] = dp if held is None else DataPoints(np.concatenate([dp.uv, held.uv]), np.concatenate([dp.target, held.target]),
                                                           np.concatenate([dp.is_contact, held.is_contact]))
            path = self.defs[i].path
            if i in corrective:
                controls = corrective_controls(controls, parent.depth)
            # a corrective round's samples, half a finest patch apart, each ask a few millimetres
            # that differ from the next one's by about as much: its solve drops the weak modes that
            # would amplify their disagreement (`datapoints.CORRECTIVE_RCOND`)
            rcond = P.CORRECTIVE_RCOND if i in corrective else 1e-4
            # a later round asks millimetres of each level, whose exact fit rings through the weak
            # modes: those that move CVs further than a lone point would are dropped
            # (`datapoints.LATER_AMPLIFY`); a pair of two deformables keeps eq. 4.15's split only
            # with its held contacts fitted exactly
            amplify = P.LATER_AMPLIFY if it > 0 and i not in shared else None
            surfaces[i], rep = _respond_bounded(path, frame, parent, dp, controls, self.options, held, rcond, amplify)
            S.seed_details(surfaces[i], rep.details, self.options.density, parent=parent, moved=rep.moved)
            surfaces[i] = self.carry.after_response(i, parent, surfaces[i])
            if it == 0:
                st.data_points[path] = (np.concatenate([o for _, _, o in lst]), np.concatenate([w for _, w, _ in lst]))
            ms = 1e3 * (time.perf_counter() - t_i)
            st.ms_respond += ms
            st.ms_respond_by[path] = st.ms_respond_by.get(path, 0.0) + ms

    def frame(self, frame: int, result: output_layer.FramesResult) -> FrameStats:
        """Process ``frame``: rounds of detect → data points → respond from the animator's shape
        (plus what is carried), keep the round with the least residual, add its display to
        ``result``; return the frame's statistics."""
        defs, options = self.defs, self.options
        t0 = time.perf_counter()
        st = FrameStats(frame)
        dstates, cstates = self.states(float(frame))
        last = self._hold_of(frame, dstates, cstates)
        if last is not None:
            return self._repeat(frame, last, result, t0)
        st.xforms = {m.path: s.xform for m, s in zip(defs, dstates)}
        st.xforms.update({c.path: s.xform for c, s in zip(self.scene.colliders, cstates)})
        surfaces = self.carry.begin(frame, [s.surface for s in dstates])
        enabled = [s.enabled for s in dstates]
        directions: dict = {}
        wrapping: set = set()  # collider pairs pushed by `collider_points_for` this frame
        pins: dict = {}  # deformable -> the data points of the frame's responses so far (`respond`)
        best = (np.inf, list(surfaces))
        kept = None  # the kept round's residual, whose answers `display.finish` takes where it shows the same
        first = None  # the first round's residual and detection's unseen part, while it holds lower bounds only
        rounds = max(1, options.iterations)
        for it in range(rounds + 1):
            setup0 = S.SetupClock.ms
            geoms = [geometry.SurfaceGeometry(surfaces[i], dstates[i].xform, name=defs[i].path, density=options.density) for i in range(len(defs))]
            cgeoms = [geometry.ColliderGeometry(self.statics[j], cstates[j].xform) for j in range(len(self.statics))]
            if it == 0:  # the animator's surfaces: detection's scale stays fixed while rounds reshape them
                sizes = _Sizes(geoms)
            st.ms_setup += S.SetupClock.ms - setup0
            # detection reads nothing of the display measure: on the animator's shapes it runs
            # first, so the measure knows the pairs it found, whose displays need only show the
            # frame over the tolerance (`_settle`)
            rnd = self._detected(st, frame, it, geoms, cgeoms, sizes, enabled) if it == 0 else None
            # the display measure builds the shape data it reads (a responded surface's coarse grid
            # for its orientation; its patch boxes only where `_measured`'s inner boxes do not
            # meet): that is set-up, as it is when detection builds them
            tv, setup1 = time.perf_counter(), S.SetupClock.ms
            vis, by_pair = self.visible(geoms, cgeoms, enabled, *(_settle(rnd, sizes, options.tolerance) if it == 0 else ()))
            st.ms_setup += S.SetupClock.ms - setup1
            st.ms_visible += 1e3 * (time.perf_counter() - tv) - (S.SetupClock.ms - setup1)
            if rnd is None and vis.worst_rel <= options.tolerance and self._displays_judge(geoms, enabled):
                # every pair is judged by its displays alone and they are within the tolerance:
                # this round ends the frame whatever detection would find
                rnd = _Round([], {}, {}, 0.0, 0.0)
            elif rnd is None:
                rnd = self._detected(st, frame, it, geoms, cgeoms, sizes, enabled)
            if it == 0:
                st.in_collision = bool(rnd.found) or vis.worst_rel > options.tolerance  # a pair to respond to
                st.contacts = [(c.point_a, c.point_b) for _, _, c in rnd.found]
                st.regions = {defs[i].path: c.region_a.points for i, _, c in rnd.found}
            # a round is judged by what the user sees: the certified depth of each deformable's
            # display inside the other object of its pair, both ways between two closed
            # deformables; any other pair is also judged by what detection still finds (a
            # collider wholly inside a closed deformable shows nothing of itself, yet is inside)
            score = max(vis.worst_rel, rnd.unseen_rel)
            if first is not None and score > options.tolerance:
                # the first round holds lower bounds over the tolerance: a round within it is kept
                # before it whatever its exact figures, one over it is held against them. Its full
                # score is at least its lower one over `residual.OVER` (a stopped side's full bound
                # is at least its deepest point found but for eq. (6)'s rounding), so a round
                # below that is kept before it too, and the first round is never reported: it
                # needs no full measure
                if not residual.OVER * score < best[0]:
                    kept, best = self._completed(st, first, best)
                first = None
            if score < best[0]:
                best = (score, list(surfaces))
                kept = vis
                self._report(st, vis)
                first = (vis, rnd.unseen_rel) if vis.stopped else None
            # what the user would see still over the tolerance, per pair and side
            over = {key: {side: p for side, p in sides.items() if p.rel > options.tolerance}
                    for key, sides in by_pair.items()}
            over = {key: sides for key, sides in over.items() if sides}
            if (not rnd.found and not over) or score <= options.tolerance or it == rounds:
                break
            tr, setup0 = time.perf_counter(), S.SetupClock.ms
            # The first round is eq. 4.15-4.16 on detection's regions alone: it gives the
            # response its look. Where the display is still over the tolerance afterwards, a
            # later round joins the display's own points inside the other object to the pair's
            # regions (`P.with_shown`); a pair detection finds clear, or misses, while its display
            # is over gets points from the display alone (`visible_points`); a deformable whose
            # points all come from there only corrects what the earlier rounds left, locally
            # (`corrective`), unless its finest absorbing level translates or rotates
            # (`P.corrects`: the display's deepest point per patch, `P.deepest_shown`).
            found = {(i, other) for i, other, _ in rnd.found}
            seen = {key: by_pair[key] for key in over if it > 0 and key in found}
            over = {key: sides for key, sides in over.items() if key not in found}
            points = self.data_points(rnd, geoms, cgeoms, sizes, enabled, surfaces, directions, wrapping, over, seen)
            detected = {i for i, _, _ in rnd.found} | {o[1] for _, o, _ in rnd.found if o[0] == "d"}
            detected |= {i for i in points if not P.corrects(self.controls[i], surfaces[i].depth)}
            st.ms_setup += S.SetupClock.ms - setup0
            st.ms_convert += 1e3 * (time.perf_counter() - tr) - (S.SetupClock.ms - setup0)
            # deformables in a pair with another deformable: their earlier contacts hold eq. 4.15's split
            shared = frozenset(k for (i, other) in directions if other[0] == "d" for k in (i, other[1]))
            self.respond(frame, it, st, points, surfaces, pins, shared, set(points) - detected - shared)
            st.iterations = it + 1
        if first is not None:  # the first round kept: its figures are reported, so measured in full
            kept, best = self._completed(st, first, best)
        surfaces = best[1]
        if kept is not None:
            result.residuals[frame] = residual.known(kept, options.tolerance)
        carried = self.carry.end(frame, surfaces)
        st.volume_targets = self.carry.volume_targets()
        for i, model in enumerate(defs):  # the display is the run's, chosen after every frame (`display.finish`)
            result.add(frame, model.path, output_layer.DeformableResult(None, None, surfaces[i], st.residual, st.in_collision, carried[i]))
        self._last = _Answered(frame, dstates, cstates, st, surfaces, result.residuals.get(frame))
        st.ms_total = 1e3 * (time.perf_counter() - t0)
        return st

    def _detected(self, st: FrameStats, frame: int, it: int, geoms: list, cgeoms: list, sizes, enabled: list) -> _Round:
        """`detect`, its time and the set-up it triggers counted in ``st``."""
        td, setup0 = time.perf_counter(), S.SetupClock.ms
        rnd = self.detect(frame, it, geoms, cgeoms, sizes, enabled)
        st.ms_setup += S.SetupClock.ms - setup0
        st.ms_detect += 1e3 * (time.perf_counter() - td) - (S.SetupClock.ms - setup0)
        return rnd

    def _report(self, st: FrameStats, vis: residual.FrameResidual) -> None:
        """The kept round's residual ``vis`` into ``st``: the worst, and each pair's."""
        defs = self.defs
        st.residual, st.residual_rel = vis.worst, vis.worst_rel
        st.pair_residual_rel = {(defs[i].path, self._name(other)): vis.pair_rel(defs[i].path, self._name(other))
                                for i, other in _pairs(len(defs), len(self.statics))}

    def _completed(self, st: FrameStats, first: tuple, best: tuple) -> tuple[residual.FrameResidual, tuple]:
        """The first round's residual measured in full (`residual.complete`, ``first`` its lower
        bounds and detection's unseen part), reported in ``st``, and ``best`` with its score."""
        vis, unseen = first
        t0, setup0 = time.perf_counter(), S.SetupClock.ms
        vis = residual.complete(vis, self.options.tolerance, self._depths)
        st.ms_setup += S.SetupClock.ms - setup0
        st.ms_visible += 1e3 * (time.perf_counter() - t0) - (S.SetupClock.ms - setup0)
        self._report(st, vis)
        return vis, (max(vis.worst_rel, unseen), best[1])

    def _hold_of(self, frame: int, dstates: list, cstates: list) -> _Answered | None:
        """The previous frame's answer where ``frame`` holds it: ``frame`` follows that frame directly and
        its input is that frame's bit for bit (each deformable's surface, matrix and
        ``acra:enabled``, each collider's matrix), and nothing carries state across frames.

        A frame is a function of its input and of the contact rewinding (`contact.rewind`), which
        reads the input at earlier times: from a hold it steps back one more whole frame,
        through the previous frame's identical input, to the same last free time and the same
        first touch, and the slide since it (`contact.slide_since`) reads the same two times'
        input. So every round gives what the previous frame's gave, and the hold takes its
        answer. A rewind that would step back more than `REWIND_FRAMES` frames is not assumed."""
        last = self._last
        if (last is None or last.frame != frame - 1 or self.carry.active
                or frame - self.scene.start >= REWIND_FRAMES):
            return None
        for a, b in zip(last.dstates, dstates):
            # the animator's hierarchy does not vary in time (`states`): equal level-0 CVs are the
            # same surface, whether or not `states` handed back the same object
            same = a.surface is b.surface or np.array_equal(a.surface.cvs, b.surface.cvs)
            if not same or a.enabled != b.enabled or a.xform.tobytes() != b.xform.tobytes():
                return None
        for a, b in zip(last.cstates, cstates):
            if a.xform.tobytes() != b.xform.tobytes():
                return None
        return last

    def _repeat(self, frame: int, last: _Answered, result: output_layer.FramesResult, t0: float) -> FrameStats:
        """``frame``'s statistics and results: the answer ``last`` of the frame it holds (`_hold_of`)."""
        was = last.stats
        st = replace(was, frame=frame, hold=True, ms_setup=0.0, ms_detect=0.0, ms_convert=0.0, ms_respond=0.0,
                     ms_respond_by={}, ms_output=0.0, ms_visible=0.0, contacts=list(was.contacts),
                     data_points=dict(was.data_points), xforms=dict(was.xforms), regions=dict(was.regions),
                     events=list(was.events), volume_targets=dict(was.volume_targets),
                     pair_residual_rel=dict(was.pair_residual_rel))
        if last.residuals is not None:
            result.residuals[frame] = last.residuals
        for i, model in enumerate(self.defs):
            result.add(frame, model.path, output_layer.DeformableResult(None, None, last.surfaces[i], st.residual, st.in_collision, None))
        self._last = replace(last, frame=frame)
        st.ms_total = 1e3 * (time.perf_counter() - t0)
        return st

    def _name(self, other: tuple) -> str:
        """Prim path of ``("d", j)`` or ``("c", j)``."""
        return self.defs[other[1]].path if other[0] == "d" else self.scene.colliders[other[1]].path


def _settle(rnd: _Round, sizes, tolerance: float) -> tuple[dict, bool]:
    """`_Run.visible`'s ``settle`` and ``over`` for the first round, detection's ``rnd``: the sides
    of the pairs it found, each guessed as deep as its deepest region vertex over its inner
    object's size; ``over`` where detection alone shows the frame over the tolerance (a pair
    the displays do not judge, `_Round.unseen_rel`).

    At the animator's shapes a pair detection found is responded to whatever its display shows
    (`_Run.frame` leaves it out of the display's own data points), so its display's figure is
    read only as the round's score, and the round's score only against the tolerance (to end
    the frame) and against a later round's (to keep the better): one point deeper than the
    tolerance settles the first, and a later round within the tolerance is kept before it
    whatever its exact figure; `_Run.frame` measures the rest where a later round is over the
    tolerance, or the first round is kept. Nothing is settled where detection found no pair."""
    if not rnd.found:
        return {}, False
    settle: dict = {}
    for i, other, c in rnd.found:
        settle[(i, other), "a"] = c.region_a.max_depth / sizes[i]
        if other[0] == "d":
            settle[(i, other), "b"] = c.region_b.max_depth / sizes[other[1]]
    return settle, rnd.unseen_rel > tolerance


def _run_frames(stage, scene, frames, options, on_frame, initial=None, displays=None):
    run = _Run(stage, scene, options, state.for_run(stage, scene, frames, options, initial), displays)
    result = output_layer.FramesResult()
    stats: list[FrameStats] = []
    # the frames' second calls side by side go to one parked thread, ended with the loop (or
    # with the run around it, `pipeline.run.run_file`)
    with workers.kept():
        for frame in frames:
            stats.append(run.frame(frame, result))
            if on_frame is not None:
                on_frame(stats[-1], result)
    return result, stats
