"""`acra.floattext` writes a ``float3[]`` value's text as USD's ``.usda`` writer does, byte for byte
(`pipeline.output_layer._SharedText` writes its text in place of USD's); the float32 digits it
writes are `acra.floatdigits`' (`tests/test_floatdigits.py`)."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import Vt

from acra import doubledigits, floatdigits, floattext
from pipeline.output_layer import _float_texts

from conftest import usd_array_text


def _cases() -> dict:
    rng = np.random.default_rng(19)
    n = 60000
    special = [227.140625, 227.140635, 0.0, -0.0, 1.0, -1.0, 0.1, 0.3, 2.5, 100.0, 1e-4, 1e-5, 1e-6, 9.999999e-7, 1.5e-6, 1e-7, 1.234e-7, 1e-8,
               3e-8, 1e14, 9.99999e14, 1e15, 1e16, 1.5e17, 1e21, 2.0**39, 2.0**40, 16777216.0, 16777217.0, 123456789.0,
               1.17549435e-38, 1.4e-45, 3.4028235e38, -3.4028235e38]
    special += [2.0**i for i in range(-149, 128)] + [10.0**i for i in range(-45, 39)]
    special += list(np.nextafter(np.float32(10.0) ** np.arange(-40, 38, dtype=np.float32), np.float32(np.inf)))
    return {
        "any bits": rng.integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32).view(np.float32),
        "normals": (rng.standard_normal(n) / 3).astype(np.float32),
        "every scale": (rng.standard_normal(n) * 10.0 ** rng.integers(-12, 16, n)).astype(np.float32),
        "few digits": (rng.integers(-10**6, 10**6, n) / 10.0 ** rng.integers(0, 9, n)).astype(np.float32),
        "near powers of two": (2.0 ** rng.integers(-40, 50, n) * (1 + rng.integers(-3, 4, n) * 2.0**-23)).astype(np.float32),
        "special": np.array(special, dtype=np.float32),
    }


@pytest.mark.parametrize("name", list(_cases()))
def test_same_text_as_usd(name):
    values = _cases()[name]
    values = values[np.isfinite(values)]
    values = np.ascontiguousarray(values[: values.size // 3 * 3].reshape(-1, 3))
    assert floattext.tuples_text(values, _float_texts).decode() == usd_array_text(values, "float3[]")


def test_every_layout_of_nine_stored_digits():
    """`floattext._put_short` stores nine digits whatever the value and ends the text where the
    value's ends: values of 1 to 9 digits with the decimal point at every place it handles
    (``0.00000d`` to ``ddddddddd``), and just past them (exponent form, ten places), signed, next
    to each other in tuples so that a value's extra stores are written over; the text is USD's."""
    values = []
    for nd in range(1, 10):
        for point in range(-6, 12):
            c = int("123456789"[:nd]) if nd % 2 else int("987654321"[:nd])
            values.append(c * 10.0 ** (point - nd))
            values.append(-c * 10.0 ** (point - nd))
    values = np.array(values + [1e8, 999999936.0, 1e9, 123456792.0, 1e-6, 9.99999e-6, 1e-5, 0.5, 5.0], dtype=np.float32)
    for shift in range(3):  # each value beside each kind of neighbour
        rows = np.ascontiguousarray(np.roll(values, shift)[: values.size // 3 * 3].reshape(-1, 3))
        assert floattext.tuples_text(rows, _float_texts).decode() == usd_array_text(rows, "float3[]")
        assert floattext.tuples_text(rows[::-1].copy(), _float_texts).decode() == usd_array_text(rows[::-1].copy(), "float3[]")


def test_tuple_widths():
    values = np.array([[1.5, -0.0], [1e-9, 2.0]], dtype=np.float32)
    assert floattext.tuples_text(values, _float_texts).decode() == "[(1.5, -0), (1e-9, 2)]"
    assert floattext.tuples_text(values.reshape(-1, 1), _float_texts).decode() == "[(1.5), (-0), (1e-9), (2)]"


@pytest.mark.parametrize("shape", [(1,), (7,), (5000,), (1, 2), (2500, 2)])
def test_ints_same_text_as_usd(shape):
    rng = np.random.default_rng(7)
    values = rng.integers(-2**31, 2**31, shape, dtype=np.int64).astype(np.int32)
    values.reshape(-1)[:4] = [0, -1, 2**31 - 1, -2**31][: values.size]
    values.reshape(-1)[4:2000] = rng.integers(-1000, 1000, max(0, min(values.size, 2000) - 4))
    assert floattext.ints_text(values).decode() == usd_array_text(values, "int[]" if values.ndim == 1 else "int2[]")


def test_ints_text_compiles_once_for_read_only_and_writable_arrays():
    """USD's int arrays come read-only and numpy's copies writable: both take one specialisation
    of the kernel, so a run loads (and a first run compiles) it once."""
    values = np.arange(-3, 3, dtype=np.int32)
    shown = values.copy()
    shown.flags.writeable = False
    assert floattext.ints_text(values) == floattext.ints_text(shown) == floattext.ints_text(Vt.IntArray.FromNumpy(values))
    assert len(floattext._ints_text.signatures) == 1


def test_doubles_same_text_as_usd():
    """float64 values with a short exact decimal (a display's surface parameters: dyadic) and
    any others are written by the kernel from their shortest digits; the text is USD's."""
    rng = np.random.default_rng(11)
    n = 40000
    dyadic = rng.integers(-2**20, 2**20, n) / 2.0 ** rng.integers(0, 30, n)
    ints = rng.integers(-10**15, 10**15, 2000).astype(np.float64)
    other = rng.standard_normal(4000) * 10.0 ** rng.integers(-30, 30, 4000)
    special = np.array([0.0, -0.0, 1.0, 0.5, 2.0**-20, 2.0**-21, 99999999999999.0, 1e14, 1e15, 1e16, 2.0**46, 2.0**47, 2.0**48,
                        1e-6, 0.000001, 1.5e-6, 2.0**-30, 5e-324, 1.7976931348623157e308, 0.1, 1 / 3])
    values = np.concatenate([dyadic, ints, other, special])
    values = np.ascontiguousarray(values[: values.size // 2 * 2].reshape(-1, 2))
    assert floattext.tuples_text(values, _float_texts).decode() == usd_array_text(values, "double2[]")
    short = rng.integers(-2**12, 2**12, n) / 2.0 ** rng.integers(0, 13, n)  # i 5^s < 10^14
    assert all(doubledigits._exact(np.int64(b) & 0x7FFFFFFFFFFFFFFF)[2] for b in short[short != 0].view(np.uint64))


def test_several_arrays_with_one_call_for_their_hard_values():
    rng = np.random.default_rng(5)
    arrays = [(rng.standard_normal((500, 3)) * 10.0 ** rng.integers(-40, 30, (500, 3))).astype(np.float32) for _ in range(3)]
    for a in arrays:  # infinities and NaN: the float32 values the kernel leaves to USD's writer
        a[rng.integers(0, 500, 20), rng.integers(0, 3, 20)] = rng.choice([np.inf, -np.inf, np.nan], 20)
    arrays.append(rng.integers(-2**20, 2**20, (300, 2)) / 2.0 ** rng.integers(0, 60, (300, 2)))
    arrays[3][rng.integers(0, 300, 10), rng.integers(0, 2, 10)] = rng.choice([np.inf, -np.inf, np.nan], 10)
    calls = []
    texts = floattext.tuples_texts(arrays, lambda v: calls.append(v.dtype) or _float_texts(v))
    assert calls == [np.float32, np.float64]
    assert [t.tobytes().decode() for t in texts[:3]] == [usd_array_text(a, "float3[]") for a in arrays[:3]]
    assert texts[3].tobytes().decode() == usd_array_text(arrays[3], "double2[]")


def test_text_copied_from_a_reference_array_is_the_text_formatted_afresh():
    """`tuples_texts` with ``refs``: tuples whose bits equal the reference's are copied from its
    text (runs of them, signs, zeros and values USD's writer formats among them); the text is the
    same bytes as formatting every value."""
    rng = np.random.default_rng(23)
    n = 4000
    base = (rng.standard_normal((n, 3)) * 10.0 ** rng.integers(-12, 16, (n, 3))).astype(np.float32)
    base[rng.random((n, 3)) < 0.02] = -0.0
    moved = base.copy()
    for lo in rng.integers(0, n, 12):  # changed runs of tuples, as a response moves the points near a contact
        moved[lo:lo + rng.integers(1, 200)] += rng.standard_normal(3).astype(np.float32)
    moved[rng.random(n) < 0.05, 1] *= -1
    moved[0], moved[-1] = -moved[0], moved[-1] * 1e-30
    again = moved.copy()
    again[rng.random(n) < 0.5] = 0.0
    arrays = [base, moved, again, base.reshape(-1, 2), moved[:-1]]
    refs = [None, 0, 1, 0, 1]  # the last two differ in shape from their reference: formatted afresh
    texts = lambda *a: [t.tobytes() for t in floattext.tuples_texts(*a)]  # noqa: E731
    assert texts(arrays, _float_texts, refs) == texts(arrays, _float_texts)
    assert [t.decode() for t in texts(arrays[:3], _float_texts, refs[:3])] == [usd_array_text(a, "float3[]") for a in arrays[:3]]
    same = np.zeros(n, np.bool_)
    cs, ks, st = floatdigits.shortest_digits(moved.reshape(-1).view(np.uint32), base.reshape(-1).view(np.uint32), same)
    assert np.array_equal(same, (moved == base).all(axis=1) & (np.signbit(moved) == np.signbit(base)).all(axis=1))
    whole = floatdigits.shortest_digits(moved.reshape(-1).view(np.uint32))
    changed = ~np.repeat(same, 3)
    assert all(np.array_equal(a[changed], b[changed]) for a, b in zip((cs, ks, st), whole))


def test_two_sides_give_the_bytes_of_one():
    """`tuples_texts` with ``both``: the chains of references are dealt to two sides of about
    equal work, each side found and formatted by one call of ``both``'s two (here in two threads,
    the second started first), and the texts are the bytes one call gives; ``hard`` is called once
    a type, in the caller."""
    import threading

    rng = np.random.default_rng(41)
    n = 9000
    base = (rng.standard_normal((n, 3)) * 10.0 ** rng.integers(-12, 16, (n, 3))).astype(np.float32)
    base[rng.integers(0, n, 30), rng.integers(0, 3, 30)] = rng.choice([np.inf, -np.inf, np.nan], 30)
    normals = (rng.standard_normal((n, 3)) / 3).astype(np.float32)
    arrays, refs = [base, normals], [None, None]
    for f in range(4):  # two attributes' samples, each moved near a contact from the one before
        for k in (0, 1):
            moved = arrays[-2].copy()
            lo = int(rng.integers(0, n - 500))
            moved[lo:lo + 400] += np.float32(0.25 * (f + 1))
            arrays.append(moved)
            refs.append(len(arrays) - 3)
    arrays.append(rng.integers(-2**20, 2**20, (3000, 3)) / 2.0 ** rng.integers(0, 60, (3000, 3)))  # a response's float64 offsets
    arrays[-1][rng.integers(0, 3000, 10), rng.integers(0, 3, 10)] = rng.choice([np.inf, -np.inf, np.nan], 10)
    refs.append(None)
    calls, sides = [], []
    hard = lambda v: calls.append((v.dtype, threading.get_ident())) or _float_texts(v)  # noqa: E731

    def both(first, second):
        sides.append(1)
        out = [None]
        worker = threading.Thread(target=lambda: out.__setitem__(0, second()))
        worker.start()
        worker.join()
        return first(), out[0]

    one = [t.tobytes() for t in floattext.tuples_texts(arrays, hard, refs)]
    two = [t.tobytes() for t in floattext.tuples_texts(arrays, hard, refs, both)]
    assert two == one
    assert len(sides) == 2  # the values found, then the texts, each on two sides
    assert [dtype for dtype, _ in calls] == [np.float32, np.float64] * 2
    assert {ident for _, ident in calls} == {threading.get_ident()}
    assert one[0].decode().startswith("[(") and one[-1] == floattext.tuples_text(arrays[-1], _float_texts)


def test_sides_deal_whole_chains_by_work():
    """`floattext._sides`: each chain on one side, the heaviest first to the lighter side; one
    side where ``both`` is absent, there is one chain, or the lighter side holds too little."""
    chains = floattext._chains([None, None, 0, 1, None, 2, 4, 10])
    assert chains == [[0, 2, 5], [1, 3], [4, 6], [7]]
    work = [30000, 25000, 100, 100, 9000, 100, 9000, 50]
    both = object()
    assert floattext._sides(chains, work, both) == [[0, 2, 5, 7], [1, 3, 4, 6]]
    assert floattext._sides(chains, work, None) == [list(range(8))]
    assert floattext._sides(chains[:1], work, both) == [[0, 2, 5]]
    assert floattext._sides(chains, [w // 10 for w in work], both) == [list(range(8))]
