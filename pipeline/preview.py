"""Rerun preview of a run or of an output layer, for an animator to scrub: the scene as keyed, what
ACRA moved and by how much, and the figures of each frame.

Entities (all temporal data on the ``frame`` sequence timeline):

* ``world`` — static ``ViewCoordinates`` from the stage's ``upAxis`` (right-handed, Z or Y up) and a
  static ``Transform3D`` scaling by ``metersPerUnit``, so the recording's root is in metres while
  everything under ``world`` stays in stage units;
* ``world<prim path>`` — each deformable's display mesh (triangles static; points, normals and
  vertex colours per frame, object space) and each collider's mesh (static), under a per-frame
  ``Transform3D`` with the prim's USD world matrix, so the scene moves as keyed. The vertex colour
  says how far ACRA moved that vertex from the key-framed shape (`moved_colours`): the object's own
  colour where it did not move, the viridis map on a log scale from 1e-4 to 1e-1 of the object's
  size where it did;
* ``legend`` — a static markdown text saying what the colours and markers mean;
* ``metrics/residual<prim path>`` — the ``acra:response:residual`` written for each deformable
  (scene units); ``metrics/absorbed<prim path>/level<k>`` — how much each level absorbed: the
  largest change ACRA made to a level-k offset (level 0: CV) from the key-framed hierarchy;
* ``log`` — one line per collision frame and, at the deepest collision, a row saying so (a click on
  its frame cell, ``#N``, moves the viewer's time cursor there).

A run (`Preview`) also logs what only the run knows (`RUN_ONLY`): the rewound contact points
``world/acra/contacts``, the data points as arrows ``world/acra/data_points<prim path>``, the
tessellation vertices inside the other object ``world/acra/region<prim path>`` (their sizes scale
with the smallest deformable), and the plots ``metrics/residual_rel`` (fraction of object size),
``metrics/pairs<path>/vs<other path>`` (the same per pair of objects: a deformable and another
deformable or a collider; 0 where they do not touch), ``metrics/over_tolerance`` (1 on a frame
left over the tolerance, with an error row in ``log``),
``metrics/rounds`` and ``metrics/ms/*``. An output layer read back (`pipeline.preview_usd`) gives
the same entities and frames minus those.

Markers of a frame without collision are cleared, so scrubbing never shows stale points (static
data would hide temporal data of the same component, field-notes). The default blueprint
(`blueprint`) opens the large 3D view looking at the deepest collision.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from acra import hspline
from acra.hspline import HSpline
from acra.tessellate import grid_samples
from pipeline import usdio
from pipeline.model import DeformableModel, SceneModel, apply_xform

__all__ = [
    "RUN_ONLY", "ObjectFrame", "Deepest", "Recording", "Preview", "blueprint", "entity", "view_coordinates",
    "moved_colours", "keyframed_points", "absorbed_by_level", "save_atomically", "log_state",
]

ROOT = "world"
#: entity prefixes a run logs that an output layer cannot give back (`pipeline.preview_usd`)
RUN_ONLY = ("world/acra", "metrics/residual_rel", "metrics/pairs", "metrics/over_tolerance", "metrics/rounds", "metrics/ms")

#: viridis (matplotlib's data) at 9 even stops, RGB 0-255: perceptually uniform, dark to bright
VIRIDIS = np.array([
    [68, 1, 84], [71, 45, 123], [59, 82, 139], [44, 114, 142], [33, 145, 140],
    [40, 174, 128], [94, 201, 98], [173, 220, 48], [253, 231, 37],
], dtype=np.float64)
#: log10 of (moved distance / object size) at the dark and the bright end of the map
MOVED_DECADES = (-4.0, -1.0)
DEFORMABLE_COLOUR = (217, 199, 179)
COLLIDER_COLOUR = (140, 153, 179)
CONTACT_COLOUR = (255, 40, 40)
DATA_POINT_COLOUR = (60, 160, 255)
REGION_COLOUR = (255, 140, 0)

LEGEND = f"""# What the colours mean

* **Object's own colour** (beige: deformable, blue-grey: rigid collider): ACRA did not move this
  part; it is exactly the key-framed shape.
* **Viridis, dark purple → green → yellow**: ACRA moved this vertex away from the key-framed shape,
  on a log scale of the object's size (bounding-box diagonal): dark purple
  10^{MOVED_DECADES[0]:.0f} or less, teal 10^{np.mean(MOVED_DECADES):.1f}, yellow
  10^{MOVED_DECADES[1]:.0f} or more.
