"""Frames and angles shared by the stations."""

from __future__ import annotations

import math

import numpy as np


def yaw_of(quat_wxyz: np.ndarray) -> float:
    """Heading [rad] of a world-frame orientation quaternion (w, x, y, z), z up."""
    w, x, y, z = quat_wxyz
    return float(math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def wrap_rad(angle_rad: float) -> float:
    """The same angle in [-pi, pi)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi
