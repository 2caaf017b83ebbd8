"""One frame of a scene in CPU time, stage by stage (`FrameStats`), with a digest of what it gave.

    PYTHONPATH=$PWD python3 benchmarks/one_frame.py [SCENE.py] [--frame 12] [--after 5] [--repeat 9]

Runs ``--frame`` after ``--after`` (a free frame, so every kernel is loaded and the run's
collider and display data are built as a run's first frame builds them), once untimed and then
``--repeat`` times, each from a fresh stage and an empty memo (`pipeline.run.forget`), with the
frame loop's clock read as the process's CPU time (``time.process_time``). Prints the frame's CPU
time and its `FrameStats` split, medians and ranges over the runs, then the frame's rounds and
residual and a digest of every `FrameStats` figure but the times: two checkouts agree on the
frame where their digests agree. Another checkout's code runs with its own ``PYTHONPATH``, so two
checkouts can be alternated. The default is the demo's frame 12: the spike's display comes
within the head's box and is measured, detection finds no contact, and the first round ends
the frame.
"""

from __future__ import annotations

import argparse
import hashlib
import pathlib
import statistics
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
STAGES = ("ms_setup", "ms_detect", "ms_convert", "ms_respond", "ms_visible", "ms_total")
TIMES = {"ms_setup", "ms_detect", "ms_convert", "ms_respond", "ms_respond_by", "ms_output", "ms_visible", "ms_total"}


def _digest(h, x) -> None:
    """``x`` (a `FrameStats` field's value) into the hash ``h``: arrays by dtype, shape and bytes,
    floats by their bits, containers item by item."""
    if isinstance(x, dict):
        for k in sorted(x, key=repr):
            _digest(h, repr(k))
            _digest(h, x[k])
    elif isinstance(x, (list, tuple)):
        for y in x:
            _digest(h, y)
    elif isinstance(x, np.ndarray):
        h.update(repr((x.dtype.str, x.shape)).encode())
        h.update(np.ascontiguousarray(x).tobytes())
    elif isinstance(x, float):
        h.update(np.float64(x).tobytes())
    else:
        h.update(repr(x).encode())


def frame_runs(scene: pathlib.Path, frame: int, after: int, repeat: int, reset=None, collect=None) -> list:
    """``repeat`` timed runs of ``frame`` after ``after`` (each from a fresh stage and an empty
    memo), after one untimed run: a list of ``(ms, FrameStats, collected)``, the frame's CPU ms
    (`respond_frames`), its statistics and what ``collect()`` returns after it (None without
    ``collect``); ``reset()`` runs just before each frame is timed. The frame loop's clock must be
    the process's CPU time (the caller sets ``time.perf_counter``)."""
    from pipeline import frames as F
    from pipeline import usdio
    from pipeline.run import forget

    def once():
        forget()
        stage = usdio.open_input(usdio.load_scene_file(scene))
        model = usdio.read_scene(stage)
        F.run_frames(stage, model, [after])
        if reset is not None:
            reset()
        t = time.process_time()
        _, stats = F.respond_frames(stage, model, [frame])
        return 1e3 * (time.process_time() - t), stats[0], (collect() if collect is not None else None)

    once()
    return [once() for _ in range(repeat)]


def line(label: str, values: list) -> None:
    """One table row: ``label``, the median and range of ``values``."""
    print(f"| {label} | {statistics.median(values):.2f} | {min(values):.2f}–{max(values):.2f} |")


def stage_table(title: str, runs: list) -> None:
    """The heading ``title`` and the rows of the frame's CPU ms and its `FrameStats` split over ``runs``
    (`frame_runs`)."""
    print(f"{title}, ms CPU, median and range of {len(runs)} runs\n")
    print("| part | median | range |\n|---|---:|---:|")
    line("frame (`respond_frames`)", [r[0] for r in runs])
    for key in STAGES:
        line(f"`FrameStats.{key}`", [getattr(r[1], key) for r in runs])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", type=pathlib.Path, default=ROOT / "scenes" / "dog_head_spike.py")
    ap.add_argument("--frame", type=int, default=12)
    ap.add_argument("--after", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=9)
    args = ap.parse_args()
    time.perf_counter = time.process_time  # the frame loop's clock

    runs = frame_runs(args.scene, args.frame, args.after, args.repeat)
    stage_table(f"{args.scene.name} frame {args.frame} after {args.after}", runs)
    st = runs[0][1]
    h = hashlib.sha1()
    for k, v in vars(st).items():
        if k not in TIMES:
            _digest(h, k)
            _digest(h, v)
    print(f"\nin collision {st.in_collision}, rounds {st.iterations}, residual {st.residual_rel:.3e} of the size; "
          f"statistics {h.hexdigest()[:12]}")


if __name__ == "__main__":
    main()
