"""`acra bench`: the Fig. 5.2 table is measured stage by stage and the targets are judged."""

from pathlib import Path

import numpy as np
import pytest

from pipeline import bench as B
from pipeline.cli import main

BOX = Path(__file__).resolve().parents[1] / "scenes" / "box_into_sheet.py"


def test_bench_splits_every_stage_over_collision_and_free_frames():
    b = B.run_bench(BOX, repeat=1)
    # the box scene: frames 11-16 collide, and 12-16 hold frame 11 (the box stays): their own line
    assert (b.n_collision, b.n_free, b.holds[0]) == (1, 10, 5)
    assert 0 <= b.holds[1] < b.frame_ms[0]
    assert set(B.THESIS) <= set(b.rows)
    for stage, (c, f) in b.rows.items():
        assert np.isfinite(c) and np.isfinite(f) and c >= 0 and f >= 0, stage
    # a free frame never converts or responds; the sheet is the only deformable (large = small)
    assert b.rows["conversion"][1] == 0 and b.rows["response, large"][1] == 0
    assert b.rows["response, large"][0] > 0 and b.large == b.small == "/World/Sheet"
    assert b.frame_ms[0] > b.frame_ms[1] > 0 and b.end_to_end_s > 0 and b.end_to_end_usdc_s > 0
    # the same results written as .usdc too: only the writing differs between the two frame times
    # (one run, so one write time per frame kind and medians shift by it exactly)
    write, write_usdc = b.rows["USD writing"], b.rows["USD writing, .usdc"]
    assert all(np.isfinite(write_usdc)) and min(write_usdc) > 0
    assert b.frame_ms_usdc[1] - write_usdc[1] == pytest.approx(b.frame_ms[1] - write[1], rel=1e-9, abs=1e-9)
    assert b.residual_rel <= 1e-3
    # the process's first run is its own line: the one collision frame's loop in each run, and the
    # medians (one later run) are that run's frame loop plus its write
    assert set(b.per_frame) == {11} and all(ms > 0 for ms in b.per_frame[11])
    assert b.frame_ms[0] - write[0] == pytest.approx(b.per_frame[11][1], rel=1e-9)
    assert np.isfinite(b.first_in_process).all() and b.first_in_process[0] > b.first_in_process[1] > 0
    text = B.format_report(b)
    assert "The process's first run, left out of the medians above" in text
    assert f"| 11 | {b.per_frame[11][0]:.1f} | {b.per_frame[11][1]:.1f} |" in text
    assert "| collision frame, the process's first run | " in text
    assert "medians over 1 cold runs after the process's first" in text
    assert "| detection |" in text and "30: 16" in text and "end to end" in text
    assert "free frame, `-o NAME.usdc`" in text and "end to end, `-o NAME.usdc`" in text
    assert "Holds, left out of both kinds: 5 frames" in text and "(1 collision frame, 10 free frames)" in text


def test_bench_times_a_first_run_with_an_empty_numba_cache(monkeypatch, tiny_stage):
    """The first run after a fresh install: one `acra run` whose numba cache directory is empty.
    On a stage whose box stays above the sheet (free frames only, so the fresh process compiles
    only a free frame's kernels), where the collision frames' figures are not measured."""
    free_only = tiny_stage(frames=3, depth=-1.0)
    seen = []
    real = B.subprocess.run

    def run(cmd, **kw):
        seen.append(kw.get("env", {}).get("NUMBA_CACHE_DIR"))
        if seen[-1] is not None:
            assert Path(seen[-1]).is_dir() and not any(Path(seen[-1]).iterdir())  # empty when it starts
        return real(cmd, **kw)

    monkeypatch.setattr(B.subprocess, "run", run)
    b = B.run_bench(free_only, repeat=1, first_run=True)
    assert sum(d is not None for d in seen) == 1 and seen[-1] is not None  # the last process, alone
    wall, cpu = b.first_run
    assert wall > 0 and cpu > 0
    text = B.format_report(b)
    assert "First run after a fresh install" in text
    assert (b.n_collision, b.n_free) == (0, 3) and "nan" not in text
    assert "| collision frame | — | ≤ 10 ms | not measured: no collision frame in this scene |" in text
    assert "| collision frame, the process's first run | — | ≤ 10 ms | not measured: no collision frame in this scene |" in text
    assert "Each collision frame's frame loop" not in text
    assert "| free frame | " in text and "| free frame | — " not in text
    assert B.run_bench(free_only, repeat=1).first_run is None


