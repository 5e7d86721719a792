"""Frames and angles shared by the stations."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def yaw_of(quat_wxyz: np.ndarray) -> float:
    """Heading [rad] of a world-frame orientation quaternion (w, x, y, z), z up."""
    w, x, y, z = quat_wxyz
    return float(math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def roll_pitch_of(quat_wxyz: np.ndarray) -> tuple[float, float]:
    """Roll and pitch [rad] of a world-frame orientation (w, x, y, z), z up, as rotation_of_rpy
    composes them (the inverse of its roll and pitch)."""
    r = rotation_of(quat_wxyz)
    return float(math.atan2(r[2, 1], r[2, 2])), float(-math.asin(max(-1.0, min(1.0, r[2, 0]))))


def wrap_rad(angle_rad: float) -> float:
    """The same angle in [-pi, pi)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def rotation_of(quat_wxyz: np.ndarray) -> np.ndarray:
    """The rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = np.asarray(quat_wxyz, dtype=float) / np.linalg.norm(quat_wxyz)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def quat_wxyz_of(rotation: np.ndarray) -> np.ndarray:
    """The unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (Shepperd's method)."""
    r = np.asarray(rotation, dtype=float)
    trace = float(np.trace(r))
    candidates = (trace, r[0, 0], r[1, 1], r[2, 2])
    i = int(np.argmax(candidates))
    if i == 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = np.array([s / 4, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s])
    else:
        j, k = (i % 3) + 1, ((i + 1) % 3) + 1  # the other two axes, cyclic
        a, b, c = i - 1, j - 1, k - 1
        s = 2.0 * math.sqrt(1.0 + r[a, a] - r[b, b] - r[c, c])
        q = np.zeros(4)
        q[0] = (r[c, b] - r[b, c]) / s
        q[i] = s / 4
        q[j] = (r[a, b] + r[b, a]) / s
        q[k] = (r[a, c] + r[c, a]) / s
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def rotation_of_rpy(roll_rad: float, pitch_rad: float, yaw_rad: float) -> np.ndarray:
    """Rotations about the fixed x, then y, then z axes: Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr, cp, sp = math.cos(roll_rad), math.sin(roll_rad), math.cos(pitch_rad), math.sin(pitch_rad)
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def small_rotation_wxyz(rotvec: np.ndarray) -> np.ndarray:
    """The unit quaternion (w, x, y, z) of a rotation vector [rad]."""
    angle = float(np.linalg.norm(rotvec))
    if angle < 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return np.r_[np.cos(angle / 2), np.sin(angle / 2) * rotvec / angle]


def rotation_about(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """The rotation matrix of `angle_rad` about the unit vector `axis`."""
    return rotation_of(small_rotation_wxyz(np.asarray(axis, dtype=float) * angle_rad))


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The Hamilton product a b of quaternions (w, x, y, z)."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


@dataclass(frozen=True)
class Intrinsics:
    """A pinhole camera's: its image's size and focal lengths [px], its principal point [px]."""

    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float

    @staticmethod
    def from_fovy(width_px: int, height_px: int, fovy_deg: float) -> Intrinsics:
        """MuJoCo's cameras: vertical field of view, square pixels, centred principal point."""
        f = 0.5 * height_px / np.tan(np.radians(fovy_deg) / 2.0)
        return Intrinsics(width_px, height_px, f, f, width_px / 2.0, height_px / 2.0)

    def matrix(self) -> np.ndarray:
        return np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])
