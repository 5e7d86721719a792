"""Onboard's core without Zenoh, its heartbeats from the vessel carried by linkemu's `Link` on
explicit times, out of the core's sight (as under `--link netem` or on a real tether): a cut
link must still trip the failsafe, and the vehicle must go on once the link returns."""

from __future__ import annotations

import numpy as np
import pytest

from abyss.config import Config, load
from abyss.config.linkprofile import profile
from abyss.interface.messages import (
    ArmGoal,
    CommandAck,
    Heartbeat,
    InterventionGoal,
    JointState,
    NavState,
    OperatorMode,
    Waypoints,
    decode,
    encode,
)
from abyss.linkemu.link import Link
from abyss.stations.onboard.core import Onboard, OnboardInputs
from abyss.stations.onboard.navigation import SETTLE_FIXES

STEP_S = 0.05


def test_a_cut_tether_trips_the_failsafe_by_heartbeats_alone_and_it_lets_go_after() -> None:
    config = Config()
    core = Onboard(config)
    tether = Link(profile("tether"), np.random.default_rng(0))
    joints = JointState(np.zeros(6), np.zeros(6), 0.0, 0.0)
    cut_s, restored_s = 5.0, 10.0
    held: list[tuple[float, str]] = []
    for step in range(int(20.0 / STEP_S)):
        now_s = step * STEP_S
        if abs(now_s - cut_s) < 1e-9:
            tether.reconfigure(profile("outage"))
        if abs(now_s - restored_s) < 1e-9:
            tether.reconfigure(profile("tether"))
        if step % round(config.vessel.heartbeat_period_s / STEP_S) == 0:
            tether.offer(now_s, encode(Heartbeat(0.0, True), step, now_s))
        beats = [decode("k", d.payload, Heartbeat).message for d in tether.advance(now_s)]
        nav = NavState(
            np.array([0.0, 0.0, -5.0]),
            np.array([1.0, 0.0, 0.0, 0.0]),
            np.zeros(3),
            np.zeros(3),
            sim_time_s=now_s,
            usbl_time_s=now_s,
            depth_m=5.0,
        )
        out = core.step(OnboardInputs(heartbeats=beats, nav=[nav], joints=joints), now_s)
        assert out.vehicle is not None and out.arm is not None
        if out.telemetry is not None:
            held.append((now_s, out.telemetry.failsafe))
    before = [reason for t, reason in held if t < cut_s]
    entered = next(t for t, reason in held if t >= cut_s and reason)
    assert not any(before)
    timeout_s = config.onboard.goal_timeout_s
    # the last beat before the cut left up to one heartbeat period earlier and took the tether's delay
    assert cut_s + timeout_s - config.vessel.heartbeat_period_s <= entered <= cut_s + timeout_s + 0.5
    assert "no heartbeat" in dict(held)[entered]
    left = next(t for t, reason in held if t > restored_s and not reason)
    assert left < restored_s + 8.0  # the tether's TCP resumes after a backed-off retransmission timeout
    assert core.failsafe.events == 1


def test_an_intervention_sent_before_navigation_settles_waits_and_is_judged_once_it_has() -> None:
    """A restarted onboard hears shore's goals again before its navigation has a settled estimate:
    judged from nowhere, the intervention was refused ("out of reach: 8.68 m from the shoulder")
    and not sent again. It waits unanswered, resends do not multiply it, and it is answered once
    navigation settles, judged from where the vehicle is."""
    core = Onboard(Config())
    joints = JointState(np.zeros(6), np.zeros(6), 0.0, 0.0)
    near_m_world = np.array([1.0, 0.0, -5.5])  # about an arm's length ahead of the vehicle
    goal = InterventionGoal(
        7, "valve_1", near_m_world, np.array([0.0, 1.0, 0.0]), near_m_world, np.array([1.0, 0, 0, 0]), 0.5
    )
    answers: list[tuple[float, CommandAck]] = []
    for step in range(int(6.0 / STEP_S)):
        now_s = step * STEP_S
        resend = step % 20 == 0  # shore resends every second until answered
        here = NavState(np.array([0.0, 0.0, -5.0]), np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3),
                        sim_time_s=now_s, usbl_time_s=np.floor(now_s), depth_m=5.0)  # fmt: skip
        nav = [here] if now_s >= 1.0 else []  # no estimate for the first second
        out = core.step(OnboardInputs(commands=[goal] if resend else [], nav=nav, joints=joints), now_s)
        answers += [(now_s, ack) for ack in out.acks]
    answered_s = answers[0][0]  # the first answer: none while it waited, however often sent
    assert all(a.accepted for _, a in answers), answers
    settled_s = 1.0 + SETTLE_FIXES - 1  # a fix a second from 1 s
    assert settled_s <= answered_s <= settled_s + 1.0 + STEP_S


