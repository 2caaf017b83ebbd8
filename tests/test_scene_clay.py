"""Scene clay: plasticity 1 keeps the dent exactly, plasticity 0.5 keeps exactly half of it.

Read from the output layer as a USD client sees it: the responded hierarchy
(``acra:response:*``, `output_layer.read_output_hierarchy`) and the display points.
"""

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from acra import relax
from pipeline import output_layer

FULL, HALF = "/World/Full/Sheet", "/World/Half/Sheet"
LAST_HIT, LAST = 4, 8
DEPTH = 0.12  # the scene's press


@pytest.fixture(scope="module")
def run(run_scene):
    report = run_scene("clay")
    src = report.output.with_name(report.output.name.replace(".acra.usda", ".usda"))
    return report, Usd.Stage.Open(str(src)), Usd.Stage.Open(str(report.output))


def _dent(inp, out, path, frame):
    """Display points less the animator's: ``(n, 3) float64``."""
    rest = output_layer.input_points(out, path)  # the animator's surface at the output's display vertices
    return np.asarray(UsdGeom.Mesh(out.GetPrimAtPath(path)).GetPointsAttr().Get(frame), dtype=np.float64) - rest


def _field(out, path, frame, rest):
    """The written surface at ``frame`` less the animator's ``rest``, as an offset field."""
    return relax.difference(output_layer.read_output_hierarchy(out, path, frame), rest)


def _max(field):
    return float(relax.level_magnitudes(field).max())


def test_the_balls_press_both_sheets_to_their_depth(run):
    report, inp, out = run
    assert [s.frame for s in report.stats if s.in_collision] == [2, 3, 4]
    for path in (FULL, HALF):
        # the sheets lie at z = 0; a press is cleared within 1e-3 of the sheet's size (0.0035);
        # measured 0.1233 (0.1187 before the display-driven rounds, whose result left the limit
        # surface 4.3e-3 of the size inside the ball; 0.1248 when a corrective round's samples took
        # their chords' whole lag)
        assert -_dent(inp, out, path, LAST_HIT)[:, 2].min() == pytest.approx(DEPTH, abs=0.0035), path


def test_plasticity_1_keeps_the_dent_exactly(run):
    report, inp, out = run
    rest = output_layer.read_output_hierarchy(out, FULL, 1)  # nothing yet: the animator's surface
    kept = _field(out, FULL, LAST_HIT, rest)
    assert _max(kept) > 0.15
    for f in range(LAST_HIT + 1, LAST + 1):
        assert _max(relax.difference(_field(out, FULL, f, rest), kept)) <= 1e-15, f
        np.testing.assert_array_equal(_dent(inp, out, FULL, f), _dent(inp, out, FULL, LAST_HIT))


def test_plasticity_half_keeps_half_of_the_dent(run):
    """Held while pressed (relax 0), released at frame 5 (relax 1): the surface is the animator's
    plus half of the pressed field from then on, coefficient by coefficient; the response is on
    level 1 over a level 0 that does not move, so the display's dent is exactly half too."""
    report, inp, out = run
    rest = output_layer.read_output_hierarchy(out, HALF, 1)
    pressed = _field(out, HALF, LAST_HIT, rest)
    np.testing.assert_array_equal(output_layer.read_output_hierarchy(out, HALF, LAST_HIT).cvs, rest.cvs)  # level 0 untouched
    for f in range(LAST_HIT + 1, LAST + 1):
        kept = _field(out, HALF, f, rest)
        assert _max(relax.difference(kept, relax.scaled(pressed, [0.5, 0.5]))) <= 1e-15, f
        np.testing.assert_allclose(_dent(inp, out, HALF, f), 0.5 * _dent(inp, out, HALF, LAST_HIT), rtol=0, atol=1e-6)
    assert -_dent(inp, out, HALF, LAST)[:, 2].min() == pytest.approx(-_dent(inp, out, HALF, LAST_HIT)[:, 2].min() / 2, abs=1e-6)


def test_the_state_written_is_the_plastic_part(run):
    _, _, out = run
    for path, p in ((FULL, 1.0), (HALF, 0.5)):
        prim = out.GetPrimAtPath(path)
        for f in range(LAST_HIT + 1, LAST + 1):
            assert not np.any(np.asarray(prim.GetAttribute("acra:state:elasticOffsets").Get(f))), (path, f)
            assert np.any(np.asarray(prim.GetAttribute("acra:state:plasticOffsets").Get(f))), (path, f)
