"""One `acra run` as a function: checks, the frames, and every output file written together.

`run_file` is what the command line (`pipeline.cli`), `acra bench` (`pipeline.bench`) and the
tests call. In order it

1. refuses an output path (``-o``, ``--rrd``, ``--report``) that is an input, before reading even
   the input's layer list, then against every layer the stage uses (`pipeline.guard`);
2. opens the stage and refuses one whose predicted memory exceeds the budget, before anything large
   is built (`guard.predict_memory`); the response's direct solves are bounded by the same budget
   while the run goes (`frames.RunOptions.memory_budget`);
3. runs the frames in this process (`frames.run_frames`) or as chunks on Dask (`pipeline.farm`),
   with answers kept across frames in a memo of the run's own (`acra.memo.scope`), dropped when
   the run ends;
4. writes the output layer (or a part file, `pipeline.parts`), the Rerun recording and the JSON
   report to hidden temporary siblings, and renames them into place together with SIGINT and
   SIGTERM held, so a run writes every file or none.
"""

from __future__ import annotations

import functools
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from acra import memo
from pipeline import guard, report
from pipeline import workers as second_core
from pipeline.model import InputError

__all__ = ["RunReport", "run_file", "frame_list", "refuse_outputs"]


def frame_list(arg: str | None, start: int, end: int) -> list[int]:
    """``--frames START:END`` (inclusive) as a list; ``None`` gives ``start..end``."""
    if arg is None:
        return list(range(start, end + 1))
    try:
        a, b = (int(x) for x in arg.split(":"))
    except ValueError:
        raise InputError("--frames", None, f"expected START:END with integers, got {arg!r}") from None
    if b < a:
        raise InputError("--frames", None, f"END {b} is before START {a}")
    return list(range(a, b + 1))


@dataclass
class RunReport:
    """What a run did: the output path, per-frame statistics, the write time, what was written.

    ``stage_path`` is the USD input read (the exported ``.usda`` of a scene file) and ``result`` the
    `output_layer.FramesResult` written, so a caller can write it again (``acra bench`` times ``.usdc``).
    ``over`` lists ``(frame, residual_rel)`` of the frames over tolerance
    (`report.frames_over_tolerance`) and ``status`` is the exit status they give (0 or 3).
    ``phases`` is the wall-clock seconds of the run's start-up and work, in order (`run_file`).
    """

    output: Path
    stats: list
    ms_write: float
    seconds: float
    scene: object = None
    stage_path: Path | None = None
    result: object = None
    over: list = field(default_factory=list)
    status: int = 0
    phases: dict = field(default_factory=dict)

    def summary(self) -> str:
        return report.summary_line(self.stats, self.ms_write, self.seconds, self.output)


def refuse_outputs(outputs: list, protected: list[Path]) -> None:
    """Refuse an output that is an input (`guard.refuse_overwrite`) or the same file as another
    output (one would overwrite the other). ``outputs``: ``(option, path or None)`` pairs."""
    for i, (option, path) in enumerate(outputs):
        guard.refuse_overwrite(option, path, protected)
        for other, earlier in outputs[:i]:
            if path is not None and earlier is not None and guard.same_file(path, earlier):
                raise InputError(option, None, f"{path} is also the {other} file; choose another path")


class _PhaseClock:
    """Wall-clock seconds per phase of a run, ``phases[name]``, in the order first reached; a
    phase named again adds the time since the last lap to its figure."""

    def __init__(self, t_start: float, imports_s: float | None) -> None:
        self.last = t_start
        self.phases: dict[str, float] = {"imports": float(imports_s or 0.0)}

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.phases[name] = self.phases.get(name, 0.0) + now - self.last
        self.last = now


