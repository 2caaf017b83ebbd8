"""Each collision frame's detection, run by run: ``FrameStats.ms_detect`` of every warm run.

    NUMBA_NUM_THREADS=1 PYTHONPATH=$PWD python3 benchmarks/detect_frames.py [--repeat 7] [scene]

Runs the scene (default ``scenes/dog_head_spike.py``) ``--repeat`` times in one process, each run
cold (`pipeline.run.forget`), drops the first run (it loads the compiled kernels from numba's
cache) and prints per collision frame ``ms_detect`` of each later run, its range and median, and
the process CPU milliseconds of each later run. Run it from each checkout, alternated, to compare
one stage frame by frame (frame 13, the first touch, holds the rewinding search).
"""

from __future__ import annotations

import argparse
import pathlib
import statistics
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", default=str(ROOT / "scenes" / "dog_head_spike.py"))
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    from pipeline.run import forget, run_file

    scene = pathlib.Path(args.scene).resolve()
    rows: dict[int, list[float]] = {}
    cpu: list[float] = []
    with tempfile.TemporaryDirectory() as tmp:
        src = pathlib.Path(tmp) / scene.name
        src.write_text(scene.read_text())
        for i in range(max(2, args.repeat)):
            forget()
            t = time.process_time()
            report = run_file(src, output=pathlib.Path(tmp) / "out.acra.usda")
            if i == 0:
                continue
            cpu.append(1e3 * (time.process_time() - t))
            for st in report.stats:
                if st.in_collision and not st.hold:
                    rows.setdefault(st.frame, []).append(st.ms_detect)
    print("| frame | ms_detect, each warm run | range | median |\n|---:|---|---|---:|")
    for frame, runs in sorted(rows.items()):
        print(f"| {frame} | {' '.join(f'{x:.2f}' for x in runs)} | {min(runs):.2f}-{max(runs):.2f} | "
              f"{statistics.median(runs):.2f} |")
    print(f"\nrun CPU ms, each warm run: {' '.join(f'{x:.0f}' for x in cpu)}; median {statistics.median(cpu):.0f}")


if __name__ == "__main__":
    main()
