"""A box presses a soft sheet off its centre, near one corner: the dent stays under the box.

    python scenes/off_centre_press.py          # writes off_centre_press.usda beside this file
    acra run scenes/off_centre_press.py --rrd off_centre_press.rrd

The sheet is 4 x 4 units (9 x 9 level-0 patches, 3 levels). A 0.8-unit box comes straight down
over the point (1.1, -0.9), a patch and a half from two edges, from frame 1 to frame 9, until
its underside is 0.25 below the sheet, and stays there to frame 12. The dent must follow the
box's underside and leave the far side of the sheet where the animator put it.
"""

from pathlib import Path

from pipeline.authoring import add_collider, add_surface, add_xform, box, key_translate, new_stage, save, sheet

BOX_XY = (1.1, -0.9)  # where the box's centre comes down (world units)
BOX_SIZE = 0.8
BOX_Z = ([1, 9, 12], [0.8, 0.4 - 0.25, 0.4 - 0.25])  # frame, z of the box's centre (underside = z - 0.4)


def build():
    stage = new_stage(1, 12, fps=24, up_axis="Z")
    add_surface(stage, "/World/Sheet", sheet(12, 12, width=4.0, depth=4.0, levels=3), absorption=[0.2, 0.3, 0.5],
                rigidity=10, samples=4)
    mover = add_xform(stage, "/World/Mover")
    add_collider(stage, "/World/Mover/Box", *box(BOX_SIZE))
    key_translate(mover, "xyz", BOX_Z[0], [[*BOX_XY, z] for z in BOX_Z[1]])
    return stage


if __name__ == "__main__":
    save(build(), Path(__file__).with_suffix(".usda"))
