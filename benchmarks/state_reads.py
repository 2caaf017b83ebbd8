"""Reading the stage at each time code a run asks for (`usdio.state_at`), timed in a run.

    PYTHONPATH=$PWD python3 benchmarks/state_reads.py [SCENE.py] [--repeat 9]

Runs frame 5 and the collision frames 13-17 of ``SCENE`` (default `scenes/dog_head_spike.py`)
``--repeat`` times (`frames.run_frames`, a new run each time, after two untimed), with
`usdio.state_at` wrapped to sum its CPU time (`time.process_time`); prints its calls a run and
its CPU milliseconds per collision frame, median and range over the runs. A run asks for the
stage at its frames and at the sub-frames of its rewinds (`contact.rewind`), between the
geometry work that evicts USD's data from the caches, which is why a call costs more here than
in a loop of calls. The digest is of every world matrix and CVs array it handed back, so two
checkouts can be shown to read the same stage. ``--per-call`` also prints each call's CPU
microseconds in a run's order, median over the runs (the first call reads what the run holds,
`usdio.state_at`'s ``held``; frame 13's rewind asks for sub-frames, then frames 14-17 one call
each). The script imports `acra` and `pipeline` from ``PYTHONPATH``: run it with two checkouts'
paths, alternated, to compare them.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import pathlib
import statistics
import time

from pipeline import frames, usdio

ROOT = pathlib.Path(__file__).resolve().parents[1]
FRAMES = [5, 13, 14, 15, 16, 17]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene", nargs="?", type=pathlib.Path, default=ROOT / "scenes" / "dog_head_spike.py")
    parser.add_argument("--repeat", type=int, default=9)
    parser.add_argument("--per-call", action="store_true", help="each call's CPU microseconds in a run's order")
    args = parser.parse_args()
    stage_path = usdio.load_scene_file(args.scene)
    stage = usdio.open_input(stage_path)
    scene = usdio.read_scene(stage)
    state_at = usdio.state_at
    spent, calls, digest = [0.0], [0], hashlib.sha256()
    each: dict = {}  # a call's place in its run -> its CPU microseconds in each run

    def timed(*a, **kw):
        t = time.process_time()
        out = state_at(*a, **kw)
        dt = time.process_time() - t
        spent[0] += dt
        each.setdefault(calls[0], []).append(1e6 * dt)
        calls[0] += 1
        for s in out[0] + out[1]:
            digest.update(s.xform.tobytes())
        for s in out[0]:
            digest.update(s.surface.cvs.tobytes())
        return out

    usdio.state_at = timed
    per = []
    for i in range(args.repeat + 2):
        spent[0], calls[0] = 0.0, 0
        if i == 2:
            each.clear()
        frames.run_frames(stage, scene, FRAMES)
        if i >= 2:
            per.append(1e3 * spent[0] / (len(FRAMES) - 1))
    print(f"`python3 benchmarks/state_reads.py {args.scene.name} --repeat {args.repeat}`, load average {os.getloadavg()[0]:.1f} (1 min): "
          f"`state_at` {calls[0]} calls a run of frames {FRAMES}, CPU ms per collision frame "
          f"{statistics.median(per):.3f} ({min(per):.3f}–{max(per):.3f}); digest {digest.hexdigest()[:12]}")
    if args.per_call:
        print("each call, CPU us, median of the runs: " + " ".join(f"{statistics.median(v):.0f}" for _, v in sorted(each.items())))


if __name__ == "__main__":
    main()
