"""The onboard navigation estimate, a complementary filter: the DVL's velocity integrated in
the world frame and pulled towards the USBL/pressure fix, and the gyro's rates integrated and
pulled towards the IMU's attitude, both with one time constant. The fix alone has the USBL's
noise (5 cm by default) and the attitude's noise moves a tool 1.5 m away by millimetres; no
controller holds a millimetre goal on those. The rates are precise but drift when integrated
alone."""

from __future__ import annotations

import numpy as np

from abyss.common.geometry import quat_multiply, rotation_of, small_rotation_wxyz
from abyss.common.messages import NavState

MAX_GAP_S = 1.0  # a longer gap in the fixes restarts the estimate from the next fix


class NavFilter:
    def __init__(self, time_constant_s: float) -> None:
        self.time_constant_s = time_constant_s
        self.position_m_world: np.ndarray | None = None
        self.orientation_wxyz_world = np.array([1.0, 0.0, 0.0, 0.0])
        self._stamp_s = 0.0

    def update(self, nav: NavState) -> tuple[np.ndarray, np.ndarray]:
        """The estimate after one fix: position [m, world], orientation (w, x, y, z)."""
        dt = nav.sim_time_s - self._stamp_s
        self._stamp_s = nav.sim_time_s
        if self.position_m_world is None or self.time_constant_s == 0 or not 0 <= dt <= MAX_GAP_S:
            self.position_m_world = np.array(nav.position_m_world, dtype=float)
            self.orientation_wxyz_world = np.array(nav.orientation_wxyz_world, dtype=float)
            return self.position_m_world, self.orientation_wxyz_world
        gain = dt / (self.time_constant_s + dt)
        velocity_mps_world = rotation_of(self.orientation_wxyz_world) @ nav.velocity_mps_body
        predicted = self.position_m_world + velocity_mps_world * dt
        self.position_m_world = predicted + gain * (nav.position_m_world - predicted)
        rotated = small_rotation_wxyz(nav.angular_velocity_radps_body * dt)  # body rates: right product
        turned = quat_multiply(self.orientation_wxyz_world, rotated)
        self.orientation_wxyz_world = nlerp(turned, nav.orientation_wxyz_world, gain)
        return self.position_m_world, self.orientation_wxyz_world


def nlerp(a_wxyz: np.ndarray, b_wxyz: np.ndarray, fraction: float) -> np.ndarray:
    """The unit quaternion `fraction` of the way from a to b (the short way); for small steps."""
    if float(a_wxyz @ b_wxyz) < 0.0:
        b_wxyz = -b_wxyz
    q = (1.0 - fraction) * a_wxyz + fraction * b_wxyz
    return q / np.linalg.norm(q)
