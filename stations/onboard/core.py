"""Onboard's core, without Zenoh: one control step from what came in since the last one to
what goes out. The vehicle flies its waypoints, the arm moves once the vehicle holds its last
waypoint (with `onboard.whole_body`, the vehicle then moves with the arm); both hold still
while the failsafe is on (the vessel's heartbeats stopped, or it reports shore silent) or the
operator says hold; in teleop mode the arm follows its goal at once. Each operator command is
checked (`commands.py`) and acknowledged with its fate before it is flown."""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from abyss.common.geometry import quat_wxyz_of, yaw_of
from abyss.config import Config, robot_of, site_of
from abyss.interface.messages import (
    ArmGoal,
    ArmVelocityRef,
    CommandAck,
    Heartbeat,
    InterventionGoal,
    JointState,
    NavState,
    OperatorMode,
    Telemetry,
    VelocityRef,
    Waypoints,
    new_id,
)
from abyss.stations.onboard.arm_control import ArmController, ArmOutput
from abyss.stations.onboard.commands import CommandGate
from abyss.stations.onboard.failsafe import Failsafe
from abyss.stations.onboard.homing import Homing
from abyss.stations.onboard.intervention import Grip, InterventionRun
from abyss.stations.onboard.modes import ControlMode, Mode
from abyss.stations.onboard.navigation import NavFilter
from abyss.stations.onboard.vehicle_control import ControlOutput, VehicleController

GRIPPER_GAIN_PER_S = 2.0
log = logging.getLogger(__name__)
Command = Waypoints | ArmGoal | OperatorMode | InterventionGoal  # an operator's


@dataclass
class OnboardInputs:
    """What reached onboard since the last step, oldest first."""

    commands: list[Command] = field(default_factory=list)
    heartbeats: list[Heartbeat] = field(default_factory=list)
    nav: list[NavState] = field(default_factory=list)
    joints: JointState | None = None  # the latest


@dataclass
class OnboardOutputs:
    acks: list[CommandAck] = field(default_factory=list)
    vehicle: VelocityRef | None = None  # None until navigation and joints have come
    arm: ArmVelocityRef | None = None
    telemetry: Telemetry | None = None  # every `telemetry_period_s`
    # the navigation estimate after each navigation message, once settled: for the frames' poses, and
    # published (nav/estimate) for a hybrid run's twin to render at
    estimates: list[NavState] = field(default_factory=list)
    arm_m_world: np.ndarray | None = None  # the arm's chain, for the perception's self-filter


