"""The display a USD client shows: one tessellation per deformable for the whole run, and every
frame's points and normals on it (contract §1).

A response refines a surface where it dents it, so the levels an object uses differ from frame to
frame. The display must show every level at every frame with one topology for the run, so it is
chosen after the responses: `run_topologies` takes, per deformable, the adaptive tessellation
(`acra.tessellate.run_topology`) of the union of every frame's refinement, ``acra:samples`` steps
per edge of the finest patch present at each place. `evaluate_run` then evaluates each distinct
surface of the run on it: the first in full, each later one only on the cells where it differs
from the surface evaluated before it (`acra.hspline.changed_cells`: its CVs and detail vectors
compared), which a response keeps local. Every vertex is evaluated on its own, so an
incremental evaluation equals a full one bit for bit.

The frame loop (`pipeline.frames`) leaves the results' points empty; the run (`pipeline.run`),
the farm's client (`pipeline.farm`) and a merge of part files (`pipeline.parts`) call
`finish`, which evaluates the display and measures every frame's residual on it
(`pipeline.residual`), the figure the summary, the report, the preview and the exit status use.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from threadpoolctl import ThreadpoolController

from acra import hspline, memo
from acra.tessellate import MeshTopology, grid_samples, held_notes, note_held, pole_normals, run_topology
from pipeline.model import SceneModel

__all__ = ["run_topologies", "evaluate_run", "finish", "kept_triangles", "surface_details", "SurfaceDisplay", "Displays"]


def surface_details(surface: hspline.HSpline, density: int = 8) -> hspline.Details | None:
    """The level details of ``surface`` (``None`` for one level): its `pipeline.shape.Shape`'s,
    which a response seeds, so a responded surface's are not computed again."""
    from pipeline.shape import shape_of

    return shape_of(surface, density).details


def _distinct(result, path: str) -> list[hspline.HSpline]:
    """The distinct surface objects of deformable ``path`` over the run's frames, in frame order."""
    seen: dict = {}
    for f in sorted(result.frames):
        s = result.frames[f][path].surface
        seen.setdefault(id(s), s)
    return list(seen.values())


def run_topologies(scene: SceneModel, result) -> dict[str, MeshTopology]:
    """Per deformable path, the display topology of the run: `run_topology` of every frame's
    surface at the deformable's ``acra:samples`` (the one a round displayed, where the union of
    the run's refinements is a refinement a round showed: `_topology`)."""
    out = {}
    for m in scene.deformables:
        surfaces = _distinct(result, m.path)
        out[m.path] = topology_of(surfaces, m.controls.samples)
    return out


def topology_of(surfaces: list, samples: int) -> MeshTopology:
    """`run_topology` of one object's ``surfaces`` at ``samples``, through the kept topologies
    (`_topology`): the rest display a scene's reading builds is the one the frame loop's rounds
    and the run's display get for the same refinement."""
    return _topology(_refinement(surfaces, samples), lambda: run_topology(surfaces, samples))[0]


KEPT_TOPOLOGIES = 16
_TOPOLOGIES = memo.Table("display.topologies", KEPT_TOPOLOGIES)  # `_refinement` key -> (topology, its triangles), most recent last


def _topology(key: tuple, build) -> tuple[MeshTopology, np.ndarray]:
    """The topology of the refinement ``key`` (`_refinement`) and its fan triangles, ``build()``
    where none of the last `KEPT_TOPOLOGIES` asked for was of it. `run_topology` is a function
    of the key alone, so the rounds of a frame, the frames of a contact and the run's display
    (`run_topologies`) that refine the same patches share one."""
    def built():
        topo = build()
        return topo, topo.triangles()
    return _TOPOLOGIES.kept(key, built)


def kept_triangles(topo: MeshTopology) -> np.ndarray:
    """The fan triangles ``(t, 3) int64`` of ``topo``: those `_topology` keeps with it, else
    ``topo.triangles()`` (the run's display is a topology a round built, its triangles taken then)."""
    for kept, triangles in _TOPOLOGIES.values():
        if kept is topo:
            return triangles
    return topo.triangles()


