"""USD input validation, per-time evaluation and the output layer (pipeline.usdio)."""

import math

import numpy as np
import pytest
from pxr import Gf, Sdf, Ts, Usd, UsdGeom, UsdValidation, Vt

from acra import hspline as H
from acra import shapes
from acra.tessellate import evaluate_grid, run_topology
from pipeline import authoring as A
from pipeline import output_layer
from pipeline import usdio as U
from pipeline.model import InputError

SHEET = "/World/rig/sheet"
FLOOR = "/World/floor"


def sheet_hierarchy(seed=0):
    """A 6×5 open sheet, 3 levels, refined and offset at levels 1 and 2 (random float64 offsets)."""
    rng = np.random.default_rng(seed)
    cvs, _, _ = shapes.sheet(6, 5, width=3.0, depth=2.0, height=0.2 * rng.normal(size=(6, 5)))
    hs = H.from_grid(cvs, depth=3)
    hs = H.make_movable(hs, 1, [[2, 1]])
    hs = H.make_movable(hs, 2, [[5, 3]])
    for k in (1, 2):
        idx, off = H.offsets_of(hs, k)
        hs = H.set_offsets(hs, k, idx, 0.05 * rng.normal(size=off.shape))
    return hs


def build_stage(frames=(1, 3)):
    """Parent Xform keyed in translate; a keyed sheet; a box collider."""
    stage = A.new_stage(*frames)
    rig = A.add_xform(stage, "/World/rig")
    A.key_transform(rig, frames[0], translate=(0, 0, 0))
    A.key_transform(rig, frames[1], translate=(1, 2, 0), rotate_xyz=(0, 0, 20))
    hs = sheet_hierarchy()
    sheet = A.add_deformable(stage, SHEET, hs.cvs, levels=3, hierarchy=hs, absorption=[0.2, 0.3, 0.5], samples=2)
    A.key_cvs(sheet, frames[0], hs.cvs)
    A.key_cvs(sheet, frames[1], hs.cvs + [0.0, 0.0, 0.5])
    A.add_collider(stage, FLOOR, *A.box((4, 4, 0.2), center=(0, 0, -1)))
    return stage


@pytest.fixture
def scene_file(tmp_path):
    path = tmp_path / "in.usda"
    A.save(build_stage(), path)
    return path


def run_identity(stage, scene, frames=None, perturb=None):
    """Frame results holding the animator's shape (optionally with a perturbed hierarchy)."""
    res = output_layer.FramesResult()
    for f in frames or range(scene.start, scene.end + 1):
        ds, _ = U.state_at(stage, scene, f)
        for m, d in zip(scene.deformables, ds):
            surface = d.surface if perturb is None else perturb(d.surface, f)
            p, n = evaluate_grid(surface, m.topology)
            res.add(f, m.path, output_layer.DeformableResult(p, n, surface, residual=0.01 * f, in_collision=f % 2 == 0))
    return res


def validate(stage):
    ctx = UsdValidation.ValidationContext(UsdValidation.ValidationRegistry().GetOrLoadAllValidators())
    return [e.GetMessage() for e in ctx.Validate(stage)]


# --------------------------------------------------------------------------------------------
# reading


def test_read_scene_models(scene_file):
    stage = U.open_input(scene_file)
    scene = U.read_scene(stage)
    assert (scene.start, scene.end, scene.up_axis, scene.meters_per_unit) == (1, 3, "Z", 1.0)
    (m,) = scene.deformables
    (c,) = scene.colliders
    assert m.path == SHEET and (m.nu, m.nv, m.depth) == (6, 5, 3)
    np.testing.assert_array_equal(m.controls.absorption, np.float32([0.2, 0.3, 0.5]))
    np.testing.assert_array_equal(m.controls.deform, [1, 1, 1])
    np.testing.assert_array_equal(m.controls.translate + m.controls.rotate, [0, 0, 0])
    assert (m.controls.rigidity, m.controls.refine, m.controls.samples) == (50.0, True, 2)
    expected = H.to_arrays(sheet_hierarchy())
    for name in ("patch_level", "patches", "offset_level", "offset_cvs", "offsets"):
        np.testing.assert_array_equal(getattr(m.hierarchy, name), getattr(expected, name))
    # the rest display: 2 steps per edge of the finest patch the animator's hierarchy has there
    rest = run_topology([sheet_hierarchy()], 2)
    np.testing.assert_array_equal(m.topology.u, rest.u)
    np.testing.assert_array_equal(m.topology.indices, rest.indices)
    assert c.path == FLOOR and c.vertices.shape == (8, 3) and c.triangles.shape == (12, 3)


def test_grid_index_convention(tmp_path):
    """USD acra:cvs index j * uCount + i is our cvs[i, j]."""
    stage = A.new_stage(0, 0)
    cvs = np.random.default_rng(3).normal(size=(5, 7, 3))
    prim = A.add_deformable(stage, "/World/s", cvs)
    flat = np.asarray(prim.GetAttribute("acra:cvs").Get())
    nu = 5
    for i, j in [(0, 0), (4, 0), (1, 6), (3, 2)]:
        np.testing.assert_array_equal(flat[j * nu + i], cvs[i, j].astype(np.float32))
    scene = U.read_scene(stage)
    (d,), _ = U.state_at(stage, scene, 0)
    np.testing.assert_array_equal(d.surface.cvs, cvs.astype(np.float32).astype(np.float64))


def test_frame_range_from_samples_or_zero():
    stage = Usd.Stage.CreateInMemory()
    assert U.frame_range(stage) == (0, 0)
    xf = UsdGeom.Xform.Define(stage, "/X")
    op = xf.AddTranslateXOp()
    spline = Ts.Spline("double")
    for t, v in ((-2.0, 0.0), (7.5, 1.0)):
        spline.SetKnot(Ts.Knot(time=t, value=v, nextInterp=Ts.InterpLinear))
    op.GetAttr().SetSpline(spline)
    xf.AddScaleOp().Set(Gf.Vec3f(1, 1, 1), 3.0)
    assert U.frame_range(stage) == (-2, 8)
    stage.SetStartTimeCode(1.5)
    with pytest.raises(InputError, match="startTimeCode: 1.5 is not an integer frame"):
        U.frame_range(stage)


def test_collider_fan_triangulation_and_orientation():
    stage = A.new_stage(0, 0)
    verts = np.array([[0, 0, 0], [1, 0, 0], [1.5, 1, 0], [0.5, 1.5, 0], [-0.5, 1, 0], [3, 0, 0], [3, 1, 0]], float)
    A.add_collider(stage, "/World/c", verts, [[0, 1, 2, 3, 4], [1, 5, 6]])
    (c,) = U.read_scene(stage).colliders
    np.testing.assert_array_equal(c.triangles, [[0, 1, 2], [0, 2, 3], [0, 3, 4], [1, 5, 6]])
    UsdGeom.Mesh(stage.GetPrimAtPath("/World/c")).CreateOrientationAttr().Set(UsdGeom.Tokens.leftHanded)
    (c,) = U.read_scene(stage).colliders
    np.testing.assert_array_equal(c.triangles[0], [2, 1, 0])


