"""Frame results as plain arrays, part files of frame ranges, and their merge into the output layer.

A run's frames are independent (each starts from the animator's shape, `pipeline.frames`), so a
shot can be split into frame ranges run anywhere and put back together. This module holds what
travels between the pieces:

* **records**: one frame's results as plain NumPy arrays (`records_from_result`), what a Dask
  task returns (`pipeline.farm`) and what a part file stores. They carry the *responded H-spline*
  (level-0 CVs and the full hierarchy, what `output_layer.write_output` writes as ``acra:response:*``),
  not only display points, so the assembly can recompute anything that depends on the whole run
  (a display topology chosen from the union of all frames' refinements) from the surfaces.
* **part files** (`write_part`, `read_part`): the records of one frame range plus what they came
  from: the input stage's path, its identity (`input_identity`, a content hash of every layer the
  stage uses), the run's options and the per-frame statistics. A part is an ``.npz`` archive read
  with ``allow_pickle=False``: data, never code.
* **the merge** (`merge_parts`): checks that the parts form one run of one input (same identity
  and options, no frame twice, no frame missing) and writes the one output layer of contract §2
  through `assemble` and `output_layer.write_output`, the same bytes as a single-process run.

Record layout, per frame and deformable (``records[frame][prim path][field]``):

=============== ==================== =====================================================
field           shape, dtype         meaning
=============== ==================== =====================================================
points          (n, 3) float64       display tessellation points (object space)
normals         (n, 3) float64       their unit normals
cvs             (nu, nv, 3) float64  responded level-0 CVs (``cvs[i, j]``)
patch_level     (m,) int32           `acra.hspline.HierarchyArrays` of the responded surface
patches         (m, 2) int32
offset_level    (c,) int32
offset_cvs      (c, 2) int32
offsets         (c, 3) float64
residual        () float64           remaining penetration (scene units)
in_collision    () bool              detection found the object in collision
stateful        () bool              the object carries offsets out of this frame
elastic_*       as cvs ... offsets   the carried elastic field (`acra.relax.Carried`), same
plastic_*                            layout as the surface's fields; empty when not stateful
=============== ==================== =====================================================
"""

from __future__ import annotations

import hashlib
import io
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from acra.hspline import HierarchyArrays, from_arrays, from_grid, to_arrays
from pipeline import guard
from pipeline.model import InputError, SceneModel

__all__ = [
    "PART_SUFFIX",
    "PART_FORMAT",
    "RECORD_FIELDS",
    "STAT_FIELDS",
    "Part",
    "input_identity",
    "used_layer_paths",
    "records_from_result",
    "assemble",
    "stats_table",
    "stats_from_table",
    "frame_spans",
    "part_name",
    "write_part",
    "read_part",
    "check_parts",
    "merge_parts",
]

PART_SUFFIX = ".acrapart.npz"
PART_FORMAT = "acra-part/2"
RECORD_FIELDS = {
    "points": np.float64,
    "normals": np.float64,
    "cvs": np.float64,
    "patch_level": np.int32,
    "patches": np.int32,
    "offset_level": np.int32,
    "offset_cvs": np.int32,
    "offsets": np.float64,
    "residual": np.float64,
    "in_collision": np.bool_,
    "stateful": np.bool_,
}
_HIERARCHY_FIELDS = {name: RECORD_FIELDS[name] for name in ("cvs", "patch_level", "patches", "offset_level", "offset_cvs", "offsets")}
for _field in ("elastic", "plastic"):
    RECORD_FIELDS.update({f"{_field}_{name}": dtype for name, dtype in _HIERARCHY_FIELDS.items()})
_SHAPE_FIELDS = ("cvs", "patch_level", "patches", "offset_level", "offset_cvs", "offsets", "points", "normals")
# the `pipeline.frames.FrameStats` fields a part keeps: what the summary and a report read
STAT_FIELDS = {
    "frame": np.int64,
    "in_collision": np.bool_,
    "iterations": np.int64,
    "hold": np.bool_,
    "residual": np.float64,
    "residual_rel": np.float64,
    "ms_setup": np.float64,
    "ms_detect": np.float64,
    "ms_convert": np.float64,
    "ms_respond": np.float64,
    "ms_visible": np.float64,
    "ms_output": np.float64,
    "ms_total": np.float64,
}


# --------------------------------------------------------------------------------------------
# identity of an input


def used_layer_paths(stage) -> list[Path]:
    """Files of every layer ``stage`` uses (root, sublayers, references, payloads), sorted.

    Anonymous layers (the session layer) have no file and are left out.
    """
    paths = {Path(layer.realPath).resolve() for layer in stage.GetUsedLayers() if not layer.anonymous and layer.realPath}
    return sorted(paths)


