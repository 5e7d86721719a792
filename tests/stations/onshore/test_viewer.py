"""The Rerun viewer: messages logged through it land in a recording, read back with Rerun's
own reader, at the entity paths and timelines the operator's layout expects; the arm drawn
from the logged transforms is where MuJoCo puts it."""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

import mujoco
import numpy as np
import pyarrow as pa
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from abyss.common.geometry import rotation_of
from abyss.common.images import encode_jpeg
from abyss.common.messages import ArmGoal, Image, LinkStats, RecognisedObjects, Telemetry, Waypoints
from abyss.common.models import ARM_JOINTS, END_EFFECTOR_SITE, ROBOT_FILE
from abyss.stations.onshore.viewer import Viewer

STAMP_S = 1.7e9  # a wall-clock stamp [s since the epoch]
YAW_RAD = 0.6
ARM_RAD = np.array([0.4, 0.9, -1.6, 0.3, 0.7, -0.5])
Recording = tuple[dict[str, list[pa.RecordBatch]], Path]  # batches by entity path, the file
HAND = "world/vehicle/arm_base/arm_link1/arm_link2/arm_link3/arm_link4/arm_link5/arm_link6"


def telemetry(i: int, failsafe: str = "") -> Telemetry:
    return Telemetry(
        position_m_world=np.array([1.0 + i, -2.0, -6.0]), yaw_rad=YAW_RAD, mode="moving", command_id=1,
        waypoint_index=0, waypoints_total=2, position_error_m_world=np.array([0.3, 0.4, 0.0]),
        heading_error_rad=-0.1, arm_mode="moving", arm_command_id=1,
        ee_position_error_m_world=np.array([0.0, 0.003, 0.004]), ee_orientation_error_rad=0.05,
        ee_position_m_world=np.array([2.0, -2.0, -7.0]), ee_orientation_wxyz_world=np.array([1.0, 0, 0, 0]),
        arm_positions_rad=ARM_RAD, failsafe=failsafe, failsafe_events=int(bool(failsafe)), sim_time_s=0.1 * i,
    )  # fmt: skip


def link_stats(bytes_delivered: float) -> LinkStats:
    stats = {"bytes_delivered": bytes_delivered, "delay_p50_ms": 250.0, "delay_p95_ms": 400.0,
             "messages_lost": 2.0, "queue_drops": 1.0}  # fmt: skip
    return LinkStats(hop="satellite", direction="vessel->onshore", profile="satellite", stats=stats)


def read(path: Path) -> dict[str, list[pa.RecordBatch]]:
    """The recording's chunks as record batches, by entity path (no leading slash)."""
    batches = defaultdict(list)
    for chunk in RrdReader(path).stream().to_chunks():
        batches[chunk.entity_path.lstrip("/")].append(chunk.to_record_batch())
    return batches


def values(batches: list[pa.RecordBatch], column: str) -> list:
    """One column's values, in the order logged (the batches' rows sorted by stamp)."""
    rows = [
        (stamp, value)
        for b in batches
        if column in b.schema.names
        for stamp, value in zip(b.column("stamp").cast(pa.int64()).to_pylist(), b.column(column).to_pylist(),
                                strict=True)
    ]  # fmt: skip
    return [value for _, value in sorted(rows, key=lambda row: row[0])]


def scalars(batches: list[pa.RecordBatch]) -> list[float]:
    return [value for (value,) in values(batches, "Scalars:scalars")]


@pytest.fixture
def recording(tmp_path: Path) -> Recording:
    """Each kind of message, a few times, logged through a Viewer into a file, and read back."""
    path = tmp_path / "view.rrd"
    stream = rr.RecordingStream("abyss-test", recording_id="test-viewer")
    stream.save(path)
    viewer = Viewer(stream)
    for i in range(3):
        viewer.telemetry(telemetry(i, failsafe="shore lost" if i == 1 else ""), STAMP_S + i)
    viewer.waypoints(
        Waypoints(command_id=1, waypoints=np.array([[0.0, 0, -6, 0], [4.0, 0, -6, 0.5]])), STAMP_S + 3
    )
    goal = ArmGoal(command_id=1, position_m_world=np.array([5.0, 0, -7]), orientation_wxyz_world=np.eye(4)[0])
    viewer.arm_goal(goal, STAMP_S + 3)
    centres = np.array([[5.0, 0.0, -7.0], [5.0, 0.1, -7.0]])
    colors = np.array([[200, 100, 50], [50, 100, 200]], np.uint8)
    viewer.scene(centres, colors, 0.1, STAMP_S + 4, sim_time_s=0.4)
    viewer.scene_update(centres[:1], colors[:1], STAMP_S + 4, sim_time_s=0.4)
    viewer.objects(RecognisedObjects(names=("panel",), poses_world=np.array([[5.0, 0, -7, 1, 0, 0, 0]]),
                                     half_sizes_m=np.array([[0.05, 0.5, 0.4]]), confidences=np.array([0.87]),
                                     method="texture", sim_time_s=0.4), STAMP_S + 4)  # fmt: skip
    jpeg = encode_jpeg(np.full((24, 32, 3), 90, np.uint8), 80)
    pose_camera = np.array([1.0, 0, -6, 1, 0, 0, 0])
    viewer.image(Image(camera="cam_left", encoding="jpeg", pose_frame="world", width_px=32, height_px=24,
                       fx_px=30.0, fy_px=30.0, cx_px=16.0, cy_px=12.0, pose_camera=pose_camera, data=jpeg,
                       sim_time_s=0.5), STAMP_S + 5)  # fmt: skip
    viewer.link_stats(link_stats(0.0), STAMP_S + 5)
    viewer.link_stats(link_stats(250_000.0), STAMP_S + 7)  # 2 Mbit in 2 s
    stream.flush()
    stream.disconnect()
    return read(path), path


