"""pipeline.residual: the residual as the user sees it, on exact cases and against the independent
measure (acceptance.visible)."""

import numpy as np
import pytest
import trimesh

from acra import hspline as H, meshrows
from acra import shapes
from acra.tessellate import grid_samples, run_topology
from acceptance import visible
from pipeline import clearance, residual
from pipeline.model import apply_xform, is_translation, translated


def box_collider(half: float = 0.5, xform=None) -> residual.Shown:
    m = trimesh.creation.box(extents=(2 * half,) * 3)
    xform = np.eye(4) if xform is None else xform
    v = apply_xform(xform, m.vertices)
    box = np.stack([v.min(axis=0), v.max(axis=0)])
    return residual.collider_shown("/box", box, float(np.linalg.norm(box[1] - box[0])),
                                   residual.collider_solid(m.vertices, m.faces), xform)


def sheet(z: float, n: int = 6, width: float = 2.0):
    """A flat open sheet at height ``z``: its surface, display points, triangles and parameters."""
    cvs, up, vp = shapes.sheet(n, n, width=width, depth=width)
    cvs[..., 2] = z
    hs = H.from_grid(cvs, up, vp)
    topo = run_topology([hs], 4)
    return hs, grid_samples(hs, topo)[0], topo.triangles(), np.stack([topo.u, topo.v], axis=1)


def test_shown_is_what_the_output_stores():
    """float32 points under the world matrix; the size is the diagonal of their world box."""
    _, pts, tris, uv = sheet(0.1)
    m = np.diag([2.0, 2.0, 2.0, 1.0])
    m[:3, 3] = (1.0, 0.0, 0.0)
    s = residual.shown("/sheet", pts + 1e-9, tris, m, uv)
    world = apply_xform(m, np.asarray(pts + 1e-9, np.float32).astype(np.float64))
    np.testing.assert_array_equal(s.corners, world[tris])
    assert s.size == pytest.approx(np.linalg.norm(np.ptp(world, axis=0)), rel=1e-15)
    assert not s.closed


@pytest.mark.parametrize("t", [(0.1, 2.2, 0.15), (0.0, 0.0, 0.0), (-0.0, 1.0, 0.0), "minus first"])
def test_a_translated_display_is_placed_in_one_pass_with_apply_xform_s_bits(t):
    """Under a matrix whose linear part is the identity, `shown`'s float32 points, world points
    and box come from one compiled pass with the bits of numpy's matmul and `bvh.bounds`: also at
    signed zeros and at world points that sum to exactly zero; a -0.0 translation, where the sign
    of a zero sum depends on the matmul's order, takes numpy's path."""
    from acra import bvh

    rng = np.random.default_rng(7)
    p = rng.normal(size=(500, 3)) * 3.0
    p[rng.random(p.shape) < 0.1] = 0.0
    p[rng.random(p.shape) < 0.1] = -0.0
    p[3] = (0.7, -1.3, 2.1)
    m = np.eye(4)
    m[:3, 3] = -np.asarray(p[3], np.float32) if t == "minus first" else t
    local = np.asarray(p, np.float32).astype(np.float64)
    world = local @ m[:3, :3].T + m[:3, 3]  # numpy's arithmetic, as `apply_xform` states it
    got = residual._placed(p, m)
    for a, b in zip(got, (local, world, bvh.bounds(world))):
        assert a.tobytes() == b.tobytes()
    out = np.empty((500, 3)), np.empty((500, 3)), np.empty((2, 3))
    assert translated(p, m, True, *out) == (t != (-0.0, 1.0, 0.0))
    m[0, 1] = 1e-3  # a shear: numpy's matmul
    assert not translated(p, m, True, *out)
    local, world = residual._placed(p, m)[:2]
    assert world.tobytes() == (local @ m[:3, :3].T + m[:3, 3]).tobytes()


@pytest.mark.parametrize("seed", range(6))
def test_a_display_s_object_space_box_under_the_identity_is_its_world_box(seed):
    """`Shown.box_local` under an identity matrix (a translation of +0.0 or -0.0) is the world box
    `shown` took, the values of `bvh.bounds` of the object-space points (a zero's sign aside),
    so the grid's cells and the weld's scale are the same bits; under a translation, or with a
    point that is not finite, it is `bvh.bounds`' own."""
    from acra import bvh, clearcells

    rng = np.random.default_rng(seed)
    p = rng.normal(size=(300, 3)) * 10.0 ** rng.integers(-3, 4)
    p[rng.random(p.shape) < 0.2] = 0.0
    p[rng.random(p.shape) < 0.2] = -0.0
    tris = np.arange(300, dtype=np.int64).reshape(-1, 3)
    m = np.eye(4)
    m[:3, 3] = rng.choice([0.0, -0.0], 3)
    s = residual.shown("/pts", p, tris, m, closed=True)
    ref = bvh.bounds(s.local)
    assert s.box_local is s.box and np.array_equal(s.box_local, ref)
    assert s.diagonal_local == float(np.linalg.norm(ref[1] - ref[0]))
    # the cells the grid reads of the box: floor((x - origin) / h) at the box's corners
    origin, h = rng.normal(size=3) * np.abs(ref).max(), 0.37 * float(np.ptp(ref, axis=0).max())
    assert np.array_equal(np.floor((s.box_local - origin) / h), np.floor((ref - origin) / h))
    tri = s.corners[:20]
    rho = np.full(len(tri), 1e-3)
    # `clearcells.clear_of` with either box: the same answer
    first, got = (clearcells.clear_of(s.local, s.triangles, tri, rho, 0.0, 0.1, box) for box in (s.box_local, ref))
    assert (got is None) == (first is None)
    if got is not None:
        assert all(np.array_equal(a, b) for a, b in zip(got[:2], first[:2])) and got[2] == first[2]
    m[:3, 3] = (0.25, 0.0, 0.0)  # a translation: its own box
    t = residual.shown("/pts", p, tris, m, closed=True)
    assert t.box_local is not t.box and t.box_local.tobytes() == bvh.bounds(t.local).tobytes()
    q = p.copy()
    q[5, 1] = np.inf
    with np.errstate(invalid="ignore"):  # the point's row through the matrix's zeros: inf * 0
        u = residual.shown("/pts", q, tris, np.eye(4), closed=True)
    assert u.box_local is not u.box and u.box_local.tobytes() == bvh.bounds(u.local).tobytes()


def test_a_display_s_triangles_and_parameters_are_held_as_given():
    """`shown` holds a display's own triangles and parameters (the topology's: a numba kernel's
    output can carry another instance of the int64 dtype), so every round's `Shown` of the
    display digests them by identity; other dtypes are converted."""
    _, pts, tris, uv = sheet(0.1)
    tris = tris.view(np.dtype(np.int64).newbyteorder("="))  # an equal dtype, another instance
    assert tris.dtype == np.int64 and np.asarray(tris, np.int64) is not tris  # numpy would make a new view
    s = residual.shown("/sheet", pts, tris, np.eye(4), uv)
    assert s.triangles is tris and s.vertex_uv is uv
    s = residual.shown("/sheet", pts, tris.astype(np.int32), np.eye(4), uv.astype(np.float32))
    assert s.triangles.dtype == np.int64 and s.vertex_uv.dtype == np.float64

def test_an_array_with_a_kept_array_s_bytes_takes_its_digest_without_hashing(monkeypatch):
    """`_digest` hashes a new array whose bytes no kept array holds; one holding a kept array's
    bytes gets that digest unhashed, and bytes that differ anywhere (a -0.0 for a 0.0) differ."""
    import hashlib

    residual._DIGESTS.clear()
    hashed, sha1 = [], hashlib.sha1
    monkeypatch.setattr(residual.hashlib, "sha1", lambda *a: hashed.append(1) or sha1(*a))
    tris = np.arange(3000, dtype=np.int64).reshape(-1, 3)
    uv = np.linspace(-1.0, 1.0, 2000).reshape(-1, 2)
    uv[::7, 0] = 0.0
    first = residual._digest(tris), residual._digest(uv)
    assert len(hashed) == 2 and not tris.flags.writeable
    assert (residual._digest(tris.copy()), residual._digest(uv.copy())) == first and len(hashed) == 2
    signed = uv.copy()
    signed[signed == 0.0] = -0.0
    assert signed.tobytes() != uv.tobytes() and residual._digest(signed) != first[1]
    other = tris.copy()
    other[-1, -1] += 1
    assert residual._digest(other) != first[0]
    assert residual._digest(tris.astype(np.int32)) != first[0]  # the same values as other bytes
    assert len(hashed) == 5
    residual._DIGESTS.clear()

def test_a_display_s_faces_near_a_box_are_the_full_scan_s_through_chunks_listed_once_a_topology(monkeypatch):
    """`Shown.near_rows` opens the chunks near the box (`meshrows.face_chunks`, built once a `Shown`)
    and gives the rows a scan of every face gives, boxes anywhere about the display and pads
    from none to past it; the points each chunk uses are listed once for the triangles array
    (made read-only), so every display on one topology takes the same lists."""

    ball = H.from_grid(*shapes.sphere(10, 8))
    topo = run_topology([ball], 4)
    pts, tris = grid_samples(ball, topo)[0], topo.triangles()
    assert len(tris) > 32 * 32  # more than one group of chunks
    listed, chunk_vertices = [], meshrows.chunk_vertices
    monkeypatch.setattr(residual.meshrows, "chunk_vertices", lambda *a: listed.append(1) or chunk_vertices(*a))
    residual._CHUNK_VERTICES.clear()
    m = np.eye(4)
    m[:3, 3] = (0.3, -0.2, 0.1)
    rng = np.random.default_rng(5)
    for k in range(3):
        s = residual.shown("/ball", pts * (1.0 + 0.01 * k), tris, m, None, closed=True)
        for _ in range(40):
            lo, hi = np.sort(rng.uniform(-1.5, 1.5, (2, 3)) * rng.uniform(0.05, 1.0), axis=0) + m[:3, 3]
            pad = float(rng.choice([0.0, 0.01, 0.3, 3.0]))
            want = meshrows.faces_meet_rows(s.world, s.triangles, lo, hi, pad)
            assert np.array_equal(s.near_rows(np.stack([lo, hi]), pad), want)
        assert 0 < len(s.near_rows(s.box, 0.0)) == len(tris)
    assert len(listed) == 1 and not tris.flags.writeable
    residual._CHUNK_VERTICES.clear()