def test_telemetry_tells_the_estimated_attitude_the_navigations_velocity_and_the_effort_sent() -> None:
    """A waypoint behind the vehicle and turned to its left: surge backwards at the speed limit
    (effort -1), the yaw rate positive; each effort the velocity sent over its limit."""
    config = Config()
    core = Onboard(config)
    core.step(OnboardInputs(commands=[Waypoints(1, ((-20.0, 0.0, -5.0, 0.3),))]), 0.0)
    joints = JointState(np.zeros(6), np.zeros(6), 0.0, 0.0)
    turned = np.array([np.cos(0.05), 0.0, 0.0, np.sin(0.05)])  # 0.1 rad of yaw
    nav = NavState(
        np.array([0.0, 0.0, -5.0]), turned, np.array([0.2, -0.05, 0.01]), np.zeros(3), 0.0, 0.0, 5.0
    )
    out = core.step(OnboardInputs(nav=[nav], joints=joints), 0.0)
    t, sent = out.telemetry, out.vehicle
    assert t is not None and sent is not None
    assert np.allclose(t.orientation_wxyz_world, core.orientation_wxyz_world)
    assert np.allclose(t.orientation_wxyz_world, turned)
    assert np.array_equal(t.velocity_mps_body, [0.2, -0.05, 0.01])
    cfg = config.onboard
    limits = [cfg.max_speed_mps] * 3 + [cfg.max_yaw_rate_radps]
    assert np.allclose(t.effort_body, np.r_[sent.linear_mps_body, sent.yaw_rate_radps] / limits)
    assert t.effort_body[0] < -0.9 and t.effort_body[3] > 0.0  # backwards, turning left
    assert np.allclose(np.linalg.norm(t.effort_body[:3]), 1.0)  # at the speed limit


def test_a_real_vehicle_whose_navigation_stops_is_stopped_not_steered_by_the_last_estimate() -> None:
    """A hybrid run: its navigation stopped, onboard sends zero velocities to the vehicle and the
    arm (held station on an estimate gone still, it would push on at its last error), and steers
    again once navigation returns."""
    config = load(overrides=['hybrid.vehicle=["nav", "joints"]'])
    core = Onboard(config)
    core.step(OnboardInputs(commands=[Waypoints(1, ((20.0, 0.0, -5.0, 0.0),))]), 0.0)
    speeds: dict[float, float] = {}
    for step in range(int(4.0 / STEP_S)):
        now_s = step * STEP_S
        silent = 1.0 <= now_s < 2.5  # the vehicle's navigation stops for 1.5 s
        nav = NavState(
            np.array([0.0, 0.0, -5.0]), np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3), now_s, now_s, 5.0
        )
        joints = JointState(np.zeros(6), np.zeros(6), 0.0, now_s)  # its joints come on
        out = core.step(OnboardInputs(nav=[] if silent else [nav], joints=joints), now_s)
        assert out.vehicle is not None
        speeds[round(now_s, 3)] = float(np.linalg.norm(out.vehicle.linear_mps_body))
    bound_s = config.hybrid.nav_max_age_s
    assert speeds[0.9] > 0.1  # flying to the waypoint
    assert max(v for t, v in speeds.items() if 1.0 + bound_s + STEP_S <= t < 2.5) == 0.0
    assert speeds[3.9] > 0.1 and core.failsafe.events == 1


