"""What a free frame costs, part by part, in CPU time: ``python3 benchmarks/free_frame.py [SCENE]``.

A free frame (no contact) of a run does three things: it evaluates the stage at the frame
(`usdio.state_at`: ``acra:cvs``, ``acra:enabled``, world transforms), runs detection's broad phase
(each deformable's world patch boxes, `geometry.SurfaceGeometry.boxes`, then the pair tests) and
hands back the display of its unchanged surface; the output layer then holds one more time
sample of each attribute. This measures, on ``SCENE`` (default `scenes/dog_head_spike.py`) after
one run of all its frames, medians over ``--repeat`` passes of CPU milliseconds per frame
(`time.process_time`, which a busy machine inflates far less than the wall clock):

* the whole free frame (`frames._Run.frame` on frames already known to be free), and inside it
  `state_at` (with the run's inputs that cannot vary in time, `_Run.held`) and the world boxes and
  size of the deformables' `SurfaceGeometry`;
* writing a layer that holds only the free frames, as ``.usda`` and ``.usdc``, over their count
  (each layer to a new file, as `acra bench` writes them);
  for comparison, a ``.usda`` layer of only the collision frames over theirs, and the run's whole
  ``.usda`` layer over all frames (`output_layer._SharedText` formats each repeated array once);
* the ``.usda`` text writer's floor: `Sdf.Layer.ExportToString` of a layer holding only the free
  frames' display ``points`` (then ``points`` and ``normals``) of every deformable; and the
  ``.usdc`` crate's: `Sdf.Layer.Export` of the second to a new ``.usdc`` file (every sample holds
  the one shared array of its attribute: the crate hashes each sample's array to find repeats).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE))

from pxr import Sdf  # noqa: E402

from pipeline import geometry
from pipeline import frames, output_layer, state, usdio  # noqa: E402


def cpu_ms(fn, n: int) -> float:
    """CPU milliseconds per call of ``fn()`` over ``n`` calls."""
    t = time.process_time()
    for _ in range(n):
        fn()
    return 1e3 * (time.process_time() - t) / n


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene", nargs="?", type=Path, default=HERE / "scenes" / "dog_head_spike.py")
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / args.scene.name
        shutil.copy(args.scene, src)
        stage_path = usdio.load_scene_file(src)
        stage = usdio.open_input(stage_path)
        scene = usdio.read_scene(stage)
        options = frames.RunOptions()
        all_frames = list(range(scene.start, scene.end + 1))
        result, stats = frames.run_frames(stage, scene, all_frames, options)
        free = [s.frame for s in stats if not s.in_collision and s.frame != scene.start]
        run = frames._Run(stage, scene, options, state.for_run(stage, scene, all_frames, options, None))
        run.frame(scene.start, output_layer.FramesResult())  # the first frame builds the shapes
        rows: dict[str, list[float]] = {k: [] for k in ("whole free frame", "state_at", "world boxes and size", "write .usda",
                                                        "write .usdc", "write .usda, collision frames (per collision frame)",
                                                        "write .usda, the run's layer (per frame)", "text writer, points",
                                                        "text writer, points + normals", "crate writer, points + normals")}
        part = output_layer.FramesResult({f: r for f, r in result.frames.items() if f in set(free)}, result.topologies)
        colliding = [s.frame for s in stats if s.in_collision]
        col_part = output_layer.FramesResult({f: r for f, r in result.frames.items() if f in set(colliding)}, result.topologies)
        for _ in range(args.repeat):
            sink = output_layer.FramesResult()
            frame_iter = iter(free * 3)
            rows["whole free frame"].append(cpu_ms(lambda: run.frame(next(frame_iter), sink), len(free) * 3))
            t_iter = iter(free * 3)
            rows["state_at"].append(cpu_ms(lambda: usdio.state_at(stage, scene, float(next(t_iter)), run.held), len(free) * 3))
            dstates, _ = run.states(float(free[0]))

            def boxes():
                for s in dstates:
                    geometry.SurfaceGeometry(s.surface, s.xform, density=options.density).size

            rows["world boxes and size"].append(cpu_ms(boxes, len(free) * 3))
            for fmt in ("usda", "usdc"):
                out = Path(tmp) / f"free.acra.{fmt}"
                out.unlink(missing_ok=True)  # a new file, as `acra bench` writes (no old blocks to free)
                rows[f"write .{fmt}"].append(cpu_ms(lambda: output_layer.write_output(stage_path, out, scene, part), 1) / len(free))
            out = Path(tmp) / "kind.acra.usda"
            if colliding:
                out.unlink(missing_ok=True)
                rows["write .usda, collision frames (per collision frame)"].append(
                    cpu_ms(lambda: output_layer.write_output(stage_path, out, scene, col_part), 1) / len(colliding))
            out.unlink(missing_ok=True)
            rows["write .usda, the run's layer (per frame)"].append(
                cpu_ms(lambda: output_layer.write_output(stage_path, out, scene, result), 1) / len(all_frames))
            for name, attrs in (("text writer, points", ("points",)), ("text writer, points + normals", ("points", "normals"))):
                layer = Sdf.Layer.CreateAnonymous("floor.usda")
                with Sdf.ChangeBlock():
                    for m in scene.deformables:
                        prim = Sdf.CreatePrimInLayer(layer, m.path)
                        for attr in attrs:
                            spec = Sdf.AttributeSpec(prim, attr, Sdf.ValueTypeNames.Point3fArray)
                            for f in free:
                                r = part.frames[f][m.path]
                                layer.SetTimeSample(spec.path, float(f), output_layer._checked_vec3f(m, part.topology(m), f, attr, getattr(r, attr)))
                rows[name].append(cpu_ms(layer.ExportToString, 1) / len(free))
            crate = Path(tmp) / "floor.usdc"
            crate.unlink(missing_ok=True)
            rows["crate writer, points + normals"].append(cpu_ms(lambda: layer.Export(str(crate)), 1) / len(free))
    load = os.getloadavg()
    print(f"`python3 benchmarks/free_frame.py {args.scene.name} --repeat {args.repeat}`: {len(free)} free frames, "
          f"CPU ms per free frame, medians of {args.repeat}; load average {load[0]:.1f} (1 min)\n")
    print("| part | CPU ms per free frame |\n|---|---:|")
    for name, values in rows.items():
        print(f"| {name} | {np.median(values) if values else float('nan'):.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
