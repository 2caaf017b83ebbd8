"""acra.quat: unit quaternions of the rotational response."""

import numpy as np

from acra.quat import quat_from_axis_angle, slerp_mean


def test_slerp_mean_of_two_rotations_is_the_half_way_rotation():
    q1 = quat_from_axis_angle(np.array([[0, 0, 1.0]]), np.array([0.2]))[0]
    q2 = quat_from_axis_angle(np.array([[0, 0, 1.0]]), np.array([0.6]))[0]
    np.testing.assert_allclose(slerp_mean(np.stack([q1, q2])), quat_from_axis_angle(np.array([[0, 0, 1.0]]), np.array([0.4]))[0], atol=1e-12)