def test_collider_uses_start_time_points():
    stage = A.new_stage(4, 6)
    v, f = A.box(1.0)
    prim = A.add_collider(stage, "/World/c", v, f)
    UsdGeom.Mesh(prim).GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy((v + 5).astype(np.float32)), 4.0)
    UsdGeom.Mesh(prim).GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy((v + 9).astype(np.float32)), 6.0)
    (c,) = U.read_scene(stage).colliders
    np.testing.assert_array_equal(c.vertices, v + 5)


# --------------------------------------------------------------------------------------------
# per-time evaluation


def test_state_at_spline_op_and_animated_parent_at_subframes():
    stage = A.new_stage(0, 4)
    parent = A.add_xform(stage, "/World/parent")
    A.key_transform(parent, 0, translate=(0, 0, 0), rotate_xyz=(0, 0, 0))
    A.key_transform(parent, 4, translate=(0, 10, 0), rotate_xyz=(0, 0, 90))
    cvs, _, _ = shapes.sheet(4, 4)
    prim = A.add_deformable(stage, "/World/parent/s", cvs)
    spline = Ts.Spline("double")
    spline.SetKnot(Ts.Knot(time=1.0, value=2.0, nextInterp=Ts.InterpLinear))
    spline.SetKnot(Ts.Knot(time=2.0, value=4.0, nextInterp=Ts.InterpLinear))
    UsdGeom.Xformable(prim).AddTranslateXOp().GetAttr().SetSpline(spline)
    A.add_collider(stage, "/World/parent/c", *A.box(1.0))
    scene = U.read_scene(stage)
    for t in (0.25, 1.5, 1.75, 3.5):
        (d,), (c,) = U.state_at(stage, scene, t)
        a = math.radians(90.0 * t / 4.0)
        par = np.eye(4)
        par[:3, :3] = [[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]]
        par[:3, 3] = (0, 10 * t / 4, 0)
        child = np.eye(4)
        child[0, 3] = 2.0 + 2.0 * min(max(t - 1.0, 0.0), 1.0)  # held outside the knots
        np.testing.assert_allclose(d.xform, par @ child, atol=1e-6)
        np.testing.assert_allclose(c.xform, par, atol=1e-6)
        # column convention: the object origin lands at the world translation
        np.testing.assert_allclose(d.xform @ [0, 0, 0, 1], (par @ child)[:, 3], atol=1e-6)


def test_state_at_with_held_transforms_gives_the_stages_matrices_at_every_time():
    """`state_at` with ``held`` reads world transforms through the one `UsdGeom.XformCache` it
    keeps, moved to each time code: under a static parent, an animated parent, a spline op or
    keyed ops, every matrix is the same bits as a new cache's (no ``held``), whatever time is
    asked first and in whatever order, and a new array at each call."""
    stage = A.new_stage(0, 4)
    cvs, _, _ = shapes.sheet(4, 4)
    still = A.add_xform(stage, "/World/still")
    A.key_transform(still, 2, translate=(1.5, -2.25, 0.1), rotate_xyz=(10, 20, 30))  # one sample: cannot vary
    A.add_deformable(stage, "/World/still/s", cvs)
    moving = A.add_xform(stage, "/World/moving")
    A.key_transform(moving, 0, translate=(0, 0, 0), rotate_xyz=(0, 0, 0))
    A.key_transform(moving, 4, translate=(0, 10, 0), rotate_xyz=(0, 0, 90))
    A.add_deformable(stage, "/World/moving/s", cvs)
    splined = A.add_deformable(stage, "/World/splined", cvs)
    spline = Ts.Spline("double")
    spline.SetKnot(Ts.Knot(time=1.0, value=2.0, nextInterp=Ts.InterpLinear))
    spline.SetKnot(Ts.Knot(time=2.0, value=4.0, nextInterp=Ts.InterpLinear))
    UsdGeom.Xformable(splined).AddTranslateXOp().GetAttr().SetSpline(spline)
    keyed = A.add_deformable(stage, "/World/keyed", cvs)
    A.key_transform(keyed, 1, translate=(0, 0, 0))
    A.key_transform(keyed, 3, translate=(0, 0, 6))
    A.add_collider(stage, "/World/still/c", *A.box(1.0))
    A.add_collider(stage, "/World/moving/c", *A.box(1.0))
    A.add_collider(stage, "/World/c", *A.box(2.0))
    scene = U.read_scene(stage)
    times = (2.5, 0.0, 0.25, 1.5, 1.75, 3.5, 4.0, 2.5)
    for first in (0, 3):  # a static transform read first at a time where the others are still and where they move
        held: dict = {}
        seen = []
        for t in times[first:] + times[:first]:
            ds, cs = U.state_at(stage, scene, t, held)
            ds0, cs0 = U.state_at(stage, scene, t)
            for a, b in zip(ds + cs, ds0 + cs0):
                assert a.xform.dtype == np.float64 and a.xform.flags.c_contiguous and a.xform.flags.writeable
                np.testing.assert_array_equal(a.xform, b.xform)
                assert all(a.xform is not s and not np.shares_memory(a.xform, s) for s in seen)
                seen.append(a.xform)
            ds[3].xform[:] = np.nan  # a caller's changes to its matrix stay its own
            cs[0].xform[:] = np.nan
        assert isinstance(held.get("xform cache"), UsdGeom.XformCache)


def test_state_at_interpolates_cvs_and_holds_enabled(scene_file):
    stage = U.open_input(scene_file)
    A.key_enabled(stage.GetPrimAtPath(SHEET), 1, True)
    A.key_enabled(stage.GetPrimAtPath(SHEET), 2, False)
    scene = U.read_scene(stage)
    base = sheet_hierarchy()
    (d1,), _ = U.state_at(stage, scene, 1.0)
    (dm,), _ = U.state_at(stage, scene, 2.5)
    np.testing.assert_allclose(dm.surface.cvs, base.cvs + [0, 0, 0.375], atol=1e-6)
    # the hierarchy rides along unchanged, only level-0 CVs swap
    assert dm.surface.fine is not None and all(a is b for a, b in zip(dm.surface.fine, d1.surface.fine))
    got = H.to_arrays(dm.surface)
    np.testing.assert_array_equal(got.offsets, H.to_arrays(base).offsets)
    assert [U.state_at(stage, scene, t)[0][0].enabled for t in (1.0, 1.9, 2.0, 2.7, 3.0)] == [True, True, False, False, False]


# --------------------------------------------------------------------------------------------
# writing


def perturbed(surface, frame):
    """A response-like surface: moved CVs, an extra refined region with full-precision offsets."""
    rng = np.random.default_rng(frame)
    hs = H.make_movable(surface, 2, [[1, 1]])
    idx, off = H.offsets_of(hs, 2)
    hs = H.set_offsets(hs, 2, idx, off + rng.normal(size=off.shape) / 3.0)
    from dataclasses import replace

    return replace(hs, cvs=hs.cvs + rng.normal(size=hs.cvs.shape) * np.pi / 7.0)


