"""The vehicle and the arm: navigation, joint states, velocity references, the heartbeat."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from abyss.interface.messages.schema import MAX_ARM_JOINTS, Message, array, check_unit_quaternion, scalar


@dataclass(frozen=True)
class NavState(Message):
    """Vehicle navigation state. The simulation's truth on its truth key; on `simulation/nav`
    (simulation -> onboard), what the sensors last gave: the latest USBL fix delivered (taken at
    `usbl_time_s`, delivered later; repeated until the next), the IMU's attitude and rates, the
    DVL's velocity (meaningless without bottom lock: `dvl_valid`) and the pressure sensor's depth,
    each as of `sim_time_s`."""

    VERSION: ClassVar[int] = 2  # 2: usbl_time_s, depth_m, dvl_valid

    position_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)
    orientation_wxyz_world: np.ndarray = array("f8", (4,), -1.0, 1.0)
    velocity_mps_body: np.ndarray = array("f8", (3,), -100.0, 100.0)
    angular_velocity_radps_body: np.ndarray = array("f8", (3,), -100.0, 100.0)
    sim_time_s: float = scalar(0.0)
    # when the position was measured [s, simulated]; -1: no fix yet (the position means nothing)
    usbl_time_s: float = field(default=-1.0, metadata={"lo": -1.0, "hi": math.inf, "choices": ()})
    # [m] below the surface, from the pressure
    depth_m: float = field(default=0.0, metadata={"lo": -100.0, "hi": 11000.0, "choices": ()})
    dvl_valid: bool = True  # the DVL has bottom lock

    def __post_init__(self) -> None:
        super().__post_init__()
        check_unit_quaternion(self.orientation_wxyz_world)


@dataclass(frozen=True)
class VelocityRef(Message):
    """Vehicle velocity reference in the body frame, onboard -> simulation."""

    linear_mps_body: np.ndarray = array("f8", (3,), -10.0, 10.0)
    yaw_rate_radps: float = scalar(-5.0, 5.0)


@dataclass(frozen=True)
class ArmVelocityRef(Message):
    """Arm joint velocity references (model order: the robot package's arm joints, description.robot)
    and the gripper's opening speed; onboard -> simulation."""

    joint_velocities_radps: np.ndarray = array("f8", (None,), -5.0, 5.0, MAX_ARM_JOINTS)
    gripper_velocity_mps: float = scalar(-0.5, 0.5)


@dataclass(frozen=True)
class JointState(Message):
    """Arm joint positions and velocities (model order), the gripper's opening (the two fingers'
    travel, summed) and the force its motors squeeze with (as a real gripper reports from its
    motor current; 0 with the kinematic low level); simulation -> onboard."""

    VERSION: ClassVar[int] = 2  # 2: gripper_force_n

    positions_rad: np.ndarray = array("f8", (None,), -10.0, 10.0, MAX_ARM_JOINTS)
    velocities_radps: np.ndarray = array("f8", (None,), -100.0, 100.0, MAX_ARM_JOINTS)
    gripper_opening_m: float = scalar(0.0, 1.0)
    sim_time_s: float = scalar(0.0)
    gripper_force_n: float = field(default=0.0, metadata={"lo": 0.0, "hi": 1e4, "choices": ()})


@dataclass(frozen=True)
class Heartbeat(Message):
    """The vessel's heartbeat to onboard: goals keep flowing, and whether shore is heard
    (the satellite link is up). Onboard holds station when it stops or shore is lost."""

    shore_silence_s: float = scalar(0.0)  # since shore was last heard [s]
    shore_heard: bool = True
