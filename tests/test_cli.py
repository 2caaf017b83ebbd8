"""`pipeline.cli.main` as a library call and as the process's command (the GC freeze of a program run)."""

import gc
import shutil
import subprocess
import sys
from pathlib import Path

from pxr import Usd

from pipeline.cli import main

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "box_into_sheet.py"


def test_library_calls_leave_the_callers_gc_alone(tmp_path):
    """Only a process that is the command freezes its objects; a test or script calling main() keeps
    collecting its garbage."""
    scene = tmp_path / SCENE.name
    shutil.copy(SCENE, scene)
    before = gc.get_freeze_count()
    assert main(["run", str(scene), "--quiet", "--frames", "1:2"]) == 0
    assert main(["run", str(tmp_path / "missing.usda"), "--quiet"]) == 2
    assert gc.get_freeze_count() == before


def test_program_run_freezes_and_still_runs_exit_handlers(tmp_path):
    """As the command (argv from sys.argv) the run freezes import-time objects and, at the end,
    everything; atexit handlers still run, and the output layer and the recording are complete."""
    from rerun.chunk import RrdReader

    scene = tmp_path / SCENE.name
    shutil.copy(SCENE, scene)
    out, rrd = tmp_path / "box.acra.usda", tmp_path / "box.rrd"
    code = (
        "import atexit, gc, sys\n"
        "atexit.register(lambda: print('atexit frozen', gc.get_freeze_count() > 0, flush=True))\n"
        "from pipeline.cli import main\n"
        f"sys.argv = ['acra', 'run', {str(scene)!r}, '-o', {str(out)!r}, '--rrd', {str(rrd)!r}, '--quiet', '--frames', '1:2']\n"
        "sys.exit(main())\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "atexit frozen True" in done.stdout
    assert "acra: 2 frames" in done.stdout
    stage = Usd.Stage.Open(str(out))
    assert stage.GetPrimAtPath("/World/Sheet").GetAttribute("points").GetTimeSamples() == [1.0, 2.0]
    assert "/world/World/Sheet" in {c.entity_path for c in RrdReader(str(rrd)).stream()}
