"""Where a response's time goes, statement by statement: CPU laps inside one function of the replay.

    python3 benchmarks/respond_laps.py acra.respond:respond [--repeat 25] [--top 25]
    python3 benchmarks/respond_laps.py acra.details:moved_details [--calls 0 1]

Records the `acra.respond.respond` calls of frames 13–17 as `benchmarks/respond_calls.py` does,
then compiles the named function again with a lap before each of its statements (in loops and
branches too) and one as it returns, and replays the calls ``--repeat`` times (each repeat after
`pipeline.run.forget`, a cold run of the frames). Each statement's lap runs from its start to the
next lap: a compound statement's own test, a simple one's whole work with the functions it calls.
Prints, per statement, the least over the repeats of its CPU ms in each call, summed over the
calls, per collision frame (a lap costs about 0.5 µs of the time it measures), and a digest of the
responded surfaces (`respond_calls.surface_arrays`), which the laps do not change. ``--calls n
...`` sums the laps of those calls alone (numbered as `benchmarks/respond_calls.py --per-call`
prints them), still per collision frame of the whole replay.
"""

from __future__ import annotations

import argparse
import ast
import collections
import hashlib
import importlib
import inspect
import pathlib
import sys
import textwrap
import time

from threadpoolctl import threadpool_limits

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import respond_calls as RC  # noqa: E402

from acra import respond as R  # noqa: E402
from pipeline import run  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]


class _Laps(ast.NodeTransformer):
    """A lap before every statement of a function's body, its loops' and its branches'."""

    def _body(self, body):
        out = []
        for st in body:
            out += [ast.parse(f"__lap({st.lineno})").body[0], self.visit(st)]
        return out

    def visit_FunctionDef(self, node):
        node.body = [ast.Try(body=self._body(node.body), handlers=[], orelse=[], finalbody=ast.parse("__lap(-1)").body)]
        node.decorator_list = []
        return node

    def visit_For(self, node):
        node.body = self._body(node.body)
        return node

    visit_While = visit_For

    def visit_If(self, node):
        node.body = self._body(node.body)
        node.orelse = self._body(node.orelse) if node.orelse else []
        return node


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("function", help="MODULE:FUNCTION, named where it is defined")
    ap.add_argument("--repeat", type=int, default=25)
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--calls", type=int, nargs="+", default=None, metavar="N")
    args = ap.parse_args()
    module, name = args.function.split(":")
    mod = importlib.import_module(module)
    calls = RC.record(ROOT / "scenes" / "dog_head_spike.py", 13, 17, 5)
    src = textwrap.dedent(inspect.getsource(getattr(mod, name)))
    tree = ast.parse(src)
    tree.body[0] = _Laps().visit(tree.body[0])
    ast.fix_missing_locations(tree)
    acc: dict = collections.defaultdict(float)
    state = {"line": -1, "t": 0.0}

    def lap(line: int) -> None:
        t = time.process_time()
        if state["line"] != -1:
            acc[state["line"]] += t - state["t"]
        state["line"], state["t"] = line, time.process_time()

    original = getattr(mod, name)
    mod.__dict__["__lap"] = lap
    exec(compile(tree, mod.__file__, "exec"), mod.__dict__)  # the lapped function in the module's namespace
    least: dict = {}
    digest = hashlib.sha256()
    try:
        with threadpool_limits(limits=1, user_api="blas"):  # as the frame loop runs: BLAS on one thread
            for rep in range(args.repeat):
                run.forget()
                for n, (a, kw) in enumerate(calls):
                    acc.clear()
                    state["line"] = -1
                    hs, report = R.respond(*a, **kw)
                    for line, t in acc.items():
                        least[n, line] = min(least.get((n, line), float("inf")), t)
                    if rep == 0:
                        for x in RC.surface_arrays(hs, report):
                            digest.update(x.tobytes())
    finally:
        setattr(mod, name, original)
        del mod.__dict__["__lap"]
    per: dict = collections.defaultdict(float)
    for (n, line), t in least.items():
        if args.calls is None or n in args.calls:
            per[line] += t
    lines = src.splitlines()
    nframes = 5
    print(f"{args.function}: {1e3 * sum(per.values()) / nframes:.3f} ms CPU per collision frame in its statements "
          f"(least of {args.repeat} per call, summed); surfaces digest {digest.hexdigest()[:12]}")
    for line, t in sorted(per.items(), key=lambda x: -x[1])[: args.top]:
        print(f"{1e3 * t / nframes:7.3f} ms  {lines[line - 1].strip()[:100]}")


if __name__ == "__main__":
    main()
