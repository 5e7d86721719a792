"""The Rerun viewer: messages logged through it land in a recording, read back with Rerun's
own reader, at the entity paths and timelines the operator's layout expects; each plot of the
layout is in one unit, named in its title and in the paths it shows; the arm drawn from the
logged transforms is where MuJoCo puts it."""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

import mujoco
import numpy as np
import pyarrow as pa
import pytest
import rerun as rr
import rerun.blueprint as rrb
from rerun.chunk import RrdReader

from abyss.common.geometry import rotation_of
from abyss.description.robot import robot_at
from abyss.interface import keys
from abyss.interface.images import encode_jpeg
from abyss.interface.messages import (
    ArmGoal,
    Image,
    LinkStats,
    PerceptionStatus,
    RecognisedObjects,
    SonarImage,
    Telemetry,
    Waypoints,
)
from abyss.interface.sonar_frames import encode_polar
from abyss.stations.onshore.layout import blueprint
from abyss.stations.onshore.viewer import Viewer

ROBOT = robot_at("")  # the shipped robot package


STAMP_S = 1.7e9  # a wall-clock stamp [s since the epoch]
YAW_RAD = 0.6
ARM_RAD = np.array([0.4, 0.9, -1.6, 0.3, 0.7, -0.5])
Recording = tuple[dict[str, list[pa.RecordBatch]], Path]  # batches by entity path, the file
HAND = "world/vehicle/arm_base/arm_link1/arm_link2/arm_link3/arm_link4/arm_link5/arm_link6"
DELAY_MS = "links/satellite/delay_ms/vessel_to_onshore"  # the satellite hop's downlink's
COUNT = "links/satellite/count/vessel_to_onshore"
# a plot's unit, as its title gives it -> how the paths of its series say it
UNIT_IN_PATH = {"m": "_m", "mm": "_mm", "deg": "_deg", "ms": "_ms", "kbit/s": "_kbps", "count": "count",
                "N": "_n", "points/s": "_per_s", "0-1": "confidence"}  # fmt: skip
# the intervention, a call each: target, phase, reason, turned [deg], goal [deg], opening [mm], force [N]
INTERVENTION = [
    ("valve_1", "approach", "", 0.0, 90.0, 80.0, 0.0),
    ("valve_1", "approach", "", 0.0, 90.0, 60.0, 0.0),  # the same phase: no second line
    ("valve_1", "turning", "", 30.0, 90.0, 40.0, 12.0),
    ("valve_1", "failed", "slipped off the handle", 35.0, 90.0, 80.0, 0.5),
]


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
             "delay_p99_ms": 700.0, "messages_lost": 2.0, "queue_drops": 1.0, "retransmissions": 4.0,
             "messages_offered": 90.0}  # fmt: skip
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


def views(part: rrb.Container | rrb.View) -> list[rrb.View]:
    """The views in a blueprint's container, depth first."""
    if isinstance(part, rrb.View):
        return [part]
    return [view for content in part.contents for view in views(content)]


def plots() -> dict[str, str]:
    """The layout's time series views: name -> origin."""
    layout = views(blueprint().root_container)
    return {str(v.name): str(v.origin) for v in layout if v.class_identifier == "TimeSeries"}


@pytest.fixture
def recording(tmp_path: Path) -> Recording:
    """Each kind of message, a few times, logged through a Viewer into a file, and read back."""
    path = tmp_path / "view.rrd"
    stream = rr.RecordingStream("abyss-test", recording_id="test-viewer")
    stream.save(path)
    viewer = Viewer(stream, ROBOT)
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
    polar = np.zeros((20, 9), np.uint8)
    polar[10, 4] = 255  # an echo at 5 m dead ahead
    sonar = SonarImage(sonar="sonar", encoding="png8", pose_frame="world", beams=9, bins=20, range_max_m=10.0,
                       horizontal_fov_rad=1.0, vertical_aperture_rad=0.3, dynamic_range_db=40.0,
                       pose_sonar=np.array([1.0, 0, -6, 1, 0, 0, 0]), data=encode_polar(polar, "png8"),
                       sim_time_s=0.5)  # fmt: skip
    viewer.sonar(sonar, STAMP_S + 5)
    for i, source in enumerate(("cameras", "sonar")):
        rates = {"depth": 100.0 * (1 - i), "stereo": 0.0, "sonar": 40.0}
        viewer.perception(PerceptionStatus(points_per_s=rates, window_s=10.0, scene_source=source,
                                           recognition_confidence=0.5 - 0.2 * i, recognition_method="shape",
                                           sim_time_s=0.5 + i), STAMP_S + 5 + i)  # fmt: skip
    viewer.link_stats(link_stats(0.0), STAMP_S + 5)
    viewer.link_stats(link_stats(250_000.0), STAMP_S + 7)  # 2 Mbit in 2 s
    for i, (target, phase, reason, turned_deg, goal_deg, opening_mm, force_n) in enumerate(INTERVENTION):
        viewer.intervention(STAMP_S + 8 + i, 1.0 + i, target, phase, reason, turned_deg, goal_deg, opening_mm,
                            force_n)  # fmt: skip
    stream.flush()
    stream.disconnect()
    return read(path), path


