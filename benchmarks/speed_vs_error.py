"""Time per collision frame against residual penetration, per iteration cap, solver, density and tolerance.

    python3 benchmarks/speed_vs_error.py                  # the tables and plot of docs/speed-vs-error.md
    python3 benchmarks/speed_vs_error.py --quick          # smoke run: caps 1, 2; density 8
    python3 benchmarks/speed_vs_error.py --base /tmp/base --base-label 40d8a1c --markdown docs/speed-vs-error.md
    python3 benchmarks/speed_vs_error.py --scene scenes/box_into_sheet.py --plot /tmp/p.png

The scene runs once at the defaults (cap 4, ``direct``, density 8, tolerance 1e-3) to find its
collision frames; then every configuration -- cap ``N`` on detect -> respond rounds per frame,
solver (``direct`` minimum-norm or ``blend`` iterated Bartels-Beatty, thesis §4.3.1), collision
density ``D`` (least tessellation steps per level-0 patch edge, `pipeline.geometry.patch_density`)
and tolerance -- runs `pipeline.run.run_file` on the range of those frames. Three sweeps: caps 1-8
x both solvers x densities 4, 8, 16 at the contract tolerance 1e-3 (the loop stops at the first
round that meets it, so a cap only matters where rounds do not); caps 1, 2, 4, 8 x both solvers
at density 8 with tolerance 1e-9, so that every run uses its whole cap (what more rounds buy);
and the defaults at tolerances 1e-3, 5e-4, 2.5e-4 (what a tighter tolerance costs).

Every run happens in a worker process (this file with ``--worker``) that answers one run per
request, so that ``--base DIR`` can run the same configurations in another checkout (a ``git
archive`` copy: the worker runs with cwd and ``PYTHONPATH`` set to ``DIR`` and imports that
checkout's ``pipeline``), alternating base and this checkout run by run (ABBA order, so neither
gets the machine's quieter moments), with the same input stage. Both workers get one untimed run
at the defaults first (imports, numba caches). Each configuration is reported over the
collision frames:

* median ``FrameStats.ms_total`` (wall clock) and the process CPU time of the worker's whole
  ``run_file`` call over its frames (steadier on a shared machine; the plot's x axis);
* rounds per frame (``FrameStats.iterations``);
* the reported residual, ``FrameStats.residual_rel`` as the run reports it: the run's display's
  certified bound where the user looks (docs/cli.md, *Residual penetration*), and at how many
  collision frames it is within the run's tolerance;
* the independent residual: the written output layer as a USD client composes it (the displays'
  ``points``), measured by `acceptance.visible.measure_layer` (USD, trimesh and fcl; no
  ``pipeline`` or ``acra`` code), and the frames where the reported figure is under it by more
  than `acceptance.visible.SLACK` (the tool must never under-report);
* the reference residual: the written response (``acra:response:*`` read back with
  `pipeline.output_layer.read_output_hierarchy`) measured on the limit surfaces by
  `pipeline.detect.residual` at density ``--reference`` (32), over the pair's size (the smaller
  deformable's), so coarse densities cannot look good by measuring coarsely.

All three residual measures are taken in this process with this checkout's code, for the base's
outputs too: one ruler for both. Residuals are the largest over a frame's pairs (deformables),
then the max and the mean over collision frames. The input's own penetration is measured by the
reference for scale. All numbers come from one invocation on a shared machine: compare ratios
within it, not across runs. ``--markdown FILE`` writes the tables between the markers
``<!-- speed_vs_error.py: begin -->`` and ``<!-- speed_vs_error.py: end -->`` of ``FILE`` (the
page's generated part), or to ``FILE`` alone if it has no markers.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))  # doc_tables, beside this script
import doc_tables  # noqa: E402
_RESPONSE = ("cvs", "patchLevel", "patches", "offsetLevel", "offsetCvs", "offsets")
BEGIN, END = "<!-- speed_vs_error.py: begin -->", "<!-- speed_vs_error.py: end -->"
DEFAULTS = dict(method="direct", density=8, cap=4)


@dataclass
class Row:
    """One configuration's results over the collision frames of one checkout's run."""

    method: str
    density: int
    cap: int
    tolerance: float
    ms: float  # median wall ms per collision frame
    rounds: float  # mean responses per collision frame
    loop_max: float  # reported residual (`FrameStats.residual_rel`), max over collision frames
    loop_mean: float
    ref_max: float  # reference residual (limit surfaces, density --reference)
    ref_mean: float
    cpu_ms: float  # process CPU ms of the whole run_file call over the frames it ran
    ind_max: float = 0.0  # independent residual (the composed output layer, acceptance.visible)
    ind_mean: float = 0.0
    rounds_by_frame: list = field(default_factory=list)
    within: int = 0  # collision frames whose reported residual is within the tolerance
    ind_within: int = 0  # ... whose independent residual is
    under: list = field(default_factory=list)  # frames whose reported residual is under the independent one
    frames: int = 0
    same_as: int | None = None  # cap of the run this row repeats (see `sweep`)

    def key(self) -> tuple:
        return (self.method, self.density, self.cap, self.tolerance)


# --- the worker: one run_file call per request, in the checkout it was started in --------------
def worker() -> None:
    """Answer JSON requests on stdin (``src``, ``output``, ``frames``, ``iterations``,
    ``tolerance``, ``method``, ``density``) with one JSON line each on stdout: the run's CPU
    seconds and per-frame statistics. Imports ``pipeline`` from ``sys.path`` (the caller sets
    ``PYTHONPATH`` to the checkout measured); anything the run prints goes to stderr."""
    out = sys.stdout
    with contextlib.redirect_stdout(sys.stderr):
        from pipeline import run
    forget = getattr(run, "forget", lambda: None)  # a checkout older than `forget` keeps its stores
    for line in sys.stdin:
        req = json.loads(line)
        with contextlib.redirect_stdout(sys.stderr):
            forget()  # each request from a cold start, not served the request before's answers
            c0 = time.process_time()
            rep = run.run_file(Path(req["src"]), output=Path(req["output"]), frames=req["frames"],
                           iterations=req["iterations"], tolerance=req["tolerance"], method=req["method"],
                           density=req["density"])
            cpu = time.process_time() - c0
        stats = [dict(frame=s.frame, in_collision=bool(s.in_collision), iterations=int(s.iterations),
                      residual_rel=float(s.residual_rel), ms_total=float(s.ms_total)) for s in rep.stats]
        out.write(json.dumps(dict(cpu=cpu, seconds=rep.seconds, stats=stats)) + "\n")
        out.flush()


class Worker:
    """A worker process running `worker` in checkout ``root`` (cwd and ``PYTHONPATH``)."""

    def __init__(self, root: Path, label: str):
        self.root, self.label = Path(root).resolve(), label
        env = dict(os.environ, PYTHONPATH=str(self.root))
        self.proc = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--worker"], cwd=self.root, env=env,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)

    def run(self, **req) -> dict:
        self.proc.stdin.write(json.dumps({k: str(v) if isinstance(v, Path) else v for k, v in req.items()}) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise SystemExit(f"the {self.label} worker ({self.root}) stopped; see its stderr above")
        return json.loads(line)

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(timeout=60)


# --- the rulers, in this process ----------------------------------------------------------------
def pair_residual(stage, scene, statics, frame: int, density: int, surfaces=None) -> float:
    """Largest penetration over the frame's pairs, over the pair's size, measured at ``density``.

    ``surfaces`` (one `HSpline` per deformable, scene order) replaces the input's (the default)."""
    from pipeline import detect as D
    from pipeline import geometry, usdio

    dstates, cstates = usdio.state_at(stage, scene, float(frame))
    geoms = [geometry.SurfaceGeometry(surfaces[i] if surfaces else s.surface, s.xform, m.path, density=density)
             for i, (m, s) in enumerate(zip(scene.deformables, dstates))]
    worst = 0.0
    for i, ga in enumerate(geoms):
        others = [(g, min(ga.size, g.size)) for g in geoms[i + 1:]]
        others += [(geometry.ColliderGeometry(st, c.xform), ga.size) for st, c in zip(statics, cstates)]
        for gb, size in others:
            worst = max(worst, D.residual(ga, gb).max / size)
    return worst


