"""Shore's operator core (stations.onshore.core.Operator), without Zenoh: when it sends the
mission's commands (onboard's first telemetry, or JOIN_WAIT_S without any), how a restarted
shore takes the commands onboard already flies instead of starting over, how it hands the
goals in force again to a rebooted onboard, the waypoints from the one not yet reached, and
that an arm goal or intervention follows the waypoints' answer (onboard judges it where the
vehicle will hold)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from abyss.config import Config
from abyss.config.system import MissionConfig
from abyss.interface.messages import (
    ArmGoal,
    CommandAck,
    Heartbeat,
    Intervention,
    Message,
    MissionStatus,
    OperatorMode,
    Telemetry,
    Waypoints,
)
from abyss.stations.onshore.core import (
    JOIN_WAIT_S,
    STATUS_PERIOD_S,
    Operator,
    OperatorInputs,
    OperatorOutputs,
)

OP_TOPICS = {"op/mode", "op/waypoints", "op/arm"}


@pytest.fixture
def mission() -> MissionConfig:
    mission = dataclasses.replace(
        Config().mission, interventions=(), arm_target=(4.86, 0.0, -8.35, 1.57, 0.0, 0.0)
    )
    assert len(mission.waypoints) == 3 and mission.arm_goal() is not None
    return mission


def telemetry(**fields: object) -> Telemetry:
    """Onboard's telemetry: a fresh onboard at rest, with `fields` changed."""
    values: dict[str, object] = {
        "position_m_world": np.zeros(3),
        "yaw_rad": 0.0,
        "mode": "idle",
        "command_id": -1,
        "waypoint_index": 0,
        "waypoints_total": 0,
        "position_error_m_world": np.zeros(3),
        "heading_error_rad": 0.0,
        "arm_mode": "idle",
        "arm_command_id": -1,
        "ee_position_error_m_world": np.zeros(3),
        "ee_orientation_error_rad": 0.0,
        "ee_position_m_world": np.zeros(3),
        "ee_orientation_wxyz_world": np.array([1.0, 0.0, 0.0, 0.0]),
        "arm_positions_rad": np.zeros(6),
        "failsafe": "",
        "failsafe_events": 0,
        "sim_time_s": 1.0,
        "operator_mode": "auto",
        "boot_id": 1,
    }
    values.update(fields)
    return Telemetry(**values)  # type: ignore[arg-type]


def commands(out: OperatorOutputs) -> dict[str, Message]:
    """The op/* commands a step sent, by topic (each at most once a step)."""
    sent = [(topic, message) for topic, message in out.messages if topic.startswith("op/")]
    assert len({topic for topic, _ in sent}) == len(sent), sent
    return dict(sent)


def command_id(message: Message) -> int:
    assert isinstance(message, (Waypoints, ArmGoal, OperatorMode))
    return message.command_id


def waypoints_taken(operator: Operator, now_s: float) -> dict[str, Message]:
    """Onboard takes the waypoints sent: what shore sends at `now_s` on hearing it."""
    waypoints = operator.waypoints.message
    assert isinstance(waypoints, Waypoints)
    return commands(
        operator.step(OperatorInputs(acks=[CommandAck(waypoints.command_id, "waypoints", "")]), now_s)
    )


def assert_mission_commands(sent: dict[str, Message], mission: MissionConfig) -> None:
    assert set(sent) == OP_TOPICS
    mode, waypoints, arm = sent["op/mode"], sent["op/waypoints"], sent["op/arm"]
    assert isinstance(mode, OperatorMode) and mode.mode == "auto"
    assert isinstance(waypoints, Waypoints)
    np.testing.assert_array_equal(waypoints.waypoints, np.array(mission.waypoints))
    goal = mission.arm_goal()
    assert isinstance(arm, ArmGoal) and goal is not None
    np.testing.assert_allclose(arm.position_m_world, goal[0])
    np.testing.assert_allclose(arm.orientation_wxyz_world, goal[1])


