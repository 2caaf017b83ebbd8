"""Thesis Fig. 5.5 against 5.6: the same press absorbed by levels 1–3 or by levels 1–2.

    python scenes/absorb_levels.py          # writes absorb_levels.usda beside this file
    acra run scenes/absorb_levels.py --rrd absorb_levels.rrd

Two identical sheets side by side, each pressed 0.15 deep by its own identical rigid ball. Both
have 4 levels, numbered as in the thesis (§4.1.3: level 0 the coarsest). The left sheet spreads
the absorption equally over levels 1–3, ``[0, 1/3, 1/3, 1/3]`` (Fig. 5.5); the right one over
levels 1–2, ``[0, 1/2, 1/2, 0]`` (Fig. 5.6). The thesis's objects have 5 levels, but a level
that absorbs nothing is never refined (``refine`` policy), so a fifth level would change
nothing here.

Under the ball both sheets take the ball's shape. Around it the sheet is pulled back to the
points at the rim of the contact, which hardly move, and overshoots into a raised rim; the left
sheet, with a third of the response on the finest level, keeps that disturbance closer to the
ball: a smaller moved area, a lower rim and a faster fall-off.
"""

from pathlib import Path

from pipeline.authoring import add_collider, add_surface, add_xform, key_translate, moved, new_stage, save, sheet, uv_sphere

SHEETS = {  # name: (x of the sheet's centre, absorption per level 0..3)
    "Levels123": (-2.0, [0.0, 1 / 3, 1 / 3, 1 / 3]),
    "Levels12": (2.0, [0.0, 0.5, 0.5, 0.0]),
}
RADIUS, DEPTH = 0.45, 0.15  # the balls, and how far their lowest points go below the sheets
DEEPEST = (12, 14)  # frames the balls are lowest


def build():
    stage = new_stage(1, 20, fps=24, up_axis="Z")
    flat = sheet(10, 10, width=3.5, depth=3.5, levels=4)  # 7×7 patches of 0.5
    verts, faces = uv_sphere(RADIUS, 48, 24)
    for name, (x, absorption) in SHEETS.items():
        add_surface(stage, f"/World/{name}/Sheet", moved(flat, (x, 0.0, 0.0)), absorption=absorption, samples=8)
        mover = add_xform(stage, f"/World/{name}/Mover")
        add_collider(stage, f"/World/{name}/Mover/Ball", verts, faces)
        # identical keys, off the knot lines (native USD splines, linear knots)
        key_translate(mover, "x", [1, 20], [x + 0.05, x + 0.05])
        key_translate(mover, "y", [1, 20], [0.03, 0.03])
        key_translate(mover, "z", [1, 8, *DEEPEST, 19], [RADIUS + 0.3, RADIUS - 0.01, RADIUS - DEPTH, RADIUS - DEPTH, RADIUS + 0.3],
                        interp="linear")
    return stage


if __name__ == "__main__":
    save(build(), Path(__file__).with_suffix(".usda"))
