"""Start-up and the whole process of `acra run`: wall clock, CPU time, phases, imports by package.

    python3 benchmarks/startup.py                                   # scenes/dog_head_spike.py, 5 runs
    python3 benchmarks/startup.py scenes/box_into_sheet.py --repeat 3
    python3 benchmarks/startup.py --bytecode                        # as an installed package runs

Each figure is from fresh processes of this checkout (``PYTHONPATH`` set to it), the scene file
copied into a temporary directory:

* ``acra --version``: the command line alone (median wall and CPU seconds);
* ``acra run SCENE -o OUT.usda --quiet`` and ``-o OUT.usdc``, one warm-up each and then ``repeat``
  runs interleaved: median wall seconds (as ``/usr/bin/time`` gives them) and median CPU seconds
  (user + system of the child, which a busy machine inflates far less than the wall clock), and the
  median of each phase of the run's ``--report`` (`pipeline.run.run_file`; the interpreter's start
  and exit is the wall clock less the phases);
* one more ``.usda`` run under ``python -X importtime``: the imports' own time summed by top-level
  package (``-X importtime`` adds its own overhead, so compare the packages' shares, not the sum
  with the table above);
* one more ``.usda`` run with numba's cache loads timed (``numba.core.caching.Cache.load_overload``
  wrapped): how many kernels the run loads from the on-disk cache, the first load (which also
  initialises numba's typing and target contexts) and the rest (wall and CPU seconds), and the CPU
  seconds of the process's end (the child's CPU after `pipeline.cli.main` returned, ended as
  `acra` ends, `pipeline.cli.end`: atexit handlers, and module teardown where it is not skipped);
* the CPU seconds of compiling, from source, the checkout's modules that run imported: with
  ``PYTHONDONTWRITEBYTECODE`` set (as on the project's machine) every process compiles them
  inside its imports; an installed package has their ``.pyc``. ``--bytecode`` runs every process
  as an installed package does: ``PYTHONDONTWRITEBYTECODE`` unset and ``PYTHONPYCACHEPREFIX`` a
  temporary directory, so the warm-up writes the ``.pyc`` the measured runs read and the checkout
  gets no ``__pycache__``.

Prints markdown tables (docs/performance.md, *Start-up and the whole process*).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]
PHASES = ("interpreter", "imports", "scene", "read", "frames", "write")
PACKAGES = ("numpy", "pxr", "scipy", "trimesh", "networkx", "fcl", "acra", "pipeline")


def timed(argv: list[str], cwd: Path, env: dict) -> tuple[float, float, subprocess.CompletedProcess]:
    """Wall and CPU (user + system) seconds of the child process ``argv``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    done = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode not in (0, 3):
        raise RuntimeError(f"{' '.join(argv)} failed:\n{done.stderr}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), done


def imports_by_package(stderr: str) -> dict[str, float]:
    """Seconds of each top-level package's own import time in ``-X importtime`` output."""
    total: dict[str, float] = defaultdict(float)
    for line in stderr.splitlines():
        if not line.startswith("import time:") or "self [us]" in line:
            continue
        own, _, name = line[len("import time:"):].split("|")
        top = name.strip().split(".")[0]
        total[top if top in PACKAGES else "other"] += int(own) / 1e6
    return dict(total)


# a child process: `acra run` with numba's cache loads timed, the figures as JSON on stderr
NUMBA_LOADS = """
import json, sys, time
import acra  # first, as `acra run` imports it: numba without PyYAML, and its cache loads installed before they are wrapped
import numba.core.caching as caching
loads = []
load = caching.Cache.load_overload
def timed(self, sig, target_context):
    w, c = time.perf_counter(), time.process_time()
    got = load(self, sig, target_context)
    loads.append((time.perf_counter() - w, time.process_time() - c, got is not None))
    return got
caching.Cache.load_overload = timed
# a load's parts, CPU seconds summed over the loads after the first (which also sets numba up)
import numba.core.codegen as codegen
from llvmlite import binding as ll
parts = {}
def part(owner, attr, name):
    f = getattr(owner, attr)
    def w(*a, **k):
        c = time.process_time()
        try:
            return f(*a, **k)
        finally:
            if len(loads) > 0:
                parts[name] = parts.get(name, 0.0) + time.process_time() - c
    setattr(owner, attr, w)
part(caching.IndexDataCacheFile, "_load_index", "index lookup (the index file read and unpickled)")
part(caching.IndexDataCacheFile, "_load_data", "the kernel's data read and unpickled")
part(ll, "parse_bitcode", "LLVM bitcode parsed (`llvmlite.binding.parse_bitcode`)")
part(codegen.JitEngine, "_load_defined_symbols", "the symbols of the LLVM modules added listed (`JitEngine._load_defined_symbols`)")
part(codegen.CPUCodeLibrary, "_finalize_final_module", "its object code added to the JIT and finalised")
import acra.kernelcache as kernelcache
part(kernelcache, "defined_symbols", "the symbols the object code defines read (`acra.kernelcache`)")
from pipeline.cli import end, main
sys.argv = ["acra"] + sys.argv[1:]
try:
    status = main()
finally:
    sys.stderr.write("NUMBA_LOADS " + json.dumps(loads) + "\\n")
    sys.stderr.write("LOAD_PARTS " + json.dumps(parts) + "\\n")
    sys.stderr.write("MODULES " + json.dumps([getattr(m, "__file__", None) for m in list(sys.modules.values())]) + "\\n")
    import resource
    r = resource.getrusage(resource.RUSAGE_SELF)
    sys.stderr.write(f"CPU_AT_EXIT {r.ru_utime + r.ru_stime}\\n")
end(status)  # as `acra` ends (`pipeline.cli.program`)
"""


def tagged(stderr: str, tag: str):
    """The JSON after ``tag`` on the last line of ``stderr`` that starts with it."""
    line = [x for x in stderr.splitlines() if x.startswith(tag + " ")][-1]
    return json.loads(line[len(tag) + 1:])


def source_compile_s(files: list) -> float:
    """CPU seconds of compiling the checkout's (``HERE``) modules among ``files`` from source."""
    own = sorted({Path(f) for f in files if f and f.endswith(".py") and Path(f).resolve().is_relative_to(HERE)})
    t = time.process_time()
    for f in own:
        compile(f.read_text(), str(f), "exec")
    return time.process_time() - t


def numba_loads(stderr: str) -> list[tuple[float, float, bool]]:
    """The (wall s, CPU s, found in the cache) of each kernel load `NUMBA_LOADS` reported."""
    line = [x for x in stderr.splitlines() if x.startswith("NUMBA_LOADS ")][-1]
    return json.loads(line[len("NUMBA_LOADS "):])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scene", nargs="?", type=Path, default=HERE / "scenes" / "dog_head_spike.py")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--bytecode", action="store_true",
                        help="the modules' .pyc written by the warm-up and read by the measured runs")
    args = parser.parse_args()
    env = dict(os.environ, PYTHONPATH=str(HERE))
    cli = [sys.executable, "-m", "pipeline.cli"]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        if args.bytecode:
            env.pop("PYTHONDONTWRITEBYTECODE", None)
            env["PYTHONPYCACHEPREFIX"] = str(work / "pycache")
        src = work / args.scene.name
        shutil.copy(args.scene, src)
        wall: dict = {"usda": [], "usdc": []}
        cpu: dict = {"usda": [], "usdc": []}
        phases: dict = {fmt: defaultdict(list) for fmt in wall}
        for k in range(args.repeat + 1):  # the first is a warm-up
            for fmt in wall:
                report = work / f"r.{fmt}.json"
                w, c, _ = timed(cli + ["run", str(src), "-o", str(work / f"out.acra.{fmt}"), "--quiet", "--over-tolerance", "warn",
                                       "--report", str(report)], work, env)
                if k == 0:
                    continue
                wall[fmt].append(w)
                cpu[fmt].append(c)
                split = json.loads(report.read_text())["phases"]
                phases[fmt]["interpreter"].append(w - sum(split.values()))
                for name, sec in split.items():
                    phases[fmt][name].append(sec)
        version = [timed(cli + ["--version"], work, env)[:2] for _ in range(args.repeat)]  # after the warm-up's .pyc
        _, _, traced = timed([sys.executable, "-X", "importtime", "-m", "pipeline.cli", "run", str(src), "-o",
                              str(work / "traced.acra.usda"), "--quiet", "--over-tolerance", "warn"], work, env)
        _, counted_cpu, counted = timed([sys.executable, "-c", NUMBA_LOADS, "run", str(src), "-o", str(work / "loads.acra.usda"), "--quiet",
                               "--over-tolerance", "warn"], work, env)
    med = lambda xs: float(np.median(xs))  # noqa: E731
    load = os.getloadavg()
    flags = " --bytecode" if args.bytecode else ""
    print(f"`python3 benchmarks/startup.py {args.scene.name} --repeat {args.repeat}{flags}`: medians of {args.repeat} "
          f"after a warm-up; load average at the end {load[0]:.1f} (1 min), {load[1]:.1f} (5 min)\n")
    print("| process | wall s | CPU s |\n|---|---:|---:|")
    print(f"| `acra --version` | {med([w for w, _ in version]):.3f} | {med([c for _, c in version]):.3f} |")
    for fmt in wall:
        print(f"| `acra run {args.scene.name} -o OUT.{fmt} --quiet` | {med(wall[fmt]):.3f} | {med(cpu[fmt]):.3f} |")
    print("\n| phase (wall s) | `.usda` | `.usdc` |\n|---|---:|---:|")
    for name in PHASES:
        print(f"| {name} | {med(phases['usda'][name]):.3f} | {med(phases['usdc'][name]):.3f} |")
    own = imports_by_package(traced.stderr)
    print("\n| imports of `acra run`, by package (`-X importtime`, own time) | s |\n|---|---:|")
    for name in sorted(own, key=own.get, reverse=True):
        print(f"| {name} | {own[name]:.3f} |")
    print(f"| **all** | **{sum(own.values()):.3f}** |")
    loads = numba_loads(counted.stderr)
    rest = loads[1:]
    print("\n| numba kernels loaded from its cache (one `.usda` run) | loads | wall s | CPU s |\n|---|---:|---:|---:|")
    print(f"| first (with numba's typing and target contexts) | 1 | {loads[0][0]:.3f} | {loads[0][1]:.3f} |")
    print(f"| the rest | {len(rest)} | {sum(x[0] for x in rest):.3f} | {sum(x[1] for x in rest):.3f} |")
    split = tagged(counted.stderr, "LOAD_PARTS")
    if rest:
        print("\n| of a load after the first, CPU ms each (`numba.core.caching`, `codegen`) | ms |\n|---|---:|")
        for name, sec in split.items():
            print(f"| {name} | {1e3 * sec / len(rest):.2f} |")
        print(f"| the rest (the compile result and its environment rebuilt, the dispatcher's entry) | "
              f"{1e3 * (sum(x[1] for x in rest) - sum(split.values())) / len(rest):.2f} |")
    if not all(x[2] for x in loads):
        print(f"\n{sum(not x[2] for x in loads)} of the loads missed the cache (compiled in that run)")
    files = tagged(counted.stderr, "MODULES")
    exit_cpu = counted_cpu - tagged(counted.stderr, "CPU_AT_EXIT")
    print("\n| more of one `.usda` run | CPU s |\n|---|---:|")
    bytecode = "unset" if "PYTHONDONTWRITEBYTECODE" not in env else "set"
    print(f"| compiling this checkout's {sum(1 for f in files if f and Path(f).resolve().is_relative_to(HERE))} modules "
          f"from source, if no `.pyc` (`PYTHONDONTWRITEBYTECODE` {bytecode} in the runs) | "
          f"{source_compile_s(files):.3f} |")
    print(f"| the process's end (`pipeline.cli.end`: atexit handlers, no module teardown) | {exit_cpu:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
