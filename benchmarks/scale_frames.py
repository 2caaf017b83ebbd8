"""The scale curve's ×1 head and its ×16 head at the default density 8, collision frame by frame.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=$PWD python3 benchmarks/scale_frames.py [--repeat 5]
    PYTHONPATH=$PWD python3 benchmarks/scale_frames.py --scenes   # first rounds completed per scene

`benchmarks/scale_curve.py`'s ×1 stage (density 8) and ×16 stage at density 8 (the run whose
ratio to ×1 is the goal's hardest; docs/scale-curve.md), each run over the whole 30-frame scene
with `pipeline.run.run_file` from a cold memo (`pipeline.run.forget`), after one untimed warm-up
run of each. First one counting pass per scale: per collision frame its rounds
(`FrameStats.iterations`), residual and the display measure's calls (`residual.measure_frame`,
its stopped first rounds, `residual.complete` and the pairs it measures in full,
`residual.pair_depth` with and without a ``stop``). Then ``--repeat`` timed passes, alternating
the scales, with the frame loop's clock read as the process's CPU time (``time.process_time``):
the median over the passes of each pass's median CPU ms a collision frame (``ms_total`` and
``ms_visible``), their ranges, and the ×16/×1 ratio of the medians. Last, a digest of every
`FrameStats` figure but the times and of the output layers' bytes: two checkouts agree where
their digests agree. Another checkout's code runs with its own ``PYTHONPATH``, so two checkouts
can be alternated.

``--scenes`` instead runs every scene of ``scenes/`` once and prints, per scene, how many
stopped first rounds `residual.complete` measured in full and how many stopped pairs they held.

``--functions`` adds, after the timed passes, ``--repeat`` passes per scale with the CPU time
spent in each of `FUNCTIONS` (the work that a larger model can make larger: the CV hull's
inside test, the coarse grid's orientation, the display's translation to world, the level-0
box of a responded surface) summed per
collision frame, inclusive of what they call, and prints their median CPU ms per collision
frame at ×1 and ×16 (the median over the passes of each pass's median over the five frames).
"""

from __future__ import annotations

import argparse
import hashlib
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # scale_curve and one_frame, beside this script
import one_frame  # noqa: E402
import scale_curve  # noqa: E402
from pipeline import residual  # noqa: E402
from pipeline.run import forget, run_file  # noqa: E402

RUNS = ((0, 8), (2, 8))  # (refinements of the head's level 0, collision density): ×1 and ×16
TIMES = one_frame.TIMES
STAGES = ("ms_setup", "ms_detect", "ms_convert", "ms_respond", "ms_visible", "ms_output")


def _functions() -> list[tuple[object, str, str]]:
    """``(owner, attribute, label)`` of the functions ``--functions`` times: class attributes
    (a ``cached_property``'s function) and module functions that the frame loop calls through
    their module."""
    from pipeline import frames, model, queries, shape
    return [(shape.HullIndex, "within", "HullIndex.within"), (shape.Shape, "outward", "Shape.outward (with _coarse)"),
            (shape.Shape, "_coarse", "Shape._coarse"), (shape.Shape, "closed", "Shape.closed"),
            (queries, "signed", "queries.signed"), (model, "_translated", "model._translated"),
            (frames, "_inner_box", "frames._inner_box")]


def _timing(spent: dict):
    """Wrap `_functions` to add their CPU seconds to ``spent`` (label -> s); return a function
    restoring the originals."""
    import functools
    undo = []
    for owner, name, label in _functions():
        held = owner.__dict__[name] if isinstance(owner, type) else getattr(owner, name)
        target = held.func if isinstance(held, functools.cached_property) else held

        def timed(*args, _f=target, _label=label, **kw):
            t = time.process_time()
            try:
                return _f(*args, **kw)
            finally:
                spent[_label] = spent.get(_label, 0.0) + time.process_time() - t
        if isinstance(held, functools.cached_property):
            held.func = timed
            undo.append(lambda held=held, target=target: setattr(held, "func", target))
        else:
            setattr(owner, name, timed)
            undo.append(lambda owner=owner, name=name, held=held: setattr(owner, name, held))

    def restore():
        for u in undo:
            u()
    return restore


