"""Volume preservation: a balloon pressed by a finger bulges around the dent and keeps its volume.

    python scenes/balloon.py          # writes balloon.usda beside this file
    acra run scenes/balloon.py --rrd balloon.rrd

Two identical balls (2 levels, absorption ``[0.3, 0.7]``) are each pressed
0.35 deep by a rigid finger (a sphere of radius 0.3) coming in along -x at frames 2-5.
``/World/Balloon`` has ``acra:preserveVolume = 1`` (``acra:bulgeLevel = 0``,
``acra:bulgeFalloff = 0.5``): its level-0 net bulges away from the dent so the display mesh
encloses the animator's volume. ``/World/Ball`` is the same press without it, and loses volume.
"""

from pathlib import Path

from pipeline.authoring import (
    add_collider, add_surface, add_xform, key_translate, new_stage, save, set_state_controls,
    sphere, uv_sphere,
)

BALLS = {"Balloon": (0.0, True), "Ball": (4.0, False)}  # name: (y of the centre, keeps its volume)
FINGER, DEPTH = 0.3, 0.35


def build():
    stage = new_stage(1, 6, fps=24, up_axis="Z")
    tip = uv_sphere(FINGER, 24, 12)
    for name, (y, keep) in BALLS.items():
        ball = add_surface(stage, f"/World/{name}", sphere(8, 8, center=(0.0, y, 0.0), levels=2), absorption=[0.3, 0.7],
                           samples=4)
        if keep:
            set_state_controls(ball, preserve_volume=1.0, bulge_level=0, bulge_falloff=0.5)
        finger = add_xform(stage, f"/World/{name}Finger")
        add_collider(stage, f"/World/{name}Finger/Tip", *tip)
        key_translate(finger, "x", [1.0, 5.0, 6.0], [1.0 + FINGER + 0.05, 1.0 + FINGER - DEPTH, 1.0 + FINGER + 0.3],
                        interp="linear")
        key_translate(finger, "y", [1.0], [y + 0.03])
        key_translate(finger, "z", [1.0], [0.02])
    return stage


if __name__ == "__main__":
    save(build(), Path(__file__).with_suffix(".usda"))