* **Red balls** (a run only): the rewound contact points P1, P2 of each colliding pair.
* **Blue arrows** (a run only): data points, from the surface to the target ACRA moves it to.
* **Orange dots** (a run only): display vertices found inside the other object before the response.

Views: the large 3D view opens on the deepest collision (the frame where ACRA moved a vertex
farthest); click #N at the left of its row in *events* to move the time cursor there. The small view shows the whole
scene. Plots: residual penetration per object (scene units), how much each level absorbed.
"""


def entity(prim_path: str) -> str:
    """The entity of a USD prim: its path under ``world`` (``/World/Head`` → ``world/World/Head``)."""
    return ROOT + prim_path


def view_coordinates(up_axis: str) -> rr.ViewCoordinates:
    """Right-handed view coordinates with the stage's ``upAxis`` (``"Y"`` or ``"Z"``) up."""
    return rr.ViewCoordinates.RIGHT_HAND_Z_UP if str(up_axis).upper() == "Z" else rr.ViewCoordinates.RIGHT_HAND_Y_UP


def up_vector(up_axis: str) -> np.ndarray:
    """``(3,) float64`` unit vector of the stage's up axis."""
    return np.array([0.0, 0.0, 1.0]) if str(up_axis).upper() == "Z" else np.array([0.0, 1.0, 0.0])


def moved_colours(moved: np.ndarray, size: float, own=DEFORMABLE_COLOUR) -> np.ndarray:
    """Vertex colours ``(n, 3) uint8`` for distances ``moved (n,) float64`` ACRA moved each vertex.

    A vertex that did not move (``moved == 0``: the output point equals the key-framed one bit for
    bit in float32, as USD stores it) keeps ``own``; any other gets viridis at
    ``(log10(moved / size) - lo) / (hi - lo)`` clipped to [0, 1] (`MOVED_DECADES`), so a dent of a
    few per cent of the object and the faint spread of a coarse level both read.
    """
    moved = np.asarray(moved, dtype=np.float64)
    out = np.tile(np.asarray(own, dtype=np.uint8), (moved.size, 1))
    hit = moved > 0
    if hit.any():
        lo, hi = MOVED_DECADES
        t = np.clip((np.log10(moved[hit] / max(size, 1e-300)) - lo) / (hi - lo), 0.0, 1.0)
        x = t * (len(VIRIDIS) - 1)
        i = np.minimum(x.astype(np.int64), len(VIRIDIS) - 2)
        w = (x - i)[:, None]
        out[hit] = np.rint((1 - w) * VIRIDIS[i] + w * VIRIDIS[i + 1]).astype(np.uint8)
    return out


def keyframed_points(surface: HSpline, model: DeformableModel, topology=None) -> np.ndarray:
    """The key-framed surface on the run's display tessellation ``topology`` (default: the
    model's), ``(n, 3) float32`` object space.

    The same evaluation (`acra.tessellate.grid_samples`) that gives the output's points, so an
    untouched vertex compares equal bit for bit.
    """
    return np.asarray(grid_samples(surface, model.topology if topology is None else topology)[0], dtype=np.float32)


def absorbed_by_level(keyframed: HSpline, responded: HSpline) -> np.ndarray:
    """``(depth,) float64``: per level, the largest change of a level-k offset (level 0: a CV) from
    ``keyframed`` to ``responded``, an offset the key-framed hierarchy lacks counting from zero."""
    out = np.zeros(responded.depth, np.float64)
    for k in range(responded.depth):
        if k == 0:
            if keyframed.cvs.shape == responded.cvs.shape:
                out[0] = float(np.linalg.norm(responded.cvs - keyframed.cvs, axis=-1).max(initial=0.0))
            continue
        idx, off = hspline.offsets_of(responded, k)
        before = {}
        if k < keyframed.depth:
            kidx, koff = hspline.offsets_of(keyframed, k)
            before = {(int(a), int(b)): o for (a, b), o in zip(kidx, koff)}
        diff = [np.linalg.norm(o - before.get((int(a), int(b)), 0.0)) for (a, b), o in zip(idx, off)]
        out[k] = float(max(diff, default=0.0))
    return out


