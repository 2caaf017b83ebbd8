"""Issue #6's hard cases, each run end to end through `pipeline.run.run_file` (docs/hard-cases.md).

Every case builds a small stage with `pipeline.authoring`, saves it into ``tmp_path`` and runs it
as ``acra run`` does. Each asserts, at every frame:

* finite output points;
* every display point moved at most ``2 d + tol · size`` from the animator's (input) point, with
  ``d`` the input's penetration depth computed here from the geometry, not by the pipeline: the
  deepest point's depth (points of one surface inside a box: distance to its nearest face), or,
  where the collider arrived by moving, the depth along its motion (how far a point must go to
  leave the way the collider came), which is what the response must undo;
* residual penetration ``<= 1e-3`` of the deformable's size, both as the frame loop reports it and
  measured here on the responded surface (the output layer's ``acra:response:*`` state evaluated
  on detection's own grid, 8 steps per patch edge; between those samples the surface can be
  deeper, which one xfail test shows) — or a documented remainder, asserted exactly.

Cases that expose a bug elsewhere are ``xfail(strict=True)`` with the failure in the reason; the
repros are in docs/hard-cases.md.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import fcl
import numpy as np
import pytest
import trimesh
from pxr import Usd, UsdGeom

from acceptance import visible
from acra import hspline as H
from acra import shapes
from acra.tessellate import evaluate_grid
from pipeline import authoring as A
from pipeline import usdio
from pipeline import output_layer
from pipeline.animation import usdkeys as K
from pipeline.run import run_file

TOL = 1e-3  # the contract's residual, fraction of the deformable's size
STEPS = 8  # detection's tessellation: steps per level-0 patch edge (RunOptions.density, levels <= 3)
F32 = 2.0**-23  # float32 output points: displacements are known to ~F32 of the coordinates


# --- running a stage and reading it back ---------------------------------------------------------
@dataclass
class Frame:
    """One deformable at one frame: display points ``p_in``, ``p_out`` ``(n, 3)`` (object space),
    the input and responded surfaces, and the world matrix ``xform (4, 4)``."""

    p_in: np.ndarray
    p_out: np.ndarray
    hs_in: H.HSpline
    hs_out: H.HSpline
    xform: np.ndarray

    def world(self, hs: H.HSpline, per: int = STEPS) -> np.ndarray:
        """World points ``(m, 3)`` of ``hs`` on a grid of ``per`` steps per level-0 patch edge."""
        return _world(self.xform, _grid(hs, per)[0])


@dataclass
class Run:
    """A finished run: the report, the input layer, and per deformable path ``{frame: Frame}``."""

    report: object
    src: Path
    frames: dict

    @property
    def stats(self):
        return self.report.stats


def run(stage: Usd.Stage, tmp_path: Path, name: str, **options) -> Run:
    """Save ``stage`` as ``tmp_path/name.usda``, run it (``options`` go to `run_file`), read back.

    Every run needs its own ``name``: USD keeps an opened layer, so a rewritten file of the same
    name could be read stale.
    """
    src = A.save(stage, tmp_path / f"{name}.usda")
    report = run_file(src, output=tmp_path / f"{name}.acra.usda", **options)
    sin, sout = Usd.Stage.Open(str(src)), Usd.Stage.Open(str(report.output))
    frames = {}
    for k, model in enumerate(report.scene.deformables):
        per = {}
        shown = output_layer.read_display_topology(sout, model.path)
        for st in report.stats:
            state = usdio.state_at(sin, report.scene, st.frame)[0][k]
            det = H.details(state.surface) if state.surface.depth > 1 else None
            p_in = evaluate_grid(state.surface, shown, det)[0]  # the animator's at the output's vertices
            p_out = np.asarray(UsdGeom.Mesh(sout.GetPrimAtPath(model.path)).GetPointsAttr().Get(st.frame), np.float64)
            hs_out = output_layer.read_output_hierarchy(sout, model.path, st.frame)
            per[st.frame] = Frame(p_in, p_out, state.surface, hs_out, state.xform)
        frames[model.path] = per
    _check_visible(name, report, options.get("tolerance", TOL))
    return Run(report, src, frames)


# --- the independent measure of every run (acceptance.visible) -----------------------------------
#: runs whose output the measure does not pass, with the first fault and the count: a strict
#: expected failure that lets the case's own assertions run (a run listed here that passes fails
#: its test, so the entry goes when the cause is fixed).
VISIBLE_KNOWN: dict[str, str] = {
    "obey": "the documented remainder (absorption left on an unrefined level): frame 2: measured 1.18e-02 of size, over 1e-03 (4 faults)",
}


def _check_visible(name: str, report, tol: float) -> None:
    """Measure the run's output layer where the user looks (`acceptance.visible`: display vertices
    and triangle samples inside other objects, no code of `pipeline` or `acra`) at every frame
    and hold it against the reported residual (`acceptance.visible.disagreements`). With
    ``ACRA_VISIBLE_TABLE=FILE`` set, each run adds a Markdown row to ``FILE``."""
    measures = visible.measure_layer(report.output, [s.frame for s in report.stats])
    measured = visible.worst_by_frame(measures)
    reported = {s.frame: float(s.residual_rel) for s in report.stats}
    problems = visible.disagreements(reported, measured, tol)
    table = os.environ.get("ACRA_VISIBLE_TABLE")
    if table:
        frame = max(measured, key=lambda f: (measured[f], -f))
        vert = max(m.vertices for m in measures if m.frame == frame) if measures else 0.0
        with open(table, "a", encoding="utf-8") as fh:
            fh.write(f"| {name} | {frame} | {reported[frame]:.2e} | {vert:.2e} | {measured[frame]:.2e} | "
                     f"{max(s.iterations for s in report.stats)} | {len(problems)} |\n")
    if name in VISIBLE_KNOWN:
        assert problems, f"{name} is now clear where the user looks: remove it from VISIBLE_KNOWN"
    else:
        assert problems == [], f"{name}: " + "; ".join(problems)


def _grid(hs: H.HSpline, per: int) -> tuple[np.ndarray, tuple[int, int]]:
    """Object-space points ``(m, 3)`` of ``hs`` on a ``per``-steps-per-patch grid, and its shape."""
    u = np.linspace(0.0, hs.u.patches0, per * hs.u.patches0 + 1)
    v = np.linspace(0.0, hs.v.patches0, per * hs.v.patches0 + 1)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    det = H.details(hs) if hs.depth > 1 else None
    return H.evaluate(hs, uu.ravel(), vv.ravel(), det=det).points, uu.shape


def _world(xform: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ xform[:3, :3].T + xform[:3, 3]


def box_bounds(src: Path, path: str, frame: float) -> tuple[np.ndarray, np.ndarray]:
    """World ``lo, hi (3,)`` of an axis-aligned box collider at ``frame``, read through USD."""
    stage = Usd.Stage.Open(str(src))
    prim = stage.GetPrimAtPath(path)
    pts = np.asarray(UsdGeom.Mesh(prim).GetPointsAttr().Get(), np.float64)
    m = np.asarray(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(frame), np.float64).T
    w = _world(m, pts)
    return w.min(axis=0), w.max(axis=0)


def box_depth(p: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Depth ``(m,)`` of points inside the box ``[lo, hi]``: distance to its nearest face, 0 outside."""
    return np.maximum(np.minimum(p - lo, hi - p).min(axis=1), 0.0)


