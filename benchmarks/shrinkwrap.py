"""ACRA side by side with Blender's Shrinkwrap modifier (OUTSIDE), on the same meshes and frames.

    python3 benchmarks/shrinkwrap.py                              # default scene, writes docs/shrinkwrap.md
    python3 benchmarks/shrinkwrap.py scenes/box_into_sheet.py --frames 9:16
    python3 benchmarks/shrinkwrap.py scenes/dog_head_spike.py --samples 16 --frames 12:18
    python3 benchmarks/shrinkwrap.py scenes/box_into_sheet.py --wrap-method PROJECT
    python3 benchmarks/shrinkwrap.py STAGE.usda --venv PATH --no-doc

What an animator would do without ACRA: put a Shrinkwrap modifier (nearest surface point, snap
mode *Outside*, offset 0) on the soft object, targeting the collider. Per frame this benchmark

1. exports, in world space, the deformable's display mesh as the animator keyed it (the input
   H-spline evaluated on the input's display topology, `DeformableModel.topology`: ``acra:samples``
   steps per edge of the finest patch present, triangle fans where the density changes, faces
   as USD's counts and indices) and every target's mesh and keyed matrix;
2. runs Blender (``bpy``, in its own venv ``.venv-blender/``: the wheel pins numpy < 2) on them
   and times only the modifiers (``Modifier.execution_time``, median of ``--repeats``);
3. runs ACRA on the same stage and frames (`pipeline.run.run_file`) and reads back, with USD, its
   output layer's display: ``faceVertexCounts``/``faceVertexIndices`` and the composed
   ``points``. That topology is the union of the run's refinements, not the input's, so ACRA is
   measured on its own mesh (its own `weld`), and its moves against the animator's surface on
   that mesh (`pipeline.output_layer.input_points`);
4. measures both results the same way (`pair_residual`, `displacement`), each on its own mesh:
   how deep a vertex of one object still lies inside the other (trimesh ``contains`` +
   ``signed_distance``), also between vertices (points sampled on the deformable's triangles),
   relative to the deformable's size (its keyed display mesh's bounding-box diagonal, the same
   for both); and how far each method moved the vertices that were NOT inside anything
   (Shrinkwrap moves only penetrating vertices: a crease; ACRA a dent).

``--samples N`` sets every deformable's ``acra:samples`` to N (an override layer over the stage),
so both methods work on the display an animator with that setting sees: Shrinkwrap on the keyed
display at N, ACRA on its output display at N. The ratio ACRA ms / Shrinkwrap ms is reported per
collision frame.

Every deformable is shrinkwrapped against every collider; of two deformables, the softer (lower
``acra:rigidity``) is shrinkwrapped against the stiffer one's keyed shape, which stays as keyed
(Blender cannot make two modifiers target each other's result).
"""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

BPY = "bpy==5.0.1"  # newest bpy with a CPython 3.11 wheel (field notes, "Peers")
DEFAULT_VENV = REPO / ".venv-blender"
BLENDER_SIDE = Path(__file__).resolve().with_name("_blender_shrinkwrap.py")
DOC = REPO / "docs" / "shrinkwrap.md"
MOVED = 1e-6  # a vertex "moved" when it moved more than this fraction of the object's size
FACE_STEPS = 4  # barycentric steps per triangle edge for the between-vertices residual


def default_scene() -> Path:
    """``scenes/dog_head_spike.py`` when it exists, else ``scenes/box_into_sheet.py``."""
    p = REPO / "scenes" / "dog_head_spike.py"
    return p if p.exists() else REPO / "scenes" / "box_into_sheet.py"


# --------------------------------------------------------------------------------------------
# the Blender venv


def venv_python(venv: Path) -> Path:
    return venv / ("Scripts/python.exe" if os.name == "nt" else "bin/python")


def ensure_venv(venv: Path | None) -> Path:
    """The python of a venv that imports ``bpy``; creates ``.venv-blender/`` once if needed.

    ``--venv PATH`` must already hold ``bpy``; the default venv is created with ``python3 -m venv``
    and ``pip install bpy==5.0.1``. Raises `RuntimeError` with pip's own message on failure.
    """
    target = DEFAULT_VENV if venv is None else Path(venv)
    py = venv_python(target)
    if not py.exists():
        if venv is not None:
            raise RuntimeError(f"--venv {venv}: no python at {py}")
        print(f"creating {target} with {BPY} (once; about 400 MB)", file=sys.stderr)
        subprocess.run([sys.executable, "-m", "venv", str(target)], check=True)
        pip = subprocess.run([str(py), "-m", "pip", "install", BPY], capture_output=True, text=True)
        if pip.returncode != 0:
            raise RuntimeError(f"pip install {BPY} failed in {target}:\n{pip.stdout[-2000:]}{pip.stderr[-2000:]}")
    check = subprocess.run([str(py), "-c", "import bpy; print(bpy.app.version_string)"], capture_output=True, text=True)
    if check.returncode != 0:
        raise RuntimeError(f"{py} cannot import bpy:\n{check.stderr[-2000:]}")
    return py


# --------------------------------------------------------------------------------------------
# exporting the keyed scene