@dataclass
class ObjectFrame:
    """One deformable at one frame, as the recording shows it.

    Attributes
    ----------
    path : str
    points, normals : (n, 3) float32
        The output's display points and normals (object space), as USD stores them.
    keyframed : (n, 3) float32
        The key-framed surface on the same tessellation (`keyframed_points`).
    xform : (4, 4) float64
        Object-to-world matrix, column convention.
    residual : float
        ``acra:response:residual`` (scene units).
    in_collision : bool
    absorbed : (depth,) float64
        `absorbed_by_level`.
    """

    path: str
    points: np.ndarray
    normals: np.ndarray
    keyframed: np.ndarray
    xform: np.ndarray
    residual: float
    in_collision: bool
    absorbed: np.ndarray


@dataclass
class Deepest:
    """The deepest collision of a recording: the frame where ACRA moved a display vertex farthest.

    Attributes
    ----------
    frame : int
    path : str
        The deformable that vertex belongs to.
    moved : float
        How far it moved (scene units).
    target : (3,) float64
        The vertex, world space.
    normal : (3,) float64
        Its output unit normal, world space (outward: the side the other object came from).
    radius : float
        World radius around ``target`` of the vertices that moved at least a tenth as far.
    size : float
        The object's bounding-box diagonal (world) at that frame.
    region : (m, 3) float64
        Those vertices (world), at most 200 of them: what the view must show.
    """

    frame: int
    path: str
    moved: float
    target: np.ndarray
    normal: np.ndarray
    radius: float
    size: float
    region: np.ndarray | None = None

    def distance(self) -> float:
        """Eye distance: a sphere of radius ``max(1.5 radius, 0.2 size)`` around the dent fills the
        view (Rerun's default vertical field of view is about 55 degrees: 2.2 radii)."""
        return 2.2 * max(1.5 * self.radius, 0.2 * self.size)

    def directions(self, up: np.ndarray) -> np.ndarray:
        """Candidate view directions ``(25, 3) float64``, unit, from the dent toward the eye: the
        outward normal, then tilted 30, 55 and 75 degrees from it at 8 azimuths (azimuth 0 toward
        ``up``)."""
        n = self.normal
        a = up if abs(float(up @ n)) < 0.9 else np.roll(up, 1)
        t1 = a - (a @ n) * n
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(n, t1)
        out = [n]
        for tilt in np.radians([30.0, 55.0, 75.0]):
            for az in np.radians(np.arange(0.0, 360.0, 45.0)):
                out.append(np.cos(tilt) * n + np.sin(tilt) * (np.cos(az) * t1 + np.sin(az) * t2))
        return np.array(out)

    def eye(self, meshes: list[tuple[np.ndarray, np.ndarray]] | None = None, up: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(position, look target)``, each ``(3,) float64``, `distance` from the dent.

        Without ``meshes``: along the outward normal. With ``meshes`` (every object at that frame,
        world ``(points (n, 3), triangles (f, 3))``): along the first of `directions` from which the
        most of ``region`` is seen unoccluded (rays from each region vertex to the eye that hit no
        triangle before it), so an object resting on the dent (a slab over a bump) does not hide it.
        """
        dist = self.distance()
        if not meshes or self.region is None or not len(self.region):
            return self.target + dist * self.normal, self.target
        import trimesh

        offsets = np.cumsum([0] + [len(p) for p, _ in meshes[:-1]])
        scene = trimesh.Trimesh(np.concatenate([p for p, _ in meshes]),
                                np.concatenate([t + o for (_, t), o in zip(meshes, offsets)]), process=False)
        best, best_seen = self.normal, -1
        for d in self.directions(np.asarray(up if up is not None else [0.0, 0.0, 1.0], np.float64)):
            eye = self.target + dist * d
            ray = eye - self.region
            length = np.linalg.norm(ray, axis=1)
            ray /= length[:, None]
            start = self.region + 1e-4 * self.size * ray  # off the surface the ray leaves
            hits, index, _ = scene.ray.intersects_location(start, ray, multiple_hits=False)
            blocked = np.zeros(len(start), bool)
            near = np.linalg.norm(hits - start[index], axis=1) < length[index]
            blocked[index[near]] = True
            seen = int(np.count_nonzero(~blocked))
            if seen > best_seen:
                best, best_seen = d, seen
            if seen == len(start):
                break
        return self.target + dist * best, self.target


def blueprint(deepest: Deepest | None = None, up_axis: str = "Z", collision_frames: list[int] | None = None,
              meshes: list | None = None) -> rrb.Blueprint:
    """Large 3D view on the deepest collision (eye from `Deepest.eye` with ``meshes``, the up axis
    up) over a small whole-scene view and the legend | plots of residual and absorption over the
    event log; the time panel selects the collision frames."""
    eye = None
    if deepest is not None:
        position, target = deepest.eye(meshes, up_vector(up_axis))
        eye = rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=position, look_target=target, eye_up=up_vector(up_axis))
    title = f"collision, deepest at frame {deepest.frame}" if deepest is not None else "scene"
    selection = None
    if collision_frames:
        selection = rrb.components.AbsoluteTimeRange(min(collision_frames), max(collision_frames))
    time_panel = rrb.TimePanel(timeline="frame", state="collapsed", time_selection=selection)
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial3DView(name=title, origin=ROOT, eye_controls=eye),
                rrb.Horizontal(
                    rrb.Spatial3DView(name="whole scene", origin=ROOT),
                    rrb.TextDocumentView(name="legend", origin="legend"),
                ),
                row_shares=[3, 1],
            ),
            rrb.Vertical(
                rrb.TimeSeriesView(name="residual penetration (scene units)", origin="metrics/residual"),
                rrb.TimeSeriesView(name="absorbed per level (largest offset change)", origin="metrics/absorbed"),
                rrb.TimeSeriesView(name="residual / size: worst, per pair; over tolerance",
                                   contents=["metrics/residual_rel", "metrics/pairs/**", "metrics/over_tolerance"]),
                rrb.TimeSeriesView(name="ms per frame", origin="metrics/ms"),
                rrb.TextLogView(name="events", origin="log"),
                row_shares=[2, 2, 2, 2, 4],  # events: room for a dozen rows, the deepest one among them
            ),
            column_shares=[3, 2],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        time_panel,
    )


def _transform(m: np.ndarray) -> rr.Transform3D:
    return rr.Transform3D(translation=m[:3, 3], mat3x3=m[:3, :3])


def _diagonal(points: np.ndarray) -> float:
    return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0))) if len(points) else 0.0


def log_state(rec: rr.RecordingStream, scene: SceneModel, st, frame_result, topologies: dict) -> None:
    """Plots of what each deformable carries across frames and of its volume (`pipeline.state`):
    ``metrics/state/<path>/{elastic,plastic}/level_<k>`` the largest carried vector per level,
    ``metrics/volume/<path>`` (``metrics/area/<path>`` for an open sheet) the display mesh's
    volume over the animator's (objects with ``acra:preserveVolume``). The carried displacement
    shows on the mesh through the moved colours (`moved_colours`): the key-framed shape a vertex
    is compared with is the animator's, without the carried offsets. Objects without either log
    nothing."""
    from acra import relax, volume

    for model in scene.deformables:
        r = frame_result[model.path]
        if r.carried is not None:
            for part in ("elastic", "plastic"):
                for k, m in enumerate(relax.level_magnitudes(getattr(r.carried, part))):
                    rec.log(f"metrics/state{model.path}/{part}/level_{k}", rr.Scalars(m))
        if model.path in st.volume_targets:
            measure, target = st.volume_targets[model.path]
            v = volume.MEASURES[measure][0](np.asarray(r.points, dtype=np.float64), volume.triangles(topologies[model.path]))
            rec.log(f"metrics/{measure}{model.path}", rr.Scalars(v / target))


class Recording:
    """What a run and an output layer share: conventions, meshes, colours, plots, the deepest frame.

    ``triangles`` maps each deformable's prim path to its display triangles ``(f, 3) int64``.
    """

    def __init__(self, scene: SceneModel, name: str, triangles: dict[str, np.ndarray], spawn: bool = False):
        self.scene = scene
        self.rec = rr.RecordingStream(f"acra-{name}")
        if spawn:
            self.rec.spawn(default_blueprint=blueprint(up_axis=scene.up_axis))
        self.deepest: Deepest | None = None
        self._deepest_meshes: list = []  # every object at the deepest frame, world (points, triangles)
        self._triangles = None
        self.collision_frames: list[int] = []
        self.rec.log(ROOT, view_coordinates(scene.up_axis), static=True)
        self.rec.log(ROOT, rr.Transform3D(scale=float(scene.meters_per_unit)), static=True)
        self.rec.log("legend", rr.TextDocument(LEGEND, media_type=rr.MediaType.MARKDOWN), static=True)
        if triangles is not None:
            self.set_triangles(triangles)
        for c in scene.colliders:
            self.rec.log(entity(c.path), rr.Mesh3D(vertex_positions=c.vertices, triangle_indices=c.triangles,
                                                   vertex_colors=np.tile(COLLIDER_COLOUR, (len(c.vertices), 1))), static=True)

    def set_triangles(self, triangles: dict[str, np.ndarray]) -> None:
        """Log each deformable's display triangles ``(f, 3) int64`` (static: one topology per run)."""
        self._triangles = triangles
        for model in self.scene.deformables:
            self.rec.log(entity(model.path), rr.Mesh3D.from_fields(triangle_indices=triangles[model.path]), static=True)

    def log_frame(self, frame: int, objects: list[ObjectFrame], collider_xforms: dict[str, np.ndarray], line: str | None) -> None:
        """Transforms, coloured meshes and the shared plots of one frame; ``line`` goes to ``log``."""
        self.rec.set_time("frame", sequence=frame)
        for path, m in collider_xforms.items():
            self.rec.log(entity(path), _transform(np.asarray(m)))
        deeper = False
        for o in objects:
            moved = np.linalg.norm(o.points.astype(np.float64) - o.keyframed.astype(np.float64), axis=1)
            world = apply_xform(o.xform, o.points.astype(np.float64))
            size = _diagonal(world)
            self.rec.log(entity(o.path), _transform(o.xform))
            self.rec.log(entity(o.path), rr.Mesh3D.from_fields(vertex_positions=o.points, vertex_normals=o.normals,
                                                                vertex_colors=moved_colours(moved, size)))
            self.rec.log(f"metrics/residual{o.path}", rr.Scalars(float(o.residual)))
            for k, a in enumerate(o.absorbed):
                self.rec.log(f"metrics/absorbed{o.path}/level{k}", rr.Scalars(float(a)))
            peak = float(moved.max(initial=0.0))
            if peak > 0 and (self.deepest is None or peak > self.deepest.moved):
                at = int(np.argmax(moved))
                normal = o.xform[:3, :3] @ o.normals[at].astype(np.float64)
                near = np.nonzero(moved >= 0.1 * peak)[0]
                region = world[near[:: max(1, len(near) // 200)]]
                self.deepest = Deepest(int(frame), o.path, peak, world[at], normal / max(np.linalg.norm(normal), 1e-300),
                                       float(np.linalg.norm(world[near] - world[at], axis=1).max()), size, region)
                deeper = True
        if deeper:
            self._deepest_meshes = [(apply_xform(o.xform, o.points.astype(np.float64)), self._triangles[o.path]) for o in objects]
            self._deepest_meshes += [(apply_xform(np.asarray(collider_xforms[c.path]), c.vertices), c.triangles)
                                     for c in self.scene.colliders]
        if any(o.in_collision for o in objects):
            self.collision_frames.append(int(frame))
        if line:
            self.rec.log("log", rr.TextLog(line, level=rr.TextLogLevel.INFO))

    def finish(self) -> rrb.Blueprint:
        """Log the deepest-collision row (at its frame) and return the blueprint framed on it."""
        d = self.deepest
        if d is not None:
            self.rec.set_time("frame", sequence=d.frame)
            self.rec.log("log", rr.TextLog(
                f"DEEPEST collision: frame {d.frame}, ACRA moved {d.path} up to {d.moved:.3g} "
                f"({d.moved / max(d.size, 1e-300):.2%} of its size); click #{d.frame} at the left of this row to go there",
                level=rr.TextLogLevel.WARN))
        return blueprint(d, self.scene.up_axis, self.collision_frames, self._deepest_meshes)


def save_atomically(rec: rr.RecordingStream, path: Path, bp: rrb.Blueprint) -> Path:
    """Save ``rec`` with ``bp`` to ``path`` atomically (`guard.atomic_file`), so an error or an
    interruption leaves no partial recording."""
    from pipeline import guard

    path = Path(path)
    with guard.atomic_file(path) as tmp:
        rec.save(str(tmp), default_blueprint=bp)
        rec.flush()
        rec.disconnect()
    return path


class Preview:
    """The recording of a run (``rrd`` file, live viewer, or both): `Recording` plus the run's own
    markers and figures (`RUN_ONLY`). ``stage`` is the input stage, for the key-framed shapes."""

    def __init__(self, scene: SceneModel, name: str, rrd: Path | None = None, spawn: bool = False, *,
                 stage, tolerance: float = 1e-3):
        self.scene = scene
        self.stage = stage
        self.tolerance = tolerance
        self.recording = Recording(scene, name, None, spawn)  # the run's display topology comes with its first frame
        self.rec = self.recording.rec
        self.spawn = spawn
        self.rrd = rrd
        self._marked: set = set()
        self._keyframed: dict = {}  # path -> (level-0 CVs, points): a shape keyed once is evaluated once
        self._marker = None
        defs = [m.path for m in scene.deformables]
        self._pairs = [(a, b) for i, a in enumerate(defs) for b in defs[i + 1:] + [c.path for c in scene.colliders]]

    def _keyframed_surfaces(self, frame: int) -> dict[str, HSpline]:
        dstates, _ = usdio.state_at(self.stage, self.scene, float(frame))
        return {m.path: s.surface for m, s in zip(self.scene.deformables, dstates)}

    def _keyframed_points(self, model: DeformableModel, surface: HSpline, topology) -> np.ndarray:
        hit = self._keyframed.get(model.path)
        if hit is None or not np.array_equal(hit[0], surface.cvs):
            hit = self._keyframed[model.path] = (surface.cvs, keyframed_points(surface, model, topology))
        return hit[1]

    def _mark(self, entity_path: str, archetype) -> None:
        self.rec.log(entity_path, archetype)
        self._marked.add(entity_path)

    def log_frame(self, st, result) -> None:
        if self.recording._triangles is None:
            self.recording.set_triangles({m.path: result.topology(m).triangles() for m in self.scene.deformables})
        frame_result = result.frames[st.frame]
        keyed = self._keyframed_surfaces(st.frame)
        objects = []
        for model in self.scene.deformables:
            r = frame_result[model.path]
            objects.append(ObjectFrame(
                model.path, np.asarray(r.points, np.float32), np.asarray(r.normals, np.float32),
                self._keyframed_points(model, keyed[model.path], result.topology(model)), np.asarray(st.xforms[model.path], np.float64),
                float(r.residual), bool(r.in_collision), absorbed_by_level(keyed[model.path], r.surface)))
        colliders = {c.path: st.xforms[c.path] for c in self.scene.colliders}
        line = None
        if st.in_collision:
            rounds = f"holds frame {st.frame - 1} ({st.iterations} rounds there)" if st.hold else f"{st.iterations} rounds"
            line = f"frame {st.frame}: collision, {rounds}, residual {st.residual_rel:.2e} of size, {st.ms_total:.0f} ms"
        self.recording.log_frame(st.frame, objects, colliders, line)
        log_state(self.rec, self.scene, st, frame_result, {m.path: result.topology(m) for m in self.scene.deformables})
        if self._marker is None:  # markers scale with the smallest deformable, as first seen
            sizes = [_diagonal(apply_xform(o.xform, o.points.astype(np.float64))) for o in objects]
            self._marker = min(sizes, default=1.0) or 1.0
        s = self._marker
        now: set = set()
        if st.contacts:
            pts = np.array([p for pair in st.contacts for p in pair])
            self._mark("world/acra/contacts", rr.Points3D(pts, radii=0.02 * s, colors=CONTACT_COLOUR))
            now.add("world/acra/contacts")
        for path, (start, target) in st.data_points.items():
            e = f"world/acra/data_points{path}"
            self._mark(e, rr.Arrows3D(origins=start, vectors=target - start, radii=0.004 * s, colors=DATA_POINT_COLOUR))
            now.add(e)
        for path, pts in st.regions.items():
            e = f"world/acra/region{path}"
            self._mark(e, rr.Points3D(pts, radii=0.008 * s, colors=REGION_COLOUR))
            now.add(e)
        for e in self._marked - now:
            self.rec.log(e, rr.Clear(recursive=False))
        self._marked = now
        over = st.residual_rel > self.tolerance
        self.rec.log("metrics/residual_rel", rr.Scalars(st.residual_rel))
        for a, b in self._pairs:
            self.rec.log(f"metrics/pairs{a}/vs{b}", rr.Scalars(float(st.pair_residual_rel.get((a, b), 0.0))))
        self.rec.log("metrics/over_tolerance", rr.Scalars(1.0 if over else 0.0))
        if over:
            self.rec.log("log", rr.TextLog(
                f"frame {st.frame}: OVER TOLERANCE, residual {st.residual_rel:.2e} of size > {self.tolerance:g}",
                level=rr.TextLogLevel.ERROR))
        self.rec.log("metrics/rounds", rr.Scalars(st.iterations))
        for name in ("setup", "detect", "convert", "respond", "visible", "output", "total"):
            self.rec.log(f"metrics/ms/{name}", rr.Scalars(getattr(st, f"ms_{name}")))

    def close(self) -> None:
        bp = self.recording.finish()
        if self.spawn:
            self.rec.send_blueprint(bp)
        if self.rrd is not None:
            save_atomically(self.rec, Path(self.rrd), bp)