def closed_mesh(hs: H.HSpline, xform: np.ndarray, per: int = STEPS) -> trimesh.Trimesh:
    """A watertight mesh of a sphere-like surface (u periodic, v open): its grid with each end
    row merged into its mean point, so an inside test needs no help from the pipeline (and a pole
    the response opened slightly is closed over, not leaked through)."""
    pts, (nu, nv) = _grid(hs, per)
    grid = _world(xform, pts).reshape(nu, nv, 3)[:-1]  # the periodic seam once
    nu, m = grid.shape[0], nv - 2
    verts = np.concatenate([grid[:, 1:-1].reshape(-1, 3), [grid[:, 0].mean(axis=0), grid[:, -1].mean(axis=0)]])
    south, north = len(verts) - 2, len(verts) - 1
    i, j = np.meshgrid(np.arange(nu), np.arange(m - 1), indexing="ij")
    a, b, c, d = i * m + j, (i + 1) % nu * m + j, (i + 1) % nu * m + j + 1, i * m + j + 1
    ring = np.arange(nu)
    faces = np.concatenate([
        np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3),
        np.stack([np.full(nu, south), (ring + 1) % nu * m, ring * m], -1),
        np.stack([ring * m + m - 1, (ring + 1) % nu * m + m - 1, np.full(nu, north)], -1),
    ])
    mesh = trimesh.Trimesh(verts, faces, process=False)
    assert mesh.is_watertight
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def depth_inside(mesh: trimesh.Trimesh, p: np.ndarray) -> np.ndarray:
    """Depth ``(m,)`` of points inside a watertight mesh (distance to its surface), 0 outside."""
    d = np.zeros(len(p))
    inside = mesh.contains(p)
    if inside.any():
        d[inside] = trimesh.proximity.closest_point(mesh, p[inside])[1]
    return d


def check(r: Run, path: str, depth: dict, size: float, residual: dict, tol: float = TOL) -> None:
    """The three assertions of every case for one deformable.

    ``depth[frame]``: the input's penetration depth (world units, computed by the caller);
    ``residual[frame]``: the penetration left on the responded surface, measured by the caller;
    ``tol``: the run's tolerance.
    """
    for st in r.stats:
        fr = r.frames[path][st.frame]
        assert np.all(np.isfinite(fr.p_out)), (path, st.frame)
        moved = np.linalg.norm(fr.p_out - fr.p_in, axis=1).max()
        bound = 2.0 * depth[st.frame] + tol * size
        assert moved <= bound, f"{path} frame {st.frame}: moved {moved:.4g} > 2 x depth {depth[st.frame]:.4g} + tol"
        assert st.residual_rel <= tol, f"{path} frame {st.frame}: residual {st.residual_rel:.3e} of size"
        assert residual[st.frame] <= tol * size, f"{path} frame {st.frame}: measured residual {residual[st.frame] / size:.3e} of size"


def box_case(r: Run, path: str, box: str, size: float, along=None, tol: float = TOL) -> None:
    """`check` for a deformable against a box collider: depths and residuals from `box_depth`.

    ``along``: ``(axis, sign)`` of the box's motion when it arrived moving; the depth is then how
    far each point inside must go to leave through the face the box came in by.
    """
    depth, residual = {}, {}
    for st in r.stats:
        fr = r.frames[path][st.frame]
        lo, hi = box_bounds(r.src, box, st.frame)
        p = fr.world(fr.hs_in)
        d = box_depth(p, lo, hi)
        if along is not None and np.any(d > 0):
            axis, sign = along
            face = lo[axis] if sign < 0 else hi[axis]  # the leading face, where the surface went in
            d = np.maximum(d, np.where(d > 0, sign * (face - p[:, axis]), 0.0))
        depth[st.frame] = float(d.max())
        residual[st.frame] = float(box_depth(fr.world(fr.hs_out), lo, hi).max())
    check(r, path, depth, size, residual, tol)