def _check_farm_options(output, workers, scheduler, chunk, part) -> None:
    """Options of `pipeline.farm` and `pipeline.parts` that contradict each other or are out of
    range, before the input is read."""
    if part is not None and output is not None:
        raise InputError("--part", None, "writes a part file, not an output layer: drop -o (acra merge writes the layer)")
    if workers is not None or scheduler is not None:
        from pipeline import farm

        farm.require("--scheduler" if scheduler else "--workers")
        for name, value in (("--workers", workers), ("--chunk", chunk)):
            if value is not None and value < 1:
                raise InputError(name, None, f"must be at least 1, got {value}")
    elif chunk is not None:
        raise InputError("--chunk", None, "sets frames per Dask task: it needs --workers or --scheduler")


def forget() -> None:
    """Drop every answer kept across frames by the current memo (`acra.memo`): shapes and
    refinement tables, detection's answers, world data, layouts, casts and anchors, rims,
    topologies, digests, placements and chunk lists, responses' refinements, closed rings and
    solves' decompositions. Within a run they spare a frame what an earlier frame computed. A
    run of `run_file` keeps them in a memo of its own; frames run outside it (a test, a
    benchmark calling the frame loop) share the context's, and after `forget` the next frames
    compute everything as the first frames of a fresh process do, which is what a benchmark's
    repeated runs must measure."""
    memo.forget()


def _own_memo(run):
    """``run`` inside a memo of its own (`acra.memo.scope`): what its frames keep is the run's,
    dropped with it; a run after it, or beside it in another thread, starts from nothing. Its
    frames' second thread is parked between their calls and ended with it
    (`pipeline.workers.kept`)."""
    @functools.wraps(run)
    def in_scope(*args, **kwargs):
        with memo.scope(), second_core.kept():
            return run(*args, **kwargs)
    return in_scope