def test_hierarchy_round_trip_bit_for_bit(scene_file, tmp_path):
    stage = U.open_input(scene_file)
    scene = U.read_scene(stage)
    res = run_identity(stage, scene, perturb=perturbed)
    out = output_layer.write_output(scene_file, tmp_path / "out.usda", scene, res)
    ostage = Usd.Stage.Open(str(out))
    for f, per in res.frames.items():
        written = per[SHEET].surface
        back = output_layer.read_output_hierarchy(ostage, SHEET, f)
        assert back.cvs.dtype == np.float64
        np.testing.assert_array_equal(back.cvs, written.cvs)
        a, b = H.to_arrays(back), H.to_arrays(written)
        for name in ("patch_level", "patches", "offset_level", "offset_cvs", "offsets"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        for la, lb in zip(back.fine, written.fine):
            np.testing.assert_array_equal(la.cv_keys, lb.cv_keys)
            np.testing.assert_array_equal(la.offsets, lb.offsets)
        prim = ostage.GetPrimAtPath(SHEET)
        assert prim.GetAttribute("acra:response:residual").Get(f) == pytest.approx(0.01 * f, abs=0)
        assert prim.GetAttribute("acra:response:inCollision").Get(f) == (f % 2 == 0)


def test_output_composes_validates_and_holds_only_overs(scene_file, tmp_path):
    before = scene_file.read_bytes()
    stage = U.open_input(scene_file)
    scene = U.read_scene(stage)
    res = run_identity(stage, scene, perturb=perturbed)
    out_dir = tmp_path / "renders"
    out_dir.mkdir()
    out = output_layer.write_output(scene_file, out_dir / "shot.acra.usda", scene, res)
    assert scene_file.read_bytes() == before

    layer = Sdf.Layer.OpenAsAnonymous(str(out))
    assert list(layer.subLayerPaths) == ["../in.usda"]
    specs = []
    layer.Traverse(layer.pseudoRoot.path, specs.append)
    allowed = {"points", "normals", "faceVertexCounts", "faceVertexIndices", output_layer.DISPLAY_UV, *U.RESPONSE_TYPES}
    for path in specs:
        if path.IsPrimPath():
            assert layer.GetPrimAtPath(path).specifier == Sdf.SpecifierOver, path
        elif path.IsPropertyPath():
            assert path.name in allowed, path
    assert {p.name for p in specs if p.IsPropertyPath()} == allowed

    ostage = Usd.Stage.Open(str(out))
    assert validate(ostage) == []
    assert ostage.GetPrimAtPath(FLOOR).HasAPI("PhysicsCollisionAPI")  # input prims show through
    for key in ("startTimeCode", "endTimeCode", "timeCodesPerSecond", "framesPerSecond", "upAxis", "metersPerUnit", "defaultPrim"):
        assert ostage.GetMetadata(key) == stage.GetMetadata(key), key
    mesh = UsdGeom.Mesh(ostage.GetPrimAtPath(SHEET))
    assert mesh.GetNormalsInterpolation() == UsdGeom.Tokens.vertex
    for f in (1, 2, 3):
        np.testing.assert_array_equal(np.asarray(mesh.GetPointsAttr().Get(f)), res.frames[f][SHEET].points.astype(np.float32))
        np.testing.assert_array_equal(np.asarray(mesh.GetNormalsAttr().Get(f)), res.frames[f][SHEET].normals.astype(np.float32))
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get())
    assert counts.sum() == np.asarray(mesh.GetFaceVertexIndicesAttr().Get()).size
    # each display vertex's surface parameter, written once: the input surface evaluated there is
    # the input's display on the output's topology, vertex for vertex
    (m,) = scene.deformables
    uv = output_layer.read_display_uv(ostage, SHEET)
    np.testing.assert_array_equal(uv, np.stack([m.topology.u, m.topology.v], axis=1))
    assert ostage.GetPrimAtPath(SHEET).GetAttribute(output_layer.DISPLAY_UV).GetVariability() == Sdf.VariabilityUniform
    assert not ostage.GetPrimAtPath(SHEET).GetAttribute(output_layer.DISPLAY_UV).GetNumTimeSamples()
    surface = U.state_at(stage, scene, 2)[0][0].surface
    at_sites, _ = evaluate_grid(surface, output_layer.FramesResult().topology(m))
    np.testing.assert_allclose(H.evaluate(surface, uv[:, 0], uv[:, 1], det=H.details(surface)).points, at_sites, rtol=0, atol=1e-14)
    # the animator's rest surface at the output's vertices is the input's rest display (authored
    # from the CVs before they were stored as float32: the same to float32 precision)
    rest = np.asarray(UsdGeom.Mesh(stage.GetPrimAtPath(SHEET)).GetPointsAttr().Get(), np.float64)
    np.testing.assert_allclose(output_layer.input_points(ostage, SHEET), rest, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(output_layer.read_display_topology(ostage, SHEET).indices, m.topology.indices)
    # transforms are untouched at every frame and between frames
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Xformable):
            for t in (1.0, 1.5, 2.0, 2.25, 3.0):
                a = UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(t)
                b = UsdGeom.Xformable(ostage.GetPrimAtPath(prim.GetPath())).ComputeLocalToWorldTransform(t)
                assert a == b, (prim.GetPath(), t)
    # acra: inputs resolve to the input's values (not overridden)
    for name in U.INPUT_ATTRIBUTES:
        a, b = stage.GetPrimAtPath(SHEET).GetAttribute(name), ostage.GetPrimAtPath(SHEET).GetAttribute(name)
        if a.HasAuthoredValue():
            assert a.GetTimeSamples() == b.GetTimeSamples() and a.Get(2) == b.Get(2), name


def test_output_bounds_follow_written_points(scene_file, tmp_path):
    """No extent is authored on deformables, so USD bounds come from the output's points."""
    stage = U.open_input(scene_file)
    scene = U.read_scene(stage)
    res = run_identity(stage, scene, perturb=perturbed)
    ostage = Usd.Stage.Open(str(output_layer.write_output(scene_file, tmp_path / "out.usda", scene, res)))
    for f in (1, 3):
        box = UsdGeom.BBoxCache(f, [UsdGeom.Tokens.default_]).ComputeLocalBound(ostage.GetPrimAtPath(SHEET))
        rng = box.ComputeAlignedRange()
        pts = res.frames[f][SHEET].points.astype(np.float32)
        np.testing.assert_allclose([rng.GetMin(), rng.GetMax()], [pts.min(axis=0), pts.max(axis=0)], rtol=1e-6)


def test_output_is_deterministic(scene_file, tmp_path):
    stage = U.open_input(scene_file)
    scene = U.read_scene(stage)
    res = run_identity(stage, scene, perturb=perturbed)
    a = output_layer.write_output(scene_file, tmp_path / "a.usda", scene, res)
    b = output_layer.write_output(scene_file, tmp_path / "b.usda", scene, run_identity(stage, U.read_scene(stage), perturb=perturbed))
    assert a.read_bytes() == b.read_bytes()


@pytest.mark.parametrize("where", ["export", "replace"])
def test_write_is_atomic(scene_file, tmp_path, monkeypatch, where):
    stage = U.open_input(scene_file)
    scene = U.read_scene(stage)
    res = run_identity(stage, scene)
    out = tmp_path / "out.usda"
    real_export = U._export

    def export_then_fail(layer, path):
        real_export(layer, path)  # the temporary file is complete on disk ...
        raise KeyboardInterrupt  # ... and the run is interrupted before the rename

    if where == "export":
        monkeypatch.setattr(U, "_export", export_then_fail)
    else:
        monkeypatch.setattr(U.os, "replace", lambda *a: (_ for _ in ()).throw(OSError("disk full")))
    with pytest.raises((KeyboardInterrupt, OSError)):
        output_layer.write_output(scene_file, out, scene, res)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.usda"]