def sheet_stage(frames: int, n: int = 10, width: float = 3.0, levels: int = 3, absorption=(0.2, 0.3, 0.5),
                refine: str = "refine", cvs=None) -> tuple[Usd.Stage, float]:
    """A stage with a flat ``n × n`` sheet ``/World/Sheet`` (z = 0), and the sheet's size."""
    stage = A.new_stage(1, frames)
    if cvs is None:
        cvs = shapes.sheet(n, n, width=width, depth=width)[0]
    A.add_deformable(stage, "/World/Sheet", cvs, levels=levels, absorption=list(absorption), rigidity=10, refine=refine)
    return stage, H.from_grid(cvs).size()


def ball_stage(frames: int, path: str = "/World/Ball", levels: int = 3, absorption=(0.2, 0.3, 0.5),
               stage: Usd.Stage | None = None, rigidity: float = 10) -> tuple[Usd.Stage, float]:
    """A stage with an 8 × 8-CV unit sphere at ``path`` (poles on z), and its size."""
    stage = A.new_stage(1, frames) if stage is None else stage
    cvs, _, _ = shapes.sphere(8, 8)
    A.add_deformable(stage, path, cvs, u_wrap="periodic", levels=levels, absorption=list(absorption), rigidity=rigidity)
    return stage, H.from_grid(cvs, True, False).size()


def moving_box(stage: Usd.Stage, size, keys: dict, path: str = "/World/Mover", center=(0.0, 0.0, 0.0)) -> str:
    """A box collider under an Xform keyed per axis, ``keys = {"z": [values per frame]}`` (linear)."""
    mover = A.add_xform(stage, path)
    A.add_collider(stage, f"{path}/Box", *A.box(size, center))
    for axis, values in keys.items():
        K.key_translate(mover, axis, list(range(1, len(values) + 1)), list(values), interp="linear")
    return f"{path}/Box"


# --- 1. grazing contact ----------------------------------------------------------------------------
def test_grazing_contact_is_found_and_left_within_tolerance(tmp_path):
    """A box lands 1e-6 of the sheet's size deep: detected with that depth and, being within the
    contract's tolerance, left alone; at a tolerance of 1e-7 the response acts and clears it
    without overshooting, pushing the sheet the way the box came (down)."""
    for tol in (TOL, 1e-7):
        stage, size = sheet_stage(3, n=8, width=2.0)
        depth = 1e-6 * size
        box = moving_box(stage, 0.6, {"z": [0.35, 0.3 - depth, 0.3 - depth]})
        r = run(stage, tmp_path, f"grazing_{tol:g}", tolerance=tol)
        assert [s.in_collision for s in r.stats] == [False, True, True]
        box_case(r, "/World/Sheet", box, size, along=(2, -1), tol=tol)
        for st in r.stats[1:]:
            shown = np.linalg.norm(np.ptp(r.frames["/World/Sheet"][st.frame].p_out, axis=0))  # the display's diagonal
            if tol == TOL:  # found with its depth (float32 box corners: 1%), nothing done
                assert st.iterations == 0 and st.residual_rel == pytest.approx(depth / shown, rel=1e-2)
            else:
                assert st.iterations >= 1
            assert r.frames["/World/Sheet"][st.frame].p_out[:, 2].max() <= F32 * size


# --- 2. penetration half the object deep -------------------------------------------------------------
@pytest.fixture(scope="module")
def flat_half(tmp_path_factory):
    """A 1.6 × 1.6 × 1 box sits with its middle on the sheet in a one-frame scene (no earlier free
    time to rewind to): its top and bottom faces are both 0.5 away."""
    stage, size = sheet_stage(1, n=12, width=4.0)
    box = moving_box(stage, (1.6, 1.6, 1.0), {"x": [0.1], "y": [-0.1]})
    return run(stage, tmp_path_factory.mktemp("half_flat"), "half_flat"), box, size


def test_flat_box_half_deep_from_the_first_frame_clears_to_one_side(flat_half):
    """The sheet must leave the box wholly by one of its two nearest faces."""
    r, box, size = flat_half
    box_case(r, "/World/Sheet", box, size)
    for st in r.stats:
        p = r.frames["/World/Sheet"][st.frame].p_out
        under = (np.abs(p[:, 0] - 0.1) < 0.75) & (np.abs(p[:, 1] + 0.1) < 0.75)
        assert p[under, 2].max() <= -0.5 + TOL * size or p[under, 2].min() >= 0.5 - TOL * size


def test_flat_box_half_deep_is_cleared_between_detection_samples(flat_half):
    r, box, size = flat_half
    fr = r.frames["/World/Sheet"][1]
    lo, hi = box_bounds(r.src, box, 1)
    # 64 steps per patch edge over the patches under the box (the flat sheet's x, y are linear in u, v)
    u0, u1 = np.clip((np.array([lo[0], hi[0]]) + 2.0) * 9 / 4.0 + [-1, 1], 0, 9).astype(int)
    v0, v1 = np.clip((np.array([lo[1], hi[1]]) + 2.0) * 9 / 4.0 + [-1, 1], 0, 9).astype(int)
    uu, vv = np.meshgrid(np.linspace(u0, u1, 64 * (u1 - u0) + 1), np.linspace(v0, v1, 64 * (v1 - v0) + 1), indexing="ij")
    p = H.evaluate(fr.hs_out, uu.ravel(), vv.ravel(), det=H.details(fr.hs_out)).points
    assert box_depth(p, lo, hi).max() <= TOL * size


