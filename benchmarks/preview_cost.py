"""What the Rerun preview costs: recording size and logging ms per frame, on the demo and the ×16 head.

    python3 benchmarks/preview_cost.py              # the table of docs/preview.md
    python3 benchmarks/preview_cost.py --repeat 5

Models: `scenes/dog_head_spike.py` (30 frames, the head's 5 280 display vertices, the spike's 672)
and the ×16 model of `benchmarks/scale_curve.py` (the plain head's level-0 grid exactly refined
twice, 64×39 CVs, its display samples scaled so the display mesh matches ×1's; the spike refined to
level 2), each over its 30 frames.

Per model:

* **logging ms per frame** — `pipeline.preview.Preview.log_frame` timed around each call, on the
  statistics and results of one run (so the frame loop is not in the figure): median over frames
  and, separately, over collision frames (the response makes the key-framed shape differ from the
  output, so colours and absorption are computed there); plus the one-off ``close`` (blueprint and
  writing the ``.rrd``);
* **recording size** — the ``.rrd`` written, bytes and bytes per frame;
* **acra preview** — seconds to rebuild the same recording from the output layer alone
  (`pipeline.preview_usd.build` plus saving);
* **no recording** — ``acra run`` without ``--rrd`` in a fresh interpreter: whether ``rerun`` or
  ``pipeline.preview`` were imported at all, and the run's total seconds with and without
  ``--rrd`` (median of ``--repeat`` alternating runs in fresh interpreters).

One invocation on a shared machine: compare the ratios within it, and note the load it prints.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import scale_curve  # noqa: E402
from pipeline import authoring, frames, preview, preview_usd, usdio  # noqa: E402
from pipeline import output_layer

PROBE = """
import json, sys, time
t = time.perf_counter()
from pipeline.run import run_file
rep = run_file(sys.argv[1], output=sys.argv[2], rrd=sys.argv[3] if len(sys.argv) > 3 else None)
print(json.dumps({"seconds": time.perf_counter() - t, "rerun": "rerun" in sys.modules,
                  "preview": "pipeline.preview" in sys.modules}))
"""


def stages(tmp: Path) -> dict[str, Path]:
    """The demo's stage and the ×16 model's."""
    demo = usdio.load_scene_file(ROOT / "scenes" / "dog_head_spike.py")
    x16 = tmp / "x16.usda"
    authoring.save(scale_curve.build_stage(2, scale_curve.head_grids()[2]), x16)
    return {"dog_head_spike": demo, "x16 head": x16}


def logging_cost(src: Path, tmp: Path) -> dict:
    """Time `Preview.log_frame` per frame and `close` on one run's statistics; size of the .rrd."""
    stage = usdio.open_input(src)
    scene = usdio.read_scene(stage)
    result, stats = frames.run_frames(stage, scene, list(range(scene.start, scene.end + 1)))
    rrd = tmp / f"{src.stem}.rrd"
    view = preview.Preview(scene, src.stem, rrd=rrd, stage=stage)
    per, hit = [], []
    for st in stats:
        t = time.perf_counter()
        view.log_frame(st, result)
        ms = 1e3 * (time.perf_counter() - t)
        per.append(ms)
        if st.in_collision:
            hit.append(ms)
    t = time.perf_counter()
    view.close()
    close_ms = 1e3 * (time.perf_counter() - t)
    out = tmp / f"{src.stem}.acra.usda"
    output_layer.write_output(src, out, scene, result)
    t = time.perf_counter()
    rec = preview_usd.build(out)
    preview.save_atomically(rec.rec, tmp / f"{src.stem}_preview.rrd", rec.finish())
    rebuild = time.perf_counter() - t
    vertices = sum(len(result.topology(m).u) for m in scene.deformables)
    return dict(frames=len(stats), collision=len(hit), vertices=vertices, log_ms=float(np.median(per)),
                log_hit_ms=float(np.median(hit)) if hit else 0.0, close_ms=close_ms, bytes=rrd.stat().st_size,
                preview_s=rebuild, output=out)


def run_cost(src: Path, tmp: Path, repeat: int) -> dict:
    """``run_file`` in fresh interpreters, alternating without and with ``--rrd``."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    runs: dict = {"off": [], "on": []}
    for i in range(repeat):
        for mode in ("off", "on"):
            args = [sys.executable, "-c", PROBE, str(src), str(tmp / f"probe_{mode}.acra.usda")]
            if mode == "on":
                args.append(str(tmp / "probe.rrd"))
            out = subprocess.run(args, env=env, capture_output=True, text=True, check=True)
            runs[mode].append(json.loads(out.stdout.strip().splitlines()[-1]))
    med = lambda xs: float(np.median([x["seconds"] for x in xs]))  # noqa: E731
    return dict(off_s=med(runs["off"]), on_s=med(runs["on"]),
                off_imports_rerun=any(x["rerun"] or x["preview"] for x in runs["off"]))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=3, help="alternating runs per mode for the no-recording check")
    args = p.parse_args()
    print(f"load: {os.getloadavg()}")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        rows = []
        for name, src in stages(tmp).items():
            r = logging_cost(src, tmp)
            r.update(run_cost(src, tmp, args.repeat), name=name)
            rows.append(r)
    print("| model | frames (collision) | display vertices | log ms/frame median (collision frames) | close ms "
          "| .rrd bytes (per frame) | acra preview s | run s without / with --rrd | rerun imported without --rrd |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['name']} | {r['frames']} ({r['collision']}) | {r['vertices']} | {r['log_ms']:.1f} ({r['log_hit_ms']:.1f}) "
              f"| {r['close_ms']:.0f} | {r['bytes']:,} ({r['bytes'] // r['frames']:,}) | {r['preview_s']:.2f} "
              f"| {r['off_s']:.2f} / {r['on_s']:.2f} ({r['on_s'] / r['off_s']:.2f}x) | {'yes' if r['off_imports_rerun'] else 'no'} |")
    print(f"load: {os.getloadavg()}")


if __name__ == "__main__":
    main()
