"""The command line (contract §3, docs/cli.md): ``acra run``, ``acra merge``, ``acra preview``,
``acra bench``, ``acra --version``.

    acra run INPUT [-o OUTPUT] [--frames START:END] [--rrd FILE | --spawn] [--iterations N]
             [--tolerance T] [--over-tolerance fail|warn] [--report FILE.json]
             [--memory-budget SIZE] [--quiet] [--workers N | --scheduler ADDRESS | --part DIR]
             [--chunk FRAMES]
    acra merge DIR [-o OUTPUT] [--frames START:END]
    acra preview OUTPUT [--rrd FILE | --web | --spawn]
    acra bench [SCENE] [--repeat N] [--no-first-run]

A thin layer over `pipeline.run` (what a run does), `pipeline.parts` (the merge),
`pipeline.preview_usd` (a recording from an output layer) and `pipeline.bench`: it parses, prints the summary, and maps outcomes to exit statuses
(`pipeline.report`): 0 ok, 1 chunks that kept failing on a Dask cluster, 2 bad input (one line
naming the prim, the attribute and the problem; nothing written), 3 frames over tolerance, 130 and
143 interrupted by SIGINT and SIGTERM (nothing written).
"""

from __future__ import annotations

import time

_LOADED = time.perf_counter()  # start of this module: the command line's imports are timed from here

import argparse  # noqa: E402
import atexit  # noqa: E402
import gc  # noqa: E402
import os  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

__all__ = ["main", "program", "end", "build_parser"]

# What a command needs is imported when it runs, not here: `acra --version` and `acra --help`
# import argparse alone, `acra run` without --rrd or --workers never imports rerun or dask, and
# nothing the run path uses imports matplotlib (docs/cli.md, *Start-up*).


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="acra", description="Automatic collision response for key-framed H-spline objects.")
    p.add_argument("--version", action=_Version)
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
    farm = run.add_mutually_exclusive_group()  # docs/farm.md
    farm.add_argument("--workers", type=int, help="run chunks of frames on a local Dask cluster of N worker processes (needs acra[farm])")
    farm.add_argument("--scheduler", help="run chunks of frames on the Dask cluster at ADDRESS, e.g. tcp://10.0.0.5:8786")
    farm.add_argument("--part", type=Path, help="write this frame range's results as a part file in DIR for `acra merge` (no output layer)")
    run.add_argument("--chunk", type=int, help="frames per Dask task (default: about 3 tasks per worker)")
    merge = sub.add_parser("merge", help="assemble the part files in DIR (from `acra run --part`) into the output layer")
    merge.add_argument("parts", type=Path, help="directory of .acrapart.npz files")
    merge.add_argument("-o", "--output", type=Path, help="output layer (default: <input stem>.acra.usda beside the input)")
    merge.add_argument("--frames", help="START:END the parts must cover (default: the stage's time codes)")
    bench = sub.add_parser("bench", help="time the thesis's Fig. 5.2 stages on a scene (default: dog_head_spike)")
    bench.add_argument("scene", nargs="?", type=Path, help="scene file or stage (default scenes/dog_head_spike.py)")
    bench.add_argument("--repeat", type=int, default=3, help="cold runs to take medians over (default 3)")
    bench.add_argument("--no-first-run", action="store_true",
                       help="skip timing the first run after a fresh install (numba compiling every kernel, about 2 min CPU)")
    view = sub.add_parser("preview", help="build the Rerun recording of an output layer alone (no ACRA run)")
    view.add_argument("output", type=Path, help="an ACRA output layer (.acra.usda)")
    shown = view.add_mutually_exclusive_group()
    shown.add_argument("--rrd", type=Path, help="save the recording to FILE")
    shown.add_argument("--web", action="store_true", help="serve it to the browser (Rerun web viewer) until Ctrl-C")
    shown.add_argument("--spawn", action="store_true", help="open the Rerun native viewer")
    return p


