"""A robot's velocity loops, decided here alone (`robot_gains`): those its package states
(`simulation.vehicle_kp`, `vehicle_ki` in its `[config]`), else derived from its mass, its added
mass and its thrusters' lag, as the shipped work-class ROV's were tuned. Its loops close at kp / (m
+ m_A) = 1.50 1/s in surge (6000 N s/m over 2989 + 1004 kg), 1.26 in sway and heave (6000 over 2989
+ 1788) and 2.92 in yaw (5000 N m s/rad over 1228 + 483 kg m^2), with integrals at ki / kp = 0.25
1/s (yaw 0.12), its rotors lagging 0.2 s; a robot whose rotors lag less takes bandwidths higher in
proportion (the same phase lag at the crossover), and its integral with them. The BlueROV2's
package states the gains this gives (its robot.toml works them through). The configuration's
`simulation.vehicle_kp` and `vehicle_ki` are empty unless a user sets them, and then they are flown
instead (the simulation's world)."""

from __future__ import annotations

from abyss.description.robot import Robot

BANDWIDTH_PER_S = (1.50, 1.26, 1.26, 2.92)  # surge, sway, heave, yaw: kp / (m + m_A) [1/s]
INTEGRAL_PER_S = (0.25, 0.25, 0.25, 0.12)  # ki / kp [1/s]
ROTOR_LAG_S = 0.2  # the work-class's thrusters' time constant [s]
AXES = (0, 1, 2, 5)  # of the body's six: surge, sway, heave, yaw


Gains = tuple[tuple[float, ...], tuple[float, ...]]  # (kp, ki): surge, sway, heave, yaw


def robot_gains(robot: Robot) -> Gains:
    """The velocity loops `robot` flies by (kp, ki): those its package states, else derived."""
    stated = robot.spec.config.get("simulation", {})
    kp, ki = derived_gains(robot)
    return (
        tuple(float(k) for k in stated.get("vehicle_kp", kp)),
        tuple(float(k) for k in stated.get("vehicle_ki", ki)),
    )


def derived_gains(robot: Robot) -> Gains:
    """(kp, ki) for `robot`: its rigid mass
    (the base with all it carries) and yaw inertia as the package's load measured them, plus its
    added mass, times the work-class's bandwidths scaled by the rotors' lag; three significant
    figures."""
    added = robot.marine.added_mass.diagonal()
    rigid = (robot.mass_kg, robot.mass_kg, robot.mass_kg, robot.yaw_inertia_kg_m2)
    scale = ROTOR_LAG_S / robot.spec.thrusters.time_constant_s
    kp = [scale * w * (m + added[a]) for w, m, a in zip(BANDWIDTH_PER_S, rigid, AXES, strict=True)]
    ki = [scale * r * p for r, p in zip(INTEGRAL_PER_S, kp, strict=True)]
    return tuple(_figures(k) for k in kp), tuple(_figures(k) for k in ki)


def _figures(value: float, digits: int = 3) -> float:
    return float(f"{value:.{digits}g}")
