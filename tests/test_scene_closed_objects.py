"""closed_objects (issue #5, scene 7): a ball with poles and a torus on a spline-keyed parent collide.

Contact displacements are measured at the contact's material points: each world contact point of
the frame's first detection (on the animator's input) is projected onto its input surface for its
``(u, v)``, and the responded surface (``acra:response:*``, double precision) is evaluated there.
"""

import shutil

import numpy as np
import pytest
from pxr import Gf, Usd, UsdGeom

from acra import hspline as H
from acra import respond as R
from acra.controls import check_controls
from acra.targets import DataPoints, contact_targets, rigidity_share
from acra import shapes
from pipeline import geometry
from pipeline import detect as D
from pipeline import usdio
from pipeline import output_layer
from pipeline.animation import curves as C
from pipeline.run import run_file
from pipeline.model import apply_xform
from scenes import closed_objects as S

from conftest import SCENES

NAME = "closed_objects"
BALL, TORUS, CARRIER = "/World/Ball", "/World/Carrier/Torus", "/World/Carrier"
# eq. 4.15: R = R_ball / (R_ball + R_torus); the ball moves 1 - R = 3/4 of the gap, the torus 1/4
SHARE = rigidity_share(S.RIGIDITY["ball"], S.RIGIDITY["torus"])
RATIO = (1.0 - SHARE) / SHARE


def _stages(report):
    src = Usd.Stage.Open(str(report.output.with_name(f"{NAME}.usda")))
    return src, Usd.Stage.Open(str(report.output)), usdio.read_scene(src)


def _contact_moves(report, st):
    """World contact points ``P_A`` (ball), ``P_B`` (torus) of frame ``st`` and where their material
    points are after the response, ``(4, 3) float64``: P_A, P_B, Q_A, Q_B."""
    src, out, scene = _stages(report)
    states, _ = usdio.state_at(src, scene, st.frame)
    p_a, p_b = st.contacts[0]
    moved = []
    for m, state, p in zip(scene.deformables, states, (p_a, p_b)):
        proj = D.project(geometry.SurfaceGeometry(state.surface, state.xform), p[None])
        assert proj.distance[0] <= 1e-9, m.path  # the contact point is a material point of the input
        hs = output_layer.read_output_hierarchy(out, m.path, st.frame)
        q = H.evaluate(hs, proj.uv[:, 0], proj.uv[:, 1], det=H.details(hs)).points
        moved.append(apply_xform(state.xform, q)[0])
    return np.array([p_a, p_b, *moved])


def test_one_round_lands_both_contact_points_on_the_eq_4_15_point(tmp_path):
    """With one detect → respond round, the deepest frame shows eq. 4.15 exactly: both surfaces
    pass through ``P' = R P_A + (1 - R) P_B``, so the ball moved 3 times as far as the torus
    (measured: 2.4e-9 off P', 1e-8 of the 0.2 gap)."""
    shutil.copy(SCENES / f"{NAME}.py", tmp_path / f"{NAME}.py")
    report = run_file(tmp_path / f"{NAME}.py", frames="6:6", iterations=1)
    (st,) = report.stats
    p_a, p_b, q_a, q_b = _contact_moves(report, st)
    gap = np.linalg.norm(p_b - p_a)
    assert gap > 0.15, gap
    target = contact_targets(p_a, p_b, SHARE)
    assert np.linalg.norm(q_a - target) <= 1e-6 * gap
    assert np.linalg.norm(q_b - target) <= 1e-6 * gap
    assert np.linalg.norm(q_a - p_a) / np.linalg.norm(q_b - p_b) == pytest.approx(RATIO, rel=1e-5)


def test_both_deform_in_their_rigidity_shares_at_every_frame(run_scene):
    """Over a whole run later rounds push again, each surface by its share of the overlap left at its
    own data points. Measured: ratio 3.000 and the gap closed exactly (1.000) at every frame; a
    response that moves a contact's patch by its region's larger move (tried in `acra.respond`)
    gave 3.00–3.26 and 1.00–1.09, hence the 15% band."""
    report = run_scene(NAME)
    hit = [st for st in report.stats if st.in_collision]
    assert [st.frame for st in hit] == [4, 5, 6, 7, 8]
    tol = 1e-3 * min(m.size for m in _sizes(report, hit[0].frame))
    for st in hit:
        p_a, p_b, q_a, q_b = _contact_moves(report, st)
        push = (p_b - p_a) / np.linalg.norm(p_b - p_a)
        ball, torus = (q_a - p_a) @ push, (p_b - q_b) @ push  # both toward the other
        assert ball > 0 and torus > 0, st.frame
        assert ball / torus == pytest.approx(RATIO, rel=0.15), st.frame
        gap = np.linalg.norm(p_b - p_a)
        assert gap - tol <= ball + torus <= 1.15 * gap + tol, (st.frame, ball + torus, gap)


def _sizes(report, frame):
    src, _, scene = _stages(report)
    states, _ = usdio.state_at(src, scene, frame)
    return [geometry.SurfaceGeometry(s.surface, s.xform) for s in states]


