"""`acra.clearcells`: triangles proven clear of a closed mesh by a flooded grid of cells."""

import numpy as np

from acra import depthbound
from acra import hspline as H
from acra import shapes
from acra.clearcells import clear_of
from acra.tessellate import grid_samples, run_topology
from pipeline import residual


def _ball_display():
    """A closed unit ball's display (`residual.Shown`), in its object space."""
    ball = H.from_grid(*shapes.sphere(10, 8))
    topo = run_topology([ball], 4)
    return residual.shown("/ball", grid_samples(ball, topo)[0], topo.triangles(), np.eye(4), None, closed=True, outward=1.0)


def test_triangles_clear_of_a_solid_are_those_outside_by_more_than_their_covering_radius():
    """`clear_of` on a closed ball's display: a triangle far outside is clear; one outside
    but nearer the surface than its covering radius, one crossing the surface and one deep
    inside (no face near it: its cells are not joined to the outside) are kept, and the faces
    chosen hold every face whose box comes within the reach of a kept triangle's."""
    b = _ball_display()
    r = float(b.box[1, 2])  # the ball's top
    tri = np.array([[0.0, 0.0, 0.0], [0.02, 0.0, 0.0], [0.0, 0.02, 0.0]])  # rho 0.01 (right-angled)
    cases = {"far": tri + [0.0, 0.0, r + 0.3], "near": tri + [0.0, 0.0, r + 0.005], "across": tri * 5 + [0.0, 0.0, r - 0.02]}
    corners = np.stack(list(cases.values()))
    rho = depthbound.covering_radii(corners)
    keep, chosen, reach = clear_of(b.local, b.triangles, corners, rho, 0.0, 0.05, b.box_local)
    assert dict(zip(cases, keep.tolist())) == {"far": False, "near": True, "across": True}
    deep = np.concatenate([corners, tri[None]])  # the ball's centre: kept, and deeper than a part near it reaches
    assert clear_of(b.local, b.triangles, deep, depthbound.covering_radii(deep), 0.0, 0.05, b.box_local) is None
    assert reach >= 0.05
    box_lo, box_hi = corners[keep].min(axis=1), corners[keep].max(axis=1)
    tri_b = b.local[b.triangles]
    near = np.zeros(len(tri_b), bool)
    for lo, hi in zip(box_lo, box_hi):
        near |= np.all((tri_b.min(axis=1) <= hi + reach) & (tri_b.max(axis=1) >= lo - reach), axis=1)
    assert np.isin(np.nonzero(near)[0], chosen).all() and len(chosen) < len(tri_b)


def _reference_cells(points, faces, rows, tri, rho, slack, reach, origin, h, dims, box):
    """`acra.clearcells._clear_cells` in numpy and scipy's labelling: the touched cells counted
    face by face, the outside as the components of untouched cells (sharing sides) holding a
    cell beyond the box, then each triangle's test and the wanted cells. Returns ``(m, keep
    (t,) bool, chosen (m,) int64)``, ``m = -1`` where the grid cannot answer."""
    from scipy import ndimage

    cell = lambda x, k: np.floor((x - origin[k]) / h).astype(np.int64)  # noqa: E731
    n = [int(d) for d in dims]
    corner = points[faces[rows]]  # (r, 3, 3)
    flo = np.stack([np.maximum(cell(corner[:, :, k].min(axis=1) - slack, k), 0) for k in range(3)], axis=1)
    fhi = np.stack([np.minimum(cell(corner[:, :, k].max(axis=1) + slack, k), n[k] - 1) for k in range(3)], axis=1)
    touch = np.zeros(n, np.int64)
    for lo, hi in zip(flo, fhi):
        if (lo <= hi).all():
            touch[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1] += 1
    bl = [int(cell(box[0][k], k)) for k in range(3)]
    bh = [int(cell(box[1][k], k)) for k in range(3)]
    i, j, q = np.indices(n)
    beyond = (i < bl[0]) | (i > bh[0]) | (j < bl[1]) | (j > bh[1]) | (q < bl[2]) | (q > bh[2])
    labels, _ = ndimage.label(touch == 0)  # sides shared: scipy's default structure in 3-d
    out = np.isin(labels, np.unique(labels[(touch == 0) & beyond])) & (touch == 0)
    near_touch = ndimage.maximum_filter(touch > 0, size=3, mode="constant", cval=False)
    want = np.zeros(n, bool)
    keep = np.zeros(len(tri), bool)
    wide = reach * (1.0 + 1e-9) + slack
    for t in range(len(tri)):
        a, b = tri[t].min(axis=0), tri[t].max(axis=0)
        pad = rho[t] * (1.0 + 1e-9) + slack
        lo, hi = [cell(a[k] - pad, k) for k in range(3)], [cell(b[k] + pad, k) for k in range(3)]
        inside = all(0 <= lo[k] and hi[k] < n[k] for k in range(3))
        if inside and out[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1].all():
            continue
        keep[t] = True
        lo = [max(cell(a[k], k), 0) for k in range(3)]
        hi = [min(cell(b[k], k), n[k] - 1) for k in range(3)]
        s = np.s_[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1]
        if (~out[s] & (touch[s] == 0) & ~near_touch[s]).any():
            return -1, keep, None
        lo, hi = [cell(a[k] - wide, k) for k in range(3)], [cell(b[k] + wide, k) for k in range(3)]
        if any(lo[k] < 0 or hi[k] >= n[k] for k in range(3)):
            return -1, keep, None
        want[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1] = True
    chosen = [r for r, lo, hi in zip(rows, flo, fhi)
              if (lo <= hi).all() and want[lo[0]:hi[0] + 1, lo[1]:hi[1] + 1, lo[2]:hi[2] + 1].any()]
    return len(chosen), keep, np.array(chosen, np.int64)