@pytest.mark.parametrize("z", [0.25, -0.4999, 0.6])
def test_a_sheet_in_a_box_is_as_deep_as_its_distance_to_the_nearest_face(z):
    """A flat sheet through [-0.5, 0.5]^3 at height z, wider than the box: the deepest point is on
    the box's vertical axis, 0.5 - |z| from the top or bottom; outside the box nothing. Exact
    (eq. (7) on the convex box), and never under the independent measure."""
    _, pts, tris, uv = sheet(z)
    a = residual.shown("/sheet", pts, tris, np.eye(4), uv)
    ins = residual.pair_depth(a, box_collider(), 1e-4)
    truth = max(0.0, 0.5 - abs(np.float32(z)))
    assert ins.depth == pytest.approx(truth, abs=1e-12)
    assert ins.lower <= ins.depth and (truth == 0) == (len(ins.points) == 0)
    if len(ins.points):  # the points found inside carry the sheet's parameters
        hs = sheet(z)[0]
        np.testing.assert_allclose(H.evaluate(hs, ins.uv[:, 0], ins.uv[:, 1]).points[:, :2], ins.points[:, :2], atol=1e-12)


def test_a_uniformly_scaled_collider_scales_the_depth():
    """The box in object space [-0.5, 0.5]^3 under a scale of 3 (and a turn): the sheet at z = 0.3
    is 1.5 - 0.3 deep in world units, found in the box's object space and mapped back."""
    c, s = np.cos(0.3), np.sin(0.3)
    m = np.eye(4)
    m[:3, :3] = 3.0 * np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    _, pts, tris, uv = sheet(0.3, width=8.0)
    ins = residual.pair_depth(residual.shown("/sheet", pts, tris, np.eye(4), uv), box_collider(xform=m), 1e-4)
    assert clearance.sigma_max(m) == pytest.approx(3.0)
    assert ins.depth == pytest.approx(1.5 - np.float32(0.3), rel=1e-9)


def test_a_deformable_s_part_answers_as_its_whole_solid():
    """A sheet through a closed deformable's display: the part of the ball near the sheet gives
    the bound the whole ball's solid gives (exact closest points and pseudo-normals within the
    part's reach), and never less than the independent measure."""
    ball = H.from_grid(*shapes.sphere(10, 8))
    topo = run_topology([ball], 4)
    pts = grid_samples(ball, topo)[0]
    b = residual.shown("/ball", pts, topo.triangles(), np.eye(4), None, closed=True, outward=1.0)
    _, spts, stris, suv = sheet(0.2, width=3.0)
    a = residual.shown("/sheet", spts, stris, np.eye(4), suv)
    target = 5e-4 * a.size
    part = residual.pair_depth(a, b, target)
    whole = clearance.triangle_depth(b.whole(), a.corners, target)
    assert part.depth == pytest.approx(whole.bound, rel=1e-12)
    ball_body = visible.Body("/ball", trimesh.Trimesh(b.local, b.triangles), True, True)
    samples = visible.triangle_samples(trimesh.Trimesh(apply_xform(np.eye(4), np.asarray(spts, np.float32).astype(np.float64)), stris))
    assert part.depth >= visible.depth_inside(samples, ball_body).max() - 1e-12


def test_a_triangle_below_a_curved_part_s_box_is_measured():
    """A small flat triangle 0.05 under the top of a closed ball's display: the part of the ball
    near it (the faces within its box's diagonal) is a thin cap whose box lies wholly above the
    triangle, yet the triangle is inside the ball and within the part's reach, so the part is
    queried on it and gives the whole ball's bound; a triangle beyond the part's reach is
    answered by the whole solid."""
    from acra import bvh

    ball = H.from_grid(*shapes.sphere(10, 8))
    topo = run_topology([ball], 4)
    b = residual.shown("/ball", grid_samples(ball, topo)[0], topo.triangles(), np.eye(4), None, closed=True, outward=1.0)
    z = b.box[1, 2] - 0.05
    tri = np.array([[-0.05, -0.05, z], [0.05, -0.05, z], [0.0, 0.05, z]])
    a = residual.shown("/tri", tri, np.array([[0, 1, 2]]), np.eye(4))
    region = bvh.bounds(a.corners)
    pad = float(np.linalg.norm(region[1] - region[0]))
    rows = b.near_rows(region, pad)
    part = clearance.solid(b.local, b.triangles[rows], part=True, outward=1.0, scale=b.diagonal_local)
    assert part.bounds[0, 2] > region[1, 2]  # the cap's box lies above the triangle
    target = 1e-6
    got = residual.pair_depth(a, b, target)
    whole = clearance.triangle_depth(b.whole(), a.corners, target)
    assert whole.bound > 0.05 and whole.complete
    assert got.depth == pytest.approx(whole.bound, rel=1e-12)
    assert clearance.triangle_depth(part, a.corners, target, reach=pad).bound == pytest.approx(whole.bound, rel=1e-12)
    far = a.corners - [0.0, 0.0, 0.5]  # deep in the ball, beyond the cap's reach
    assert clearance.triangle_depth(part, far, target, reach=pad) is None


