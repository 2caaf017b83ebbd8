"""The first run after a fresh install: numba compiling every kernel `acra run` calls.

    python3 benchmarks/first_run.py                       # scenes/dog_head_spike.py -o .usdc, 3 runs
    python3 benchmarks/first_run.py --repeat 1 --kernels  # and the per-kernel table (one more run)
    python3 benchmarks/first_run.py --format usda
    python3 benchmarks/first_run.py --base /tmp/base  # alternating with another checkout

Each run is a fresh ``python -m pipeline.cli run SCENE -o OUT --quiet`` of this checkout
(``PYTHONPATH`` set to it) whose ``NUMBA_CACHE_DIR`` is a new empty directory, so every kernel the
run calls is compiled and cached, as on a machine where the package was just installed. Prints the
median user, system and wall seconds and the number of cached specialisations (``*.nbc`` files),
with the kernels cached more than once.

``--kernels`` runs the same command once more in-process under numba's event API
(``numba:compile`` and ``numba:run_pass``, nested, so each figure is exclusive of the kernels the
kernel's typing compiled): per kernel and specialisation the CPU seconds of type inference, of
lowering to LLVM IR, of LLVM (optimising and emitting machine code, `CodeLibrary.finalize`) and of
the rest (bytecode analysis, rewrites, the cache's save), the top ``--top`` by total.

``--warm N`` fills a new empty cache from N processes at once, each compiling a disjoint group of
the kernels the run calls from Python (with the kernels they call, balanced by `_groups`) for the signatures a run of
this checkout records, as a TD could once after install; then runs the scene on that cache.
Prints the warm-up's wall and user seconds (and each process's user seconds: on N idle cores
its wall would be about the largest), the specialisations compiled in more than one process (a
kernel two groups call) and the run's user and wall seconds after it.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]


def _argv(scene: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "pipeline.cli", "run", str(scene), "-o", str(out), "--quiet",
            "--over-tolerance", "warn"]


def one_run(scene: Path, fmt: str, checkout: Path = HERE) -> tuple[float, float, float, list[str]]:
    """User, system and wall seconds of one empty-cache run of ``checkout``, and the cached
    specialisations."""
    with tempfile.TemporaryDirectory() as tmp:
        cache = Path(tmp) / "cache"
        env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "PYTHONPATH": str(checkout)}
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        subprocess.run(_argv(scene, Path(tmp) / f"out.{fmt}"), check=True, capture_output=True, env=env, cwd=tmp)
        wall = time.perf_counter() - t
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        nbc = sorted(p.name for p in cache.rglob("*.nbc"))
    return after.ru_utime - before.ru_utime, after.ru_stime - before.ru_stime, wall, nbc


def _kernel_of(nbc: str) -> str:
    """``bvh._box_distance`` from ``bvh._box_distance-196.py311.1.nbc``."""
    return re.sub(r"-\d+\.py\d+\.\d+\.nbc$", "", nbc)


def profile(scene: Path, fmt: str) -> None:
    """Child of ``--kernels``: run in this process, print the per-kernel table's rows as TSV."""
    from numba.core import codegen, event

    clock = time.process_time
    stack: list[list] = []  # [key, start, child seconds, {phase: seconds}]
    rows: dict = defaultdict(lambda: defaultdict(float))
    phase_stack: list[list] = []  # [phase, start, child seconds]
    parents: dict = {}  # the kernel whose typing compiled this one

    def phase_of(name: str) -> str:
        name = name.split(" ")[0]
        if "type_inference" in name:
            return "typing"
        if "lowering" in name:
            return "lowering"
        return "other"

    class Compile(event.Listener):
        def on_start(self, ev):
            d = ev.data["dispatcher"]
            key = (f"{d.py_func.__module__.rsplit('.', 1)[-1]}.{d.py_func.__name__}", str(ev.data["args"]))
            stack.append([key, clock(), 0.0])

        def on_end(self, ev):
            key, start, child = stack.pop()
            total = clock() - start
            rows[key]["total"] += total - child
            rows[key]["count"] += 1
            parents.setdefault(key, stack[-1][0][0] if stack else "")
            if stack:
                stack[-1][2] += total

    class Pass(event.Listener):
        def on_start(self, ev):
            phase_stack.append([phase_of(ev.data["name"]), clock(), 0.0, stack[-1][0] if stack else None])

        def on_end(self, ev):
            phase, start, child, key = phase_stack.pop()
            total = clock() - start
            if key is not None:
                rows[key][phase] += total - child
            if phase_stack:
                phase_stack[-1][2] += total

    finalize = codegen.CPUCodeLibrary.finalize

    def timed_finalize(self):
        start = clock()
        try:
            return finalize(self)
        finally:
            spent = clock() - start
            if stack:
                rows[stack[-1][0]]["llvm"] += spent
                if phase_stack:  # LLVM runs inside the lowering pass: take it out of lowering
                    rows[stack[-1][0]][phase_stack[-1][0]] -= spent

    codegen.CPUCodeLibrary.finalize = timed_finalize
    event.register("numba:compile", Compile())
    event.register("numba:run_pass", Pass())
    from pipeline import cli

    t0 = clock()
    with tempfile.TemporaryDirectory() as tmp:
        cli.main(["run", str(scene), "-o", str(Path(tmp) / f"out.{fmt}"), "--quiet", "--over-tolerance", "warn"])
    print(f"#process\t{clock() - t0:.3f}")
    for (name, args), r in rows.items():
        print("\t".join([name, args, str(int(r["count"]))] +
                        [f"{r[k]:.3f}" for k in ("total", "typing", "lowering", "llvm", "other")] +
                        [parents.get((name, args), "")]))


