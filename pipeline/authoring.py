"""The scene-file API (contract §4): build a stage in a few lines, like a Blender script.

A scene file defines ``build() -> Usd.Stage`` composed of these helpers and can be run on its own::

    from pathlib import Path
    from pipeline.authoring import add_bump, add_collider, add_surface, box, key_transform, new_stage, save, sphere

    def build():
        stage = new_stage(1, 24)
        ball = add_bump(sphere(8, 8, levels=3), level=2, centre=(4.0, 2.5), radius=0.5, height=0.1)
        prim = add_surface(stage, "/World/ball", ball, absorption=[0.2, 0.3, 0.5])
        key_transform(prim, 1, translate=(0, 0, 3))
        key_transform(prim, 24, translate=(0, 0, 0.5))
        add_collider(stage, "/World/floor", *box((10, 10, 1)))
        return stage

    if __name__ == "__main__":
        save(build(), Path(__file__).with_suffix(".usda"))

Three layers, each usable alone:

* **shapes** (`sheet`, `sphere`, `cone`, `torus`, `tube`) return an `acra.hspline.HSpline` with
  ``levels`` levels and no detail yet; `moved` and `turned` place it;
* **detail** (`refine_region`, `add_bump`, `add_spike`) refines the levels under a region given
  in level-0 parameter units (patch ``p`` of level 0 spans ``[p, p + 1)``) and offsets the
  CVs there along their local normals, so an animator never handles CV indices or Greville
  abscissae; `spike_offsets` and `spike_positions` read a spike back;
* **stage** (`new_stage`, `add_surface` / `add_deformable`, `add_collider`, `key_transform`,
  `key_translate`, `key_rotate`, `key_cvs`, `key_enabled`, `save`) authors the contract's prims
  and keys; `add_skinned_arm` authors a skinned two-bone arm whose elbow follows per-frame angles,
  and `keyed_values` samples keys through an interpolation or easing curve at given frames.

Every deformable gets its rest display tessellation (points, normals, topology) so the stage is
viewable before any response; `key_cvs` keys that preview along with the CVs. No ``extent`` is
authored on deformables: the output layer may not override it (contract §2), so a stale rest
extent would make viewers cull or frame the deformed surface wrongly; USD computes bounds from
``points`` when ``extent`` is absent.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

from acra import hspline, shapes
from acra.hspline import HSpline, from_arrays, from_grid, to_arrays
from acra.tessellate import MeshTopology, evaluate_grid, run_topology

from .animation import curves
from .animation.usdkeys import key_rotate, key_translate
from .usdio import WRAPS, cvs_to_flat, export_layer, read_hierarchy

if TYPE_CHECKING:
    from .animation.skinning import ArmRig

__all__ = [
    "sheet",
    "sphere",
    "cone",
    "torus",
    "tube",
    "moved",
    "turned",
    "refine_region",
    "add_bump",
    "add_spike",
    "spike_cvs",
    "spike_offsets",
    "spike_positions",
    "new_stage",
    "add_surface",
    "key_translate",
    "key_rotate",
    "add_xform",
    "add_deformable",
    "key_cvs",
    "keyed_values",
    "add_skinned_arm",
    "add_collider",
    "box",
    "uv_sphere",
    "key_transform",
    "key_enabled",
    "set_state_controls",
    "key_relax",
    "save",
]

T = Sdf.ValueTypeNames
_OP_ORDER = ("xformOp:translate", "xformOp:rotateXYZ", "xformOp:scale")


# --------------------------------------------------------------------------------------------
# shapes: level-0 grids of `acra.shapes` as H-splines with room for detail


def _surface(grid: tuple[np.ndarray, bool, bool], levels: int) -> HSpline:
    cvs, u_periodic, v_periodic = grid
    return from_grid(cvs, u_periodic, v_periodic, depth=levels)


def sheet(nu: int, nv: int, width: float = 1.0, depth: float = 1.0, levels: int = 1) -> HSpline:
    """An open sheet of ``nu × nv`` CVs in the xy-plane, centred at the origin, facing +z.

    The surface (not the control net) spans ``width × depth``: ``nu - 3`` by ``nv - 3`` level-0
    patches (`acra.shapes.sheet`).
    """
    return _surface(shapes.sheet(nu, nv, width=width, depth=depth), levels)


def sphere(nu: int = 8, nv: int = 8, radii=(1.0, 1.0, 1.0), center=(0.0, 0.0, 0.0), levels: int = 1) -> HSpline:
    """A closed ellipsoid with semi-axes ``radii``: periodic in u (``nu`` CVs around z, even),
    open in v (``nv`` CVs from the pole at −z to the pole at +z; `acra.shapes.sphere`).
    Level-0 parameters: u in ``[0, nu)`` (u = 0 faces +x), v in ``[0, nv - 3]`` (v = 0 the
    south pole)."""
    return _surface(shapes.sphere(nu, nv, radii=radii, center=center), levels)


def cone(nu: int = 8, nv: int = 8, radius: float = 0.5, height: float = 1.0, levels: int = 1) -> HSpline:
    """A closed cone along z, centred at the origin, tip at ``z = height / 2``.

    It is the ellipsoid ``sphere(nu, nv, radii=(radius, radius, height / 2))`` with each CV's
    distance from the axis scaled by ``(height / 2 - z) / height``: 1 at the base pole, 0 at
    the tip, so the surface tapers linearly to a point while both ends stay closed poles.
    """
    cvs, u_periodic, v_periodic = shapes.sphere(nu, nv, radii=(radius, radius, height / 2.0))
    cvs[..., :2] *= np.clip(height / 2.0 - cvs[..., 2:3], 0.0, None) / height
    return from_grid(cvs, u_periodic, v_periodic, depth=levels)


def torus(nu: int = 12, nv: int = 8, major: float = 1.0, minor: float = 0.35, levels: int = 1) -> HSpline:
    """A torus around z (`acra.shapes.torus`): u runs around the major circle, v around the
    tube, both periodic."""
    return _surface(shapes.torus(nu, nv, major=major, minor=minor), levels)


def tube(nu: int = 8, nv: int = 8, radius: float = 0.5, length: float = 2.0, levels: int = 1) -> HSpline:
    """An open-ended cylinder along z (`acra.shapes.tube`): periodic around (u), open along (v)."""
    return _surface(shapes.tube(nu, nv, radius=radius, length=length), levels)


def moved(surface: HSpline, offset) -> HSpline:
    """``surface`` with its level-0 CVs moved by ``offset (3,) float64``.

    Detail offsets live in each CV's local frame (thesis eq. 3.2), so they move with it.
    """
    return replace(surface, cvs=surface.cvs + np.asarray(offset, dtype=np.float64))


_AXES = {"x": 0, "y": 1, "z": 2}


def turned(surface: HSpline, axis: str, quarter_turns: int = 1) -> HSpline:
    """``surface`` turned by ``quarter_turns × 90°`` about the ``axis`` (``"x"``, ``"y"`` or
    ``"z"``) through the origin, right-handed.

    Quarter turns only: each coordinate is another one, possibly negated, so the CVs are exact
    (no ``cos 90° ≈ 6e-17`` residue) and a pole stays exactly collapsed.
    """
    a = _AXES[axis]
    b, c = (a + 1) % 3, (a + 2) % 3
    cvs = surface.cvs
    for _ in range(int(quarter_turns) % 4):
        # +90° about a: b' = −c, c' = b
        turned_cvs = cvs.copy()
        turned_cvs[..., b] = -cvs[..., c]
        turned_cvs[..., c] = cvs[..., b]
        cvs = turned_cvs
    return replace(surface, cvs=cvs)


# --------------------------------------------------------------------------------------------
# detail: regions in level-0 parameter units, offsets along the local normal


def _patch_span(lo: float, hi: float, level: int) -> np.ndarray:
    """Level-``level`` patches meeting the level-0 parameter interval ``[lo, hi)``:
    ``(m,) int64``. Patch ``p`` of level ``k`` spans ``[p, p + 1) / 2^k``."""
    n = 2**level
    return np.arange(int(np.floor(lo * n)), int(np.ceil(hi * n)), dtype=np.int64)


def _grid(pu: np.ndarray, pv: np.ndarray) -> np.ndarray:
    return np.stack(np.meshgrid(pu, pv, indexing="ij"), -1).reshape(-1, 2)


def refine_region(surface: HSpline, level: int, u, v) -> HSpline:
    """Refine ``level`` (and the levels above it) over the parameter box ``u × v``.

    ``u = (u0, u1)`` and ``v = (v0, v1)`` are level-0 parameters; every level-``level`` patch
    meeting ``[u0, u1) × [v0, v1)`` is activated with zero offsets, so the surface is unchanged
    (thesis §3.3): the region is where a response on ``level`` can later put detail. Patches
    past an open border are ignored; a periodic direction wraps.
    """
    patches = _grid(_patch_span(*u, level), _patch_span(*v, level))
    return hspline.refine(surface, level, patches)


def add_bump(surface: HSpline, level: int, centre, radius, height: float) -> HSpline:
    """Add a smooth bump of ``height`` on ``level``, along the normal of level ``level - 1``.

    Parameters
    ----------
    centre : (2,) float64
        ``(u, v)`` in level-0 parameter units.
    radius : float or (2,) float64
        Radii ``(ru, rv)`` in level-0 parameter units.

    Each level-``level`` CV at parameter centre ``(u, v)`` (its Greville abscissa) is offset by
    ``height · (1 − d²)²`` with ``d² = ((u − uc)/ru)² + ((v − vc)/rv)²``, zero outside the
    ellipse: the profile is C1 at its rim and its peak is ``height`` when a CV sits at the
    centre. Only the patches under the bump are refined, with the 7×7 blocks that make their
    CVs movable (the C2 rule of `acra.hspline.make_movable`). Offsets add to any already there,
    so bumps overlap.
    """
    n = 2**level
    uc, vc = (float(x) for x in centre)
    ru, rv = np.broadcast_to(np.asarray(radius, dtype=np.float64), (2,))
    pu = np.arange(int(np.floor((uc - ru) * n)) - 1, int(np.ceil((uc + ru) * n)) + 1)
    pv = np.arange(int(np.floor((vc - rv) * n)) - 1, int(np.ceil((vc + rv) * n)) + 1)
    surface = hspline.make_movable(surface, level, _grid(pu, pv))
    idx, _ = hspline.offsets_of(surface, level)
    du = surface.u.greville(idx[:, 0], level) - uc
    if surface.u.periodic:  # the nearer way round
        du = (du + surface.u.patches0 / 2) % surface.u.patches0 - surface.u.patches0 / 2
    dv = surface.v.greville(idx[:, 1], level) - vc
    weight = np.clip(1.0 - (du / ru) ** 2 - (dv / rv) ** 2, 0.0, None) ** 2
    inside = weight > 0
    offsets = np.zeros((int(inside.sum()), 3))
    offsets[:, 2] = height * weight[inside]
    return hspline.set_offsets(surface, level, idx[inside], offsets, add=True)


def spike_cvs(surface: HSpline, level: int, centre=None) -> np.ndarray:
    """Indices ``(9, 2) int64`` of the 3×3 level-``level`` CVs of a spike at ``centre``
    (level-0 ``(u, v)``, default the middle of the domain), row-major, the middle one at [4].

    Level-``k`` CV ``j`` is centred at ``(j − 1) / 2^k``, so the CV nearest ``u`` is
    ``1 + round(u · 2^k)``.
    """
    u, v = (surface.u.patches0 / 2, surface.v.patches0 / 2) if centre is None else centre
    cu, cv = (1 + int(round(x * 2**level)) for x in (u, v))
    return np.array([(cu + a, cv + b) for a in (-1, 0, 1) for b in (-1, 0, 1)], np.int64)


def add_spike(surface: HSpline, level: int, height: float, spread: float, centre=None) -> HSpline:
    """Add a spike (small ``spread``) or a round bump (``spread`` near 1) on ``level``.

    The 3×3 level-``level`` CVs of `spike_cvs` are offset along their normal by
    ``height · w_a · w_b`` with ``w = (spread, 1, spread)``: a separable, so nearly round,
    profile whose tip offset is exactly ``height``. The four patches around the middle CV are
    made fully movable (C2 rule), so a contact at the tip reaches all nine CVs and a response
    on ``level`` moves or turns the spike as a whole (thesis Fig. 5.7–5.11).
    """
    idx = spike_cvs(surface, level, centre)
    # patches (cu − 2 .. cu − 1) × (cv − 2 .. cv − 1): those whose 4×4 CV blocks hold the middle CV
    surface = hspline.make_movable(surface, level, idx[[0, 1, 3, 4]] - 1)
    weight = np.array([spread, 1.0, spread])
    offsets = np.zeros((9, 3))
    offsets[:, 2] = height * np.outer(weight, weight).reshape(-1)
    return hspline.set_offsets(surface, level, idx, offsets, add=True)


def _spike_rows(surface: HSpline, level: int, centre=None) -> np.ndarray:
    """Rows ``(9,) int64`` of the spike's CVs among the level's movable CVs (`offsets_of`)."""
    idx = spike_cvs(surface, level, centre)
    movable, _ = hspline.offsets_of(surface, level)
    match = np.all(movable[None, :, :] == idx[:, None, :], axis=2)
    if not match.any(axis=1).all():
        raise ValueError(f"level {level}: the spike's CVs are not refined and movable")
    return np.argmax(match, axis=1)


def spike_offsets(surface: HSpline, level: int, centre=None) -> np.ndarray:
    """Local-frame offsets ``(9, 3) float64`` of a spike's CVs (order of `spike_cvs`)."""
    return hspline.offsets_of(surface, level)[1][_spike_rows(surface, level, centre)]


