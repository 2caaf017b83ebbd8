"""The display work of a collision frame in CPU time: a round's displays and the run's.

    PYTHONPATH=$PWD python3 benchmarks/display_split.py [--repeat 5] [--calls]

Runs `dog_head_spike` frame 5, then frames 13-17 once to warm up and ``--repeat`` more times in
one process, each after `pipeline.run.forget` (every answer kept by content dropped, as a fresh
run starts without them) and an untimed frame 5 (the input's shapes, which a run builds at its
first frame), and prints per function the least over the repeats of its
CPU milliseconds (``time.process_time``, nested) per collision frame: `display.Displays.of` (at a
checkout with `Displays.build`, which `of` calls and the frame loop calls for a round's two
displays at once, that; a
round's display, with `run_topology` and `grid_samples` inside it), `display.finish` (the run's
display and its residual: `evaluate_run`, `run_topologies`), `acra.respond.respond`, and the
whole `run_frames` call; then the median over the repeats of the minor page faults a collision
frame (``getrusage``: memory the loop takes anew) and the process's resident size after the
last. Then one more untimed pass of frames 13-17 prints a digest of what the displays hold: every
display `display.Displays.of` builds (its points, limit normals, face counts and indices, in the
order built) and the run's display of each frame (`display.finish`: points and normals), so two
checkouts can be shown to give the same bits. The CPU time is the process's: where a round's two
displays are built in two threads, a function's figure holds the other thread's work while both
run, so compare functions with ``NUMBA_NUM_THREADS=1`` (``--calls`` too). ``--calls`` adds one more pass, outside the table's figures,
that lists every display `display.Displays.of` builds (at a checkout with `Displays.build`, each
display its `_build` builds, the plans outside the row), by frame: its vertices, the points
evaluated (`acra.hspline.evaluate` inside it, a degenerate row's second-order evaluation
included) and the CPU milliseconds of its topology (``built`` where `acra.lattice.adaptive_mesh`
ran), its evaluations, its `grid_samples` and the whole call, with the sum a frame. Run it with ``PYTHONPATH`` set to another checkout
to compare.
"""

from __future__ import annotations

import argparse
import collections
import hashlib
import pathlib
import resource
import statistics
import time

import numpy as np

from acra import respond as R
from pipeline import display, frames, usdio

ROOT = pathlib.Path(__file__).resolve().parents[1]
SPENT: dict = collections.defaultdict(float)


def _timed(label: str, f):
    def wrapper(*args, **kwargs):
        t = time.process_time()
        try:
            return f(*args, **kwargs)
        finally:
            SPENT[label] += time.process_time() - t
    return wrapper


# what builds the rounds' displays: `display.Displays.build` (which `of` calls, and which the frame
# loop calls for a round's two displays at once) where the checkout has it, else `Displays.of`
_BUILDS = "build" if hasattr(display.Displays, "build") else "of"


def _digest(stage, scene) -> str:
    """The first 16 hex digits of a SHA-256 over frames 13-17's displays (after `forget` and frame
    5, as a timed repeat runs them): each display `display.Displays.of` builds, in the order built
    (points, limit normals, the topology's face counts and indices), then each frame's run
    display (`display.finish`'s points and normals, by frame and deformable path)."""
    from pipeline.run import forget

    h = hashlib.sha256()
    name = _BUILDS
    built = getattr(display.Displays, name)

    def hashed(self, *args):
        wanted = args[0] if name == "build" else [args]  # `build`'s (surface, samples) list, or `of`'s
        hits = [self._shown.get(id(surface)) for surface, _ in wanted]
        out = built(self, *args)
        for hit, sd in zip(hits, out if name == "build" else [out]):
            if hit is not sd:  # a display built in this call
                for a in (sd.points, sd.normals, sd.topology.counts, sd.topology.indices):
                    h.update(np.ascontiguousarray(a).tobytes())
        return out

    forget()
    frames.run_frames(stage, scene, [5])
    setattr(display.Displays, name, hashed)
    try:
        result, _ = frames.run_frames(stage, scene, list(range(13, 18)))
    finally:
        setattr(display.Displays, name, built)
    for f in sorted(result.frames):
        for path in sorted(result.frames[f]):
            r = result.frames[f][path]
            for a in (r.points, r.normals):
                h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


