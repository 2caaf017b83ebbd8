"""The cast rays' box test (`acra.patch_boxes.rays_meet`) on the scale curve's ×1 and ×16 heads.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=$PWD python3 benchmarks/ray_boxes.py [--repeat 7]

Records every `rays_meet` call (`pipeline.queries.cast`'s patch boxes, origins and directions)
of one `pipeline.run.run_file` of `benchmarks/scale_curve.py`'s ×1 stage and ×16 stage at the
default density 8, then replays each run's calls 20 times per repeat and prints the CPU ms a
run's calls take (median and least over ``--repeat``), their shapes, and a digest of the
answers: two checkouts agree where their digests agree. Another checkout's code runs with its
own ``PYTHONPATH``.
"""

from __future__ import annotations

import argparse
import hashlib
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # scale_curve, beside this script
import scale_curve  # noqa: E402
from pipeline import queries  # noqa: E402
from pipeline.run import forget, run_file  # noqa: E402

RUNS = ((0, 8), (2, 8))  # (refinements of the head's level 0, collision density): ×1 and ×16
REPLAYS = 20


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    held = tempfile.TemporaryDirectory(prefix="ray_boxes_")  # removed when main returns
    tmp = Path(held.name)
    grids = scale_curve.head_grids()
    meet = queries.rays_meet
    for scale, density in RUNS:
        src = tmp / f"scale{scale}.usda"
        scale_curve.A.save(scale_curve.build_stage(scale, grids[scale]), src)
        calls = []

        def recorded(lo, hi, o, d):
            calls.append((lo.copy(), hi.copy(), o.copy(), d.copy()))
            return meet(lo, hi, o, d)
        queries.rays_meet = recorded
        forget()
        try:
            run_file(src, output=tmp / "out.acra.usda", density=density)
        finally:
            queries.rays_meet = meet
        out = [meet(*c) for c in calls]  # compiled before the clock
        ms = []
        for _ in range(args.repeat):
            t = time.process_time()
            for _ in range(REPLAYS):
                out = [meet(*c) for c in calls]
            ms.append(1e3 * (time.process_time() - t) / REPLAYS)
        h = hashlib.sha1(b"".join(a.tobytes() + b.tobytes() for a, b in out)).hexdigest()[:12]
        shapes = ", ".join(f"{len(c[2])}×{len(c[0])}" for c in calls)
        print(f"×{4 ** scale} density {density}: {len(calls)} calls (rays × boxes: {shapes}); CPU ms a run's calls "
              f"{statistics.median(ms):.3f} (least {min(ms):.3f}); digest {h}")


if __name__ == "__main__":
    main()