def _dispatchers() -> dict:
    """Every compiled kernel of ``acra``: ``{"module:name": dispatcher}``."""
    import importlib
    import pkgutil

    import acra
    from numba.core.registry import CPUDispatcher

    found = {}
    for info in pkgutil.iter_modules(acra.__path__):
        mod = importlib.import_module(f"acra.{info.name}")
        for name, obj in vars(mod).items():
            if isinstance(obj, CPUDispatcher) and obj.py_func.__module__ == mod.__name__:
                found[f"{mod.__name__}:{name}"] = obj
    return found


def record(scene: Path, fmt: str, out: Path) -> None:
    """Child of ``--warm``: run the scene in this process and pickle each kernel's signatures."""
    import pickle

    from pipeline import cli

    with tempfile.TemporaryDirectory() as tmp:
        cli.main(["run", str(scene), "-o", str(Path(tmp) / f"out.{fmt}"), "--quiet", "--over-tolerance", "warn"])
    sigs = {key: list(d.signatures) for key, d in _dispatchers().items() if d.signatures}
    out.write_bytes(pickle.dumps(sigs))


def compile_group(path: Path) -> None:
    """Child of ``--warm``: compile the pickled ``{"module:name": signatures}`` of one group."""
    import pickle

    found = _dispatchers()
    for key, sigs in pickle.loads(path.read_bytes()).items():
        for sig in sigs:
            found[key].compile(sig)
    print(sum(len(d.signatures) for d in found.values()), resource.getrusage(resource.RUSAGE_SELF).ru_utime)


def _groups(sigs: dict, n: int) -> list[dict]:
    """The recorded kernels that no recorded kernel calls, in ``n`` groups of about equal weight,
    heaviest first to the lightest group. Each is compiled with the kernels it calls, whose code
    numba links into the caller's and LLVM optimises and emits again there: a kernel weighs its
    source and the weight of each kernel it calls, once per caller."""
    import inspect
    from functools import cache

    found = _dispatchers()
    calls = {key: {f"{g[name].py_func.__module__}:{g[name].py_func.__name__}" for name in found[key].py_func.__code__.co_names
                   if name in (g := found[key].py_func.__globals__) and hasattr(g[name], "py_func")} & set(sigs)
             for key in sigs}
    called = set().union(*calls.values())

    @cache
    def weight(key: str) -> int:
        return len(inspect.getsource(found[key].py_func)) + sum(weight(c) for c in calls[key])

    groups: list[tuple[list, dict]] = [([0], {}) for _ in range(n)]
    for key in sorted((k for k in sigs if k not in called), key=lambda k: -weight(k)):
        total, group = min(groups, key=lambda g: g[0][0])
        total[0] += weight(key)
        group[key] = sigs[key]
    return [g for _, g in groups]


def warm(scene: Path, fmt: str, n: int, checkout: Path = HERE) -> None:
    """``--warm N``: the cache filled by ``n`` processes at once, then the scene run on it."""
    import pickle

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        env = {**os.environ, "PYTHONPATH": str(checkout)}
        subprocess.run([sys.executable, __file__, "--record", str(tmp / "sigs.pkl"), "--format", fmt, str(scene)],
                       check=True, capture_output=True, env=env, cwd=tmp)
        sigs = pickle.loads((tmp / "sigs.pkl").read_bytes())
        env["NUMBA_CACHE_DIR"] = str(tmp / "cache")
        for i, group in enumerate(_groups(sigs, n)):
            (tmp / f"group{i}.pkl").write_bytes(pickle.dumps(group))
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t = time.perf_counter()
        procs = [subprocess.Popen([sys.executable, __file__, "--compile", str(tmp / f"group{i}.pkl")],
                                  stdout=subprocess.PIPE, text=True, env=env, cwd=tmp) for i in range(n)]
        counts = [p.communicate()[0].split()[-2:] for p in procs]
        compiled, users = [int(c) for c, _ in counts], [float(u) for _, u in counts]
        wall = time.perf_counter() - t
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cached = len(list((tmp / "cache").rglob("*.nbc")))
        t = time.perf_counter()
        subprocess.run(_argv(scene, tmp / f"out.{fmt}"), check=True, capture_output=True, env=env, cwd=tmp)
        run_wall = time.perf_counter() - t
        last = resource.getrusage(resource.RUSAGE_CHILDREN)
    print(f"{checkout}: cache warmed by {n} processes at once: wall {wall:.1f} s, user {after.ru_utime - before.ru_utime:.1f}"
          f" s, system {after.ru_stime - before.ru_stime:.1f} s; {sum(compiled)} specialisations compiled "
          f"({', '.join(map(str, compiled))}), {cached} cached: {sum(compiled) - cached} compiled twice; user s a process "
          f"{', '.join(f'{u:.1f}' for u in users)} (on {n} idle cores the wall would be about the largest)")
    print(f"  then {scene.name} -o .{fmt}: user {last.ru_utime - after.ru_utime:.1f} s, wall {run_wall:.1f} s")


