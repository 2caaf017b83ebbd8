"""Render one frame of an ACRA output layer to a PNG, headlessly (matplotlib), for docs and reviews.

    python -m pipeline.snapshot scenes/dog_head_spike.acra.usda -o docs/img/dog_head_spike.png

Without ``--frame`` the deepest collision frame is chosen: the frame in collision where the response
moved a display vertex farthest from the animator's input. Deformables are drawn with flat Lambert
shading, coloured by how far the response moved each face (grey: untouched, orange: moved most);
colliders are drawn in blue-grey. World transforms come from USD at that frame.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from pxr import Usd, UsdGeom, UsdPhysics

from pipeline import output_layer

__all__ = ["World", "world_meshes", "deepest_frame", "render", "main"]


class World:
    """One mesh in world space: ``points (n, 3)``, ``triangles (f, 3) int64``, per-vertex
    ``moved (n,)`` (response displacement, 0 for colliders) and ``deformable``."""

    def __init__(self, path: str, points: np.ndarray, triangles: np.ndarray, moved: np.ndarray, deformable: bool):
        self.path, self.points, self.triangles, self.moved, self.deformable = path, points, triangles, moved, deformable


def _triangles(mesh: UsdGeom.Mesh) -> np.ndarray:
    """The mesh's faces as fans ``(f, 3) int64``: a face of ``c`` corners starting at index ``s``
    gives triangles ``(s, s+1+j, s+2+j)`` for ``j < c - 2``, in face order."""
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(), np.int64)
    idx = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), np.int64)
    fans = np.maximum(counts - 2, 0)
    starts = np.repeat(np.cumsum(counts) - counts, fans)  # each triangle's face start
    j = np.arange(fans.sum()) - np.repeat(np.cumsum(fans) - fans, fans)  # its place in the fan
    return np.stack([idx[starts], idx[starts + 1 + j], idx[starts + 2 + j]], axis=1)


def world_meshes(output: "Path | Usd.Stage", frame: float) -> list[World]:
    """Every deformable (``acra:cvs``) and collider (``PhysicsCollisionAPI``) Mesh at ``frame``;
    ``output`` is the output layer's path or its stage, opened once for many frames."""
    out = output if isinstance(output, Usd.Stage) else Usd.Stage.Open(str(output))
    tc, meshes = Usd.TimeCode(frame), []
    for prim in out.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        deformable = prim.HasAttribute("acra:cvs")
        if not deformable and not prim.HasAPI(UsdPhysics.CollisionAPI):
            continue
        mesh = UsdGeom.Mesh(prim)
        local = np.asarray(mesh.GetPointsAttr().Get(tc), np.float64)
        m = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(tc), np.float64).T  # column convention
        world = local @ m[:3, :3].T + m[:3, 3]
        moved = np.zeros(len(local))
        if deformable:  # the animator's surface at the same display vertices (`output_layer.input_points`)
            moved = np.linalg.norm(local - output_layer.input_points(out, str(prim.GetPath()), frame), axis=1)
        meshes.append(World(str(prim.GetPath()), world, _triangles(mesh), moved, deformable))
    return meshes


def deepest_frame(output: Path) -> int:
    """The collision frame whose response moved a display vertex farthest (first frame if none)."""
    out = Usd.Stage.Open(str(output))
    frames = range(int(out.GetStartTimeCode()), int(out.GetEndTimeCode()) + 1)
    best, best_frame = -1.0, frames[0]
    for f in frames:
        moved = max((m.moved.max() for m in world_meshes(out, f) if m.deformable and len(m.moved)), default=0.0)
        if moved > best:
            best, best_frame = moved, f
    return best_frame


def render(meshes: list[World], png: Path, title: str = "", size=(8.0, 6.0), dpi: int = 100, view=(18.0, -60.0)) -> Path:
    """Draw ``meshes`` to ``png`` with a fixed light; returns the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    fig = plt.figure(figsize=size, dpi=dpi)
    ax = fig.add_subplot(projection="3d")
    light = np.array([0.4, -0.5, 0.75])
    light /= np.linalg.norm(light)
    peak = max((m.moved.max() for m in meshes if m.deformable and len(m.moved)), default=0.0) or 1.0
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for m in meshes:
        tri = m.points[m.triangles]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        shade = 0.35 + 0.65 * np.abs(n @ light)
        if m.deformable:
            w = np.clip(m.moved[m.triangles].max(axis=1) / peak, 0.0, 1.0)[:, None]
            base = (1 - w) * np.array([0.82, 0.8, 0.78]) + w * np.array([1.0, 0.55, 0.15])
        else:
            base = np.tile([0.45, 0.55, 0.72], (len(tri), 1))
        ax.add_collection3d(Poly3DCollection(tri, facecolors=np.clip(base * shade[:, None], 0, 1), edgecolors="none"))
        lo, hi = np.minimum(lo, m.points.min(axis=0)), np.maximum(hi, m.points.max(axis=0))
    centre, half = (lo + hi) / 2, (hi - lo).max() / 2
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1, 1, 1), zoom=1.5)
    ax.view_init(*view)
    ax.set_axis_off()
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(png, dpi=dpi)
    plt.close(fig)
    return Path(png)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m pipeline.snapshot", description=__doc__.splitlines()[0])
    p.add_argument("output", type=Path, help="an ACRA output layer (.acra.usda)")
    p.add_argument("-o", "--png", type=Path, required=True)
    p.add_argument("--frame", type=int, help="frame to draw (default: the deepest collision frame)")
    p.add_argument("--view", type=float, nargs=2, default=(18.0, -60.0), metavar=("ELEV", "AZIM"))
    args = p.parse_args(argv)
    frame = deepest_frame(args.output) if args.frame is None else args.frame
    meshes = world_meshes(args.output, frame)
    peak = max((m.moved.max() for m in meshes if m.deformable and len(m.moved)), default=0.0)
    render(meshes, args.png, f"{args.output.name} — frame {frame} (orange: moved by ACRA, up to {peak:.3g})", view=tuple(args.view))
    print(f"{args.png}: frame {frame}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