@_own_memo
def run_file(
    src: Path,
    output: Path | None = None,
    frames: str | None = None,
    iterations: int = 4,
    tolerance: float = 1e-3,
    rrd: Path | None = None,
    spawn: bool = False,
    progress: bool = False,
    method: str = "direct",
    density: int = 8,
    report_path: Path | None = None,
    memory_budget: str | None = None,
    over_tolerance: str = "fail",
    workers: int | None = None,
    scheduler: str | None = None,
    chunk: int | None = None,
    part: Path | None = None,
    imports_s: float | None = None,
) -> RunReport:
    """Everything `acra run` does but printing (docs/cli.md, docs/farm.md).

    ``over_tolerance`` (``fail`` or ``warn``) sets ``RunReport.status`` when frames stay over
    ``tolerance``; ``workers``/``scheduler``/``chunk`` run the frames on Dask (`pipeline.farm`);
    ``part`` writes a part file into that directory instead of the output layer
    (`pipeline.parts`, assembled by ``acra merge``).

    ``RunReport.phases`` splits the wall clock: ``imports`` (``imports_s``, what the command line
    spent importing before it called this, plus the frame loop's modules if not yet imported),
    ``scene`` (running a scene file and exporting its stage), ``read`` (opening, checking and
    reading the stage, the preview's set-up), ``frames`` (the frame loop, first frame included)
    and ``write`` (the output layer or part file and the recording), each ending where the next
    begins; ``RunReport.seconds`` ends with ``write``.
    """
    t_start = time.perf_counter()
    from pipeline import frames as frame_loop
    from pipeline import usdio
    from pipeline import output_layer

    clock = _PhaseClock(t_start, imports_s)
    src = Path(src)
    if iterations < 1:
        raise InputError("--iterations", None, f"must be at least 1, got {iterations}")
    if not np.isfinite(tolerance) or tolerance <= 0:
        raise InputError("--tolerance", None, f"must be a positive number, got {tolerance}")
    budget = guard.memory_budget(memory_budget)
    _check_farm_options(output, workers, scheduler, chunk, part)
    on_farm = workers is not None or scheduler is not None
    is_scene = src.suffix == ".py"
    stage_path = src.with_suffix(".usda") if is_scene else src
    out = Path(output) if output else stage_path.with_name(stage_path.stem + ".acra.usda")
    outputs = ([("-o", out)] if part is None else []) + [("--rrd", rrd), ("--report", report_path)]
    refuse_outputs(outputs, [src, stage_path])  # before reading even the input's layer list
    # the layers the walk of the input's dependencies loads, held until the stage opens on them:
    # each file is parsed once (`guard.protected_paths`)
    held: list = []
    if not is_scene:  # a scene file's build rewrites its .usda: its layers are walked once it has
        refuse_outputs(outputs, guard.protected_paths(src, held=held))
    clock.lap("imports")
    if is_scene:  # the exported stage may reference further layers
        stage_path = usdio.load_scene_file(src, held)
        refuse_outputs(outputs, guard.protected_paths(src, stage_path, held))
    clock.lap("scene")
    stage = usdio.open_input(stage_path)
    held.clear()  # the stage holds what it uses
    start, end = usdio.frame_range(stage)
    frames_run = frame_list(frames, start, end)
    guard.check_budget(guard.predict_memory(stage, len(frames_run)), budget)
    scene = usdio.read_scene(stage)
    guard.check_transforms(stage, scene, frames_run)
    identity = None
    if on_farm or part is not None:
        from pipeline import parts

        identity = parts.input_identity(stage)  # as read now: workers and merges check they see the same

    preview = rrd_tmp = None
    if rrd or spawn:
        from pipeline import preview as rerun_preview

        rrd_tmp = guard.temporary_sibling(rrd) if rrd else None
        preview = rerun_preview.Preview(scene, stage_path.stem, rrd=rrd_tmp, spawn=spawn, stage=stage, tolerance=tolerance)
    # every file goes to a hidden temporary sibling first; all are renamed over their targets at
    # the end with SIGINT/SIGTERM held (`guard.signals_held`), so a run either writes every file
    # or none, and an interruption removes the temporaries
    pending: list[tuple[Path, Path]] = []
    try:
        clock.lap("read")
        bar = report.Progress(len(frames_run)) if progress and len(frames_run) > 1 else None
        options = frame_loop.RunOptions(iterations, tolerance, method, density, budget)
        if on_farm:
            from pipeline import farm

            result, stats = farm.run_frames(stage_path, identity, scene, frames_run, options, workers, scheduler, chunk,
                                            (lambda n: bar.update(None, n)) if bar is not None else None)
        else:
            def on_frame(st, result) -> None:
                guard.raise_arrived()  # a signal whose exception was lost stops the run here
                if bar is not None:
                    bar.update(st.frame)

            result, stats = frame_loop.run_frames(stage, scene, frames_run, options, on_frame)
        if bar is not None:
            bar.close()
        for st in stats if preview is not None else ():  # the display is the run's: known after every frame
            preview.log_frame(st, result)
        over = report.frames_over_tolerance(stats, tolerance)
        status = report.EXIT_OVER_TOLERANCE if over and over_tolerance == "fail" else report.EXIT_OK
        clock.lap("frames")
        tw = time.perf_counter()
        if part is not None:  # written atomically by parts itself
            out = parts.write_part(part, stage_path, identity, options, parts.records_from_result(result), stats)
        else:
            out_tmp = guard.temporary_sibling(out)
            pending.append((out_tmp, out))
            output_layer.write_output(stage_path, out_tmp, scene, result)
        ms_write = 1e3 * (time.perf_counter() - tw)
        if preview is not None:
            preview.close()
            if rrd_tmp is not None:
                guard.flush_recording(preview)
                pending.append((rrd_tmp, rrd))
        # the run's seconds and its phases end at one instant, so the phases after the imports add
        # up to the seconds less the run's own imports; the report file's write and the renames
        # (a few ms) are in neither
        clock.lap("write")
        run_report = RunReport(out, stats, ms_write, clock.last - t_start, scene, stage_path, result, over, status,
                               clock.phases)
        if report_path is not None:
            pending.append((guard.temporary_sibling(report_path), report_path))
            report.write_json(pending[-1][0], report.report_dict(run_report, tolerance, over, status))
        with guard.signals_held():
            for tmp, final in pending:
                os.replace(tmp, final)
            pending.clear()
    finally:
        for tmp in [t for t, _ in pending] + [rrd_tmp]:
            if tmp is not None and tmp.exists():
                tmp.unlink()
    return run_report
