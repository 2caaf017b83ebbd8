"""The compiled H-spline evaluator (`acra.kernels`) against the array form it replaced.

    python3 benchmarks/eval_kernel.py [CASE.pkl] [--repeat 15] [--small-repeat 400]

``CASE.pkl`` holds ``(hs, det, topo)``: an `HSpline`, its `Details` and a display topology whose
``topo.u, topo.v`` are the parameters evaluated. Without it, the case is the demo head after its
response at frame 15 (7 levels, 23,491 display points): `dog_head_spike` runs frames 5 and 13–15,
and the head's surface at 15, its details and its display's topology (`display.Displays.of` at
the head's ``acra:samples``) are written to a temporary file for the fresh processes to read. Prints markdown tables of:

* milliseconds per call, numpy (`hspline._evaluate_numpy`) and kernel (`hspline.evaluate`), at
  derivative orders 0 and 1, for the whole display and for calls of 50 points (50 consecutive
  display parameters, and 50 drawn at random from them; the display again by v, then u, the
  order `acra.tessellate.grid_samples` evaluates in, where a point reuses the v contraction of the
  point before on the same v and block): the median of ``--repeat`` (display)
  or ``--small-repeat`` (50 points) calls, the two forms alternating in this one process, BLAS
  on one thread as in the frame loop (`pipeline.frames`), and the largest difference between
  them relative to the object's size;
* from fresh processes (``PYTHONPATH`` at this checkout, ``NUMBA_CACHE_DIR`` a new temporary
  directory, so the checkout's own cache is neither read nor written): ``import numba``; the first
  call of a trivial cached function (numba's own set-up, which the first compiled call of a
  process pays whatever the function); then the first `hspline.evaluate` call with an empty
  cache (compiling the kernel) and, in later processes, with the cache the first wrote (loading
  it); the median of ``--fresh`` processes each.
"""

from __future__ import annotations

import argparse
import os
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from acra import hspline as H  # noqa: E402

# run in a fresh process (argv: the case, a directory holding `_TRIVIAL` as trivial.py): seconds
# of `import numba`, of importing acra.hspline after it, of a trivial cached function's first
# call (numba's own set-up on its first compiled call in a process), and of the first and second
# evaluate call on the case
_FRESH = """
import pickle, sys, time
t0 = time.perf_counter()
import numba
t1 = time.perf_counter()
from acra import hspline as H
t2 = time.perf_counter()
hs, det, topo = pickle.load(open(sys.argv[1], "rb"))
u, v = topo.u[:50].copy(), topo.v[:50].copy()
sys.path.insert(0, sys.argv[2])
import trivial
t3 = time.perf_counter()
trivial.f(u)
t4 = time.perf_counter()
H.evaluate(hs, u, v, det=det)
t5 = time.perf_counter()
H.evaluate(hs, u, v, det=det)
t6 = time.perf_counter()
print(t1 - t0, t2 - t1, t4 - t3, t5 - t4, t6 - t5)
"""
_TRIVIAL = """
from numba import njit


@njit(cache=True)
def f(x):
    return x[0] + 1.0
"""


def alternating(calls: dict, repeat: int) -> dict:
    """Median seconds of each of ``calls`` (name -> function), called in turn ``repeat`` times."""
    times = {name: [] for name in calls}
    for _ in range(repeat):
        for name, fn in calls.items():
            t = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t)
    return {name: float(np.median(ts)) for name, ts in times.items()}


def largest_difference(hs, det, u, v, order) -> float:
    """Largest difference of any output between the two forms, relative to the object's size."""
    a = H.evaluate(hs, u, v, order=order, det=det)
    b = H._evaluate_numpy(hs, u, v, order=order, det=det)
    names = ("points", "du", "dv")[: 1 + 2 * order]
    return max(float(np.abs(getattr(a, n) - getattr(b, n)).max()) for n in names) / hs.size()


