"""A box drops into a soft sheet and stays there: the sheet is pushed out below it.

    python scenes/box_into_sheet.py          # writes box_into_sheet.usda beside this file
    acra run scenes/box_into_sheet.py --rrd box_into_sheet.rrd

The box jumps 70% of its height through the sheet in one frame (10 → 11) and stays for five
frames; ACRA rewinds to where the box first touched, so the sheet is dented the way the box came.
"""

from pathlib import Path

import numpy as np

from acra import shapes
from pipeline import authoring as A
from pipeline.animation import usdkeys as K


def build():
    stage = A.new_stage(1, 16, fps=24, up_axis="Z")
    cvs, _, _ = shapes.sheet(12, 12, width=4.0, depth=4.0)
    A.add_deformable(
        stage, "/World/Sheet", cvs, levels=3, absorption=[0.2, 0.3, 0.5], rigidity=10, samples=4,
    )
    verts, faces = A.box(1.0)
    box = A.add_xform(stage, "/World/Mover")
    A.add_collider(stage, "/World/Mover/Box", verts, faces)
    # native USD splines on single-axis translate ops (linear knots: the jump at 10 -> 11 is kept)
    K.key_translate(box, "x", [1, 16], [0.2, 0.2])
    K.key_translate(box, "y", [1, 16], [-0.1, -0.1])
    K.key_translate(box, "z", [1, 10, 11, 16], [1.5, 0.55, -0.2, -0.2], interp="linear")
    return stage


if __name__ == "__main__":
    A.save(build(), Path(__file__).with_suffix(".usda"))
