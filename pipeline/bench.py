"""`acra bench`: the thesis's Fig. 5.2 timing table, measured on this machine.

Runs a scene (default: `scenes/dog_head_spike.py`, the thesis's 30-frame dog head and spike)
``repeat`` times in-process, each from a cold start (no cached shape data), and reports median
milliseconds per frame for each stage of Fig. 5.2 — set-up, detection, conversion to response
inputs, response of the large and the small object, USD writing — over the collision frames and
over the free frames, beside the thesis's figures (Pentium 150 MHz, 1998). USD writing is the
default ``.usda`` text output; each run's result is also written as a binary ``.usdc`` (what
``-o NAME.usdc`` costs: the text writer's float formatting is the ``.usda`` floor, docs/cli.md).
Then times ``acra run`` end to end in a fresh process (start-up included), writing ``.usda`` and
``.usdc`` in turn, and judges the speed targets (`TARGETS`, docs/performance.md). Numbers are
medians of one invocation; the machine is shared, so compare ratios within one run.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
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
# the speed targets: ms per collision frame, ms per free frame, s end to end
TARGETS = {"collision frame": 10.0, "free frame": 2.0, "end to end": 3.0}


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


def _median(xs) -> float:
    return float(np.median(xs)) if len(xs) else float("nan")


def run_bench(scene: Path | None = None, repeat: int = 3) -> Bench:
    """Measure the Fig. 5.2 table on ``scene`` (see the module docstring)."""
    from pipeline import usdio
    from pipeline import output_layer
    from pipeline.run import run_file
    from pipeline.shape import _SHAPES as shape_cache

    scene = Path(scene or default_scene()).resolve()
    per_stage: dict = {k: ([], []) for k in ("set-up", "detection", "conversion", "response, large",
                                             "response, small", "display tessellation", "USD writing",
                                             "USD writing, .usdc")}
    frame_ms: tuple = ([], [])
    frame_ms_usdc: tuple = ([], [])
    worst = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / scene.name
        src.write_text(scene.read_text())
        for _ in range(repeat):
            shape_cache.clear()  # cold start: every run builds its own shape data
            report = run_file(src, output=Path(tmp) / "out.acra.usda")
            large, small = _large_small(report)
            write = report.ms_write / max(1, len(report.stats))
            stage = usdio.open_input(report.stage_path)  # the input layer open, as in the run
            tw = time.perf_counter()
            output_layer.write_output(report.stage_path, Path(tmp) / "out.acra.usdc", report.scene, report.result)
            del stage
            write_usdc = 1e3 * (time.perf_counter() - tw) / max(1, len(report.stats))
            for s in report.stats:
                col = 0 if s.in_collision else 1
                per_stage["set-up"][col].append(s.ms_setup)
                per_stage["detection"][col].append(s.ms_detect)
                per_stage["conversion"][col].append(s.ms_convert)
                per_stage["response, large"][col].append(s.ms_respond_by.get(large, 0.0))
                per_stage["response, small"][col].append(s.ms_respond_by.get(small, 0.0))
                per_stage["display tessellation"][col].append(s.ms_output)
                per_stage["USD writing"][col].append(write)
                per_stage["USD writing, .usdc"][col].append(write_usdc)
                frame_ms[col].append(s.ms_total + write)
                frame_ms_usdc[col].append(s.ms_total + write_usdc)
                worst = max(worst, s.residual_rel)
        n_col = sum(s.in_collision for s in report.stats)
        runs: dict[str, list[float]] = {"usda": [], "usdc": []}
        for _ in range(repeat):
            for fmt in runs:  # interleaved, so both formats see the same load
                t = time.perf_counter()
                subprocess.run([sys.executable, "-m", "pipeline.cli", "run", str(src), "-o", str(Path(tmp) / f"e2e.acra.{fmt}"),
                                "--quiet"], check=True, capture_output=True)
                runs[fmt].append(time.perf_counter() - t)
    rows = {k: (_median(c), _median(f)) for k, (c, f) in per_stage.items()}
    return Bench(scene, rows, n_col, len(report.stats) - n_col, (_median(frame_ms[0]), _median(frame_ms[1])),
                 (_median(frame_ms_usdc[0]), _median(frame_ms_usdc[1])), _median(runs["usda"]), worst, large, small, repeat,
                 _median(runs["usdc"]))


def _large_small(report) -> tuple[str, str]:
    """Paths of the deformables with the most and the fewest stored CVs."""
    from acra.hspline import storage_size
    from pipeline import usdio

    sizes = {m.path: storage_size(usdio.surface_template(report.scene, m)) for m in report.scene.deformables}
    order = sorted(sizes, key=sizes.get)
    return order[-1], order[0]


def format_report(b: Bench) -> str:
    """The markdown report: Fig. 5.2 beside ours, then the targets."""
    lines = [
        f"`acra bench {b.scene.name}` — medians over {b.repeat} cold runs, ms per frame "
        f"({b.n_collision} collision frames, {b.n_free} free frames); large = `{b.large}`, small = `{b.small}`",
        "",
        "| stage | ACRA here: collision frames | ACRA here: free frames | thesis Fig. 5.2 (frames: ms) |",
        "|---|---:|---:|---|",
    ]
    for stage, (c, f) in b.rows.items():
        n, ms = THESIS.get(stage, (None, "—"))
        lines.append(f"| {stage} | {c:.1f} | {f:.2f} | {'' if n is None else f'{n}: '}{ms} |")
    lines.append(f"| **whole frame** (USD writing .usda) | **{b.frame_ms[0]:.1f}** | **{b.frame_ms[1]:.2f}** | |")
    lines.append(f"| whole frame, `-o NAME.usdc` | {b.frame_ms_usdc[0]:.1f} | {b.frame_ms_usdc[1]:.2f} | |")
    lines += ["", "| target | measured | goal | |", "|---|---:|---:|---|"]
    for name, got, goal in (
        ("collision frame", b.frame_ms[0], TARGETS["collision frame"]),
        ("free frame", b.frame_ms[1], TARGETS["free frame"]),
        ("free frame, `-o NAME.usdc`", b.frame_ms_usdc[1], TARGETS["free frame"]),
        ("end to end", b.end_to_end_s, TARGETS["end to end"]),
        ("end to end, `-o NAME.usdc`", b.end_to_end_usdc_s, TARGETS["end to end"]),
    ):
        unit = "s" if name.startswith("end to end") else "ms"
        verdict = "met" if got <= goal else f"missed by {got / goal:.1f}×"
        lines.append(f"| {name} | {got:.2f} {unit} | ≤ {goal:g} {unit} | {verdict} |")
    lines.append(f"| residual penetration | {b.residual_rel:.2e} of size | ≤ 1e-3 | {'met' if b.residual_rel <= 1e-3 else 'missed'} |")
    return "\n".join(lines)