class Onboard:
    def __init__(self, config: Config) -> None:
        cfg = self.cfg = config.onboard
        self.vehicle = VehicleController(cfg, config.mission)
        self.robot = robot_of(config)
        self.arm = ArmController(cfg, config.mission, self.robot)
        gripper = self.robot.spec.arm.gripper
        self.grip = Grip.of(
            gripper.opening_m, self.robot.closed_gap_m, site_of(config).panel.handle_thickness_m
        )
        self.nav_filter = NavFilter(cfg)
        self.joints_s: float | None = None  # the latest joints' time (a stale one does not move it)
        self.failsafe = Failsafe(
            cfg.goal_timeout_s,
            cfg.hold_on_shore_loss,
            config.hybrid.nav_max_age_s if config.hybrid.on else 0.0,
        )
        self.gate = CommandGate(config.mission, *self.arm.kinematics.reach())
        self.operator_mode = ControlMode.AUTO
        self.every = max(1, round(cfg.telemetry_period_s / cfg.control_period_s))
        self.position_m_world: np.ndarray | None = None
        self.orientation_wxyz_world = np.array([1.0, 0.0, 0.0, 0.0])
        self.velocity_mps_body = np.zeros(3)  # as the latest navigation gave it
        self.sim_time_s = 0.0
        self.tick = 0
        self.boot_id = new_id()  # shore sees a reboot by it, and hands the goals in force again
        self.intervention: InterventionRun | None = None  # the latest, once taken
        self.homing: Homing | None = None  # whole body: the way back onto the mark after an intervention
        self.waiting: dict[tuple[str, int], Command] = {}  # arm goals judged once navigation settles
        self.pilot_goals: set[int] = set()  # waypoint commands that are a pilot's goal (mavlink.vehicle)

    def _arm_busy(self) -> str:
        run = self.intervention
        if run is None or not run.active:
            return ""
        return f"the intervention on {run.goal.target} is in progress ({run.phase.value})"

    def _holding_at(self) -> np.ndarray:
        """Where the vehicle will hold: x, y, z [m, world], yaw [rad]."""
        if len(self.vehicle.waypoints):
            return np.asarray(self.vehicle.waypoints[-1])
        if self.position_m_world is not None:
            return np.r_[self.position_m_world, yaw_of(self.orientation_wxyz_world)]
        return np.zeros(4)

    def _judged_now(self, commands: Sequence[Command]) -> list[Command]:
        """The commands to judge in this period. An arm's or an intervention's goal waits,
        unanswered, while navigation has not settled: where the vehicle will hold is not known yet
        (a restarted onboard judged the first intervene from nowhere, "out of reach: 8.68 m"), and
        a goal refused there would not be sent again. It is judged once navigation settles."""
        if self.nav_filter.settled:
            judged, self.waiting = [*self.waiting.values(), *commands], {}
            return judged
        judged = []
        for command in commands:
            known = (command.TYPE, command.command_id) in self.gate.answers
            if isinstance(command, ArmGoal | InterventionGoal) and not known:
                if (command.TYPE, command.command_id) not in self.waiting:
                    log.info("%s command %d waits for navigation to settle", command.TYPE, command.command_id)
                self.waiting[command.TYPE, command.command_id] = command
            else:
                judged.append(command)
        return judged

    def step(self, inputs: OnboardInputs, now_s: float) -> OnboardOutputs:
        """One control period at `now_s` [s, this station's monotonic clock]."""
        out = OnboardOutputs()
        for command in self._judged_now(inputs.commands):
            ack, taken = self.gate.answer(command, self._holding_at(), self._arm_busy())
            out.acks.append(ack)
            if (
                not taken
                and isinstance(command, InterventionGoal)
                and self.intervention is not None
                and self.intervention.refine(command)
            ):
                log.info("intervention %d refined", command.command_id)
            elif not taken:
                log.info("%s command %d not taken: %s", ack.command, ack.command_id, ack.reason or "a resend")
            elif isinstance(command, Waypoints):
                self.vehicle.set_waypoints(command.command_id, command.waypoints)
            elif isinstance(command, ArmGoal):
                self.arm.set_goal(
                    command.command_id, command.position_m_world, command.orientation_wxyz_world
                )
                self.intervention = None
            elif isinstance(command, InterventionGoal):
                self.intervention, self.homing = InterventionRun(command, self.grip), None
            elif isinstance(command, OperatorMode):
                self.operator_mode = ControlMode(command.mode)  # from the wire
        for beat in inputs.heartbeats:
            self.failsafe.heard(now_s, beat)
        if inputs.nav:
            self.failsafe.navigated(now_s)
        for nav in inputs.nav:
            self.position_m_world, self.orientation_wxyz_world = self.nav_filter.update(nav)
            self.velocity_mps_body = nav.velocity_mps_body
            self.sim_time_s = nav.sim_time_s
            if self.position_m_world is not None and self.nav_filter.settled:  # else frames wait
                out.estimates.append(
                    NavState(
                        self.position_m_world.copy(),
                        np.array(self.orientation_wxyz_world),
                        nav.velocity_mps_body,
                        nav.angular_velocity_radps_body,
                        nav.sim_time_s,
                        usbl_time_s=nav.usbl_time_s,
                        depth_m=nav.depth_m,
                        dvl_valid=nav.dvl_valid,
                    )
                )
        if inputs.joints is not None and inputs.joints.sim_time_s != self.joints_s:
            self.failsafe.jointed(now_s)
            self.joints_s = inputs.joints.sim_time_s
        if self.position_m_world is None or inputs.joints is None:
            return out
        self._control(inputs.joints, now_s, out)
        self.tick += 1
        return out

    def _control(self, joints: JointState, now_s: float, out: OnboardOutputs) -> None:
        assert self.position_m_world is not None
        cfg, vehicle, arm = self.cfg, self.vehicle, self.arm
        position, orientation = self.position_m_world, self.orientation_wxyz_world
        arm_rad = joints.positions_rad
        operator_hold = self.operator_mode == ControlMode.HOLD
        hold = self.failsafe.check(now_s) or ("operator hold" if operator_hold else "")
        v = vehicle.step(position, yaw_of(orientation), cfg.control_period_s, hold=bool(hold))
        arm_free = v.mode in (Mode.REACHED, Mode.IDLE) or self.operator_mode == ControlMode.TELEOP
        enabled = not hold and arm_free and self.nav_filter.steady  # the arm's goals are in the world
        run, reference, gripper_mps = self.intervention, None, None
        if run is not None:
            arm.kinematics.update(position, orientation, arm_rad)
            command = run.step(
                arm.kinematics.pose(arm.kinematics.ee),
                joints.gripper_opening_m,
                cfg.control_period_s,
                enabled,
            )
            reference, gripper_mps = command.reference, command.gripper_mps
        backed_off = run is not None and not run.active
        homing = self._homing(v.mode == Mode.MOVING or backed_off)
        if homing is not None and backed_off:  # the tool told against its stowed pose
            reference = homing.reference(arm.kinematics, position, orientation)
        a = arm.step(position, orientation, arm_rad, enabled, reference, joints.sim_time_s)
        if backed_off and a.mode == Mode.MOVING:
            a = dataclasses.replace(a, mode=Mode.REACHED)
        stowing = homing is not None and not hold  # in the joints: no need of a settled navigation
        gripper = self._gripper_mps(gripper_mps, a, joints)
        if stowing:
            assert homing is not None
            stow_radps, gripper = homing.step(arm_rad, joints.gripper_opening_m)
            mode = (Mode.REACHED if homing.stowed else Mode.MOVING) if backed_off else a.mode
            a = dataclasses.replace(a, joint_velocities_radps=stow_radps, vehicle_velocity=None, mode=mode)
        out.arm_m_world = arm.kinematics.chain_m_world()
        linear, yaw_rate = v.linear_mps_body, v.yaw_rate_radps
        if a.vehicle_velocity is not None and a.mode in (Mode.MOVING, Mode.REACHED):
            linear, yaw_rate = a.vehicle_velocity[:3], float(a.vehicle_velocity[3])
        if stowing and homing is not None and not homing.stowed:  # held still until the arm is stowed
            linear, yaw_rate = np.zeros(3), 0.0
        sent = out.vehicle = VelocityRef(linear, yaw_rate)
        out.arm = ArmVelocityRef(a.joint_velocities_radps, gripper)
        if self.failsafe.blind:  # no navigation: stopped, not steered by an estimate gone still
            sent = out.vehicle = VelocityRef(np.zeros(3), 0.0)
            out.arm = ArmVelocityRef(np.zeros(len(arm_rad)), 0.0)
        armless = self.failsafe.arm_check(now_s)
        if armless:  # the joints stopped: the arm is not driven on from its last ones
            out.arm = ArmVelocityRef(np.zeros(len(arm_rad)), 0.0)
        if self.tick % self.every == 0:
            out.telemetry = self._telemetry(v, a, joints, hold or armless, sent)

    def _homing(self, due: bool) -> Homing | None:
        """A whole-body vehicle's homing (homing.py), kept while it is `due` (the vehicle flies
        between waypoints, or the intervention backed off) in automatic mode; None otherwise."""
        if not (due and self.cfg.whole_body and self.operator_mode == ControlMode.AUTO):
            self.homing = None
        elif self.homing is None:
            self.homing = Homing(self.robot.stowed_rad, self.cfg.max_joint_speed_radps, self.grip)
        return self.homing

    def _gripper_mps(self, intervention_mps: float | None, a: ArmOutput, joints: JointState) -> float:
        """The gripper's speed [m/s]: the intervention's; without one, opened while the arm
        reaches for its goal; else still."""
        if self.intervention is None and a.mode in (Mode.MOVING, Mode.REACHED):
            opening_error_m = self.grip.reach_m - joints.gripper_opening_m
            return float(np.clip(GRIPPER_GAIN_PER_S * opening_error_m, -0.05, 0.05))
        return 0.0 if intervention_mps is None else intervention_mps

    def _telemetry(
        self, v: ControlOutput, a: ArmOutput, joints: JointState, hold: str, sent: VelocityRef
    ) -> Telemetry:
        """The controllers' state for the vessel; modes and phases as their wire values; `sent`:
        the velocity sent to the vehicle this step, as effort."""
        assert self.position_m_world is not None
        cfg = self.cfg
        limits = (cfg.max_speed_mps, cfg.max_speed_mps, cfg.max_speed_mps, cfg.max_yaw_rate_radps)
        effort = np.clip(np.r_[sent.linear_mps_body, sent.yaw_rate_radps] / limits, -1.0, 1.0)
        arm, run = self.arm, self.intervention
        ee_pose = arm.kinematics.pose(arm.kinematics.ee)
        intervention_id, target, phase, reason, turned_rad, turn_goal_rad = (
            (-1, "", "", "", 0.0, 0.0)
            if run is None
            else (
                run.goal.command_id,
                run.goal.target,
                run.phase.value,
                run.reason or run.retry,
                float(np.clip(run.turned_rad, -10.0, 10.0)),
                run.goal.turn_rad,
            )
        )
        return Telemetry(
            position_m_world=self.position_m_world,
            yaw_rad=yaw_of(self.orientation_wxyz_world),
            mode=v.mode.value,
            command_id=self.vehicle.command_id,
            waypoint_index=v.waypoint_index,
            waypoints_total=v.waypoints_total,
            position_error_m_world=v.position_error_m_world,
            heading_error_rad=v.heading_error_rad,
            arm_mode=a.mode.value,
            arm_command_id=arm.command_id,
            ee_position_error_m_world=a.position_error_m_world,
            ee_orientation_error_rad=a.orientation_error_rad,
            ee_position_m_world=ee_pose.translation,
            ee_orientation_wxyz_world=quat_wxyz_of(ee_pose.rotation),
            arm_positions_rad=joints.positions_rad[: len(self.robot.arm_joints)],
            failsafe=hold,
            failsafe_events=self.failsafe.events,
            sim_time_s=self.sim_time_s,
            operator_mode=self.operator_mode.value,
            boot_id=self.boot_id,
            gripper_opening_m=joints.gripper_opening_m,
            gripper_force_n=joints.gripper_force_n,
            intervention_id=intervention_id,
            intervention_target=target,
            intervention_phase=phase,
            intervention_reason=reason,
            turned_rad=turned_rad,
            turn_goal_rad=turn_goal_rad,
            orientation_wxyz_world=self.orientation_wxyz_world,
            velocity_mps_body=self.velocity_mps_body,
            effort_body=effort,
            piloted=self.vehicle.command_id in self.pilot_goals,
        )
