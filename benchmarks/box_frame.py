"""`box_into_sheet`'s computed collision frame (frame 11) in CPU time, stage by stage, and the rim
points' share of its conversion.

    PYTHONPATH=$PWD python3 benchmarks/box_frame.py [--repeat 9]

Runs frame 11 after frame 5 (once to load every kernel, then ``--repeat`` times, a fresh stage each
time) with the frame loop's clock read as the process's CPU time (``time.process_time``): on a
shared machine other processes' load counts far less than in wall-clock figures. Prints the frame's
CPU time and the frame loop's own split (`one_frame.stage_table`) (`FrameStats`: set-up, detection, conversion, response,
residual where the user looks), then the nested time inside the rim points
(`rim._rim_points`, `datapoints._rim_points` in a checkout without `pipeline.rim`) and the inside
tests and casts they ask (and, where the checkout has it, the bisection `rim._bisected`, which settles its points' sides itself: its inside tests
do not go through `detect.inside`), medians over the runs and their ranges. Another checkout's code runs with its own ``PYTHONPATH`` (functions it lacks are
left out), so two checkouts can be alternated.
"""

from __future__ import annotations

import argparse
import collections
import functools
import pathlib
import time

from one_frame import frame_runs, line, stage_table

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=9)
    args = ap.parse_args()
    time.perf_counter = time.process_time  # the frame loop's and the wrappers' clock

    from pipeline import detect as D

    try:
        from pipeline import rim as P
    except ImportError:  # a checkout whose rim is in `pipeline.datapoints`
        from pipeline import datapoints as P

    spent: dict = collections.defaultdict(float)
    depth = [0]  # inside `_rim_points`

    def timed(module, name: str, outer: bool = False) -> None:
        fn = getattr(module, name, None)
        if fn is None:
            return

        @functools.wraps(fn)
        def wrapper(*a, **k):
            if not outer and not depth[0]:
                return fn(*a, **k)
            depth[0] += outer
            t = time.process_time()
            try:
                return fn(*a, **k)
            finally:
                spent[name] += time.process_time() - t
                depth[0] -= outer

        setattr(module, name, wrapper)

    timed(P, "_rim_points", outer=True)
    for name in ("inside", "_cast"):
        timed(D, name)
    for name in ("_missing_neighbours", "_on_counted_faces", "_bisected"):
        timed(P, name)

    runs = frame_runs(ROOT / "scenes" / "box_into_sheet.py", 11, 5, args.repeat, reset=spent.clear,
                      collect=lambda: {k: 1e3 * v for k, v in spent.items()})
    stage_table("box_into_sheet frame 11", runs)
    for name in ("_rim_points", "inside", "_cast", "_missing_neighbours", "_on_counted_faces", "_bisected"):
        if any(name in r[2] for r in runs):
            line(f"in the rim: `{name}`" if name != "_rim_points" else f"`{P.__name__.split('.')[-1]}._rim_points`",
                 [r[2].get(name, 0.0) for r in runs])
    print(f"\nrounds {runs[0][1].iterations}, residual {runs[0][1].residual_rel:.3e} of the size")


if __name__ == "__main__":
    main()
