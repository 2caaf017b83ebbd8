"""A 240-frame shot on 1 and 2 Dask workers: wall time, speed-up, cluster start-up, merge.

    python3 benchmarks/farm.py [--jabs 8] [--workers 1 2] [--repeat 3] [--dir DIR]

The shot is the demo (`scenes/dog_head_spike.py`: a spike jabs a 7-level head) with the jab
repeated ``--jabs`` times, 30 frames each (keys at 30k + 1, 12, 15, 18, 30), so 240 frames of
which 40 are in collision. Each repeat runs, in this order: one process (`run.run_file`, no
Dask); then for each ``--workers`` N a fresh `LocalCluster` of N processes (`farm.run_frames`)
and `output_layer.write_output`; then the one-process run's records cut into parts of 30 frames
(`parts.write_part`) and `parts.merge_parts`. Every output must be byte-identical to the
one-process output (checked). Reported: medians over the repeats of wall seconds (end to end,
including writing the layer), cluster start-up (processes started and the pipeline imported on
every worker), frames (submit to last chunk gathered), assembly, write; and the merge (reading
the parts, checking, assembling, writing); and CPU seconds (the whole one-process run; each
worker's chunks, summed and the busiest worker's), which the machine's other load does not
change. The load average is printed before, during and after: on a shared machine it changes
the wall figures.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

from pipeline import authoring, farm, parts, usdio
from pipeline.run import run_file
from pipeline import output_layer
from pipeline.animation import usdkeys
from pipeline.frames import RunOptions
from scenes import dog_head_spike

JAB = ([1, 12, 15, 18, 30], [[0.1, 2.2, 0.15], [0.1, 1.5, 0.1], [0.1, 1.36, 0.08], [0.1, 1.5, 0.1], [0.1, 2.2, 0.15]])


def build(jabs: int):
    """The demo stage over ``30 * jabs`` frames, the spike's jab keyed once per 30 frames."""
    stage = authoring.new_stage(1, 30 * jabs, fps=24, up_axis="Z")
    cvs, hs = dog_head_spike.head()
    authoring.add_deformable(stage, "/World/Head", cvs, u_wrap="periodic", v_wrap="open", hierarchy=hs,
                             absorption=[0, 0, 0.2, 0.3, 0.5, 0, 0], rigidity=10, samples=6)
    cvs, hs = dog_head_spike.spike()
    mover = authoring.add_xform(stage, "/World/Jab")
    authoring.add_deformable(stage, "/World/Jab/Spike", cvs, u_wrap="periodic", v_wrap="open", hierarchy=hs,
                             absorption=[0, 0.5, 0.5], rigidity=80, samples=4)
    frames = [30 * k + f for k in range(jabs) for f in JAB[0]]
    values = [v for _ in range(jabs) for v in JAB[1]]
    usdkeys.key_translate(mover.GetPrim() if hasattr(mover, "GetPrim") else mover, "xyz", frames, values, interp="catmull_rom")
    return stage


