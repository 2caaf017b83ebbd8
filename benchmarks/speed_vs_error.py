"""Time per collision frame against residual penetration, per iteration cap, solver and density.

    python3 benchmarks/speed_vs_error.py                  # the tables and plot of docs/speed-vs-error.md
    python3 benchmarks/speed_vs_error.py --quick          # smoke run: caps 1, 2; density 8
    python3 benchmarks/speed_vs_error.py --scene scenes/box_into_sheet.py --plot /tmp/p.png

The scene runs once at the defaults (cap 4, ``direct``, density 8) to find its collision frames;
then every configuration -- cap ``N`` on detect -> respond rounds per frame, solver (``direct``
minimum-norm or ``blend`` iterated Bartels-Beatty, thesis §4.3.1) and collision density ``D``
(least tessellation steps per level-0 patch edge, `pipeline.detect.patch_density`) -- runs
`pipeline.run.run_file` on the range of those frames. Two sweeps: caps 1-8 x both solvers x
densities 4, 8, 16 at the contract tolerance 1e-3 (the loop stops at the first round that meets
it, so a cap only matters where rounds do not), and caps 1, 2, 4, 8 x both solvers at density 8
with tolerance 1e-9, so that every run uses its whole cap (what more rounds buy). Each
configuration is reported over the collision frames:

* median ``FrameStats.ms_total`` (wall clock, set-up and display tessellation included), and the
  process CPU time of the whole ``run_file`` call over its frames (steadier on a shared machine;
  the plot's x axis);
* the loop's residual, ``FrameStats.residual_rel`` as the run reports it: the run's display's
  certified bound where the user looks (docs/cli.md, *Residual penetration*), refined against the
  run's tolerance;
* the reference residual: the written response (``acra:response:*`` read back with
  `pipeline.output_layer.read_output_hierarchy`) measured by `pipeline.detect.residual` at density
  ``--reference`` (32) for every configuration, over the pair's size (the smaller deformable's),
  so coarse densities cannot look good by measuring coarsely.

Residuals are the largest over a frame's pairs, then the max and the mean over collision frames.
The input's own penetration (no response) is measured the same way for scale. All numbers
come from one invocation on a shared machine: compare ratios within it, not across runs.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from pxr import Usd

from pipeline import detect as D
from pipeline import usdio
from pipeline import output_layer
from pipeline.run import run_file

ROOT = Path(__file__).resolve().parents[1]
_RESPONSE = ("cvs", "patchLevel", "patches", "offsetLevel", "offsetCvs", "offsets")


@dataclass
class Row:
    """One configuration's results over the collision frames."""

    method: str
    density: int
    cap: int
    ms: float  # median ms per collision frame
    rounds: float  # mean responses per collision frame
    loop_max: float
    loop_mean: float
    ref_max: float
    ref_mean: float
    cpu_ms: float  # process CPU ms of the whole run_file call over the frames it ran
    same_as: int | None = None  # cap of the run this row repeats (see `sweep`)


def pair_residual(stage: Usd.Stage, scene, statics, frame: int, density: int, surfaces=None) -> float:
    """Largest penetration over the frame's pairs, over the pair's size, measured at ``density``.

    ``surfaces`` (one `HSpline` per deformable, scene order) replaces the input's (the default)."""
    dstates, cstates = usdio.state_at(stage, scene, float(frame))
    geoms = [D.SurfaceGeometry(surfaces[i] if surfaces else s.surface, s.xform, m.path, density=density)
             for i, (m, s) in enumerate(zip(scene.deformables, dstates))]
    worst = 0.0
    for i, ga in enumerate(geoms):
        others = [(g, min(ga.size, g.size)) for g in geoms[i + 1:]]
        others += [(D.ColliderGeometry(st, c.xform), ga.size) for st, c in zip(statics, cstates)]
        for gb, size in others:
            worst = max(worst, D.residual(ga, gb).max / size)
    return worst


