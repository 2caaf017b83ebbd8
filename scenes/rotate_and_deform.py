"""A slab comes down on a bump and moves on across it; the bump responds half by deformation on
level 1 and half by rotation on level 2 (thesis Fig. 5.11).

    python scenes/rotate_and_deform.py          # writes rotate_and_deform.usda beside this file
    acra run scenes/rotate_and_deform.py --rrd rotate_and_deform.rrd

The bump and slab are those of `rolling_bump` (Fig. 5.10); the slab's underside meets the crest
and pushes it down and forward. Level 1 absorbs half of the response as a deformation: the sheet
under the bump is dented and carries the bump with it; level 2 absorbs the other half as a
rotation: the bump's detail turns over in the direction of the motion.
"""

from pathlib import Path

from pipeline.authoring import add_collider, add_spike, add_surface, add_xform, box, key_translate, new_stage, save, sheet

#: the slab's underside (z) and the x of its leading face at the first and last frame (the crest
#: is at z = 0.405, x = 0, first touched between frames 4 and 5)
SLAB_Z = (0.5, 0.22)
SLAB_X = (0.1, 0.4)


def build():
    stage = new_stage(1, 12, fps=24, up_axis="Z")
    bump = add_spike(sheet(7, 7, width=3.0, depth=3.0, levels=3), level=2, height=0.5, spread=0.7)
    add_surface(stage, "/World/Sheet", bump, absorption=[0, 0.5, 0.5], deform=[1, 1, 0], rotate=[0, 0, 1],
                rigidity=10, samples=8)
    slab = add_xform(stage, "/World/Mover")
    # the slab's leading face is at local x = 0, its underside at local z = 0
    add_collider(stage, "/World/Mover/Slab", *box((1.2, 1.2, 0.3), center=(-0.6, 0.0, 0.15)))
    key_translate(slab, "z", [1, 12], list(SLAB_Z))
    key_translate(slab, "x", [1, 12], list(SLAB_X))
    return stage


if __name__ == "__main__":
    save(build(), Path(__file__).with_suffix(".usda"))