def spike_positions(surface: HSpline, level: int, centre=None) -> np.ndarray:
    """Object-space positions ``(9, 3) float64`` of a spike's CVs (derived + offset)."""
    lev = surface.level(level)
    positions = hspline.cv_positions(surface, level)[lev.movable]
    return positions[_spike_rows(surface, level, centre)]


# --------------------------------------------------------------------------------------------
# stage: prims, controls and keys


def new_stage(start: int, end: int, fps: float = 24, up_axis: str = "Z", meters_per_unit: float = 1.0) -> Usd.Stage:
    """An in-memory stage with a ``/World`` Xform as default prim and its metadata set.

    ``start``..``end`` are the frames a run processes; ``fps`` sets both time codes and frames per
    second (one time code per frame).
    """
    stage = Usd.Stage.CreateInMemory()
    world = UsdGeom.Xform.Define(stage, "/World").GetPrim()
    stage.SetDefaultPrim(world)
    stage.SetStartTimeCode(int(start))
    stage.SetEndTimeCode(int(end))
    stage.SetTimeCodesPerSecond(float(fps))
    stage.SetFramesPerSecond(float(fps))
    UsdGeom.SetStageUpAxis(stage, {"Y": UsdGeom.Tokens.y, "Z": UsdGeom.Tokens.z}[up_axis.upper()])
    UsdGeom.SetStageMetersPerUnit(stage, float(meters_per_unit))
    return stage


