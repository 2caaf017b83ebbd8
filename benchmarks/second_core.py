"""The residual's measures of a run on one thread and on two, replayed in one process.

    python3 benchmarks/second_core.py [SCENE.py] [--frames 13:17] [--passes 9] [--kernels | --bound]

Runs the scene's ``--frames`` (after a free frame, as `residual_calls.py` does), keeping every
`residual.measure_frame` call's arguments (the frame loop's rounds and the run's display), then
replays them ``--passes`` times with one thread and with two (`pipeline.workers.threads`, the
value of numba's ``NUMBA_NUM_THREADS``, set for the pass), the two alternated, each pass with
empty part caches and answer tables and one fresh copy of each recorded `Shown` (as
`residual_calls.py`). A pair measured both ways (a closed pair's two sides after a response)
runs its two `pair_depth` calls side by side with two threads (`residual.measure_frame`).

Prints, for each setting, the wall milliseconds (``time.perf_counter``) and CPU milliseconds
(``time.process_time``, both threads counted) of the passes, range and median, the calls that
ran side by side, and a digest of every answer (each pair's depths, completeness, the points,
parameters and depths found inside): one thread and two must give the same digest, and so must
two checkouts. Wall time is the figure two threads change; it needs an otherwise idle machine
(give ``uptime`` with it), and CPU time must stay about the same. The first line says whether a
second core was free: a compiled loop of about 10 ms twice, one after the other and side by
side in two threads, fastest of 5 (side by side in about half the time on a free second core).

``--bound`` gives instead what two threads could gain at most, from CPU time alone (so on a
loaded machine too): each pair measured side by side is replayed on one thread, its two
`pair_depth` calls timed whole (``a``, ``b``) and inside the compiled kernels they call from
Python (``ka``, ``kb``: every numba dispatcher of an ``acra`` module, timed where a module's
Python calls it by its module attribute; numpy's own loops are counted as holding the GIL, so
the bound errs high). Two threads sharing one GIL take at least ``max(a, b, (a - ka) + (b - kb))``
of wall time for the pair, against ``a + b`` on one; the fastest pass's sums are printed. Then
the same split of `display.Displays.of` (the round's displays, which two threads could build
side by side too), over a cold run of the frames, fastest of ``--passes``.

``--kernels`` times instead two compiled kernels split over numba's threads (``prange`` over
chunks of their points, `_closest_split` and `_eval_split` below, numba's default threading
layer), against the kernel itself, on the calls the frames make: `acra.kernels.eval_points`' calls
(`acra.hspline.evaluate`, the displays' among them) and `acra.bvh._closest` on the distinct
corners of each `acra.depthbound.depth` call's triangles (its level-0 walks, within its
``reach``). Each call is timed alone, fastest of ``--passes``, with the whole kernel, and the
split one on 1 and on 2 threads (``numba.set_num_threads``); the sums are given by call size,
with a digest of the answers of each (the split's must be the kernel's: each point's answer is
its own, whichever chunk takes it).
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import hashlib
import pathlib
import statistics
import time

import numba
import numpy as np
from numba import njit, prange
from numba.core import config
from threadpoolctl import threadpool_limits

from acra.bvh import _closest
from acra.kernels import eval_points
from pipeline import residual, usdio
from pipeline import frames as F

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _fresh(s, parts: dict, made: dict):
    """``s`` with empty part caches, one per display (``parts``: by the recorded cache's id),
    and so the display it may take parts from (``like``); one fresh object per recorded one
    (``made``: by its id), so the calls of a pass share them as the run did."""
    if id(s) in made:
        return made[id(s)][1]
    like = getattr(s, "like", None)
    more = {} if like is None else {"like": _fresh(like, parts, made)}
    out = dataclasses.replace(s, parts=None if s.parts is None else parts.setdefault(id(s.parts), {}), **more)
    made[id(s)] = (s, out)
    return out


@njit(nogil=True, cache=True)
def _spin(n):
    """``n (int64)`` square roots summed: a compiled loop that holds no lock."""
    s = 0.0
    for i in range(n):
        s += np.sqrt(i + 0.5)
    return s


def _free_core() -> str:
    """The first line: a compiled loop twice, one after the other and side by side."""
    import threading

    n = np.int64(3_000_000)
    _spin(n)

    def after():
        _spin(n)
        _spin(n)

    def beside():
        worker = threading.Thread(target=_spin, args=(n,))
        worker.start()
        _spin(n)
        worker.join()

    return (f"a free second core? a compiled loop twice: one after the other {1e3 * _best(after, 5):.1f} ms, "
            f"side by side {1e3 * _best(beside, 5):.1f} ms wall")


def _pass(calls: list, threads: int) -> tuple[float, float, str, int]:
    """One replay of ``calls`` with ``threads``: wall s, CPU s, the answers' digest, the pairs
    measured side by side."""
    from pipeline import workers

    config.NUMBA_NUM_THREADS = threads
    both, sides = workers.both, [0]

    def counted(first, second):
        sides[0] += 1
        return both(first, second)

    workers.both = counted
    try:
        parts: dict = {}
        made: dict = {}
        fresh = [([_fresh(s, parts, made) for s in objects], kw) for objects, kw in calls]
        h = hashlib.sha1()
        w0, c0 = time.perf_counter(), time.process_time()
        for objects, kw in fresh:
            fr = residual.measure_frame(objects, **kw, measured={})
            for p in fr.pairs:
                ins = p.inside
                h.update(np.float64([ins.depth, ins.lower, ins.complete, ins.stopped, p.rel]).tobytes())
                for arr in (ins.points, ins.uv, ins.deep):
                    if arr is not None:
                        h.update(np.ascontiguousarray(arr).tobytes())
        return time.perf_counter() - w0, time.process_time() - c0, h.hexdigest()[:16], sides[0]
    finally:
        workers.both = both


@njit(parallel=True, nogil=True, cache=True)
def _closest_split(tri, order, lo, hi, left, right, start, count, points, bound, dist, close, face, bary, parts):
    """`acra.bvh._closest` on ``parts`` chunks of ``points (k, 3) float64`` in parallel: each
    point's answer does not depend on where its walk starts, so the same bits."""
    n = points.shape[0]
    for c in prange(parts):
        a, b = n * c // parts, n * (c + 1) // parts
        _closest(tri, order, lo, hi, left, right, start, count, points[a:b], bound[a:b], dist[a:b], close[a:b], face[a:b],
                 bary[a:b])


@njit(parallel=True, nogil=True, cache=True)
def _eval_split(u, v, order, side, top, nu, u_periodic, nv, v_periodic, cvs, levels, keys, shifts, ends, patch_rows,
                table_rows, table, out, parts):
    """`acra.kernels.eval_points` on ``parts`` chunks of the points in parallel, each chunk into
    its own ``(slots, m_c, 3) float64`` block copied into ``out``: each point is summed on its own."""
    n = u.shape[0]
    for c in prange(parts):
        a, b = n * c // parts, n * (c + 1) // parts
        block = np.empty((out.shape[0], b - a, 3))
        eval_points(u[a:b], v[a:b], order, side, top, nu, u_periodic, nv, v_periodic, cvs, levels, keys, shifts, ends,
                    patch_rows, table_rows, table, block)
        out[:, a:b] = block


def _best(f, passes: int) -> float:
    best = np.inf
    for _ in range(passes):
        t = time.perf_counter()
        f()
        best = min(best, time.perf_counter() - t)
    return best


def _kernels(stage, scene, frames: list, passes: int) -> None:
    """``--kernels``: the split kernels against the whole ones, call by call."""
    from acra import bvh, depthbound, kernels

    evals, depths = [], []
    real_eval, real_depth = kernels.eval_points, depthbound.depth

    def keep_eval(*a):
        evals.append(tuple(x.copy() if isinstance(x, np.ndarray) else x for x in a))
        return real_eval(*a)

    def keep_depth(tri, box, part, reach, *rest, **kw):
        tree = rest[6]
        pts = np.unique(np.ascontiguousarray(tri, np.float64).reshape(-1, 3), axis=0)
        depths.append((tree, pts, float(reach) if np.isfinite(reach) else np.inf))
        return real_depth(tri, box, part, reach, *rest, **kw)

    kernels.eval_points, depthbound.depth = keep_eval, keep_depth
    try:
        F.run_frames(stage, scene, frames)
    finally:
        kernels.eval_points, depthbound.depth = real_eval, real_depth
    rows: dict = {}
    digests: dict = collections.defaultdict(hashlib.sha1)
    for a in evals:
        out = a[-1]
        m = a[0].shape[0]
        size = "eval_points, calls of 1,000 points or more" if m >= 1000 else "eval_points, calls under 1,000 points"

        def whole(a=a, out=out):
            real_eval(*a[:-1], out)

        def split(a=a, out=out):
            _eval_split(*a[:-1], out, np.int64(2))

        _times(rows, digests, size, m, passes, whole, split, lambda out=out: out.tobytes())
    for tree, pts, reach in depths:
        k = len(pts)
        bound = np.full(k, reach)
        res = (np.full(k, np.inf), np.zeros((k, 3)), np.full(k, -1, np.int64), np.zeros((k, 3)))
        args = (tree.leaf_tri, tree.order, tree.lo, tree.hi, tree.left, tree.right, tree.start, tree.count, pts, bound)
        size = "closest walks, calls of 1,000 points or more" if k >= 1000 else "closest walks, calls under 1,000 points"

        def whole(args=args, res=res):
            bvh._closest(*args, *res)

        def split(args=args, res=res):
            _closest_split(*args, *res, np.int64(2))

        _times(rows, digests, size, k, passes, whole, split, lambda res=res: b"".join(r.tobytes() for r in res))
    print(f"compiled kernels split over numba's threads ({numba.threading_layer()} layer), fastest of {passes} per call, wall ms summed:")
    for size, (n, items, w, s1, s2) in sorted(rows.items()):
        print(f"  {size}: {n} calls, {items} points; whole {1e3 * w:.2f}, split on 1 thread {1e3 * s1:.2f}, "
              f"on 2 threads {1e3 * s2:.2f}; answers whole {digests[size, 'whole'].hexdigest()[:12]}, "
              f"split {digests[size, 'split'].hexdigest()[:12]}")


def _times(rows: dict, digests: dict, size: str, items: int, passes: int, whole, split, answer) -> None:
    """One call's fastest time whole and split on 1 and 2 threads, added to ``rows[size]``, and
    its answers to ``digests``."""
    whole()
    digests[size, "whole"].update(answer())
    numba.set_num_threads(1)
    split()
    digests[size, "split"].update(answer())
    w = _best(whole, passes)
    s1 = _best(split, passes)
    numba.set_num_threads(2)
    s2 = _best(split, passes)
    n, total, tw, t1, t2 = rows.get(size, (0, 0, 0.0, 0.0, 0.0))
    rows[size] = (n + 1, total + items, tw + w, t1 + s1, t2 + s2)


def _bound(calls: list, passes: int, stage=None, scene=None, frames=()) -> tuple:
    """``--bound``: the pairs measured side by side, their calls' CPU time whole and in the
    compiled kernels, and the least wall time two threads sharing the GIL could take (the
    fastest pass's sums: one thread's CPU, the least wall, the kernels' CPU, the pairs); and
    `_bound_displays` of a run of ``frames`` (with ``stage``)."""
    from _replay import kernels_clocked

    from pipeline import workers

    inside = [0.0]
    displays: list = []
    wrapped = kernels_clocked(inside)
    sides: list = []

    def one_after_the_other(first, second):
        out = []
        for f in (first, second):
            k0, t0 = inside[0], time.process_time()
            out.append(f())
            sides.append((time.process_time() - t0, inside[0] - k0))
        return tuple(out)

    config.NUMBA_NUM_THREADS = 2  # the path that measures a pair's sides side by side, run one after the other
    both = workers.both
    workers.both = one_after_the_other
    best = None
    try:
        if stage is not None:
            displays.extend(_bound_displays(stage, scene, frames, passes, inside, sides))
        with threadpool_limits(limits=1, user_api="blas"):
            for _ in range(passes):
                parts: dict = {}
                made: dict = {}
                fresh = [([_fresh(s, parts, made) for s in objects], kw) for objects, kw in calls]
                sides.clear()
                for objects, kw in fresh:
                    residual.measure_frame(objects, **kw, measured={})
                pairs = [(sides[i], sides[i + 1]) for i in range(0, len(sides), 2)]
                seq = sum(a[0] + b[0] for a, b in pairs)
                if best is None or seq < best[0]:
                    least = sum(max(a[0], b[0], (a[0] - a[1]) + (b[0] - b[1])) for a, b in pairs)
                    kernel = sum(a[1] + b[1] for a, b in pairs)
                    best = (seq, least, kernel, len(pairs))
        return best, displays
    finally:
        workers.both = both
        for module, name, f in wrapped:
            setattr(module, name, f)


def _bound_displays(stage, scene, frames: list, passes: int, inside: list, sides: list) -> tuple:
    """`display.Displays.of` (at a checkout with `Displays.build`, which `of` calls and the frame
    loop calls for a round's two displays at once, that) over a cold run of ``frames``: CPU s,
    CPU s inside the kernels (``inside``, `_bound`'s counter), calls; and of the calls that build
    two displays side by side (`pipeline.workers.both`, run one after the other into ``sides``
    by `_bound`): their count, the two builds' CPU s, and the least wall time two threads sharing
    the GIL take for them (as for a pair's sides); the fastest of ``passes`` runs."""
    from pipeline import display, run

    name = "build" if hasattr(display.Displays, "build") else "of"
    real = getattr(display.Displays, name)
    spent: list = []

    def built(self, *a, **k):
        k0, t0, n0 = inside[0], time.process_time(), len(sides)
        try:
            return real(self, *a, **k)
        finally:
            spent.append((time.process_time() - t0, inside[0] - k0, sides[n0:]))

    best = None
    setattr(display.Displays, name, built)
    try:
        with threadpool_limits(limits=1, user_api="blas"):
            for _ in range(passes):
                run.forget()
                F.run_frames(stage, scene, [5])
                spent.clear()
                F.run_frames(stage, scene, frames)
                pairs = [x[2] for x in spent if len(x[2]) == 2]
                total = (sum(x[0] for x in spent), sum(x[1] for x in spent), len(spent), len(pairs),
                         sum(a[0] + b[0] for a, b in pairs),
                         sum(max(a[0], b[0], (a[0] - a[1]) + (b[0] - b[1])) for a, b in pairs))
                if best is None or total[0] < best[0]:
                    best = total
    finally:
        setattr(display.Displays, name, real)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", type=pathlib.Path, default=ROOT / "scenes" / "dog_head_spike.py")
    ap.add_argument("--frames", default="13:17", help="frames START:END (default 13:17)")
    ap.add_argument("--passes", type=int, default=9)
    ap.add_argument("--kernels", action="store_true", help="time the split kernels instead (module docstring)")
    ap.add_argument("--bound", action="store_true", help="the most two threads could gain, from CPU time (module docstring)")
    args = ap.parse_args()
    a, b = (int(x) for x in args.frames.split(":"))
    stage = usdio.open_input(usdio.load_scene_file(args.scene))
    scene = usdio.read_scene(stage)
    F.run_frames(stage, scene, [5])
    if args.kernels:
        with threadpool_limits(limits=1, user_api="blas"):
            _kernels(stage, scene, list(range(a, b + 1)), args.passes)
        return
    calls = []
    real = residual.measure_frame

    def keep(objects, tolerance, pairs=None, measured=None, known=None, settle=(), over=False):
        calls.append((list(objects), {"tolerance": tolerance, "pairs": pairs, "known": known, "settle": settle,
                                      "over": over}))
        return real(objects, tolerance, pairs, measured, known, settle, over)

    residual.measure_frame = keep
    F.run_frames(stage, scene, list(range(a, b + 1)))
    residual.measure_frame = real
    kept = config.NUMBA_NUM_THREADS
    if args.bound:
        try:
            (seq, least, kernel, n), displays = _bound(calls, args.passes, stage, scene, list(range(a, b + 1)))
        finally:
            config.NUMBA_NUM_THREADS = kept
        print(f"{n} pairs measured side by side, fastest of {args.passes} passes on one thread: {1e3 * seq:.1f} ms CPU, "
              f"{1e3 * kernel:.1f} of it in compiled kernels called from Python; two threads sharing the GIL: at least "
              f"{1e3 * least:.1f} ms wall ({1e3 * (seq - least):.1f} less at most)")
        total, inner, count, two, builds, wall = displays
        print(f"display.Displays.of, frames {a}-{b} cold, fastest of {args.passes}: {count} calls, {1e3 * total:.1f} ms CPU, "
              f"{1e3 * inner:.1f} of it in compiled kernels called from Python")
        if two:
            print(f"{two} of them build two displays side by side: the builds {1e3 * builds:.1f} ms CPU on one thread; "
                  f"two threads sharing the GIL: at least {1e3 * wall:.1f} ms wall ({1e3 * (builds - wall):.1f} less at most)")
        return
    out: dict = {1: [], 2: []}
    try:
        with threadpool_limits(limits=1, user_api="blas"):  # as the frame loop runs
            _pass(calls, 1)  # untimed: the kernels' first calls
            for _ in range(args.passes):
                for threads in (1, 2):
                    out[threads].append(_pass(calls, threads))
    finally:
        config.NUMBA_NUM_THREADS = kept
    print(_free_core())
    print(f"{args.scene.name}, frames {a}-{b}: {len(calls)} measure_frame calls, {args.passes} passes each, alternated")
    for threads, runs in out.items():
        wall = [1e3 * r[0] for r in runs]
        cpu = [1e3 * r[1] for r in runs]
        digests = sorted({r[2] for r in runs})
        print(f"  {threads} thread{'s' if threads > 1 else ''}: wall {min(wall):.1f}-{max(wall):.1f} ms "
              f"(median {statistics.median(wall):.1f}), CPU {min(cpu):.1f}-{max(cpu):.1f} ms "
              f"(median {statistics.median(cpu):.1f}), pairs side by side {runs[0][3]}; answers {' '.join(digests)}")


if __name__ == "__main__":
    main()
