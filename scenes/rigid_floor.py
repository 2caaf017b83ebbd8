"""Thesis Fig. 5.3: a soft pillow pressed onto a stiff floor takes the dent itself.

    python scenes/rigid_floor.py          # writes rigid_floor.usda beside this file
    acra run scenes/rigid_floor.py --rrd rigid_floor.rrd

Both objects are deformable H-splines with the same controls; the floor has rigidity 10, the
pillow 1, so by eq. 4.15 the pillow flattens by 10/11 of the overlap and the floor gives 1/11.
`rigid_top` is the same stage with the rigidities swapped (Fig. 5.4); the shared stage is
`scenes/_rigidity.py`.
"""

from pathlib import Path

from pipeline import authoring as A
from scenes._rigidity import build as _build


def build():
    return _build(rigid_floor=True)


if __name__ == "__main__":
    A.save(build(), Path(__file__).with_suffix(".usda"))