def test_write_rejects_incomplete_results(scene_file, tmp_path):
    stage = U.open_input(scene_file)
    scene = U.read_scene(stage)
    res = run_identity(stage, scene)
    del res.frames[2][SHEET]
    with pytest.raises(ValueError, match=f"frame 2: no result for {SHEET}"):
        output_layer.write_output(scene_file, tmp_path / "out.usda", scene, res)
    res = run_identity(stage, scene)
    r = res.frames[3][SHEET]
    res.frames[3][SHEET] = output_layer.DeformableResult(r.points[:-1], r.normals[:-1], r.surface)
    with pytest.raises(ValueError, match="points has shape"):
        output_layer.write_output(scene_file, tmp_path / "out.usda", scene, res)
    assert not (tmp_path / "out.usda").exists()



def _shared_and_copied(stage, scene):
    """Results whose frames 1-3 hold the very same objects (as the frame loop gives free frames), and
    the same results with every frame's arrays and surface copied."""
    one = run_identity(stage, scene, frames=[1], perturb=perturbed).frames[1][SHEET]
    shared, copied = output_layer.FramesResult(), output_layer.FramesResult()
    for f in (1, 2, 3):
        shared.add(f, SHEET, output_layer.DeformableResult(one.points, one.normals, one.surface, 0.01 * f, f == 2))
        surface = H.from_arrays(H.from_grid(one.surface.cvs.copy(), depth=one.surface.depth), H.to_arrays(one.surface))
        copied.add(f, SHEET, output_layer.DeformableResult(one.points.copy(), one.normals.copy(), surface, 0.01 * f, f == 2))
    return one, shared, copied


@pytest.mark.parametrize("gather", [True, False])
def test_text_layer_pieces_are_written_whole_however_the_writes_split(tmp_path, monkeypatch, gather):
    """`output_layer._write_pieces` writes every piece in order when each system call takes only
    part of what it is handed (at most 7 bytes here), gathering with `os.writev` or not."""
    import os

    rng = np.random.default_rng(5)
    pieces = [bytes(rng.integers(0, 256, int(n), dtype=np.uint8)) for n in rng.integers(1, 40, 1100)]
    real = os.writev

    def short_writev(fd, views):
        return real(fd, [b"".join(bytes(v) for v in views)[:7]])

    if gather:
        monkeypatch.setattr(output_layer.os, "writev", short_writev)
    else:
        monkeypatch.delattr(output_layer.os, "writev")
    with open(tmp_path / "out", "wb", buffering=0) as fh:
        if not gather:
            fh = SimpleWriter(fh)
        output_layer._write_pieces(fh, [memoryview(p) for p in pieces])
    assert (tmp_path / "out").read_bytes() == b"".join(pieces)


class SimpleWriter:
    """A file whose ``write`` takes at most 5 bytes a call, as a raw file may."""

    def __init__(self, fh):
        self.fh = fh

    def write(self, data):
        return self.fh.write(bytes(data[:5]))


