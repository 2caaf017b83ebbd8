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

from pipeline.authoring import add_collider, add_spike, add_surface, add_xform, box, key_transform, key_translate, new_stage, save, sheet

#: x of the two spikes' centres (deform, translate)
SPIKES = {"Deform": -2.0, "Translate": 2.0}
#: z of the planes' underside at the first and last frame; the spikes' tips are at z = 0.47
PLANE_Z = (0.56, 0.32)


def build():
    stage = new_stage(1, 12, fps=24, up_axis="Z")
    spiked = add_spike(sheet(7, 7, width=3.0, depth=3.0, levels=3), level=2, height=0.8, spread=0.3)
    for name, x in SPIKES.items():
        group = add_xform(stage, f"/World/{name}")
        key_transform(group, 1, translate=(x, 0.0, 0.0))
        mix = {"deform": [1, 1, 1]} if name == "Deform" else {"deform": [1, 1, 0], "translate": [0, 0, 1]}
        add_surface(stage, f"/World/{name}/Sheet", spiked, absorption=[0, 0, 1], rigidity=10, samples=8, **mix)
        plane = add_xform(stage, f"/World/{name}/Mover")
        add_collider(stage, f"/World/{name}/Mover/Plane", *box((1.2, 1.2, 0.3), center=(0.0, 0.0, 0.15)))
        # native USD spline, linear: the plane (underside at local z = 0) comes down 0.022 per frame
        key_translate(plane, "z", [1, 12], list(PLANE_Z))
    return stage


if __name__ == "__main__":
    save(build(), Path(__file__).with_suffix(".usda"))
