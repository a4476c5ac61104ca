"""Planar angles: wrapping and the yaw-only quaternion of the contract (one place for both).

Angles in rad, yaw counter-clockwise about +z (REP-103). Quaternions are (x, y, z, w).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["quaternion_to_yaw", "wrap_angle", "yaw_to_quaternion"]


def wrap_angle(a: ArrayLike) -> NDArray[np.float64]:
    """Angles (rad) wrapped to [-pi, pi); any shape, float64."""
    x = np.asarray(a, dtype=np.float64)
    return np.asarray((x + np.pi) % (2.0 * np.pi) - np.pi, dtype=np.float64)


def yaw_to_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """Yaw-only quaternion (x, y, z, w) of a rotation by `yaw` rad about +z."""
    half = 0.5 * float(yaw)
    return (0.0, 0.0, math.sin(half), math.cos(half))


def quaternion_to_yaw(x: float, y: float, z: float, w: float) -> float:
    """Yaw (rad, in [-pi, pi]) of the quaternion (x, y, z, w): rotation about +z of the body's
    x axis projected onto the x-y plane (exact for yaw-only quaternions)."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
