"""The residual as the user sees it, per scene: ``python3 benchmarks/visible.py [NAME ...]``.

Runs each scene of ``scenes/`` (or the named ones) as ``acra run`` does into a temporary
directory, then measures the output layer with the independent measure of
``tests/test_visible.py`` (USD + trimesh only): per scene, the worst frame's depth of display
vertices and of triangle samples inside another object, as a fraction of the object's own
display diagonal, beside what the run's summary reported. Prints a Markdown table.
"""

from __future__ import annotations

import importlib.util
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _measure_module():
    spec = importlib.util.spec_from_file_location("visible_measure", ROOT / "tests" / "test_visible.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["visible_measure"] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def main(names: list[str]) -> None:
    from pipeline.run import run_file

    measure = _measure_module()
    names = names or [p.stem for p in sorted((ROOT / "scenes").glob("*.py")) if not p.stem.startswith("_")]
    print("| scene | reported (worst frame) | measured: vertices | measured: triangle samples | frames over 1e-3 | reported < measured |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            d = Path(tmp) / name
            d.mkdir()
            shutil.copy(ROOT / "scenes" / f"{name}.py", d / f"{name}.py")
            report = run_file(d / f"{name}.py")
            ms = measure.measure_layer(report.output, [s.frame for s in report.stats])
            worst = measure.worst_by_frame(ms)
            reported = max(s.residual_rel for s in report.stats)
            vert = max((m.vertices for m in ms), default=0.0)
            samp = max((m.samples for m in ms), default=0.0)
            over = sorted(f for f, x in worst.items() if x > 1e-3)
            under = sorted(s.frame for s in report.stats if s.residual_rel < worst[s.frame])
            print(f"| {name} | {reported:.2e} | {vert:.2e} | {samp:.2e} | {over or '-'} | {under or '-'} |", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
