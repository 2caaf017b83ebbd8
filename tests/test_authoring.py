"""The scene-file API (pipeline.authoring)."""

import subprocess
import sys

import numpy as np
import pytest
import trimesh
from pxr import Sdf, Usd, UsdGeom, UsdPhysics, UsdValidation

from acra import hspline as H
from acra import shapes
from acra.tessellate import display_topology, evaluate_grid, run_topology
from pipeline import authoring as A
from pipeline import usdio as U


def test_new_stage_metadata():
    stage = A.new_stage(3, 40, fps=30, up_axis="Y", meters_per_unit=0.01)
    assert stage.GetRootLayer().anonymous
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (3, 40)
    assert stage.GetTimeCodesPerSecond() == stage.GetFramesPerSecond() == 30
    assert UsdGeom.GetStageUpAxis(stage) == "Y" and UsdGeom.GetStageMetersPerUnit(stage) == 0.01
    assert stage.GetDefaultPrim().GetPath() == "/World" and stage.GetDefaultPrim().IsA(UsdGeom.Xform)


def test_add_deformable_authors_contract_attributes_and_rest_tessellation():
    stage = A.new_stage(1, 1)
    cvs, up, vp = shapes.sphere(8, 7)
    prim = A.add_deformable(stage, "/World/a/ball", cvs, u_wrap="periodic", levels=2, samples=3)
    assert stage.GetPrimAtPath("/World/a").IsA(UsdGeom.Xform)
    for name, tname in U.CONTRACT_TYPES.items():
        attr = prim.GetAttribute(name)
        assert attr.HasAuthoredValue() and attr.GetTypeName() == tname, name
    get = lambda n: prim.GetAttribute(n).Get()  # noqa: E731
    assert (get("acra:uCount"), get("acra:vCount"), get("acra:uWrap"), get("acra:vWrap")) == (8, 7, "periodic", "open")
    assert list(get("acra:absorption")) == [0, 1] and list(get("acra:deform")) == [1, 1]
    assert list(get("acra:translate")) == list(get("acra:rotate")) == [0, 0]
    assert (get("acra:rigidity"), get("acra:refine"), get("acra:samples"), get("acra:enabled")) == (50, "refine", 3, True)

    mesh = UsdGeom.Mesh(prim)
    hs = H.from_grid(cvs, up, vp, depth=2)
    topo = display_topology(hs.u, hs.v, 3)
    points, normals = evaluate_grid(hs, topo)
    np.testing.assert_array_equal(np.asarray(mesh.GetPointsAttr().Get()), points.astype(np.float32))
    np.testing.assert_array_equal(np.asarray(mesh.GetNormalsAttr().Get()), normals.astype(np.float32))
    np.testing.assert_array_equal(np.asarray(mesh.GetFaceVertexIndicesAttr().Get()), topo.quads.reshape(-1))
    assert set(np.asarray(mesh.GetFaceVertexCountsAttr().Get())) == {4}
    assert mesh.GetNormalsInterpolation() == "vertex" and mesh.GetSubdivisionSchemeAttr().Get() == "none"
    assert not mesh.GetExtentAttr().HasAuthoredValue()  # the output may not override a stale extent
    (m,) = U.read_scene(stage).deformables  # what the author wrote is valid input
    assert m.topology.u.size == len(points)


def test_partial_mix_defaults_to_zero():
    stage = A.new_stage(1, 1)
    cvs, _, _ = shapes.sheet(4, 4)
    prim = A.add_deformable(stage, "/World/s", cvs, levels=2, translate=[1, 0.5], rotate=[0, 0.5])
    assert list(prim.GetAttribute("acra:deform").Get()) == [0, 0]
    (m,) = U.read_scene(stage).deformables
    np.testing.assert_array_equal(m.controls.translate + m.controls.rotate + m.controls.deform, [1, 1])


