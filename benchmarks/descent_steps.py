"""The finer-level steps of the response's moves, counted: what `acra.details.moved_details` evaluates.

    python3 benchmarks/descent_steps.py [SCENE.py] [--frames 13:17]

Records the `acra.respond.respond` calls of the frames as `benchmarks/respond_calls.py` does, then
replays them once after `pipeline.run.forget` (a cold run of the frames) with
`levelkernels.stale_rows` watched: each call is one finer level of a move followed down the levels
(`moved_details` asks it once for every level below the moved one that has movable CVs, while a
coarser level's vectors changed bits). Prints, per collision frame, the moves followed
(`moved_details` calls) and those level steps, then every step in order as ``level: stale / movable``
coarse to fine (the frames evaluated among the level's movable CVs, ``+ring`` where one of them is on a pole ring
and takes its end's one normal, `details._end_normal`), and a digest of the responded surfaces
(`respond_calls.surface_arrays`), which watching does not change.
"""

from __future__ import annotations

import argparse
import hashlib
import pathlib
import sys

import numpy as np
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import respond_calls as RC  # noqa: E402

from acra import details as D  # noqa: E402
from acra import levelkernels  # noqa: E402
from acra import respond as R  # noqa: E402
from pipeline import run  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", default=str(ROOT / "scenes" / "dog_head_spike.py"))
    ap.add_argument("--frames", default="13:17")
    args = ap.parse_args()
    first, last = (int(x) for x in args.frames.split(":"))
    calls = RC.record(pathlib.Path(args.scene), first, last, 5)
    steps, moves = [], [0]
    stale_rows, moved_details = levelkernels.stale_rows, D.moved_details

    def watched_rows(stale, centre, ring, ends, every, pending):
        pos = stale_rows(stale, centre, ring, ends, every, pending)
        steps.append((every.size, pos.size, bool(np.any(ring[pos] >= 0))))
        return pos

    def watched_details(old, old_det, new, level):
        moves[0] += 1
        steps.append(("move", level))
        return moved_details(old, old_det, new, level)

    digest = hashlib.sha256()
    levelkernels.stale_rows, D.moved_details = watched_rows, watched_details
    try:
        with threadpool_limits(limits=1, user_api="blas"):
            run.forget()
            for a, kw in calls:
                for x in RC.surface_arrays(*R.respond(*a, **kw)):
                    digest.update(np.ascontiguousarray(x).tobytes())
    finally:
        levelkernels.stale_rows, D.moved_details = stale_rows, moved_details
    nframes = last - first + 1
    level_steps = [s for s in steps if s[0] != "move"]
    print(f"{len(calls)} respond calls, per collision frame: {moves[0] / nframes:.1f} moves followed, "
          f"{len(level_steps) / nframes:.1f} finer-level steps, {sum(s[1] for s in level_steps) / nframes:.1f} frames evaluated")
    head, line = None, []
    for s in steps + [("move", None)]:
        if s[0] == "move":
            if head is not None:
                print(f"  move of level {head}: " + (", ".join(line) or "no finer step"))
            head, line = s[1], []
            continue
        line.append(f"{s[1]} / {s[0]}{' +ring' if s[2] else ''}")
    print("surfaces digest", digest.hexdigest()[:12])


if __name__ == "__main__":
    main()
