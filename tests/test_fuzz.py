"""Fuzzing the command line: valid stages mutated (attribute types, counts, values with NaN, inf and
huge numbers, time samples, wraps, levels, hierarchy, collider meshes, transforms that are
singular, mirrored, huge or tiny) and run in-process with `pipeline.cli.main`.

Every run ends in exit 0 or 3 with a finite output layer and a report, or exit 2 with one line
naming a prim (or the file) and the attribute and nothing written; never an uncaught exception,
never a partial or temporary file, and the input's bytes are unchanged. Seeded
(``derandomize=True``) and bounded: 60 examples on a 4x4 sheet and a box over 2 frames (~25 s).
"""

import contextlib
import io
import json
import math
import re
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pxr import Sdf, Usd, UsdGeom, Vt

from pipeline.cli import main

SHEET, BOX, MOVER = "/World/Sheet", "/World/Mover/Box", "/World/Mover"
T = Sdf.ValueTypeNames
WEIRD = [math.nan, math.inf, -math.inf, 1e30, -1e30, 1e-30, 0.0, -1.0, 0.5, 1.0]
INTS = [-1, 0, 1, 2, 3, 4, 5, 7, 13, 40, 100000, 2**31 - 1]
ERROR = re.compile(r"^acra: error: (?P<where>/[^\s:.]*|\S+?\.usda)(?P<attr>\.[A-Za-z][\w:]*)?: \S")


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    from conftest import write_tiny_stage

    return write_tiny_stage(tmp_path_factory.mktemp("fuzz") / "base.usda", frames=2, levels=2, samples=2, depth=0.1)


def _retype(prim, name, tname, value):
    prim.RemoveProperty(name)
    prim.CreateAttribute(name, tname, custom=True).Set(value)