def test_cube_half_deep_from_the_first_frame_clears_to_one_side(tmp_path):
    stage, size = sheet_stage(1, n=12, width=4.0)
    box = moving_box(stage, 1.0, {"x": [0.1], "y": [-0.1]})
    r = run(stage, tmp_path, "half_cube")
    box_case(r, "/World/Sheet", box, size)
    p = r.frames["/World/Sheet"][1].p_out  # wholly out by the top or the bottom face
    under = (np.abs(p[:, 0] - 0.1) < 0.45) & (np.abs(p[:, 1] + 0.1) < 0.45)
    assert p[under, 2].max() <= -0.5 + TOL * size or p[under, 2].min() >= 0.5 - TOL * size


def test_sphere_pushed_half_its_height_from_the_side(tmp_path):
    """A slab drives into the unit sphere's equator from +x until its face reaches the centre
    (depth = radius, half the sphere); the sphere gives way along -x, the way the slab came."""
    stage, size = ball_stage(3, absorption=(0.1, 0.3, 0.6))
    box = moving_box(stage, (1.0, 3.0, 1.2), {"x": [1.8, 1.15, 0.5]})
    r = run(stage, tmp_path, "half_ball")
    box_case(r, "/World/Ball", box, size, along=(0, -1))
    for st in r.stats[1:]:  # every point in the slab's shadow is at or behind its leading face
        lo, hi = box_bounds(r.src, box, st.frame)
        p = r.frames["/World/Ball"][st.frame].p_out
        shadow = np.all((p[:, 1:] > lo[1:] + 0.05) & (p[:, 1:] < hi[1:] - 0.05), axis=1)
        assert p[shadow, 0].max() <= lo[0] + TOL * size, (st.frame, p[shadow, 0].max(), lo[0])


# --- 3. a collider wholly inside a closed deformable ---------------------------------------------------
def _box_corners(lo, hi) -> np.ndarray:
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def _inside_case(r: Run, box: str, size: float, entry_depth: dict) -> None:
    """`check` for a sphere and a box inside it: residual = how deep the box's corners still are
    in the responded sphere, and the sphere's points in the box (either way of penetrating)."""
    residual = {}
    for st in r.stats:
        fr = r.frames["/World/Ball"][st.frame]
        lo, hi = box_bounds(r.src, box, st.frame)
        corners = depth_inside(closed_mesh(fr.hs_out, fr.xform), _box_corners(lo, hi))
        residual[st.frame] = float(max(corners.max(), box_depth(fr.world(fr.hs_out), lo, hi).max()))
    check(r, "/World/Ball", entry_depth, size, residual)


def _fcl_sees_contact(r: Run, box: str, frame: int) -> bool:
    """fcl on the input meshes: any crossing triangles between the sphere and the box."""
    fr = r.frames["/World/Ball"][frame]
    lo, hi = box_bounds(r.src, box, frame)
    objects = []
    for mesh in (closed_mesh(fr.hs_in, fr.xform), trimesh.creation.box(bounds=np.stack([lo, hi]))):
        model = fcl.BVHModel()
        model.beginModel(len(mesh.vertices), len(mesh.faces))
        model.addSubModel(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int32))
        model.endModel()
        objects.append(fcl.CollisionObject(model, fcl.Transform()))
    return fcl.collide(*objects, fcl.CollisionRequest(), fcl.CollisionResult()) > 0


def _inside_jump(tmp_path, name, iterations):
    """A 0.3 box jumps from outside (x = 1.6) to the unit sphere's centre in one frame and stays."""
    stage, size = ball_stage(3)
    box = moving_box(stage, 0.3, {"x": [1.6, 0.0, 0.0]})
    r = run(stage, tmp_path, name, iterations=iterations)
    depth = {}
    for st in r.stats:  # how far the wall in front of the box must go: to the box's far face
        fr = r.frames["/World/Ball"][st.frame]
        lo, hi = box_bounds(r.src, box, st.frame)
        p = fr.world(fr.hs_in)
        front = np.all((p[:, 1:] > lo[1:]) & (p[:, 1:] < hi[1:]), axis=1) & (p[:, 0] > lo[0])
        depth[st.frame] = float((p[front, 0] - lo[0]).max()) if st.in_collision else 0.0
    return r, box, size, depth


def test_box_jumping_wholly_inside_a_sphere_is_found_and_pushed_the_way_it_came(tmp_path):
    """fcl sees no crossing once the box is inside; detection still finds it, rewinds to where it
    entered (+x), and the sphere's +x wall is pushed in along -x (it must reach the box's far
    face, x = -0.15, a move of 1.15 = 0.30 of the size): after the default 4 rounds the wall in
    the box's shadow is past the box's centre (measured x <= -0.152, past the far face) and the far
    side of the sphere (x = -1) has not moved toward +x. The
    residual is the next test."""
    r, box, size, depth = _inside_jump(tmp_path, "inside_jump", 4)
    assert not _fcl_sees_contact(r, box, 2)
    assert [s.in_collision for s in r.stats] == [False, True, True]
    assert depth[2] == pytest.approx(1.15, abs=1e-3)
    for st in r.stats[1:]:
        fr = r.frames["/World/Ball"][st.frame]
        assert np.all(np.isfinite(fr.p_out))
        assert np.linalg.norm(fr.p_out - fr.p_in, axis=1).max() <= 2 * depth[st.frame] + TOL * size
        lo, hi = box_bounds(r.src, box, st.frame)
        p = fr.world(fr.hs_out)
        shadow = np.all((p[:, 1:] > lo[1:]) & (p[:, 1:] < hi[1:]), axis=1) & (p[:, 0] > -0.5)
        assert shadow.any() and p[shadow, 0].max() < 0.0, p[shadow, 0].max()
        assert fr.p_out[:, 0].min() <= -1.0 + TOL * size


