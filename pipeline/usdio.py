"""USD in: open and validate an input stage, evaluate it per time code (the output layer is
`pipeline.output_layer`).

Reading builds a `SceneModel` once per run and checks every rule of contract §1; any violation is an
`InputError` naming the prim, the attribute and the problem, raised before anything is written.
`state_at` evaluates the animator's shapes and world transforms at any (sub-frame) time code.
`export_layer` writes a layer atomically (the exported stage of a scene file, the output layer).

Conventions
-----------
* USD ``acra:cvs`` is flat, index ``j * uCount + i`` with ``i`` along u; `acra.hspline` uses
  ``cvs[i, j]``, so ``cvs = flat.reshape(vCount, uCount, 3).transpose(1, 0, 2)``.
* USD matrices are row-vector (translation in the last row); ours are column-vector, so every
  matrix read is transposed.
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import os
import re
import runpy
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdGeom, Vt

from acra.hspline import HierarchyArrays, HSpline, from_arrays, from_grid

from . import display
from .model import (
    ColliderModel,
    ColliderState,
    Controls,
    DeformableModel,
    DeformableState,
    InputError,
    SceneModel,
)

__all__ = [
    "USD_SUFFIXES",
    "open_input",
    "load_scene_file",
    "read_scene",
    "read_deformable",
    "read_hierarchy",
    "frame_range",
    "surface_template",
    "state_at",
    "export_layer",
    "vt_array",
    "vt_buffer",
    "cvs_to_flat",
    "flat_to_cvs",
]

USD_SUFFIXES = (".usda", ".usdc", ".usd")
SUM_TOLERANCE = 1e-6

T = Sdf.ValueTypeNames
# contract §1 (name, type, default); None marks a required attribute
CONTRACT_TYPES = {
    "acra:cvs": T.Point3fArray,
    "acra:uCount": T.Int,
    "acra:vCount": T.Int,
    "acra:uWrap": T.Token,
    "acra:vWrap": T.Token,
    "acra:levels": T.Int,
    "acra:absorption": T.FloatArray,
    "acra:deform": T.FloatArray,
    "acra:translate": T.FloatArray,
    "acra:rotate": T.FloatArray,
    "acra:rigidity": T.Float,
    "acra:refine": T.Token,
    "acra:samples": T.Int,
    "acra:enabled": T.Bool,
}
# the project's input hierarchy (docs/usd-schema.md), fields of acra.hspline.HierarchyArrays
HIERARCHY_TYPES = {
    "acra:hierarchy:patchLevel": T.IntArray,
    "acra:hierarchy:patches": T.Int2Array,
    "acra:hierarchy:offsetLevel": T.IntArray,
    "acra:hierarchy:offsetCvs": T.Int2Array,
    "acra:hierarchy:offsets": T.Double3Array,
}
_HIERARCHY_FIELDS = {
    "acra:hierarchy:patchLevel": "patch_level",
    "acra:hierarchy:patches": "patches",
    "acra:hierarchy:offsetLevel": "offset_level",
    "acra:hierarchy:offsetCvs": "offset_cvs",
    "acra:hierarchy:offsets": "offsets",
}
# the output state (docs/usd-schema.md), time-sampled at every processed frame
RESPONSE_TYPES = {
    "acra:response:cvs": T.Double3Array,
    "acra:response:patchLevel": T.IntArray,
    "acra:response:patches": T.Int2Array,
    "acra:response:offsetLevel": T.IntArray,
    "acra:response:offsetCvs": T.Int2Array,
    "acra:response:offsets": T.Double3Array,
    "acra:response:residual": T.Double,
    "acra:response:inCollision": T.Bool,
}
# state across frames (docs/usd-schema.md §2a); acra:plasticity may also be a float[] per level
STATE_CONTROL_TYPES = {
    "acra:relax": T.FloatArray,
    "acra:plasticity": T.Float,
    "acra:preserveVolume": T.Float,
    "acra:bulgeLevel": T.Int,
    "acra:bulgeFalloff": T.Float,
}
# the carried state written per frame when a deformable carries state (docs/usd-schema.md §4)
STATE_TYPES = {
    "acra:state:patchLevel": T.IntArray,
    "acra:state:patches": T.Int2Array,
    "acra:state:elasticCvs": T.Double3Array,
    "acra:state:plasticCvs": T.Double3Array,
    "acra:state:offsetLevel": T.IntArray,
    "acra:state:offsetCvs": T.Int2Array,
    "acra:state:elasticOffsets": T.Double3Array,
    "acra:state:plasticOffsets": T.Double3Array,
}
INPUT_ATTRIBUTES = tuple(CONTRACT_TYPES) + tuple(HIERARCHY_TYPES) + tuple(STATE_CONTROL_TYPES)
WRAPS = {"open": False, "periodic": True}
REFINE_POLICIES = {"refine": True, "obey": False}
_REQUIRED = object()


# --------------------------------------------------------------------------------------------
# opening


def _tf_message(exc: BaseException) -> str:
    """The first human part of a (multi-line, C++-decorated) ``Tf.ErrorException``."""
    text = str(exc)
    quoted = re.findall(r" : '(.*?)'(?:\n|$)", text, flags=re.S)
    msg = quoted[0] if quoted else text
    return " ".join(msg.split()) or type(exc).__name__


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def open_input(path: str | os.PathLike) -> Usd.Stage:
    """Open a USD input stage (``.usda``, ``.usdc``, ``.usd``); never saved by the pipeline.

    A layer already open in this process is reloaded from disk (unless it has unsaved edits), so
    the stage always shows the file as it is now. Raises `InputError` naming the file when it does
    not exist, is unreadable, broken or has composition errors.
    """
    p = Path(path)
    name = str(path)
    if p.suffix.lower() not in USD_SUFFIXES:
        raise InputError(name, None, f"cannot open: not a USD file (expected {', '.join(USD_SUFFIXES)})")
    if not p.exists():
        raise InputError(name, None, "cannot open: no such file")
    if not p.is_file():
        raise InputError(name, None, "cannot open: not a regular file")
    if not os.access(p, os.R_OK):
        raise InputError(name, None, "cannot open: permission denied")
    try:
        layer = Sdf.Layer.Find(str(p.resolve()))
        if layer is not None and not layer.dirty:
            layer.Reload()
        stage = Usd.Stage.Open(str(p.resolve()), Usd.Stage.LoadAll)
    except Exception as exc:  # Tf.ErrorException from the parsers
        raise InputError(name, None, f"cannot open: {_tf_message(exc)}") from exc
    if stage is None:
        raise InputError(name, None, "cannot open: USD returned no stage")
    for layer in stage.GetLayerStack(includeSessionLayers=False):
        for sub in layer.subLayerPaths:
            if Sdf.Layer.FindOrOpenRelativeToLayer(layer, sub) is None:
                raise InputError(name, None, f"cannot open: sublayer @{sub}@ of {layer.identifier} not found")
    errors = stage.GetCompositionErrors()
    if errors:
        raise InputError(name, None, f"cannot open: composition error: {' '.join(str(errors[0]).split())}")
    return stage


def load_scene_file(path: str | os.PathLike, held: list | None = None) -> Path:
    """Run a scene file's ``build()`` and export its stage's root layer to ``<dir>/<stem>.usda``.

    ``held``: where given, the layer of the exported file, open in this process with the content
    just written (`_written_layer`), is appended to it: while a caller holds it, the walk of the
    stage's layers and the stage's opening find the file loaded instead of parsing it again.

    Scene files are trusted Python (contract §4). The module runs with ``__name__`` set to
    ``"acra_scene"`` (so its ``if __name__ == "__main__"`` block does not fire) and with its
    directory on ``sys.path``, as when run on its own. Any exception, a missing ``build`` or a
    result that is not a `Usd.Stage` is an `InputError` naming the file.

    Returns
    -------
    Path of the exported ``.usda`` (written atomically).
    """
    p = Path(path)
    name = str(path)
    if not p.is_file():
        raise InputError(name, None, "cannot open: no such file")
    sys.path.insert(0, str(p.resolve().parent))
    try:
        try:
            namespace = runpy.run_path(str(p), run_name="acra_scene")
        except Exception as exc:
            raise InputError(name, None, f"scene failed to load: {type(exc).__name__}: {_one_line(exc)}") from exc
        build = namespace.get("build")
        if not callable(build):
            raise InputError(name, None, "scene defines no build() function")
        try:
            stage = build()
        except Exception as exc:
            raise InputError(name, "build()", f"raised {type(exc).__name__}: {_one_line(exc)}") from exc
    finally:
        sys.path.remove(str(p.resolve().parent))
    if not isinstance(stage, Usd.Stage):
        raise InputError(name, "build()", f"returned {type(stage).__name__}, expected a Usd.Stage")
    with quiet_spline_deprecation():
        out = export_layer(stage.GetRootLayer(), p.with_suffix(".usda"))
    if held is not None:
        held.append(_written_layer(stage.GetRootLayer(), out))
    return out


def _written_layer(layer: Sdf.Layer, path: Path) -> Sdf.Layer:
    """The layer of the ``.usda`` file ``path`` that ``layer`` was just exported to, open in this
    process and holding ``layer``'s content (copied in memory, `Sdf.Layer.TransferContent`)
    instead of the file parsed back: the text format writes every value so that it reads back
    the same, so the two hold the same specs and values (the demo's export: 2.3 MB, about 0.06 s
    CPU to parse, 1 ms to copy). A layer of that file open already (an earlier run in this
    process) gets the new content too, as `open_input`'s reload from disk would give it. The
    layer has unsaved changes by USD's account, so `open_input` opens on it without reloading."""
    identifier = str(Path(path).resolve())
    written = Sdf.Layer.Find(identifier) or Sdf.Layer.New(Sdf.FileFormat.FindByExtension("usda"), identifier)
    written.TransferContent(layer)
    return written


