"""`pipeline.guard`: outputs that are inputs are refused before anything is read or written; memory is
predicted from the inputs and a run over the budget is refused with one line; singular transforms
are named; SIGTERM unwinds like Ctrl-C."""

import os
import signal
import shutil
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom, Vt

from pipeline import guard
from pipeline.cli import main
from pipeline.run import run_file
from pipeline.model import InputError

SCENES = Path(__file__).resolve().parents[1] / "scenes"


def _run(argv, capsys):
    code = main(argv)
    err = capsys.readouterr().err
    return code, err


def _one_error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert lines[0].startswith("acra: error: ") and "Traceback" not in err
    return lines[0]


def _no_temporaries(directory: Path) -> None:
    assert not [p.name for p in directory.iterdir() if ".tmp" in p.name]


# --- paths -------------------------------------------------------------------------------------


def test_same_file_sees_through_links_dots_and_relative_paths(tmp_path, monkeypatch):
    a = tmp_path / "a.usda"
    a.write_text("#usda 1.0\n")
    (tmp_path / "sub").mkdir()
    (tmp_path / "link.usda").symlink_to(a)
    os.link(a, tmp_path / "hard.usda")
    monkeypatch.chdir(tmp_path / "sub")
    assert guard.same_file("../a.usda", a)
    assert guard.same_file(tmp_path / "sub" / ".." / "a.usda", a)
    assert guard.same_file(tmp_path / "link.usda", a)
    assert guard.same_file(tmp_path / "hard.usda", a)
    assert not guard.same_file(tmp_path / "b.usda", a)
    assert guard.same_file(tmp_path / "new.usda", "../new.usda")  # neither exists: real paths


def test_same_file_follows_the_file_systems_case_rule(tmp_path):
    a = tmp_path / "Shot.usda"
    a.write_text("#usda 1.0\n")
    insensitive = (tmp_path / "SHOT.usda").exists()
    assert guard.same_file(tmp_path / "SHOT.usda", a) == insensitive


@pytest.mark.parametrize("option", ["-o", "--rrd", "--report"])
def test_an_output_that_is_the_input_is_refused_and_the_input_is_intact(tiny_stage, tmp_path, capsys, option):
    """Issue 18, row 1: `acra run shot.usda -o shot.usda` overwrote the animator's stage."""
    src = tiny_stage()
    before = src.read_bytes()
    argv = ["run", str(src), "--quiet"]
    argv += [option, str(src)] if option == "-o" else ["-o", str(tmp_path / "out.usda"), option, str(src)]
    code, err = _run(argv, capsys)
    assert code == 2
    line = _one_error_line(err)
    assert f"{option}: " in line and "is the input" in line
    assert src.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == [src.name]


def test_relative_symlinked_and_dotted_spellings_of_the_input_are_refused(tiny_stage, tmp_path, capsys, monkeypatch):
    src = tiny_stage()
    before = src.read_bytes()
    (tmp_path / "d").mkdir()
    (tmp_path / "alias.usda").symlink_to(src)
    monkeypatch.chdir(tmp_path / "d")
    for out in ("../tiny.usda", str(tmp_path / "d" / ".." / "tiny.usda"), str(tmp_path / "alias.usda")):
        code, err = _run(["run", "../tiny.usda", "-o", out, "--quiet"], capsys)
        assert code == 2 and "-o: " in _one_error_line(err), out
    assert src.read_bytes() == before


def _with_layers(tiny_stage, tmp_path):
    """A shot that sublayers the tiny stage and references a prop layer: (shot, base, prop)."""
    base = tiny_stage("base.usda")
    prop = tmp_path / "prop.usda"
    layer = Sdf.Layer.CreateNew(str(prop))
    Sdf.CreatePrimInLayer(layer, "/Prop").specifier = Sdf.SpecifierDef
    layer.defaultPrim = "Prop"
    layer.Save()
    shot = tmp_path / "shot.usda"
    stage = Usd.Stage.CreateNew(str(shot))
    stage.GetRootLayer().subLayerPaths.append("./base.usda")
    stage.DefinePrim("/World/Prop").GetReferences().AddReference("./prop.usda")
    stage.GetRootLayer().Save()
    return shot, base, prop


