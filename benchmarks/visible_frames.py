"""The residual where the user looks, frame by frame: what each collision frame spends in it.

    PYTHONPATH=$PWD python3 benchmarks/visible_frames.py [SCENE.py] [--frames 13:17] [--repeat 5] [--passes 9] [--midpoints]

Runs the scene's ``--frames`` (after a free frame, as `residual_calls.py` does) ``--repeat``
times in one process, on one thread, and prints per frame the CPU milliseconds of
`pipeline.frames._Run.visible` (every call of the frame summed; each run's sum, their least and
median). Then it runs the frames once more keeping a copy of the arguments of every call the
stage makes of the compiled kernels in ``KERNELS``, replays each frame's calls of each kernel
``--passes`` times and prints the fastest pass's CPU milliseconds and the calls' count: the
stage's cost a frame split by kernel, and what is left for the rest (the other compiled steps,
numpy and Python between them: the stage's least less the kernels' sum; a replayed call finds
its data in the processor's caches, so the rest is an upper bound). Frames that cost more than
others show which kernel carries the difference. Each `acra.depthbound._depth` call is also
listed (its triangles, the part's faces, the points evaluated, the last level and its CPU).

With ``--midpoints`` it instead runs the frames once through the branch and bound's array form
(`clearance._triangle_depth` with ``compiled=False``, the same bits) and counts, per refined
level of each call, the distinct midpoints, those whose signed distance lies below minus the
largest covering radius of a child cell they are a corner of (and below twice that), and those
inside: such a point is never its cell's largest corner with a bound above 0, so only eq. (6),
a deepest point or the part's reach could read its exact value.
"""

from __future__ import annotations

import os

# one thread (before numba is imported): a pair's two sides then run one after the other
# (`pipeline.workers`), so each kernel's calls come in one order
os.environ["NUMBA_NUM_THREADS"] = "1"

import argparse
import collections
import importlib
import pathlib
import statistics
import time

import numpy as np
from threadpoolctl import threadpool_limits

from pipeline import frames as F
from pipeline import usdio

ROOT = pathlib.Path(__file__).resolve().parents[1]

# compiled kernels the stage calls through their module's attribute, as ``MODULE.NAME`` in `acra`
KERNELS = ("depthbound._depth", "kernels.eval_points", "pseudonormals.welded_part", "bvh._part_tree",
           "clearcells._clear_cells", "meshrows._faces_at", "meshrows._face_chunks", "meshrows._faces_meet_chunks",
           "tessellate._carry", "kernels.place_normals")


def _visible_ms(stage, scene, frames: list[int], repeat: int) -> dict[int, list[float]]:
    """``{frame: [CPU ms of the frame's `_Run.visible` calls, one a run]}``."""
    real, now, spent = F._Run.visible, [0], collections.defaultdict(float)

    def timed(self, *args, **kwargs):
        t = time.process_time()
        try:
            return real(self, *args, **kwargs)
        finally:
            spent[now[0]] += time.process_time() - t

    F._Run.visible = timed
    out: dict[int, list[float]] = collections.defaultdict(list)
    try:
        for _ in range(repeat):
            spent.clear()
            now[0] = -1
            F.run_frames(stage, scene, [5])
            for f in frames:
                now[0] = f
                F.run_frames(stage, scene, [f])
                out[f].append(1e3 * spent[f])
    finally:
        F._Run.visible = real
    return out


def _kernel_calls(stage, scene, frames: list[int]) -> tuple[dict, dict]:
    """``({(kernel, frame): [arguments, ...]}, {kernel: the compiled function})`` of the stage's
    calls in one run of ``frames``."""
    calls: dict = collections.defaultdict(list)
    real_visible, now, inside = F._Run.visible, [0], [False]
    reals, modules = {}, {}

    def keeper(kernel: str, real):
        def keep(*arrays):
            if inside[0]:
                calls[kernel, now[0]].append([x.copy() if isinstance(x, np.ndarray) and x.flags.writeable else x
                                              for x in arrays])
            return real(*arrays)
        return keep

    def visible(self, *args, **kwargs):
        inside[0] = True
        try:
            return real_visible(self, *args, **kwargs)
        finally:
            inside[0] = False

    for kernel in KERNELS:
        module_name, name = kernel.rsplit(".", 1)
        modules[kernel] = importlib.import_module(f"acra.{module_name}")
        reals[kernel] = getattr(modules[kernel], name)
        setattr(modules[kernel], name, keeper(kernel, reals[kernel]))
    F._Run.visible = visible
    try:
        F.run_frames(stage, scene, [5])
        for f in frames:
            now[0] = f
            F.run_frames(stage, scene, [f])
    finally:
        F._Run.visible = real_visible
        for kernel in KERNELS:
            setattr(modules[kernel], kernel.rsplit(".", 1)[1], reals[kernel])
    return calls, reals


