"""`pipeline.rim`: eq. 4.16's points at a collider's outline."""

import numpy as np
import pytest

from pipeline import geometry
from pipeline import rim as R


def test_rim_points_lie_one_step_outside_a_box_on_the_face_it_pushes_to():
    """Eq. 4.16's middles pin the surface only inside a box's outline,
    and the C2 surface curls back up inside the box before the side face. `rim.rim_points`
    puts a point one detection step outside each side-face crossing, aimed at the bottom face's
    plane, so the rise happens outside. A curved collider's flank gives none (its plane extended
    past the outline would cut into what the ball needs: `elbow_contact`)."""
    import trimesh

    from acra import hspline as H
    from acra import shapes
    from pipeline import detect as D
    from pipeline.model import ColliderModel

    cvs, _, _ = shapes.sheet(12, 12, width=4.0, depth=4.0)
    sheet = geometry.SurfaceGeometry(H.from_grid(cvs, depth=3), np.eye(4), "/sheet")
    lo, hi = np.array([-0.7, -0.9, -0.5]), np.array([0.9, 0.7, 0.5])
    mesh = trimesh.creation.box(bounds=np.stack([lo, hi]))
    box = geometry.ColliderGeometry(geometry.prepare_collider(ColliderModel("/box", mesh.vertices, mesh.faces)), np.eye(4))
    region, _ = D.regions(sheet, box)
    down = np.array([0.0, 0.0, -1.0])
    uv, points, goals = R.rim_points(sheet, box, region.uv, down, 2)
    step = 4.0 / 9 / 8  # one detection step (8 per level-0 patch edge) in world units
    x, y = points[:, 0], points[:, 1]
    beyond = np.maximum.reduce([lo[0] - x, x - hi[0], lo[1] - y, y - hi[1]])
    assert len(uv) >= 4 * 3  # every side of the outline has rim points
    # outside, one step past the crossing (bisected to 1/64 of the step): measured 0.022 to 0.0561
    assert np.all(beyond > 0) and np.all(beyond <= step * (1 + 2.0**-R.RIM_BISECT) + 1e-9), beyond
    np.testing.assert_allclose(goals[:, :2], points[:, :2], atol=1e-12)  # moved along the push
    np.testing.assert_allclose(goals[:, 2], lo[2], atol=1e-9)  # onto the bottom face's plane
    for side in (x < lo[0], x > hi[0], y < lo[1], y > hi[1]):
        assert side.any()

    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.45)
    ball.apply_translation([0.1, -0.1, 0.3])  # 0.15 into the sheet
    ball_geom = geometry.ColliderGeometry(geometry.prepare_collider(ColliderModel("/ball", ball.vertices, ball.faces)), np.eye(4))
    region, _ = D.regions(sheet, ball_geom)
    assert len(region.uv) and len(R.rim_points(sheet, ball_geom, region.uv, down, 2)[0]) == 0


def test_rim_points_are_kept_by_content_and_never_served_for_other_content(monkeypatch):
    """`rim_points` keeps its answers by the pair's content, the region and the direction: a new
    sheet and box of the same content get the kept answer without bisecting again (and arrays of
    their own), a moved box or a changed CV (one ulp) a new answer equal to a fresh one, and at
    most `RIMS_KEPT` answers are kept."""
    import trimesh

    from acra import hspline as H
    from acra import shapes
    from pipeline import detect as D
    from pipeline.model import ColliderModel

    cvs, _, _ = shapes.sheet(12, 12, width=4.0, depth=4.0)
    hs = H.from_grid(cvs, depth=3)
    mesh = trimesh.creation.box(bounds=np.array([[-0.7, -0.9, -0.5], [0.9, 0.7, 0.5]]))
    static = geometry.prepare_collider(ColliderModel("/box", mesh.vertices, mesh.faces))
    down = np.array([0.0, 0.0, -1.0])

    def pair(surface=hs, dx=0.0):
        sheet = geometry.SurfaceGeometry(surface, np.eye(4), "/sheet")
        xform = np.eye(4)
        xform[0, 3] = dx
        box = geometry.ColliderGeometry(static, xform)
        return sheet, box, D.regions(sheet, box)[0].uv

    computed = []
    fresh = R._rim_points
    monkeypatch.setattr(R, "_rim_points", lambda *a: computed.append(1) or fresh(*a))
    R._RIMS.clear()
    sheet, box, uv = pair()
    first = R.rim_points(sheet, box, uv, down, 2)
    first[1][:] = np.nan  # the caller's arrays are its own
    again = R.rim_points(*pair(H.with_cvs(hs, hs.cvs.copy())), down, 2)
    assert len(computed) == 1 and len(again[0]) >= 12 and np.isfinite(again[1]).all()
    moved = R.rim_points(*pair(dx=0.25), down, 2)
    ulp = hs.cvs.copy()
    ulp[5, 5, 2] = np.nextafter(ulp[5, 5, 2], np.inf)
    changed = pair(H.with_cvs(hs, ulp))
    bumped = R.rim_points(*changed, down, 2)
    assert len(computed) == 3
    for got, want in ((moved, fresh(*pair(dx=0.25), down, 2)), (bumped, fresh(*changed, down, 2))):
        for a, b in zip(got, want):
            np.testing.assert_array_equal(a, b)
    assert not np.array_equal(moved[1], again[1])
    for k in range(2 * R.RIMS_KEPT):
        R.rim_points(*pair(dx=0.01 * (k + 1)), down, 2)
    assert len(R._RIMS) == R.RIMS_KEPT


