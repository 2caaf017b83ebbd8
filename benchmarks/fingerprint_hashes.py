"""What `pipeline.residual.Shown.fingerprint`'s hash costs, against the other hashes hashlib offers.

    python3 benchmarks/fingerprint_hashes.py [SCENE.py] [--frame 13] [--repeat 50]

Runs the scene's ``--frame`` (after a free frame), keeps the object-space points of every display
the frame loop shows (`residual.shown`), and hashes the largest one's float32 copy (what the
fingerprint hashes of it) with each algorithm: the CPU milliseconds of the fastest of
``--repeat`` hashes each, and the sha1 digest of those bytes (two checkouts hash the same
points when it agrees). The fingerprint keys answers across frames (`residual.known`), so only
collision-safe (cryptographic) hashes are listed.
"""

from __future__ import annotations

import argparse
import hashlib
import pathlib
import time

import numpy as np

from pipeline import residual, usdio
from pipeline import frames as F

ROOT = pathlib.Path(__file__).resolve().parents[1]
ALGORITHMS = ("sha1", "sha256", "blake2b", "md5", "sha512", "blake2s", "sha3_256")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scene", nargs="?", type=pathlib.Path, default=ROOT / "scenes" / "dog_head_spike.py")
    ap.add_argument("--frame", type=int, default=13)
    ap.add_argument("--repeat", type=int, default=50)
    args = ap.parse_args()
    stage = usdio.open_input(usdio.load_scene_file(args.scene))
    scene = usdio.read_scene(stage)
    F.run_frames(stage, scene, [5])
    shown = []
    real = residual.shown

    def keep(*a, **k):
        shown.append(real(*a, **k))
        return shown[-1]

    residual.shown = keep
    F.run_frames(stage, scene, [args.frame])
    residual.shown = real
    points = max((s.local for s in shown), key=len).astype(np.float32)
    print(f"{args.scene.name}, frame {args.frame}: {len(points)} display points ({points.nbytes} bytes as float32), "
          f"sha1 {hashlib.sha1(points.data).hexdigest()[:12]}")
    for name in ALGORITHMS:
        best = np.inf
        for _ in range(args.repeat):
            t = time.process_time()
            hashlib.new(name, points.data).digest()
            best = min(best, time.process_time() - t)
        print(f"  {name}: {1e3 * best:.3f} ms ({points.nbytes / best / 1e9:.2f} GB/s)")


if __name__ == "__main__":
    main()