def evaluate_run(scene: SceneModel, result, topologies: dict[str, MeshTopology], density: int = 8,
                 displays: Displays | None = None, spent: bool = False) -> dict[int, float]:
    """Evaluate every frame's surfaces on ``topologies`` into ``result`` (its points and normals,
    object space), and set ``result.topologies``. Returns the milliseconds spent per frame (a
    surface's evaluation is charged to the first frame that shows it).

    A surface the frame loop's ``displays`` still holds (`Displays.shown`) is not evaluated
    again: on the same topology (`_same_topology`) its display's points and limit normals are
    the run's; on another topology (the run's refines a round's where another frame's response
    refined more) only the vertices that display lacks are evaluated
    (`acra.tessellate.grid_samples` since it, no cell changed). A surface the displays do not
    hold has its normals taken only where it differs from the surface before it, the others
    copied. With ``spent`` (no display is read again: `finish`, at the end of the frame loop), a
    display on the run's topology has its limit normals written over by the display normals
    (`pole_normals` in place), which spares a copy of the display; without it they stay whole."""
    ms: dict[int, float] = {f: 0.0 for f in result.frames}
    matches: dict = {}  # `grid_samples`' matches: each vertex's cells on a topology, shared by its frames
    for model in scene.deformables:
        topo = topologies[model.path]
        done: dict = {}  # id(surface) -> (surface, points, normals, limit normals or None)
        last = None
        order = sorted(result.frames)
        # a surface's limit normals are read again only where the next frame shows another surface
        # the displays do not hold (`since`); elsewhere the display normals overwrite them
        read_again = set()
        for f, g in zip(order, order[1:]):
            a, b = result.frames[f][model.path].surface, result.frames[g][model.path].surface
            if b is not a and (displays is None or displays.shown(b) is None):
                read_again.add(id(a))
        for f in order:
            r = result.frames[f][model.path]
            hit = done.get(id(r.surface))
            if hit is None or hit[0] is not r.surface:
                t0 = time.perf_counter()
                det = surface_details(r.surface, density)
                shown = None if displays is None else displays.shown(r.surface)
                since = None if last is None or shown is not None else (last[1], last[3], hspline.changed_cells(
                    last[0], surface_details(last[0], density), r.surface, det, _cell_level(r.surface)))
                if since is not None and since[2].all():
                    since = None
                if shown is not None and _same_topology(shown.topology, topo):
                    pts, limit = shown.points, shown.normals
                elif shown is not None:
                    # every vertex of both is an exact surface point: those at the display's
                    # parameters are copied with their limit normals, the others evaluated
                    unchanged = np.zeros((r.surface.u.patches0, r.surface.v.patches0), bool)
                    pts, limit = grid_samples(r.surface, topo, det, (shown.topology, shown.points, shown.normals,
                                                                     unchanged), matches)
                else:
                    pts, limit = grid_samples(r.surface, topo, det, since, matches)
                kept = id(r.surface) in read_again
                # a display's own limit normals stay whole while a later round's display may be
                # evaluated since it
                own = spent or shown is None or limit is not shown.normals
                normals = pole_normals(r.surface, topo, pts, limit, in_place=own and not kept)
                hit = done[id(r.surface)] = (r.surface, pts, normals, limit if kept else None)
                ms[f] += 1e3 * (time.perf_counter() - t0)
            last = hit
            result.frames[f][model.path] = replace(r, points=hit[1], normals=hit[2])
    result.topologies = dict(topologies)
    return ms


