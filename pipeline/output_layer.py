"""The output layer of a run (contract §2, docs/usd-schema.md): per-frame results in, one layer
out, and the response state read back.

`write_output` writes one layer that sublayers the input by a relative path and holds only
``over`` opinions: the display topology once, time-sampled ``points`` and ``normals`` of every
deformable at every processed frame, the response state in ``acra:response:*`` and, for objects
that carry state across frames, ``acra:state:*``; the input's stage metadata; nothing else. It is
written atomically (`usdio.export_layer`) and deterministically (sorted paths and frames).
`read_output_hierarchy` reads a frame's responded surface back. Reading the input lives in
`pipeline.usdio`.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

from acra import float32, floattext
from acra.hspline import HierarchyArrays, HSpline, details, from_arrays, from_grid, to_arrays
from acra.tessellate import MeshTopology, grid_samples
from pipeline import workers
from pipeline.model import DeformableModel, SceneModel
from pipeline.usdio import RESPONSE_TYPES, STATE_TYPES, WRAPS, T, cvs_to_flat, export_layer, flat_to_cvs, read_hierarchy, vt_array, vt_buffer

__all__ = ["DISPLAY_UV", "DeformableResult", "FramesResult", "write_output", "read_output_hierarchy", "read_display_uv", "read_display_topology", "input_points"]

DISPLAY_UV = "acra:display:uv"  # double2[], uniform: each display vertex's (u, v), level-0 units


@dataclass(frozen=True)
class DeformableResult:
    """One deformable at one processed frame, after the response (object space).

    Attributes
    ----------
    points, normals : (n, 3) float64 or None
        Display tessellation (the run's topology, `FramesResult.topology`) and its unit normals;
        ``None`` until the run's display is evaluated (`pipeline.display.finish`).
    surface : HSpline
        The surface after the response: level-0 CVs and the full hierarchy.
    residual : float
        Remaining penetration depth after the response (scene units).
    in_collision : bool
        Whether detection found the object in collision at this frame.
    carried : acra.relax.Carried or None
        The offsets carried out of this frame (`pipeline.state`), written as ``acra:state:*``;
        ``None`` for an object that carries nothing (no ``acra:state:*`` attribute is written).
    """

    points: np.ndarray
    normals: np.ndarray
    surface: HSpline
    residual: float = 0.0
    in_collision: bool = False
    carried: object = None


@dataclass
class FramesResult:
    """Results of a run: ``frames[frame][prim path] -> DeformableResult``, and the display
    topology of each deformable for the whole run (``topologies[prim path]``, a
    `acra.tessellate.GridTopology` or `MeshTopology`; where absent, the model's), which every
    frame's ``points`` follow. ``residuals[frame]`` holds the frame loop's residual answers of the
    kept round by content, which `pipeline.residual.measure_run` takes where the run's display
    shows the same."""

    frames: dict[int, dict[str, DeformableResult]] = field(default_factory=dict)
    topologies: dict = field(default_factory=dict)
    residuals: dict = field(default_factory=dict)  # frame -> `pipeline.residual.known` of the kept round's display

    def topology(self, model: DeformableModel):
        """The display topology ``model``'s points follow in this run."""
        return self.topologies.get(model.path, model.topology)

    def add(self, frame: int, path: str, result: DeformableResult) -> None:
        self.frames.setdefault(int(frame), {})[str(path)] = result


def _relative_asset(target: Path, anchor_dir: Path) -> str:
    rel = Path(os.path.relpath(target.resolve(), anchor_dir.resolve())).as_posix()
    return rel if rel.startswith("../") else f"./{rel}"


def _stage_metadata(input_path: Path, scene: SceneModel) -> dict:
    """The input's effective stage metadata, so the output opens as a complete stage.

    Values the input leaves unauthored are written as USD resolves them (fallbacks), and the
    frame range as `read_scene` resolved it, so the output means exactly what the input meant.
    """
    root = Sdf.Layer.FindOrOpen(str(input_path.resolve()))
    src = Usd.Stage.OpenMasked(root, Usd.StagePopulationMask(), Usd.Stage.LoadNone)
    return {
        "startTimeCode": float(root.startTimeCode) if root.HasStartTimeCode() else float(scene.start),
        "endTimeCode": float(root.endTimeCode) if root.HasEndTimeCode() else float(scene.end),
        "timeCodesPerSecond": float(src.GetTimeCodesPerSecond()),
        "framesPerSecond": float(src.GetFramesPerSecond()),
        "upAxis": str(UsdGeom.GetStageUpAxis(src)),
        "metersPerUnit": float(UsdGeom.GetStageMetersPerUnit(src)),
        "defaultPrim": root.defaultPrim if root.HasDefaultPrim() else None,
    }


def _spec(prim_spec: Sdf.PrimSpec, name: str, tname: Sdf.ValueTypeName, custom: bool) -> Sdf.AttributeSpec:
    spec = prim_spec.layer.GetAttributeAtPath(prim_spec.path.AppendProperty(name))
    return spec if spec is not None else Sdf.AttributeSpec(prim_spec, name, tname, Sdf.VariabilityVarying, custom)


def _checked_shape(model: DeformableModel, topology, frame: int, name: str, a: np.ndarray) -> np.ndarray:
    """Display points or normals ``(n, 3)`` as an array, after checking their shape."""
    n = topology.u.size
    a = np.asarray(a)
    if a.shape != (n, 3):
        raise ValueError(f"frame {frame}, {model.path}: {name} has shape {a.shape}, the display topology needs ({n}, 3)")
    return a


def _checked_floats(model: DeformableModel, topology, frame: int, name: str, a: np.ndarray) -> np.ndarray:
    """Display points or normals ``(n, 3)`` as ``(n, 3) float32``, after checking shape and values."""
    values = float32.rounded(_checked_shape(model, topology, frame, name, a))
    if values is None:
        raise ValueError(f"frame {frame}, {model.path}: {name} hold NaN or inf")
    return values


def _checked_vec3f(model: DeformableModel, topology, frame: int, name: str, a: np.ndarray) -> Vt.Vec3fArray:
    """Display points or normals ``(n, 3)`` as float32 Vt values, after checking shape and values:
    rounded straight into the Vt array's own buffer (`usdio.vt_buffer`), else through numpy."""
    a = _checked_shape(model, topology, frame, name, a)
    out, buffer = vt_buffer(Vt.Vec3fArray, a.shape, np.float32)
    if out is None:
        return vt_array(Vt.Vec3fArray, _checked_floats(model, topology, frame, name, a))
    if not float32.round_into(a, buffer):
        raise ValueError(f"frame {frame}, {model.path}: {name} hold NaN or inf")
    return out


class _Pending:
    """An array the layer holds as a ``vt`` value (a `Vt` array type), kept as numpy until USD
    needs it: a ``.usda`` layer's `_COMPILED` arrays stand in and have their text written by
    `acra.floattext` from the numpy array, so converting them to Vt (`usdio.vt_array`) would be
    spent on nothing.

    Attributes
    ----------
    array : (n,) or (n, m) numpy array
        The values, of the dtype ``vt`` holds (float32, float64 or int32).
    vt : type
        The `Vt` array type USD authors.
    """

    def __init__(self, vt: type, array: np.ndarray) -> None:
        self.vt, self.array, self._value = vt, array, None

    def __len__(self) -> int:
        return len(self.array)

    def value(self):
        """The array as its `Vt` value, converted at the first call."""
        if self._value is None:
            self._value = vt_array(self.vt, self.array)
        return self._value


def _vt_type(value) -> type:
    """The `Vt` type ``value`` is authored as."""
    return value.vt if type(value) is _Pending else type(value)


def _authored(value):
    """``value`` as USD authors it (a `_Pending` array as its Vt value)."""
    return value.value() if type(value) is _Pending else value


class _Hierarchy:
    """The ``acra:response:*`` values of a run's responded surfaces, each part made once per
    distinct content: a response changes the offsets near the contact and keeps the refined
    patches (its levels' ``patches`` and ``cv_keys`` are the surface's it started from, the same
    objects), so successive frames hand the same structure arrays, and often the same offsets. A part
    whose levels are the objects of an earlier surface's is that surface's value (one object:
    one text in a ``.usda`` layer, one Vt array in a crate). Keeps the levels alive while their
    ``id`` is a key.

    ``as_vt(vt, array)`` makes an array's value (`Vt` now, or `_Pending` for a text layer).
    """

    def __init__(self, as_vt) -> None:
        self.as_vt = as_vt
        self._memo: dict = {}  # (part, v direction, ids of the levels' arrays) -> (the arrays, their values)

    def _part(self, part: str, v, arrays: tuple, make):
        key = (part, v) + tuple(map(id, arrays))
        hit = self._memo.get(key)
        if hit is None or any(a is not b for a, b in zip(hit[0], arrays)):
            hit = self._memo[key] = (arrays, make())
        return hit[1]

    def __call__(self, model: DeformableModel, frame: int, surface: HSpline) -> dict:
        """The ``acra:response:*`` values of a checked surface (float64: exact round trip)."""
        if surface.cvs.shape != (model.nu, model.nv, 3) or surface.depth != model.depth:
            raise ValueError(f"frame {frame}, {model.path}: surface does not match the model's grid or levels")
        if not np.all(np.isfinite(surface.cvs)):
            raise ValueError(f"frame {frame}, {model.path}: surface CVs are not finite")
        fine = surface.fine
        whole = None

        def levels() -> HierarchyArrays:
            nonlocal whole
            if whole is None:
                whole = to_arrays(surface)
            return whole

        structure = self._part("structure", surface.v, tuple(lev.patches for lev in fine), lambda: (
            self.as_vt(Vt.IntArray, levels().patch_level), self.as_vt(Vt.Vec2iArray, levels().patches)))
        offsets = self._part("offsets", surface.v, tuple(lev.cv_keys for lev in fine) + tuple(lev.offsets for lev in fine), lambda: (
            self.as_vt(Vt.IntArray, levels().offset_level), self.as_vt(Vt.Vec2iArray, levels().offset_cvs),
            self.as_vt(Vt.Vec3dArray, levels().offsets)))
        return {
            "acra:response:cvs": vt_array(Vt.Vec3dArray, cvs_to_flat(np.asarray(surface.cvs, dtype=np.float64))),
            "acra:response:patchLevel": structure[0],
            "acra:response:patches": structure[1],
            "acra:response:offsetLevel": offsets[0],
            "acra:response:offsetCvs": offsets[1],
            "acra:response:offsets": offsets[2],
        }


class _Converted:
    """Vt values of the objects of a run's results, built once per distinct object.

    The frame loop hands back the same surface and the same display arrays at every frame whose
    result is unchanged (the free frames), so each is checked and converted once and the time
    samples share one Vt array (copy-on-write, so sharing is safe). Objects are kept alive here
    while their ``id`` is a key.
    """

    def __init__(self) -> None:
        self._memo: dict = {}

    def __call__(self, kind: tuple, obj, make):
        """``make()``'s value for ``obj``, made at the first call with this ``kind`` and object."""
        hit = self._memo.get((kind, id(obj)))
        if hit is None or hit[0] is not obj:
            hit = self._memo[(kind, id(obj))] = (obj, make())
        return hit[1]


class _Direct:
    """Time samples authored as they are (a binary crate stores a repeated array once itself)."""

    def stand_in(self, path: Sdf.Path, time: float | None, value):
        return _authored(value)

    def export(self, layer: Sdf.Layer, out: Path) -> Path:
        return export_layer(layer, out)


# an array value's stand-in in the layer: one element no result holds (points, normals and CVs
# are finite, levels and indices not negative; `_SharedText.export` counts the stand-ins found),
# ``k`` telling the stand-ins apart; and its text in USD's writer, ``k`` an integer below 2^24
# written as its digits (`tests/test_usdio.py` holds each to USD's text)
_STAND_INS = {
    Vt.Vec3fArray: (T.Float3Array, lambda k: Vt.Vec3fArray([Gf.Vec3f(math.nan, k, math.nan)]), "[(nan, {}, nan)]"),
    Vt.Vec3dArray: (T.Double3Array, lambda k: Vt.Vec3dArray([Gf.Vec3d(math.nan, k, math.nan)]), "[(nan, {}, nan)]"),
    Vt.Vec2dArray: (T.Double2Array, lambda k: Vt.Vec2dArray([Gf.Vec2d(math.nan, k)]), "[(nan, {})]"),
    Vt.Vec2iArray: (T.Int2Array, lambda k: Vt.Vec2iArray([Gf.Vec2i(-1000000007, k)]), "[(-1000000007, {})]"),
    Vt.IntArray: (T.IntArray, lambda k: Vt.IntArray([-1000000007, k]), "[-1000000007, {}]"),
}
_SHARED_MIN = 64  # arrays shorter than this are written as they are
# characters of text an element can take at most in USD's writer (float32 and int32 shortest
# repr, float64 to 17 digits, separators), and the most text `_SharedText` may hold in memory
# while it writes: a run whose layer would be longer is written by USD's own writer, which
# streams it to the file
_CHARS = {Vt.Vec3fArray: 56, Vt.Vec3dArray: 80, Vt.Vec2dArray: 54, Vt.Vec2iArray: 28, Vt.IntArray: 13}
TEXT_HELD_MAX = 256 * 2**20
_SCRATCH_LINE = re.compile(r"^ +custom [\w\[\]]+ (v)(\d+) = (.*)$", re.M)
# arrays whose text `acra.floattext` writes (the bytes USD's writer gives, faster,
# `tests/test_floattext.py`): every one stands in, a collision frame's and a default value too
_COMPILED = {
    Vt.Vec3fArray: lambda value: floattext.tuples_text(_numpy(value), _float_texts),
    Vt.Vec2dArray: lambda value: floattext.tuples_text(_numpy(value), _float_texts),
    Vt.Vec3dArray: lambda value: floattext.tuples_text(_numpy(value), _float_texts),
    Vt.IntArray: lambda value: floattext.ints_text(_numpy(value)),
    Vt.Vec2iArray: lambda value: floattext.ints_text(_numpy(value)),
}
_FLOATS = {Vt.Vec3fArray, Vt.Vec2dArray, Vt.Vec3dArray}  # of them, written together (`floattext.tuples_texts`)


def _numpy(value) -> np.ndarray:
    """A Vt array's or a `_Pending` array's values as numpy (a view where USD's buffer allows)."""
    return value.array if type(value) is _Pending else np.asarray(value)


def _float_texts(values: np.ndarray) -> list[str]:
    """USD's text of each float32 or float64 of ``values`` (those `acra.floattext` leaves to it)."""
    double = np.asarray(values).dtype == np.float64
    scratch = Sdf.Layer.CreateAnonymous("acra_floats.usda")
    prim = Sdf.CreatePrimInLayer(scratch, "/A")
    Sdf.AttributeSpec(prim, "f", T.DoubleArray if double else T.FloatArray, Sdf.VariabilityVarying, True).default = (
        Vt.DoubleArray if double else Vt.FloatArray).FromNumpy(np.ascontiguousarray(values))
    text = re.search(r"^ +custom \w+\[\] f = \[(.*)\]$", scratch.ExportToString(), re.M).group(1)
    return text.split(", ")


class _SharedText:
    """A ``.usda`` layer whose repeated arrays are formatted once.

    USD's text writer formats every float of every time sample; the free frames of a run share
    one display and one surface (`_Converted`), so most samples repeat an earlier one. Each
    array held by more than one sample is authored as a one-element stand-in (`stand_in`);
    `export` formats each such array once through USD's own writer (a scratch layer holding each
    as a default value, the same text a time sample gets), exports the layer of stand-ins and
    writes its text with each stand-in replaced by its array's text: the bytes USD's writer gives
    for the layer of the arrays themselves, written atomically (`usdio.export_layer`). Should any
    stand-in's text be found other than once per sample it stands for, the arrays are authored
    back and USD writes the layer.
    """

    def __init__(self, samples) -> None:
        """``samples``: every value the layer will hold, each sample once (repeats by identity)."""
        self._uses: dict[int, int] = {}  # id(array) -> samples holding it
        self.chars = 0  # an upper bound of the text held while writing: each distinct array once
        for value in samples:
            vt = _vt_type(value)
            if vt in _STAND_INS and len(value) >= _SHARED_MIN:
                self._uses[id(value)] = self._uses.get(id(value), 0) + 1
            if vt in _CHARS and (self._uses.get(id(value), 0) <= 1):
                self.chars += _CHARS[vt] * len(value)
        self._index: dict[int, int] = {}  # id(array) -> k
        self._arrays: list = []  # k -> array (kept alive while its id is a key)
        self._made: list = []  # k -> its stand-in, authored at every sample (Vt values are shared copy-on-write)
        self._samples: list[tuple[Sdf.Path, float, int]] = []

    def stand_in(self, path: Sdf.Path, time: float | None, value):
        """What to author at ``path`` and ``time`` (``None``: the default value) for ``value``:
        an array held by one sample alone (a collision frame's) whose text USD's writer formats
        is formatted where it stands, with nothing saved."""
        vt = _vt_type(value)
        kind = _STAND_INS.get(vt)
        if kind is None or self._uses.get(id(value), 0) < (1 if vt in _COMPILED else 2):
            return _authored(value)
        k = self._index.get(id(value))
        if k is None:
            k = self._index[id(value)] = len(self._arrays)
            self._arrays.append(value)
            self._made.append(kind[1](k))
        self._samples.append((path, time, k))
        return self._made[k]

    def _texts(self) -> tuple[list[bytes], list[str]]:
        """Each array's text (bytes, or a ``(bytes,) uint8`` array from `floattext.tuples_texts`)
        and its stand-in's text, as USD's text writer formats them: the arrays of `_COMPILED`
        types by `acra.floattext`, the others' by USD's writer (a scratch layer holding each as a
        default value), the stand-ins' from their types' text (`_STAND_INS`)."""
        texts: dict = {"v": [None] * len(self._arrays), "s": [_STAND_INS[_vt_type(value)][2].format(k) for k, value in enumerate(self._arrays)]}
        others = [k for k, value in enumerate(self._arrays) if _vt_type(value) not in _COMPILED]
        if others:
            scratch = Sdf.Layer.CreateAnonymous("acra_arrays.usda")
            with Sdf.ChangeBlock():
                prim = Sdf.CreatePrimInLayer(scratch, "/A")
                for k in others:
                    value = self._arrays[k]
                    Sdf.AttributeSpec(prim, f"v{k}", _STAND_INS[_vt_type(value)][0], Sdf.VariabilityVarying, True).default = _authored(value)
            for m in _SCRATCH_LINE.finditer(scratch.ExportToString()):
                texts["v"][int(m.group(2))] = m.group(3).encode()
        floats = [k for k, value in enumerate(self._arrays) if _vt_type(value) in _FLOATS]
        # each array's text starts from the one authored before it on the same attribute (the
        # previous frame's display): a response moves the points near the contact alone
        place = {k: i for i, k in enumerate(floats)}
        last: dict = {}  # attribute path -> the array authored there last
        refs: list = [None] * len(floats)
        for path, _, k in self._samples:
            j = last.get(path)
            if j is not None and j != k and k in place and refs[place[k]] is None and j in place:
                refs[place[k]] = place[j]
            last[path] = k
        arrays = [_numpy(self._arrays[k]) for k in floats]
        # the attributes' chains are formatted on two sides where a frame may use two threads
        # (`pipeline.workers`): each chain's text is its own, the same bytes on one side or two
        both = workers.both if workers.threads() > 1 else None
        for k, text in zip(floats, floattext.tuples_texts(arrays, _float_texts, refs, both)):
            texts["v"][k] = text
        for k, value in enumerate(self._arrays):
            if _vt_type(value) in _COMPILED and _vt_type(value) not in _FLOATS:
                texts["v"][k] = _COMPILED[_vt_type(value)](value)
        return texts["v"], texts["s"]

    def export(self, layer: Sdf.Layer, out: Path) -> Path:
        if not self._arrays:
            return export_layer(layer, out)
        values, stand_ins = self._texts()
        stand_ins = [t.encode() for t in stand_ins]
        which = {text: k for k, text in enumerate(stand_ins)}
        text = layer.ExportToString().encode()  # the stand-ins' layer: its arrays' text is not in it
        pattern = re.compile(b"|".join(re.escape(t) for t in stand_ins))
        found, expected = [0] * len(self._arrays), [0] * len(self._arrays)
        for _, _, k in self._samples:
            expected[k] += 1
        if all(v is not None for v in values) and len(which) == len(stand_ins):
            for m in pattern.finditer(text):
                found[which[m.group()]] += 1
        if found != expected:
            del text
            with Sdf.ChangeBlock():
                for path, time, k in self._samples:
                    if time is None:
                        layer.GetAttributeAtPath(path).default = _authored(self._arrays[k])
                    else:
                        layer.SetTimeSample(path, time, _authored(self._arrays[k]))
            return export_layer(layer, out)
        return export_layer(_Text(text, pattern, which, values), out)


class _Text:
    """A ``.usda`` layer's ``text`` (UTF-8) whose stand-ins (``pattern``, ``which`` of them) are
    written as their arrays' text ``values`` (bytes or ``uint8`` arrays), as `Sdf.Layer.Export` writes a layer
    (`usdio.export_layer`). The pieces are views of the text and the arrays' texts, handed to the
    file a few hundred at a time (`os.writev`: one system call for them, no copy into a buffer),
    so a long run's text is held once."""

    def __init__(self, text: bytes, pattern: re.Pattern, which: dict, values: list[bytes]) -> None:
        self.text, self.pattern, self.which, self.values = text, pattern, which, values

    def Export(self, path: str) -> bool:  # noqa: N802 (Sdf.Layer's name)
        text = memoryview(self.text)
        pieces, at = [], 0
        for m in self.pattern.finditer(self.text):
            pieces += (text[at:m.start()], self.values[self.which[m.group()]])
            at = m.end()
        pieces.append(text[at:])
        with open(path, "wb", buffering=0) as fh:
            _write_pieces(fh, [memoryview(p) for p in pieces if len(p)])
        return True


def _write_pieces(fh, pieces: list[memoryview]) -> None:
    """Write ``pieces`` in order to the unbuffered file ``fh``, up to 512 a system call where
    the platform gathers writes (`os.writev`), each written whole however the calls split them."""
    if not hasattr(os, "writev"):
        for piece in pieces:
            while len(piece):
                piece = piece[fh.write(piece):]
        return
    i = 0
    while i < len(pieces):
        n = os.writev(fh.fileno(), pieces[i:i + 512])
        while n and i < len(pieces):  # the pieces it wrote, and the rest of one it cut
            if n >= len(pieces[i]):
                n -= len(pieces[i])
                i += 1
            else:
                pieces[i], n = pieces[i][n:], 0


def write_output(input_path: str | os.PathLike, output_path: str | os.PathLike, scene: SceneModel, frames_result: FramesResult) -> Path:
    """Write the output layer: overs of points, normals, topology and response state per frame.

    The layer sublayers ``input_path`` by a path relative to the output's directory, copies the
    input's stage metadata, and holds nothing else (no transform, no ``acra:`` input attribute).
    Every frame must hold a result for every deformable of ``scene``. The file is written
    atomically and deterministically (sorted paths and frames, no timestamps); its format follows
    the suffix (``.usda`` text, ``.usdc``/``.usd`` binary crate, see docs/cli.md for the cost).
    Results that repeat an earlier frame's objects are checked and converted once (`_Converted`),
    and in a ``.usda`` layer their text is formatted once (`_SharedText`).
    """
    inp, out = Path(input_path), Path(output_path)
    meta = _stage_metadata(inp, scene)
    frames = sorted(frames_result.frames)
    models = sorted(scene.deformables, key=lambda m: m.path)
    convert = _Converted()
    # a text layer writes its display arrays from numpy (`_Pending`); a crate stores Vt values
    text_layer = out.suffix == ".usda"
    vec3f = (lambda *a: _Pending(Vt.Vec3fArray, _checked_floats(*a))) if text_layer else _checked_vec3f
    as_vt = (lambda vt, a: _Pending(vt, a)) if text_layer else vt_array  # noqa: E731
    hierarchy = _Hierarchy(as_vt)
    values: dict = {}  # (frame, path) -> {attribute name: value}
    for f in frames:
        per = frames_result.frames[f]
        extra = sorted(set(per) - {m.path for m in models})
        if extra:
            raise ValueError(f"frame {f}: result for {extra[0]}, which is not a deformable of the scene")
        for m in models:
            if m.path not in per:
                raise ValueError(f"frame {f}: no result for {m.path}")
            r, topo = per[m.path], frames_result.topology(m)
            if not math.isfinite(float(r.residual)):
                raise ValueError(f"frame {f}, {m.path}: residual is not finite")
            values[f, m.path] = {
                "points": convert((m.path, "points"), r.points, lambda: vec3f(m, topo, f, "points", r.points)),
                "normals": convert((m.path, "normals"), r.normals, lambda: vec3f(m, topo, f, "normals", r.normals)),
                **convert((m.path, "state"), r.surface, lambda: hierarchy(m, f, r.surface)),
                "acra:response:residual": float(r.residual),
                "acra:response:inCollision": bool(r.in_collision),
            }
            if r.carried is not None:
                from pipeline import state

                values[f, m.path].update(convert((m.path, "carried"), r.carried, lambda: state.carried_values(m, r.carried)))

    int_array = lambda a: as_vt(Vt.IntArray, np.ascontiguousarray(a, dtype=np.int32))  # noqa: E731
    # each display vertex's surface parameter (level-0 units), so a client evaluates any other
    # surface of the object (the input's) at the same sites
    sites = {m.path: as_vt(Vt.Vec2dArray, np.ascontiguousarray(np.stack([frames_result.topology(m).u, frames_result.topology(m).v], axis=1),
                                                                dtype=np.float64)) for m in models}
    topologies = {m.path: (int_array(frames_result.topology(m).counts), int_array(frames_result.topology(m).indices)) for m in models}
    layer = Sdf.Layer.CreateAnonymous(f"acra_output{out.suffix or '.usda'}")
    shared = _Direct()
    if text_layer:
        text = _SharedText([v for per in values.values() for v in per.values()] + [a for t in topologies.values() for a in t] + list(sites.values()))
        if text.chars <= TEXT_HELD_MAX:
            shared = text
    with Sdf.ChangeBlock():
        layer.subLayerPaths.append(_relative_asset(inp, out.parent))
        for key, value in meta.items():
            if value is not None:
                layer.pseudoRoot.SetInfo(key, value)
        for m in models:
            prim = Sdf.CreatePrimInLayer(layer, m.path)
            for name, value in zip(("faceVertexCounts", "faceVertexIndices"), topologies[m.path]):
                spec = _spec(prim, name, T.IntArray, False)
                spec.default = shared.stand_in(spec.path, None, value)
            uv = Sdf.AttributeSpec(prim, DISPLAY_UV, T.Double2Array, Sdf.VariabilityUniform, True)
            uv.default = shared.stand_in(uv.path, None, sites[m.path])
            normals = _spec(prim, "normals", T.Normal3fArray, False)
            normals.SetInfo("interpolation", UsdGeom.Tokens.vertex)
            specs = {
                "points": _spec(prim, "points", T.Point3fArray, False).path,
                "normals": normals.path,
                **{n: _spec(prim, n, tn, True).path for n, tn in RESPONSE_TYPES.items()},
            }
            if any(frames_result.frames[f][m.path].carried is not None for f in frames):
                specs.update({n: _spec(prim, n, tn, True).path for n, tn in STATE_TYPES.items()})
            for f in frames:
                for name, value in values[f, m.path].items():
                    layer.SetTimeSample(specs[name], float(f), shared.stand_in(specs[name], float(f), value))
    return shared.export(layer, out)


def read_output_hierarchy(stage: Usd.Stage, prim_path: str, t: float) -> HSpline:
    """The response state written at time code ``t``: level-0 CVs plus the full hierarchy."""
    prim = stage.GetPrimAtPath(prim_path)
    if not prim:
        raise KeyError(f"no prim at {prim_path}")
    tc = Usd.TimeCode(float(t))
    nu, nv = _grid_size(prim)
    get = lambda n, dt, shape: np.array(prim.GetAttribute(n).Get(tc), dtype=dt).reshape(shape)  # noqa: E731
    cvs = flat_to_cvs(get("acra:response:cvs", np.float64, (-1, 3)), nu, nv)
    arrays = HierarchyArrays(
        patch_level=get("acra:response:patchLevel", np.int32, (-1,)),
        patches=get("acra:response:patches", np.int32, (-1, 2)),
        offset_level=get("acra:response:offsetLevel", np.int32, (-1,)),
        offset_cvs=get("acra:response:offsetCvs", np.int32, (-1, 2)),
        offsets=get("acra:response:offsets", np.float64, (-1, 3)),
    )
    return from_arrays(_base(prim, cvs), arrays)


def _grid_size(prim: Usd.Prim) -> tuple[int, int]:
    """A deformable's level-0 grid size ``(nu, nv)``."""
    return int(prim.GetAttribute("acra:uCount").Get()), int(prim.GetAttribute("acra:vCount").Get())


def _base(prim: Usd.Prim, cvs: np.ndarray) -> HSpline:
    """The level-0 surface of level-0 ``cvs (nu, nv, 3)`` on the deformable's wraps and levels."""
    wrap = lambda n: WRAPS[str(prim.GetAttribute(n).Get() or "open")]  # noqa: E731
    levels_attr = prim.GetAttribute("acra:levels")
    levels = int(levels_attr.Get()) if levels_attr and levels_attr.HasAuthoredValue() else 1
    return from_grid(cvs, wrap("acra:uWrap"), wrap("acra:vWrap"), depth=levels)


def read_display_uv(stage: Usd.Stage, prim_path: str) -> np.ndarray:
    """Each output display vertex's surface parameter ``(n, 2) float64`` (level-0 units), as
    written in ``acra:display:uv``: evaluating any surface of the object there gives points on the
    output's topology, vertex for vertex."""
    attr = stage.GetPrimAtPath(prim_path).GetAttribute(DISPLAY_UV)
    if not attr or not attr.HasAuthoredValue():
        raise KeyError(f"{prim_path}: no {DISPLAY_UV}")
    return np.asarray(attr.Get(), dtype=np.float64).reshape(-1, 2)


def read_display_topology(stage: Usd.Stage, prim_path: str) -> MeshTopology:
    """The output's display topology of a deformable: its ``faceVertexCounts``,
    ``faceVertexIndices`` and each vertex's surface parameter (`read_display_uv`)."""
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath(prim_path))
    uv = read_display_uv(stage, prim_path)
    return MeshTopology(uv[:, 0], uv[:, 1], np.asarray(mesh.GetFaceVertexCountsAttr().Get(), np.int64),
                        np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), np.int64))


def input_points(stage: Usd.Stage, prim_path: str, t: float | None = None) -> np.ndarray:
    """The animator's surface (``acra:cvs`` at time code ``t``, the default value if ``None``,
    with the ``acra:hierarchy:*`` offsets) at the output's display vertices (`read_display_uv`),
    rounded to float32 as a layer stores points: ``(n, 3) float64``, vertex for vertex comparable
    with the output's ``points`` however the run refined the display. ``stage`` is the output
    layer's stage (the input shows through it)."""
    prim = stage.GetPrimAtPath(prim_path)
    topology = read_display_topology(stage, prim_path)
    tc = Usd.TimeCode.Default() if t is None else Usd.TimeCode(float(t))
    cvs = flat_to_cvs(np.asarray(prim.GetAttribute("acra:cvs").Get(tc), np.float64), *_grid_size(prim))
    surface = from_arrays(_base(prim, cvs), read_hierarchy(prim))
    det = details(surface) if surface.depth > 1 else None
    points, _ = grid_samples(surface, topology, det)
    return points.astype(np.float32).astype(np.float64)
