"""Triangle-mesh helpers in trimesh's arithmetic, without importing trimesh.

`acra run` needs only a few of trimesh's operations on the demo's path: for the ray casts of
`pipeline.queries`, the merged mesh, its face normals and size, and the line-plane hit of a ray on
the triangle embree reports (the closest points' barycentric coordinates are trimesh's Cramer rule
compiled, `acra.nearest.face_uv`). Importing trimesh costs about 0.25 s on top of scipy (it pulls
in networkx) and builds a tracked, cached `Trimesh` per mesh; these are the same numpy expressions
in the same order as trimesh 5.2's (``grouping.merge_vertices``, ``Trimesh.face_normals``,
``Parent.scale``, ``util.unitize``, ``intersections.planes_lines``), so each result is the same
bits as trimesh's (tests/test_meshops.py holds them to it). Arrays are float64 unless stated.
"""

from __future__ import annotations

import numpy as np

__all__ = ["TOL_ZERO", "MERGE_DIGITS", "merge_keys", "merge_vertices", "face_normals", "scale", "unitize", "planes_lines"]

TOL_ZERO = float(np.finfo(np.float64).resolution * 100)  # trimesh.util.TOL_ZERO: a zero vector's norm
MERGE_DIGITS = 8  # trimesh.util.decimal_to_digits(tol.merge = 1e-8): vertices equal to 1e-8 are merged
_ONES = [1.0, 1.0, 1.0]  # trimesh's row dot is ``np.dot(a * b, [1.0] * 3)``: BLAS sums in its own order


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row dot products of ``a, b (n, 3)`` (trimesh.util.diagonal_dot)."""
    return np.dot(a * b, _ONES)


def merge_keys(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What a vertex merge groups by: which of ``vertices (n, 3) float64`` the ``faces (f, 3)
    int64`` reference ``(n,) bool`` (all of them when there are no faces, as trimesh keeps an
    unreferenced cloud) and each row rounded to multiples of ``10 ** -MERGE_DIGITS``
    ``(n, 3) int64``, C-contiguous. Two referenced vertices merge exactly when their keys are
    equal."""
    referenced = np.zeros(len(vertices), dtype=bool)
    if len(faces):
        referenced[faces] = True
    else:
        referenced[:] = True
    keys = np.ascontiguousarray((vertices * (10 ** MERGE_DIGITS)).round().astype(np.int64))
    return referenced, keys


def merge_vertices(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``Trimesh(vertices, faces, process=False).merge_vertices()``: the referenced vertices
    whose coordinates round to the same multiples of 1e-8 become one, the first in vertex
    order, kept in order of first appearance; unreferenced vertices are dropped. Returns the
    vertices ``(m, 3)`` and the faces ``(f, 3) int64`` renumbered."""
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    if not len(vertices):
        return vertices, faces
    referenced, keys = merge_keys(vertices, faces)
    rows = np.ascontiguousarray(keys[referenced])
    # group equal integer rows: which rows are equal, not how they are hashed, fixes the answer
    key = rows.view(np.dtype((np.void, rows.itemsize * 3))).reshape(-1)
    _, index, inverse = np.unique(key, return_index=True, return_inverse=True)
    order = index.argsort()  # first appearances in vertex order (trimesh.grouping.unique_ordered)
    inverse_all = np.zeros(len(vertices), dtype=np.int64)
    inverse_all[referenced] = order.argsort()[inverse.reshape(-1)]
    mask = np.nonzero(referenced)[0][index[order]]
    return vertices[mask], inverse_all[faces.reshape(-1)].reshape((-1, 3))


def unitize(vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit rows of ``vectors (n, 3)`` and which rows were longer than `TOL_ZERO` ``(n,) bool``;
    shorter rows are returned unchanged (trimesh.util.unitize)."""
    vectors = np.asanyarray(vectors)
    norm = np.sqrt(np.dot(vectors * vectors, _ONES))
    valid = norm > TOL_ZERO
    norm[valid] **= -1
    return vectors * norm.reshape((-1, 1)), valid


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit normals ``(f, 3)`` of the faces, zero for a face of no area (Trimesh.face_normals)."""
    tri = vertices[faces]
    vectors = tri[:, 1:, :] - tri[:, :2, :]
    unit, valid = unitize(np.cross(vectors[:, 0], vectors[:, 1]))
    if valid.all():
        return unit
    padded = np.zeros((len(tri), 3), dtype=np.float64)
    padded[valid] = unit[valid]
    return padded


def scale(vertices: np.ndarray, box: np.ndarray | None = None) -> float:
    """The diagonal of the referenced vertices' box, 1 if below trimesh's zero (Parent.scale);
    ``vertices (n, 3)`` all referenced, as `merge_vertices` leaves them. ``box (2, 3)``: their
    ``min(axis=0)`` and ``max(axis=0)`` where the caller has them (`acra.bvh.bounds` finds both in
    one pass, where numpy's reductions over a short last axis go row by row)."""
    if not len(vertices):
        return 1.0
    if box is None:
        box = np.array([vertices.min(axis=0), vertices.max(axis=0)])
    extents = np.ptp(box, axis=0)
    size = float((extents**2).sum() ** 0.5)
    return 1.0 if size < 1e-13 else size


def planes_lines(plane_origins: np.ndarray, plane_normals: np.ndarray, line_origins: np.ndarray,
                 line_directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where lines meet planes ``(m, 3)``, for the ``valid (n,) bool`` lines not parallel to
    their plane (trimesh.intersections.planes_lines)."""
    origin_vectors = plane_origins - line_origins
    projection_ori = _dot(origin_vectors, plane_normals)
    projection_dir = _dot(line_directions, plane_normals)
    valid = np.abs(projection_dir) > 1e-5
    distance = np.divide(projection_ori[valid], projection_dir[valid])
    on_plane = line_directions[valid] * distance.reshape((-1, 1))
    on_plane += line_origins[valid]
    return on_plane, valid