def _same_topology(a: MeshTopology, b: MeshTopology) -> bool:
    """Whether ``a`` and ``b`` hold the same vertex parameters and faces: the same object, or two
    with one `MeshTopology.key` (`acra.lattice.adaptive_mesh` is a function of the leaves the key
    digests; a round's refinement and the run's union of them name different patch keys where
    finer patches cover them, and so build two topologies of the same leaves). A display on
    either then holds the run display's vertices in its rows: its points are the run's, not a
    copy of every row through `grid_samples`, and the run's residual reads the `Shown` the frame
    loop built of them (`pipeline.residual.measure_run`)."""
    key = getattr(a, "key", None)
    return a is b or (key is not None and key == getattr(b, "key", None))


def finish(stage, scene: SceneModel, result, stats: list, options, displays: Displays | None = None) -> None:
    """Choose the run's display topology, evaluate every frame on it, and measure every frame's
    residual where the user looks (`pipeline.residual.measure_run`): ``stats`` (the frames'
    `frames.FrameStats`, in any order) and the results' residuals are set to what the output
    shows. ``options`` is the run's `frames.RunOptions` (its tolerance); ``displays`` the frame
    loop's (`evaluate_run` takes the surfaces they hold from them)."""
    from pipeline import residual

    # BLAS on one thread, as in the frame loop (`frames.respond_frames`): the run's display and its
    # residual call it on small arrays only, and a threaded OpenBLAS leaves its workers spinning
    # on the second core after a call, where the output layer's writing that follows runs
    with _blas().limit(limits=1, user_api="blas"):
        ms = evaluate_run(scene, result, run_topologies(scene, result), options.density, displays, spent=True)
        residual.measure_run(stage, scene, result, stats, options, displays)
    for st in stats:
        st.ms_output += ms.get(st.frame, 0.0)
        st.ms_total += ms.get(st.frame, 0.0)


_CONTROLLER: list = []  # the process's `threadpoolctl.ThreadpoolController`, built at its first use


def _blas() -> ThreadpoolController:
    """The process's thread-pool controller, built once, which the frame loop
    (`frames.respond_frames`) and `finish` both limit BLAS through: building one scans every
    loaded library for a BLAS (0.25 ms CPU on this machine with USD's libraries loaded), where
    the limit it then sets takes 0.01 ms. It is built after importing `pipeline.residual`, whose
    imports load scipy.linalg, so both BLAS libraries the process has (numpy's and scipy's
    OpenBLAS) are loaded by the first scan."""
    if not _CONTROLLER:
        from pipeline import residual  # noqa: F401  (its imports load scipy's BLAS before the scan)

        _CONTROLLER.append(ThreadpoolController())
    return _CONTROLLER[0]


VIEWS_KEPT = 1  # `SurfaceDisplay.view`s kept per display: the rounds of a frame show a surface under one
# matrix, and an unchanged surface moved from frame to frame would otherwise keep a world copy per frame