def test_hierarchy_is_stored_and_shapes_the_rest_preview():
    cvs, up, vp = shapes.sheet(6, 5, width=3.0, depth=2.0)
    hs = H.make_movable(H.from_grid(cvs, up, vp, depth=3), 2, [[4, 3]])
    idx, off = H.offsets_of(hs, 2)
    hs = H.set_offsets(hs, 2, idx, np.random.default_rng(0).normal(size=off.shape) * 0.1)
    stage = A.new_stage(1, 1)
    prim = A.add_deformable(stage, "/World/s", cvs, hierarchy=hs, samples=2)
    assert prim.GetAttribute("acra:levels").Get() == 3
    # the rest display shows every level the animator used: 2 steps per edge of the finest patch
    # present at each place (`run_topology`), so the level-2 offsets get level-2 density
    topo = run_topology([hs], 2)
    points, _ = evaluate_grid(hs, topo)
    flat, _ = evaluate_grid(H.from_grid(cvs, up, vp), topo)
    mesh = UsdGeom.Mesh(prim)
    got = np.asarray(mesh.GetPointsAttr().Get())
    np.testing.assert_array_equal(got, points.astype(np.float32))
    np.testing.assert_array_equal(mesh.GetFaceVertexCountsAttr().Get(), topo.counts)
    np.testing.assert_array_equal(mesh.GetFaceVertexIndicesAttr().Get(), topo.indices)
    assert np.abs(got - flat).max() > 1e-3  # the offsets show in the preview
    assert len(got) > display_topology(hs.u, hs.v, 2).u.size  # denser than level 0's grid where the detail is
    scene = U.read_scene(stage)
    template = U.surface_template(scene, scene.deformables[0])
    a, b = H.to_arrays(template), H.to_arrays(hs)
    np.testing.assert_array_equal(a.offset_cvs, b.offset_cvs)
    np.testing.assert_array_equal(a.offsets, b.offsets)
    with pytest.raises(ValueError, match="levels"):
        A.add_deformable(stage, "/World/t", cvs, hierarchy=hs, levels=2)
    with pytest.raises(ValueError, match="do not match"):
        A.add_deformable(stage, "/World/t", cvs[:5], hierarchy=hs)


def test_key_cvs_keys_cvs_and_preview():
    stage = A.new_stage(1, 10)
    cvs, _, _ = shapes.sheet(5, 4)
    prim = A.add_deformable(stage, "/World/s", cvs, samples=2)
    bent = cvs.copy()
    bent[2, 1, 2] = 1.0
    A.key_cvs(prim, 1, cvs)
    A.key_cvs(prim, 10, bent)
    assert prim.GetAttribute("acra:cvs").GetTimeSamples() == [1.0, 10.0]
    mesh = UsdGeom.Mesh(prim)
    assert mesh.GetPointsAttr().GetTimeSamples() == [1.0, 10.0]
    hs = H.from_grid(bent)
    expected, _ = evaluate_grid(hs, display_topology(hs.u, hs.v, 2))
    np.testing.assert_array_equal(np.asarray(mesh.GetPointsAttr().Get(10)), expected.astype(np.float32))
    scene = U.read_scene(stage)
    (d,), _ = U.state_at(stage, scene, 5.5)
    np.testing.assert_allclose(d.surface.cvs[2, 1, 2], 0.5, atol=1e-6)
    with pytest.raises(ValueError, match="cvs shape"):
        A.key_cvs(prim, 3, cvs[:, :3])


def test_box_and_uv_sphere_are_closed_and_outward():
    for verts, faces, volume in (
        (*A.box((2.0, 3.0, 4.0)), 24.0),
        (*A.uv_sphere(2.0, segments=24, rings=12), 4.0 / 3.0 * np.pi * 8.0),
    ):
        tri = faces if faces.shape[1] == 3 else np.concatenate([faces[:, [0, 1, 2]], faces[:, [0, 2, 3]]])
        tm = trimesh.Trimesh(verts, tri, process=False)
        assert tm.is_watertight and tm.is_winding_consistent
        assert tm.volume > 0 and tm.volume == pytest.approx(volume, rel=0.05)
    v, f = A.uv_sphere(1.0, 5, 3, center=(1, 2, 3))
    assert v.shape == (2 + 2 * 5, 3) and f.shape == (2 * 5 * 2, 3)
    np.testing.assert_allclose(np.linalg.norm(v - [1, 2, 3], axis=1), 1.0)