def test_the_compiled_cells_are_the_reference_cells_on_random_triangles_and_boxes():
    """`_clear_cells` against `_reference_cells` on a ball's display, seeded random triangles
    around its surface and random boxes of the solid (within, across and beyond the grid, a
    face's box clipped at its sides): the same triangles kept, the same faces chosen, the same
    refusals."""
    from acra.clearcells import _clear_cells
    from acra.meshrows import _read_only

    b = _ball_display()
    rng = np.random.default_rng(47)
    seen = set()
    for case in range(60):
        centre = rng.normal(size=3)
        centre *= rng.uniform(0.5, 1.3) / np.linalg.norm(centre)
        m = int(rng.integers(1, 40))
        tri = centre + rng.uniform(-0.15, 0.15, (m, 1, 3)) + rng.uniform(-0.02, 0.02, (m, 3, 3))
        rho = depthbound.covering_radii(tri)
        slack, reach, cells = float(rng.choice([0.0, 1e-6, 0.01])), float(rng.uniform(0.0, 0.1)), int(rng.integers(8, 30))
        margin = reach + float(rho.max()) * (1.0 + 1e-9) + slack
        lo, hi = tri.reshape(-1, 3).min(axis=0), tri.reshape(-1, 3).max(axis=0)
        h = float((hi - lo).max() + 2.0 * margin) / (cells - 6)
        origin = lo - margin - h
        dims = np.maximum(np.ceil((hi + margin + h - origin) / h).astype(np.int64) + 1, 1)
        box = b.box_local + rng.uniform(-0.3, 0.3, (2, 3)) * (case % 3 != 0)
        rows = np.arange(len(b.triangles), dtype=np.int64)[rng.random(len(b.triangles)) < (0.7 if case % 4 else 1.0)]
        keep, chosen = np.empty(m, np.bool_), np.empty(len(rows), np.int64)
        got = _clear_cells(b.local, _read_only(b.triangles), rows, tri, rho, slack, reach + 2 * h, origin, h, dims,
                           box[0].copy(), box[1].copy(), keep, chosen)
        want, want_keep, want_chosen = _reference_cells(b.local, b.triangles, rows, tri, rho, slack, reach + 2 * h,
                                                        origin, h, dims, box)
        assert got == want
        if got >= 0:
            assert np.array_equal(keep, want_keep) and np.array_equal(chosen[:got], want_chosen)
            seen.add((bool(keep.any()), bool((~keep).any())))
        else:
            seen.add("refused")
    assert seen >= {(True, True), "refused"}  # kept and clear triangles in one call, and refusals
