"""What `acra run` checks before it reads or writes anything: that no output is an input, and that
the run fits in memory; and the signal handling that makes SIGTERM stop a run like Ctrl-C.

Paths
-----
`protected_paths` lists every file a run reads (the input stage, the scene file and the ``.usda``
it exports, and every layer the stage's layer stack, references and payloads bring in, through
`UsdUtils.ComputeAllDependencies`); `refuse_overwrite` raises an `InputError` when an output
(``-o``, ``--rrd``, ``--report``) resolves to one of them or to another output. Two paths are the
same file when `os.path.samefile` says so (symlinks, hard links, ``..``, case on a
case-insensitive file system) and, where either does not exist yet, when their normalised real
paths are equal.

Memory
------
`predict_memory` estimates, from attribute values alone (level-0 grid, ``acra:levels``,
``acra:absorption``, ``acra:refine``, ``acra:samples``, the animator's hierarchy, collider
triangle counts and the frame count), the peak memory of a run, and `check_budget` refuses a stage
whose estimate exceeds the budget (`memory_budget`: half the physical memory unless
``--memory-budget`` or ``ACRA_MEMORY_BUDGET`` says otherwise) with one line naming the prim, the
attribute that drives the estimate and the predicted size. It runs before `usdio.read_scene`
builds anything, so nothing large is allocated before the check.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
import signal
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Usd, UsdGeom, UsdUtils

from pipeline.model import InputError

__all__ = [
    "Terminated",
    "interruption",
    "raise_arrived",
    "terminate_raises",
    "signals_held",
    "same_file",
    "protected_paths",
    "refuse_overwrite",
    "parse_size",
    "format_size",
    "memory_budget",
    "Estimate",
    "predict_memory",
    "check_budget",
    "MAX_KEY",
    "atomic_file",
    "temporary_sibling",
]


# --------------------------------------------------------------------------------------------
# signals


class Terminated(BaseException):
    """SIGTERM arrived: unwinds the run like `KeyboardInterrupt` (every ``finally`` and
    ``except BaseException`` cleanup runs, so no temporary file survives); exit status 143."""


def _signalled(signum: int) -> BaseException:
    """The exception a run unwinds with for ``signum``."""
    return Terminated(signum) if signum == signal.SIGTERM else KeyboardInterrupt()


# each open `terminate_raises` block's record of the signals that arrived in it, innermost last
_BLOCKS: list[list[int]] = []


def interruption(err: BaseException, arrived: list[int] | tuple = ()) -> BaseException | None:
    """The `KeyboardInterrupt` or `Terminated` that ``err`` carries, or, where it carries none,
    the first signal of ``arrived`` (`terminate_raises`' record) as one; else ``None``.

    A signal's handler runs at the next point the interpreter checks for signals. Inside a
    compiled kernel's call that can be Python code the kernel's wrapper runs (boxing its result),
    whose C caller then returns its result with the handler's exception set: Python reports that
    as a `SystemError` caused by it. A C call may also replace the handler's exception with its
    own error, without a cause (numpy's comparison of two arrays reports "cannot compare" when
    the comparison it tried failed): the record of the signals that arrived names it then. The run
    was interrupted all the same."""
    seen = set()
    while err is not None and id(err) not in seen:
        if isinstance(err, (KeyboardInterrupt, Terminated)):
            return err
        seen.add(id(err))
        err = err.__cause__ or err.__context__
    return _signalled(arrived[0]) if arrived else None


def raise_arrived() -> None:
    """Raise the first signal that arrived inside the innermost `terminate_raises` block as its
    exception. A handler's exception raised where the interpreter only reports it (a weak
    reference's callback, a ``__del__``) is lost, and the run would go on: this is where it
    stops instead (between frames, before a run's files are renamed into place)."""
    if _BLOCKS and _BLOCKS[-1]:
        raise _signalled(_BLOCKS[-1][0])


@contextlib.contextmanager
def terminate_raises():
    """SIGTERM raises `Terminated` and SIGINT `KeyboardInterrupt` inside the block (SIGINT only
    where it has Python's default handler), each recorded as it arrives; yields the record
    ``(k,) list of int`` for `interruption` (main thread only; elsewhere a no-op that yields an
    empty record)."""
    arrived: list[int] = []

    def raised(signum, frame):
        arrived.append(signum)
        raise _signalled(signum)

    try:
        previous = {signal.SIGTERM: signal.signal(signal.SIGTERM, raised)}
    except ValueError:  # not the main thread: signals cannot be handled here
        yield arrived
        return
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        previous[signal.SIGINT] = signal.signal(signal.SIGINT, raised)
    _BLOCKS.append(arrived)
    try:
        yield arrived
    finally:
        _BLOCKS.pop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)


@contextlib.contextmanager
def signals_held():
    """SIGINT and SIGTERM do nothing inside the block (the final renames of a run's files, a few
    microseconds): a run that gets there completes and has written everything, so a signal then
    is dropped rather than reported as "nothing written" (main thread; elsewhere a no-op). A
    signal that arrived before the block and whose exception was lost (`raise_arrived`) stops the
    run at its entry, before anything is renamed."""
    raise_arrived()
    held = (signal.SIGINT, signal.SIGTERM)
    try:
        previous = {sig: signal.signal(sig, lambda signum, frame: None) for sig in held}
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


# --------------------------------------------------------------------------------------------
# paths


def _normalised(path: Path) -> str:
    return os.path.normcase(os.path.realpath(os.path.abspath(path)))


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether ``a`` and ``b`` name one file: `os.path.samefile` where both exist (links, case on
    a case-insensitive file system), else equal normalised real paths."""
    a, b = Path(a), Path(b)
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return _normalised(a) == _normalised(b)


def protected_paths(src: Path, stage_path: Path | None = None, held: list | None = None) -> list[Path]:
    """Every file a run on ``src`` reads: ``src``; for a scene file (``.py``) the ``.usda`` it
    exports; and every layer of the stage's layer stack, references and payloads (resolved by
    USD). A stage USD cannot open yet contributes only its own path (opening reports it).

    ``held``: where given, the layers USD opened for the walk (``Sdf.Layer``) are appended to it,
    so a caller that opens the stage next while holding them finds them loaded instead of parsing
    each file again (`usdio.open_input` reloads a loaded layer only when its file changed)."""
    src = Path(src)
    paths = [src]
    usd = Path(stage_path) if stage_path is not None else (src.with_suffix(".usda") if src.suffix == ".py" else src)
    if usd != src:
        paths.append(usd)
    if usd.is_file():
        try:
            layers, _assets, _unresolved = UsdUtils.ComputeAllDependencies(str(usd.resolve()))
        except Exception:  # a broken file: open_input names it; the direct path is protected
            layers = []
        if held is not None:
            held.extend(layers)
        for layer in layers:
            real = getattr(layer, "realPath", "")
            if real:
                paths.append(Path(real))
    return paths


def refuse_overwrite(option: str, path: Path | None, protected: list[Path]) -> None:
    """Raise `InputError` naming ``option`` when ``path`` is one of ``protected`` (the input
    first, as `protected_paths` lists them)."""
    if path is None:
        return
    for p in protected:
        if same_file(path, p):
            what = "the input" if same_file(p, protected[0]) else f"a file the run reads ({p})"
            raise InputError(option, None, f"{path} is {what}; refusing to overwrite it (choose another path)")


# --------------------------------------------------------------------------------------------
# memory


_UNITS = {"": 1, "b": 1, "k": 2**10, "kb": 2**10, "kib": 2**10, "m": 2**20, "mb": 2**20, "mib": 2**20,
          "g": 2**30, "gb": 2**30, "gib": 2**30, "t": 2**40, "tb": 2**40, "tib": 2**40}


def parse_size(text: str, name: str = "--memory-budget") -> int:
    """Bytes of a size such as ``8G``, ``512MiB``, ``2e9`` (binary units)."""
    m = re.fullmatch(r"\s*([0-9.eE+]+)\s*([a-zA-Z]*)\s*", str(text))
    try:
        value = float(m.group(1)) * _UNITS[m.group(2).lower()] if m else math.nan
    except (KeyError, ValueError):
        value = math.nan
    if not math.isfinite(value) or value <= 0:
        raise InputError(name, None, f"expected a positive size such as 8G or 512M, got {text!r}")
    return int(value)


def format_size(nbytes: float) -> str:
    """``~40 GB``-style text (binary units, 2 significant figures); astronomically large sizes as
    a power of two."""
    if not math.isfinite(nbytes) or nbytes >= 2.0**60:
        return f"~2^{math.log2(nbytes):.0f} bytes" if math.isfinite(nbytes) else "an unbounded amount"
    for unit, scale in (("PB", 2**50), ("TB", 2**40), ("GB", 2**30), ("MB", 2**20), ("kB", 2**10)):
        if nbytes >= scale:
            x = nbytes / scale
            return f"~{x:.2g} {unit}" if x < 10 else f"~{x:.0f} {unit}"
    return f"~{nbytes:.0f} bytes"


def physical_memory() -> int:
    """Bytes of physical memory (``SC_PHYS_PAGES``), or 8 GiB where the system does not say."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 8 * 2**30