def test_nothing_but_a_heartbeat_before_telemetry_or_the_join_wait(mission: MissionConfig) -> None:
    operator = Operator(mission)
    out = operator.step(OperatorInputs(), 0.0)
    assert [topic for topic, _ in out.messages] == ["heartbeat"]
    assert isinstance(out.messages[0][1], Heartbeat)
    out = operator.step(OperatorInputs(), JOIN_WAIT_S - 0.1)
    assert commands(out) == {} and out.first_sent == []
    assert out.status is not None and out.status.waypoints_total == 3 and not out.status.done


def test_a_fresh_onboards_first_telemetry_releases_the_mission(mission: MissionConfig) -> None:
    operator = Operator(mission)
    assert commands(operator.step(OperatorInputs(), 0.0)) == {}
    out = operator.step(OperatorInputs(telemetry=[telemetry(command_id=-1)]), 0.1)
    sent = commands(out)
    # onboard judges the arm goal where the vehicle will hold: it waits for the waypoints' answer
    assert set(sent) == {"op/mode", "op/waypoints"}
    assert sorted(type(m).__name__ for m in out.first_sent) == ["OperatorMode", "Waypoints"]
    assert operator.events == []  # a fresh start is no event
    # unanswered, each is resent after the resend period, with its own id; the arm goal still waits
    again = commands(operator.step(OperatorInputs(), 0.1 + mission.resend_period_s + 0.1))
    assert {t: command_id(m) for t, m in again.items()} == {t: command_id(m) for t, m in sent.items()}
    arm = waypoints_taken(operator, 0.1 + mission.resend_period_s + 0.2)
    assert_mission_commands({**sent, **arm}, mission)
    assert set(arm) == {"op/arm"}


def test_without_telemetry_the_mission_goes_out_after_the_join_wait(mission: MissionConfig) -> None:
    operator = Operator(mission)
    assert commands(operator.step(OperatorInputs(), 0.0)) == {}
    assert commands(operator.step(OperatorInputs(), JOIN_WAIT_S - 0.1)) == {}
    sent = commands(operator.step(OperatorInputs(), JOIN_WAIT_S + 0.1))
    assert_mission_commands({**sent, **waypoints_taken(operator, JOIN_WAIT_S + 0.2)}, mission)


def test_a_restarted_shore_takes_the_mission_onboard_flies(mission: MissionConfig) -> None:
    history: list[dict[str, object]] = [
        {
            "command": "waypoints",
            "command_id": 123,
            "sends": 1,
            "answered": False,
            "accepted": False,
            "reason": "",
        }
    ]
    operator = Operator(mission, history=history)
    flying = telemetry(
        command_id=123,
        waypoints_total=3,
        waypoint_index=2,
        mode="moving",
        arm_command_id=456,
        arm_mode="idle",
        operator_mode="auto",
        boot_id=7,
    )
    out = operator.step(OperatorInputs(telemetry=[flying]), 0.0)
    assert commands(out) == {} and out.first_sent == []
    assert [e["station"] for e in operator.events] == ["onshore"]
    assert out.status is not None
    assert (out.status.waypoint_index, out.status.waypoints_total) == (2, 3)
    assert not out.status.done
    entry = operator.history[("op/waypoints", 123)]
    assert entry["answered"] is True and entry["accepted"] is True
    # the last waypoint reached, the end-effector at its goal, but the vehicle still 6 cm off
    # its mark (a whole-body arm moved it): not done yet; back on it, the mission is done
    reached = telemetry(
        command_id=123,
        waypoints_total=3,
        waypoint_index=2,
        mode="reached",
        arm_command_id=456,
        arm_mode="reached",
        boot_id=7,
        position_error_m_world=np.array([0.0, 0.06, 0.0]),
    )
    out = operator.step(OperatorInputs(telemetry=[reached]), STATUS_PERIOD_S + 0.01)
    assert mission.done_position_tolerance_m == 0.05 and out.status is not None and not out.status.done
    reached = dataclasses.replace(reached, position_error_m_world=np.array([0.0, 0.04, 0.0]))
    out = operator.step(OperatorInputs(telemetry=[reached]), 2 * STATUS_PERIOD_S + 0.02)
    assert isinstance(out.status, MissionStatus) and out.status.done
    assert (out.status.waypoint_index, out.status.waypoints_total) == (2, 3)
    # taken as answered: nothing is resent, however long shore waits
    out = operator.step(OperatorInputs(), JOIN_WAIT_S + 2 * mission.resend_period_s)
    assert commands(out) == {}
    assert len(operator.events) == 1


