"""Onboard's frame sets without Zenoh (frame_sets.FrameSets), on frames MuJoCo renders at the
default mission's start, the panel ahead: the newest complete set is worked on and the older
ones shed, a set with no pose estimate skipped, stereo on every N-th set by its index (cam_right
rendered for those alone), the image at its rate, the core resting after its work, frames that
do not decode rejected with their reason."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from abyss.config import Config
from abyss.config.simulation import SimulationConfig
from abyss.config.stations import OnboardConfig
from abyss.description.robot import robot_at
from abyss.interface.images import decode_image
from abyss.interface.messages import Image
from abyss.stations.onboard.frame_sets import FrameSetInputs, FrameSets
from abyss.stations.onboard.navigation import PoseHistory
from abyss.stations.simulation import cameras_of_set
from abyss.stations.simulation.encoding import encode_image
from abyss.stations.simulation.rendering import Cameras
from abyss.stations.simulation.world import World

ROBOT = robot_at("")  # the shipped robot package


DEPTH_ONLY = OnboardConfig(cloud_sources=("depth",))
RATE_HZ = 1.0  # the cameras' (simulation.camera_rate_hz): a set's index is its time [s]


@dataclasses.dataclass(frozen=True)
class Scene:
    frames: dict[str, Image]  # one frame of each camera
    poses: PoseHistory  # the true pose from 0 to 100 s


@pytest.fixture(scope="module")
def scene() -> Scene:
    world = World(SimulationConfig(), np.random.default_rng(0))
    cameras = Cameras(world.model, 160, 120, depth_camera=ROBOT.depth_camera)
    try:
        frames = {camera: encode_image(cameras, world.data, camera, 90) for camera in ROBOT.cameras}
    finally:
        cameras.close()
    truth = world.truth()
    poses = PoseHistory(span_s=200.0).added(
        (t, truth.position_m_world, truth.orientation_wxyz_world) for t in np.arange(0.0, 100.0, 0.5)
    )
    return Scene(frames, poses)


def frames_at(
    scene: Scene, sim_time_s: float, cameras: tuple[str, ...] = ROBOT.cameras
) -> list[tuple[str, Image]]:
    """One set of frames, as if taken at `sim_time_s` [s]."""
    return [(c, dataclasses.replace(scene.frames[c], sim_time_s=sim_time_s)) for c in cameras]


def test_of_several_complete_sets_only_the_newest_is_worked_on_and_the_others_are_shed(scene: Scene) -> None:
    core = FrameSets(DEPTH_ONLY, RATE_HZ, ROBOT.spec.cameras)
    frames = [
        *frames_at(scene, 1.0),
        *frames_at(scene, 1.1),
        *frames_at(scene, 1.2),
        *frames_at(scene, 1.3)[:1],
    ]
    out = core.step(FrameSetInputs(frames, scene.poses), 0.0)
    assert out.taken_s == 1.2 and out.shed == 2 and not out.rejected
    assert [cloud.source for cloud in out.clouds] == ["depth"] and out.clouds[0].count > 100
    assert all(cloud.sim_time_s == 1.2 for cloud in out.clouds)
    assert set(core.sets) == {1.3}  # a newer set not yet complete waits for its frames
    core.finished(0.0)
    out = core.step(FrameSetInputs(frames_at(scene, 1.3)[1:], scene.poses), 0.1)
    assert out.taken_s == 1.3 and out.shed == 0 and len(out.clouds) == 1
    stale = frames_at(scene, 1.25)  # complete, but older than the set taken: let go on the next set
    out = core.step(FrameSetInputs([*stale, *frames_at(scene, 1.4)], scene.poses), 0.2)
    assert out.taken_s == 1.4 and out.shed == 1 and not core.sets


def test_sets_that_never_complete_are_let_go_but_the_newest_few(scene: Scene) -> None:
    core = FrameSets(DEPTH_ONLY, RATE_HZ, ROBOT.spec.cameras)
    lonely = [frame for t in np.arange(1.0, 2.0, 0.1) for frame in frames_at(scene, float(t), ("cam_left",))]
    out = core.step(FrameSetInputs(lonely, scene.poses), 0.0)
    assert out.taken_s is None and out.shed == 0 and not out.clouds
    assert len(core.sets) == 4 and min(core.sets) == pytest.approx(1.6)


def test_a_set_without_a_navigation_estimate_is_skipped(scene: Scene) -> None:
    core = FrameSets(OnboardConfig(stereo_every=2), RATE_HZ, ROBOT.spec.cameras)
    out = core.step(FrameSetInputs(frames_at(scene, 150.0), scene.poses), 0.0)  # the estimate ends at 99.5 s
    assert out.skipped_s == 150.0 and out.taken_s is None
    assert not out.clouds and out.image is None and not out.rejected and not core.sets
    out = core.step(FrameSetInputs(frames_at(scene, 99.6), scene.poses), 0.1)  # within the tolerance
    assert out.taken_s == 99.6 and out.skipped_s is None
    assert [c.source for c in out.clouds] == ["depth"]  # set 100: not one of the stereo matcher's
    out = core.step(FrameSetInputs(frames_at(scene, 5.0), PoseHistory()), 0.2)  # no estimate at all yet
    assert out.skipped_s == 5.0 and not out.clouds


def test_stereo_runs_on_every_nth_set_by_its_index_and_only_those_sets_wait_for_the_right_camera(
    scene: Scene,
) -> None:
    config = Config(
        onboard=OnboardConfig(stereo_every=3), simulation=SimulationConfig(camera_rate_hz=RATE_HZ)
    )
    core = FrameSets(config.onboard, RATE_HZ, ROBOT.spec.cameras)
    sources, counts = [], []
    for i in range(6):
        t = 1.0 + i
        rendered = cameras_of_set(config, t)  # what the simulation renders for the set
        assert ("cam_right" in rendered) == (round(t) % 3 == 1)
        without_right = [frame for frame in frames_at(scene, t, rendered) if frame[0] != "cam_right"]
        out = core.step(FrameSetInputs(without_right, scene.poses), float(i))
        if "cam_right" in rendered:  # a stereo set waits for its right frame
            assert out.taken_s is None and set(core.sets) == {t}
            out = core.step(FrameSetInputs(frames_at(scene, t, ("cam_right",)), scene.poses), float(i))
        assert out.taken_s == t
        core.finished(float(i))
        sources.append(tuple(cloud.source for cloud in out.clouds))
        counts += [cloud.count for cloud in out.clouds]
    stereo_and_depth, depth = ("depth", "stereo"), ("depth",)
    assert sources == [stereo_and_depth, depth, depth, stereo_and_depth, depth, depth]
    assert min(counts) > 100  # the stereo clouds as well as the depth ones hold the panel's face
    no_stereo = Config(onboard=DEPTH_ONLY)
    assert all("cam_right" not in cameras_of_set(no_stereo, float(t)) for t in range(6))  # never consumed


def test_the_image_goes_on_at_its_rate_placed_in_the_world(scene: Scene) -> None:
    core = FrameSets(dataclasses.replace(DEPTH_ONLY, image_rate_hz=2.0), RATE_HZ, ROBOT.spec.cameras)
    sent = []
    for i, now_s in enumerate((0.0, 0.2, 0.4, 0.5, 0.9, 1.0, 1.1)):
        out = core.step(FrameSetInputs(frames_at(scene, 1.0 + i), scene.poses), now_s)
        core.finished(now_s)
        assert out.taken_s is not None
        if out.image is not None:
            sent.append(now_s)
            image = out.image
    assert sent == [0.0, 0.5, 1.0]
    left = scene.frames["cam_left"]
    assert image.pose_frame == "world" and image.camera == "cam_left" and image.sim_time_s == 6.0
    assert decode_image(image).shape == (left.height_px, left.width_px, 3)
    # the camera sits on the vehicle, which is where the pose estimate says
    position_m_world, _ = scene.poses.at(6.0)  # type: ignore[misc]
    assert 0.05 < np.linalg.norm(image.pose_camera[:3] - position_m_world) < 2.0
    quiet = FrameSets(dataclasses.replace(DEPTH_ONLY, image_rate_hz=0.0), RATE_HZ, ROBOT.spec.cameras)
    assert quiet.step(FrameSetInputs(frames_at(scene, 1.0), scene.poses), 0.0).image is None


def test_the_core_rests_after_a_set_so_as_to_be_busy_its_share_of_the_time(scene: Scene) -> None:
    core = FrameSets(dataclasses.replace(DEPTH_ONLY, perception_max_busy=0.25), RATE_HZ, ROBOT.spec.cameras)
    assert core.step(FrameSetInputs(frames_at(scene, 1.0), scene.poses), 10.0).taken_s == 1.0
    core.finished(10.1)  # 0.1 s of work: rest until 10.4
    for now_s, t in ((10.2, 1.1), (10.35, 1.2)):
        out = core.step(FrameSetInputs(frames_at(scene, t), scene.poses), now_s)
        assert out.taken_s is None and out.shed == 0 and not out.clouds  # the frames wait
    out = core.step(FrameSetInputs(frames_at(scene, 1.3), scene.poses), 10.4)
    assert out.taken_s == 1.3 and out.shed == 2


def test_frames_that_do_not_decode_or_sit_in_the_wrong_frame_are_rejected_with_the_reason(
    scene: Scene,
) -> None:
    core = FrameSets(DEPTH_ONLY, RATE_HZ, ROBOT.spec.cameras)
    frames = frames_at(scene, 1.0)
    garbled = [(c, dataclasses.replace(f, data=b"not a jpeg") if c == "cam_left" else f) for c, f in frames]
    out = core.step(FrameSetInputs(garbled, scene.poses), 0.0)
    assert out.taken_s == 1.0 and not out.clouds and out.image is None
    assert (
        len(out.rejected) == 1 and "cam_left" in out.rejected[0] and "decodes to nothing" in out.rejected[0]
    )
    core.finished(0.0)
    misplaced = [
        (c, dataclasses.replace(f, pose_frame="world") if c == "cam_depth" else f)
        for c, f in frames_at(scene, 2.0)
    ]
    out = core.step(FrameSetInputs(misplaced, scene.poses), 0.1)
    assert out.rejected == ["cam_depth: pose in the world frame, expected the vehicle's"] and not out.clouds
    core.finished(0.1)
    out = core.step(FrameSetInputs(frames_at(scene, 3.0), scene.poses), 0.2)  # good frames again
    assert not out.rejected and len(out.clouds) == 1 and out.image is not None