SPLINE_DEPRECATION = "TsSpline inner looping is deprecated"


@contextlib.contextmanager
def quiet_spline_deprecation():
    """Drop usd-core's own ``TsSpline inner looping is deprecated`` warning, which its ``.usda``
    writer posts for every spline it writes (the pipeline authors no inner loops); every other
    diagnostic posted inside the block reaches the user as usual when the block ends, and errors
    still raise."""
    from pxr import Tf

    with Tf.DiagnosticTrap() as trap:
        try:
            yield
        finally:
            trap.EraseMatching(lambda d: SPLINE_DEPRECATION in str(getattr(d, "commentary", "")))


# --------------------------------------------------------------------------------------------
# reading and validation


def _typed(prim: Usd.Prim, name: str, tname: Sdf.ValueTypeName) -> Usd.Attribute | None:
    """The attribute if declared, after checking its type; ``None`` if not declared."""
    attr = prim.GetAttribute(name)
    if not attr or not attr.IsAuthored():
        return None
    if attr.GetTypeName() != tname:
        raise InputError(str(prim.GetPath()), name, f"has type {attr.GetTypeName()}, expected {tname}")
    return attr


def _static(prim: Usd.Prim, name: str, tname: Sdf.ValueTypeName, default=_REQUIRED):
    """Value of a non-animatable attribute (its default, or its single time sample)."""
    path = str(prim.GetPath())
    attr = _typed(prim, name, tname)
    if attr is None or not attr.HasAuthoredValue():
        if default is _REQUIRED:
            state = "declared without a value" if attr is not None else "missing required attribute"
            raise InputError(path, name, f"{state} ({tname})")
        return default
    if attr.ValueMightBeTimeVarying():
        raise InputError(path, name, "is not animatable: author one default value")
    value = attr.Get(Usd.TimeCode.EarliestTime())
    if value is None:
        raise InputError(path, name, "has no value")
    return value


