"""The bus recording of a whole run, and the recorded stations played back in place of live ones:
the live stations reach the recorded run's scene and mission; `--compare` finds a changed gain and
nothing in an unchanged system; a run killed mid-mission keeps its recording up to the kill."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import Up, abyss

from abyss.interface import keys
from abyss.recording.reader import open_recording
from abyss.recording.store import data_spec

pytestmark = pytest.mark.timeout(240)


def test_every_data_key_is_recorded_as_sent_and_as_received(recorded_run: Path) -> None:
    recording = open_recording(recorded_run)
    assert recording.stations == set(keys.STATIONS) and all(f.complete for f in recording.files)
    size_mb = sum(f.size_bytes for f in recording.files) / 1e6
    assert size_mb < 50, f"{size_mb:.1f} MB"
    seen = {(r.direction, r.topic) for r in recording.records()}
    for spec in keys.KEYS:
        topic = f"{spec.station}/{spec.topic}"
        events = (
            "scene_request",
            "op/waypoints",
            "op/arm",
            "op/mode",
            "op/intervene",
            "goal/waypoints",
            "goal/arm",
            "goal/mode",
            "goal/intervene",
            "ack",
        )
        if (spec.topic in events and ("sent", topic) not in seen) or spec.feature:
            continue  # events a run may not have; a feature it does not run (mavlink)
        assert ("sent", topic) in seen and ("received", topic) in seen, topic
    summary = json.loads((recorded_run / "summary.json").read_text())
    for r in recording.records(stations=("vessel",), directions=("received",)):
        spec = data_spec(r.key)
        assert spec is not None and r.hop == spec.hop

    # as received: the tether's 100 ms +/- 10 ms is in the receiver's stamps, none on the ideal rov hop
    def delays_s(station: str, topic: str) -> list[float]:
        return sorted(
            r.recorded_s - r.sent_s for r in recording.records((station,), ("received",)) if r.topic == topic
        )

    tether, rov = delays_s("vessel", "onboard/telemetry"), delays_s("onboard", "simulation/nav")
    assert tether[len(tether) // 2] > 0.08 and rov[len(rov) // 2] < 0.05
    sent = summary["stations"]["onboard"]["sent"]["abyss/default/onboard/telemetry"]
    recorded = sum(1 for r in recording.published(("onboard",)) if r.topic == "onboard/telemetry")
    assert recorded == sent  # under its cap: every message
    assert {r.topic for r in recording.observed()} >= {"simulation/truth", "onshore/mission"}


REPLAYS = {  # name: what is replayed (and compared); the rest runs live
    # the whole recording (the mission, then 10 s for the scene stream to reach shore whole): by
    # default a replay lasts the recording's span (its 40 s and the stations' start) and 2 s more
    "shore-live": ("--as", "simulation", "--as", "onboard", "--keep-running"),
    "onboard-live": ("--as", "simulation", "--as", "vessel", "--as", "onshore", "--compare"),
    "onboard-changed": (
        "--as",
        "simulation",
        "--as",
        "vessel",
        "--as",
        "onshore",
        "--compare",
        "--set",
        "onboard.kp_position=1.2",
    ),
}


@pytest.fixture(scope="module")
def replays(
    recorded_run: Path,
    tmp_path_factory: pytest.TempPathFactory,
) -> dict[str, tuple[subprocess.CompletedProcess[str], Path]]:
    """The replays the tests below judge, as a user runs them (each its own system), all at once:
    the exit, the output and the run directory of each. Shore-live's live vessel drops clouds it
    cannot insert in time (a bounded inbox), so a machine busier than in the recorded run would
    shrink its scene: the two comparisons (onboard live, the rest replayed) run beside it at the
    lowest CPU priority (nice 19), on what it leaves."""
    base = tmp_path_factory.mktemp("replays")
    started = {
        name: subprocess.Popen(
            [
                *([] if name == "shore-live" else ["nice", "-n", "19"]),
                sys.executable,
                "-P",
                "-m",
                "abyss.cli",
                "replay",
                str(recorded_run),
                *REPLAYS[name],
                "--out",
                str(base / name),
                "--viewer",
                "none",
                "--port",
                "0",
                "--system",
                name,
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=base,
        )
        for name in REPLAYS
    }
    done = {}
    for name, process in started.items():
        stdout, stderr = process.communicate(timeout=200)
        result = subprocess.CompletedProcess(process.args, process.returncode, stdout, stderr)
        done[name] = (result, base / name)
    return done


def test_replayed_simulation_and_onboard_drive_live_vessel_and_shore_to_the_recorded_end(
    recorded_run: Path, replays: dict[str, tuple[subprocess.CompletedProcess[str], Path]]
) -> None:
    done, out = replays["shore-live"]
    assert done.returncode == 0, done.stdout + done.stderr
    recorded, replayed = (json.loads((run / "summary.json").read_text()) for run in (recorded_run, out))
    assert replayed["verdict"] == "done" and replayed["mission_done_s"] is not None
    cells = [s["scene"]["occupied_cells"] for s in (recorded, replayed)]
    vessel = [
        (
            s["stations"]["vessel"]["received"].get(f"abyss/{s['system']}/onboard/cloud"),
            s["stations"]["vessel"].get("shed"),
            s["scene"]["updates_applied"],
            s["wall_s"],
        )
        for s in (recorded, replayed)
    ]  # clouds in, clouds shed, map updates on shore, run length
    assert abs(cells[1] - cells[0]) <= 0.05 * cells[0], (cells, vessel)
    state = ("mode", "waypoint_index", "waypoints_total", "arm_mode", "done")
    assert {k: replayed["mission"][k] for k in state} == {k: recorded["mission"][k] for k in state}
    assert sorted(replayed["scene"]["objects"]) == sorted(recorded["scene"]["objects"])
    # the replayed stations ran no station code: onboard sent what its recording holds (up to the
    # mission's end on the live shore), and took the live shore's commands (new ids) as the recorded ones
    assert "replaying simulation, onboard" in done.stdout
    onboard_sent = sum(replayed["stations"]["onboard"]["sent"].values())
    recorded_sent = sum(1 for r in open_recording(recorded_run).published(("onboard",)))
    assert 0.9 * recorded_sent <= onboard_sent <= recorded_sent + 3, (onboard_sent, recorded_sent)


@pytest.mark.parametrize("name", ["onboard-live", "onboard-changed"])
def test_compare_names_the_keys_a_changed_gain_changes_and_nothing_else(
    replays: dict[str, tuple[subprocess.CompletedProcess[str], Path]], name: str
) -> None:
    done, out = replays[name]
    rows = {row["key"]: row for row in json.loads((out / "compare.json").read_text())}
    assert set(rows) == {f"onboard/{s.topic}" for s in keys.KEYS if s.station == "onboard" and not s.feature}
    differing = sorted(k for k, row in rows.items() if row["differs"])
    if name == "onboard-live":
        assert done.returncode == 0 and differing == [], done.stdout + done.stderr
        assert f"0 of {len(rows)} keys differ" in done.stdout
    else:
        # the command, and in telemetry only the effort, which reports that command to the pilot
        assert done.returncode == 1, done.stdout
        assert differing == ["onboard/cmd/vehicle_velocity", "onboard/telemetry"], done.stdout
        assert rows["onboard/cmd/vehicle_velocity"]["fields"]["linear_mps_body"]["differs"]
        telemetry = rows["onboard/telemetry"]["fields"]
        assert [f for f, row in telemetry.items() if row["differs"]] == ["effort_body"], telemetry
        assert f"2 of {len(rows)} keys differ: onboard/cmd/vehicle_velocity, onboard/telemetry" in done.stdout
    assert all(row["paired"] > 0 for row in rows.values())


def test_a_killed_run_keeps_its_recording_up_to_the_kill(tmp_path: Path) -> None:
    up = Up(tmp_path / "killed", "--viewer", "none", "--record", "control")
    state = up.wait_up()
    up.wait_for(r"t=\s+5 s", 60)
    for pid in [*(s.pid for s in state.stations.values() if s.pid), state.supervisor_pid]:
        os.kill(pid, signal.SIGKILL)  # every station, then abyss up (whose death would stop them)
    up.wait()
    recording = open_recording(tmp_path / "killed")
    assert recording.stations == set(keys.STATIONS)
    assert not any(f.complete for f in recording.files)  # none was closed
    nav = [r for r in recording.published(("simulation",)) if r.topic == "simulation/nav"]
    assert len(nav) >= 20 * 4  # at 20 Hz, past t = 5 s less the last flush
    assert all(r.decode().message for r in nav)  # every record read whole
    assert not [r for r in recording.records() if data_spec(r.key) and data_spec(r.key).priority == "bulk"]


def test_bad_replays_fail_at_start_with_the_fix(tmp_path: Path, recorded_run: Path) -> None:
    empty = abyss("replay", str(tmp_path), "--as", "onboard")
    assert empty.returncode == 2 and f"{tmp_path}/record: no recording" in empty.stderr
    assert "--record all" in empty.stderr
    unknown = abyss("replay", str(recorded_run), "--as", "rov")
    assert unknown.returncode == 2 and "invalid choice: 'rov'" in unknown.stderr
    same = abyss("replay", str(recorded_run), "--as", "onboard", "--out", str(recorded_run))
    assert same.returncode == 2 and "is the recorded run" in same.stderr
    stopped = abyss("replay", str(recorded_run), "--as", "onboard", "--speed", "0")
    assert stopped.returncode == 2 and "--speed: 0.0 must be a positive factor" in stopped.stderr
    compare = abyss("replay", str(recorded_run), "--compare")
    assert compare.returncode == 2 and "--as STATION" in compare.stderr
    alias = abyss("replay", str(tmp_path))
    assert "is now `abyss view" in alias.stderr


def test_a_run_a_campaign_kept_replays_on_the_wall_clock(tmp_path: Path) -> None:
    """A lockstep run, in the shape a campaign keeps it (`<campaign>/runs/<run id>/`, its
    config.json with the scenario's holds and every path under the worker's run directory):
    `abyss replay` plays its simulation and vessel back to a live onboard and shore, in real
    time, named by the campaign's directory and a prefix of the run's id."""
    worker = tmp_path / "worker" / "run"
    worker.parent.mkdir()
    up = Up(worker, "--time", "lockstep", "--duration", "6", "--viewer", "none", "--system", "small-1")
    assert up.wait(120) == 3, up.output()  # incomplete: lockstep ends at its duration
    run = tmp_path / "campaign" / "runs" / "3f9a1c0d5e6b7a81"
    shutil.copytree(worker, run)
    (tmp_path / "campaign" / "plan.json").write_text("{}")
    config = json.loads((run / "config.json").read_text())
    config["time"]["holds_s"] = [2.0, 3.0]  # as a scenario's timed events leave it
    (run / "config.json").write_text(json.dumps(config))
    shutil.rmtree(worker)
    done = abyss(
        "replay",
        str(tmp_path / "campaign" / "3f9a1c0d"),
        "--as",
        "simulation",
        "--as",
        "vessel",
        "--duration",
        "8",
        "--viewer",
        "none",
        "--port",
        "0",
        "--out",
        str(tmp_path / "replay"),
        timeout_s=120,
    )
    assert done.returncode == 3, done.stdout + done.stderr  # incomplete: a live shore, 8 s
    assert "ran in lockstep time; its replay runs on the wall clock" in done.stdout
    assert f"replaying simulation, vessel of {run}" in done.stdout
    summary = json.loads((tmp_path / "replay" / "summary.json").read_text())
    assert summary["time"]["mode"] == "real", summary["time"]
    received = summary["stations"]["onboard"]["received"]
    assert received.get("abyss/small-1/simulation/nav", 0) > 50, received  # 20 Hz, replayed