class SurfaceDisplay:
    """One surface's own adaptive display (`acra.tessellate.run_topology` of the surface alone):
    ``topology``, object-space ``points (n, 3) float64`` and limit unit ``normals (n, 3)
    float64`` (`acra.hspline.surface_normals`', before a pole's are shared: taken beside the
    points where they are evaluated and copied with them elsewhere, they spare the run's display
    a pass over every vertex's derivatives, `evaluate_run`), and, built on first use, its fan
    ``triangles (t, 3) int64`` and its inside, ``solid()`` (`_Inside`)."""

    def __init__(self, surface: hspline.HSpline, topology: MeshTopology, points: np.ndarray, normals: np.ndarray,
                 triangles: np.ndarray | None = None, details: hspline.Details | None = None):
        self.surface, self.topology, self.points, self.normals = surface, topology, points, normals
        self.details = details  # the details the points were evaluated with (`Displays.of`)
        self.solid = _Inside(points, topology, triangles)
        self._uv = None
        self.parts: dict = {}  # `pipeline.residual`'s part solids of this display, by their face rows
        self._views: dict = {}  # (path, world matrix bytes) -> `pipeline.residual.Shown`, most recent last

    def view(self, path: str, xform: np.ndarray, build=None):
        """The `pipeline.residual.Shown` of this display as ``path`` under the world matrix
        ``xform (4, 4)``: one kept from before (the frame loop's rounds build them; the run's
        residual, `pipeline.residual.measure_run`, takes them where the run shows these points,
        their fingerprints taken), else ``build()`` kept (``None`` without ``build``)."""
        key = (path, np.ascontiguousarray(xform, np.float64).tobytes())
        hit = self._views.pop(key, None)
        if hit is None and build is not None:
            hit = build()
        if hit is not None:
            self._views[key] = hit
            while len(self._views) > VIEWS_KEPT:
                del self._views[next(iter(self._views))]
        return hit

    @property
    def triangles(self) -> np.ndarray:
        return self.solid.fan()

    @property
    def uv(self) -> np.ndarray:
        """Parameters ``(n, 2) float64`` of the vertices: the topology's one array
        (`acra.tessellate.MeshTopology.uv`), so its digest, `pipeline.residual.Shown.fingerprint`,
        is taken once for every display on it."""
        if self._uv is None:
            kept = getattr(self.topology, "uv", None)
            self._uv = kept if kept is not None else np.stack([self.topology.u, self.topology.v], axis=1)
        return self._uv


class _Inside:
    """A display's inside as the output stores it (float32 points), for a closed surface: called,
    `pipeline.clearance.Solid` of the display's ``points (n, 3) float64`` and fan ``triangles (t,
    3) int64`` (``topology.triangles()`` where none were given), built on the first call and kept.

    It holds the display's arrays, not the display: the `pipeline.residual.Shown` a display keeps
    (`SurfaceDisplay.view`) holds it as its ``whole``, and a reference back to the display would
    make a cycle, which frees a dropped display's arrays only at the cyclic collector's next pass:
    meanwhile every new display takes new memory (about 25 MB more resident after each repeat of
    `benchmarks/display_split.py`'s frames, about 850 page faults a collision frame more)."""

    __slots__ = ("points", "solid", "topology", "triangles")

    def __init__(self, points: np.ndarray, topology: MeshTopology, triangles: np.ndarray | None) -> None:
        self.points, self.topology, self.triangles, self.solid = points, topology, triangles, None

    def fan(self) -> np.ndarray:
        """The display's fan triangles ``(t, 3) int64``, built on first use."""
        if self.triangles is None:
            self.triangles = self.topology.triangles()
        return self.triangles

    def __call__(self):
        if self.solid is None:
            from pipeline import clearance

            self.solid = clearance.solid(np.asarray(self.points, np.float32).astype(np.float64), self.fan())
        return self.solid


