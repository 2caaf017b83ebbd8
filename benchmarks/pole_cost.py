"""What a closed display's poles cost the residual's kernels: their copies and degenerate triangles counted.

    python3 benchmarks/pole_cost.py [SCENE.py] [--frames 13:17] [--passes 40]

A closed H-spline's display repeats each pole's point in a row of vertices (the spike's tip: 128
copies) and fans zero-area triangles around it (two corners the same point). Runs the scene's
``--frames`` after a free frame (frame 5), keeping the arguments of every call of
`acra.depthbound._depth` (the branch and bound), `acra.clearcells._clear_cells`,
`acra.meshrows._faces_at` and `acra.meshrows._faces_meet_chunks`, and counting each
`acra.kernels.eval_points` call's points whose point slot repeats another's bits. Prints, per
kernel, the degenerate triangles and faces it is handed (two corners with the same bits) against
all, and the CPU milliseconds of its calls replayed as recorded and with the degenerate
triangles left out (the branch and bound also with its part's pole fan, the faces at a vertex
of more than 12, moved beyond every walk's reach): the difference bounds what they cost. The
variants answer otherwise, so they are estimates, not candidates.
"""

from __future__ import annotations

import os

# one thread (before numba is imported): the calls come in one order (`pipeline.workers`)
os.environ["NUMBA_NUM_THREADS"] = "1"

import pathlib
import time

import numpy as np
from threadpoolctl import threadpool_limits

from _replay import arguments
from acra import clearcells, depthbound, kernels, meshrows


def _flat(tri: np.ndarray) -> np.ndarray:
    """Which triangles ``tri (t, 3, 3) float64`` have two corners with the same bits: ``(t,) bool``."""
    b = np.ascontiguousarray(tri).view(np.uint64)
    return (b[:, 0] == b[:, 1]).all(1) | (b[:, 1] == b[:, 2]).all(1) | (b[:, 2] == b[:, 0]).all(1)


def _fastest(calls: list, kernel, passes: int) -> float:
    """CPU ms of the fastest of ``passes`` replays of ``calls`` (lists of arguments) of ``kernel``."""
    best = np.inf
    for _ in range(passes):
        t = time.process_time()
        for a in calls:
            kernel(*a)
        best = min(best, time.process_time() - t)
    return 1e3 * best