def _finite_scalar(path: str, name: str, value: float) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise InputError(path, name, f"{value} is not finite")
    return value


def _float_array(path: str, name: str, value, levels: int) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64).reshape(-1)
    if a.size != levels:
        raise InputError(path, name, f"has {a.size} values, expected acra:levels = {levels}")
    bad = ~np.isfinite(a)
    if np.any(bad):
        raise InputError(path, name, f"{a[bad][0]} at level {int(np.nonzero(bad)[0][0])} is not finite")
    neg = a < 0.0
    if np.any(neg):
        lvl = int(np.nonzero(neg)[0][0])
        raise InputError(path, name, f"negative share {a[lvl]:g} at level {lvl}")
    return a


def _token(path: str, name: str, value: str, allowed: dict) -> bool:
    if value not in allowed:
        raise InputError(path, name, f"unknown token {value!r}, expected one of {', '.join(map(repr, allowed))}")
    return allowed[value]


def _read_controls(prim: Usd.Prim, levels: int) -> Controls:
    path = str(prim.GetPath())
    absorption = _static(prim, "acra:absorption", T.FloatArray, None)
    absorption = np.eye(levels)[-1] if absorption is None else _float_array(path, "acra:absorption", absorption, levels)
    total = float(absorption.sum())
    if abs(total - 1.0) > SUM_TOLERANCE:
        raise InputError(path, "acra:absorption", f"shares sum to {total:.9g}, expected 1 (within {SUM_TOLERANCE:g})")

    # unauthored mix arrays are zeros, except that with none authored everything deforms
    raw = {n: _static(prim, f"acra:{n}", T.FloatArray, None) for n in ("deform", "translate", "rotate")}
    mix = {}
    for n, value in raw.items():
        if value is not None:
            mix[n] = _float_array(path, f"acra:{n}", value, levels)
        else:
            mix[n] = np.ones(levels) if n == "deform" and all(v is None for v in raw.values()) else np.zeros(levels)
    sums = mix["deform"] + mix["translate"] + mix["rotate"]
    off = np.abs(sums - 1.0) > SUM_TOLERANCE
    if np.any(off):
        lvl = int(np.nonzero(off)[0][0])
        parts = " + ".join(f"{mix[n][lvl]:g}" for n in ("deform", "translate", "rotate"))
        raise InputError(
            path, "acra:deform",
            f"level {lvl}: deform + translate + rotate = {parts} = {sums[lvl]:.9g}, expected 1 "
            f"(within {SUM_TOLERANCE:g}; acra:deform, acra:translate, acra:rotate)",
        )

    rigidity = _finite_scalar(path, "acra:rigidity", _static(prim, "acra:rigidity", T.Float, 50.0))
    if not 1.0 <= rigidity <= 100.0:
        raise InputError(path, "acra:rigidity", f"{rigidity:g} outside [1, 100]")
    refine = _token(path, "acra:refine", str(_static(prim, "acra:refine", T.Token, "refine")), REFINE_POLICIES)
    samples = int(_static(prim, "acra:samples", T.Int, 4))
    if samples < 1:
        raise InputError(path, "acra:samples", f"{samples} is less than 1")
    return Controls(absorption, mix["deform"], mix["translate"], mix["rotate"], rigidity, refine, samples,
                    **_read_state_controls(prim, levels))