def _parents(stage: Usd.Stage, path: str) -> None:
    """Define missing ancestors as Xforms, so transforms inherit through them."""
    for anc in reversed(Sdf.Path(path).GetParentPath().GetPrefixes()):
        if not stage.GetPrimAtPath(anc):
            UsdGeom.Xform.Define(stage, anc)


def add_xform(stage: Usd.Stage, path: str) -> Usd.Prim:
    """An Xform prim (a group whose transform its children inherit)."""
    _parents(stage, path)
    return UsdGeom.Xform.Define(stage, path).GetPrim()


def _set(prim: Usd.Prim, name: str, tname: Sdf.ValueTypeName, value, time=None) -> Usd.Attribute:
    attr = prim.CreateAttribute(name, tname)
    attr.Set(value) if time is None else attr.Set(value, Usd.TimeCode(time))
    return attr


def _set_display(mesh: UsdGeom.Mesh, points: np.ndarray, normals: np.ndarray, time=None) -> None:
    tc = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
    mesh.CreatePointsAttr().Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(points, dtype=np.float32)), tc)
    mesh.CreateNormalsAttr().Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(normals, dtype=np.float32)), tc)


def add_deformable(
    stage: Usd.Stage,
    path: str,
    cvs: np.ndarray,
    u_wrap: str = "open",
    v_wrap: str = "open",
    levels: int | None = None,
    absorption=None,
    deform=None,
    translate=None,
    rotate=None,
    rigidity: float = 50.0,
    refine: str = "refine",
    samples: int = 4,
    hierarchy: HSpline | None = None,
    enabled: bool = True,
) -> Usd.Prim:
    """A deformable H-spline Mesh: every ``acra:`` attribute plus the rest display tessellation.

    Parameters
    ----------
    cvs : (nu, nv, 3) float64
        Level-0 CVs in object space, ``cvs[i, j]`` with ``i`` along u.
    levels : int, optional
        ``acra:levels``; defaults to ``hierarchy.depth``, else 1.
    absorption, deform, translate, rotate : (levels,) float, optional
        Controls (contract §1); unset ones are authored with the contract's defaults
        (``[0, …, 0, 1]``, all deform). Values are written as given: `pipeline.usdio.read_scene`
        is the single place that validates them.
    hierarchy : HSpline, optional
        The animator's refined patches and offsets (its ``cvs`` are replaced by ``cvs``); stored
        in ``acra:hierarchy:*``. Its grid size and wraps must match.
    """
    cvs = np.asarray(cvs, dtype=np.float64)
    if cvs.ndim != 3 or cvs.shape[2] != 3:
        raise ValueError(f"cvs must have shape (nu, nv, 3), got {cvs.shape}")
    nu, nv = cvs.shape[:2]
    uper, vper = u_wrap == "periodic", v_wrap == "periodic"
    if levels is None:
        levels = hierarchy.depth if hierarchy is not None else 1
    if hierarchy is not None:
        if hierarchy.cvs.shape != cvs.shape or (hierarchy.u.periodic, hierarchy.v.periodic) != (uper, vper):
            raise ValueError(f"{path}: hierarchy grid {hierarchy.cvs.shape[:2]} / wraps do not match cvs {cvs.shape[:2]} / ({u_wrap}, {v_wrap})")
        if hierarchy.depth != levels:
            raise ValueError(f"{path}: hierarchy has {hierarchy.depth} levels, levels={levels}")
    _parents(stage, path)
    mesh = UsdGeom.Mesh.Define(stage, path)
    prim = mesh.GetPrim()
    L = int(levels)
    ones, zeros = np.ones(L), np.zeros(L)
    mix_given = any(x is not None for x in (deform, translate, rotate))
    floats = lambda x, default: Vt.FloatArray(list(np.asarray(default if x is None else x, dtype=np.float64).reshape(-1)))  # noqa: E731
    _set(prim, "acra:cvs", T.Point3fArray, Vt.Vec3fArray.FromNumpy(cvs_to_flat(cvs).astype(np.float32)))
    _set(prim, "acra:uCount", T.Int, int(nu))
    _set(prim, "acra:vCount", T.Int, int(nv))
    _set(prim, "acra:uWrap", T.Token, u_wrap)
    _set(prim, "acra:vWrap", T.Token, v_wrap)
    _set(prim, "acra:levels", T.Int, L)
    _set(prim, "acra:absorption", T.FloatArray, floats(absorption, np.eye(L)[-1] if L else zeros))
    _set(prim, "acra:deform", T.FloatArray, floats(deform, zeros if mix_given else ones))
    _set(prim, "acra:translate", T.FloatArray, floats(translate, zeros))
    _set(prim, "acra:rotate", T.FloatArray, floats(rotate, zeros))
    _set(prim, "acra:rigidity", T.Float, float(rigidity))
    _set(prim, "acra:refine", T.Token, refine)
    _set(prim, "acra:samples", T.Int, int(samples))
    _set(prim, "acra:enabled", T.Bool, bool(enabled))
    if hierarchy is not None:
        a = to_arrays(hierarchy)
        _set(prim, "acra:hierarchy:patchLevel", T.IntArray, Vt.IntArray.FromNumpy(a.patch_level))
        _set(prim, "acra:hierarchy:patches", T.Int2Array, Vt.Vec2iArray.FromNumpy(np.ascontiguousarray(a.patches)))
        _set(prim, "acra:hierarchy:offsetLevel", T.IntArray, Vt.IntArray.FromNumpy(a.offset_level))
        _set(prim, "acra:hierarchy:offsetCvs", T.Int2Array, Vt.Vec2iArray.FromNumpy(np.ascontiguousarray(a.offset_cvs)))
        _set(prim, "acra:hierarchy:offsets", T.Double3Array, Vt.Vec3dArray.FromNumpy(np.ascontiguousarray(a.offsets)))

    template, topology = _structure(prim)
    points, normals = evaluate_grid(replace(template, cvs=np.ascontiguousarray(cvs)), topology)
    mesh.CreateFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(np.asarray(topology.counts, np.int32)))
    mesh.CreateFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(np.asarray(topology.indices, np.int32)))
    mesh.CreateSubdivisionSchemeAttr().Set(UsdGeom.Tokens.none)
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    _set_display(mesh, points, normals)
    return prim


