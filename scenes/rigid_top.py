"""Thesis Fig. 5.4: a stiff pillow pressed onto a soft floor dents the floor.

    python scenes/rigid_top.py          # writes rigid_top.usda beside this file
    acra run scenes/rigid_top.py --rrd rigid_top.rrd

The stage of `rigid_floor` (Fig. 5.3) with the rigidities swapped: the pillow has rigidity 10,
the floor 1, so by eq. 4.15 the floor sinks by 10/11 of the overlap under the pillow's shape
and the pillow gives 1/11.
"""

from pathlib import Path

from pipeline.authoring import save
from scenes.rigid_floor import pillow_on_floor


def build():
    return pillow_on_floor(floor_rigidity=1.0, pillow_rigidity=10.0)


if __name__ == "__main__":
    save(build(), Path(__file__).with_suffix(".usda"))