def functions(srcs: dict, tmp: Path, repeat: int) -> None:
    """``--functions``: median CPU ms per collision frame in each of `_functions`, ×1 and ×16."""
    from pipeline import frames as F
    spent: dict = {}
    per = {r: {} for r in RUNS}  # label -> each pass's median over its collision frames
    on_frame = F._Run.frame
    restore = _timing(spent)
    try:
        for _ in range(repeat):
            for scale, density in RUNS:
                frames = []

                def frame(self, f, result):
                    spent.clear()
                    st = on_frame(self, f, result)
                    if st.in_collision:
                        frames.append(dict(spent))
                    return st
                F._Run.frame = frame
                forget()
                try:
                    run_file(srcs[scale], output=tmp / f"fn{scale}.acra.usda", density=density)
                finally:
                    F._Run.frame = on_frame
                for _, _, label in _functions():
                    per[scale, density].setdefault(label, []).append(
                        1e3 * float(np.median([fr.get(label, 0.0) for fr in frames])))
    finally:
        restore()
    print("CPU ms per collision frame in (median of passes of the median over the collision frames): ×1 / ×16")
    for _, _, label in _functions():
        a, b = (statistics.median(per[r][label]) for r in RUNS)
        print(f"  {label}: {a:.2f} / {b:.2f}")


