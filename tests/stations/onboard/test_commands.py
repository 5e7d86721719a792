"""Onboard's check of operator commands: what it refuses and why, and that a resent command is
answered the same way without being taken twice."""

from __future__ import annotations

import numpy as np

from abyss.config.system import MissionConfig
from abyss.description.robot import robot_at
from abyss.interface.messages import ArmGoal, OperatorMode, Waypoints
from abyss.stations.onboard.arm_control import ArmKinematics
from abyss.stations.onboard.commands import CommandGate, box_clearance_m

ROBOT = robot_at("")  # the shipped robot package


IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
LAST_WAYPOINT = np.array([3.2, 0.0, -8.0, 0.0])  # the default mission's, facing the panel


def gate() -> CommandGate:
    return CommandGate(MissionConfig(), *ArmKinematics(ROBOT).reach())


def test_box_clearance() -> None:
    box = (0.0, 0.0, 0.0, 1.0, 2.0, 3.0)
    assert box_clearance_m(np.array([0.5, 0.0, 0.0]), box) == 0.0
    assert np.isclose(box_clearance_m(np.array([4.0, 6.0, 0.0]), box), 5.0)


def test_waypoints_near_the_surface_or_an_obstacle_are_refused_with_the_reason() -> None:
    g = gate()
    assert g.check_waypoints(np.array(MissionConfig().waypoints)) == ""
    assert "of the surface" in g.check_waypoints(np.array([[1.0, 0.0, -0.2, 0.0]]))
    assert "obstacle 1" in g.check_waypoints(np.array([[1.0, 0.0, -7.0, 0.0], [2.0, 0.0, -9.7, 0.0]]))
    assert "waypoint 1" in g.check_waypoints(np.array([[1.0, 0.0, -7.0, 0.0], [2.0, 0.0, -9.7, 0.0]]))
    assert "obstacle 0" in g.check_waypoints(np.array([[4.7, 0.0, -8.6, 0.0]]))  # at the panel's plate


def test_an_arm_goal_out_of_reach_from_where_the_vehicle_will_hold_is_refused() -> None:
    g = gate()
    x, y, z = 4.86, 0.0, -8.35  # the middle valve's handle
    assert g.check_arm(np.array([x, y, z]), LAST_WAYPOINT) == ""
    assert "out of reach" in g.check_arm(np.array([x + 1.5, y, z]), LAST_WAYPOINT)
    turned_away = np.r_[LAST_WAYPOINT[:3], np.pi]  # the shoulder is on the bow: now 1.8 m further off
    assert "out of reach" in g.check_arm(np.array([x, y, z]), turned_away)


def test_a_resent_command_gets_the_same_answer_and_is_not_taken_twice() -> None:
    g = gate()
    far = ArmGoal(7, np.array([9.0, 0.0, -7.0]), IDENTITY)
    ack, taken = g.answer(far, LAST_WAYPOINT)
    assert not taken and not ack.accepted and ack.command == "arm" and ack.command_id == 7
    again, taken_again = g.answer(far, LAST_WAYPOINT)
    assert again == ack and not taken_again
    near = ArmGoal(9, np.array([4.86, 0.0, -8.35]), IDENTITY)
    assert g.answer(near, LAST_WAYPOINT)[1] and g.answer(near, LAST_WAYPOINT) == (
        g.answers["ArmGoal", 9],
        False,
    )
    mode = OperatorMode(7, "hold")  # the same id on another kind of command is its own command
    ack, taken = g.answer(mode, LAST_WAYPOINT)
    assert taken and ack.accepted and ack.command == "mode"
    waypoints = Waypoints(8, np.array(MissionConfig().waypoints))
    assert g.answer(waypoints, LAST_WAYPOINT)[1] and not g.answer(waypoints, LAST_WAYPOINT)[1]


def test_a_refusal_is_judged_again_once_its_cause_has_cleared() -> None:
    """The arm busy with an intervention refuses a goal; the same goal sent again once the
    intervention is over is taken (a refusal is not cached as final), and then only once."""
    g = gate()
    goal = ArmGoal(11, np.array([4.86, 0.0, -8.35]), IDENTITY)
    busy = "the intervention on valve_1 is in progress (turn)"
    ack, taken = g.answer(goal, LAST_WAYPOINT, busy)
    assert not taken and ack.reason == busy
    ack, taken = g.answer(goal, LAST_WAYPOINT)
    assert taken and ack.accepted
    assert g.answer(goal, LAST_WAYPOINT) == (ack, False)
    # a goal out of reach from where the vehicle will hold, reachable once it holds elsewhere
    far = ArmGoal(12, np.array([6.0, 0.0, -8.35]), IDENTITY)
    assert not g.answer(far, LAST_WAYPOINT)[1]
    assert g.answer(far, np.r_[4.0, LAST_WAYPOINT[1:]])[1]
