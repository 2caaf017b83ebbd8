"""Two soft tori slide into each other side by side and apart again; both give way.

    python scenes/sliding_tori.py          # writes sliding_tori.usda beside this file
    acra run scenes/sliding_tori.py --rrd sliding_tori.rrd

Both are closed deformables (`torus`, periodic both ways, 3 levels) lying in the xy-plane. The
left one rests at the origin; the right one's parent ``/World/Slider`` carries it along x from
2.9 (apart: the outer sides of the tubes are 0.2 apart) to 2.45 at frame 6 (the tubes overlap
0.25) and back to 2.8 at frame 11. Equal rigidities: by eq. 4.15 each takes half of the push.
"""

from pathlib import Path

from pipeline.authoring import add_surface, add_xform, key_translate, new_stage, save, torus

SLIDER_KEYS = ([1.0, 6.0, 11.0], [2.9, 2.45, 2.8])  # frame, x of the right torus's centre


def build():
    stage = new_stage(1, 11, fps=24, up_axis="Z")
    controls = dict(absorption=[0.2, 0.3, 0.5], rigidity=30.0, samples=4)
    add_surface(stage, "/World/Left", torus(12, 8, major=1.0, minor=0.35, levels=3), **controls)
    slider = add_xform(stage, "/World/Slider")
    add_surface(stage, "/World/Slider/Right", torus(12, 8, major=1.0, minor=0.35, levels=3), **controls)
    key_translate(slider, "x", *SLIDER_KEYS, interp="catmull_rom")
    return stage


if __name__ == "__main__":
    save(build(), Path(__file__).with_suffix(".usda"))