def test_a_frame_measures_every_deformable_in_every_other_closed_object():
    """Two overlapping balls and an open sheet: each ball's display in the other, the sheet in
    both, nothing in the sheet (it has no inside); the frame's worst is over the inner object's
    own size."""
    objects = []
    for name, x in (("/a", 0.0), ("/b", 1.8)):
        ball = H.from_grid(*shapes.sphere(10, 8))
        topo = run_topology([ball], 4)
        m = np.eye(4)
        m[0, 3] = x
        objects.append(residual.shown(name, grid_samples(ball, topo)[0], topo.triangles(), m, None, True, 1.0))
    _, spts, stris, suv = sheet(0.0, width=5.0)
    objects.append(residual.shown("/sheet", spts, stris, np.eye(4), suv))
    fr = residual.measure_frame(objects, 1e-3)
    pairs = {(p.a, p.b) for p in fr.pairs}
    assert pairs == {("/a", "/b"), ("/b", "/a"), ("/sheet", "/a"), ("/sheet", "/b")}
    assert fr.worst_rel == max(p.rel for p in fr.pairs) and fr.worst_rel > 0.01
    assert fr.pair_rel("/a", "/b") == max(p.rel for p in fr.pairs if {p.a, p.b} == {"/a", "/b"})


def test_a_measured_pair_is_taken_by_content_where_the_displays_hold_the_same():
    """`known` answers a pair whose two displays hold what a measured pair's held (new `Shown`
    objects of the same points: the run's display showing the kept round's surfaces), with the
    answer measuring it gives; a display moved by one float32 step is measured again."""
    ball = H.from_grid(*shapes.sphere(10, 8))
    topo = run_topology([ball], 4)
    pts, tris = grid_samples(ball, topo)[0], topo.triangles()
    _, spts, stris, suv = sheet(0.2, width=3.0)

    def objects(dz: float = 0.0):
        return [residual.shown("/sheet", spts + [0.0, 0.0, dz], stris, np.eye(4), suv),
                residual.shown("/ball", pts, tris, np.eye(4), None, closed=True, outward=1.0)]

    first = residual.measure_frame(objects(), 1e-3)
    known = residual.known(first, 1e-3)
    again = objects()
    assert [o.fingerprint for o in again] == [o.fingerprint for o in objects()]
    taken = residual.measure_frame(again, 1e-3, known=known)
    assert len(taken.pairs) == len(first.pairs) == 1 and first.pairs[0].inside.depth > 0
    got, want = taken.pairs[0].inside, first.pairs[0].inside
    assert (got.depth, got.lower, got.complete, taken.worst_rel) == (want.depth, want.lower, want.complete, first.worst_rel)
    assert len(got.points) == 0 and len(want.points) > 0  # the depths alone are kept
    fresh = residual.measure_frame(objects(), 1e-3)
    assert [p.inside.depth for p in fresh.pairs] == [p.inside.depth for p in first.pairs]
    step = float(np.spacing(np.float32(0.2)))
    moved = residual.measure_frame(objects(2 * step), 1e-3, known=known)
    assert len(moved.pairs[0].inside.points) > 0  # measured again
    assert len(residual.measure_frame(again, 2e-3, known=known).pairs[0].inside.points) > 0


