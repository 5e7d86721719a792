"""Scenario files: every file of the library loads; a bad one is refused at load, naming the file,
the field and what is allowed; assertions judge the figures a run leaves."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from abyss.common.errors import ConfigError
from abyss.description.robot import robot_at
from abyss.interface.messages import Telemetry
from abyss.validation.scenario.checks import Run, Verdict, arm_ranges_rad, judge
from abyss.validation.scenario.report import junit
from abyss.validation.scenario.runner import Result
from abyss.validation.scenario.spec import USES, Assertion, load_scenario, scenario_of

ROBOT = robot_at("")  # the shipped robot package


LIBRARY = sorted((Path(__file__).resolve().parents[2] / "scenarios").glob("*.toml"))
MINIMAL = {"name": "x", "use": "degradation", "duration_s": 10, "assert": [{"kind": "stations"}]}


def test_the_library_loads_and_covers_the_five_uses_but_parallel() -> None:
    scenarios = [load_scenario(p) for p in LIBRARY]
    assert len(scenarios) >= 9
    assert {s.use for s in scenarios} == set(USES) - {"parallel"}  # parallel is how they run, not a file
    assert [s.name for s in scenarios if s.expect_failed] == [
        "recognition-biased",
        "satellite-down",
        "valve-seized",
    ]


@pytest.mark.parametrize(("change", "field", "allowed"), [
    ({"use": "fun"}, "use", "degradation"),
    ({"links": {"satellite": "fast"}}, "links.satellite", "satellite-storm"),
    ({"links": {"radio": "ideal"}}, "links.radio", "tether"),
    ({"events": [{"at_s": 1, "action": "explode"}]}, "events[0].action", "link, fault, kill"),
    ({"events": [{"at_s": 1, "action": "fault", "fault": "leak"}]}, "events[0].fault", "thruster"),
    ({"events": [{"at_s": 1, "action": "kill", "station": "shore"}]}, "station", "onshore"),
    ({"assert": [{"kind": "vibes"}]}, "assert[0].kind", "mission_done"),
    ({"assert": [{"kind": "mission_done", "within": 3}]}, "assert[0].within", "within_s"),
    ({"assert": [{"kind": "mission_done", "within_s": "soon"}]}, "assert[0].within_s", "finite number"),
    ({"config": {"mission.position_tolerance_m": -1}}, "mission.position_tolerance_m", "positive"),
    ({"expect_failed": ["scene"]}, "expect_failed[0]", "stations"),
    ({"colour": "red"}, "scenario.colour", "duration_s"),
    ({"assert": []}, "assert", "at least one"),
    ({"events": [{"at_s": 1, "phase": "twist", "action": "kill", "station": "vessel"}]}, "events[0].phase",
     "turn"),
    ({"assert": [{"kind": "intervention", "part": "valve_9"}]}, "assert[0].part", "valve_1"),
    ({"assert": [{"kind": "intervention", "part": "valve_1", "outcome": "half"}]}, "assert[0].outcome",
     "failed"),
    ({"events": [{"at_s": 1, "hop": "tether"}]}, "events[0].action", "is required: one of link, fault, kill"),
    ({"events": [{"at_s": 1, "action": "link", "hop": "tether", "profile": "outage", "station": "vessel"}]},
     "events[0].station", "unknown field; allowed: at_s, hop, phase, profile (a link event)"),
    ({"assert": [{"kind": "perception"}]}, "assert[0].source", "is required: one of depth, stereo, sonar"),
    ({"config": {"mission.nonsense": 1}}, "config.mission.nonsense", "unknown field; allowed:"),
])  # fmt: skip
def test_a_bad_scenario_is_refused_naming_the_field(change: dict, field: str, allowed: str) -> None:
    with pytest.raises(ConfigError) as error:
        scenario_of({**MINIMAL, **change}, "bad.toml")
    assert error.value.field.endswith(field) and allowed in str(error.value), str(error.value)
    assert str(error.value).startswith("bad.toml: ")


def test_a_typo_is_an_unknown_field_and_a_missing_use_names_its_values() -> None:
    typo = {**{k: v for k, v in MINIMAL.items() if k != "duration_s"}, "durations_s": 10}
    with pytest.raises(ConfigError) as error:
        scenario_of(typo, "bad.toml")
    assert str(error.value).startswith("bad.toml: scenario.durations_s: unknown field; allowed: assert, ")
    assert "duration_s" in error.value.reason
    with pytest.raises(ConfigError) as error:
        scenario_of({k: v for k, v in MINIMAL.items() if k != "use"}, "bad.toml")
    assert str(error.value) == (
        "bad.toml: scenario.use: is required: one of distributed, interface, degradation, parallel, "
        "fault-recovery"
    )


def test_the_configuration_travels_as_typed_data() -> None:
    """`[config]` with `section.field` keys or nested tables, values typed as a Config reads
    them; in lockstep the holds are a real list in the table `abyss up --config` is given."""
    scenario = scenario_of({
        **MINIMAL,
        "config": {"mission.arm_target": [4.86, 0, -8.35, 1.5708, 0, 0], "mission.interventions": [],
                   "time": {"mode": "lockstep"},
                   "simulation.camera_rate_hz": 2},
        "links": {"tether": "tether-degraded"},
        "events": [{"at_s": 3, "action": "kill", "station": "vessel"}],
    })  # fmt: skip
    table = scenario.up_table()
    assert table["mission"]["arm_target"] == [4.86, 0.0, -8.35, 1.5708, 0.0, 0.0]
    assert table["simulation"]["camera_rate_hz"] == 2.0 and table["links"] == {"tether": "tether-degraded"}
    assert table["time"] == {"mode": "lockstep", "holds_s": [3.0]}
    assert scenario.configuration.links.tether == "tether-degraded"
    real, _ = scenario.on_time("real", None)
    assert real.config["time"] == {"mode": "real", "speed": "1"} and "holds_s" not in real.up_table()["time"]


def test_an_unreadable_file_names_itself(tmp_path: Path) -> None:
    (tmp_path / "broken.toml").write_text("name = ")
    with pytest.raises(ConfigError, match=r"broken\.toml: scenario: cannot read"):
        load_scenario(tmp_path / "broken.toml")


def state(failsafe: str) -> Telemetry:
    z = np.zeros(3)
    return Telemetry(z, 0.0, "hold" if failsafe else "moving", 1, 0, 3, z, 0.0, "idle", -1, z, 0.0, z,
                     np.array([1.0, 0, 0, 0]), np.zeros(6), failsafe, 1, 0.0)  # fmt: skip


def test_the_failsafe_assertion_times_entry_and_exit() -> None:
    times = np.arange(0, 30, 0.1)
    states = [(t, state("tether link reported down" if 8.5 <= t < 19.0 else "")) for t in times]
    run = Run({}, states=states)
    window = {"from_s": 8.0, "to_s": 16.0, "enter_within_s": 1.0}
    held, late = judge(run, (Assertion("failsafe", {**window, "leave_within_s": 5.0}),
                             Assertion("failsafe", {**window, "leave_within_s": 2.0})))  # fmt: skip
    assert held.passed and "entered 0.5 s after" in held.detail
    assert not late.passed and "not left within 2 s" in late.detail
    never = judge(Run({}, states=[(t, state("")) for t in times]), (Assertion("failsafe", window),))
    assert not never[0].passed


def test_commands_and_links_are_judged_from_the_run() -> None:
    summary = {"links": {"satellite": {"vessel->onshore": {"delay_p50_ms": 240.0}}}}
    commands = [{"command": "arm", "command_id": 3, "sends": 4, "answered": False}]
    delay = {"hop": "satellite", "direction": "vessel->onshore", "stat": "delay_p50_ms"}
    verdicts = judge(Run(summary, commands=commands), (
        Assertion("commands_answered", {}), Assertion("link", {**delay, "max": 300.0}),
        Assertion("link", {**delay, "min": 300.0})))  # fmt: skip
    assert [v.passed for v in verdicts] == [False, True, False]
    assert "unanswered: arm 3" in verdicts[0].detail


def test_an_intervention_is_judged_on_what_onboard_said_and_on_the_truth() -> None:
    def worked(phase: str, reason: str = "") -> Telemetry:
        return dataclasses.replace(
            state(""),
            intervention_id=4,
            intervention_target="valve_1",
            intervention_phase=phase,
            intervention_reason=reason,
        )

    turned = [(1.0, worked("turn")), (2.0, worked("done"))]
    judged = {"part": "valve_1", "target_deg": 90.0}
    on_target = {"interventions": [{**judged, "truth_deg": 88.0, "success": True}]}
    short = {"interventions": [{**judged, "truth_deg": 9.0, "success": False}]}
    done = Assertion("intervention", {"part": "valve_1", "outcome": "done"})
    assert judge(Run(on_target, states=turned), (done,))[0].passed
    believed = judge(Run(short, states=turned), (done,))[0]  # onboard says done; the truth does not
    assert not believed.passed and "truth 9.0 deg" in believed.detail
    stalled = [
        (1.0, worked("turn")),
        (2.0, worked("failed", "valve_1 does not turn: stopped at 8 of 90 deg")),
    ]
    seized = Assertion("intervention", {"part": "valve_1", "outcome": "failed", "reason": "does not turn"})
    assert judge(Run(short, states=stalled), (seized,))[0].passed
    assert not judge(Run(short, states=stalled), (done,))[0].passed
    unfinished = judge(Run(short, states=turned[:1]), (seized,))[0]
    assert not unfinished.passed and "last phase: turn" in unfinished.detail


def test_an_arm_joint_past_its_range_fails_the_limits() -> None:
    elbow_high_rad = arm_ranges_rad(ROBOT)[1][2]
    inside = state("")
    bent_rad = np.r_[0.0, 0.0, elbow_high_rad + np.radians(3), 0.0, 0.0, 0.0]
    past = dataclasses.replace(inside, arm_positions_rad=bent_rad)
    limits = Assertion("arm_limits", {"margin_deg": 1.0})
    assert judge(Run({}, states=[(0.0, inside)]), (limits,))[0].passed
    verdict = judge(Run({}, states=[(0.0, inside), (1.0, past)]), (limits,))[0]
    assert not verdict.passed and "elbow at +3.0 deg" in verdict.detail


def test_a_scenario_goes_on_simulated_time_unless_it_needs_the_wall_clock() -> None:
    root = Path(__file__).resolve().parents[2] / "scenarios"
    nominal, why = load_scenario(root / "nominal.toml").on_time("sim", "4")
    assert not why and nominal.time.simulated and nominal.time.speed_factor == 4.0
    back, _ = nominal.on_time("real", None)
    assert not back.time.simulated and back.time.speed_factor == 1.0
    for name, mode, said in (
        ("external-onboard", "sim", "external onboard keeps the wall clock"),
        ("onboard-starved", "lockstep", "a CPU cap is a share of wall time"),
    ):
        scenario = load_scenario(root / f"{name}.toml")
        kept, why = scenario.on_time(mode, "4" if mode == "sim" else None)
        assert kept is scenario and not kept.time.simulated and said in why, why
    assert not load_scenario(root / "vessel-crash.toml").holds_s  # real time: no holds
    crash, why = load_scenario(root / "vessel-crash.toml").on_time("lockstep", None)
    assert not why and crash.time.mode == "lockstep" and crash.holds_s == (6.0,)  # its kill's time
    assert "phase_holds" not in crash.up_table()["time"]
    outage, why = load_scenario(root / "tether-outage.toml").on_time("lockstep", None)
    assert not why and outage.time.mode == "lockstep" and outage.phase_held  # events timed on a phase
    assert outage.holds_s == () and outage.up_table()["time"]["phase_holds"] is True  # added as it runs


def test_a_failed_scenario_says_which_assertions_came_out_wrong(tmp_path: Path) -> None:
    """The line the CLI prints last, and JUnit's failure message: the assertions that did not come
    out as the scenario expects, with their figures, not those that did."""
    table = {
        **MINIMAL,
        "assert": [
            {"kind": "stations"},
            {"kind": "mission_done", "within_s": 20},
            {"kind": "commands_answered"},
        ],
        "expect_failed": ["mission_done"],
    }
    scenario = scenario_of(table)
    stations, done, answered = scenario.assertions
    as_expected = [Verdict(stations, True, "0 restarts"), Verdict(done, False, "not done")]
    assert (
        Result(
            scenario, tmp_path, [*as_expected, Verdict(answered, True, "all answered")], True, 1.0
        ).why_failed
        == ""
    )
    result = Result(
        scenario, tmp_path, [*as_expected, Verdict(answered, False, "unanswered: mode 7")], False, 1.0
    )
    assert result.why_failed == "commands_answered failed: unanswered: mode 7"
    held = Result(
        scenario,
        tmp_path,
        [as_expected[0], Verdict(done, True, "done at 12 s"), Verdict(answered, True, "all answered")],
        False,
        1.0,
    )
    assert held.why_failed == "mission_done within_s=20.0 held: done at 12 s"
    broken = Result(scenario, tmp_path, [], False, 1.0, error="no summary.json:\nlast lines")
    assert broken.why_failed == "no summary.json:"
    junit([result, held, broken], tmp_path / "junit.xml")
    text = (tmp_path / "junit.xml").read_text()
    assert 'message="commands_answered failed: unanswered: mode 7"' in text
    assert 'message="mission_done within_s=20.0 held: done at 12 s"' in text


def test_an_intervention_is_named_by_its_part_or_by_its_place_in_the_mission() -> None:
    """`part = "#i"` is the mission's i-th intervention's part, as the summary judged them: a
    scenario written so runs on any site; an i past the mission's fails saying so."""
    ended = dataclasses.replace(state(""), intervention_target="gate", intervention_phase="done")
    summary = {"interventions": [{"part": "gate", "success": True, "truth_deg": 90.0, "target_deg": 90.0}]}
    run = Run(summary, states=[(1.0, ended)])
    by_place, by_name, past = judge(
        run, tuple(Assertion("intervention", {"part": part}) for part in ("#0", "gate", "#1"))
    )
    assert by_place.passed and by_name.passed and by_place.detail == by_name.detail
    assert not past.passed and past.detail == "#1: the mission has no such intervention"
    with pytest.raises(ConfigError, match=r"assert\[0\]\.part: 'valve_9' is neither #i .* valve_1"):
        scenario_of({**MINIMAL, "assert": [{"kind": "intervention", "part": "valve_9"}]}, "x.toml")
