"""A soft ball pressed by a finger recovers its shape over the following frames (thesis §5.4).

    python scenes/soft_ball.py          # writes soft_ball.usda beside this file
    acra run scenes/soft_ball.py --rrd soft_ball.rrd

A ball (2 levels, absorption ``[0.4, 0.6]``) rests at the origin. A
finger, a rigid sphere of radius 0.3, comes in along -x, presses 0.15 into the ball at frame 4
and leaves by frame 6. The ball carries its dent across frames (``acra:relax = [0.5, 0.7]``):
after the finger has left, level 0 releases half of what it still carries at every frame and
level 1 seventy per cent, so the dent fades geometrically, each level at its own rate.
"""

from pathlib import Path

from pipeline.authoring import (
    add_collider, add_surface, add_xform, key_translate, new_stage, save, set_state_controls,
    sphere, uv_sphere,
)

RELAX = [0.5, 0.7]
FINGER = 0.3  # radius
PRESS = ([1.0, 4.0, 6.0], [1.0 + FINGER + 0.05, 1.0 + FINGER - 0.15, 1.0 + FINGER + 0.6])  # frame, x of its centre


def build():
    stage = new_stage(1, 12, fps=24, up_axis="Z")
    ball = add_surface(stage, "/World/Ball", sphere(8, 8, levels=2), absorption=[0.4, 0.6], samples=4)
    set_state_controls(ball, relax=RELAX)
    finger = add_xform(stage, "/World/Finger")
    add_collider(stage, "/World/Finger/Tip", *uv_sphere(FINGER, 24, 12))
    key_translate(finger, "x", *PRESS, interp="linear")
    key_translate(finger, "y", [1.0], [0.03])
    key_translate(finger, "z", [1.0], [0.02])
    return stage


if __name__ == "__main__":
    save(build(), Path(__file__).with_suffix(".usda"))