def add_surface(stage: Usd.Stage, path: str, surface: HSpline, **controls) -> Usd.Prim:
    """A deformable for ``surface`` (a shape of this module with its detail).

    Its level-0 CVs, wraps and number of levels come from ``surface``; its refined patches and
    offsets are stored in ``acra:hierarchy:*`` when it has any. ``controls`` are the keyword
    arguments of `add_deformable` (``absorption``, ``deform``, ``translate``, ``rotate``,
    ``rigidity``, ``refine``, ``samples``, ``enabled``).
    """
    wrap = lambda periodic: "periodic" if periodic else "open"  # noqa: E731
    detailed = any(lev.patches.size for lev in surface.fine)
    return add_deformable(stage, path, surface.cvs, u_wrap=wrap(surface.u.periodic), v_wrap=wrap(surface.v.periodic),
                          levels=surface.depth, hierarchy=surface if detailed else None, **controls)


def _structure(prim: Usd.Prim) -> tuple[HSpline, MeshTopology]:
    """The deformable's refinement structure (zero CVs) and rest display topology: the adaptive
    tessellation of the animator's hierarchy (`acra.tessellate.run_topology`), as authored.

    Controls are not validated here (scenes may author bad values on purpose; `read_scene`
    reports them), only what the preview tessellation needs.
    """
    get = lambda n, d: prim.GetAttribute(n).Get() if prim.GetAttribute(n).HasAuthoredValue() else d  # noqa: E731
    nu, nv = int(get("acra:uCount", 0)), int(get("acra:vCount", 0))
    uper, vper = WRAPS.get(str(get("acra:uWrap", "open")), False), WRAPS.get(str(get("acra:vWrap", "open")), False)
    base = from_grid(np.zeros((nu, nv, 3)), uper, vper, depth=int(get("acra:levels", 1)))
    template = from_arrays(base, read_hierarchy(prim))
    return template, run_topology([template], int(get("acra:samples", 4)))


