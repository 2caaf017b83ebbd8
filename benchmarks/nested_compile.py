"""What a kernel that calls `acra.kernels.eval_points` adds to the first run after a fresh install.

    python3 benchmarks/nested_compile.py [--repeat 3]

Each repeat is a fresh process (``PYTHONPATH`` as given, else this checkout) whose
``NUMBA_CACHE_DIR`` is a new empty directory. It calls `kernels.eval_points` once on empty
arguments of the types `acra.hspline.evaluate` passes (plain ints and bools, C-contiguous
writeable arrays), which compiles it; then it compiles a kernel that calls `eval_points` with
those same types (defined in the child, not cached), and, where the checkout has it,
`levelkernels.descend_level` (a level of `acra.details.moved_details` in one call, which calls
`eval_points`, `framekernels.frames_at`, `restate_rows`, `mark_changed` and `stale_rows`) on
empty arguments, after a first call of each of those callees (a run's Python calls compile them
anyway), so its figure is what the kernel itself adds. Prints the CPU seconds of each first call, the median over the repeats, and a
digest of what the calls returned (the same in every process).

A call between compiled functions whose argument types match a specialisation the callee has
links that code into the caller; a literal argument (``1`` written in the caller) or another
array layout or writeability makes numba compile the callee again for the caller.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import statistics
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

CHILD = r"""
import time
import numpy as np
from numba import njit
from acra import kernels, levelkernels
i64 = np.int64
ev = (np.zeros(0), np.zeros(0), 1, 0, 0, 4, False, 4, False, np.zeros((16, 3)), np.zeros(1, i64), np.zeros(0, i64),
      np.zeros(0, i64), np.zeros(0, i64), np.zeros((0, 4, 4), i64), np.zeros(1, i64), np.zeros((0, 3)), np.zeros((3, 0, 3)))
t = time.process_time(); kernels.eval_points(*ev); a = time.process_time() - t

@njit
def caller(u, v, order, side, top, nu, up, nv, vp, cvs, levels, keys, shifts, ends, patch_rows, table_rows, table, out):
    kernels.eval_points(u, v, order, side, top, nu, up, nv, vp, cvs, levels, keys, shifts, ends, patch_rows, table_rows,
                        table, out)
    return out.shape[1]

t = time.process_time(); got = [caller(*ev)]; b = time.process_time() - t
c = float("nan")
if hasattr(levelkernels, "descend_level"):
    from acra import framekernels
    z, e3 = np.zeros(0, i64), np.zeros((0, 3))
    # its callees compiled first, as the Python calls of a run compile them anyway
    levelkernels.stale_rows(np.zeros((2, 2), np.bool_), z, z, np.zeros((0, 2), i64), z, z)
    levelkernels.restate_rows(np.zeros((0, 3, 3)), np.zeros((0, 3, 3)), z, e3, e3, e3, e3)
    levelkernels.mark_changed(np.zeros((0, 3), i64), np.zeros((0, 3), i64), z, z, 4, 2, 1, 1, False, False,
                              np.zeros((2, 2), np.bool_))
    framekernels.frames_at(e3, e3, 1e-6, 1e-12, np.zeros(0, np.bool_), e3, np.zeros((0, 3, 3)))
    args = (np.zeros((2, 2), np.bool_), z, z, np.zeros((0, 2), i64), z, z, np.zeros(1, np.bool_), np.zeros(1, np.bool_),
            np.zeros((1, 3)), np.zeros(0), np.zeros(0), *ev[4:17], 1e-6, 1e-12, np.zeros((0, 3, 3)), e3.copy(), e3.copy(),
            np.zeros((0, 3), i64), z, 4, 2, 1, 1)
    t = time.process_time(); got.append(levelkernels.descend_level(*args)[0]); c = time.process_time() - t
print(a, b, c, got)
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    env = dict(os.environ)
    env.setdefault("PYTHONPATH", HERE)
    runs, outs = [], set()
    for _ in range(args.repeat):
        with tempfile.TemporaryDirectory() as cache:
            env["NUMBA_CACHE_DIR"] = cache
            line = subprocess.run([sys.executable, "-c", CHILD], env=env, check=True, capture_output=True,
                                  text=True).stdout.strip().split(" ", 3)
        runs.append([float(x) for x in line[:3]])
        outs.add(line[3])
    for i, name in enumerate(("eval_points, first call", "a kernel calling it, after it", "levelkernels.descend_level")):
        xs = [r[i] for r in runs]
        print(f"{name}: {min(xs):.2f}-{max(xs):.2f} s CPU, median {statistics.median(xs):.2f} ({len(xs)} processes)")
    print("digest", hashlib.sha256("".join(sorted(outs)).encode()).hexdigest()[:12], "(one answer)" if len(outs) == 1 else "(answers differ)")


if __name__ == "__main__":
    main()