def fresh(case: Path, cache: str, runs: int) -> np.ndarray:
    """The `_FRESH` figures of ``runs`` fresh processes with ``NUMBA_CACHE_DIR=cache``, median
    of each: ``(5,) float64`` seconds."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), NUMBA_CACHE_DIR=cache)
    (Path(cache) / "trivial.py").write_text(_TRIVIAL)
    rows = []
    for _ in range(runs):
        done = subprocess.run([sys.executable, "-c", _FRESH, str(case), cache], env=env, capture_output=True, text=True,
                              check=True)
        rows.append([float(x) for x in done.stdout.split()])
    return np.median(np.array(rows), axis=0)


def table(hs, det, cases) -> None:
    """Print a table row per ``(name, u, v, repeat)`` of ``cases`` and order 0 and 1: both
    forms' median ms, the speed-up and the largest difference."""
    for name, uu, vv, repeat in cases:
        for order in (0, 1):
            t = alternating({
                "numpy": lambda: H._evaluate_numpy(hs, uu, vv, order=order, det=det),
                "kernel": lambda: H.evaluate(hs, uu, vv, order=order, det=det),
            }, repeat)
            diff = largest_difference(hs, det, uu, vv, order)
            print(f"| {name} | {order} | {t['numpy'] * 1e3:.3f} | {t['kernel'] * 1e3:.3f} | "
                  f"{t['numpy'] / t['kernel']:.1f}x | {diff:.1e} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("case", nargs="?", type=Path, help="a pickled (hs, det, topo); default: the demo head at frame 15")
    ap.add_argument("--repeat", type=int, default=15, help="display-size calls per form (default 15)")
    ap.add_argument("--small-repeat", type=int, default=400, help="50-point calls per form (default 400)")
    ap.add_argument("--fresh", type=int, default=3, help="fresh processes per start-up figure (default 3)")
    args = ap.parse_args()

    made = None
    if args.case is None:
        made = tempfile.TemporaryDirectory()
        args.case = demo_case(Path(made.name) / "head15.pkl")
    with open(args.case, "rb") as f:
        hs, det, topo = pickle.load(f)
    u, v = np.ascontiguousarray(topo.u, np.float64), np.ascontiguousarray(topo.v, np.float64)
    pick = np.random.default_rng(0).choice(u.size, 50, replace=False)
    by_v = np.argsort(v, kind="stable")  # by v, then u: the order `tessellate.grid_samples` passes
    cases = [
        (f"display, {u.size:,} points", u, v, args.repeat),
        (f"display, {u.size:,} points by v, then u", u[by_v], v[by_v], args.repeat),
        ("50 consecutive display points", u[:50].copy(), v[:50].copy(), args.small_repeat),
        ("50 random display points", u[pick], v[pick], args.small_repeat),
    ]
    H.evaluate(hs, u[:2], v[:2], det=det)  # compile or load the kernel before timing
    print(f"levels {hs.depth}, visited {hs._terms_index[0].tolist()}, "
          f"active patches {[lev.patches.size for lev in hs.fine]}, load average {os.getloadavg()[0]:.2f}\n")
    print("| call | order | numpy ms | kernel ms | speed-up | largest difference / size |")
    print("|---|---:|---:|---:|---:|---:|")
    with threadpool_limits(limits=1, user_api="blas"):
        table(hs, det, cases)

    with tempfile.TemporaryDirectory() as top:
        caches = [tempfile.mkdtemp(dir=top) for _ in range(args.fresh)]
        cold = np.median([fresh(args.case, c, 1) for c in caches], axis=0)  # each compiles into its own
        warm = fresh(args.case, caches[0], args.fresh)  # each loads what the first wrote
    print(f"\nfresh processes (median of {args.fresh}), seconds, load average {os.getloadavg()[0]:.2f}:\n")
    print("| step | empty cache | warm cache |")
    print("|---|---:|---:|")
    print(f"| `import numba` | {cold[0]:.3f} | {warm[0]:.3f} |")
    print(f"| `from acra import hspline` after it | {cold[1]:.3f} | {warm[1]:.3f} |")
    print(f"| a trivial cached function's first call (numba's set-up) | {cold[2]:.3f} | {warm[2]:.3f} |")
    print(f"| first `evaluate` call after it (50 points) | {cold[3]:.3f} | {warm[3]:.3f} |")
    print(f"| second call | {cold[4]:.5f} | {warm[4]:.5f} |")
    if made is not None:
        made.cleanup()


def demo_case(path: Path) -> Path:
    """``path`` holding the demo head after its response at frame 15 as ``(hs, det, topo)``:
    its surface, its details (`acra.details.details`) and its display's topology."""
    from types import SimpleNamespace

    from acra import details as D
    from pipeline import display, frames, usdio

    root = Path(__file__).resolve().parents[1]
    stage = usdio.open_input(usdio.load_scene_file(root / "scenes" / "dog_head_spike.py"))
    scene = usdio.read_scene(stage)
    frames.run_frames(stage, scene, [5])
    result, _ = frames.run_frames(stage, scene, [13, 14, 15])
    model = next(m for m in scene.deformables if m.path == "/World/Head")
    hs = result.frames[15][model.path].surface
    uv = display.Displays().of(hs, model.controls.samples).uv
    with open(path, "wb") as f:
        pickle.dump((hs, D.details(hs), SimpleNamespace(u=uv[:, 0].copy(), v=uv[:, 1].copy())), f)
    return path


if __name__ == "__main__":
    main()