def test_the_arm_goal_of_another_command_is_not_done(mission: MissionConfig) -> None:
    operator = Operator(mission)
    first = telemetry(
        command_id=123,
        waypoints_total=3,
        waypoint_index=2,
        mode="reached",
        arm_command_id=456,
        arm_mode="reached",
    )
    operator.step(OperatorInputs(telemetry=[first]), 0.0)
    other = telemetry(
        command_id=123,
        waypoints_total=3,
        waypoint_index=2,
        mode="reached",
        arm_command_id=789,
        arm_mode="reached",
    )
    out = operator.step(OperatorInputs(telemetry=[other]), STATUS_PERIOD_S + 0.01)
    assert out.status is not None and not out.status.done


def test_a_rebooted_onboard_is_handed_the_goals_in_force(mission: MissionConfig) -> None:
    operator = Operator(mission)
    now_s = 0.0
    sent = commands(operator.step(OperatorInputs(telemetry=[telemetry(boot_id=1)]), now_s))
    sent.update(waypoints_taken(operator, now_s))
    assert set(sent) == OP_TOPICS
    ids = {topic: command_id(m) for topic, m in sent.items()}
    acks = [CommandAck(ids[f"op/{c}"], c, "") for c in ("waypoints", "arm", "mode")]
    now_s += STATUS_PERIOD_S + 0.01
    out = operator.step(OperatorInputs(acks=acks), now_s)
    assert commands(out) == {} and len(out.answers) == 3
    boot_a = telemetry(
        boot_id=1,
        command_id=ids["op/waypoints"],
        waypoint_index=2,
        waypoints_total=3,
        mode="moving",
        arm_command_id=-1,
        sim_time_s=40.0,
    )
    now_s += STATUS_PERIOD_S + 0.01
    out = operator.step(OperatorInputs(telemetry=[boot_a]), now_s)
    assert commands(out) == {}
    assert out.status is not None and (out.status.waypoint_index, out.status.waypoints_total) == (2, 3)
    assert operator.events == []

    boot_b = telemetry(boot_id=2, command_id=-1, sim_time_s=41.0)
    now_s += STATUS_PERIOD_S + 0.01
    out = operator.step(OperatorInputs(telemetry=[boot_b]), now_s)
    again = commands(out)
    assert set(again) == {"op/mode", "op/waypoints"}  # the arm goal once the waypoints are taken
    again.update(waypoints_taken(operator, now_s))
    assert set(again) == OP_TOPICS
    waypoints = again["op/waypoints"]
    assert isinstance(waypoints, Waypoints) and waypoints.command_id != ids["op/waypoints"]
    np.testing.assert_array_equal(waypoints.waypoints, np.array(mission.waypoints)[2:])
    assert command_id(again["op/arm"]) == ids["op/arm"]
    assert command_id(again["op/mode"]) == ids["op/mode"]
    assert [e["station"] for e in operator.events] == ["onboard"]
    assert out.status is not None and (out.status.waypoint_index, out.status.waypoints_total) == (2, 3)

    # onboard flies the remaining waypoint: counted from the mission's first
    flying = telemetry(
        boot_id=2,
        command_id=waypoints.command_id,
        waypoint_index=0,
        waypoints_total=1,
        mode="moving",
        sim_time_s=42.0,
    )
    now_s += STATUS_PERIOD_S + 0.01
    out = operator.step(OperatorInputs(telemetry=[flying]), now_s)
    assert out.status is not None
    assert (out.status.waypoint_index, out.status.waypoints_total) == (2, 3)
    assert not out.status.done