BUDGET_FRACTION = 0.5


def memory_budget(option: str | None = None) -> int:
    """The run's memory budget in bytes: ``option`` (``--memory-budget``), else the environment
    variable ``ACRA_MEMORY_BUDGET``, else half the physical memory (the rest is the machine's)."""
    if option is not None:
        return parse_size(option)
    env = os.environ.get("ACRA_MEMORY_BUDGET")
    if env:
        return parse_size(env, "ACRA_MEMORY_BUDGET")
    return int(BUDGET_FRACTION * physical_memory())


# The hierarchy indexes level-k patches by int64 keys that run over every level up to k
# (`acra.hspline.HSpline._terms_index`): the sum of P0u 2^k * P0v 2^k must stay below 2^63.
MAX_KEY = 2**62

# Bytes per item, measured with /usr/bin/time -v (docs/cli.md, "Resource bounds"). A CV of a
# refined level carries its offset, detail vector, 3x3 frame, patch rows and the evaluation
# blocks built for it: ~8 kB each on a sheet pressed all over with up to ~400 CVs moved. The
# response's dense systems add ~39 N^2 bytes for N CVs moved by one contact (1,225 CVs +58 MB,
# 4,489 CVs +794 MB); that term depends on the contact's extent, which the inputs do not bound,
# so each solve checks it against the budget itself (`acra.interpolate.dense_bytes`).
BYTES_PER_CV = 8192
# a display vertex: its (u, v), quad and patch indices, points, limit normals and normals per
# distinct frame, and their float32 copies in the output layer
BYTES_PER_DISPLAY_VERTEX = 400
# a collision-grid vertex (`shape.Shape.grids_for`, at most max_density steps per patch edge)
BYTES_PER_COLLISION_VERTEX = 200
# a collider triangle: the mesh, its fcl BVH (OBBRSS), its embree scene and the residual's solid
# (welded mesh, pseudo-normals, BVH): runs pressing a sheet with 250,000, 1,000,000 and 2,000,000
# triangles peak 2.9, 2.8 and 2.7 kB a triangle above a small run's peak (benchmarks/stress.py)
BYTES_PER_COLLIDER_TRIANGLE = 3200
# a processed frame's statistics and Vt arrays besides the display arrays
BYTES_PER_FRAME = 4096
# the interpreter with numpy, scipy, pxr, trimesh, fcl and numba's kernels loaded: a 3-frame run of
# a 4x4 sheet and a box peaks at 315 MB (benchmarks/stress.py)
BASELINE = 330 * 2**20