class Displays:
    """The displays the frame loop measures the residual on, one per surface (`SurfaceDisplay`), kept for
    the last ``kept`` surfaces. A responded surface is evaluated only where it differs from the
    display it is evaluated since (`_nearest`: its nearest displayed ancestor, the surface it was
    responded from through `pipeline.shape.Shape.parent`, or where that display is on a coarser
    topology, the last on its own of a surface with its level-0 CVs): the cells `acra.hspline.changed_cells` finds, on the
    topology its refinement gives (`acra.tessellate.grid_samples` with another topology)."""

    def __init__(self, density: int = 8, kept: int = 16) -> None:
        self.density, self.kept = density, kept
        self._shown: dict = {}  # id(surface) -> SurfaceDisplay, most recent last
        self._matches: dict = {}  # `grid_samples`' matches over the kept topologies

    def topology(self, surface: hspline.HSpline, samples: int) -> tuple[MeshTopology, np.ndarray]:
        """`run_topology` of ``surface`` alone and its fan triangles (`_topology`: a surface whose
        response refined the same patches as one shown before gets that one's)."""
        if len(self._matches) > 4 * self.kept:
            self._matches.clear()
        return _topology(_refinement([surface], samples), lambda: run_topology([surface], samples))

    def of(self, surface: hspline.HSpline, samples: int) -> SurfaceDisplay:
        """`SurfaceDisplay` of ``surface`` at ``samples`` steps per finest patch edge."""
        return self.build([(surface, samples)])[0]

    def build(self, wanted: list) -> list[SurfaceDisplay]:
        """`of` of each ``(surface, samples)`` of ``wanted``, in order: the same displays, and
        the same tables after, as those calls one after the other, with two displays' topologies
        and evaluations built side by side (`pipeline.workers.both`) where neither needs the
        other (a round's two deformables).

        Each display is planned in the caller's thread, in order (`_plan`: the kept topology,
        the display it is evaluated since, its changed cells), its place in the tables taken by
        a `_Pending` (`_TOPOLOGIES`, ``_shown``, so each later plan reads them as it would after
        the calls before it), and built (`_build`) from what its plan found: a build writes no
        shared table. Each build is then committed in order (`_commit`): its topology and
        display into their places, its matches and nudged rows added. A display planned since
        another's, or on another's new topology, is built after that one is committed, all of
        them in order in the caller's thread."""
        plans: list = []
        todo: list = []  # the plans that build a display, in order
        done = 0  # of them committed
        try:
            for surface, samples in wanted:
                plans.append(self._plan(surface, samples))
                if plans[-1].display is None:
                    todo.append(plans[-1])
            if len(todo) >= 2 and not any(isinstance(p.old, _Pending) or p.topology is not p and
                                          isinstance(p.topology, _Pending) for p in todo):
                from pipeline.workers import both

                both(lambda: [self._build(p) for p in todo[0::2]], lambda: [self._build(p) for p in todo[1::2]])
                for p in todo:
                    self._commit(p)
                    done += 1
            else:
                for p in todo:
                    self._build(p)
                    self._commit(p)
                    done += 1
        except BaseException:  # no stand-in is left in the tables
            for p in todo[done:]:
                self._drop(p)
            raise
        return [p.display.display if isinstance(p.display, _Pending) else p.display for p in plans]

    def _plan(self, surface: hspline.HSpline, samples: int) -> _Pending:
        """What `of` finds in the tables for ``surface``, in its order: a kept display (the
        plan's ``display``), else its topology (kept, or to build), its shape's details, the
        display it is evaluated since and the cells changed since it; the plan stands in
        ``_shown`` and, for a new topology, in `_TOPOLOGIES` until committed."""
        from pipeline.shape import shape_of

        hit = self._shown.pop(id(surface), None)
        if hit is not None and hit.surface is surface:
            self._keep(surface, hit)
            return _Pending(surface, samples, display=hit)
        p = _Pending(surface, samples)
        p.key = _refinement([surface], samples)
        kept = _TOPOLOGIES.kept(p.key, lambda: (p, None))
        p.topology, p.triangles = kept  # a `_Pending` where a plan builds it (``p`` itself: this one)
        try:
            shape = shape_of(surface, self.density)
            p.details = shape.details
            p.old = self._nearest(shape, p.topology)
            if p.old is not None:
                p.stale = hspline.changed_cells(p.old.surface, p.old.details, surface, p.details, _cell_level(surface))
        except BaseException:
            self._drop(p)
            raise
        self._keep(surface, p)
        return p

    def _build(self, p: _Pending) -> None:
        """Build plan ``p``'s topology (where it builds one) and display, reading the shared
        tables only: the matches it reads or makes go to ``p.matches``, its nudged rows to
        ``p.notes`` (`acra.tessellate.held_notes`)."""
        if p.topology is p:
            topo = run_topology([p.surface], p.samples)
            p.built = (topo, topo.triangles())
        else:
            p.built = (p.topology.built if isinstance(p.topology, _Pending) else (p.topology, p.triangles))
        topo, triangles = p.built
        old = p.old.display if isinstance(p.old, _Pending) else p.old
        since = None
        if old is not None and not p.stale.all():
            since = (old.topology, old.points, old.normals, p.stale)
        p.matches = _Matches(self._matches)
        with held_notes() as p.notes:
            pts, limit = grid_samples(p.surface, topo, p.details, since, p.matches)
        p.display = SurfaceDisplay(p.surface, topo, pts, limit, triangles, p.details)

    def _commit(self, p: _Pending) -> None:
        """Put built plan ``p`` where it stood: its topology in `_TOPOLOGIES`, its display in
        ``_shown`` (each unless a later plan evicted it, as that plan's call would have), its
        matches in the kept matches (emptied first past ``4 * kept``, as before each display
        is evaluated) and its nudged rows in `acra.tessellate`'s table."""
        entries = _TOPOLOGIES.entries()
        if p.topology is p and p.key in entries and entries[p.key][0] is p:
            entries[p.key] = p.built
        if self._shown.get(id(p.surface)) is p:
            self._shown[id(p.surface)] = p.display
        if len(self._matches) > 4 * self.kept:
            self._matches.clear()
        self._matches.update(p.matches)
        note_held(p.notes)
        # a plan that builds its topology stands for it (``p.topology is p``): a cycle, which would
        # keep the display it was evaluated since until the cyclic collector's next pass
        p.topology, p.old, p.matches, p.notes = p.built[0], None, None, None

    def _drop(self, p: _Pending) -> None:
        """Take uncommitted plan ``p`` out of the tables (a build raised)."""
        entries = _TOPOLOGIES.entries()
        if p.key is not None and p.key in entries and entries[p.key][0] is p:
            del entries[p.key]
        if self._shown.get(id(p.surface)) is p:
            del self._shown[id(p.surface)]
        p.topology = p.old = None

    def _keep(self, surface: hspline.HSpline, shown) -> None:
        """``shown`` (a display or a plan) as ``surface``'s, the most recent; the last ``kept``."""
        self._shown[id(surface)] = shown
        while len(self._shown) > self.kept:
            del self._shown[next(iter(self._shown))]

    def shown(self, surface: hspline.HSpline) -> SurfaceDisplay | None:
        """The display of ``surface`` kept from `of`, else ``None`` (nothing is evaluated)."""
        hit = self._shown.get(id(surface))
        return hit if hit is not None and hit.surface is surface else None

    def _nearest(self, shape, topo: MeshTopology | None = None) -> SurfaceDisplay | None:
        """The display to evaluate ``shape``'s surface since: its nearest displayed ancestor
        (`pipeline.shape.Shape.parent`: the surface a response started from) where that display
        is on the surface's own topology ``topo``; else the last display on ``topo`` of a surface
        with the same level-0 CVs (bit for bit); else the ancestor's display on another topology;
        else the last display of a surface on the same grid (a frame's start that has no parent,
        the animator's surface after the last frame's response). Any is exact (`changed_cells`
        compares the two); a near one differs on few cells.

        The second is the response of the frame before where a contact is held and the animator
        moves no level-0 CV (only the object's transform): the responses of two such frames
        differ where their data points do, and on one topology each vertex is copied from the one
        at its own row, where the ancestor (the animator's surface, displayed on a coarser
        topology) differs by the whole response and is matched vertex by vertex. An ancestor on
        the same topology (a later round's response from an earlier round's) comes first: it
        differs by one response alone."""
        hs = shape.surface
        ancestor = None
        up = shape
        while up.parent is not None and ancestor is None:
            up = up.parent
            old = self._shown.get(id(up.surface))
            if old is not None and old.surface is up.surface:
                ancestor = old
        if topo is not None and (ancestor is None or ancestor.topology is not topo):
            for old in reversed(self._shown.values()):
                if old.topology is topo and _same_level0(old.surface, hs):
                    return old
        if ancestor is not None:
            return ancestor
        for old in reversed(self._shown.values()):
            if (old.surface.u, old.surface.v, old.surface.depth) == (hs.u, hs.v, hs.depth):
                return old
        return None


