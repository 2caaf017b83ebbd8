"""The sure hits of a run's casts (`acra.raycast.sure_hits`), replayed and timed alone.

    PYTHONPATH=$PWD python3 benchmarks/sure_hits_calls.py [SCENE.py] [--frames 13:17] [--repeat 300]

Runs the scene once, records every `pipeline.queries.RayMesh.first_hits` call of the collision
frames in ``--frames`` (its mesh and rays), then calls `raycast.sure_hits` on each recorded call's
arrays as `first_hits` makes them (unit directions, the float32 rays in the mesh's frame) and
prints, in CPU time, each call's frame, rays and least microseconds over ``--repeat`` calls, their
sum per collision frame, and a digest of every answer (triangles, sureness, which rows hit and
their hits): two checkouts answer alike when their digests agree. Run it with ``PYTHONPATH`` at
each checkout, alternating, for a comparison.
"""

from __future__ import annotations

import argparse
import hashlib
import pathlib
import tempfile
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]


def record(scene: pathlib.Path, first: int, last: int) -> tuple[list, int]:
    """``[(frame, RayMesh, origins (n, 3), directions (n, 3)), ...]`` of the collision frames
    ``first..last`` and how many collision frames ran."""
    from pipeline import frames, queries
    from pipeline.run import forget, run_file

    calls: list = []
    now = {"frame": None}
    frame, first_hits = frames._Run.frame, queries.RayMesh.first_hits

    def framed(self, f, result):
        now["frame"] = f
        return frame(self, f, result)

    def recording(self, origins, directions):
        if first <= now["frame"] <= last:
            calls.append((now["frame"], self, np.array(origins), np.array(directions)))
        return first_hits(self, origins, directions)

    frames._Run.frame, queries.RayMesh.first_hits = framed, recording
    try:
        with tempfile.TemporaryDirectory() as tmp:
            src = pathlib.Path(tmp) / scene.name
            src.write_text(scene.read_text())
            forget()
            report = run_file(src, output=pathlib.Path(tmp) / "out.acra.usda")
    finally:
        frames._Run.frame, queries.RayMesh.first_hits = frame, first_hits
    count = sum(1 for st in report.stats if st.in_collision and not st.hold and first <= st.frame <= last)
    return calls, count


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", default=str(ROOT / "scenes" / "dog_head_spike.py"))
    ap.add_argument("--frames", default="13:17")
    ap.add_argument("--repeat", type=int, default=300)
    args = ap.parse_args()
    from acra import meshops, raycast

    first, last = (int(x) for x in args.frames.split(":"))
    calls, count = record(pathlib.Path(args.scene).resolve(), first, last)
    digest, total, rows = hashlib.sha1(), 0.0, []
    for f, mesh, o, d in calls:
        origins = np.ascontiguousarray(o, dtype=np.float64)
        directions = meshops.unitize(np.ascontiguousarray(d, dtype=np.float64))[0]
        scaled = ((origins - mesh.origin) * mesh.factor).astype(np.float32)
        arrays = (mesh.scaled, mesh.faces, mesh.boxes, scaled, directions.astype(np.float32),
                  (mesh.vertices, origins, directions))
        tri, sure, loc, has = raycast.sure_hits(*arrays)
        for a in (tri, sure, has, loc[has]):
            digest.update(np.ascontiguousarray(a).tobytes())
        best = np.inf
        for _ in range(args.repeat):
            t = time.process_time()
            raycast.sure_hits(*arrays)
            best = min(best, time.process_time() - t)
        total += best
        rows.append(f"{f}:{len(o)}:{1e6 * best:.0f}")
    print(f"{len(calls)} sure_hits calls (frame:rays:us) {' '.join(rows)}")
    print(f"{1e6 * total / max(count, 1):.1f} us CPU per collision frame ({count} frames); digest {digest.hexdigest()[:12]}")


if __name__ == "__main__":
    main()