def test_add_collider():
    stage = A.new_stage(1, 1)
    prim = A.add_collider(stage, "/World/props/crate", *A.box(2.0, center=(0, 0, 1)))
    assert prim.HasAPI(UsdPhysics.CollisionAPI) and prim.IsA(UsdGeom.Mesh)
    assert stage.GetPrimAtPath("/World/props").IsA(UsdGeom.Xform)
    (c,) = U.read_scene(stage).colliders
    assert c.triangles.shape == (12, 3)
    tm = trimesh.Trimesh(c.vertices, c.triangles, process=False)
    assert tm.is_watertight and tm.volume == pytest.approx(8.0)
    lo, hi = UsdGeom.Mesh(prim).GetExtentAttr().Get()
    assert tuple(lo) == (-1, -1, 0) and tuple(hi) == (1, 1, 2)


def test_key_transform_order_and_linear_interpolation():
    stage = A.new_stage(0, 10)
    prim = A.add_xform(stage, "/World/x")
    A.key_transform(prim, 0, scale=(1, 1, 1))
    A.key_transform(prim, 0, rotate_xyz=(0, 0, 0), translate=(0, 0, 0))
    A.key_transform(prim, 10, translate=(10, 0, 0), rotate_xyz=(0, 0, 90), scale=(3, 3, 3))
    names = [op.GetOpName() for op in UsdGeom.Xformable(prim).GetOrderedXformOps()]
    assert names == ["xformOp:translate", "xformOp:rotateXYZ", "xformOp:scale"]
    m = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(5)).T
    c = s = np.sqrt(0.5)
    np.testing.assert_allclose(m[:3, :3], 2.0 * np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]), atol=1e-6)
    np.testing.assert_allclose(m[:3, 3], [5, 0, 0], atol=1e-9)


def test_key_enabled_is_held():
    stage = A.new_stage(1, 5)
    cvs, _, _ = shapes.sheet(4, 4)
    prim = A.add_deformable(stage, "/World/s", cvs)
    A.key_enabled(prim, 1, True)
    A.key_enabled(prim, 3, False)
    scene = U.read_scene(stage)
    assert [U.state_at(stage, scene, t)[0][0].enabled for t in (1, 2.99, 3, 5)] == [True, True, False, False]


def test_save_writes_a_valid_stage_and_leaves_the_stage(tmp_path):
    stage = A.new_stage(1, 4)
    cvs, _, _ = shapes.torus(8, 6)
    ring = A.add_deformable(stage, "/World/ring", cvs, u_wrap="periodic", v_wrap="periodic", samples=2)
    A.key_transform(ring, 1, translate=(0, 0, 2))
    A.key_transform(ring, 4, translate=(0, 0, 0))
    A.add_collider(stage, "/World/floor", *A.box((5, 5, 0.1)))
    path = A.save(stage, tmp_path / "scene.usda")
    assert stage.GetRootLayer().anonymous and sorted(p.name for p in tmp_path.iterdir()) == ["scene.usda"]
    opened = Usd.Stage.Open(str(path))
    ctx = UsdValidation.ValidationContext(UsdValidation.ValidationRegistry().GetOrLoadAllValidators())
    assert [e.GetMessage() for e in ctx.Validate(opened)] == []
    scene = U.read_scene(U.open_input(path))
    assert [m.path for m in scene.deformables] == ["/World/ring"] and (scene.start, scene.end) == (1, 4)


