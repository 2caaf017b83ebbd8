"""Area preservation: an open sheet pressed by a ball keeps its area by drawing in its edges.

    python scenes/drum.py          # writes drum.usda beside this file
    acra run scenes/drum.py --rrd drum.rrd

Two identical sheets (2 levels, absorption ``[0.3, 0.7]``) are each pressed 0.25 deep by a rigid
ball at frames 2-5; the balls are gone at frame 6. An open surface encloses no volume, so on
``/World/Drum`` ``acra:preserveVolume = 1`` keeps its display area (``acra:bulgeLevel = 0``,
``acra:bulgeFalloff = 0.5``): the dent stretches the sheet and the level-0 net around it draws in.
``/World/Cloth`` is the same press without it and gains area.
"""

from pathlib import Path

from pipeline.authoring import (
    add_collider, add_surface, add_xform, key_translate, moved, new_stage, save,
    set_state_controls, sheet, uv_sphere,
)

SHEETS = {"Drum": (0.0, True), "Cloth": (4.0, False)}  # name: (y of the centre, keeps its area)
RADIUS, DEPTH = 0.45, 0.25


def build():
    stage = new_stage(1, 6, fps=24, up_axis="Z")
    cloth = sheet(8, 8, width=2.5, depth=2.5, levels=2)
    ball = uv_sphere(RADIUS, 48, 24)
    for name, (y, keep) in SHEETS.items():
        prim = add_surface(stage, f"/World/{name}", moved(cloth, (0.0, y, 0.0)), absorption=[0.3, 0.7], samples=4)
        if keep:
            set_state_controls(prim, preserve_volume=1.0, bulge_level=0, bulge_falloff=0.5)
        mover = add_xform(stage, f"/World/{name}Mover")
        add_collider(stage, f"/World/{name}Mover/Ball", *ball)
        key_translate(mover, "x", [1], [0.04])
        key_translate(mover, "y", [1], [y + 0.03])
        key_translate(mover, "z", [1, 5, 6], [RADIUS + 0.05, RADIUS - DEPTH, RADIUS + 0.4], interp="linear")
    return stage


if __name__ == "__main__":
    save(build(), Path(__file__).with_suffix(".usda"))