@dataclass
class Keyed:
    """The animator's scene at the benchmark's frames, world space.

    Attributes
    ----------
    frames : (F,) int64
    def_paths : list[str]
    def_points : list of (F, n, 3) float64
        Keyed display mesh of each deformable (input H-spline, no response).
    def_xform : list of (F, 4, 4) float64
        Object-to-world matrices (column-vector convention), to map ACRA's object-space output.
    tgt_paths : list[str]
        Every collider, then every deformable (its keyed shape as a Shrinkwrap target).
    tgt_tris : list of (t, 3) int64
        Welded (`weld`) and wound outward when closed: Shrinkwrap's inside test is the side of
        the nearest face, and a degenerate pole triangle has no side.
    tgt_points : list of (1 or F, m, 3) float64
        In the target's object space, welded: one sample when the shape does not change (every
        collider; a deformable whose ``acra:cvs`` are not animated), else one per frame.
    tgt_matrix : list of (F, 4, 4) float64
        Object-to-world matrices of the targets: the animator moves them by their transforms, so
        Blender keeps a target's BVH tree between frames as ACRA keeps its collider's.
    tgt_deformable : list[int]
        Deformable index of a target, -1 for a collider.
    def_rigidity : list[float]
        ``acra:rigidity`` of each deformable (who is shrinkwrapped against whom).
    def_weld : list of Weld
        Each deformable's keyed display mesh welded at its poles (from the first frame).
    def_topology : list of MeshTopology
        Each deformable's input display topology (`DeformableModel.topology`): the faces
        Shrinkwrap's mesh is built from (``counts``, ``indices``).
    """

    frames: np.ndarray
    def_paths: list
    def_points: list
    def_xform: list
    tgt_paths: list
    tgt_tris: list
    tgt_points: list
    tgt_matrix: list
    tgt_deformable: list
    def_rigidity: list
    def_weld: list
    def_topology: list

    def targets_of(self, i: int) -> list[int]:
        """Shrinkwrap targets of deformable ``i``: every collider, and every other deformable
        that is stiffer (on equal rigidity, the one that comes first by path).

        An animator wraps the soft object around the stiff one and leaves the stiff one as keyed;
        wrapping both would push each out of the other's keyed shape, twice the correction.
        """
        r = self.def_rigidity
        return [k for k, d in enumerate(self.tgt_deformable) if d < 0 or (d != i and (r[d], -d) > (r[i], -i))]

    def target_world(self, k: int, f: int) -> np.ndarray:
        """World vertices of target ``k`` at frame index ``f``: ``(m, 3) float64``."""
        from pipeline.model import apply_xform

        pts = self.tgt_points[k]
        return apply_xform(self.tgt_matrix[k][f], pts[0 if len(pts) == 1 else f])

    def save_npz(self, path: Path) -> None:
        """The file `_blender_shrinkwrap.py` reads (its docstring lists the arrays)."""
        arrays = {"frames": self.frames, "n_deformables": np.int64(len(self.def_paths)), "n_targets": np.int64(len(self.tgt_paths))}
        for i in range(len(self.def_paths)):
            arrays[f"def{i}_counts"] = np.asarray(self.def_topology[i].counts, np.int64)
            arrays[f"def{i}_indices"] = np.asarray(self.def_topology[i].indices, np.int64)
            arrays[f"def{i}_points"] = self.def_points[i]
            arrays[f"def{i}_targets"] = np.array(self.targets_of(i), np.int64)
        for k in range(len(self.tgt_paths)):
            arrays[f"target{k}_faces"] = self.tgt_tris[k]
            arrays[f"target{k}_points"] = self.tgt_points[k]
            arrays[f"target{k}_matrix"] = self.tgt_matrix[k]
        np.savez(path, **arrays)


def parse_frames(arg: str | None, start: int, end: int) -> np.ndarray:
    """``"A:B"`` (inclusive) or the scene's range, as ``(F,) int64``."""
    if arg is None:
        return np.arange(start, end + 1, dtype=np.int64)
    a, b = (int(x) for x in arg.split(":"))
    if b < a:
        raise ValueError(f"--frames {arg}: END before START")
    return np.arange(a, b + 1, dtype=np.int64)


def with_samples(stage_path: Path, samples: int, work: Path) -> Path:
    """A layer in ``work`` over ``stage_path`` that sets every deformable's ``acra:samples`` to
    ``samples``: the display an animator with that setting sees, for both methods."""
    from pxr import Sdf

    from pipeline import usdio

    scene = usdio.read_scene(usdio.open_input(stage_path))
    layer = Sdf.Layer.CreateNew(str(work / f"{Path(stage_path).stem}-samples{samples}.usda"))
    layer.subLayerPaths.append(str(Path(stage_path).resolve()))
    for m in scene.deformables:
        prim = Sdf.CreatePrimInLayer(layer, m.path)
        Sdf.AttributeSpec(prim, "acra:samples", Sdf.ValueTypeNames.Int).default = int(samples)
    layer.Save()
    return Path(layer.realPath)