def _hash(out, scene, frame: int, names: tuple, prefix: str) -> str:
    from pxr import Usd

    h = hashlib.sha1()
    for m in scene.deformables:
        prim = out.GetPrimAtPath(m.path)
        for name in names:
            h.update(np.asarray(prim.GetAttribute(f"{prefix}{name}").Get(Usd.TimeCode(frame))).tobytes())
    return h.hexdigest()


def reference(output: Path, scene, statics, frames: list[int], density: int, memo: dict) -> np.ndarray:
    """Reference residual ``(len(frames),) float64`` of a written response, measured at ``density``.

    A frame whose written response arrays are byte-identical to one measured before (``memo``,
    keyed by frame and a hash of the arrays) is not measured again."""
    from pxr import Usd

    from pipeline import output_layer

    out = Usd.Stage.Open(str(output))
    res = []
    for f in frames:
        key = ("reference", f, _hash(out, scene, f, _RESPONSE, "acra:response:"))
        if key not in memo:
            surfaces = [output_layer.read_output_hierarchy(out, m.path, f) for m in scene.deformables]
            memo[key] = pair_residual(out, scene, statics, f, density, surfaces)
        res.append(memo[key])
    return np.array(res)


def independent(output: Path, scene, frames: list[int], memo: dict) -> np.ndarray:
    """Independent residual ``(len(frames),) float64``: per frame the largest depth of any
    deformable's composed display inside another object over its own display diagonal, as
    `acceptance.visible` measures the output layer (USD, trimesh, fcl). Frames whose composed
    display meshes are byte-identical to ones measured before are not measured again."""
    from pxr import Usd

    from acceptance import visible

    out = Usd.Stage.Open(str(output))
    res = []
    for f in frames:
        key = ("independent", f, _hash(out, scene, f, ("points", "faceVertexIndices", "faceVertexCounts"), ""))
        if key not in memo:
            memo[key] = visible.worst_by_frame(visible.measure_frame(out, f)).get(f, 0.0)
        res.append(memo[key])
    return np.array(res)


