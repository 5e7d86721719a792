"""The small panel (description/models/sites/small_panel), sized for the BlueROV2 Heavy's Reach Alpha 5:
the site loads and composes with the robot, its mission's waypoints pass onboard's checks, both
parts lie within the arm's reach from the last waypoint, and the arm with the vehicle's axes
(whole body, as the robot's configuration flies it) brings the tool onto each part's grasp from
there, on the kinematic low level (the tool measured on MuJoCo's site)."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from abyss.common.geometry import rotation_of
from abyss.config import Config, load
from abyss.description.robot import ROBOTS_DIR, robot_at
from abyss.description.site import SITES_DIR, site_at, world_model
from abyss.interface.messages import Heartbeat, Intervention, InterventionGoal, RecognisedObjects, Waypoints
from abyss.launch.mission_check import check_reach
from abyss.stations.onboard.arm_control import ArmController, ArmKinematics, PoseReference
from abyss.stations.onboard.commands import CommandGate
from abyss.stations.onboard.core import Onboard, OnboardInputs, OnboardOutputs
from abyss.stations.onboard.intervention import InterventionRun, Phase
from abyss.stations.simulation.lowlevel import References
from abyss.stations.simulation.world import World
from abyss.stations.vessel.intents import resolve

pytestmark = pytest.mark.timeout(120)
ROBOT = robot_at(str(ROBOTS_DIR / "bluerov2_heavy_alpha5"))
SITE = site_at(str(SITES_DIR / "small_panel"))
PERIOD_S = 0.05


def config(*overrides: str) -> Config:
    return load(
        None, [f"simulation.robot={ROBOT.directory}", f"simulation.site={SITE.directory}", *overrides]
    )


def test_the_site_loads_with_a_valve_and_a_lever_and_composes_with_the_robot() -> None:
    panel = SITE.panel
    assert [(p.name, p.kind) for p in panel.parts] == [("valve", "valve"), ("lever", "lever")]
    assert 2 * panel.plate_half_size_m[1] == pytest.approx(0.6) and 2 * panel.plate_half_size_m[2] == 0.5
    model = world_model(ROBOT, SITE)
    for part in panel.part_names:
        assert np.allclose(model.body(part).pos, panel.parts[panel.part_names.index(part)].pivot_m_panel)
    flown = config()
    assert flown.mission.interventions == (("valve", "90"), ("lever", "down"))
    assert flown.simulation.start_position_m_world == (1.5, 0.0, -8.5)


def test_the_waypoints_pass_onboards_checks_and_both_parts_lie_within_reach_of_the_last() -> None:
    flown = config()
    check_reach(flown)  # as `abyss up` checks it before any station starts
    shoulder_m_vehicle, reach_m = ArmKinematics(ROBOT).reach()
    gate = CommandGate(flown.mission, shoulder_m_vehicle, reach_m)
    assert gate.check_waypoints(np.array(flown.mission.waypoints)) == ""
    last = np.array(flown.mission.waypoints[-1])
    for part in SITE.panel.part_names:
        pivot, _, grasp = SITE.panel.part_geometry(part)
        grasp_m_world = np.add(SITE.panel.position_m_world, pivot + grasp)
        assert gate.check_arm(grasp_m_world, last) == ""
        distance_m = float(np.linalg.norm(grasp_m_world - (last[:3] + shoulder_m_vehicle)))
        assert distance_m < 0.9 * reach_m, (part, distance_m, reach_m)  # not at the arm's stretch


def at_the_last_waypoint() -> tuple[Config, World]:
    """The robot's configuration on the kinematic low level, cameras off, and a world with the
    vehicle on the mission's last waypoint."""
    flown = config("simulation.low_level=kinematic", "simulation.camera_rate_hz=0")
    x, y, z, yaw = flown.mission.waypoints[-1]
    start = config(
        "simulation.low_level=kinematic",
        "simulation.camera_rate_hz=0",
        f"simulation.start_position_m_world=[{x}, {y}, {z}]",
        f"simulation.start_yaw_rad={yaw}",
    )
    return flown, World(start.simulation, np.random.default_rng(0))


def resolved(part: str, amount: str) -> InterventionGoal:
    """The goal the vessel resolves for `part` with the panel recognised where it stands."""
    panel = SITE.panel
    objects = RecognisedObjects(
        ("panel",), np.array([[*panel.position_m_world, 1.0, 0, 0, 0]]), np.array([panel.plate_half_size_m]),
        np.ones(1), "texture", 0.0,
    )  # fmt: skip
    goal, why = resolve(panel, Intervention(1, part, *panel.intent(part, amount)), objects)
    assert goal is not None, why
    return goal