def input_identity(stage) -> str:
    """A content hash of the input: SHA-256 over every used layer's bytes and its path relative
    to the root layer's directory.

    Relative paths keep the identity the same where a shot's directory is mounted at another
    place (farm machines); any edit to any layer changes it.
    """
    root_dir = Path(stage.GetRootLayer().realPath).resolve().parent
    h = hashlib.sha256()
    for p in used_layer_paths(stage):
        h.update(os.path.relpath(p, root_dir).encode())
        h.update(b"\0")
        h.update(hashlib.sha256(p.read_bytes()).digest())
    return h.hexdigest()


# --------------------------------------------------------------------------------------------
# records


def _hierarchy_fields(surface, prefix: str = "") -> dict:
    """A surface's level-0 CVs and `acra.hspline.HierarchyArrays` as record fields (lossless);
    ``surface=None`` gives empty arrays."""
    if surface is None:
        empty = {"cvs": (0, 0, 3), "patch_level": (0,), "patches": (0, 2), "offset_level": (0,), "offset_cvs": (0, 2),
                 "offsets": (0, 3)}
        return {prefix + name: np.zeros(shape, _HIERARCHY_FIELDS[name]) for name, shape in empty.items()}
    a = to_arrays(surface)
    return {prefix + "cvs": np.asarray(surface.cvs, dtype=np.float64), prefix + "patch_level": a.patch_level,
            prefix + "patches": a.patches, prefix + "offset_level": a.offset_level, prefix + "offset_cvs": a.offset_cvs,
            prefix + "offsets": a.offsets}


def _hierarchy_from(r: dict, model, prefix: str = ""):
    """`_hierarchy_fields` back to a surface on the deformable's own grid."""
    arrays = HierarchyArrays(r[prefix + "patch_level"], r[prefix + "patches"], r[prefix + "offset_level"],
                             r[prefix + "offset_cvs"], r[prefix + "offsets"])
    return from_arrays(from_grid(r[prefix + "cvs"], model.u_periodic, model.v_periodic, depth=model.depth), arrays)


def records_from_result(result) -> dict:
    """`output_layer.FramesResult` to records (module docstring): plain arrays, picklable, no USD."""
    records: dict = {}
    for frame, per in result.frames.items():
        out = records.setdefault(int(frame), {})
        for path, r in per.items():
            carried = r.carried
            out[str(path)] = {
                "points": np.zeros((0, 3)) if r.points is None else np.asarray(r.points, dtype=np.float64),
                "normals": np.zeros((0, 3)) if r.normals is None else np.asarray(r.normals, dtype=np.float64),
                **_hierarchy_fields(r.surface),
                "residual": np.float64(r.residual),
                "in_collision": np.bool_(r.in_collision),
                "stateful": np.bool_(carried is not None),
                **_hierarchy_fields(None if carried is None else carried.elastic, "elastic_"),
                **_hierarchy_fields(None if carried is None else carried.plastic, "plastic_"),
            }
    return records


def assemble(scene: SceneModel, records: dict):
    """Records of all frames to the `output_layer.FramesResult` that `output_layer.write_output` writes.

    Each responded surface is rebuilt from its arrays on the deformable's own grid
    (`acra.hspline.from_arrays`, lossless), so whatever the output derives from the surfaces is
    derived here from all frames at once. Records are not modified.
    """
    from acra.relax import Carried
    from pipeline import output_layer

    models = {m.path: m for m in scene.deformables}
    result = output_layer.FramesResult()
    previous: dict = {}  # path -> (record, DeformableResult) of the frame before
    for frame in sorted(records):
        for path in sorted(records[frame]):
            r, m = records[frame][path], models[path]
            last = previous.get(path)
            if last is not None and all(np.array_equal(r[n], last[0][n]) for n in _SHAPE_FIELDS):
                # a free frame repeating the frame before: hand back the same objects, as the frame
                # loop does, so the writer converts them once (`output_layer._Converted`)
                done = last[1]
                points, normals, surface = done.points, done.normals, done.surface
            else:  # a frame responded but not yet displayed has no points (`display.finish`)
                points, normals, surface = r["points"], r["normals"], _hierarchy_from(r, m)
                points, normals = (None, None) if not len(points) else (points, normals)
            carried = Carried(_hierarchy_from(r, m, "elastic_"), _hierarchy_from(r, m, "plastic_")) if r["stateful"] else None
            out = output_layer.DeformableResult(points, normals, surface, float(r["residual"]), bool(r["in_collision"]), carried)
            previous[path] = (r, out)
            result.add(frame, path, out)
    return result


