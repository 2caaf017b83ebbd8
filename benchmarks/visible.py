"""The residual as the user sees it, per scene: ``python3 benchmarks/visible.py [NAME ...]``.

Runs each scene of ``scenes/`` (or the named ones) as ``acra run`` does into a temporary
directory, then measures the output layer with the independent measure `acceptance.visible`
(USD, trimesh and fcl only): per scene, the worst measured frame's depth of display vertices and of
triangle samples inside another object, as a fraction of the object's own display diagonal,
beside what the run reported at that frame, the most rounds a frame took, and the frames where the
two disagree (`acceptance.visible.disagreements`). Prints a Markdown table.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(names: list[str]) -> None:
    from acceptance import visible as measure
    from pipeline.run import run_file

    names = names or [p.stem for p in sorted((ROOT / "scenes").glob("*.py")) if not p.stem.startswith("_")]
    print("| scene | worst frame | reported | measured: vertices | measured: triangle samples | most rounds | frames over 1e-3 | reported < measured |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            d = Path(tmp) / name
            d.mkdir()
            shutil.copy(ROOT / "scenes" / f"{name}.py", d / f"{name}.py")
            report = run_file(d / f"{name}.py")
            ms = measure.measure_layer(report.output, [s.frame for s in report.stats])
            worst = measure.worst_by_frame(ms)
            frame = max(worst, key=lambda f: (worst[f], -f))  # the worst measured frame, the first of equals
            reported = {s.frame: s.residual_rel for s in report.stats}[frame]
            vert = max((m.vertices for m in ms if m.frame == frame), default=0.0)
            samp = worst[frame]
            over = sorted(f for f, x in worst.items() if x > 1e-3)
            under = sorted(s.frame for s in report.stats if s.residual_rel < worst[s.frame] - measure.SLACK)
            rounds = max(s.iterations for s in report.stats)
            print(f"| {name} | {frame} | {reported:.2e} | {vert:.2e} | {samp:.2e} | {rounds} | {over or '-'} | {under or '-'} |", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
