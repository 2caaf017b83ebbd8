"""Blender side of `benchmarks/shrinkwrap.py`: Shrinkwrap OUTSIDE on exported frames, timed.

Runs inside the Blender venv's python (``bpy`` + its own numpy, nothing from this project):

    .venv-blender/bin/python benchmarks/_blender_shrinkwrap.py IN.npz OUT.npz [--repeats N] [--wrap-method M]

IN.npz (written by `shrinkwrap.Keyed.save_npz`; Z up like Blender):

* ``frames (F,) int64``; ``n_deformables``, ``n_targets`` (0-d int64)
* ``def{i}_counts (f,) int64`` and ``def{i}_indices (sum counts,) int64`` the display's faces as
  USD's ``faceVertexCounts``/``faceVertexIndices`` (quads, and triangles where the display's
  density changes); ``def{i}_points (F, n, 3) float64`` keyed shape, world space (the object
  stays at the origin)
* ``def{i}_targets (k,) int64`` which targets deformable ``i`` is shrinkwrapped against
* ``target{k}_faces (t, 3) int64``; ``target{k}_points (1 or F, m, 3) float64`` object space (one
  sample: the shape never changes); ``target{k}_matrix (F, 4, 4) float64`` object-to-world,
  column-vector convention like `mathutils.Matrix`

Each deformable gets one Shrinkwrap modifier per target (``NEAREST_SURFACEPOINT``, ``OUTSIDE``,
offset 0): a vertex found inside a target goes to the nearest point of its surface, every other
vertex stays. With ``--wrap-method PROJECT`` a vertex is cast along its normal both ways and the
nearest hit is taken; ``TARGET_PROJECT`` casts along the target's normals. A target moves by its object matrix, as an animator keys it, so Blender keeps the
target's BVH tree between frames (as ACRA keeps its collider's) unless its shape changes.

OUT.npz: ``def{i}_points (F, n, 3) float64`` evaluated positions; ``ms_modifier (F,)`` median over
the repeats of the summed ``Modifier.execution_time`` of every Shrinkwrap (Blender's own timer of
the modifier's evaluation, nothing else); ``ms_cold (F,)`` the same for the first evaluation after
the frame's data changed; ``ms_depsgraph (F,)`` median wall time of the whole ``depsgraph.update()``;
``version`` Blender's version string.
"""

import argparse
import time

import bpy
import numpy as np
from mathutils import Matrix


def polygons(counts, indices):
    """Faces of ``counts (f,)`` vertices each, read in order from ``indices``: a list of lists."""
    return [list(map(int, face)) for face in np.split(np.asarray(indices, int), np.cumsum(counts)[:-1])]


def new_mesh_object(name, points, faces):
    """A mesh object at the world origin: ``points (n, 3)``, ``faces`` polygons (``(f, k)`` or a
    list of vertex lists)."""
    me = bpy.data.meshes.new(name)
    me.from_pydata(np.asarray(points, float).tolist(), [], [list(map(int, face)) for face in faces])
    me.update()
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def set_points(ob, points):
    """Overwrite the base mesh's vertex positions, ``points (n, 3)``."""
    ob.data.vertices.foreach_set("co", np.ascontiguousarray(points, np.float32).reshape(-1))
    ob.data.update()


def evaluated_points(ob, depsgraph):
    """Positions after the modifier stack: ``(n, 3) float64`` (identity object matrix)."""
    me = ob.evaluated_get(depsgraph).data
    out = np.empty(3 * len(me.vertices), np.float32)
    me.vertices.foreach_get("co", out)
    return out.reshape(-1, 3).astype(np.float64)


def modifier_ms(obs, depsgraph):
    """Summed ``execution_time`` of every modifier of ``obs`` in this evaluation, milliseconds."""
    return 1e3 * sum(m.execution_time for ob in obs for m in ob.evaluated_get(depsgraph).modifiers)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("inp")
    ap.add_argument("out")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--wrap-method", default="NEAREST_SURFACEPOINT", choices=("NEAREST_SURFACEPOINT", "PROJECT", "TARGET_PROJECT"))
    args = ap.parse_args()
    data = np.load(args.inp)
    frames = data["frames"]
    n_def, n_tgt = int(data["n_deformables"]), int(data["n_targets"])

    bpy.ops.wm.read_factory_settings(use_empty=True)
    targets = []
    for k in range(n_tgt):
        pts = data[f"target{k}_points"]
        targets.append((new_mesh_object(f"target{k}", pts[0], data[f"target{k}_faces"]), pts, data[f"target{k}_matrix"]))
    defs = []
    for i in range(n_def):
        pts = data[f"def{i}_points"]
        ob = new_mesh_object(f"def{i}", pts[0], polygons(data[f"def{i}_counts"], data[f"def{i}_indices"]))
        for k in data[f"def{i}_targets"]:
            m = ob.modifiers.new(f"shrinkwrap{k}", "SHRINKWRAP")
            m.target = targets[int(k)][0]
            m.wrap_method = args.wrap_method
            m.use_negative_direction = m.use_positive_direction = True  # PROJECT: both ways along the normal
            m.wrap_mode = "OUTSIDE"
            m.offset = 0.0
        defs.append((ob, pts))
    obs = [ob for ob, _ in defs]
    depsgraph = bpy.context.evaluated_depsgraph_get()

    out = {f"def{i}_points": np.zeros_like(pts) for i, (_, pts) in enumerate(defs)}
    ms_mod, ms_cold, ms_dg = (np.zeros(len(frames)) for _ in range(3))
    for f in range(len(frames)):
        for ob, pts, mats in targets:
            ob.matrix_world = Matrix(mats[f].tolist())
            if len(pts) > 1:
                set_points(ob, pts[f])
        for ob, pts in defs:
            set_points(ob, pts[f])
        depsgraph.update()
        ms_cold[f] = modifier_ms(obs, depsgraph)
        for i, ob in enumerate(obs):
            out[f"def{i}_points"][f] = evaluated_points(ob, depsgraph)
        mods, walls = [], []
        for _ in range(max(1, args.repeats)):
            for ob in obs:
                ob.update_tag(refresh={"DATA"})
            t0 = time.perf_counter()
            depsgraph.update()
            walls.append(1e3 * (time.perf_counter() - t0))
            mods.append(modifier_ms(obs, depsgraph))
        ms_mod[f], ms_dg[f] = np.median(mods), np.median(walls)
    np.savez(args.out, ms_modifier=ms_mod, ms_cold=ms_cold, ms_depsgraph=ms_dg, version=bpy.app.version_string, **out)


if __name__ == "__main__":
    main()