def reference(output: Path, scene, statics, frames: list[int], density: int, memo: dict) -> np.ndarray:
    """Reference residual ``(len(frames),) float64`` of a written response, measured at ``density``.

    A frame whose written response arrays are byte-identical to one measured before (``memo``,
    keyed by frame and a hash of the arrays) is not measured again."""
    out = Usd.Stage.Open(str(output))
    res = []
    for f in frames:
        h = hashlib.sha1()
        for m in scene.deformables:
            prim = out.GetPrimAtPath(m.path)
            for name in _RESPONSE:
                h.update(np.asarray(prim.GetAttribute(f"acra:response:{name}").Get(Usd.TimeCode(f))).tobytes())
        key = (f, h.hexdigest())
        if key not in memo:
            surfaces = [output_layer.read_output_hierarchy(out, m.path, f) for m in scene.deformables]
            memo[key] = pair_residual(out, scene, statics, f, density, surfaces)
        res.append(memo[key])
    return np.array(res)


def measure(src: Path, tmp: Path, frames: list[int], method: str, density: int, cap: int, tolerance: float,
            ref_density: int, scene, statics, memo: dict) -> tuple[Row, bool]:
    """Run one configuration on the range of ``frames`` (free frames in it are not reported);
    also return whether every frame stopped before the cap (a larger cap then runs the same)."""
    out = tmp / f"{method}_{density}_{cap}.acra.usda"
    c0 = time.process_time()
    rep = run_file(src, output=out, frames=f"{frames[0]}:{frames[-1]}", iterations=cap, tolerance=tolerance,
                   method=method, density=density)
    cpu = time.process_time() - c0
    hit = [s for s in rep.stats if s.frame in frames]
    loop = np.array([s.residual_rel for s in hit])
    ref = reference(out, scene, statics, frames, ref_density, memo)
    row = Row(method, density, cap, float(np.median([s.ms_total for s in hit])),
              float(np.mean([s.iterations for s in hit])), loop.max(), loop.mean(), ref.max(), ref.mean(),
              1e3 * cpu / len(rep.stats))
    return row, all(s.iterations < cap for s in rep.stats)


def sweep(src, tmp, frames, method, density, caps, tolerance, ref_density, scene, statics, memo) -> list[Row]:
    """Rows for ``caps`` (ascending). Once every frame of a run stopped before its cap (the loop
    met its stopping rule: the larger of the residual where the user looks and detection's within
    the tolerance, or nothing found), a larger cap runs the same rounds: larger caps repeat that
    run's row, marked ``same_as``, instead of running again."""
    rows: list[Row] = []
    done = None
    for cap in caps:
        if done is not None:
            rows.append(replace(done, cap=cap, same_as=done.cap))
            continue
        row, converged = measure(src, tmp, frames, method, density, cap, tolerance, ref_density, scene, statics, memo)
        rows.append(row)
        print(f"  {method} d{density} cap {cap}: {row.ms:.0f} ms, reference {row.ref_max:.2e}, loop {row.loop_max:.2e}, "
              f"rounds {row.rounds:.1f}", flush=True)
        done = row if converged else None
    return rows


def table(rows: list[Row]) -> str:
    """The rows as a markdown table."""
    lines = ["| solver | density | cap | median ms / collision frame | rounds (mean) | loop residual max | loop mean "
             "| ≤ 1e-3 | reference max | reference mean | CPU ms / frame |", "|---|---:|---:|---:|---:|---:|---:|:-:|---:|---:|---:|"]
    for r in rows:
        if r.same_as is not None:
            lines.append(f"| {r.method} | {r.density} | {r.cap} | = cap {r.same_as} (every frame stopped before its cap) | | | | | | | |")
            continue
        lines.append(f"| {r.method} | {r.density} | {r.cap} | {r.ms:.0f} | {r.rounds:.1f} | {r.loop_max:.3e} | "
                     f"{r.loop_mean:.2e} | {'yes' if r.loop_max <= 1e-3 else 'no'} | {r.ref_max:.3e} | {r.ref_mean:.2e} | {r.cpu_ms:.0f} |")
    return "\n".join(lines)