# --- the sweeps ---------------------------------------------------------------------------------
class Bench:
    """The input stage, its collision frames, the rulers' state and the workers (``new``, and
    ``base`` or None)."""

    def __init__(self, src: Path, tmp: Path, frames: list[int], scene, reference_density: int, new: Worker,
                 base: Worker | None):
        from pipeline import geometry

        self.src, self.tmp, self.frames, self.scene, self.ref_density = src, tmp, frames, scene, reference_density
        self.statics = [geometry.prepare_collider(c) for c in scene.colliders]
        self.memo: dict = {}
        self.new, self.base = new, base
        self.turn = 0

    def measure(self, w: Worker, method: str, density: int, cap: int, tolerance: float) -> tuple[Row, bool]:
        """Run one configuration in ``w`` on the range of the collision frames (free frames in it
        are not reported); also return whether every frame stopped before the cap (a larger cap
        then runs the same)."""
        out = self.tmp / f"{w.label}_{method}_{density}_{cap}_{tolerance:g}.acra.usda"
        frames = self.frames
        rep = w.run(src=self.src, output=out, frames=f"{frames[0]}:{frames[-1]}", iterations=cap, tolerance=tolerance,
                    method=method, density=density)
        hit = [s for s in rep["stats"] if s["frame"] in frames]
        loop = np.array([s["residual_rel"] for s in hit])
        ref = reference(out, self.scene, self.statics, frames, self.ref_density, self.memo)
        ind = independent(out, self.scene, frames, self.memo)
        from acceptance.visible import SLACK

        row = Row(method, density, cap, tolerance, float(np.median([s["ms_total"] for s in hit])),
                  float(np.mean([s["iterations"] for s in hit])), float(loop.max()), float(loop.mean()),
                  float(ref.max()), float(ref.mean()), 1e3 * rep["cpu"] / len(rep["stats"]),
                  float(ind.max()), float(ind.mean()), [s["iterations"] for s in hit],
                  int(np.sum(loop <= tolerance)), int(np.sum(ind <= tolerance)),
                  [f for f, r, m in zip(frames, loop, ind) if r < m - SLACK], len(hit))
        out.unlink()
        return row, all(s["iterations"] < cap for s in rep["stats"])

    def sweep(self, method: str, density: int, caps: list[int], tolerance: float) -> tuple[list[Row], list[Row]]:
        """Rows for ``caps`` (ascending), this checkout's and the base's (empty without one).
        Once every frame of a run stopped before its cap (the loop met its stopping rule, or
        nothing was found), a larger cap runs the same rounds: larger caps repeat that run's
        row, marked ``same_as``, instead of running again (per checkout)."""
        rows: dict[str, list[Row]] = {"new": [], "base": []}
        done: dict[str, Row | None] = {"new": None, "base": None}
        for cap in caps:
            workers = [("new", self.new)] + ([("base", self.base)] if self.base else [])
            if self.turn % 2:
                workers.reverse()
            self.turn += 1
            for name, w in workers:
                if done[name] is not None:
                    rows[name].append(replace(done[name], cap=cap, same_as=done[name].cap))
                    continue
                row, converged = self.measure(w, method, density, cap, tolerance)
                rows[name].append(row)
                print(f"  {w.label} {method} d{density} cap {cap} tol {tolerance:g}: {row.cpu_ms:.0f} ms CPU, rounds "
                      f"{row.rounds:.1f}, reported {row.loop_max:.3e}, independent {row.ind_max:.3e}, "
                      f"reference {row.ref_max:.3e}", flush=True)
                done[name] = row if converged else None
        return rows["new"], rows["base"]