def test_box_jumping_wholly_inside_a_sphere_is_cleared(tmp_path):
    r, box, size, depth = _inside_jump(tmp_path, "inside_jump8", 8)
    _inside_case(r, box, size, depth)


def test_box_wholly_inside_a_sphere_from_the_first_frame_is_cleared(tmp_path):
    stage, size = ball_stage(1)
    box = moving_box(stage, 0.3, {"x": [0.0]})
    r = run(stage, tmp_path, "inside_static")
    assert not _fcl_sees_contact(r, box, 1)
    assert r.stats[0].in_collision
    # the nearest way out: the wall nearest a corner moves to the far corner (1 + 0.15 sqrt 3)
    _inside_case(r, box, size, {1: 1.0 + 0.15 * np.sqrt(3)})


def test_box_wholly_inside_a_sphere_is_wrapped_by_a_pocket_along_one_axis(tmp_path):
    """Case 3c's mechanism (`datapoints.collider_points_for`, docs/hard-cases.md case 3): the wall in
    front of the box is pushed along the way out the fallback chose, one of the box's axes, past
    its far face, and wraps it: every sphere point in the box's shadow on that side ends at or
    past the far face (the thin finger of the contact point alone left most of them short), and
    the wall on the other side of the sphere has not moved."""
    stage, size = ball_stage(1)
    box = moving_box(stage, 0.3, {"x": [0.0]})
    r = run(stage, tmp_path, "inside_pocket")
    fr = r.frames["/World/Ball"][1]
    lo, hi = box_bounds(r.src, box, 1)
    p_in, p_out = fr.world(fr.hs_in), fr.world(fr.hs_out)
    wrapped = []
    for axis in range(3):
        rest = [k for k in range(3) if k != axis]
        shadow = np.all((p_in[:, rest] >= lo[rest]) & (p_in[:, rest] <= hi[rest]), axis=1)
        for sign in (1.0, -1.0):  # the wall on the sign side pushed along -sign
            side = shadow & (sign * p_in[:, axis] > 0)
            far = lo[axis] if sign > 0 else hi[axis]
            if np.all(sign * (p_out[side, axis] - far) <= TOL * size):
                wrapped.append((axis, sign))
                other = shadow & (sign * p_in[:, axis] < 0)
                np.testing.assert_allclose(p_out[other], p_in[other], atol=TOL * size)
    assert len(wrapped) == 1, wrapped


# --- 4. tangent and coplanar faces ------------------------------------------------------------------
@pytest.mark.parametrize("keys", [
    {"z": [0.75, 0.25, 0.25]},  # lands from above; its bottom face lies on the sheet
    {"z": [-0.25]},  # its top face coplanar with the sheet, below it, in a one-frame scene
], ids=["lands_on_sheet", "coplanar_below"])
def test_tangent_and_coplanar_faces_leave_the_sheet_alone(tmp_path, keys):
    """Depth 0 exactly (0.25 and the 0.5 box are exact in float32): no response, no residual."""
    stage, size = sheet_stage(len(keys["z"]))
    box = moving_box(stage, 0.5, {"x": [0.125] * len(keys["z"]), **keys})
    r = run(stage, tmp_path, "tangent")
    box_case(r, "/World/Sheet", box, size)
    for st in r.stats:
        fr = r.frames["/World/Sheet"][st.frame]
        assert st.residual == 0.0
        assert np.abs(fr.p_out - fr.p_in).max() <= F32 * size  # untouched (float32 rounding)


# --- 5. the poles of closed objects -------------------------------------------------------------------
def _pole_box(tmp_path, name, absorption):
    stage, size = ball_stage(3, levels=len(absorption), absorption=absorption)
    box = moving_box(stage, 0.6, {"z": [1.6, 1.25, 1.2]})  # its bottom 0.05 and 0.1 into the north pole
    return run(stage, tmp_path, name), box, size


def _assert_pole_closed(r: Run, size: float) -> None:
    """Both poles are one finite point (33 values of u) and the full surface has no hole."""
    for st in r.stats:
        hs = r.frames["/World/Ball"][st.frame].hs_out
        u = np.linspace(0.0, hs.u.patches0, 33)
        det = H.details(hs) if hs.depth > 1 else None
        for end in (0.0, float(hs.v.patches0)):
            pole = H.evaluate(hs, u, np.full_like(u, end), det=det).points
            assert np.all(np.isfinite(pole))
            assert np.ptp(pole, axis=0).max() <= 1e-9 * size, (st.frame, end, np.ptp(pole, axis=0))
        assert np.ptp(hs.cvs[:, 1], axis=0).max() <= 1e-9 * size  # collapsed pole CV rows stay one point
        assert np.ptp(hs.cvs[:, -2], axis=0).max() <= 1e-9 * size


