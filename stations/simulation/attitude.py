"""The dynamic low level's attitude hold: roll and pitch kept level by the thrusters, as a small
ROV's autopilot keeps them (ArduSub's stabilise mode), where the layout moves those axes beyond
surge, sway, heave and yaw. A PD on the angles towards level, its moment allocated with the
velocity loop's wrench through one pseudo-inverse of the thrust matrix's rows.

A work-class ROV leaves roll and pitch to its hydrostatic restoring moment, which its weight makes
stiff (2989 kg, 0.17 m between the centres: 5 kN m/rad); a small one's is not (the BlueROV2's 1.7
N m/rad rolls it 17 degrees under half a newton metre), and its arm's reactions, a valve's torque
and its own sway rock it on a lightly damped mode (about 3.4 s) that the arm's controller, which
does not command roll or pitch, excites in turn."""

from __future__ import annotations

import math

import numpy as np

from abyss.stations.simulation.thrusters import Thrusters

ROLL, PITCH = 3, 4  # rows of the body wrench (fx, fy, fz, mx, my, mz)


class AttitudeHold:
    """Roll and pitch held level by the thrusters beside the axes they already drive (`held`: the
    rows among roll and pitch that add to the thrust matrix's rank; none with zero gains)."""

    def __init__(self, thrusters: Thrusters, kp: tuple[float, float], kd: tuple[float, float]) -> None:
        """`kp` [N m/rad] and `kd` [N m/(rad/s)]: roll's, then pitch's."""
        self.thrusters = thrusters
        rows = [int(a) for a in thrusters.actuated]
        held: list[int] = []
        for axis in (ROLL, PITCH):
            if (kp[axis - ROLL] or kd[axis - ROLL]) and np.linalg.matrix_rank(
                thrusters.allocation[[*rows, axis]]
            ) > len(rows):
                rows.append(axis)
                held.append(axis)
        self.held = tuple(held)
        self.kp = np.array([kp[a - ROLL] for a in held])
        self.kd = np.array([kd[a - ROLL] for a in held])
        self.allocation = thrusters.allocation[rows]  # the actuated rows, then the held ones
        self.pseudo_inverse = np.linalg.pinv(self.allocation)

    def moment(self, rotation: np.ndarray, rates_radps_body: np.ndarray) -> np.ndarray:
        """The held axes' moments [N m] from the body's rotation (body to world) and its roll and
        pitch rates [rad/s, body]: towards level, damped."""
        roll_rad = math.atan2(rotation[2, 1], rotation[2, 2])
        pitch_rad = -math.asin(max(-1.0, min(1.0, float(rotation[2, 0]))))
        angles = np.array([roll_rad, pitch_rad])[[a - ROLL for a in self.held]]
        rates = np.asarray(rates_radps_body)[[a - ROLL for a in self.held]]
        return -self.kp * angles - self.kd * rates

    def allocate(self, wrench: np.ndarray) -> np.ndarray:
        """Thrusts [N] for the actuated rows' wrench and the held rows' moments, in that order,
        scaled down together so that none exceeds its limit (as Thrusters.allocate_actuated)."""
        thrust = self.pseudo_inverse @ wrench
        excess = (np.abs(thrust) / self.thrusters.max_thrust_n(thrust)).max()
        return thrust / max(1.0, float(excess))
