"""`pipeline.report`: the over-tolerance rule, the summary, the --report JSON, exit status 3 and
progress that writes no carriage return into a log."""

import io
import json
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pipeline import report
from pipeline.cli import main
from pipeline.frames import FrameStats


def _frame(frame: int, residual_rel: float) -> FrameStats:
    """A collision frame's figures: ``residual_rel`` of the pair's size after one round."""
    return FrameStats(frame, in_collision=True, iterations=1, residual_rel=residual_rel, ms_detect=1.0, ms_respond=2.0,
                      ms_total=3.0)


def test_frames_over_tolerance_lists_frames_above_it_and_unmeasurable_ones():
    stats = [_frame(f, r) for f, r in [(4, 2e-3), (1, 1e-3), (2, 1.0000001e-3), (3, math.nan), (5, math.inf), (6, 0.0)]]
    over = report.frames_over_tolerance(stats, 1e-3)
    assert [f for f, _ in over] == [2, 3, 4, 5]  # exactly at the tolerance passes; NaN never does
    assert over[0] == (2, 1.0000001e-3) and math.isnan(over[1][1])


@settings(max_examples=60, derandomize=True, deadline=None)
@given(st.lists(st.floats(min_value=0.0, max_value=1.0, allow_nan=False), max_size=20),
       st.floats(min_value=1e-9, max_value=1.0))
def test_the_rule_splits_frames_exactly_at_the_tolerance(residuals, tolerance):
    stats = [_frame(i, r) for i, r in enumerate(residuals)]
    over = {f for f, _ in report.frames_over_tolerance(stats, tolerance)}
    assert over == {i for i, r in enumerate(residuals) if r > tolerance}


def test_the_over_tolerance_line_names_frames_and_residuals():
    assert report.over_tolerance_line([(11, 3.1e-3), (12, 1.2e-3)], 1e-3) == \
        "acra: 2 frames over tolerance 1e-03: 11 (3.10e-03), 12 (1.20e-03)"
    many = [(f, 1e-2) for f in range(25)]
    line = report.over_tolerance_line(many, 1e-3)
    assert line.startswith("acra: 25 frames over tolerance") and line.endswith(", and 15 more (see --report)")


def test_write_json_is_atomic_and_leaves_no_temporary_file(tmp_path):
    out = tmp_path / "r.json"
    report.write_json(out, {"a": 1})
    assert json.loads(out.read_text()) == {"a": 1}
    with pytest.raises(ValueError):
        report.write_json(out, {"a": math.nan})  # not JSON: refused, the old file stays
    assert json.loads(out.read_text()) == {"a": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["r.json"]


def test_progress_off_a_terminal_is_plain_lines():
    stream = io.StringIO()
    bar = report.Progress(5, stream=stream, every=3600.0)
    for f in range(10, 15):
        bar.update(f)
    bar.close()
    text = stream.getvalue()
    assert "\r" not in text
    assert text.splitlines() == ["acra: frame 10 done (1/5)", "acra: frame 14 done (5/5)"]


def test_over_tolerance_exits_3_and_lists_frames_and_warn_makes_it_0(tiny_stage, tmp_path, capsys):
    """Issue 18, row 5: a run whose frames stay over tolerance exited 0 with one summary number."""
    src = tiny_stage(n=4, levels=1, depth=0.3)
    out, rep = tmp_path / "out.usdc", tmp_path / "r.json"
    argv = ["run", str(src), "-o", str(out), "--iterations", "1", "--tolerance", "1e-9", "--quiet", "--report", str(rep)]
    assert main(argv) == report.EXIT_OVER_TOLERANCE
    captured = capsys.readouterr()
    assert captured.err.strip().startswith("acra: 1 frame over tolerance 1e-09: 3 (")
    data = json.loads(rep.read_text())
    assert data["status"] == 3 and data["frames"] == 3 and data["tolerance"] == 1e-9
    assert [o["frame"] for o in data["over_tolerance"]] == [3]
    per = {p["frame"]: p for p in data["per_frame"]}
    assert sorted(per) == [1, 2, 3]
    assert per[3]["residual"] == data["over_tolerance"][0]["residual"] == data["largest_residual"] > 1e-9
    assert per[3]["in_collision"] and per[3]["rounds"] == 1 and set(per[3]["ms"]) == {"setup", "detect", "convert", "respond", "visible", "output", "total"}
    assert out.exists()  # the result is written: the status says it is not within tolerance

    assert main(argv + ["--over-tolerance", "warn"]) == 0
    captured = capsys.readouterr()
    assert "1 frame over tolerance" in captured.out and captured.err == ""
    assert json.loads(rep.read_text())["status"] == 0

    assert main(argv[:-2] + ["--tolerance", "1"]) == 0  # within tolerance: nothing listed
    assert "over tolerance" not in capsys.readouterr().out
