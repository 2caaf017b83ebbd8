"""pipeline.run: `forget`, which drops what runs keep across frames, and a run's own memo."""

import sys

from acra import memo
from pipeline import frames as F
from pipeline import run, usdio


def _containers() -> dict:
    """Every module-level dict, set and list of the loaded acra and pipeline modules."""
    out = {}
    for name, mod in list(sys.modules.items()):
        if name.split(".")[0] in ("acra", "pipeline"):
            for key, value in vars(mod).items():
                if isinstance(value, (dict, set, list)) and not key.startswith("__"):
                    out[name, key] = value
    return out


def _sizes() -> dict:
    """The number of entries of each table of the current memo."""
    return {name: len(entries) for name, entries in memo.current().tables.items()}


def test_forget_empties_every_table_a_run_fills(tiny_stage):
    """Frames keep answers by content across frames (shapes, detection's answers, ...) in the
    current memo's tables, and in no module-level container; after `forget` no table holds
    anything, so a repeated run in one process is not served what the one before it computed."""
    stage = usdio.open_input(tiny_stage(frames=4, n=7, levels=3, depth=0.15, samples=2))
    scene = usdio.read_scene(stage)
    F.run_frames(stage, scene, [1])  # every module a run imports, imported
    run.forget()
    containers = {k: len(v) for k, v in _containers().items()}
    F.run_frames(stage, scene, [1, 2, 3, 4])
    grown = {k for k, n in _sizes().items() if n}
    assert {"detect.answers", "shape.shapes", "contact.at", "display.topologies"} <= grown  # the run kept answers
    assert {k for k, v in _containers().items() if len(v) > containers.get(k, 0)} == set()  # in the memo alone
    run.forget()
    assert not any(_sizes().values())


def test_run_file_keeps_its_answers_in_its_own_memo(tiny_stage, tmp_path, monkeypatch):
    """`run_file` computes in a memo of its own: the context's tables are as they were after it,
    and what it kept is dropped with it."""
    stage_path = tiny_stage(frames=3, n=7, levels=3, depth=0.15, samples=2)
    run.forget()
    before = memo.current()
    seen = []
    frames = F.run_frames

    def spy(*args, **kwargs):
        seen.append(memo.current())
        return frames(*args, **kwargs)

    monkeypatch.setattr(F, "run_frames", spy)
    run.run_file(stage_path, tmp_path / "out.usda", over_tolerance="warn")
    assert len(seen) == 1 and seen[0] is not before
    assert {k for k, n in _sizes().items() if n} == set() and memo.current() is before
    assert {"detect.answers", "shape.shapes"} <= {k for k, e in seen[0].tables.items() if e}
