"""The responses inside the frame loop against the same calls replayed, in one process, CPU time.

    PYTHONPATH=$PWD python3 benchmarks/respond_loop.py [--passes 8]

Runs `dog_head_spike` frames 13–17 after frame 5 ``--passes`` + 1 times (each after
`pipeline.run.forget`; the first pass loads the kernels and is not counted) and, after each pass,
calls `acra.respond.respond` again on every argument set the pass gave it (after `forget`, as
`benchmarks/respond_calls.py` replays them, BLAS on one thread). Prints, as ms CPU a collision
frame (`time.process_time`), the median (range) over the passes of: the frame loop's response row
(`FrameStats.ms_respond`, `pipeline.frames._Run.respond`'s clock), the `respond` calls inside it,
the part of the row around them (the data points gathered, the parent's details looked up,
`pipeline.shape.seed_details`, the carried state) and the same calls replayed; then each call's
median in the loop and replayed. A pass's sum is its calls' one run each, where
`respond_calls.py` sums each call's least over its repeats.
"""

from __future__ import annotations

import argparse
import pathlib
import statistics
import time

import numpy as np
from threadpoolctl import threadpool_limits

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--passes", type=int, default=8)
    args = ap.parse_args()
    time.perf_counter = time.process_time  # the frame loop's clock, as `detection_split.py` sets it

    from acra import respond as R
    from pipeline import frames as F
    from pipeline import usdio
    from pipeline.run import forget

    respond = R.respond
    calls: list = []
    inside: list = []

    def recording(*a, **k):
        calls.append((a, k))
        c = time.process_time()
        try:
            return respond(*a, **k)
        finally:
            inside[-1].append(time.process_time() - c)

    rows, replayed = [], []
    nframes = 1
    for _ in range(args.passes + 1):
        forget()
        stage = usdio.open_input(usdio.load_scene_file(ROOT / "scenes" / "dog_head_spike.py"))
        scene = usdio.read_scene(stage)
        F.run_frames(stage, scene, [5])
        calls.clear()
        inside.append([])
        R.respond = recording
        try:
            _, stats = F.respond_frames(stage, scene, list(range(13, 18)))
        finally:
            R.respond = respond
        hit = [s for s in stats if s.ms_respond > 0]
        rows.append(sum(s.ms_respond for s in hit) / len(hit))
        once = []
        with threadpool_limits(limits=1, user_api="blas"):
            forget()
            for a, k in calls:
                c = time.process_time()
                respond(*a, **k)
                once.append(time.process_time() - c)
        replayed.append(once)
        nframes = len(hit)
    loop = 1e3 * np.array(inside[1:])
    again = 1e3 * np.array(replayed[1:])
    row = np.array(rows[1:])
    calls_loop = loop.sum(axis=1) / nframes
    calls_again = again.sum(axis=1) / nframes

    def cell(x) -> str:
        return f"{statistics.median(x):.2f} ({min(x):.2f}-{max(x):.2f})"

    print(f"dog_head_spike frames 13-17, ms CPU a collision frame, median (range) of {args.passes} passes")
    print(f"frame loop's respond row {cell(row)}; its respond calls {cell(calls_loop)}; "
          f"around them {cell(row - calls_loop)}; the calls replayed {cell(calls_again)}")
    print("each call, ms CPU (median): loop " + " ".join(f"{x:.3f}" for x in np.median(loop, axis=0)))
    print("                        replayed " + " ".join(f"{x:.3f}" for x in np.median(again, axis=0)))


if __name__ == "__main__":
    main()
