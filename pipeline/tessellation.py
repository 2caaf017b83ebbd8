"""World tessellations of level-0 patch sets: the collision grids detection meets (notes §4).

A pair's narrow phase, its interpenetration regions and its touch tests ask for the grids of a
set of level-0 patches (`pipeline.detect`): each patch's grid is the object-space `PatchGrid` of
its `pipeline.shape.Shape`, mapped by the geometry's matrix and kept in the content's world data
(`pipeline.geometry._World`), so every set asked of one content takes the same bits of a patch
(a matrix product's rounding may depend on its batch). A set's layout (parameters, triangles,
their patches) and its distinct vertex rows depend on the patches, their densities and the
domain alone, not on the surface's shape, and the last few are kept across rounds and frames.
The display's tessellation is `acra.tessellate`'s. World units; arrays are float64 unless stated.
"""

from __future__ import annotations

import numpy as np

from acra import memo, narrow
from pipeline.geometry import Geometry, SurfaceGeometry, Tessellation, _World, candidate_patches, wrap_uv
from pipeline.grids import PatchGrid
from pipeline.model import apply_xform

__all__ = ["unique_patches", "unique_rows", "tessellate", "tessellate_sorted", "tessellated", "distinct", "vertices_in_box"]


def unique_patches(patches: np.ndarray) -> np.ndarray:
    """The distinct rows of level-0 ``patches (m, 2) int64`` (non-negative), ascending as
    ``np.unique(axis=0)`` gives them: one integer key a row instead of its structured sort."""
    patches = np.asarray(patches, np.int64).reshape(-1, 2)
    if not len(patches):
        return patches
    width = int(patches[:, 1].max()) + 1
    key = np.unique(patches[:, 0] * width + patches[:, 1])
    return np.stack([key // width, key % width], axis=1)


def unique_rows(x: np.ndarray) -> np.ndarray:
    """Rows ``(u,) int64`` of the first of each distinct row of ``x (n, 2) float64``, in the order
    of the distinct rows (the first column, then the second): ``np.unique(x, axis=0,
    return_index=True)[1]``, from a stable sort of the two columns instead of a structured one."""
    if not len(x):
        return np.zeros(0, np.int64)
    order = np.lexsort((x[:, 1], x[:, 0]))
    s = x[order]
    return order[np.r_[True, (s[1:, 0] != s[:-1, 0]) | (s[1:, 1] != s[:-1, 1])]]


def tessellate(geom: SurfaceGeometry, patches: np.ndarray) -> Tessellation:
    """Collision grids over level-0 ``patches (m, 2) int64`` at their `patch_density`, cached per
    patch on ``geom`` (grids of different density meet at T-junctions, gaps ~ tessellation error);
    the last few patch sets' tessellations are kept too (the narrow phase, the regions and the
    on-surface search of a round ask for the same sets)."""
    return tessellate_sorted(geom, unique_patches(patches))


def tessellate_sorted(geom: SurfaceGeometry, patches: np.ndarray) -> Tessellation:
    """`tessellate` of distinct ascending ``patches (m, 2) int64`` (`candidate_patches` and its
    row subsets are), without sorting them again."""
    if not len(patches):
        return Tessellation(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 3), np.int64), np.zeros((0, 2), np.int64))
    key = patches.tobytes()
    geom._asked.setdefault(key, patches)
    kept = geom._world.tessellations
    hit = kept.pop(key, None)
    if hit is None:
        hit = _tessellation(geom, patches)
    kept[key] = hit
    while len(kept) > 8:
        del kept[next(iter(kept))]
    return hit


def _tessellation(geom: SurfaceGeometry, patches: np.ndarray) -> Tessellation:
    world = geom._world
    if not world.grids and world.mapped is None:
        # a new content's first set (each step of a rewinding search): its grids' points mapped
        # in one product, each grid's rows split off only if another set of this content asks
        obj, grids = geom.shape.cache.set_points(patches)
        world.mapped = (patches, apply_xform(geom.xform, obj), grids)
        uv, triangles, tri_patch = _LAYOUTS.kept(_patch_set_key(geom, patches), lambda: _layout(patches, grids))
        return Tessellation(world.mapped[1], uv, triangles, tri_patch)
    if world.mapped is not None:
        _split_mapped(world)
    cache = world.grids
    keys = list(map(tuple, patches.tolist()))
    todo = [k for k in keys if k not in cache]
    points = None
    if todo:
        whole = len(todo) == len(keys)  # a new content's first set: every grid is mapped here
        obj = geom.shape.grids_for(patches if whole else np.array(todo, np.int64))
        # one product over the missing grids; a grid's rows are then kept, so whichever set asks
        # for the patch later gets these bits (a product's rounding may depend on its batch)
        mapped = apply_xform(geom.xform, np.concatenate([g.points for g in obj]))
        end = 0
        for p, g in zip(todo, obj):
            start, end = end, end + len(g.points)
            cache[p] = (mapped[start:end], g.uv, g.triangles)
        if whole:  # the set's points, in its order, already
            points = mapped
    grids = [cache[k] for k in keys]
    # a grid's parameters and triangles are its patch's and density's alone
    # (`acra.tessellate.patch_grids`): only the points are the surface's
    uv, triangles, tri_patch = _LAYOUTS.kept(_patch_set_key(geom, patches),
                                             lambda: _layout(patches, [PatchGrid(*g, None) for g in grids]))
    return Tessellation(np.concatenate([g[0] for g in grids]) if points is None else points, uv, triangles, tri_patch)