def test_a_display_on_a_keyed_topology_is_known_by_its_points_and_the_topology_s_key():
    """`shown` with the topology its triangles and parameters are of: the topology's key stands
    for those arrays in the fingerprint. The same points on the same refinement built again (new
    topology, triangles and parameter arrays) share a fingerprint and take the measured answer;
    one point's last float32 bit, a refinement with one patch more, or the arrays digested
    without a topology do not."""
    ball = H.from_grid(*shapes.sphere(10, 8))
    cvs, up, vp = shapes.sheet(6, 6, width=3.0, depth=3.0)
    cvs[..., 2] = 0.2
    hs = H.from_grid(cvs, up, vp, depth=2)
    finer = H.make_movable(hs, 1, [[2, 2]])

    def objects(surface=hs, nudge: int = -1, keyed: bool = True):
        topo = run_topology([surface], 4)
        pts = grid_samples(surface, topo)[0].astype(np.float32)
        if nudge >= 0:
            pts[nudge, 2] = np.nextafter(pts[nudge, 2], np.float32(1))
        btopo = run_topology([ball], 4)
        return [residual.shown("/sheet", pts, topo.triangles(), np.eye(4), np.stack([topo.u, topo.v], axis=1),
                               topology=topo if keyed else None),
                residual.shown("/ball", grid_samples(ball, btopo)[0], btopo.triangles(), np.eye(4), None, closed=True,
                               outward=1.0, topology=btopo if keyed else None)]

    first = objects()
    assert all(o.topology.key is not None for o in first)
    again = objects()
    assert [o.fingerprint for o in again] == [o.fingerprint for o in first]
    measured = residual.measure_frame(first, 1e-3)
    assert measured.pairs[0].inside.depth > 0
    taken = residual.measure_frame(again, 1e-3, known=residual.known(measured, 1e-3))
    got, want = taken.pairs[0].inside, measured.pairs[0].inside
    assert (got.depth, got.lower, got.complete, len(got.points)) == (want.depth, want.lower, want.complete, 0)
    assert len(want.points) > 0
    n = int(np.argmax(first[0].local[:, 2] == first[0].local[:, 2].max()))
    others = [objects(nudge=n)[0], objects(finer)[0], objects(keyed=False)[0]]
    assert others[0].local[n, 2] != first[0].local[n, 2] and np.array_equal(np.delete(others[0].local, n, 0),
                                                                             np.delete(first[0].local, n, 0))
    assert len({o.fingerprint for o in others + [first[0]]}) == 4


def test_a_part_s_answer_is_kept_for_the_same_triangles_in_another_display(monkeypatch):
    """Two displays of the inner object that differ only far from the other object (the run's
    display and the round's, `measure_run`): their pairs' fingerprints differ, but the triangles
    near the other object are the same bits, so the second pair takes the first one's answer
    from the part solid (`clearance.triangle_depth` runs once) and gives the same figures and
    points; triangles one float32 step away are measured again."""
    ball = H.from_grid(*shapes.sphere(10, 8))
    topo = run_topology([ball], 4)
    parts: dict = {}
    b = residual.shown("/ball", grid_samples(ball, topo)[0], topo.triangles(), np.eye(4), None, closed=True, outward=1.0,
                       parts=parts)
    _, spts, stris, suv = sheet(0.2, width=3.0)
    n = len(spts)
    far = [[5.0, 5.0, 5.0], [5.5, 5.0, 5.0], [5.0, 5.5, 5.0]]  # beyond the ball's box
    a = residual.shown("/sheet", spts, stris, np.eye(4), suv)
    other = residual.shown("/sheet", np.vstack([spts, far]), np.vstack([stris, [[n, n + 1, n + 2]]]), np.eye(4),
                           np.vstack([suv, np.zeros((3, 2))]))
    assert other.fingerprint != a.fingerprint
    runs = []
    real = clearance.triangle_depth
    monkeypatch.setattr(clearance, "triangle_depth", lambda *args, **kw: runs.append(1) or real(*args, **kw))
    target = 5e-4 * a.size
    want = residual.pair_depth(a, b, target, 2 * target)
    got = residual.pair_depth(other, b, target, 2 * target)
    assert len(runs) == 1 and want.depth > 0
    assert (got.depth, got.lower, got.complete) == (want.depth, want.lower, want.complete)
    for x, y in ((got.points, want.points), (got.uv, want.uv), (got.deep, want.deep)):
        assert np.array_equal(x, y)
    step = float(np.spacing(np.float32(0.2)))
    moved = residual.shown("/sheet", spts + [0.0, 0.0, 2 * step], stris, np.eye(4), suv)
    residual.pair_depth(moved, b, target, 2 * target)
    assert len(runs) == 2


def test_a_part_of_another_display_with_the_same_content_answers(monkeypatch):
    """The run's display of a surface shows other points than the round's (another topology far
    from the other object) but the same faces near it: a pair on it (``like``: the round's
    display) takes the round's part solid and its answer (`clearance.solid` and
    `clearance.triangle_depth` run once) and gives what a part of its own gives; a display
    whose faces there lie one float32 step higher builds its own."""
    ball = H.from_grid(*shapes.sphere(10, 8))
    topo = run_topology([ball], 4)
    pts, tris = grid_samples(ball, topo)[0], topo.triangles()
    round_ = residual.shown("/ball", pts, tris, np.eye(4), None, closed=True, outward=1.0, parts={})
    z = round_.box[1, 2] - 0.05
    a = residual.shown("/tri", [[-0.2, -0.2, z], [0.2, -0.2, z], [0.0, 0.2, z]], np.array([[0, 1, 2]]), np.eye(4))
    low = np.nonzero(pts[:, 2] < pts[:, 2].min() + 0.3 * np.ptp(pts[:, 2]))[0][:3]  # far below the triangle
    extra = np.vstack([pts, pts[low] * 0.999])  # points inside the box: the same weld scale
    n = len(pts)
    other = np.vstack([tris, [[n, n + 1, n + 2]]])
    run_ = residual.shown("/ball", extra, other, np.eye(4), None, closed=True, outward=1.0)
    assert run_.diagonal_local == round_.diagonal_local and run_.fingerprint != round_.fingerprint
    built, runs = [], []
    real, real_depth = clearance.solid, clearance.triangle_depth
    monkeypatch.setattr(clearance, "solid", lambda *args, **kw: built.append(1) or real(*args, **kw))
    monkeypatch.setattr(clearance, "triangle_depth", lambda *args, **kw: runs.append(1) or real_depth(*args, **kw))
    target = 1e-6
    want = residual.pair_depth(a, round_, target, 2 * target)
    assert (len(built), len(runs)) == (1, 1) and want.depth > 0.04
    got = residual.pair_depth(a, residual.replace(run_, like=round_), target, 2 * target)
    assert (len(built), len(runs)) == (1, 1)
    alone = residual.pair_depth(a, run_, target, 2 * target)
    assert (len(built), len(runs)) == (2, 2)
    for x in (got, alone):
        assert (x.depth, x.lower, x.complete) == (want.depth, want.lower, want.complete)
        assert np.array_equal(x.points, want.points) and np.array_equal(x.deep, want.deep)
    step = np.float32(pts) + np.spacing(np.float32(pts)) * (pts[:, 2:] > 0)  # the upper half a step up
    moved = residual.shown("/ball", np.vstack([step, extra[n:]]), other, np.eye(4), None, closed=True, outward=1.0)
    residual.pair_depth(a, residual.replace(moved, like=round_), target, 2 * target)
    assert len(built) == 3