def test_scene_file_runs_on_its_own(tmp_path):
    py = tmp_path / "drop.py"
    py.write_text(
        "from pathlib import Path\n"
        "from acra import shapes\n"
        "from pipeline.authoring import new_stage, add_deformable, save\n"
        "def build():\n"
        "    stage = new_stage(1, 2)\n"
        "    add_deformable(stage, '/World/s', shapes.sheet(4, 5)[0])\n"
        "    return stage\n"
        "if __name__ == '__main__':\n"
        "    save(build(), Path(__file__).with_suffix('.usda'))\n"
    )
    subprocess.run([sys.executable, str(py)], check=True, cwd=tmp_path)
    standalone = (tmp_path / "drop.usda").read_bytes()
    (tmp_path / "drop.usda").unlink()
    assert U.load_scene_file(py).read_bytes() == standalone
    assert Sdf.Layer.OpenAsAnonymous(str(tmp_path / "drop.usda")).GetPrimAtPath("/World/s")


# --------------------------------------------------------------------------------------------
# shapes and detail at the animator's level

from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from acra import hspline  # noqa: E402
from pipeline import authoring  # noqa: E402


def test_shapes_are_the_acra_grids_with_room_for_levels():
    for made, (cvs, u_periodic, v_periodic) in [
        (authoring.sheet(6, 5, width=2.0, depth=1.5, levels=3), shapes.sheet(6, 5, width=2.0, depth=1.5)),
        (authoring.sphere(8, 7, radii=(1, 2, 3), levels=2), shapes.sphere(8, 7, radii=(1, 2, 3))),
        (authoring.torus(12, 8, major=2.0, minor=0.5, levels=4), shapes.torus(12, 8, major=2.0, minor=0.5)),
        (authoring.tube(8, 6, radius=0.3, length=1.0, levels=2), shapes.tube(8, 6, radius=0.3, length=1.0)),
    ]:
        np.testing.assert_array_equal(made.cvs, cvs)
        assert (made.u.periodic, made.v.periodic) == (u_periodic, v_periodic)
        assert all(lev.patches.size == 0 for lev in made.fine)  # no detail yet
    assert authoring.sheet(6, 5, levels=3).depth == 3


def test_cone_tapers_linearly_from_base_to_a_closed_tip():
    radius, height = 0.3, 1.2
    cone = authoring.cone(8, 8, radius=radius, height=height, levels=2)
    egg, _, _ = shapes.sphere(8, 8, radii=(radius, radius, height / 2))
    np.testing.assert_array_equal(cone.cvs[..., 2], egg[..., 2])
    scale = np.clip(height / 2 - egg[..., 2], 0.0, None) / height  # 1 at the base, 0 at the tip
    np.testing.assert_allclose(cone.cvs[..., :2], egg[..., :2] * scale[..., None], rtol=0, atol=1e-15)
    tip = hspline.evaluate(cone, np.array([0.0, 3.0]), np.array([float(cone.v.patches0)] * 2)).points
    np.testing.assert_allclose(tip, [[0, 0, height / 2]] * 2, atol=1e-12)  # both meridians meet at the tip


def test_turned_quarter_turns_are_exact_and_right_handed():
    ball = authoring.sphere(8, 8, radii=(1.0, 2.0, 3.0))
    x, y, z = (ball.cvs[..., i] for i in range(3))
    np.testing.assert_array_equal(authoring.turned(ball, "x").cvs, np.stack([x, -z, y], -1))  # +z -> -y
    np.testing.assert_array_equal(authoring.turned(ball, "y").cvs, np.stack([z, y, -x], -1))  # +z -> +x
    np.testing.assert_array_equal(authoring.turned(ball, "z").cvs, np.stack([-y, x, z], -1))  # +x -> +y
    np.testing.assert_array_equal(authoring.turned(ball, "y", 4).cvs, ball.cvs)
    np.testing.assert_array_equal(authoring.turned(authoring.turned(ball, "z", 3), "z").cvs, ball.cvs)


