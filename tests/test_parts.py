"""pipeline.parts: records, part files, and what `acra merge` refuses (one line, exit 2, nothing written).

The byte-identity of merged parts with a single-process run is in tests/test_farm.py; here the
shot is rolling_bump (free frames 1-3, collision from frame 4), cheap enough to run per test.
"""

from __future__ import annotations

import os
import runpy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline import cli, parts, usdio
from pipeline.run import run_file
from pipeline.model import InputError

ROOT = Path(__file__).parents[1]


@pytest.fixture(scope="module")
def shot(tmp_path_factory) -> Path:
    stage = runpy.run_path(str(ROOT / "scenes" / "rolling_bump.py"), run_name="acra_scene")["build"]()
    return usdio.export_layer(stage.GetRootLayer(), tmp_path_factory.mktemp("shot") / "shot.usda")


def _part(stage: Path, frames: str, directory: Path, *extra: str) -> None:
    assert cli.main(["run", str(stage), "--frames", frames, "--part", str(directory), "--quiet", *extra]) == 0


def _merge(directory: Path, out: Path, capsys, *extra: str) -> str:
    """Run `acra merge`, expecting a refusal: returns its one stderr line; nothing was written."""
    assert cli.main(["merge", str(directory), "-o", str(out), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("acra: error: ")
    assert not out.exists() and not [p for p in out.parent.iterdir() if p.name.startswith(f".{out.name}")]
    return err


def test_frame_spans_exact():
    assert parts.frame_spans([10, 1, 2, 3, 7, 9]) == "1-3, 7, 9-10"
    assert parts.frame_spans([-2, -1, 0]) == "-2-0"
    assert parts.frame_spans([]) == ""


def test_part_is_self_describing(shot, tmp_path):
    _part(shot, "3:5", tmp_path)
    (path,) = tmp_path.iterdir()
    assert path.name == "shot.000003_000005.acrapart.npz"
    p = parts.read_part(path)
    assert p.meta["input"] == str(shot.resolve())
    assert p.meta["identity"] == parts.input_identity(usdio.open_input(shot))
    assert p.meta["frames"] == [3, 4, 5] and p.meta["deformables"] == ["/World/Sheet"]
    assert p.meta["options"] == {"iterations": 4, "tolerance": 1e-3, "method": "direct", "density": 8}
    assert list(p.stats["frame"]) == [3, 4, 5] and list(p.stats["in_collision"]) == [False, True, True]
    r = p.records[4]["/World/Sheet"]
    assert set(r) == set(parts.RECORD_FIELDS)
    assert r["offsets"].shape[0] > 0 and r["offsets"].dtype == np.float64  # a responded frame carries its hierarchy


def test_records_round_trip_through_assemble_exactly(shot):
    report = run_file(shot, shot.parent / "round.usda", "4:5")
    records = parts.records_from_result(report.result)
    again = parts.records_from_result(parts.assemble(report.scene, records))
    for f in records:
        for path, r in records[f].items():
            for name, a in r.items():
                np.testing.assert_array_equal(again[f][path][name], a)
                assert again[f][path][name].dtype == a.dtype


def test_merge_refuses_overlapping_frames(shot, tmp_path, capsys):
    _part(shot, "1:3", tmp_path / "p")
    _part(shot, "2:5", tmp_path / "p")
    err = _merge(tmp_path / "p", tmp_path / "out.usda", capsys, "--frames", "1:5")
    assert err.endswith("shot.000002_000005.acrapart.npz: frames 2-3 are also in shot.000001_000003.acrapart.npz")


def test_merge_refuses_missing_frames(shot, tmp_path, capsys):
    _part(shot, "1:1", tmp_path / "p")
    _part(shot, "4:4", tmp_path / "p")
    err = _merge(tmp_path / "p", tmp_path / "out.usda", capsys, "--frames", "1:5")
    assert err == f"acra: error: {tmp_path / 'p'}: frames 2-3, 5 are missing: no part holds them"
    # without --frames the stage's whole range is expected
    assert _merge(tmp_path / "p", tmp_path / "out.usda", capsys).endswith("frames 2-3, 5-11 are missing: no part holds them")
    assert _merge(tmp_path / "p", tmp_path / "out.usda", capsys, "--frames", "1:3").endswith("frame 4 is outside the expected 1:3")


def test_merge_refuses_parts_of_different_inputs(shot, tmp_path, capsys):
    other = tmp_path / "other.usda"
    other.write_text(shot.read_text() + "\n")  # another file, other bytes: another identity
    _part(shot, "1:2", tmp_path / "p")
    _part(other, "3:4", tmp_path / "p")
    err = _merge(tmp_path / "p", tmp_path / "out.usda", capsys, "--frames", "1:4")
    assert "parts of different inputs" in err and str(other.resolve()) in err and str(shot.resolve()) in err


def test_merge_refuses_parts_of_different_options(shot, tmp_path, capsys):
    _part(shot, "1:2", tmp_path / "p")
    _part(shot, "3:4", tmp_path / "p", "--tolerance", "0.002")
    assert "parts of different options" in _merge(tmp_path / "p", tmp_path / "out.usda", capsys, "--frames", "1:4")


def test_merge_refuses_an_output_that_is_an_input_layer(shot, tmp_path, capsys):
    _part(shot, "1:2", tmp_path / "p")
    before = shot.read_bytes()
    assert cli.main(["merge", str(tmp_path / "p"), "-o", str(shot), "--frames", "1:2"]) == 2
    assert capsys.readouterr().err.strip() == f"acra: error: {shot}: is a layer the input {shot.resolve()} uses: refusing to overwrite it"
    assert shot.read_bytes() == before


def test_merge_refuses_an_input_changed_since_the_parts(shot, tmp_path, capsys):
    copy = tmp_path / "copy.usda"
    copy.write_bytes(shot.read_bytes())
    _part(copy, "1:2", tmp_path / "p")
    copy.write_text(copy.read_text() + "\n")
    assert "changed since the parts were written" in _merge(tmp_path / "p", tmp_path / "out.usda", capsys, "--frames", "1:2")


def test_merge_refuses_empty_directories_and_broken_parts(tmp_path, capsys):
    (tmp_path / "p").mkdir()
    assert _merge(tmp_path / "p", tmp_path / "out.usda", capsys).endswith("holds no ACRA parts (*.acrapart.npz)")
    (tmp_path / "p" / "x.acrapart.npz").write_bytes(b"not a zip")
    assert f"{tmp_path / 'p' / 'x.acrapart.npz'}: not a readable ACRA part" in _merge(tmp_path / "p", tmp_path / "out.usda", capsys)
    np.savez(tmp_path / "p" / "x.acrapart.npz", meta=np.array(f'{{"format": "{parts.PART_FORMAT}"}}'))
    assert "incomplete ACRA part" in _merge(tmp_path / "p", tmp_path / "out.usda", capsys)
    np.savez(tmp_path / "p" / "x.acrapart.npz", meta=np.array('{"format": "acra-part/1"}'))  # before holds were kept
    assert "part format 'acra-part/1', expected 'acra-part/2'" in _merge(tmp_path / "p", tmp_path / "out.usda", capsys)


def test_part_and_output_together_are_refused(shot, tmp_path, capsys):
    assert cli.main(["run", str(shot), "--part", str(tmp_path / "p"), "-o", str(tmp_path / "o.usda")]) == 2
    assert capsys.readouterr().err.strip().startswith("acra: error: --part: writes a part file, not an output layer")
    assert not (tmp_path / "p").exists()


def test_merge_command_line_exit_status_and_one_line(shot, tmp_path):
    _part(shot, "1:2", tmp_path / "p")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    cmd = [sys.executable, "-m", "pipeline.cli", "merge", str(tmp_path / "p"), "-o", str(tmp_path / "out.usda")]
    refused = subprocess.run(cmd, env=env, capture_output=True, text=True)
    assert refused.returncode == 2 and refused.stderr.strip().endswith("frames 3-11 are missing: no part holds them")
    done = subprocess.run(cmd + ["--frames", "1:2"], env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("acra: 2 frames, 0 in collision;") and (tmp_path / "out.usda").is_file()
    with pytest.raises(InputError):
        parts.read_part(tmp_path / "out.usda")
