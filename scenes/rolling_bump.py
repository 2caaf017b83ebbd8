"""A slab slides over a bump whose response is rotational on level 2 (thesis Fig. 5.10): the bump
turns over in the direction the slab moves until the slab slides past it.

    python scenes/rolling_bump.py          # writes rolling_bump.usda beside this file
    acra run scenes/rolling_bump.py --rrd rolling_bump.rrd

The bump is local detail on level 2 of a 3-level sheet, and level 2 absorbs all of the response
as a rotation (the thesis: "since that is the level where the control vertices were offset to
create the bump"). The rotation turns the bump's detail about its base on the level-1 surface.
"""

from pathlib import Path

from pipeline.authoring import add_collider, add_spike, add_surface, add_xform, box, key_translate, new_stage, save, sheet

#: the slab's underside (z) and the x of its leading face at the first and last frame (the
#: bump's crest is at z = 0.405, x = 0, and it rises above the underside from x = -0.252: the face
#: first cuts it between frames 3 and 4, and is past its far foot, x = 0.48, from frame 9 on)
SLAB_Z = 0.2
SLAB_X = (-0.6, 0.76)


def bump_under_slab(last_frame: int, absorption, slab_z, slab_x):
    """The stage: a bump on level 2 of a 3-level sheet, level 2 rotational, and a slab keyed
    linearly from frame 1 to ``last_frame`` through ``slab_z`` (underside) and ``slab_x`` (leading face)."""
    stage = new_stage(1, last_frame, fps=24, up_axis="Z")
    bump = add_spike(sheet(7, 7, width=3.0, depth=3.0, levels=3), level=2, height=0.5, spread=0.7)
    add_surface(stage, "/World/Sheet", bump, absorption=absorption, deform=[1, 1, 0], rotate=[0, 0, 1],
                rigidity=10, samples=8)
    slab = add_xform(stage, "/World/Mover")
    # the slab's leading face is at local x = 0, its underside at local z = 0
    add_collider(stage, "/World/Mover/Slab", *box((1.2, 1.2, 0.3), center=(-0.6, 0.0, 0.15)))
    key_translate(slab, "z", [1, last_frame], list(slab_z))
    key_translate(slab, "x", [1, last_frame], list(slab_x))
    return stage


def build():
    return bump_under_slab(11, absorption=[0, 0, 1], slab_z=(SLAB_Z, SLAB_Z), slab_x=SLAB_X)


if __name__ == "__main__":
    save(build(), Path(__file__).with_suffix(".usda"))