def test_every_view_lands_at_its_entity_path(recording: Recording) -> None:
    batches, path = recording
    expected = ["world", "world/vehicle", "world/vehicle/hull", HAND, f"{HAND}/finger_left", "world/ee",
                "world/path", "world/mission/waypoints", "world/mission/arm_goal", "world/scene/octree",
                "world/scene/latest_update", "world/objects/panel", "world/objects/panel/label",
                "world/camera", "world/camera/image", "errors/vehicle_position_m/distance",
                "errors/heading_deg/heading", "errors/tool_position_mm/distance",
                "errors/tool_orientation_deg/angle", "status/failsafe", "status/mode", f"{DELAY_MS}/p50",
                f"{DELAY_MS}/p99", f"{COUNT}/messages_lost", f"{COUNT}/retransmissions",
                "links/satellite/throughput_kbps/vessel_to_onshore", "intervention/phase",
                "intervention/angle_deg/valve_1/turned", "intervention/angle_deg/valve_1/goal",
                "intervention/grasp/opening_mm", "intervention/grasp/force_n", "sonar/fan", "world/sonar",
                "perception/points_per_s/sonar", "perception/recognition_confidence",
                "status/perception"]  # fmt: skip
    missing = [p for p in expected if sum(b.num_rows for b in batches.get(p, [])) == 0]
    assert not missing, f"no rows at {missing}; logged: {sorted(batches)}"
    assert RrdReader(path).blueprints(), "no blueprint sent"
    assert all("stamp" in b.schema.names for b in batches["world/vehicle"])


def test_values_read_back(recording: Recording) -> None:
    batches, _ = recording
    assert scalars(batches["errors/vehicle_position_m/distance"]) == pytest.approx([0.5] * 3)
    assert scalars(batches["errors/tool_position_mm/distance"]) == pytest.approx([5.0] * 3)
    assert scalars(batches["errors/heading_deg/heading"]) == pytest.approx([5.7296] * 3, abs=1e-4)
    assert scalars(batches["errors/tool_orientation_deg/angle"]) == pytest.approx([2.8648] * 3, abs=1e-4)
    throughput = scalars(batches["links/satellite/throughput_kbps/vessel_to_onshore"])
    assert throughput == pytest.approx([1000.0])  # only from the second report on
    assert scalars(batches[f"{DELAY_MS}/p99"]) == pytest.approx([700.0] * 2)
    assert scalars(batches[f"{COUNT}/queue_drops"]) == pytest.approx([1.0] * 2)
    assert scalars(batches[f"{COUNT}/retransmissions"]) == pytest.approx([4.0] * 2)
    assert values(batches["status/failsafe"], "TextLog:text") == [["shore lost"], ["cleared"]]
    path_m_world = np.array(values(batches["world/path"], "LineStrips3D:strips")[-1][0])
    assert path_m_world == pytest.approx(np.array([[1.0, -2, -6], [2.0, -2, -6], [3.0, -2, -6]]))


def test_the_sonar_and_what_perception_works_with(recording: Recording) -> None:
    batches, _ = recording
    fan_shape = values(batches["sonar/fan"], "Image:format")
    assert fan_shape, "no fan"
    echoes = np.array(values(batches["world/sonar"], "Points3D:positions")[0])
    assert np.linalg.norm(echoes - [1.0, 0, -6], axis=1) == pytest.approx(np.full(len(echoes), 5.25))
    assert scalars(batches["perception/points_per_s/depth"]) == pytest.approx([100.0, 0.0])
    assert scalars(batches["perception/recognition_confidence"]) == pytest.approx([0.5, 0.3])
    assert values(batches["status/perception"], "TextLog:text") == [
        ["the scene is mapped from cameras"],
        ["the scene is mapped from sonar"],
    ]
    assert values(batches["status/perception"], "TextLog:level") == [["INFO"], ["WARN"]]