def _layout(patches: np.ndarray, grids: list[PatchGrid]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Parameters ``(n, 2)``, triangles ``(f, 3) int64`` and their patches ``(f, 2) int64`` of
    the grids of ``patches (m, 2) int64`` one after the other."""
    points = np.array([len(g.points) for g in grids])
    faces = np.array([len(g.triangles) for g in grids])
    triangles = np.concatenate([g.triangles for g in grids])
    triangles += np.repeat(np.cumsum(points) - points, faces)[:, None]  # each grid's rows after the ones before
    return np.concatenate([g.uv for g in grids]), triangles, np.repeat(patches, faces, axis=0)


def _split_mapped(world: _World) -> None:
    """Each grid's rows of the set a content mapped first (`_World.mapped`) into its per-patch
    grids, so the sets asked later take those bits (a product's rounding may depend on its batch)."""
    patches, points, grids = world.mapped
    end = 0
    for p, g in zip(map(tuple, patches.tolist()), grids):
        start, end = end, end + len(g.points)
        world.grids[p] = (points[start:end], g.uv, g.triangles)
    world.mapped = None


# a patch set's layout and distinct parameters, the 8 most recent kept: a whole-surface set of a
# large model holds megabytes, and `dog_head_spike`'s 30 frames ask for 5 sets
_LAYOUTS = memo.Table("tessellation.layouts", 8)  # `_tessellation`'s parameters, triangles and their patches, most recent last
_DISTINCT = memo.Table("tessellation.distinct", 8)  # `distinct`'s answers, most recent last


def _patch_set_key(geom: SurfaceGeometry, patches: np.ndarray) -> tuple:
    """What a tessellation's layout depends on: distinct ascending level-0 ``patches (m, 2)``,
    their densities and the domain (its wrapping)."""
    u, v = geom.surface.u, geom.surface.v
    return (patches.tobytes(), geom.shape.density_map[patches[:, 0], patches[:, 1]].tobytes(),
            u.periodic, u.patches0, v.periodic, v.patches0)


def tessellated(geom: SurfaceGeometry) -> np.ndarray:
    """Level-0 patches ``(m, 2) int64`` tessellated so far for ``geom`` (broad-phase audit; their
    grids may have been built for an earlier geometry of the same content, `_World`)."""
    if not geom._asked:
        return np.zeros((0, 2), np.int64)
    return unique_patches(np.concatenate(list(geom._asked.values())))


def distinct(geom: SurfaceGeometry, patches: np.ndarray, tess: Tessellation) -> np.ndarray:
    """``unique_rows(wrap_uv(geom.surface, tess.uv))`` for ``tess = tessellate(geom, patches)``
    (``patches`` distinct and ascending): the first row of each distinct vertex. A grid's
    parameters are its patch's and density's alone (`acra.tessellate.patch_grids`), so the
    answer is one of the patch set, the patches' densities and the domain's wrapping, whatever
    the surface's shape: the rounds and frames of a contact ask for the same set again (25 of
    28 times over `dog_head_spike`'s frames 13-17), and the last few answers are kept."""
    return _DISTINCT.kept(_patch_set_key(geom, patches), lambda: unique_rows(wrap_uv(geom.surface, tess.uv)))


def vertices_in_box(geom: Geometry, bounds: np.ndarray, pad: float) -> tuple[np.ndarray, np.ndarray | None]:
    """Distinct tessellation vertices of ``geom`` within ``bounds (2, 3)`` widened by ``pad``:
    world ``(k, 3)``, and their parameters ``(k, 2)`` on a deformable, ``None`` on a collider (its
    mesh's vertices): the candidates of a region or a touch test (`pipeline.detect.regions`)."""
    lo, hi = bounds[0] - pad, bounds[1] + pad
    if isinstance(geom, SurfaceGeometry):
        # the distinct vertices within the padded box, gathered in one compiled pass
        # (`acra.narrow.rows_in_box`): most of the candidate patches' vertices lie outside it
        patches = candidate_patches(geom, bounds, pad)
        tess = tessellate_sorted(geom, patches)
        return narrow.rows_in_box(tess.points, tess.uv, distinct(geom, patches, tess), lo, hi)
    # a collider: the vertices of the faces near the box, in order
    used = np.unique(geom.static.mesh.faces[geom.static.faces_near(geom.xform, np.stack([lo, hi]))])
    pts = apply_xform(geom.xform, geom.static.mesh.vertices[used])
    keep = (pts >= lo) & (pts <= hi)
    keep = keep[:, 0] & keep[:, 1] & keep[:, 2]  # `np.all(axis=1)`, without its row-by-row reduction
    return pts[keep], None
