"""Output layers of two checkouts side by side: byte-identical, equal as USD data, or different.

    python3 benchmarks/compare_outputs.py BASE_CHECKOUT                 # every bundled scene, .usda
    python3 benchmarks/compare_outputs.py BASE_CHECKOUT dog_head_spike soft_ball --format usdc

Runs ``acra run SCENE -o OUT --quiet --over-tolerance warn`` for each scene of ``scenes/`` once
with this checkout and once with ``BASE_CHECKOUT`` (a directory holding another version's
``pipeline/``, ``acra/`` and ``scenes/``, e.g. ``git archive COMMIT | tar -x -C DIR``), each as
its own process with ``PYTHONPATH`` set to that checkout, the scene file copied into a fresh
directory so both outputs have the same relative sublayer path. A pair of outputs whose bytes
differ is compared as USD data: every spec path, every field of every spec and every time sample
(`Sdf.Layer`), so a layer written in another order or by another writer that means the same
counts as equal. Prints one table row per scene and exits 1 if any scene differs.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]


def run_scene(checkout: Path, scene: Path, work: Path, suffix: str) -> tuple[Path, float]:
    """Run ``scene`` with ``checkout``'s code in ``work``; the output layer and the wall seconds."""
    work.mkdir(parents=True)
    src = work / scene.name
    shutil.copy(scene, src)
    out = work / f"{scene.stem}.acra.{suffix}"
    env = dict(os.environ, PYTHONPATH=str(checkout))
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "pipeline.cli", "run", str(src), "-o", str(out), "--quiet",
                    "--over-tolerance", "warn"], check=True, capture_output=True, env=env, cwd=work)
    return out, time.perf_counter() - t


def layer_data(path: Path) -> dict:
    """Every spec of the layer at ``path``: ``{spec path: {field: value}}``, time samples included."""
    from pxr import Sdf

    layer = Sdf.Layer.OpenAsAnonymous(str(path))
    data: dict = {}

    def visit(spec_path):
        spec = layer.GetObjectAtPath(spec_path)
        fields = {}
        for key in spec.ListInfoKeys():
            if key == "subLayerOffsets":  # no Python converter for the field: read it from the layer
                fields[key] = [(o.offset, o.scale) for o in layer.subLayerOffsets]
            else:
                fields[key] = spec.GetInfo(key)
        if layer.GetNumTimeSamplesForPath(spec_path):
            fields["timeSamples"] = {t: layer.QueryTimeSample(spec_path, t) for t in layer.ListTimeSamplesForPath(spec_path)}
        data[str(spec_path)] = fields

    layer.Traverse(Sdf.Path.absoluteRootPath, visit)
    return data


def compare(a: Path, b: Path) -> str:
    """``identical bytes``, ``equal as USD data`` or the first difference found."""
    if a.read_bytes() == b.read_bytes():
        return "identical bytes"
    da, db = layer_data(a), layer_data(b)
    if da.keys() != db.keys():
        return f"differs: spec paths {sorted(set(da) ^ set(db))[:3]}"
    for path in sorted(da):
        if da[path].keys() != db[path].keys():
            return f"differs: fields of {path}: {sorted(set(da[path]) ^ set(db[path]))}"
        for key in da[path]:
            if da[path][key] != db[path][key]:
                return f"differs: {path} {key}"
    return "equal as USD data"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("base", type=Path, help="the other checkout (directory with pipeline/, acra/, scenes/)")
    parser.add_argument("scenes", nargs="*", help="scene names (default: every scenes/*.py but _*.py)")
    parser.add_argument("--format", choices=("usda", "usdc"), default="usda")
    args = parser.parse_args()
    names = args.scenes or sorted(p.stem for p in (HERE / "scenes").glob("*.py") if not p.name.startswith("_"))
    failed = 0
    print(f"| scene | this checkout s | base s | .{args.format} outputs |\n|---|---:|---:|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            scene = HERE / "scenes" / f"{name}.py"
            mine, t_mine = run_scene(HERE, scene, Path(tmp) / name / "this", args.format)
            base, t_base = run_scene(args.base.resolve(), args.base.resolve() / "scenes" / scene.name, Path(tmp) / name / "base",
                                     args.format)
            verdict = compare(mine, base)
            failed += verdict.startswith("differs")
            print(f"| {name} | {t_mine:.2f} | {t_base:.2f} | {verdict} |", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
