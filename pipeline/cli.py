"""`acra run INPUT [-o OUTPUT] [--frames START:END] [--rrd FILE | --spawn] [--iterations N] [--tolerance T]`.

Contract §3. User errors (bad input, unreadable files) print one line on stderr and exit 2 with
nothing written; the output layer is written atomically at the end.
"""

from __future__ import annotations

import argparse
import gc
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.model import InputError

__all__ = ["main", "build_parser", "run_file", "RunReport"]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="acra", description="Automatic collision response for key-framed H-spline objects.")
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
    run.add_argument("--quiet", action="store_true", help="no progress bar")
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
    return p


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
    """

    output: Path
    stats: list
    ms_write: float
    seconds: float
    scene: object = None
    stage_path: Path | None = None
    result: object = None

    def summary(self) -> str:
        hit = [s for s in self.stats if s.in_collision]
        worst = max((s.residual_rel for s in self.stats), default=0.0)
        med = lambda xs: float(np.median(xs)) if xs else 0.0  # noqa: E731
        n = len(self.stats)
        return (
            f"acra: {n} frames, {len(hit)} in collision; largest residual penetration "
            f"{worst:.2e} of object size; median ms per frame: detection {med([s.ms_detect for s in self.stats]):.1f}, "
            f"response {med([s.ms_respond for s in self.stats]):.1f}, writing {self.ms_write / max(1, n):.1f}; "
            f"total {self.seconds:.2f} s -> {self.output}"
        )


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
    workers: int | None = None,
    scheduler: str | None = None,
    chunk: int | None = None,
    part: Path | None = None,
) -> RunReport:
    """Everything `acra run` does, as a function (the tests and `acra bench` call it).

    ``workers``/``scheduler``/``chunk`` run the frames on Dask (`pipeline.farm`); ``part`` writes
    a part file into that directory instead of the output layer (`pipeline.parts`).
    """
    from pipeline import frames as F
    from pipeline import usdio

    t_start = time.perf_counter()
    src = Path(src)
    if iterations < 1:
        raise InputError("--iterations", None, f"must be at least 1, got {iterations}")
    if not np.isfinite(tolerance) or tolerance <= 0:
        raise InputError("--tolerance", None, f"must be a positive number, got {tolerance}")
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
    stage_path = usdio.load_scene_file(src) if src.suffix == ".py" else src
    out = Path(output) if output else stage_path.with_name(stage_path.stem + ".acra.usda")
    stage = usdio.open_input(stage_path)
    scene = usdio.read_scene(stage)
    if workers is not None or scheduler is not None or part is not None:
        from pipeline import farm, parts

        identity = parts.input_identity(stage)  # as read now: workers and merges check they see the same
    frame_list = _frames(frames, scene.start, scene.end)

    preview = None
    if rrd or spawn:
        from pipeline import preview as P

        preview = P.Preview(scene, stage_path.stem, rrd=rrd, spawn=spawn)

    bar = None
    if progress and len(frame_list) > 1:
        from tqdm import tqdm

        bar = tqdm(total=len(frame_list), unit="frame", file=sys.stderr, leave=False)

    def on_frame(st, result):
        if preview is not None:
            preview.log_frame(st, result)
        if bar is not None:
            bar.update(1)

    options = F.RunOptions(iterations, tolerance, method, density)
    if workers is not None or scheduler is not None:
        result, stats = farm.run_frames(stage_path, identity, scene, frame_list, options,
                                        workers, scheduler, chunk, bar.update if bar is not None else None)
        for st in stats if preview is not None else ():
            preview.log_frame(st, result)
    else:
        result, stats = F.run_frames(stage, scene, frame_list, options, on_frame)
    if bar is not None:
        bar.close()
    tw = time.perf_counter()
    if part is not None:
        out = parts.write_part(part, stage_path, identity, options, parts.records_from_result(result), stats)
    else:
        usdio.write_output(stage_path, out, scene, result)
    ms_write = 1e3 * (time.perf_counter() - tw)
    if preview is not None:
        preview.close()
    return RunReport(out, stats, ms_write, time.perf_counter() - t_start, scene, stage_path, result)


def run(args: argparse.Namespace) -> int:
    report = run_file(
        args.input, args.output, args.frames, args.iterations, args.tolerance,
        rrd=args.rrd, spawn=args.spawn, progress=not args.quiet,
        workers=args.workers, scheduler=args.scheduler, chunk=args.chunk, part=args.part,
    )
    print(report.summary())
    return 0


def merge(args: argparse.Namespace) -> int:
    """`acra merge DIR [-o OUT] [--frames START:END]` (docs/farm.md)."""
    from pipeline import parts

    t_start = time.perf_counter()
    expected = None if args.frames is None else _frames(args.frames, 0, 0)
    out, stats, ms_write, scene, stage_path = parts.merge_parts(args.parts, args.output, expected)
    print(RunReport(out, stats, ms_write, time.perf_counter() - t_start, scene, stage_path).summary())
    return 0


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
        if as_program:
            _settle_imports(args.command)
        return {"bench": bench, "merge": merge}.get(args.command, run)(args)
    except InputError as err:
        print(f"acra: error: {err}", file=sys.stderr)
        return 2
    except RuntimeError as err:
        from pipeline.farm import FarmError

        if not isinstance(err, FarmError):
            raise
        print(f"acra: error: {err}; nothing written", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("acra: interrupted; nothing written", file=sys.stderr)
        return 130
    finally:
        if as_program:
            gc.freeze()


if __name__ == "__main__":
    sys.exit(main())
