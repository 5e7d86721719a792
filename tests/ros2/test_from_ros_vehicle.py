"""A real vehicle's ROS 2 driver in the simulation's place (`--ros2 simulation`, a hybrid run):
its nav_msgs/Odometry and sensor_msgs/JointState parse back to the abyss messages the gateway
sends the other way (a round trip through CDR gives the same message), the refusals say what is
wrong, and the gateway's keys for the simulation are the vehicle's, onboard's unchanged."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from abyss.common.errors import BadInput
from abyss.description.robot import robot_at
from abyss.interface.messages import JointState, Message, NavState, encode
from abyss.ros2 import from_ros, motion, msgs, types
from abyss.ros2.session import Session

SESSION = Session(robot_at(""))  # the shipped robot package
ROBOT = SESSION.robot


def _wire(message: Any) -> Any:
    """A ROS 2 message as the gateway receives it: CDR out and back."""
    return msgs.TYPESTORE.deserialize_cdr(msgs.serialize(message), message.__msgtype__)


def _same(a: Message, b: Message) -> bool:
    """The same message: the same bytes on abyss's wire."""
    return encode(a, 0, 0.0) == encode(b, 0, 0.0)


def _odometry(nav: NavState) -> Any:
    return _wire(motion.odometry(nav, msgs.header(nav.sim_time_s, msgs.WORLD), SESSION))


def _joint_state(joints: JointState) -> Any:
    return _wire(motion.joint_state(joints, msgs.header(joints.sim_time_s, ""), SESSION))


def _fused(position: list[float], quat: list[float], rates: list[float], ns: int) -> NavState:
    """A fused navigation, as the simulation's truth is and a driver's Odometry says: a fix every
    sample, the depth from the position, the DVL locked."""
    t = ns / 1e9
    q = np.array(quat) / np.linalg.norm(quat)
    return NavState(
        np.array(position),
        q,
        np.array(rates[:3]),
        np.array(rates[3:]),
        t,
        usbl_time_s=t,
        depth_m=-position[2],
    )


coordinate = st.floats(-1e3, 1e3, allow_nan=False)
height = st.floats(-1e3, 100.0, allow_nan=False)  # z: no more than 100 m above the surface (depth_m)
component = st.floats(-1.0, 1.0, allow_nan=False).filter(lambda v: abs(v) > 1e-3)
rate = st.floats(-50.0, 50.0, allow_nan=False)
stamp_ns = st.integers(0, 10**6 * 10**9)  # a stamp on whole nanoseconds, as ROS 2 has them


@given(
    position=st.tuples(coordinate, coordinate, height).map(list),
    quat=st.lists(component, min_size=4, max_size=4),
    rates=st.lists(rate, min_size=6, max_size=6),
    ns=stamp_ns,
)
def test_a_fused_navigation_goes_round_to_ros_and_back_unchanged(
    position: list[float], quat: list[float], rates: list[float], ns: int
) -> None:
    nav = _fused(position, quat, rates, ns)
    back = from_ros.odometry_in(_odometry(nav), SESSION)
    assert _same(back, nav), (back, nav)


def test_odometry_is_the_vehicle_s_fused_navigation() -> None:
    """usbl_time_s (every sample a fix) and sim_time_s are the stamp, depth -z, the DVL locked;
    a stamp off whole nanoseconds comes back within one."""
    nav = NavState(
        np.array([4.0, 0.5, -8.2]),
        np.array([np.cos(0.2), 0.0, 0.0, np.sin(0.2)]),
        np.array([0.1, 0.0, -0.05]),
        np.array([0.0, 0.0, 0.3]),
        12.345678901234,
        usbl_time_s=11.0,  # a measured fix's own time: Odometry has no place for it
        depth_m=8.19,
        dvl_valid=False,
    )
    back = from_ros.odometry_in(_odometry(nav), SESSION)
    assert back.sim_time_s == pytest.approx(nav.sim_time_s, abs=1e-9) and back.usbl_time_s == back.sim_time_s
    assert back.depth_m == pytest.approx(8.2) and back.dvl_valid
    assert np.array_equal(back.position_m_world, nav.position_m_world)
    assert np.array_equal(back.orientation_wxyz_world, nav.orientation_wxyz_world)
    assert np.array_equal(back.velocity_mps_body, nav.velocity_mps_body)
    assert np.array_equal(back.angular_velocity_radps_body, nav.angular_velocity_radps_body)


