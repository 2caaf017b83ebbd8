"""The responses of a run's collision frames, replayed and timed.

    python3 benchmarks/respond_calls.py [SCENE.py] [--frames 13:17] [--repeat 5] [--save FILE] [--check FILE]
                                        [--split MODULE:FUNCTION ...] [--per-call] [--decompositions]

Runs the scene's ``--frames`` (after a free frame, as `benchmarks/stage_split.py` does) and
records every `acra.respond.respond` call with its arguments, then calls `respond` again on each
recorded argument set ``--repeat`` times (each repeat after `pipeline.run.forget`, as a cold run
of the frames) and prints the calls and the milliseconds (wall and
CPU) per collision frame of all of them (the least over the repeats of each call, summed). Run it with
``PYTHONPATH`` set to two checkouts to compare their responses on the same calls. ``--save FILE``
stores each call's responded surface (level-0 CVs, every level's keys and offsets, the
details it hands back) and
``--check FILE`` prints the largest difference from a stored run over the surface's size
(the calls are the same when both checkouts give the same surfaces up to the recorded frames).
``--split acra.respond:solve acra.details:moved_details ...`` (each function named where its caller
looks it up: `respond` calls `acra.respond.solve`) records every call of each named
function during one cold pass of the responses, then calls it again on each recorded argument
set ``--repeat`` times (each repeat after `pipeline.run.forget`) and prints its calls and CPU
milliseconds per collision frame (the least of each call, summed): each function alone, run
warm in a loop, so a lower bound of its share of the responses (nested functions count in
each that calls them). ``--per-call`` prints each call's least CPU milliseconds with its
surface's depth and data points (call ``n`` is `benchmarks/respond_laps.py`'s ``--calls n``).
``--decompositions`` lists each solve whose decomposition a cold pass of the responses computes
(`acra.interpolate._decomposition` with no kept entry): its call, level, dense weights' shape,
their rows and columns with no nonzero entry, the least CPU microseconds over ``--repeat`` x 20
of the dense weights, the Gram product and `eigh` (as `_decomposition` takes them), and the
earlier computed solve whose dense weights have the same bits, if any.
"""

from __future__ import annotations

import argparse
import pathlib
import pickle
import time

import numpy as np
from threadpoolctl import threadpool_limits

from acra import respond as R
from pipeline import frames, run, usdio

ROOT = pathlib.Path(__file__).resolve().parents[1]


def record(scene: pathlib.Path, first: int, last: int, warm: int) -> list[tuple]:
    """``(args, kwargs)`` of every `respond` call of frames ``first..last``."""
    calls: list[tuple] = []
    respond = R.respond

    def recording(*args, **kwargs):
        calls.append((args, kwargs))
        return respond(*args, **kwargs)

    stage = usdio.open_input(usdio.load_scene_file(scene))
    parsed = usdio.read_scene(stage)
    frames.run_frames(stage, parsed, [warm])
    R.respond = recording
    try:
        frames.run_frames(stage, parsed, list(range(first, last + 1)))
    finally:
        R.respond = respond
    return calls


