"""The CCM paper's arm experiment: volume of a bent cylinder "arm" per skinning method.

A cylinder control grid (periodic around, open along) on a two-bone skeleton is bent at the
elbow from 0° to 120°; for each method the enclosed volume is divided by the rest volume.

    python benchmarks/arm_volume.py                 # the tables in docs/deformers.md
    python benchmarks/arm_volume.py --step 10
    python benchmarks/arm_volume.py --fine          # plus 16 x 48 and 32 x 96 (~35 s)

Tables printed:
1. 8 × 12 grid, volume of the capped control polyhedron (PSD samples 12 vertices, CCM 4);
2. the same grid, volume of the capped bicubic B-spline surface (4 steps per patch edge);
3. 8 × 24 grid, bicubic surface (the bend then spans 8 rings; PSD 24 vertices, CCM 8);
4. ablation on 8 × 12: CCM with *every* blended-ring vertex free except the 4-vertex sample
   (``ccm-wide``) and the sculpted sample shape itself (``sculpt``, the volume-preserving target);
5. with ``--fine``: the surface volume at the largest angle on finer grids.
Volumes are checked against trimesh's on the same closed mesh.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from pipeline.animation import skinning as sk  # noqa: E402

METHODS = ("lbs", "dqs", "psd", "ccm")


def volume(cvs, samples):
    v = sk.grid_volume(cvs, samples=samples)
    V, F = sk.tube_mesh(cvs, samples=samples)
    tv = abs(trimesh.Trimesh(V, F, process=False).volume)
    assert np.isclose(v, tv, rtol=1e-9), (v, tv)
    return v


def ratios(rig, method, angles, samples):
    v0 = volume(rig.rest, samples)
    if method == "sculpt":
        grids = [sk.arm_sample(rig, a) for a in angles]
    else:
        grids = sk.bent_arm(angles, method, rig)
    return np.array([volume(g, samples) / v0 for g in grids])


def table(title, rig, angles, samples, methods):
    cols = {m: ratios(rig, m, angles, samples) for m in methods}
    print(f"\n{title}")
    print("| angle | " + " | ".join(methods) + " |")
    print("|---:|" + "---:|" * len(methods))
    for k, a in enumerate(np.degrees(angles)):
        print(f"| {a:5.0f}° | " + " | ".join(f"{cols[m][k]:.3f}" for m in methods) + " |")
    worst = {m: cols[m][np.argmax(np.abs(cols[m] - 1))] for m in methods}
    print("| worst | " + " | ".join(f"{worst[m]:.3f}" for m in methods) + " |")
    return cols


def wide_ccm_rig(rig):
    """CCM with all blended-ring vertices free except the sample cluster (the ablation)."""
    w1 = rig.weights[..., 1]
    labels = np.where((w1 > 0) & (w1 < 1), sk.LABEL_FREE, sk.LABEL_LBS).astype(np.int8)
    labels.ravel()[rig.ccm_sample_vertices] = sk.LABEL_SAMPLE
    plan = sk.ccm_plan(rig.rest, labels != sk.LABEL_FREE, (True, False), rig.plan.tension)
    return dataclasses.replace(rig, labels=labels, plan=plan)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--step", type=float, default=15.0, help="angle step in degrees")
    ap.add_argument("--max-angle", type=float, default=120.0)
    ap.add_argument("--fine", action="store_true",
                    help="also the surface volume at the largest angle on finer grids (~35 s)")
    args = ap.parse_args(argv)
    angles = np.radians(np.arange(0.0, args.max_angle + 1e-9, args.step))
    t0 = time.perf_counter()
    rig = sk.arm_rig()
    print(f"arm 8 x 12, radius 1, length 11, elbow at 5.5, weight ramp ±{rig.blend:g}; "
          f"PSD samples {len(rig.psd_vertices)} vertices, CCM {len(rig.ccm_sample_vertices)}; "
          f"one sample pose at {np.degrees(rig.sample_angle):.0f}°, tension q = {rig.plan.tension}")
    table("1. 8 x 12, control polyhedron volume / rest", rig, angles, 0, METHODS)
    table("2. 8 x 12, bicubic surface volume / rest", rig, angles, 4, METHODS)
    fine = sk.arm_rig(n_along=24)
    print(f"\n(8 x 24: PSD samples {len(fine.psd_vertices)} vertices, "
          f"CCM {len(fine.ccm_sample_vertices)})")
    table("3. 8 x 24, bicubic surface volume / rest", fine, angles, 4, METHODS)
    wide = wide_ccm_rig(rig)
    cols = {"ccm-wide": ratios(wide, "ccm", angles, 0), "sculpt": ratios(rig, "sculpt", angles, 0)}
    print("\n4. 8 x 12, control polyhedron, ablation")
    print("| angle | ccm-wide | sculpt |\n|---:|---:|---:|")
    for k, a in enumerate(np.degrees(angles)):
        print(f"| {a:5.0f}° | {cols['ccm-wide'][k]:.3f} | {cols['sculpt'][k]:.3f} |")
    if args.fine:
        print(f"\n5. bicubic surface volume / rest at {np.degrees(angles[-1]):.0f}°, finer grids")
        print("| grid | PSD / CCM vertices | lbs | dqs | psd | ccm | sculpt |")
        print("|---|---|---:|---:|---:|---:|---:|")
        for nu, nv in ((8, 12), (8, 24), (16, 48), (32, 96)):
            r = sk.arm_rig(n_around=nu, n_along=nv)
            vals = [ratios(r, m, angles[-1:], 4)[0] for m in METHODS + ("sculpt",)]
            print(f"| {nu} x {nv} | {len(r.psd_vertices)} / {len(r.ccm_sample_vertices)} | "
                  + " | ".join(f"{v:.3f}" for v in vals) + " |")
    print(f"\n({time.perf_counter() - t0:.2f} s)")


if __name__ == "__main__":
    main()
