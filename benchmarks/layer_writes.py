"""The output layer's write, per frame, for each kind of frame and format, timed.

    PYTHONPATH=$PWD python3 benchmarks/layer_writes.py [SCENE.py] [--repeat 9]

Runs the scene once (`frames.run_frames`), then writes a layer of its collision frames alone, a
layer of its free frames alone (not the first frame) and a layer of every computed frame, each as
``.usda`` and as ``.usdc`` (`output_layer.write_output`, each write to a new file, removed
untimed), the layers alternated, two writes of each first untimed. Prints the CPU milliseconds
(`time.process_time`) per frame of the layer's kind, median and range over ``--repeat`` writes,
and what `acra bench` charges a collision frame: the layer of every computed frame less the layer
of the free frames alone (the first frame included, as the run writes it), over the collision
frames' count, each pass's difference, median and range. The script imports
`acra` and `pipeline` from ``PYTHONPATH``: run it with two checkouts' paths, alternated, to
compare them on the same results.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import shutil
import statistics
import tempfile
import time

from pipeline import frames, output_layer, usdio

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene", nargs="?", type=pathlib.Path, default=ROOT / "scenes" / "dog_head_spike.py")
    parser.add_argument("--repeat", type=int, default=9)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        src = pathlib.Path(tmp) / args.scene.name
        shutil.copy(args.scene, src)
        stage_path = usdio.load_scene_file(src)
        stage = usdio.open_input(stage_path)  # the input layer open, as in a run
        scene = usdio.read_scene(stage)
        result, stats = frames.run_frames(stage, scene, list(range(scene.start, scene.end + 1)), frames.RunOptions())
        computed = [s.frame for s in stats if not s.hold]
        kinds = {"collision frames alone": [s.frame for s in stats if s.in_collision and not s.hold],
                 "free frames alone": [s.frame for s in stats if not s.in_collision and not s.hold and s.frame != scene.start],
                 "free frames and the first": [s.frame for s in stats if not s.in_collision and not s.hold],
                 "every computed frame": computed}
        kinds = {k: v for k, v in kinds.items() if v}
        print(f"`python3 benchmarks/layer_writes.py {args.scene.name} --repeat {args.repeat}`: CPU ms per frame of the layer's kind, "
              f"median (range) of {args.repeat} writes; load average {os.getloadavg()[0]:.1f} (1 min)\n")
        print("| layer | frames | `.usda` | `.usdc` |\n|---|---:|---:|---:|")
        times = {(k, fmt): [] for k in kinds for fmt in ("usda", "usdc")}
        for fmt in ("usda", "usdc"):
            for i in range(args.repeat + 2):
                for kind, which in kinds.items():
                    part = output_layer.FramesResult({f: r for f, r in result.frames.items() if f in set(which)}, result.topologies)
                    out = pathlib.Path(tmp) / f"layer{i}.acra.{fmt}"
                    t = time.process_time()
                    output_layer.write_output(stage_path, out, scene, part)
                    ms = 1e3 * (time.process_time() - t)
                    out.unlink()
                    if i >= 2:
                        times[kind, fmt].append(ms)

        def cell(xs):
            return f"{statistics.median(xs):.3f} ({min(xs):.3f}–{max(xs):.3f})"

        for kind, which in kinds.items():
            print(f"| {kind} | {len(which)} | {cell([t / len(which) for t in times[kind, 'usda']])} | "
                  f"{cell([t / len(which) for t in times[kind, 'usdc']])} |")
        n_col = len(kinds.get("collision frames alone", []))
        if n_col and "free frames and the first" in kinds:
            share = [cell([(a - f) / n_col for a, f in zip(times["every computed frame", fmt], times["free frames and the first", fmt])])
                     for fmt in ("usda", "usdc")]
            print(f"| a collision frame's share of the run's write (`acra bench`) | {n_col} | {share[0]} | {share[1]} |")

if __name__ == "__main__":
    main()