def main() -> None:
    from pipeline import frames as F
    from pipeline import usdio

    args = arguments(__doc__.split("\n")[0])
    kept = {(depthbound, "_depth"): [], (clearcells, "_clear_cells"): [], (meshrows, "_faces_at"): [],
            (meshrows, "_faces_meet_chunks"): []}
    reals = {key: getattr(*key) for key in kept}
    evals = []  # (points, derivative order, points repeating another's bits) of each evaluation

    def keeper(key):
        def wrapper(*a):
            kept[key].append([x.copy() if isinstance(x, np.ndarray) and x.flags.writeable else x for x in a])
            return reals[key](*a)
        return wrapper

    real_eval = kernels.eval_points

    def counted(u, v, order, *rest):
        out = real_eval(u, v, order, *rest)
        pts = np.ascontiguousarray(rest[-1][0]).view(np.uint64).reshape(-1, 3)
        evals.append((len(pts), int(order), len(pts) - len(np.unique(pts, axis=0))))
        return out

    with threadpool_limits(1):
        stage = usdio.open_input(usdio.load_scene_file(pathlib.Path(args.scene)))
        scene = usdio.read_scene(stage)
        F.run_frames(stage, scene, [5])
        for key in kept:
            setattr(*key, keeper(key))
        kernels.eval_points = counted
        try:
            F.run_frames(stage, scene, args.frames)
        finally:
            for key, real in reals.items():
                setattr(*key, real)
            kernels.eval_points = real_eval
        n = len(args.frames)
        print(f"{os.path.basename(args.scene)} frames {args.frames[0]}-{args.frames[-1]}, CPU ms over them "
              f"(fastest of {args.passes} passes):")

        calls = kept[(depthbound, "_depth")]
        flat = [_flat(a[0]) for a in calls]
        dropped, far = [], []
        for a, f in zip(calls, flat):
            b = list(a)
            b[0] = np.ascontiguousarray(a[0][~f])
            dropped.append(b)
            c = list(a)  # the part's faces at a pole vertex: their corners beyond every walk
            faces, order = a[20], a[12]
            valence = np.bincount(faces.ravel(), minlength=len(a[19]))
            fan = np.isin(faces, np.flatnonzero(valence > 12)).any(1)[order]
            leaf = a[11].copy()
            leaf[fan] = 1e30
            c[11] = leaf
            far.append(c)
        corners = sum(3 * len(a[0]) for a in calls)
        distinct = sum(len(np.unique(a[0].reshape(-1, 3).view(np.uint64), axis=0)) for a in calls)
        print(f"  depthbound._depth: {len(calls)} calls, {sum(map(len, flat))} triangles, "
              f"{sum(int(f.sum()) for f in flat)} degenerate; {corners} corners, {distinct} distinct (the search's "
              f"level 0); {_fastest(calls, reals[(depthbound, '_depth')], args.passes):.3f} as recorded, "
              f"{_fastest(dropped, reals[(depthbound, '_depth')], args.passes):.3f} without the degenerate, "
              f"{_fastest(far, reals[(depthbound, '_depth')], args.passes):.3f} with the part's pole fans out of reach")

        calls = kept[(clearcells, "_clear_cells")]
        dropped, n_rows, n_flat_rows, n_tri, n_flat_tri = [], 0, 0, 0, 0
        for a in calls:
            points, faces, rows, tri, rho = a[0], a[1], a[2], a[3], a[4]
            fr = _flat(points[faces[rows]])
            ft = _flat(tri)
            n_rows, n_flat_rows, n_tri, n_flat_tri = (n_rows + len(rows), n_flat_rows + int(fr.sum()), n_tri + len(tri),
                                                      n_flat_tri + int(ft.sum()))
            b = list(a)
            b[2], b[3], b[4] = rows[~fr], np.ascontiguousarray(tri[~ft]), rho[~ft]
            b[12], b[13] = np.empty(int((~ft).sum()), np.bool_), np.empty(int((~fr).sum()), np.int64)
            dropped.append(b)
        print(f"  clearcells._clear_cells: {len(calls)} calls, {n_rows} face rows, {n_flat_rows} degenerate; {n_tri} "
              f"triangles, {n_flat_tri} degenerate; {_fastest(calls, reals[(clearcells, '_clear_cells')], args.passes):.3f} "
              f"as recorded, {_fastest(dropped, reals[(clearcells, '_clear_cells')], args.passes):.3f} without the "
              f"degenerate")

        calls = kept[(meshrows, "_faces_at")]
        dropped, n_rows, n_flat = [], 0, 0
        for a in calls:
            fr = _flat(a[0][a[1][a[2]]])
            n_rows, n_flat = n_rows + len(fr), n_flat + int(fr.sum())
            b = list(a)
            m = int((~fr).sum())
            b[2], b[4] = a[2][~fr], np.empty((m, 3, 3))
            b[5] = np.empty((m if len(a[5]) else 0, 3, 3))
            dropped.append(b)
        print(f"  meshrows._faces_at: {len(calls)} calls, {n_rows} rows, {n_flat} degenerate; "
              f"{_fastest(calls, reals[(meshrows, '_faces_at')], args.passes):.3f} as recorded, "
              f"{_fastest(dropped, reals[(meshrows, '_faces_at')], args.passes):.3f} without the degenerate")

        calls = kept[(meshrows, "_faces_meet_chunks")]
        n_faces = sum(len(a[1]) for a in calls)
        n_flat = sum(int(_flat(a[0][a[1]]).sum()) for a in calls)
        print(f"  meshrows._faces_meet_chunks: {len(calls)} calls over {n_faces} faces, {n_flat} degenerate; "
              f"{_fastest(calls, reals[(meshrows, '_faces_meet_chunks')], args.passes):.3f} as recorded")

        e = np.array(evals, np.int64).reshape(-1, 3)
        for order in range(3):
            s = e[e[:, 1] == order]
            print(f"  kernels.eval_points of order {order}: {len(s)} calls, {int(s[:, 0].sum())} points, "
                  f"{int(s[:, 2].sum())} repeating another's point bits")
        print(f"  ({n} frames: divide by {n} for a frame)")


if __name__ == "__main__":
    main()