def _calls(stage, scene) -> None:
    """Print `display.Displays.of`'s displays built over frames 13-17 (after `forget` and frame 5,
    as a timed repeat runs them), one row each, and their CPU milliseconds a frame."""
    from acra import tessellate
    from pipeline.run import forget

    rows: list = []
    now: dict = {}
    at = {"frame": None}
    saved = (display.Displays.of, display.Displays.topology, display.grid_samples, tessellate.evaluate,
             tessellate.adaptive_mesh, frames._Run.frame)

    def clocked(key, f):
        def wrapper(*args, **kwargs):
            t = time.process_time()
            try:
                return f(*args, **kwargs)
            finally:
                now[key] = now.get(key, 0.0) + time.process_time() - t
                if key == "evaluate":
                    now["evaluated"] = now.get("evaluated", 0) + len(args[1])
                if key == "grid_samples":
                    now["vertices"] = args[1].u.size
        return wrapper

    def of(self, surface, samples):
        hit = self._shown.get(id(surface))
        now.clear()
        t = time.process_time()
        sd = saved[0](self, surface, samples)
        if hit is not sd:  # a display built in this call
            rows.append((at["frame"], time.process_time() - t, dict(now)))
        return sd

    def frame(self, f, result):
        at["frame"] = f
        return saved[5](self, f, result)

    one = getattr(display.Displays, "_build", None)  # one display of `Displays.build` (the whole call
    # holds the plans too), its topology built by `run_topology` inside it

    def build_one(self, p):
        now.clear()
        t = time.process_time()
        one(self, p)
        rows.append((at["frame"], time.process_time() - t, dict(now)))

    forget()
    frames.run_frames(stage, scene, [5])
    display.Displays.of, display.Displays.topology = of, clocked("topology", saved[1])
    topology = display.run_topology
    if one is not None:
        display.Displays.of, display.Displays._build = saved[0], build_one
        display.run_topology = clocked("topology", topology)
    display.grid_samples, tessellate.evaluate = clocked("grid_samples", saved[2]), clocked("evaluate", saved[3])
    tessellate.adaptive_mesh, frames._Run.frame = clocked("mesh", saved[4]), frame
    try:
        frames.run_frames(stage, scene, list(range(13, 18)))
    finally:
        (display.Displays.of, display.Displays.topology, display.grid_samples, tessellate.evaluate,
         tessellate.adaptive_mesh, frames._Run.frame) = saved
        if one is not None:
            display.Displays._build, display.run_topology = one, topology
    print("\n`display.Displays.of`'s displays built, one pass, CPU ms\n")
    print("| frame | vertices | evaluated | topology | evaluations | `grid_samples` | `Displays.of` |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    per_frame: dict = collections.defaultdict(float)
    for f, sec, c in rows:
        topo = f"{1e3 * c.get('topology', 0.0):.2f}" + (" built" if "mesh" in c else "")
        print(f"| {f} | {c.get('vertices', 0):,} | {c.get('evaluated', 0):,} | {topo} | "
              f"{1e3 * c.get('evaluate', 0.0):.2f} | {1e3 * c.get('grid_samples', 0.0):.2f} | {1e3 * sec:.2f} |")
        per_frame[f] += sec
    print("\n`Displays.of` a frame: " + ", ".join(f"{f}: {1e3 * s:.2f}" for f, s in sorted(per_frame.items()))
          + f"; mean {1e3 * sum(per_frame.values()) / 5:.2f} ms")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--calls", action="store_true", help="also list the displays built, one untimed pass")
    args = ap.parse_args()
    setattr(display.Displays, _BUILDS, _timed("display.Displays.of", getattr(display.Displays, _BUILDS)))
    display.evaluate_run = _timed("display.evaluate_run", display.evaluate_run)
    display.run_topology = _timed("tessellate.run_topology (in display)", display.run_topology)
    display.grid_samples = _timed("tessellate.grid_samples (in display)", display.grid_samples)
    R.respond = _timed("respond.respond", R.respond)
    stage = usdio.open_input(usdio.load_scene_file(ROOT / "scenes" / "dog_head_spike.py"))
    scene = usdio.read_scene(stage)
    frames.run_frames(stage, scene, [5])
    frames.run_frames(stage, scene, list(range(13, 18)))
    from pipeline.run import forget
    display.finish = _timed("display.finish", display.finish)
    best: dict = {}
    faults = []
    for _ in range(args.repeat):
        # each repeat as a fresh run's frames 13-17: no answers of the repeat before (`forget`), the
        # input's shapes built at an earlier frame (5), untimed, as a run builds them at its first
        forget()
        frames.run_frames(stage, scene, [5])
        SPENT.clear()
        t, f0 = time.process_time(), resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        frames.run_frames(stage, scene, list(range(13, 18)))
        SPENT["frames.run_frames (13-17)"] = time.process_time() - t
        faults.append((resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0) / 5)
        for label, sec in SPENT.items():
            best[label] = min(best.get(label, float("inf")), sec)
    print(f"dog_head_spike frames 13-17, CPU ms per collision frame, least of {args.repeat}\n")
    print("| function | ms |\n|---|---:|")
    for label, sec in sorted(best.items(), key=lambda kv: -kv[1]):
        print(f"| `{label}` | {1e3 * sec / 5:.2f} |")
    with open("/proc/self/statm") as f:
        resident = int(f.read().split()[1]) * resource.getpagesize() / 2**20
    print(f"\ndisplays' digest: {_digest(stage, scene)}")
    if args.calls:
        _calls(stage, scene)
    print(f"\nminor page faults a collision frame, median of {args.repeat}: {statistics.median(faults):.0f} "
          f"({min(faults):.0f}-{max(faults):.0f}); resident after the repeats: {resident:.0f} MB")


if __name__ == "__main__":
    main()
