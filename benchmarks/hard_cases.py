"""The figures of docs/hard-cases.md's results table: every hard case's residuals and moves.

    python3 benchmarks/hard_cases.py            # every case, xfails included (--runxfail)
    python3 benchmarks/hard_cases.py -k pole    # pytest's -k selection

Runs `tests/test_hard_cases.py` under pytest with `check` wrapped, and prints per test the
largest residual the frame loop reported and the largest the test measured (fractions of the
deformable's size), the largest display-point move over its bound ``2 d + tol · size``, the
outcome and the test's wall time. Tests that assert without `check` (a documented remainder,
exact equalities) show only their outcome and time. For a box collider (`box_case`) the column
"between samples" is the responded surface's largest depth in the box on a grid of `FINE` steps
per level-0 patch edge, 8 times detection's: what the frame loop cannot see (docs/hard-cases.md,
Known limits).
"""

from __future__ import annotations

import pathlib
import sys
import time

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]  # the independent measure (acceptance/) and the tests
import test_hard_cases as T  # noqa: E402  (the tests' own helpers, imported once and shared with pytest)

ROWS: dict = {}
_check = T.check
_box_case = T.box_case
FINE = 64  # steps per level-0 patch edge of the "between samples" measure


def _recording(r, path, depth, size, residual, tol=T.TOL):
    """`check`, recording what it is about to assert for the running test."""
    row = ROWS.setdefault(_Plugin.current, {"reported": 0.0, "measured": 0.0, "moved": 0.0})
    for st in r.stats:
        fr = r.frames[path][st.frame]
        bound = 2.0 * depth[st.frame] + tol * size
        row["moved"] = max(row["moved"], float(np.linalg.norm(fr.p_out - fr.p_in, axis=1).max() / bound))
        row["reported"] = max(row["reported"], float(st.residual_rel))
        row["measured"] = max(row["measured"], float(residual[st.frame] / size))
    return _check(r, path, depth, size, residual, tol)


def _box_recording(r, path, box, size, along=None, tol=T.TOL):
    """`box_case`, also recording the largest depth in the box on a `FINE`-step grid."""
    row = ROWS.setdefault(_Plugin.current, {"reported": 0.0, "measured": 0.0, "moved": 0.0})
    for st in r.stats:
        fr = r.frames[path][st.frame]
        lo, hi = T.box_bounds(r.src, box, st.frame)
        deep = float(T.box_depth(fr.world(fr.hs_out, FINE), lo, hi).max() / size)
        row["between"] = max(row.get("between", 0.0), deep)
    return _box_case(r, path, box, size, along, tol)


class _Plugin:
    current = ""

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(self, item, nextitem):
        """Name the running test (its module fixtures' runs count for it) and time all its phases."""
        _Plugin.current = item.name
        t = time.perf_counter()
        yield
        ROWS.setdefault(item.name, {})["seconds"] = time.perf_counter() - t

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_makereport(self, item, call):
        yield
        if call.when == "call":
            expected = " (an expected failure)" if item.get_closest_marker("xfail") else ""
            ROWS.setdefault(item.name, {})["outcome"] = ("failed" + expected) if call.excinfo else "passed"


def main() -> None:
    T.check, T.box_case = _recording, _box_recording
    args = [str(ROOT / "tests" / "test_hard_cases.py"), "--runxfail", "-q", "-p", "no:cacheprovider", *sys.argv[1:]]
    pytest.main(args, plugins=[_Plugin()])
    print(f"\n| test | outcome | residual reported | residual measured | between samples ({FINE} steps) | moved / bound | s |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for name, row in ROWS.items():
        figs = [f"{row[k]:.2e}" if k in row else "—" for k in ("reported", "measured", "between")]
        moved = f"{row['moved']:.2f}" if "moved" in row else "—"
        print(f"| `{name}` | {row.get('outcome', '?')} | {figs[0]} | {figs[1]} | {figs[2]} | {moved} | {row.get('seconds', 0):.1f} |")


if __name__ == "__main__":
    main()