def test_the_effort_told_is_what_was_sent_zero_in_the_blind_stop() -> None:
    """Held by the operator and turned off its held heading, the vehicle turns back (a yaw
    effort); its navigation then stops: onboard sends zeros, and the effort told is zero, not the
    turn back that holding station on the estimate gone still would ask for."""
    config = load(overrides=['hybrid.vehicle=["nav", "joints"]'])
    core = Onboard(config)
    core.step(OnboardInputs(commands=[OperatorMode(1, "hold")]), 0.0)
    efforts: dict[float, np.ndarray] = {}
    for step in range(int(3.0 / STEP_S)):
        now_s = step * STEP_S
        joints = JointState(np.zeros(6), np.zeros(6), 0.0, now_s)
        yaw_rad = 0.0 if now_s < 0.5 else 0.5  # turned at 0.5 s
        attitude = np.array([np.cos(yaw_rad / 2), 0.0, 0.0, np.sin(yaw_rad / 2)])
        nav = NavState(np.array([0.0, 0.0, -5.0]), attitude, np.zeros(3), np.zeros(3), now_s, now_s, 5.0)
        out = core.step(OnboardInputs(nav=[] if now_s >= 1.5 else [nav], joints=joints), now_s)
        if out.telemetry is not None:
            efforts[round(now_s, 3)] = out.telemetry.effort_body
    assert efforts[1.4][3] < -0.05  # turning back to the held heading
    blind = [e for t, e in efforts.items() if t >= 1.5 + config.hybrid.nav_max_age_s + STEP_S]
    assert blind and not np.any(blind)


def test_a_real_vehicles_joints_that_stop_stop_the_arm_and_say_so_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A hybrid run whose vehicle sends joints of the wrong count (dropped: the latest valid ones
    stay) or none: onboard commanded the arm from its last joints while the real one moved (the
    elbow's command grew from 0.10 to 0.20 rad/s). Past hybrid.nav_max_age_s without a new valid
    JointState the arm is sent zeros, the vehicle flying on, the failsafe told in the telemetry
    and logged once as it begins and once as it ends; new joints drive the arm again. (The arm
    here follows its commands exactly; the navigation settles in about 17 s of fixes.)"""
    config = load(overrides=['hybrid.vehicle=["nav", "joints"]'])
    core = Onboard(config)
    goal = ArmGoal(1, np.array([1.26, 0.0, -5.0]), np.array([1.0, 0, 0, 0]))  # ahead, within reach
    joints_rad = np.array(core.robot.stowed_rad)
    arm: dict[float, float] = {}
    told: dict[float, str] = {}
    stall_s = (19.0, 20.5)  # no new joints for 1.5 s (the last ones stay), the arm on its way
    with caplog.at_level("INFO", logger="abyss.stations.onboard.failsafe"):
        for step in range(int(23.0 / STEP_S)):
            now_s = step * STEP_S
            if not stall_s[0] <= now_s < stall_s[1]:
                joints = JointState(joints_rad.copy(), np.zeros(len(joints_rad)), 0.0, now_s)
            here = NavState(np.array([0.0, 0.0, -5.0]), np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3),
                            sim_time_s=now_s, usbl_time_s=np.floor(now_s), depth_m=5.0)  # fmt: skip
            commands = [goal] if step % 20 == 0 else []  # resent until answered
            out = core.step(OnboardInputs(commands=commands, nav=[here], joints=joints), now_s)
            assert out.arm is not None and out.vehicle is not None
            joints_rad = joints_rad + out.arm.joint_velocities_radps * STEP_S  # the arm follows
            arm[round(now_s, 3)] = float(np.abs(out.arm.joint_velocities_radps).max())
            if out.telemetry is not None:
                told[round(now_s, 3)] = out.telemetry.failsafe
    bound_s = config.hybrid.nav_max_age_s
    assert arm[round(stall_s[0] - STEP_S, 3)] > 0.01  # on its way to the goal from the joints it is sent
    stalled = [v for t, v in arm.items() if stall_s[0] + bound_s + STEP_S <= t < stall_s[1]]
    assert stalled and max(stalled) == 0.0
    assert arm[round(stall_s[1] + STEP_S, 3)] > 0.01 and core.failsafe.events == 1  # driven again
    assert any("no valid joints" in why for t, why in told.items() if stall_s[0] + bound_s < t < stall_s[1])
    assert not told[max(told)]  # over once they came again
    begun = [r for r in caplog.records if "no valid joints" in r.getMessage()]
    ended = [r for r in caplog.records if "failsafe over (arm)" in r.getMessage()]
    assert len(begun) == 1 and len(ended) == 1