def key_cvs(prim: Usd.Prim, frame: float, cvs: np.ndarray) -> None:
    """Key ``acra:cvs`` (``(nu, nv, 3)``) at ``frame``, with the matching display preview.

    Once any key exists USD uses the keys at every time (held before the first and after the
    last), not the rest value `add_deformable` authored.
    """
    template, topology = _structure(prim)
    cvs = np.asarray(cvs, dtype=np.float64)
    if cvs.shape != template.cvs.shape:
        raise ValueError(f"{prim.GetPath()}: cvs shape {cvs.shape}, the object has {template.cvs.shape}")
    _set(prim, "acra:cvs", T.Point3fArray, Vt.Vec3fArray.FromNumpy(cvs_to_flat(cvs).astype(np.float32)), frame)
    points, normals = evaluate_grid(replace(template, cvs=np.ascontiguousarray(cvs)), topology)
    _set_display(UsdGeom.Mesh(prim), points, normals, frame)


def keyed_values(times, values, frames, interp: str = "linear", **params) -> np.ndarray:
    """Keys ``values (k,)`` (or ``(k, d)``) at ``times (k,)`` sampled at ``frames (F,)`` through
    the curve `pipeline.animation.curves.make` builds for ``interp`` and ``params`` (e.g.
    ``"cubic"`` with ``mode="out"``): ``(F,)`` (or ``(F, d)``) float64."""
    sampled = curves.make(times, values, interp, **params).evaluate(np.asarray(frames, dtype=np.float64))
    return sampled[:, 0] if np.ndim(values) == 1 else sampled