def stats_table(stats: list) -> dict:
    """`STAT_FIELDS` of a list of `frames.FrameStats` as columns ``{field: (n,) array}``."""
    return {name: np.array([getattr(s, name) for s in stats], dtype=dtype) for name, dtype in STAT_FIELDS.items()}


def stats_from_table(table: dict) -> list:
    """`stats_table`'s columns back to `frames.FrameStats` (the other fields left empty)."""
    from pipeline.frames import FrameStats

    n = len(table["frame"])
    return [FrameStats(**{name: table[name][k].item() for name in STAT_FIELDS}) for k in range(n)]


def frame_spans(frames) -> str:
    """Sorted integer frames as spans: ``[1, 2, 3, 7, 9, 10]`` -> ``"1-3, 7, 9-10"``."""
    frames = sorted(set(int(f) for f in frames))
    spans, k = [], 0
    while k < len(frames):
        j = k
        while j + 1 < len(frames) and frames[j + 1] == frames[j] + 1:
            j += 1
        spans.append(f"{frames[k]}" if j == k else f"{frames[k]}-{frames[j]}")
        k = j + 1
    return ", ".join(spans)


def _frames_are(frames) -> str:
    """``"frame 4 is"`` or ``"frames 2-3, 5 are"``, for the merge's messages."""
    return f"frame {frame_spans(frames)} is" if len(set(frames)) == 1 else f"frames {frame_spans(frames)} are"


# --------------------------------------------------------------------------------------------
# part files


@dataclass
class Part:
    """One part file read back.

    Attributes
    ----------
    path : Path
    meta : dict
        ``format``, ``input`` (absolute path of the USD stage read), ``identity``
        (`input_identity`), ``options`` (the `frames.RunOptions` fields), ``frames`` (sorted
        list of int), ``deformables`` (sorted prim paths).
    records : dict
        ``records[frame][prim path][field]`` (module docstring).
    stats : dict
        `stats_table` columns, one row per frame.
    """

    path: Path
    meta: dict
    records: dict
    stats: dict


def part_name(stage_path: Path, frames: list[int]) -> str:
    """``<stage stem>.<first>_<last>.acrapart.npz``: names sort by stage, then first frame."""
    return f"{Path(stage_path).stem}.{min(frames):06d}_{max(frames):06d}{PART_SUFFIX}"


def write_part(directory, stage_path, identity: str, options, records: dict, stats: list) -> Path:
    """Write the records and statistics of one frame range as a part in ``directory``, atomically.

    ``options`` is the run's `frames.RunOptions`; ``directory`` is created if missing. Returns the
    part's path (`part_name`), replaced if it exists (a farm task run again writes the same part).
    """
    directory = Path(directory)
    frames = sorted(records)
    if not frames:
        raise ValueError("a part needs at least one frame")
    paths = sorted(records[frames[0]])
    meta = {
        "format": PART_FORMAT,
        "input": str(Path(stage_path).resolve()),
        "identity": identity,
        "options": {"iterations": options.iterations, "tolerance": options.tolerance, "method": options.method, "density": options.density},
        "frames": frames,
        "deformables": paths,
    }
    arrays = {"meta": np.array(json.dumps(meta, sort_keys=True))}
    for f in frames:
        for k, path in enumerate(paths):
            for name, dtype in RECORD_FIELDS.items():
                arrays[f"r{f}_{k}_{name}"] = np.asarray(records[f][path][name], dtype=dtype)
    for name, column in stats_table(sorted(stats, key=lambda s: s.frame)).items():
        arrays[f"stat_{name}"] = column
    directory.mkdir(parents=True, exist_ok=True)
    out = directory / part_name(stage_path, frames)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    with guard.atomic_file(out) as tmp:
        tmp.write_bytes(buf.getvalue())
    return out


