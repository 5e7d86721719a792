"""Angles read back from orientations: roll and pitch as the pilot's console shows them."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from abyss.common.geometry import quat_wxyz_of, roll_pitch_of, rotation_of_rpy, yaw_of

angles = st.floats(-math.pi / 2 + 1e-3, math.pi / 2 - 1e-3)


@given(roll=st.floats(-math.pi + 1e-3, math.pi - 1e-3), pitch=angles, yaw=st.floats(-math.pi, math.pi))
def test_roll_pitch_and_yaw_read_back_what_composed_the_orientation(
    roll: float, pitch: float, yaw: float
) -> None:
    quat = quat_wxyz_of(rotation_of_rpy(roll, pitch, yaw))
    assert np.allclose(roll_pitch_of(quat), (roll, pitch), atol=1e-6)
    assert abs(math.remainder(yaw_of(quat) - yaw, 2 * math.pi)) < 1e-6


def test_a_positive_pitch_about_y_to_port_puts_the_nose_down() -> None:
    # z up, x forward: a positive rotation about y turns the nose (x) down
    roll, pitch = roll_pitch_of(quat_wxyz_of(rotation_of_rpy(0.0, 0.2, 0.0)))
    assert roll == 0.0 and math.isclose(pitch, 0.2) and rotation_of_rpy(0.0, 0.2, 0.0)[2, 0] < 0
