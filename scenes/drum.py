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

from acra import shapes
from pipeline import authoring as A
from pipeline.animation import usdkeys as K

SHEETS = {"Drum": (0.0, True), "Cloth": (4.0, False)}  # name: (y of the centre, keeps its area)
RADIUS, DEPTH = 0.45, 0.25


def build():
    stage = A.new_stage(1, 6, fps=24, up_axis="Z")
    cvs, _, _ = shapes.sheet(8, 8, width=2.5, depth=2.5)
    verts, faces = A.uv_sphere(RADIUS, 48, 24)
    for name, (y, keep) in SHEETS.items():
        sheet = A.add_deformable(stage, f"/World/{name}", cvs + [0.0, y, 0.0], levels=2, absorption=[0.3, 0.7], samples=4)
        if keep:
            A.set_state_controls(sheet, preserve_volume=1.0, bulge_level=0, bulge_falloff=0.5)
        mover = A.add_xform(stage, f"/World/{name}Mover")
        A.add_collider(stage, f"/World/{name}Mover/Ball", verts, faces)
        K.key_translate(mover, "x", [1], [0.04])
        K.key_translate(mover, "y", [1], [y + 0.03])
        K.key_translate(mover, "z", [1, 5, 6], [RADIUS + 0.05, RADIUS - DEPTH, RADIUS + 0.4], interp="linear")
    return stage


if __name__ == "__main__":
    A.save(build(), Path(__file__).with_suffix(".usda"))