def export_keyed(stage_path: Path, frames: str | None = None) -> Keyed:
    """Evaluate the animator's input at every frame (`pipeline.usdio.state_at`), in world space,
    on each deformable's input display topology (`DeformableModel.topology`)."""
    from acra import hspline as H
    from acra.tessellate import grid_samples
    from pipeline import usdio
    from pipeline.model import apply_xform

    stage = usdio.open_input(stage_path)
    scene = usdio.read_scene(stage)
    fr = parse_frames(frames, scene.start, scene.end)
    nd = len(scene.deformables)
    topo = [m.topology for m in scene.deformables]
    pts = [np.zeros((len(fr), t.u.size, 3)) for t in topo]
    loc = [np.zeros_like(p) for p in pts]
    dx = [np.zeros((len(fr), 4, 4)) for _ in range(nd)]
    cx = [np.zeros((len(fr), 4, 4)) for _ in scene.colliders]
    for f, frame in enumerate(fr):
        dstates, cstates = usdio.state_at(stage, scene, float(frame))
        for i, s in enumerate(dstates):
            det = H.details(s.surface) if s.surface.depth > 1 else None
            local, _ = grid_samples(s.surface, topo[i], det, normals=False)
            pts[i][f], loc[i][f], dx[i][f] = apply_xform(s.xform, local), local, s.xform
        for j, c in enumerate(cstates):
            cx[j][f] = c.xform
    welds = [weld(p[0], t.triangles()) for p, t in zip(pts, topo)]
    cwelds = [weld(c.vertices, c.triangles) for c in scene.colliders]
    return Keyed(
        frames=fr,
        def_paths=[m.path for m in scene.deformables],
        def_points=pts,
        def_xform=dx,
        tgt_paths=[c.path for c in scene.colliders] + [m.path for m in scene.deformables],
        tgt_tris=[w.triangles for w in cwelds + welds],
        tgt_points=[w.apply(c.vertices)[None] for w, c in zip(cwelds, scene.colliders)]
        + [w.apply(p[:1] if np.all(p == p[:1]) else p) for w, p in zip(welds, loc)],
        tgt_matrix=cx + dx,
        tgt_deformable=[-1] * len(scene.colliders) + list(range(nd)),
        def_rigidity=[float(m.controls.rigidity) for m in scene.deformables],
        def_weld=welds,
        def_topology=topo,
    )


# --------------------------------------------------------------------------------------------
# the shared measure


@dataclass(frozen=True)
class Weld:
    """Coincident vertices of a mesh merged: ``inverse (n,) int64`` maps each vertex to its
    welded vertex, ``triangles (t, 3) int64`` are the welded, non-degenerate triangles."""

    inverse: np.ndarray
    triangles: np.ndarray

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Welded vertices of ``points (..., n, 3)``: each the mean of its group, ``(..., m, 3)``."""
        points = np.asarray(points, np.float64)
        m = int(self.inverse.max()) + 1
        total = np.zeros(points.shape[:-2] + (m, 3))
        np.add.at(total, (..., self.inverse, slice(None)), points)
        return total / np.bincount(self.inverse, minlength=m)[:, None]


def weld(points: np.ndarray, triangles: np.ndarray, tol: float = 1e-9) -> Weld:
    """Merge vertices closer than ``tol`` of the mesh's size (the rows of a pole, the seam of a
    closed display grid), drop the triangles that collapse, and wind a closed mesh outward.

    Computed once from a reference configuration and applied to every frame and every result, so
    a response that opens a pole a little still gives the same closed mesh.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    points = np.asarray(points, np.float64)
    pairs = cKDTree(points).query_pairs(tol * max(size_of(points), 1e-300), output_type="ndarray")
    n = len(points)
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)) if len(pairs) else coo_matrix((n, n))
    _, labels = connected_components(graph, directed=False)
    _, first = np.unique(labels, return_index=True)  # number groups by their first vertex
    order = np.argsort(first)
    inverse = np.empty(len(order), np.int64)
    inverse[order] = np.arange(len(order))
    tris = inverse[labels[np.asarray(triangles, np.int64)]]
    tris = tris[(tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 2] != tris[:, 0])]
    w = Weld(inverse[labels], tris)
    mesh = trimesh.Trimesh(w.apply(points), tris, process=False)
    if mesh.is_watertight and mesh.volume < 0:
        w = Weld(w.inverse, np.ascontiguousarray(tris[:, ::-1]))
    return w


def closed_mesh(points: np.ndarray, triangles: np.ndarray) -> trimesh.Trimesh | None:
    """The mesh if it is watertight (weld it first), else None: only a closed mesh has an
    inside, an open sheet is never a container."""
    mesh = trimesh.Trimesh(np.asarray(points, np.float64), np.asarray(triangles, np.int64), process=False)
    return mesh if mesh.is_watertight else None


