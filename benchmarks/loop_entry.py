"""The fixed cost of a call of the frame loop: `frames.respond_frames` of no frames, CPU time.

    PYTHONPATH=$PWD python3 benchmarks/loop_entry.py [--repeat 200]

Reads `dog_head_spike`, calls `respond_frames` with an empty frame list once untimed, then
``--repeat`` more times, and prints the median and least CPU milliseconds a call
(``time.process_time``): what a call costs before and around its frames, the BLAS limit
(`display._blas`) among it. The last line is a digest of the calls' answers (no frame results,
no statistics): two checkouts answer alike when their digests agree. Run it with ``PYTHONPATH``
set to another checkout, alternating, to compare.
"""

from __future__ import annotations

import argparse
import hashlib
import pathlib
import statistics
import time

from pipeline import frames, usdio

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=200)
    args = ap.parse_args()
    stage = usdio.open_input(usdio.load_scene_file(ROOT / "scenes" / "dog_head_spike.py"))
    scene = usdio.read_scene(stage)
    frames.respond_frames(stage, scene, [])  # warm: the process's BLAS controller built
    spent, digest = [], hashlib.sha1()
    for _ in range(args.repeat):
        t = time.process_time()
        result, stats = frames.respond_frames(stage, scene, [])
        spent.append(time.process_time() - t)
        digest.update(repr((sorted(result.frames), len(stats))).encode())
    print(f"respond_frames of no frames, CPU ms a call over {args.repeat}: median {1e3 * statistics.median(spent):.3f}, "
          f"least {1e3 * min(spent):.3f}")
    print(f"answers {digest.hexdigest()[:12]}")


if __name__ == "__main__":
    main()
