"""End to end through `acra run`: a box jumps deep into a sheet and stays; bad input writes nothing."""

import shutil
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from pipeline import detect as D
from pipeline import frames as F
from pipeline.cli import main

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "box_into_sheet.py"


@pytest.fixture(scope="module")
def box_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("box")
    scene = d / "box_into_sheet.py"
    shutil.copy(SCENE, scene)
    assert main(["run", str(scene), "--quiet"]) == 0
    return d / "box_into_sheet.usda", d / "box_into_sheet.acra.usda"


def test_box_into_sheet_is_cleared_on_the_side_it_came_from(box_run):
    src, out = box_run
    stage = Usd.Stage.Open(str(out))
    sheet = stage.GetPrimAtPath("/World/Sheet")
    points = UsdGeom.Mesh(sheet).GetPointsAttr()
    residual = sheet.GetAttribute("acra:response:residual")
    for frame in range(11, 17):  # the box sits 0.7 deep from frame 11 on
        p = np.array(points.Get(frame))
        under = (np.abs(p[:, 0] - 0.2) < 0.45) & (np.abs(p[:, 1] + 0.1) < 0.45)
        # pushed down with the box (it came from above), never left above its bottom face
        assert p[under, 2].max() <= -0.7 + 1e-3 * 5.7
        assert np.all(np.isfinite(p)) and p[:, 2].max() <= 1e-9
        assert residual.Get(frame) <= 1e-3 * 5.7
    # before the contact the sheet is untouched
    np.testing.assert_allclose(np.array(points.Get(5))[:, 2], 0.0, atol=1e-9)


def test_transforms_unchanged(box_run):
    src, out = box_run
    a, b = Usd.Stage.Open(str(src)), Usd.Stage.Open(str(out))
    for path in ("/World/Mover", "/World/Mover/Box", "/World/Sheet"):
        for f in range(1, 17):
            ma = UsdGeom.Xformable(a.GetPrimAtPath(path)).ComputeLocalToWorldTransform(f)
            mb = UsdGeom.Xformable(b.GetPrimAtPath(path)).ComputeLocalToWorldTransform(f)
            assert ma == mb


