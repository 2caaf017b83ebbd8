"""A soft sheet on a turntable turns about z while a box comes down on it and presses it.

    python scenes/turning_press.py          # writes turning_press.usda beside this file
    acra run scenes/turning_press.py --rrd turning_press.rrd

The sheet (4 x 4 units, 13 x 13 level-0 patches, 3 levels) is the child of ``/World/Turntable``, which turns 60 degrees
about z from frame 1 to frame 12. The box does not turn: it comes down over the world point
(0.7, 0.3) until its underside is 0.2 below the sheet at frame 8 and holds there, so the sheet's
material slides under the pressing box and the dent moves across the sheet in object space while
it stays under the box in the world.
"""

from pathlib import Path

from pipeline.authoring import add_collider, add_surface, add_xform, box, key_rotate, key_translate, new_stage, save, sheet

TURN = ([1, 12], [0.0, 60.0])  # frame, the turntable's angle about z (degrees)
BOX_XY = (0.7, 0.3)
BOX_Z = ([1, 8, 12], [0.8, 0.5 - 0.2, 0.5 - 0.2])  # frame, z of the 1-unit box's centre


def build():
    stage = new_stage(1, 12, fps=24, up_axis="Z")
    table = add_xform(stage, "/World/Turntable")
    add_surface(stage, "/World/Turntable/Sheet", sheet(16, 16, width=4.0, depth=4.0, levels=3),
                absorption=[0.2, 0.3, 0.5], rigidity=10, samples=4)
    key_rotate(table, "z", *TURN)
    mover = add_xform(stage, "/World/Mover")
    add_collider(stage, "/World/Mover/Box", *box(1.0, center=(*BOX_XY, 0.0)))  # the box stands over BOX_XY
    key_translate(mover, "z", *BOX_Z)
    return stage


if __name__ == "__main__":
    save(build(), Path(__file__).with_suffix(".usda"))
