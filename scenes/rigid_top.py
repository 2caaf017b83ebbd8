"""Thesis Fig. 5.4: a stiff pillow pressed onto a soft floor dents the floor.

    python scenes/rigid_top.py          # writes rigid_top.usda beside this file
    acra run scenes/rigid_top.py --rrd rigid_top.rrd

The stage of `rigid_floor` (Fig. 5.3) with the rigidities swapped: the pillow has rigidity 10,
the floor 1, so by eq. 4.15 the floor sinks by 10/11 of the overlap under the pillow's shape
and the pillow gives 1/11. The shared stage is `scenes/_rigidity.py`.
"""

from pathlib import Path

from pipeline import authoring as A
from scenes._rigidity import build as _build


def build():
    return _build(rigid_floor=False)


if __name__ == "__main__":
    A.save(build(), Path(__file__).with_suffix(".usda"))
