"""Stress benchmark of `acra run` (not a test): long runs, many objects, a huge collider, far from the
origin, tiny and huge scales. Each case is built as a stage, run as its own process under
``/usr/bin/time -v`` (peak resident memory, wall time) with ``--report`` (per-frame figures), and
summarised as a Markdown table (docs/cli.md, "Stress").

    PYTHONPATH=. python3 benchmarks/stress.py [--cases free,many,huge,offset,scale] [--out DIR]

Cases
-----
free    10,000 frames of a 4x4 sheet and a box that never touch (time per free frame)
many    100 deformable 4x4 sheets in one stage, a box pressing into one of them, 3 frames
huge    a 2,000,000-triangle collider (a subdivided box) pressing a 4x4 sheet, 3 frames
offset  the tiny scene translated 1e7 units from the origin
scale   the tiny scene scaled by 1e-3 and by 1e3
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from acra import shapes  # noqa: E402
from pipeline import authoring  # noqa: E402


def _stage(frames: int):
    """An empty stage of frames ``1..frames`` with a ``/World`` Xform."""
    return authoring.new_stage(1, frames, fps=24, up_axis="Z")


def _sheet(stage, path: str, offset=(0.0, 0.0, 0.0)):
    cvs, _, _ = shapes.sheet(4, 4, width=2.0, depth=2.0)
    cvs = cvs + np.asarray(offset)
    authoring.add_deformable(stage, path, cvs, levels=2, absorption=[0.5, 0.5], samples=4)


def _box(stage, path: str, frames: int, top: float, bottom: float, mesh=None, xy=(0.0, 0.0)):
    verts, faces = mesh if mesh is not None else authoring.box(1.0)
    mover = authoring.add_xform(stage, path)
    authoring.add_collider(stage, f"{path}/Box", verts, faces)
    authoring.key_transform(mover, 1, translate=(xy[0], xy[1], top))
    authoring.key_transform(mover, frames, translate=(xy[0], xy[1], bottom))


def subdivided_box(triangles: int) -> tuple[np.ndarray, np.ndarray]:
    """A unit box whose 6 faces are n x n quad grids (2 triangles each): ``vertices (v, 3)``,
    ``faces (f, 4) int64`` with 12 n^2 >= ``triangles``."""
    n = int(np.ceil(np.sqrt(triangles / 12.0)))
    g = np.linspace(-0.5, 0.5, n + 1)
    verts, faces = [], []
    base = 0
    for axis in range(3):
        for side in (-0.5, 0.5):
            a, b = np.meshgrid(g, g, indexing="ij")
            p = np.zeros((n + 1, n + 1, 3))
            others = [i for i in range(3) if i != axis]
            p[..., axis] = side
            p[..., others[0]], p[..., others[1]] = (a, b) if side > 0 else (b, a)
            idx = base + np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
            q = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], axis=-1).reshape(-1, 4)
            verts.append(p.reshape(-1, 3))
            faces.append(q if axis != 1 else q[:, ::-1])
            base += (n + 1) ** 2
    return np.concatenate(verts), np.concatenate(faces).astype(np.int64)


def build(case: str, d: Path) -> list[tuple[str, Path]]:
    """Stages of one case: ``[(label, path)]``."""
    out = []
    if case == "free":
        stage = _stage(10000)
        _sheet(stage, "/World/Sheet")
        _box(stage, "/World/Mover", 10000, 3.0, 1.0)  # never below z = 0.5: no contact
        out.append(("10,000 free frames", authoring.save(stage, d / "free.usdc")))
    elif case == "many":
        stage = _stage(3)
        for i in range(100):
            _sheet(stage, f"/World/Sheet_{i:03d}", offset=(3.0 * (i % 10), 3.0 * (i // 10), 0.0))
        _box(stage, "/World/Mover", 3, 1.0, 0.4)
        out.append(("100 deformables", authoring.save(stage, d / "many.usdc")))
    elif case == "huge":
        stage = _stage(3)
        _sheet(stage, "/World/Sheet")
        _box(stage, "/World/Mover", 3, 1.0, 0.4, mesh=subdivided_box(2_000_000))
        out.append(("2,000,000-triangle collider", authoring.save(stage, d / "huge.usdc")))
    elif case == "offset":
        stage = _stage(3)
        world = stage.GetPrimAtPath("/World")
        authoring.key_transform(world, 1, translate=(1e7, 1e7, 1e7))
        _sheet(stage, "/World/Sheet")
        _box(stage, "/World/Mover", 3, 1.0, 0.4)
        out.append(("offset 1e7 from the origin", authoring.save(stage, d / "offset.usdc")))
    elif case == "scale":
        for s in (1e-3, 1e3):
            stage = _stage(3)
            authoring.key_transform(stage.GetPrimAtPath("/World"), 1, scale=(s, s, s))
            _sheet(stage, "/World/Sheet")
            _box(stage, "/World/Mover", 3, 1.0, 0.4)
            out.append((f"scale {s:g}", authoring.save(stage, d / f"scale_{s:g}.usdc")))
    else:
        raise SystemExit(f"unknown case {case!r}")
    return out


def _predicted_mb(src: Path) -> float:
    """What `acra run` predicts ``src``'s run to peak at (`pipeline.guard.predict_memory`), MB."""
    from pxr import Usd

    from pipeline import guard

    stage = Usd.Stage.Open(str(src))
    frames = int(stage.GetEndTimeCode() - stage.GetStartTimeCode()) + 1
    return guard.predict_memory(stage, frames).nbytes / 2**20


