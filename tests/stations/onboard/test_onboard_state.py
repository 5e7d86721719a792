"""The onboard failsafe's decisions and the navigation filter, without a network."""

from __future__ import annotations

import numpy as np

from abyss.config.stations import OnboardConfig
from abyss.interface.messages import Heartbeat, NavState
from abyss.stations.onboard.failsafe import Failsafe
from abyss.stations.onboard.navigation import NavFilter, PoseHistory


def test_failsafe_enters_on_each_cause_counts_entries_and_resumes() -> None:
    failsafe = Failsafe(goal_timeout_s=2.0, hold_on_shore_loss=True)
    assert failsafe.check(100.0) == ""  # never heard: nothing to hold yet
    failsafe.heard(100.0, Heartbeat(0.0, True))
    assert failsafe.check(101.0) == ""
    assert "no heartbeat" in failsafe.check(102.5)
    assert "no heartbeat" in failsafe.check(103.0) and failsafe.events == 1
    failsafe.heard(103.1, Heartbeat(0.0, True))
    assert failsafe.check(103.2) == ""
    failsafe.heard(103.4, Heartbeat(6.0, False))
    assert "shore silent" in failsafe.check(103.5) and failsafe.events == 2
    relaxed = Failsafe(goal_timeout_s=2.0, hold_on_shore_loss=False)
    relaxed.heard(0.0, Heartbeat(6.0, False))
    assert relaxed.check(0.1) == ""


def test_nav_filter_cuts_the_fix_noise_and_follows_motion() -> None:
    rng = np.random.default_rng(0)
    nav_filter, raw, filtered = NavFilter(OnboardConfig(nav_usbl_sigma_m=0.05)), [], []
    for i in range(2000):  # 100 s at 20 Hz, moving at 0.2 m/s forward, a fix each time
        t_s = i * 0.05
        truth = np.array([0.2 * t_s, 0.0, -7.0])
        fix = truth + rng.normal(0, [0.05, 0.05, 0.01])
        state = NavState(
            fix,
            np.array([1.0, 0, 0, 0]),
            np.array([0.2, 0, 0]) + rng.normal(0, 0.005, 3),
            np.zeros(3),
            t_s,
            usbl_time_s=t_s,
            depth_m=7.0 + rng.normal(0, 0.01),
        )
        position, orientation = nav_filter.update(state)
        assert position is not None
        if t_s > 20:  # past the filter's settling
            raw.append(np.linalg.norm(fix - truth))
            filtered.append(np.linalg.norm(position - truth))
    assert np.median(filtered) < 0.25 * np.median(raw)
    assert np.median(filtered) < 0.01
    assert abs(np.linalg.norm(orientation) - 1.0) < 1e-9


def test_the_pose_history_is_handed_over_whole_and_looked_up_between_estimates() -> None:
    east = np.array([1.0, 0.0, 0.0, 0.0])
    history = PoseHistory(span_s=2.0).added(
        [(0.0, np.zeros(3), east), (1.0, np.array([1.0, 0.0, 0.0]), east)]
    )
    later = history.added([(3.5, np.array([3.5, 0.0, 0.0]), east)])
    assert len(history.poses) == 2 and [t for t, _, _ in later.poses] == [3.5]  # older than span_s let go
    position, _ = history.at(0.25)  # type: ignore[misc]
    assert np.allclose(position, [0.25, 0.0, 0.0])
    assert history.at(1.15) is not None and history.at(1.3) is None  # 0.2 s tolerance past the ends
    assert not later.poses[0][1].flags.writeable  # no reader can change it behind the writer's back


def test_joints_that_do_not_fit_the_robots_arm_are_refused_with_the_counts() -> None:
    """A hybrid run's real vehicle may send another arm's joints: refused, not a crash of the step."""
    from abyss.interface.messages import JointState
    from abyss.stations.onboard import wrong_joints

    six = JointState(np.zeros(6), np.zeros(6), 0.0, 0.0)
    assert wrong_joints(six, 6) == ""
    assert wrong_joints(six, 5) == "6 joints, the robot's arm has 5"
    assert (
        wrong_joints(JointState(np.zeros(6), np.zeros(7), 0.0, 0.0), 6) == "6/7 joints, the robot's arm has 6"
    )


def test_a_real_vehicles_navigation_that_stops_stops_it_and_its_return_resumes() -> None:
    failsafe = Failsafe(goal_timeout_s=2.0, hold_on_shore_loss=True, nav_timeout_s=0.5)
    failsafe.heard(0.0, Heartbeat(0.0, True))
    assert failsafe.check(0.1) == ""  # no navigation yet: nothing to stop
    failsafe.navigated(0.2)
    assert failsafe.check(0.7) == "" and not failsafe.blind
    assert failsafe.check(0.75).startswith("no navigation for 0.6 s") and failsafe.blind
    assert failsafe.events == 1
    failsafe.navigated(0.8)
    assert failsafe.check(0.8) == "" and not failsafe.blind
    simulated = Failsafe(goal_timeout_s=2.0, hold_on_shore_loss=True)  # off: all-simulated runs
    simulated.navigated(0.0)
    assert simulated.check(1.9) == "" and not simulated.blind
