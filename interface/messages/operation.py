"""The operator's commands and what comes back: telemetry, acknowledgements, mission status."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from abyss.common.errors import BadInput
from abyss.interface.messages.schema import MAX_ARM_JOINTS, Message, array, check_unit_quaternion, scalar

# missed: a waypoint not reached in its time; blocked: the arm stalled against something, it holds
MODES = ("idle", "moving", "reached", "hold", "missed", "blocked")
# hold: the vehicle holds station and the arm holds still; auto: the goals are flown, the arm
# once the vehicle holds its last waypoint; teleop: the goals are flown, the arm at once
OPERATOR_MODES = ("hold", "auto", "teleop")
COMMANDS = ("waypoints", "arm", "mode", "intervene")  # what an operator command sets
LEVER_STOPS = ("up", "down")
# an intervention's phases, in order; it ends done or failed (its reason says why); "" none yet
INTERVENTION_PHASES = ("", "approach", "pre-grasp", "grasp", "turn", "release", "retreat", "done", "failed")
IDLE_PHASES = ("", "done", "failed")  # no intervention in hand: none yet, or it ended
# before the fingers close, a goal resent is a refinement taken whole; after, its pivot's shift only
REFINABLE_PHASES = ("approach", "pre-grasp")


@dataclass(frozen=True)
class Telemetry(Message):
    """The onboard controllers' state, onboard -> vessel -> onshore. Errors are goal minus
    estimate: position in the world frame [m], heading [rad], the end-effector's position [m,
    world] and orientation (angle of the rotation from the estimate to the goal) [rad]. `mode`
    is the vehicle's, `arm_mode` the arm's; `failsafe` names why both hold ('' when they don't);
    `boot_id` is new each time onboard starts, so that shore sees a reboot and hands the goals
    in force again. The intervention (`intervention_*`, -1 and "" when none): the part, the
    phase and why it failed; how far onboard has turned it [rad], of the goal; the gripper as
    the low level reports it. The vehicle as the pilot watches it: its attitude as onboard
    estimates it (w, x, y, z), its velocity as the navigation last gave it [m/s, body] (the
    DVL's: meaningless without bottom lock), and the effort onboard commanded this step: the
    velocity sent (surge, sway, heave [m/s], yaw rate [rad/s]) over its limit (`max_speed_mps`,
    `max_yaw_rate_radps`), in [-1, 1]; zeros while onboard sends a stop. `piloted`: the waypoints
    flown are a pilot's goal (a MAVLink ground station's sticks or guided target), not a mission."""

    VERSION: ClassVar[int] = 5  # 2: boot_id; 3: the intervention; 4: attitude, velocity, effort; 5: piloted

    position_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)
    yaw_rad: float = scalar(-math.pi - 1e-6, math.pi + 1e-6)
    mode: str = scalar(choices=MODES)
    command_id: int = scalar(-1, 2**53)  # the waypoint list being flown; -1: none yet
    waypoint_index: int = scalar(0, 1000)
    waypoints_total: int = scalar(0, 1000)
    position_error_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)
    heading_error_rad: float = scalar(-math.pi - 1e-6, math.pi + 1e-6)
    arm_mode: str = scalar(choices=MODES)
    arm_command_id: int = scalar(-1, 2**53)  # the end-effector goal being reached; -1: none
    ee_position_error_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)
    ee_orientation_error_rad: float = scalar(0.0, math.pi + 1e-6)
    ee_position_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)  # where onboard sees the tool
    ee_orientation_wxyz_world: np.ndarray = array("f8", (4,), -1.0 - 1e-6, 1.0 + 1e-6)
    arm_positions_rad: np.ndarray = array("f8", (None,), -10.0, 10.0, MAX_ARM_JOINTS)  # model order
    failsafe: str = scalar()  # why the vehicle and arm hold; empty when they do not
    failsafe_events: int = scalar(0, 2**31)
    sim_time_s: float = scalar(0.0)
    operator_mode: str = field(default="auto", metadata={"choices": OPERATOR_MODES})
    boot_id: int = field(default=0, metadata={"lo": 0, "hi": 2**53, "choices": ()})
    intervention_id: int = field(default=-1, metadata={"lo": -1, "hi": 2**53, "choices": ()})
    intervention_target: str = ""
    intervention_phase: str = field(default="", metadata={"choices": INTERVENTION_PHASES})
    intervention_reason: str = ""  # why it failed, or, while a grasp is tried again, why
    turned_rad: float = field(default=0.0, metadata={"lo": -10.0, "hi": 10.0, "choices": ()})
    turn_goal_rad: float = field(default=0.0, metadata={"lo": -10.0, "hi": 10.0, "choices": ()})
    gripper_opening_m: float = field(default=0.0, metadata={"lo": 0.0, "hi": 1.0, "choices": ()})
    gripper_force_n: float = field(default=0.0, metadata={"lo": 0.0, "hi": 1e4, "choices": ()})
    orientation_wxyz_world: np.ndarray = array("f8", (4,), -1.0 - 1e-6, 1.0 + 1e-6, default=(1.0, 0, 0, 0))
    velocity_mps_body: np.ndarray = array("f8", (3,), -100.0, 100.0, default=(0.0, 0.0, 0.0))
    # the velocity command over its limit: surge, sway, heave, yaw rate
    effort_body: np.ndarray = array("f8", (4,), -1.0, 1.0, default=(0.0, 0.0, 0.0, 0.0))
    piloted: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        check_unit_quaternion(self.orientation_wxyz_world)

    @property
    def position_error_m(self) -> float:
        return float(np.linalg.norm(self.position_error_m_world))


@dataclass(frozen=True)
class ArmGoal(Message):
    """An end-effector pose goal: position [m] and orientation (w, x, y, z) in the world frame;
    onshore -> vessel -> onboard."""

    command_id: int = scalar(0, 2**53)
    position_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)
    orientation_wxyz_world: np.ndarray = array("f8", (4,), -1.0 - 1e-6, 1.0 + 1e-6)

    def __post_init__(self) -> None:
        super().__post_init__()
        check_unit_quaternion(self.orientation_wxyz_world)


@dataclass(frozen=True)
class Intervention(Message):
    """An operator's intent on a part of the panel (description.models.panel): turn valve `target` by
    `turn_rad`, or throw lever `target` to its stop `to` (up or down); onshore -> vessel, which
    resolves the part from the panel it recognised."""

    command_id: int = scalar(0, 2**53)
    target: str = scalar()
    turn_rad: float = scalar(-2 * math.pi, 2 * math.pi)  # a valve's; 0 for a lever
    to: str = scalar(choices=("", *LEVER_STOPS))  # a lever's; "" for a valve


@dataclass(frozen=True)
class InterventionGoal(Message):
    """An intervention resolved in the world frame (vessel -> onboard): the part's pivot [m] and
    rotation axis (unit), the tool point's grasp pose (position [m], orientation w, x, y, z), and
    the turn about the axis [rad, signed, from the grasp]; `to_stop`: the turn ends at a
    mechanical stop (a lever thrown), where the part stopping is success, not a fault."""

    command_id: int = scalar(0, 2**53)
    target: str = scalar()
    pivot_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)
    axis_world: np.ndarray = array("f8", (3,), -1.0 - 1e-6, 1.0 + 1e-6)
    grasp_m_world: np.ndarray = array("f8", (3,), -1e5, 1e5)
    grasp_orientation_wxyz_world: np.ndarray = array("f8", (4,), -1.0 - 1e-6, 1.0 + 1e-6)
    turn_rad: float = scalar(-2 * math.pi, 2 * math.pi)
    to_stop: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        check_unit_quaternion(self.grasp_orientation_wxyz_world)
        if abs(float(np.linalg.norm(self.axis_world)) - 1.0) > 1e-3:
            raise BadInput("axis_world: not a unit vector")


@dataclass(frozen=True)
class Waypoints(Message):
    """A list of waypoints, rows of x, y, z [m, world] and yaw [rad]; onshore -> vessel -> onboard."""

    command_id: int = scalar(0, 2**53)
    waypoints: np.ndarray = array("f8", (None, 4), -1e5, 1e5, max_rows=1000)


@dataclass(frozen=True)
class OperatorMode(Message):
    """The operator's control mode (see OPERATOR_MODES); onshore -> vessel -> onboard."""

    command_id: int = scalar(0, 2**53)
    mode: str = scalar(choices=OPERATOR_MODES)


@dataclass(frozen=True)
class CommandAck(Message):
    """Onboard's answer to an operator command: taken, or refused and why; onboard -> vessel
    -> onshore. A command sent again is answered again, the same way."""

    command_id: int = scalar(0, 2**53)
    command: str = scalar(choices=COMMANDS)
    reason: str = scalar()  # why it was refused; '' when taken

    @property
    def accepted(self) -> bool:
        return not self.reason


@dataclass(frozen=True)
class MissionStatus(Message):
    """The mission as the operator sees it from the telemetry that reached shore."""

    VERSION: ClassVar[int] = 2  # 2: the interventions

    mode: str = scalar(choices=MODES)
    waypoint_index: int = scalar(0, 1000)
    waypoints_total: int = scalar(0, 1000)
    position_error_m: float = scalar(0.0)
    heading_error_rad: float = scalar(0.0, math.pi + 1e-6)
    arm_mode: str = scalar(choices=MODES)
    ee_position_error_m: float = scalar(0.0)
    ee_orientation_error_rad: float = scalar(0.0, math.pi + 1e-6)
    failsafe: str = scalar()  # why the vehicle and arm hold; empty when they do not
    failsafe_events: int = scalar(0, 2**31)
    done: bool = False
    interventions_done: int = field(default=0, metadata={"lo": 0, "hi": 1000, "choices": ()})
    interventions_total: int = field(default=0, metadata={"lo": 0, "hi": 1000, "choices": ()})
    intervention_target: str = ""  # the one in hand, or the last
    intervention_phase: str = field(default="", metadata={"choices": INTERVENTION_PHASES})
    intervention_reason: str = ""  # why it failed, or why a grasp is tried again


@dataclass(frozen=True)
class ShoreEvent(Message):
    """Something shore saw of a station and what it did about it (onboard restarted: the goals in
    force handed again; the vessel restarted: its new scene stream kept on shore's map; shore
    restarted: the mission in progress rejoined), put on shore's own network as it happens, for
    the operator's tools: shore is the one place that tells a restart from the telemetry."""

    station: str = scalar()
    event: str = scalar()
    sim_time_s: float = scalar(0.0)  # the telemetry's latest when shore saw it [s, simulated]


# what the operator's tools (`abyss op`, `abyss teleop`, a console) hand the onshore station on
# operator/<topic>, which sends it down as op/<topic>
TOOL_COMMANDS: tuple[tuple[str, type[Message]], ...] = (
    ("mode", OperatorMode),
    ("waypoints", Waypoints),
    ("arm", ArmGoal),
    ("intervene", Intervention),
)
