"""The thesis's benchmark (Fig. 5.1–5.2): a spike jabs the cheek of a large, detailed head.

    python scenes/dog_head_spike.py          # writes dog_head_spike.usda beside this file
    acra run scenes/dog_head_spike.py --rrd dog_head_spike.rrd

The head has 7 levels and about 2200 stored CVs: a 16×12 closed level-0 grid (poles top and
bottom, the snout toward +x) with detail modelled locally — snout and ears on level 1, muzzle and
brows on level 2, nose on levels 4–5, nostrils on level 6 — so most of the model exists only
where it has detail (a dense level 6 would hold 700 000 CVs). The spike is a cone with 3 levels
and 89 CVs, keyed to jab the side of the head and pull back: 30 frames, 4 of them in collision.
The head is soft (rigidity 10) and the spike stiff (80), so by eq. 4.15 the head takes 8/9 of the
response, absorbed on levels 2–4 (a dent the size of the spike's tip); the spike's on levels 1–2.
"""

from pathlib import Path

from pipeline.authoring import add_bump, add_surface, add_xform, cone, key_translate, new_stage, refine_region, save, sphere, turned

# (level, centre (u, v), radii (u, v), height): u = 0 faces +x, u = 4 faces +y; v = 4.5 is the equator
FEATURES = [
    (1, (0.0, 4.5), (1.5, 1.4), 0.45),  # snout
    (1, (3.0, 7.0), (0.6, 0.8), 0.5),  # ears
    (1, (13.0, 7.0), (0.6, 0.8), 0.5),
    (2, (0.0, 4.6), (0.6, 0.5), 0.12),  # muzzle
    (2, (1.4, 5.8), (0.5, 0.2), 0.05),  # brows
    (2, (14.6, 5.8), (0.5, 0.2), 0.05),
    (4, (0.0, 4.9), (0.25, 0.2), 0.07),  # nose
    (5, (0.0, 5.0), (0.1, 0.08), 0.025),  # nose tip
    (6, (-0.05, 4.97), (0.035, 0.03), -0.01),  # nostrils
    (6, (0.05, 4.97), (0.035, 0.03), -0.01),
]


def head():
    """The head: level-0 CVs ``(16, 12, 3) float64`` and its 7-level `HSpline`."""
    surface = sphere(16, 12, radii=(1.0, 0.85, 0.9), levels=7)
    for feature in FEATURES:
        surface = add_bump(surface, *feature)
    return surface.cvs, surface


def spike():
    """The spike: a cone along −y (tip at y = −0.6), CVs ``(8, 8, 3)``, level 1 refined at the tip."""
    surface = refine_region(turned(cone(8, 8, radius=0.18, height=1.2, levels=3), "x"), 1, u=(0, 1), v=(4, 5))
    return surface.cvs, surface


def build():
    stage = new_stage(1, 30, fps=24, up_axis="Z")
    add_surface(stage, "/World/Head", head()[1], absorption=[0, 0, 0.2, 0.3, 0.5, 0, 0], rigidity=10, samples=4)
    mover = add_xform(stage, "/World/Jab")
    add_surface(stage, "/World/Jab/Spike", spike()[1], absorption=[0, 0.5, 0.5], rigidity=80, samples=4)
    # the tip approaches the cheek (+y side), goes 0.1 deep at frame 15 and pulls back
    key_translate(mover, "xyz", [1, 12, 15, 18, 30], [[0.1, 2.2, 0.15], [0.1, 1.5, 0.1], [0.1, 1.36, 0.08],
                                                      [0.1, 1.5, 0.1], [0.1, 2.2, 0.15]], interp="catmull_rom")
    return stage


if __name__ == "__main__":
    save(build(), Path(__file__).with_suffix(".usda"))