def add_skinned_arm(stage: Usd.Stage, path: str, frames, elbow_angles, method: str = "ccm",
                    **controls) -> ArmRig:
    """A skinned two-bone arm under ``path`` (a ``UsdSkel.Root``, defined if absent): its skeleton at ``path/Skel`` (a
    ``UsdSkel.Skeleton`` with the elbow keyed, so clients show the rig) and its skin at
    ``path/Skin``, a deformable H-spline tube (`pipeline.animation.skinning.arm_rig`: 8 CVs
    around, periodic u; 12 along +x, open v) whose level-0 CVs are skinned by ``method``
    (``"lbs"``, ``"dqs"``, ``"psd"`` or ``"ccm"``, `pipeline.animation.skinning.bent_arm`) at
    each of ``frames (F,)`` with the elbow at ``elbow_angles (F,)`` radians (bent toward +y), and
    written as ``acra:cvs`` time samples. ``controls`` are the keyword arguments of
    `add_deformable` (``levels``, ``absorption``, ``samples`` ...). Returns the rig (its
    ``elbow`` is the elbow joint's x).
    """
    # here, not at the top: a scene without an arm skips skinning's and UsdSkel's imports
    from .animation.skinning import arm_pose, arm_rig, bent_arm
    from .animation.usdrig import write_cvs_samples, write_skeleton

    rig = arm_rig()
    write_skeleton(stage, f"{path}/Skel", rig.skeleton, arm_pose(rig, elbow_angles), frames)
    skin = add_deformable(stage, f"{path}/Skin", rig.rest, u_wrap="periodic", v_wrap="open", **controls)
    write_cvs_samples(skin, frames, bent_arm(elbow_angles, method, rig))
    return rig