# --- tables -------------------------------------------------------------------------------------
def _under(r: Row) -> str:
    return "none" if not r.under else ", ".join(map(str, r.under))


def table(rows: list[Row]) -> str:
    """The rows of one sweep as a markdown table."""
    lines = ["| solver | density | cap | rounds (mean) | CPU ms / frame | median wall ms | reported max | reported mean "
             "| frames ≤ tolerance | independent max | independent mean | reported under independent | reference max "
             "| reference mean |", "|---|---:|---:|---:|---:|---:|---:|---:|:-:|---:|---:|:-:|---:|---:|"]
    for r in rows:
        if r.same_as is not None:
            lines.append(f"| {r.method} | {r.density} | {r.cap} | = cap {r.same_as} (every frame stopped before its cap) "
                         "| | | | | | | | | | |")
            continue
        lines.append(f"| {r.method} | {r.density} | {r.cap} | {r.rounds:.1f} | {r.cpu_ms:.0f} | {r.ms:.0f} | "
                     f"{r.loop_max:.3e} | {r.loop_mean:.2e} | {r.within}/{r.frames} | {r.ind_max:.3e} | {r.ind_mean:.2e} | "
                     f"{_under(r)} | {r.ref_max:.3e} | {r.ref_mean:.2e} |")
    return "\n".join(lines)


def tolerance_table(rows: list[Row]) -> str:
    """The tolerance sweep (one configuration, several tolerances) as a markdown table."""
    lines = ["| tolerance | rounds per collision frame | rounds (mean) | CPU ms / frame | reported max | frames ≤ tolerance "
             "(reported) | independent max | frames ≤ tolerance (independent) | reported under independent "
             "| reference max |", "|---:|---|---:|---:|---:|:-:|---:|:-:|:-:|---:|"]
    for r in rows:
        lines.append(f"| {r.tolerance:g} | {', '.join(map(str, r.rounds_by_frame))} | {r.rounds:.1f} | {r.cpu_ms:.0f} | "
                     f"{r.loop_max:.3e} | {r.within}/{r.frames} | {r.ind_max:.3e} | {r.ind_within}/{r.frames} | "
                     f"{_under(r)} | {r.ref_max:.3e} |")
    return "\n".join(lines)