def test_moved_shifts_level_zero_and_keeps_the_detail():
    bumped = authoring.add_bump(authoring.sheet(7, 7, levels=2), 1, (2.0, 2.0), 1.0, 0.3)
    shifted = authoring.moved(bumped, (1.0, -2.0, 0.5))
    np.testing.assert_array_equal(shifted.cvs, bumped.cvs + [1.0, -2.0, 0.5])
    np.testing.assert_array_equal(hspline.offsets_of(shifted, 1)[1], hspline.offsets_of(bumped, 1)[1])


def test_refine_region_activates_the_patches_under_the_box_and_leaves_the_surface():
    flat = authoring.sheet(7, 7, levels=3)
    refined = authoring.refine_region(flat, 2, u=(1.0, 1.5), v=(2.0, 2.25))
    pu, pv = np.divmod(refined.level(2).patches, refined.u.patches(2))
    assert sorted(zip(pu.tolist(), pv.tolist())) == [(4, 8), (5, 8)]  # [1, 1.5) x [2, 2.25) at 1/4
    assert refined.level(1).patches.size == 1  # its ancestor, level-1 patch (2, 4)
    u, v = np.meshgrid(np.linspace(0, 4, 9), np.linspace(0, 4, 9))
    np.testing.assert_array_equal(hspline.evaluate(refined, u.ravel(), v.ravel()).points,
                                  hspline.evaluate(flat, u.ravel(), v.ravel()).points)


def test_add_bump_peaks_at_its_centre_with_the_profile_one_minus_d_squared_squared():
    bumped = authoring.add_bump(authoring.sheet(7, 7, levels=3), 2, centre=(2.0, 2.0), radius=1.0, height=0.4)
    idx, offsets = hspline.offsets_of(bumped, 2)
    by_cv = {tuple(i): o for i, o in zip(idx.tolist(), offsets)}
    # level-2 CV j sits at u = (j - 1) / 4: CV 9 at the centre, CV 10 a quarter away, CV 13 on the rim
    assert by_cv[(9, 9)].tolist() == [0.0, 0.0, 0.4]
    assert by_cv[(10, 9)][2] == 0.4 * (1 - 0.25**2) ** 2
    assert by_cv[(10, 10)][2] == 0.4 * (1 - 2 * 0.25**2) ** 2
    assert by_cv[(13, 9)][2] == 0.0 and by_cv[(9, 5)][2] == 0.0
    assert np.all(offsets[:, :2] == 0.0)
    twice = authoring.add_bump(bumped, 2, centre=(2.0, 2.0), radius=1.0, height=0.4)
    np.testing.assert_array_equal(hspline.offsets_of(twice, 2)[1], 2 * offsets)  # bumps add


@settings(max_examples=25, deadline=None)
@given(st.floats(-0.6, 0.6), st.floats(0.3, 1.2))
def test_add_bump_wraps_the_nearer_way_round_a_periodic_direction(u_centre, radius):
    """On a sphere (periodic u, 8 patches) a bump at u_centre is the same bump at u_centre + 8."""
    near = authoring.add_bump(authoring.sphere(8, 9, levels=2), 1, (u_centre, 3.0), (radius, 0.8), 0.2)
    far = authoring.add_bump(authoring.sphere(8, 9, levels=2), 1, (u_centre + 8.0, 3.0), (radius, 0.8), 0.2)
    # compared where raised by more than rounding: at the rim (1 − d²)² vanishes and a CV there
    # may get 1e-30 one way round and 0 (outside the refined margin) the other
    raised = [{tuple(i): o[2] for i, o in zip(*hspline.offsets_of(s, 1)) if o[2] > 1e-12} for s in (near, far)]
    assert raised[0].keys() == raised[1].keys() and raised[0]
    np.testing.assert_allclose([raised[1][key] for key in raised[0]], list(raised[0].values()), rtol=0, atol=1e-12)


