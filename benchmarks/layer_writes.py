"""The output layer's write, per frame, for each kind of frame and format, timed.

    PYTHONPATH=$PWD python3 benchmarks/layer_writes.py [SCENE.py] [--repeat 9] [--wall]

Runs the scene once (`frames.run_frames`), then writes layers of its results, each as ``.usda``
and as ``.usdc`` (`output_layer.write_output`, each write to a new file, removed untimed), the
layers alternated, two writes of each first untimed: its collision frames alone; its free frames
alone (not the first frame); the free frames with the first; every computed frame; the free
frames around the collision frames (the computed frame before and after each run of them); and
those with the collision frames. Prints the CPU milliseconds (`time.process_time`) per frame of
the layer's kind, median and range over ``--repeat`` writes, and what `acra bench` charges a
collision frame in CPU time (`pipeline.bench._writes`): the last layer less the one before, over
the collision frames' count, each pass's difference, median and range. ``--wall`` reads the wall
clock (``time.perf_counter``) instead: a write whose arrays' texts are formatted on two threads
(`pipeline.workers`) spends more CPU time than wall time where a second core is free. ``--profile FMT``
(``usda`` or ``usdc``) then profiles that share: cProfile with the CPU clock over ``--repeat``
writes of each of the two layers, and prints the functions whose own time differs most between
them, per collision frame (cProfile's overhead included, so the parts, not the total, are the
figures to read). ``--sides`` then writes the layer of every computed frame ``.usda`` ``--repeat``
times with ``NUMBA_NUM_THREADS`` 1 and 2 alternated (numba's setting, read by
`pipeline.workers.threads` at each write), wall and CPU ms and the layers' digests (one and two
threads must give the same bytes), and ``--repeat`` times more with the two sides of its texts
(`acra.floattext.tuples_texts`) run one after the other in the caller's thread: each side's thread
CPU ms finding its values and formatting its texts, the most a second core can take of the write. The script imports
`acra` and `pipeline` from ``PYTHONPATH``: run it with two checkouts' paths, alternated, to
compare them on the same results.
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pathlib
import pstats
import shutil
import statistics
import tempfile
import time

from pipeline import frames, output_layer, usdio

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene", nargs="?", type=pathlib.Path, default=ROOT / "scenes" / "dog_head_spike.py")
    parser.add_argument("--repeat", type=int, default=9)
    parser.add_argument("--profile", choices=("usda", "usdc"), help="profile a collision frame's share of the run's write")
    parser.add_argument("--wall", action="store_true", help="wall-clock time instead of CPU time")
    parser.add_argument("--sides", action="store_true", help="one thread against two on the whole run's .usda layer, and each side's CPU")
    args = parser.parse_args()
    clock = time.perf_counter if args.wall else time.process_time
    with tempfile.TemporaryDirectory() as tmp:
        src = pathlib.Path(tmp) / args.scene.name
        shutil.copy(args.scene, src)
        stage_path = usdio.load_scene_file(src)
        stage = usdio.open_input(stage_path)  # the input layer open, as in a run
        scene = usdio.read_scene(stage)
        result, stats = frames.run_frames(stage, scene, list(range(scene.start, scene.end + 1)), frames.RunOptions())
        computed = [s.frame for s in stats if not s.hold]
        kinds = {"collision frames alone": [s.frame for s in stats if s.in_collision and not s.hold],
                 "free frames alone": [s.frame for s in stats if not s.in_collision and not s.hold and s.frame != scene.start],
                 "free frames and the first": [s.frame for s in stats if not s.in_collision and not s.hold],
                 "every computed frame": computed}
        hit = set(kinds["collision frames alone"])
        kinds["the free frames around them"] = [f for i, f in enumerate(computed) if f not in hit and (
            (i > 0 and computed[i - 1] in hit) or (i + 1 < len(computed) and computed[i + 1] in hit))]
        kinds["those with the collision frames"] = sorted(set(kinds["the free frames around them"]) | hit)
        kinds = {k: v for k, v in kinds.items() if v}
        print(f"`python3 benchmarks/layer_writes.py {args.scene.name} --repeat {args.repeat}{' --wall' if args.wall else ''}`: "
              f"{'wall' if args.wall else 'CPU'} ms per frame of the layer's kind, "
              f"median (range) of {args.repeat} writes; load average {os.getloadavg()[0]:.1f} (1 min)\n")
        print("| layer | frames | `.usda` | `.usdc` |\n|---|---:|---:|---:|")
        times = {(k, fmt): [] for k in kinds for fmt in ("usda", "usdc")}
        for fmt in ("usda", "usdc"):
            for i in range(args.repeat + 2):
                for kind, which in kinds.items():
                    part = output_layer.FramesResult({f: r for f, r in result.frames.items() if f in set(which)}, result.topologies)
                    out = pathlib.Path(tmp) / f"layer{i}.acra.{fmt}"
                    t = clock()
                    output_layer.write_output(stage_path, out, scene, part)
                    ms = 1e3 * (clock() - t)
                    out.unlink()
                    if i >= 2:
                        times[kind, fmt].append(ms)

        def cell(xs):
            return f"{statistics.median(xs):.3f} ({min(xs):.3f}–{max(xs):.3f})"

        for kind, which in kinds.items():
            print(f"| {kind} | {len(which)} | {cell([t / len(which) for t in times[kind, 'usda']])} | "
                  f"{cell([t / len(which) for t in times[kind, 'usdc']])} |")
        n_col = len(kinds.get("collision frames alone", []))
        if n_col:
            share = [cell([(a - f) / n_col for a, f in zip(times["those with the collision frames", fmt], times["the free frames around them", fmt])])
                     for fmt in ("usda", "usdc")]
            print(f"| a collision frame's share of the run's write (`acra bench`) | {n_col} | {share[0]} | {share[1]} |")
            if args.profile:
                print(_profile_share(stage_path, scene, result, kinds, args.profile, args.repeat, pathlib.Path(tmp)))
        if args.sides:
            part = output_layer.FramesResult({f: r for f, r in result.frames.items() if f in set(computed)}, result.topologies)
            print(_sides(stage_path, scene, part, args.repeat, pathlib.Path(tmp)))


def _profile_share(stage_path, scene, result, kinds: dict, fmt: str, repeat: int, tmp: pathlib.Path) -> str:
    """The functions whose own CPU time differs most between a layer of the collision frames with
    the free frames around them and one of those free frames alone, per collision frame: where
    a collision frame's share of the run's write goes."""
    own = {}
    for kind in ("those with the collision frames", "the free frames around them"):
        part = output_layer.FramesResult({f: r for f, r in result.frames.items() if f in set(kinds[kind])}, result.topologies)
        prof = cProfile.Profile(time.process_time)
        for i in range(repeat + 1):
            out = tmp / f"profile{i}.acra.{fmt}"
            if i:
                prof.enable()
            output_layer.write_output(stage_path, out, scene, part)
            if i:
                prof.disable()
            out.unlink()
        own[kind] = {k: v[2] for k, v in pstats.Stats(prof).stats.items()}
    n = len(kinds["collision frames alone"]) * repeat
    every, free = own["those with the collision frames"], own["the free frames around them"]
    diff = sorted(((t - free.get(k, 0.0)) / n, k) for k, t in every.items())[::-1]
    lines = [f"\nA collision frame's share of the `.{fmt}` write, by function (own CPU ms, cProfile, {repeat} writes of each layer):\n",
             "| function | ms |", "|---|---:|"]
    lines += [f"| `{pathlib.Path(k[0]).name}:{k[2]}` | {1e3 * t:.3f} |" for t, k in diff[:12]]
    lines.append(f"| all | {1e3 * sum(t for t, _ in diff):.3f} |")
    return "\n".join(lines)

def _sides(stage_path, scene, part, repeat: int, tmp: pathlib.Path) -> str:
    """The layer ``part`` written ``.usda`` with one thread and two, alternated, then its texts'
    two sides one after the other, each side's calls timed by their thread's CPU clock."""
    import hashlib

    from numba.core import config

    from acra import floattext
    from pipeline import workers

    def cell(xs):
        return f"{statistics.median(xs):.1f} ({min(xs):.1f}–{max(xs):.1f})"

    setting = config.NUMBA_NUM_THREADS
    times: dict = {n: ([], [], set()) for n in (1, 2)}
    try:
        for i in range(repeat + 1):
            for n in ((1, 2) if i % 2 else (2, 1)):
                config.NUMBA_NUM_THREADS = n
                out = tmp / f"sides{i}_{n}.acra.usda"
                w, c = time.perf_counter(), time.process_time()
                output_layer.write_output(stage_path, out, scene, part)
                w, c = 1e3 * (time.perf_counter() - w), 1e3 * (time.process_time() - c)
                times[n][2].add(hashlib.sha256(out.read_bytes()).hexdigest()[:12])
                out.unlink()
                if i:
                    times[n][0].append(w)
                    times[n][1].append(c)
        lines = [f"\nThe layer of every computed frame, `.usda`, {repeat} writes each, alternated (ms):\n",
                 "| threads | wall | CPU | digest |", "|---:|---:|---:|---|"]
        lines += [f"| {n} | {cell(w)} | {cell(c)} | {', '.join(sorted(d))} |" for n, (w, c, d) in times.items()]
        spent: dict = {}
        real = {name: getattr(floattext, name) for name in ("_found", "_formatted")}

        def timed(name):
            def call(*a):
                t = time.thread_time()
                got = real[name](*a)
                spent.setdefault(name, []).append(1e3 * (time.thread_time() - t))  # a write's sides in order
                return got
            return call

        config.NUMBA_NUM_THREADS = 2
        both, workers.both = workers.both, lambda first, second: (first(), second())
        for name in real:
            setattr(floattext, name, timed(name))
        per: dict = {}
        try:
            for i in range(repeat + 1):
                spent.clear()
                out = tmp / f"sides{i}.acra.usda"
                output_layer.write_output(stage_path, out, scene, part)
                out.unlink()
                if i:
                    for name, ms in spent.items():
                        for side, t in enumerate(ms):
                            per.setdefault((name, side), []).append(t)
        finally:
            workers.both = both
            for name, f in real.items():
                setattr(floattext, name, f)
        lines += ["\nIts texts' two sides one after the other, each side's thread CPU ms:\n", "| call | side 1 | side 2 |", "|---|---:|---:|"]
        lines += [f"| `floattext.{name}` | {cell(per.get((name, 0), [0.0]))} | {cell(per.get((name, 1), [0.0]))} |" for name in real]
        return "\n".join(lines)
    finally:
        config.NUMBA_NUM_THREADS = setting


if __name__ == "__main__":
    main()