def _midpoints(stage, scene, frames: list[int]) -> None:
    """Print, per `clearance._triangle_depth` call and refined level, ``(midpoints, below -rho,
    below -2 rho, inside)`` (`--midpoints`)."""
    from acra import depthbound
    from pipeline import clearance

    real_depth, real_children = clearance._triangle_depth, depthbound.children

    def array_form(s, corners, target, max_split, budget, reach, decide, compiled, stop):
        print(f"  call: {len(corners)} triangles")
        return real_depth(s, corners, target, max_split, budget, reach, decide, False, stop)

    def children(lattice, mid, sd, sd_mid, fc, face_mid, inverse, rows, rho):
        child = np.full(len(sd_mid), -np.inf)  # the largest covering radius of a child cell at each midpoint
        np.maximum.at(child, inverse, np.repeat(rho, 3) / 2)
        print(f"    level: {len(sd_mid)} midpoints, {int((sd_mid < -child).sum())} below -rho, "
              f"{int((sd_mid < -2 * child).sum())} below -2 rho, {int((sd_mid > 0).sum())} inside")
        return real_children(lattice, mid, sd, sd_mid, fc, face_mid, inverse, rows, rho)

    clearance._triangle_depth, depthbound.children = array_form, children
    try:
        F.run_frames(stage, scene, [5])
        for f in frames:
            print(f"frame {f}")
            F.run_frames(stage, scene, [f])
    finally:
        clearance._triangle_depth, depthbound.children = real_depth, real_children


def _fastest(f, calls: list, passes: int) -> float:
    """CPU ms of the fastest of ``passes`` replays of ``calls`` through ``f``."""
    best = np.inf
    for _ in range(passes):
        t = time.process_time()
        for arrays in calls:
            f(*arrays)
        best = min(best, time.process_time() - t)
    return 1e3 * best if calls else 0.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", type=pathlib.Path, default=ROOT / "scenes" / "dog_head_spike.py")
    ap.add_argument("--frames", default="13:17", help="frames START:END (default 13:17)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--passes", type=int, default=9)
    ap.add_argument("--midpoints", action="store_true", help="count the refined levels' midpoints instead")
    args = ap.parse_args()
    a, b = (int(x) for x in args.frames.split(":"))
    frames = list(range(a, b + 1))
    stage = usdio.open_input(usdio.load_scene_file(args.scene))
    scene = usdio.read_scene(stage)
    if args.midpoints:
        with threadpool_limits(limits=1, user_api="blas"):
            _midpoints(stage, scene, frames)
        return
    with threadpool_limits(limits=1, user_api="blas"):  # as the frame loop runs
        visible = _visible_ms(stage, scene, frames, args.repeat)
        calls, reals = _kernel_calls(stage, scene, frames)
        split = {(k, f): _fastest(reals[k], calls.get((k, f), []), args.passes) for k in KERNELS for f in frames}
        depth_calls = [(f, arrays, _fastest(reals["depthbound._depth"], [arrays], args.passes))
                       for f in frames for arrays in calls.get(("depthbound._depth", f), [])]
    print(f"{args.scene.name}: `_Run.visible` CPU ms a frame, {args.repeat} runs, one thread")
    print("| frame | runs | least | median |")
    print("|---:|---|---:|---:|")
    for f in frames:
        print(f"| {f} | {' '.join(f'{x:.2f}' for x in visible[f])} | {min(visible[f]):.2f} | "
              f"{statistics.median(visible[f]):.2f} |")
    print(f"\nits compiled kernels' calls replayed, calls: fastest of {args.passes} passes, CPU ms")
    print("| kernel | " + " | ".join(f"frame {f}" for f in frames) + " |")
    print("|---|" + "---:|" * len(frames))
    for k in KERNELS:
        print(f"| `{k}` | " + " | ".join(f"{len(calls.get((k, f), []))}: {split[k, f]:.2f}" for f in frames) + " |")
    total = {f: sum(split[k, f] for k in KERNELS) for f in frames}
    print("| the kernels' sum | " + " | ".join(f"{total[f]:.2f}" for f in frames) + " |")
    print("| the rest (least less the sum) | " + " | ".join(f"{min(visible[f]) - total[f]:.2f}" for f in frames) + " |")
    print("\n`acra.depthbound._depth`'s calls: frame, triangles, part faces, points evaluated, last level, CPU ms")
    for f, arrays, ms in depth_calls:
        out = reals["depthbound._depth"](*arrays)
        print(f"  {f}  {arrays[0].shape[0]:6d}  {arrays[20].shape[0]:6d}  {int(out[4]):6d}  {int(out[5])}  {ms:.3f}")


if __name__ == "__main__":
    main()
