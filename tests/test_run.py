"""pipeline.run: `forget`, which drops what runs keep across frames."""

import sys

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


def test_forget_empties_every_store_a_run_fills(tiny_stage):
    """A run fills stores kept by content across frames (shapes, detection's answers, ...);
    after `forget` none holds more than before the run, so a repeated run in one process is not
    served what the one before it computed."""
    stage = usdio.open_input(tiny_stage(frames=4, n=7, levels=3, depth=0.15, samples=2))
    scene = usdio.read_scene(stage)
    F.run_frames(stage, scene, [1])  # every module a run imports, imported
    run.forget()
    before = {k: len(v) for k, v in _containers().items()}
    F.run_frames(stage, scene, [1, 2, 3, 4])
    grown = {k for k, v in _containers().items() if len(v) > before.get(k, 0)}
    assert {("pipeline.detect", "_ANSWERS"), ("pipeline.shape", "_SHAPES")} <= grown  # the run kept answers
    run.forget()
    now = _containers()
    assert {k for k in grown if len(now[k]) > before.get(k, 0)} == set()