@pytest.mark.parametrize("periodic", [False, True])
def test_missing_neighbours_are_those_scipys_kd_tree_finds(periodic):
    """`_missing_neighbours`: a sample's neighbour one step away is missing where scipy's kd-tree
    (``cKDTree.query`` with its distance bound, on the wrapped parameters) finds no sample within
    1e-3 of the step, the same rows and parameters in the same order: samples on patch grids of
    two densities with holes, across a periodic seam, plus samples a hair (5e-4 and 2e-3 of the
    step) off a grid point."""
    from acra import hspline as H
    from acra import shapes
    from pipeline.spatial import cKDTree

    hs = H.from_grid(*(shapes.sphere(8, 8) if periodic else shapes.sheet(8, 8)[:1]), depth=2)
    rng = np.random.default_rng(3)
    pu, pv = hs.u.patches0, hs.v.patches0
    grid = np.stack(np.meshgrid(np.arange(0, pu, 1 / 8), np.arange(0, pv, 1 / 8), indexing="ij"), -1).reshape(-1, 2)
    uv = grid[rng.random(len(grid)) < 0.7]
    uv = np.concatenate([uv, [[pu - 0.125, 1.0], [0.0, 1.0], [0.0, 2.0]], uv[:20] + [[5e-4 / 8, 0.0]],
                         uv[20:40] + [[0.0, 2e-3 / 8]]])
    h = np.where(uv[:, 0] < 2.0, 1 / 8, 1 / 16)
    miss, n = R._missing_neighbours(hs, uv, h)
    src, hi = np.tile(np.arange(len(uv)), 4)[miss.reshape(-1)], n[miss]
    tree, want_src, want_hi = cKDTree(geometry.wrap_uv(hs, uv)), [], []
    for du, dv in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        n = uv + np.stack([du * h, dv * h], axis=1)
        ok = np.ones(len(n), bool)
        for c, d in enumerate((hs.u, hs.v)):
            if not d.periodic:
                ok &= (n[:, c] >= -1e-9) & (n[:, c] <= d.patches0 + 1e-9)
        dist, _ = tree.query(geometry.wrap_uv(hs, n), distance_upper_bound=2e-3 * h.max())
        miss = ok & (dist > 1e-3 * h)
        want_src.append(np.nonzero(miss)[0])
        want_hi.append(n[miss])
    np.testing.assert_array_equal(src, np.concatenate(want_src))
    np.testing.assert_array_equal(hi, np.concatenate(want_hi))
    assert 0 < len(src) < 4 * len(uv)


def test_a_box_pushed_along_an_axis_counts_every_rim_crossing_as_its_faces_would():
    """`_on_counted_faces`: a box's faces are all steep to a push along one of its axes or facing
    it, so every crossing counts without its face being found, as finding each face says (points
    on every side and face of the box); pushed at a slant, the faces are found and the slanted ones
    do not count."""
    import trimesh

    from pipeline.model import ColliderModel

    mesh = trimesh.creation.box(bounds=np.array([[-0.7, -0.9, -0.5], [0.9, 0.7, 0.5]]))
    shift = np.eye(4)
    shift[:3, 3] = [0.1, -0.05, 0.3]
    box = geometry.ColliderGeometry(geometry.prepare_collider(ColliderModel("/box", mesh.vertices, mesh.faces)), shift)
    rng = np.random.default_rng(5)
    tri = mesh.triangles[rng.integers(0, len(mesh.faces), 300)]
    points = np.einsum("ij,ijk->ik", rng.dirichlet([1.0, 1.0, 1.0], 300), tri) + shift[:3, 3]
    asked = []

    def at():
        asked.append(1)
        return points

    def by_faces(unit):
        face = box.static.index.query(points - shift[:3, 3])[2]
        nd = np.abs(geometry.world_normals(box, box.static.mesh.face_normals[face]) @ unit)
        return (nd <= R.RIM_STEEP) | (nd >= R.RIM_FACING)

    for unit in (np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.0, 0.0])):
        got = R._on_counted_faces(box, unit, len(points), at)
        np.testing.assert_array_equal(got, by_faces(unit))
        assert got.all() and not asked
    slant = np.array([0.0, 0.6, -0.8])  # |n·d| 0.6 on the ±y faces: neither steep nor facing
    got = R._on_counted_faces(box, slant, len(points), at)
    np.testing.assert_array_equal(got, by_faces(slant))
    assert asked and 0 < got.sum() < len(points)