def test_bad_input_exits_nonzero_with_one_line_and_writes_nothing(tmp_path, capsys):
    bad = tmp_path / "bad.usda"
    bad.write_text('#usda 1.0\n(\n startTimeCode = 1\n endTimeCode = 2\n)\ndef Mesh "M" {\n int acra:uCount = 4\n int acra:vCount = 4\n point3f[] acra:cvs = [(0,0,0)]\n}\n')
    code = main(["run", str(bad), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and "/M" in err[0] and "acra:cvs" in err[0]
    assert not (tmp_path / "bad.acra.usda").exists()


def test_rrd_reads_back_with_meshes_on_the_frame_timeline(tmp_path):
    from rerun.chunk import RrdReader

    scene = tmp_path / "box_into_sheet.py"
    shutil.copy(SCENE, scene)
    rrd = tmp_path / "box.rrd"
    assert main(["run", str(scene), "--quiet", "--frames", "9:12", "--rrd", str(rrd)]) == 0
    chunks = list(RrdReader(str(rrd)).stream().to_chunks())
    paths = {c.entity_path for c in chunks}
    assert {"/world/World/Sheet", "/world/World/Mover/Box", "/metrics/residual_rel", "/metrics/ms/total",
            "/metrics/ms/detect", "/world/acra/contacts", "/world/acra/data_points/World/Sheet"} <= paths
    temporal = [c for c in chunks if c.entity_path == "/world/World/Sheet" and not c.is_static]
    assert temporal and "frame" in temporal[0].to_record_batch().schema.names
    assert any(c.is_static for c in chunks if c.entity_path == "/world/World/Sheet")
    # the box is drawn where USD puts it: its transform is logged per frame (z = 0.55 at frame 10)
    box = [c for c in chunks if c.entity_path == "/world/World/Mover/Box" and not c.is_static]
    names = " ".join(str(n) for c in box for n in c.to_record_batch().schema.names)
    assert "Transform3D" in names or "translation" in names.lower()
    # the default blueprint travels with the recording: the collision and whole-scene 3D views, the
    # legend, four plots and the event log
    reader = RrdReader(str(rrd))
    stores = reader.blueprints()
    assert stores
    views = {c.entity_path.split("/")[2] for c in reader.stream(store=stores[0]).to_chunks() if c.entity_path.startswith("/view/")}
    assert len(views) == 8


def test_preview_clears_markers_of_a_free_frame(tmp_path):
    """Scrubbing from a collision frame to a free one must not show the old contacts."""
    from rerun.chunk import RrdReader

    from pipeline import frames as F
    from pipeline import preview as P
    from pipeline import usdio

    scene_file = tmp_path / "box_into_sheet.py"
    shutil.copy(SCENE, scene_file)
    stage_path = usdio.load_scene_file(scene_file)
    stage = usdio.open_input(stage_path)
    scene = usdio.read_scene(stage)
    result, stats = F.run_frames(stage, scene, [10, 11])
    assert not stats[0].in_collision and stats[1].in_collision
    rrd = tmp_path / "p.rrd"
    preview = P.Preview(scene, "p", rrd=rrd, stage=stage)
    preview.log_frame(stats[1], result)  # collision first, then the free frame
    preview.log_frame(stats[0], result)
    preview.close()
    cleared = set()
    for c in RrdReader(str(rrd)).stream().to_chunks():
        if any("Clear" in str(n) for n in c.to_record_batch().schema.names):
            cleared.add(c.entity_path)
    assert {"/world/acra/contacts", "/world/acra/data_points/World/Sheet", "/world/acra/region/World/Sheet"} <= cleared


def test_residual_is_relative_to_the_size_of_the_display_the_user_sees(tiny_stage):
    """``residual_rel`` is the residual over the diagonal of the world box of the deformable's own
    output display at that frame (contract §3), not the size of its control net: a box left
    1e-4 of the sheet inside it, within the tolerance, is reported with exactly that depth (the
    box is convex and the sheet lies along its bottom face, where the bound is exact) over the
    display's diagonal."""
    from pxr import Usd

    from pipeline import usdio
    from pipeline.model import apply_xform

    path = tiny_stage(frames=2, n=6, levels=1, depth=1e-4)
    stage = usdio.open_input(path)
    scene = usdio.read_scene(stage)
    result, stats = F.run_frames(stage, scene, [2])
    (st,) = stats
    r = result.frames[2]["/World/Sheet"]
    shown = apply_xform(st.xforms["/World/Sheet"], np.asarray(r.points, np.float32).astype(np.float64))
    diagonal = float(np.linalg.norm(np.ptp(shown, axis=0)))
    net = D.SurfaceGeometry(r.surface, st.xforms["/World/Sheet"]).size
    assert st.iterations == 0 and net > 1.1 * diagonal  # the net reaches past the surface
    assert st.residual == pytest.approx(1e-4, rel=1e-3)  # float32 box and sheet points
    assert st.residual_rel == pytest.approx(st.residual / diagonal, rel=1e-12)


def test_two_runs_give_byte_identical_layers(tmp_path):
    scene = tmp_path / "box_into_sheet.py"
    shutil.copy(SCENE, scene)
    outs = []
    for name in ("a.usda", "b.usda"):
        assert main(["run", str(scene), "--quiet", "--frames", "10:12", "-o", str(tmp_path / name)]) == 0
        outs.append((tmp_path / name).read_bytes())
    assert outs[0] == outs[1]


def test_demo_motion_is_keyed_with_native_usd_splines(tmp_path):
    import runpy

    stage = runpy.run_path(str(SCENE))["build"]()
    op = stage.GetPrimAtPath("/World/Mover").GetAttribute("xformOp:translateZ")
    assert op.HasSpline() and not op.GetTimeSamples()
    assert op.Get(10.5) == pytest.approx(0.175)


def test_spread_keeps_additional_points_apart_and_covers_the_rest():
    """`frames._spread`: kept points are pairwise farther than the radius and farther from the
    contact; every dropped point is within the radius of a kept one or of the contact, so thinning
    leaves no part of the region without a point (seeded clusters, as at a pole)."""
    rng = np.random.default_rng(7)
    for n in (0, 1, 5, 60):
        pts = np.concatenate([rng.normal(0, 0.002, (n // 2, 3)), rng.uniform(-0.05, 0.05, (n - n // 2, 3))])
        contact, radius = np.array([0.001, 0.0, 0.0]), 4e-3
        keep = F._spread(pts, contact, radius)
        kept = pts[keep]
        if len(kept) > 1:
            d = np.linalg.norm(kept[:, None] - kept[None], axis=2) + np.eye(len(kept))
            assert d.min() > radius
        assert np.all(np.linalg.norm(kept - contact, axis=1) > radius)
        anchors = np.concatenate([kept, contact[None]])
        for p in pts[~keep]:
            assert np.linalg.norm(anchors - p, axis=1).min() <= radius
        if n == 60:
            assert 0 < keep.sum() < n  # the cluster was thinned, the spread points kept


@pytest.mark.parametrize("u_low, settled, took", [
    (2.14, 0.005, "deepest"),  # middle x = 0.02: 0.002 inside, 1/20 of the patch's depth 0.04
    (2.3, 0.005, "middle"),  # middle x = 0.1: 0.01 inside, 1/4 of it: not stalled
    (2.14, 0.05, "middle"),  # the patch's depth 0.04 counts as done
])
def test_a_patch_whose_middle_has_stalled_takes_its_deepest_sample(u_low, settled, took):
    """Eq. 4.16's point of a patch is the middle of its inside part; where that middle asks a
    move of at most `frames.STALLED` of the patch's depth (the stall of docs/hard-cases.md case 7:
    the middle on the box's face, the patch's corner sample still inside), the sample is taken
    instead. A sheet tilted as z = 0.1 x, a box whose bottom is z = 0, and two samples of
    level-0 patch (2, 2): x = 0.4 (0.04 inside) and x = u_low - 2.5 (below the box)."""
    from acra import hspline as H
    from acra import shapes
    from pipeline import detect as D
    from pipeline import frames as F
    from pipeline.model import ColliderModel

    cvs, _, _ = shapes.sheet(8, 8, width=5.0, depth=5.0)
    cvs[..., 2] = 0.1 * cvs[..., 0]
    sheet = D.SurfaceGeometry(H.from_grid(cvs), np.eye(4), "/sheet")
    corners = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (0.0, 2.0)])
    tris = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                     [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    box = D.ColliderGeometry(D.prepare_collider(ColliderModel("/box", corners, tris)), np.eye(4))
    region_uv = np.array([[2.9, 2.5], [u_low, 2.5]])
    contact = np.array([0.3, 0.0, 0.03])  # apart from both samples (`_spread` drops points on the contact)
    args = (sheet, box, np.array([2.8, 2.5]), contact, contact * [1, 1, 0], region_uv, 0.0, 0, np.array([0.0, 0.0, -1.0]))
    mid_u = (2.9 + u_low) / 2
    mean, _, _ = F.data_points_for(*args)  # without depths: the middle, as eq. 4.16 says
    np.testing.assert_allclose(mean.uv[1], [mid_u, 2.5])
    np.testing.assert_allclose(mean.target[1], [mid_u - 2.5, 0.0, 0.0], atol=1e-9)
    dp, _, _ = F.data_points_for(*args, region_depth=np.array([0.04, 0.0]), settled=settled)
    u = 2.9 if took == "deepest" else mid_u
    np.testing.assert_allclose(dp.uv[1], [u, 2.5])
    np.testing.assert_allclose(dp.target[1], [u - 2.5, 0.0, 0.0], atol=1e-9)


def _ball_and_box(lo, hi):
    """The 8 × 8-CV unit sphere with 3 levels (group level 2) and an axis-aligned box collider
    ``[lo, hi]`` (world ``(3,)`` each), as detection geometry at the identity matrix."""
    from acra import hspline as H
    from acra import shapes
    from pipeline import detect as D
    from pipeline.model import ColliderModel

    ball = D.SurfaceGeometry(H.from_grid(*shapes.sphere(8, 8), depth=3), np.eye(4), "/ball")
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])], float)
    tris = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                     [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    box = D.ColliderGeometry(D.prepare_collider(ColliderModel("/box", corners, tris)), np.eye(4))
    return ball, box


def test_a_box_inside_a_sphere_gets_the_wall_in_front_pushed_past_it():
    """`frames.collider_points_for` (docs/hard-cases.md, case 3): a 0.3 box wholly inside the unit
    sphere has no sphere vertex inside it, so eq. 4.16's own-region points are none; the box's
    faces give them instead. Pushed along -x, the wall in front (x near 1) gets one point per
    level-2 patch, at the patch centre, moved along -x only, past the box's far face by the
    clearance; in the pocket's first round the points reach beyond the box's outline on every
    side (the ring), in a later round only the patches the box covers move, by their lag."""
    from acra.basis import locate
    from pipeline import detect as D

    ball, box = _ball_and_box([-0.15] * 3, [0.15] * 3)
    ra, rb = D.regions(ball, box)
    assert ra.empty and len(rb.points) == 8
    push, clear = np.array([-1.15, 0.0, 0.0]), 0.004
    hs = ball.surface
    for first in (True, False):
        uv, target, origin = F.collider_points_for(ball, box, ra, rb, push, 0.0, 2, clear, first)
        patches = np.stack([locate(hs.u, uv[:, 0], 2)[0], locate(hs.v, uv[:, 1], 2)[0]], axis=1)
        assert len(np.unique(patches, axis=0)) == len(uv) > 0  # one point per level-2 patch
        np.testing.assert_allclose(uv, (patches + 0.5) / 4)  # at its centre
        assert np.all(origin[:, 0] > 0.85)  # on the wall in front
        np.testing.assert_allclose(target[:, 1:], origin[:, 1:], atol=1e-12)  # along the push only
        assert np.all(target[:, 0] <= -0.15 - clear + 1e-12)  # past the far face
        y, z = origin[:, 1], origin[:, 2]
        if first:  # the ring: beyond the outline on every side
            assert y.min() < -0.15 and y.max() > 0.15 and z.min() < -0.15 and z.max() > 0.15
            n_first = len(uv)
        else:  # the covered patches alone, each by its largest lag (to the far face) + clear
            assert len(uv) < n_first
            assert np.all(np.abs(y) < 0.15 + 0.2) and np.all(np.abs(z) < 0.15 + 0.2)
            assert np.all(origin[:, 0] - target[:, 0] <= 1.15 + clear + 1e-9)


def test_a_box_through_a_sphere_wall_takes_both_regions_to_its_inner_face():
    """A box [0.85, 1.15] × [-0.1, 0.1]² through the +x wall of the unit sphere, pushed along
    -x: the sphere's vertices inside the box (its own region) and the box's inner corners inside
    the sphere (the collider's) give one set of points, all aiming at the box's inner face
    x = 0.85 less the clearance."""
    from pipeline import detect as D

    ball, box = _ball_and_box([0.85, -0.1, -0.1], [1.15, 0.1, 0.1])
    ra, rb = D.regions(ball, box)
    assert not ra.empty and len(rb.points) == 4
    uv, target, origin = F.collider_points_for(ball, box, ra, rb, np.array([-0.3, 0.0, 0.0]), 0.0, 2, 0.004, False)
    assert len(uv) > 0
    np.testing.assert_allclose(target[:, 1:], origin[:, 1:], atol=1e-12)
    assert np.all(target[:, 0] <= 0.85 - 0.004 + 1e-12)
    # a patch centre moves by the largest lag of its samples: at most the wall's bulge past 0.85
    assert np.all(origin[:, 0] - target[:, 0] <= 1.0 - 0.85 + 0.004 + 1e-9)


def test_rim_points_lie_one_step_outside_a_box_on_the_face_it_pushes_to():
    """Eq. 4.16's middles pin the surface only inside a box's outline,
    and the C2 surface curls back up inside the box before the side face. `frames.rim_points`
    puts a point one detection step outside each side-face crossing, aimed at the bottom face's
    plane, so the rise happens outside. A curved collider's flank gives none (its plane extended
    past the outline would cut into what the ball needs: `elbow_contact`)."""
    import trimesh

    from acra import hspline as H
    from acra import shapes
    from pipeline import detect as D
    from pipeline.model import ColliderModel

    cvs, _, _ = shapes.sheet(12, 12, width=4.0, depth=4.0)
    sheet = D.SurfaceGeometry(H.from_grid(cvs, depth=3), np.eye(4), "/sheet")
    lo, hi = np.array([-0.7, -0.9, -0.5]), np.array([0.9, 0.7, 0.5])
    mesh = trimesh.creation.box(bounds=np.stack([lo, hi]))
    box = D.ColliderGeometry(D.prepare_collider(ColliderModel("/box", mesh.vertices, mesh.faces)), np.eye(4))
    region, _ = D.regions(sheet, box)
    down = np.array([0.0, 0.0, -1.0])
    uv, points, goals = F.rim_points(sheet, box, region.uv, down, 2)
    step = 4.0 / 9 / 8  # one detection step (8 per level-0 patch edge) in world units
    x, y = points[:, 0], points[:, 1]
    beyond = np.maximum.reduce([lo[0] - x, x - hi[0], lo[1] - y, y - hi[1]])
    assert len(uv) >= 4 * 3  # every side of the outline has rim points
    # outside, one step past the crossing (bisected to 1/64 of the step): measured 0.022 to 0.0561
    assert np.all(beyond > 0) and np.all(beyond <= step * (1 + 2.0**-F.RIM_BISECT) + 1e-9), beyond
    np.testing.assert_allclose(goals[:, :2], points[:, :2], atol=1e-12)  # moved along the push
    np.testing.assert_allclose(goals[:, 2], lo[2], atol=1e-9)  # onto the bottom face's plane
    for side in (x < lo[0], x > hi[0], y < lo[1], y > hi[1]):
        assert side.any()

    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.45)
    ball.apply_translation([0.1, -0.1, 0.3])  # 0.15 into the sheet
    ball_geom = D.ColliderGeometry(D.prepare_collider(ColliderModel("/ball", ball.vertices, ball.faces)), np.eye(4))
    region, _ = D.regions(sheet, ball_geom)
    assert len(region.uv) and len(F.rim_points(sheet, ball_geom, region.uv, down, 2)[0]) == 0

