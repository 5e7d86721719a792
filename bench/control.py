"""Onboard control figures: the arm's task-priority step (Pinocchio kinematics, constraints,
set-based solve) against its floor, a plain damped pseudo-inverse of the end-effector Jacobian
on the same kinematics, and the share of the 50 ms control period it takes; then the closed
loop on the MuJoCo vehicle (kinematic low level): time to bring the end-effector within 1 mm
and 0.5 degree of the default mission's goal from the stowed arm. Each time is the fastest of
ROUNDS passes over the same samples, the step's and the floor's taken in turn.
Run: .venv/bin/python bench/control.py. Prints figures; asserts nothing."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from abyss.config import load
from abyss.description.robot import robot_at
from abyss.stations.onboard.arm_control import ArmController
from abyss.stations.onboard.task_priority import damped_pinv
from abyss.stations.simulation.lowlevel import References
from abyss.stations.simulation.world import World

ROBOT = robot_at("")  # the shipped robot package

REPEATS = 2000
ROUNDS = 5


def seconds(run: Callable[[], None]) -> float:
    t0 = time.perf_counter()
    run()
    return time.perf_counter() - t0


def main() -> None:
    config = load(
        None,
        [
            "simulation.low_level=kinematic",
            "mission.interventions=[]",
            "mission.arm_target=[4.86, 0, -8.35, 1.5708, 0, 0]",  # the middle valve's handle
            "simulation.start_position_m_world=[3.2, 0, -8.0]",
        ],
    )
    arm = ArmController(config.onboard, config.mission, ROBOT)
    goal = config.mission.arm_goal()
    assert goal is not None
    arm.set_goal(1, *goal)
    position, quat, q = np.array([3.2, 0.0, -8.0]), np.array([1.0, 0, 0, 0]), np.array(ROBOT.stowed_rad)
    rng = np.random.default_rng(0)
    samples = [q + rng.normal(0, 0.2, 6) for _ in range(REPEATS)]
    kin = arm.kinematics

    def full() -> None:
        for arm_rad in samples:
            arm.step(position, quat, arm_rad, enabled=True)

    def floor() -> None:
        for arm_rad in samples:
            kin.update(position, quat, arm_rad)
            error, rotation = arm.errors()
            damped_pinv(kin.jacobian(kin.ee), 0.05, 0.05) @ np.r_[error, rotation]

    full_s, floor_s = [], []
    for _ in range(ROUNDS):  # in turn, so that both see the same load
        full_s.append(seconds(full))
        floor_s.append(seconds(floor))
    full_us, floor_us = min(full_s) / REPEATS * 1e6, min(floor_s) / REPEATS * 1e6  # the least disturbed
    period_us = config.onboard.control_period_s * 1e6
    print(f"arm step, task priority + limits + clearance: {full_us:7.0f} us")
    print(
        f"floor, one damped pseudo-inverse:             {floor_us:7.0f} us  (ratio {full_us / floor_us:.2f}x)"
    )
    print(f"share of the {period_us / 1e3:.0f} ms control period: {full_us / period_us:.1%}")

    world = World(config.simulation, np.random.default_rng(0))
    arm = ArmController(config.onboard, config.mission, ROBOT)
    arm.set_goal(1, *goal)
    site = world.model.site("ee").id
    for step in range(1, 601):
        truth = world.truth()
        arm_rad = world.joints().positions_rad
        out = arm.step(truth.position_m_world, truth.orientation_wxyz_world, arm_rad, True)
        world.step(References(np.zeros(4), out.joint_velocities_radps, 0.0), config.onboard.control_period_s)
        error_m = np.linalg.norm(goal[0] - world.data.site_xpos[site])
        rotation = world.data.site_xmat[site].reshape(3, 3)
        angle_deg = np.degrees(np.arccos(np.clip((np.trace(arm.goal_rotation.T @ rotation) - 1) / 2, -1, 1)))
        if error_m < 1e-3 and angle_deg < 0.5:
            print(
                f"closed loop, stowed -> valve handle: within 1 mm and 0.5 deg after "
                f"{step * config.onboard.control_period_s:.2f} s (true site: {error_m * 1e3:.2f} mm, "
                f"{angle_deg:.2f} deg)"
            )
            return
    print("closed loop: not within 1 mm and 0.5 deg in 30 s")


if __name__ == "__main__":
    main()