class _Pending:
    """A display `Displays.build` planned: its ``surface`` and ``samples``; the kept
    ``display`` (a `SurfaceDisplay`, or the plan of the same surface before it), else what its
    plan found: its ``topology`` (a `MeshTopology` with its fan ``triangles``, or the `_Pending`
    that builds it, itself where it does), its shape's ``details``, the display ``old`` it is
    evaluated since (or a `_Pending`, or None) and the cells ``stale`` changed since it
    (`hspline.changed_cells`); once built, ``built`` (its topology and triangles), its
    ``display``, the ``matches`` its evaluation read or made and its nudged rows ``notes``. It
    stands in the tables for its display until committed, with the ``surface``, ``details`` and
    ``topology`` `Displays._nearest` reads of one."""

    __slots__ = ("surface", "samples", "display", "key", "topology", "triangles", "details", "old", "stale",
                 "built", "matches", "notes")

    def __init__(self, surface: hspline.HSpline, samples: int, display=None) -> None:
        self.surface, self.samples, self.display = surface, samples, display
        self.key = self.topology = self.triangles = self.details = self.old = self.stale = None
        self.built = self.matches = self.notes = None


class _Matches(dict):
    """`grid_samples`' matches as one build sees them: ``kept``'s (the `Displays`' shared ones)
    read, each entry the build reads or makes recorded in itself in that order, which
    `Displays._commit` adds to ``kept`` after: ``kept`` then holds what it would hold had the
    build used it, and the build writes no shared table."""

    def __init__(self, kept: dict) -> None:
        super().__init__()
        self.kept = kept

    def get(self, key, default=None):
        if key in self:
            return self[key]
        hit = self.kept.get(key)
        if hit is None:
            return default
        self[key] = hit
        return hit