def test_bench_rejects_a_bad_repeat(capsys):
    assert main(["bench", str(BOX), "--repeat", "0"]) == 2
    assert "--repeat" in capsys.readouterr().err


def test_bench_charges_collision_frames_what_they_add_to_the_run_write(monkeypatch, tmp_path):
    """A free frame's write is the free frames' layer over their count; a collision frame's is a
    layer of the collision frames with the free frames around them less a layer of those free
    frames alone, over the collision frames' count, in CPU time, given in wall clock at the
    writes' ratio (never below one over the threads a frame may use); holds are in neither. Fake
    clocks make each write cost exactly a layer's fixed 7 ms CPU, 11 ms for its first frame's
    whole display, then 2 ms a free frame and 5 ms a collision frame after it (each collision
    frame adds 5 ms CPU), the wall clock running 1.5 times as fast (a loaded machine), 0.8 or 0.3
    times (a write on two threads; one thread's wall clock cannot run slower than its CPU clock,
    nor two threads' slower than half of it)."""
    from types import SimpleNamespace as NS

    from pipeline import workers

    kinds = {0: False, 1: False, 2: True, 3: True, 4: False, 5: True, 6: False, 7: False}  # frame -> in collision
    stats = [NS(frame=f, in_collision=c, hold=False) for f, c in kinds.items()]
    stats.append(NS(frame=8, in_collision=True, hold=True))  # a hold: written in neither layer
    report = NS(stats=stats, result=NS(frames={s.frame: object() for s in stats}, topologies={}), stage_path="in.usda", scene=None)
    # (threads a frame may use, the wall clock's pace against the CPU clock's, what a collision frame is charged)
    for threads, pace, charged in ((2, 1.5, 5 * 1.5), (2, 0.8, 5 * 0.8), (2, 0.3, 5 * 0.5), (1, 0.8, 5)):
        monkeypatch.setattr(workers, "threads", lambda threads=threads: threads)
        wall, cpu, written = [0.0], [0.0], []

        def write_output(stage_path, path, scene, part):
            frames = sorted(part.frames)
            written.append(tuple(frames))
            cost = 1e-3 * (7 + 11 + sum(5 if kinds[f] else 2 for f in frames[1:]))
            cpu[0] += cost
            wall[0] += pace * cost
            Path(path).write_text("layer")

        fake = NS(FramesResult=lambda frames, topologies: NS(frames=frames), write_output=write_output)
        monkeypatch.setattr(B.time, "perf_counter", lambda: wall[0])
        monkeypatch.setattr(B.time, "process_time", lambda: cpu[0])
        out = B._writes(fake, report, tmp_path)
        # the layers: the free frames; the free frames around a collision frame (1, 4, 6), with the collision frames
        assert set(written) == {(0, 1, 4, 6, 7), (1, 4, 6), (1, 2, 3, 4, 5, 6)}
        assert len(written) == 2 * 3 * (B.WRITES + 1)
        for fmt in ("usda", "usdc"):
            assert out[1, fmt] == pytest.approx(pace * (7 + 11 + 4 * 2) / 5, abs=1e-12)  # wall clock
            assert out[0, fmt] == pytest.approx(charged, abs=1e-12)  # what each collision frame adds
        assert not any(tmp_path.iterdir())  # every layer removed after its write
    only_free = NS(**{**vars(report), "stats": [s for s in stats if not s.in_collision]})
    out = B._writes(fake, only_free, tmp_path)
    assert np.isnan(out[0, "usda"]) and out[1, "usda"] == pytest.approx(0.8 * (7 + 11 + 4 * 2) / 5, abs=1e-12)