def test_a_run_s_frames_apart_are_not_measured_and_read_zero(monkeypatch):
    """`measure_run` skips a frame whose objects' boxes (each display's object-space box mapped
    by its world matrix) all lie apart: its figures are those measuring it gives (every pair 0),
    and a frame in contact is measured as before."""
    import pathlib

    from pipeline import frames, usdio

    scene_file = pathlib.Path(__file__).resolve().parents[1] / "scenes" / "dog_head_spike.py"
    stage = usdio.open_input(usdio.load_scene_file(scene_file))
    scene = usdio.read_scene(stage)

    def figures():
        result, stats = frames.run_frames(stage, scene, [0, 5, 14])
        return ([(st.frame, st.residual, st.residual_rel, st.pair_residual_rel) for st in stats],
                [(f, p, r.residual) for f in sorted(result.frames) for p, r in sorted(result.frames[f].items())])

    calls = []  # per `measure_frame` call, whether the run's residual (`measure_run`) made it
    in_run = [False]
    real, real_run = residual.measure_frame, residual.measure_run

    def run(*a, **k):
        in_run[0] = True
        try:
            return real_run(*a, **k)
        finally:
            in_run[0] = False

    monkeypatch.setattr(residual, "measure_run", run)
    monkeypatch.setattr(residual, "measure_frame", lambda objects, *a, **k: calls.append(
        bool(objects) and in_run[0]) or real(objects, *a, **k))
    got = figures()
    skipped = 3 - sum(calls)
    monkeypatch.setattr(residual, "_any_meet", lambda boxes, n: True)
    assert got == figures()
    assert skipped == 2 and got[0][2][1] > 0  # the free frames 0 and 5 skipped, frame 14 measured


def test_a_part_within_a_kept_part_is_answered_by_the_kept_one(monkeypatch):
    """A triangle under the top of a closed ball's display, then a smaller one within it: the
    second pair's part (the ball's faces within its box's diagonal) lies within the first
    pair's, so the kept part answers it (`clearance.solid` runs once) and gives what a fresh
    part of its own gives."""
    from acra import bvh

    ball = H.from_grid(*shapes.sphere(10, 8))
    topo = run_topology([ball], 4)
    pts, tris = grid_samples(ball, topo)[0], topo.triangles()
    b = residual.shown("/ball", pts, tris, np.eye(4), None, closed=True, outward=1.0, parts={})
    z = b.box[1, 2] - 0.05
    big = np.array([[-0.2, -0.2, z], [0.2, -0.2, z], [0.0, 0.2, z]])
    a = residual.shown("/big", big, np.array([[0, 1, 2]]), np.eye(4))
    piece = residual.shown("/piece", 0.25 * big + [0.0, 0.0, 0.75 * z], np.array([[0, 1, 2]]), np.eye(4))
    rows = [b.near_rows(bvh.bounds(x.corners), float(np.linalg.norm(np.ptp(bvh.bounds(x.corners), axis=0))))
            for x in (a, piece)]
    assert len(rows[1]) < len(rows[0]) and np.isin(rows[1], rows[0]).all()
    built = []
    real = clearance.solid
    monkeypatch.setattr(clearance, "solid", lambda *args, **kw: built.append(1) or real(*args, **kw))
    target = 1e-6
    residual.pair_depth(a, b, target)
    got = residual.pair_depth(piece, b, target)
    assert len(built) == 1
    want = residual.pair_depth(piece, residual.shown("/ball", pts, tris, np.eye(4), None, closed=True, outward=1.0), target)
    assert len(built) == 2 and want.depth > 0.04
    assert (got.depth, got.lower, got.complete) == (want.depth, want.lower, want.complete)
    assert np.array_equal(got.points, want.points) and np.array_equal(got.deep, want.deep)


