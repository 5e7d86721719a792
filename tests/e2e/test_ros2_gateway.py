"""The ROS 2 gateway end to end, with ROS 2 nodes written from rmw_zenoh's wire contract alone
(rosnode.py: zenoh-python and pycdr2, none of the gateway's code). `abyss up --ros2 onboard`:
the node discovers the gateway's endpoints, flies the mission's waypoints with velocity
commands, and meanwhile bad samples on every topic the gateway takes are counted and dropped,
and `abyss check onboard` judges the node's keys through the gateway. `--ros2 vessel`: the node
maps onboard's clouds, and shore's scene is its map. And the node under each Zenoh release the
supported rmw_zenoh releases bundle, against the gateway on abyss's own Zenoh."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import rosnode
import zenoh
import zenoh.ext
from conftest import Up
from rosnode import (
    QOS_SENSOR,
    DiagnosticArray,
    Float64MultiArray,
    Odometry,
    PointCloud2,
    PoseStamped,
    RosNode,
    TFMessage,
    TwistStamped,
    WaypointPilot,
    data_key,
    dds_name,
    gateway_graph,
    rihs01,
    ros_type,
)

from abyss.common.ports import free_port
from abyss.interface.messages import NavState, SceneUpdate, decode
from abyss.recording.reader import open_recording
from abyss.scene.export import SCENE_FILE
from abyss.scene.octree import cell_keys, iterate_leaves, leaves_to_cells, read_binary

LAST_WAYPOINT_M = np.array([3.2, 0.0, -8.0])  # the default mission's
UP_TOPICS = {  # what the gateway takes from the node, and the bad samples each is sent
    "/abyss/onboard/cmd/vehicle_velocity": TwistStamped,
    "/abyss/onboard/cmd/arm_velocity": Float64MultiArray,
    "/abyss/onboard/telemetry/diagnostics": DiagnosticArray,
    "/abyss/onboard/telemetry/ee_pose": PoseStamped,
    "/abyss/onboard/cloud": PointCloud2,
}


def _send_bad_samples(session: zenoh.Session, gid: bytes) -> int:
    """Malformed CDR, a wrong type hash, a missing attachment, a wrong type: each on every topic
    the gateway takes; returns how many per topic."""
    attachment = rosnode.attachment(1, gid)
    for topic, message in UP_TOPICS.items():
        key = data_key(0, topic, message)
        prefix = key.rsplit("/", 2)[0]
        session.put(key, b"\x00\x01\x00\x00\xff\xff", attachment=attachment)
        session.put(
            f"{prefix}/{dds_name(ros_type(message))}/RIHS01_{'0' * 64}",
            b"\x00\x01\x00\x00",
            attachment=attachment,
        )
        session.put(key, b"\x00\x01\x00\x00" + bytes(64))
        session.put(
            f"{prefix}/std_msgs::msg::dds_::String_/{rihs01('std_msgs/msg/String')}",
            b"\x00\x01\x00\x00\x01\x00\x00\x00\x00",
            attachment=attachment,
        )
    return 4


def test_a_ros2_node_flies_the_mission_through_the_gateway(tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    up = Up(
        tmp_path / "run",
        "--ros2",
        "onboard",
        "--set",
        f'ros2.listen=["{endpoint}"]',
        "--set",
        "mission.interventions=[]",
        "--duration",
        "120",
        "--viewer",
        "none",
        "--record",
        "control",
        # the node flies on the raw USBL fixes, with no filter: a 3 m outlier late in the run
        # would leave the vehicle metres off (onboard's own filter rejects them: test_nav_filter)
        "--set",
        "simulation.usbl_outlier_probability=0",
    )
    up.wait_for(r"onboard is a ROS 2 gateway .*connect/endpoints=\[\"" + endpoint)
    up_endpoint = up.wait_for(r"Zenoh endpoint (\S+)").group(1)
    up.wait_up()
    node = RosNode(endpoint)
    stop, workers = threading.Event(), list[threading.Thread]()
    try:
        graph = gateway_graph(
            node,
            "abyss_onboard_gateway",
            {
                ("MP", "/abyss/simulation/nav"),
                ("MS", "/abyss/onboard/cmd/vehicle_velocity"),
                ("MP", "/tf_static"),
                ("MP", "/clock"),
            },
        )
        by_topic = {(t.kind, t.topic): t for t in graph if t.node == "abyss_onboard_gateway"}
        odometry = by_topic["MP", "/abyss/simulation/nav"]
        assert (odometry.namespace, odometry.type, odometry.hash, odometry.qos) == (
            "/abyss",
            "nav_msgs::msg::dds_::Odometry_",
            rihs01("nav_msgs/msg/Odometry"),
            QOS_SENSOR,
        )
        velocity = by_topic["MS", "/abyss/onboard/cmd/vehicle_velocity"]
        assert velocity.type == "geometry_msgs::msg::dds_::TwistStamped_"
        assert by_topic["MP", "/tf_static"].qos == ":1:,1:,:,:,,"  # reliable, transient local, depth 1
        assert by_topic["MP", "/clock"].qos == "2::,1:,:,:,,"
        assert {
            ("MP", "/abyss/vessel/goal/waypoints"),
            ("MS", "/abyss/onboard/cmd/arm_velocity"),
            ("MP", "/abyss/simulation/camera/left/image"),
        } <= set(by_topic)

        pilot = WaypointPilot(node)
        workers.append(threading.Thread(target=pilot.fly, args=(stop,), daemon=True))
        workers[-1].start()
        check = subprocess.run(
            [
                sys.executable,
                "-P",
                "-m",
                "abyss.cli",
                "check",
                "onboard",
                "--connect",
                up_endpoint,
                "--duration",
                "4",
            ],
            capture_output=True,
            text=True,
            timeout=60,
        )
        bad_each = _send_bad_samples(node.session, bytes(16))
        # /tf_static from the gateway's cache to a subscriber that comes late, as tf2's does
        static: list[TFMessage] = []
        late = zenoh.ext.declare_advanced_subscriber(
            node.session,
            data_key(0, "/tf_static", TFMessage),
            lambda s: static.append(TFMessage.deserialize(s.payload.to_bytes())),
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
        )
        assert up.wait(120) == 0, up.output()
        late.undeclare()
    finally:
        stop.set()
        for worker in workers:  # no publish in flight while the node's entities go
            worker.join()
        node.close()
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["verdict"] == "done" and summary["mission"]["done"], summary["mission"]
    recording = open_recording(tmp_path / "run")
    truth = [
        m for _, m in recording.messages([r for r in recording.observed() if r.topic == "simulation/truth"])
    ]
    assert isinstance(truth[-1], NavState)
    # the node steers on the raw USBL fixes (1 Hz, each up to 1.3 s old, no filter): it calls a
    # waypoint reached on a stale fix, with the vehicle up to a few decimetres on (measured 0.27
    # and 0.36 m)
    assert np.linalg.norm(truth[-1].position_m_world - LAST_WAYPOINT_M) < 0.5, truth[-1]
    # the node read odometry and simulated time, and commanded the vehicle by TwistStamped
    assert len(pilot.flight.odometry) > 100 and pilot.flight.commands > 100
    assert pilot.flight.clock_s[-1] > 5.0 and np.all(np.diff(pilot.flight.clock_s) >= 0)
    last = pilot.flight.odometry[-1]
    assert isinstance(last, Odometry) and last.child_frame_id == "base_link"
    # what the node published reached the simulation as onboard's keys
    received = summary["stations"]["simulation"]["received"]
    assert received["abyss/default/onboard/cmd/vehicle_velocity"] > 100
    # every bad sample dropped and counted on its topic, nothing crashed
    rejected = summary["stations"]["onboard"]["rejected"]
    for topic, message in UP_TOPICS.items():
        assert rejected.get(data_key(0, topic, message), 0) >= bad_each, (topic, rejected)
    assert all(s["exit_code"] == 0 for s in summary["stations"].values())
    log = (tmp_path / "run" / "onboard.log").read_text()
    for reason in (
        "does not decode",
        "type hash RIHS01_000",
        "no attachment",
        "type std_msgs::msg::dds_::String_",
    ):
        assert reason in log, reason
    # abyss check judges the node's rates and contents through the gateway
    assert "onboard/cmd/vehicle_velocity" in check.stdout, check.stdout + check.stderr
    lines = {line.split()[0]: line for line in check.stdout.splitlines() if line.strip().startswith("abyss/")}
    for key in ("cmd/vehicle_velocity", "cmd/arm_velocity", "telemetry"):
        assert lines[f"abyss/default/onboard/{key}"].rstrip().endswith("ok"), check.stdout
    assert "FAIL" in lines["abyss/default/onboard/cloud"]  # this node sends no clouds: the check says so
    assert static and {"arm_base", "ee"} <= {t.child_frame_id for t in static[-1].transforms}


def test_a_ros2_scene_model_maps_for_the_vessel(tmp_path: Path) -> None:
    """`--ros2 vessel`: the node is the vessel's scene model. It is handed onboard's clouds as
    PointCloud2 and publishes its map as an Octomap, which the vessel streams to shore in place
    of its own octree; maps it cannot adopt are refused with their reason."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    up = Up(
        tmp_path / "run",
        "--ros2",
        "vessel",
        "--set",
        f'ros2.listen=["{endpoint}"]',
        "--duration",
        "25",
        "--keep-running",
        "--viewer",
        "save",
        "--record",
        "none",
    )
    up.wait_up()
    node = RosNode(endpoint, name="team_mapper")
    stop, workers = threading.Event(), list[threading.Thread]()
    try:
        graph = gateway_graph(
            node,
            "abyss_vessel_gateway",
            {("MP", "/abyss/onboard/cloud"), ("MS", "/abyss/vessel/scene"), ("MP", "/clock")},
        )
        mine = {(t.kind, t.topic) for t in graph if t.node == "abyss_vessel_gateway"}
        assert ("MP", "/abyss/simulation/nav") not in mine  # the vessel is handed clouds only
        mapper = rosnode.Mapper(node, 0.1)  # vessel.octree_resolution_m
        workers.append(threading.Thread(target=mapper.run, args=(stop,), daemon=True))
        workers[-1].start()
        head = rosnode.Header(rosnode.Time(0, 0), "world")
        wrong = [
            rosnode.Octomap(head, True, "OcTree", 0.05, [0, 0]),  # another resolution
            rosnode.Octomap(head, False, "OcTree", 0.1, []),  # a full map, not binary
            rosnode.Octomap(head, True, "OcTree", 0.1, [3, 0, 0]),
        ]  # torn data
        for octomap in wrong:
            node.publish(mapper.scene, octomap)
        assert up.wait(90) == 0, up.output()
    finally:
        stop.set()
        for worker in workers:
            worker.join()
        node.close()
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert mapper.maps >= 5 and summary["scene"]["occupied_cells"] > 100, summary["scene"]
    snapshot = decode("scene", (tmp_path / "run" / SCENE_FILE).read_bytes(), SceneUpdate).message
    assert isinstance(snapshot, SceneUpdate)
    centres, sizes, occupied = iterate_leaves(read_binary(snapshot.octree, 0.1))[:3]
    shore, owners = leaves_to_cells(centres, sizes, 0.1)
    shore = shore[occupied[owners]]
    node_cells = set(cell_keys(mapper.map_points(), 0.1).tolist())
    assert len(shore) > 100 and set(shore.tolist()) <= node_cells  # the node's map, not the vessel's own
    rejected = summary["stations"]["vessel"]["rejected"]
    assert rejected.get(data_key(0, mapper.scene, rosnode.Octomap), 0) >= len(wrong), rejected
    log = (tmp_path / "run" / "vessel.log").read_text()
    assert "tree resolution 0.05" in log and "a full 'OcTree' map" in log and "not OctoMap's binary" in log