def _counting():
    """Wrap `residual.measure_frame`, `complete` and `pair_depth` with counters; return the
    counters (a dict) and a function restoring the originals."""
    counts = {"measure_frame": 0, "settled": 0, "complete": 0, "completed_pairs": 0, "pair_depth": 0, "pair_depth_stop": 0}
    originals = residual.measure_frame, residual.complete, residual.pair_depth

    def measure_frame(*args, **kw):
        counts["measure_frame"] += 1
        fr = originals[0](*args, **kw)
        counts["settled"] += bool(fr.stopped)
        return fr

    def complete(fr, *args, **kw):
        counts["complete"] += bool(fr.stopped)
        counts["completed_pairs"] += sum(ins.stopped for _, _, ins in fr.measured)
        return originals[1](fr, *args, **kw)

    def pair_depth(a, b, target, decide=np.inf, stop=np.inf):
        counts["pair_depth_stop" if stop < np.inf else "pair_depth"] += 1
        return originals[2](a, b, target, decide, stop)

    residual.measure_frame, residual.complete, residual.pair_depth = measure_frame, complete, pair_depth

    def restore():
        residual.measure_frame, residual.complete, residual.pair_depth = originals
    return counts, restore


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--scenes", action="store_true", help="count the completed first rounds of every scene")
    ap.add_argument("--functions", action="store_true", help="CPU ms per collision frame in the model-sized functions")
    args = ap.parse_args()
    if args.scenes:
        return scenes()
    held = tempfile.TemporaryDirectory(prefix="scale_frames_")  # removed when main returns
    tmp = Path(held.name)
    grids = scale_curve.head_grids()
    srcs = {}
    for scale, _ in RUNS:
        srcs[scale] = tmp / f"scale{scale}.usda"
        scale_curve.A.save(scale_curve.build_stage(scale, grids[scale]), srcs[scale])
    h = hashlib.sha1()
    for scale, density in RUNS:  # warm-up: imports, numba's cache
        run_file(srcs[scale], output=tmp / "warmup.acra.usda", density=density)
    for scale, density in RUNS:  # the counting pass, frame by frame
        forget()
        counts, restore = _counting()
        rows, last = [], dict(counts)
        from pipeline import frames as F
        on_frame = F._Run.frame

        def frame(self, f, result):
            nonlocal last
            st = on_frame(self, f, result)
            if st.in_collision:
                rows.append((f, st.iterations, st.residual_rel, {k: counts[k] - last[k] for k in counts}))
            last = dict(counts)
            return st
        F._Run.frame = frame
        try:
            rep = run_file(srcs[scale], output=tmp / f"count{scale}.acra.usda", density=density)
        finally:
            F._Run.frame = on_frame
            restore()
        print(f"×{4 ** scale} density {density}: per collision frame (rounds, loop's residual, display-measure calls)")
        for f, its, rel, c in rows:
            print(f"  frame {f}: rounds {its}, residual {rel:.6e}, " + ", ".join(f"{k} {v}" for k, v in c.items()))
        for st in rep.stats:
            for k, v in sorted(vars(st).items()):
                if k not in TIMES:
                    one_frame._digest(h, k)
                    one_frame._digest(h, v)
        h.update((tmp / f"count{scale}.acra.usda").read_bytes())
    cpu = {r: [] for r in RUNS}
    vis = {r: [] for r in RUNS}
    per = {r: {} for r in RUNS}  # frame -> CPU ms of each pass
    split = {r: {} for r in RUNS}  # (frame, stage) -> CPU ms of each pass
    wall = time.perf_counter
    for k in range(args.repeat):
        for scale, density in RUNS:
            forget()
            time.perf_counter = time.process_time
            try:
                stats = run_file(srcs[scale], output=tmp / f"cpu{scale}.acra.usda", density=density).stats
            finally:
                time.perf_counter = wall
            hit = [s for s in stats if s.in_collision]
            cpu[scale, density].append(float(np.median([s.ms_total for s in hit])))
            vis[scale, density].append(float(np.median([s.ms_visible for s in hit])))
            for s in hit:
                per[scale, density].setdefault(s.frame, []).append(s.ms_total)
                for key in STAGES:
                    split[scale, density].setdefault((s.frame, key), []).append(getattr(s, key))
    med = {}
    for r in RUNS:
        med[r] = statistics.median(cpu[r])
        print(f"×{4 ** r[0]} density {r[1]}: CPU ms a collision frame {med[r]:.2f} ({min(cpu[r]):.2f}–{max(cpu[r]):.2f}), "
              f"rounds' residual {statistics.median(vis[r]):.2f} ({min(vis[r]):.2f}–{max(vis[r]):.2f})")
        print("  per frame, median CPU ms: " + ", ".join(f"{f}: {statistics.median(v):.2f}" for f, v in sorted(per[r].items())))
        for f in sorted(per[r]):
            print(f"    frame {f}: " + ", ".join(f"{k[3:]} {statistics.median(split[r][f, k]):.2f}" for k in STAGES))
    print(f"ratio ×16 density 8 / ×1: {med[RUNS[1]] / med[RUNS[0]]:.3f}")
    print(f"digest {h.hexdigest()[:12]}")
    if args.functions:
        functions(srcs, tmp, args.repeat)


def scenes() -> None:
    """Per scene of ``scenes/``: the stopped first rounds `residual.complete` measured in full,
    and the stopped pairs they held."""
    counts, restore = _counting()
    held = tempfile.TemporaryDirectory(prefix="scale_frames_")  # removed when main returns
    tmp = Path(held.name)
    rows = []
    try:
        for src in sorted((Path(__file__).resolve().parents[1] / "scenes").glob("[!_]*.py")):
            before = dict(counts)
            forget()
            run_file(src, output=tmp / f"{src.stem}.acra.usda")
            rows.append(f"{src.stem} {counts['complete'] - before['complete']}/{counts['completed_pairs'] - before['completed_pairs']}")
    finally:
        restore()
    print("completed first rounds / their stopped pairs: " + ", ".join(rows))
    print(f"all scenes: {counts['complete']} / {counts['completed_pairs']}")


if __name__ == "__main__":
    main()
