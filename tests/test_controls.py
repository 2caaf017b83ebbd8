"""acra.controls: the contract's checks and defaults of an object's controls."""

import numpy as np
import pytest

from acra.controls import ControlError, check_controls


@pytest.mark.parametrize(
    "kwargs,attr,words",
    [
        (dict(absorption=[0.5, 0.4]), "acra:absorption", "sums to 0.9"),
        (dict(absorption=[1.5, -0.5]), "acra:absorption", "negative"),
        (dict(absorption=[1.0]), "acra:absorption", "has 1 values but acra:levels is 2"),
        (dict(deform=[1, 1], translate=[0.5, 0]), "acra:deform", "level 0 sums to 1.5"),
        (dict(translate=[0, -0.1], deform=[1, 1.1]), "acra:translate", "negative"),
        (dict(rigidity=0.5), "acra:rigidity", "outside [1, 100]"),
        (dict(rigidity=101), "acra:rigidity", "outside [1, 100]"),
        (dict(rigidity=float("nan")), "acra:rigidity", "outside"),
        (dict(refine="maybe"), "acra:refine", "unknown token"),
        (dict(absorption=[float("nan"), 1]), "acra:absorption", "NaN"),
    ],
)
def test_invalid_controls_name_the_attribute(kwargs, attr, words):
    with pytest.raises(ControlError) as err:
        check_controls(2, **kwargs)
    assert err.value.attribute == attr and words in str(err.value)


def test_control_defaults():
    c = check_controls(3)
    np.testing.assert_array_equal(c.absorption, [0, 0, 1])
    np.testing.assert_array_equal(c.deform, [1, 1, 1])
    assert c.rigidity == 50 and c.refine
    # within 1e-6 of 1 is accepted
    check_controls(2, absorption=[0.5, 0.5 + 5e-7])