def run(label: str, src: Path) -> dict:
    """Run ``acra run`` on ``src`` under ``/usr/bin/time -v``; figures of the run."""
    out, rep = src.with_suffix(".acra.usdc"), src.with_suffix(".json")
    cmd = ["/usr/bin/time", "-v", sys.executable, "-m", "pipeline.cli", "run", str(src), "-o", str(out),
           "--report", str(rep), "--quiet", "--over-tolerance", "warn"]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", done.stderr)
    row = {"case": label, "status": done.returncode, "wall_s": wall, "peak_mb": int(rss.group(1)) / 1024 if rss else None,
           "predicted_mb": _predicted_mb(src)}
    if rep.exists():
        data = json.loads(rep.read_text())
        per = data["per_frame"]
        ms = np.array([p["ms"]["total"] for p in per])
        free = np.array([p["ms"]["total"] for p in per if not p["in_collision"]])
        hit = np.array([p["ms"]["total"] for p in per if p["in_collision"]])
        # the whole run less the write, over the frames: includes evaluating the stage per frame
        # and the frame loop's own imports, which the per-stage figures leave out
        row["ms_run_per_frame"] = (1e3 * data["seconds"] - data["ms_write"]) / max(1, data["frames"])
        row.update(frames=data["frames"], in_collision=data["in_collision"], largest_residual=data["largest_residual"],
                   seconds=data["seconds"], ms_write=data["ms_write"], ms_frame_median=float(np.median(ms)) if ms.size else None,
                   ms_free_median=float(np.median(free)) if free.size else None,
                   ms_collision_median=float(np.median(hit)) if hit.size else None)
    else:
        row["error"] = done.stderr.strip().splitlines()[-25:]
    return row


def table(rows: list[dict]) -> str:
    """Markdown table of `run` rows: "process wall s" is the whole process (start-up included),
    "predicted MB" what the memory guard predicts before reading the stage (at least the peak),
    "run ms/frame" the run less the write over the frames, "stage ms/frame" the median of
    `FrameStats.ms_total` (detection, conversion, response, display; not the stage evaluation)."""
    head = ("| case | exit | frames (in collision) | process wall s | peak MB | predicted MB | run ms/frame | "
            "stage ms/frame median (free / collision) | write ms | largest residual |")
    lines = [head, "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    f = lambda x, spec: "—" if x is None else format(x, spec)  # noqa: E731
    for r in rows:
        lines.append(
            f"| {r['case']} | {r['status']} | {r.get('frames', '—')} ({r.get('in_collision', '—')}) | {r['wall_s']:.1f} | "
            f"{f(r['peak_mb'], '.0f')} | {f(r.get('predicted_mb'), '.0f')} | {f(r.get('ms_run_per_frame'), '.2f')} | "
            f"{f(r.get('ms_frame_median'), '.2f')} ({f(r.get('ms_free_median'), '.2f')} / "
            f"{f(r.get('ms_collision_median'), '.1f')}) | {f(r.get('ms_write'), '.0f')} | {f(r.get('largest_residual'), '.2e')} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="free,many,huge,offset,scale")
    ap.add_argument("--out", type=Path, help="keep stages, outputs and reports here (default: a temporary directory)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        d = args.out or Path(tmp)
        d.mkdir(parents=True, exist_ok=True)
        rows = []
        for case in args.cases.split(","):
            for label, src in build(case, d):
                rows.append(run(label, src))
                print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
        print(table(rows))


if __name__ == "__main__":
    main()
