"""The ray parity `box_into_sheet`'s computed collision frame (frame 11) asks of the points near a
face of the box, how near they lie in embree's float32 numbers, and what the parity costs.

    PYTHONPATH=$PWD python3 benchmarks/rim_parity.py [--repeat 100]

Runs frame 11 after frame 5 and records each parity call of the inside tests (``detect._parity``
where the checkout has it, else ``Trimesh.contains``: the points within `detect.SIDE_SURE` of the
box's surface). Prints the calls and points,
each point's distance from the nearest face plane in float32 roundings of its coordinates in
embree's scaled frame (trimesh's scene: the box's low corner at 0, a diagonal of 100), the count
beyond 8 and 64 roundings (``acra.raycast.sure_hits`` proves a triangle where its tests clear 64
roundings), and the CPU time of replaying the calls ``--repeat`` times through ``Trimesh.contains``
(the generator reseeded before each call, as `detect._collider_inside` does), in ms a frame;
where the checkout has ``acra.meshops.contains`` (a measured alternative, commit ``2c9f3fe``),
the same calls through it too. The digest is of the recorded calls' parity answers: two
checkouts that ask the same points print the same.
"""

from __future__ import annotations

import argparse
import hashlib
import pathlib
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=100)
    args = ap.parse_args()

    import trimesh

    from acra import meshops
    from pipeline import detect as D
    from pipeline import frames as F
    from pipeline import usdio
    from pipeline.run import forget

    calls = []
    contains = trimesh.Trimesh.contains

    def recorded(mesh, points):
        calls.append((mesh, np.array(points, np.float64)))
        return contains(mesh, points)

    parity = getattr(D, "_parity", None)  # the inside tests' one route to the parity, where there is one
    if parity is not None:

        def recorded_parity(static, local):
            calls.append((static.mesh, np.array(local, np.float64)))
            return parity(static, local)

        D._parity = recorded_parity
    else:
        trimesh.Trimesh.contains = recorded
    forget()
    stage = usdio.open_input(usdio.load_scene_file(ROOT / "scenes" / "box_into_sheet.py"))
    scene = usdio.read_scene(stage)
    F.run_frames(stage, scene, [5])
    calls.clear()
    F.respond_frames(stage, scene, [11])
    trimesh.Trimesh.contains = contains

    def seeded():
        trimesh.util._RANDOM_DEFAULT = np.random.default_rng(20260311)

    roundings, digest = [], hashlib.sha256()
    for mesh, p in calls:
        factor = 100.0 / mesh.scale
        height = np.abs(np.einsum("pfk,fk->pf", p[:, None, :] - mesh.triangles[None, :, 0, :], mesh.face_normals))
        scaled = (p - mesh.bounds[0]) * factor
        unit = np.spacing(np.abs(scaled).max(axis=1).astype(np.float32)).astype(np.float64)
        roundings.append(height.min(axis=1) * factor / unit)
        seeded()
        digest.update(contains(mesh, p).tobytes())
    r = np.concatenate(roundings) if roundings else np.zeros(0)
    print(f"box_into_sheet frame 11: {len(calls)} parity calls, {len(r)} points near a face "
          f"({', '.join(str(len(p)) for _, p in calls)})")
    if len(r):
        print(f"distance from the nearest face plane, float32 roundings: min {r.min():.2f}, median "
              f"{np.median(r):.2f}, max {r.max():.2f}; beyond 8: {int((r > 8).sum())}, beyond 64: {int((r > 64).sum())}")

    routes = {"Trimesh.contains": lambda mesh, p: contains(mesh, p)}
    if hasattr(meshops, "contains"):
        kept = {}

        def through_meshops(mesh, p):
            a = kept.get(id(mesh))
            if a is None:
                a = kept[id(mesh)] = (mesh.ray._scene.run, np.array(mesh.bounds), np.array(mesh.triangles[:, 0, :]),
                                      np.array(mesh.face_normals), float(mesh.scale))
            return meshops.contains(*a, p, lambda: trimesh.util.unitize(trimesh.util.random_generator().random(3) - 0.5))

        routes["meshops.contains"] = through_meshops
    same = {}
    for name, route in routes.items():  # once untimed (caches, first calls), against trimesh's answers
        got = hashlib.sha256()
        for mesh, p in calls:
            seeded()
            got.update(route(mesh, p).tobytes())
        same[name] = got.hexdigest() == digest.hexdigest()
    ms = {name: [] for name in routes}
    for _ in range(3):
        for name, route in routes.items():
            t = time.process_time()
            for _ in range(args.repeat):
                for mesh, p in calls:
                    seeded()
                    route(mesh, p)
            ms[name].append(1e3 * (time.process_time() - t) / args.repeat)
    for name, runs in ms.items():
        print(f"{name}: {min(runs):.3f}-{max(runs):.3f} ms CPU a frame (three runs of {args.repeat} replays), "
              f"{'the same answers' if same[name] else 'OTHER ANSWERS'}")
    print(f"digest {digest.hexdigest()[:12]}")


if __name__ == "__main__":
    main()