def _unit_interval(path: str, name: str, a: np.ndarray, when: str = "") -> None:
    """Every value of ``a`` finite and in [0, 1], else an `InputError` naming the first bad one."""
    a = np.asarray(a, dtype=np.float64).reshape(-1)
    bad = ~(np.isfinite(a) & (a >= 0.0) & (a <= 1.0))
    if np.any(bad):
        i = int(np.nonzero(bad)[0][0])
        where = f" at level {i}" if a.size > 1 else ""
        raise InputError(path, name, f"{a[i]:g}{where}{when} outside [0, 1]")


def _read_state_controls(prim: Usd.Prim, levels: int) -> dict:
    """``acra:relax`` (animatable, every sample checked), ``acra:plasticity``, ``acra:preserveVolume``,
    ``acra:bulgeLevel``, ``acra:bulgeFalloff`` as `Controls` fields; unauthored ones keep the
    defaults that carry nothing (docs/usd-schema.md §2a)."""
    path = str(prim.GetPath())
    out: dict = {}
    attr = _typed(prim, "acra:relax", T.FloatArray)
    if attr is not None and attr.HasAuthoredValue():
        times = attr.GetTimeSamples() or [Usd.TimeCode.Default()]
        values = []
        for t in times:
            when = " at the default time" if isinstance(t, Usd.TimeCode) else f" at time {t:g}"
            a = np.asarray(attr.Get(t), dtype=np.float64).reshape(-1)
            if a.size != levels:
                raise InputError(path, "acra:relax", f"has {a.size} values{when}, expected acra:levels = {levels}")
            _unit_interval(path, "acra:relax", a, when)
            values.append(a)
        out["relax_times"] = np.array([np.nan if isinstance(t, Usd.TimeCode) else float(t) for t in times])
        out["relax_values"] = np.stack(values)
    plast = prim.GetAttribute("acra:plasticity")
    if plast and plast.IsAuthored():
        tname = plast.GetTypeName()
        if tname not in (T.Float, T.FloatArray):
            raise InputError(path, "acra:plasticity", f"has type {tname}, expected {T.Float} or {T.FloatArray}")
        value = _static(prim, "acra:plasticity", tname, None)
        if value is not None:
            a = np.asarray(value, dtype=np.float64).reshape(-1)
            if tname == T.FloatArray and a.size != levels:
                raise InputError(path, "acra:plasticity", f"has {a.size} values, expected acra:levels = {levels}")
            _unit_interval(path, "acra:plasticity", a)
            out["plasticity"] = np.broadcast_to(a, (levels,)).copy()
    strength = _static(prim, "acra:preserveVolume", T.Float, None)
    if strength is not None:
        _unit_interval(path, "acra:preserveVolume", np.array([strength]))
        out["preserve_volume"] = float(strength)
    level = _static(prim, "acra:bulgeLevel", T.Int, None)
    if level is not None:
        if not 0 <= int(level) < levels:
            raise InputError(path, "acra:bulgeLevel", f"{int(level)} outside 0..{levels - 1}")
        out["bulge_level"] = int(level)
    falloff = _static(prim, "acra:bulgeFalloff", T.Float, None)
    if falloff is not None:
        falloff = _finite_scalar(path, "acra:bulgeFalloff", falloff)
        if falloff <= 0.0:
            raise InputError(path, "acra:bulgeFalloff", f"{falloff:g} is not positive")
        out["bulge_falloff"] = falloff
    return out


def read_hierarchy(prim: Usd.Prim) -> HierarchyArrays:
    """The animator's ``acra:hierarchy:*`` arrays, checked for type, matching lengths and NaN.

    Whether the entries fit the grid (levels, ranges, the C2 rule) is checked by
    `read_deformable`, which rebuilds the hierarchy with `acra.hspline.from_arrays`.
    """
    path = str(prim.GetPath())
    empty = {
        "acra:hierarchy:patchLevel": np.zeros(0, np.int32),
        "acra:hierarchy:patches": np.zeros((0, 2), np.int32),
        "acra:hierarchy:offsetLevel": np.zeros(0, np.int32),
        "acra:hierarchy:offsetCvs": np.zeros((0, 2), np.int32),
        "acra:hierarchy:offsets": np.zeros((0, 3), np.float64),
    }
    arrays = {}
    for name, tname in HIERARCHY_TYPES.items():
        value = _static(prim, name, tname, None)
        arrays[name] = empty[name] if value is None else np.array(value, dtype=empty[name].dtype).reshape((-1,) + empty[name].shape[1:])
    for a, b in (("patchLevel", "patches"), ("offsetLevel", "offsetCvs"), ("offsetLevel", "offsets")):
        na, nb = len(arrays[f"acra:hierarchy:{a}"]), len(arrays[f"acra:hierarchy:{b}"])
        if na != nb:
            raise InputError(path, f"acra:hierarchy:{b}", f"has {nb} entries but acra:hierarchy:{a} has {na}")
    offs = arrays["acra:hierarchy:offsets"]
    if not np.all(np.isfinite(offs)):
        row = int(np.nonzero(~np.all(np.isfinite(offs), axis=1))[0][0])
        raise InputError(path, "acra:hierarchy:offsets", f"NaN or inf at index {row}")
    _check_magnitude(path, "acra:hierarchy:offsets", offs, "")
    return HierarchyArrays(**{_HIERARCHY_FIELDS[n]: a for n, a in arrays.items()})


