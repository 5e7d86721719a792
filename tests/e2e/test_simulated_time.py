"""Whole systems on simulated time (`--time sim`): the simulation's clock drives every station
and every emulated link, the summary says how fast it went and what held it back, a failsafe
scenario keeps its bounds in simulated time, and what cannot follow simulated time is refused
at start."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import ROOT, Up, abyss

from abyss.interface import keys
from abyss.recording.reader import read_file

pytestmark = pytest.mark.timeout(240)


def test_a_whole_system_on_simulated_time(tmp_path: Path) -> None:
    up = Up(
        tmp_path / "run",
        "--time",
        "sim",
        "--speed",
        "4",
        "--keep-running",
        "--duration",
        "20",
        "--system",
        "e2e-sim",
        "--viewer",
        "none",
        "--record",
        "none",
    )
    assert up.wait(180) == 0, up.output()
    summary = up.summary()
    timing = summary["time"]
    assert timing["mode"] == "sim" and timing["speed"] == "4"
    assert timing["sim_s"] >= 20.0 and timing["wall_s"] > 0  # the duration is simulated seconds
    assert timing["achieved_speed"] == pytest.approx(timing["sim_s"] / timing["wall_s"], rel=1e-2)
    assert set(timing["held_s"]) == {"simulation", "onboard", "vessel", "onshore"}
    assert timing["limited_by"] in {"speed asked", *timing["held_s"]}
    assert "(x" in up.output()  # the progress lines give the speed
    assert f"time: sim at speed 4: {timing['sim_s']:.1f} s simulated" in up.output()
    for name, station in summary["stations"].items():
        assert station["exit_code"] == 0 and station["alive_seen"], name
    # the stations' progress paces the physics, not deadlines: no real-time priority
    assert summary["stations"]["simulation"]["scheduler"].startswith("normal (time.mode sim: ")
    # the links delay by their profiles in simulated time, as the receiver's stamps show too
    tether = summary["links"]["tether"]["onboard->vessel"]
    assert 90 < tether["delay_p50_ms"] < 130, tether  # the tether's 100 ms +/- 10 ms
    telemetry = keys.spec("onboard", "telemetry").key("e2e-sim")
    assert 90 < summary["stations"]["vessel"]["latency_ms"][telemetry]["latency_p50_ms"] < 140
    satellite = summary["links"]["satellite"]["vessel->onshore"]
    assert 100 < satellite["delay_p50_ms"] < 400, satellite  # 150 ms +/- 75 ms, queued behind the scene
    # the mission was flown as in real time: 20 simulated seconds reach the second waypoint
    assert summary["mission"]["waypoint_index"] >= 1, summary["mission"]
    control = summary["stations"]["onboard"]["loops"]["control"]
    assert control["ticks"] >= 0.9 * 20 / control["period_s"], control  # its rate in simulated time
    assert summary["simulation"]["sim_time_s"] >= 15.0  # its status comes once a wall second


def test_speed_max_runs_as_fast_as_the_slowest_station_and_names_it(tmp_path: Path) -> None:
    up = Up(
        tmp_path / "run",
        "--time",
        "sim",
        "--speed",
        "max",
        "--keep-running",
        "--duration",
        "10",
        "--system",
        "e2e-max",
        "--viewer",
        "none",
        "--record",
        "none",
    )
    assert up.wait(150) == 0, up.output()
    timing = up.summary()["time"]
    assert timing["speed"] == "max" and timing["sim_s"] >= 10.0
    assert timing["achieved_speed"] > 0 and timing["limited_by"] in timing["held_s"], timing
    assert timing["limited_by"] != "speed asked"  # nothing asked: a station or the simulation limits it
    summary = up.summary()
    assert summary["links"]["tether"]["onboard->vessel"]["delay_p50_ms"] < 130  # still the profile's


@pytest.mark.timeout(300)
def test_the_tether_outage_failsafe_keeps_its_bounds_at_speed_4(tmp_path: Path) -> None:
    done = abyss(
        "scenario",
        "run",
        str(ROOT / "scenarios" / "tether-outage.toml"),
        "--time",
        "sim",
        "--speed",
        "4",
        "--report",
        str(tmp_path / "rep"),
        timeout_s=280,
    )
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr
    assert "ok   failsafe phase=turn from_s=1.0 to_s=7.0" in done.stdout
    summary = json.loads(next((tmp_path / "rep" / "runs").glob("*/summary.json")).read_text())
    assert summary["time"]["mode"] == "sim" and summary["verdict"] == "done"
    assert summary["mission_done_s"] <= 145  # simulated seconds, the scenario's bound


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (
            ("up", "--time", "sim", "--external", "onboard"),
            "--external: a real component or a replay runs on the wall clock",
        ),
        (("up", "--speed", "4"), "--speed: time.speed: 4: only with time.mode sim"),
        (
            ("up", "--time", "sim", "--speed", "fast"),
            "--speed: time.speed: 'fast': a number from 0.01 to 1000, or max",
        ),
        (
            ("up", "--time", "sim", "--speed", "4", "--cpu", "onboard=0.3"),
            "--cpu: a CPU cap is a share of wall time",
        ),
        (("up", "--time", "sim", "--ros2", "onboard"), "time.mode: sim: a ROS 2 node (ros2.station, --ros2)"),
        (("up", "--time", "lockstep", "--restart"), "--restart: a station restarted mid-period"),
    ],
)
def test_what_cannot_follow_simulated_time_is_refused_at_start(
    tmp_path: Path, args: tuple[str, ...], said: str
) -> None:
    done = abyss(*args, "--out", str(tmp_path / "run"), "--port", "0", timeout_s=60)
    assert done.returncode == 2 and said in done.stderr, done.stdout + done.stderr


def test_a_station_on_real_links_refuses_simulated_time(tmp_path: Path) -> None:
    done = abyss(
        "station",
        "onboard",
        "--time",
        "sim",
        "--link",
        "tun",
        "--listen",
        "tcp/127.0.0.1:0",
        "--status-file",
        str(tmp_path / "status.json"),
        timeout_s=60,
    )
    assert done.returncode != 0
    assert "link mode tun: shapes real packets on the wall clock" in done.stderr, done.stderr[-3000:]


def _lockstep_run(out: Path, system: str) -> Up:
    return Up(
        out,
        "--time",
        "lockstep",
        "--keep-running",
        "--duration",
        "15",
        "--system",
        system,
        "--viewer",
        "none",
        "--record",
        "all",
    )


@pytest.mark.timeout(300)
def test_lockstep_repeats_bit_for_bit_on_a_loaded_machine(tmp_path: Path) -> None:
    """The same seed twice, the first run beside a whole real-time system that loads the machine:
    every message each station sent, onboard's telemetry as recorded (control.csv) and the scene
    shore ends with, byte for byte; and a run ends on the same period however late it is stopped."""
    load = Up(
        tmp_path / "load",
        "--keep-running",
        "--duration",
        "60",
        "--system",
        "e2e-load",
        "--viewer",
        "none",
        "--record",
        "none",
    )
    first = _lockstep_run(tmp_path / "a", "e2e-lockstep")
    assert first.wait(200) == 0, first.output()
    load.process.terminate()
    load.wait(30)
    second = _lockstep_run(tmp_path / "b", "e2e-lockstep")
    assert second.wait(200) == 0, second.output()
    a, b = tmp_path / "a", tmp_path / "b"
    assert (a / "control.csv").read_bytes() == (b / "control.csv").read_bytes()
    rows = (a / "control.csv").read_text().splitlines()
    assert len(rows) > 140 and 14.8 < float(rows[-1].split(",")[0]) < 15.0, rows[-1]  # 10 Hz to the end
    assert (a / "scene.msgpack").read_bytes() == (b / "scene.msgpack").read_bytes()
    for station in keys.STATIONS:
        sent = [
            {
                (r.key, r.seq): r.payload
                for r in read_file(run / "record" / f"{station}.mcap").records
                if r.direction == "sent"
            }
            for run in (a, b)
        ]
        assert sent[0] and sent[0] == sent[1], station
    summary = first.summary()
    assert summary["time"]["mode"] == "lockstep" and summary["time"]["sim_s"] >= 14.9
    assert summary["mission"]["waypoint_index"] >= 1


def test_the_pytest_fixture_takes_the_time_source_and_refuses_what_cannot_follow_it(abyss_system) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(pytest.UsageError, match="external onboard keeps the wall clock"):
        abyss_system(ROOT / "scenarios" / "external-onboard.toml", time="sim", speed="4")
    system = abyss_system(
        {
            "name": "short",
            "use": "interface",
            "duration_s": 8,
            "stop_when_done": False,
            "assert": [{"kind": "stations"}],
        },
        time="sim",
        speed="4",
    )
    assert system.scenario.time.simulated and system.scenario.time.speed_factor == 4.0
    result = system.result(timeout_s=120)
    assert result.passed, [v.detail for v in result.verdicts]
    summary = json.loads((result.out_dir / "summary.json").read_text())
    assert summary["time"]["mode"] == "sim" and summary["time"]["sim_s"] >= 8.0


def test_a_lockstep_event_past_the_runs_end_is_not_reached_and_the_verdict_stands(tmp_path: Path) -> None:
    """A kill timed after the run ends (the kill campaign's latest moment, once a mission is done
    before it) is not reached, as in real time: the run ends with its verdict, not an error
    (it was "lockstep: the system ended while waiting for the simulation held at t=9 s")."""
    scenario = tmp_path / "late-kill.toml"
    scenario.write_text(
        'name = "late-kill"\ndescription = "a kill after the end"\nuse = "fault-recovery"\n'
        "duration_s = 5\nstop_when_done = false\nrestart = true\n"
        '[[events]]\nat_s = 9\naction = "kill"\nstation = "vessel"\n'
        '[[assert]]\nkind = "stations"\nmax_restarts = 0\n'
    )
    done = abyss("scenario", "run", str(scenario), "--time", "lockstep", "--report", str(tmp_path / "rep"),
                 timeout_s=200)  # fmt: skip
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr
    assert "t=9 s: not reached (the run ended first), kill vessel not done" in done.stdout, done.stdout[
        -3000:
    ]