@pytest.mark.parametrize("victim", ["base", "prop"])
def test_sublayers_and_references_of_the_input_are_refused(tiny_stage, tmp_path, capsys, victim):
    shot, base, prop = _with_layers(tiny_stage, tmp_path)
    target = {"base": base, "prop": prop}[victim]
    files = {p: p.read_bytes() for p in (shot, base, prop)}
    code, err = _run(["run", str(shot), "-o", str(target), "--quiet"], capsys)
    assert code == 2
    assert "a file the run reads (" in _one_error_line(err)
    assert {p: p.read_bytes() for p in files} == files
    assert guard.same_file(target, [p for p in guard.protected_paths(shot) if guard.same_file(p, target)][0])


def test_a_scene_file_and_the_stage_it_exports_are_refused(tmp_path, capsys):
    scene = tmp_path / "box_into_sheet.py"
    shutil.copy(SCENES / scene.name, scene)
    code, err = _run(["run", str(scene), "-o", str(scene), "--quiet"], capsys)
    assert code == 2 and "is the input" in _one_error_line(err)
    code, err = _run(["run", str(scene), "-o", str(scene.with_suffix(".usda")), "--quiet"], capsys)
    assert code == 2 and "a file the run reads (" in _one_error_line(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == [scene.name]  # refused before the export


def test_a_scene_files_export_is_walked_once_and_opened_on_the_walked_layers(tmp_path, monkeypatch):
    """A scene file's build rewrites its .usda, so its layers are walked once, after the build;
    the stage then opens on the layers that walk loaded (held, not parsed a second time)."""
    from pxr import UsdUtils

    from pipeline import usdio

    scene = tmp_path / "box_into_sheet.py"
    shutil.copy(SCENES / scene.name, scene)
    walked, loaded_at_open = [], []
    walk, open_input = UsdUtils.ComputeAllDependencies, usdio.open_input
    monkeypatch.setattr(UsdUtils, "ComputeAllDependencies", lambda path: walked.append(path) or walk(path))

    def opened(path):
        loaded_at_open.append(Sdf.Layer.Find(str(Path(path).resolve())) is not None)
        return open_input(path)

    monkeypatch.setattr(usdio, "open_input", opened)
    run_file(scene, tmp_path / "out.usdc", frames="0:1", progress=False, over_tolerance="warn")
    run_file(scene, tmp_path / "out.usdc", frames="0:1", progress=False, over_tolerance="warn")  # its .usda now exists
    assert [Path(p).name for p in walked] == ["box_into_sheet.usda"] * 2
    assert loaded_at_open == [True, True]


def test_a_scene_files_export_opens_on_its_content_copied_not_parsed(tmp_path):
    """The layer the stage of a scene file opens on holds the build's layer copied in memory
    (`usdio._written_layer`): the exported .usda is not parsed back, and its text reads back to
    the same content; a second load refreshes that open layer with the new build's content."""
    from pipeline import usdio

    scene = tmp_path / "box_into_sheet.py"
    shutil.copy(SCENES / scene.name, scene)
    held: list = []
    path = usdio.load_scene_file(scene, held)
    layer = Sdf.Layer.Find(str(path.resolve()))
    assert held == [layer] and layer.dirty  # in memory: USD never read the file for it
    stage = usdio.open_input(path)
    assert stage.GetRootLayer() == layer
    assert Sdf.Layer.OpenAsAnonymous(str(path)).ExportToString() == layer.ExportToString()
    scene.write_text(scene.read_text().replace("def build(", "def _unused(", 1) + "\n\ndef build():\n"
                     "    stage = _unused()\n    stage.SetEndTimeCode(stage.GetEndTimeCode() + 1)\n    return stage\n")
    usdio.load_scene_file(scene, held)
    assert usdio.open_input(path).GetEndTimeCode() == stage.GetEndTimeCode() == Sdf.Layer.OpenAsAnonymous(str(path)).endTimeCode


def test_two_outputs_on_one_file_are_refused(tiny_stage, tmp_path, capsys):
    src = tiny_stage()
    out = tmp_path / "out.usda"
    code, err = _run(["run", str(src), "-o", str(out), "--rrd", str(out), "--quiet"], capsys)
    assert code == 2 and "also the -o file" in _one_error_line(err)
    assert not out.exists()


# --- memory ------------------------------------------------------------------------------------


def _set(src: Path, dst: Path, levels=None, **attrs) -> Path:
    stage = Usd.Stage.Open(str(src))
    prim = stage.GetPrimAtPath("/World/Sheet")
    if levels is not None:
        prim.GetAttribute("acra:levels").Set(levels)
        prim.GetAttribute("acra:absorption").Set(Vt.FloatArray([0.0] * (levels - 1) + [1.0]))
        for name, share in (("deform", 1.0), ("translate", 0.0), ("rotate", 0.0)):
            prim.GetAttribute(f"acra:{name}").Set(Vt.FloatArray([share] * levels))
    for name, value in attrs.items():
        prim.GetAttribute(f"acra:{name}").Set(value)
    stage.GetRootLayer().Export(str(dst))
    return dst


@pytest.mark.parametrize("levels, samples, attribute, size", [
    (40, None, "acra:levels", "64-bit keys"),  # issue 18: an OverflowError traceback
    (12, None, "acra:levels", "TB"),  # issue 18: killed by the kernel at 24 GB
    (None, 100000, "acra:samples", "TB display mesh"),  # issue 18: a 5.9 TiB MemoryError
])
def test_oversized_objects_are_refused_before_allocation(tmp_path, capsys, levels, samples, attribute, size):
    src = _set(_box_stage(tmp_path), tmp_path / "big.usda", levels=levels, **({"samples": samples} if samples else {}))
    before = src.read_bytes()
    tracemalloc.start()
    code, err = _run(["run", str(src), "-o", str(tmp_path / "out.usda"), "--quiet"], capsys)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert code == 2
    line = _one_error_line(err)
    assert line.startswith(f"acra: error: /World/Sheet.{attribute}: ") and size in line and "memory budget" in line
    assert peak < 50 * 2**20  # refused from attribute values: nothing large was built
    assert src.read_bytes() == before and not (tmp_path / "out.usda").exists()


_BOX = {}


def _box_stage(tmp_path: Path) -> Path:
    """scenes/box_into_sheet.py exported once per test (12x12 sheet, 3 levels, 16 frames)."""
    from pipeline import usdio

    scene = tmp_path / "box_into_sheet.py"
    shutil.copy(SCENES / scene.name, scene)
    return usdio.load_scene_file(scene)


def test_prediction_counts_the_cvs_of_every_level_the_response_may_refine():
    """12 x 12 open sheet: 9 x 9 patches; level k refined everywhere has (9 * 2^k + 3)^2 CVs."""
    parts = guard.predict_deformable("/S", 12, 12, False, False, 3, [0.2, 0.3, 0.5], True, 4, [], 16)
    cvs = {p[1]: p for p in parts}["acra:levels"]
    assert cvs[2] == (21**2 + 39**2) * guard.BYTES_PER_CV
    obey = guard.predict_deformable("/S", 12, 12, False, False, 3, [0.2, 0.3, 0.5], False, 4, [2, 2], 16)
    assert {p[1]: p for p in obey}["acra:hierarchy:patchLevel"][2] == 32 * guard.BYTES_PER_CV
    display = {p[1]: p for p in parts}["acra:samples"]
    assert "1,369 vertices" in display[3]  # (9 * 4 + 1)^2
    periodic = guard.predict_deformable("/S", 8, 6, True, False, 1, [1.0], True, 2, [], 1)
    assert "112 vertices" in {p[1]: p for p in periodic}["acra:samples"][3]  # (8 * 2) x (3 * 2 + 1)


def test_forty_levels_are_refused_without_overflow():
    parts = guard.predict_deformable("/S", 12, 12, False, False, 40, [0.0] * 39 + [1.0], True, 4, [], 16)
    assert parts[0][1] == "acra:levels" and parts[0][2] == float("inf")
    est = guard.Estimate(float("inf"), parts)
    with pytest.raises(InputError, match=r"^/S\.acra:levels: 40 levels would need ~2\^\d+ bytes.*; refused whatever the memory budget$"):
        guard.check_budget(est, 2**30)


def test_the_budget_comes_from_the_option_then_the_environment_then_physical_memory(monkeypatch):
    monkeypatch.delenv("ACRA_MEMORY_BUDGET", raising=False)
    assert guard.memory_budget("512M") == 512 * 2**20
    assert guard.memory_budget("1.5G") == 3 * 2**29
    monkeypatch.setenv("ACRA_MEMORY_BUDGET", "2G")
    assert guard.memory_budget() == 2 * 2**30
    assert guard.memory_budget("4G") == 4 * 2**30
    monkeypatch.delenv("ACRA_MEMORY_BUDGET")
    assert guard.memory_budget() == guard.physical_memory() // 2
    for bad in ("", "-1G", "lots", "1Q", "nan"):
        with pytest.raises(InputError, match="--memory-budget"):
            guard.parse_size(bad)


def test_a_small_budget_refuses_an_ordinary_scene(tiny_stage, tmp_path, capsys, monkeypatch):
    src = tiny_stage()
    out = tmp_path / "out.usda"
    code, err = _run(["run", str(src), "-o", str(out), "--quiet", "--memory-budget", "1M"], capsys)
    assert code == 2 and "over the memory budget of ~1 MB" in _one_error_line(err) and not out.exists()
    monkeypatch.setenv("ACRA_MEMORY_BUDGET", "1M")
    code, err = _run(["run", str(src), "-o", str(out), "--quiet"], capsys)
    assert code == 2 and "ACRA_MEMORY_BUDGET" in _one_error_line(err) and not out.exists()
    code, _ = _run(["run", str(src), "-o", str(out), "--quiet", "--memory-budget", "4G"], capsys)
    assert code == 0 and out.exists()


def test_a_response_solve_over_the_budget_is_refused_at_the_solve(tiny_stage, tmp_path, capsys, monkeypatch):
    """A contact's extent, and so the size of its direct solve, is known only once it is found: with
    the prediction passed (here: bypassed), the solve itself refuses to allocate past the budget."""
    src = tiny_stage(n=6, levels=3)  # frame 3's level-2 solve: 61 points on 117 CVs, ~199 kB
    out = tmp_path / "out.usda"
    monkeypatch.setattr(guard, "check_budget", lambda estimate, budget: None)
    code, err = _run(["run", str(src), "-o", str(out), "--quiet", "--memory-budget", "100k"], capsys)
    line = _one_error_line(err)
    assert code == 2 and not out.exists(), err
    assert line == ("acra: error: /World/Sheet.acra:absorption: at frame 3 the response's solve of 61 data points "
                    "on 117 CVs would need ~199 kB, over the memory budget of ~100 kB; absorb on a coarser level or "
                    "raise --memory-budget"), line
    code, _ = _run(["run", str(src), "-o", str(out), "--quiet", "--memory-budget", "200k"], capsys)
    assert code == 0 and out.exists()


def _deep_local_detail(path: Path, levels: int = 12) -> Path:
    """An 8 x 8 sheet with ``levels`` levels whose authored detail is one patch's CVs on the finest
    level (`hspline.make_movable`), absorbing on levels 0 and 1, pressed by the box elsewhere."""
    from acra import hspline, shapes
    from pipeline import authoring

    stage = authoring.new_stage(1, 3, fps=24, up_axis="Z")
    cvs, pu, pv = shapes.sheet(8, 8, width=4.0, depth=4.0)
    k = levels - 1
    hs = hspline.make_movable(hspline.from_grid(cvs, pu, pv, depth=levels), k, np.array([[2**k, 2**k]]))
    idx, off = hspline.offsets_of(hs, k)
    off = np.zeros_like(off)
    off[len(off) // 2, 2] = 1e-4
    hs = hspline.set_offsets(hs, k, idx, off)
    absorption = [0.5, 0.5] + [0.0] * (levels - 2)
    authoring.add_deformable(stage, "/World/Sheet", cvs, levels=levels, absorption=absorption, samples=4, hierarchy=hs)
    verts, faces = authoring.box(1.0)
    mover = authoring.add_xform(stage, "/World/Mover")
    authoring.add_collider(stage, "/World/Mover/Box", verts, faces)
    authoring.key_transform(mover, 1, translate=(0.5, 0.5, 1.0))
    authoring.key_transform(mover, 3, translate=(0.5, 0.5, 0.4))
    return authoring.save(stage, path)


def test_twelve_levels_with_local_detail_run_in_bounded_memory(tmp_path):
    """Issue 18: a 12-level object whose detail is local must run in bounded memory. What is built
    is proportional to the refined area (the patch's 7 x 7 neighbourhood and its ancestors on each
    level), not to a dense finest level: the traced peak of the 12-level run (after a 3-level run
    has done the imports) stays under 32 MB (measured 9.4 MB, 3.8 MB with 3 levels), where level
    11 refined everywhere would be (5 * 2^11 + 3)^2 = 1.05e8 CVs."""
    peaks = {}
    for levels in (3, 12):
        src = _deep_local_detail(tmp_path / f"deep{levels}.usda", levels)
        tracemalloc.start()
        rep = run_file(src, tmp_path / f"out{levels}.usdc")
        peaks[levels] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert [s.frame for s in rep.stats] == [1, 2, 3] and any(s.in_collision for s in rep.stats)
    assert peaks[12] < 32 * 2**20, peaks


# --- transforms and signals ---------------------------------------------------------------------


def _scale_mover(src: Path, dst: Path, frame: int, scale) -> Path:
    stage = Usd.Stage.Open(str(src))
    xf = UsdGeom.Xformable(stage.GetPrimAtPath("/World/Mover"))
    op = xf.AddScaleOp()
    op.Set((1.0, 1.0, 1.0), 1)
    op.Set(tuple(scale), frame)
    op.Set((1.0, 1.0, 1.0), frame + 1)
    stage.GetRootLayer().Export(str(dst))
    return dst


def test_a_collider_scaled_to_zero_at_one_frame_is_named(tiny_stage, tmp_path, capsys):
    """Issue 18, row 5: a collider scaled to 0 at one frame ran with exit 0 and nothing said."""
    src = _scale_mover(tiny_stage(frames=4), tmp_path / "zero.usda", 2, (0.0, 0.0, 0.0))
    code, err = _run(["run", str(src), "-o", str(tmp_path / "out.usda"), "--quiet"], capsys)
    assert code == 2
    line = _one_error_line(err)
    assert line.startswith("acra: error: /World/Mover.xformOp:scale: world transform of /World/Mover/Box is singular at frame 2")
    assert not (tmp_path / "out.usda").exists()
    # frames that skip the singular one run
    assert main(["run", str(src), "-o", str(tmp_path / "out.usda"), "--quiet", "--frames", "3:4"]) == 0


def test_a_mirrored_collider_is_accepted(tiny_stage, tmp_path):
    src = _scale_mover(tiny_stage(frames=3), tmp_path / "mirror.usda", 2, (-1.0, 1.0, 1.0))
    assert main(["run", str(src), "-o", str(tmp_path / "out.usda"), "--quiet"]) == 0


def test_sigterm_raises_inside_the_block_only():
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(guard.Terminated):
        with guard.terminate_raises():
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)  # the handler raises at the next bytecode: the sleep is interrupted
    assert signal.getsignal(signal.SIGTERM) is before


def _raised_inside_a_compiled_call(signal_error: BaseException):
    """What Python raises when a signal's handler raised inside a C call that then returned a result
    (a compiled kernel's wrapper boxing its result): a `SystemError` caused by it."""
    try:
        raise signal_error
    except BaseException as err:
        raise SystemError("CPUDispatcher(<function _depth>) returned a result with an exception set") from err


def test_sigint_is_recorded_and_raises_inside_the_block_only():
    before = signal.getsignal(signal.SIGINT)
    with pytest.raises(KeyboardInterrupt):
        with guard.terminate_raises() as arrived:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(5)
    assert arrived == [signal.SIGINT] and signal.getsignal(signal.SIGINT) is before


def _replaced_by_a_c_call(sig: int) -> tuple[BaseException, list]:
    """What a C call that catches the handler's exception and raises its own error, without a
    cause, leaves (numpy's comparison of two arrays: "cannot compare"), with the block's record."""
    try:
        with guard.terminate_raises() as arrived:
            try:
                os.kill(os.getpid(), sig)
                time.sleep(5)
            except (guard.Terminated, KeyboardInterrupt):
                raise TypeError("Cannot compare structured arrays unless they have a common dtype.") from None
    except TypeError as err:
        err.__context__ = None  # a C call sets neither the cause nor the context
        return err, arrived
    raise AssertionError("the signal raised nothing")


@pytest.mark.parametrize("sig, kind", [(signal.SIGTERM, guard.Terminated), (signal.SIGINT, KeyboardInterrupt)])
def test_an_error_that_replaced_a_signal_is_the_signal_by_the_record(sig, kind):
    err, arrived = _replaced_by_a_c_call(sig)
    assert arrived == [sig]
    assert guard.interruption(err) is None  # nothing in the chain
    found = guard.interruption(err, arrived)
    assert type(found) is kind and (kind is KeyboardInterrupt or found.args == (sig,))
    assert guard.interruption(TypeError("not a signal"), []) is None


def test_the_command_reports_a_signal_an_error_replaced(monkeypatch, tmp_path, capsys):
    """`acra run` ends with 143 and its one line when a C call turned SIGTERM into its own error."""
    import pipeline.cli as cli

    def replaced(args, imports_s=None):
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)
        except guard.Terminated:
            raise TypeError("Cannot compare structured arrays unless they have a common dtype.") from None
        raise AssertionError("the signal raised nothing")

    monkeypatch.setattr(cli, "run", replaced)
    code, err = _run(["run", str(SCENES / "dog_head_spike.py"), "-o", str(tmp_path / "o.usda")], capsys)
    assert code == 143 and err.strip().splitlines() == ["acra: interrupted; nothing written"]
    monkeypatch.setattr(cli, "run", lambda args, imports_s=None: (_ for _ in ()).throw(TypeError("a defect")))
    with pytest.raises(TypeError, match="a defect"):  # an error without a signal is not hidden
        main(["run", str(SCENES / "dog_head_spike.py"), "-o", str(tmp_path / "o.usda")])