@dataclass(frozen=True)
class Estimate:
    """A predicted memory need: ``nbytes`` in total and, per (prim, attribute, what), the share
    that drives it (``parts``: list of ``(prim, attribute, nbytes, text)``)."""

    nbytes: float
    parts: list


def _grid_cvs(patches0: int, periodic: bool, k: int) -> int:
    """CVs along one direction of a level-k grid refined everywhere (Python int: no overflow)."""
    return patches0 * 2**k + (0 if periodic else 3)


def predict_deformable(path: str, nu: int, nv: int, u_periodic: bool, v_periodic: bool, levels: int,
                       absorption, refine: bool, samples: int, hierarchy_levels, frames: int,
                       collision_density: int = 8, max_density: int = 64) -> list[tuple[str, str, float, str]]:
    """The memory shares of one deformable (see `predict_memory`).

    ``hierarchy_levels`` : (m,) int — the level of every refined patch the animator authored.
    """
    pu = nu if u_periodic else nu - 3
    pv = nv if v_periodic else nv - 3
    parts = []
    top = levels - 1
    # 4^k patches per level-0 patch on level k: past 32 levels no grid fits 64-bit keys, so the
    # sums below stop there (a levels value of 2^31 must not loop 2^31 times)
    keys = sum(pu * 2**k * pv * 2**k for k in range(min(levels, 33)))
    if keys > MAX_KEY:
        need = float(_grid_cvs(pu, u_periodic, top) * _grid_cvs(pv, v_periodic, top)) * BYTES_PER_CV if top < 512 else math.inf
        parts.append((path, "acra:levels", math.inf,
                      f"{levels} levels would need {format_size(need)} refined everywhere, and level {top} has "
                      f"more patches than the hierarchy's 64-bit keys can index"))
        return parts
    # the response refines, where contact asks, up to the finest absorbing level (acra:refine =
    # refine; obey never refines): the worst case is that level everywhere, with every coarser
    # level (refinement is nested). The animator's hierarchy is counted as authored: at most 16
    # CVs per refined patch, so detail that is local costs its area only.
    shares = [float(a) for a in absorption]
    absorbing = [k for k, a in enumerate(shares) if a > 0]
    reach = min(absorbing[-1], top) if (absorbing and refine) else 0
    authored_levels = [int(k) for k in hierarchy_levels if 0 <= int(k) <= top]  # others: validation names them
    finest = max([reach] + authored_levels)
    grid = {k: _grid_cvs(pu, u_periodic, k) * _grid_cvs(pv, v_periodic, k) for k in range(1, reach + 1)}
    cvs = sum(grid.values()) + 16 * len(authored_levels)
    if cvs:
        nbytes = float(cvs) * BYTES_PER_CV
        attr = "acra:levels" if reach == top else "acra:absorption" if reach else "acra:hierarchy:patchLevel"
        where = "where a contact covers the whole surface" if reach else "authored"
        parts.append((path, attr, nbytes,
                      f"{levels} levels (responses down to level {reach}) would need "
                      f"{format_size(nbytes)} for {cvs:,} CVs {where}"))
    display = (pu * samples + (0 if u_periodic else 1)) * (pv * samples + (0 if v_periodic else 1))
    display_bytes = float(display) * BYTES_PER_DISPLAY_VERTEX * (1 + min(frames, 8) / 8)
    parts.append((path, "acra:samples", display_bytes,
                  f"{samples} samples per patch edge is a {format_size(display_bytes)} display mesh "
                  f"of {display:,} vertices"))
    # collision grids: `shape.Shape.density_map` steps per patch edge, 2 * 2^k for the finest level
    # k inside a patch, between the detection density and its cap
    density = min(max(collision_density, 2 * 2**min(finest, 30)), max_density)
    collision = float(pu * pv) * (density + 1) ** 2 * BYTES_PER_COLLISION_VERTEX
    parts.append((path, "acra:uCount", collision,
                  f"collision grids of {pu} x {pv} patches at {density} steps would need {format_size(collision)}"))
    return parts