def _faces(faces) -> tuple[np.ndarray, np.ndarray]:
    """Polygon list (``(f, k)`` array or sequence of sequences) to USD counts and indices."""
    if isinstance(faces, np.ndarray) and faces.ndim == 2:
        return np.full(len(faces), faces.shape[1], np.int32), faces.reshape(-1).astype(np.int32)
    polys = [np.asarray(f, dtype=np.int32).reshape(-1) for f in faces]
    return np.array([len(p) for p in polys], np.int32), np.concatenate(polys) if polys else np.zeros(0, np.int32)


def add_collider(stage: Usd.Stage, path: str, vertices: np.ndarray, faces) -> Usd.Prim:
    """A rigid collider: a Mesh with ``PhysicsCollisionAPI`` applied.

    Parameters
    ----------
    vertices : (n, 3) float64
        Object-space points.
    faces : (f, k) int or sequence of int sequences
        Polygons, counter-clockwise seen from outside.
    """
    _parents(stage, path)
    mesh = UsdGeom.Mesh.Define(stage, path)
    v = np.ascontiguousarray(vertices, dtype=np.float32).reshape(-1, 3)
    counts, indices = _faces(faces)
    mesh.CreatePointsAttr().Set(Vt.Vec3fArray.FromNumpy(v))
    mesh.CreateFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(counts))
    mesh.CreateFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(np.ascontiguousarray(indices)))
    mesh.CreateSubdivisionSchemeAttr().Set(UsdGeom.Tokens.none)
    mesh.CreateExtentAttr().Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, v.min(axis=0))), Gf.Vec3f(*map(float, v.max(axis=0)))]))
    from pxr import UsdPhysics  # here: a scene of deformables alone never loads it

    UsdPhysics.CollisionAPI.Apply(mesh.GetPrim())
    return mesh.GetPrim()


def box(size=1.0, center=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """An axis-aligned box: ``vertices (8, 3) float64``, ``faces (6, 4) int64`` (outward, CCW).

    ``size`` is one edge length or ``(sx, sy, sz)``.
    """
    half = np.broadcast_to(np.asarray(size, dtype=np.float64), (3,)) / 2.0
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
    faces = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]], np.int64)
    return corners * half + np.asarray(center, dtype=np.float64), faces