# the Zenoh releases that rmw_zenoh's releases bundle (its zenoh_cpp_vendor): 1.4.0 in Humble
# 0.1.2-0.1.7, Jazzy 0.2.5-0.2.8 and Kilted 0.6.2; 1.6.2 in Humble 0.1.8 and Jazzy 0.2.9
RMW_ZENOH_ZENOH = ("1.4.0", "1.6.2")


def zenoh_release(version: str) -> Path:
    """eclipse-zenoh `version` in a directory of its own for a PYTHONPATH, installed from PyPI
    once and cached (~/.cache/abyss)."""
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    target = cache / "abyss" / f"eclipse-zenoh-{version}"
    if not (target / "zenoh").is_dir():
        subprocess.run(
            [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(target),
             f"eclipse-zenoh=={version}"],
            check=True, timeout=300,
        )  # fmt: skip
    return target


def test_nodes_on_the_zenoh_releases_rmw_zenoh_bundles_fly_through_the_gateway(tmp_path: Path) -> None:
    """The contract node, run under zenoh-python 1.4.0 and then 1.6.2 (each in a process of its
    own, that release first on its path) for 8 s each against `abyss up --ros2 onboard` on
    abyss's own Zenoh: each finds the gateway in the ROS graph (liveliness), reads odometry and
    the clock, takes /tf_static from the gateway's cache as a late subscriber (transient local;
    1.6.2 only: zenoh-python has advanced subscribers from 1.5 on), and its velocity commands
    reach the simulation."""
    here = Path(__file__).parent
    releases = {version: zenoh_release(version) for version in RMW_ZENOH_ZENOH}
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    up = Up(tmp_path / "run", "--ros2", "onboard", "--set", f'ros2.listen=["{endpoint}"]',
            "--set", "mission.interventions=[]", "--duration", "45", "--viewer", "none",
            "--record", "none")  # fmt: skip
    up.wait_for(r"onboard is a ROS 2 gateway")
    up.wait_up()
    seen = {}
    for version, path in releases.items():
        done = subprocess.run(
            [sys.executable, str(here / "rosnode_versions.py"), endpoint, "8"],
            env={**os.environ, "PYTHONPATH": f"{path}{os.pathsep}{here}"},
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-3000:]
        seen[version] = json.loads(done.stdout.strip().splitlines()[-1])
    assert up.wait(120) == 3, up.output()  # incomplete: 16 s of flying do not finish the mission
    for version, s in seen.items():
        assert s["zenoh"] == version and str(releases[version]) in s["zenoh_file"], s
        assert s["gateway_endpoints"] >= 4, (version, s)
        assert s["tf_static"] is None or s["tf_static"] >= 1, (version, s)  # None: 1.4's python has no way
        assert s["odometry"] > 50 and s["clock"] > 20 and s["commands"] > 100, (version, s)
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    received = summary["stations"]["simulation"]["received"]["abyss/default/onboard/cmd/vehicle_velocity"]
    assert received > 0.8 * sum(s["commands"] for s in seen.values()), (received, seen)
    assert seen["1.6.2"]["tf_static"] >= 1  # the one release whose python can ask the cache
