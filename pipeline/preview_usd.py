"""`acra preview OUTPUT [--rrd FILE | --web | --spawn]`: the Rerun recording of an output layer
alone, without running ACRA.

The layer is opened as a USD client sees it (the output over the input it sublayers), so what the
recording shows is what the user opens: at every frame that holds ``acra:response:residual``
samples, each deformable's composed ``points`` and ``normals`` on the layer's own topology
(``faceVertexCounts``/``faceVertexIndices``, fan-triangulated), the world transforms, the
``acra:response:*`` state (residual, in-collision, and the hierarchy for `preview.absorbed_by_level`)
and the key-framed shape evaluated from the input's ``acra:`` attributes at the run's display
vertices (``acra:display:uv``, `preview.keyframed_points`). The entities and frames equal those a run logs with
``--rrd``, minus `preview.RUN_ONLY` (contacts, data points, region, rounds, timings, residual as a
fraction of size), which only a run knows.

Bad input (a missing or unreadable file, a layer with no ACRA output, an unwritable ``--rrd``)
raises `InputError`: one line, exit 2, nothing written.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
from pxr import Usd, UsdGeom

from acra.tessellate import MeshTopology
from pipeline import preview, usdio
from pipeline import output_layer
from pipeline.model import InputError

__all__ = ["triangulate", "output_frames", "build", "check_rrd_path", "preview_file"]


def triangulate(counts: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Fan triangles ``(f, 3) int64`` of polygons ``counts (p,)`` over ``indices (sum counts,)``
    (a quad ``a b c d`` gives ``a b c``, ``a c d``, as `acra.tessellate.GridTopology.triangles`)."""
    empty = np.zeros(0, np.float64)
    return MeshTopology(empty, empty, np.asarray(counts, np.int64), np.asarray(indices, np.int64)).triangles()


def output_frames(stage: Usd.Stage, paths: list[str], where: str) -> list[int]:
    """Integer frames at which every deformable of ``paths`` holds ``acra:response:residual``;
    `InputError` when none does (not an ACRA output layer)."""
    frames = None
    for path in paths:
        attr = stage.GetPrimAtPath(path).GetAttribute("acra:response:residual")
        samples = {int(round(t)) for t in (attr.GetTimeSamples() if attr else [])}
        frames = samples if frames is None else frames & samples
    if not frames:
        raise InputError(where, None, "holds no ACRA output (no acra:response:residual time samples on a deformable); "
                                      "make one with `acra run`")
    return sorted(frames)


def check_rrd_path(rrd: Path) -> None:
    """`InputError` unless a recording can be written at ``rrd`` (its directory exists and is writable)."""
    parent = Path(rrd).parent
    if Path(rrd).is_dir():
        raise InputError("--rrd", None, f"{rrd} is a directory")
    if not parent.is_dir():
        raise InputError("--rrd", None, f"cannot write {rrd}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise InputError("--rrd", None, f"cannot write {rrd}: directory {parent} is not writable")


def build(output: Path, spawn: bool = False) -> preview.Recording:
    """The recording of the output layer ``output`` (see the module's docstring)."""
    output = Path(output)
    if not output.is_file():
        raise InputError(str(output), None, "no such file")
    stage = usdio.open_input(output)
    scene = usdio.read_scene(stage)
    if not scene.deformables:
        raise InputError(str(output), None, "holds no deformable object (a Mesh with acra:cvs)")
    frames = output_frames(stage, [m.path for m in scene.deformables], str(output))
    triangles, topologies = {}, {}
    for m in scene.deformables:
        try:
            topologies[m.path] = output_layer.read_display_topology(stage, m.path)  # the run's display sites
        except KeyError:
            raise InputError(m.path, output_layer.DISPLAY_UV, "is missing: the layer was not written by this version of `acra run`") from None
        triangles[m.path] = topologies[m.path].triangles()
    recording = preview.Recording(scene, output.name.split(".")[0], triangles, spawn)
    keyed_cache: dict = {}
    for f in frames:
        tc = Usd.TimeCode(float(f))
        dstates, cstates = usdio.state_at(stage, scene, float(f))
        objects = []
        for m, s in zip(scene.deformables, dstates):
            prim = stage.GetPrimAtPath(m.path)
            mesh = UsdGeom.Mesh(prim)
            hit = keyed_cache.get(m.path)
            if hit is None or not np.array_equal(hit[0], s.surface.cvs):
                hit = keyed_cache[m.path] = (s.surface.cvs, preview.keyframed_points(s.surface, m, topologies[m.path]))
            responded = output_layer.read_output_hierarchy(stage, m.path, float(f))
            objects.append(preview.ObjectFrame(
                m.path, np.asarray(mesh.GetPointsAttr().Get(tc), np.float32), np.asarray(mesh.GetNormalsAttr().Get(tc), np.float32),
                hit[1], s.xform, float(prim.GetAttribute("acra:response:residual").Get(tc)),
                bool(prim.GetAttribute("acra:response:inCollision").Get(tc)), preview.absorbed_by_level(s.surface, responded)))
        colliders = {c.path: s.xform for c, s in zip(scene.colliders, cstates)}
        line = None
        if any(o.in_collision for o in objects):
            worst = max(o.residual for o in objects)
            line = f"frame {f}: collision, residual {worst:.2e} (scene units)"
        recording.log_frame(f, objects, colliders, line)
    return recording


def preview_file(output: Path, rrd: Path | None = None, web: bool = False, spawn: bool = False) -> str:
    """Everything `acra preview` does; returns a one-line summary. ``--web`` serves the recording
    to the browser and blocks until interrupted."""
    t0 = time.perf_counter()
    if rrd is not None:
        check_rrd_path(Path(rrd))
    recording = build(Path(output), spawn=spawn)
    bp = recording.finish()
    d = recording.deepest
    where = f"deepest collision at frame {d.frame} ({d.path} moved {d.moved:.3g})" if d else "ACRA moved nothing"
    if spawn:
        recording.rec.send_blueprint(bp)
    if rrd is not None:
        preview.save_atomically(recording.rec, Path(rrd), bp)
    summary = f"acra preview: {output}: {where}; {time.perf_counter() - t0:.2f} s" + (f" -> {rrd}" if rrd else "")
    if web:
        import rerun as rr

        uri = recording.rec.serve_grpc(default_blueprint=bp)
        rr.serve_web_viewer(connect_to=uri, open_browser=False)
        print(f"{summary}; serving the web viewer (Ctrl-C to stop)", flush=True)
        try:
            while True:
                time.sleep(3600)
        except KeyboardInterrupt:
            pass
    return summary
