"""A skinned arm bends at the elbow and its forearm swings into a rigid ball.

    python scenes/elbow_contact.py          # writes elbow_contact.usda beside this file
    acra run scenes/elbow_contact.py --rrd elbow_contact.rrd

The arm is the H-spline tube of `pipeline.authoring.add_skinned_arm` (8 CVs around, periodic
u; 12 along +x, open v) bent toward +y by the Control Cluster Method, one skinned level-0 grid
per frame written as ``acra:cvs`` time samples; the UsdSkel skeleton beside it only shows the
rig. The elbow is keyed 0° → 110° with a cubic ease-out, so the
forearm slows as it reaches the ball, which it enters for the last six frames, up to 0.2 deep
(a fifth of the arm's radius). ACRA dents the forearm around the ball: only levels 1 and 2
absorb (thesis eq. 4.12), so the dent is local and the rest of the skinned arm is untouched.
"""

from pathlib import Path

import numpy as np

from pipeline.authoring import add_collider, add_skinned_arm, keyed_values, new_stage, save, uv_sphere

FRAMES = np.arange(1, 21)
ELBOW_KEYS = ([1.0, 20.0], [0.0, 110.0])  # frame, elbow angle (degrees)
BALL_RADIUS = 0.8
BALL_FROM_ELBOW = (4.0, 132.0)  # distance and direction (degrees from +x) of the ball's centre


def elbow_angles() -> np.ndarray:
    """Elbow angle at each of `FRAMES`, radians ``(F,) float64``: the keys eased out (cubic)."""
    return np.radians(keyed_values(*ELBOW_KEYS, FRAMES, "cubic", mode="out"))


def ball_center(rig) -> np.ndarray:
    """The ball's centre ``(3,) float64`` in the forearm's sweep (the xy-plane)."""
    dist, deg = BALL_FROM_ELBOW
    return np.array([rig.elbow + dist * np.cos(np.radians(deg)), dist * np.sin(np.radians(deg)), 0.0])


def build():
    stage = new_stage(int(FRAMES[0]), int(FRAMES[-1]), fps=24, up_axis="Z")
    rig = add_skinned_arm(stage, "/World/Arm", FRAMES, elbow_angles(), "ccm", levels=3, absorption=[0.0, 0.4, 0.6],
                          samples=4)
    add_collider(stage, "/World/Ball", *uv_sphere(BALL_RADIUS, 24, 12, center=ball_center(rig)))
    return stage


if __name__ == "__main__":
    save(build(), Path(__file__).with_suffix(".usda"))