def _cvs_samples(prim: Usd.Prim, count: int, desc: str):
    """Yield ``(time, (count, 3) float32)`` for every time sample of acra:cvs (or its default)."""
    path = str(prim.GetPath())
    attr = _typed(prim, "acra:cvs", T.Point3fArray)
    if attr is None or not attr.HasAuthoredValue():
        state = "declared without a value" if attr is not None else "missing required attribute"
        raise InputError(path, "acra:cvs", f"{state} (point3f[])")
    times = attr.GetTimeSamples() or [Usd.TimeCode.Default()]
    for t in times:
        value = attr.Get(t)
        when = "at the default time" if isinstance(t, Usd.TimeCode) else f"at time {t:g}"
        flat = np.asarray(value if value is not None else Vt.Vec3fArray())
        if len(flat) != count:
            raise InputError(path, "acra:cvs", f"has {len(flat)} values {when}, expected {desc}")
        bad = ~np.all(np.isfinite(flat), axis=1)
        if np.any(bad):
            raise InputError(path, "acra:cvs", f"NaN or inf {when} at index {int(np.nonzero(bad)[0][0])}")
        _check_magnitude(path, "acra:cvs", flat, when)
        yield t, flat


# Object-space coordinates are float32 in USD and float64 in ACRA; past 1e15 float64 resolves
# no better than 0.125 units, and products of coordinates (areas, squared distances, the
# barycentric denominators of detection) lose every digit of a unit-sized feature.
MAX_COORDINATE = 1e15


def _check_magnitude(path: str, name: str, points: np.ndarray, when: str) -> None:
    big = np.abs(np.asarray(points, dtype=np.float64)) > MAX_COORDINATE
    if np.any(big):
        row = int(np.nonzero(np.any(big.reshape(len(big), -1), axis=1))[0][0])
        where = f" {when}" if when else ""
        raise InputError(path, name, f"coordinate beyond {MAX_COORDINATE:g}{where} at index {row}: "
                                     "too far from the object's origin to compute with (move the object by its transform)")


def flat_to_cvs(flat: np.ndarray, nu: int, nv: int) -> np.ndarray:
    """USD row-major ``(nu * nv, 3)`` (index ``j * nu + i``) to ``cvs[i, j]``: ``(nu, nv, 3) float64``."""
    return np.ascontiguousarray(np.asarray(flat, dtype=np.float64).reshape(nv, nu, 3).transpose(1, 0, 2))


def cvs_to_flat(cvs: np.ndarray) -> np.ndarray:
    """``cvs[i, j]`` ``(nu, nv, 3)`` to USD row-major ``(nu * nv, 3)`` (index ``j * nu + i``)."""
    cvs = np.asarray(cvs)
    return np.ascontiguousarray(cvs.transpose(1, 0, 2).reshape(-1, 3))


def read_deformable(prim: Usd.Prim) -> tuple[DeformableModel, HSpline]:
    """Validate one deformable prim (contract §1 and the hierarchy attributes).

    Returns the model and the surface at the first ``acra:cvs`` sample (or its default value).
    """
    path = str(prim.GetPath())
    if not prim.IsA(UsdGeom.Mesh):
        raise InputError(path, "acra:cvs", f"deformables must be UsdGeom.Mesh prims, this is a {prim.GetTypeName() or 'typeless prim'}")
    if prim.IsInstanceProxy():
        raise InputError(path, None, "a deformable inside an instance cannot be overridden: make it uninstanced")
    nu = int(_static(prim, "acra:uCount", T.Int))
    nv = int(_static(prim, "acra:vCount", T.Int))
    uper = _token(path, "acra:uWrap", str(_static(prim, "acra:uWrap", T.Token, "open")), WRAPS)
    vper = _token(path, "acra:vWrap", str(_static(prim, "acra:vWrap", T.Token, "open")), WRAPS)
    for name, n, per in (("acra:uCount", nu, uper), ("acra:vCount", nv, vper)):
        need = 3 if per else 4
        if n < need:
            kind = "a periodic" if per else "an open"
            raise InputError(path, name, f"{n} CVs, {kind} direction needs at least {need}")
    levels = int(_static(prim, "acra:levels", T.Int, 1))
    if levels < 1:
        raise InputError(path, "acra:levels", f"{levels} is less than 1")
    controls = _read_controls(prim, levels)
    _typed(prim, "acra:enabled", T.Bool)  # animatable: only its type is checked here
    hierarchy = read_hierarchy(prim)

    first = None
    for _, flat in _cvs_samples(prim, nu * nv, f"acra:uCount * acra:vCount = {nu} * {nv} = {nu * nv}"):
        first = flat if first is None else first
    base = from_grid(flat_to_cvs(first, nu, nv), uper, vper, depth=levels)
    # patches first (no offsets), so an error names the attribute that holds the bad entry
    for stage_, arrays in (
        ("patch", replace(hierarchy, offset_level=hierarchy.offset_level[:0], offset_cvs=hierarchy.offset_cvs[:0], offsets=hierarchy.offsets[:0])),
        ("offset", hierarchy),
    ):
        try:
            surface = from_arrays(base, arrays)
        except ValueError as exc:
            msg = str(exc)
            if msg.startswith("refined patch at level"):
                name = "acra:hierarchy:patchLevel"
            elif msg.startswith("offset at level"):
                name = "acra:hierarchy:offsetLevel"
            else:
                name = "acra:hierarchy:patches" if stage_ == "patch" else "acra:hierarchy:offsetCvs"
            raise InputError(path, name, msg) from exc
    topology = display.topology_of([surface], controls.samples)  # the rest display: every level the animator used
    model = DeformableModel(path, uper, vper, nu, nv, levels, controls, hierarchy, topology)
    return model, surface