def depth_inside(points: np.ndarray, mesh: trimesh.Trimesh | None) -> np.ndarray:
    """Depth of each point inside a closed ``mesh``: ``(n,) float64``, 0 outside or on it.

    ``contains`` (ray parity, embree) picks the points inside; their depth is the distance to the
    nearest surface point (``proximity.signed_distance``, positive inside).
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    depth = np.zeros(len(points))
    if mesh is None or not len(points):
        return depth
    inside = mesh.contains(points)
    if np.any(inside):
        depth[inside] = np.maximum(trimesh.proximity.signed_distance(mesh, points[inside]), 0.0)
    return depth


def face_samples(points: np.ndarray, triangles: np.ndarray, steps: int = FACE_STEPS) -> np.ndarray:
    """Points strictly inside every triangle on a barycentric grid of ``steps`` per edge.

    Returns ``(t * s, 3) float64`` with ``s = (steps - 1)(steps - 2) / 2`` (vertices and edges
    excluded: the vertex measure already has them). These catch a crease whose vertices sit on
    the collider's faces while the triangle between them cuts through the collider's edge.
    """
    k = [(a, b) for a in range(1, steps) for b in range(1, steps - a)]
    if not k:
        return np.zeros((0, 3))
    w = np.array([(a, b, steps - a - b) for a, b in k], np.float64) / steps  # (s, 3)
    tri = np.asarray(points, np.float64)[np.asarray(triangles)]  # (t, 3, 3)
    return np.einsum("sk,tkd->tsd", w, tri).reshape(-1, 3)


@dataclass(frozen=True)
class Penetration:
    """Penetration left between two objects, in units of the deformable's size.

    ``max`` and ``mean`` over the vertices found inside (0 when none), ``count`` of them;
    ``faces_max`` the deepest of the points sampled on the deformables' triangles.
    """

    max: float
    mean: float
    count: int
    faces_max: float


def pair_residual(pa, ta, pb, tb, size: float, b_is_deformable: bool, steps: int = FACE_STEPS) -> Penetration:
    """Residual penetration of the pair (A: a deformable, B: a collider or a deformable).

    A's vertices inside B (when B is closed) and B's vertices inside A (when A is closed), depths
    over ``size``; the between-vertices measure samples A's triangles (and B's when B is a
    deformable) the same way.

    Parameters
    ----------
    pa, pb : (n, 3) float64 welded world vertices; ta, tb : (f, 3) int64 their triangles (`weld`).
    """
    ma, mb = closed_mesh(pa, ta), closed_mesh(pb, tb)
    d = np.concatenate([depth_inside(pa, mb), depth_inside(pb, ma)])
    d = d[d > 0]
    faces = depth_inside(face_samples(pa, ta, steps), mb).max(initial=0.0)
    if b_is_deformable:
        faces = max(faces, depth_inside(face_samples(pb, tb, steps), ma).max(initial=0.0))
    return Penetration(
        float(d.max() / size) if d.size else 0.0,
        float(d.mean() / size) if d.size else 0.0,
        int(d.size),
        float(faces / size),
    )


def size_of(points: np.ndarray) -> float:
    """Object size: the bounding-box diagonal of ``points (n, 3)``."""
    return float(np.linalg.norm(np.ptp(points, axis=0)))


@dataclass(frozen=True)
class Displacement:
    """How a method moved a deformable's vertices from the keyed shape (sizes relative).

    ``moved``: vertices moved by more than `MOVED`; ``free_moved`` those of them that were not
    inside anything in the keyed shape, ``free_max`` the largest move of such a vertex;
    ``max`` the largest move of any vertex.
    """

    moved: int
    free_moved: int
    free_max: float
    max: float


def displacement(keyed: np.ndarray, out: np.ndarray, in_contact: np.ndarray, size: float) -> Displacement:
    """Compare ``out`` with ``keyed`` (both ``(n, 3)``); ``in_contact (n,) bool`` marks the
    vertices that were inside another object before any response."""
    d = np.linalg.norm(np.asarray(out) - np.asarray(keyed), axis=1) / size
    moved = d > MOVED
    free = moved & ~np.asarray(in_contact, bool)
    return Displacement(int(moved.sum()), int(free.sum()), float(d[free].max(initial=0.0)), float(d.max(initial=0.0)))


def opposite_moves(keyed: np.ndarray, a: np.ndarray, b: np.ndarray, size: float) -> int:
    """Vertices both results moved (> `MOVED`), but in opposite directions (negative dot product).

    ACRA rewinds to where the collider first touched and pushes the way it came; Shrinkwrap
    pushes to the nearest surface point, which after a deep jump is the far side.
    """
    da, db = np.asarray(a) - keyed, np.asarray(b) - keyed
    both = (np.linalg.norm(da, axis=1) > MOVED * size) & (np.linalg.norm(db, axis=1) > MOVED * size)
    return int(np.sum(both & (np.einsum("ij,ij->i", da, db) < 0)))


# --------------------------------------------------------------------------------------------
# the two runs


def run_blender(python: Path, keyed: Keyed, work: Path, repeats: int, wrap_method: str = "NEAREST_SURFACEPOINT") -> dict:
    """Run `_blender_shrinkwrap.py` on the keyed frames; returns its OUT.npz as a dict."""
    inp, out = work / "keyed.npz", work / "shrinkwrap.npz"
    keyed.save_npz(inp)
    cmd = [str(python), str(BLENDER_SIDE), str(inp), str(out), "--repeats", str(repeats), "--wrap-method", wrap_method]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"Blender side failed ({proc.returncode}):\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}")
    with np.load(out) as z:
        return {k: z[k] for k in z.files}


@dataclass
class Shown:
    """One method's deformables as its user sees them, each on its own mesh: per deformable,
    ``points (F, n, 3) float64`` world space, the mesh's ``weld`` (`Weld`), and ``keyed
    (F, n, 3) float64`` the animator's surface at the same vertices (what the method moved from);
    ``uv`` each vertex's surface parameter ``(n, 2)`` (vertex correspondence between methods)."""

    points: list
    welds: list
    keyed: list
    uv: list


