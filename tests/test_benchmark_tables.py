"""The speed-vs-error and scale-curve benchmarks' own parts that need no run: the tables they
generate, the before/after ratios, the goal check, the CPU clock and the pages' generated blocks
(benchmarks/speed_vs_error.py, benchmarks/scale_curve.py)."""

import importlib.util
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _load(name: str):
    spec = importlib.util.spec_from_file_location(f"{name}_bench", ROOT / "benchmarks" / f"{name}.py")
    mod = sys.modules[spec.name] = importlib.util.module_from_spec(spec)  # dataclasses look it up
    spec.loader.exec_module(mod)
    return mod


SVE = _load("speed_vs_error")
SC = _load("scale_curve")


def row(cap, cpu, tolerance=1e-3, same_as=None, loop=9e-4, ind=8e-4, **kw):
    return SVE.Row("direct", 8, cap, tolerance, ms=cpu, rounds=1.0, loop_max=loop, loop_mean=loop, ref_max=1e-3,
                   ref_mean=1e-3, cpu_ms=cpu, ind_max=ind, ind_mean=ind, rounds_by_frame=[1, 1], within=2, ind_within=2,
                   frames=2, same_as=same_as, **kw)


def test_replace_block_keeps_the_page_around_the_markers():
    page = f"# Title\n\nprose\n\n{SVE.BEGIN}\nold table\n{SVE.END}\n\nmore prose\n"
    new = SVE.replace_block(page, "new table")
    assert new == f"# Title\n\nprose\n\n{SVE.BEGIN}\nnew table\n{SVE.END}\n\nmore prose\n"
    assert SVE.replace_block(new, "new table") == new  # idempotent
    assert SVE.replace_block("no markers", "block") == "block\n"
    assert SC.replace_block(f"a\n{SC.BEGIN}\nx\n{SC.END}\nb", "y") == f"a\n{SC.BEGIN}\ny\n{SC.END}\nb"


@pytest.mark.parametrize("path, begin, end", [("docs/speed-vs-error.md", SVE.BEGIN, SVE.END),
                                              ("docs/scale-curve.md", SC.BEGIN, SC.END)])
def test_the_pages_carry_the_generated_block(path, begin, end):
    """``--markdown`` rewrites what lies between the markers: each page has them once, in order."""
    text = (ROOT / path).read_text(encoding="utf-8")
    assert text.count(begin) == 1 and text.count(end) == 1
    assert text.index(begin) < text.index(end)


def test_before_after_ratios_count_each_distinct_run_once():
    base = [row(1, 200.0), row(2, 300.0), row(3, 300.0, same_as=2)]
    new = [row(1, 100.0), row(2, 150.0, same_as=1), row(3, 150.0, same_as=1)]
    text = SVE.before_after(new, base, "old", "new")
    lines = [ln for ln in text.splitlines() if ln.startswith("| 0.001")]
    assert [ln.split(" | ")[7] for ln in lines] == ["0.50", "0.50", "0.50"]
    assert "150 (= cap 1)" in lines[1] and "300 (= cap 2)" in lines[2]
    # caps 1 and 2 are distinct runs in one checkout or the other; cap 3 repeats a row in both
    assert "over the 2 distinct runs (median 0.50; summed 500 → 250 ms, 0.50)" in text


def test_tables_name_the_frames_where_the_report_is_under_the_independent_measure():
    honest, flattering = row(1, 100.0), row(2, 120.0, under=[14, 16])
    text = SVE.table([honest, flattering, row(3, 120.0, same_as=2)])
    assert "| none |" in text.splitlines()[2] and "| 14, 16 |" in text.splitlines()[3]
    assert "= cap 2 (every frame stopped before its cap)" in text.splitlines()[4]
    sweep = SVE.tolerance_table([honest, row(4, 150.0, tolerance=5e-4, under=[15])])
    assert "| 0.001 | 1, 1 | 1.0 | 100 |" in sweep and "| 0.0005 | 1, 1 | 1.0 | 150 |" in sweep and "| 15 |" in sweep


def _scale_row(scale, density, collision, cpu, free, cpu_free):
    return dict(scale=scale, density=density, ms_total=collision, cpu_ms=cpu, free_ms=free, cpu_free_ms=cpu_free)


def test_goal_table_states_both_ratios_against_the_goal():
    rows = [_scale_row(1, 8, 100.0, 80.0, 1.0, 0.5), _scale_row(4, 4, 110.0, 85.0, 1.1, 0.55),
            _scale_row(16, 2, 140.0, 100.0, 1.6, 0.7), _scale_row(16, 8, 150.0, 130.0, 1.2, 0.74)]
    lines = SC.goal_table(rows).splitlines()
    assert lines[2] == "| collision frame, wall | 100.00 | 140.00 | 1.40 | 150.00 | 1.50 | yes |"
    assert lines[3] == "| collision frame, CPU | 80.00 | 100.00 | 1.25 | 130.00 | 1.62 | no |"
    assert lines[4] == "| free frame, wall | 1.00 | 1.60 | 1.60 | 1.20 | 1.20 | no |"
    assert lines[5] == "| free frame, CPU | 0.50 | 0.70 | 1.40 | 0.74 | 1.48 | yes |"
    assert SC._ratio(1.0, 0.0) == "–"


def test_cpu_clock_reads_process_time_inside_and_wall_time_after():
    wall = time.perf_counter
    with SC.cpu_clock():
        assert time.perf_counter is time.process_time
    assert time.perf_counter is wall
    with pytest.raises(RuntimeError), SC.cpu_clock():
        raise RuntimeError
    assert time.perf_counter is wall