def _rim_points_every_row(ga, gb, region_uv, direction, level):
    """`rim._rim_points` as arrays over every row of the region, repeats included: each
    crossing bisected and each sample cast once per row."""
    from acra import hspline as H
    from acra.targets import patch_groups
    from pipeline import detect as D
    from pipeline.model import apply_xform

    hs = ga.surface
    unit = direction / np.linalg.norm(direction)
    dens = geometry.patch_density(ga)
    pu = np.clip(np.floor(region_uv[:, 0]).astype(np.int64) % hs.u.patches0, 0, hs.u.patches0 - 1)
    pv = np.clip(np.floor(region_uv[:, 1]).astype(np.int64) % hs.v.patches0, 0, hs.v.patches0 - 1)
    miss, n = R._missing_neighbours(hs, region_uv, 1.0 / dens[pu, pv])
    src, hi = np.tile(np.arange(len(region_uv)), 4)[miss.reshape(-1)], n[miss]

    def world(uv):
        return apply_xform(ga.xform, H.evaluate(hs, *geometry.wrap_uv(hs, uv).T, det=ga.details).points)

    outside = ~D.inside(gb, world(hi))
    src, hi = src[outside], hi[outside]
    lo = region_uv[src]
    step = hi - lo
    for _ in range(R.RIM_BISECT):
        mid = 0.5 * (lo + hi)
        m_in = D.inside(gb, world(mid))[:, None]
        lo, hi = np.where(m_in, mid, lo), np.where(m_in, hi, mid)
    use = R._on_counted_faces(gb, unit, len(hi), lambda: world(hi))
    s_hit, hit = D.cast(gb, world(region_uv[src[use]]), np.broadcast_to(unit, (int(use.sum()), 3)))
    cross = geometry.wrap_uv(hs, (hi + step)[use][hit])
    mids, _, inv = patch_groups(hs, cross, level)
    g = len(mids)
    plane = np.stack([np.bincount(inv, s_hit[hit, c], g) for c in range(3)], axis=1)
    plane /= np.bincount(inv, minlength=g)[:, None]
    points = world(mids)
    ahead = (plane - points) @ unit
    keep = ahead > 0
    return mids[keep], points[keep], points[keep] + ahead[keep, None] * unit


@pytest.mark.parametrize("direction,turn", [((0.0, 0.0, -0.8), 0.0), ((0.1, -0.05, -1.0), 0.3)])
def test_rim_points_ask_each_distinct_crossing_once_with_every_rows_bits(monkeypatch, direction, turn):
    """`_rim_points` bisects each distinct sample's crossings and casts each sample once, every
    region row taking its sample's: the same bits as the arrays over every row
    (`_rim_points_every_row`) on a region whose samples on shared patch edges come twice, for
    fewer points asked; pushed along the box's axis and at a slant to a turned box (whose faces
    are found for each crossing)."""
    import trimesh

    from acra import hspline as H
    from acra import shapes
    from pipeline import detect as D
    from pipeline.model import ColliderModel

    cvs, _, _ = shapes.sheet(12, 12, width=4.0, depth=4.0)
    sheet = geometry.SurfaceGeometry(H.from_grid(cvs, depth=3), np.eye(4), "/sheet")
    mesh = trimesh.creation.box(bounds=np.array([[-0.7, -0.9, -0.5], [0.9, 0.7, 0.5]]))
    xform = trimesh.transformations.rotation_matrix(turn, [0.2, 0.3, 1.0])
    box = geometry.ColliderGeometry(geometry.prepare_collider(ColliderModel("/box", mesh.vertices, mesh.faces)), xform)
    region, _ = D.regions(sheet, box)
    uv = np.concatenate([region.uv, region.uv[::3]])  # samples given twice
    down = np.array(direction)
    asked, inside = [], D.inside
    monkeypatch.setattr(D, "inside", lambda g, p: asked.append(len(p)) or inside(g, p))
    got = R._rim_points(sheet, box, uv, down, 2)
    once = sum(asked)
    asked.clear()
    want = _rim_points_every_row(sheet, box, uv, down, 2)
    assert len(got[0]) >= 12 and once < sum(asked)
    for a, b in zip(got, want):
        assert a.tobytes() == b.tobytes()


