"""Plasticity: a clay sheet that keeps its dent and one that keeps half of it (thesis §5.4).

    python scenes/clay.py          # writes clay.usda beside this file
    acra run scenes/clay.py --rrd clay.rrd

Two identical sheets (2 levels, the response on level 1) are pressed 0.12 deep by identical rigid
balls at frames 2-4; the balls are gone from frame 6. ``/World/Full/Sheet`` has
``acra:plasticity = 1``: every response is kept for good, so the dent stays exactly as the last
press left it. ``/World/Half/Sheet`` has ``acra:plasticity = 0.5`` and holds its elastic half while
pressed (``acra:relax`` keyed 0 up to frame 4), then releases it at once (1 from frame 5): from
frame 5 on it keeps exactly half of the dent, coefficient by coefficient.
"""

from pathlib import Path

from pipeline.authoring import (
    add_collider, add_surface, add_xform, key_relax, key_translate, moved, new_stage, save,
    set_state_controls, sheet, uv_sphere,
)

SHEETS = {"Full": (-2.0, 1.0), "Half": (2.0, 0.5)}  # name: (x of the centre, plasticity)
RADIUS, DEPTH = 0.45, 0.12


def build():
    stage = new_stage(1, 8, fps=24, up_axis="Z")
    clay = sheet(8, 8, width=2.5, depth=2.5, levels=2)  # 5x5 patches of 0.5
    ball = uv_sphere(RADIUS, 48, 24)
    for name, (x, plasticity) in SHEETS.items():
        prim = add_surface(stage, f"/World/{name}/Sheet", moved(clay, (x, 0.0, 0.0)), absorption=[0.0, 1.0], samples=8)
        set_state_controls(prim, plasticity=plasticity)
        if plasticity < 1.0:
            key_relax(prim, 4, [0.0, 0.0])
            key_relax(prim, 5, [1.0, 1.0])
        mover = add_xform(stage, f"/World/{name}/Mover")
        add_collider(stage, f"/World/{name}/Mover/Ball", *ball)
        key_translate(mover, "x", [1], [x + 0.05])
        key_translate(mover, "y", [1], [0.03])
        key_translate(mover, "z", [1, 4, 6], [RADIUS + 0.05, RADIUS - DEPTH, RADIUS + 0.4], interp="linear")
    return stage


if __name__ == "__main__":
    save(build(), Path(__file__).with_suffix(".usda"))
