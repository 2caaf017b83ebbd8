"""Each `pipeline.workers.both` call site of a run: one thread, a thread started per call, the
run's parked thread.

    PYTHONPATH=$PWD python3 benchmarks/second_thread.py [SCENE.py] [--runs 6]

Runs the scene (default ``scenes/dog_head_spike.py``) ``--runs`` times in each of three settings,
alternated in one process after one warm run, each run cold (`pipeline.run.forget`, a run's own
memo): ``one`` (`workers.threads` read as 1: both calls in the caller's thread), ``started``
(a thread started for each call: `workers.kept`'s parked thread left out) and ``parked`` (the
run's parked thread, `workers.kept`). The run keeps the process's numba thread count otherwise
(``NUMBA_NUM_THREADS`` unset: the machine's cores). Prints, per call site (the function that calls
`workers.both`: `residual.measure_frame`, `display.Displays.build`, the output layer's
`output_layer._SharedText._texts`) and setting, the calls a run makes and the wall and CPU
milliseconds (``time.perf_counter``, ``time.process_time``: both threads counted) they take a
run, median and range over the runs, those of the frame loop's frames and of its collision
frames apart; the collision frames' summed ``FrameStats.ms_total`` and
CPU time (every run's), and a digest of the output layer's bytes (the same in every run of every
setting). Wall time needs an idle second core to show what a second thread gains (give
``uptime`` with it); CPU time is the cost of the second thread on a loaded machine too.
"""

from __future__ import annotations

import argparse
import collections
import hashlib
import pathlib
import statistics
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", default=str(ROOT / "scenes" / "dog_head_spike.py"))
    ap.add_argument("--runs", type=int, default=6)
    args = ap.parse_args()
    from pipeline import workers
    from pipeline.run import forget, run_file

    if workers.threads() < 2:
        sys.exit("needs two threads or more: leave NUMBA_NUM_THREADS unset")
    from pipeline import display, frames, output_layer, residual

    parked, threads = workers._parked, workers.threads
    mode = {"now": None, "run": 0, "frame": None}  # "frame": the calls of the frame under way
    # mode -> call site -> run -> [(wall s, CPU s) of each call]
    times: dict = collections.defaultdict(lambda: collections.defaultdict(lambda: collections.defaultdict(list)))
    frame_cpu: dict = collections.defaultdict(lambda: collections.defaultdict(float))  # mode -> run -> CPU s
    run_times: dict = collections.defaultdict(list)  # mode -> the collision frames' summed ms_total of each run

    def timed(owner, name: str, label: str) -> None:
        call = getattr(owner, name)

        def wrapper(*args, **kwargs):
            w, c = time.perf_counter(), time.process_time()
            try:
                return call(*args, **kwargs)
            finally:
                where = "" if mode["frame"] is None else " (frames)"
                cost = (time.perf_counter() - w, time.process_time() - c)
                times[mode["now"]][label + where][mode["run"]].append(cost)
                if mode["frame"] is not None:
                    mode["frame"].append((label, cost))
        setattr(owner, name, wrapper)

    timed(residual, "measure_frame", "residual.measure_frame")
    timed(display.Displays, "build", "display.Displays.build")
    timed(output_layer._SharedText, "_texts", "output_layer._SharedText._texts")
    frame = frames._Run.frame

    def one_frame(self, f, result):
        c, mode["frame"] = time.process_time(), []
        try:
            st = frame(self, f, result)
        finally:
            calls, mode["frame"] = mode["frame"], None
        if st.in_collision and not st.hold:
            frame_cpu[mode["now"]][mode["run"]] += time.process_time() - c
            for label, cost in calls:
                times[mode["now"]][label + " (collision frames)"][mode["run"]].append(cost)
        return st
    frames._Run.frame = one_frame
    workers.threads = lambda: 1 if mode["now"] == "one" else threads()
    workers._parked = lambda: None if mode["now"] == "started" else parked()
    digests = set()
    with tempfile.TemporaryDirectory() as tmp:
        src = pathlib.Path(tmp) / pathlib.Path(args.scene).name
        src.write_text(pathlib.Path(args.scene).read_text())
        out = pathlib.Path(tmp) / "out.acra.usda"
        mode["now"] = "warm"
        run_file(src, output=out)
        for n in range(args.runs):
            mode["run"] = n
            for m in ("one", "started", "parked"):
                mode["now"] = m
                forget()
                report = run_file(src, output=out)
                run_times[m].append(sum(st.ms_total for st in report.stats if st.in_collision and not st.hold))
                digests.add(hashlib.sha1(out.read_bytes()).hexdigest()[:16])
    for m in ("one", "started", "parked"):
        for s, by_run in sorted(times[m].items()):
            runs = [by_run.get(n, []) for n in range(args.runs)]
            n = statistics.median(len(r) for r in runs)
            wall = [1e3 * sum(w for w, _ in r) for r in runs]
            cpu = [1e3 * sum(c for _, c in r) for r in runs]
            if n:
                print(f"{m:8s} {s:32s} {n:4.0f} calls  wall {statistics.median(wall):7.2f} ({min(wall):.2f}-{max(wall):.2f})"
                      f"  CPU {statistics.median(cpu):7.2f} ({min(cpu):.2f}-{max(cpu):.2f}) ms a run")
        r = run_times[m]
        print(f"{m:8s} collision frames' ms_total summed: {statistics.median(r):.1f} ({min(r):.1f}-{max(r):.1f})")
        r = [1e3 * frame_cpu[m][n] for n in range(args.runs)]
        print(f"{m:8s} collision frames' CPU summed: {statistics.median(r):.1f} ({min(r):.1f}-{max(r):.1f}): "
              + " ".join(f"{x:.1f}" for x in r))
    print("output digests:", sorted(digests))


if __name__ == "__main__":
    main()
