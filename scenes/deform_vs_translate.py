"""Two identical spikes, two identical rigid planes pushing down on them (thesis Fig. 5.7–5.9):
the left spike responds by deformation, the right one by translation, both on the finest level.

    python scenes/deform_vs_translate.py          # writes deform_vs_translate.usda beside this file
    acra run scenes/deform_vs_translate.py --rrd deform_vs_translate.rrd

Each spike is local detail on level 2 of a 3-level sheet and all of the response is absorbed on
level 2, as in the thesis. The deformed spike's tip is flattened against the plane; the
translated spike keeps its shape and is pushed down into the sheet as a whole. The planes are
thicker (0.3) than the spikes reach into them (0.15), so a tip never pokes out of the top.
"""

from pathlib import Path

from pipeline import authoring as A
from pipeline.animation import usdkeys as K
from scenes._spikes import feature_sheet

#: x of the two spikes' centres (deform, translate)
SPIKES = {"Deform": -2.0, "Translate": 2.0}
#: z of the planes' underside at the first and last frame; the spikes' tips are at z = 0.47
PLANE_Z = (0.56, 0.32)


def build():
    stage = A.new_stage(1, 12, fps=24, up_axis="Z")
    cvs, hs = feature_sheet(tip=0.8, spread=0.3)
    for name, x in SPIKES.items():
        group = A.add_xform(stage, f"/World/{name}")
        A.key_transform(group, 1, translate=(x, 0.0, 0.0))
        mix = {"deform": [1, 1, 1]} if name == "Deform" else {"deform": [1, 1, 0], "translate": [0, 0, 1]}
        A.add_deformable(stage, f"/World/{name}/Sheet", cvs, levels=3, absorption=[0, 0, 1], rigidity=10,
                         samples=8, hierarchy=hs, **mix)
        plane = A.add_xform(stage, f"/World/{name}/Mover")
        A.add_collider(stage, f"/World/{name}/Mover/Plane", *A.box((1.2, 1.2, 0.3), center=(0.0, 0.0, 0.15)))
        # native USD spline, linear: the plane (underside at local z = 0) comes down 0.022 per frame
        K.key_translate(plane, "z", [1, 12], list(PLANE_Z))
    return stage


if __name__ == "__main__":
    A.save(build(), Path(__file__).with_suffix(".usda"))