def test_vt_array_is_from_numpy():
    """`usdio.vt_array` (one block copy into a new Vt array from `VT_COPY_MIN` values, USD's
    conversion below) gives `FromNumpy`'s value for every array type the output layer writes, its
    own copy (a later change to the source does not show), and USD's conversion where the dtype is
    not the Vt type's own (float64 into float3[])."""
    rng = np.random.default_rng(3)
    cases = [(Vt.Vec3fArray, rng.normal(size=(257, 3)).astype(np.float32)), (Vt.Vec3dArray, rng.normal(size=(65, 3))),
             (Vt.Vec2dArray, rng.normal(size=(70, 2))), (Vt.Vec2iArray, rng.integers(-9, 9, (33, 2)).astype(np.int32)),
             (Vt.IntArray, rng.integers(-9, 9, 40).astype(np.int32)), (Vt.Vec3fArray, rng.normal(size=(9, 3))),
             (Vt.Vec3fArray, np.zeros((0, 3), np.float32)), (Vt.Vec3dArray, np.asfortranarray(rng.normal(size=(12, 3)))),
             (Vt.Vec3fArray, rng.normal(size=(U.VT_COPY_MIN, 3)).astype(np.float32)), (Vt.Vec3dArray, rng.normal(size=(700, 3))),
             (Vt.IntArray, rng.integers(-9, 9, U.VT_COPY_MIN).astype(np.int32)), (Vt.Vec2dArray, rng.normal(size=(U.VT_COPY_MIN // 2, 2))),
             (Vt.Vec2iArray, rng.integers(-9, 9, (U.VT_COPY_MIN // 2 - 1, 2)).astype(np.int32))]
    cases[0][1][5] = [-0.0, np.float32(1e-40), np.float32(3.4e38)]
    cases[8][1][5] = [-0.0, np.float32(1e-40), np.float32(3.4e38)]
    for vt, a in cases:
        got = U.vt_array(vt, a)
        assert type(got) is vt and got == vt.FromNumpy(np.ascontiguousarray(a))
        before = np.array(got)
        a[...] = 7
        assert np.array_equal(np.asarray(got), before)


def test_vt_buffer_is_the_new_arrays_own_memory():
    """Values written through `usdio.vt_buffer`'s view are the Vt array's: the value `FromNumpy`
    gives for them, kept after the source changes; a view of another shape or dtype is refused."""
    rng = np.random.default_rng(4)
    values = rng.normal(size=(3001, 3)).astype(np.float32)
    out, view = U.vt_buffer(Vt.Vec3fArray, values.shape, np.float32)
    assert view.flags.writeable and view.shape == values.shape and view.dtype == np.float32
    view[...] = values
    assert type(out) is Vt.Vec3fArray and out == Vt.Vec3fArray.FromNumpy(values)
    values[...] = 7
    assert np.array_equal(np.asarray(out).view(np.uint32), np.asarray(view).view(np.uint32)) and np.asarray(out)[0, 0] != 7
    assert U.vt_buffer(Vt.Vec3fArray, (4, 3), np.float64) == (None, None)
    assert U.vt_buffer(Vt.Vec3fArray, (4, 2), np.float32) == (None, None)
    assert U.vt_buffer(Vt.Vec3fArray, (0, 3), np.float32) == (None, None)


@pytest.mark.parametrize("closed", [False, True])
def test_response_hierarchy_is_to_arrays_and_one_value_per_levels(closed):
    """`output_layer._Hierarchy`'s values are `H.to_arrays`' arrays, and it hands surfaces that
    hold the same levels' arrays (a response's next frame with new level-0 CVs) the same values,
    its own to a surface whose offsets differ."""
    import dataclasses
    from types import SimpleNamespace

    from conftest import with_random_offsets

    hs = H.from_grid(*(shapes.sphere(10, 8) if closed else shapes.sheet(10, 8, 7.0, 5.0)), depth=4)
    hs = with_random_offsets(H.refine(H.refine(hs, 1, [[2, 2], [5, 3]]), 3, [[20, 17], [21, 17]]), 0.05, 0)
    idx, off = H.offsets_of(hs, 2)
    off[::2] = 0.0
    hs = H.set_offsets(hs, 2, idx, off)
    model = SimpleNamespace(nu=hs.cvs.shape[0], nv=hs.cvs.shape[1], depth=hs.depth, path="/A")
    hierarchy = output_layer._Hierarchy(lambda vt, a: vt.FromNumpy(a))
    first = hierarchy(model, 1, hs)
    moved = hierarchy(model, 2, dataclasses.replace(hs, cvs=hs.cvs + 1.0))
    other = hierarchy(model, 3, with_random_offsets(hs, 0.05, 1))
    names = ("patchLevel", "patches", "offsetLevel", "offsetCvs", "offsets")
    assert all(moved[f"acra:response:{n}"] is first[f"acra:response:{n}"] for n in names)
    assert other["acra:response:offsets"] is not first["acra:response:offsets"]
    for values, surface in ((first, hs), (other, with_random_offsets(hs, 0.05, 1))):
        want = H.to_arrays(surface)
        for n, field in zip(names, ("patch_level", "patches", "offset_level", "offset_cvs", "offsets")):
            np.testing.assert_array_equal(np.asarray(values[f"acra:response:{n}"]).reshape(getattr(want, field).shape), getattr(want, field))


def test_shared_results_are_written_as_their_copies(scene_file, tmp_path):
    """Repeated objects are converted once; the layer is byte-identical to one from copies."""
    stage = U.open_input(scene_file)
    scene = U.read_scene(stage)
    one, shared, copied = _shared_and_copied(stage, scene)
    a = output_layer.write_output(scene_file, tmp_path / "shared.usda", scene, shared)
    b = output_layer.write_output(scene_file, tmp_path / "copied.usda", scene, copied)
    assert a.read_bytes() == b.read_bytes()
    ostage = Usd.Stage.Open(str(a))
    prim = ostage.GetPrimAtPath(SHEET)
    for f in (1, 2, 3):
        np.testing.assert_array_equal(np.asarray(UsdGeom.Mesh(prim).GetPointsAttr().Get(f)), one.points.astype(np.float32))
        np.testing.assert_array_equal(output_layer.read_output_hierarchy(ostage, SHEET, f).cvs, one.surface.cvs)
        assert prim.GetAttribute("acra:response:residual").Get(f) == pytest.approx(0.01 * f, abs=0)
        assert prim.GetAttribute("acra:response:inCollision").Get(f) == (f == 2)


def _usd_text(path):
    """USD's own text of the layer at ``path``: what `Sdf.Layer.Export` writes as ``.usda``."""
    return Sdf.Layer.OpenAsAnonymous(str(path)).ExportToString().encode()


@pytest.mark.parametrize("make", ["shared", "copied", "mixed", "moved"])
def test_text_output_is_usds_own_text(scene_file, tmp_path, make):
    """A ``.usda`` layer, whose repeated arrays are formatted once and whose arrays' text is
    copied from the previous frame's where their values are the same, holds the bytes USD's text
    writer gives for the same layer (the ``.usdc`` written from the same results, exported)."""
    stage = U.open_input(scene_file)
    scene = U.read_scene(stage)
    one, shared, copied = _shared_and_copied(stage, scene)
    mixed = output_layer.FramesResult({1: shared.frames[1], 2: copied.frames[2], 3: shared.frames[3]})
    moved = output_layer.FramesResult()
    for f, r in copied.frames.items():  # a contact moving some of the points and normals at frames 2 and 3
        points, normals = r[SHEET].points.copy(), r[SHEET].normals.copy()
        points[3 * f:len(points) // f] += 0.25 * f
        normals[f::5] *= -1
        moved.add(f, SHEET, output_layer.DeformableResult(points, normals, r[SHEET].surface, 0.01 * f, f == 2))
    res = {"shared": shared, "copied": copied, "mixed": mixed, "moved": moved}[make]
    assert len(one.points) >= output_layer._SHARED_MIN
    text = output_layer.write_output(scene_file, tmp_path / "out.usda", scene, res)
    crate = output_layer.write_output(scene_file, tmp_path / "out.usdc", scene, res)
    assert text.read_bytes() == _usd_text(crate)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.usda", "out.usda", "out.usdc"]


def test_text_output_formats_display_arrays_without_vt_copies(scene_file, tmp_path, monkeypatch):
    """A ``.usda`` layer writes the text of its display points and normals from numpy
    (`acra.floattext`): none is converted to a Vt array (a copy element by element), and the
    bytes are USD's own text of the same layer."""
    stage = U.open_input(scene_file)
    scene = U.read_scene(stage)
    _, shared, copied = _shared_and_copied(stage, scene)
    crates = [output_layer.write_output(scene_file, tmp_path / f"{name}.usdc", scene, res)
              for name, res in (("shared", shared), ("copied", copied))]

    def no_vt(*a):
        raise AssertionError("a display array converted to Vt for a text layer")

    monkeypatch.setattr(output_layer, "_checked_vec3f", no_vt)
    for crate, res in zip(crates, (shared, copied)):
        text = output_layer.write_output(scene_file, tmp_path / f"{crate.stem}.usda", scene, res)
        assert text.read_bytes() == _usd_text(crate)


def test_a_long_text_output_is_streamed_by_usds_writer(scene_file, tmp_path, monkeypatch):
    """A layer whose text would exceed `output_layer.TEXT_HELD_MAX` is written by USD itself
    (streamed to the file), with the same bytes; a short one formats its shared arrays once."""
    stage = U.open_input(scene_file)
    scene = U.read_scene(stage)
    _, shared, _ = _shared_and_copied(stage, scene)
    crate = output_layer.write_output(scene_file, tmp_path / "out.usdc", scene, shared)
    used = []
    export = output_layer._SharedText.export
    monkeypatch.setattr(output_layer._SharedText, "export", lambda self, *a: used.append(self.chars) or export(self, *a))
    small = output_layer.write_output(scene_file, tmp_path / "small.usda", scene, shared)
    assert len(used) == 1 and 0 < used[0] <= output_layer.TEXT_HELD_MAX
    monkeypatch.setattr(output_layer, "TEXT_HELD_MAX", used[0] - 1)
    big = output_layer.write_output(scene_file, tmp_path / "big.usda", scene, shared)
    assert len(used) == 1
    assert small.read_bytes() == big.read_bytes() == _usd_text(crate)


def test_text_output_falls_back_to_usds_writer_when_a_stand_in_is_ambiguous(scene_file, tmp_path, monkeypatch):
    """Stand-ins whose text cannot tell two arrays apart: the layer is written by USD itself."""
    stage = U.open_input(scene_file)
    scene = U.read_scene(stage)
    _, shared, _ = _shared_and_copied(stage, scene)
    crate = output_layer.write_output(scene_file, tmp_path / "out.usdc", scene, shared)
    tname, _, _ = output_layer._STAND_INS[Vt.Vec3fArray]  # points and normals stand in alike
    monkeypatch.setitem(output_layer._STAND_INS, Vt.Vec3fArray, (tname, lambda k: Vt.Vec3fArray([Gf.Vec3f(math.nan, 0, math.nan)]),
                                                                 "[(nan, 0, nan)]"))
    text = output_layer.write_output(scene_file, tmp_path / "out.usda", scene, shared)
    assert text.read_bytes() == _usd_text(crate)


def test_stand_ins_text_is_usds():
    """Each stand-in's text (`output_layer._STAND_INS`) is what USD's writer gives its value."""
    layer = Sdf.Layer.CreateAnonymous("s.usda")
    prim = Sdf.CreatePrimInLayer(layer, "/A")
    want = {}
    for i, (tname, make, text) in enumerate(output_layer._STAND_INS.values()):
        for k in (0, 7, 10, 99, 123456, 2**24 - 1):
            Sdf.AttributeSpec(prim, f"s{i}_{k}", tname, Sdf.VariabilityVarying, True).default = make(k)
            want[f"s{i}_{k}"] = text.format(k)
    got = {line.split()[2]: line.split(" = ", 1)[1] for line in layer.ExportToString().splitlines() if line.strip().startswith("custom ")}
    assert got == want


def test_shared_invalid_values_are_rejected_at_their_first_frame(scene_file, tmp_path):
    stage = U.open_input(scene_file)
    scene = U.read_scene(stage)
    one, shared, _ = _shared_and_copied(stage, scene)
    one.normals[5, 1] = np.nan  # the array every frame holds
    with pytest.raises(ValueError, match=f"frame 1, {SHEET}: normals hold NaN"):
        output_layer.write_output(scene_file, tmp_path / "out.usda", scene, shared)
    with pytest.raises(ValueError, match=f"frame 1, {SHEET}: normals hold NaN"):  # rounded into a Vt array's buffer
        output_layer.write_output(scene_file, tmp_path / "out.usdc", scene, shared)
    assert not (tmp_path / "out.usdc").exists()
    _, shared, _ = _shared_and_copied(stage, scene)
    r = shared.frames[3][SHEET]
    shared.frames[3][SHEET] = output_layer.DeformableResult(r.points, r.normals, r.surface, float("inf"))
    with pytest.raises(ValueError, match=f"frame 3, {SHEET}: residual is not finite"):
        output_layer.write_output(scene_file, tmp_path / "out.usda", scene, shared)
    assert not (tmp_path / "out.usda").exists()


@pytest.mark.parametrize("suffix", [".usdc", ".usd"])
def test_binary_output_round_trips_and_is_deterministic(scene_file, tmp_path, suffix):
    """``-o NAME.usdc`` (and ``.usd``, whose default format is the crate) writes the binary crate
    with the same content: points, the response state bit for bit, byte-identical across runs."""
    stage = U.open_input(scene_file)
    scene = U.read_scene(stage)
    res = run_identity(stage, scene, perturb=perturbed)
    out = output_layer.write_output(scene_file, tmp_path / f"out{suffix}", scene, res)
    again = output_layer.write_output(scene_file, tmp_path / f"again{suffix}", scene, run_identity(stage, U.read_scene(stage), perturb=perturbed))
    assert out.read_bytes()[:8] == b"PXR-USDC"
    assert out.read_bytes() == again.read_bytes()
    ostage = Usd.Stage.Open(str(out))
    assert validate(ostage) == []
    mesh = UsdGeom.Mesh(ostage.GetPrimAtPath(SHEET))
    for f, per in res.frames.items():
        np.testing.assert_array_equal(np.asarray(mesh.GetPointsAttr().Get(f)), per[SHEET].points.astype(np.float32))
        back, written = output_layer.read_output_hierarchy(ostage, SHEET, f), per[SHEET].surface
        np.testing.assert_array_equal(back.cvs, written.cvs)
        a, b = H.to_arrays(back), H.to_arrays(written)
        for name in ("patch_level", "patches", "offset_level", "offset_cvs", "offsets"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))

# --------------------------------------------------------------------------------------------
# invalid input


def _retype(prim, name, tname, value):
    prim.RemoveProperty(name)
    prim.CreateAttribute(name, tname).Set(value)


def _set(prim, name, value, time=None):
    attr = prim.GetAttribute(name)
    attr.Set(value) if time is None else attr.Set(value, time)


def _counts(nu, nv, u_wrap="open"):
    def edit(prim):
        _set(prim, "acra:uCount", nu)
        _set(prim, "acra:vCount", nv)
        _set(prim, "acra:uWrap", u_wrap)
        cvs = Vt.Vec3fArray.FromNumpy(np.zeros((nu * nv, 3), np.float32))
        prim.GetAttribute("acra:cvs").Clear()
        _set(prim, "acra:cvs", cvs)
        for name in U.HIERARCHY_TYPES:
            prim.RemoveProperty(name)

    return edit


def _cvs_at(frame, fn):
    def edit(prim):
        flat = np.asarray(prim.GetAttribute("acra:cvs").Get(frame)).copy()
        _set(prim, "acra:cvs", Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(fn(flat), dtype=np.float32)), frame)

    return edit


F = Vt.FloatArray
BAD = {
    "missing uCount": (lambda p: p.RemoveProperty("acra:uCount"), "acra:uCount", "missing required attribute"),
    "missing cvs": (lambda p: p.RemoveProperty("acra:cvs"), "acra:cvs", "missing required attribute"),
    "cvs float[]": (lambda p: _retype(p, "acra:cvs", Sdf.ValueTypeNames.FloatArray, F([0.0] * 30)), "acra:cvs", "has type float[], expected point3f[]"),
    "cvs size at one sample": (_cvs_at(3, lambda a: a[:-1]), "acra:cvs", "has 29 values at time 3"),
    "NaN in cvs": (_cvs_at(3, lambda a: np.where(np.arange(len(a))[:, None] == 7, np.nan, a)), "acra:cvs", "NaN or inf at time 3 at index 7"),
    "inf rigidity": (lambda p: _set(p, "acra:rigidity", float("inf")), "acra:rigidity", "inf is not finite"),
    "rigidity double": (lambda p: _retype(p, "acra:rigidity", Sdf.ValueTypeNames.Double, 5.0), "acra:rigidity", "expected float"),
    "absorption sum 0.9": (lambda p: _set(p, "acra:absorption", F([0.2, 0.2, 0.5])), "acra:absorption", "sum to 0.9"),
    "negative share": (lambda p: _set(p, "acra:absorption", F([-0.5, 0.5, 1.0])), "acra:absorption", "negative share -0.5 at level 0"),
    "mix sum": (lambda p: _set(p, "acra:translate", F([0.0, 0.5, 0.0])), "acra:deform", "level 1: deform + translate + rotate = 1 + 0.5 + 0 = 1.5"),
    "negative mix": (lambda p: (_set(p, "acra:translate", F([0, 0, -0.5])), _set(p, "acra:deform", F([1, 1, 1.5]))), "acra:translate", "negative share"),
    "rigidity 0": (lambda p: _set(p, "acra:rigidity", 0.0), "acra:rigidity", "0 outside [1, 100]"),
    "rigidity 101": (lambda p: _set(p, "acra:rigidity", 101.0), "acra:rigidity", "101 outside [1, 100]"),
    "uWrap token": (lambda p: _set(p, "acra:uWrap", "closed"), "acra:uWrap", "unknown token 'closed'"),
    "refine token": (lambda p: _set(p, "acra:refine", "always"), "acra:refine", "unknown token 'always'"),
    "open uCount 3": (_counts(3, 5), "acra:uCount", "3 CVs, an open direction needs at least 4"),
    "periodic uCount 2": (_counts(2, 5, "periodic"), "acra:uCount", "2 CVs, a periodic direction needs at least 3"),
    "absorption length": (lambda p: _set(p, "acra:absorption", F([0.5, 0.5])), "acra:absorption", "has 2 values, expected acra:levels = 3"),
    "rotate length": (lambda p: _set(p, "acra:rotate", F([0.0] * 4)), "acra:rotate", "has 4 values"),
    "levels 0": (lambda p: _set(p, "acra:levels", 0), "acra:levels", "0 is less than 1"),
    "samples 0": (lambda p: _set(p, "acra:samples", 0), "acra:samples", "0 is less than 1"),
    "enabled int": (lambda p: _retype(p, "acra:enabled", Sdf.ValueTypeNames.Int, 1), "acra:enabled", "expected bool"),
    "animated control": (lambda p: (_set(p, "acra:rigidity", 20.0, 1.0), _set(p, "acra:rigidity", 30.0, 2.0)), "acra:rigidity", "is not animatable"),
    "hierarchy C2": (
        lambda p: (_set(p, "acra:hierarchy:offsetCvs", Vt.Vec2iArray([Gf.Vec2i(2, 3)])),
                   _set(p, "acra:hierarchy:offsetLevel", Vt.IntArray([2])),
                   _set(p, "acra:hierarchy:offsets", Vt.Vec3dArray([Gf.Vec3d(0, 0, 1)]))),
        "acra:hierarchy:offsetCvs", "level 2: CV (2, 3) is not free to move"),
    "hierarchy level": (lambda p: _set(p, "acra:hierarchy:patchLevel", Vt.IntArray([3] * len(p.GetAttribute("acra:hierarchy:patchLevel").Get()))), "acra:hierarchy:patchLevel", "outside 1..2"),
    "hierarchy lengths": (lambda p: _set(p, "acra:hierarchy:offsetLevel", Vt.IntArray([1])), "acra:hierarchy:offsetCvs", "acra:hierarchy:offsetLevel has 1"),
    "hierarchy NaN": (lambda p: _set(p, "acra:hierarchy:offsets", Vt.Vec3dArray.FromNumpy(np.full((len(p.GetAttribute("acra:hierarchy:offsets").Get()), 3), np.nan))), "acra:hierarchy:offsets", "NaN or inf at index 0"),
}



def _new(name, tname, value, time=None):
    """An edit authoring a (state-control) attribute the sheet does not have yet."""
    def edit(prim):
        attr = prim.CreateAttribute(name, tname)
        attr.Set(value) if time is None else attr.Set(value, time)

    return edit


def _both(*edits):
    return lambda prim: [e(prim) for e in edits]


N = Sdf.ValueTypeNames
BAD.update({
    "relax length": (_new("acra:relax", N.FloatArray, F([0.5, 0.5])), "acra:relax", "has 2 values at the default time, expected acra:levels = 3"),
    "relax above 1 at a sample": (_both(_new("acra:relax", N.FloatArray, F([1, 1, 1]), 1.0), _new("acra:relax", N.FloatArray, F([0.5, 1.5, 1]), 2.0)),
                                  "acra:relax", "1.5 at level 1 at time 2 outside [0, 1]"),
    "relax NaN": (_new("acra:relax", N.FloatArray, F([0.5, float("nan"), 1])), "acra:relax", "nan at level 1 at the default time outside [0, 1]"),
    "relax double[]": (_new("acra:relax", N.DoubleArray, Vt.DoubleArray([1.0, 1.0, 1.0])), "acra:relax", "has type double[], expected float[]"),
    "plasticity negative": (_new("acra:plasticity", N.Float, -0.1), "acra:plasticity", "-0.1 outside [0, 1]"),
    "plasticity per level": (_new("acra:plasticity", N.FloatArray, F([0.0, 2.0, 0.0])), "acra:plasticity", "2 at level 1 outside [0, 1]"),
    "plasticity length": (_new("acra:plasticity", N.FloatArray, F([0.5])), "acra:plasticity", "has 1 values, expected acra:levels = 3"),
    "plasticity double": (_new("acra:plasticity", N.Double, 0.5), "acra:plasticity", "has type double, expected float or float[]"),
    "plasticity animated": (_both(_new("acra:plasticity", N.Float, 0.1, 1.0), _new("acra:plasticity", N.Float, 0.2, 2.0)), "acra:plasticity", "is not animatable"),
    "preserveVolume 2": (_new("acra:preserveVolume", N.Float, 2.0), "acra:preserveVolume", "2 outside [0, 1]"),
    "bulgeLevel 3": (_new("acra:bulgeLevel", N.Int, 3), "acra:bulgeLevel", "3 outside 0..2"),
    "bulgeFalloff 0": (_new("acra:bulgeFalloff", N.Float, 0.0), "acra:bulgeFalloff", "0 is not positive"),
    "bulgeFalloff inf": (_new("acra:bulgeFalloff", N.Float, float("inf")), "acra:bulgeFalloff", "inf is not finite"),
})


def test_state_controls_default_to_carrying_nothing(scene_file):
    c = U.read_scene(U.open_input(scene_file)).deformables[0].controls
    assert not c.stateful and c.plasticity is None and c.preserve_volume == 0.0
    np.testing.assert_array_equal(c.relax_at(2.0), [1.0, 1.0, 1.0])


def test_state_controls_are_read_and_relax_interpolates_between_samples(tmp_path):
    stage = build_stage()
    prim = stage.GetPrimAtPath(SHEET)
    A.key_relax(prim, 1, [1.0, 0.5, 0.2])
    A.key_relax(prim, 3, [0.0, 0.5, 0.6])
    A.set_state_controls(prim, plasticity=0.25, preserve_volume=0.5, bulge_level=1, bulge_falloff=0.3)
    A.save(stage, tmp_path / "s.usda")
    st = U.open_input(tmp_path / "s.usda")
    c = U.read_scene(st).deformables[0].controls
    assert c.stateful
    for t in (0.0, 1.0, 1.5, 2.0, 2.75, 3.0, 7.0):  # as USD interpolates the float[] (held past the ends);
        want = np.asarray(st.GetPrimAtPath(SHEET).GetAttribute("acra:relax").Get(t), dtype=np.float64)
        np.testing.assert_allclose(c.relax_at(t), want, rtol=2e-7, atol=0)  # USD rounds to float32, ACRA does not
    mid = (np.float32([1.0, 0.5, 0.2]).astype(np.float64) + np.float32([0.0, 0.5, 0.6])) / 2
    np.testing.assert_array_equal(c.relax_at(2.0), mid)
    np.testing.assert_array_equal(c.plasticity, [0.25] * 3)
    assert (c.preserve_volume, c.bulge_level, c.bulge_falloff) == (0.5, 1, np.float32(0.3))


@pytest.mark.parametrize("case", sorted(BAD))
def test_invalid_input_names_prim_and_attribute(case, tmp_path):
    edit, attribute, problem = BAD[case]
    stage = build_stage()
    edit(stage.GetPrimAtPath(SHEET))
    path = tmp_path / "bad.usda"
    A.save(stage, path)
    with pytest.raises(InputError) as info:
        U.read_scene(U.open_input(path))
    err = info.value
    assert (err.prim, err.attribute) == (SHEET, attribute)
    message = str(err)
    assert "\n" not in message and message.startswith(f"{SHEET}.{attribute}: ")
    assert problem in message


def test_invalid_collider(tmp_path):
    stage = build_stage()
    UsdGeom.Mesh(stage.GetPrimAtPath(FLOOR)).GetFaceVertexIndicesAttr().Set(Vt.IntArray([0, 1, 2, 99] * 6))
    with pytest.raises(InputError, match=rf"^{FLOOR}\.faceVertexIndices: index outside 0\.\.7$"):
        U.read_scene(stage)


@pytest.mark.parametrize(
    "name, content, problem",
    [
        ("missing.usda", None, "cannot open: no such file"),
        ("broken.usda", b'#usda 1.0\ndef Mesh "a" {\n  int x = \n', "cannot open: "),
        ("garbage.usdc", b"\x00\x01 not crate", "cannot open: "),
        ("scene.txt", b"hello", "not a USD file"),
        ("nosub.usda", b'#usda 1.0\n(\n    subLayers = [@./anim.usda@]\n)\n', "cannot open: sublayer @./anim.usda@ of "),
        ("noref.usda", b'#usda 1.0\ndef Xform "W" (references = @./gone.usda@) {}\n', "cannot open: composition error: Could not open asset"),
    ],
)
def test_unreadable_files(tmp_path, name, content, problem):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(InputError) as info:
        U.open_input(path)
    assert info.value.prim == str(path) and problem in str(info.value) and "\n" not in str(info.value)


def test_directory_is_not_a_stage(tmp_path):
    (tmp_path / "dir.usda").mkdir()
    with pytest.raises(InputError, match=r"dir\.usda: cannot open: not a regular file$"):
        U.open_input(tmp_path / "dir.usda")


# --------------------------------------------------------------------------------------------
# scene files

SCENE = """
import numpy as np
from acra import shapes
from pipeline import authoring as A

def build():
    stage = A.new_stage(1, 2)
    cvs, up, vp = shapes.sheet(5, 4)
    A.add_deformable(stage, "/World/s", cvs)
    {extra}
    return stage

if __name__ == "__main__":
    raise SystemExit("must not run as main when loaded by acra")
"""


def test_load_scene_file(tmp_path):
    py = tmp_path / "shot.py"
    py.write_text(SCENE.format(extra=""))
    usda = U.load_scene_file(py)
    assert usda == tmp_path / "shot.usda" and usda.is_file()
    scene = U.read_scene(U.open_input(usda))
    assert [m.path for m in scene.deformables] == ["/World/s"] and (scene.start, scene.end) == (1, 2)


@pytest.mark.parametrize("extra, problem", [("raise RuntimeError('boom')", "build(): raised RuntimeError: boom"), ("return 42", "build(): returned int")])
def test_scene_file_errors(tmp_path, extra, problem):
    py = tmp_path / "shot.py"
    py.write_text(SCENE.format(extra=extra))
    with pytest.raises(InputError) as info:
        U.load_scene_file(py)
    assert str(info.value).startswith(f"{py}.{problem}")
    assert not (tmp_path / "shot.usda").exists()
    (tmp_path / "bad.py").write_text("import nonexistent_module_xyz\n")
    with pytest.raises(InputError, match="scene failed to load: ModuleNotFoundError"):
        U.load_scene_file(tmp_path / "bad.py")


# --- usd-core's own spline deprecation warning --------------------------------------------------


def test_a_scene_file_with_splines_loads_without_the_spline_deprecation_warning(tmp_path, capfd):
    """usd-core 26.11's .usda writer posts `TsSpline inner looping is deprecated` for each spline it
    writes; exporting a scene file's stage (box_into_sheet keys USD splines) must not show it."""
    import shutil

    scene = tmp_path / "box_into_sheet.py"
    shutil.copy(__import__('pathlib').Path(__file__).resolve().parents[1] / "scenes" / scene.name, scene)
    capfd.readouterr()
    U.load_scene_file(scene)
    assert U.SPLINE_DEPRECATION not in capfd.readouterr().err
    assert ".spline = {" in scene.with_suffix(".usda").read_text()


def test_other_usd_diagnostics_still_reach_the_user(capfd):
    from pxr import Tf

    capfd.readouterr()
    with U.quiet_spline_deprecation():
        Tf.Warn("a real USD warning")
    assert "a real USD warning" in capfd.readouterr().err
    with pytest.raises(Tf.ErrorException, match="a real USD error"):
        with U.quiet_spline_deprecation():
            Tf.RaiseRuntimeError("a real USD error")


def test_coordinates_too_far_to_compute_with_are_refused(tmp_path):
    """A CV at 1e30 is finite float32 but leaves float64 no digit of a unit-sized feature
    (fuzzing found detection's barycentric solve returning NaN there): refused, named."""
    cvs, _, _ = shapes.sheet(4, 4, width=2.0, depth=2.0)
    for value, ok in ((1e15, True), (1.01e15, False), (1e30, False)):
        stage = A.new_stage(1, 2)
        bad = cvs.copy()
        bad[1, 0, 2] = value
        A.add_deformable(stage, "/World/Sheet", bad)
        if ok:
            U.read_scene(stage)
        else:
            with pytest.raises(InputError, match=r"^/World/Sheet\.acra:cvs: coordinate beyond 1e\+15 at the default time at index 1: "):
                U.read_scene(stage)


def test_text_output_on_two_threads_is_one_threads_bytes(tmp_path, monkeypatch):
    """A real run's ``.usda`` layer (`box_into_sheet`, a free frame and a collision frame) with
    its arrays' texts formatted on two sides (`floattext.tuples_texts` through
    `pipeline.workers.both`, the second side in a thread of its own) holds the bytes of the layer
    formatted on one thread (``NUMBA_NUM_THREADS=1``), and USD's own text of the same results."""
    import pathlib
    import shutil
    import threading

    from numba.core import config

    from acra import floattext
    from pipeline import frames as F
    from pipeline import workers

    scene_file = tmp_path / "box_into_sheet.py"
    shutil.copy(pathlib.Path(__file__).resolve().parents[1] / "scenes" / "box_into_sheet.py", scene_file)
    stage_path = U.load_scene_file(scene_file)
    stage = U.open_input(stage_path)
    scene = U.read_scene(stage)
    result, stats = F.run_frames(stage, scene, [10, 11])
    assert [s.in_collision for s in stats] == [False, True]
    monkeypatch.setattr(floattext, "SIDE_MIN", 0)  # the sheet's arrays are small: two sides however little each holds
    threads, both = [], workers.both

    def seen(first, second):
        return both(first, lambda: threads.append(threading.get_ident()) or second())

    monkeypatch.setattr(workers, "both", seen)
    texts = {}
    for n in (1, 2):
        monkeypatch.setattr(config, "NUMBA_NUM_THREADS", n)
        texts[n] = output_layer.write_output(stage_path, tmp_path / f"out{n}.usda", scene, result).read_bytes()
    assert len(threads) == 2 and threading.get_ident() not in threads  # found and formatted, each on a second thread
    assert texts[2] == texts[1]
    crate = output_layer.write_output(stage_path, tmp_path / "out.usdc", scene, result)
    assert texts[2] == _usd_text(crate)
