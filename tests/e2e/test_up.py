"""Whole systems as real processes over real Zenoh on loopback."""

from __future__ import annotations

import json
import os
import shutil
import signal
import threading
import time
from collections import Counter
from pathlib import Path

import pytest
import zenoh
from conftest import Up, abyss
from rerun.chunk import RrdReader

from abyss.bus.session import open_session, zenoh_config
from abyss.interface import keys

pytestmark = pytest.mark.timeout(150)


def test_up_runs_every_station_and_counts_every_hop(tmp_path: Path) -> None:
    up = Up(tmp_path / "run", "--keep-running", "--duration", "20", "--system", "e2e-up")
    assert up.wait(90) == 0, up.output()  # asked to run 20 s, mission or not: not judged on it
    summary = up.summary()
    assert summary["verdict"] in ("done", "incomplete") and summary["keep_running"]
    for name, station in summary["stations"].items():
        assert station["exit_code"] == 0 and station["alive_seen"], name
        assert 0.0 < station["cpu"]["cores"] < 2.0 and station["cpu"]["wall_s"] > 20.0, (name, station["cpu"])
    # the physics in C where setup.sh had a compiler to build it (stations/simulation/native.py)
    assert summary["stations"]["simulation"]["physics"] == ("c" if shutil.which("cc") else "python")
    if os.geteuid() == 0:  # CAP_SYS_NICE: the physics at real-time priority, said in the summary
        assert summary["stations"]["simulation"]["scheduler"] == "fifo 10"
        assert "(scheduler: fifo 10)" in up.output()
    # every key carries traffic, so every hop in both directions does (but the arm goal's: the
    # default mission's arm works through its interventions; tests/e2e/test_operator sends one;
    # and shore's scene request, sent only while it has no snapshot or a gap waits for one: none if
    # the vessel's first snapshot lands before shore's first look, which is where a real-time
    # event lands; tests/scene/test_shore_scene.py holds it)
    for spec in keys.KEYS:
        if spec.topic in ("op/arm", "goal/arm", "scene_request") or spec.feature:  # mavlink: off
            continue
        key = spec.key("e2e-up")
        assert summary["stations"][spec.station]["sent"].get(key, 0) > 0, key
        assert summary["stations"][spec.to]["received"].get(key, 0) > 0, key
    for hop, (a, b) in keys.HOPS.items():
        for direction in (f"{a}->{b}", f"{b}->{a}"):
            assert summary["links"][hop][direction]["messages_delivered"] > 0, (hop, direction)
    tether = summary["links"]["tether"]["onboard->vessel"]
    assert 90 < tether["delay_p50_ms"] < 130  # the tether profile's 100 ms +/- 10 ms
    telemetry = keys.spec("onboard", "telemetry").key("e2e-up")  # the same, seen by the receiver
    assert 90 < summary["stations"]["vessel"]["latency_ms"][telemetry]["latency_p50_ms"] < 140
    mission = summary["mission"]  # the mission went down, was flown, and shore saw progress
    assert mission["waypoints_total"] == 3 and mission["mode"] in ("moving", "reached")
    assert mission["waypoint_index"] >= 1
    assert "all 4 stations up" in up.output()
    # the scene went camera -> cloud -> octree -> satellite -> shore, and the panel was recognised
    scene = summary["scene"]
    assert scene["occupied_cells"] > 100 and scene["updates_applied"] >= 1, scene
    assert "panel" in scene["objects"] and "valve_1" in scene["objects"]
    panel_m = scene["objects"]["panel"]["pose_world"][:3]
    assert abs(panel_m[0] - 5.0) < 0.15 and abs(panel_m[1]) < 0.15 and abs(panel_m[2] + 8.6) < 0.15
    export = abyss("scene", "export", str(tmp_path / "run"))
    assert export.returncode == 0, export.stderr
    assert (tmp_path / "run" / "scene.bt").stat().st_size > 0 and (tmp_path / "run" / "scene.ply").is_file()
    assert f"({scene['occupied_cells']} occupied cells" in export.stdout
    missing = abyss("scene", "export", str(tmp_path))
    assert missing.returncode == 2 and "holds no scene.msgpack" in missing.stderr
    # the operator's recording, read with rerun's own reader: every part of the view holds data
    rows: Counter[str] = Counter()
    for chunk in RrdReader(tmp_path / "run" / "onshore.rrd").stream().to_chunks():
        rows[chunk.entity_path.lstrip("/")] += chunk.num_rows
    arm = "world/vehicle/arm_base/arm_link1/arm_link2/arm_link3/arm_link4/arm_link5/arm_link6"
    for path in (
        "world/vehicle",
        "world/vehicle/hull",
        arm,
        "world/path",
        "world/mission/waypoints",
        "world/scene/octree",
        "world/scene/latest_update",
        "world/objects/panel",
        "world/objects/valve_1",
        "world/camera/image",
        "errors/vehicle_position_m/distance",
        "errors/tool_orientation_deg/angle",
        "links/satellite/delay_ms/vessel_to_onshore/p50",
        "links/tether/throughput_kbps/onboard_to_vessel",
    ):
        assert rows[path] > 0, (path, sorted(rows))
    assert rows["world/vehicle"] >= 10 and rows[arm] == rows["world/vehicle"]  # telemetry at 2 Hz, 20 s