def predict_memory(stage, frames: int) -> Estimate:
    """Peak memory of a run on ``stage`` over ``frames`` frames, from its attribute values alone.

    Per deformable (`predict_deformable`): the CVs of every level the response may refine, as if a
    contact covered the whole surface (the hierarchy is sparse, so a local contact costs its area
    only, but the inputs alone cannot bound the contact); the display mesh; the collision grids.
    Per collider: its triangles. Plus the interpreter's imports and a per-frame record. Reads
    only scalar attributes and array lengths, before `usdio.read_scene` validates them: values the
    validation rejects predict nothing, so its message names them.
    """
    from pipeline import usdio

    parts = []
    for prim in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
        if usdio._is_deformable(prim):
            parts.extend(_prim_parts(prim, frames))
        elif usdio._is_collider(prim):
            counts = prim.GetAttribute("faceVertexCounts").Get()
            try:
                ntri = int(np.maximum(np.asarray(counts, dtype=np.int64) - 2, 0).sum()) if counts is not None else 0
            except (TypeError, ValueError):
                ntri = 0
            nbytes = float(ntri) * BYTES_PER_COLLIDER_TRIANGLE
            parts.append((str(prim.GetPath()), "faceVertexCounts", nbytes, f"{ntri:,} triangles need {format_size(nbytes)}"))
    total = BASELINE + frames * BYTES_PER_FRAME + sum(p[2] for p in parts)
    return Estimate(total, parts)