class _LosesASignal:
    """Raises SIGTERM while being collected: the handler's exception is reported by the interpreter
    (an "Exception ignored in" line) and dropped."""

    def __del__(self):
        os.kill(os.getpid(), signal.SIGTERM)
        for _ in range(100_000):  # the handler runs at the next check of the interpreter's loop
            pass


def test_a_lost_signal_stops_the_run_between_frames_and_before_the_renames(monkeypatch, tmp_path):
    dropped = []
    monkeypatch.setattr("sys.unraisablehook", lambda u: dropped.append(u.exc_type))
    with guard.terminate_raises() as arrived:
        guard.raise_arrived()  # nothing arrived: nothing raised
        lost = _LosesASignal()
        del lost
        assert dropped == [guard.Terminated] and arrived == [signal.SIGTERM]
        with pytest.raises(guard.Terminated):
            guard.raise_arrived()
        tmp, final = tmp_path / ".o.tmp", tmp_path / "o.usda"
        tmp.write_text("x")
        with pytest.raises(guard.Terminated):
            with guard.signals_held():
                os.replace(tmp, final)
        assert not final.exists() and tmp.exists()
    guard.raise_arrived()  # outside the block: nothing recorded


@pytest.mark.parametrize("signal_error", [guard.Terminated(15), KeyboardInterrupt()])
def test_an_interruption_is_found_behind_the_system_error_it_caused(signal_error):
    with pytest.raises(SystemError) as raised:
        _raised_inside_a_compiled_call(signal_error)
    assert guard.interruption(raised.value) is signal_error
    assert guard.interruption(signal_error) is signal_error
    try:  # an exception raised while handling the signal's (its context, not its cause)
        try:
            raise signal_error
        except BaseException:
            raise RuntimeError("cleanup failed")
    except RuntimeError as err:
        assert guard.interruption(err) is signal_error
    with pytest.raises(SystemError) as raised:
        try:
            raise ValueError("not a signal")
        except ValueError as err:
            raise SystemError("returned a result with an exception set") from err
    assert guard.interruption(raised.value) is None


