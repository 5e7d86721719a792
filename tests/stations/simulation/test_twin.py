"""A hybrid run's twin (stations/simulation/twin.py): it puts the virtual vehicle and arm where
onboard's navigation estimate and the real vehicle's joints say, on the site registered to the
vehicle's frame, and withholds its sensors while either is missing or stale. Here onboard's
estimate is the truth (a perfect estimate), so that the twin must stand exactly there."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from abyss.common.errors import BadInput
from abyss.common.geometry import quat_multiply
from abyss.config import Config, load
from abyss.interface.messages import JointState, NavState
from abyss.stations.simulation.twin import Twin
from abyss.stations.simulation.world import World, references

HYBRID = [
    'hybrid.vehicle=["nav", "joints", "sonar", "camera/right"]',
    'hybrid.twin=["camera/left", "camera/depth"]',
]


@pytest.fixture(scope="module")
def moved() -> tuple[Config, World]:
    """A whole simulation some way into a commanded motion, the arm off its stowed pose: the real
    vehicle the twin follows."""
    config = load(overrides=HYBRID)
    world = World(config.simulation, np.random.default_rng(0))
    for _ in range(10):
        world.step(references(None, None), config.simulation.control_period_s)
    p = world.plant.qpos
    world.data.qpos[p : p + 3] += [0.3, -0.2, 0.1]
    world.data.qpos[p + 3 : p + 7] = [math.cos(0.2), 0.02, -0.01, math.sin(0.2)]
    world.data.qpos[p + 3 : p + 7] /= np.linalg.norm(world.data.qpos[p + 3 : p + 7])
    for name, angle in zip(world.robot.arm_joints, (0.3, -0.4, 0.5, 0.2, -0.1, 0.6), strict=False):
        world.data.qpos[world.model.joint(name).qposadr[0]] = angle
    return config, world


def robot_qpos(world: World | Twin, names: tuple[str, ...]) -> np.ndarray:
    return np.array([world.data.qpos[world.model.joint(n).qposadr[0]] for n in names])


def test_the_twin_stands_where_the_real_vehicle_is_with_its_arm_and_gripper(
    moved: tuple[Config, World],
) -> None:
    config, world = moved
    twin = Twin(config)
    truth, joints = world.truth(), world.joints()  # onboard's estimate, perfect
    twin.take_estimate(truth, 0.0)
    twin.take_joints(joints, 0.0)
    base = world.model.joint(world.robot.base).qposadr[0]
    np.testing.assert_allclose(twin.data.qpos[base : base + 7], world.data.qpos[base : base + 7], atol=1e-9)
    names = world.robot.arm_joints + world.robot.gripper_joints
    np.testing.assert_allclose(robot_qpos(twin, names), robot_qpos(world, names), atol=1e-9)
    assert twin.data.time == truth.sim_time_s  # the frames rendered there carry the estimate's time
    # the twin's model is the simulation's world, so its cameras see what the simulation's would
    assert twin.model.nq == world.model.nq and twin.model.ncam == world.model.ncam


def test_on_a_registered_site_the_twin_stands_where_the_vehicle_is_on_it(moved: tuple[Config, World]) -> None:
    config, world = moved
    heading, origin = 0.7, np.array([120.0, -40.0, 3.0])
    registered = dataclasses.replace(
        config,
        hybrid=dataclasses.replace(config.hybrid, site_origin_m_nav=tuple(origin), site_heading_rad=heading),
    )
    twin = Twin(registered)
    truth = world.truth()
    c, s = math.cos(heading), math.sin(heading)
    in_nav = NavState(
        origin + np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ truth.position_m_world,
        quat_multiply(
            np.array([math.cos(heading / 2), 0.0, 0.0, math.sin(heading / 2)]), truth.orientation_wxyz_world
        ),
        truth.velocity_mps_body,
        truth.angular_velocity_radps_body,
        truth.sim_time_s,
        usbl_time_s=truth.sim_time_s,
        depth_m=truth.depth_m - origin[2],
    )
    twin.take_estimate(in_nav, 0.0)
    base = world.model.joint(world.robot.base).qposadr[0]
    np.testing.assert_allclose(twin.data.qpos[base : base + 7], world.data.qpos[base : base + 7], atol=1e-9)


def test_its_sensors_wait_for_navigation_and_joints_and_stop_when_either_goes_stale(
    moved: tuple[Config, World],
) -> None:
    config, world = moved
    twin = Twin(config)
    age = config.hybrid.nav_max_age_s
    assert twin.why_not(0.0) == "no navigation estimate from onboard yet"
    twin.take_estimate(world.truth(), 10.0)
    assert twin.why_not(10.0) == "no joints from the real vehicle yet"
    twin.take_joints(world.joints(), 10.2)
    assert twin.why_not(10.0 + age) == ""
    assert (
        twin.why_not(10.0 + age + 0.01)
        == "onboard's navigation estimate is older than hybrid.nav_max_age_s (0.5 s)"
    )
    twin.take_estimate(world.truth(), 10.6)
    assert twin.why_not(10.2 + age + 0.01) == "the joints are older than hybrid.nav_max_age_s (0.5 s)"


def test_it_renders_only_the_sensors_it_provides_and_refuses_another_arm(moved: tuple[Config, World]) -> None:
    config, world = moved
    twin = Twin(config)
    robot = world.robot
    assert twin.cameras(robot.cameras) == tuple(
        c for c in robot.cameras if robot.camera_topic(c) in ("camera/left", "camera/depth")
    )
    assert twin.renders("cameras") and not twin.renders("sonar")
    joints = world.joints()
    with pytest.raises(BadInput, match="5 joints, the robot's arm has 6"):
        twin.take_joints(dataclasses.replace(joints, positions_rad=joints.positions_rad[:5]), 0.0)
    assert isinstance(joints, JointState)
