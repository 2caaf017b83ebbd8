"""Signals sent to a running `acra run`: how each run ends.

    PYTHONPATH=$PWD python3 benchmarks/interrupts.py [--runs 40] [--seed 0]

Starts ``--runs`` real `acra run` processes of a 400-frame stage in contact every frame
(`tests/conftest.py`'s tiny stage and `interrupted_run`), each with SIGINT and SIGTERM at their default actions, and
sends SIGINT to the even runs and SIGTERM to the odd ones at a random moment (0-0.5 s, seeded)
after the first frame is reported, so the signals land anywhere in the frame loop, compiled
kernels included. Prints the count of each exit status and the last stderr line of any run that
did not end with 130 (SIGINT) or 143 (SIGTERM) and ``acra: interrupted; nothing written``, and
whether any file besides the input was left. The command line's contract (`docs/cli.md`,
*Interruption*) is every run 130 or 143 with that line and nothing written.
"""

from __future__ import annotations

import argparse
import collections
import pathlib
import random
import signal
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT / "tests"))
    from conftest import interrupted_run, write_tiny_stage

    rng = random.Random(args.seed)
    statuses: collections.Counter = collections.Counter()
    wrong = []
    with tempfile.TemporaryDirectory() as tmp:
        work = pathlib.Path(tmp)
        src = write_tiny_stage(work / "tiny.usda", frames=400, top=0.4, depth=0.2)
        for k in range(args.runs):
            sig = signal.SIGTERM if k % 2 else signal.SIGINT
            code, err, files = interrupted_run(src, work / "out.usda", sig, rng.uniform(0.0, 0.5))
            left = [name for name in files if name != src.name]
            statuses[code] += 1
            last = err.strip().splitlines()[-1] if err.strip() else ""
            want = 143 if sig == signal.SIGTERM else 130
            if code != want or last != "acra: interrupted; nothing written" or left:
                wrong.append((k, sig.name, code, last, left))
            for name in left:
                (work / name).unlink()
    print(f"{args.runs} runs: exit statuses {dict(sorted(statuses.items()))}; {len(wrong)} not as the contract says")
    for k, name, code, last, left in wrong:
        print(f"  run {k} ({name}): status {code}, last line {last!r}, files left {left}")


if __name__ == "__main__":
    main()