def _value(prim, name, default):
    attr = prim.GetAttribute(name)
    if not attr or not attr.HasAuthoredValue():
        return default
    v = attr.Get(Usd.TimeCode.EarliestTime())
    return default if v is None else v


def _prim_parts(prim, frames: int) -> list:
    """`predict_deformable` on a prim's raw attribute values; called before `usdio.read_deformable`
    builds anything, so a levels value that would overflow is caught here. Values the validation
    rejects (wrong types, counts below 4) predict nothing: the validation names them."""
    path = str(prim.GetPath())
    try:
        nu = int(_value(prim, "acra:uCount", 0))
        nv = int(_value(prim, "acra:vCount", 0))
        levels = int(_value(prim, "acra:levels", 1))
        samples = int(_value(prim, "acra:samples", 4))
        uper = str(_value(prim, "acra:uWrap", "open")) == "periodic"
        vper = str(_value(prim, "acra:vWrap", "open")) == "periodic"
        refine = str(_value(prim, "acra:refine", "refine")) != "obey"
        absorption = _value(prim, "acra:absorption", None)
        if levels > 32:  # refused by key range whatever the shares (`predict_deformable`)
            absorption = [1.0]
        elif absorption is None:
            absorption = [0.0] * (levels - 1) + [1.0]
        else:
            absorption = [float(a) for a in absorption]
        hierarchy = _value(prim, "acra:hierarchy:patchLevel", [])
        hierarchy = [int(k) for k in hierarchy]
    except (TypeError, ValueError, OverflowError):
        return []
    if nu < 3 or nv < 3 or levels < 1 or samples < 1:
        return []
    return predict_deformable(path, nu, nv, uper, vper, levels, absorption, refine, samples, hierarchy, frames)


def check_budget(estimate: Estimate, budget: int) -> None:
    """Raise `InputError` when ``estimate`` exceeds ``budget``, naming the largest share's prim and
    attribute and the predicted size (one line)."""
    if estimate.nbytes <= budget:
        return
    prim, attr, nbytes, text = max(estimate.parts, key=lambda p: p[2]) if estimate.parts else ("stage", None, 0, "")
    if not math.isfinite(estimate.nbytes):
        raise InputError(prim, attr, f"{text}; refused whatever the memory budget")
    raise InputError(prim, attr, f"{text}; the run's predicted peak {format_size(estimate.nbytes)} is over the memory "
                                 f"budget of {format_size(budget)} (--memory-budget or ACRA_MEMORY_BUDGET)")


