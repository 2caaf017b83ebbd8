"""The same contact on a model with ×1, ×4 and ×16 the level-0 CVs: how frame time grows.

    python3 benchmarks/scale_curve.py                # the tables, plot and profiles of docs/scale-curve.md
    python3 benchmarks/scale_curve.py --no-profile   # timings only
    python3 benchmarks/scale_curve.py --markdown docs/scale-curve.md   # and write them into the page

A collision frame should cost what the contact region costs, not what the model costs. The test:
`scenes/dog_head_spike.py`'s spike and jab against its head *without* the animator's detail (the
16×12 ellipsoid grid, 7 levels, absorption on levels 2–4), and the same head with its level-0
grid exactly refined once (×4: 32×21 CVs) and twice (×16: 64×39 CVs). Uniform cubic subdivision
(`acra.basis.refine_rows`: a periodic direction doubles its CVs, an open one with ``n`` CVs gets
``2n − 3``) leaves the surface unchanged, and level ``k`` of the ×4 model is level ``k + 1`` of
the ×1 model (same CV centres, same patches), so the spatial settings shift with it: absorption
moves one level coarser per refinement, and the collision density (least steps per level-0
patch edge) halves (8/4/2). The display keeps 4 samples: they are steps per edge of the finest
patch present (`acra:samples`), and the responded region's finest patches are the same in space
at every scale, so the display the residual is measured on is the same there (away from it the
display of an unrefined level-0 patch is 2x and 4x denser at x4 and x16). The spike is refined to level 2
everywhere, so its own tessellation is 8 steps per patch edge at any of these densities. A
fourth run takes ×16 at the default density 8 (4× finer in space), as a user would run it.

The ×1 CVs are rounded to multiples of 2⁻¹² so that they and their dyadic refinements are exact
in the float32 ``acra:cvs``; the benchmark stops unless the stages' surfaces agree to 1e-12 at
4000 random parameters, and reports how far the written responses are from ×1's after one
round and after the default four.

Per run it processes the whole 30-frame scene with `pipeline.run.run_file` and reports median
ms (``FrameStats``: set-up, detection, conversion, response, each round's residual where the
user looks, the run's display and its residual, total) over
the collision frames, the median total over the free frames, and the time to compute the head's
world patch boxes (the broad phase every frame pays). Each run alternates with the same run on
the frame loop's clock read as the process's CPU time (`cpu_clock`), which gives the median CPU
ms per collision frame and per free frame beside the wall-clock medians: on a shared machine
other processes' load counts far less in it. Each clock's runs are repeated (``--repeat``, 3),
round robin over the scales: a figure is the median over the repeats of a run's median. The ×16/×1 ratios of both are stated against the goal,
at most `GOAL` (1.5×) per collision frame and per free frame. Then it profiles (cProfile) the
frame loop on the collision frames at ×1 and at ×16 and lists the functions with the most own
time at ×16 and those whose own time grew most. One invocation on a shared machine: compare the
ratios within it. ``--markdown FILE`` writes the tables between the markers
``<!-- scale_curve.py: begin -->`` and ``<!-- scale_curve.py: end -->`` of ``FILE``, or to
``FILE`` alone if it has no markers.
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import os
import pstats
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from pxr import Usd

from acra import hspline as H
from acra import shapes
from acra.basis import Direction, refine_rows
from pipeline import geometry
from pipeline import authoring as A
from pipeline import frames as F
from pipeline import usdio
from pipeline import output_layer
from pipeline.shape import shape_of
from pipeline.run import forget, run_file
from scenes import dog_head_spike as dog

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))  # doc_tables, beside this script
import doc_tables  # noqa: E402
HEAD, SPIKE = "/World/Head", "/World/Jab/Spike"
ABSORPTION = [0, 0, 0.2, 0.3, 0.5, 0, 0]  # the dog head's
STAGES = ("ms_setup", "ms_detect", "ms_convert", "ms_respond", "ms_visible", "ms_output", "ms_total")
GOAL = 1.5  # ×16 level-0 CVs against ×1: most growth per collision frame and per free frame
BEGIN, END = "<!-- scale_curve.py: begin -->", "<!-- scale_curve.py: end -->"


@contextlib.contextmanager
def cpu_clock():
    """Inside, ``time.perf_counter`` (the clock of `FrameStats`'s timings) reads the process's
    CPU time (``time.process_time``), so a run's per-frame milliseconds are CPU milliseconds."""
    wall = time.perf_counter
    time.perf_counter = time.process_time
    try:
        yield
    finally:
        time.perf_counter = wall


def refine_grid(cvs: np.ndarray, u_periodic: bool, v_periodic: bool) -> np.ndarray:
    """Level-1 CVs ``(nu', nv', 3)`` of a level-0 grid ``cvs (nu, nv, 3)``: the same surface on
    twice the patches per direction (thesis eq. 3.13–3.15, `acra.basis.refine_rows`)."""
    mats = []
    for n, periodic in ((cvs.shape[0], u_periodic), (cvs.shape[1], v_periodic)):
        d = Direction(n, periodic)
        j = np.arange(d.cvs(1))
        idx, w = refine_rows(d, 0, j)
        m = np.zeros((j.size, n))
        np.add.at(m, (np.repeat(j, 3), idx.reshape(-1)), w.reshape(-1))
        mats.append(m)
    return np.einsum("ia,jb,abk->ijk", mats[0], mats[1], cvs)


def head_grids() -> list[np.ndarray]:
    """Level-0 grids of the ×1, ×4, ×16 heads (periodic u, open v), float32-exact."""
    cvs, up, vp = shapes.sphere(16, 12, radii=(1.0, 0.85, 0.9))
    grids = [np.round(cvs * 4096.0) / 4096.0]
    for _ in range(2):
        grids.append(refine_grid(grids[-1], up, vp))
    for g in grids:
        assert np.array_equal(g.astype(np.float32).astype(np.float64), g), "a refined grid is not float32-exact"
    return grids


def build_stage(scale: int, grid: np.ndarray) -> Usd.Stage:
    """`dog_head_spike.build()` with the head replaced by the plain ``grid`` refined ``scale``
    times and the spike refined to level 2 everywhere (see the module docstring)."""
    stage = dog.build()
    stage.RemovePrim(HEAD)
    stage.RemovePrim(SPIKE)
    A.add_deformable(stage, HEAD, grid, u_wrap="periodic", v_wrap="open", levels=7 - scale,
                     absorption=ABSORPTION[scale:], rigidity=10, samples=4)
    cvs, hs = dog.spike()
    npu, npv = hs.u.patches(2), hs.v.patches(2)
    hs = H.refine(hs, 2, np.stack(np.meshgrid(np.arange(npu), np.arange(npv), indexing="ij"), -1).reshape(-1, 2))
    A.add_deformable(stage, SPIKE, cvs, u_wrap="periodic", v_wrap="open", hierarchy=hs,
                     absorption=[0, 0.5, 0.5], rigidity=80, samples=4)
    return stage


def head_points(stage: Usd.Stage, scene, scale: int, u: np.ndarray, v: np.ndarray, frame: int, output=None) -> np.ndarray:
    """World points ``(m, 3)`` of the head at ×1 parameters ``(u, v)``: the input's, or the
    response written in ``output`` (a stage) at ``frame``."""
    (head, _), _ = usdio.state_at(stage, scene, float(frame))
    hs = head.surface if output is None else output_layer.read_output_hierarchy(output, HEAD, frame)
    pts = H.evaluate(hs, u * (1 << scale), v * (1 << scale)).points
    return pts @ head.xform[:3, :3].T + head.xform[:3, 3]


def response_diff(srcs: list[Path], outputs: list[Path], scenes: list, shifts: list[int], frames: list[int], u, v) -> list[float]:
    """Largest distance (world units) over ``frames`` between each run's written head and the first's
    (runs on the stage refined ``shifts[i]`` times)."""
    pts = [[head_points(Usd.Stage.Open(str(src)), sc, shift, u, v, f, Usd.Stage.Open(str(out))) for f in frames]
           for src, out, sc, shift in zip(srcs, outputs, scenes, shifts)]
    return [max(float(np.abs(a - b).max()) for a, b in zip(p, pts[0])) for p in pts]


def boxes_ms(src: Path, density: int, repeat: int = 50) -> float:
    """Median ms to compute the head's world patch boxes (`pipeline.geometry.SurfaceGeometry.boxes`,
    the broad phase every frame pays) at frame 1, with its object-space `Shape` already built."""
    stage = usdio.open_input(src)
    (head, _), _ = usdio.state_at(stage, usdio.read_scene(stage), 1.0)
    shape_of(head.surface, density).hulls
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        geometry.SurfaceGeometry(head.surface, head.xform, density=density).boxes
        ts.append(time.perf_counter() - t)
    return 1e3 * float(np.median(ts))


# (scale, collision density): the three spatially equal runs, then ×16 at the default density 8
RUNS = ((0, 8), (1, 4), (2, 2), (2, 8))


def _medians(runs: list[list], collision: bool, key: str) -> float:
    """Median over ``runs`` (each a run's `FrameStats` list) of each run's median ``key`` over
    its collision (or free) frames."""
    return float(np.median([np.median([getattr(s, key) for s in stats if s.in_collision == collision]) for stats in runs]))


def run_scales(tmp: Path, repeat: int = 3):
    """Write the three stages, run each of `RUNS` ``repeat`` times on the wall clock and as many
    on the CPU clock, alternating (after one untimed warm-up run), and check that the surfaces
    and the responses agree; return the rows (one per run of `RUNS`)."""
    rng = np.random.default_rng(0)
    u, v = rng.uniform(0, 16, 4000), rng.uniform(0, 9, 4000)
    srcs = []
    for scale, grid in enumerate(head_grids()):
        srcs.append(tmp / f"scale{scale}.usda")
        A.save(build_stage(scale, grid), srcs[-1])
    run_file(srcs[0], output=tmp / "warmup.acra.usda")  # imports, caches: not timed
    reps, walls, cpus = {}, {r: [] for r in RUNS}, {r: [] for r in RUNS}
    for k in range(repeat):  # round robin over the runs, so that the machine's load falls on every scale alike
        for scale, density in RUNS:
            forget()  # each run from a cold start, as a fresh process's
            rep = reps[scale, density] = run_file(srcs[scale], output=tmp / f"scale{scale}_{density}_{k}.acra.usda",
                                                  density=density)
            walls[scale, density].append(rep.stats)
            forget()
            with cpu_clock():  # the same run again, every stage of it on the CPU clock
                cpus[scale, density].append(run_file(srcs[scale], output=tmp / f"scale{scale}_{density}_cpu.acra.usda",
                                                     density=density).stats)
    rows = []
    for scale, density in RUNS:
        src, rep = srcs[scale], reps[scale, density]
        hit = [s for s in rep.stats if s.in_collision]
        model = next(m for m in rep.scene.deformables if m.path == HEAD)
        rows.append(dict(
            scale=4**scale, shift=scale, density=density, level0=model.nu * model.nv, dims=(model.nu, model.nv),
            frames=[s.frame for s in hit], seconds=rep.seconds, src=src, output=rep.output, scene=rep.scene,
            free_ms=_medians(walls[scale, density], False, "ms_total"), cpu_ms=_medians(cpus[scale, density], True, "ms_total"),
            cpu_free_ms=_medians(cpus[scale, density], False, "ms_total"),
            **{k: _medians(walls[scale, density], True, k) for k in STAGES},
            residual=max(s.residual_rel for s in rep.stats), rounds=float(np.mean([s.iterations for s in hit])),
            points=head_points(Usd.Stage.Open(str(src)), rep.scene, scale, u, v, 1),
            boxes_ms=boxes_ms(src, density),
        ))
    frames = rows[0]["frames"]
    one = [run_file(r["src"], output=tmp / f"one{i}.acra.usda", frames=f"{frames[0]}:{frames[-1]}", iterations=1,
                    density=r["density"]).output for i, r in enumerate(rows)]
    shifts, scenes = [r["shift"] for r in rows], [r["scene"] for r in rows]
    full = response_diff([r["src"] for r in rows], [r["output"] for r in rows], scenes, shifts, frames, u, v)
    first = response_diff([r["src"] for r in rows], one, scenes, shifts, frames, u, v)
    for r, d4, d1 in zip(rows, full, first):
        r.update(surface_diff=float(np.abs(r["points"] - rows[0]["points"]).max()), response_diff=d4, response1_diff=d1)
        if r["surface_diff"] > 1e-12:
            raise SystemExit(f"×{r['scale']}: the refined surface is {r['surface_diff']:.1e} off ×1's")
    return rows


def table(rows) -> str:
    """Median ms per frame of every run (wall clock by stage, then CPU), and the ×16/×1 ratios."""
    head = ["×", "head level-0 CVs", "density", "set-up", "detection", "conversion", "response", "rounds' residual", "display",
            "**collision frame**", "collision frame CPU", "rounds", "free frame", "free frame CPU", "head patch boxes",
            "surface vs ×1", "response vs ×1 (1 round / 4)", "residual"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---:|" * len(head)]
    for r in rows:
        lines.append(
            f"| {r['scale']} | {r['level0']} ({r['dims'][0]}×{r['dims'][1]}) | {r['density']} | "
            + " | ".join(f"{r[k]:.1f}" for k in STAGES[:-1])
            + f" | **{r['ms_total']:.1f}** | {r['cpu_ms']:.1f} | {r['rounds']:.1f} | {r['free_ms']:.2f} | {r['cpu_free_ms']:.2f} | "
            f"{r['boxes_ms']:.2f} | {r['surface_diff']:.1e} | {r['response1_diff']:.1e} / {r['response_diff']:.1e} | "
            f"{r['residual']:.2e} |")
    base = rows[0]
    for big in rows[2:]:
        lines.append(f"| ratio ×16 (density {big['density']}) / ×1 | | | " + " | ".join(_ratio(big[k], base[k]) for k in STAGES[:-1])
                     + f" | **{big['ms_total'] / base['ms_total']:.2f}** | {big['cpu_ms'] / base['cpu_ms']:.2f} | | "
                     f"{big['free_ms'] / base['free_ms']:.2f} | {big['cpu_free_ms'] / base['cpu_free_ms']:.2f} | "
                     f"{big['boxes_ms'] / base['boxes_ms']:.2f} | | | |")
    return "\n".join(lines)


def _ratio(a: float, b: float) -> str:
    """``a / b`` to two decimals, or a dash where ``b`` is 0 (a stage that took no time at ×1)."""
    return f"{a / b:.2f}" if b > 0 else "–"


def goal_table(rows) -> str:
    """The ×16/×1 ratios per collision frame and per free frame, wall and CPU, against `GOAL`."""
    base, bigs = rows[0], rows[2:]
    lines = ["| median ms per | ×1 | " + " | ".join(f"×16, density {b['density']} | ratio" for b in bigs)
             + f" | ≤ {GOAL}× |", "|---|---:|" + "---:|---:|" * len(bigs) + ":-:|"]
    for key, name in (("ms_total", "collision frame, wall"), ("cpu_ms", "collision frame, CPU"),
                      ("free_ms", "free frame, wall"), ("cpu_free_ms", "free frame, CPU")):
        ratios = [b[key] / base[key] for b in bigs]
        lines.append(f"| {name} | {base[key]:.2f} | " + " | ".join(f"{b[key]:.2f} | {q:.2f}" for b, q in zip(bigs, ratios))
                     + f" | {'yes' if max(ratios) <= GOAL else 'no'} |")
    return "\n".join(lines)


def replace_block(text: str, block: str) -> str:
    """``text`` with this benchmark's generated block (between `BEGIN` and `END`) replaced by
    ``block`` (`doc_tables.replace_block`)."""
    return doc_tables.replace_block(text, block, BEGIN, END)


def plot(rows, path: Path) -> None:
    """Median ms per collision frame (total and per stage) and per free frame (wall, and the
    totals' CPU ms) against the head's level-0 CV count, log–log, for the spatially equal runs (the first three rows), beside a line
    proportional to the CV count; further rows are starred points."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows, extra = rows[:3], rows[3:]
    x = [r["level0"] for r in rows]
    fig, ax = plt.subplots(figsize=(9.5, 5))
    names = {"ms_total": "collision frame (total)", "ms_setup": "set-up", "ms_detect": "detection",
             "ms_respond": "response", "ms_output": "display tessellation", "ms_convert": "conversion"}
    for k, name in names.items():
        ax.plot(x, [r[k] for r in rows], "-o", lw=2.5 if k == "ms_total" else 1.2, label=name)
    ax.plot(x, [r["free_ms"] for r in rows], "--s", color="grey", label="free frame (total)")
    ax.plot(x, [r["cpu_ms"] for r in rows], "-.o", color="C0", lw=1.2, label="collision frame (total), CPU")
    ax.plot(x, [r["cpu_free_ms"] for r in rows], "-.s", color="dimgrey", lw=1.2, label="free frame (total), CPU")
    ax.plot(x, [r["boxes_ms"] for r in rows], ":^", color="grey", label="head patch boxes (in every frame)")
    for r in extra:
        ax.plot([r["level0"]], [r["ms_total"]], "*", ms=12, color="C0", label=f"collision frame at density {r['density']} (×16)")
    ax.plot(x, [rows[0]["ms_total"] * xi / x[0] for xi in x], ":", color="k", lw=0.8, label="∝ level-0 CVs")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xticks(x, [f"×{r['scale']}: {r['level0']} CVs" for r in rows])
    ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
    ax.set_xlabel("head level-0 CVs (same surface, same contact)")
    ax.set_ylabel("median ms per frame (wall clock but the CPU lines, shared machine)")
    ax.set_title("dog-head spike jab on the plain head, level-0 grid exactly refined ×1 / ×4 / ×16", fontsize=10)
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def profile(src: Path, frames: list[int], density: int) -> pstats.Stats:
    """cProfile of the frame loop alone (`pipeline.frames.run_frames`, no reading or writing)."""
    stage = usdio.open_input(src)
    scene = usdio.read_scene(stage)
    prof = cProfile.Profile()
    prof.enable()
    F.run_frames(stage, scene, frames, F.RunOptions(density=density))
    prof.disable()
    return pstats.Stats(prof)


def profile_table(small: pstats.Stats, large: pstats.Stats, top: int = 10, grown: int = 5) -> str:
    """The ``top`` functions by own time (tottime) at ×16 and the ``grown`` whose own time grew
    most from ×1, with calls, own and cumulative seconds at both scales."""
    def name(fn):
        file, _, func = fn
        return f"{Path(file).parent.name}/{Path(file).name}:{func}" if file != "~" else func
    a = {name(fn): v for fn, v in small.stats.items()}
    b = {name(fn): v for fn, v in large.stats.items()}
    zero = (0, 0, 0.0, 0.0, None)
    keys = sorted(b, key=lambda k: -b[k][2])[:top]
    keys += [k for k in sorted(b, key=lambda k: a.get(k, zero)[2] - b[k][2]) if k not in keys][:grown]
    lines = ["| function | calls ×1 | calls ×16 | own s ×1 | own s ×16 | cumulative s ×1 | cumulative s ×16 |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for k in keys:
        x, y = a.get(k, zero), b[k]
        lines.append(f"| `{k}` | {x[1]} | {y[1]} | {x[2]:.3f} | {y[2]:.3f} | {x[3]:.3f} | {y[3]:.3f} |")
    lines.append(f"| **all** | | | **{small.total_tt:.3f}** | **{large.total_tt:.3f}** | | |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--plot", type=Path, default=ROOT / "docs" / "img" / "scale_curve.png")
    ap.add_argument("--no-profile", action="store_true")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per clock and scale (default 3)")
    ap.add_argument("--markdown", type=Path, help="write the tables between this file's markers (see the docstring)")
    args = ap.parse_args()
    t0, load, label = time.perf_counter(), os.getloadavg(), doc_tables.commit_of(ROOT)
    parts = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        rows = run_scales(tmp, args.repeat)
        parts += [table(rows), f"Against the goal (×16 at most {GOAL}× ×1):", goal_table(rows),
                  f"Collision frames: {', '.join(str(r['frames']) for r in rows)}; whole-run s: "
                  + ", ".join(f"{r['seconds']:.1f}" for r in rows) + "."]
        plot(rows, args.plot)
        if not args.no_profile:
            hit = rows[0]["frames"]
            frames = list(range(hit[0], hit[-1] + 1))
            stats = [profile(r["src"], frames, r["density"]) for r in rows]
            for i in (2, 3):
                parts += [f"**cProfile of the frame loop on the collision frames {frames[0]}–{frames[-1]}: ×1 (density 8) "
                          f"and ×16 (density {rows[i]['density']})**; top own time at ×16, then most grown:",
                          profile_table(stats[0], stats[i])]
    wall = time.perf_counter() - t0
    command = "python3 benchmarks/scale_curve.py" + (" --no-profile" if args.no_profile else "") + (
        f" --repeat {args.repeat}" if args.repeat != 3 else "")
    parts.insert(0, f"Generated by `{command}` at `{label}`, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}: "
                    f"{wall:.0f} s wall, load average {load[0]:.1f} at the start. Times are median ms per frame.")
    block = "\n\n".join(parts)
    print(block)
    if args.markdown:
        old = args.markdown.read_text(encoding="utf-8") if args.markdown.exists() else ""
        args.markdown.write_text(replace_block(old, block), encoding="utf-8")
    print(f"\nplot: {args.plot}; benchmark wall time {wall:.0f} s")


if __name__ == "__main__":
    main()
