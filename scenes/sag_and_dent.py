"""Two hierarchy levels relaxing at their own rates: a fast fine dent on a slow coarse sag.

    python scenes/sag_and_dent.py          # writes sag_and_dent.usda beside this file
    acra run scenes/sag_and_dent.py --rrd sag_and_dent.rrd

A sheet (2 levels, absorption ``[0.3, 0.7]``: 30 % of every response on the coarse level-0 net,
70 % on the fine level 1) is pressed 0.1 deep by a rigid ball (radius 0.6) at frames 2-3; gone from
frame 5. ``acra:relax = [0.1, 0.6]``: the coarse sag releases a tenth of what it carries per frame,
the fine dent sixty per cent, so a few frames later the dent has gone while the sag is still
there, easing back over many frames.
"""

from pathlib import Path

from pipeline.authoring import (
    add_collider, add_surface, add_xform, key_translate, new_stage, save, set_state_controls,
    sheet, uv_sphere,
)

RELAX = [0.1, 0.6]
RADIUS, DEPTH = 0.6, 0.1


def build():
    stage = new_stage(1, 10, fps=24, up_axis="Z")
    prim = add_surface(stage, "/World/Sheet", sheet(8, 8, width=2.5, depth=2.5, levels=2), absorption=[0.3, 0.7], samples=8)
    set_state_controls(prim, relax=RELAX)
    mover = add_xform(stage, "/World/Mover")
    add_collider(stage, "/World/Mover/Ball", *uv_sphere(RADIUS, 48, 24))
    key_translate(mover, "x", [1], [0.04])
    key_translate(mover, "y", [1], [0.03])
    key_translate(mover, "z", [1, 3, 5], [RADIUS + 0.02, RADIUS - DEPTH, RADIUS + 0.5], interp="linear")
    return stage


if __name__ == "__main__":
    save(build(), Path(__file__).with_suffix(".usda"))
