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

from pipeline.authoring import save
from scenes.rolling_bump import bump_under_slab

#: the slab's underside (z) and the x of its leading face at the first and last frame (the crest
#: is at z = 0.405, x = 0, first touched between frames 4 and 5)
SLAB_Z = (0.5, 0.22)
SLAB_X = (0.1, 0.4)


def build():
    return bump_under_slab(12, absorption=[0, 0.5, 0.5], slab_z=SLAB_Z, slab_x=SLAB_X)


if __name__ == "__main__":
    save(build(), Path(__file__).with_suffix(".usda"))