def _ball_display(parts=None):
    ball = H.from_grid(*shapes.sphere(10, 8))
    topo = run_topology([ball], 4)
    return residual.shown("/ball", grid_samples(ball, topo)[0], topo.triangles(), np.eye(4), None, closed=True, outward=1.0,
                          parts=parts)


def test_a_display_mostly_clear_of_a_deformable_is_measured_on_a_smaller_part(monkeypatch):
    """A tilted sheet cutting a shallow cap off a small closed ball's display, most of its
    triangles in the ball's box far outside: the triangles proven clear are left out and the
    part near the others is smaller than the part near the sheet's box, with the same figures
    and points. A sheet through the ball's middle, whose deepest points lie farther from the
    surface than a part near the kept triangles reaches (such a part would not hold their
    closest faces), is measured on the part near its box and gives the whole ball's bound."""
    small = 0.2
    _, spts, stris, suv = sheet(0.0, n=16, width=1.0)
    built = []
    real = clearance.solid
    monkeypatch.setattr(clearance, "solid", lambda v, f, *args, **kw: built.append(len(f)) or real(v, f, *args, **kw))

    def ball():
        b = _ball_display()
        return residual.shown("/ball", small * b.local, b.triangles, np.eye(4), None, closed=True, outward=1.0, parts={})

    for c, part_smaller in ((0.19 * np.sqrt(2.0) * small / 0.2, True), (0.0, False)):
        tilted = spts.copy()
        tilted[:, 2] = tilted[:, 0] + c  # the plane z = x + c, at c / sqrt(2) from the ball's centre
        a = residual.shown("/sheet", tilted, stris, np.eye(4), suv)
        target = 1e-4 * a.size
        monkeypatch.setattr(residual, "CLEAR_ROWS", 10 ** 9)
        built.clear()
        want = residual.pair_depth(a, ball(), target, 2 * target)
        box_part = built[-1]
        monkeypatch.setattr(residual, "CLEAR_ROWS", 0)
        built.clear()
        got = residual.pair_depth(a, ball(), target, 2 * target)
        assert want.depth > 0
        assert (got.depth, got.lower, got.complete) == (want.depth, want.lower, want.complete)
        for x, y in ((got.points, want.points), (got.uv, want.uv), (got.deep, want.deep)):
            assert np.array_equal(x, y)
        assert (len(built) == 1 and built[0] < box_part / 2) == part_smaller
    b = ball()
    exact = clearance.triangle_depth(b.whole(), a.near(b.box)[0], target, decide=2 * target)
    assert got.depth == pytest.approx(exact.bound, rel=1e-12) and got.depth > 0.5 * small


@pytest.mark.parametrize("seed", range(4))
def test_any_meet_is_every_pair_of_boxes_met(seed):
    """`_any_meet`: whether any of the first ``n`` boxes meets another, as the per-pair comparisons
    (each box's low corner at most the other's high corner, both ways) give it, on boxes that touch
    at a side, lie apart by a rounding, hold NaN, or are only colliders'."""
    rng = np.random.default_rng(seed)
    for _ in range(60):
        m = int(rng.integers(1, 9))
        lo = rng.integers(-4, 4, size=(m, 3)).astype(np.float64)
        hi = lo + rng.integers(0, 3, size=(m, 3))
        nudge = rng.random((m, 3)) < 0.1  # a side one rounding past an integer another box touches
        lo[nudge] = np.nextafter(lo[nudge], np.inf)
        if rng.random() < 0.2:
            hi[rng.integers(m), rng.integers(3)] = np.nan
        boxes = np.stack([lo, hi], axis=1)
        n = int(rng.integers(0, m + 1))
        want = any(bool(np.all(boxes[i, 0] <= boxes[j, 1]) and np.all(boxes[j, 0] <= boxes[i, 1]))
                   for i in range(n) for j in range(m) if j != i)
        assert residual._any_meet(boxes, n) == want


def test_pair_rel_is_the_larger_of_a_pairs_two_ways():
    """`FrameResidual.pair_rel` of two paths: the larger ``rel`` of the pair's measured ways
    whichever way it is asked, 0 for a pair not measured, and the pairs appended after a first
    ask counted."""
    fr = residual.FrameResidual()
    nothing = residual.Inside(0.0, 0.0, np.zeros((0, 3)), None, np.zeros(0))
    for a, b, rel in (("/b", "/a", 0.2), ("/a", "/b", 0.3), ("/a", "/c", 0.1), ("/c", "/a", 0.05)):
        fr.pairs.append(residual.PairDepth(a, b, nothing, rel))
    assert fr.pair_rel("/a", "/b") == fr.pair_rel("/b", "/a") == 0.3
    assert fr.pair_rel("/c", "/a") == 0.1 and fr.pair_rel("/b", "/c") == 0.0
    fr.pairs.append(residual.PairDepth("/c", "/b", nothing, 0.7))
    assert fr.pair_rel("/b", "/c") == 0.7



