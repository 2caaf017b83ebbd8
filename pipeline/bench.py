"""`acra bench`: the thesis's Fig. 5.2 timing table, measured on this machine.

Runs a scene (default: `scenes/dog_head_spike.py`, the thesis's 30-frame dog head and spike)
``repeat + 1`` times in-process, each from a cold start (no cached shape data), and reports median
milliseconds per frame over the last ``repeat`` runs for each stage of Fig. 5.2 — set-up, detection, conversion to response
inputs, response of the large and the small object, USD writing — over the collision frames and
over the free frames, beside the thesis's figures (Pentium 150 MHz, 1998). The process's first run
is reported on its own line and judged against the same target: it also loads each compiled
kernel from numba's cache at the kernel's first call (about 80 ms over the demo's collision
frames, `benchmarks/frame_totals.py`), a cost a process pays once, which the medians of the later runs leave out and the
whole process (below) includes. Each collision frame's frame loop is listed too, since the
first touch costs about twice the contact's last frame. USD writing is the
default ``.usda`` text output and, in its own row, the binary ``.usdc`` (what ``-o NAME.usdc``
costs: the text writer's float formatting is the ``.usda`` floor, docs/cli.md). A free frame's
figure is the write of a layer of the free frames alone over their count, so a free frame is not
charged the conversion of the collision frames' new surfaces; a collision frame's is what the
collision frames add to the run's write: a layer of them with the free frames around them less a
layer of those free frames alone, over their count, the difference taken in CPU time and given
in wall clock at the writes' own ratio (`_writes`).
Then times ``acra run`` end to end in a fresh process (start-up included), writing ``.usda`` and
``.usdc`` in turn after one warm-up run, splits each process's wall clock into its phases (the
run's ``--report`` phases, `pipeline.run.run_file`; the interpreter's start and exit is the rest),
and checks the targets. With ``first_run`` (``acra bench`` does it unless ``--no-first-run``) it
also times one ``acra run`` as the first run after a fresh install: numba's cache directory
(``NUMBA_CACHE_DIR``) is an empty temporary one, so every compiled kernel is compiled once, as on a
machine where the package was just installed. Numbers are medians of one invocation; the machine
is shared, so compare ratios within one run.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["THESIS", "TARGETS", "Bench", "run_bench", "format_report", "default_scene"]

# Fig. 5.2: (stage, frames requiring it, wall-clock ms averaged over those frames)
THESIS = {
    "set-up": (5, "large 3919, small 12"),
    "detection": (30, "16"),
    "conversion": (4, "358"),
    "response, large": (4, "590"),
    "response, small": (4, "14"),
    "USD writing": (None, "—"),
}
# targets: ms per collision frame, ms per free frame (.usda, .usdc output), s end to end
TARGETS = {"collision frame": 10.0, "free frame": 2.0, "free frame, .usdc": 0.5, "end to end": 2.0}
# timed writes of each layer whose median a repeat takes (`_writes`): a collision frame's write is
# a difference of two layers' writes, and the median of five keeps a disturbed write out of it
WRITES = 5
# phases of one `acra run` process, in order (`pipeline.run.run_file`; "interpreter" is the rest of
# the process's wall clock: starting Python before the command line's first line, and exiting)
PHASES = {
    "interpreter": "interpreter start and exit",
    "imports": "imports",
    "scene": "scene build (running the scene file, exporting its stage)",
    "read": "reading and checking the stage",
    "frames": "frames",
    "write": "writing the output layer",
}


def default_scene() -> Path:
    return Path(__file__).resolve().parents[1] / "scenes" / "dog_head_spike.py"


@dataclass
class Bench:
    """Per-stage medians ``rows[stage] = (collision ms, free ms)``, frame counts, end-to-end s.

    ``frame_ms`` is a whole frame written as ``.usda`` (the default), ``frame_ms_usdc`` the same
    frame written as ``.usdc``; both ``(collision ms, free ms)``.
    """

    scene: Path
    rows: dict
    n_collision: int
    n_free: int
    frame_ms: tuple
    frame_ms_usdc: tuple
    end_to_end_s: float
    residual_rel: float
    large: str
    small: str
    repeat: int
    end_to_end_usdc_s: float = float("nan")
    startup: dict = field(default_factory=dict)  # phase -> (median s writing .usda, writing .usdc), `PHASES`
    first_run: tuple | None = None  # (wall s, CPU s) of one `acra run` -o .usdc with an empty numba cache
    holds: tuple = (0, float("nan"))  # (frames, median ms of their frame loop): frames that hold the previous frame
    first_in_process: tuple = (float("nan"), float("nan"))  # `frame_ms` of the process's first run, which loads the kernels
    per_frame: dict = field(default_factory=dict)  # collision frame -> (first run's ms_total, median of the later runs')


def _median(xs) -> float:
    return float(np.median(xs)) if len(xs) else float("nan")


def _first_run(src: Path, out: Path) -> tuple[float, float]:
    """Wall and CPU seconds (user and system) of one ``acra run src -o out`` whose numba cache
    directory is empty: every kernel it calls is compiled, as after a fresh install."""
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        subprocess.run([sys.executable, "-m", "pipeline.cli", "run", str(src), "-o", str(out), "--quiet",
                        "--over-tolerance", "warn"], check=True, capture_output=True, env=env)
        wall = time.perf_counter() - t
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def run_bench(scene: Path | None = None, repeat: int = 3, first_run: bool = False) -> Bench:
    """Measure the Fig. 5.2 table on ``scene`` (see the module docstring)."""
    from pipeline import usdio
    from pipeline import output_layer
    from pipeline.run import forget, run_file

    scene = Path(scene or default_scene()).resolve()
    per_stage: dict = {k: ([], []) for k in ("set-up", "detection", "conversion", "response, large",
                                             "response, small", "residual where the user looks", "display tessellation",
                                             "USD writing", "USD writing, .usdc")}
    frame_ms: tuple = ([], [])
    frame_ms_usdc: tuple = ([], [])
    hold_ms: list = []
    phases: dict = {fmt: {k: [] for k in PHASES} for fmt in ("usda", "usdc")}
    first_ms: tuple = ([], [])
    loop_ms: dict = {}
    worst = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / scene.name
        src.write_text(scene.read_text())
        for k in range(repeat + 1):
            forget()  # cold start: every run computes its own shapes and answers
            report = run_file(src, output=Path(tmp) / "out.acra.usda")
            large, small = _large_small(report)
            stage = usdio.open_input(report.stage_path)  # the input layer open, as in the run
            writes = _writes(output_layer, report, Path(tmp))
            del stage
            for s in report.stats:
                if not s.hold and s.in_collision:
                    loop_ms.setdefault(s.frame, []).append(s.ms_total)
                if k == 0:  # the process's first run: its kernel loads fall in its frames
                    if not s.hold:
                        first_ms[0 if s.in_collision else 1].append(s.ms_total + writes[0 if s.in_collision else 1, "usda"])
                    continue
                if s.hold:  # a hold takes the previous frame's answer (`frames.FrameStats.hold`): neither kind's cost
                    hold_ms.append(s.ms_total)
                    continue
                col = 0 if s.in_collision else 1
                write, write_usdc = writes[col, "usda"], writes[col, "usdc"]
                per_stage["set-up"][col].append(s.ms_setup)
                per_stage["detection"][col].append(s.ms_detect)
                per_stage["conversion"][col].append(s.ms_convert)
                per_stage["response, large"][col].append(s.ms_respond_by.get(large, 0.0))
                per_stage["response, small"][col].append(s.ms_respond_by.get(small, 0.0))
                per_stage["residual where the user looks"][col].append(s.ms_visible)
                per_stage["display tessellation"][col].append(s.ms_output)
                per_stage["USD writing"][col].append(write)
                per_stage["USD writing, .usdc"][col].append(write_usdc)
                frame_ms[col].append(s.ms_total + write)
                frame_ms_usdc[col].append(s.ms_total + write_usdc)
                worst = max(worst, s.residual_rel)
        n_col = sum(s.in_collision and not s.hold for s in report.stats)
        n_hold = sum(s.hold for s in report.stats)
        runs: dict[str, list[float]] = {"usda": [], "usdc": []}
        for k in range(repeat + 1):  # the first is a warm-up (file caches, bytecode), not timed
            for fmt in runs:  # interleaved, so both formats see the same load
                json_path = Path(tmp) / f"e2e.{fmt}.json"
                t = time.perf_counter()
                subprocess.run([sys.executable, "-m", "pipeline.cli", "run", str(src), "-o", str(Path(tmp) / f"e2e.acra.{fmt}"),
                                "--quiet", "--over-tolerance", "warn", "--report", str(json_path)], check=True, capture_output=True)
                wall = time.perf_counter() - t
                if k == 0:
                    continue
                runs[fmt].append(wall)
                split = json.loads(json_path.read_text())["phases"]
                for name in PHASES:
                    phases[fmt][name].append(wall - sum(split.values()) if name == "interpreter" else split.get(name, 0.0))
        first = _first_run(src, Path(tmp) / "first.acra.usdc") if first_run else None
    rows = {k: (_median(c), _median(f)) for k, (c, f) in per_stage.items()}
    return Bench(scene, rows, n_col, len(report.stats) - n_col - n_hold, (_median(frame_ms[0]), _median(frame_ms[1])),
                 (_median(frame_ms_usdc[0]), _median(frame_ms_usdc[1])), _median(runs["usda"]), worst, large, small, repeat,
                 _median(runs["usdc"]), {k: (_median(phases["usda"][k]), _median(phases["usdc"][k])) for k in PHASES},
                 first, (n_hold, _median(hold_ms)), (_median(first_ms[0]), _median(first_ms[1])),
                 {f: (ms[0], _median(ms[1:])) for f, ms in sorted(loop_ms.items())})


def _writes(output_layer, report, tmp: Path) -> dict:
    """Milliseconds per frame of writing ``report``'s result, ``{(col, fmt): ms}`` with ``col`` 0
    for a collision frame and 1 for a free frame, ``fmt`` "usda" or "usdc" (NaN where the scene has
    no frame of that kind). Holds are neither kind and written in neither.

    A free frame's is the wall clock of a layer of the free frames alone over their count. A
    collision frame's is what the collision frames add to the run's write: a layer of the
    collision frames with the free frames around them (the computed frame before and after each
    run of collision frames) less a layer of those free frames alone, over the collision frames'
    count. A frame's text formats only what differs from the frame before it, so that difference
    is the formatting of what the collision frames changed and of the free frame after them
    formatting the surface back, their bytes and their response's arrays, as in the run's layer;
    the whole display's first formatting and the layer's fixed costs fall in both layers and
    cancel. The difference is taken in CPU time, which other processes' load leaves alone (a
    difference of two wall clocks on a loaded machine is mostly the load's), and given in wall
    clock at the two layers' writes' own ratio of wall to CPU time, never below one over the
    threads a write may use (`pipeline.workers.threads`: a ``.usda`` layer's texts are formatted
    on two threads where two are allowed, so its wall clock can be below its CPU time, never
    below that share of it). Each figure is the median of `WRITES` writes,
    the layers alternated after one untimed write of each (a format's first write in a process
    loads what later ones reuse)."""
    from pipeline import workers

    order = [s.frame for s in sorted(report.stats, key=lambda s: s.frame) if not s.hold]
    hit = {s.frame for s in report.stats if not s.hold and s.in_collision}
    free = set(order) - hit
    near = {f for i, f in enumerate(order) if f in free and ((i > 0 and order[i - 1] in hit) or (i + 1 < len(order) and order[i + 1] in hit))}
    layers = {"free": free, "near": near, "both": near | hit}
    out = {}
    for fmt in ("usda", "usdc"):
        wall: dict = {k: [] for k in layers}
        cpu: dict = {k: [] for k in layers}
        for i in range(WRITES + 1):
            for k, frames in layers.items():
                w, c = _write_ms(output_layer, report, frames, tmp / f"{k}.acra.{fmt}")
                if i:
                    wall[k].append(w)
                    cpu[k].append(c)
        out[1, fmt] = _median(wall["free"]) / len(free) if free else float("nan")
        if hit:
            ratio = sum(wall["near"] + wall["both"]) / max(sum(cpu["near"] + cpu["both"]), 1e-12)
            out[0, fmt] = (_median(cpu["both"]) - _median(cpu["near"])) * max(ratio, 1.0 / workers.threads()) / len(hit)
        else:
            out[0, fmt] = float("nan")
    return out


def _write_ms(output_layer, report, frames: set, path: Path) -> tuple[float, float]:
    """Wall and CPU milliseconds of one write of a layer of only ``frames`` of ``report``'s
    result to ``path`` (its suffix picks the format); zeros for no frames. ``path`` must not
    exist, and is removed afterwards, untimed: replacing an earlier file would charge the write
    the freeing of that file's blocks (tens of ms wall for a 55 MB layer here)."""
    if not frames:
        return 0.0, 0.0
    part = output_layer.FramesResult({f: r for f, r in report.result.frames.items() if f in frames}, report.result.topologies)
    t, c = time.perf_counter(), time.process_time()
    output_layer.write_output(report.stage_path, path, report.scene, part)
    ms = 1e3 * (time.perf_counter() - t), 1e3 * (time.process_time() - c)
    path.unlink()
    return ms


