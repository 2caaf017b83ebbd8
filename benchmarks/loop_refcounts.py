"""Reference-count calls and compiled calls inside the loops of acra's kernels, read from their LLVM.

    python3 benchmarks/loop_refcounts.py [MODULE ...]

Runs `dog_head_spike` frames 13-17 after frame 5 and `box_into_sheet` frame 11 with numba's cache
in a fresh directory (a kernel loaded from the cache has no LLVM to show), then, for each kernel
of the named `acra` modules (default: every module with kernels) and each signature the run
compiled, prints how many ``NRT_incref`` / ``NRT_decref`` calls its own LLVM function holds, how
many of them lie in a basic block on a cycle (a loop), and the calls of other compiled functions
left in loops after LLVM's inlining. A reference-count call in a loop is what a row view, or an
array handed to a compiled function that is not inlined, costs per item (*Kernels* in
``docs/performance.md``); one in the entry or exit block costs once a call. Blocks are read as
the text of ``inspect_llvm``: a block is on a cycle when it reaches itself along ``label``
branches.
"""

from __future__ import annotations

import os
import pathlib
import re
import sys
import tempfile

_CACHE = tempfile.TemporaryDirectory(prefix="loop_refcounts_")  # removed at exit
os.environ["NUMBA_CACHE_DIR"] = _CACHE.name  # before numba is imported

ROOT = pathlib.Path(__file__).resolve().parents[1]
MODULES = ("nearest", "kdtree", "narrow", "levelkernels", "framekernels", "halfspaces", "raycast", "patch_boxes",
           "orientation", "float32", "floatdigits", "floattext", "pseudonormals", "bvh", "depthbound", "meshrows", "clearcells",
           "kernels", "tessellate", "lattice")


def _blocks(body: str) -> tuple[list, dict]:
    """The basic blocks of one LLVM function's text: their labels in order and their lines."""
    order, lines, label = ["entry"], {"entry": []}, "entry"
    for line in body.split("\n")[1:]:
        m = re.match(r"^([\w.\-]+):", line)
        if m:
            label = m.group(1)
            order.append(label)
            lines[label] = []
        else:
            lines[label].append(line)
    return order, lines


def _on_cycles(order: list, lines: dict) -> list:
    succ = {b: set(re.findall(r"label %([\w.\-]+)", "\n".join(ls))) for b, ls in lines.items()}
    out = []
    for b in order:
        seen, stack = set(), list(succ[b])
        while stack:
            x = stack.pop()
            if x not in seen:
                seen.add(x)
                stack.extend(succ.get(x, ()))
        if b in seen:
            out.append(b)
    return out


def report(module) -> None:
    for name, f in sorted(vars(module).items()):
        if not hasattr(f, "inspect_llvm") or getattr(f, "py_func", None) is None or f.py_func.__module__ != module.__name__:
            continue
        for sig in f.signatures:
            ir = f.inspect_llvm(sig)
            pattern = r"define [^@]*@(_ZN[^(]*?%d%s[^(]*?)\((.*?)\n}\n" % (len(name), re.escape(name))
            own = [m for m in re.finditer(pattern, ir, re.S) if "cpython" not in m.group(1)]
            if not own:
                continue
            order, lines = _blocks(own[0].group(0))
            refs = [(b, ln.strip()) for b in order for ln in lines[b] if "@NRT_incref" in ln or "@NRT_decref" in ln]
            loops = set(_on_cycles(order, lines))
            in_loops = [r for r in refs if r[0] in loops]
            calls = [(b, re.search(r"@(_ZN\S+?)\(", ln).group(1)) for b in order if b in loops for ln in lines[b]
                     if re.search(r"call [^\n]*@_ZN", ln)]
            print(f"{module.__name__}.{name}: {len(refs)} reference-count calls, {len(in_loops)} in loops, "
                  f"{len(calls)} compiled calls in loops")
            for b, ln in in_loops[:8]:
                print(f"    {b}: {ln[:100]}")
            for b, c in calls[:8]:
                print(f"    call in {b}: {c[:80]}")


def main() -> None:
    import importlib

    from pipeline import frames as F
    from pipeline import usdio
    from pipeline.run import forget

    forget()
    for scene, free, frames in (("dog_head_spike", [5], list(range(13, 18))), ("box_into_sheet", [], [11])):
        stage = usdio.open_input(usdio.load_scene_file(ROOT / "scenes" / f"{scene}.py"))
        parsed = usdio.read_scene(stage)
        if free:
            F.run_frames(stage, parsed, free)
        F.respond_frames(stage, parsed, frames)
    for name in sys.argv[1:] or MODULES:
        report(importlib.import_module(f"acra.{name}"))


if __name__ == "__main__":
    main()