def test_contact_is_at_the_ball_equator(run_scene):
    report = run_scene(NAME)
    src, _, scene = _stages(report)
    for st in report.stats:
        if st.in_collision:
            states, _ = usdio.state_at(src, scene, st.frame)
            p_a = st.contacts[0][0]
            uv = D.project(geometry.SurfaceGeometry(states[0].surface, states[0].xform), p_a[None]).uv[0]
            # v runs 0 (south pole) .. 5 (north pole): the contact is in the middle patch row
            assert abs(p_a[2]) <= 0.02 and 2.0 < uv[1] < 3.0, (st.frame, p_a, uv)


def test_ball_poles_stay_closed(run_scene):
    """Level 0 absorbs 0.2 of each push, which moves the ball's CV rows next to its poles. The poles
    stay one point each (detection's criterion: 4 samples per patch within 1e-12 of the size),
    the pole CV rows still coincide and the pole normals are ∓z (measured: 2e-6 off)."""
    report = run_scene(NAME)
    _, out, scene = _stages(report)
    prim = out.GetPrimAtPath(BALL)
    for st in report.stats:
        hs = output_layer.read_output_hierarchy(out, BALL, st.frame)
        size = hs.size()
        for row in (1, hs.v.n - 2):
            assert np.ptp(hs.cvs[:, row], axis=0).max() <= 1e-12 * size, (st.frame, row)
        assert geometry.SurfaceGeometry(hs, np.eye(4)).closed, st.frame
        nrm = np.asarray(UsdGeom.Mesh(prim).GetNormalsAttr().Get(st.frame), dtype=np.float64)
        v = output_layer.read_display_uv(out, BALL)[:, 1]  # the pole rows: v at either end
        assert np.abs(nrm[v == 0.0] - [0, 0, -1]).max() <= 1e-5, st.frame
        assert np.abs(nrm[v == v.max()] - [0, 0, 1]).max() <= 1e-5, st.frame
        assert (v == 0.0).sum() >= hs.u.patches0 and (v == v.max()).sum() >= hs.u.patches0


def test_level0_response_keeps_a_sphere_closed():
    """Regression (`acra.respond`): a level-0 move of the CV rows next to a pole must not split it.

    The surface's pole is ``(R0 + 4 R1 + R2) / 6`` along every meridian, so moving row 2 alone
    (any level-0 contact within two patches, here one on the equator) opened a hole there, 2e-4
    wide with this scene's controls: detection then saw the ball as open and stopped finding what
    was inside it, and the pole normals flipped. (Finer levels near a pole still split it: not
    covered here, see the report.)
    """
    cvs, up, vp = shapes.sphere(8, 8)
    hs = H.from_grid(cvs, up, vp, depth=3)
    cases = [([7.0, 2.5], [0.2, 0.3, 0.5])] + [(uv, [1.0, 0.0, 0.0]) for uv in ([3.0, 1.2], [5.0, 0.6], [5.0, 0.0])]
    for uv, absorption in cases:  # the equator with this scene's controls; near and at the south pole
        uv = np.array([uv])
        p = H.evaluate(hs, uv[:, 0], uv[:, 1]).points
        out, report = R.respond(hs, DataPoints(uv, 0.85 * p, np.array([True])), check_controls(3, absorption))
        assert geometry.SurfaceGeometry(out, np.eye(4)).closed, uv
        for row in (1, hs.v.n - 2):
            assert np.ptp(out.cvs[:, row], axis=0).max() <= 1e-12, (uv, row)
        if uv[0, 1] >= 2.0:  # only the pole's patch row changes: an equatorial contact is still met
            assert np.abs(report.remaining).max() <= 1e-12


def test_parented_torus_moves_with_its_spline(run_scene):
    """The torus's world motion is its parent's Ts spline, untouched: the output holds no opinion on
    any transform, and the torus's world matrix is a translation by the Catmull-Rom value."""
    report = run_scene(NAME)
    src, out, _ = _stages(report)
    op = UsdGeom.Xformable(src.GetPrimAtPath(CARRIER)).GetOrderedXformOps()
    assert [o.GetOpName() for o in op] == ["xformOp:translateX"] and op[0].GetAttr().HasSpline()
    spec = out.GetRootLayer().GetPrimAtPath(CARRIER)
    assert spec is None or not spec.properties
    curve = C.make(*S.CARRIER_KEYS, "catmull_rom")
    torus = UsdGeom.Xformable(out.GetPrimAtPath(TORUS))
    for t in [st.frame for st in report.stats] + [5.5, 6.25]:
        want = Gf.Matrix4d().SetTranslate(Gf.Vec3d(float(curve.evaluate(t)[0]), 0.0, 0.0))
        got = torus.ComputeLocalToWorldTransform(t)
        assert np.abs(np.array(got) - np.array(want)).max() <= 1e-12, t


def test_residual_cleared_at_every_frame(run_scene):
    report = run_scene(NAME)
    _, out, _ = _stages(report)
    for st in report.stats:
        tol = 1e-3 * min(g.size for g in _sizes(report, st.frame))
        for path in (BALL, TORUS):
            assert out.GetPrimAtPath(path).GetAttribute("acra:response:residual").Get(st.frame) <= tol, (st.frame, path)