def test_every_view_lands_at_its_entity_path(recording: Recording) -> None:
    batches, path = recording
    expected = ["world", "world/vehicle", "world/vehicle/hull", HAND, f"{HAND}/finger_left", "world/ee",
                "world/path", "world/mission/waypoints", "world/mission/arm_goal", "world/scene/octree",
                "world/scene/latest_update", "world/objects/panel", "world/camera", "world/camera/image",
                "errors/vehicle/position_m", "errors/vehicle/heading_deg", "errors/arm/position_mm",
                "errors/arm/orientation_deg", "status/failsafe", "status/mode",
                "links/satellite/vessel_to_onshore/delay_p50_ms", "links/satellite/vessel_to_onshore/lost",
                "links/satellite/vessel_to_onshore/throughput_kbps"]  # fmt: skip
    missing = [p for p in expected if sum(b.num_rows for b in batches.get(p, [])) == 0]
    assert not missing, f"no rows at {missing}; logged: {sorted(batches)}"
    assert RrdReader(path).blueprints(), "no blueprint sent"
    assert all("stamp" in b.schema.names for b in batches["world/vehicle"])


def test_values_read_back(recording: Recording) -> None:
    batches, _ = recording
    assert scalars(batches["errors/vehicle/position_m"]) == pytest.approx([0.5] * 3)
    assert scalars(batches["errors/arm/position_mm"]) == pytest.approx([5.0] * 3)
    assert scalars(batches["errors/vehicle/heading_deg"]) == pytest.approx([5.7296] * 3, abs=1e-4)
    throughput = scalars(batches["links/satellite/vessel_to_onshore/throughput_kbps"])
    assert throughput == pytest.approx([1000.0])  # only from the second report on
    assert values(batches["status/failsafe"], "TextLog:text") == [["shore lost"], ["cleared"]]
    path_m_world = np.array(values(batches["world/path"], "LineStrips3D:strips")[-1][0])
    assert path_m_world == pytest.approx(np.array([[1.0, -2, -6], [2.0, -2, -6], [3.0, -2, -6]]))
    assert values(batches["world/objects/panel"], "Boxes3D:labels") == [["panel (confidence 0.87)"]]


def test_messages_without_sim_time_are_not_logged_at_a_stale_one(recording: Recording) -> None:
    batches, _ = recording
    assert all("sim_time" in b.schema.names for b in batches["world/vehicle"])
    for path in (
        "world/mission/waypoints",
        "world/mission/arm_goal",
        "links/satellite/vessel_to_onshore/lost",
    ):
        assert all("sim_time" not in b.schema.names for b in batches[path]), path


def test_logged_arm_transforms_put_the_end_effector_where_mujoco_does(recording: Recording) -> None:
    batches, _ = recording
    rotation, position = np.eye(3), np.zeros(3)  # the hand's frame in the world, composed from the root
    for depth in range(2, HAND.count("/") + 2):
        entity = "/".join(HAND.split("/")[:depth])
        translation = values(batches[entity], "Transform3D:translation")[-1][0]
        x, y, z, w = values(batches[entity], "Transform3D:quaternion")[-1][0]
        position = position + rotation @ translation
        rotation = rotation @ rotation_of(np.array([w, x, y, z]))

    model = mujoco.MjModel.from_xml_path(str(ROBOT_FILE))
    data = mujoco.MjData(model)
    last_m_world = telemetry(2).position_m_world  # where the last telemetry put the vehicle
    data.qpos[:7] = np.r_[last_m_world, math.cos(YAW_RAD / 2), 0.0, 0.0, math.sin(YAW_RAD / 2)]
    data.qpos[[model.joint(name).qposadr[0] for name in ARM_JOINTS]] = ARM_RAD
    mujoco.mj_kinematics(model, data)
    site = model.site(END_EFFECTOR_SITE)
    assert position + rotation @ site.pos == pytest.approx(data.site(END_EFFECTOR_SITE).xpos, abs=1e-4)
    assert rotation == pytest.approx(data.xmat[site.bodyid[0]].reshape(3, 3), abs=1e-4)