def _mutate(stage: Usd.Stage, m: tuple) -> None:
    """Apply one mutation ``(kind, *args)`` to the stage."""
    sheet, box, mover = (stage.GetPrimAtPath(p) for p in (SHEET, BOX, MOVER))
    kind, *args = m
    if kind == "int":
        name, value = args
        sheet.GetAttribute(name).Set(int(value))
    elif kind == "retype":
        name, tname, value = args
        _retype(sheet, name, tname, value)
    elif kind == "remove":
        sheet.RemoveProperty(args[0])
    elif kind == "token":
        name, value = args
        sheet.GetAttribute(name).Set(value)
    elif kind == "floats":
        name, values = args
        if name == "acra:rigidity":
            sheet.GetAttribute(name).Set(float(values[0]) if values else 0.0)
        else:
            sheet.GetAttribute(name).Set(Vt.FloatArray([float(v) for v in values]))
    elif kind == "cvs":
        how, index, value = args
        cvs = np.array(sheet.GetAttribute("acra:cvs").Get(), dtype=np.float64)
        if how == "truncate":
            cvs = cvs[: index % len(cvs)]
        elif how == "extend":
            cvs = np.concatenate([cvs, cvs[: 1 + index % 5]])
        else:
            cvs[index % len(cvs), index % 3] = value
        sheet.GetAttribute("acra:cvs").Set(Vt.Vec3fArray.FromNumpy(cvs.astype(np.float32)))
    elif kind == "cvs_samples":
        lengths, scale = args
        cvs = np.array(sheet.GetAttribute("acra:cvs").Get(), dtype=np.float64)
        attr = sheet.GetAttribute("acra:cvs")
        for frame, n in zip((1, 2), lengths):
            rows = np.resize(cvs * scale, (n, 3))
            attr.Set(Vt.Vec3fArray.FromNumpy(rows.astype(np.float32)), frame)
    elif kind == "enabled":
        for frame, value in zip((1, 2), args[0]):
            sheet.GetAttribute("acra:enabled").Set(bool(value), frame)
    elif kind == "hierarchy":
        levels, patches = args
        _retype(sheet, "acra:hierarchy:patchLevel", T.IntArray, Vt.IntArray(levels))
        _retype(sheet, "acra:hierarchy:patches", T.Int2Array, Vt.Vec2iArray([tuple(p) for p in patches]))
    elif kind == "xform":
        op, frame, value = args
        xf = UsdGeom.Xformable(mover)
        ops = {o.GetOpName(): o for o in xf.GetOrderedXformOps()}
        if op == "scale":
            target = ops.get("xformOp:scale") or xf.AddScaleOp()
            target.Set(tuple(float(v) for v in value), frame)
        elif op == "translate":
            ops["xformOp:translate"].Set(tuple(float(v) for v in value), frame)
        else:
            target = ops.get("xformOp:rotateXYZ") or xf.AddRotateXYZOp()
            target.Set(tuple(float(v) for v in value), frame)
    elif kind == "sheet_xform":
        xf = UsdGeom.Xformable(sheet)
        xf.AddScaleOp().Set(tuple(float(v) for v in args[0]))
    elif kind == "collider":
        how, value = args
        if how == "points":
            pts = np.array(box.GetAttribute("points").Get(), dtype=np.float64)
            pts[int(value) % len(pts)] = WEIRD[int(value) % len(WEIRD)]
            box.GetAttribute("points").Set(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
        elif how == "indices":
            idx = list(box.GetAttribute("faceVertexIndices").Get())
            idx[int(value) % len(idx)] = int(value)
            box.GetAttribute("faceVertexIndices").Set(Vt.IntArray(idx))
        else:
            box.GetAttribute("faceVertexCounts").Set(Vt.IntArray([int(value)] * 6))
    else:
        raise AssertionError(kind)


_weird = st.sampled_from(WEIRD)
_vec = st.tuples(_weird, _weird, _weird)
MUTATIONS = st.one_of(
    st.tuples(st.just("int"), st.sampled_from(["acra:uCount", "acra:vCount", "acra:levels", "acra:samples"]), st.sampled_from(INTS)),
    st.tuples(st.just("retype"), st.sampled_from(["acra:uCount", "acra:levels", "acra:samples"]), st.just(T.Float), st.just(4.0)),
    st.tuples(st.just("retype"), st.just("acra:cvs"), st.just(T.Double3Array), st.just(Vt.Vec3dArray([(0, 0, 0)] * 16))),
    st.tuples(st.just("retype"), st.just("acra:uWrap"), st.just(T.String), st.just("open")),
    st.tuples(st.just("retype"), st.just("acra:absorption"), st.just(T.DoubleArray), st.just(Vt.DoubleArray([0.0, 1.0]))),
    st.tuples(st.just("remove"), st.sampled_from(["acra:cvs", "acra:uCount", "acra:absorption", "acra:deform", "acra:levels"])),
    st.tuples(st.just("token"), st.sampled_from(["acra:uWrap", "acra:vWrap", "acra:refine"]),
              st.sampled_from(["open", "periodic", "refine", "obey", "bogus", ""])),
    st.tuples(st.just("floats"), st.sampled_from(["acra:absorption", "acra:deform", "acra:translate", "acra:rotate", "acra:rigidity"]),
              st.lists(_weird, max_size=3)),
    st.tuples(st.just("cvs"), st.sampled_from(["truncate", "extend", "value"]), st.integers(0, 40), _weird),
    st.tuples(st.just("cvs_samples"), st.tuples(st.sampled_from([16, 15, 20]), st.sampled_from([16, 12])), st.sampled_from([1.0, -1.0, 1e-3, 1e3, 0.0])),
    st.tuples(st.just("enabled"), st.tuples(st.booleans(), st.booleans())),
    st.tuples(st.just("hierarchy"), st.lists(st.sampled_from([-1, 0, 1, 2, 5]), min_size=1, max_size=3),
              st.lists(st.tuples(st.sampled_from([-1, 0, 1, 3, 100]), st.sampled_from([0, 2, 7])), min_size=1, max_size=3)),
    st.tuples(st.just("xform"), st.sampled_from(["scale", "translate", "rotate"]), st.sampled_from([1, 2]),
              st.one_of(_vec, st.sampled_from([(0, 0, 0), (-1, 1, 1), (1e-3,) * 3, (1e3,) * 3, (1e7, 1e7, 1e7), (1, 1, 0)]))),
    st.tuples(st.just("sheet_xform"), st.sampled_from([(-1.0, 1.0, 1.0), (1e-3,) * 3, (1e3,) * 3, (0.0, 1.0, 1.0)])),
    st.tuples(st.just("collider"), st.sampled_from(["points", "indices", "counts"]), st.integers(-2, 12)),
)


def _check_output(out: Path, rep: Path, code: int) -> None:
    stage = Usd.Stage.Open(str(out))
    prim = stage.GetPrimAtPath(SHEET)
    for t in prim.GetAttribute("points").GetTimeSamples():
        pts = np.asarray(prim.GetAttribute("points").Get(t))
        assert pts.size and np.all(np.isfinite(pts)), t
    assert json.loads(rep.read_text())["status"] == code


@settings(max_examples=60, derandomize=True, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(mutations=st.lists(MUTATIONS, min_size=1, max_size=2))
def test_mutated_stages_run_or_are_refused_in_one_line(base, mutations):
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        stage = Usd.Stage.Open(str(base))
        for m in mutations:
            try:
                _mutate(stage, m)
            except Exception:  # a mutation that does not apply to an earlier one's result (e.g.
                pass  # values of a removed attribute): the stage is run as it stands
        src = d / "in.usda"
        stage.GetRootLayer().Export(str(src))
        before = src.read_bytes()
        out, rep = d / "out.usda", d / "out.json"
        err, std = io.StringIO(), io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(std):
            code = main(["run", str(src), "-o", str(out), "--report", str(rep), "--quiet"])
        assert src.read_bytes() == before
        assert code in (0, 2, 3), (code, err.getvalue())
        if code == 2:
            lines = err.getvalue().splitlines()
            assert len(lines) == 1, err.getvalue()
            named = ERROR.match(lines[0])
            assert named, lines[0]
            assert named["attr"] or named["where"].endswith(".usda") or named["where"] == str(src), lines[0]
            assert sorted(p.name for p in d.iterdir()) == ["in.usda"]
        else:
            _check_output(out, rep, code)
            assert sorted(p.name for p in d.iterdir()) == ["in.usda", "out.json", "out.usda"]