@pytest.mark.parametrize("part", ["valve", "lever"])
def test_the_whole_body_arm_brings_the_tool_onto_each_grasp_from_the_last_waypoint(part: str) -> None:
    """From the stowed arm at the last waypoint, within 20 s: the tool within 5 mm and 2 degrees of
    the grasp the vessel resolves for the mission's intervention, the vehicle within 0.25 m of it
    (measured: 0.02 mm and 0.0003 deg, the vehicle 0.14 m off for the valve, 0.07 for the lever;
    without whole body the arm cannot level the approach, and unweighed the vehicle moves 0.29 m)."""
    flown, world = at_the_last_waypoint()
    goal = resolved(part, dict(flown.mission.interventions)[part])
    arm = ArmController(flown.onboard, flown.mission, ROBOT)
    reference = PoseReference(np.array(goal.grasp_m_world), rotation_of(goal.grasp_orientation_wxyz_world))
    for _ in range(round(20.0 / PERIOD_S)):
        truth, joints = world.truth(), world.joints()
        out = arm.step(
            truth.position_m_world, truth.orientation_wxyz_world, joints.positions_rad, True, reference
        )
        assert out.vehicle_velocity is not None
        world.step(References(out.vehicle_velocity, out.joint_velocities_radps, 0.0), PERIOD_S)
    site = world.data.site(ROBOT.end_effector_site)
    error_m = float(np.linalg.norm(site.xpos - reference.position_m_world))
    rotation = site.xmat.reshape(3, 3)
    error_deg = math.degrees(np.linalg.norm(pin.log3(reference.rotation @ rotation.T)))
    moved_m = float(np.linalg.norm(world.truth().position_m_world - flown.mission.waypoints[-1][:3]))
    assert error_m < 0.005 and error_deg < 2.0 and moved_m < 0.25, (error_m, error_deg, moved_m)


@pytest.mark.parametrize("then", ["done", "onboard restarted"])
def test_a_whole_body_vehicle_stows_its_arm_then_flies_back_onto_its_mark(then: str) -> None:
    """The whole-body arm brings the tool onto the valve's pre-grasp pose from the last waypoint,
    moving the vehicle off its mark; the intervention then done, or onboard restarted and handed
    the waypoint again, the arm stows while the vehicle holds still, then the vehicle flies back
    onto its mark with the arm stowed. The arm held the tool on the pre-grasp pose in the world
    before, and with it the vehicle wherever that left it (292 mm off its mark at the end of the
    library's nominal run); carried back unstowed, the tool swept into the lever it had just
    thrown, and a restarted onboard's vehicle turned the valve to -45 degrees."""
    flown, world = at_the_last_waypoint()
    mark = np.array(flown.mission.waypoints[-1])
    goal = resolved("valve", "90")
    core = Onboard(flown)
    commands: list[Waypoints] = [Waypoints(1, (tuple(mark),))]

    def step(now_s: float) -> OnboardOutputs:
        nonlocal commands
        beats = [Heartbeat(0.0, True)] if round(now_s / PERIOD_S) % 10 == 0 else []
        out = core.step(OnboardInputs(commands, beats, [world.truth()], world.joints()), now_s)
        commands = []
        assert out.vehicle is not None and out.arm is not None
        world.step(
            References(np.r_[out.vehicle.linear_mps_body, out.vehicle.yaw_rate_radps],
                       out.arm.joint_velocities_radps, out.arm.gripper_velocity_mps),
            PERIOD_S,
        )  # fmt: skip
        return out

    for i in range(round(5.0 / PERIOD_S)):  # on the mark, navigation settled: the waypoint reached
        step(i * PERIOD_S)
    assert core.vehicle.index == 1  # reached
    run = core.intervention = InterventionRun(goal, core.grip)  # taken where the vehicle holds
    now_s = 5.0
    while run.phase == Phase.APPROACH:  # the whole-body arm brings the tool onto the pre-grasp pose
        step(now_s)
        now_s += PERIOD_S
        assert now_s < 30.0, "the pre-grasp pose not reached"
    left_at = world.truth().position_m_world
    # at the joints' speed limit, then a little more to settle
    stow_s = (
        np.abs(world.joints().positions_rad - ROBOT.stowed_rad).max() / flown.onboard.max_joint_speed_radps
        + 3.0
    )
    if then == "done":
        run.phase = Phase.DONE  # backed off there, as the retreat ends
    else:  # a new onboard, handed the mission's last waypoint again by shore
        core, commands = Onboard(flown), [Waypoints(2, (tuple(mark),))]
    done_s, stowed_s, moved_while_stowing_m, telemetry = now_s, None, 0.0, None
    for i in range(round(30.0 / PERIOD_S)):
        telemetry = step(done_s + i * PERIOD_S).telemetry or telemetry
        if stowed_s is None and core.homing is not None and core.homing.stowed:
            stowed_s = i * PERIOD_S
        if stowed_s is None:
            moved_while_stowing_m = max(
                moved_while_stowing_m, float(np.linalg.norm(world.truth().position_m_world - left_at))
            )
    moved_m = float(np.linalg.norm(left_at - mark[:3]))
    off_m = float(np.linalg.norm(world.truth().position_m_world - mark[:3]))
    stow_rad = float(np.abs(world.joints().positions_rad - np.array(ROBOT.stowed_rad)).max())
    assert stowed_s is not None and stowed_s < stow_s and stow_rad < 0.03, (stowed_s, stow_s, stow_rad)
    assert moved_m > 0.1 and moved_while_stowing_m < 0.02 and off_m < 0.02, (
        moved_m,
        moved_while_stowing_m,
        off_m,
    )
    assert telemetry is not None
    if then == "done":
        assert telemetry.arm_mode == "reached"
        assert np.linalg.norm(telemetry.ee_position_error_m_world) < 0.01  # told against the stowed tool