def uv_sphere(radius: float = 1.0, segments: int = 16, rings: int = 8, center=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """A latitude-longitude sphere around z: ``vertices (2 + (rings-1) segments, 3) float64``,
    ``faces (2 segments (rings-1), 3) int64`` triangles (outward, CCW).
    """
    if segments < 3 or rings < 2:
        raise ValueError(f"a uv sphere needs segments >= 3 and rings >= 2, got {segments}, {rings}")
    phi = np.pi * np.arange(1, rings) / rings - np.pi / 2.0  # latitudes of the inner rings
    theta = 2.0 * np.pi * np.arange(segments) / segments
    pp, tt = np.meshgrid(phi, theta, indexing="ij")
    ring = np.stack([np.cos(pp) * np.cos(tt), np.cos(pp) * np.sin(tt), np.sin(pp)], axis=-1).reshape(-1, 3)
    verts = np.concatenate([[[0.0, 0.0, -1.0]], ring, [[0.0, 0.0, 1.0]]]) * radius + np.asarray(center, dtype=np.float64)
    north = len(verts) - 1
    j = np.arange(segments)
    j1 = (j + 1) % segments
    idx = lambda r, s: 1 + r * segments + s  # noqa: E731
    tris = [np.stack([np.zeros_like(j), idx(0, j1), idx(0, j)], axis=1)]
    for r in range(rings - 2):
        a, b, c, d = idx(r, j), idx(r, j1), idx(r + 1, j1), idx(r + 1, j)
        tris += [np.stack([a, b, c], axis=1), np.stack([a, c, d], axis=1)]
    tris.append(np.stack([idx(rings - 2, j), idx(rings - 2, j1), np.full_like(j, north)], axis=1))
    return verts, np.concatenate(tris).astype(np.int64)


def key_transform(prim: Usd.Prim, frame: float, translate=None, rotate_xyz=None, scale=None) -> None:
    """Key the prim's translate / rotateXYZ (degrees) / scale ops at ``frame`` (linear in between).

    Missing ops are added; the three are kept in the order translate, rotateXYZ, scale (so the
    object is scaled, then rotated, then moved), ahead of any other ops the prim has.
    """
    xf = UsdGeom.Xformable(prim)
    ops = {op.GetOpName(): op for op in xf.GetOrderedXformOps()}
    values = {"xformOp:translate": translate, "xformOp:rotateXYZ": rotate_xyz, "xformOp:scale": scale}
    add = {"xformOp:translate": xf.AddTranslateOp, "xformOp:rotateXYZ": xf.AddRotateXYZOp, "xformOp:scale": xf.AddScaleOp}
    changed = False
    for name, value in values.items():
        if value is not None and name not in ops:
            ops[name] = add[name]()
            changed = True
    if changed:
        ordered = [ops[n] for n in _OP_ORDER if n in ops]
        ordered += [op for op in xf.GetOrderedXformOps() if op.GetOpName() not in _OP_ORDER]
        xf.SetXformOpOrder(ordered)
    tc = Usd.TimeCode(frame)
    for name, value in values.items():
        if value is not None:
            v = np.asarray(value, dtype=np.float64).reshape(3)
            ops[name].Set(Gf.Vec3d(*v) if name == "xformOp:translate" else Gf.Vec3f(*map(float, v)), tc)


def key_enabled(prim: Usd.Prim, frame: float, value: bool) -> None:
    """Key ``acra:enabled`` at ``frame``, held until the next key.

    As with every USD attribute, once keyed the keys alone define the value (the first key holds
    before it): key ``True`` where the response should start as well as ``False`` where it stops.
    """
    _set(prim, "acra:enabled", T.Bool, bool(value), frame)


def set_state_controls(prim: Usd.Prim, relax=None, plasticity=None, preserve_volume=None, bulge_level=None,
                       bulge_falloff=None) -> None:
    """Author the state-across-frames controls (docs/usd-schema.md §2a) that are given.

    ``relax`` is a ``float[]`` per level (its default value; `key_relax` keys it); ``plasticity``
    a float for the object or a sequence per level; ``preserve_volume`` a float strength;
    ``bulge_level`` an int; ``bulge_falloff`` a float. Values are written as given:
    `pipeline.usdio.read_scene` validates them.
    """
    if relax is not None:
        _set(prim, "acra:relax", T.FloatArray, Vt.FloatArray([float(x) for x in np.ravel(relax)]))
    if plasticity is not None:
        if np.ndim(plasticity) == 0:
            _set(prim, "acra:plasticity", T.Float, float(plasticity))
        else:
            _set(prim, "acra:plasticity", T.FloatArray, Vt.FloatArray([float(x) for x in np.ravel(plasticity)]))
    if preserve_volume is not None:
        _set(prim, "acra:preserveVolume", T.Float, float(preserve_volume))
    if bulge_level is not None:
        _set(prim, "acra:bulgeLevel", T.Int, int(bulge_level))
    if bulge_falloff is not None:
        _set(prim, "acra:bulgeFalloff", T.Float, float(bulge_falloff))


def key_relax(prim: Usd.Prim, frame: float, relax) -> None:
    """Key ``acra:relax`` (one rate per level) at ``frame``; USD interpolates linearly between keys."""
    _set(prim, "acra:relax", T.FloatArray, Vt.FloatArray([float(x) for x in np.ravel(relax)]), frame)


def save(stage: Usd.Stage, path: str | os.PathLike) -> Path:
    """Write the stage's root layer to ``path`` (atomically); the stage itself is left as is."""
    return export_layer(stage.GetRootLayer(), Path(path))
