"""Two closed deformables collide: a ball with poles and a torus carried by a spline-keyed parent.

    python scenes/closed_objects.py          # writes closed_objects.usda beside this file
    acra run scenes/closed_objects.py --rrd closed_objects.rrd

The ball (`acra.shapes.sphere`: periodic u, open v, each pole a collapsed CV row) rests at the
origin. The torus (`acra.shapes.torus`, periodic both ways) lies in the same plane; its parent
Xform ``/World/Carrier`` slides it along x with a native USD spline (Catmull-Rom keys through
`usdkeys.key_translate`), so the outside of its tube presses into the ball's equator, 0.2 deep
at the turn, and pulls back out. Both objects deform (thesis eq. 4.15): the ball has rigidity 20
and the torus 60, so the ball takes 3/4 of the push and the torus 1/4. Level 0 absorbs a share of
each response, which moves the ball's CVs next to its poles: the poles must stay closed.
"""

from pathlib import Path

from pipeline.authoring import add_surface, add_xform, key_translate, new_stage, save, sphere, torus

CARRIER_KEYS = ([1.0, 5.0, 7.0, 11.0], [2.9, 2.2, 2.2, 2.7])  # frame, x of the torus's centre
RIGIDITY = {"ball": 20.0, "torus": 60.0}


def build():
    stage = new_stage(1, 11, fps=24, up_axis="Z")
    controls = dict(absorption=[0.2, 0.3, 0.5], samples=4)
    add_surface(stage, "/World/Ball", sphere(8, 8, levels=3), rigidity=RIGIDITY["ball"], **controls)
    carrier = add_xform(stage, "/World/Carrier")
    add_surface(stage, "/World/Carrier/Torus", torus(12, 8, major=1.0, minor=0.35, levels=3), rigidity=RIGIDITY["torus"],
                **controls)
    key_translate(carrier, "x", *CARRIER_KEYS, interp="catmull_rom")
    return stage


if __name__ == "__main__":
    save(build(), Path(__file__).with_suffix(".usda"))