def _large_small(report) -> tuple[str, str]:
    """Paths of the deformables with the most and the fewest stored CVs."""
    from acra.hspline import storage_size
    from pipeline import usdio

    sizes = {m.path: storage_size(usdio.surface_template(report.scene, m)) for m in report.scene.deformables}
    order = sorted(sizes, key=sizes.get)
    return order[-1], order[0]


def _ms(x: float, digits: int) -> str:
    """A median in ms, or "—" where the scene has no frame of that kind (a NaN median)."""
    return "—" if math.isnan(x) else f"{x:.{digits}f}"


def _frames(n: int, kind: str) -> str:
    return f"{n} {kind} frame{'' if n == 1 else 's'}"


def format_report(b: Bench) -> str:
    """The markdown report: Fig. 5.2 beside ours, then the targets."""
    lines = [
        f"`acra bench {b.scene.name}` — medians over {b.repeat} cold runs after the process's first, ms per frame "
        f"({_frames(b.n_collision, 'collision')}, {_frames(b.n_free, 'free')}); large = `{b.large}`, small = `{b.small}`",
        "",
        "| stage | ACRA here: collision frames | ACRA here: free frames | thesis Fig. 5.2 (frames: ms) |",
        "|---|---:|---:|---|",
    ]
    for stage, (c, f) in b.rows.items():
        n, ms = THESIS.get(stage, (None, "—"))
        lines.append(f"| {stage} | {_ms(c, 1)} | {_ms(f, 2)} | {'' if n is None else f'{n}: '}{ms} |")
    lines.append(f"| **whole frame** (USD writing .usda) | **{_ms(b.frame_ms[0], 1)}** | **{_ms(b.frame_ms[1], 2)}** | |")
    lines.append(f"| whole frame, `-o NAME.usdc` | {_ms(b.frame_ms_usdc[0], 1)} | {_ms(b.frame_ms_usdc[1], 2)} | |")
    if b.per_frame:  # a scene with collision frames: the first run's loads fall in them
        lines += ["", (f"The process's first run, left out of the medians above (it also loads each compiled kernel from "
                       f"numba's cache at the kernel's first call): collision frame {_ms(b.first_in_process[0], 1)} ms, "
                       f"free frame {_ms(b.first_in_process[1], 2)} ms (USD writing .usda).")]
        lines += ["", "Each collision frame's frame loop without writing (`FrameStats.ms_total`), ms:", "",
                  "| frame | the process's first run | later runs (median) |", "|---:|---:|---:|"]
        lines += [f"| {f} | {a:.1f} | {m:.1f} |" for f, (a, m) in b.per_frame.items()]
    if b.holds[0]:
        lines += ["", f"Holds, left out of both kinds: {b.holds[0]} frames whose input is the previous frame's bit for "
                      f"bit take its answer, {b.holds[1]:.2f} ms each (the frame loop's median, without writing)."]
    if b.startup:
        lines += ["", f"Whole process, `acra run {b.scene.name} --quiet`, median of {b.repeat} after a warm-up, s:", "",
                  "| phase | `-o NAME.usda` | `-o NAME.usdc` |", "|---|---:|---:|"]
        lines += [f"| {PHASES[k]} | {a:.3f} | {c:.3f} |" for k, (a, c) in b.startup.items()]
        lines.append(f"| **whole process** | **{b.end_to_end_s:.3f}** | **{b.end_to_end_usdc_s:.3f}** |")
    if b.first_run is not None:
        wall, cpu = b.first_run
        lines += ["", f"First run after a fresh install (`-o NAME.usdc`, numba's cache empty: every kernel compiled): "
                      f"{wall:.1f} s wall, {cpu:.1f} s CPU; later runs load the compiled kernels from the cache."]
    lines += ["", "| target | measured | goal | |", "|---|---:|---:|---|"]
    for name, got, goal in (
        ("collision frame", b.frame_ms[0], TARGETS["collision frame"]),
        ("collision frame, the process's first run", b.first_in_process[0], TARGETS["collision frame"]),
        ("free frame", b.frame_ms[1], TARGETS["free frame"]),
        ("free frame, `-o NAME.usdc`", b.frame_ms_usdc[1], TARGETS["free frame, .usdc"]),
        ("end to end", b.end_to_end_s, TARGETS["end to end"]),
        ("end to end, `-o NAME.usdc`", b.end_to_end_usdc_s, TARGETS["end to end"]),
    ):
        unit = "s" if name.startswith("end to end") else "ms"
        if math.isnan(got):  # the scene has no frame of this kind: nothing to judge
            lines.append(f"| {name} | — | ≤ {goal:g} {unit} | not measured: no {name.split(',')[0]} in this scene |")
            continue
        verdict = "met" if got <= goal else f"missed by {got / goal:.1f}×"
        lines.append(f"| {name} | {got:.2f} {unit} | ≤ {goal:g} {unit} | {verdict} |")
    lines.append(f"| residual penetration where the user looks (the display's certified bound) | {b.residual_rel:.2e} of size | ≤ 1e-3 | "
                 f"{'met' if b.residual_rel <= 1e-3 else 'missed'} |")
    return "\n".join(lines)


