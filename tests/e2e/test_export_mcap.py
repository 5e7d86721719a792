"""`abyss export mcap` on a whole recorded run, the export read back by readers abyss does not
write it with: rerun (`rerun mcap check`, `rerun mcap convert`, the .rrd's entities) and mcap with
mcap-ros2-support (topics, counts, QoS, and one message of each type against the recording)."""

from __future__ import annotations

import math
import subprocess
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

import cv2
import mujoco
import numpy as np
import pytest
import yaml
from conftest import abyss
from mcap.reader import make_reader
from mcap.writer import Writer
from mcap_ros2.decoder import DecoderFactory
from rerun.chunk import RrdReader

from abyss.common.geometry import rotation_of
from abyss.description.robot import robot_at
from abyss.description.site import site_at, world_model
from abyss.interface import keys
from abyss.interface.clouds import unpack_cloud
from abyss.interface.messages import Message, SceneUpdate, decode
from abyss.recording.reader import Recording, open_recording

ROBOT = robot_at("")  # the shipped robot package


pytestmark = pytest.mark.timeout(240)

RERUN = Path(sys.executable).parent / "rerun"
TF, TF_STATIC, CLOCK = "/tf", "/tf_static", "/clock"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
CAMERA_TOPICS = {"image/compressed": "sensor_msgs/msg/CompressedImage", "camera_info": CAMERA_INFO}
DIAGNOSTICS = "diagnostic_msgs/msg/DiagnosticArray"
POSE = "geometry_msgs/msg/PoseStamped"
TELEMETRY = {"diagnostics": DIAGNOSTICS, "ee_pose": POSE}
# abyss key -> its ROS 2 topics ('' : /abyss/<key> itself; a name under it; or an absolute one) and types,
# as the issue and the README ask for them
EXPECTED: dict[str, dict[str, str]] = {
    "simulation/nav": {"": "nav_msgs/msg/Odometry", TF: "tf2_msgs/msg/TFMessage"},
    "simulation/truth": {"": "nav_msgs/msg/Odometry"},
    "simulation/joints": {"": "sensor_msgs/msg/JointState", TF: "tf2_msgs/msg/TFMessage"},
    "simulation/camera/left": CAMERA_TOPICS,
    "simulation/camera/right": CAMERA_TOPICS,
    "simulation/camera/depth": {"image": "sensor_msgs/msg/Image", "camera_info": CAMERA_INFO},
    "simulation/status": {CLOCK: "rosgraph_msgs/msg/Clock", "": DIAGNOSTICS},
    "onboard/cmd/vehicle_velocity": {"": "geometry_msgs/msg/TwistStamped"},
    "onboard/cmd/arm_velocity": {"": "std_msgs/msg/Float64MultiArray"},
    "onboard/nav/estimate": {"": "nav_msgs/msg/Odometry"},
    "onboard/telemetry": TELEMETRY,
    "onboard/state": TELEMETRY,
    "onboard/cloud": {"": "sensor_msgs/msg/PointCloud2"},
    "onboard/image": CAMERA_TOPICS,
    "onboard/ack": {"": DIAGNOSTICS},
    "vessel/goal/waypoints": {"": "nav_msgs/msg/Path"},
    "vessel/goal/arm": {"": POSE},
    "vessel/goal/mode": {"": "std_msgs/msg/String"},
    "vessel/heartbeat": {"": DIAGNOSTICS},
    "vessel/telemetry": TELEMETRY,
    "vessel/scene": {"": "octomap_msgs/msg/Octomap"},
    "vessel/objects": {"": "visualization_msgs/msg/MarkerArray"},
    "vessel/image": CAMERA_TOPICS,
    "vessel/ack": {"": DIAGNOSTICS},
    "onshore/op/waypoints": {"": "nav_msgs/msg/Path"},
    "onshore/op/arm": {"": POSE},
    "onshore/op/mode": {"": "std_msgs/msg/String"},
    "onshore/heartbeat": {"": DIAGNOSTICS},
    "onshore/mission": {"": DIAGNOSTICS},
    "simulation/sonar": {"image/compressed": "sensor_msgs/msg/CompressedImage"},
    "onboard/sonar": {"image/compressed": "sensor_msgs/msg/CompressedImage"},
    "vessel/sonar": {"image/compressed": "sensor_msgs/msg/CompressedImage"},
    "vessel/perception": {"": DIAGNOSTICS},
}


def ros_topic(key: str, name: str) -> str:
    return name if name.startswith("/") else f"/abyss/{key}/{name}".rstrip("/")