def _read_collider(prim: Usd.Prim, time: Usd.TimeCode) -> ColliderModel:
    """A collision mesh in object space, its polygons fan-triangulated (counter-clockwise)."""
    path = str(prim.GetPath())
    mesh = UsdGeom.Mesh(prim)
    pts = _typed(prim, "points", T.Point3fArray)
    counts = _typed(prim, "faceVertexCounts", T.IntArray)
    indices = _typed(prim, "faceVertexIndices", T.IntArray)
    for name, attr in (("points", pts), ("faceVertexCounts", counts), ("faceVertexIndices", indices)):
        if attr is None or not attr.HasAuthoredValue():
            raise InputError(path, name, "a collider mesh needs points and faces")
    vertices = np.asarray(pts.Get(time), dtype=np.float64).reshape(-1, 3)
    counts = np.asarray(counts.Get(time), dtype=np.int64).reshape(-1)
    indices = np.asarray(indices.Get(time), dtype=np.int64).reshape(-1)
    if not np.all(np.isfinite(vertices)):
        raise InputError(path, "points", f"NaN or inf at index {int(np.nonzero(~np.all(np.isfinite(vertices), axis=1))[0][0])}")
    _check_magnitude(path, "points", vertices, "")
    if counts.size == 0:
        raise InputError(path, "faceVertexCounts", "a collider mesh needs at least one face")
    if np.any(counts < 3):
        raise InputError(path, "faceVertexCounts", f"face {int(np.argmax(counts < 3))} has {int(counts[counts < 3][0])} vertices, at least 3 needed")
    if counts.sum() != indices.size:
        raise InputError(path, "faceVertexIndices", f"has {indices.size} values, faceVertexCounts sum to {int(counts.sum())}")
    if np.any((indices < 0) | (indices >= len(vertices))):
        raise InputError(path, "faceVertexIndices", f"index outside 0..{len(vertices) - 1}")
    starts = np.cumsum(counts) - counts
    ntri = counts - 2
    face = np.repeat(np.arange(counts.size), ntri)
    k = np.arange(int(ntri.sum())) - np.repeat(np.cumsum(ntri) - ntri, ntri)
    s = starts[face]
    tris = np.stack([indices[s], indices[s + k + 1], indices[s + k + 2]], axis=1)
    if mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded:
        tris = tris[:, ::-1]
    return ColliderModel(path, vertices, np.ascontiguousarray(tris))


def _metadata_frame(stage: Usd.Stage, key: str) -> int | None:
    if not stage.HasAuthoredMetadata(key):
        return None
    value = float(stage.GetMetadata(key))
    if not math.isfinite(value) or value != round(value):
        raise InputError(stage.GetRootLayer().identifier, key, f"{value:g} is not an integer frame")
    return int(value)


def _sample_range(stage: Usd.Stage) -> tuple[float, float] | None:
    """Earliest and latest time sample or spline knot of any attribute on the stage."""
    lo, hi = math.inf, -math.inf
    for prim in stage.Traverse():
        for attr in prim.GetAttributes():
            times = list(attr.GetTimeSamples())
            if attr.HasSpline():
                times += [float(t) for t in attr.GetSpline().GetKnots().keys()]
            if times:
                lo, hi = min(lo, min(times)), max(hi, max(times))
    return None if lo > hi else (lo, hi)


