"""`levelkernels.restate_rows` compiled from nothing: what it adds to the first run after a fresh install.

    python3 benchmarks/restate_compile.py [--repeat 3]
    PYTHONPATH=/tmp/base python3 benchmarks/restate_compile.py   # another checkout's kernel

Each repeat is a fresh process (``PYTHONPATH`` as given, else this checkout) whose
``NUMBA_CACHE_DIR`` is a new empty directory: it imports `acra.levelkernels` and calls
`restate_rows` once, which compiles it (and saves it to the cache), and prints the CPU seconds of
that call. The kernel takes five arguments in a checkout without moves and seven with them
(``moves, moved``, `acra.moves.move_level`); either way it is called on the same seeded rows
without a move, and the script prints a digest of the vectors it returns, the same in both.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

CHILD = r"""
import inspect, time
import numpy as np
from acra import levelkernels as LK
rng = np.random.default_rng(5)
frames = rng.normal(size=(40, 3, 3)); offsets = rng.normal(size=(40, 3)); vectors = np.zeros((40, 3))
rows = np.arange(0, 40, 3, dtype=np.int64)
args = [frames, np.zeros((0, 3, 3)), rows, offsets, vectors]
if len(inspect.signature(LK.restate_rows.py_func).parameters) == 7:
    args += [np.zeros((0, 3)), np.zeros((0, 3))]
t = time.process_time()
vec = LK.restate_rows(*args)[1]
print(time.process_time() - t, vec.tobytes().hex())
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    env = dict(os.environ)
    env.setdefault("PYTHONPATH", HERE)
    seconds, digests = [], set()
    for _ in range(args.repeat):
        with tempfile.TemporaryDirectory() as cache:
            out = subprocess.run([sys.executable, "-c", CHILD], env=dict(env, NUMBA_CACHE_DIR=cache),
                                 capture_output=True, text=True, check=True).stdout.split()
        seconds.append(float(out[0]))
        digests.add(hashlib.sha256(bytes.fromhex(out[1])).hexdigest()[:12])
    seconds.sort()
    print(f"restate_rows compiled in {seconds[len(seconds) // 2]:.2f} s CPU (median of {args.repeat}: "
          f"{', '.join(f'{s:.2f}' for s in seconds)}); vectors digest {', '.join(sorted(digests))}")


if __name__ == "__main__":
    main()