def expected_of(key: str) -> dict[str, str]:
    return {"": DIAGNOSTICS} if "/linkstats/" in key else EXPECTED.get(key, {})


# -- the export, read once ----------------------------------------------------------------
@pytest.fixture(scope="module")
def recording(recorded_run: Path) -> Recording:
    return open_recording(recorded_run)


@pytest.fixture(scope="module")
def exported(recorded_run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`abyss export mcap` as a user types it, -o relative to the shell's directory."""
    here = tmp_path_factory.mktemp("export")
    done = abyss("export", "mcap", str(recorded_run), "-o", "run.mcap", cwd=here, timeout_s=180)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "abyss: wrote run.mcap" in done.stdout
    return here / "run.mcap"


@pytest.fixture(scope="module")
def decoded(exported: Path) -> dict[str, list[Any]]:
    """Every message of the export by topic, in log-time order, decoded by mcap-ros2-support."""
    topics: dict[str, list[Any]] = defaultdict(list)
    with exported.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, _, message in reader.iter_decoded_messages():
            topics[channel.topic].append(message)
    return topics


def recorded(recording: Recording, key: str) -> list[Message]:
    """The messages of one key as the export takes them (as published; the testbed's as observed)."""
    records = recording.observed() + recording.published()
    return [
        m
        for _, m in recording.messages(
            sorted((r for r in records if r.topic == key), key=lambda r: r.recorded_s)
        )
    ]


def seconds(stamp: Any) -> float:
    return float(stamp.sec + stamp.nanosec * 1e-9)


def xyz(v: Any) -> list[float]:
    return [v.x, v.y, v.z]


def wxyz(q: Any) -> list[float]:
    return [q.w, q.x, q.y, q.z]


def matrix(transform: Any) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = rotation_of(np.array(wxyz(transform.rotation))), xyz(transform.translation)
    return m


# -- the tests ----------------------------------------------------------------------------
def test_rerun_checks_the_export_and_converts_it_with_every_topic_an_entity(
    exported: Path, decoded: dict[str, list[Any]], tmp_path: Path
) -> None:
    check = subprocess.run(
        [str(RERUN), "mcap", "check", str(exported)], capture_output=True, text=True, timeout=120
    )
    assert check.returncode == 0, check.stdout + check.stderr
    rrd = tmp_path / "run.rrd"
    convert = subprocess.run(
        [str(RERUN), "mcap", "convert", str(exported), "-o", str(rrd)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert convert.returncode == 0, convert.stdout + convert.stderr
    rows: dict[str, int] = defaultdict(int)
    columns: dict[str, set[str]] = defaultdict(set)
    for chunk in RrdReader(rrd).stream().to_chunks():
        rows[chunk.entity_path] += chunk.num_rows
        columns[chunk.entity_path] |= set(chunk.to_record_batch().schema.names)
    for topic, messages in decoded.items():
        assert rows[topic] >= len(messages), (topic, rows[topic], len(messages))
    # what rerun understood, not only carried: clouds with colour, transforms, images, intrinsics, poses
    semantic = {
        "/abyss/onboard/cloud": {"Points3D:positions", "Points3D:rgb"},
        TF: {"Transform3D:translation", "Transform3D:child_frame"},
        TF_STATIC: {"Transform3D:translation", "Transform3D:parent_frame"},
        "/abyss/simulation/camera/left/image/compressed": {"EncodedImage:blob"},
        "/abyss/simulation/camera/depth/image": {"DepthImage:buffer"},
        "/abyss/simulation/camera/left/camera_info": {"Pinhole:image_from_camera"},
        "/abyss/onboard/telemetry/ee_pose": {"InstancePoses3D:translations"},
    }
    for entity, wanted in semantic.items():
        assert wanted <= columns[entity], (entity, sorted(columns[entity]))
    assert rows[TF] >= sum(len(m.transforms) for m in decoded[TF])  # a row per transform


def test_topics_types_qos_and_counts_are_the_recordings(exported: Path, recording: Recording) -> None:
    counts: dict[str, int] = defaultdict(int)
    types: dict[str, str] = {}
    for r in recording.published() + recording.observed():
        for name, type_name in expected_of(r.topic).items():
            counts[ros_topic(r.topic, name)] += 1
            types[ros_topic(r.topic, name)] = type_name
    counts[TF_STATIC], types[TF_STATIC] = 1, "tf2_msgs/msg/TFMessage"
    with exported.open("rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
    assert summary is not None and summary.statistics is not None
    channels = {c.topic: c for c in summary.channels.values()}
    assert sorted(channels) == sorted(counts)
    assert {c.topic: summary.statistics.channel_message_counts[c.id] for c in channels.values()} == counts
    for topic, channel in channels.items():
        schema = summary.schemas[channel.schema_id]
        assert (schema.name, schema.encoding, channel.message_encoding) == (types[topic], "ros2msg", "cdr")
        (qos,) = yaml.safe_load(channel.metadata["offered_qos_profiles"])
        spec = next((s for s in keys.KEYS if topic.startswith(f"/abyss/{s.station}/{s.topic}")), None)
        if topic == TF_STATIC:
            assert (qos["reliability"], qos["durability"]) == ("reliable", "transient_local")
        elif spec is not None:
            assert qos["reliability"] == spec.reliability.replace("-", "_"), topic
            assert qos["durability"] == "volatile"


def test_poses_joints_and_transforms_are_the_recorded_ones_in_ros_frames(
    recording: Recording, decoded: dict[str, list[Any]]
) -> None:
    for key in ("simulation/nav", "simulation/truth"):
        nav, odometry = recorded(recording, key), decoded[f"/abyss/{key}"]
        k = len(nav) // 2
        o = odometry[k]
        assert (o.header.frame_id, o.child_frame_id) == ("world", "base_link")  # ENU, FLU: as abyss's
        assert seconds(o.header.stamp) == pytest.approx(nav[k].sim_time_s, abs=1e-9)
        np.testing.assert_allclose(xyz(o.pose.pose.position), nav[k].position_m_world)
        np.testing.assert_allclose(wxyz(o.pose.pose.orientation), nav[k].orientation_wxyz_world)
        np.testing.assert_allclose(xyz(o.twist.twist.linear), nav[k].velocity_mps_body)
    nav = recorded(recording, "simulation/nav")
    vehicle = [t for m in decoded[TF] for t in m.transforms if t.child_frame_id == "base_link"]
    assert len(vehicle) == len(nav) and vehicle[5].header.frame_id == "world"
    np.testing.assert_allclose(xyz(vehicle[5].transform.translation), nav[5].position_m_world)

    joints, states = recorded(recording, "simulation/joints"), decoded["/abyss/simulation/joints"]
    k = len(joints) * 2 // 3
    assert list(states[k].name[:6]) == list(ROBOT.arm_joints)
    np.testing.assert_allclose(states[k].position[:6], joints[k].positions_rad)
    np.testing.assert_allclose(sum(states[k].position[6:]), joints[k].gripper_opening_m)

    # the arm's links, chained from base_link to the tool point, against MuJoCo's kinematics
    static = {t.child_frame_id: t for t in decoded[TF_STATIC][0].transforms}
    stamp = joints[k].sim_time_s
    moving = {
        t.child_frame_id: t
        for m in decoded[TF]
        for t in m.transforms
        if t.header.frame_id != "world" and seconds(t.header.stamp) == pytest.approx(stamp, abs=1e-9)
    }
    chain = [static["arm_base"], *(moving[f"arm_link{i}"] for i in range(1, 7)), static["ee"]]
    parents = ["base_link", "arm_base", *(f"arm_link{i}" for i in range(1, 7))]
    assert [t.header.frame_id for t in chain] == parents
    ee_in_vehicle = np.linalg.multi_dot([matrix(t.transform) for t in chain])
    model = world_model(ROBOT, site_at(""))
    data = mujoco.MjData(model)
    data.qpos[:7] = [0, 0, 0, 1, 0, 0, 0]  # the vehicle at the origin: the site's pose is in its frame
    for name, value in zip(ROBOT.arm_joints, joints[k].positions_rad, strict=True):
        data.qpos[model.joint(name).qposadr[0]] = value
    mujoco.mj_kinematics(model, data)
    site = model.site(ROBOT.end_effector_site).id
    np.testing.assert_allclose(ee_in_vehicle[:3, 3], data.site_xpos[site], atol=1e-9)
    np.testing.assert_allclose(ee_in_vehicle[:3, :3], data.site_xmat[site].reshape(3, 3), atol=1e-9)

    # each camera's optical frame on the vehicle: its mounting as the simulation sent it
    for camera in ROBOT.cameras:
        first = recorded(recording, f"simulation/{ROBOT.camera_topic(camera)}")[0]
        mount = static[f"{camera}_optical_frame"]
        assert mount.header.frame_id == "base_link"
        np.testing.assert_allclose(xyz(mount.transform.translation), first.pose_camera[:3])
        np.testing.assert_allclose(wxyz(mount.transform.rotation), first.pose_camera[3:])
    # and the sonar's frame, which its images' headers name, from its mounting likewise
    ping = recorded(recording, "simulation/sonar")[0]
    mount = static[ping.sonar]
    assert mount.header.frame_id == "base_link" and ping.sonar == ROBOT.sonar_site
    np.testing.assert_allclose(xyz(mount.transform.translation), ping.pose_sonar[:3])
    np.testing.assert_allclose(wxyz(mount.transform.rotation), ping.pose_sonar[3:])

    ref = recorded(recording, "onboard/cmd/vehicle_velocity")
    twists = decoded["/abyss/onboard/cmd/vehicle_velocity"]
    assert twists[3].header.frame_id == "base_link"
    np.testing.assert_allclose(xyz(twists[3].twist.linear), ref[3].linear_mps_body)
    assert twists[3].twist.angular.z == ref[3].yaw_rate_radps


def test_stamps_without_simulated_time_are_their_senders_in_simulated_time(
    recording: Recording, decoded: dict[str, list[Any]]
) -> None:
    navigation = [r for r in recording.published(("simulation",)) if r.topic == "simulation/nav"]
    sent = sorted((r.sent_s, m.sim_time_s) for r, m in recording.messages(navigation))
    wall_s, sim_s = np.array(sent).T
    refs = sorted(
        r.sent_s for r in recording.published(("onboard",)) if r.topic == "onboard/cmd/vehicle_velocity"
    )
    stamps = [seconds(t.header.stamp) for t in decoded["/abyss/onboard/cmd/vehicle_velocity"]]
    checked = 0
    for sent_s, stamp_s in zip(refs, stamps, strict=True):
        i = int(np.searchsorted(wall_s, sent_s))
        if 0 < i < len(wall_s):  # between two navigation messages: between their simulated times
            assert sim_s[i - 1] - 1e-9 <= stamp_s <= sim_s[i] + 1e-9
            checked += 1
    assert checked > 0.9 * len(refs)
    clock = [seconds(c.clock) for c in decoded[CLOCK]]
    assert clock == pytest.approx([m.sim_time_s for m in recorded(recording, "simulation/status")], abs=1e-9)


def test_images_clouds_scene_paths_and_diagnostics_hold_the_recorded_values(
    recording: Recording, decoded: dict[str, list[Any]], recorded_run: Path
) -> None:
    left, jpeg = (
        recorded(recording, "simulation/camera/left"),
        decoded["/abyss/simulation/camera/left/image/compressed"][2],
    )
    assert (jpeg.format, jpeg.header.frame_id) == ("jpeg", "cam_left_optical_frame")
    pixels = cv2.imdecode(np.frombuffer(bytes(jpeg.data), np.uint8), cv2.IMREAD_COLOR)
    assert pixels.shape[:2] == (left[2].height_px, left[2].width_px)
    info = decoded["/abyss/simulation/camera/left/camera_info"][2]
    assert (info.width, info.height) == (left[2].width_px, left[2].height_px)
    frame = left[2]
    assert list(info.k) == pytest.approx([frame.fx_px, 0, frame.cx_px, 0, frame.fy_px, frame.cy_px, 0, 0, 1])
    depth, raw = (
        recorded(recording, "simulation/camera/depth")[1],
        decoded["/abyss/simulation/camera/depth/image"][1],
    )
    assert (raw.encoding, raw.width, raw.height, raw.step) == (
        "16UC1",
        depth.width_px,
        depth.height_px,
        2 * depth.width_px,
    )
    png_mm = cv2.imdecode(np.frombuffer(depth.data, np.uint8), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(np.frombuffer(bytes(raw.data), "<u2").reshape(png_mm.shape), png_mm)

    clouds, exported_clouds = recorded(recording, "onboard/cloud"), decoded["/abyss/onboard/cloud"]
    k = len(clouds) // 2
    cloud = exported_clouds[k]
    assert (cloud.header.frame_id, cloud.width, cloud.height) == ("world", clouds[k].count, 1)
    assert [(f.name, f.offset, f.datatype) for f in cloud.fields] == [
        ("x", 0, 7),
        ("y", 4, 7),
        ("z", 8, 7),
        ("rgb", 12, 7),
    ]
    points = np.frombuffer(bytes(cloud.data), [("xyz", "<f4", 3), ("rgb", "<u4")])
    points_m, colors = unpack_cloud(clouds[k])
    np.testing.assert_allclose(points["xyz"], points_m, atol=1e-5)
    rgb = points["rgb"]
    np.testing.assert_array_equal(np.column_stack((rgb >> 16 & 255, rgb >> 8 & 255, rgb & 255)), colors)

    # the scene: each message the whole map; the one after the update shore saved last is shore's map
    saved = decode("scene.msgpack", (recorded_run / "scene.msgpack").read_bytes(), SceneUpdate).message
    updates, maps = recorded(recording, "vessel/scene"), decoded["/abyss/vessel/scene"]
    at = next(i for i, u in enumerate(updates) if u.scene_seq == saved.scene_seq)
    octomap = maps[at]
    assert (octomap.binary, octomap.id, octomap.resolution) == (True, "OcTree", saved.resolution_m)
    assert np.array(octomap.data, np.int8).tobytes() == saved.octree.split(b"\ndata\n", 1)[1]

    for key in ("vessel/goal/waypoints", "onshore/op/waypoints"):
        for waypoints, path in zip(recorded(recording, key), decoded[f"/abyss/{key}"], strict=True):
            assert path.header.frame_id == "world" and len(path.poses) == len(waypoints.waypoints)
            for pose, row in zip(path.poses, waypoints.waypoints, strict=True):
                np.testing.assert_allclose(xyz(pose.pose.position), row[:3])
                q = np.array(wxyz(pose.pose.orientation))
                assert math.atan2(2 * q[0] * q[3], 1 - 2 * q[3] ** 2) == pytest.approx(row[3])
    goal, goal_pose = recorded(recording, "vessel/goal/arm")[0], decoded["/abyss/vessel/goal/arm"][0]
    np.testing.assert_allclose(xyz(goal_pose.pose.position), goal.position_m_world)
    np.testing.assert_allclose(wxyz(goal_pose.pose.orientation), goal.orientation_wxyz_world)
    for key in ("vessel/goal/mode", "onshore/op/mode"):
        modes = [m.mode for m in recorded(recording, key)]
        assert modes and [m.data for m in decoded[f"/abyss/{key}"]] == modes
    commands = recorded(recording, "onboard/cmd/arm_velocity")
    for ref, command in zip(commands, decoded["/abyss/onboard/cmd/arm_velocity"], strict=True):
        np.testing.assert_allclose(command.data, [*ref.joint_velocities_radps, ref.gripper_velocity_mps])

    for key in sorted({r.topic for r in recording.observed() if "/linkstats/" in r.topic}):
        stats, array = recorded(recording, key)[-1], decoded[f"/abyss/{key}"][-1]
        values = {v.key: v.value for v in array.status[0].values}
        assert stats.hop in array.status[0].name and values["profile"] == stats.profile
        for name, value in stats.stats.items():
            assert float(values[name]) == pytest.approx(value, rel=1e-5), (key, name)
    telemetry = recorded(recording, "onboard/telemetry")
    for t, array in zip(telemetry, decoded["/abyss/onboard/telemetry/diagnostics"], strict=True):
        status = array.status[0]
        values = {v.key: v.value for v in status.values}
        assert (values["mode"], values["failsafe"]) == (t.mode, t.failsafe)
        assert status.level == (1 if t.failsafe else 0)  # WARN while the failsafe holds
    objects, markers = recorded(recording, "vessel/objects")[-1], decoded["/abyss/vessel/objects"][-1]
    assert sorted(m.ns for m in markers.markers[1:]) == sorted(objects.names)


def test_bad_run_directories_fail_with_the_path_and_the_fix(tmp_path: Path) -> None:
    empty = abyss("export", "mcap", str(tmp_path))
    assert empty.returncode == 2 and f"abyss: {tmp_path}/record: no recording" in empty.stderr
    assert "--record all" in empty.stderr and not (tmp_path / "run.mcap").exists()
    (tmp_path / "record").mkdir()
    (tmp_path / "record" / "onboard.mcap").write_bytes(b"not an mcap file at all")
    garbage = abyss("export", "mcap", str(tmp_path))
    assert garbage.returncode == 2 and "onboard.mcap: not an abyss recording" in garbage.stderr
    with (tmp_path / "record" / "onboard.mcap").open("wb") as f:  # a recording of another format's version
        writer = Writer(f)
        writer.start(profile="abyss")
        writer.add_metadata(
            "abyss", {"format_version": "0", "station": "onboard", "system": "x", "level": "all"}
        )
        writer.finish()
    older = abyss("export", "mcap", str(tmp_path))
    assert older.returncode == 2 and "recording format version 0" in older.stderr
    assert "record the run again" in older.stderr and not list(tmp_path.glob("*.mcap*"))
