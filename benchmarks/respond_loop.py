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
`respond_calls.py` sums each call's least over its repeats. Last, the cyclic garbage collections
that start inside the calls (`gc.callbacks`), in the loop and replayed: per call, how many over
the passes, of which generations, and their CPU ms (the median collection's and the whole sum,
over the passes): a collection runs where the frame's allocations cross the collector's
threshold, and walks the young objects every stage of the frame left.
"""

from __future__ import annotations

import argparse
import collections
import gc
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
        where[0], n0 = ("loop", len(calls) - 1), len(events)
        c = time.process_time()
        try:
            return respond(*a, **k)
        finally:
            inside[-1].append(time.process_time() - c)
            note("loop", len(calls) - 1, n0, len(inside) > 1)

    rows, replayed = [], []
    nframes = 1
    events: list = []  # (phase, generation, CPU seconds) of each collection, from `gc.callbacks`
    where: list = [None]  # ("loop" | "replayed", call) while a call runs, else None
    collected: dict = collections.defaultdict(list)  # (where, call) -> [(generation, CPU ms)] past the first pass

    def watch(phase, info):
        if where[0] is not None:
            events.append((phase, info["generation"], time.process_time()))

    def note(tag: str, i: int, n0: int, counted: bool) -> None:
        # the collections that started and stopped inside call ``i``
        for (a, g, t0), (b, _, t1) in zip(events[n0::2], events[n0 + 1::2]):
            if counted and a == "start" and b == "stop":
                collected[(tag, i)].append((g, 1e3 * (t1 - t0)))
        del events[n0:]
        where[0] = None

    gc.callbacks.append(watch)
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
            for i, (a, k) in enumerate(calls):
                where[0], n0 = ("replayed", i), len(events)
                c = time.process_time()
                respond(*a, **k)
                once.append(time.process_time() - c)
                note("replayed", i, n0, len(inside) > 1)
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
    print(f"cyclic collections inside the calls over the {args.passes} passes (call: count, generations, "
          "median and summed ms CPU):")
    for tag in ("loop", "replayed"):
        cells = []
        for (t, i), got in sorted(collected.items()):
            if t == tag:
                gens = collections.Counter(g for g, _ in got)
                ms = [x for _, x in got]
                cells.append(f"call {i}: {len(got)}, gen {dict(sorted(gens.items()))}, "
                             f"{statistics.median(ms):.3f}, {sum(ms):.3f}")
        print(f"  {tag}: " + ("; ".join(cells) if cells else "none"))


if __name__ == "__main__":
    main()
