"""Rerun preview of a run: meshes per frame on a ``frame`` timeline, contacts, data points, metrics.

Topology is logged once as static; vertex positions and normals per frame (not static, or they
would hide the temporal data, field-notes). Plots: residual penetration, rounds and milliseconds
per frame; a text log of collision events.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr

from pipeline.model import SceneModel

__all__ = ["Preview"]


def _entity(path: str) -> str:
    return "world" + path


class Preview:
    """A recording for one run (``rrd`` file, live viewer, or both)."""

    def __init__(self, scene: SceneModel, name: str, rrd: Path | None = None, spawn: bool = False):
        self.scene = scene
        self.rec = rr.RecordingStream(f"acra-{name}")
        if spawn:
            self.rec.spawn()
        self.rrd = rrd
        self._static_done = False

    def _log_static(self, result_frame) -> None:
        for model in self.scene.deformables:
            tris = model.topology.triangles()
            self.rec.log(_entity(model.path), rr.Mesh3D(vertex_positions=result_frame[model.path].points, triangle_indices=tris), static=True)
        self._static_done = True

    def log_frame(self, st, result) -> None:
        frame_result = result.frames[st.frame]
        if not self._static_done:
            self._log_static(frame_result)
        self.rec.set_time("frame", sequence=st.frame)
        for model in self.scene.deformables:
            r = frame_result[model.path]
            self.rec.log(_entity(model.path), rr.Mesh3D.from_fields(vertex_positions=r.points, vertex_normals=r.normals))
        if st.contacts:
            pts = np.array([p for pair in st.contacts for p in pair])
            self.rec.log("contacts", rr.Points3D(pts, radii=0.02, colors=[255, 60, 60]))
        else:
            self.rec.log("contacts", rr.Clear(recursive=False))
        for path, pts in st.data_points.items():
            self.rec.log(f"data_points{path}", rr.Points3D(pts, radii=0.012, colors=[60, 160, 255]))
        for path, pts in st.regions.items():
            self.rec.log(f"region{path}", rr.Points3D(pts, radii=0.008, colors=[255, 200, 0]))
        self.rec.log("metrics/residual_rel", rr.Scalars(st.residual_rel))
        self.rec.log("metrics/rounds", rr.Scalars(st.iterations))
        self.rec.log("metrics/ms_frame", rr.Scalars(st.ms_total))
        if st.in_collision:
            self.rec.log("log", rr.TextLog(f"frame {st.frame}: collision, {st.iterations} rounds, residual {st.residual_rel:.2e} of size"))

    def close(self) -> None:
        if self.rrd is not None:
            self.rec.save(str(self.rrd))