@pytest.mark.parametrize("seed", range(3))
def test_a_pair_measured_both_ways_in_two_threads_gives_one_thread_s_answers(monkeypatch, seed):
    """Two overlapping balls, each measured in the other: with two threads (numba's
    ``NUMBA_NUM_THREADS``) the two sides run side by side (`pipeline.workers.both`) and give
    the bits of one thread, kept in ``measured`` in the same order; a second frame on the same
    `Shown` objects takes the kept answers."""
    from numba.core import config

    from pipeline import workers

    rng = np.random.default_rng(seed)
    ball = H.from_grid(*shapes.sphere(10, 8))
    topo = run_topology([ball], 4)
    pts, tris = grid_samples(ball, topo)[0], topo.triangles()
    shift = np.array([1.2, 0.0, 0.0]) + rng.uniform(-0.2, 0.2, 3)

    def frame(threads: int):
        monkeypatch.setattr(config, "NUMBA_NUM_THREADS", threads)
        objects = []
        for name, x in (("/a", np.zeros(3)), ("/b", shift)):
            m = np.eye(4)
            m[:3, 3] = x
            objects.append(residual.shown(name, pts, tris, m, None, closed=True, outward=1.0, parts={}))
        measured: dict = {}
        fr = residual.measure_frame(objects, 1e-3, measured=measured)
        return fr, measured, residual.measure_frame(objects, 1e-3, measured=measured)

    sides = []
    real = workers.both
    monkeypatch.setattr(workers, "both", lambda f, g: sides.append(1) or real(f, g))
    (one, kept_one, again_one), (two, kept_two, again_two) = frame(1), frame(2)
    assert len(sides) == 1  # the second frame's answers are kept ones
    assert [(p.a, p.b) for p in one.pairs] == [(p.a, p.b) for p in two.pairs] == [("/a", "/b"), ("/b", "/a")]
    for fr in (one, two, again_one, again_two):
        assert fr.pairs[0].inside.depth > 0
    for x, y in ((one, two), (again_one, again_two), (one, again_two)):
        for p, q in zip(x.pairs, y.pairs):
            got, want = p.inside, q.inside
            assert (got.depth, got.lower, got.complete, got.stopped, p.rel) == (want.depth, want.lower, want.complete,
                                                                                 want.stopped, q.rel)
            assert np.array_equal(got.points, want.points) and np.array_equal(got.deep, want.deep)
    assert [(k[2], v[0].path, v[1].path) for k, v in kept_one.items()] == [(k[2], v[0].path, v[1].path)
                                                                          for k, v in kept_two.items()]


@pytest.mark.parametrize("seed", range(4))
def test_a_displays_box_under_a_translation_is_its_views_bit_for_bit(seed):
    """`_display_box`: a run display's gate box taken from the `Shown` the loop built of the same
    points (`shown`'s world box) equals the box of its points' own corners (`_outer_box` of
    `_local_box`) bit for bit, under translations of +0.0 and nonzero values, on points holding
    zeros of both signs, values that round to one float32 and values that round to zero; under a
    translation of -0.0, a matrix that is not one, or a point that is not finite it takes the
    points' own box."""
    rng = np.random.default_rng(seed)
    for _ in range(40):
        pts = rng.normal(size=(int(rng.integers(1, 200)), 3)) * 10.0 ** rng.integers(-3, 4)
        special = rng.random(pts.shape)
        pts[special < 0.05] = 0.0
        pts[(special >= 0.05) & (special < 0.1)] = -0.0
        pts[(special >= 0.1) & (special < 0.13)] = rng.choice([1e-50, -1e-50, 1.0 + 1e-12, 1.0 - 1e-12])
        xform = np.eye(4)
        xform[:3, 3] = rng.choice([0.0, 1.5, -2.25, 1e-8, 3e5], size=3) if rng.random() < 0.8 else 0.0
        want = residual._outer_box(xform, residual._local_box({}, pts))
        view = residual.shown("/s", pts, np.zeros((0, 3), np.int64), xform)
        assert is_translation(xform)
        assert residual._display_box(xform, pts, view, {}).tobytes() == want.tobytes()
        assert residual._display_box(xform, pts, None, {}).tobytes() == want.tobytes()
    pts = rng.normal(size=(50, 3))
    for change in ("minus zero", "rotation", "scale", "nan"):
        xform, p = np.eye(4), pts.copy()
        if change == "minus zero":
            xform[1, 3] = -0.0
        elif change == "rotation":
            xform[:2, :2] = [[0.0, -1.0], [1.0, 0.0]]
        elif change == "scale":
            xform[2, 2] = 2.0
        else:
            p[3, 1] = np.nan
        view = residual.shown("/s", p, np.zeros((0, 3), np.int64), xform)
        assert is_translation(xform) == (change == "nan")
        got = residual._display_box(xform, p, view, {})
        want = residual._outer_box(xform, residual._local_box({}, p))
        assert got.tobytes() == want.tobytes()
