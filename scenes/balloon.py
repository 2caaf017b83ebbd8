"""Volume preservation: a balloon pressed by a finger bulges around the dent and keeps its volume.

    python scenes/balloon.py          # writes balloon.usda beside this file
    acra run scenes/balloon.py --rrd balloon.rrd

Two identical balls (`acra.shapes.sphere`, 2 levels, absorption ``[0.3, 0.7]``) are each pressed
0.35 deep by a rigid finger (a sphere of radius 0.3) coming in along -x at frames 2-5.
``/World/Balloon`` has ``acra:preserveVolume = 1`` (``acra:bulgeLevel = 0``,
``acra:bulgeFalloff = 0.5``): its level-0 net bulges away from the dent so the display mesh
encloses the animator's volume. ``/World/Ball`` is the same press without it, and loses volume.
"""

from pathlib import Path

from acra import shapes
from pipeline import authoring as A
from pipeline.animation import usdkeys as K

BALLS = {"Balloon": (0.0, True), "Ball": (4.0, False)}  # name: (y of the centre, keeps its volume)
FINGER, DEPTH = 0.3, 0.35


def build():
    stage = A.new_stage(1, 6, fps=24, up_axis="Z")
    tip = A.uv_sphere(FINGER, 24, 12)
    for name, (y, keep) in BALLS.items():
        cvs, _, _ = shapes.sphere(8, 8, center=(0.0, y, 0.0))
        ball = A.add_deformable(stage, f"/World/{name}", cvs, u_wrap="periodic", v_wrap="open", levels=2,
                                absorption=[0.3, 0.7], samples=4)
        if keep:
            A.set_state_controls(ball, preserve_volume=1.0, bulge_level=0, bulge_falloff=0.5)
        finger = A.add_xform(stage, f"/World/{name}Finger")
        A.add_collider(stage, f"/World/{name}Finger/Tip", *tip)
        K.key_translate(finger, "x", [1.0, 5.0, 6.0], [1.0 + FINGER + 0.05, 1.0 + FINGER - DEPTH, 1.0 + FINGER + 0.3],
                        interp="linear")
        K.key_translate(finger, "y", [1.0], [y + 0.03])
        K.key_translate(finger, "z", [1.0], [0.02])
    return stage


if __name__ == "__main__":
    A.save(build(), Path(__file__).with_suffix(".usda"))