def test_the_missions_interventions_go_one_after_the_other_and_end_it(mission: MissionConfig) -> None:
    mission = dataclasses.replace(
        mission, arm_target=(), interventions=(("valve_1", "90"), ("lever_0", "down"))
    )
    operator = Operator(mission)
    assert "op/intervene" not in commands(operator.step(OperatorInputs(telemetry=[telemetry()]), 0.0))
    first = waypoints_taken(operator, 0.0)["op/intervene"]
    assert isinstance(first, Intervention) and first.target == "valve_1"
    assert first.turn_rad == pytest.approx(np.pi / 2)
    waypoints = operator.waypoints.message
    assert isinstance(waypoints, Waypoints)
    flown = {"command_id": waypoints.command_id, "mode": "reached", "waypoints_total": 3, "waypoint_index": 2}
    turning = telemetry(**flown, intervention_id=first.command_id, intervention_phase="turn")
    out = operator.step(OperatorInputs(telemetry=[turning]), 1.0)
    assert out.status is not None and not out.status.done and out.status.interventions_done == 0
    done = telemetry(**flown, intervention_id=first.command_id, intervention_phase="done")
    out = operator.step(OperatorInputs(telemetry=[done]), 2.0)
    second = commands(out)["op/intervene"]
    assert isinstance(second, Intervention) and second.target == "lever_0" and second.to == "down"
    assert out.status is not None and not out.status.done and out.status.interventions_done == 1
    failed = telemetry(
        **flown,
        intervention_id=second.command_id,
        intervention_phase="failed",
        intervention_reason="lever_0 does not turn",
    )
    status = operator.step(OperatorInputs(telemetry=[failed]), 3.0).status
    assert status is not None and not status.done and status.intervention_reason == "lever_0 does not turn"
    thrown = telemetry(**flown, intervention_id=second.command_id, intervention_phase="done")
    status = operator.step(OperatorInputs(telemetry=[thrown]), 4.0).status
    assert status is not None and status.done and status.interventions_done == 2


def test_a_restarted_shore_refused_as_onboard_works_the_part_takes_that_run_and_goes_on(
    mission: MissionConfig,
) -> None:
    """Shore killed just as onboard began valve_1 (kill campaign, 6.7 s): the restarted shore
    joined from telemetry older than the run, sent its own intent, and onboard refused it as busy.
    Shore takes onboard's run (the old shore's command) as the mission's, says so, and goes on to
    lever_0 when it is done; its refused command is not sent again."""
    mission = dataclasses.replace(
        mission, arm_target=(), interventions=(("valve_1", "90"), ("lever_0", "down"))
    )
    operator = Operator(mission)
    operator.step(OperatorInputs(telemetry=[telemetry()]), 0.0)
    own = waypoints_taken(operator, 0.0)["op/intervene"]
    assert isinstance(own, Intervention)
    waypoints = operator.waypoints.message
    assert isinstance(waypoints, Waypoints)
    flown = {"command_id": waypoints.command_id, "mode": "reached", "waypoints_total": 3, "waypoint_index": 2}
    old = 4850217519377534  # the shore before the restart sent it
    busy = "the intervention on valve_1 is in progress (approach)"
    approach = telemetry(
        **flown, intervention_id=old, intervention_target="valve_1", intervention_phase="approach"
    )
    out = operator.step(
        OperatorInputs(acks=[CommandAck(own.command_id, "intervene", busy)], telemetry=[approach]), 1.0
    )
    current = operator.intervene.message
    assert current is not None and current.command_id == old and operator.intervene.answer is not None
    assert "took onboard's intervention on valve_1" in str(operator.events[-1]["event"]), operator.events
    assert "op/intervene" not in commands(operator.step(OperatorInputs(), 1.0 + 2 * mission.resend_period_s))
    done = telemetry(**flown, intervention_id=old, intervention_target="valve_1", intervention_phase="done")
    out = operator.step(OperatorInputs(telemetry=[done]), 30.0)
    second = commands(out)["op/intervene"]
    assert isinstance(second, Intervention) and second.target == "lever_0"
    assert out.status is not None and out.status.interventions_done == 1
