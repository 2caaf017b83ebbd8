"""A collision frame's wall clock against its CPU time, in one process.

`acra bench` reports wall clock; the replays (`detection_split.py`, `residual_calls.py`, ...)
report CPU time. This runs the scene cold (`pipeline.run.forget`) ``--repeat`` times, alternating
`pipeline.frames`' clock between `time.perf_counter` (wall) and `time.process_time` (CPU), and
prints each run's median `FrameStats.ms_total` of its collision frames and its stages. Where the
two agree within the runs' spread, nothing in a frame waits (I/O, locks, other threads) and a
wall figure that moves is the machine's other load. Run with ``OPENBLAS_NUM_THREADS=1`` for CPU
figures without idle BLAS workers' spinning.

    PYTHONPATH=$PWD OPENBLAS_NUM_THREADS=1 python3 benchmarks/wall_cpu.py --repeat 8
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
import types
from pathlib import Path

STAGES = ("ms_setup", "ms_detect", "ms_convert", "ms_visible", "ms_output")


def measure(scene: Path, repeat: int) -> dict[str, list[tuple[float, dict[str, float]]]]:
    """Per clock (``"wall"``, ``"cpu"``), each run's median collision-frame ``ms_total`` and
    stage medians, the clocks alternated run by run (wall first)."""
    from pipeline import frames
    from pipeline.run import forget, run_file

    cpu = types.SimpleNamespace(perf_counter=time.process_time, process_time=time.process_time)
    out: dict = {"wall": [], "cpu": []}
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / scene.name
        src.write_text(scene.read_text())
        try:
            for i in range(repeat):
                kind = "cpu" if i % 2 else "wall"
                frames.time = cpu if kind == "cpu" else time
                forget()
                report = run_file(src, output=Path(tmp) / f"out{i}.acra.usdc")
                hit = [s for s in report.stats if s.in_collision]
                if not hit:
                    raise SystemExit(f"{scene.name}: no collision frame to measure")
                out[kind].append((statistics.median(s.ms_total for s in hit),
                                  {k: statistics.median(getattr(s, k) for s in hit) for k in STAGES}))
        finally:
            frames.time = time
    return out


def report(scene: Path, runs: dict) -> str:
    """A Markdown table of `measure`'s runs."""
    lines = [f"`{scene.name}`, collision frames, ms per frame (median over the frames of a run)", "",
             "| clock | runs' `ms_total` | median | " + " | ".join(k[3:] for k in STAGES) + " |",
             "|---|---|---:|" + "---:|" * len(STAGES)]
    for kind, rs in runs.items():
        totals = [t for t, _ in rs]
        stages = [statistics.median(st[k] for _, st in rs) for k in STAGES]
        lines.append(f"| {kind} | {', '.join(f'{t:.1f}' for t in totals)} | {statistics.median(totals):.1f} | "
                     + " | ".join(f"{x:.1f}" for x in stages) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", nargs="?", default=str(Path(__file__).resolve().parents[1] / "scenes" / "dog_head_spike.py"))
    ap.add_argument("--repeat", type=int, default=8, help="runs, the clocks alternated (default 8)")
    args = ap.parse_args()
    scene = Path(args.scene)
    print(report(scene, measure(scene, max(2, args.repeat))))


if __name__ == "__main__":
    main()