def test_box_into_a_pole_level0(tmp_path):
    """All absorption on level 0: the pole stays one point and the dent is resolved."""
    r, box, size = _pole_box(tmp_path, "pole0", (1.0,))
    box_case(r, "/World/Ball", box, size, along=(2, -1))
    _assert_pole_closed(r, size)


@pytest.fixture(scope="module")
def pole3(tmp_path_factory):
    return _pole_box(tmp_path_factory.mktemp("pole3"), "pole3", (0.2, 0.3, 0.5))


def test_box_into_a_pole_is_resolved(pole3):
    """Three levels (0.2, 0.3, 0.5): the penetration is cleared (whether the pole stays shut is
    the next test)."""
    r, box, size = pole3
    box_case(r, "/World/Ball", box, size, along=(2, -1))


def test_box_into_a_pole_keeps_it_closed_on_every_level(pole3):
    """Moves on levels 1-2 near the pole must not open it into a ring of points (a hole, through
    which detection would see the sphere as open): `respond` keeps every fine level's pole ring
    closed (`_ring_constraints`, `_close_rings`)."""
    r, _, size = pole3
    _assert_pole_closed(r, size)


# --- 6. rigidity -----------------------------------------------------------------------------------
def _evaluate(hs: H.HSpline, uv: np.ndarray) -> np.ndarray:
    """Object-space point ``(3,)`` of ``hs`` at parameters ``uv (2,)``."""
    return H.evaluate(hs, uv[:1], uv[1:], det=H.details(hs) if hs.depth > 1 else None).points[0]