def _same_level0(a: hspline.HSpline, b: hspline.HSpline) -> bool:
    """Whether ``a`` and ``b`` have the same grid, depth and level-0 CVs ``(nu, nv, 3) float64``,
    bit for bit."""
    if (a.u, a.v, a.depth) != (b.u, b.v, b.depth):
        return False
    return a.cvs is b.cvs or (a.cvs.shape == b.cvs.shape and a.cvs.tobytes() == b.cvs.tobytes())


CELL_LEVEL = 4  # the finest level whose patches `hspline.changed_cells` tells changed from unchanged
# (a display's points and limit normals read a vertex's own cells alone, except a limit normal
# taken at nudged points, whose vertex `acra.tessellate.grid_samples` evaluates again)


def _cell_level(surface: hspline.HSpline) -> int:
    """The level of the cells a changed display is re-evaluated by: its finest, up to `CELL_LEVEL`
    (a finer changed patch marks its level-`CELL_LEVEL` cell)."""
    return min(surface.depth - 1, CELL_LEVEL)


def _refinement(surfaces: list, samples: int) -> tuple:
    """What `run_topology` of ``surfaces`` (one object's) depends on: the grid, ``samples`` and
    the sorted distinct active patch keys of each finer level over the surfaces."""
    first = surfaces[0]

    def keys(k: int) -> bytes:
        each = [np.asarray(hs.level(k).patches, np.int64) for hs in surfaces]
        if len(each) == 1:
            return each[0].tobytes()
        # the union of the distinct key lists alone: a run's frames mostly refine alike (the
        # demo's head the same patches at every frame), and one strictly increasing list is its
        # own union, as `np.unique` would give it
        distinct = {a.tobytes(): a for a in each}
        if len(distinct) == 1:
            (b, a), = distinct.items()
            if a.size < 2 or bool((a[1:] > a[:-1]).all()):
                return b
        return np.unique(np.concatenate(list(distinct.values()))).tobytes()

    return (first.u, first.v, first.depth, int(samples), tuple(keys(k) for k in range(1, first.depth)))
