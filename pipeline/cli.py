"""`acra run INPUT [-o OUTPUT] [--frames START:END] [--rrd FILE | --spawn] [--iterations N] [--tolerance T]
[--over-tolerance fail|warn] [--report FILE.json] [--memory-budget SIZE] [--quiet]`, `acra --version`.

Contract §3 and docs/cli.md. Before anything is read, an output path (``-o``, ``--rrd``,
``--report``) that is an input is refused (`pipeline.guard`); before anything large is built, a
stage whose predicted memory exceeds the budget is refused. User errors print one line on stderr
and exit 2 with nothing written; every file is written atomically at the end; SIGINT and SIGTERM
stop the run with nothing written (130, 143); frames over tolerance exit 3 (`pipeline.report`).
"""

from __future__ import annotations

import argparse
import gc
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline import guard, report
from pipeline.model import InputError

__all__ = ["main", "build_parser", "run_file", "RunReport"]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="acra", description="Automatic collision response for key-framed H-spline objects.")
    p.add_argument("--version", action="version", version=f"acra {_version()}")
    sub = p.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="process a USD stage or a scene file and write the response layer")
    run.add_argument("input", type=Path, help="a USD stage (.usda/.usdc/.usd) or a scene file (.py)")
    run.add_argument("-o", "--output", type=Path, help="output layer (default: <input stem>.acra.usda beside the input)")
    run.add_argument("--frames", help="START:END, inclusive (default: the stage's time codes)")
    group = run.add_mutually_exclusive_group()
    group.add_argument("--rrd", type=Path, help="save a Rerun recording of the run")
    group.add_argument("--spawn", action="store_true", help="open the Rerun viewer live")
    run.add_argument("--iterations", type=int, default=4, help="cap on detect/respond rounds per frame (default 4)")
    run.add_argument("--tolerance", type=float, default=1e-3, help="accepted residual penetration, fraction of object size (default 1e-3)")
    run.add_argument("--over-tolerance", choices=("fail", "warn"), default="fail",
                     help="frames whose residual stays over --tolerance: exit 3 (fail, default) or only list them (warn)")
    run.add_argument("--report", type=Path, help="write the summary and per-frame figures as JSON to FILE")
    run.add_argument("--memory-budget", help="refuse stages predicted to need more memory (e.g. 8G; default half the "
                     "physical memory, or ACRA_MEMORY_BUDGET)")
    run.add_argument("--quiet", action="store_true", help="no progress")
    bench = sub.add_parser("bench", help="time the thesis's Fig. 5.2 stages on a scene (default: dog_head_spike)")
    bench.add_argument("scene", nargs="?", type=Path, help="scene file or stage (default scenes/dog_head_spike.py)")
    bench.add_argument("--repeat", type=int, default=3, help="cold runs to take medians over (default 3)")
    return p


def _version() -> str:
    """The installed package's version (package metadata), or ``unknown`` in a bare checkout."""
    from importlib import metadata

    try:
        return metadata.version("acra")
    except metadata.PackageNotFoundError:
        return "unknown"


def _frames(arg: str | None, start: int, end: int) -> list[int]:
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
    `usdio.FramesResult` written, so a caller can write it again (``acra bench`` times ``.usdc``).
    ``over`` lists ``(frame, residual_rel)`` of the frames over tolerance
    (`report.frames_over_tolerance`) and ``status`` is the exit status they give (0 or 3).
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

    def summary(self) -> str:
        return report.summary_line(self.stats, self.ms_write, self.seconds, self.output)


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
) -> RunReport:
    """Everything `acra run` does but printing, as a function (the tests and `acra bench` call
    it): checks, the frames, and the output layer, ``rrd`` recording and ``report_path`` JSON
    written together at the end. ``over_tolerance`` (``fail`` or ``warn``) sets
    ``RunReport.status`` when frames stay over ``tolerance``."""
    from pipeline import frames as F
    from pipeline import usdio

    t_start = time.perf_counter()
    src = Path(src)
    if iterations < 1:
        raise InputError("--iterations", None, f"must be at least 1, got {iterations}")
    if not np.isfinite(tolerance) or tolerance <= 0:
        raise InputError("--tolerance", None, f"must be a positive number, got {tolerance}")
    budget = guard.memory_budget(memory_budget)
    is_scene = src.suffix == ".py"
    stage_path = src.with_suffix(".usda") if is_scene else src
    out = Path(output) if output else stage_path.with_name(stage_path.stem + ".acra.usda")
    outputs = [("-o", out), ("--rrd", rrd), ("--report", report_path)]
    _refuse_outputs(outputs, [src, stage_path])  # before reading even the input's layer list
    _refuse_outputs(outputs, guard.protected_paths(src))
    if is_scene:  # the exported stage may reference further layers
        stage_path = usdio.load_scene_file(src)
        _refuse_outputs(outputs, guard.protected_paths(src, stage_path))
    stage = usdio.open_input(stage_path)
    start, end = usdio.frame_range(stage)
    frame_list = _frames(frames, start, end)
    guard.check_budget(guard.predict_memory(stage, len(frame_list)), budget)
    scene = usdio.read_scene(stage)
    guard.check_transforms(stage, scene, frame_list)

    preview = rrd_tmp = None
    if rrd or spawn:
        from pipeline import preview as P

        rrd_tmp = guard.temporary_sibling(rrd) if rrd else None
        preview = P.Preview(scene, stage_path.stem, rrd=rrd_tmp, spawn=spawn)
    # every file goes to a hidden temporary sibling first; all are renamed over their targets at
    # the end with SIGINT/SIGTERM held (`guard.signals_held`), so a run either writes every file
    # or none, and an interruption removes the temporaries
    pending: list[tuple[Path, Path]] = []
    try:
        bar = report.Progress(len(frame_list)) if progress and len(frame_list) > 1 else None

        def on_frame(st, result):
            if preview is not None:
                preview.log_frame(st, result)
            if bar is not None:
                bar.update(st.frame)

        result, stats = F.run_frames(stage, scene, frame_list, F.RunOptions(iterations, tolerance, method, density, budget), on_frame)
        if bar is not None:
            bar.close()
        over = report.frames_over_tolerance(stats, tolerance)
        status = report.EXIT_OVER_TOLERANCE if over and over_tolerance == "fail" else report.EXIT_OK
        tw = time.perf_counter()
        out_tmp = guard.temporary_sibling(out)
        pending.append((out_tmp, out))
        usdio.write_output(stage_path, out_tmp, scene, result)
        ms_write = 1e3 * (time.perf_counter() - tw)
        if preview is not None:
            preview.close()
            if rrd_tmp is not None:
                guard.flush_recording(preview)
                pending.append((rrd_tmp, rrd))
        run_report = RunReport(out, stats, ms_write, time.perf_counter() - t_start, scene, stage_path, result, over, status)
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