def kernels(scene: Path, fmt: str, top: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "NUMBA_CACHE_DIR": str(Path(tmp) / "cache"), "PYTHONPATH": str(HERE)}
        done = subprocess.run([sys.executable, __file__, "--profile", "--format", fmt, str(scene)],
                              check=True, capture_output=True, text=True, env=env, cwd=tmp)
    rows, process = [], 0.0
    for line in done.stdout.splitlines():
        parts = line.split("\t")
        if parts[0] == "#process":
            process = float(parts[1])
        elif len(parts) == 9:
            rows.append((parts[0], parts[1], int(parts[2]), *map(float, parts[3:8]), parts[8]))
    rows.sort(key=lambda r: -r[3])
    compiled = sum(r[3] for r in rows)
    per_kernel = Counter(r[0] for r in rows)
    print(f"\nIn-process run: {process:.1f} s CPU, of which {compiled:.1f} s compiling {len(rows)} "
          f"specialisations of {len(per_kernel)} kernels (typing {sum(r[4] for r in rows):.1f}, lowering "
          f"{sum(r[5] for r in rows):.1f}, LLVM {sum(r[6] for r in rows):.1f}, other {sum(r[7] for r in rows):.1f} s).\n")
    print("| kernel | argument types | CPU s | typing | lowering | LLVM | other |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for name, args, _, total, typing, lowering, llvm, other, _ in rows[:top]:
        shown = args if len(args) <= 90 else args[:87] + "..."
        print(f"| `{name}` | `{shown}` | {total:.2f} | {typing:.2f} | {lowering:.2f} | {llvm:.2f} | {other:.2f} |")
    twice = {k: n for k, n in per_kernel.items() if n > 1}
    if twice:
        print("\nKernels compiled for more than one signature: " +
              ", ".join(f"`{k}` {n}" for k, n in sorted(twice.items(), key=lambda kv: -kv[1])))
        for name in sorted(twice):
            for r in rows:
                if r[0] == name:
                    print(f"  {name}: {r[1]}  ({r[3]:.2f} s, from {r[8] or 'Python'})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", nargs="?", type=Path, default=HERE / "scenes" / "dog_head_spike.py")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--format", choices=("usdc", "usda"), default="usdc")
    ap.add_argument("--kernels", action="store_true", help="also the per-kernel compile table (one more run)")
    ap.add_argument("--top", type=int, default=15)
    ap.add_argument("--base", type=Path, help="another checkout: its runs alternate with this one's (ratio of medians)")
    ap.add_argument("--warm", type=int, metavar="N", help="also the cache warmed by N processes at once, then a run")
    ap.add_argument("--profile", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--record", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--compile", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    scene = args.scene.resolve()
    if args.profile:
        profile(scene, args.format)
        return
    if args.record:
        record(scene, args.format, args.record)
        return
    if args.compile:
        compile_group(args.compile)
        return
    if args.repeat < 1:
        if args.warm:
            warm(scene, args.format, args.warm)
        if args.kernels or not args.warm:
            kernels(scene, args.format, args.top)
        return
    checkouts = ([] if args.base is None else [args.base.resolve()]) + [HERE]
    runs: dict = {c: [] for c in checkouts}
    for _ in range(args.repeat):
        for c in checkouts:
            runs[c].append(one_run(scene, args.format, c))
    medians = {}
    for c in checkouts:
        rs = runs[c]
        med = medians[c] = [float(np.median([r[i] for r in rs])) for i in range(3)]
        print(f"{c}: {scene.name} -o .{args.format}, {len(rs)} empty-cache runs: user "
              + ", ".join(f"{r[0]:.1f}" for r in rs) + f" s (median {med[0]:.1f}), system median {med[1]:.1f} s, wall "
              + ", ".join(f"{r[2]:.1f}" for r in rs) + f" s (median {med[2]:.1f})")
        nbc = rs[-1][3]
        counts = Counter(_kernel_of(n) for n in nbc)
        print(f"  {len(nbc)} specialisations cached, {len(counts)} kernels; more than one: " +
              (", ".join(f"{k} {n}" for k, n in counts.most_common() if n > 1) or "none"))
    for c in checkouts[1:]:
        b, h = medians[checkouts[0]], medians[c]
        print(f"{c} / {checkouts[0]}, medians: "
              f"user {h[0] / b[0]:.3f}, wall {h[2] / b[2]:.3f}")
    if args.warm:
        warm(scene, args.format, args.warm)
    if args.kernels:
        kernels(scene, args.format, args.top)


if __name__ == "__main__":
    main()