def before_after(new: list[Row], base: list[Row], base_label: str, new_label: str) -> str:
    """Per configuration run in both checkouts (a row standing for a larger cap counts as that
    cap's run): rounds, CPU ms per collision frame and its ratio, reported and independent
    residual, base → this checkout; then the median ratio and the ratio of the sums."""
    by_key = {r.key(): r for r in base}
    lines = [f"| tolerance | solver | density | cap | rounds `{base_label}` → `{new_label}` | CPU ms / frame `{base_label}` "
             f"| CPU ms / frame `{new_label}` | ratio | reported max `{base_label}` → `{new_label}` | independent max "
             f"`{base_label}` → `{new_label}` |", "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    ratios, sums = [], [0.0, 0.0]
    for r in new:
        b = by_key.get(r.key())
        if b is None:
            continue
        ratio = r.cpu_ms / b.cpu_ms
        if r.same_as is None or b.same_as is None:  # a pair that both repeat an earlier row counts once
            ratios.append(ratio)
            sums[0] += b.cpu_ms
            sums[1] += r.cpu_ms
        mark = lambda q: "" if q.same_as is None else f" (= cap {q.same_as})"  # noqa: E731
        lines.append(f"| {r.tolerance:g} | {r.method} | {r.density} | {r.cap} | {b.rounds:.1f} → {r.rounds:.1f} | "
                     f"{b.cpu_ms:.0f}{mark(b)} | {r.cpu_ms:.0f}{mark(r)} | {ratio:.2f} | {b.loop_max:.3e} → {r.loop_max:.3e} | "
                     f"{b.ind_max:.3e} → {r.ind_max:.3e} |")
    if ratios:
        lines.append(f"\nCPU per collision frame, `{new_label}` against `{base_label}`: {min(ratios):.2f}–{max(ratios):.2f} "
                     f"of it over the {len(ratios)} distinct runs (median {np.median(ratios):.2f}; summed "
                     f"{sums[0]:,.0f} → {sums[1]:,.0f} ms, {sums[1] / sums[0]:.2f}).")
    return "\n".join(lines)


def replace_block(text: str, block: str) -> str:
    """``text`` with this benchmark's generated block (between `BEGIN` and `END`) replaced by
    ``block`` (`doc_tables.replace_block`)."""
    return doc_tables.replace_block(text, block, BEGIN, END)


# --- plot ---------------------------------------------------------------------------------------
def plot(panels: list[tuple[str, list[Row], list[Row]]], path: Path, title: str, base_label: str | None) -> None:
    """Reference residual (top: max, bottom: mean over the collision frames) against CPU ms per
    collision frame (`Row.cpu_ms`), one column per ``(title, rows, base rows)``, one curve per
    solver × density, points labelled by iteration cap (caps repeating a run share its point);
    the base's runs, if any, as faint curves of the same colours."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(panels), figsize=(6.5 * len(panels), 9), sharey="row", squeeze=False)
    colors = plt.get_cmap("tab10")
    curves = sorted({(r.method, r.density) for _, rows, _ in panels for r in rows})
    for col, (name, rows, base) in enumerate(panels):
        for ax, key, what in ((axes[0][col], "ref_max", "max"), (axes[1][col], "ref_mean", "mean")):
            for k, (method, density) in enumerate(curves):
                for runs, faint in ((base, True), (rows, False)):
                    pts = sorted((r for r in runs if (r.method, r.density) == (method, density) and r.same_as is None),
                                 key=lambda r: r.cap)
                    if not pts:
                        continue
                    x, y = [r.cpu_ms for r in pts], [getattr(r, key) for r in pts]
                    label = f"{method}, density {density}" + (f" ({base_label})" if faint else "")
                    ax.plot(x, y, "-o" if method == "direct" else "--s", color=colors(k), ms=4, label=label,
                            alpha=0.3 if faint else 1.0)
                    if faint:
                        continue
                    for r, xi, yi in zip(pts, x, y):
                        caps = [q.cap for q in runs if (q.method, q.density) == (method, density) and r.cap in (q.cap, q.same_as)]
                        text = str(r.cap) if len(caps) == 1 else f"{caps[0]}–{caps[-1]}"
                        ax.annotate(text, (xi, yi), textcoords="offset points", xytext=(3, 3), fontsize=7, color=colors(k))
            if key == "ref_max":
                ax.axhline(1e-3, color="k", lw=0.8, ls=":", label="contract tolerance 1e-3")
                ax.set_title(name, fontsize=10)
            ax.set_ylabel(f"reference residual / size, {what} over collision frames")
            ax.set_xlabel("CPU ms per collision frame (whole run_file call / its frames)")
            ax.grid(True, lw=0.3)
        axes[0][col].legend(fontsize=7)
    fig.suptitle(title + "; point labels: iteration cap", fontsize=11)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--scene", type=Path, default=ROOT / "scenes" / "dog_head_spike.py")
    ap.add_argument("--quick", action="store_true", help="caps 1, 2 at density 8 only; tolerances 1e-3, 5e-4")
    ap.add_argument("--caps", default="1,2,3,4,5,6,7,8", help="caps at the contract tolerance")
    ap.add_argument("--densities", default="4,8,16")
    ap.add_argument("--methods", default="direct,blend")
    ap.add_argument("--forced", default="1,2,4,8", help="caps run at tolerance 1e-9 (density 8)")
    ap.add_argument("--tolerances", default="1e-3,5e-4,2.5e-4", help="tolerances run at the defaults")
    ap.add_argument("--reference", type=int, default=32, help="density of the reference measure (default 32)")
    ap.add_argument("--base", type=Path, help="also run every configuration in this checkout (a git archive copy)")
    ap.add_argument("--base-label", help="the base's name in the tables (default: its commit, or 'base')")
    ap.add_argument("--plot", type=Path, default=ROOT / "docs" / "img" / "speed_vs_error.png")
    ap.add_argument("--markdown", type=Path, help="write the tables between this file's markers (see the docstring)")
    ap.add_argument("--json", type=Path, help="also save the rows as JSON")
    args = ap.parse_args()
    if args.worker:
        return worker()
    sys.path.insert(0, str(ROOT))  # this checkout's pipeline and acceptance measure both checkouts' outputs
    from pxr import Usd

    from pipeline import usdio

    ints = lambda text: sorted(int(x) for x in text.split(","))  # noqa: E731
    caps, densities, forced = ([1, 2], [8], [1, 2]) if args.quick else (ints(args.caps), ints(args.densities), ints(args.forced))
    tolerances = [1e-3, 5e-4] if args.quick else [float(x) for x in args.tolerances.split(",")]
    methods = args.methods.split(",")
    new_label = doc_tables.commit_of(ROOT)
    base_label = (args.base_label or (doc_tables.commit_of(args.base) if doc_tables.commit_of(args.base) != "?" else "base")) if args.base else None

    t_start, load = time.perf_counter(), os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        copy = Path(shutil.copy(args.scene, tmp / args.scene.name))
        src = usdio.load_scene_file(copy) if copy.suffix == ".py" else copy
        new = Worker(ROOT, new_label)
        base = Worker(args.base, base_label) if args.base else None
        try:
            warm = {w.label: w.run(src=src, output=tmp / f"defaults_{i}.acra.usda", frames=None, iterations=4,
                                   tolerance=1e-3, method="direct", density=8) for i, w in enumerate(filter(None, (new, base)))}
            frames = [s["frame"] for s in warm[new_label]["stats"] if s["in_collision"]]
            if not frames:
                raise SystemExit(f"{args.scene.name}: no collision frame")
            if base and [s["frame"] for s in warm[base_label]["stats"] if s["in_collision"]] != frames:
                print(f"note: {base_label}'s collision frames differ; both run frames {frames[0]}–{frames[-1]}")
            scene = usdio.read_scene(usdio.open_input(src))
            bench = Bench(src, tmp, frames, scene, args.reference, new, base)
            input_pen = max(pair_residual(Usd.Stage.Open(str(src)), scene, bench.statics, f, args.reference) for f in frames)
            print(f"{args.scene.name}: collision frames {frames}; input penetration {input_pen:.3e} of size "
                  f"(density {args.reference}); {new_label} full run at the defaults {warm[new_label]['seconds']:.1f} s")
            sweeps = {"grid": [], "rounds": [], "tolerance": []}
            bases = {"grid": [], "rounds": [], "tolerance": []}
            for m in methods:
                for d in densities:
                    n, b = bench.sweep(m, d, caps, 1e-3)
                    sweeps["grid"] += n
                    bases["grid"] += b
            for m in methods:
                n, b = bench.sweep(m, 8, forced, 1e-9)
                sweeps["rounds"] += n
                bases["rounds"] += b
            for tol in tolerances:
                n, b = bench.sweep(DEFAULTS["method"], DEFAULTS["density"], [DEFAULTS["cap"]], tol)
                sweeps["tolerance"] += n
                bases["tolerance"] += b
        finally:
            for w in filter(None, (new, base)):
                w.close()
    wall = time.perf_counter() - t_start
    command = "python3 benchmarks/speed_vs_error.py" + (" --quick" if args.quick else "") + (
        f" --base DIR --base-label {base_label}" if base else "")
    parts = [f"Generated by `{command}` at `{new_label}`" + (f" against `{base_label}`" if base else "")
             + f", {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}: {wall:.0f} s wall, load average "
             f"{load[0]:.1f} at the start. Scene `{args.scene.name}`, collision frames {frames[0]}–{frames[-1]}; "
             f"input penetration {input_pen:.3e} of the size (reference, density {args.reference}).",
             "### Tolerance 1e-3 (the contract)", table(sweeps["grid"]),
             "### Tolerance 1e-9 (every run uses its whole cap), density 8", table(sweeps["rounds"]),
             f"### Tolerance sweep at the defaults ({DEFAULTS['method']}, density {DEFAULTS['density']}, cap {DEFAULTS['cap']})",
             tolerance_table(sweeps["tolerance"])]
    if base:
        parts += [f"### The time axis before and after: `{base_label}` → `{new_label}`",
                  before_after(sweeps["grid"] + sweeps["rounds"] + sweeps["tolerance"],
                               bases["grid"] + bases["rounds"] + bases["tolerance"], base_label, new_label)]
    block = "\n\n".join(parts)
    print("\n" + block)
    plot([("tolerance 1e-3 (contract): the loop stops when met", sweeps["grid"], bases["grid"]),
          ("tolerance 1e-9: every round runs, density 8", sweeps["rounds"], bases["rounds"])], args.plot,
         f"{args.scene.name} at {new_label}, frames {frames[0]}–{frames[-1]} (input penetration {input_pen:.2e} of size)",
         base_label)
    if args.markdown:
        old = args.markdown.read_text(encoding="utf-8") if args.markdown.exists() else ""
        args.markdown.write_text(replace_block(old, block), encoding="utf-8")
    if args.json:
        args.json.write_text(json.dumps({"frames": frames, "input": input_pen, "new": new_label, "base": base_label,
                                         **{k: [asdict(r) for r in v] for k, v in sweeps.items()},
                                         **{f"base_{k}": [asdict(r) for r in v] for k, v in bases.items()}}, indent=1))
    print(f"\nplot: {args.plot}; benchmark wall time {wall:.0f} s")


if __name__ == "__main__":
    main()
