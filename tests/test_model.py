"""pipeline.model: `apply_xform`'s compiled pass under a translation has numpy's bits."""

import numpy as np
import pytest

from pipeline import model
from pipeline.model import apply_xform


def _numpy(xform, points):
    """`apply_xform`'s arithmetic as numpy states it."""
    return points @ xform[:3, :3].T + xform[:3, 3]


@pytest.mark.parametrize("t", [(0.1, -2.2, 0.15), (0.0, 0.0, 0.0), (1.0, 0.0, -0.0), "cancel"])
def test_a_translation_maps_many_points_in_one_pass_with_numpy_s_bits(t, monkeypatch):
    """Many float64 points under a matrix whose linear part is the identity are mapped by
    `model.translated` with the bits of numpy's matmul and sum: at signed zeros, at sums that
    cancel to zero and at huge and tiny values. A -0.0 translation or a non-finite point
    (whose row numpy fills with NaN through the zeros' products) takes numpy's path."""
    rng = np.random.default_rng(3)
    p = rng.normal(size=(400, 3)) * 10.0 ** rng.integers(-300, 300, size=(400, 1))
    p[rng.random(p.shape) < 0.1] = 0.0
    p[rng.random(p.shape) < 0.1] = -0.0
    p[5] = (0.25, -3.5, 7.0)
    m = np.eye(4)
    m[:3, 3] = -p[5] if t == "cancel" else t
    called = []
    real = model.translated
    monkeypatch.setattr(model, "translated", lambda *a: called.append(real(*a)) or called[-1])
    assert apply_xform(m, p).tobytes() == _numpy(m, p).tobytes()
    assert called == [t != (1.0, 0.0, -0.0)]
    for bad in (np.inf, np.nan):
        q = p.copy()
        q[7, 1] = bad
        called.clear()
        with np.errstate(invalid="ignore"):  # inf times zero, as numpy's matmul meets it
            assert apply_xform(m, q).tobytes() == _numpy(m, q).tobytes()
        assert called == [False]


def test_other_matrices_and_arrays_take_numpy_s_path(monkeypatch):
    """A rotation, a few points, float32 points, non-contiguous points: numpy's arithmetic."""
    rng = np.random.default_rng(4)
    p = rng.normal(size=(300, 3))
    called = []
    real = model.translated
    monkeypatch.setattr(model, "translated", lambda *a: called.append(real(*a)) or called[-1])
    c, s = np.cos(0.3), np.sin(0.3)
    rot = np.eye(4)
    rot[:2, :2] = [[c, -s], [s, c]]
    rot[:3, 3] = (1.0, 2.0, 3.0)
    assert apply_xform(rot, p).tobytes() == _numpy(rot, p).tobytes()
    assert called == [False]
    shift = np.eye(4)
    shift[:3, 3] = (1.0, 2.0, 3.0)
    called.clear()
    for q in (p[:8], p.astype(np.float32), p[::2], np.asfortranarray(p)):
        assert apply_xform(shift, q).tobytes() == _numpy(shift, q).tobytes()
    assert called == []


@pytest.mark.parametrize("round32", [True, False])
@pytest.mark.parametrize("n", [0, 1, 2, 7, 500])
def test_a_translation_s_rows_and_box_are_the_array_forms(round32, n):
    """`model.translated`: ``local`` is the points rounded to float32 (where ``round32``),
    ``world`` is ``local`` plus the translation by numpy's arithmetic, and ``box`` is
    `acra.bvh.bounds` of ``world``, bit for bit: signed zeros (which the box's comparisons pick
    in row order), sums that cancel, values of every magnitude; no rows: true, the box unset."""
    from acra import bvh

    rng = np.random.default_rng(17 + n)
    p = rng.normal(size=(n, 3)) * 10.0 ** rng.integers(-30, 30, size=(n, 1))
    p[rng.random(p.shape) < 0.2] = 0.0
    p[rng.random(p.shape) < 0.2] = -0.0
    m = np.eye(4)
    m[:3, 3] = (0.0, 1.5, -2.25)
    if n:
        p[-1] = (-0.0, -1.5, 2.25)  # a world row of zeros from both sides
    local, world, box = np.empty((n, 3)), np.empty((n, 3)), np.full((2, 3), 7.0)
    assert model.translated(p, m, round32, local, world, box)
    want_local = p.astype(np.float32).astype(np.float64) if round32 else p
    assert local.tobytes() == want_local.tobytes()
    assert world.tobytes() == _numpy(m, want_local).tobytes()
    if n:
        assert box.tobytes() == bvh.bounds(world).tobytes()
    else:
        assert (box == 7.0).all()
    same = p.copy()
    assert model.translated(same, m, False, same, same, box) and same.tobytes() == _numpy(m, p).tobytes()


def test_is_translation_is_translated_s_test_of_the_matrix():
    """`model.is_translation` answers as `model.translated` does on finite points: the identity's
    entries (a zero of either sign) and no -0.0 in the translation; any other entry, a -0.0
    translation or a NaN answers false."""
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(5, 3))
    out = np.empty((5, 3))
    cases = []
    for _ in range(200):
        m = np.eye(4)
        m[:3, 3] = rng.choice([0.0, -0.0, 1.5, -2.25, 1e-300], size=3)
        i, j = rng.integers(0, 3, size=2)
        change = rng.integers(0, 4)
        if change == 1:
            m[i, j] = -0.0 if i != j else 1.0 + 2.0**-52
        elif change == 2:
            m[i, j] = np.nan
        cases.append(m)
    answers = [model.is_translation(m) for m in cases]
    assert answers == [model.translated(pts, m, False, out, out, np.empty((2, 3))) for m in cases]
    assert any(answers) and not all(answers)
