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
    bench = sub.add_parser("bench", help="time the thesis's Fig. 5.2 stages on a scene (default: dog_head_spike)")
    bench.add_argument("scene", nargs="?", type=Path, help="scene file or stage (default scenes/dog_head_spike.py)")
    bench.add_argument("--repeat", type=int, default=3, help="cold runs to take medians over (default 3)")
    view = sub.add_parser("preview", help="build the Rerun recording of an output layer alone (no ACRA run)")
    view.add_argument("output", type=Path, help="an ACRA output layer (.acra.usda)")
    shown = view.add_mutually_exclusive_group()
    shown.add_argument("--rrd", type=Path, help="save the recording to FILE")
    shown.add_argument("--web", action="store_true", help="serve it to the browser (Rerun web viewer) until Ctrl-C")
    shown.add_argument("--spawn", action="store_true", help="open the Rerun native viewer")
    return p


def preview(args: argparse.Namespace) -> int:
    from pipeline import preview_usd

    if not (args.rrd or args.web or args.spawn):
        raise InputError("acra preview", None, "say where the recording goes: --rrd FILE, --web or --spawn")
    print(preview_usd.preview_file(args.output, rrd=args.rrd, web=args.web, spawn=args.spawn))
    return 0


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
) -> RunReport:
    """Everything `acra run` does, as a function (the tests and `acra bench` call it)."""
    from pipeline import frames as F
    from pipeline import usdio

    t_start = time.perf_counter()
    src = Path(src)
    if iterations < 1:
        raise InputError("--iterations", None, f"must be at least 1, got {iterations}")
    if not np.isfinite(tolerance) or tolerance <= 0:
        raise InputError("--tolerance", None, f"must be a positive number, got {tolerance}")
    stage_path = usdio.load_scene_file(src) if src.suffix == ".py" else src
    out = Path(output) if output else stage_path.with_name(stage_path.stem + ".acra.usda")
    stage = usdio.open_input(stage_path)
    scene = usdio.read_scene(stage)
    frame_list = _frames(frames, scene.start, scene.end)

    preview = None
    if rrd or spawn:
        from pipeline import preview as P

        preview = P.Preview(scene, stage_path.stem, rrd=rrd, spawn=spawn, stage=stage, tolerance=tolerance)

    bar = None
    if progress and len(frame_list) > 1:
        from tqdm import tqdm

        bar = tqdm(total=len(frame_list), unit="frame", file=sys.stderr, leave=False)

    def on_frame(st, result):
        if preview is not None:
            preview.log_frame(st, result)
        if bar is not None:
            bar.update(1)

    result, stats = F.run_frames(stage, scene, frame_list, F.RunOptions(iterations, tolerance, method, density), on_frame)
    if bar is not None:
        bar.close()
    tw = time.perf_counter()
    usdio.write_output(stage_path, out, scene, result)
    ms_write = 1e3 * (time.perf_counter() - tw)
    if preview is not None:
        preview.close()
    return RunReport(out, stats, ms_write, time.perf_counter() - t_start, scene, stage_path, result)


def run(args: argparse.Namespace) -> int:
    report = run_file(
        args.input, args.output, args.frames, args.iterations, args.tolerance,
        rrd=args.rrd, spawn=args.spawn, progress=not args.quiet,
    )
    print(report.summary())
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
        return {"bench": bench, "preview": preview}.get(args.command, run)(args)
    except InputError as err:
        print(f"acra: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("acra: interrupted; nothing written", file=sys.stderr)
        return 130
    finally:
        if as_program:
            gc.freeze()


if __name__ == "__main__":
    sys.exit(main())
