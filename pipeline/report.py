"""What `acra run` tells the user and a script: the summary line, the frames over tolerance, the
exit status, progress, and the ``--report FILE.json`` record.

Exit statuses (docs/cli.md): `EXIT_OK` 0, `EXIT_FARM` 1 (chunks that kept failing on a Dask
cluster, `pipeline.farm.FarmError`; nothing written), `EXIT_INPUT` 2 (invalid input, refused output path,
over the memory budget), `EXIT_OVER_TOLERANCE` 3 (a frame's residual penetration stays over
``--tolerance``; ``--over-tolerance warn`` makes it 0), `EXIT_INTERRUPTED` 130 (SIGINT) and
`EXIT_TERMINATED` 143 (SIGTERM).

A frame is over tolerance (`frames_over_tolerance`) when its `FrameStats.residual_rel` exceeds the
tolerance or is not a finite number: a residual that could not be measured never passes.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

__all__ = [
    "EXIT_OK",
    "EXIT_FARM",
    "EXIT_INPUT",
    "EXIT_OVER_TOLERANCE",
    "EXIT_INTERRUPTED",
    "EXIT_TERMINATED",
    "REPORT_VERSION",
    "frames_over_tolerance",
    "summary_line",
    "over_tolerance_line",
    "report_dict",
    "write_json",
    "Progress",
]

EXIT_OK = 0
EXIT_FARM = 1
EXIT_INPUT = 2
EXIT_OVER_TOLERANCE = 3
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143
REPORT_VERSION = 1
LISTED = 10  # frames over tolerance named in the summary line (all of them go in the report)


def frames_over_tolerance(stats, tolerance: float) -> list[tuple[int, float]]:
    """``(frame, residual_rel)`` of every frame whose relative residual penetration is over
    ``tolerance`` or not finite, in frame order. ``stats``: `pipeline.frames.FrameStats` items
    (anything with ``frame`` and ``residual_rel``)."""
    out = []
    for s in stats:
        r = float(s.residual_rel)
        if not math.isfinite(r) or r > tolerance:
            out.append((int(s.frame), r))
    return sorted(out)


def _median(xs) -> float:
    return float(np.median(xs)) if len(xs) else 0.0


def summary_line(stats, ms_write: float, seconds: float, output) -> str:
    """One line: frames, frames in collision, the largest residual, the most detect → respond
    rounds any frame took, median ms per frame per stage, writing time per frame, total seconds
    and the output path."""
    hit = [s for s in stats if s.in_collision]
    worst = max((float(s.residual_rel) for s in stats), default=0.0, key=lambda r: math.inf if math.isnan(r) else r)
    rounds = max((int(s.iterations) for s in stats), default=0)
    n = len(stats)
    return (
        f"acra: {n} frames, {len(hit)} in collision; largest residual penetration "
        f"{worst:.2e} of object size; at most {rounds} round{'s' if rounds != 1 else ''} a frame; median ms per frame: detection {_median([s.ms_detect for s in stats]):.1f}, "
        f"response {_median([s.ms_respond for s in stats]):.1f}, writing {ms_write / max(1, n):.1f}; "
        f"total {seconds:.2f} s -> {output}"
    )


def over_tolerance_line(over: list[tuple[int, float]], tolerance: float) -> str:
    """``acra: 2 frames over tolerance 1e-03: 11 (3.10e-03), 12 (1.20e-03)``; the first `LISTED`
    frames are named, the count is always complete."""
    listed = ", ".join(f"{f} ({r:.2e})" for f, r in over[:LISTED])
    more = f", and {len(over) - LISTED} more (see --report)" if len(over) > LISTED else ""
    return f"acra: {len(over)} frame{'s' if len(over) != 1 else ''} over tolerance {tolerance:.0e}: {listed}{more}"


def _finite_or_none(x: float):
    x = float(x)
    return x if math.isfinite(x) else None


def report_dict(run, tolerance: float, over: list[tuple[int, float]], status: int) -> dict:
    """The ``--report`` record of a finished run (``run``: `pipeline.run.RunReport`).

    Keys: ``version``, ``input``, ``output``, ``status``, ``tolerance``, ``frames`` (count),
    ``in_collision`` (count), ``largest_residual``, ``seconds``, ``ms_write``,
    ``over_tolerance`` (list of ``{"frame", "residual"}``) and ``per_frame`` (list of ``{"frame",
    "in_collision", "residual", "residual_abs", "rounds", "ms": {"setup", "detect", "convert",
    "respond", "output", "total"}}``). Residuals are fractions of object size (``residual_abs`` in
    scene units); a residual that is not a number is ``null``.
    """
    stats = run.stats
    return {
        "version": REPORT_VERSION,
        "input": str(run.stage_path) if run.stage_path is not None else None,
        "output": str(run.output),
        "status": int(status),
        "tolerance": float(tolerance),
        "frames": len(stats),
        "in_collision": sum(1 for s in stats if s.in_collision),
        "largest_residual": _finite_or_none(max((float(s.residual_rel) for s in stats), default=0.0)),
        "seconds": round(float(run.seconds), 4),
        "ms_write": round(float(run.ms_write), 3),
        "phases": {name: round(float(sec), 4) for name, sec in getattr(run, "phases", {}).items()},
        "over_tolerance": [{"frame": f, "residual": _finite_or_none(r)} for f, r in over],
        "per_frame": [
            {
                "frame": int(s.frame),
                "in_collision": bool(s.in_collision),
                "residual": _finite_or_none(s.residual_rel),
                "residual_abs": _finite_or_none(s.residual),
                "rounds": int(s.iterations),
                "hold": bool(s.hold),
                "ms": {k: round(float(getattr(s, f"ms_{k}")), 3) for k in ("setup", "detect", "convert", "respond", "visible", "output", "total")},
            }
            for s in stats
        ],
    }


def write_json(path: str | os.PathLike, data: dict) -> Path:
    """Write ``data`` as JSON to ``path`` atomically (`guard.atomic_file`)."""
    from pipeline import guard

    out = Path(path)
    with guard.atomic_file(out) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(data, fh, indent=1, allow_nan=False)
            fh.write("\n")
    return out


class Progress:
    """Progress of a run on stderr: a tqdm bar when stderr is a terminal; otherwise (logs, CI,
    pipes) plain lines without carriage returns, ``acra: frame F done (i/N)``, after the first
    frame and then at most every ``every`` seconds, and after the last."""

    def __init__(self, total: int, stream=None, every: float = 10.0, tty: bool | None = None):
        self.stream = sys.stderr if stream is None else stream
        self.total, self.done, self.every = total, 0, every
        isatty = getattr(self.stream, "isatty", lambda: False)
        self.tty = bool(isatty()) if tty is None else tty
        self.bar = None
        self.last = -math.inf
        if self.tty:
            from tqdm import tqdm

            self.bar = tqdm(total=total, unit="frame", file=self.stream, leave=False)

    def update(self, frame: int | None, count: int = 1) -> None:
        """``count`` more frames done, the last of them ``frame`` (``None``: a chunk of frames
        finished on a Dask worker, `pipeline.farm`)."""
        self.done += count
        if self.bar is not None:
            self.bar.update(count)
            return
        now = time.monotonic()
        if self.done == count or self.done == self.total or now - self.last >= self.every:
            self.last = now
            what = f"frame {frame} done" if frame is not None else f"{count} frames done"
            print(f"acra: {what} ({self.done}/{self.total})", file=self.stream, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
