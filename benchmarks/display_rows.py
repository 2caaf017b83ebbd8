"""How many display vertices the frame loop's rounds evaluate, scene by scene.

    PYTHONPATH=$PWD python3 benchmarks/display_rows.py [SCENE ...]   # default: every bundled scene

Runs each scene's whole frame range through the frame loop and its run display
(`pipeline.frames.run_frames`, as ``acra run`` does) and counts, inside `display.Displays.of`,
the displays that evaluate any vertex and the vertices they evaluate with their normals
(`acra.tessellate._normals_into`' rows; the others are copied from the display each is evaluated
since). The counts are a function of the code alone, not of the machine's load, so one run of
each checkout compares them (``PYTHONPATH`` at the other checkout, this file the same). Prints a
table row per scene and a digest (the first 16 hex digits of a SHA-256) of every display
`Displays.of` builds, in the order built (points, limit normals, face counts and indices), so
two checkouts can be shown to build the same bits.
"""

from __future__ import annotations

import argparse
import hashlib
import pathlib

import numpy as np

from acra import tessellate
from pipeline import display, frames, usdio

ROOT = pathlib.Path(__file__).resolve().parents[1]


def count(name: str, digest) -> tuple[int, int, int]:
    """``(displays built, displays evaluating a vertex, vertices evaluated)`` over the run of scene
    ``name``; every display built is added to ``digest``."""
    inside = [0]
    seen = {"built": 0, "evaluating": 0, "rows": 0}
    # `Displays.build` (which `of` calls, and the frame loop for a round's two displays at once)
    # where the checkout has it, else `Displays.of`
    name = "build" if hasattr(display.Displays, "build") else "of"
    of, normals_into = getattr(display.Displays, name), tessellate._normals_into

    def counted_of(self, *args):
        wanted = args[0] if name == "build" else [args]
        hits = [self._shown.get(id(surface)) for surface, _ in wanted]
        inside[0] += 1
        try:
            out = of(self, *args)
        finally:
            inside[0] -= 1
        for hit, sd in zip(hits, out if name == "build" else [out]):
            if hit is not sd:  # a display built in this call
                seen["built"] += 1
                for a in (sd.points, sd.normals, sd.topology.counts, sd.topology.indices):
                    digest.update(np.ascontiguousarray(a).tobytes())
        return out

    def counted_normals(hs, u, v, det, rows, points, limit):
        if inside[0]:
            seen["evaluating"] += 1
            seen["rows"] += len(rows)
        return normals_into(hs, u, v, det, rows, points, limit)

    stage = usdio.open_input(usdio.load_scene_file(ROOT / "scenes" / f"{name}.py"))
    scene = usdio.read_scene(stage)
    span = list(range(int(stage.GetStartTimeCode()), int(stage.GetEndTimeCode()) + 1))
    setattr(display.Displays, name, counted_of)
    tessellate._normals_into = counted_normals
    try:
        frames.run_frames(stage, scene, span)
    finally:
        setattr(display.Displays, name, of)
        tessellate._normals_into = normals_into
    return seen["built"], seen["evaluating"], seen["rows"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scenes", nargs="*", help="scene names in scenes/ (default: all)")
    args = ap.parse_args()
    names = args.scenes or sorted(p.stem for p in (ROOT / "scenes").glob("*.py") if p.stem != "__init__")
    digest = hashlib.sha256()
    print("| scene | displays built | displays evaluating | vertices evaluated |\n|---|---:|---:|---:|")
    for name in names:
        built, evaluating, rows = count(name, digest)
        print(f"| {name} | {built} | {evaluating} | {rows:,} |")
    print(f"\ndisplays' digest: {digest.hexdigest()[:16]}")


if __name__ == "__main__":
    main()
