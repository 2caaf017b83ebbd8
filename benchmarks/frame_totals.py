"""Each collision frame's whole cost, frame by frame, a process's first run apart from the rest.

    PYTHONPATH=$PWD python3 benchmarks/frame_totals.py [--repeat 3] [scene]

Runs the scene (default ``scenes/dog_head_spike.py``) ``--repeat`` times in one process, each run
cold (`pipeline.run.forget`), and prints per collision frame the frame loop's
``FrameStats.ms_total`` of every run and the part no stage counts (the total less set-up,
detection, conversion, the responses, the residual where the user looks and the run's display).
The first run of a process loads the compiled kernels from numba's cache as it first calls
them; the later runs do not. `acra bench`'s whole collision frame is one median over all the
runs' collision frames, which mixes frames that cost 2:1 (the first touch against the last
frame of a contact) with the first run's loads: this splits them, so a change that the median
hides shows frame by frame. Run it from each checkout, alternated, and compare the sums.
"""

from __future__ import annotations

import argparse
import pathlib
import statistics
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]


def frame_totals(scene: pathlib.Path, repeat: int) -> dict[int, list[tuple[float, float]]]:
    """``{frame: [(ms_total, unstaged ms), ...]}`` of each computed collision frame, one pair a run,
    in run order."""
    from pipeline.run import forget, run_file

    rows: dict[int, list[tuple[float, float]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        src = pathlib.Path(tmp) / scene.name
        src.write_text(scene.read_text())
        for _ in range(repeat):
            forget()
            report = run_file(src, output=pathlib.Path(tmp) / "out.acra.usda")
            for st in report.stats:
                if st.in_collision and not st.hold:
                    staged = (st.ms_setup + st.ms_detect + st.ms_convert + sum(st.ms_respond_by.values())
                              + st.ms_visible + st.ms_output)
                    rows.setdefault(st.frame, []).append((st.ms_total, st.ms_total - staged))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", default=str(ROOT / "scenes" / "dog_head_spike.py"))
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    rows = frame_totals(pathlib.Path(args.scene).resolve(), max(2, args.repeat))
    print("| frame | ms_total, each run | not in a stage, each run |")
    print("|---:|---|---|")
    for frame, runs in sorted(rows.items()):
        print(f"| {frame} | {' '.join(f'{t:.1f}' for t, _ in runs)} | {' '.join(f'{u:.2f}' for _, u in runs)} |")
    first = sum(runs[0][0] for runs in rows.values())
    later = sum(statistics.median(t for t, _ in runs[1:]) for runs in rows.values())
    print(f"\ncollision frames summed: the first run {first:.1f} ms; the later runs, each frame's median, {later:.1f} ms")


if __name__ == "__main__":
    main()
