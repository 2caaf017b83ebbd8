"""What a run's frames leave to the cyclic garbage collector: objects in reference cycles.

    PYTHONPATH=$PWD python3 benchmarks/cycle_garbage.py [--repeat 3] [--scene scenes/dog_head_spike.py]

Runs every frame of the scene once to warm up, then ``--repeat`` times with the cyclic collector
off: each repeat runs every frame after `pipeline.run.forget` (as a fresh run starts), drops the
results and forgets again, so what is still allocated is held only by reference cycles; then
``gc.collect()`` (with ``gc.DEBUG_SAVEALL``, which keeps what it finds) counts those objects.
Prints per repeat the count, the most common types among them and the megabytes of the numpy
arrays they hold directly (each array's owner counted once): memory that reference counting
would have freed at once and that waits instead for the collector's next pass. The last line is
a digest of every run's frames' responded level-0 CVs and residuals: two checkouts answer alike when
their digests agree. Run it with ``PYTHONPATH`` set to another checkout to compare.
"""

from __future__ import annotations

import argparse
import collections
import gc
import hashlib
import pathlib

import numpy as np

from pipeline import frames, usdio
from pipeline.run import forget

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _array_megabytes(found: list) -> float:
    """Megabytes of the arrays the objects ``found`` refer to directly, each owner (an array's
    ``base`` chain to its end) once."""
    owners = {}
    for obj in found:
        for ref in gc.get_referents(obj):
            if isinstance(ref, np.ndarray):
                while isinstance(ref.base, np.ndarray):
                    ref = ref.base
                owners[id(ref)] = ref.nbytes
    return sum(owners.values()) / 2**20


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--scene", default=str(ROOT / "scenes" / "dog_head_spike.py"))
    args = ap.parse_args()
    stage = usdio.open_input(usdio.load_scene_file(pathlib.Path(args.scene)))
    scene = usdio.read_scene(stage)
    every = list(range(int(stage.GetStartTimeCode()), int(stage.GetEndTimeCode()) + 1))
    digest = hashlib.sha1()

    def run() -> None:
        """Every frame, its answers into the digest, the results dropped."""
        result, _ = frames.run_frames(stage, scene, every)
        for frame in sorted(result.frames):
            for _, res in sorted(result.frames[frame].items()):
                digest.update(np.ascontiguousarray(res.surface.cvs).tobytes())
                digest.update(np.float64(res.residual).tobytes())

    run()  # warm: kernels loaded, modules' tables built
    print(f"{pathlib.Path(args.scene).name}, frames {every[0]}-{every[-1]}: objects in reference cycles a run\n")
    print("| repeat | objects | arrays MB | most common |\n|---:|---:|---:|---|")
    enabled = gc.isenabled()
    try:
        for rep in range(args.repeat):
            forget()
            gc.collect()
            gc.disable()
            run()
            forget()
            gc.set_debug(gc.DEBUG_SAVEALL)
            count = gc.collect()
            gc.set_debug(0)
            kinds = collections.Counter(type(o).__name__ for o in gc.garbage).most_common(6)
            print(f"| {rep + 1} | {count} | {_array_megabytes(gc.garbage):.2f} | "
                  + ", ".join(f"{name} {n}" for name, n in kinds) + " |")
            gc.garbage.clear()
            gc.enable()
    finally:
        gc.set_debug(0)
        if enabled:
            gc.enable()
    print(f"\nanswers {digest.hexdigest()[:12]}")


if __name__ == "__main__":
    main()