def _on_surface(hs: H.HSpline, xform: np.ndarray, point: np.ndarray, size: float) -> np.ndarray:
    """Parameters ``(2,)`` of the world ``point`` that lies on ``hs`` (under ``xform``): the
    nearest point of a 16-steps-per-patch grid, then least squares on the parameters; asserts
    the point is on the surface to 1e-9 of ``size``."""
    from scipy.optimize import least_squares

    pts, shape = _grid(hs, 16)
    k = int(np.argmin(np.linalg.norm(_world(xform, pts) - point, axis=1)))
    i, j = np.unravel_index(k, shape)
    fit = least_squares(lambda uv: _world(xform, _evaluate(hs, uv)[None])[0] - point, [i / 16, j / 16],
                        bounds=([0.0, 0.0], [hs.u.patches0, hs.v.patches0]), xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert np.linalg.norm(fit.fun) <= 1e-9 * size, np.linalg.norm(fit.fun)
    return fit.x


@pytest.mark.parametrize("ra, rb", [
    (1, 100), (100, 100)])
def test_two_deformables_share_the_move_by_rigidity(tmp_path, ra, rb):
    """Two spheres driven 0.1 and then 0.2 into each other along x. Eq. 4.15: both aim at
    ``P' = R P_A + (1 - R) P_B``, ``R = ra / (ra + rb)``, so the surface at A's contact moves
    ``rb / (ra + rb)`` of the gap ``|P_B - P_A|`` and B's the rest (100/101 and 1/2 for A).
    Measured at each contact's own parameters on its surface (the dent's tip, `_on_surface`):
    0.990099 and 0.500000."""
    stage = A.new_stage(1, 3)
    size = 0.0
    for name, rig, x0, sign in (("A", ra, -1.5, 1), ("B", rb, 1.5, -1)):
        grp = A.add_xform(stage, f"/World/{name}")
        _, size = ball_stage(3, f"/World/{name}/Ball", stage=stage, rigidity=rig)
        K.key_translate(grp, "x", [1, 2, 3], [x0, sign * -0.95, sign * -0.9], interp="linear")
    r = run(stage, tmp_path, f"rigidity_{ra}_{rb}")
    a, b = "/World/A/Ball", "/World/B/Ball"
    depth, residual = {}, {}
    for st in r.stats:
        fa, fb = r.frames[a][st.frame], r.frames[b][st.frame]
        ma_in, mb_in = closed_mesh(fa.hs_in, fa.xform), closed_mesh(fb.hs_in, fb.xform)
        depth[st.frame] = float(max(depth_inside(mb_in, ma_in.vertices).max(), depth_inside(ma_in, mb_in.vertices).max()))
        ma, mb = closed_mesh(fa.hs_out, fa.xform), closed_mesh(fb.hs_out, fb.xform)
        residual[st.frame] = float(max(depth_inside(mb, ma.vertices).max(), depth_inside(ma, mb.vertices).max()))
    check(r, a, depth, size, residual)
    check(r, b, depth, size, residual)
    for st in r.stats[1:]:
        tips = []
        for path, contact in zip((a, b), st.contacts[0]):
            fr = r.frames[path][st.frame]
            uv = _on_surface(fr.hs_in, fr.xform, contact, size)
            moved = _world(fr.xform, np.stack([_evaluate(fr.hs_in, uv), _evaluate(fr.hs_out, uv)]))
            tips.append(np.linalg.norm(moved[1] - moved[0]))
        gap = np.linalg.norm(st.contacts[0][1] - st.contacts[0][0])
        assert tips[0] / (tips[0] + tips[1]) == pytest.approx(rb / (ra + rb), abs=1e-4)
        assert tips[0] + tips[1] == pytest.approx(gap, rel=1e-3)


# --- 7. absorption on an unrefined level -------------------------------------------------------------
def _level2_only(tmp_path, refine, **options):
    stage, size = sheet_stage(3, absorption=(0.0, 0.0, 1.0), refine=refine)
    box = moving_box(stage, 1.0, {"x": [0.13] * 3, "y": [-0.07] * 3, "z": [0.8, 0.45, 0.3]})
    return run(stage, tmp_path, refine, **options), box, size


def test_obey_leaves_absorption_on_an_unrefined_level_unapplied(tmp_path):
    """All absorption on level 2, which the sheet never refined: under ``obey`` the level is
    skipped everywhere, so the documented remainder is the whole input penetration, exactly, and
    the sheet is the animator's (no offset anywhere)."""
    r, box, size = _level2_only(tmp_path, "obey")
    for st in r.stats:
        fr = r.frames["/World/Sheet"][st.frame]
        lo, hi = box_bounds(r.src, box, st.frame)
        depth = box_depth(fr.world(fr.hs_in), lo, hi).max()  # 0, 0.05 and 0.2 (the box's bottom)
        assert st.residual == pytest.approx(depth, rel=1e-6, abs=1e-12)
        assert np.abs(fr.p_out - fr.p_in).max() <= F32 * size
        assert H.to_arrays(fr.hs_out).offsets.size == 0
    assert r.stats[-1].residual == pytest.approx(0.2, rel=1e-6)


def test_refine_clears_absorption_on_an_unrefined_level(tmp_path):
    """All absorption on level 2 under ``refine``: the response refines where the box is and
    later rounds act at each rim patch's deepest sample once its middle is on its target
    (`datapoints.data_points_for`); before that, 4.5e-3 of the size stayed inside at the box's
    bottom corners whatever the number of rounds."""
    r, box, size = _level2_only(tmp_path, "refine", iterations=8)
    box_case(r, "/World/Sheet", box, size, along=(2, -1))


# --- 8. scene scale ------------------------------------------------------------------------------
Q = 125 / 256  # unit of the scaled scene: Q · 10^±3 and its dyadic fractions are exact in float32


def _scaled_scene(s: float) -> tuple[Usd.Stage, float]:
    """A box pressing onto a bump of a sheet, every length times ``s`` and exact in float32, so the
    three runs get exactly proportional input (the bump makes the deepest point unique)."""
    h = np.zeros((11, 11))
    h[5, 4] = Q / 4
    cvs, _, _ = shapes.sheet(11, 11, width=8 * Q * s, depth=8 * Q * s, height=h * s)
    stage, size = sheet_stage(3, cvs=cvs)
    moving_box(stage, 2 * Q * s, {"x": [13 / 128 * Q * s] * 3, "y": [-21 / 128 * Q * s] * 3,
                                  "z": [2 * Q * s, 0.75 * Q * s, 0.5 * Q * s]})
    return stage, size


@pytest.fixture(scope="module")
def unit_scale(tmp_path_factory):
    return _scale_numbers(tmp_path_factory.mktemp("unit_scale"), 1.0)


def _scale_numbers(tmp_path, s: float):
    stage, size = _scaled_scene(s)
    r = run(stage, tmp_path, f"scale_{s:g}")
    box_case(r, "/World/Sheet", "/World/Mover/Box", size, along=(2, -1))
    moved = [np.linalg.norm(r.frames["/World/Sheet"][st.frame].p_out - r.frames["/World/Sheet"][st.frame].p_in, axis=1) / size
             for st in r.stats]
    return np.array([st.residual_rel for st in r.stats]), moved


@pytest.mark.parametrize("s", [1e3, 1e-3])  # 1e-3 failed while trimesh's closest points ran in absolute units
def test_scaled_scene_matches_unit_scale(tmp_path, unit_scale, s):
    """Relative residuals and relative displacements of every point equal the unit scene's within
    1e-6 relative (plus float32 rounding of the output points, 2^-23 of the size).

    The residual is a depth of the display's float32 points, and 10^±3 is not a power of 2, so
    the scaled runs round their coordinates differently: a point moves by at most sqrt(3) 2^-24 of
    its largest coordinate, under half the size here (the sheet is centred), so each run's depth
    is within 0.87 · 2^-24 of the size of its exact value and two runs within 2^-23 = `F32`
    (measured 3.9e-10 of the size at frame 2, 8.6e-7 of the residual). A displacement is a
    difference of two rounded points: twice that."""
    res1, moved1 = unit_scale
    res_s, moved_s = _scale_numbers(tmp_path, s)
    np.testing.assert_allclose(res_s, res1, rtol=1e-6, atol=F32)
    for a, b in zip(moved_s, moved1):
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=2 * F32)


# --- 9. frame jumps -------------------------------------------------------------------------------
def _jump(tmp_path, name, z_keys):
    stage, size = sheet_stage(len(z_keys), n=12, width=4.0)
    box = moving_box(stage, 1.0, {"x": [0.1] * len(z_keys), "y": [-0.1] * len(z_keys), "z": z_keys})
    r = run(stage, tmp_path, name)
    return r, box, size


def _assert_came_from_above(r: Run, box: str, size: float) -> None:
    """Every sheet point under the box (0.05 in from its sides) is at or below its bottom face."""
    for st in r.stats:
        lo, hi = box_bounds(r.src, box, st.frame)
        if lo[2] > 0:
            continue
        p = r.frames["/World/Sheet"][st.frame].p_out
        under = np.all((p[:, :2] > lo[:2] + 0.05) & (p[:, :2] < hi[:2] - 0.05), axis=1)
        assert p[under, 2].max() <= lo[2] + TOL * size, (st.frame, p[under, 2].max(), lo[2])