def run_acra(stage_path: Path, keyed: Keyed, work: Path, repeats: int) -> tuple[list, np.ndarray, Shown]:
    """ACRA on the same stage and frames, ``repeats`` times.

    Returns the last run's per-frame stats, the median over runs of each frame's ``ms_total``
    ``(F,)``, and its output display read back with USD (`Shown`): the output's
    ``faceVertexCounts``/``faceVertexIndices`` (the run's own topology, welded on its own) and
    composed ``points`` in world space, with the animator's surface on that topology
    (`pipeline.output_layer.input_points`, float32 as the layer stores points).
    """
    from pxr import Usd, UsdGeom

    from acra.tessellate import MeshTopology
    from pipeline import output_layer
    from pipeline.model import apply_xform
    from pipeline.run import forget, run_file

    span = f"{keyed.frames[0]}:{keyed.frames[-1]}"
    out = work / "acra.usda"
    times = []
    for _ in range(max(1, repeats)):
        forget()  # each run from a cold start: not served the run before's shapes and answers
        report = run_file(stage_path, output=out, frames=span)
        times.append([s.ms_total for s in report.stats])
    stage = Usd.Stage.Open(str(out))
    shown = Shown([], [], [], [])
    for i, path in enumerate(keyed.def_paths):
        mesh = UsdGeom.Mesh(stage.GetPrimAtPath(path))
        counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(), np.int64)
        indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), np.int64)
        xf = keyed.def_xform[i]
        pts = np.stack([apply_xform(xf[f], np.asarray(mesh.GetPointsAttr().Get(float(fr)), np.float64)) for f, fr in enumerate(keyed.frames)])
        ref = np.stack([apply_xform(xf[f], output_layer.input_points(stage, path, float(fr))) for f, fr in enumerate(keyed.frames)])
        shown.points.append(pts)
        shown.keyed.append(ref)
        # the layer stores float32: a pole's coincident vertices may differ by a float32 step
        shown.welds.append(weld(ref[0], MeshTopology(np.zeros(0), np.zeros(0), counts, indices).triangles(), tol=1e-6))
        shown.uv.append(output_layer.read_display_uv(stage, path))
    return report.stats, np.median(np.array(times), axis=0), shown


# --------------------------------------------------------------------------------------------
# comparison and report


@dataclass
class FrameRow:
    """One frame of the comparison; each pair of values is (ACRA, Shrinkwrap)."""

    frame: int
    keyed: Penetration
    ms: tuple
    residual: tuple
    moved: tuple
    opposite: int
    acra_own: float = 0.0  # ACRA's own residual (FrameStats.residual_rel, its certified bound on its display)
    hold: bool = False  # ACRA took the previous frame's answer: the input is that frame's bit for bit (FrameStats.hold)

    @property
    def ratio(self) -> float:
        """ACRA ms over Shrinkwrap ms at this frame (above 1: ACRA is slower)."""
        return self.ms[0] / self.ms[1] if self.ms[1] > 0 else float("inf")


def shrinkwrap_shown(keyed: Keyed, sw: dict) -> Shown:
    """Shrinkwrap's result (`_blender_shrinkwrap.py`'s OUT.npz) on the keyed display mesh."""
    points = [sw[f"def{i}_points"] for i in range(len(keyed.def_paths))]
    uv = [np.column_stack([t.u, t.v]) for t in keyed.def_topology]
    return Shown(points, list(keyed.def_weld), list(keyed.def_points), uv)