def frame_range(stage: Usd.Stage) -> tuple[int, int]:
    """``startTimeCode..endTimeCode``; where unauthored, the span of the time samples, else 0..0."""
    start, end = _metadata_frame(stage, "startTimeCode"), _metadata_frame(stage, "endTimeCode")
    if start is None or end is None:
        span = _sample_range(stage)
        lo, hi = (0, 0) if span is None else (math.floor(span[0]), math.ceil(span[1]))
        start = lo if start is None else start
        end = hi if end is None else end
    if start > end:
        raise InputError(stage.GetRootLayer().identifier, "endTimeCode", f"{end} is before startTimeCode {start}")
    return start, end


def _is_deformable(prim: Usd.Prim) -> bool:
    return any(prim.GetAttribute(n).IsAuthored() for n in INPUT_ATTRIBUTES if prim.HasAttribute(n))


def _is_collider(prim: Usd.Prim) -> bool:
    """A Mesh with ``PhysicsCollisionAPI``. UsdPhysics is imported at the first Mesh, so a stage of
    deformables alone never loads it (about 14 ms CPU)."""
    if not prim.IsA(UsdGeom.Mesh):
        return False
    from pxr import UsdPhysics

    return prim.HasAPI(UsdPhysics.CollisionAPI)


def read_scene(stage: Usd.Stage) -> SceneModel:
    """Every deformable and rigid collider of a stage, validated against contract §1.

    A prim carrying any ``acra:`` input attribute is a deformable (so a forgotten ``acra:cvs`` is
    reported, not ignored); any other Mesh with ``PhysicsCollisionAPI`` is a collider, read at
    ``startTimeCode``. Objects are sorted by path. ``extra["templates"]`` maps each deformable's
    path to its surface (level-0 CVs of the first sample plus the animator's hierarchy), the
    structure `state_at` reuses.
    """
    start, end = frame_range(stage)
    deformables, colliders, templates = [], [], {}
    for prim in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
        if _is_deformable(prim):
            model, surface = read_deformable(prim)
            deformables.append(model)
            templates[model.path] = surface
        elif _is_collider(prim):
            colliders.append(_read_collider(prim, Usd.TimeCode(start)))
    deformables.sort(key=lambda m: m.path)
    colliders.sort(key=lambda m: m.path)
    return SceneModel(
        deformables=tuple(deformables),
        colliders=tuple(colliders),
        start=start,
        end=end,
        meters_per_unit=float(UsdGeom.GetStageMetersPerUnit(stage)),
        up_axis=str(UsdGeom.GetStageUpAxis(stage)),
        extra={"templates": templates},
    )


# --------------------------------------------------------------------------------------------
# per-time evaluation


def surface_template(scene: SceneModel, model: DeformableModel) -> HSpline:
    """The deformable's refinement structure (cached in ``scene.extra``): swap ``cvs`` per frame."""
    templates = scene.extra.setdefault("templates", {})
    hs = templates.get(model.path)
    if hs is None:
        base = from_grid(np.zeros((model.nu, model.nv, 3)), model.u_periodic, model.v_periodic, depth=model.depth)
        hs = templates[model.path] = from_arrays(base, model.hierarchy)
    return hs


def _matrix(m) -> np.ndarray:
    """USD row-vector ``Gf.Matrix4d`` to a column-vector ``(4, 4) float64``."""
    return np.asarray(m, np.float64).T.copy()  # a Gf matrix's buffer: its 16 doubles, row by row


def _world(stage: Usd.Stage, path: str, t: float, caches: list, held: dict | None) -> np.ndarray:
    """The object-to-world matrix ``(4, 4) float64`` (column-vector) of the prim at ``path`` at
    time code ``t``, a new array. ``caches`` holds the time code's one `UsdGeom.XformCache`,
    taken at its first need (ancestors' transforms are shared between the objects of one time
    code): a new one, or with ``held`` the one ``held`` keeps, moved to the time code
    (`UsdGeom.XformCache.SetTime`), and the prim looked up once."""
    if held is None:
        prim = stage.GetPrimAtPath(path)
    else:
        prim = held.get(("prim", path))
        if prim is None:
            prim = held[("prim", path)] = stage.GetPrimAtPath(path)
    if not caches:
        if held is None:
            caches.append(UsdGeom.XformCache(t))  # a float: USD's conversion to its time code
        else:
            # one cache for the run: moved to another time it keeps each prim's transform ops
            # and their attribute queries, which a new cache finds again at every call
            cache = held.get("xform cache")
            if cache is None:
                cache = held["xform cache"] = UsdGeom.XformCache(t)
            cache.SetTime(t)
            caches.append(cache)
    return _matrix(caches[0].GetLocalToWorldTransform(prim))