def surface_arrays(hs, report) -> list[np.ndarray]:
    """A responded surface as plain arrays: level-0 CVs, each fine level's CV keys, offsets,
    patches, then the details the response hands back (vectors and frames of each level)."""
    out = [np.asarray(hs.cvs)]
    for lev in hs.fine:
        out += [np.asarray(lev.cv_keys), np.asarray(lev.offsets), np.asarray(lev.patches)]
    if report.details is not None:
        out += [*report.details.vectors, *report.details.frames]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", default=str(ROOT / "scenes" / "dog_head_spike.py"))
    ap.add_argument("--frames", default="13:17")
    ap.add_argument("--warm", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--save")
    ap.add_argument("--check")
    ap.add_argument("--split", nargs="+", default=[], metavar="MODULE:FUNCTION")
    ap.add_argument("--per-call", action="store_true")
    ap.add_argument("--decompositions", action="store_true")
    args = ap.parse_args()
    first, last = (int(x) for x in args.frames.split(":"))
    calls = record(pathlib.Path(args.scene), first, last, args.warm)
    best = np.full(len(calls), np.inf)
    cpu = np.full(len(calls), np.inf)
    results = []
    with threadpool_limits(limits=1, user_api="blas"):  # as the frame loop runs: BLAS on one thread
        _replay(calls, args.repeat, best, cpu, results)
    nframes = last - first + 1
    print(f"{len(calls)} respond calls, per collision frame: {1e3 * best.sum() / nframes:.2f} ms wall, "
          f"{1e3 * cpu.sum() / nframes:.2f} ms CPU (least of {args.repeat} per call, summed)")
    if args.per_call:
        for n, (a, _) in enumerate(calls):
            print(f"call {n}: depth {a[0].depth}, {len(a[1].uv)} data points, {1e3 * cpu[n]:.3f} ms CPU")
    _check(args, calls, results)
    if args.split:
        with threadpool_limits(limits=1, user_api="blas"):
            _split(calls, args.split, args.repeat, nframes)
    if args.decompositions:
        with threadpool_limits(limits=1, user_api="blas"):
            _decompositions(calls, args.repeat)


def _split(calls, names, repeat, nframes) -> None:
    """Each named function's CPU ms per collision frame over the responses' calls of it (see the
    module's docstring)."""
    import importlib

    targets = []
    for name in names:
        module, function = name.split(":")
        targets.append((importlib.import_module(module), function, []))
    originals = [getattr(m, f) for m, f, _ in targets]

    def recording(f, seen):
        def g(*a, **kw):
            seen.append((a, kw))
            return f(*a, **kw)
        return g

    for (m, f, seen), original in zip(targets, originals):
        setattr(m, f, recording(original, seen))
    try:
        run.forget()
        for a, kw in calls:
            R.respond(*a, **kw)
    finally:
        for (m, f, _), original in zip(targets, originals):
            setattr(m, f, original)
    for (m, f, seen), original in zip(targets, originals):
        least = np.full(len(seen), np.inf)
        for _ in range(repeat):
            run.forget()
            for n, (a, kw) in enumerate(seen):
                c = time.process_time()
                original(*a, **kw)
                least[n] = min(least[n], time.process_time() - c)
        print(f"{m.__name__}.{f}: {len(seen) / nframes:.1f} calls, {1e3 * least.sum() / nframes:.3f} ms CPU per collision frame")


def _decompositions(calls, repeat) -> None:
    """`main` with ``--decompositions`` (see the module's docstring)."""
    from acra import interpolate as I

    decomposition, eigh, seen, at, solved = I._decomposition, I._eigh, [], [0], [False]

    def solving(g):
        solved[0] = True
        return eigh(g)

    def recording(pw, act, every):
        solved[0] = False
        out = decomposition(pw, act, every)
        if solved[0]:  # no kept entry: `_decomposition` decomposed the Gram matrix
            seen.append((at[0], pw, act, every, out[0]))
        return out

    I._decomposition, I._eigh = recording, solving
    try:
        run.forget()
        for n, (a, kw) in enumerate(calls):
            at[0] = n
            R.respond(*a, **kw)
    finally:
        I._decomposition, I._eigh = decomposition, eigh
    for i, (n, pw, act, every, W) in enumerate(seen):
        least = [np.inf] * 3
        for _ in range(20 * repeat):
            t0 = time.process_time()
            dense = pw.dense() if every else pw.dense()[act]
            t1 = time.process_time()
            gram = dense @ dense.T
            t2 = time.process_time()
            eigh(gram)
            t3 = time.process_time()
            least = [min(x, y) for x, y in zip(least, (t1 - t0, t2 - t1, t3 - t2))]
        same = next((j for j in range(i) if seen[j][4].shape == W.shape and np.array_equal(seen[j][4], W)), None)
        print(f"call {n} level {pw.level}: weights {W.shape[0]}x{W.shape[1]}, {int(np.count_nonzero(~W.any(axis=1)))} zero rows, "
              f"{int(np.count_nonzero(~W.any(axis=0)))} zero columns; dense {1e6 * least[0]:.1f}, Gram {1e6 * least[1]:.1f}, "
              f"eigh {1e6 * least[2]:.1f} us CPU; " + ("no earlier one's weights the same" if same is None else f"the weights of decomposition {same}"))


def _replay(calls, repeat, best, cpu, results) -> None:
    for rep in range(repeat):
        # each repeat a cold run: what a response keeps across frames (`acra.respond._KEPT`)
        # serves a repeat's later frames, as in a run, not the next repeat
        run.forget()
        for n, (a, kw) in enumerate(calls):
            t, c = time.perf_counter(), time.process_time()
            hs, report = R.respond(*a, **kw)
            best[n] = min(best[n], time.perf_counter() - t)
            cpu[n] = min(cpu[n], time.process_time() - c)
            if rep == 0:
                results.append(surface_arrays(hs, report))


def _check(args, calls, results) -> None:
    if args.save:
        pathlib.Path(args.save).write_bytes(pickle.dumps(results))
    if args.check:
        ref = pickle.loads(pathlib.Path(args.check).read_bytes())
        worst, same = 0.0, 0
        for n, (mine, theirs) in enumerate(zip(results, ref)):
            size = calls[n][0][0].size()
            if len(mine) != len(theirs) or any(x.shape != y.shape for x, y in zip(mine, theirs)):
                print(f"call {n}: the surfaces differ in structure")
                continue
            d = max((float(np.abs(x.astype(float) - y.astype(float)).max()) if x.size else 0.0) for x, y in zip(mine, theirs))
            same += all(np.array_equal(x, y) for x, y in zip(mine, theirs))
            worst = max(worst, d / size)
        print(f"against {args.check}: {same} of {len(results)} surfaces the same bits; largest difference {worst:.3g} of the size")


if __name__ == "__main__":
    main()