def test_objects_are_labelled_by_name_above_their_box(recording: Recording) -> None:
    batches, _ = recording
    assert values(batches["world/objects/panel/label"], "Points3D:labels") == [["panel"]]
    top_m_world = values(batches["world/objects/panel/label"], "Points3D:positions")[0][0]
    assert top_m_world == pytest.approx([5.0, 0.0, -6.6])  # the panel's top edge: its centre + 0.4 m
    assert values(batches["world/objects/panel"], "confidence") == [[pytest.approx(0.87)]]
    assert "Boxes3D:labels" not in {name for b in batches["world/objects/panel"] for name in b.schema.names}


def test_the_intervention_logs_its_phase_changes_angles_and_grasp(recording: Recording) -> None:
    batches, _ = recording
    phase = batches["intervention/phase"]
    assert values(phase, "TextLog:text") == [["valve_1: approach"], ["valve_1: turning"],
                                             ["valve_1: failed (slipped off the handle)"]]  # fmt: skip
    assert values(phase, "TextLog:level") == [["INFO"], ["INFO"], ["WARN"]]
    _, _, _, turned_deg, goal_deg, opening_mm, force_n = zip(*INTERVENTION, strict=True)
    assert scalars(batches["intervention/angle_deg/valve_1/turned"]) == pytest.approx(turned_deg)
    assert scalars(batches["intervention/angle_deg/valve_1/goal"]) == pytest.approx(goal_deg)
    assert scalars(batches["intervention/grasp/opening_mm"]) == pytest.approx(opening_mm)
    assert scalars(batches["intervention/grasp/force_n"]) == pytest.approx(force_n)
    assert all("sim_time" in b.schema.names for b in phase)


def test_each_plot_has_one_unit_named_in_its_title_and_its_paths() -> None:
    link_plots = ("throughput [kbit/s]", "delay [ms]", "losses and retransmissions [count]")
    assert sorted(plots()) == sorted([
        "Vehicle position error [m]", "Heading error [deg]", "Tool position error [mm]",
        "Tool orientation error [deg]", "Valve and lever angles [deg]", "Grasp: gripper opening [mm]",
        "Grasp: grip force [N]", "Points per source [points/s]", "Panel recognition confidence [0-1]",
        *(f"{hop} {plot}" for hop in keys.HOPS for plot in link_plots)])  # fmt: skip
    for name, origin in plots().items():
        unit = name.rpartition("[")[2].rstrip("]")
        assert origin.endswith(UNIT_IN_PATH[unit]), (name, origin)
    by_name = {view.name: view for view in views(blueprint().root_container)}
    assert (by_name["Intervention phase"].class_identifier, by_name["Intervention phase"].origin) == (
        "TextLog", "intervention/phase")  # fmt: skip
    assert by_name["World"].class_identifier == "3D"


def test_every_scalar_logged_is_in_exactly_one_plot(recording: Recording) -> None:
    batches, _ = recording
    origins = plots().values()
    logged = [path for path, b in batches.items() if any("Scalars:scalars" in x.schema.names for x in b)]
    plots_of = {path: [o for o in origins if f"{path}/".startswith(f"{o}/")] for path in logged}
    # 4 errors, 6 of the satellite's downlink, 4 of the intervention, 3 sources and the confidence
    assert len(logged) == 18, logged
    assert all(len(plots) == 1 for plots in plots_of.values()), plots_of
    empty = set(origins) - {plot for plots in plots_of.values() for plot in plots}
    groups = ("throughput_kbps", "delay_ms", "count")
    assert empty == {f"links/{hop}/{group}" for hop in ("rov", "tether") for group in groups}  # no reports


def test_messages_without_sim_time_are_not_logged_at_a_stale_one(recording: Recording) -> None:
    batches, _ = recording
    assert all("sim_time" in b.schema.names for b in batches["world/vehicle"])
    for path in (
        "world/mission/waypoints",
        "world/mission/arm_goal",
        f"{COUNT}/messages_lost",
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

    model = mujoco.MjModel.from_xml_path(str(ROBOT.model_file))
    data = mujoco.MjData(model)
    last_m_world = telemetry(2).position_m_world  # where the last telemetry put the vehicle
    data.qpos[:7] = np.r_[last_m_world, math.cos(YAW_RAD / 2), 0.0, 0.0, math.sin(YAW_RAD / 2)]
    data.qpos[[model.joint(name).qposadr[0] for name in ROBOT.arm_joints]] = ARM_RAD
    mujoco.mj_kinematics(model, data)
    site = model.site(ROBOT.end_effector_site)
    assert position + rotation @ site.pos == pytest.approx(data.site(ROBOT.end_effector_site).xpos, abs=1e-4)
    assert rotation == pytest.approx(data.xmat[site.bodyid[0]].reshape(3, 3), abs=1e-4)
