"""Thesis Fig. 5.3: a soft pillow pressed onto a stiff floor takes the dent itself.

    python scenes/rigid_floor.py          # writes rigid_floor.usda beside this file
    acra run scenes/rigid_floor.py --rrd rigid_floor.rrd

A pillow is pressed 0.1 into a floor slab and lifted off. Both are deformable with the same
controls (3 levels, absorbed half on level 1 and half on level 2, as the top object of Fig. 5.3)
except their rigidity: floor 10, pillow 1. By eq. 4.15 both move to ``P' = R P1 + (1 − R) P2``
with ``R = R1 / (R1 + R2)``, so the pillow flattens by 10/11 of the overlap and the floor gives
1/11. `rigid_top` is `pillow_on_floor` with the rigidities swapped (Fig. 5.4).

The floor is a slab, not a sheet: a sheet has no inside, so the pillow would have no
interpenetration region of its own and each round would clear only the stiff side's 1/11 of what
is left. Both objects have their poles on ±x: a response on levels ≥ 1 whose CVs reach the three
rows at a collapsed pole opens the pole and detection no longer sees an inside; with 10 CVs from
pole to pole the pillow's data points stay more than 2 level-0 patches from its poles.
"""

from pathlib import Path

from pipeline.authoring import add_surface, add_xform, key_translate, moved, new_stage, save, sphere, turned

ABSORPTION = [0.0, 0.5, 0.5]
DEEPEST = (11, 12)  # frames where the pillow is lowest


def pillow_on_floor(floor_rigidity: float, pillow_rigidity: float):
    """The stage: a 3 × 3 × 0.5 slab, top at z = 0, and a 2 × 1.4 × 0.8 pillow lowered onto it."""
    stage = new_stage(1, 20, fps=24, up_axis="Z")
    slab = moved(turned(sphere(12, 8, radii=(0.25, 1.5, 1.5), levels=3), "y"), (0.0, 0.0, -0.25))
    add_surface(stage, "/World/Floor", slab, absorption=ABSORPTION, rigidity=floor_rigidity)
    mover = add_xform(stage, "/World/Mover")
    pillow = turned(sphere(8, 10, radii=(0.4, 0.7, 1.0), levels=3), "y")
    add_surface(stage, "/World/Mover/Pillow", pillow, absorption=ABSORPTION, rigidity=pillow_rigidity)
    key_translate(mover, "x", [1, 20], [0.1, 0.1])
    key_translate(mover, "y", [1, 20], [0.05, 0.05])
    key_translate(mover, "z", [1, 7, *DEEPEST, 16, 20], [0.8, 0.42, 0.3, 0.3, 0.42, 0.8], interp="linear")
    return stage


def build():
    return pillow_on_floor(floor_rigidity=10.0, pillow_rigidity=1.0)


if __name__ == "__main__":
    save(build(), Path(__file__).with_suffix(".usda"))