def test_a_killed_station_is_reported_and_up_fails(tmp_path: Path) -> None:
    up = Up(tmp_path / "run", "--duration", "60", "--system", "e2e-kill")
    pid = up.wait_up().stations["onboard"].pid
    assert pid is not None
    os.kill(pid, signal.SIGKILL)
    assert up.wait(60) != 0
    assert "station onboard died with exit code -9 (SIGKILL)" in up.output()
    summary = up.summary()
    assert summary["verdict"] == "failed" and summary["stations"]["onboard"]["exit_code"] == -9
    assert all(s["exit_code"] == 0 for n, s in summary["stations"].items() if n != "onboard")


def test_a_satellite_outage_all_run_long_is_incomplete_and_every_station_stops(tmp_path: Path) -> None:
    """Nothing crosses the satellite: the mission never starts, reliable messages pile up on the
    link until senders block, and each station still stops within its bound."""
    up = Up(
        tmp_path / "run",
        "--duration",
        "15",
        "--system",
        "e2e-outage",
        "--profile",
        "satellite=outage",
        "--viewer",
        "none",
    )
    assert up.wait(90) == 3, up.output()  # incomplete
    summary = up.summary()
    assert summary["verdict"] == "incomplete" and summary["failure"] == "", up.output()
    assert not summary["mission"]["done"] and summary["mission_done_s"] is None
    for name, station in summary["stations"].items():
        assert station["exit_code"] == 0 and station["stop_s"] < 5.0, (name, station)
    satellite = summary["links"]["satellite"]
    assert all(d["messages_delivered"] == 0 and d["undelivered_at_close"] > 0 for d in satellite.values())
    assert json.loads((tmp_path / "run" / "state.json").read_text())["verdict"] == "incomplete"
    assert "abyss: e2e-outage: incomplete;" in up.output()


def test_an_external_station_that_never_comes_ends_the_run_at_its_duration(tmp_path: Path) -> None:
    """`--external onboard --duration 5` with no onboard ever started: the duration bounds the
    wait for it too (not the 180 s start-up bound, nor the user's Ctrl-C)."""
    t0 = time.monotonic()
    up = Up(
        tmp_path / "run",
        "--external",
        "onboard",
        "--duration",
        "5",
        "--system",
        "e2e-never",
        "--viewer",
        "none",
    )
    assert up.wait(60) == 3, up.output()  # incomplete
    assert time.monotonic() - t0 < 40, up.output()
    assert "external station onboard never came" in up.output() and "--duration of 5 s" in up.output()
    assert "all 4 stations up" not in up.output()
    summary = up.summary()
    assert summary["verdict"] == "incomplete" and summary["failure"] == "", up.output()
    assert all(s["exit_code"] == 0 for n, s in summary["stations"].items() if n != "onboard"), summary