def state_at(stage: Usd.Stage, scene: SceneModel, t: float, held: dict | None = None) -> tuple[list[DeformableState], list[ColliderState]]:
    """The animator's scene at time code ``t`` (any real, sub-frames included).

    Level-0 CVs come from ``acra:cvs`` at ``t`` (USD interpolates time samples linearly), the
    hierarchy from the model; world transforms resolve time samples, Ts splines and animated
    ancestors. States are in ``scene`` order. ``held`` (a dict the caller keeps for one stage
    left unedited, e.g. a run's) holds each deformable's surface and ``acra:enabled`` where USD
    says they cannot vary in time (`Usd.Attribute.ValueMightBeTimeVarying`: at most one time
    sample, no varying clips; these array and bool types take no spline), read at the first call
    and handed back, the same objects, at every later one; and each object's prim and one
    `UsdGeom.XformCache` for the world transforms (`_world`).
    """
    t = float(t)
    caches: list = []  # the time code's XformCache, made where a transform is read from the stage
    dstates = []
    for m in scene.deformables:
        fixed = held.get(m.path) if held is not None else None
        if fixed is None:
            tc = Usd.TimeCode(t)
            prim = stage.GetPrimAtPath(m.path)
            cvs_attr = prim.GetAttribute("acra:cvs")
            flat = np.asarray(cvs_attr.Get(tc))
            if len(flat) != m.nu * m.nv:
                raise InputError(m.path, "acra:cvs", f"has {len(flat)} values at time {t:g}, expected {m.nu * m.nv}")
            surface = replace(surface_template(scene, m), cvs=flat_to_cvs(flat, m.nu, m.nv))
            enabled_attr = prim.GetAttribute("acra:enabled")
            enabled = bool(enabled_attr.Get(tc)) if enabled_attr and enabled_attr.HasAuthoredValue() else True
            if held is not None and not cvs_attr.ValueMightBeTimeVarying() and not (enabled_attr and enabled_attr.ValueMightBeTimeVarying()):
                held[m.path] = (surface, enabled)
        else:
            surface, enabled = fixed
        dstates.append(DeformableState(surface, _world(stage, m.path, t, caches, held), enabled))
    cstates = [ColliderState(_world(stage, c.path, t, caches, held)) for c in scene.colliders]
    return dstates, cstates


# --------------------------------------------------------------------------------------------
# writing


# values (scalars) below which `vt_array` hands the array to USD's conversion: `FromNumpy`
# takes 0.4-2.4 us for up to 1,000 ints and 7.5 for 3,000 doubles, the block copy about 6-8
VT_COPY_MIN = 2048


def vt_array(vt: type, array: np.ndarray):
    """``vt.FromNumpy(array)`` (``vt`` a `Vt` array type, ``array (n,) or (n, m)`` of its scalar
    type), the same value, made by one block copy.

    USD's conversion goes element by element through the buffer protocol (about 13 ns a
    ``Vec3f``: 0.3 ms for the demo head's 23,491 display points); a new Vt array of ``n``
    elements owns its buffer alone, and numpy's read-only view of it is that buffer, so the
    bytes are copied into it at once (0.03 ms). The copy has a fixed cost of about 6 us (the new
    array, two views of it, the check), more than USD's conversion of fewer than about 2,000
    values (`VT_COPY_MIN`), which USD converts. Where that view is not of ``array``'s shape and
    dtype, or the copied bytes do not read back through a new view, USD converts."""
    a = np.ascontiguousarray(array)
    if a.size < VT_COPY_MIN:
        return vt.FromNumpy(a)
    out = vt(len(a))
    view = np.asarray(out)
    if a.size == 0 or view.shape != a.shape or view.dtype != a.dtype:
        return vt.FromNumpy(a)
    ctypes.memmove(view.ctypes.data, a.ctypes.data, a.nbytes)
    if not np.array_equal(np.asarray(out).reshape(-1).view(np.uint8), a.reshape(-1).view(np.uint8)):
        return vt.FromNumpy(a)
    return out


def vt_buffer(vt: type, shape: tuple, dtype) -> tuple:
    """A new ``vt`` array of ``shape[0]`` elements and a writable numpy view ``shape dtype`` of
    its own buffer, for values written straight into it (no array between, no copy); ``(None,
    None)`` where numpy's view of the new array is not of that shape and dtype or not the
    array's own memory (two views at one address: a copy made for each view could not share
    it while the first lives). The view is valid while the Vt array lives and is not copied."""
    out = vt(int(shape[0]))
    first, second = np.asarray(out), np.asarray(out)
    if first.size == 0 or first.shape != tuple(shape) or first.dtype != dtype or first.ctypes.data != second.ctypes.data:
        return None, None
    memory = (ctypes.c_byte * first.nbytes).from_address(first.ctypes.data)
    return out, np.frombuffer(memory, dtype).reshape(shape)


def _export(layer: Sdf.Layer, path: str) -> None:
    """Write a layer to ``path`` (format from the suffix); raises on failure."""
    if not layer.Export(path):
        raise OSError(f"USD could not write {path}")


def export_layer(layer: Sdf.Layer, path: str | os.PathLike) -> Path:
    """Write ``layer`` to ``path`` atomically (`guard.atomic_file`): on any error or interruption
    the temporary file is removed and ``path`` is untouched."""
    from pipeline import guard

    out = Path(path)
    with guard.atomic_file(out) as tmp:
        _export(layer, str(tmp))
    return out