def _bisected_in_turn(gb, world, lo, hi):
    """`_bisected` as the array form: `detect.inside` of the neighbours, then of each halving's
    midpoints in turn."""
    from pipeline import detect as D

    outside = ~D.inside(gb, world(hi))
    lo, hi = lo[outside], hi[outside]
    for _ in range(R.RIM_BISECT):
        mid = 0.5 * (lo + hi)
        m_in = D.inside(gb, world(mid))[:, None]
        lo, hi = np.where(m_in, mid, lo), np.where(m_in, hi, mid)
    return outside, hi


@pytest.mark.parametrize("paths,seed", [(R.RIM_PATHS, 0), (R.RIM_PATHS, 1), (0, 2)])
def test_bisected_asks_the_parity_once_with_the_answers_of_asking_in_turn(monkeypatch, paths, seed):
    """`_bisected` follows a segment whose point lies near the box's surface both ways and asks
    every near point's parity at the end: the same outside rows and crossings, bit for bit, as
    asking `detect.inside` in turn, for one parity call instead of one a round. Segments across
    the box's faces, edges and corners in the plane ``z = 0.1`` (the parameters are the points'
    x and y), their midpoints on a face, a rounding error or 1e-7 of the size off it at one
    halving or another, some neighbours inside or near; with no path to spare (``RIM_PATHS``
    0) each round asks its near points at once."""
    import trimesh

    from pipeline import detect as D
    from pipeline.model import ColliderModel

    monkeypatch.setattr(R, "RIM_PATHS", paths)
    mesh = trimesh.creation.box(bounds=np.array([[-0.5, -0.25, -0.5], [0.5, 0.75, 0.5]]))
    shift = np.eye(4)
    shift[:3, 3] = [0.125, -0.0625, 0.0]
    box = geometry.ColliderGeometry(geometry.prepare_collider(ColliderModel("/box", mesh.vertices, mesh.faces)), shift)
    rng = np.random.default_rng(seed)
    size = box.static.scale
    face = np.array([[0.625, 0.0], [-0.375, 0.0], [0.0, 0.6875], [0.0, -0.3125]])  # x = 0.625 (+x face), ...
    n = 400
    which = rng.integers(0, 4, n)
    along = rng.uniform(-0.3, 0.6, n)
    step = 2.0 ** -rng.integers(2, 6, n)
    # the face crossed at a halving's midpoint: lo and hi placed so that midpoint k lies on it
    k = rng.integers(0, R.RIM_BISECT + 1, n)
    off = rng.choice([0.0, 1e-16, 1e-7 * size, -1e-7 * size, 3e-3], n)
    lo, hi = np.empty((n, 2)), np.empty((n, 2))
    for i in range(n):
        axis, sign = (0 if which[i] < 2 else 1), (1.0 if which[i] in (0, 2) else -1.0)
        at = face[which[i], axis] + off[i]
        t = 1.0 - 2.0 ** -k[i]  # the k-th midpoint of [0, 1] always halving towards its outer end
        a = at - sign * t * step[i]
        lo[i, axis], hi[i, axis] = a, a + sign * step[i]
        lo[i, 1 - axis] = hi[i, 1 - axis] = along[i]
    lo[:20] = [0.125, 0.1875] + rng.uniform(-0.2, 0.2, (20, 2))  # neighbours inside
    hi[:20] = lo[:20] + rng.uniform(-0.05, 0.05, (20, 2))

    def world(uv):
        return np.column_stack([uv, np.full(len(uv), 0.1)])

    calls, parity = [], D._parity
    monkeypatch.setattr(D, "_parity", lambda s, p: calls.append(len(p)) or parity(s, p))
    got = R._bisected(box, world, lo, hi)
    ours = len(calls)
    calls.clear()
    want = _bisected_in_turn(box, world, lo, hi)
    assert got[0].tobytes() == want[0].tobytes() and got[1].tobytes() == want[1].tobytes()
    assert 0 < got[0].sum() < n - 20 + 1 and sum(calls) > 20  # near points at several halvings
    assert (ours == 1 if paths else ours == len(calls)) and len(calls) > 3