def common_vertices(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(ia, ib)`` of the vertices of two display meshes of one object at the same surface
    parameter (``a (n, 2)``, ``b (m, 2)``, `Shown.uv`): both topologies sit on the same dyadic
    lattice, so a vertex both have carries the same parameter, bit for bit."""
    ka = {(float(u), float(v)): k for k, (u, v) in enumerate(a)}
    pairs = [(ka[(float(u), float(v))], k) for k, (u, v) in enumerate(b) if (float(u), float(v)) in ka]
    ia, ib = (np.array(x, np.int64) for x in zip(*pairs)) if pairs else (np.zeros(0, np.int64),) * 2
    return ia, ib


def compare(keyed: Keyed, acra: Shown, sw: Shown, ms_acra: np.ndarray, ms_sw: np.ndarray) -> list[FrameRow]:
    """Measure the keyed input and both results with the same functions, frame by frame, each on
    its own mesh (ACRA's output display, Shrinkwrap's keyed display).

    Pairs are every deformable with every collider and every later deformable, measured between
    the results (for Shrinkwrap: shrinkwrapped meshes and colliders; for the keyed row: input).
    Per frame, penetrations take the worst pair, displacements add up over deformables. Sizes are
    the keyed display's, the same for both methods.
    """
    rows = []
    nd = len(keyed.def_paths)
    colliders = [k for k, d in enumerate(keyed.tgt_deformable) if d < 0]
    common = [common_vertices(acra.uv[i], sw.uv[i]) for i in range(nd)]
    for f, frame in enumerate(keyed.frames):
        sizes = [size_of(keyed.def_points[i][f]) for i in range(nd)]

        def meshes(shown, pts):
            return [(shown.welds[i].apply(pts[i][f]), shown.welds[i].triangles) for i in range(nd)]

        def worst(objs):
            best = Penetration(0.0, 0.0, 0, 0.0)
            means = []
            for i in range(nd):
                pa, ta = objs[i]
                others = [(keyed.target_world(k, f), keyed.tgt_tris[k], sizes[i], False) for k in colliders]
                others += [(*objs[j], min(sizes[i], sizes[j]), True) for j in range(i + 1, nd)]
                for pb, tb, size, deformable in others:
                    p = pair_residual(pa, ta, pb, tb, size, deformable)
                    means += [p.mean] * p.count
                    best = Penetration(max(best.max, p.max), 0.0, best.count + p.count, max(best.faces_max, p.faces_max))
            return Penetration(best.max, float(np.mean(means)) if means else 0.0, best.count, best.faces_max)

        def contact(vertices, i):
            """Vertices of deformable ``i``'s keyed shape ``(n, 3)`` inside any other object."""
            depth = np.zeros(len(vertices))
            for k in (k for k, d in enumerate(keyed.tgt_deformable) if d != i):  # inside anything
                mesh = closed_mesh(keyed.target_world(k, f), keyed.tgt_tris[k])
                depth = np.maximum(depth, depth_inside(vertices, mesh))
            return depth > 0

        def moved(shown):
            ds = [displacement(shown.keyed[i][f], shown.points[i][f], contact(shown.keyed[i][f], i), sizes[i]) for i in range(nd)]
            return Displacement(sum(d.moved for d in ds), sum(d.free_moved for d in ds), max(d.free_max for d in ds), max(d.max for d in ds))

        rows.append(FrameRow(
            int(frame),
            worst(meshes(sw, sw.keyed)),
            (float(ms_acra[f]), float(ms_sw[f])),
            (worst(meshes(acra, acra.points)), worst(meshes(sw, sw.points))),
            (moved(acra), moved(sw)),
            sum(opposite_moves(sw.keyed[i][f][ib], acra.points[i][f][ia], sw.points[i][f][ib], sizes[i])
                for i, (ia, ib) in enumerate(common)),
        ))
    return rows


def _e(x: float) -> str:
    return "0" if x == 0 else f"{x:.1e}"


def tables(rows: list[FrameRow]) -> str:
    """Two markdown tables over ``rows`` (the collision frames) with a median row each."""
    med = lambda xs: float(np.median(xs)) if len(xs) else 0.0  # noqa: E731
    t1 = [
        "| frame | keyed: vertices inside / max depth | ms ACRA | ms Shrinkwrap | ACRA / Shrinkwrap | residual max ACRA | residual max Shrinkwrap "
        "| residual mean ACRA | residual mean Shrinkwrap | between vertices ACRA | between vertices Shrinkwrap | ACRA's own residual |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        a, s = r.residual
        t1.append(
            f"| {r.frame}{' (hold)' if r.hold else ''} | {r.keyed.count} / {_e(r.keyed.max)} | {r.ms[0]:.1f} | {r.ms[1]:.2f} | {r.ratio:.1f}× | {_e(a.max)} | {_e(s.max)} "
            f"| {_e(a.mean)} | {_e(s.mean)} | {_e(a.faces_max)} | {_e(s.faces_max)} | {_e(r.acra_own)} |"
        )
    col = lambda get: [get(r) for r in rows]  # noqa: E731
    computed = [r for r in rows if not r.hold] or rows  # the times' medians leave holds out
    timed = lambda get: [get(r) for r in computed]  # noqa: E731
    t1.append(
        f"| **median** | {med(col(lambda r: r.keyed.count)):.0f} / {_e(med(col(lambda r: r.keyed.max)))} "
        f"| {med(timed(lambda r: r.ms[0])):.1f} | {med(timed(lambda r: r.ms[1])):.2f} | {med(timed(lambda r: r.ratio)):.1f}× "
        + " ".join(f"| {_e(med(col(get)))}" for get in (
            lambda r: r.residual[0].max, lambda r: r.residual[1].max, lambda r: r.residual[0].mean,
            lambda r: r.residual[1].mean, lambda r: r.residual[0].faces_max, lambda r: r.residual[1].faces_max,
            lambda r: r.acra_own))
        + " |"
    )
    t2 = [
        "| frame | moved ACRA | moved Shrinkwrap | moved but not inside, ACRA: count / max | same, Shrinkwrap "
        "| largest move ACRA | largest move Shrinkwrap | moved opposite ways |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        a, s = r.moved
        t2.append(
            f"| {r.frame}{' (hold)' if r.hold else ''} | {a.moved} | {s.moved} | {a.free_moved} / {_e(a.free_max)} | {s.free_moved} / {_e(s.free_max)} "
            f"| {_e(a.max)} | {_e(s.max)} | {r.opposite} |"
        )
    t2.append(
        f"| **median** | {med(col(lambda r: r.moved[0].moved)):.0f} | {med(col(lambda r: r.moved[1].moved)):.0f} "
        f"| {med(col(lambda r: r.moved[0].free_moved)):.0f} / {_e(med(col(lambda r: r.moved[0].free_max)))} "
        f"| {med(col(lambda r: r.moved[1].free_moved)):.0f} / {_e(med(col(lambda r: r.moved[1].free_max)))} "
        f"| {_e(med(col(lambda r: r.moved[0].max)))} | {_e(med(col(lambda r: r.moved[1].max)))} "
        f"| {med(col(lambda r: r.opposite)):.0f} |"
    )
    held = [r for r in rows if r.hold]
    note = "" if not held else (
        f"\nHolds: at frames {', '.join(str(r.frame) for r in held)} the input is the previous frame's bit for bit, "
        f"and ACRA takes that frame's answer (`FrameStats.hold`): {med([r.ms[0] for r in held]):.2f} ms against "
        f"Shrinkwrap's {med([r.ms[1] for r in held]):.2f} ms (medians). The median row's times and ratio are over the "
        f"{len(rows) - len(held)} frames ACRA computed; its other columns over every frame above.\n")
    return "\n".join(t1) + "\n" + note + "\n" + "\n".join(t2) + "\n"


def quiet_frames(rows: list[FrameRow]) -> str:
    """What each method did at the frames outside the collision: it should be nothing."""
    parts = []
    for k, name in enumerate(("ACRA", "Shrinkwrap")):
        hit = [r for r in rows if r.moved[k].moved]
        parts.append(
            f"{name} moved vertices at {len(hit)} of them"
            + (f" (up to {max(r.moved[k].moved for r in hit)} vertices, up to {_e(max(r.moved[k].max for r in hit))})" if hit else "")
        )
    return f"At the {len(rows)} frames without collision, " + " and ".join(parts) + "."


def section(name: str, command: str, rows: list[FrameRow], quiet: list[FrameRow], notes: dict) -> str:
    """The generated part of docs/shrinkwrap.md for one scene."""
    return (
        f"<!-- bench:{name} -->\n### `{name}`\n\n"
        f"    {command}\n\n"
        f"{notes['machine']}. Frames in collision (the keyed mesh penetrates, or ACRA reports a "
        f"collision): {', '.join(str(r.frame) for r in rows) or 'none'}; {notes['vertices']}. "
        f"Residuals and moves are fractions of the deformable's size (bounding-box diagonal of its "
        f"keyed mesh at the frame: {notes['size']}; of two deformables, the smaller); a vertex *moved* when it moved more than "
        f"{MOVED:g} of it. Each method is measured on its own mesh: Shrinkwrap on the keyed display, "
        f"ACRA on its output layer's display ({notes['acra_vertices']}); *moved opposite ways* counts "
        f"the vertices both meshes have (same surface parameter). *Between vertices*: the deepest of "
        f"{notes['samples']} points sampled inside each of the deformable's triangles. *ACRA's own "
        f"residual*: what ACRA reported for its output (`FrameStats.residual_rel`, its certified bound "
        f"on its display triangles). *ACRA / Shrinkwrap*: ms ACRA over ms Shrinkwrap at the frame "
        f"(above 1: ACRA is slower).\n\n"
        f"{tables(rows)}\n{quiet_frames(quiet) if quiet else 'Every frame collides.'}\n<!-- /bench:{name} -->\n"
    )


def update_doc(doc: Path, name: str, text: str) -> None:
    """Replace scene ``name``'s generated section of ``doc`` (between its markers) or append it."""
    old = doc.read_text() if doc.exists() else "# ACRA and Blender's Shrinkwrap\n"
    start, end = f"<!-- bench:{name} -->", f"<!-- /bench:{name} -->"
    if start in old and end in old:
        head, rest = old.split(start, 1)
        new = head + text.rstrip("\n") + rest.split(end, 1)[1]
    else:
        new = old.rstrip("\n") + "\n\n" + text
    doc.write_text(new)


def collect(src: Path, frames: str | None, python: Path, repeats: int, acra_repeats: int, samples: int | None = None,
            wrap_method: str = "NEAREST_SURFACEPOINT"):
    """Both runs on scene file or stage ``src`` (with ``samples``, every deformable's
    ``acra:samples`` set to it, `with_samples`): ``(keyed, shrinkwrap npz dict, ACRA stats, ACRA
    median ms per frame (F,), ACRA's output display (`Shown`))``."""
    from pipeline import usdio

    with tempfile.TemporaryDirectory(prefix="acra-shrinkwrap-") as tmp:
        work = Path(tmp)
        if src.suffix == ".py":  # build a copy, so nothing is written into the repository
            shutil.copy(src, work / src.name)
            stage_path = usdio.load_scene_file(work / src.name)
        else:
            stage_path = src
        if samples is not None:
            stage_path = with_samples(stage_path, samples, work)
        keyed = export_keyed(stage_path, frames)
        sw = run_blender(python, keyed, work, repeats, wrap_method)
        stats, ms_acra, acra = run_acra(stage_path, keyed, work, acra_repeats)
    return keyed, sw, stats, ms_acra, acra


def revision() -> str:
    """The repository's short commit, with ``+changes`` when the work tree differs from it."""
    run = lambda *a: subprocess.run(["git", *a], cwd=REPO, capture_output=True, text=True).stdout.strip()  # noqa: E731
    head = run("rev-parse", "--short", "HEAD") or "unknown"
    return head + ("+changes" if run("status", "--porcelain", "--untracked-files=no", "--", "acra", "pipeline") else "")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", type=Path, help="scene file (.py) or USD stage (default: scenes/dog_head_spike.py, else scenes/box_into_sheet.py)")
    ap.add_argument("--frames", help="START:END inclusive (default: the stage's range)")
    ap.add_argument("--venv", type=Path, help="an existing venv with bpy (default: create .venv-blender/ once)")
    ap.add_argument("--repeats", type=int, default=7, help="Shrinkwrap evaluations per frame, median (default 7)")
    ap.add_argument("--acra-repeats", type=int, default=3, help="ACRA runs, median per frame (default 3)")
    ap.add_argument("--samples", type=int, help="set every deformable's acra:samples (steps per edge of the finest patch present) "
                    "to this for both methods (default: the stage's)")
    ap.add_argument("--wrap-method", default="NEAREST_SURFACEPOINT", choices=("NEAREST_SURFACEPOINT", "PROJECT", "TARGET_PROJECT"),
                    help="Shrinkwrap's wrap method (default %(default)s; PROJECT casts along the vertex normal both ways)")
    ap.add_argument("--no-doc", action="store_true", help="print only; do not update docs/shrinkwrap.md")
    args = ap.parse_args(argv)
    src = (args.scene or default_scene()).resolve()
    try:
        python = ensure_venv(args.venv)
    except (RuntimeError, subprocess.CalledProcessError) as exc:
        print(f"shrinkwrap: {exc}", file=sys.stderr)
        return 1

    t0 = time.perf_counter()
    keyed, sw, stats, ms_acra, acra = collect(src, args.frames, python, args.repeats, args.acra_repeats, args.samples,
                                              args.wrap_method)
    all_rows = compare(keyed, acra, shrinkwrap_shown(keyed, sw), ms_acra, sw["ms_modifier"])
    for r, s in zip(all_rows, stats):
        r.acra_own, r.hold = float(s.residual_rel), bool(s.hold)
    hit = [bool(r.keyed.count or s.in_collision) for r, s in zip(all_rows, stats)]
    rows = [r for r, h in zip(all_rows, hit) if h]
    quiet = [r for r, h in zip(all_rows, hit) if not h]

    rel = os.path.relpath(src, REPO) if src.is_relative_to(REPO) else str(src)
    command = "python3 benchmarks/shrinkwrap.py " + " ".join(
        shlex.quote(a) for a in [rel] + (["--frames", args.frames] if args.frames else [])
        + (["--samples", str(args.samples)] if args.samples else [])
        + (["--wrap-method", args.wrap_method] if args.wrap_method != "NEAREST_SURFACEPOINT" else [])
        + (["--repeats", str(args.repeats)] if args.repeats != 7 else [])
        + (["--acra-repeats", str(args.acra_repeats)] if args.acra_repeats != 3 else []))
    notes = {
        "machine": (
            f"{os.cpu_count()} cores (shared machine), Python {platform.python_version()}, Blender {sw['version']}, "
            f"ACRA at commit {revision()}; "
            f"ms per frame are medians: ACRA's whole frame (detect, respond, evaluate; `FrameStats.ms_total`) "
            f"over {args.acra_repeats} runs, Shrinkwrap's `Modifier.execution_time` over {args.repeats} evaluations "
            f"(whole `depsgraph.update()`: median {np.median(sw['ms_depsgraph']):.2f} ms; first evaluation of a frame: "
            f"median {np.median(sw['ms_cold']):.2f} ms)"
        ),
        "vertices": f"Shrinkwrap `wrap_method='{args.wrap_method}'`, `wrap_mode='OUTSIDE'`, `offset=0`: " + "; ".join(
            f"`{p}` ({len(keyed.def_points[i][0])} vertices) "
            + (("shrinkwrapped against " + ", ".join(f"`{keyed.tgt_paths[k]}` ({len(keyed.tgt_tris[k])} triangles)"
                                                     for k in keyed.targets_of(i))) if keyed.targets_of(i) else "not modified (the stiffer one)")
            for i, p in enumerate(keyed.def_paths)),
        "size": ", ".join(f"{p} {size_of(keyed.def_points[i][0]):.3g}" for i, p in enumerate(keyed.def_paths)) + " units at the first frame",
        "samples": len(face_samples(np.eye(3), np.array([[0, 1, 2]]))),
        "acra_vertices": ", ".join(f"{p} {len(acra.points[i][0])} vertices, {len(acra.welds[i].triangles)} triangles welded, against "
                                   f"{len(keyed.def_points[i][0])} and {len(keyed.def_weld[i].triangles)} keyed"
                                   for i, p in enumerate(keyed.def_paths)),
    }
    name = src.stem + (f"-samples{args.samples}" if args.samples else "") + (f"-frames{args.frames}" if args.frames else "")
    name += "" if args.wrap_method == "NEAREST_SURFACEPOINT" else f"-{args.wrap_method.lower()}"
    text = section(name, command, rows, quiet, notes)
    print(text)
    print(f"({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    if not args.no_doc:
        update_doc(DOC, name, text)
        print(f"updated {DOC.relative_to(REPO)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
