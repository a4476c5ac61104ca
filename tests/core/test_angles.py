"""dbcslam_core.angles: the one angle wrapping and yaw-quaternion conversion."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from dbcslam_core import geometry, metrics, observation
from dbcslam_core.angles import quaternion_to_yaw, wrap_angle, yaw_to_quaternion

angles = st.floats(-1e3, 1e3, allow_nan=False)


@given(angles)
def test_wrap_angle_lands_in_half_open_interval_and_keeps_the_direction(a: float) -> None:
    w = float(wrap_angle(a))
    assert -math.pi <= w < math.pi
    assert math.isclose(math.cos(w), math.cos(a), abs_tol=1e-9)
    assert math.isclose(math.sin(w), math.sin(a), abs_tol=1e-9)


def test_wrap_angle_keeps_the_array_shape() -> None:
    a = np.linspace(-10.0, 10.0, 12).reshape(3, 4)
    assert wrap_angle(a).shape == (3, 4)
    assert float(wrap_angle(math.pi)) == -math.pi


@given(st.floats(-math.pi + 1e-9, math.pi, allow_nan=False))
def test_yaw_quaternion_round_trip(yaw: float) -> None:
    q = yaw_to_quaternion(yaw)
    assert math.isclose(math.hypot(*q), 1.0, rel_tol=1e-12)
    assert q[:2] == (0.0, 0.0)
    assert abs(math.remainder(quaternion_to_yaw(*q) - yaw, 2.0 * math.pi)) < 1e-12


def test_core_modules_share_the_one_wrap() -> None:
    assert geometry.wrap_angle is wrap_angle
    assert observation.wrap_angle is wrap_angle
    assert metrics.wrap_angle is wrap_angle
