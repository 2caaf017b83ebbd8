"""Rerun preview of a run, for an animator to scrub: every object per frame, what ACRA did, metrics.

Entities (all on the ``frame`` sequence timeline):

* ``world/<prim path>`` — each deformable's response mesh (topology static, positions and normals
  per frame, in object space) and each collider's mesh (static), each under a per-frame
  ``Transform3D`` with its USD world matrix, so the scene moves as keyed;
* ``world/acra/contacts`` — the rewound contact points ``P1, P2`` (red);
* ``world/acra/data_points/<path>`` — data points as arrows from the surface to their targets (blue);
* ``world/acra/region/<path>`` — tessellation vertices inside the other object (yellow);
* ``metrics/residual_rel``, ``metrics/rounds``, ``metrics/ms/*`` — plots; ``log`` — one line per
  collision frame.

Markers of a frame without collision are cleared, so scrubbing never shows stale points (static
data would hide temporal data of the same component, field-notes). The default blueprint puts
the 3D view beside the residual and timing plots and the event log.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from pipeline.model import SceneModel

__all__ = ["Preview", "blueprint", "log_state"]


def _entity(path: str) -> str:
    return "world" + path


def blueprint() -> rrb.Blueprint:
    """3D view (left, wide) | residual, rounds and milliseconds plots over the event log (right)."""
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="scene", origin="world"),
            rrb.Vertical(
                rrb.TimeSeriesView(name="residual penetration (fraction of size)", origin="metrics/residual_rel"),
                rrb.TimeSeriesView(name="rounds", origin="metrics/rounds"),
                rrb.TimeSeriesView(name="ms per frame", origin="metrics/ms"),
                rrb.TextLogView(name="events", origin="log"),
                row_shares=[3, 2, 3, 2],
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


def _transform(m: np.ndarray) -> rr.Transform3D:
    return rr.Transform3D(translation=m[:3, 3], mat3x3=m[:3, :3])


CARRIED_FULL = 0.05  # a carried displacement of this fraction of the object's size shows full red
_REST_COLOUR, _CARRIED_COLOUR = np.array([217.0, 199.0, 178.0]), np.array([230.0, 50.0, 40.0])


def log_state(rec: rr.RecordingStream, scene: SceneModel, st, frame_result) -> None:
    """Plots of what each deformable carries across frames and of its volume (`pipeline.state`):
    ``metrics/state/<path>/{elastic,plastic}/level_<k>`` the largest carried vector per level,
    ``metrics/volume/<path>`` (``metrics/area/<path>`` for an open sheet) the display mesh's
    volume over the animator's (objects with ``acra:preserveVolume``); and the carried displacement as colour on the mesh (from the base
    colour to red at `CARRIED_FULL` of the object's size): each display point's distance from
    where the animator's surface puts it (the output's surface less both carried fields).
    Objects without either log nothing."""
    from acra import relax, volume
    from acra.tessellate import evaluate_grid

    for model in scene.deformables:
        r = frame_result[model.path]
        if r.carried is not None:
            for part in ("elastic", "plastic"):
                for k, m in enumerate(relax.level_magnitudes(getattr(r.carried, part))):
                    rec.log(f"metrics/state{model.path}/{part}/level_{k}", rr.Scalars(m))
            minus = np.full(r.surface.depth, -1.0)
            animator = relax.added(r.surface, relax.scaled(r.carried.plastic, minus), relax.scaled(r.carried.elastic, minus))
            rest, _ = evaluate_grid(animator, model.topology)
            t = np.clip(np.linalg.norm(r.points - rest, axis=1) / (CARRIED_FULL * r.surface.size()), 0.0, 1.0)
            colours = (_REST_COLOUR + t[:, None] * (_CARRIED_COLOUR - _REST_COLOUR)).astype(np.uint8)
            rec.log(_entity(model.path), rr.Mesh3D.from_fields(vertex_colors=colours))
        if model.path in st.volume_targets:
            measure, target = st.volume_targets[model.path]
            v = volume.MEASURES[measure][0](np.asarray(r.points, dtype=np.float64), volume.triangles(model.topology))
            rec.log(f"metrics/{measure}{model.path}", rr.Scalars(v / target))


class Preview:
    """A recording for one run (``rrd`` file, live viewer, or both)."""

    def __init__(self, scene: SceneModel, name: str, rrd: Path | None = None, spawn: bool = False):
        self.scene = scene
        self.rec = rr.RecordingStream(f"acra-{name}")
        if spawn:
            self.rec.spawn(default_blueprint=blueprint())
        self.rrd = rrd
        self._static_done = False
        self._marked: set = set()

    def _log_static(self, result_frame) -> None:
        for model in self.scene.deformables:
            tris = model.topology.triangles()
            self.rec.log(_entity(model.path), rr.Mesh3D(vertex_positions=result_frame[model.path].points, triangle_indices=tris,
                                                        albedo_factor=[0.85, 0.78, 0.7]), static=True)
        for c in self.scene.colliders:
            self.rec.log(_entity(c.path), rr.Mesh3D(vertex_positions=c.vertices, triangle_indices=c.triangles,
                                                    albedo_factor=[0.55, 0.6, 0.7]), static=True)
        self._static_done = True

    def _mark(self, entity: str, archetype) -> None:
        self.rec.log(entity, archetype)
        self._marked.add(entity)

    def log_frame(self, st, result) -> None:
        frame_result = result.frames[st.frame]
        if not self._static_done:
            self._log_static(frame_result)
        self.rec.set_time("frame", sequence=st.frame)
        for path, m in st.xforms.items():
            self.rec.log(_entity(path), _transform(np.asarray(m)))
        for model in self.scene.deformables:
            r = frame_result[model.path]
            self.rec.log(_entity(model.path), rr.Mesh3D.from_fields(vertex_positions=r.points, vertex_normals=r.normals))
        now: set = set()
        if st.contacts:
            pts = np.array([p for pair in st.contacts for p in pair])
            self._mark("world/acra/contacts", rr.Points3D(pts, radii=0.015, colors=[255, 60, 60]))
            now.add("world/acra/contacts")
        for path, (start, target) in st.data_points.items():
            e = f"world/acra/data_points{path}"
            self._mark(e, rr.Arrows3D(origins=start, vectors=target - start, radii=0.004, colors=[60, 160, 255]))
            now.add(e)
        for path, pts in st.regions.items():
            e = f"world/acra/region{path}"
            self._mark(e, rr.Points3D(pts, radii=0.006, colors=[255, 200, 0]))
            now.add(e)
        for e in self._marked - now:
            self.rec.log(e, rr.Clear(recursive=False))
        self._marked = now
        self.rec.log("metrics/residual_rel", rr.Scalars(st.residual_rel))
        self.rec.log("metrics/rounds", rr.Scalars(st.iterations))
        for name in ("setup", "detect", "convert", "respond", "output", "total"):
            self.rec.log(f"metrics/ms/{name}", rr.Scalars(getattr(st, f"ms_{name}")))
        log_state(self.rec, self.scene, st, frame_result)
        if st.in_collision:
            self.rec.log("log", rr.TextLog(
                f"frame {st.frame}: collision, {st.iterations} rounds, residual {st.residual_rel:.2e} of size, "
                f"{st.ms_total:.0f} ms", level=rr.TextLogLevel.INFO))

    def close(self) -> None:
        if self.rrd is not None:
            self.rec.save(str(self.rrd), default_blueprint=blueprint())