def test_half_box_jumps_push_the_sheet_back_the_way_the_box_came(tmp_path):
    """The unit box falls half its height per frame: touching, half through, then 95% through
    (its top 0.05 above the sheet, where the nearest face is the top): the sheet goes down."""
    r, box, size = _jump(tmp_path, "jumps", [1.0, 0.5, 0.0, -0.45])
    box_case(r, "/World/Sheet", box, size, along=(2, -1))
    _assert_came_from_above(r, box, size)


def test_half_box_jump_onto_the_far_face_pushes_back(tmp_path):
    r, box, size = _jump(tmp_path, "jumps_through", [1.0, 0.5, 0.0, -0.5])
    _assert_came_from_above(r, box, size)
    for st in r.stats:  # the depth along the motion: from the sheet (z = 0) to the box's bottom face
        lo, hi = box_bounds(r.src, box, st.frame)
        fr = r.frames["/World/Sheet"][st.frame]
        along = -lo[2] if lo[2] < 0.0 <= hi[2] else 0.0
        assert np.linalg.norm(fr.p_out - fr.p_in, axis=1).max() <= 2.0 * along + TOL * size, st.frame
        assert st.residual_rel <= TOL


# --- 10. degenerate patches -------------------------------------------------------------------------
def _fan_cvs(n: int = 8, width: float = 3.0) -> np.ndarray:
    """A triangular sheet: CV row 1 (its v = 0 edge) collapsed to one point, row 0 the mirror of
    row 2 through it, so the whole edge is one point (the apex at y = -1.5): the first row of
    patches is degenerate (zero-length edge, vanishing du)."""
    cvs, _, _ = shapes.sheet(n, n, width=width, depth=width)
    cvs[:, :, 0] *= ((np.arange(n) - 1.0) / (n - 3))[None, :]
    cvs[:, 0, 0] = -cvs[:, 2, 0]
    return cvs


FAN_ROUNDS = 12  # the fan's apex needs up to 5 rounds where the user looks (docs/hard-cases.md, case 10)


def _fan(tmp_path, name, absorption) -> None:
    """A 0.6 box pressed 0.1, then 0.15 into the fan's apex, which lies inside its footprint.

    Besides the common checks, no display normal may point down by more than 0.1 in z: a dent's
    walls are at most vertical (measured -4e-12 on the fine level), a fold turns them over. And
    the apex stays one point, as a pole does (case 5): the responded surface at v = 0 for 33
    values of u spreads at most 1e-9 of the size, and the collapsed CV row stays one point.

    The residual where the user looks falls slowly at the apex, a sliver on the box's side face
    at the collapsed edge: the case runs with `FAN_ROUNDS`. At the default cap of 4 the frames
    that are left over are reported over the tolerance, never under what the output shows."""
    stage, size = sheet_stage(3, cvs=_fan_cvs(), absorption=absorption)
    box = moving_box(stage, 0.6, {"y": [-1.2] * 3, "z": [0.6, 0.2, 0.15]})
    capped = run_file(A.save(stage, tmp_path / f"{name}_capped.usda"), output=tmp_path / f"{name}_capped.acra.usda")
    measured = visible.worst_by_frame(visible.measure_layer(capped.output, [s.frame for s in capped.stats]))
    assert all(s.residual_rel >= measured[s.frame] - visible.SLACK for s in capped.stats)  # never under
    over = [(s.frame, s.residual_rel) for s in capped.stats if s.residual_rel > TOL]
    assert capped.over == over and capped.status == (3 if over else 0)
    r = run(stage, tmp_path, name, iterations=FAN_ROUNDS)
    box_case(r, "/World/Sheet", box, size, along=(2, -1))
    out = Usd.Stage.Open(str(r.report.output))
    normals = UsdGeom.Mesh(out.GetPrimAtPath("/World/Sheet")).GetNormalsAttr()
    for st in r.stats:
        n = np.asarray(normals.Get(st.frame))
        assert np.all(np.isfinite(n)) and n[:, 2].min() >= -0.1, (st.frame, n[:, 2].min())
        hs = r.frames["/World/Sheet"][st.frame].hs_out
        u = np.linspace(0.0, hs.u.patches0, 33)
        apex = H.evaluate(hs, u, np.zeros_like(u), det=H.details(hs) if hs.depth > 1 else None).points
        assert np.all(np.isfinite(apex)) and np.ptp(apex, axis=0).max() <= 1e-9 * size, (st.frame, np.ptp(apex, axis=0))
        assert np.ptp(hs.cvs[:, 1], axis=0).max() <= 1e-9 * size  # the collapsed CV row stays one point


def test_collapsed_edge_dented_on_the_fine_level(tmp_path):
    """All absorption on level 2 at the apex of a sheet with a collapsed edge: the apex stays one
    point and, closed after the finest level's solve rather than within it, the case clears
    (docs/algorithm.md, "a fan's apex")."""
    _fan(tmp_path, "fan_fine", (0.0, 0.0, 1.0))


def test_collapsed_edge_dented_on_every_level(tmp_path):
    """Levels 0-2 (0.2, 0.3, 0.5): the apex is a closed end (`H.closed_ends`), every fine ring
    frames its detail with the end's one normal (`H.details`) so coarse moves do not fold the fan,
    and the finest level's ring is closed after its solve (`respond.respond`)."""
    _fan(tmp_path, "fan_levels", (0.2, 0.3, 0.5))