def plot(panels: list[tuple[str, list[Row]]], path: Path, title: str) -> None:
    """Reference residual (top: max, bottom: mean over the collision frames) against CPU ms per
    collision frame (`Row.cpu_ms`), one column per ``(title, rows)``, one curve per solver ×
    density, points labelled by iteration cap (caps repeating a run share its point)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(panels), figsize=(6.5 * len(panels), 9), sharey="row", squeeze=False)
    colors = plt.get_cmap("tab10")
    curves = sorted({(r.method, r.density) for _, rows in panels for r in rows})
    for col, (name, rows) in enumerate(panels):
        for ax, key, what in ((axes[0][col], "ref_max", "max"), (axes[1][col], "ref_mean", "mean")):
            for k, (method, density) in enumerate(curves):
                pts = sorted((r for r in rows if (r.method, r.density) == (method, density) and r.same_as is None),
                             key=lambda r: r.cap)
                if not pts:
                    continue
                x, y = [r.cpu_ms for r in pts], [getattr(r, key) for r in pts]
                ax.plot(x, y, "-o" if method == "direct" else "--s", color=colors(k), ms=4, label=f"{method}, density {density}")
                for r, xi, yi in zip(pts, x, y):
                    caps = [q.cap for q in rows if (q.method, q.density) == (method, density) and r.cap in (q.cap, q.same_as)]
                    label = str(r.cap) if len(caps) == 1 else f"{caps[0]}–{caps[-1]}"
                    ax.annotate(label, (xi, yi), textcoords="offset points", xytext=(3, 3), fontsize=7, color=colors(k))
            if key == "ref_max":
                ax.axhline(1e-3, color="k", lw=0.8, ls=":", label="contract tolerance 1e-3")
                ax.set_title(name, fontsize=10)
            ax.set_ylabel(f"reference residual / size, {what} over collision frames")
            ax.set_xlabel("CPU ms per collision frame (whole run_file call / its frames)")
            ax.grid(True, lw=0.3)
        axes[0][col].legend(fontsize=8)
    fig.suptitle(title + "; point labels: iteration cap", fontsize=11)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", type=Path, default=ROOT / "scenes" / "dog_head_spike.py")
    ap.add_argument("--quick", action="store_true", help="caps 1, 2 at density 8 only")
    ap.add_argument("--caps", default="1,2,3,4,5,6,7,8", help="caps at the contract tolerance")
    ap.add_argument("--densities", default="4,8,16")
    ap.add_argument("--methods", default="direct,blend")
    ap.add_argument("--forced", default="1,2,4,8", help="caps run at tolerance 1e-9 (density 8)")
    ap.add_argument("--reference", type=int, default=32, help="density of the reference measure (default 32)")
    ap.add_argument("--plot", type=Path, default=ROOT / "docs" / "img" / "speed_vs_error.png")
    ap.add_argument("--json", type=Path, help="also save the rows as JSON")
    args = ap.parse_args()
    ints = lambda text: sorted(int(x) for x in text.split(","))  # noqa: E731
    caps, densities, forced = ([1, 2], [8], [1, 2]) if args.quick else (ints(args.caps), ints(args.densities), ints(args.forced))
    methods = args.methods.split(",")

    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        copy = Path(shutil.copy(args.scene, tmp / args.scene.name))
        src = usdio.load_scene_file(copy) if copy.suffix == ".py" else copy
        base = run_file(src, output=tmp / "defaults.acra.usda")
        frames = [s.frame for s in base.stats if s.in_collision]
        if not frames:
            raise SystemExit(f"{args.scene.name}: no collision frame")
        scene = base.scene
        statics = [D.prepare_collider(c) for c in scene.colliders]
        input_pen = max(pair_residual(Usd.Stage.Open(str(src)), scene, statics, f, args.reference) for f in frames)
        print(f"{args.scene.name}: collision frames {frames}; input penetration {input_pen:.3e} of size "
              f"(density {args.reference}); full run at the defaults {base.seconds:.1f} s")
        memo: dict = {}
        common = (args.reference, scene, statics, memo)
        grid = [r for m in methods for d in densities for r in sweep(src, tmp, frames, m, d, caps, 1e-3, *common)]
        rounds = [r for m in methods for r in sweep(src, tmp, frames, m, 8, forced, 1e-9, *common)]
    print("\nTolerance 1e-3 (the contract):\n")
    print(table(grid))
    print("\nTolerance 1e-9 (every run uses its whole cap), density 8:\n")
    print(table(rounds))
    plot([("tolerance 1e-3 (contract): the loop stops when met", grid),
          ("tolerance 1e-9: every round runs, density 8", rounds)], args.plot,
         f"{args.scene.name}, frames {frames[0]}–{frames[-1]} (input penetration {input_pen:.2e} of size)")
    if args.json:
        args.json.write_text(json.dumps({"frames": frames, "input": input_pen, "grid": [asdict(r) for r in grid],
                                         "rounds": [asdict(r) for r in rounds]}, indent=1))
    print(f"\nplot: {args.plot}; benchmark wall time {time.perf_counter() - t_start:.0f} s")


if __name__ == "__main__":
    main()