class _Version(argparse._VersionAction):
    """``--version``: the package's version, read from its metadata only when asked (a search of
    ``sys.path`` for the distribution and the email parser for its ``METADATA``: 4-5 ms CPU with
    importlib.metadata imported, 24 ms without, which every other command skips)."""

    def __call__(self, parser, namespace, values, option_string=None):
        self.version = f"acra {_version()}"
        super().__call__(parser, namespace, values, option_string)


def _version() -> str:
    """The installed package's version (package metadata), or ``unknown`` in a bare checkout."""
    from importlib import metadata

    try:
        return metadata.version("acra")
    except metadata.PackageNotFoundError:
        return "unknown"


def run(args: argparse.Namespace, imports_s: float | None = None) -> int:
    """`acra run`: the summary line and the frames over tolerance; the exit status. ``imports_s``:
    the seconds this process spent importing before the run (`RunReport.phases`)."""
    from pipeline import report
    from pipeline.run import run_file

    run_report = run_file(
        args.input, args.output, args.frames, args.iterations, args.tolerance,
        rrd=args.rrd, spawn=args.spawn, progress=not args.quiet,
        report_path=args.report, memory_budget=args.memory_budget, over_tolerance=args.over_tolerance,
        workers=args.workers, scheduler=args.scheduler, chunk=args.chunk, part=args.part, imports_s=imports_s,
    )
    print(run_report.summary())
    if run_report.over:
        line = report.over_tolerance_line(run_report.over, args.tolerance)
        print(line, file=sys.stderr if run_report.status else sys.stdout)
    return run_report.status


def merge(args: argparse.Namespace) -> int:
    """`acra merge DIR [-o OUT] [--frames START:END]` (docs/farm.md)."""
    from pipeline import parts
    from pipeline.run import RunReport, frame_list

    t_start = time.perf_counter()
    expected = None if args.frames is None else frame_list(args.frames, 0, 0)
    out, stats, ms_write, scene, stage_path = parts.merge_parts(args.parts, args.output, expected)
    print(RunReport(out, stats, ms_write, time.perf_counter() - t_start, scene, stage_path).summary())
    return 0


def preview(args: argparse.Namespace) -> int:
    """`acra preview OUTPUT [--rrd FILE | --web | --spawn]` (docs/preview.md)."""
    from pipeline import guard, preview_usd
    from pipeline.model import InputError
    from pipeline.run import refuse_outputs

    if not (args.rrd or args.web or args.spawn):
        raise InputError("acra preview", None, "say where the recording goes: --rrd FILE, --web or --spawn")
    if args.rrd is not None and Path(args.output).is_file():
        refuse_outputs([("--rrd", args.rrd)], guard.protected_paths(Path(args.output)))
    print(preview_usd.preview_file(args.output, rrd=args.rrd, web=args.web, spawn=args.spawn))
    return 0


def bench(args: argparse.Namespace) -> int:
    from pipeline.bench import format_report, run_bench
    from pipeline.model import InputError

    if args.repeat < 1:
        raise InputError("--repeat", None, f"must be at least 1, got {args.repeat}")
    print(format_report(run_bench(args.scene, args.repeat, first_run=not args.no_first_run)))
    return 0


def _farm_error() -> tuple:
    """`pipeline.farm.FarmError` if this process ran a farm (imported the module), else no class.
    Evaluated only while an exception is matched, so a run in this process never imports the
    farm's module for its except clause."""
    farm = sys.modules.get("pipeline.farm")
    return () if farm is None else (farm.FarmError,)


def _settle_imports(command: str) -> None:
    """Import what ``command`` will run, then move every object so far out of the cyclic GC's reach.

    ``gc.freeze`` keeps the collector from re-walking the ~90 000 long-lived objects the imports
    create (numpy, pxr, scipy, numba) at each full collection during the run (measured: 0.11 s of
    GC in a dog_head_spike run, 0.07 s after). For processes that are the command only.
    """
    if command == "run":
        from pipeline import frames, usdio  # noqa: F401
    gc.freeze()
    gc.enable()  # `main` disabled it for the imports