@pytest.mark.parametrize("signal_error, status", [(guard.Terminated(15), 143), (KeyboardInterrupt(), 130)])
def test_a_signal_raised_inside_a_compiled_call_ends_the_run_as_interrupted(signal_error, status, monkeypatch, capsys,
                                                                           tiny_stage, tmp_path):
    """The command line ends with the signal's status and one line, whether the signal's exception
    arrives as itself or behind the `SystemError` of a compiled call; any other `SystemError` is
    not taken for an interruption."""
    from pipeline import cli

    def interrupted(args, loaded):
        _raised_inside_a_compiled_call(signal_error)

    monkeypatch.setattr(cli, "run", interrupted)
    argv = ["run", str(tiny_stage(frames=2)), "-o", str(tmp_path / "o.usda"), "--quiet"]
    assert main(argv) == status
    assert capsys.readouterr().err.strip().splitlines()[-1] == "acra: interrupted; nothing written"

    def broken(args, loaded):
        raise SystemError("returned a result with an exception set")

    monkeypatch.setattr(cli, "run", broken)
    with pytest.raises(SystemError):
        main(argv)


def test_signals_during_the_final_renames_are_dropped():
    """The run's files are renamed into place together with SIGINT/SIGTERM held: a signal then
    neither interrupts the renames nor is reported afterwards as an interruption."""
    before = signal.getsignal(signal.SIGINT)
    with guard.signals_held():
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)
    assert signal.getsignal(signal.SIGINT) is before