def _refuse_outputs(outputs: list, protected: list[Path]) -> None:
    """Refuse an output that is an input (`guard.refuse_overwrite`) or the same file as another
    output (one would overwrite the other)."""
    for i, (option, path) in enumerate(outputs):
        guard.refuse_overwrite(option, path, protected)
        for other, earlier in outputs[:i]:
            if path is not None and earlier is not None and guard.same_file(path, earlier):
                raise InputError(option, None, f"{path} is also the {other} file; choose another path")


def run(args: argparse.Namespace) -> int:
    """`acra run`: the summary line and the frames over tolerance; the exit status."""
    run_report = run_file(
        args.input, args.output, args.frames, args.iterations, args.tolerance,
        rrd=args.rrd, spawn=args.spawn, progress=not args.quiet,
        report_path=args.report, memory_budget=args.memory_budget, over_tolerance=args.over_tolerance,
    )
    print(run_report.summary())
    if run_report.over:
        line = report.over_tolerance_line(run_report.over, args.tolerance)
        print(line, file=sys.stderr if run_report.status else sys.stdout)
    return run_report.status


def bench(args: argparse.Namespace) -> int:
    from pipeline.bench import format_report, run_bench

    if args.repeat < 1:
        raise InputError("--repeat", None, f"must be at least 1, got {args.repeat}")
    print(format_report(run_bench(args.scene, args.repeat)))
    return 0


def _settle_imports(command: str) -> None:
    """Import what ``command`` will run, then move every object so far out of the cyclic GC's reach.

    ``gc.freeze`` keeps the collector from re-walking the ~90 000 long-lived objects the imports
    create (numpy, pxr, scipy, trimesh) at each full collection during the run (measured: 0.11 s of
    GC in a dog_head_spike run, 0.07 s after). For processes that are the command only.
    """
    if command == "run":
        from pipeline import frames, usdio  # noqa: F401
    gc.freeze()


def main(argv: list[str] | None = None) -> int:
    """The command line (contract §3); returns the exit status.

    ``argv=None`` means this process is the command (the ``acra`` script, ``python -m
    pipeline.cli``): then import-time objects are frozen out of the cyclic GC (`_settle_imports`),
    and so is everything at the end, so the interpreter's final collection does not walk trimesh's
    and scipy's object graphs before exiting (0.15-0.2 s measured; atexit handlers still run).
    """
    as_program = argv is None
    args = build_parser().parse_args(argv)
    try:
        with guard.terminate_raises():
            if as_program:
                _settle_imports(args.command)
            return bench(args) if args.command == "bench" else run(args)
    except InputError as err:
        print(f"acra: error: {err}", file=sys.stderr)
        return report.EXIT_INPUT
    except OSError as err:  # an output directory that is missing or read-only, a full disk
        print(f"acra: error: {err.filename or 'file system'}: {err.strerror or err}; nothing written", file=sys.stderr)
        return report.EXIT_INPUT
    except KeyboardInterrupt:
        print("acra: interrupted; nothing written", file=sys.stderr)
        return report.EXIT_INTERRUPTED
    except guard.Terminated:
        print("acra: interrupted; nothing written", file=sys.stderr)
        return report.EXIT_TERMINATED
    finally:
        if as_program:
            gc.freeze()


if __name__ == "__main__":
    sys.exit(main())
