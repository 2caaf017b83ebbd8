"""The `acra.details.details` calls of a run's responses, replayed and timed.

    PYTHONPATH=$PWD python3 benchmarks/details_calls.py [--repeat 9]

Records the `acra.respond.respond` calls of `dog_head_spike` frames 13-17 (as
`benchmarks/respond_calls.py` does), runs them once recording every `details` call they make,
then replays those ``--repeat`` times and prints the CPU milliseconds per collision frame (the
least over the repeats of each call, summed). Run it with ``PYTHONPATH`` set to two checkouts to
compare.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np
from threadpoolctl import threadpool_limits

from acra import details as LD
from acra import respond as R

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from respond_calls import record  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=9)
    args = ap.parse_args()
    calls = record(ROOT / "scenes" / "dog_head_spike.py", 13, 17, 5)
    seen: list = []
    details = LD.details

    def recording(*a, **kw):
        seen.append((a, kw))
        return details(*a, **kw)

    with threadpool_limits(limits=1, user_api="blas"):
        LD.details = recording
        try:
            for a, kw in calls:
                R.respond(*a, **kw)
        finally:
            LD.details = details
        best = np.full(len(seen), np.inf)
        for _ in range(args.repeat):
            for n, (a, kw) in enumerate(seen):
                t = time.process_time()
                details(*a, **kw)
                best[n] = min(best[n], time.process_time() - t)
    print(f"{len(seen)} details calls of {len(calls)} respond calls, per collision frame: "
          f"{1e3 * best.sum() / 5:.2f} ms CPU (least of {args.repeat} per call, summed)")


if __name__ == "__main__":
    main()