def test_ctrl_c_is_interrupted_and_everything_is_written(tmp_path: Path) -> None:
    up = Up(tmp_path / "run", "--duration", "60", "--system", "e2e-ctrl-c", "--viewer", "none")
    up.wait_up()
    up.wait_for(r"t=\s*\d+ s  mission: moving")  # under way, far from done
    os.kill(up.process.pid, signal.SIGINT)  # what Ctrl-C sends
    assert up.wait(30) == 130, up.output()
    summary = up.summary()
    assert summary["verdict"] == "interrupted" and not summary["mission"]["done"], up.output()
    for name, station in summary["stations"].items():
        assert station["exit_code"] == 0 and station["stop_s"] < 5.0, (name, station)
        assert (tmp_path / "run" / f"{name}.json").is_file()
    commands = json.loads((tmp_path / "run" / "commands.json").read_text())
    assert {c["command"] for c in commands} == {"mode", "waypoints", "intervene"}
    assert json.loads((tmp_path / "run" / "state.json").read_text())["verdict"] == "interrupted"


def test_a_killed_up_takes_its_stations_down(tmp_path: Path) -> None:
    up = Up(tmp_path / "run", "--duration", "60", "--system", "e2e-orphans", "--viewer", "none")
    pids = [s.pid for s in up.wait_up().stations.values()]
    assert len(pids) == 4
    os.kill(up.process.pid, signal.SIGKILL)
    deadline = time.monotonic() + 20.0
    while time.monotonic() < deadline and any(Path(f"/proc/{pid}").exists() for pid in pids):
        time.sleep(0.2)
    alive = [pid for pid in pids if Path(f"/proc/{pid}").exists()]
    assert not alive, f"stations outlived abyss up: {alive}"


def test_two_systems_side_by_side_without_crosstalk(tmp_path: Path) -> None:
    ups = {
        name: Up(tmp_path / name, "--keep-running", "--duration", "12", "--system", name)
        for name in ("alpha", "beta")
    }
    for up in ups.values():
        up.wait_up()
    seen: dict[str, set[str]] = {}
    for name, up in ups.items():
        session = open_session(zenoh_config(connect=[up.endpoint], mode="client"), "test")
        keys_seen: set[str] = set()
        lock = threading.Lock()

        def on_sample(sample: zenoh.Sample, ks: set[str] = keys_seen, lk: threading.Lock = lock) -> None:
            with lk:
                ks.add(str(sample.key_expr))

        subscriber = session.declare_subscriber("abyss/**", on_sample)
        time.sleep(3)
        subscriber.undeclare()
        session.close()
        seen[name] = keys_seen
    for name, up in ups.items():
        assert up.wait(60) == 0, up.output()
        assert seen[name], f"nothing seen on {name}"
        assert all(k.startswith(f"abyss/{name}/") for k in seen[name]), seen[name]
        received = up.summary()["stations"]["onboard"]["received"]
        own = {s.key(name) for s in keys.KEYS if s.to == "onboard"}
        assert set(received) <= own


def test_runtime_link_change_and_bad_bytes(tmp_path: Path) -> None:
    system = "e2e-live"
    up = Up(tmp_path / "run", "--keep-running", "--duration", "40", "--system", system)
    up.wait_up()
    endpoint = up.endpoint
    done = abyss("link", "set", "satellite", "--loss", "30%", "--connect", endpoint, "--system", system)
    assert done.returncode == 0, done.stderr
    shown = abyss("link", "show", "satellite", "--json", "--connect", endpoint, "--system", system)
    links = json.loads(shown.stdout)
    assert {s["direction"] for s in links} == {"vessel->onshore", "onshore->vessel"}
    assert all(s["fields"]["loss"] == "30%" for s in links)
    bad = abyss("link", "set", "satellite", "--loss", "300%", "--connect", endpoint, "--system", system)
    assert bad.returncode == 2 and "loss" in bad.stderr

    session = open_session(zenoh_config(connect=[endpoint], mode="client"), "test")
    nav_key = keys.spec("simulation", "nav").key(system)
    for garbage in (b"", b"\xc1\xc1", b"\x80", json.dumps({"type": "NavState"}).encode()):
        session.put(nav_key, garbage)
    time.sleep(1.0)
    session.close()
    up.interrupt()
    summary = up.summary()
    onboard = summary["stations"]["onboard"]
    assert onboard["exit_code"] == 0 and onboard["rejected"][nav_key] == 4
    assert summary["links"]["satellite"]["vessel->onshore"]["profile"] == "satellite"
    assert "dropped a message on" in (tmp_path / "run" / "onboard.log").read_text()