def main(argv: list[str] | None = None) -> int:
    """The command line (contract §3); returns the exit status.

    ``argv=None`` means this process is the command (the ``acra`` script, ``python -m
    pipeline.cli``): then import-time objects are frozen out of the cyclic GC (`_settle_imports`),
    and so is everything at the end, so the interpreter's final collection does not walk trimesh's
    and scipy's object graphs before exiting (0.15-0.2 s measured; atexit handlers still run).
    """
    as_program = argv is None
    if as_program:
        # the imports create ~90 000 long-lived objects and no garbage: collecting while they
        # load only walks them (gen 0-2 collections); `_settle_imports` freezes them, then enables
        gc.disable()
    args = build_parser().parse_args(argv)
    from pipeline import guard, report
    from pipeline.model import InputError

    arrived: list[int] = []
    try:
        with guard.terminate_raises() as arrived:
            if as_program:
                _settle_imports(args.command)
            if args.command == "run":  # as a program, the imports since this module started
                return run(args, time.perf_counter() - _LOADED if as_program else None)
            return {"bench": bench, "merge": merge, "preview": preview}[args.command](args)
    except BaseException as err:
        # a signal first: an error raised while the run unwinds from one is part of that signal
        signal = guard.interruption(err, arrived)
        if signal is None:
            status = _failed(err, report, InputError)
            if status is None:
                raise
            return status
        print("acra: interrupted; nothing written", file=sys.stderr)
        return report.EXIT_TERMINATED if isinstance(signal, guard.Terminated) else report.EXIT_INTERRUPTED
    finally:
        if as_program:
            gc.freeze()


def _failed(err: BaseException, report, input_error: type) -> int | None:
    """The exit status of a run that ``err`` ended without a signal, with its one line on stderr,
    or ``None`` for an error no line explains (raised again: a traceback is a defect to fix)."""
    if isinstance(err, input_error):
        print(f"acra: error: {err}", file=sys.stderr)
        return report.EXIT_INPUT
    if isinstance(err, _farm_error()):  # chunks that kept failing on the cluster (retries spent)
        print(f"acra: error: {err}; nothing written", file=sys.stderr)
        return report.EXIT_FARM
    if isinstance(err, OSError):  # an output directory that is missing or read-only, a full disk
        print(f"acra: error: {err.filename or 'file system'}: {err.strerror or err}; nothing written", file=sys.stderr)
        return report.EXIT_INPUT
    return None


# what keeps a process alive past its main thread or flushes at exit beyond atexit: a recording
# (rerun's sink threads), a Dask cluster; a run with either ends as the interpreter ends it
_EXIT_AS_USUAL = ("rerun", "dask", "distributed")


def program() -> None:
    """`acra` as the process's command (the ``acra`` script, ``python -m pipeline.cli``): `main`,
    then `end` with its status."""
    end(main())


def end(status: int) -> None:
    """End the process with exit status ``status`` without the interpreter's teardown.

    After a run the interpreter would free every object of numpy, pxr, scipy and numba's typing
    one at a time and clear ~1 500 modules (0.07-0.09 s CPU of a 2.3 s dog_head_spike run,
    `benchmarks/startup.py`); the operating system reclaims the process's memory at once. The
    atexit handlers still run and stdout and stderr are flushed first, so what a run prints and
    writes is the same; a process with other threads, a recording or a cluster exits as usual.
    """
    if _threading_alone() and not any(m in sys.modules for m in _EXIT_AS_USUAL):
        atexit._run_exitfuncs()  # runs each handler once: the interpreter's exit would find none left
        try:
            for stream in (sys.stdout, sys.stderr):
                stream.flush()
        except OSError:  # a closed pipe: the interpreter's exit reports it, as without `end`
            sys.exit(status)
        os._exit(status)
    sys.exit(status)


def _threading_alone() -> bool:
    """Whether the main thread is the process's only Python thread (or threading never started)."""
    threading = sys.modules.get("threading")
    return threading is None or threading.active_count() == 1


if __name__ == "__main__":
    program()