def uptime() -> str:
    return "load average " + ", ".join(f"{x:.2f}" for x in os.getloadavg())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jabs", type=int, default=8)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--dir", type=Path, help="where the shot and outputs go (default: a temporary directory)")
    args = ap.parse_args()
    work = args.dir or Path(tempfile.mkdtemp(prefix="acra_farm_"))
    work.mkdir(parents=True, exist_ok=True)
    built = build(args.jabs)  # held: the root layer lives as long as its stage
    stage_path = usdio.export_layer(built.GetRootLayer(), work / "jabs.usda")
    stage = usdio.open_input(stage_path)
    scene, identity = usdio.read_scene(stage), parts.input_identity(stage)
    frames = list(range(scene.start, scene.end + 1))
    print(f"shot: {len(frames)} frames, {os.cpu_count()} cores; before: {uptime()}", flush=True)

    rows: dict = {}
    for r in range(args.repeat):
        t, cpu = time.perf_counter(), time.process_time()
        report = run_file(stage_path, work / "single.usda")
        rows.setdefault("one process", []).append({"wall": time.perf_counter() - t, "write": report.ms_write / 1e3,
                                                   "cpu": time.process_time() - cpu, "busiest": time.process_time() - cpu})
        reference = report.output.read_bytes()
        hit = sum(s.in_collision for s in report.stats)
        print(f"repeat {r + 1}: one process {rows['one process'][-1]['wall']:.1f} s, {hit} frames in collision ({uptime()})", flush=True)
        for n in args.workers:
            timings = farm.FarmTimings()
            t = time.perf_counter()
            result, _ = farm.run_frames(stage_path, identity, scene, frames, RunOptions(), workers=n, timings=timings)
            tw = time.perf_counter()
            out = output_layer.write_output(stage_path, work / f"workers{n}.usda", scene, result)
            end = time.perf_counter()
            assert out.read_bytes() == reference, f"{n} workers: output differs from one process"
            rows.setdefault(f"{n} workers", []).append({"wall": end - t, "startup": timings.startup, "frames": timings.frames,
                                                        "assemble": timings.assemble, "write": end - tw, "chunks": len(timings.chunks),
                                                        "cpu": sum(timings.cpu.values()), "busiest": max(timings.cpu.values())})
            print(f"repeat {r + 1}: {n} workers {end - t:.1f} s ({uptime()})", flush=True)
        part_dir = work / "parts"
        for old in part_dir.glob(f"*{parts.PART_SUFFIX}"):
            old.unlink()
        records = parts.records_from_result(report.result)
        for k in range(0, len(frames), 30):
            chunk = frames[k:k + 30]
            parts.write_part(part_dir, stage_path, identity, RunOptions(), {f: records[f] for f in chunk},
                             [s for s in report.stats if s.frame in set(chunk)])
        t = time.perf_counter()
        out, _, ms_write, _, _ = parts.merge_parts(part_dir, work / "merged.usda")
        merge = time.perf_counter() - t
        assert out.read_bytes() == reference, "merged parts differ from one process"
        rows.setdefault("merge of parts", []).append({"wall": merge, "write": ms_write / 1e3})

    med = lambda name, key: statistics.median(x[key] for x in rows[name])  # noqa: E731
    base = med("one process", "wall")
    print(f"\nafter: {uptime()}; medians of {args.repeat}; every output byte-identical to one process "
          f"({len(reference) / 1e6:.1f} MB .usda)")
    print(f"{'run':<18}{'wall s':>8}{'speed-up':>10}{'start-up s':>12}{'frames s':>10}{'assemble s':>12}{'write s':>9}"
          f"{'CPU s':>8}{'busiest CPU s':>15}")
    print(f"{'one process':<18}{base:>8.1f}{1.0:>10.2f}{'':>12}{'':>10}{'':>12}{med('one process', 'write'):>9.2f}"
          f"{med('one process', 'cpu'):>8.1f}{med('one process', 'busiest'):>15.1f}")
    for n in args.workers:
        name = f"{n} workers"
        print(f"{name:<18}{med(name, 'wall'):>8.1f}{base / med(name, 'wall'):>10.2f}{med(name, 'startup'):>12.1f}"
              f"{med(name, 'frames'):>10.1f}{med(name, 'assemble'):>12.2f}{med(name, 'write'):>9.2f}"
              f"{med(name, 'cpu'):>8.1f}{med(name, 'busiest'):>15.1f}   ({rows[name][0]['chunks']} chunks)")
    print("CPU s: CPU seconds of the frames (one process: the whole run; workers: their chunks, summed); "
          "busiest: the most any one worker spent, what bounds the frames on an idle machine")
    n_parts = len(range(0, len(frames), 30))
    print(f"{f'merge of {n_parts} parts':<18}{med('merge of parts', 'wall'):>8.1f}{'':>10}{'':>12}{'':>10}{'':>12}{med('merge of parts', 'write'):>9.2f}")


if __name__ == "__main__":
    main()
