"""The output layer's write, per frame, for each kind of frame and format, timed.

    PYTHONPATH=$PWD python3 benchmarks/layer_writes.py [SCENE.py] [--repeat 9]

Runs the scene once (`frames.run_frames`), then writes, as `acra bench` charges them, a layer of
its collision frames alone and a layer of its free frames alone (not the first frame), each as
``.usda`` and as ``.usdc`` (`output_layer.write_output`, each write to a new file, removed
untimed), two writes of each first untimed. Prints the CPU milliseconds (`time.process_time`)
per frame of the layer's kind, median and range over ``--repeat`` writes. The script imports
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
        kinds = {"collision": [s.frame for s in stats if s.in_collision and not s.hold],
                 "free": [s.frame for s in stats if not s.in_collision and not s.hold and s.frame != scene.start]}
        print(f"`python3 benchmarks/layer_writes.py {args.scene.name} --repeat {args.repeat}`: CPU ms per frame of the layer's kind, "
              f"median (range) of {args.repeat} writes; load average {os.getloadavg()[0]:.1f} (1 min)\n")
        print("| layer | frames | `.usda` | `.usdc` |\n|---|---:|---:|---:|")
        for kind, which in kinds.items():
            if not which:
                continue
            part = output_layer.FramesResult({f: r for f, r in result.frames.items() if f in set(which)}, result.topologies)
            cells = []
            for fmt in ("usda", "usdc"):
                times = []
                for i in range(args.repeat + 2):
                    out = pathlib.Path(tmp) / f"{kind}{i}.acra.{fmt}"
                    t = time.process_time()
                    output_layer.write_output(stage_path, out, scene, part)
                    ms = 1e3 * (time.process_time() - t) / len(which)
                    out.unlink()
                    if i >= 2:
                        times.append(ms)
                cells.append(f"{statistics.median(times):.3f} ({min(times):.3f}–{max(times):.3f})")
            print(f"| {kind} frames alone | {len(which)} | {cells[0]} | {cells[1]} |")


if __name__ == "__main__":
    main()
