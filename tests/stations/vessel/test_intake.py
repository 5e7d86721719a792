"""The vessel's intake as a core (stations.vessel.intake.Intake), without Zenoh: the cameras'
clouds feed the scene model, the sonar's echoes take over while the cameras bring no point and
hand back when they do, recognition runs every `recognition_period_s`, and perception's status
counts the points of each source. Real clouds (pack_cloud), real sonar frames, a real model."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from abyss.common.geometry import rotation_about, rotation_of
from abyss.config.hybrid import HybridConfig
from abyss.config.stations import VesselConfig
from abyss.description.site import site_at
from abyss.interface.clouds import pack_cloud, unpack_cloud
from abyss.interface.messages import Image, PerceptionStatus, PointCloud, RecognisedObjects, SonarImage
from abyss.interface.sonar_frames import echo_arcs, encode_polar
from abyss.scene.model import SceneModel
from abyss.scene.octree import cell_keys
from abyss.stations.vessel.intake import Intake, IntakeInputs
from abyss.stations.vessel.recognition import PanelTracker, expected_pose, model_points, rotation_error_rad

panel = site_at("").panel  # the shipped site's

RESOLUTION_M = 0.1


def config(**fields: float) -> VesselConfig:
    defaults = {
        "octree_resolution_m": RESOLUTION_M,
        "scene_track_period_s": 0.0,  # each insertion queues its changes at once
        "sonar_fallback_s": 5.0,
        "perception_period_s": 2.0,
        "perception_window_s": 10.0,
        "recognition_period_s": 2.0,
    }
    return VesselConfig(**{**defaults, **fields})  # type: ignore[arg-type]


def seabed(source: str, centre_x_m: float, sim_time_s: float, n: int = 2000) -> PointCloud:
    """A patch of seabed 3 m below its camera, around x = `centre_x_m` [m, world]."""
    rng = np.random.default_rng(int(centre_x_m * 10) + n)
    xy = rng.uniform(-1.0, 1.0, (n, 2)) + np.array([centre_x_m, 0.0])
    points = np.c_[xy, rng.normal(0, 0.02, n)]
    colors = rng.integers(0, 255, (n, 3), dtype=np.uint8)
    return pack_cloud(source, points, colors, np.array([centre_x_m, 0.0, 3.0]), 0.001, sim_time_s)


def empty(source: str, sim_time_s: float) -> PointCloud:
    """A cloud with no point (murk, a blacked-out camera)."""
    return pack_cloud(source, np.zeros((0, 3)), np.zeros((0, 3), np.uint8), np.zeros(3), 0.001, sim_time_s)


def ping(x_m: float, sim_time_s: float, beams: int = 9, bins: int = 20) -> SonarImage:
    """A sonar at x = `x_m` [m, world] looking along x, each beam echoing at 5.25 m."""
    polar = np.zeros((bins, beams), np.uint8)
    polar[10, :] = 250
    return SonarImage(
        sonar="sonar",
        encoding="png8",
        pose_frame="world",
        beams=beams,
        bins=bins,
        range_max_m=10.0,
        horizontal_fov_rad=math.radians(60.0),
        vertical_aperture_rad=math.radians(20.0),
        dynamic_range_db=40.0,
        pose_sonar=np.array([x_m, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]),
        data=encode_polar(polar, "png8"),
        sim_time_s=sim_time_s,
    )


def modelled(model: SceneModel, points_m_world: np.ndarray) -> float:
    """The share of the points whose cells the model holds occupied (queued for shore)."""
    queued = set(model.pending.keys[model.pending.occupied].tolist())
    return float(np.mean([k in queued for k in cell_keys(points_m_world, RESOLUTION_M).tolist()]))


def statuses(out_messages: list) -> list[PerceptionStatus]:  # type: ignore[type-arg]
    return [m for topic, m in out_messages if topic == "perception"]


def test_the_sonar_feeds_the_model_while_the_cameras_bring_nothing_and_hands_back() -> None:
    cfg = config()
    model = SceneModel(RESOLUTION_M, cfg.octree_max_range_m, track_period_s=0.0)
    intake = Intake(cfg, panel, model, 0.0)
    first = seabed("depth", 0.0, 1.0)
    out = intake.step(IntakeInputs(clouds=[first], pings=[ping(20.0, 1.0)]), 0.0)
    assert modelled(model, unpack_cloud(first)[0]) > 0.9  # the cameras' cloud is mapped
    assert modelled(model, echo_arcs(ping(20.0, 1.0), RESOLUTION_M)[0]) == 0.0  # the echoes are not
    assert statuses(out.messages)[0].scene_source == "cameras"
    # the cameras go blind: empty clouds; the sonar takes over `sonar_fallback_s` after the last point
    intake.step(IntakeInputs(clouds=[empty("stereo", 3.0)], pings=[ping(30.0, 3.0)]), 3.0)
    assert modelled(model, echo_arcs(ping(30.0, 3.0), RESOLUTION_M)[0]) == 0.0
    out = intake.step(IntakeInputs(clouds=[empty("stereo", 5.0)], pings=[ping(40.0, 5.5)]), 5.0)
    echoes = echo_arcs(ping(40.0, 5.5), RESOLUTION_M)[0]
    assert modelled(model, echoes) > 0.9
    assert intake.sim_time_s.get() == 5.5  # the echoes' time, later than the last cloud's
    assert statuses(out.messages)[0].scene_source == "sonar"
    assert intake.sonar.get() is not None and intake.sonar.get().sim_time_s == 5.5  # type: ignore[union-attr]
    # the cameras see again: they feed the model, the sonar no more
    back = seabed("depth", -20.0, 7.0)
    out = intake.step(IntakeInputs(clouds=[back], pings=[ping(60.0, 7.0)]), 7.0)
    assert modelled(model, unpack_cloud(back)[0]) > 0.9
    assert modelled(model, echo_arcs(ping(60.0, 7.0), RESOLUTION_M)[0]) == 0.0
    assert statuses(out.messages)[0].scene_source == "cameras"


def test_a_ros2_node_maps_in_the_models_place() -> None:
    cfg = config()
    model = SceneModel(RESOLUTION_M, cfg.octree_max_range_m, track_period_s=0.0)
    intake = Intake(cfg, panel, model, 0.0, maps=False)
    cloud = seabed("depth", 0.0, 1.0)
    out = intake.step(IntakeInputs(clouds=[cloud]), 0.0)
    assert len(model.pending) == 0 and intake.sim_time_s.get() == 1.0  # counted, not inserted
    assert statuses(out.messages)[0].points_per_s["depth"] > 0


@pytest.mark.parametrize("period_s", [2.0, 3.0])
def test_recognition_runs_every_recognition_period(period_s: float) -> None:
    """Each run decodes the latest image: a frame that does not decode is rejected once a run."""
    cfg = config(recognition_period_s=period_s)
    intake = Intake(cfg, panel, SceneModel(RESOLUTION_M, cfg.octree_max_range_m), 0.0)
    assert intake.step(IntakeInputs(), 0.0).rejected == []  # nothing to recognise from yet
    garbled = Image(
        camera="cam_left",
        encoding="jpeg",
        pose_frame="world",
        width_px=64,
        height_px=48,
        fx_px=50.0,
        fy_px=50.0,
        cx_px=32.0,
        cy_px=24.0,
        pose_camera=np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]),
        data=b"not a jpeg",
        sim_time_s=0.0,
    )
    runs = []
    for step in range(1, 29):
        now_s = 0.25 * step
        out = intake.step(IntakeInputs(image=garbled), now_s)
        if out.rejected:
            assert [topic for topic, _ in out.rejected] == ["image"]
            assert "decodes to nothing" in out.rejected[0][1]
            runs.append(now_s)
    assert runs == pytest.approx(list(np.arange(0.25, 7.01, period_s)))
    assert intake.objects.get() is None  # nothing recognised in it


def test_perception_status_counts_each_sources_points_every_period() -> None:
    cfg = config(perception_period_s=2.0)
    intake = Intake(cfg, panel, SceneModel(RESOLUTION_M, cfg.octree_max_range_m), 0.0)
    depth, stereo, sonar = (
        seabed("depth", 0.0, 0.0, n=1000),
        seabed("stereo", 5.0, 1.0, n=500),
        ping(9.0, 1.5),
    )
    published = {}
    inputs = {
        0.0: IntakeInputs(clouds=[depth]),
        1.0: IntakeInputs(clouds=[stereo]),
        1.5: IntakeInputs(pings=[sonar]),
    }
    for step in range(9):
        now_s = 0.5 * step
        found = statuses(intake.step(inputs.get(now_s, IntakeInputs()), now_s).messages)
        if found:
            published[now_s] = found[0]
    assert sorted(published) == [0.0, 2.0, 4.0]  # every perception_period_s
    status = published[2.0]
    assert status.window_s == pytest.approx(2.0)  # since the first message, within the window
    echoes = len(echo_arcs(sonar, RESOLUTION_M)[0])
    assert echoes > 0
    assert status.points_per_s == pytest.approx(
        {
            "depth": len(unpack_cloud(depth)[0]) / 2.0,
            "stereo": len(unpack_cloud(stereo)[0]) / 2.0,
            "sonar": echoes / 2.0,
        }
    )
    assert status.scene_source == "cameras" and status.sim_time_s == 1.0
    assert published[4.0].points_per_s["depth"] == pytest.approx(len(unpack_cloud(depth)[0]) / 4.0)


def test_perception_status_tells_the_scene_streams_backlog_till_it_is_sent() -> None:
    """The cells the model has queued for shore and not sent: all of a new cloud's, fewer as
    updates go, none once all went, the whole map again once shore asks for a snapshot."""
    cfg = config(perception_period_s=1.0)
    model = SceneModel(RESOLUTION_M, cfg.octree_max_range_m, track_period_s=0.0)
    intake = Intake(cfg, panel, model, 0.0)

    def backlog(now_s: float) -> int:
        return statuses(intake.step(IntakeInputs(), now_s).messages)[0].scene_backlog_cells

    out = intake.step(IntakeInputs(clouds=[seabed("depth", 0.0, 1.0)]), 0.0)
    queued = len(model.pending)
    assert queued > 0 and statuses(out.messages)[0].scene_backlog_cells == queued
    assert model.next_update(1.0, 2000) is not None  # a first part goes
    assert 0 < len(model.pending) < queued and backlog(1.0) == len(model.pending)
    while model.next_update(1.0) is not None:
        pass
    assert backlog(2.0) == 0
    model.request_snapshot()
    assert backlog(3.0) == len(model.published) == queued


def test_a_sonar_frame_that_does_not_decode_is_rejected_and_kept_as_the_latest() -> None:
    cfg = config()
    intake = Intake(cfg, panel, SceneModel(RESOLUTION_M, cfg.octree_max_range_m), 0.0)
    bad = dataclasses.replace(ping(0.0, 2.0), data=b"\x00not an image")
    out = intake.step(IntakeInputs(pings=[bad]), 0.0)
    assert [topic for topic, _ in out.rejected] == ["sonar"] and "decodes to nothing" in out.rejected[0][1]
    assert intake.sonar.get() is bad  # the stream sends the latest frame on (and rejects it there)
    assert statuses(out.messages)[0].points_per_s["sonar"] == 0.0


def test_in_a_hybrid_run_the_panel_is_found_by_its_shape_alone_where_the_registration_puts_it() -> None:
    """With the site registered (origin (30, -12, 0) m, heading 40 deg), the panel stands in the
    vessel's world (the navigation frame) at the registered pose: the intake looks for it there,
    facing as turned, and finds it by the cloud alone (no image, no marker). Looked for at the site
    package's own pose, or there but unturned, it is not found."""
    heading = math.radians(40.0)
    hybrid = HybridConfig(
        vehicle=("nav", "joints"), site_origin_m_nav=(30.0, -12.0, 0.0), site_heading_rad=heading
    )
    turn = rotation_about(np.array([0.0, 0.0, 1.0]), heading)
    position = turn @ np.array(panel.position_m_world) + hybrid.site_origin_m_nav
    points = model_points(panel, 0.01) @ turn.T + position
    camera = position + turn @ np.array([-2.0, 0.0, 0.0])  # 2 m in front of its face
    cloud = pack_cloud("depth", points, np.full((len(points), 3), 128, np.uint8), camera, 0.001, 0.0)

    def recognised(hybrid: HybridConfig | None) -> RecognisedObjects | None:
        cfg = config()
        intake = Intake(cfg, panel, SceneModel(RESOLUTION_M, cfg.octree_max_range_m), 0.0, False, hybrid)
        intake.step(IntakeInputs(clouds=[cloud]), 0.0)
        return intake.objects.get()

    found = recognised(hybrid)
    assert found is not None and found.method == "shape"
    pose = found.poses_world[found.names.index("panel")]
    assert np.linalg.norm(pose[:3] - position) < 0.02, pose
    assert np.degrees(rotation_error_rad(rotation_of(pose[3:]), turn)) < 1.0, pose
    assert recognised(None) is None  # at the site package's pose, 33 m away: nothing there
    unturned = PanelTracker(panel, expected_m_world=position)
    assert unturned.update(None, None, points) is None  # the face is 40 deg off the guess's
    # with no registration, the site package's pose untouched
    expected_m_world, rotation = expected_pose(panel, HybridConfig())
    assert expected_m_world.tolist() == list(panel.position_m_world) and np.array_equal(rotation, np.eye(3))
    assert not np.signbit(rotation).any()
