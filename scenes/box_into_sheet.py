"""A box drops into a soft sheet and stays there: the sheet is pushed out below it.

    python scenes/box_into_sheet.py          # writes box_into_sheet.usda beside this file
    acra run scenes/box_into_sheet.py --rrd box_into_sheet.rrd

The box jumps 70% of its height through the sheet in one frame (10 → 11) and stays for five
frames; ACRA rewinds to where the box first touched, so the sheet is dented the way the box came.
"""

from pathlib import Path

from pipeline.authoring import add_collider, add_surface, add_xform, box, key_translate, new_stage, save, sheet


def build():
    stage = new_stage(1, 16, fps=24, up_axis="Z")
    add_surface(stage, "/World/Sheet", sheet(12, 12, width=4.0, depth=4.0, levels=3), absorption=[0.2, 0.3, 0.5],
                rigidity=10, samples=4)
    mover = add_xform(stage, "/World/Mover")
    add_collider(stage, "/World/Mover/Box", *box(1.0))
    # native USD splines on single-axis translate ops (linear knots: the jump at 10 -> 11 is kept)
    key_translate(mover, "x", [1, 16], [0.2, 0.2])
    key_translate(mover, "y", [1, 16], [-0.1, -0.1])
    key_translate(mover, "z", [1, 10, 11, 16], [1.5, 0.55, -0.2, -0.2], interp="linear")
    return stage


if __name__ == "__main__":
    save(build(), Path(__file__).with_suffix(".usda"))