def test_odometry_is_refused_with_its_reason() -> None:
    nav = _fused([4.0, 0.0, -8.0], [1, 0, 0, 0], [0.0] * 6, 2 * 10**9)
    cases = [
        (lambda m: setattr(m.header, "frame_id", "odom"), "frame_id 'odom', expected 'world'"),
        (lambda m: setattr(m, "child_frame_id", "base_footprint"), "child_frame_id 'base_footprint'"),
        (lambda m: setattr(m.pose.pose.position, "x", float("nan")), "the pose is not finite"),
        (lambda m: setattr(m.twist.twist.angular, "z", float("inf")), "the twist is not finite"),
        (lambda m: setattr(m.pose.pose.orientation, "w", 0.5), r"not a unit quaternion \(norm 0\.5000\)"),
        (lambda m: setattr(m.pose.pose.position, "z", 500.0), "depth_m"),  # above the surface's bound
    ]
    for spoil, reason in cases:
        odometry = _odometry(nav)
        spoil(odometry)
        with pytest.raises(BadInput, match=reason):
            from_ros.odometry_in(odometry, SESSION)


@given(
    positions=st.lists(st.floats(-3.0, 3.0, allow_nan=False), min_size=6, max_size=6),
    velocities=st.lists(st.floats(-2.0, 2.0, allow_nan=False), min_size=6, max_size=6),
    opening=st.floats(0.0, 0.2, allow_nan=False, allow_subnormal=False),
    ns=stamp_ns,
)
def test_joints_go_round_to_ros_and_back_unchanged(
    positions: list[float], velocities: list[float], opening: float, ns: int
) -> None:
    joints = JointState(np.array(positions), np.array(velocities), opening, ns / 1e9)
    back = from_ros.joint_state_in(_joint_state(joints), SESSION)
    assert _same(back, joints), (back, joints)


def test_joints_are_read_by_name_in_any_order() -> None:
    """The arm's joints by the robot's names, other joints ignored, the gripper's opening its
    fingers' positions summed; no velocities: zeros."""
    names = [*ROBOT.arm_joints, *ROBOT.gripper_joints]
    order = [*reversed(names), "camera_tilt"]
    values = {name: 0.05 * (i + 1) for i, name in enumerate(names)} | {"camera_tilt": 0.7}
    message = msgs.ROS["sensor_msgs/msg/JointState"](
        header=msgs.header(3.5, ""),
        name=order,
        position=msgs.floats([values[n] for n in order]),
        velocity=msgs.floats([]),
        effort=msgs.floats([]),
    )
    back = from_ros.joint_state_in(_wire(message), SESSION)
    assert np.allclose(back.positions_rad, [values[n] for n in ROBOT.arm_joints])
    assert back.gripper_opening_m == pytest.approx(sum(values[n] for n in ROBOT.gripper_joints))
    assert np.array_equal(back.velocities_radps, np.zeros(len(ROBOT.arm_joints))) and back.sim_time_s == 3.5


def test_joints_are_refused_with_their_reason() -> None:
    joints = JointState(np.zeros(len(ROBOT.arm_joints)), np.zeros(len(ROBOT.arm_joints)), 0.05, 1.0)
    missing = ROBOT.arm_joints[2]
    cases = [
        (
            lambda m: setattr(m, "name", [n if n != missing else "unknown_joint" for n in m.name]),
            f"no joint {missing}",
        ),
        (lambda m: setattr(m, "position", m.position[:-1]), "positions"),
        (lambda m: setattr(m, "velocity", m.velocity[:2]), "2 velocities"),
        (lambda m: m.position.__setitem__(0, np.nan), "positions are not finite"),
        (lambda m: m.position.__setitem__(1, 20.0), "positions_rad"),  # outside abyss's bounds
    ]
    for spoil, reason in cases:
        message = _joint_state(joints)
        message.position = message.position.copy()
        spoil(message)
        with pytest.raises(BadInput, match=reason):
            from_ros.joint_state_in(message, SESSION)


def test_the_simulation_s_node_is_a_vehicle_and_onboard_s_is_unchanged() -> None:
    """The vehicle's driver is handed the velocity commands and provides its navigation and
    joints; the truth's Odometry parses nothing back and no node is handed or gives it."""
    assert types.gateway_keys("simulation") == (  # onboard's estimate too, which a twin renders at
        ("onboard/cmd/vehicle_velocity", "onboard/cmd/arm_velocity", "onboard/nav/estimate"),
        ("simulation/nav", "simulation/joints"),
    )
    down, up = types.gateway_keys("onboard")
    assert up == (
        "onboard/cmd/vehicle_velocity",
        "onboard/cmd/arm_velocity",
        "onboard/nav/estimate",  # a ROS 2 onboard's estimate (nav_msgs/Odometry), for a hybrid run's twin
        "onboard/telemetry",
        "onboard/cloud",
    )
    assert down[:2] == ("simulation/nav", "simulation/joints") and "simulation/truth" not in down
    truth = types.key_map("simulation/truth")
    assert truth is not None and all(t.parse is None for t in truth.topics)
    nav = types.key_map("simulation/nav")
    assert nav is not None and [t.name for t in nav.topics if t.parse is not None] == ["{key}"]
    assert [t.export for t in nav.topics] == [True, True]