def test_add_spike_offsets_and_reads_back():
    spiked = authoring.add_spike(authoring.sheet(7, 7, width=3.0, depth=3.0, levels=3), 2, height=0.8, spread=0.3)
    idx = authoring.spike_cvs(spiked, 2)
    assert idx[4].tolist() == [9, 9]  # the middle of 4 level-0 patches: u = 2 = (9 - 1) / 4
    offsets = authoring.spike_offsets(spiked, 2)
    np.testing.assert_array_equal(offsets[:, 2], 0.8 * np.outer([0.3, 1, 0.3], [0.3, 1, 0.3]).ravel())
    assert offsets[4, 2] == 0.8 and np.all(offsets[:, :2] == 0.0)
    tip = authoring.spike_positions(spiked, 2)[4]
    np.testing.assert_allclose(tip, [0.0, 0.0, 0.8], atol=1e-12)  # a flat sheet: derived (0, 0, 0), normal +z
    with pytest.raises(ValueError, match="not refined"):
        authoring.spike_offsets(authoring.sheet(7, 7, levels=3), 2)


def test_add_surface_takes_wraps_levels_and_detail_from_the_surface():
    stage = authoring.new_stage(1, 1)
    plain = authoring.add_surface(stage, "/World/ball", authoring.sphere(8, 8, levels=3), absorption=[0.2, 0.3, 0.5])
    assert (plain.GetAttribute("acra:uWrap").Get(), plain.GetAttribute("acra:vWrap").Get()) == ("periodic", "open")
    assert plain.GetAttribute("acra:levels").Get() == 3
    assert not plain.GetAttribute("acra:hierarchy:offsets").HasAuthoredValue()  # no detail, nothing stored
    bumped = authoring.add_bump(authoring.sphere(8, 8, levels=3), 2, (4.0, 2.5), 0.5, 0.1)
    prim = authoring.add_surface(stage, "/World/bumped", bumped, rigidity=5.0)
    (_, model) = U.read_scene(stage).deformables
    assert model.path == "/World/bumped" and prim.GetAttribute("acra:rigidity").Get() == 5.0
    assert model.depth == 3
    np.testing.assert_array_equal(model.hierarchy.offsets, hspline.to_arrays(bumped).offsets)


def test_the_module_docstring_example_builds_a_valid_stage():
    namespace: dict = {}
    example = authoring.__doc__.split("::")[1].split("Three layers")[0]
    exec(compile("\n".join(line[4:] for line in example.splitlines()), "example", "exec"), namespace)
    stage = namespace["build"]()
    scene = U.read_scene(stage)
    assert [m.path for m in scene.deformables] == ["/World/ball"] and len(scene.colliders) == 1


def test_every_bundled_scene_fits_a_screen_and_uses_only_the_authoring_api():
    """A scene file reads like a Blender script: at most 60 lines, importing only
    `pipeline.authoring` (besides pathlib, numpy and another scene), and ``scenes/`` holds no
    helper modules beside the scenes."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "scenes"
    files = sorted(p for p in root.glob("*.py") if p.name != "__init__.py")
    assert len(files) >= 15 and not [p.name for p in files if p.name.startswith("_")]
    for path in files:
        text = path.read_text()
        assert len(text.splitlines()) <= 60, path.name
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ImportFrom):
                names = [node.module]
            elif isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            else:
                continue
            for name in names:
                assert name in ("pathlib", "numpy", "pipeline.authoring") or name.startswith("scenes."), (path.name, name)


def test_keyed_values_samples_keys_through_the_named_curve():
    """Linear keys interpolate linearly; a cubic ease-out is ``1 − (1 − t)³`` of the key change;
    vector keys keep their width."""
    frames = np.arange(1, 6)
    np.testing.assert_allclose(A.keyed_values([1, 5], [0.0, 8.0], frames), [0, 2, 4, 6, 8], rtol=0, atol=1e-12)
    eased = A.keyed_values([1, 5], [0.0, 8.0], frames, "cubic", mode="out")
    np.testing.assert_allclose(eased, 8 * (1 - (1 - np.linspace(0, 1, 5)) ** 3), rtol=0, atol=1e-12)
    np.testing.assert_allclose(A.keyed_values([1, 5], [[0, 0], [4, 8]], frames), np.outer(np.arange(5), [1, 2]),
                               rtol=0, atol=1e-12)
