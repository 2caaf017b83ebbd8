"""`pipeline.queries`: the merged mesh a cast builds over the patches its rays meet."""

import numpy as np
import pytest

from acra import hspline as H
from acra import shapes
from pipeline import queries
from pipeline import shape as S
from pipeline.grids import PatchGrid


def _reference(grids: list[PatchGrid]) -> queries.RayMesh:
    """The mesh of ``grids`` one grid at a time: each grid's solid triangles moved past the points
    of the grids before it."""
    base = np.cumsum([0] + [len(g.points) for g in grids[:-1]])
    return queries.RayMesh(np.concatenate([g.points for g in grids]),
                           np.concatenate([g.triangles[g.solid] + b for g, b in zip(grids, base)]))


def _same(mesh: queries.RayMesh, want: queries.RayMesh) -> None:
    for got, ref in ((mesh.vertices, want.vertices), (mesh.faces, want.faces)):
        assert got.dtype == ref.dtype and got.shape == ref.shape
        assert got.tobytes() == ref.tobytes()
    assert mesh.scale == want.scale


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("kind", ["torus", "sphere"])
def test_ray_mesh_is_each_grids_solid_triangles_one_after_another(kind, seed):
    """`queries._ray_mesh` gives the mesh of its grids taken one at a time, bit for bit: a torus's
    grids (one density, every triangle solid: one sum over the shared triangles) and a sphere's
    with its pole grids among them (their slivers dropped, the lists joined and moved by one sum)."""
    hs = H.from_grid(*shapes.torus(12, 8), depth=2) if kind == "torus" else H.from_grid(*shapes.sphere(10, 15), depth=2)
    shape = S.Shape(hs)
    patches = shape._boxes[2]
    rng = np.random.default_rng(seed)
    hit = np.unique(np.concatenate([[0], rng.choice(len(patches), size=int(rng.integers(1, 12)), replace=False)])).astype(np.int64)
    shape.ray_meshes.clear()
    mesh = queries._ray_mesh(shape, patches, hit)
    grids = shape.grids_for(patches[hit])
    shared = all(g.triangles is grids[0].triangles and len(g.solid) == len(g.triangles) for g in grids)
    assert shared == (kind == "torus")
    _same(mesh, _reference(grids))


def test_ray_mesh_of_grids_of_different_densities():
    """Grids of different densities (their own triangle lists, some rows not solid) give the
    mesh of the grids taken one at a time."""
    rng = np.random.default_rng(3)
    grids = []
    for p, n in enumerate((5, 3, 9, 4)):
        u, v = np.meshgrid(np.linspace(p, p + 1, n), np.linspace(0, 1, n), indexing="ij")
        pts = np.stack([u, v, 0.1 * np.sin(3 * u + v)], -1).reshape(-1, 3)
        idx = np.arange(n * n).reshape(n, n)
        a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
        tri = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)
        grids.append(PatchGrid(pts, pts[:, :2].copy(), tri, np.flatnonzero(rng.random(len(tri)) > 0.2)))

    class Stub:
        ray_meshes: dict = {}

        def grids_for(self, patches):
            return [grids[i] for i in patches[:, 0]]

    patches = np.stack([np.arange(4), np.zeros(4, np.int64)], 1)
    _same(queries._ray_mesh(Stub(), patches, np.arange(4)), _reference(grids))


def test_grid_faces_gather_only_the_grids_that_drop_rows():
    """Three grids of 4 points sharing two triangles, the middle one dropping its first: its one
    solid row moved by 4, the last grid's two rows by 8, the first grid's as they are."""
    tri = np.array([[0, 1, 2], [0, 2, 3]], np.int64)
    pts = np.zeros((4, 3))
    grids = [PatchGrid(pts, pts[:, :2], tri, np.arange(2)), PatchGrid(pts, pts[:, :2], tri, np.array([1])),
             PatchGrid(pts, pts[:, :2], tri, np.arange(2))]
    faces = queries._grid_faces(grids)
    assert faces.dtype == np.int64
    assert faces.tolist() == [[0, 1, 2], [0, 2, 3], [4, 6, 7], [8, 9, 10], [8, 10, 11]]
    assert tri.tolist() == [[0, 1, 2], [0, 2, 3]]  # the shared list is left as it is
