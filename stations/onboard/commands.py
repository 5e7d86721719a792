"""The operator's commands as onboard takes them: each is checked against what the vehicle can
do before it is flown, and answered with its fate. A command taken and sent again (shore resends
until it hears the answer) gets the same answer and changes nothing; a refused one sent again is
judged again, so that a refusal whose cause has cleared (the arm busy, a goal out of reach from
where the vehicle would have held) is not final."""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence

import numpy as np

from abyss.common.geometry import rotation_of_rpy
from abyss.config.system import Box, MissionConfig
from abyss.interface.messages import ArmGoal, CommandAck, InterventionGoal, OperatorMode, Waypoints

ANSWERS_KEPT = 64


def box_clearance_m(point_m_world: np.ndarray, box: Box) -> float:
    """Distance from a point to a box (centre, half sizes) [m]; 0 inside."""
    outside = np.maximum(np.abs(point_m_world - np.array(box[:3])) - np.array(box[3:]), 0.0)
    return float(np.linalg.norm(outside))


def shoulder_distance_m(
    shoulder_m_vehicle: np.ndarray, vehicle_goal: np.ndarray, position_m_world: np.ndarray
) -> float:
    """How far `position_m_world` lies from the arm's shoulder with the vehicle holding at
    `vehicle_goal` (x, y, z [m, world], yaw [rad]) [m]: what an arm goal's reach is judged by."""
    x, y, z, yaw = vehicle_goal
    shoulder_m_world = np.array([x, y, z]) + rotation_of_rpy(0.0, 0.0, yaw) @ shoulder_m_vehicle
    return float(np.linalg.norm(np.asarray(position_m_world) - shoulder_m_world))


class CommandGate:
    """Checks operator commands and remembers the ones it took."""

    def __init__(self, mission: MissionConfig, shoulder_m_vehicle: np.ndarray, reach_m: float) -> None:
        self.clearance_m = mission.vehicle_clearance_m
        self.obstacles: Sequence[Box] = mission.obstacles
        self.shoulder_m_vehicle = shoulder_m_vehicle
        self.reach_m = reach_m
        self.answers: OrderedDict[tuple[str, int], CommandAck] = OrderedDict()  # taken, by (type, id)

    def answer(
        self,
        command: Waypoints | ArmGoal | OperatorMode | InterventionGoal,
        vehicle_goal: np.ndarray,
        arm_busy: str = "",
    ) -> tuple[CommandAck, bool]:
        """The acknowledgement of `command`, and whether it is new and taken (to be applied).
        `vehicle_goal`: x, y, z [m, world], yaw [rad] where the vehicle will hold; `arm_busy`:
        why the arm takes no new goal now ('' when it does)."""
        known = self.answers.get((command.TYPE, command.command_id))
        if known is not None:
            return known, False
        if isinstance(command, Waypoints):
            kind, reason = "waypoints", self.check_waypoints(command.waypoints)
        elif isinstance(command, ArmGoal):
            kind, reason = "arm", arm_busy or self.check_arm(command.position_m_world, vehicle_goal)
        elif isinstance(command, InterventionGoal):
            kind, reason = "intervene", arm_busy or self.check_arm(command.grasp_m_world, vehicle_goal)
        else:
            kind, reason = "mode", ""
        ack = CommandAck(command.command_id, kind, reason)
        if ack.accepted:
            self.answers[command.TYPE, command.command_id] = ack
            while len(self.answers) > ANSWERS_KEPT:
                self.answers.popitem(last=False)
        return ack, ack.accepted

    def check_waypoints(self, waypoints: np.ndarray) -> str:
        """Why the list cannot be flown; '' when it can."""
        if len(waypoints) == 0:
            return "no waypoints"
        for i, (x, y, z, _) in enumerate(waypoints):
            where = f"waypoint {i} ({x:.2f}, {y:.2f}, {z:.2f}) m"
            if z > -self.clearance_m:
                return f"{where} is within {self.clearance_m} m of the surface"
            for j, box in enumerate(self.obstacles):
                if box_clearance_m(np.array([x, y, z]), box) < self.clearance_m:
                    return f"{where} is within {self.clearance_m} m of obstacle {j} (mission.obstacles)"
        return ""

    def check_arm(self, position_m_world: np.ndarray, vehicle_goal: np.ndarray) -> str:
        """Why the end-effector cannot reach the goal from where the vehicle will hold; ''
        when it can."""
        x, y, z, _ = vehicle_goal
        distance_m = shoulder_distance_m(self.shoulder_m_vehicle, vehicle_goal, position_m_world)
        if distance_m > self.reach_m:
            return (
                f"out of reach: {distance_m:.2f} m from the shoulder where the vehicle will hold "
                f"({x:.2f}, {y:.2f}, {z:.2f}) m, the arm reaches {self.reach_m:.2f} m"
            )
        return ""
