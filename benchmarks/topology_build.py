"""The display topologies of a run's collision frames, built again warm and timed.

    PYTHONPATH=$PWD python3 benchmarks/topology_build.py [SCENE.py] [--frames 13:17] [--repeat 15]

Runs the scene's free frame ``--warm`` and its ``--frames`` and records every surface the frame
loop displays (`pipeline.display.Displays.build`, or `of`); then, for each distinct refinement among them
(`display._refinement`), builds its topology (`acra.tessellate.run_topology` and its fan
triangles, as `display.Displays.topology` does on a new refinement) ``--repeat`` times in a row
and prints its vertices, the least and the median CPU milliseconds (``time.process_time``) of the
whole build and of `acra.lattice.adaptive_mesh` alone on the same arguments, and a digest of
every topology's arrays (vertex parameters, face counts and indices, rows by v, triangles: the
first 16 hex digits of a SHA-256), so two checkouts can be shown to build the same meshes. Run it
with ``PYTHONPATH`` set to two checkouts to compare them. The builds repeat on warm memory: in
the frame loop a new topology's arrays are colder, and it takes more (`benchmarks/display_split.py
--calls`, its topology column).
"""

from __future__ import annotations

import argparse
import hashlib
import pathlib
import statistics
import time

import numpy as np

from acra import lattice, tessellate
from pipeline import display, frames, usdio

ROOT = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", type=pathlib.Path, default=ROOT / "scenes" / "dog_head_spike.py")
    ap.add_argument("--frames", default="13:17", help="collision frames START:END (default 13:17)")
    ap.add_argument("--warm", type=int, default=5, help="a free frame run first (default 5)")
    ap.add_argument("--repeat", type=int, default=15, help="builds of each topology (default 15)")
    args = ap.parse_args()
    first, last = (int(x) for x in args.frames.split(":"))

    shown: list = []
    # every display goes through `Displays.build` (`of` is `build` of one) where the checkout has it
    name = "build" if hasattr(display.Displays, "build") else "of"
    real = getattr(display.Displays, name)

    def recording(self, *args):
        shown.extend(args[0] if name == "build" else [args])
        return real(self, *args)

    setattr(display.Displays, name, recording)
    try:
        stage = usdio.open_input(usdio.load_scene_file(args.scene))
        scene = usdio.read_scene(stage)
        frames.run_frames(stage, scene, [args.warm])
        frames.run_frames(stage, scene, list(range(first, last + 1)))
    finally:
        setattr(display.Displays, name, real)

    distinct: dict = {}
    for surface, samples in shown:
        distinct.setdefault(display._refinement([surface], samples), (surface, samples))

    # adaptive_mesh's arguments for each build, recorded as `tessellate._adaptive_keys` passes them
    mesh_args: list = []
    mesh = tessellate.adaptive_mesh

    def recording_mesh(*a):
        mesh_args.append(a)
        return mesh(*a)

    digest = hashlib.sha256()
    print(f"{args.scene.name}, frames {first}-{last}: {len(distinct)} distinct refinements displayed\n")
    print("| vertices | build ms, least | median | `adaptive_mesh` ms, least | median |")
    print("|---:|---:|---:|---:|---:|")
    for surface, samples in distinct.values():
        tessellate.adaptive_mesh = recording_mesh
        try:
            topo = tessellate.run_topology([surface], samples)
        finally:
            tessellate.adaptive_mesh = mesh
        for a in (topo.u, topo.v, topo.counts, topo.indices, topo.by_v, topo.triangles()):
            digest.update(np.ascontiguousarray(a).tobytes())
        build, alone = [], []
        for _ in range(args.repeat):
            t = time.process_time()
            tessellate.run_topology([surface], samples).triangles()
            build.append(1e3 * (time.process_time() - t))
        for _ in range(args.repeat):
            t = time.process_time()
            lattice.adaptive_mesh(*mesh_args[-1])
            alone.append(1e3 * (time.process_time() - t))
        print(f"| {topo.u.size:,} | {min(build):.3f} | {statistics.median(build):.3f} | {min(alone):.3f} | "
              f"{statistics.median(alone):.3f} |")
    print(f"\ntopologies' digest: {digest.hexdigest()[:16]}")


if __name__ == "__main__":
    main()