def read_part(path) -> Part:
    """Read a part file; anything that is not a complete part is an `InputError` naming the file."""
    path = Path(path)
    name = str(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as exc:
        raise InputError(name, None, f"not a readable ACRA part: {type(exc).__name__}: {' '.join(str(exc).split())}") from exc
    try:
        meta = json.loads(str(data["meta"]))
        if meta.get("format") != PART_FORMAT:
            raise InputError(name, None, f"part format {meta.get('format')!r}, expected {PART_FORMAT!r}")
        frames = [int(f) for f in meta["frames"]]
        paths = list(meta["deformables"])
        records = {f: {p: {n: data[f"r{f}_{k}_{n}"] for n in RECORD_FIELDS} for k, p in enumerate(paths)} for f in frames}
        stats = {n: data[f"stat_{n}"] for n in STAT_FIELDS}
        for key in ("input", "identity", "options"):
            meta[key]  # noqa: B018 (a missing key is a broken part)
    except InputError:
        raise
    except (KeyError, ValueError, TypeError) as exc:
        raise InputError(name, None, f"incomplete ACRA part: missing or bad {exc}") from exc
    if sorted(int(f) for f in stats["frame"]) != frames:
        raise InputError(name, None, "incomplete ACRA part: statistics do not match its frames")
    return Part(path, meta, records, stats)


def check_parts(parts: list[Part], expected: list[int]) -> None:
    """Refuse parts that are not exactly one run of one input over the ``expected`` frames.

    Raises `InputError` naming the parts involved: different inputs (path or identity),
    different options, a frame in two parts, frames no part holds, frames outside ``expected``.
    """
    first = parts[0]
    for p in parts[1:]:
        for key, what in (("identity", "inputs"), ("input", "inputs"), ("options", "options")):
            if p.meta[key] != first.meta[key]:
                a, b = first.meta[key], p.meta[key]
                if key == "identity":
                    a, b = f"{first.meta['input']} (identity {a[:12]})", f"{p.meta['input']} (identity {b[:12]})"
                raise InputError(str(p.path), None, f"parts of different {what}: {first.path.name} has {a}, {p.path.name} has {b}")
    owner: dict = {}
    for p in parts:
        twice = [f for f in p.meta["frames"] if f in owner]
        if twice:
            other = owner[twice[0]]
            both = [f for f in twice if owner[f] is other]
            raise InputError(str(p.path), None, f"{_frames_are(both)} also in {other.path.name}")
        owner.update({f: p for f in p.meta["frames"]})
    outside = sorted(set(owner) - set(expected))
    if outside:
        raise InputError(str(owner[outside[0]].path), None, f"{_frames_are(outside)} outside the expected {min(expected)}:{max(expected)}")
    missing = sorted(set(expected) - set(owner))
    if missing:
        raise InputError(str(first.path.parent), None, f"{_frames_are(missing)} missing: no part holds them")


def merge_parts(directory, output=None, frames: list[int] | None = None) -> tuple:
    """`acra merge DIR [-o OUT] [--frames A:B]`: check the parts and write the output layer.

    The parts' input stage is opened from the path they record and must still have their
    identity. Expected frames are ``frames`` or else the stage's time codes. ``output`` defaults to ``<input stem>.acra.usda`` beside the input; an output that
    is a layer the input uses is refused. Nothing is written unless every check passes.

    Returns
    -------
    (output path, list of `frames.FrameStats`, milliseconds writing, the scene, the stage path)
    """
    import time

    from pipeline import output_layer, usdio

    directory = Path(directory)
    if not directory.is_dir():
        raise InputError(str(directory), None, "no such directory")
    files = sorted(directory.glob(f"*{PART_SUFFIX}"))
    if not files:
        raise InputError(str(directory), None, f"holds no ACRA parts (*{PART_SUFFIX})")
    parts = [read_part(f) for f in files]
    stage_path = Path(parts[0].meta["input"])
    out = Path(output) if output else stage_path.with_name(stage_path.stem + ".acra.usda")
    stage = usdio.open_input(stage_path)
    if out.resolve() in used_layer_paths(stage):
        raise InputError(str(out), None, f"is a layer the input {stage_path} uses: refusing to overwrite it")
    identity = input_identity(stage)
    if identity != parts[0].meta["identity"]:
        raise InputError(str(stage_path), None, f"changed since the parts were written (identity {identity[:12]}, parts {parts[0].meta['identity'][:12]})")
    scene = usdio.read_scene(stage)
    expected = list(range(scene.start, scene.end + 1)) if frames is None else list(frames)
    check_parts(parts, expected)
    names = sorted(m.path for m in scene.deformables)
    for p in parts:
        if p.meta["deformables"] != names:
            raise InputError(str(p.path), None, f"holds deformables {', '.join(p.meta['deformables'])}; the input has {', '.join(names)}")
    records = {f: r for p in parts for f, r in p.records.items()}
    stats = sorted((s for p in parts for s in stats_from_table(p.stats)), key=lambda s: s.frame)
    from pipeline import display, frames as frame_loop

    result = assemble(scene, records)
    options = frame_loop.RunOptions(**parts[0].meta["options"])
    display.finish(stage, scene, result, stats, options)  # the run's display and residuals, from all parts
    tw = time.perf_counter()
    output_layer.write_output(stage_path, out, scene, result)
    return out, stats, 1e3 * (time.perf_counter() - tw), scene, stage_path