# --------------------------------------------------------------------------------------------
# transforms


def _singular(m) -> str | None:
    """Why a ``(4, 4)`` transform cannot carry an object: ``"not finite"``, an entry beyond
    `usdio.MAX_COORDINATE`, ``"singular"`` (a determinant of its 3x3 part below 1e-9 of the
    product of its row lengths: a scale of 0 or a collapse onto a plane), or None. Mirrored
    transforms (negative determinant) are fine."""
    from pipeline.usdio import MAX_COORDINATE

    a = np.asarray(m, dtype=np.float64)
    if not np.all(np.isfinite(a)):
        return "not finite"
    if np.max(np.abs(a)) > MAX_COORDINATE:
        return f"beyond {MAX_COORDINATE:g} (too far or too large to compute with)"
    lin = a[:3, :3]
    scale = float(np.prod(np.linalg.norm(lin, axis=1)))
    if scale == 0.0 or abs(float(np.linalg.det(lin))) <= 1e-9 * scale:
        return "singular"
    return None


def _culprit(prim, tc) -> tuple[str, str]:
    """The prim (``prim`` or an ancestor) and the xformOp attribute whose transform at ``tc`` is
    singular or not finite; the prim and ``xformOpOrder`` where no single op is to blame."""
    p = prim
    while p and p.GetPath() != p.GetPath().absoluteRootPath:
        xf = UsdGeom.Xformable(p)
        if xf:
            for op in xf.GetOrderedXformOps():
                if _singular(op.GetOpTransform(tc)):
                    return str(p.GetPath()), op.GetName()
        p = p.GetParent()
    return str(prim.GetPath()), "xformOpOrder"


def check_transforms(stage, scene, frames: list[int]) -> None:
    """Raise `InputError` when an object's world transform at a processed frame is singular (a
    scale of 0 leaves a collider or deformable with no volume and no surface to measure depth
    against) or not finite, naming the prim and xformOp, the frame and the object."""
    objects = [m.path for m in scene.deformables] + [c.path for c in scene.colliders]
    if not objects:
        return
    prims = [stage.GetPrimAtPath(p) for p in objects]
    for f in frames:
        tc = Usd.TimeCode(float(f))
        cache = UsdGeom.XformCache(tc)
        for path, prim in zip(objects, prims):
            why = _singular(cache.GetLocalToWorldTransform(prim))
            if why:
                where, attr = _culprit(prim, tc)
                raise InputError(where, attr, f"world transform of {path} is {why} at frame {f}; "
                                              "ACRA needs an invertible transform at every processed frame")


# --------------------------------------------------------------------------------------------
# temporary files


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike):
    """Yield a hidden temporary sibling of ``path`` to write; when the block ends normally it is
    renamed over ``path`` (`os.replace`, atomic on one file system), otherwise removed, so ``path``
    is afterwards either the whole new file or as it was. The sibling keeps ``path``'s suffix, which
    picks USD's file format."""
    out = Path(path)
    tmp = temporary_sibling(out)
    try:
        yield tmp
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)


def temporary_sibling(path: str | os.PathLike) -> Path:
    """A hidden temporary path beside ``path`` (same file system, so `os.replace` is atomic)."""
    import uuid

    out = Path(path)
    return out.parent / f".{out.name}.{uuid.uuid4().hex}.tmp{out.suffix}"


def flush_recording(preview) -> None:
    """Block until a Rerun recording's file sink has written everything logged."""
    rec = getattr(preview, "rec", None)
    flush = getattr(rec, "flush", None)
    if flush is not None:
        try:
            flush(blocking=True)
        except TypeError:
            flush()
